"""The one training loop every family goes through.

``fit`` standardises the training data, asks the family whether the data can
carry it (:meth:`~thermonet.models.base.Family.check_fittable`), starts it in
closed form (:meth:`~thermonet.models.base.Family.initialize`), then refines
it by full-batch gradient descent (skorch's ``fit_loop → run_epoch →
train_step / valid_step``), keeping the parameters with the best validation
loss.  The loss is the mean squared error in standardised units:

.. math:: L = \\frac{1}{N A} \\sum_{n, a} \\left(\\frac{\\hat y_{na} - y_{na}}{s_{y,a}}\\right)^2

The optimizer minimises :math:`L` plus the family's own penalty where it has one
(:meth:`~thermonet.models.base.Family.penalty`: the MLP's weight decay); the history and
early stopping use :math:`L` alone.

Epoch 0 in the history is the initialised model, so the history always shows
what training added to the closed-form start.
"""

from __future__ import annotations

import contextlib
import math
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

# torch.optim's optimisers would import torch._dynamo (about a second of start-up): every fit
# builds and steps them through .optim, which never does
from ..core.errors import ConfigError, FitError, InputError, check_interrupted
from ..core.recording import contiguous_segments
from ..core.trainconfig import TrainConfig  # re-exported: the ``train`` section
from ..features.dynamics import dynamic_signals, saturation_margin
from ..features.inputs import FeatureSpec
from ..models import DriftModel, build_family
from ..models.base import Family, check_output_shape
from ..models.composite import DriftModels
from ..models.sequence import stream_relative
from ..scoring.domain import guard_tables
from .optim import optimizer_step, optimizer_without_dynamo
from .recurrent import fit_recurrent
from .scaling import EarlyStopping, caller_rng_kept, nan_loss_said, seed_torch, training_scaling

__all__ = ["TrainConfig", "FitResult", "fit", "predict", "decimate", "average_windows",
           "rest_signals"]


@dataclass
class FitResult:
    """What :func:`fit` returns."""

    model: DriftModel
    history: list[dict] = field(default_factory=list)
    best_epoch: int = 0
    best_val_loss: float | None = None
    fit_seconds: float = 0.0
    n_params: int = 0


def decimate(runs: Sequence[tuple[np.ndarray, np.ndarray]], max_samples: int
             ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Keep every k-th sample of every run, k = ceil(total / max_samples)."""
    total = sum(s.shape[0] for s, _ in runs)
    step = max(1, math.ceil(total / max_samples))
    return [(s[::step], y[::step]) for s, y in runs]


def average_windows(signals: np.ndarray, targets: np.ndarray, time_s: np.ndarray,
                    window_s: float, *, min_samples: int = 1
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means of signals, targets and time over consecutive windows, O(n).

    A window is ``window_s`` seconds long, aligned on the start of its
    contiguous segment (:func:`thermonet.features.inputs.contiguous_segments`: a time
    step over :data:`~thermonet.features.inputs.GAP_FACTOR` × the median step starts a
    new segment), so a window never spans a gap.  With ``window_s = 0`` the
    windows are ``min_samples`` consecutive samples instead (bringing a long
    series under a sample budget by averaging rather than thinning).

    .. math:: \\bar s_w = \\frac{1}{|w|} \\sum_{k \\in w} s_k

    Returns
    -------
    (signals, targets, time_s) averaged, each with one row per window.
    """
    t = np.asarray(time_s, dtype=np.float64)
    n = t.shape[0]
    if n == 0 or (window_s <= 0 and min_samples <= 1):
        return signals, targets, t
    key = np.empty(n, dtype=np.int64)
    offset = 0
    for seg in contiguous_segments(t):
        if window_s > 0:
            w = np.floor((t[seg] - t[seg.start]) / window_s).astype(np.int64)
        else:
            w = np.arange(seg.stop - seg.start) // max(min_samples, 1)
        key[seg] = offset + w
        offset = int(key[seg.stop - 1]) + 1
    starts = np.concatenate([[0], np.flatnonzero(np.diff(key)) + 1])
    counts = np.diff(np.append(starts, n)).astype(np.float64)

    def mean(a: np.ndarray) -> np.ndarray:
        a = np.asarray(a, dtype=np.float64)
        sums = np.add.reduceat(a, starts, axis=0)
        return sums / (counts if a.ndim == 1 else counts[:, None])

    return mean(signals), mean(targets), mean(t)


def _reduce(runs: Sequence[tuple[np.ndarray, ...]], config: TrainConfig
            ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Average each run into ``config.average_s`` windows, then — if still over
    ``max_train_samples`` — into windows of k consecutive samples; runs given
    without time are decimated instead."""
    if any(len(r) < 3 for r in runs):
        return decimate([(r[0], r[1]) for r in runs], config.max_train_samples)
    avg = [average_windows(r[0], r[1], r[2], config.average_s) for r in runs]
    total = sum(s.shape[0] for s, _, _ in avg)
    k = math.ceil(total / config.max_train_samples)
    if k > 1:
        avg = [average_windows(s, y, t, 0.0, min_samples=k) for s, y, t in avg]
    return [(s, y) for s, y, _ in avg]


def _check_run(what: str, signals: object, targets: object, n_sig: int, outputs: list[str],
               signal_names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    s = np.asarray(signals, dtype=np.float64)
    y = np.asarray(targets, dtype=np.float64)
    if y.ndim == 1:
        y = y[:, None]
    if s.ndim != 2 or s.shape[1] != n_sig:
        raise InputError(f"{what}: signals have shape {s.shape}, expected (n, {n_sig}) "
                         f"for {signal_names}")
    if y.ndim != 2 or y.shape != (s.shape[0], len(outputs)):
        raise InputError(f"{what}: targets have shape {y.shape}, expected "
                         f"({s.shape[0]}, {len(outputs)}) for {outputs}")
    for arr, names, kind in ((s, signal_names, "signal"), (y, outputs, "target")):
        bad = np.argwhere(~np.isfinite(arr))
        if bad.size:
            row, col = (int(v) for v in bad[0])
            raise FitError(f"{what}: {kind} '{names[col]}' is {float(arr[row, col])} at row {row}; "
                           "remove or fill non-finite samples before fitting")
    return s, y


def _time(what: str, run: Sequence[object]) -> tuple[np.ndarray, ...]:
    """The run's time column as a 1-tuple, or () when the run was given without one."""
    if len(run) < 3:
        return ()
    t = np.asarray(run[2], dtype=np.float64)
    n = np.asarray(run[0]).shape[0]
    if t.ndim != 1 or t.shape[0] != n:
        raise InputError(f"{what}: time_s has shape {t.shape}, expected ({n},)")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise InputError(f"{what}: time_s must be finite and strictly increasing")
    return (t,)


def _resolve_device(name: str) -> torch.device:
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError("train.device is 'cuda' but no CUDA device is available")
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def fit(*, family: str, inputs: list[str], outputs: list[str],
        train: Sequence[tuple[np.ndarray, ...]], val: tuple[np.ndarray, ...] | None,
        spec: FeatureSpec, hyper: dict | None, config: TrainConfig,
        on_epoch: Callable[[int, float, float | None], None] | None = None,
        target: Sequence[str] | None = None) -> FitResult:
    """Fit one family to drift.

    Parameters
    ----------
    family : str
        A name in :data:`thermonet.models.MODELS`.
    inputs : list of str
        Feature names; must equal ``spec.inputs``.
    outputs : list of str
        Output axis names (columns of the targets).
    train : list of (signals (n, S), targets (n, A)[, time_s (n,)])
        One tuple per training run; signals in ``spec.signals`` order
        (see :func:`thermonet.training.parts.build_part`), targets = observed drift,
        time in s.  With time, the run is averaged into ``config.average_s``
        windows (:func:`average_windows`); without, only decimated to
        ``config.max_train_samples``.
    val : (signals, targets[, time_s]) or None
        The held-out run for early stopping (reduced the same way); None stops on
        a training-loss plateau.
    spec : FeatureSpec
    hyper : dict
        Family hyper-parameters.
    config : TrainConfig
    on_epoch : callable(epoch, train_loss, val_loss), optional
        Called after every epoch, epoch 0 (the initialised model) included.
    target : sequence of str, optional
        Target mode per output (:mod:`thermonet.features.target`; default ``channel``
        for every axis: the targets are the drift itself).  ``at-t-ref`` axes
        are normalised to zero at the rest signals (:func:`rest_signals`).
        Whatever the modes, the mean training target is removed in float64
        before standardisation and kept in the model's float64 ``y_offset``.

    Returns
    -------
    FitResult
        ``model`` in eval mode on CPU, holding the best-monitored-loss parameters.

    Raises
    ------
    FitError
        The data cannot carry the family (reason given), a non-finite target,
        a NaN loss, or a model whose outputs are not finite.
    ConfigError
        Unknown family / hyper-parameter, inputs not matching the spec.
    """
    with thread_limits(config.threads), caller_rng_kept():   # the caller's torch RNG kept
        return _fit(family=family, inputs=inputs, outputs=outputs, train=train, val=val,
                    spec=spec, hyper=hyper, config=config, on_epoch=on_epoch, target=target)


@contextlib.contextmanager
def thread_limits(threads: int) -> Iterator[None]:
    """Cap torch's intra-op threads and the native pools numpy and scikit-learn use
    (OpenBLAS, MKL, OpenMP: k-means, least squares; threadpoolctl) at ``threads`` for
    the duration — what ``OMP_NUM_THREADS`` would do, restored afterwards; ``threads``
    0 leaves them alone.  :func:`fit` runs under it, and a comparison as a whole
    (its evaluation at full resolution too)."""
    if not threads:
        yield
        return
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        with _pool_controller().limit(limits=threads):
            yield
    finally:
        torch.set_num_threads(before)


_CONTROLLER: list = []          # [(len(sys.modules) when made, ThreadpoolController)]
_CONTROLLER_LOCK = threading.Lock()


def _pool_controller() -> Any:
    """The native thread pools loaded in this process (threadpoolctl's controller), made
    once and made again only after a module import (a new native library, scikit-learn's
    OpenMP, comes with one): ``threadpool_limits`` scans every loaded shared library on each
    call — about 4 ms, paid by every fit of a comparison (hundreds in ``calibrate``)."""
    from threadpoolctl import ThreadpoolController

    with _CONTROLLER_LOCK:
        n = len(sys.modules)
        if not _CONTROLLER or _CONTROLLER[0][0] != n:
            _CONTROLLER[:] = [(n, ThreadpoolController())]
        return _CONTROLLER[0][1]


def _fit(*, family: str, inputs: list[str], outputs: list[str],
         train: Sequence[tuple[np.ndarray, ...]], val: tuple[np.ndarray, ...] | None,
         spec: FeatureSpec, hyper: dict | None, config: TrainConfig,
         on_epoch: Callable[[int, float, float | None], None] | None,
         target: Sequence[str] | None) -> FitResult:
    t0 = time.perf_counter()
    if list(inputs) != list(spec.inputs):
        raise ConfigError(f"inputs {list(inputs)} differ from the feature spec's {spec.inputs}")
    if not outputs:
        raise ConfigError("outputs: need at least one output axis")
    if not train:
        raise InputError("no training run")
    signal_names = spec.signals
    fam = build_family(family, n_inputs=len(inputs), n_outputs=len(outputs), hyper=hyper)
    model = DriftModel(family=fam, spec=spec, outputs=list(outputs))

    runs = [(*_check_run(f"training run {i + 1}", r[0], r[1], len(signal_names), list(outputs),
                         signal_names), *_time(f"training run {i + 1}", r))
            for i, r in enumerate(train)]
    val_run = None if val is None else (
        *_check_run("validation run", val[0], val[1], len(signal_names), list(outputs),
                    signal_names), *_time("validation run", val))
    modes = ["channel"] * len(outputs) if target is None else list(target)
    rest = rest_signals(spec, need_temperature="at-t-ref" in modes)
    sig_all = np.vstack([r[0] for r in runs])
    sig_lo, sig_hi = saturation_margin(spec.inputs, signal_names, sig_all.min(axis=0),
                                       sig_all.max(axis=0))
    # the constant of every axis leaves in float64, before anything is rounded to float32
    offset = np.vstack([r[1] for r in runs]).mean(axis=0)
    runs = [(r[0], r[1] - offset, *r[2:]) for r in runs]
    if val_run is not None:
        val_run = (val_run[0], val_run[1] - offset, *val_run[2:])
    if fam.recurrent:
        # the trained range first: fit_recurrent reads it from the model
        model.set_scaling(x_mean=np.zeros(len(inputs)), x_std=np.ones(len(inputs)),
                          y_mean=np.zeros(len(outputs)), y_std=np.ones(len(outputs)),
                          sig_lo=sig_lo, sig_hi=sig_hi)
        if dynamic_signals(inputs):
            raise ConfigError(f"model '{family}' learns the thermal history itself: drop the "
                              f"dynamic inputs {[d.name for d in dynamic_signals(inputs)]}")

        history, best_epoch, best_val, s_tr = fit_recurrent(
            model, runs, val_run, config, family, on_epoch, _resolve_device(config.device))
    else:
        history, best_epoch, best_val, s_tr = _fit_pointwise(
            model, runs, val_run, config, family, on_epoch, sig_lo=sig_lo, sig_hi=sig_hi)
    model.to("cpu").eval()
    # the dynamic inputs held inside what training saw near each temperature (the joint
    # envelope the folds judge with): set before the target's normalisation at rest, which
    # evaluates the model as the board will
    model.set_guard(guard_tables([r[0] for r in runs], signal_names))
    model.set_target(modes=modes, offset=offset, rest=rest)
    with torch.no_grad():
        pred = model(torch.as_tensor(s_tr, dtype=torch.float32))
    if not torch.isfinite(pred).all():
        raise FitError(f"model '{family}': the fitted model gives non-finite drift on the "
                       "training data; refusing it")
    return FitResult(model=model, history=history, best_epoch=best_epoch, best_val_loss=best_val,
                     fit_seconds=time.perf_counter() - t0, n_params=model.n_params)


def _fit_pointwise(model: DriftModel, runs: list, val_run: tuple | None, config: TrainConfig,
                   family: str, on_epoch: Callable | None, *, sig_lo: np.ndarray,
                   sig_hi: np.ndarray) -> tuple[list[dict], int, float | None, np.ndarray]:
    """Scaling, start and full-batch training of a family evaluated sample by sample;
    returns the history, best epoch, best validation loss and the training signals."""
    fam = model.family
    reduced = _reduce(runs, config)
    s_tr = np.vstack([s for s, _ in reduced])
    y_tr = np.vstack([y for _, y in reduced])

    x_tr, x_mean, x_std, y_mean, y_std = training_scaling(model, s_tr, y_tr, sig_lo=sig_lo,
                                                          sig_hi=sig_hi)
    z_tr = (x_tr - x_mean) / x_std
    yz_tr = (y_tr - y_mean) / y_std

    reason = fam.check_fittable(torch.as_tensor(z_tr))
    if reason:
        raise FitError(f"model '{family}' with inputs {list(model.inputs)} cannot be fitted: "
                       f"{reason}")

    device = _resolve_device(config.device)
    seed_torch(config.seed, device)
    fam.initialize(torch.as_tensor(z_tr), torch.as_tensor(yz_tr), seed=config.seed,
                   x_mean=x_mean, x_std=x_std)
    check_output_shape(fam, torch.as_tensor(z_tr, dtype=torch.float32), family)

    z_v = y_vz = None
    if val_run is not None:
        (s_v, y_v), = _reduce([val_run], config)
        # Validation goes through the deployed path: clamp to the trained range first.
        with torch.no_grad():
            x_v = model.features(torch.as_tensor(np.clip(s_v, sig_lo, sig_hi))).numpy()
        z_v, y_vz = (x_v - x_mean) / x_std, (y_v - y_mean) / y_std

    model.to(device)

    def dev(a: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(a, dtype=torch.float32, device=device)

    val_t = None if z_v is None or y_vz is None else (dev(z_v), dev(y_vz))
    with optimizer_without_dynamo():
        history, best_epoch, best_val = _fit_loop(fam, dev(z_tr), dev(yz_tr), val_t, config,
                                                  family, on_epoch)

    model.to("cpu")
    return history, best_epoch, best_val, s_tr


def _mse(fam: torch.nn.Module, z: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    return torch.mean((fam(z) - y) ** 2)


def _train_step(fam: Family, opt: torch.optim.Optimizer, z: torch.Tensor,
                y: torch.Tensor) -> None:
    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = _mse(fam, z, y)
        penalty = fam.penalty()  # the family's regularisation (MLP weight decay), if any
        if penalty is not None:
            loss = loss + penalty
        loss.backward()
        return loss
    optimizer_step(opt, closure)


def _valid_step(fam: torch.nn.Module, z: torch.Tensor, y: torch.Tensor) -> float:
    with torch.no_grad():
        return float(_mse(fam, z, y))


def _fit_loop(fam: Family, zt: torch.Tensor, yt: torch.Tensor,
              val: tuple[torch.Tensor, torch.Tensor] | None, config: TrainConfig, family: str,
              on_epoch: Callable | None) -> tuple[list[dict], int, float | None]:
    params = [p for p in fam.parameters() if p.requires_grad]
    if not fam.trainable():
        # a closed-form fit that is final (linear, poly, the RBF's penalised tail): epoch 0
        config = replace(config, max_epochs=0)
    opt: torch.optim.Optimizer | None = None
    if config.max_epochs > 0 and not params:
        raise FitError(f"model '{family}': no trainable parameter, yet trainable() is True; "
                       "a closed-form family returns False from trainable()")
    if config.max_epochs == 0:
        pass    # no step: no optimizer
    elif config.optimizer == "lbfgs":
        opt = torch.optim.LBFGS(params, lr=config.lr, max_iter=20, line_search_fn="strong_wolfe")
    else:
        opt = torch.optim.Adam(params, lr=config.lr)
    history: list[dict] = []
    stop = EarlyStopping(fam, patience=config.patience, min_delta=config.min_delta)
    fam.train()
    for epoch in range(config.max_epochs + 1):
        if epoch > 0 and opt is not None:
            _train_step(fam, opt, zt, yt)
        train_loss = _valid_step(fam, zt, yt)
        val_loss = None if val is None else _valid_step(fam, *val)
        if not math.isfinite(train_loss) or (val_loss is not None and not math.isfinite(val_loss)):
            raise FitError(nan_loss_said(fam, zt, family, epoch, config))
        history.append({"epoch": epoch, "train_loss": train_loss, "val_loss": val_loss})
        check_interrupted()     # a signal whose exception was lost (core.errors)
        if on_epoch is not None:
            on_epoch(epoch, train_loss, val_loss)
        if stop.update(fam, epoch, train_loss, val_loss):
            break
    best_epoch, best_val = stop.restore(fam)
    return history, best_epoch, best_val


def predict(model: DriftModels, signals: np.ndarray, time_s: np.ndarray | None = None
            ) -> np.ndarray:
    """Drift (n, A), float64, from signals (n, S) in ``model.signals`` order.

    Evaluated on CPU under ``torch.no_grad()``, through the same clamp as on
    board (use ``model.out_of_range`` to flag samples outside the trained range).
    A recurrent family (the GRU) needs the samples' time ``time_s`` (n,): the signals
    are then one stream, its state carried as on board (:mod:`thermonet.models.sequence`).
    """
    s = np.asarray(signals, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != len(model.signals):
        raise InputError(f"signals have shape {s.shape}, expected (n, {len(model.signals)}) "
                         f"for {model.signals}")
    if isinstance(model, DriftModel) and model.family.recurrent:
        if time_s is None:
            raise InputError(f"model '{model.family_name}' carries a state in time: predict "
                             "needs time_s (one stream in time order)")
        model.eval()
        rel, _ = stream_relative(model, np.asarray(time_s, dtype=np.float64), s)
        return rel + model.constant().detach().cpu().double().numpy()
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            out = model.drift64(torch.as_tensor(s, dtype=torch.float32,
                                                device=model.sig_lo.device))
    finally:
        model.train(was_training)
    return out.cpu().numpy()


def rest_signals(spec: FeatureSpec, *, need_temperature: bool = True) -> np.ndarray:
    """The signals at rest, where ``at-t-ref`` axes are normalised to zero drift.

    ``temperature_c`` at :math:`T_{ref}`, a proxy at its reference value, and
    every dynamic signal (:mod:`thermonet.features.dynamics`: ``rate_c_per_min``,
    ``rate_<tau>_c_per_min``, ``lag_<tau>_c`` = T − EMA(T), ``play_<w>_c`` =
    T − P(T)) at 0, its value after a soak at constant temperature.

    With ``need_temperature`` false (no ``at-t-ref`` axis) a value that cannot
    be known is 0 (stored, never used).

    Raises
    ------
    ConfigError
        With ``need_temperature``: a temperature-like signal with no
        :math:`T_{ref}`, or a signal with no known rest value.
    """
    dynamic = {d.signal for d in dynamic_signals(spec.inputs)}
    out = []
    for name in spec.signals:
        if name in dynamic:
            out.append(0.0)
        elif name in spec.proxy_ref:
            out.append(float(spec.proxy_ref[name]))
        elif name == "temperature_c":
            if spec.t_ref is None:
                if need_temperature:
                    raise ConfigError(f"signal '{name}': target 'at-t-ref' needs t_ref (a "
                                      "temperature in °C or 'start')")
                out.append(0.0)
            else:
                out.append(float(spec.t_ref))
        elif need_temperature:
            raise ConfigError(f"signal '{name}' has no rest value for target 'at-t-ref'")
        else:
            out.append(0.0)
    return np.asarray(out, dtype=np.float64)
