"""The one deal of rows to cross-validation folds, and the purge around a validation fold.

Two callers split data for cross-validation and both use this module, so a fold means the same
thing everywhere:

* ``compare``'s model selection (:func:`thermonet.scoring.fold_plan.plan_folds`): the samples
  of every pool run, labelled by their contiguous time block (or one label per run when whole
  runs are the folds), purged by :func:`purged` around each validation fold;
* the API's scikit-learn cross-validator (:class:`thermonet.api.cv.TimeBlockSplit`, a
  ``BaseCrossValidator``): rows that are whole runs or blocks cut by
  :func:`thermonet.api.time_blocks`, which leaves the purge out between adjacent blocks.

The deal (:func:`deal`): block ``b`` of the ``r``-th run goes to fold ``(b + r) mod k`` —
round-robin over the folds, shifted by the run so that every fold sees every run's start and
end; a whole run (block 0) is fold ``r mod k`` (leave one run out when ``k`` is the number of
runs).  It is the ``test_fold`` of scikit-learn's ``PredefinedSplit`` (fold ``f`` validates
where the label is ``f``; ``-1`` is never validated), computed with numpy alone: this module
and its callers in ``compare`` do not import scikit-learn (seconds of start-up).  Never
random: the same rows give the same folds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["deal", "purged", "Leg", "excursions", "TURN_FRACTION", "DIRECTION_NAMES"]


def deal(block: np.ndarray | int, run: np.ndarray | int, k: int) -> np.ndarray:
    """The fold of each row: ``(block + run) mod k`` (block and run numbers count from 0)."""
    return np.asarray((np.asarray(block) + np.asarray(run)) % int(k))


def purged(t: np.ndarray, val: np.ndarray, purge_s: float) -> np.ndarray:
    """Samples of one run (times ``t``, ascending) within ``purge_s`` seconds of a validation
    sample (mask ``val``), the validation samples included: what a fold's training leaves
    out so that validation does not leak into training through the dynamic inputs' memory."""
    if not val.any():
        return np.zeros(t.size, dtype=bool)
    tv = t[val]
    i = np.clip(np.searchsorted(tv, t), 1, tv.size - 1) if tv.size > 1 else np.zeros(t.size, int)
    d = np.abs(t - tv[i])
    if tv.size > 1:
        d = np.minimum(d, np.abs(t - tv[i - 1]))
    return (d <= purge_s) | val


#: What a leg's direction is called (results.json, the console).
DIRECTION_NAMES = {1: "heating", -1: "cooling", 0: "soak"}


@dataclass(frozen=True)
class Leg:
    """One thermal excursion of a run: a heating or cooling leg and the soak that ends it.

    ``start`` / ``stop``: sample indices (``stop`` exclusive); ``direction``: +1 heating, −1
    cooling, 0 a run that never moves by more than its turn threshold (a soak);
    ``from_value`` / ``to_value``: the temperature signal at its ends (smoothed)."""

    start: int
    stop: int
    direction: int
    from_value: float
    to_value: float

    def describe(self) -> str:
        return f"{DIRECTION_NAMES[self.direction]} {self.from_value:.4g} -> {self.to_value:.4g}"


#: A turn must reverse the temperature by this fraction of the run's range (5th–95th
#: percentile) — and by six times the signal's sample-to-sample noise — to end an excursion.
TURN_FRACTION = 0.15


def _coarse(x: np.ndarray, points: int) -> tuple[np.ndarray, np.ndarray]:
    """``x`` as the means of at most ``points`` consecutive groups, and each group's first
    sample index (a 1-M sample run's zig-zag reads 4,000 numbers, not a million)."""
    n = x.size
    if n <= points:
        return x.copy(), np.arange(n)
    starts = (np.arange(points) * n) // points
    sums = np.add.reduceat(x, starts)
    counts = np.diff(np.append(starts, n))
    return sums / counts, starts


def _median5(x: np.ndarray) -> np.ndarray:
    """A running median of five samples (the ends kept): one stray reading is no turn."""
    if x.size < 5:
        return x
    from numpy.lib.stride_tricks import sliding_window_view

    out = x.copy()
    out[2:-2] = np.median(sliding_window_view(x, 5), axis=1)
    return out


def excursions(temperature: np.ndarray, *, turn: float | None = None,
               min_turn: bool = False) -> list[Leg]:
    """The thermal excursions of one run's temperature trace (any monotone signal of it: a
    thermometer in °C or its raw counts), in time order, covering every sample.

    A zig-zag with hysteresis over the trace (group means of at most 4,000 groups, then a
    running median of five): a *turn* is registered once the signal has reversed from its
    running extreme by ``turn`` (default :data:`TURN_FRACTION` of the run's 5th–95th
    percentile range, and at least six times its sample-to-sample noise, so neither noise nor
    a wobble in a soak is a turn; ``min_turn``: a ``turn`` given is raised to that noise
    floor too).  Each leg runs from one turn to the next; the soak at a turn
    (samples within a quarter of ``turn`` of the extreme) belongs to the leg that ends there,
    a leading soak to the first leg; a last stretch that moves by less than ``turn`` joins the
    leg before it.  A run that never moves by ``turn`` is one leg of direction 0 (a soak).
    NaN samples take the previous finite value.  Deterministic: the same trace gives the same
    legs.
    """
    x = np.asarray(temperature, dtype=np.float64)
    n = x.size
    ok = np.isfinite(x)
    if n == 0:
        return []
    if ok.sum() < 3:
        return [Leg(0, n, 0, float("nan"), float("nan"))]
    idx = np.where(ok, np.arange(n), 0)
    np.maximum.accumulate(idx, out=idx)
    idx[: int(np.argmax(ok))] = int(np.argmax(ok))
    x = x[idx]
    d = np.diff(x)
    noise = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / np.sqrt(2.0)
    c, starts = _coarse(x, 4000)
    s = _median5(c)
    lo, hi = np.percentile(s, [5.0, 95.0])
    if turn is None:
        turn = max(TURN_FRACTION * float(hi - lo), 6.0 * noise)
    elif min_turn:
        turn = max(turn, 6.0 * noise)
    m = s.size
    if not turn > 0 or float(s.max() - s.min()) < turn:
        return [Leg(0, n, 0, float(s[0]), float(s[-1]))]
    # zig-zag: an extreme is a turn once the signal has reversed from it by ``turn``
    turns: list[tuple[int, int]] = []          # (index of the extreme, direction of its leg)
    direction, i_max, i_min = 0, 0, 0
    for i in range(1, m):
        v = s[i]
        if v > s[i_max]:
            i_max = i
        if v < s[i_min]:
            i_min = i
        if direction >= 0 and v <= s[i_max] - turn:
            if direction == 1:
                turns.append((i_max, 1))
            direction, i_min = -1, i
        elif direction <= 0 and v >= s[i_min] + turn:
            if direction == -1:
                turns.append((i_min, -1))
            direction, i_max = 1, i
    bounds: list[tuple[int, int, int]] = []     # coarse (start, stop, direction)
    start = 0
    for k, (i_ext, sign) in enumerate(turns):
        nxt = turns[k + 1][0] if k + 1 < len(turns) else m
        j = i_ext
        while j + 1 < nxt and abs(s[j + 1] - s[i_ext]) <= 0.25 * turn:
            j += 1
        bounds.append((start, j + 1, sign))
        start = j + 1
    tail = s[start:]
    if tail.size and abs(float(tail[-1] - tail[0])) >= turn:
        bounds.append((start, m, int(np.sign(tail[-1] - tail[0]))))
    elif bounds:
        a, _, sign = bounds.pop()
        bounds.append((a, m, sign))
    else:
        bounds.append((0, m, int(np.sign(s[-1] - s[0]))))
    full = np.append(starts, n)
    return [Leg(int(full[a]), int(full[b]), sign, float(s[a]), float(s[b - 1]))
            for a, b, sign in bounds]
