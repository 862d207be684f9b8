"""How a family is trained: :class:`TrainConfig`, the ``train`` section of a config.

Kept apart from :mod:`thermonet.training.train` so that reading and checking a config
never imports torch (``thermonet.training.config`` imports this module only).
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
        Training (and, separately, validation) samples kept per fit, after the
        averaging below.  Longer data are averaged over longer windows (k
        samples each, k = ceil(total / max)) — or, for runs given without their
        time, decimated evenly (every k-th sample) — never randomly sampled, so
        the time structure (ramps, soaks) is kept.
    average_s : float
        Training and validation data are **averaged** into windows of this many
        seconds before fitting (signals and targets alike, the signals after
        they were computed at full rate, a window never spanning a gap in time),
        instead of being thinned: a 100 Hz recording keeps its information and
        its noise falls √100-fold, where thinning would throw 99 % of it away.
        Default 1 s: far below any thermal time constant (minutes), so the
        drift is unchanged, and a no-op at ≤ 1 Hz.  0 turns it off.  Held-out
        metrics are computed at full resolution regardless (``compare``).
    threads : int
        torch intra-op threads while this fit runs (restored afterwards), and the
        cap on numpy's and scikit-learn's native pools (OpenBLAS/MKL/OpenMP, via
        threadpoolctl) meanwhile — what ``OMP_NUM_THREADS`` would set, for the fit
        (a comparison: for the whole comparison) only.
        Default 1: these models are small, a second thread buys little, and on
        a busy machine (families, units or other jobs side by side) it costs
        2–3× in wall time (``experiments/bench_threads.py``); parallelism comes
        from running fits side by side.  0 keeps torch's own setting.
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
    average_s: float = 1.0     # s
    threads: int = 1

    def __post_init__(self) -> None:
        if self.optimizer not in _OPTIMIZERS:
            raise ConfigError(f"key 'train.optimizer': must be one of {', '.join(_OPTIMIZERS)}, "
                              f"got {self.optimizer!r}")
        if self.device not in _DEVICES:
            raise ConfigError(f"key 'train.device': must be one of {', '.join(_DEVICES)}, "
                              f"got {self.device!r}")
        # upper bounds: a setting beyond them is no training anyone means (1e12 epochs,
        # windows longer than a day), refused before anything runs; a huge lr is left to
        # the fit, which reports the epoch its loss turned NaN (tests/test_train.py)
        for key, lo, hi in (("max_epochs", 0, 1_000_000_000), ("patience", 1, 1_000_000_000),
                            ("max_train_samples", 10, 50_000_000), ("threads", 0, 1024)):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(f"key 'train.{key}': must be an integer in {lo}..{hi:,}, got {v!r}")
        for key, top in (("lr", math.inf), ("min_delta", 1.0), ("average_s", 86400.0)):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v < 0 or (key == "lr" and v == 0) or v > top:
                raise ConfigError(f"key 'train.{key}': must be a finite number "
                                  f"{'> 0' if key == 'lr' else '>= 0'}"
                                  f"{f' and <= {top:g}' if math.isfinite(top) else ''}, "
                                  f"got {v!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int):
            raise ConfigError(f"key 'train.seed': must be an integer, got {self.seed!r}")
