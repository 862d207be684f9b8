"""Each candidate's out-of-fold predictions (:class:`CandidateOOF`) and the folds' validation
windows pooled for the choice (:func:`pool`, a :class:`Pooled`):
per candidate and fold, the offset-free sums of squares of its residual's window means on
the windows inside every candidate's trained domain (the paired scores and their bootstrap
units), on its own domain (its mask), against the baseline on the windows inside both (the
gate, :mod:`thermonet.scoring.gate`), and the binned peak-to-peak sums (the guard).
:mod:`thermonet.scoring.selection` scores and chooses from them."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .fold_plan import FoldPlan, window_labels
from .metrics import binned_peak_to_peak

__all__ = ["CandidateOOF", "Pooled", "pool", "pool_fold", "gate_sums", "window_ss", "binned_pp"]


@dataclass
class CandidateOOF:
    """One candidate's out-of-fold predictions on the pool's validation rows.

    ``rows[f]``: per pool run, the validation row indices of fold ``f`` (the same for every
    candidate); ``pred[f]``: per pool run, the predicted drift (n_f, A); ``inside[f]``: per
    pool run, the rows inside the candidate's trained domain; ``failed``: why a fold could not
    be fitted (the candidate then takes no part in the choice).
    """

    label: str
    n_params: int
    pred: list[list[np.ndarray]] = field(default_factory=list)
    inside: list[list[np.ndarray]] = field(default_factory=list)
    failed: str | None = None
    #: its inputs carry the direction of temperature change (rate, lag, hysteresis): it cannot
    #: be judged for a direction the training data do not hold
    directional: bool = False
    #: the share of its drift that reads those inputs: 1 for a model with memory, the mix's
    #: weight on them for a step toward memory (:data:`thermonet.scoring.fold_plan.MEMORY_STEP`)
    memory_share: float = 1.0



def window_ss(e: np.ndarray, wl: np.ndarray, units: np.ndarray, n_units: int
               ) -> tuple[np.ndarray, np.ndarray]:
    """Per bootstrap unit: Σ n_w (m_w − m̄)² of the window means m_w of ``e`` (n, A) about
    the weighted mean m̄ of this fold; and the samples per unit."""
    uw, inv = np.unique(wl, return_inverse=True)
    nw = np.bincount(inv, minlength=uw.size).astype(np.float64)
    sums = np.zeros((uw.size, e.shape[1]))
    np.add.at(sums, inv, e)
    means = sums / nw[:, None]
    mbar = (means * nw[:, None]).sum(0) / nw.sum()
    unit_w = np.zeros(uw.size, dtype=np.int64)
    unit_w[inv] = units                 # a window lies inside one unit (block)
    ss = np.zeros((n_units, e.shape[1]))
    np.add.at(ss, unit_w, nw[:, None] * (means - mbar) ** 2)
    n = np.bincount(unit_w, weights=nw, minlength=n_units)
    return ss, n


def binned_pp(temperature: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Per axis, the binned peak-to-peak of ``e`` (n, A) over 1 °C temperature bins (0 where
    nothing is finite)."""
    out = np.zeros(e.shape[1])
    ok = np.isfinite(temperature)
    if ok.sum() < 2:
        return out
    for a in range(e.shape[1]):
        v = binned_peak_to_peak(temperature[ok], e[ok, a])
        out[a] = v if math.isfinite(v) else 0.0
    return out


@dataclass
class Pooled:
    """The folds' validation rows pooled per bootstrap unit (a validation block, numbered
    across folds): per-unit offset-free sums of squares of the window means on the windows
    common to every candidate (``ss``: ``"<raw>"`` and each candidate) and on each
    candidate's own domain (``own_ss``, ``own_raw``), binned peak-to-peak sums (raw's on the
    common windows, ``pp_raw``; each candidate's and raw's on the candidate's own domain,
    ``pp_cand`` and ``pp_own_raw``: what its mask rests on, as its score does), and the
    fractions of rows left out of the domains."""

    ss: dict[str, list[np.ndarray]]
    own_ss: dict[str, list[np.ndarray]]
    own_raw: dict[str, list[np.ndarray]]
    left_out: dict[str, list[float]]
    pp_raw: np.ndarray
    pp_cand: dict[str, np.ndarray]
    pp_own_raw: dict[str, np.ndarray] = field(default_factory=dict)
    ns: list[np.ndarray] = field(default_factory=list)
    common_left: list[float] = field(default_factory=list)
    #: per candidate and fold, the gate's sums of squares (over the fold's units, per axis):
    #: (candidate, raw) on the candidate's own domain, and (candidate, baseline, raw) on the
    #: windows inside both its and the baseline's domain; None where it has fewer than two
    #: rows there (the candidate was not judged on that fold)
    gate_own: dict[str, list[tuple[np.ndarray, np.ndarray] | None]] = field(default_factory=dict)
    gate_pair: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray] | None]] = field(
        default_factory=dict)
    base_judged: list[bool] = field(default_factory=list)
    fold_units: list[int] = field(default_factory=list)
    n_units: int = 0

    def total(self, lst: list[np.ndarray]) -> np.ndarray:
        """The per-fold arrays (each as long as the units known at its fold) summed over
        every unit."""
        out = np.zeros((self.n_units, self.pp_raw.size))
        for x in lst:
            out[: x.shape[0]] += x
        return out


def pool(plan: FoldPlan, targets: Sequence[np.ndarray], times: Sequence[np.ndarray],
          ok: Mapping[str, CandidateOOF], n_axes: int,
          temperatures: Sequence[np.ndarray] | None, baseline: str | None = None) -> Pooled:
    """Every fold's validation rows pooled (:class:`Pooled`), fold by fold."""
    pooled = Pooled(ss={k: [] for k in ["<raw>", *ok]}, own_ss={k: [] for k in ok},
                     own_raw={k: [] for k in ok}, left_out={k: [] for k in ok},
                     pp_raw=np.zeros(n_axes), pp_cand={k: np.zeros(n_axes) for k in ok},
                     pp_own_raw={k: np.zeros(n_axes) for k in ok},
                     gate_own={k: [] for k in ok}, gate_pair={k: [] for k in ok})
    for f in range(plan.k):
        parts = []
        for j, fo in enumerate(plan.fold_of):
            rows = np.flatnonzero(fo == f)
            if rows.size:
                parts.append((j, rows, plan.block_of[j][rows]))
        # units of this fold: its validation blocks, renumbered from the units so far
        ublocks = np.unique(np.concatenate([b for _, _, b in parts])) if parts else np.array([])
        remap = {int(b): pooled.n_units + i for i, b in enumerate(ublocks)}
        pooled.n_units += ublocks.size
        pooled.fold_units.append(ublocks.size)
        pool_fold(pooled, plan, f, parts, remap, targets, times, ok, temperatures, baseline)
    return pooled


def pool_fold(pooled: Pooled, plan: FoldPlan, f: int,
               parts: list[tuple[int, np.ndarray, np.ndarray]], remap: dict[int, int],
               targets: Sequence[np.ndarray], times: Sequence[np.ndarray],
               ok: Mapping[str, CandidateOOF],
               temperatures: Sequence[np.ndarray] | None, baseline: str | None = None) -> None:
    """Fold ``f``'s rows added to ``pooled``: one offset-free fold mean (this fold's runs
    stacked; an offset per fold, as the verdicts have)."""
    e_raw, wl_all, un_all, t_all = [], [], [], []
    e_c: dict[str, list[np.ndarray]] = {k: [] for k in ok}
    inside_c: dict[str, list[np.ndarray]] = {k: [] for k in ok}
    wl_base = 0
    for j, rows, blk in parts:
        y = targets[j][rows]
        wl = window_labels(times[j][rows], plan.window_s) + wl_base
        wl_base = int(wl.max()) + 1
        e_raw.append(y)
        if temperatures is not None:
            t_all.append(np.asarray(temperatures[j], dtype=np.float64)[rows])
        wl_all.append(wl)
        un_all.append(np.array([remap[int(b)] for b in blk]))
        for k, c in ok.items():
            e_c[k].append(y - c.pred[f][j])
            inside_c[k].append(c.inside[f][j])
    y = np.concatenate(e_raw)
    wl = np.concatenate(wl_all)
    un = np.concatenate(un_all)
    inside = {k: np.concatenate(v) for k, v in inside_c.items()}
    common = np.logical_and.reduce(list(inside.values()))
    pooled.common_left.append(float(1.0 - common.mean()) if common.size else 1.0)
    gate_sums(pooled, y, wl, un, {k: np.concatenate(v) for k, v in e_c.items()}, inside,
               baseline)
    for k in ok:
        pooled.left_out[k].append(float(1.0 - inside[k].mean()) if inside[k].size else 1.0)
    if common.sum() < 2:
        return
    n_units = pooled.n_units
    # every score is offset-free: window means about the fold's mean (_window_ss)
    s_raw, n = window_ss(y[common], wl[common], un[common], n_units)
    pooled.ss["<raw>"].append(s_raw)
    pooled.ns.append(n)
    t_fold = np.concatenate(t_all) if t_all else None
    if t_fold is not None:
        pooled.pp_raw += binned_pp(t_fold[common], y[common])
    for k in ok:
        e = np.concatenate(e_c[k])
        s, _ = window_ss(e[common], wl[common], un[common], n_units)
        pooled.ss[k].append(s)
        # the candidate's own domain, for its per-axis compensate decision (score and binned
        # peak-to-peak alike: the same mask whichever candidates it is compared with)
        m = inside[k]
        if m.sum() >= 2:
            so, _ = window_ss(e[m], wl[m], un[m], n_units)
            sr, _ = window_ss(y[m], wl[m], un[m], n_units)
            pooled.own_ss[k].append(so)
            pooled.own_raw[k].append(sr)
            if t_fold is not None:
                pooled.pp_cand[k] += binned_pp(t_fold[m], e[m])
                pooled.pp_own_raw[k] += binned_pp(t_fold[m], y[m])


def gate_sums(pooled: Pooled, y: np.ndarray, wl: np.ndarray, un: np.ndarray,
               e: Mapping[str, np.ndarray], inside: Mapping[str, np.ndarray],
               baseline: str | None) -> None:
    """One fold's sums of squares for the gate (:attr:`Pooled.gate_own`, ``gate_pair``):
    each candidate judged where it can be — on its own domain against raw, and on the
    windows inside both its and the baseline's domain against the baseline."""
    n_units = pooled.n_units

    def total(x: np.ndarray, m: np.ndarray) -> np.ndarray:
        return window_ss(x[m], wl[m], un[m], n_units)[0].sum(0)

    ib = inside[baseline] if baseline is not None else None
    pooled.base_judged.append(bool(ib is not None and ib.sum() >= 2))
    for k, m in inside.items():
        pooled.gate_own[k].append((total(e[k], m), total(y, m)) if m.sum() >= 2 else None)
        if ib is None:
            pooled.gate_pair[k].append(None)
            continue
        both = m & ib
        pooled.gate_pair[k].append(
            (total(e[k], both), total(e[baseline], both), total(y, both))   # type: ignore[index]
            if both.sum() >= 2 else None)
