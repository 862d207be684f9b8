"""Fitting the full sensor model (``model: sensor``): b(s) and M(s) = I + E(s) per triad.

The model and its inverse are in :mod:`thermonet.models.sensor`.  Fitting goes through the
same training loop as every bias model (:func:`thermonet.training.train._fit_loop`: LBFGS or
Adam, early stopping on the validation run, epoch 0 = the closed-form start):

* **data** — per run the signals (:func:`~thermonet.features.inputs.signal_matrix`), the
  raw outputs and their references (``ref_<output>``: turntable rate, the known gravity
  projection per position), averaged into the ``train`` section's windows like a bias fit;
* **observability** (:func:`check_excitation`) — per triad the training references must span
  every axis direction (a static single-position soak spans none: the scale factor is then
  not observable, and the fit is refused with that message), and at two temperatures at
  least;
* **closed-form start** — the training samples are cut into stretches of steady temperature
  (a soak: within :data:`STEADY_C` of its first sample); in each stretch whose references
  span every direction, :math:`r = M x + b` is solved by least squares (study 000's per-soak
  K0, K1, generalised to a triad); every family then starts from those per-stretch
  estimates (at :data:`INIT_SAMPLES` samples of each stretch) through its own
  :meth:`~thermonet.models.base.Family.initialize` (so the same family code fits a
  scale-factor curve as a bias curve);
* **loss** — the forward sensor equation in standardised units,
  :math:`L = \\text{mean}_{n,a}((b_a + \\sum_c E_{ac} x_c - (r_a - x_a))/s_a)^2`: linear in
  every element, so it is as well conditioned as a bias fit (the inverse is only applied
  when compensating);
* **do no harm** (:func:`do_no_harm`) — on the validation run, each element in turn (bias
  elements first, then E row by row) is masked to 0 (identity / zero) when that does not
  raise the residual; without a validation run every element is kept;
* **refusals** — a non-finite fit, and a singular or near-singular M anywhere on the training
  signals or at the edges of the trained range
  (:func:`~thermonet.models.sensor.check_invertible`).

``elements=False`` fits the bias-only model on the same data and code path (E masked to 0):
the reference the sensor model is judged against.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
from torch import nn

from ..core.errors import FitError, InputError
from ..core.recording import Recording, output_kind
from ..core.trainconfig import TrainConfig
from ..features.inputs import FeatureSpec, signal_matrix
from ..models import DriftModel, build_family
from ..models.base import check_output_shape
from ..models.sensor import SensorModel, check_invertible, element_names
from ..scoring.domain import guard_tables
from .scaling import column_scale, seed_torch
from .train import _fit_loop, average_windows, rest_signals, thread_limits

__all__ = ["SensorRun", "SensorFit", "STEADY_C", "sensor_run", "sensor_run_refs",
           "check_excitation",
           "steady_estimates", "fit_sensor", "do_no_harm"]

#: A stretch of samples whose temperature stays within this of its first sample is one
#: steady level (a soak) for the closed-form start, °C.
STEADY_C = 1.0
#: Samples per steady stretch the families' closed-form start sees (each with its stretch's
#: least-squares estimates): 12, the fewest a stretch has, so every stretch weighs the same.
INIT_SAMPLES = 12
#: Relative singular value below which a reference direction counts as unexcited.
RANK_RTOL = 1e-3

_GUIDE = "configs/README.md, 'Sensor model'"


@dataclass
class SensorRun:
    """One run's arrays: signals (n, S), raw outputs and references (n, O), time (n,), and
    the temperature (n,) used to find steady stretches (thermometer, or first signal)."""

    signals: np.ndarray
    raw: np.ndarray
    ref: np.ndarray
    time_s: np.ndarray
    temperature: np.ndarray
    run_id: str = "run"

    def averaged(self, window_s: float) -> SensorRun:
        """The run averaged into ``window_s`` windows (never across a gap)."""
        o = self.raw.shape[1]
        s, y, t = average_windows(np.c_[self.signals, self.temperature],
                                  np.c_[self.raw, self.ref], self.time_s, window_s)
        return SensorRun(s[:, :-1], y[:, :o], y[:, o:], t, s[:, -1], self.run_id)


def sensor_run_refs(rec: Recording, outputs: Sequence[str]) -> None:
    """Refuse a recording without a reference channel for every output."""
    source = rec.meta.get("source", "") or f"run '{rec.run_id}'"
    missing = [o for o in outputs if f"ref_{o}" not in rec.references]
    if missing:
        raise InputError.at(source, "model 'sensor' needs the known excitation of every "
                            f"output (turntable rate, gravity per position); no reference "
                            f"channel for {missing} ({_GUIDE})", column=f"ref_{missing[0]}")


def sensor_run(rec: Recording, spec: FeatureSpec, outputs: Sequence[str]) -> SensorRun:
    """A recording's arrays for the sensor model; refuses a missing reference channel."""
    sensor_run_refs(rec, outputs)
    raw = np.stack([rec.outputs[o] for o in outputs], axis=1).astype(np.float64)
    ref = np.stack([rec.references[f"ref_{o}"] for o in outputs], axis=1).astype(np.float64)
    sig = signal_matrix(rec, spec.signals, spec.gap_s)
    temp = rec.temperature_c if rec.temperature_c is not None else sig[:, 0]
    return SensorRun(sig, raw, ref, np.asarray(rec.time_s, dtype=np.float64),
                     np.asarray(temp, dtype=np.float64), rec.run_id)


def _rank(ref: np.ndarray) -> int:
    """Directions the references span (about their mean), relative to their largest."""
    if ref.shape[0] < 2:
        return 0
    sv = np.linalg.svd(ref - ref.mean(axis=0), compute_uv=False)
    return int(np.sum(sv > RANK_RTOL * max(float(sv[0]), 1e-300))) if sv[0] > 0 else 0


def _stretches(temp: np.ndarray) -> list[slice]:
    """Consecutive samples whose temperature stays within :data:`STEADY_C` of the first."""
    out, start = [], 0
    for i in range(1, temp.size + 1):
        if i == temp.size or abs(temp[i] - temp[start]) > STEADY_C:
            out.append(slice(start, i))
            start = i
    return out


def steady_estimates(runs: Sequence[SensorRun], triads: Sequence[Sequence[int]], *,
                     samples: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per steady stretch excited in every direction: mean signals (G, S), mean temperature
    (G,), bias (G, O) and E = M − I (G, sum k²), by least squares :math:`r = M x + b`.

    A stretch is kept when every triad's references span all its directions there and it
    has at least 3 (k + 1) samples.  ``samples`` > 0: instead of the stretch's mean, that
    many evenly spaced samples of it (its signals as recorded, the stretch's estimates
    repeated): the closed-form start of a family that needs more rows than there are
    soaks (the RBF's inner cross-validation) or whose inputs vary within a soak."""
    sig, temps, bias, elems = [], [], [], []
    for run in runs:
        for sl in _stretches(run.temperature):
            if sl.stop - sl.start < 3 * 4:
                continue
            b_row, e_row = [], []
            for idx in triads:
                x, r = run.ref[sl][:, idx], run.raw[sl][:, idx]
                k = len(idx)
                if _rank(x) < k or sl.stop - sl.start < 3 * (k + 1):
                    break
                a = np.c_[x, np.ones(x.shape[0])]
                coef, *_ = np.linalg.lstsq(a, r, rcond=None)  # (k + 1, k)
                m = coef[:k].T
                b_row.extend(coef[k].tolist())
                e_row.extend((m - np.eye(k)).ravel().tolist())
            else:
                if samples > 0:
                    at = np.linspace(sl.start, sl.stop - 1, samples).round().astype(int)
                    sig.extend(run.signals[at])
                    temps.extend(run.temperature[at].tolist())
                    bias.extend([b_row] * at.size)
                    elems.extend([e_row] * at.size)
                else:
                    sig.append(run.signals[sl].mean(axis=0))
                    temps.append(float(run.temperature[sl].mean()))
                    bias.append(b_row)
                    elems.append(e_row)
    if not sig:
        return (np.zeros((0, runs[0].signals.shape[1])), np.zeros(0), np.zeros((0, 0)),
                np.zeros((0, 0)))
    return np.asarray(sig), np.asarray(temps), np.asarray(bias), np.asarray(elems)


def check_excitation(runs: Sequence[SensorRun], outputs: Sequence[str],
                     triads: Sequence[Sequence[int]], *, source: str = "training runs"
                     ) -> None:
    """Refuse data on which the scale factor and misalignment are not observable."""
    ref = np.vstack([r.ref for r in runs])
    for idx in triads:
        names = [outputs[i] for i in idx]
        rank = _rank(ref[:, idx])
        if rank < len(idx):
            raise InputError(
                f"{source}: the scale factor{' and misalignment' if len(idx) > 1 else ''} of "
                f"'{output_kind(names[0])}' {'are' if len(idx) > 1 else 'is'} not observable: "
                f"the references {['ref_' + n for n in names]} span {rank} of {len(idx)} "
                "direction(s) (a static single-position soak spans none); record a "
                f"multi-position or turntable test ({_GUIDE}), or use model 'bias'")
    _, temps, _, _ = steady_estimates(runs, triads)
    levels = np.unique(np.round(temps / STEADY_C)) if temps.size else temps
    if levels.size < 2:
        raise InputError(f"{source}: the scale factor is not observable versus temperature: "
                         f"the excitation spans every direction at {levels.size} steady "
                         "temperature(s), need 2 or more (a multi-position test at each soak, "
                         f"{_GUIDE})")


class _Core(nn.Module):
    """The families of b and E as one module for :func:`~.train._fit_loop`: standardised
    features and the references in, the standardised forward error r − x out."""

    def __init__(self, fam_b: nn.Module, fam_e: nn.Module | None, n_feat: int,
                 triads: Sequence[Sequence[int]], scales: dict[str, np.ndarray]) -> None:
        super().__init__()
        self.fam_b, self.fam_e, self.n_feat = fam_b, fam_e, n_feat
        self.triads = [list(t) for t in triads]
        for name, value in scales.items():
            self.register_buffer(name, torch.as_tensor(value, dtype=torch.float32))

    def forward(self, zx: torch.Tensor) -> torch.Tensor:
        z, x = zx[:, :self.n_feat], zx[:, self.n_feat:]
        pred = self.fam_b(z) * self.b_std + self.b_mean
        if self.fam_e is not None:
            e = self.fam_e(z) * self.e_std + self.e_mean
            cols, j = [], 0
            for idx in self.triads:
                k = len(idx)
                m = e[:, j:j + k * k].reshape(-1, k, k)
                cols.append(torch.einsum("nrc,nc->nr", m, x[:, idx]))
                j += k * k
            pred = pred + torch.cat(cols, dim=1)
        return (pred - self.y_mean) / self.y_std

    def penalty(self) -> torch.Tensor | None:
        terms = [p for f in (self.fam_b, self.fam_e) if f is not None
                 if (p := f.penalty()) is not None]  # type: ignore[operator]
        return sum(terms[1:], terms[0]) if terms else None

    def trainable(self) -> bool:
        return True


@dataclass
class SensorFit:
    """What :func:`fit_sensor` returns."""

    model: SensorModel
    history: list[dict]
    best_epoch: int
    n_estimates: int          # steady stretches the closed-form start used
    condition: float          # largest condition number of M on the training signals
    kept: dict[str, bool]     # per element (bias axes, then E): used (True) or masked


def fit_sensor(*, family: str, spec: FeatureSpec, outputs: Sequence[str],
               triads: Sequence[Sequence[str]], train: Sequence[SensorRun],
               val: SensorRun | None, hyper: dict | None, config: TrainConfig,
               elements: bool = True) -> SensorFit:
    """Fit b(s) (and, with ``elements``, E(s)) with ``family`` for every element.

    Raises
    ------
    InputError
        No excitation (:func:`check_excitation`).
    FitError
        The family cannot be fitted on the per-stretch estimates, NaN, or a singular M.
    """
    with thread_limits(config.threads):
        return _fit_sensor(family=family, spec=spec, outputs=list(outputs), triads=triads,
                           train=train, val=val, hyper=hyper, config=config, elements=elements)


def _fit_sensor(*, family: str, spec: FeatureSpec, outputs: list[str],
                triads: Sequence[Sequence[str]], train: Sequence[SensorRun],
                val: SensorRun | None, hyper: dict | None, config: TrainConfig,
                elements: bool) -> SensorFit:
    idx = [[outputs.index(o) for o in t] for t in triads]
    names_e = [e for t in triads for e in element_names(t)]
    if elements:
        check_excitation(train, outputs, idx)
    hyper = dict(hyper or {})
    fam_b = build_family(family, n_inputs=len(spec.inputs), n_outputs=len(outputs), hyper=hyper)
    fam_e = build_family(family, n_inputs=len(spec.inputs), n_outputs=len(names_e), hyper=hyper)
    bias = DriftModel(family=fam_b, spec=spec, outputs=outputs)
    elem = DriftModel(family=fam_e, spec=spec, outputs=names_e)

    s_tr, x_ref, y_tr = _training_windows(train, config)
    sig_lo, sig_hi = s_tr.min(axis=0), s_tr.max(axis=0)
    with torch.no_grad():
        x_tr = bias.features(torch.as_tensor(s_tr)).numpy()
    x_mean, x_std = x_tr.mean(axis=0), column_scale(x_tr)
    scales, n_estimates = _closed_form_start(
        family, spec, train, idx, bias, (fam_b, fam_e), len(names_e), s_tr, y_tr,
        (x_mean, x_std), config, elements)
    y_mean, y_std = y_tr.mean(axis=0), column_scale(y_tr)
    scales.update(y_mean=y_mean, y_std=y_std)
    core = _Core(fam_b, fam_e if elements else None, len(spec.inputs), idx, scales)

    def zx(r_sig: np.ndarray, r_ref: np.ndarray) -> torch.Tensor:
        with torch.no_grad():
            x = bias.features(torch.as_tensor(np.clip(r_sig, sig_lo, sig_hi))).numpy()
        return torch.as_tensor(np.c_[(x - x_mean) / x_std, r_ref], dtype=torch.float32)

    zt = zx(s_tr, x_ref)
    yt = torch.as_tensor((y_tr - y_mean) / y_std, dtype=torch.float32)
    val_t = None
    if val is not None:
        v = val.averaged(config.average_s)
        val_t = (zx(v.signals, v.ref),
                 torch.as_tensor((v.raw - v.ref - y_mean) / y_std, dtype=torch.float32))
    label = f"{family} (sensor)" if elements else f"{family} (bias-only)"
    history, best_epoch, _ = _fit_loop(core, zt, yt, val_t, replace(config), label,  # type: ignore[arg-type]
                                       None)
    model = _assembled(bias, elem, triads, spec, scales, (x_mean, x_std, sig_lo, sig_hi),
                       elements, label, guard_tables([s_tr], spec.signals))
    kept = {n: True for n in outputs + names_e}
    if not elements:
        kept.update({n: False for n in names_e})
    elif val is not None:
        kept = do_no_harm(model, val.averaged(config.average_s))
    edges = np.vstack([s_tr, sig_lo, sig_hi])
    cond = check_invertible(model, edges, what=f"model '{label}'")
    return SensorFit(model=model, history=history, best_epoch=best_epoch,
                     n_estimates=n_estimates // INIT_SAMPLES if elements else 0,
                     condition=cond,
                     kept=kept)


def _training_windows(train: Sequence[SensorRun], config: TrainConfig
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The training windows as a bias fit takes them (``average_s``, then the sample budget):
    signals, references and raw − reference, stacked."""
    runs = [r.averaged(config.average_s) for r in train]
    total = sum(r.time_s.size for r in runs)
    k = math.ceil(total / config.max_train_samples)
    if k > 1:
        runs = [_thin(r, k) for r in runs]
    return (np.vstack([r.signals for r in runs]), np.vstack([r.ref for r in runs]),
            np.vstack([r.raw - r.ref for r in runs]))


def _closed_form_start(family: str, spec: FeatureSpec, train: Sequence[SensorRun],
                       idx: list[list[int]], bias: DriftModel, fams: tuple[Any, Any],
                       n_elements: int, s_tr: np.ndarray, y_tr: np.ndarray, x_scale: tuple[np.ndarray, np.ndarray],
                       config: TrainConfig, elements: bool) -> tuple[dict[str, Any], int]:
    """The closed-form start of the bias and element families: per steady stretch
    (full-resolution samples) an estimate of b and E, then each family initialised on them.
    Returns the bias and element scales and the number of estimate samples."""
    fam_b, fam_e = fams
    x_mean, x_std = x_scale
    g_sig, _, g_b, g_e = steady_estimates(train, idx, samples=INIT_SAMPLES)
    if not elements:  # bias-only: every window is an estimate of b (E = 0)
        g_sig, g_b, g_e = s_tr, y_tr, np.zeros((s_tr.shape[0], n_elements))
    with torch.no_grad():
        xg = (bias.features(torch.as_tensor(g_sig)).numpy() - x_mean) / x_std
    b_mean, b_std = g_b.mean(axis=0), column_scale(g_b)
    e_mean, e_std = g_e.mean(axis=0), column_scale(g_e)
    if elements:
        reason = fam_b.check_fittable(torch.as_tensor(xg))
        if reason:
            raise FitError(f"model '{family}' with inputs {spec.inputs} cannot be fitted as a "
                           f"sensor model on {xg.shape[0]} steady-temperature estimates: "
                           f"{reason}")
    seed_torch(config.seed, torch.device("cpu"))   # its fits run on the CPU
    fam_b.initialize(torch.as_tensor(xg), torch.as_tensor((g_b - b_mean) / b_std),
                     seed=config.seed, x_mean=x_mean, x_std=x_std)
    fam_e.initialize(torch.as_tensor(xg), torch.as_tensor((g_e - e_mean) / e_std),
                     seed=config.seed, x_mean=x_mean, x_std=x_std)
    for fam in (fam_b, fam_e):     # one column per bias / element, N rows
        check_output_shape(fam, torch.as_tensor(xg, dtype=torch.float32), family)
    return ({"b_mean": b_mean, "b_std": b_std, "e_mean": e_mean, "e_std": e_std},
            int(g_sig.shape[0]))


def _assembled(bias: DriftModel, elem: DriftModel, triads: Sequence[Sequence[str]],
               spec: FeatureSpec, scales: dict[str, Any], x_box: tuple[np.ndarray, ...], elements: bool,
               label: str, guard: dict[str, np.ndarray] | None) -> SensorModel:
    """The fitted families as a :class:`SensorModel`: scaling, targets and domain set (the
    dynamic inputs' joint ``guard`` too, :meth:`DriftModel.set_guard`), the elements masked
    in a bias-only fit; refused if any parameter is not finite."""
    x_mean, x_std, sig_lo, sig_hi = x_box
    rest = rest_signals(spec, need_temperature=False)
    for dm, mean, std in ((bias, scales["b_mean"], scales["b_std"]),
                          (elem, scales["e_mean"], scales["e_std"])):
        dm.set_scaling(x_mean=x_mean, x_std=x_std, y_mean=mean, y_std=std, sig_lo=sig_lo,
                       sig_hi=sig_hi)
        dm.set_guard(guard)
        dm.set_target(modes=["channel"] * len(dm.outputs),
                      offset=np.zeros(len(dm.outputs)), rest=rest)
        dm.eval()
    if not elements:
        elem.set_compensate(np.zeros(len(elem.outputs), dtype=bool))
    model = SensorModel(bias=bias, elements=elem, triads=triads).eval()
    for name, p in list(model.named_parameters()) + list(model.named_buffers()):
        if p.is_floating_point() and not bool(torch.isfinite(p).all()):
            raise FitError(f"model '{label}': parameter '{name}' is not finite; refusing it")
    return model


def _thin(run: SensorRun, k: int) -> SensorRun:
    s, y, t = average_windows(np.c_[run.signals, run.temperature], np.c_[run.raw, run.ref],
                              run.time_s, 0.0, min_samples=k)
    o = run.raw.shape[1]
    return SensorRun(s[:, :-1], y[:, :o], y[:, o:], t, s[:, -1], run.run_id)


def _val_loss(model: SensorModel, run: SensorRun, scale: np.ndarray) -> float:
    comp = model.compensate(run.signals, run.raw)
    return float(np.mean(((comp - run.ref) / scale) ** 2))


def do_no_harm(model: SensorModel, val: SensorRun) -> dict[str, bool]:
    """Mask each element that does not lower the validation residual; returns element → kept.

    Greedy, in a fixed order (bias axes, then E row-major): an element is masked (0: identity
    on the diagonal, zero elsewhere) when the residual without it is not larger than with it.
    The residual is the mean square of (compensated − reference) per axis, each axis scaled
    by its raw error's standard deviation so that gyro and accelerometer weigh alike.
    """
    scale = column_scale(val.raw - val.ref)
    kept: dict[str, bool] = {}
    for dm in (model.bias, model.elements):
        mask = np.asarray(dm.compensated_axes, dtype=bool)
        for j, name in enumerate(dm.outputs):
            if not mask[j]:
                kept[name] = False
                continue
            with_it = _val_loss(model, val, scale)
            mask[j] = False
            dm.set_compensate(mask)
            without = _val_loss(model, val, scale)
            if without <= with_it:
                kept[name] = False
            else:
                mask[j] = True
                dm.set_compensate(mask)
                kept[name] = True
    return kept
