"""The bottom layer: what every other layer may use and that uses none of them.

Errors (one exception per kind of mistake, each printed by the command line as one line),
:class:`~thermonet.core.recording.Recording` and :class:`~thermonet.core.recording.Dataset`
(the runs, their units and signal names), safe file names and atomic writes, the YAML
loader and the typed-dataclass schema every config section is read through, the training
settings (:class:`~thermonet.core.trainconfig.TrainConfig`), output directories and the
fleet executors.  Nothing here imports torch or another thermonet layer.
"""
