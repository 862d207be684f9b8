"""What a fitted :class:`~thermonet.api.DriftEstimator` does: predict, compensate, score,
report, save and export.

:class:`FittedEstimator` is the estimator's half that uses a fitted model (the attributes a
fit or :meth:`~thermonet.api.DriftEstimator.load` set, :class:`~thermonet.api.state.EstimatorState`);
:class:`~thermonet.api.DriftEstimator` is it with the constructor, scikit-learn's contract
and the fit (:mod:`thermonet.api.estimator`).  :class:`NotFittedError` is what each method
raises before a fit.  Each method checks what every model kind shares, then calls its model
kind's own body (:data:`thermonet.api.modes.MODES`, by ``model``: :mod:`~thermonet.api.bias_mode`
or :mod:`~thermonet.api.sensor_mode`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ConfigError, ThermonetError
from ..core.recording import Recording
from .checks import path as a_path
from .checks import text, whole
from .data import Data
from .modes import mode_of
from .state import EstimatorState

if TYPE_CHECKING:
    from ..features.inputs import FeatureSpec
    from ..models.composite import DriftModels

__all__ = ["FittedEstimator", "NotFittedError", "MULTIOUTPUT"]

#: ``score(multioutput=...)``'s named rules, as scikit-learn's ``r2_score`` names them.
MULTIOUTPUT = ("uniform_average", "raw_values", "variance_weighted")


class NotFittedError(ThermonetError, AttributeError):
    """``predict``/``compensate``/``score``/``save``/``export`` before ``fit``."""


class FittedEstimator(EstimatorState):
    """A fitted estimator's methods (module docstring); ``DriftEstimator`` is this class with
    its constructor and fit."""

    model: str                   # a key of thermonet.api.modes.MODES (DriftEstimator.__init__)

    def _part(self, rec: Recording, spec: FeatureSpec, outputs: list[str]) -> Any:
        from ..training.parts import build_part  # lazy: loads yaml

        # a fitted model's own signal order (a per-axis model's: the union of its parts')
        model = self.__dict__.get("model_")
        signals = list(model.signals) if model is not None else spec.signals
        return build_part(rec, signals=signals, outputs=outputs, target=self.targets_,
                          gap_s=spec.gap_s)

    @property
    def axis_models_(self) -> dict[str, str | None] | None:
        """For a per-axis model (a ``compare`` that chose a candidate per axis, loaded with
        :meth:`load`): ``{axis: the label of the candidate that computes it, or None where
        the axis is left raw}``; None for a single-family model."""
        from ..models.composite import AxisModels  # torch boundary

        model = self._check_fitted("axis_models_")
        return model.axis_table() if isinstance(model, AxisModels) else None

    def _check_fitted(self, what: str) -> DriftModels:
        model = self.__dict__.get("model_")
        if model is None:
            raise NotFittedError(f"this DriftEstimator({self.family!r}) is not fitted yet; "
                                 f"call fit(...) before {what}()")
        return model

    # --------------------------------------------------------------- prediction
    def predict(self, data: Data, *, return_band: bool = False) -> Any:
        """Predicted drift (N, axes), float64, in the outputs' units.

        ``return_band=True`` returns ``(drift, band)``: ``band`` (N, axes) the half-width of
        the residual-drift band at each row's temperature (:attr:`band_`,
        :mod:`thermonet.scoring.band`: a window mean of ``raw − drift`` lies within ± it of
        the run's mean residual for ``band_.level`` of windows; wider past the trained range;
        NaN where the temperature is).  Only a model from ``compare`` with cross-validation
        folds carries a band; asking another refuses, saying so.

        ``data``: a Recording, a list of them or a Dataset; for several runs the rows are
        the runs' samples one run after the other (each run's dynamic inputs computed on
        that run alone).  Evaluated as on board: signals clamped to the trained range
        (``model_.out_of_range`` flags the samples outside it).

        What ``data`` must carry: the model's signals (the temperature, a proxy) in the
        units it was trained on, the temperature in degC (a unit thermonet does not know is
        refused, as by ``fit``).  A drift model needs no output channel, so a run without
        the model's outputs is predicted; one that carries them in another unit than the
        training data's is refused, naming both (the drift would be in the wrong unit).  A
        sensor model (``model="sensor"``) needs its outputs, as ``score`` does.
        """
        self._check_fitted("predict")
        if return_band and self.__dict__.get("band_") is None:
            raise ThermonetError("predict(return_band=True): this model carries no band (the "
                                 "band comes from compare's out-of-fold residuals: load a "
                                 "checkpoint compare wrote with selection.folds >= 2)")
        return mode_of(self).predict(self, data, return_band=return_band)

    def compensate(self, data: Data) -> Any:
        """``data`` with the predicted drift subtracted from each modelled output: a
        Recording for a Recording, a Dataset for a Dataset, a list for a list."""
        self._check_fitted("compensate")
        return mode_of(self).compensate(self, data)

    def score(self, data: Data, y: None = None, *,
              multioutput: str | Sequence[float] = "uniform_average") -> Any:
        """Fraction of the error's variance removed (higher is better): ``compare``'s
        offset-free score, per axis and aggregated as scikit-learn's ``r2_score`` aggregates.

        .. math:: s = 1 - \\frac{1}{A}\\sum_a \\frac{\\sum_g \\sum_{i \\in g}
                  (e_{a,i} - \\bar e_{a,g})^2}{\\sum_g \\sum_{i \\in g}
                  (y_{a,i} - \\bar y_{a,g})^2},\\qquad e = y - \\hat y

        with :math:`y_a` the target (output − reference; the output itself for a ``zero`` or
        ``at-t-ref`` axis), summed over every sample of ``data`` (a Recording, a list of
        them or a Dataset), each source run :math:`g` about its own mean (blocks cut by
        :func:`~thermonet.api.time_blocks` count as their run): a constant — a bias, gravity,
        a scale factor's nominal value — is no error, as in every thermonet score.
        :math:`1 - s` is the square of ``compare``'s score ratio on the same data
        (``results.json`` ``axes.<axis>.score_ratio``).  1 is perfect, 0 no better than the
        raw output, negative worse.  ``y`` is scikit-learn's slot and must be None (the
        drift is in the recordings).  Data in another unit than the training data is
        refused, naming both units.

        ``multioutput`` says how the axes' scores :math:`s_a = 1 - r_a` combine:
        ``"uniform_average"`` (the default, the formula above: every axis weighs the same —
        one axis made worse than raw, :math:`s_a < 0`, can hide behind good ones, so look at
        the axes too), ``"raw_values"`` (an array, one score per axis in :attr:`outputs_`
        order), ``"variance_weighted"`` (each axis weighted by its raw error variance: the
        sum of the error variances over the sum of the raw ones) or an array of one
        non-negative weight per axis (a weighted mean).
        """
        self._check_fitted("score")
        if y is not None:
            raise ThermonetError(f"score(y): expected None (the drift is taken from the "
                                 f"recordings), got {type(y).__name__}")
        weights: np.ndarray | None = None
        if isinstance(multioutput, str):
            if multioutput not in MULTIOUTPUT:
                raise ConfigError(f"score(multioutput): {multioutput!r} is not one of "
                                  f"{', '.join(MULTIOUTPUT)} or an array of weights per axis")
        else:
            weights = np.asarray(multioutput, dtype=np.float64).reshape(-1) \
                if not isinstance(multioutput, (bool, bytes)) else np.empty(0)
            if weights.size != len(self.outputs_) or not np.all(np.isfinite(weights)) \
                    or np.any(weights < 0) or weights.sum() <= 0:
                raise ConfigError(f"score(multioutput): expected {len(self.outputs_)} finite "
                                  "non-negative weights (one per axis, not all zero)")
        comp, raw = self._variances(data, "score")
        ratios = np.array([c / r if r > 0 else float("inf")
                           for c, r in zip(comp, raw, strict=True)])
        if weights is not None:
            return 1.0 - float(np.average(ratios, weights=weights))
        if multioutput == "raw_values":
            return 1.0 - ratios
        if multioutput == "variance_weighted":
            return 1.0 - float(np.sum(comp) / np.sum(raw)) if np.sum(raw) > 0 else -math.inf
        return 1.0 - float(np.mean(ratios))

    def _ratios(self, data: Data, what: str) -> np.ndarray:
        """Per axis, the error's variance after / before (each source run about its mean)."""
        comp, raw = self._variances(data, what)
        return np.array([c / r if r > 0 else float("inf") for c, r in zip(comp, raw, strict=True)])

    def _variances(self, data: Data, what: str) -> tuple[np.ndarray, np.ndarray]:
        """Per axis, the error's sum of squares after and before (each run about its mean)."""
        self._check_fitted(what)
        return mode_of(self).variances(self, data, what)

    # ------------------------------------------------------------ parameters
    def report(self) -> str:
        """A fit report in lmfit's manner: the family, data and fit, then per axis each
        parameter's value ± standard error and unit (:attr:`parameters_`)."""
        self._check_fitted("report")
        return mode_of(self).report(self)

    # ------------------------------ save, export (thermonet.api.persistence; load: DriftEstimator's)
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the fitted model as a thermonet checkpoint (atomic; loads with
        ``weights_only=True``; ``thermonet export`` reads it)."""
        self._check_fitted("save")
        return mode_of(self).save(self, a_path(path, "save(path)"))  # type: ignore[arg-type]

    def export(self, path: str | os.PathLike[str], format: str = "onnx", *,
               device_id: int | None = None, instance: int | None = None) -> Path:
        """Export through the format registry (:data:`thermonet.exporting.FORMATS`).

        ``device_id``/``instance`` apply to the autopilot formats (see
        ``thermonet export --help``).
        """
        a_path(path, "export(path)")
        text(format, "export(format)", rule="a format name such as 'onnx'")
        whole(device_id, "export(device_id)", 0, none=True)
        whole(instance, "export(instance)", 0, none=True)
        self._check_fitted("export")
        return mode_of(self).export(self, path, format, device_id=device_id, instance=instance)
