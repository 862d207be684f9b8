"""Judging predictions: metrics, verdicts, model selection and fleet limits (numpy only).

Error metrics and Allan deviation (:mod:`thermonet.scoring.metrics`), paired block-bootstrap
verdicts on held-out blocks (:mod:`thermonet.scoring.verdicts`), the one deal of rows to
cross-validation folds and its purge (:mod:`thermonet.scoring.folds`), the choice of a family from
validation scores and cross-validated out-of-fold errors (:mod:`thermonet.scoring.selection`),
and a fleet's limits, spread and outliers (:mod:`thermonet.scoring.fleetstats`).  It sits
beside :mod:`thermonet.models` and :mod:`thermonet.sim`, above the features: it judges
arrays, whatever produced them.
"""
