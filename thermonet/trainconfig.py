"""How a family is trained: :class:`TrainConfig`, the ``train`` section of a config.

Kept apart from :mod:`thermonet.train` so that reading and checking a config
never imports torch (``thermonet.config`` imports this module only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .errors import ConfigError

__all__ = ["TrainConfig"]

_OPTIMIZERS = ("adam", "lbfgs")
_DEVICES = ("auto", "cpu", "cuda")


@dataclass
class TrainConfig:
    """How a family is trained (all losses in standardised MSE units).

    Attributes
    ----------
    optimizer : "adam" or "lbfgs"
    lr : float
        Learning rate (Adam step size; L-BFGS initial step, 1.0 is usual).
    max_epochs : int
        Full-batch epochs at most (one optimizer step each; an L-BFGS step runs
        up to 20 inner iterations).
    patience : int
        Epochs without an improvement larger than ``min_delta`` of the
        monitored loss (validation, or training without a validation run)
        before stopping.
    min_delta : float
        Smallest improvement that counts, standardised MSE (absolute).
    seed : int
        Seeds torch and every numpy/scikit-learn draw (k-means, random centres).
    device : "auto", "cpu" or "cuda"
        "auto" is CUDA when available; the returned model is always on CPU.
    max_train_samples : int
        Training (and, separately, validation) samples kept per fit.  Longer
        data are **decimated evenly** — every k-th sample of every run, with
        k = ceil(total / max) — never randomly sampled, so the time structure
        (ramps, soaks) is kept.
    """

    # L-BFGS by default: every family starts from a closed-form or heuristic fit, and
    # full-batch L-BFGS polishes such a start in a few steps where Adam first wanders
    # off it (experiments/bench_rbf_speed.py measures both).
    optimizer: str = "lbfgs"
    lr: float = 1.0
    max_epochs: int = 100
    patience: int = 10
    min_delta: float = 1e-7
    seed: int = 0
    device: str = "cpu"
    max_train_samples: int = 20000

    def __post_init__(self) -> None:
        if self.optimizer not in _OPTIMIZERS:
            raise ConfigError(f"train.optimizer must be one of {', '.join(_OPTIMIZERS)}, "
                              f"got {self.optimizer!r}")
        if self.device not in _DEVICES:
            raise ConfigError(f"train.device must be one of {', '.join(_DEVICES)}, "
                              f"got {self.device!r}")
        for key, lo in (("max_epochs", 0), ("patience", 1), ("max_train_samples", 10)):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ConfigError(f"train.{key} must be an integer >= {lo}, got {v!r}")
        for key in ("lr", "min_delta"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v < 0 or (key == "lr" and v == 0):
                raise ConfigError(f"train.{key} must be a finite number "
                                  f"{'> 0' if key == 'lr' else '>= 0'}, got {v!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int):
            raise ConfigError(f"train.seed must be an integer, got {self.seed!r}")
