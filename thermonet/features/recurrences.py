"""The dynamic inputs' recurrences (:mod:`thermonet.features.dynamics`), vectorised for
training: the lag's state :math:`e = T - \\mathrm{EMA}_\\tau(T)` (:func:`lag_error`) and the
play operator's state :math:`P` (:func:`play_state`), each a causal recurrence evaluated in
O(N) by a three-pass block scan over ≈√N blocks (a linear one and a clamp one), bitwise the
numbers the sequential loop gives where it is a clamp, and stable for any time constant.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["lag_error", "play_state"]


def _block_layout(n: int) -> tuple[int, int]:
    # ≈√N blocks, at most 256 long: long enough to vectorise, short enough for the cache
    b = min(256, max(16, math.isqrt(max(n, 1))))
    return b, -(-n // b)


def _blocked(x: np.ndarray, fill: float, b: int, m: int) -> np.ndarray:
    """(b, m) layout: column j is block j, row i its i-th sample (contiguous rows)."""
    out = np.full(b * m, fill, dtype=np.float64)
    out[:x.size] = x
    return np.ascontiguousarray(out.reshape(m, b).T)


def _linear_scan(a: np.ndarray, c: np.ndarray, y0: float = 0.0) -> np.ndarray:
    """:math:`y_k = a_k y_{k-1} + c_k` (y_{-1} = ``y0``) in O(N), no division, no window factor.

    Samples are cut into √N blocks; one pass composes each block's map
    (vectorised over blocks), a scalar pass chains the ≈√N block maps, and a
    last pass replays every block from its incoming value.  Underflow of a
    product to 0 is exact here (the past is forgotten), so it is stable for
    any time constant.
    """
    n = a.size
    if n == 0:
        return np.zeros(0)
    b, m = _block_layout(n)
    ab, cb = _blocked(a, 1.0, b, m), _blocked(c, 0.0, b, m)
    y, p = np.zeros(m), np.ones(m)
    for i in range(b):
        y = ab[i] * y + cb[i]
        p = p * ab[i]
    inc = np.empty(m)
    s = float(y0)
    for j, (pj, yj) in enumerate(zip(p.tolist(), y.tolist(), strict=True)):
        inc[j] = s
        s = pj * s + yj
    out = np.empty((b, m))
    y = inc
    for i in range(b):
        y = ab[i] * y + cb[i]
        out[i] = y
    return out.T.reshape(-1)[:n]


def _clamp_scan(lo: np.ndarray, hi: np.ndarray, z0: float = 0.0) -> np.ndarray:
    """:math:`z_k = \\min(\\max(z_{k-1}, lo_k), hi_k)` in O(N) (z_{-1} = ``z0``; z_0 = lo_0 =
    hi_0 at a restart).

    Clamps compose into clamps, so the same three-pass block scan as
    :func:`_linear_scan` applies; every value is produced by exactly the
    comparisons the sequential loop makes (bitwise identical).
    """
    n = lo.size
    if n == 0:
        return np.zeros(0)
    b, m = _block_layout(n)
    lob, hib = _blocked(lo, -np.inf, b, m), _blocked(hi, np.inf, b, m)
    cl, ch = np.full(m, -np.inf), np.full(m, np.inf)
    for i in range(b):
        cl = np.minimum(np.maximum(cl, lob[i]), hib[i])
        ch = np.minimum(np.maximum(ch, lob[i]), hib[i])
    inc = np.empty(m)
    s = float(z0)
    for j, (lj, hj) in enumerate(zip(cl.tolist(), ch.tolist(), strict=True)):
        inc[j] = s
        s = min(max(s, lj), hj)
    out = np.empty((b, m))
    z = inc
    for i in range(b):
        z = np.minimum(np.maximum(z, lob[i]), hib[i])
        out[i] = z
    return out.T.reshape(-1)[:n]


def _g(h: np.ndarray) -> np.ndarray:
    """:math:`(1 - e^{-h})/h`, 1 at h = 0."""
    with np.errstate(invalid="ignore", divide="ignore"):
        g = -np.expm1(-h) / h
    return np.where(h > 0, g, 1.0)


def lag_error(t: np.ndarray, temp: np.ndarray, restart: np.ndarray, tau_s: float,
              prev: tuple[float, float, float] | None = None) -> np.ndarray:
    """:math:`e = T - \\mathrm{EMA}_\\tau(T)` on finite-T samples (see the module docstring).

    ``prev`` is (time, temperature, e) of the last finite-temperature sample before
    ``t[0]`` (a chunk's carried state); without it the first sample has no predecessor
    and must be a restart.
    """
    t0, T0, e0 = prev if prev is not None else (t[0] if t.size else 0.0,
                                                 temp[0] if temp.size else 0.0, 0.0)
    dt = np.diff(t, prepend=t0)
    dT = np.diff(temp, prepend=T0)
    h = dt / tau_s
    g = _g(h)
    a = 1.0 - h * g                # e^{-h}, as the C header computes it
    c = dT * g
    a = np.where(restart, 0.0, a)
    c = np.where(restart, 0.0, c)
    return _linear_scan(a, c, e0)


def play_state(temp: np.ndarray, restart: np.ndarray, half_width: float,
               p0: float = 0.0) -> np.ndarray:
    """State :math:`P` of the play operator of half-width ``half_width`` (restart: P = T;
    ``p0``: the state before the first sample, a chunk's carried state)."""
    lo = np.where(restart, temp, temp - half_width)
    hi = np.where(restart, temp, temp + half_width)
    return _clamp_scan(lo, hi, p0)
