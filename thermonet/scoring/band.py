"""How wrong is the corrected output: a residual-drift band per axis, from the out-of-fold
residuals that chose the model.

What the band is
----------------
For each output axis a half-width :math:`b_a(T)` such that, on a run like the training runs,
a window mean of the corrected output's residual drift lies within :math:`\\pm b_a(T)` of that
run's mean residual for a fraction ``level`` (default 0.9) of the windows.  It is a statement
about the *low-frequency* residual as the selection scores it
(:mod:`thermonet.scoring.selection`: means over ``window_s`` windows, offset-free about the
fold's mean): white noise, a run's constant turn-on offset (a navigation filter's bias state
absorbs it), shocks, aging and anything the training runs did not show are not in it.

How it is made
--------------
* **Calibration set**: the shipped candidate's out-of-fold predictions (the same purged,
  blocked folds that chose it).  Per fold, the residual ``e = y − d̂`` on the axes the model
  compensates (``e = y`` on an axis left raw: the shipped output is raw there), its window
  means inside each contiguous validation stretch of each run, taken about the fold's
  sample-weighted mean; only rows inside the fold's trained domain
  (:func:`~thermonet.scoring.selection.in_domain`) count for the in-range band.  The score of
  a window is ``|m_w − m̄|``, its position the window's mean temperature (the band is a
  function of temperature only — the first signal of the model, temperature where it reads
  one — not of the dynamic inputs: they widen nothing here; documented in configs/README.md).
* **In range**: ``band.bins`` equal-width bins over the model's trained range; adjacent bins
  are merged (the one with fewest windows into its smaller neighbour) until each holds at
  least :func:`min_windows` windows; per bin the split-conformal quantile: the
  ``⌈(n + 1)·level⌉``-th smallest of its n scores.  With fewer windows than that in the whole
  pool the band is refused (the number needed is said).
* **Past the edge** (per edge): the model's signals are clamped to the trained range on board,
  so the prediction holds its edge value and the error grows at the rate the drift itself
  changes there.  The growth rate is ``|slope| + SE`` of the raw drift's window means against
  temperature in the edge bin (least squares, each fold about its own mean), or, where folds
  did extrapolate (windows past the fold's own trained range, at least :func:`min_windows`
  of them), the conformal quantile of their excess ``(|r| − b(edge)) / distance`` if that is
  larger.  :math:`b(T) = b(\\text{edge}) + g\\,|T − \\text{edge}|` outside.

* **What it was judged on** (:attr:`Band.holds_for`, where the signal is the temperature):
  the directions of temperature change its calibration windows held (each window's
  excursion's, :mod:`thermonet.scoring.band_rates`) and, per direction, the fastest of their
  rates (°C/min, each window's least-squares slope).  A direction with fewer than
  :func:`min_windows` windows was not judged.  A test window of an excursion in a direction
  never judged, or faster than the fastest judged, is outside what the band states (a lag's
  error grows with the rate; a hysteresis flips with the direction): the report says so,
  and ``bench_uncertainty.py stress`` measures the coverage inside and outside them.

The band is what :class:`Band` holds and evaluates (:meth:`Band.evaluate`); the ONNX runtime
(``export/thermonet_runtime.py``) and the C header evaluate the same tables.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.recording import KNOWN_UNITS, TEMPERATURE
from ..data.mapping import UNIT_IN_DEFAULT
from .band_rates import (
    holds_for,
    holds_meaning,
    min_windows,
    outside_holds,
    sample_directions,
    window_directions,
    window_means,
    window_rates,
)
from .fold_plan import window_labels

__all__ = ["Band", "AxisBand", "min_windows", "conformal_quantile", "band_from_oof",
           "evaluate_tables", "DEFAULT_LEVEL", "DEFAULT_BINS", "display_units", "band_problem",
           "check_level", "shipped_band", "holds_for", "window_means", "window_rates",
           "outside_holds", "sample_directions", "window_directions"]

DEFAULT_LEVEL = 0.9
DEFAULT_BINS = 4
#: A window counts as extrapolating (for the growth rate) this fraction of the trained span
#: past its fold's edge or more: nearer, thermometer noise would make a rate of nothing.
MIN_PAST = 0.02

#: Per dimension: the display kind and the SI value of its default unit (deg/s in rad/s,
#: g in m/s²); a unit's SI value is its value in the default unit (``UNIT_IN_DEFAULT``)
#: times that.
_SI_OF_DEFAULT = {"rate": ("gyro", math.pi / 180.0), "acceleration": ("acc", 9.80665)}
_DISPLAY = {"gyro": ("deg/h", math.pi / 180.0 / 3600.0), "acc": ("mg", 9.80665e-3)}


def display_units(unit: str) -> tuple[str, float] | None:
    """(``deg/h`` or ``mg``, factor from ``unit``) for a gyro or accelerometer unit, else None."""
    of = _SI_OF_DEFAULT.get(KNOWN_UNITS.get(unit, ""))
    if of is None or unit not in UNIT_IN_DEFAULT:
        return None
    name, si = _DISPLAY[of[0]]
    return name, UNIT_IN_DEFAULT[unit] * of[1] / si


def conformal_quantile(scores: np.ndarray, level: float) -> float:
    """The ⌈(n + 1)·level⌉-th smallest of ``scores`` (inf where n is too small)."""
    s = np.sort(np.asarray(scores, dtype=np.float64))
    k = math.ceil((s.size + 1) * level - 1e-9)
    return float(s[k - 1]) if 0 < k <= s.size else math.inf


def check_level(level: Any, key: str = "band.level") -> float:
    if isinstance(level, bool) or not isinstance(level, int | float) or \
            not math.isfinite(level) or not 0.0 < level < 1.0:
        raise ConfigError(f"key '{key}': must be a number strictly between 0 and 1 (the band's "
                          f"nominal coverage, e.g. 0.9), got {level!r}")
    return float(level)


@dataclass
class AxisBand:
    """One axis: bin edges (K + 1) over the trained range, per bin the half-width and the
    windows it rests on, the growth rate past each edge (output unit per signal unit)."""

    edges: list[float]
    half: list[float]
    n: list[int]
    grow_lo: float
    grow_hi: float
    grow_rule: str = ""

    def to_json(self) -> dict[str, Any]:
        return {"edges": list(self.edges), "half_width": list(self.half), "windows": list(self.n),
                "growth_below": self.grow_lo, "growth_above": self.grow_hi,
                "growth_rule": self.grow_rule}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> AxisBand:
        return cls([float(x) for x in d["edges"]], [float(x) for x in d["half_width"]],
                   [int(x) for x in d.get("windows", [])], float(d["growth_below"]),
                   float(d["growth_above"]), str(d.get("growth_rule", "")))


def evaluate_tables(x: np.ndarray, edges: Sequence[float] | np.ndarray,
                    half: Sequence[float] | np.ndarray,
                    grow_lo: float, grow_hi: float) -> np.ndarray:
    """The band at ``x`` (N,): piecewise constant over ``edges``, growing linearly past them;
    NaN where ``x`` is NaN or infinite.  (The runtime and the C header evaluate the same
    rule.)"""
    x = np.asarray(x, dtype=np.float64)
    e = np.asarray(edges, dtype=np.float64)
    h = np.asarray(half, dtype=np.float64)
    k = np.clip(np.searchsorted(e[1:-1], x, side="right"), 0, h.size - 1)
    out = h[k].copy()
    below, above = x < e[0], x > e[-1]
    out[below] = h[0] + grow_lo * (e[0] - x[below])
    out[above] = h[-1] + grow_hi * (x[above] - e[-1])
    out[~np.isfinite(x)] = np.nan
    return out


@dataclass
class Band:
    """Per output axis an :class:`AxisBand`, all functions of one signal."""

    level: float
    signal: str
    window_s: float
    axes: dict[str, AxisBand]
    units: dict[str, str] = field(default_factory=dict)
    #: the 95th percentile of |d signal / dt| over the training runs' windows (signal unit
    #: per second): how fast the bias moves is the band's rate times this (EKF settings)
    signal_rate: float | None = None
    #: °C/min: per direction ("heating", "cooling") the fastest calibration window's rate,
    #: None where the direction was not judged (:func:`holds_for`); empty: not stated (a
    #: band of a proxy signal, or one made before it was recorded)
    holds_for: dict[str, float | None] = field(default_factory=dict)

    def evaluate(self, x: np.ndarray, outputs: Sequence[str] | None = None) -> np.ndarray:
        """Half-width (N, A) at signal values ``x`` (N,), in the outputs' units; columns in
        the order of ``outputs`` (default: the band's own)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        cols = [evaluate_tables(x, b.edges, b.half, b.grow_lo, b.grow_hi)
                for b in (self.axes[a] for a in (outputs or list(self.axes)))]
        return np.stack(cols, axis=1) if cols else np.zeros((x.size, 0))

    def filter_numbers(self) -> dict[str, dict[str, float]]:
        """Per axis: the bias bound (largest in-range half-width) and its rate of change with
        the signal (the largest of the step between bins over their spacing and the growth
        past the edges), in the output unit (per signal unit)."""
        out = {}
        for a, b in self.axes.items():
            mids = [(lo + hi) / 2 for lo, hi in zip(b.edges[:-1], b.edges[1:], strict=True)]
            steps = [abs(h2 - h1) / max(m2 - m1, 1e-12) for h1, h2, m1, m2 in
                     zip(b.half[:-1], b.half[1:], mids[:-1], mids[1:], strict=True)]
            out[a] = {"bound": float(max(b.half)),
                      "rate": float(max([*steps, b.grow_lo, b.grow_hi]))}
        return out

    def to_json(self) -> dict[str, Any]:
        doc: dict[str, Any] = {
            "level": self.level, "signal": self.signal, "window_s": self.window_s,
            "meaning": (f"a {self.window_s:g} s window mean of the corrected output's residual "
                        f"lies within ± the half-width of the run's mean residual for "
                        f"{self.level:.0%} of windows on runs like the training runs "
                        "(drift only: not noise, shocks, aging or a run's constant offset)"),
            "axes": {a: b.to_json() for a, b in self.axes.items()}}
        figures = {}
        for a, b in self.axes.items():
            du = display_units(self.units.get(a, ""))
            if du is not None:
                figures[a] = {"unit": du[0], "half_width": [h * du[1] for h in b.half],
                              "growth_below": b.grow_lo * du[1],
                              "growth_above": b.grow_hi * du[1]}
        if self.units:
            doc["units"] = dict(self.units)
        if self.signal_rate is not None:
            doc["signal_rate_p95"] = self.signal_rate
            doc["filter"] = self.filter_numbers()
        if figures:
            doc["display"] = figures
        if self.holds_for:
            doc["holds_for"] = {**{f"{k}_c_per_min": v for k, v in self.holds_for.items()},
                                "meaning": holds_meaning(self.holds_for)}
        return doc

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Band:
        """The band a checkpoint or metadata holds; ValueError naming what is wrong."""
        why = band_problem(d)
        if why:
            raise ValueError(why)
        rate = d.get("signal_rate_p95")
        held = d.get("holds_for") if isinstance(d.get("holds_for"), Mapping) else {}
        holds = {k: (float(held[f"{k}_c_per_min"]) if _finite(held.get(f"{k}_c_per_min"))
                     and held[f"{k}_c_per_min"] >= 0 else None)
                 for k in ("heating", "cooling")} if held else {}
        return cls(float(d["level"]), str(d["signal"]), float(d["window_s"]),
                   {a: AxisBand.from_json(b) for a, b in d["axes"].items()},
                   dict(d.get("units", {})), float(rate) if _finite(rate) else None,  # type: ignore[arg-type]
                   holds)


def shipped_band(extra: Mapping[str, Any]) -> dict[str, Any] | None:
    """The tables an exported file carries (ONNX metadata ``band``, the C header) from a
    checkpoint's ``extra``: level, signal, window and per axis the edges, half-widths and
    growth rates; None when the checkpoint has no band."""
    d = extra.get("band")
    if not isinstance(d, Mapping) or d.get("status", "ok") != "ok" or band_problem(d):
        return None
    return {"level": d["level"], "signal": d["signal"], "window_s": d["window_s"],
            **({"signal_rate_p95": d["signal_rate_p95"]} if _finite(d.get("signal_rate_p95"))
               else {}),
            # where it holds (C: <prefix>_band_holds); Band.from_json reads it back
            **({"holds_for": dict(d["holds_for"])} if isinstance(d.get("holds_for"), Mapping)
               else {}),
            "axes": {a: {k: b[k] for k in ("edges", "half_width", "growth_below",
                                            "growth_above")}
                     for a, b in d["axes"].items()}}


def _finite(x: Any) -> bool:
    return not isinstance(x, bool) and isinstance(x, int | float) and math.isfinite(x)


def band_problem(d: Any) -> str | None:
    """What is wrong with a band document (None when it is a band :meth:`Band.evaluate`
    can evaluate): level in (0, 1), per axis increasing finite edges, one finite half-width
    ≥ 0 per bin, finite growth rates ≥ 0."""
    if not isinstance(d, Mapping):
        return "band: expected a mapping"
    if not _finite(d.get("level")) or not 0 < d["level"] < 1:
        return f"band.level: expected a number in (0, 1), got {d.get('level')!r}"
    if not isinstance(d.get("signal"), str) or not _finite(d.get("window_s")):
        return "band: expected a signal name and window_s"
    axes = d.get("axes")
    if not isinstance(axes, Mapping) or not axes:
        return "band.axes: expected a mapping axis -> tables"
    for a, b in axes.items():
        if not isinstance(b, Mapping):
            return f"band.axes.{a}: expected a mapping"
        e, h = b.get("edges"), b.get("half_width")
        if not isinstance(e, list) or not isinstance(h, list) or len(e) < 2 or \
                len(h) != len(e) - 1 or not all(_finite(x) for x in e + h):
            return f"band.axes.{a}: expected finite edges (K + 1) and half_width (K)"
        if any(x2 <= x1 for x1, x2 in zip(e[:-1], e[1:], strict=True)) or min(h) < 0:
            return f"band.axes.{a}: edges must increase and half-widths be >= 0"
        for g in ("growth_below", "growth_above"):
            if not _finite(b.get(g)) or b[g] < 0:
                return f"band.axes.{a}.{g}: expected a finite number >= 0"
    return None


# ----------------------------------------------------------------------------- estimation
def _bins(t: np.ndarray, lo: float, hi: float, bins: int, need: int) -> list[float]:
    """Equal-width edges over [lo, hi], bins merged until each holds ``need`` windows."""
    edges = list(np.linspace(lo, hi, max(int(bins), 1) + 1))
    while len(edges) > 2:
        k = np.clip(np.searchsorted(np.asarray(edges[1:-1]), t, side="right"), 0,
                    len(edges) - 2)
        counts = np.bincount(k, minlength=len(edges) - 1)
        worst = int(np.argmin(counts))
        if counts[worst] >= need:
            break
        # merge with the neighbour holding fewer windows (an end bin has one neighbour)
        left = counts[worst - 1] if worst > 0 else None
        right = counts[worst + 1] if worst + 1 < counts.size else None
        if right is None or (left is not None and left <= right):
            del edges[worst]          # the edge between worst − 1 and worst
        else:
            del edges[worst + 1]      # the edge between worst and worst + 1
    return [float(e) for e in edges]


def _edge_slope(t: np.ndarray, y: np.ndarray, fold: np.ndarray, edge: float) -> float:
    """|slope at ``edge``| + its standard error of ``y`` on ``t``: a quadratic in
    ``t − edge`` (a line with fewer than 6 windows), each fold about its own means."""
    u = t - edge
    cols = [u, u ** 2] if t.size >= 6 else [u]
    X = np.column_stack(cols)
    yc = y.copy()
    for f in np.unique(fold):
        m = fold == f
        X[m] -= X[m].mean(axis=0)
        yc[m] -= yc[m].mean()
    if t.size < X.shape[1] + 2:
        return 0.0
    xtx = X.T @ X
    if not np.isfinite(xtx).all() or np.linalg.cond(xtx) > 1e12:
        return 0.0
    beta = np.linalg.solve(xtx, X.T @ yc)
    resid = yc - X @ beta
    s2 = float(resid @ resid) / max(t.size - X.shape[1], 1)
    se = math.sqrt(max(float(np.linalg.inv(xtx)[0, 0]) * s2, 0.0))
    return abs(float(beta[0])) + se


def band_from_oof(*, plan: Any, targets: Sequence[np.ndarray], times: Sequence[np.ndarray],
                  temps: Sequence[np.ndarray], oofs: Sequence[Any], compensate: Sequence[bool],
                  ranges: Sequence[tuple[float, float]], outputs: Sequence[str],
                  level: float = DEFAULT_LEVEL, bins: int = DEFAULT_BINS,
                  signal: str = "temperature", units: Mapping[str, str] | None = None,
                  window_s: float | None = None) -> Band:
    """The band of a shipped model from out-of-fold predictions (module docstring).

    ``plan``: the :class:`~thermonet.scoring.fold_plan.FoldPlan`; ``targets``/``times``/
    ``temps``: per pool run, every row's target (n, A), time and band signal; ``oofs``: per
    output axis, the :class:`~thermonet.scoring.selection.CandidateOOF` of the candidate that
    ships it (None: the axis is raw); ``compensate``: per axis whether the shipped model
    corrects it; ``ranges``: per axis the shipped model's trained range of the signal.
    Raises :class:`ConfigError` (naming ``band.level``) when the pool gives too few windows.
    """
    level = check_level(level)
    need = min_windows(level)
    win = float(window_s if window_s is not None else plan.window_s)
    axes: dict[str, AxisBand] = {}
    cache: dict[int, tuple[Any, ...]] = {}
    for a, axis in enumerate(outputs):
        oof = oofs[a]
        key = id(oof)
        if key not in cache:
            cache[key] = _scores(plan, targets, times, temps, oof, win)
        (s_in, t_in, y_in, f_in, s_out, t_out, d_out, edge_out, _, _) = cache[key]
        comp = bool(compensate[a]) and oof is not None
        r_in = s_in[:, a] if comp else np.abs(y_in[:, a])
        r_out = s_out[:, a] if comp else None
        if r_in.size < need:
            raise ConfigError(
                f"key 'band.level': {level:g} needs at least {need} out-of-fold windows "
                f"({win:g} s) inside the trained range, and axis {axis} has {r_in.size}; lower "
                "band.level or give more data (longer runs, more runs)")
        lo, hi = ranges[a]
        edges = _bins(t_in, lo, hi, bins, need)
        k = np.clip(np.searchsorted(np.asarray(edges[1:-1]), t_in, side="right"), 0,
                    len(edges) - 2)
        half = [conformal_quantile(r_in[k == j], level) for j in range(len(edges) - 1)]
        n = [int((k == j).sum()) for j in range(len(edges) - 1)]
        # growth past each edge: the raw drift's slope in the edge bin (clamped prediction)
        y_raw = y_in[:, a]
        grow = []
        for j, edge in ((0, edges[0]), (len(edges) - 2, edges[-1])):
            m = k == j
            grow.append(_edge_slope(t_in[m], y_raw[m], f_in[m], edge) if m.sum() >= 3
                        else 0.0)
        rule = ("raw drift slope at the edge + SE (quadratic over the edge bin; the model "
                "holds its edge value)")
        far = d_out >= MIN_PAST * (hi - lo)
        if r_out is not None and far.any():
            # windows of folds that extrapolate: their excess over the band at the fold's
            # edge per unit of distance; the conformal quantile with enough of them, their
            # largest otherwise (the finite-sample quantile at level n / (n + 1))
            at_edge = evaluate_tables(edge_out[far], edges, half, 0.0, 0.0)
            rate = np.maximum(np.abs(r_out[far]) - at_edge, 0.0) / d_out[far]
            fitted = conformal_quantile(rate, level) if rate.size >= need else float(rate.max())
            if math.isfinite(fitted) and fitted > max(grow):
                grow = [max(g, fitted) for g in grow]
                rule = (f"excess rate of {rate.size} windows of folds that extrapolate "
                        f"({'quantile' if rate.size >= need else 'largest'})")
        axes[axis] = AxisBand(edges, half, n, float(grow[0]), float(grow[1]), rule)
    # what the calibration windows held, every shipped candidate's (a temperature's rates)
    held = holds_for(np.concatenate([c[8] for c in cache.values()]),
                     np.concatenate([c[9] for c in cache.values()]), level) \
        if signal in ("temperature", TEMPERATURE) else {}
    return Band(level, signal, win, axes, dict(units or {}), _signal_rate(times, temps, win),
                held)


def _signal_rate(times: Sequence[np.ndarray], temps: Sequence[np.ndarray], window_s: float
                 ) -> float | None:
    """95th percentile of |Δ signal / Δt| between consecutive windows of every run."""
    rates = []
    for t, x in zip(times, temps, strict=True):
        t = np.asarray(t, dtype=np.float64)
        x = np.asarray(x, dtype=np.float64)
        ok = np.isfinite(t) & np.isfinite(x)
        if ok.sum() < 2:
            continue
        m, _ = window_means(np.column_stack([t[ok], x[ok]]), window_labels(t[ok], window_s))
        dt = np.diff(m[:, 0])
        good = dt > 0
        rates.append(np.abs(np.diff(m[:, 1])[good] / dt[good]))
    r = np.concatenate(rates) if rates else np.zeros(0)
    return float(np.percentile(r, 95)) if r.size else None


def _scores(plan: Any, targets: Sequence[np.ndarray], times: Sequence[np.ndarray],
            temps: Sequence[np.ndarray], oof: Any, window_s: float) -> tuple[np.ndarray, ...]:
    """Per window of every fold: the residual's and the raw target's offset-free window means
    (in the fold's trained domain), their temperature and fold; the windows past the
    fold's trained temperature range (score, temperature, distance, the fold's edge); and the
    in-domain windows' rates of the signal (per minute, :func:`window_rates`) and their
    excursions' directions (:func:`window_directions`)."""
    A = targets[0].shape[1]
    s_in, t_in, y_in, f_in, v_in, g_in = [], [], [], [], [], []
    # each run's excursions, on its whole continuous trace (a fold's rows are a part of it)
    dirs = [sample_directions(np.asarray(x, dtype=np.float64)) for x in temps]
    s_out, t_out, d_out, e_out = [], [], [], []
    for f in range(plan.k):
        # the fold's trained temperature range
        tr = [np.asarray(temps[j], dtype=np.float64)[plan.train_masks[f][j]]
              for j in range(len(targets))]
        tr = [x[np.isfinite(x)] for x in tr if x.size]
        tr = [x for x in tr if x.size]
        if not tr:
            continue
        flo = min(float(x.min()) for x in tr)
        fhi = max(float(x.max()) for x in tr)
        res_w, raw_w, tw, nw, inside_w, rw, dw = [], [], [], [], [], [], []
        for j, fo in enumerate(plan.fold_of):
            rows = np.flatnonzero(fo == f)
            if rows.size == 0:
                continue
            y = np.asarray(targets[j], dtype=np.float64)[rows]
            pred = oof.pred[f][j] if oof is not None else np.zeros_like(y)
            inside = oof.inside[f][j] if oof is not None else np.isfinite(y).all(axis=1)
            t = np.asarray(temps[j], dtype=np.float64)[rows]
            ok = np.isfinite(y).all(axis=1) & np.isfinite(pred).all(axis=1) & np.isfinite(t)
            if not ok.any():
                continue
            tj = np.asarray(times[j], dtype=np.float64)[rows]
            wl = window_labels(tj, window_s)
            vals = np.column_stack([y - pred, y, t, inside.astype(np.float64)])[ok]
            means, n = window_means(vals, wl[ok])
            rw.append(window_rates(tj[ok], t[ok], wl[ok]))
            dw.append(window_directions(dirs[j][rows][ok], wl[ok]))
            res_w.append(means[:, :A])
            raw_w.append(means[:, A:2 * A])
            tw.append(means[:, 2 * A])
            inside_w.append(means[:, 2 * A + 1] >= 0.5)
            nw.append(n)
        if not res_w:
            continue
        r, yv, t = np.vstack(res_w), np.vstack(raw_w), np.concatenate(tw)
        n, ins, rate = np.concatenate(nw), np.concatenate(inside_w), np.concatenate(rw)
        drn = np.concatenate(dw)
        if not ins.any():
            continue
        # offset-free about the fold's mean of its in-domain windows (sample-weighted)
        rbar = (r[ins] * n[ins, None]).sum(0) / n[ins].sum()
        ybar = (yv[ins] * n[ins, None]).sum(0) / n[ins].sum()
        s_in.append(np.abs(r[ins] - rbar))
        y_in.append(yv[ins] - ybar)
        t_in.append(t[ins])
        f_in.append(np.full(int(ins.sum()), f))
        v_in.append(rate[ins])
        g_in.append(drn[ins])
        past = ~ins & ((t < flo) | (t > fhi))
        if past.any():
            s_out.append(np.abs(r[past] - rbar))
            t_out.append(t[past])
            d_out.append(np.where(t[past] < flo, flo - t[past], t[past] - fhi))
            e_out.append(np.where(t[past] < flo, flo, fhi))

    def cat(x: list[np.ndarray], cols: int | None) -> np.ndarray:
        if x:
            return np.concatenate(x) if cols is None else np.vstack(x)
        return np.zeros((0,) if cols is None else (0, cols))
    # y_in: the raw drift's signed window means (its slope; |y| is the raw axis's score)
    return (cat(s_in, A), cat(t_in, None), cat(y_in, A), cat(f_in, None),
            cat(s_out, A), cat(t_out, None), cat(d_out, None), cat(e_out, None),
            cat(v_in, None), cat(g_in, None))
