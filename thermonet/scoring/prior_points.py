"""The points a unit gives the fleet prior (:mod:`thermonet.scoring.prior`): one axis's
1 °C-binned means (:func:`bin_points`: one point per contiguous stay in a bin, samples taken
while the temperature moves too fast left out unless a steady ramp visits their bin both
heating and cooling at matching rates — then the two directions' means are one paired point,
the thermometer's lag cancelling — each mean with its sampling variance), and the
design rows of the drift's shape on them (:func:`shape_design`: u, u², … of
u = (T − t_ref) / scale; :func:`centred`: each run's constant profiled out).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BIN_C", "MIN_BIN_SAMPLES", "MAX_RATE_C_PER_MIN", "RATE_WINDOW_S", "Points",
           "bin_points", "shape_design", "centred", "SOAK_RATE_C_PER_MIN", "TEST_KINDS",
           "FAST_KIND",
           "motion_counts", "kind_of_test"]

#: The width (°C) of the bins a point is the mean of, centred on whole multiples.
BIN_C = 1.0
#: A 1 °C bin with fewer samples than this is not a point (a thermometer passing through).
MIN_BIN_SAMPLES = 10
#: Samples taken while the temperature changes faster than this are not points alone
#: (°C/min; the calibration ramps the fleet prior is built from run at 1 °C/min or slower);
#: a heating and cooling pair is a point when its net rate is within it, on a ramp whose
#: rate changes by no more than it within RATE_WINDOW_S either side (:func:`bin_points`).
MAX_RATE_C_PER_MIN = 1.2
#: The temperature is smoothed over this window before its rate is taken (s); also the
#: lag scale over which a paired sample's ramp must be steady.
RATE_WINDOW_S = 60.0
#: A sample whose smoothed temperature changes slower than this (°C/min) is on a soak.
SOAK_RATE_C_PER_MIN = 0.1
#: A test whose points pair heating with cooling above MAX_RATE_C_PER_MIN
#: (:func:`kind_of_test`).
FAST_KIND = "fast ramps"
#: What a unit's test is (:func:`kind_of_test`): the kind of the samples its points are
#: made of.
TEST_KINDS = ("soaks", "heating ramps", "cooling ramps", "cycles", FAST_KIND)


@dataclass
class Points:
    """Binned means of one axis: temperature, value, sampling variance, run of each point."""

    temperature_c: np.ndarray
    value: np.ndarray
    sampling_var: np.ndarray
    run: np.ndarray
    n_samples: np.ndarray

    @property
    def n_runs(self) -> int:
        return int(np.unique(self.run).size)

    def take(self, mask: np.ndarray) -> Points:
        return Points(*(np.asarray(a)[mask] for a in (self.temperature_c, self.value,
                                                      self.sampling_var, self.run,
                                                      self.n_samples)))

    @staticmethod
    def join(parts: list[Points]) -> Points:
        return Points(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                        ("temperature_c", "value", "sampling_var", "run", "n_samples")))


def _rate_c_per_min(t: np.ndarray, time_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """dT/dt in °C/min (signed: heating positive), the temperature smoothed over
    :data:`RATE_WINDOW_S` first, and how much that rate changes within
    :data:`RATE_WINDOW_S` either side of each sample (max − min, °C/min)."""
    from scipy.ndimage import maximum_filter1d, minimum_filter1d, uniform_filter1d

    if t.size < 2:
        return np.zeros_like(t), np.zeros_like(t)
    dt = float(np.median(np.diff(time_s)))
    size = min(max(1, int(round(RATE_WINDOW_S / max(dt, 1e-9)))), t.size)
    ts = uniform_filter1d(t, size=size, mode="nearest")
    rate = np.gradient(ts, time_s) * 60.0
    span = min(2 * size + 1, 2 * t.size - 1)
    return rate, (maximum_filter1d(rate, span, mode="nearest") -
                  minimum_filter1d(rate, span, mode="nearest"))


def motion_counts(temperature_c: np.ndarray, time_s: np.ndarray) -> np.ndarray:
    """How many of a run's point-making samples (those :func:`bin_points` keeps: slow ones,
    and fast ones on a steady ramp) were taken on a soak, heating, cooling (at most
    :data:`MAX_RATE_C_PER_MIN`) and faster: ``[soak, heating, cooling, fast]``."""
    t = np.asarray(temperature_c, dtype=np.float64)
    ts = np.asarray(time_s, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(ts)
    if ok.sum() < 2:
        return np.array([int(ok.sum()), 0, 0, 0])
    rate, change = _rate_c_per_min(t[ok], ts[ok])
    slow = np.abs(rate) <= MAX_RATE_C_PER_MIN
    soak = np.abs(rate) <= SOAK_RATE_C_PER_MIN
    moving = slow & ~soak
    return np.array([int(soak.sum()), int((moving & (rate > 0)).sum()),
                     int((moving & (rate < 0)).sum()),
                     int((~slow & (change <= MAX_RATE_C_PER_MIN)).sum())])


def kind_of_test(counts: np.ndarray) -> str:
    """A test's kind from its :func:`motion_counts` (summed over its runs): ``fast ramps``
    where most of its samples are fast ones (their points pair heating with cooling:
    :func:`bin_points`); else ``soaks`` where half or more sit on soaks; else ``cycles``
    where the lesser direction holds a quarter of the moving samples or more, else
    ``heating ramps`` / ``cooling ramps``."""
    soak, heat, cool, fast = (int(x) for x in counts)
    if fast > soak + heat + cool:
        return FAST_KIND
    if soak >= heat + cool:
        return "soaks"
    if min(heat, cool) >= 0.25 * (heat + cool):
        return "cycles"
    return "heating ramps" if heat >= cool else "cooling ramps"


def _empty() -> Points:
    return Points(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, int), np.zeros(0, int))


def _visits(t: np.ndarray, y: np.ndarray, pos: np.ndarray, idx: np.ndarray,
            run: int, min_samples: int) -> Points:
    """One point per contiguous stay in a bin (``pos``: the samples' places in the run)."""
    if t.size == 0:
        return _empty()
    # a new visit where the bin changes or a sample was left out between two kept ones
    new = np.r_[True, (np.diff(idx) != 0) | (np.diff(pos) != 1)]
    inv = np.cumsum(new) - 1
    n = np.bincount(inv)
    mt, my = np.bincount(inv, t) / n, np.bincount(inv, y) / n
    var = np.bincount(inv, (y - my[inv]) ** 2) / np.maximum(n - 1, 1)
    keep = n >= min_samples
    return Points(mt[keep], my[keep], (var / n)[keep], np.full(int(keep.sum()), run), n[keep])


def _pairs(t: np.ndarray, y: np.ndarray, rate: np.ndarray, idx: np.ndarray, run: int,
           min_samples: int, max_rate: float) -> Points:
    """Fast samples' paired points: per bin, the mean of its heating samples' mean and its
    cooling samples' mean, where both exist and their net rate is within ``max_rate``."""
    up = rate > 0
    pts: list[tuple[float, float, float, int]] = []
    for b in np.unique(idx):
        h, c = (idx == b) & up, (idx == b) & ~up
        nh, nc = int(h.sum()), int(c.sum())
        if nh == 0 or nc == 0 or nh + nc < min_samples or \
                abs(rate[h].mean() + rate[c].mean()) / 2.0 > max_rate:
            continue
        mh, mc = y[h].mean(), y[c].mean()
        pooled = (((y[h] - mh) ** 2).sum() + ((y[c] - mc) ** 2).sum()) / max(nh + nc - 2, 1)
        pts.append(((t[h].mean() + t[c].mean()) / 2.0, (mh + mc) / 2.0,
                    pooled * (1.0 / nh + 1.0 / nc) / 4.0, nh + nc))
    if not pts:
        return _empty()
    a = np.array(pts)
    return Points(a[:, 0], a[:, 1], a[:, 2], np.full(len(pts), run), a[:, 3].astype(int))


def bin_points(temperature_c: np.ndarray, values: np.ndarray, *, time_s: np.ndarray | None = None,
               run: int = 0, bin_c: float = BIN_C, min_samples: int = MIN_BIN_SAMPLES,
               max_rate_c_per_min: float = MAX_RATE_C_PER_MIN, pair_fast: bool = True) -> Points:
    """Means of one run's visits to 1 °C bins (centred on whole degrees).

    A point is one contiguous stay in a bin: a soak is one point, a ramp one per degree, and
    a cycle's heating and cooling passes through a bin two points (a mean over both would
    hide the hysteresis that a one-direction test then meets).  NaNs are dropped; bins under
    ``min_samples`` too.  The sampling variance of a mean is the bin's sample variance over
    its count (white noise; correlated noise is in the fleet's misfit variance).

    **Fast samples** (with ``time_s``: the temperature, smoothed over
    :data:`RATE_WINDOW_S`, changing faster than ``max_rate_c_per_min``).  The thermometer
    lags the die, so a sample taken at rate r is off by about (lag × r) in temperature: alone
    it is no point.  Heating and cooling carry that error with opposite signs, so where one
    run visits a bin both ways, the **paired point** — the mean of the bin's fast heating
    samples' mean and its fast cooling samples' mean, the two directions weighted equally —
    is off by the lag times the pair's *net* rate (the mean of the two directions' mean
    signed rates).  That holds on a **steady** ramp only: the lag's error is τ·r − τ²·dr/dt,
    and where the rate changes (a turn, a ramp's start and end) the second term has the same
    sign both ways and does not cancel; so a fast sample pairs only where its rate changes by
    at most ``max_rate_c_per_min`` within :data:`RATE_WINDOW_S` either side (the lag the
    window assumes).  A pair is a point when its net rate is within ``max_rate_c_per_min``
    (the protection a lone sample gets) and the two directions hold ``min_samples`` together;
    its sampling variance is the pooled variance × (1/n_heat + 1/n_cool) / 4.  Fast samples
    without such a partner are dropped (a one-way fast ramp gives no points).  A pair sits
    between a hysteresis's two branches, where a slow cycle's two points show both.
    ``pair_fast=False``: fast samples are always dropped."""
    t = np.asarray(temperature_c, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(y)
    fast = np.zeros(t.shape, bool)
    rate, change = np.zeros(t.shape), np.zeros(t.shape)
    if time_s is not None and ok.sum() > 1:
        ts = np.asarray(time_s, dtype=np.float64)
        rate[ok], change[ok] = _rate_c_per_min(t[ok], ts[ok])
        fast = ok & (np.abs(rate) > max_rate_c_per_min)
    idx = np.floor(np.where(ok, t, 0.0) / bin_c + 0.5).astype(np.int64)   # centred on k·bin_c
    slow = ok & ~fast
    parts = [_visits(t[slow], y[slow], np.flatnonzero(slow), idx[slow], run, min_samples)]
    steady = fast & (change <= max_rate_c_per_min)
    if pair_fast and steady.any():
        parts.append(_pairs(t[steady], y[steady], rate[steady], idx[steady], run,
                            min_samples, max_rate_c_per_min))
    return Points.join(parts)


def shape_design(temperature_c: np.ndarray, t_ref: float, scale: float,
                 degree: int) -> np.ndarray:
    """Columns u, u², … u^degree of u = (T − t_ref) / scale."""
    u = (np.asarray(temperature_c, dtype=np.float64) - t_ref) / scale
    return np.column_stack([u ** k for k in range(1, degree + 1)])


def centred(X: np.ndarray, y: np.ndarray, w: np.ndarray,
             run: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """X and y minus each run's weighted mean (a run's constant profiled out)."""
    Xc, yc = X.copy(), y.copy()
    for r in np.unique(run):
        m = run == r
        sw = w[m].sum()
        Xc[m] -= (w[m] @ X[m]) / sw
        yc[m] -= (w[m] @ y[m]) / sw
    return Xc, yc
