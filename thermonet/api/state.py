"""What a :class:`~thermonet.api.DriftEstimator` holds, declared below the modules that read
and write it.

:class:`EstimatorState` names, with their types, the constructor's parameters that saving and
loading read and the attributes a fit sets (``*_``; :class:`~thermonet.api.DriftEstimator`
documents each).  The estimator is this class with its methods; the modules that save, load,
export and track it (:mod:`thermonet.api.persistence`) and fit it as a whole-sensor model
(:mod:`thermonet.api.sensor_mode`) take an ``EstimatorState``, so that neither imports the
estimator that imports them: no circle inside the package.  Declarations only: nothing is
set here, so an unfitted estimator has none of the ``*_`` attributes, as before.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from ..core.params import Params
from ..core.trainconfig import TrainConfig
from ..features.inputs import FeatureSpec
from ..features.target import Target
from ..models.specs import FamilySpec

if TYPE_CHECKING:
    from ..models.composite import DriftModels

__all__ = ["EstimatorState", "State"]


class EstimatorState(Params):
    """The estimator's parameters and fitted attributes (module docstring)."""

    if TYPE_CHECKING:   # DriftEstimator.__init__ (its family and inputs; the rest by keyword)
        def __init__(self, family: FamilySpec | str,
                     inputs: Sequence[str] | str | None = None, **params: Any) -> None: ...

    # -- parameters (DriftEstimator.__init__)
    family: Any                         # a spec, a name, or a name with its keywords
    t_ref: str | float
    target: str
    train_on: str
    gap_s: float | str
    t_ref_window_min: float
    stderr: str
    # -- set by fit (or load)
    model_: DriftModels
    spec_: FeatureSpec
    outputs_: list[str]
    targets_: Target
    units_: dict[str, str]
    signal_units_: dict[str, str]
    device_id_: str
    n_features_in_: int
    n_params_: int
    train_config_: TrainConfig
    history_: list[dict[str, Any]]
    best_epoch_: int
    best_val_: float | None
    val_score_: float | None
    val_ratios_: dict[str, float] | None
    tuned_: dict[str, Any]
    parameters_: Any                    # a pandas.DataFrame
    covariance_: dict[str, np.ndarray]
    band_: Any                          # a thermonet.scoring.band.Band, or None
    data_source_: dict[str, Any]
    mlflow_run_id_: str
    fit_seconds_: float

    def _check_fitted(self, what: str) -> DriftModels:
        """The fitted model, or :class:`~thermonet.api.fitted.NotFittedError`."""
        raise NotImplementedError

    def _family_spec(self) -> FamilySpec:
        """The family as a spec."""
        raise NotImplementedError

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the fitted model as a checkpoint."""
        raise NotImplementedError


#: An estimator class or one of its subclasses, as ``load`` makes one.
State = TypeVar("State", bound=EstimatorState)
