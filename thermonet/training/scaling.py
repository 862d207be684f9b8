"""What the training loops share — the point-wise one (:mod:`thermonet.training.train`), the
recurrent one (:mod:`thermonet.training.recurrent`) and the sensor model's: the per-column
scale every family trains in, and early stopping."""

from __future__ import annotations

import contextlib
import copy
import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import torch

__all__ = ["column_scale", "training_scaling", "EarlyStopping"]


def column_scale(a: np.ndarray) -> np.ndarray:
    """Per-column standard deviation of ``a`` (n, k); a constant column (rate on soaks, an
    axis with no drift) keeps unit scale."""
    mean, std = a.mean(axis=0), a.std(axis=0)
    return np.where(std > 1e-12 * np.maximum(1.0, np.abs(mean)), std, 1.0)


def training_scaling(model: Any, signals: np.ndarray, targets: np.ndarray, *,
                     sig_lo: np.ndarray, sig_hi: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The scaling every loop trains in, from its training rows, set on ``model`` (with the
    trained signal range): returns the rows' features and their mean and scale, and the
    targets' mean and scale."""
    with torch.no_grad():
        x = model.features(torch.as_tensor(signals)).numpy()
    x_mean, x_std = x.mean(axis=0), column_scale(x)
    y_mean, y_std = targets.mean(axis=0), column_scale(targets)
    model.set_scaling(x_mean=x_mean, x_std=x_std, y_mean=y_mean, y_std=y_std,
                      sig_lo=sig_lo, sig_hi=sig_hi)
    return x, x_mean, x_std, y_mean, y_std


class EarlyStopping:
    """The training loops' bookkeeping (point-wise, :mod:`thermonet.training.train`, and
    recurrent, :mod:`thermonet.training.recurrent`): keep the parameters of the epoch with the
    lowest monitored loss (the validation loss, or the training loss without a validation
    part), and stop after ``patience`` epochs without an improvement of at least
    ``min_delta``."""

    def __init__(self, module: torch.nn.Module, *, patience: int, min_delta: float) -> None:
        self.patience, self.min_delta = patience, min_delta
        self.best, self.best_epoch, self.wait = math.inf, 0, 0
        self.best_val: float | None = None
        # taken at the first update (epoch 0 always improves on inf: a NaN loss raises first)
        self.best_state: dict[str, torch.Tensor] | None = None

    def update(self, module: torch.nn.Module, epoch: int, train_loss: float,
               val_loss: float | None) -> bool:
        """Record one epoch; True when training should stop."""
        monitored = train_loss if val_loss is None else val_loss
        if monitored < self.best - self.min_delta:
            self.best, self.best_epoch, self.wait = monitored, epoch, 0
            self.best_state = _snapshot(module)
            self.best_val = val_loss
            return False
        self.wait += 1
        return self.wait >= self.patience

    def restore(self, module: torch.nn.Module) -> tuple[int, float | None]:
        """Put the best epoch's parameters back; returns that epoch and its validation loss."""
        if self.best_state is not None:
            module.load_state_dict(self.best_state)
        module.eval()
        return self.best_epoch, self.best_val


def _snapshot(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    """The module's state (every parameter and buffer) as detached copies, with the
    ``_metadata`` ``load_state_dict`` reads: what ``copy.deepcopy(module.state_dict())``
    gives, without deep-copying the dict machinery (a tenth of a calibration's fits)."""
    state = module.state_dict()
    out: Any = type(state)((k, v.detach().clone()) for k, v in state.items())
    meta = getattr(state, "_metadata", None)
    if meta is not None:
        out._metadata = copy.copy(meta)
    return out


def seed_torch(seed: int, device: torch.device) -> None:
    """Seed torch's random numbers for a fit on ``device``.  On the CPU only the CPU
    generator draws, so only it is seeded: ``torch.manual_seed`` also queues a seed for
    every accelerator torch knows (CUDA, XPU, MTIA), recording a stack trace each time,
    about 1 ms a call — a tenth of a closed-form fit.  The CPU generator's state is the
    same either way."""
    if device.type == "cpu":
        torch.default_generator.manual_seed(int(seed))
    else:
        torch.manual_seed(int(seed))


@contextlib.contextmanager
def caller_rng_kept() -> Iterator[None]:
    """torch's global random state as the caller left it, put back after the block: a fit
    seeds torch's generator (:func:`seed_torch`) inside it and draws the same numbers, and a
    caller's own ``torch.rand`` after the fit draws what it would have without it.  The CPU
    generator is restored, and each CUDA device's once CUDA is initialised (a fit that
    initialises it leaves its generator seeded)."""
    devices = list(range(torch.cuda.device_count())) if torch.cuda.is_initialized() else []
    with torch.random.fork_rng(devices=devices):
        yield


def nan_loss_said(fam: Any, zt: torch.Tensor, family: str, epoch: int, config: Any) -> str:
    """Why a training loss is not finite: at epoch 0 (no step yet), where the family's own
    output on the first rows is NaN/inf already, the family; else the optimizer's lr."""
    if epoch == 0:
        with torch.no_grad():
            out = fam(zt[:7])
        if not bool(torch.isfinite(out).all()):
            return (f"model '{family}': the family's own output is NaN/inf on the first "
                    "training rows after initialize(), before any training step (check its "
                    "initialize() and forward())")
    return (f"model '{family}': NaN loss at epoch {epoch} "
            f"(optimizer {config.optimizer}, lr {config.lr:g}; try a lower lr)")
