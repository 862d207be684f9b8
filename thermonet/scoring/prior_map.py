"""The fleet's short test: how a station's fixed test responds to a unit's drift curve,
learned from units that ran both the test and their full calibration.

Why
---
A short test read as 1 °C points (:mod:`thermonet.scoring.prior_points`) says little: a
10-minute up-and-down never lets the thermometer settle, so its fast samples are no points,
and three soaks leave the curve between them to the prior.  Yet every unit of a line runs the
*same* test: the same chamber profile, the same thermal path from chamber to die, the same
lag.  What the test reads is then, to first order, a fixed linear response to the unit's
drift curve, whatever the lag does to it — and a fleet whose units ran the test *and* their
full calibration shows that response.  This is regression calibration (Carroll et al.,
*Measurement Error in Nonlinear Models*, 2nd ed., ch. 4): the pilot units' full calibrations
are the reference, their short tests the surrogate.

What is learned
---------------
The test's record is cut into ``n`` windows of ``window_s`` from its first sample; a window's
value is the mean reading (the axis's target) over it.  A unit's window means, centred (its
turn-on offset and the level of an ``at-t-ref`` target are free) and the last one dropped (it
is minus the sum of the others), are ``f`` (``n − 1`` values).  Over the pilot units, per axis,

    f_u = f₀ + A (β_u − β̄) + ε_u,     ε_u ~ N(0, Σ)

by least squares on the units' full-calibration shapes ``β_u``
(:func:`~thermonet.scoring.prior.fit_unit` on their sweep); ``Σ`` is the Ledoit–Wolf shrunk
covariance of the residuals (scikit-learn), scaled up by ``u / (u − d − 1)`` for the fitted
coefficients.  A new unit's posterior is then the fleet prior updated by
``y = f − f₀ + A β̄ = A β + ε`` (:meth:`TestMap.stats`: whitened by ``Σ``, the same conjugate
update as points, :func:`~thermonet.scoring.prior.posterior_from_stats`).

Its limits, stated
------------------
* It applies to the test the pilot units ran, and only to it: a new unit's window
  temperatures must follow the pilot units' (:meth:`TestMap.mismatch`: each window within
  :data:`TRACE_SIGMAS` of their spread, never tighter than :data:`TRACE_FLOOR_C`), its
  record at least as long; otherwise the unit is calibrated from its points and says why.
* It learns the response of the units' *full calibration* (the shape their sweep gives), so
  the best it can do is the sweep's own error (``bench_prior.py``: 0.9–1.05× it from 10
  minutes of ramp).
* The response is linear in the shape: a cubic's coefficients enter the reading linearly at
  any lag, so this holds while the thermal path is the fleet's; a unit mounted otherwise
  (another fixture, another chamber) is outside it, and its trace check may not see that.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.errors import InputError

__all__ = ["TestMap", "numbers_only", "AxisMap", "fit_test_map", "window_means", "map_window_s",
           "map_from_dict", "MIN_MAP_UNITS", "MIN_WINDOW_S", "MAX_WINDOWS", "TRACE_SIGMAS",
           "TRACE_FLOOR_C"]

#: Pilot units needed, with both a short test and a full calibration.
MIN_MAP_UNITS = 10
#: The shortest window (s), and the most windows a test is cut into (a longer test gets
#: longer windows: duration / MAX_WINDOWS, rounded up to a whole second).
MIN_WINDOW_S = 30.0
MAX_WINDOWS = 60
#: A new unit follows the pilot units' test where each window's mean temperature is within
#: this many of their standard deviations of theirs, and within TRACE_FLOOR_C at least.
TRACE_SIGMAS = 4.0
TRACE_FLOOR_C = 1.0
#: A pilot unit whose window temperatures stray further than this (°C) from the pilots'
#: median at some window ran another test: it is left out of the map.
PILOT_TRACE_C = 5.0
#: A window is a value where at least this share of its samples are finite.
MIN_WINDOW_SHARE = 0.5


def map_window_s(duration_s: float) -> float:
    """The window a test of ``duration_s`` is cut into (:data:`MIN_WINDOW_S` at least)."""
    return max(MIN_WINDOW_S, float(math.ceil(duration_s / MAX_WINDOWS)))


def window_means(time_s: np.ndarray, values: np.ndarray, window_s: float, n: int
                 ) -> np.ndarray:
    """The means of ``values`` (samples × columns) over ``n`` windows of ``window_s`` from
    the first sample; NaN where fewer than half a window's samples are finite or the record
    ends before the window does."""
    t = np.asarray(time_s, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64).reshape(t.size, -1)
    out = np.full((n, v.shape[1]), np.nan)
    if t.size == 0:
        return out
    k = np.floor((t - t[0]) / window_s).astype(np.int64)
    dt = float(np.median(np.diff(t))) if t.size > 1 else window_s
    expected = window_s / dt if dt > 0 else 1.0
    ends = t[-1] - t[0]
    for w in range(n):
        if (w + 1) * window_s > ends + dt:
            break
        seg = v[k == w]
        ok = np.isfinite(seg)
        cnt = ok.sum(axis=0)
        good = cnt >= MIN_WINDOW_SHARE * expected
        with np.errstate(invalid="ignore"):
            out[w, good] = np.where(ok, seg, 0.0).sum(axis=0)[good] / cnt[good]
    return out


def _centre(f: np.ndarray) -> np.ndarray:
    """Window means (windows × …) about their mean, the last window dropped."""
    return (f - np.nanmean(f, axis=0, keepdims=True))[:-1]


@dataclass
class AxisMap:
    """One axis's response: ``f = f0 + A (β − β̄) + ε``, ``ε ~ N(0, cov)``."""

    f0: np.ndarray             # (n − 1,)
    A: np.ndarray              # (n − 1, d)
    beta_mean: np.ndarray      # (d,)
    cov: np.ndarray            # (n − 1, n − 1)


@dataclass
class TestMap:
    """The fleet's short test: its windows, its temperature trace and each axis's response."""

    __test__ = False           # not a pytest class, whatever imports it

    window_s: float
    trace_c: np.ndarray        # (n,) the pilot units' mean window temperature
    trace_sd_c: np.ndarray     # (n,)
    axes: dict[str, AxisMap]
    n_units: int

    @property
    def n_windows(self) -> int:
        return int(self.trace_c.size)

    def mismatch(self, time_s: np.ndarray, temperature_c: np.ndarray) -> str | None:
        """Why a unit's record is not this test (None: it is)."""
        t = np.asarray(time_s, dtype=np.float64)
        need = self.n_windows * self.window_s
        if t.size < 2 or t[-1] - t[0] + float(np.median(np.diff(t))) < need:
            got = (t[-1] - t[0]) / 60.0 if t.size else 0.0
            return (f"its record lasts {got:.3g} min, the fleet's short test "
                    f"{need / 60.0:.3g} min")
        temp = window_means(t, temperature_c, self.window_s, self.n_windows)[:, 0]
        tol = np.maximum(TRACE_SIGMAS * self.trace_sd_c, TRACE_FLOOR_C)
        with np.errstate(invalid="ignore"):
            off = np.abs(temp - self.trace_c)
        bad = np.flatnonzero(~(off <= tol))
        if bad.size:
            w = int(bad[0])
            at = "no temperature" if not math.isfinite(temp[w]) else f"{temp[w]:.1f} °C"
            return (f"at {w * self.window_s / 60.0:.3g}–{(w + 1) * self.window_s / 60.0:.3g} "
                    f"min it reads {at}, the fleet's short test {self.trace_c[w]:.1f} °C "
                    f"(± {tol[w]:.2g}): not the same test")
        return None

    def centred(self, values: np.ndarray) -> np.ndarray:
        """A unit's ``n`` raw window means on one axis as the map reads them: about their
        mean, the last dropped (``n − 1``; NaN stays NaN)."""
        return _centre(np.asarray(values, dtype=np.float64).reshape(-1)[:self.n_windows])

    def predict(self, axis: str, shape: np.ndarray) -> np.ndarray:
        """The centred window means a unit of drift shape ``shape`` reads on the test."""
        m = self.axes[axis]
        return np.asarray(m.f0 + m.A @ (np.asarray(shape, dtype=np.float64) - m.beta_mean))

    def stats(self, axis: str, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, int]:
        """The conjugate update's sufficient statistics of a unit's centred window means
        ``f`` (:meth:`centred`; NaN: not used) on ``axis``: ``J = XᵀX``, ``b = Xᵀy``,
        ``q0 = yᵀy`` of ``X = Lᵀ A``, ``y = Lᵀ (f − f0 + A β̄)`` (``L Lᵀ = Σ⁻¹`` over the
        finite windows) with a constant profiled out (the windows used may not be all that
        centred ``f``), and the residual degrees of freedom (windows − 1)."""
        m = self.axes[axis]
        ok = np.isfinite(f)
        if ok.sum() < 2:
            raise InputError(f"axis {axis}: fewer than 2 windows of the short test hold a value")
        L = np.linalg.cholesky(np.linalg.inv(m.cov[np.ix_(ok, ok)]))
        X = L.T @ m.A[ok]
        y = L.T @ (f[ok] - m.f0[ok] + m.A[ok] @ m.beta_mean)
        u = L.T @ np.ones(int(ok.sum()))
        X = X - np.outer(u, u @ X) / (u @ u)
        y = y - u * (u @ y) / (u @ u)
        return X.T @ X, X.T @ y, float(y @ y), int(ok.sum()) - 1

    def to_dict(self) -> dict[str, Any]:
        return {"window_s": self.window_s, "n_units": self.n_units,
                "trace_c": self.trace_c.tolist(), "trace_sd_c": self.trace_sd_c.tolist(),
                "method": "regression calibration: window means f = f0 + A (beta - "
                          "mean beta) + e over the pilot units, e ~ N(0, Ledoit-Wolf cov)",
                "axes": {a: {"f0": m.f0.tolist(), "A": m.A.tolist(),
                             "beta_mean": m.beta_mean.tolist(), "cov": m.cov.tolist()}
                         for a, m in self.axes.items()}}


def fit_test_map(shapes: dict[str, np.ndarray], windows: np.ndarray, temps: np.ndarray,
                 window_s: float, axes: list[str]) -> TestMap:
    """The map from pilot units' full-calibration shapes (per axis ``(units, d)``) and their
    short tests' window means (``(units, n, axes)``, raw) and window temperatures
    (``(units, n)``).  A unit missing a window, or whose window temperatures stray more than
    :data:`PILOT_TRACE_C` from the pilots' median (another test), is left out of the map;
    :attr:`TestMap.n_units` says how many it holds."""
    from sklearn.covariance import LedoitWolf

    n = temps.shape[1]
    keep = np.isfinite(windows).all(axis=(1, 2)) & np.isfinite(temps).all(axis=1)
    if keep.any():      # a unit whose chamber ran another test is not the line's test
        with np.errstate(invalid="ignore"):
            off = np.abs(temps - np.median(temps[keep], axis=0)).max(axis=1)
        keep &= off <= PILOT_TRACE_C
    if keep.sum() < MIN_MAP_UNITS or n < 3:
        raise InputError(f"{int(keep.sum())} of the prior's units have a complete short test "
                         f"({n} windows of {window_s:g} s); a map of the test needs "
                         f"{MIN_MAP_UNITS} units and 3 windows")
    temps, windows = temps[keep], windows[keep]
    out: dict[str, AxisMap] = {}
    for j, a in enumerate(axes):
        B = shapes[a][keep]
        F = np.stack([_centre(windows[u, :, j]) for u in range(B.shape[0])])
        beta_mean = B.mean(axis=0)
        X1 = np.column_stack([np.ones(B.shape[0]), B - beta_mean])
        C, *_ = np.linalg.lstsq(X1, F, rcond=None)
        E = F - X1 @ C
        dof = max(B.shape[0] - X1.shape[1], 1)
        cov = LedoitWolf(assume_centered=True).fit(E).covariance_ * B.shape[0] / dof
        floor = 1e-12 * max(float(np.trace(cov)) / cov.shape[0], 1e-300)
        out[a] = AxisMap(C[0], C[1:].T.copy(), beta_mean, cov + floor * np.eye(cov.shape[0]))
    return TestMap(float(window_s), temps.mean(axis=0), temps.std(axis=0, ddof=1), out,
                   int(keep.sum()))


# ------------------------------------------------------------------ read back, checked
def numbers_only(v: Any) -> bool:
    """Whether ``v`` is a JSON number or nested lists of them (no strings, booleans, nulls:
    NumPy would read the string "0.11" as 0.11, a prior file's hand edit)."""
    if isinstance(v, list):
        return all(numbers_only(x) for x in v)
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _arr(v: Any, shape: tuple[int, ...], source: str, key: str) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64) if numbers_only(v) else np.empty(0)
    except (TypeError, ValueError):
        a = np.empty(0)
    if a.shape != shape or not np.isfinite(a).all():
        raise InputError(f"{source}: key '{key}': expected finite numbers of shape {shape}")
    return a


def map_from_dict(v: Any, source: str, axes: list[str], degree: int) -> TestMap:
    """A short-test map read from a prior file, checked whole (each error names the key)."""
    def bad(key: str, what: str) -> InputError:
        return InputError(f"{source}: key 'short_test{key}': {what}")

    if not isinstance(v, dict):
        raise bad("", "expected a mapping")
    ws, nu = v.get("window_s"), v.get("n_units")
    if isinstance(ws, bool) or not isinstance(ws, (int, float)) or not 0 < ws < 86400:
        raise bad(".window_s", f"expected seconds in (0, 86400), got {ws!r}")
    if isinstance(nu, bool) or not isinstance(nu, int) or nu < MIN_MAP_UNITS:
        raise bad(".n_units", f"expected an integer ≥ {MIN_MAP_UNITS}, got {nu!r}")
    raw = v.get("trace_c")
    n = len(raw) if isinstance(raw, list) else 0
    if not 3 <= n <= MAX_WINDOWS:
        raise bad(".trace_c", f"expected a list of 3 to {MAX_WINDOWS} window temperatures")
    trace = _arr(raw, (n,), source, "short_test.trace_c")
    sd = _arr(v.get("trace_sd_c"), (n,), source, "short_test.trace_sd_c")
    if (sd < 0).any():
        raise bad(".trace_sd_c", "a standard deviation is negative")
    got = v.get("axes")
    if not isinstance(got, dict) or sorted(got) != sorted(axes):
        raise bad(".axes", f"expected one map per axis of the prior ({', '.join(axes)})")
    out: dict[str, AxisMap] = {}
    for a in axes:
        m, k = got[a], f"short_test.axes.{a}"
        if not isinstance(m, dict):
            raise bad(f".axes.{a}", "expected a mapping")
        cov = _arr(m.get("cov"), (n - 1, n - 1), source, f"{k}.cov")
        if not np.allclose(cov, cov.T, rtol=1e-9, atol=0) or np.linalg.eigvalsh(cov).min() <= 0:
            raise bad(f".axes.{a}.cov", "not a symmetric positive definite covariance")
        out[a] = AxisMap(_arr(m.get("f0"), (n - 1,), source, f"{k}.f0"),
                         _arr(m.get("A"), (n - 1, degree), source, f"{k}.A"),
                         _arr(m.get("beta_mean"), (degree,), source, f"{k}.beta_mean"), cov)
    return TestMap(float(ws), trace, sd, out, nu)
