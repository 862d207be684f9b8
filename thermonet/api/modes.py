"""The estimator's strategy per model kind: :data:`MODES`, keyed by ``DriftEstimator(model=...)``
(the config's ``model:`` value, :data:`thermonet.models.shipped.MODEL_KINDS`).

Each entry is a module with the same functions — ``fit``, ``predict``, ``compensate``,
``variances``, ``report``, ``save``, ``export``, ``load`` (:class:`EstimatorMode`) —
:mod:`thermonet.api.bias_mode` for a drift model per axis, :mod:`thermonet.api.sensor_mode`
for the whole-sensor model.  The estimator's methods look the entry up and call it: a
dict lookup, not a switch on the kind's name; what a kind requires of the estimator's
arguments is data (:attr:`~thermonet.models.shipped.ModelKind.estimator_requires`), and a
checkpoint is loaded by the kind its ``format`` names
(:func:`thermonet.training.checkpoint.checkpoint_kind`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..core.errors import ConfigError
from ..models.shipped import MODEL_KINDS
from . import bias_mode, sensor_mode
from .data import Data
from .state import State

__all__ = ["EstimatorMode", "MODES", "MODELS", "check_model", "mode_of", "load"]


class EstimatorMode(Protocol):
    """What the estimator calls on its model kind's entry (module docstring)."""

    def fit(self, est: Any, train: Data, val: Data | None, *, config: Any, inputs: list[str],
            family: Any, track: bool, tracking_uri: str | None, experiment: str) -> None: ...

    def predict(self, est: Any, data: Data, *, return_band: bool = False) -> Any: ...

    def compensate(self, est: Any, data: Data) -> Any: ...

    def variances(self, est: Any, data: Data, what: str) -> tuple[np.ndarray, np.ndarray]: ...

    def report(self, est: Any) -> str: ...

    def save(self, est: Any, path: str | os.PathLike[str]) -> Path: ...

    def export(self, est: Any, path: str | os.PathLike[str], fmt: str, *,
               device_id: int | None, instance: int | None) -> Path: ...

    def load(self, cls: type[State], path: str | os.PathLike[str]) -> State: ...


#: The estimator's strategy per model kind.
MODES: dict[str, EstimatorMode] = {"bias": bias_mode, "sensor": sensor_mode}
assert set(MODES) == set(MODEL_KINDS), "every model kind has its estimator strategy"

#: What ``DriftEstimator(model=...)`` takes.
MODELS = tuple(MODES)


def check_model(est: Any) -> None:
    """``model`` is one of :data:`MODELS`, and the arguments its kind requires have the value
    it takes (:attr:`~thermonet.models.shipped.ModelKind.estimator_requires`: a sensor model
    takes ``target="drift"`` and ``train_on="all"`` only; one line naming the argument)."""
    if not isinstance(est.model, str) or est.model not in MODES:
        raise ConfigError(f"model: {est.model!r} is not one of {', '.join(MODELS)}")
    for key, (want, why) in MODEL_KINDS[est.model].estimator_requires.items():
        got = getattr(est, key)
        if got != want:
            raise ConfigError(why.format(got=got))


def mode_of(est: Any) -> EstimatorMode:
    """The strategy of ``est``'s model kind."""
    return MODES[est.model]


def load(cls: type[State], path: str | os.PathLike[str]) -> State:
    """An estimator fitted as the checkpoint at ``path``, by the kind its format names."""
    from ..training.checkpoint import checkpoint_kind  # torch boundary

    return MODES[checkpoint_kind(Path(path))].load(cls, path)
