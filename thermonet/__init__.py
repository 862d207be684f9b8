"""thermonet: train, judge and export temperature-drift models for inertial sensors.

The Python API (:class:`DriftEstimator`, :func:`compare`, :func:`simulate`, :func:`read`,
:func:`time_blocks`, :class:`TimeBlockSplit`, :class:`TrainConfig`, :class:`Recording`,
:class:`Dataset`, :func:`load_config`, and the family specs :class:`Linear`, :class:`Poly`,
:class:`Lorentz`, :class:`Fuzzy`, :class:`RBF`, :class:`MLP`, :class:`GRU`;
:mod:`thermonet.api` describes it) is
importable from here; each name loads its module on first access, so ``import thermonet`` (and
the command line's start-up) stays free of torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .core.version import __version__

if TYPE_CHECKING:
    from .api import (
        ComparisonResult,
        DriftEstimator,
        NotFittedError,
        TimeBlockSplit,
        compare,
        read,
        simulate,
        time_blocks,
    )
    from .core.recording import Dataset, Recording
    from .core.trainconfig import TrainConfig
    from .models.specs import GRU, MLP, RBF, FamilySpec, Fuzzy, Linear, Lorentz, Poly
    from .training.config import load_config

__all__ = ["DriftEstimator", "NotFittedError", "simulate", "read", "compare", "ComparisonResult",
           "time_blocks", "TimeBlockSplit", "TrainConfig", "Recording", "Dataset", "load_config",
           "FamilySpec", "Linear", "Poly", "Lorentz", "Fuzzy", "RBF", "MLP", "GRU", "__version__"]

_LAZY = {
    "DriftEstimator": "api", "NotFittedError": "api", "simulate": "api", "read": "api",
    "compare": "api", "ComparisonResult": "api", "time_blocks": "api", "TimeBlockSplit": "api",
    "TrainConfig": "core.trainconfig", "Recording": "core.recording", "Dataset": "core.recording",
    "load_config": "training.config",
    **{k: "models.specs" for k in ("FamilySpec", "Linear", "Poly", "Lorentz", "Fuzzy", "RBF",
                                   "MLP", "GRU")},
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
