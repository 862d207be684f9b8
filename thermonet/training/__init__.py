"""The one split pipeline: parts → fit → score, above the models, the scoring and the simulator.

A comparison config is loaded and checked whole, torch-free (:mod:`thermonet.training.config`);
the data are split into train, validation and test runs (:mod:`thermonet.training.splits`);
each split's parts — signal and target matrices of its train, validation and test runs — are
built (:mod:`thermonet.training.parts`); a family is fitted (:mod:`thermonet.training.train`)
and saved as a checkpoint (:mod:`thermonet.training.checkpoint`);
:mod:`thermonet.training.pipeline` strings these into the one split pipeline that compare,
fleet, calibrate and the Python API all run.
"""
