"""The trained domain of a fit, and whether a row lies inside it.

Two questions share one answer.  The folds (:mod:`thermonet.scoring.selection`) judge a
candidate only on the validation rows inside what its fold trained on; a shipped model with a
dynamic input (rate, lag, hysteresis state) holds that input inside what it was trained on
near the current temperature, in torch, ONNX and C alike (the guard,
:meth:`thermonet.models.drift_model.DriftModel.set_guard`).  Both are :class:`Envelope`: every
signal's range and, for each dynamic input, its range near each temperature — *jointly*, so a
cooling rate never trained at that temperature is outside although the rate and the
temperature each lie in their own ranges.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..features.inputs import joint_columns

__all__ = ["JOINT_BINS", "GUARD_REL_TOL", "Envelope", "guard_tables", "in_domain",
           "joint_domain", "noise_widths"]


def noise_widths(signals: np.ndarray) -> np.ndarray:
    """Per signal column, 3 σ of its sample-to-sample noise (first differences / √2)."""
    x = np.asarray(signals, dtype=np.float64)
    if x.shape[0] < 3:
        return np.zeros(x.shape[1])
    d = np.diff(x, axis=0)
    # robust σ of the differences (MAD): a ramp's steady step is not noise
    med = np.nanmedian(d, axis=0)
    mad = np.nanmedian(np.abs(d - med), axis=0) * 1.4826
    return np.nan_to_num(3.0 * mad / math.sqrt(2.0))


def in_domain(signals: np.ndarray, lo: np.ndarray, hi: np.ndarray, widen: np.ndarray
              ) -> np.ndarray:
    """Rows whose every signal lies in [lo − widen, hi + widen] (NaN rows: outside)."""
    s = np.asarray(signals, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        ok = (s >= lo - widen) & (s <= hi + widen)
    return ok.all(axis=1)


#: Temperature bins of the joint domain (:class:`Envelope`, the model's guard).
JOINT_BINS = 10


@dataclass
class Envelope:
    """A trained domain: every signal's range and, for each ``joint`` column (a dynamic input:
    rate, lag, hysteresis state), its range near each temperature.

    The temperature range is cut in ``bins`` equal bins; a bin's bounds are the lowest and
    highest value of the joint column over the training rows in the bin and its two
    neighbours (a bin with no row near it takes its bounds by linear interpolation over the
    bins that have, or the nearest one's past the last); at a temperature the bounds are
    interpolated linearly between the bins' centres (:meth:`bounds`), so they change
    continuously with the temperature and every training row lies inside.  One definition,
    used twice: the folds ask it of every validation row (:meth:`contains`, built once per
    fold by :meth:`of`), and every shipped model with a dynamic input carries its tables
    (:meth:`tables`) and holds the input inside them on board, in torch, ONNX and C alike
    (:meth:`thermonet.models.drift_model.DriftModel.standardise`)."""

    lo: np.ndarray
    hi: np.ndarray
    t_col: int | None = None
    joint: tuple[int, ...] = ()
    near_lo: np.ndarray | None = None     # (bins, len(joint)): per bin and joint column
    near_hi: np.ndarray | None = None

    @classmethod
    def of(cls, train: np.ndarray, t_col: int | None, joint: Sequence[int] = (),
           bins: int = JOINT_BINS) -> Envelope:
        if bins < 2:
            raise ValueError(f"an envelope needs at least 2 temperature bins, got {bins}")
        tr = np.asarray(train, dtype=np.float64)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)     # an all-NaN column: NaN range
            lo, hi = np.nanmin(tr, axis=0), np.nanmax(tr, axis=0)
        if t_col is None or not joint or not np.isfinite(lo[t_col]):
            return cls(lo, hi)
        env = cls(lo, hi, t_col, tuple(joint))
        b = env._bin(tr[:, t_col], bins)
        near_lo = np.full((bins, len(joint)), np.inf)
        near_hi = np.full((bins, len(joint)), -np.inf)
        for i, c in enumerate(joint):
            blo = np.full(bins, np.inf)
            bhi = np.full(bins, -np.inf)
            good = (b >= 0) & np.isfinite(tr[:, c])
            np.minimum.at(blo, b[good], tr[good, c])
            np.maximum.at(bhi, b[good], tr[good, c])
            # the row's bin and its two neighbours
            near_lo[:, i] = _filled(np.minimum(blo, np.minimum(np.r_[np.inf, blo[:-1]],
                                                               np.r_[blo[1:], np.inf])))
            near_hi[:, i] = _filled(np.maximum(bhi, np.maximum(np.r_[-np.inf, bhi[:-1]],
                                                               np.r_[bhi[1:], -np.inf])))
        env.near_lo, env.near_hi = near_lo, near_hi
        return env

    def _bin(self, t: np.ndarray, bins: int) -> np.ndarray:
        """Temperature bin of each row (−1: NaN)."""
        assert self.t_col is not None
        t_lo = float(self.lo[self.t_col])
        span = max(float(self.hi[self.t_col]) - t_lo, 1e-12)
        with np.errstate(invalid="ignore"):
            b = np.floor((np.asarray(t) - t_lo) / span * bins)
        return np.clip(np.nan_to_num(b, nan=-1), -1, bins - 1).astype(np.int64)

    def knots(self) -> tuple[float, float]:
        """``(t0, k)``: a temperature ``t`` sits at ``u = (t − t0)·k − ½`` bins past the first
        bin's centre (what :meth:`bounds` and the model's guard interpolate on)."""
        assert self.t_col is not None and self.near_lo is not None
        t0 = float(self.lo[self.t_col])
        return t0, self.near_lo.shape[0] / max(float(self.hi[self.t_col]) - t0, 1e-12)

    def bounds(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The joint columns' bounds (N, J) at temperatures ``t`` (N,): linear between the
        bins' centres, constant past the first and last (a NaN temperature: the first bin's)."""
        assert self.near_lo is not None and self.near_hi is not None
        t0, k = self.knots()
        with np.errstate(invalid="ignore"):
            u = np.nan_to_num((np.asarray(t, dtype=np.float64) - t0) * k - 0.5, nan=0.0)
        i = np.clip(np.floor(u), 0, self.near_lo.shape[0] - 2)
        w = np.clip(u - i, 0.0, 1.0)[:, None]
        j = i.astype(np.int64)
        lo = self.near_lo[j] + w * (self.near_lo[j + 1] - self.near_lo[j])
        hi = self.near_hi[j] + w * (self.near_hi[j + 1] - self.near_hi[j])
        return lo, hi

    def tables(self, widen: np.ndarray) -> dict[str, np.ndarray] | None:
        """What a shipped model keeps of this envelope (:meth:`DriftModel.set_guard`): the knots
        and the per-bin bounds, each joint column's widened by ``widen[column]``; None
        without a joint column."""
        if self.near_lo is None or self.near_hi is None:
            return None
        w = np.asarray(widen, dtype=np.float64)[list(self.joint)]
        return {"knots": np.array(self.knots()), "lo": self.near_lo - w,
                "hi": self.near_hi + w}

    def contains(self, x: np.ndarray, widen: np.ndarray) -> np.ndarray:
        """Rows of ``x`` inside, each signal widened by its noise (``widen``); NaN rows:
        outside."""
        xs = np.asarray(x, dtype=np.float64)
        ok = in_domain(xs, self.lo, self.hi, widen)
        if self.near_lo is None or self.t_col is None or xs.shape[0] == 0:
            return ok
        lo, hi = self.bounds(np.clip(xs[:, self.t_col], self.lo[self.t_col],
                                     self.hi[self.t_col]))
        w = np.asarray(widen, dtype=np.float64)[list(self.joint)]
        cols = xs[:, list(self.joint)]
        with np.errstate(invalid="ignore"):
            ok &= ((cols >= lo - w) & (cols <= hi + w)).all(axis=1)
        return ok


#: The guard's least widening of a dynamic input's bounds, as a fraction of its trained
#: range: a float32 board computes the input a few ulps from the float64 training value
#: (a ``play`` state sits exactly on its bound on every steady ramp), which must not raise
#: the flag on every sample.
GUARD_REL_TOL = 1e-3


def guard_tables(runs: Sequence[np.ndarray], signals: Sequence[str]
                 ) -> dict[str, np.ndarray] | None:
    """The joint guard a model fitted on the training ``runs`` (signal matrices (n, S) over
    ``signals``) carries (:meth:`Envelope.tables`): the envelope of all their rows, each
    dynamic input widened by its noise (the median over the runs of :func:`noise_widths`,
    as the folds widen a validation run by its own) and at least :data:`GUARD_REL_TOL` of
    its trained range.  None without a dynamic input or a temperature."""
    t_col, joint = joint_columns(signals)
    if t_col is None or not joint or not runs:
        return None
    env = Envelope.of(np.vstack(runs), t_col, joint)
    if env.near_lo is None or env.near_hi is None or not np.isfinite(env.near_lo).all() or \
            not np.isfinite(env.near_hi).all():
        return None   # a dynamic input never finite in training: nothing to hold it inside
    noise = np.median(np.vstack([noise_widths(r) for r in runs]), axis=0)
    span = np.nan_to_num(env.hi - env.lo)
    return env.tables(np.maximum(noise, GUARD_REL_TOL * span))


def _filled(b: np.ndarray) -> np.ndarray:
    """Per-bin bounds with the empty bins (±inf) filled by linear interpolation over the bins
    that have a value (the nearest one's past the last); all empty stays as it is."""
    have = np.isfinite(b)
    if have.all() or not have.any():
        return b
    idx = np.arange(b.size)
    return np.interp(idx, idx[have], b[have])


def joint_domain(train: np.ndarray, x: np.ndarray, t_col: int | None, joint: Sequence[int],
                 widen: np.ndarray, bins: int = JOINT_BINS) -> np.ndarray:
    """Rows of ``x`` inside the trained domain *jointly with temperature*
    (:class:`Envelope`): every signal in its trained range (:func:`in_domain`), and each
    ``joint`` column inside what training saw near that temperature.  A cooling rate never
    trained at that temperature is outside although the rate and the temperature each lie in
    their own ranges.  NaN rows: outside."""
    return Envelope.of(train, t_col, joint, bins).contains(x, widen)
