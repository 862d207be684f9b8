"""Training a recurrent family (the GRU): windows, truncated back-propagation, the state
carried as a board carries it.

:func:`sequences` turns each run (signals, targets, time) into the sequences the stream
definition (:mod:`thermonet.models.sequence`) evaluates: one sequence per contiguous
segment (no step over the family's ``gap_s``), one step per ``step_s`` window, the
window's mean signals and mean target.  :func:`fit_loop` trains on them by truncated
back-propagation through time: the padded batch of every segment is cut into chunks of
``chunk`` windows; each chunk starts from the previous chunk's final state (detached: no
gradient flows back past a chunk) and gets one Adam step on the mean squared error
(standardised units) of the steps after each segment's ``warmup`` windows, plus the
family's penalty.  An epoch is one pass over the chunks; the step is halved after
:data:`LR_PATIENCE` epochs without a better monitored loss (measured on the cycling gyro
of ``experiments/bench_neural.py``: validation loss 2.9e-4 against 1.8e-3 at a fixed step); the history records the
full-sequence loss after it (training and validation, warm-up left out), early stopping
keeps the parameters of the best monitored loss, as :func:`~.train.fit`'s loop does.
Everything random comes from the seed (the family's start); the chunk order is fixed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from ..core.errors import FitError, InputError, check_interrupted
from ..core.trainconfig import TrainConfig
from ..models.base import check_output_shape
from ..models.sequence import stream_windows
from .optim import optimizer_step, optimizer_without_dynamo
from .scaling import EarlyStopping, seed_torch, training_scaling

__all__ = ["sequences", "padded", "fit_loop", "initial_readout", "fit_recurrent", "CLIP_NORM"]

#: Gradient norm each step is clipped to (gradients exploding through time).
CLIP_NORM = 1.0
#: Epochs without a better monitored loss after which the step is halved (Adam on chunks is
#: noisy: a smaller step late in training settles what a large one found).
LR_PATIENCE = 2


def sequences(runs: Sequence[tuple[np.ndarray, ...]], step_s: float, gap_s: float,
              what: str = "training run") -> list[tuple[np.ndarray, np.ndarray]]:
    """Per contiguous segment of every run: window-mean signals (W, S) and targets (W, A)."""
    out = []
    for i, r in enumerate(runs):
        if len(r) < 3:
            raise InputError(f"{what} {i + 1}: model 'gru' is trained on sequences in time; "
                             "the run was given without time_s")
        s, y, t = (np.asarray(a, dtype=np.float64) for a in r[:3])
        lay = stream_windows(t, np.ones(t.size, dtype=bool), step_s, gap_s)
        starts = np.flatnonzero(np.append(True, lay.window[1:] != lay.window[:-1]))
        counts = np.diff(np.append(starts, t.size)).astype(np.float64)[:, None]
        sw = np.add.reduceat(s, starts, axis=0) / counts
        yw = np.add.reduceat(y, starts, axis=0) / counts
        for sg in np.unique(lay.segment):
            rows = lay.segment == sg
            out.append((sw[rows], yw[rows]))
    return out


def padded(seqs: Sequence[tuple[torch.Tensor, torch.Tensor]], warmup: int
           ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Batch (B, T, F), targets (B, T, A) and loss mask (B, T): real steps after warm-up."""
    t_max = max(z.shape[0] for z, _ in seqs)
    z0, y0 = seqs[0]
    zb = z0.new_zeros(len(seqs), t_max, z0.shape[1])
    yb = y0.new_zeros(len(seqs), t_max, y0.shape[1])
    mask = torch.zeros(len(seqs), t_max, dtype=torch.bool, device=z0.device)
    for b, (z, y) in enumerate(seqs):
        zb[b, :z.shape[0]] = z
        yb[b, :z.shape[0]] = y
        mask[b, warmup:z.shape[0]] = True
    return zb, yb, mask


def _loss(fam: Any, zb: torch.Tensor, yb: torch.Tensor, mask: torch.Tensor,
          h0: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    states, h = fam.scan(zb, h0)
    pred = states @ fam.weight.T + fam.bias
    err = ((pred - yb) ** 2).mean(dim=2)
    n = mask.sum()
    return (err * mask).sum() / torch.clamp(n, min=1), h


def initial_readout(fam: Any, zb: torch.Tensor, yb: torch.Tensor, mask: torch.Tensor) -> None:
    """The read-out fitted by least squares to the start's states (after warm-up)."""
    with torch.no_grad():
        states, _ = fam.scan(zb)
    m = mask.cpu().numpy()
    fam.fit_readout(states.detach().cpu().double().numpy()[m],
                    yb.detach().cpu().double().numpy()[m])


def fit_loop(fam: Any, train: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
             val: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None, config: TrainConfig,
             family: str, on_epoch: Callable | None) -> tuple[list[dict], int, float | None]:
    """Truncated back-propagation through time (module docstring); returns the history,
    the best epoch and its validation loss, the family left at its best parameters."""
    zb, yb, mask = train
    if not bool(mask.any()):
        raise FitError(f"model '{family}': no training window after the warm-up of "
                       f"{fam.warmup} windows ({fam.warmup * fam.step_s:g} s) in any segment; "
                       "lower 'warmup' or 'step_s'")
    params = [p for p in fam.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params, lr=fam.lr)
    # halve the step when the monitored loss has not improved for LR_PATIENCE epochs
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=0.5, patience=LR_PATIENCE)
    history: list[dict] = []
    stop = EarlyStopping(fam, patience=config.patience, min_delta=config.min_delta)
    t_max = zb.shape[1]
    for epoch in range(config.max_epochs + 1):
        if epoch > 0:
            fam.train()
            h = None
            for c in range(0, t_max, fam.chunk):
                sl = slice(c, c + fam.chunk)
                opt.zero_grad()
                loss, h = _loss(fam, zb[:, sl], yb[:, sl], mask[:, sl], h)
                penalty = fam.penalty()
                if penalty is not None:
                    loss = loss + penalty
                loss.backward()
                torch.nn.utils.clip_grad_norm_(params, CLIP_NORM)
                optimizer_step(opt)
                h = h.detach()
            fam.eval()
        with torch.no_grad():
            train_loss = float(_loss(fam, zb, yb, mask)[0])
            val_loss = None if val is None else float(_loss(fam, *val)[0])
        if not math.isfinite(train_loss) or (val_loss is not None and not math.isfinite(val_loss)):
            raise FitError(f"model '{family}': NaN loss at epoch {epoch} (lr {fam.lr:g}; try a "
                           "lower lr)")
        history.append({"epoch": epoch, "train_loss": train_loss, "val_loss": val_loss})
        check_interrupted()     # a signal whose exception was lost (core.errors)
        if on_epoch is not None:
            on_epoch(epoch, train_loss, val_loss)
        if epoch > 0:
            sched.step(train_loss if val_loss is None else val_loss)
        if stop.update(fam, epoch, train_loss, val_loss):
            break
    best_epoch, best_val = stop.restore(fam)
    return history, best_epoch, best_val


def fit_recurrent(model: Any, runs: Sequence[tuple[np.ndarray, ...]],
                  val_run: tuple[np.ndarray, ...] | None, config: TrainConfig, family: str,
                  on_epoch: Callable | None, device: torch.device
                  ) -> tuple[list[dict], int, float | None, np.ndarray]:
    """Scaling, start and training of a recurrent family on ``runs`` (offset removed);
    returns the history, best epoch, best validation loss and the training windows'
    signals (for the final finiteness check)."""

    fam = model.family
    seqs = sequences(runs, fam.step_s, fam.gap_s)
    s_tr = np.vstack([s for s, _ in seqs])
    y_tr = np.vstack([y for _, y in seqs])
    sig_lo, sig_hi = model.sig_lo.numpy(), model.sig_hi.numpy()
    x_tr, x_mean, x_std, y_mean, y_std = training_scaling(model, s_tr, y_tr, sig_lo=sig_lo,
                                                          sig_hi=sig_hi)
    reason = fam.check_fittable(torch.as_tensor((x_tr - x_mean) / x_std))
    if reason:
        raise FitError(f"model '{family}' with inputs {list(model.inputs)} cannot be fitted: "
                       f"{reason}")

    def tensors(items: Sequence[tuple[np.ndarray, np.ndarray]], clip: bool
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        out = []
        for s, y in items:
            s = np.clip(s, sig_lo, sig_hi) if clip else s
            with torch.no_grad():
                x = model.features(torch.as_tensor(s)).numpy()
            out.append((torch.as_tensor((x - x_mean) / x_std, dtype=torch.float32, device=device),
                        torch.as_tensor((y - y_mean) / y_std, dtype=torch.float32,
                                        device=device)))
        return padded(out, fam.warmup)

    train_t = tensors(seqs, clip=False)
    val_t = None
    if val_run is not None:
        val_t = tensors(sequences([val_run], fam.step_s, fam.gap_s, "validation run"), clip=True)
        if not bool(val_t[2].any()):
            val_t = None  # nothing after the warm-up: stop on the training loss
    seed_torch(config.seed, device)
    fam.start(config.seed)
    check_output_shape(fam, torch.as_tensor((x_tr - x_mean) / x_std, dtype=torch.float32),
                       family)
    model.to(device)
    initial_readout(fam, *train_t)
    with optimizer_without_dynamo():      # Adam's constructor and zero_grad
        history, best_epoch, best_val = fit_loop(fam, train_t, val_t, config, family,
                                                 on_epoch)
    model.to("cpu")
    return history, best_epoch, best_val, s_tr
