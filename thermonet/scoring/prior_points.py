"""The points a unit gives the fleet prior (:mod:`thermonet.scoring.prior`): one axis's
1 °C-binned means (:func:`bin_points`: one point per contiguous stay in a bin, samples taken
while the temperature moves too fast left out, each mean with its sampling variance), and the
design rows of the drift's shape on them (:func:`shape_design`: u, u², … of
u = (T − t_ref) / scale; :func:`centred`: each run's constant profiled out).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BIN_C", "MIN_BIN_SAMPLES", "MAX_RATE_C_PER_MIN", "RATE_WINDOW_S", "Points",
           "bin_points", "shape_design", "centred"]

#: The width (°C) of the bins a point is the mean of, centred on whole multiples.
BIN_C = 1.0
#: A 1 °C bin with fewer samples than this is not a point (a thermometer passing through).
MIN_BIN_SAMPLES = 10
#: Samples taken while the temperature changes faster than this are not points (°C/min;
#: the calibration ramps the fleet prior is built from run at 1 °C/min or slower).
MAX_RATE_C_PER_MIN = 1.2
#: The temperature is smoothed over this window before its rate is taken (s).
RATE_WINDOW_S = 60.0


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


def _rate_c_per_min(t: np.ndarray, time_s: np.ndarray) -> np.ndarray:
    """|dT/dt| in °C/min, the temperature smoothed over :data:`RATE_WINDOW_S` first."""
    from scipy.ndimage import uniform_filter1d

    dt = float(np.median(np.diff(time_s))) if time_s.size > 1 else 1.0
    size = max(1, int(round(RATE_WINDOW_S / max(dt, 1e-9))))
    ts = uniform_filter1d(t, size=min(size, t.size), mode="nearest")
    return np.abs(np.gradient(ts, time_s)) * 60.0 if t.size > 1 else np.zeros_like(t)


def bin_points(temperature_c: np.ndarray, values: np.ndarray, *, time_s: np.ndarray | None = None,
               run: int = 0, bin_c: float = BIN_C, min_samples: int = MIN_BIN_SAMPLES,
               max_rate_c_per_min: float = MAX_RATE_C_PER_MIN) -> Points:
    """Means of one run's visits to 1 °C bins (centred on whole degrees).

    A point is one contiguous stay in a bin: a soak is one point, a ramp one point per
    degree, and a cycle's heating and cooling passes through a bin two points (a mean over
    both would hide the hysteresis that a one-direction test then meets).  NaNs are dropped, and with ``time_s`` the samples taken while the temperature changed
    faster than ``max_rate_c_per_min`` (the thermometer lags the die: a point taken while
    the chamber jumps is wrong by the lag times the rate); bins under ``min_samples`` too.
    The sampling variance of a mean is the bin's sample variance over its count (white
    noise; correlated noise is in the fleet's misfit variance)."""
    t = np.asarray(temperature_c, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(y)
    if time_s is not None and ok.sum() > 1:
        ts = np.asarray(time_s, dtype=np.float64)
        rate = np.full(t.shape, np.inf)
        rate[ok] = _rate_c_per_min(t[ok], ts[ok])
        ok &= rate <= max_rate_c_per_min
    t, y = t[ok], y[ok]
    if t.size == 0:
        return Points(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, int), np.zeros(0, int))
    idx = np.floor(t / bin_c + 0.5).astype(np.int64)   # bins centred on k·bin_c
    pos = np.flatnonzero(ok)
    # a new visit where the bin changes or a sample was left out between two kept ones
    new = np.r_[True, (np.diff(idx) != 0) | (np.diff(pos) != 1)]
    inv = np.cumsum(new) - 1
    n = np.bincount(inv)
    mt, my = np.bincount(inv, t) / n, np.bincount(inv, y) / n
    var = np.bincount(inv, (y - my[inv]) ** 2) / np.maximum(n - 1, 1)
    keep = n >= min_samples
    return Points(mt[keep], my[keep], (var / n)[keep], np.full(int(keep.sum()), run),
                  n[keep])


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
