"""How ``compare``'s cross-validation cuts the training pool into folds
(:func:`plan_folds`, a :class:`FoldPlan`): whole runs, whole thermal excursions, or
interleaved time blocks, each fold's training rows purged by the longest memory of any
candidate's inputs — the folds :mod:`thermonet.scoring.selection` judges every candidate on.
The rules (what a fold holds out and why) are in that module's docstring and in
configs/README.md, "Folds that look like the next excursion"."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import counted
from ..core.recording import contiguous_segments
from ..features.dynamics import dynamic_signals
from .folds import DIRECTION_NAMES, TURN_FRACTION, Leg, deal, excursions, purged

__all__ = ["FoldPlan", "plan_folds", "purge_rule", "window_rule", "window_labels", "HOLD_OUT",
           "EXCURSION_INSIDE", "MIN_FOLD_SAMPLES", "MIN_GATE_FOLDS", "RATE_SPREAD",
           "TWO_FOLD_MARGIN", "leg_rates", "validation_stretches",
           "memory_judgeable", "rate_spread", "MEMORY_STEP", "memory_share"]


#: Samples a fold needs in training and in validation.
MIN_FOLD_SAMPLES = 20

#: Folds a candidate must have been judged on to replace its reference with the worst-fold
#: test alone (:mod:`thermonet.scoring.gate`): "better on both of two folds" happens by chance
#: one time in four.
MIN_GATE_FOLDS = 3

#: On exactly two judged folds (two runs held out in turn: a fast and a slow cycle, each the
#: other's new excursion) a candidate must be at least this much better than its reference on
#: *each* (its ratio at most ``TWO_FOLD_MARGIN`` times the reference's): a margin, where a
#: lead of any size on both is what a tie gives one time in four.
TWO_FOLD_MARGIN = 0.9

#: The pool's ramp rates must spread by this factor (:func:`rate_spread`) for a model with
#: memory to be judged at another rate than it was fitted at
#: (:func:`thermonet.scoring.gate.one_rate`).  Linear ramps spread by 1.02–1.11 (the
#: thermometer's lag at a leg's ends), a sinusoidal cycle by 1.5, a fast and a slow cycle by 3
#: (``stress-imu``, ``consumer-imu``, ``patent-gyro`` and tests/test_per_axis.py's device).
RATE_SPREAD = 1.3


#: Where the pool ramps at one rate (both directions held), a candidate whose share of the
#: drift read from inputs with memory is at most this (a ``poly`` ``mix``: a third of the way
#: from the cubic to the cubic at the delayed temperature) is judged, where a full model with
#: memory is held back.  At one rate a lag (its error ∝ the rate) and a hysteresis (its error
#: the same at any rate) are the same correction c; at another rate r' = ρ r the full step
#: corrects ρ c where the sensor needs ρ c (a lag) or c (a hysteresis): |1 − ρ| c off, worse
#: than no correction beyond ρ = 2.  A step w corrects w ρ c: (1 − w) ρ c off a lag,
#: |1 − w ρ| c off a hysteresis — no worse than the static model up to ρ = 2 / w under either.
#: A half step was tried first (``bench_selection.py --stress``, fitted on one cycle, tested
#: on one 3× slower): 1.055× and 1.016× the cubic on the axis with a hysteresis of its own,
#: whose cubic curve the lag also bends; a third kept every axis at or under the cubic.  No
#: default candidate is a step (configs/README.md, "A step toward memory at one rate").
MEMORY_STEP = 1.0 / 3.0


def memory_share(inputs: Sequence[str], mix: Sequence[float] | None) -> float:
    """The share of a candidate's drift read from inputs with memory (rate, lag, delayed
    temperature, hysteresis): 0 without one, 1 for a joint fit, a ``mix``'s weights on them
    (:data:`MEMORY_STEP`)."""
    dyn = [bool(dynamic_signals([i])) for i in inputs]
    if not any(dyn):
        return 0.0
    if mix is None or len(mix) != len(inputs):
        return 1.0
    return float(sum(w for w, d in zip(mix, dyn, strict=True) if d))


def memory_judgeable(directions: Sequence[int], rates: Sequence[float]) -> bool:
    """Whether the pool lets a model with memory be judged: heating and cooling both, and
    ramps at two rates or more (:func:`rate_spread` at least :data:`RATE_SPREAD`)."""
    return len(set(directions)) >= 2 and rate_spread(rates) >= RATE_SPREAD


def window_rule(rate_hz: float, block_s: float | None) -> float:
    """Score window: 60 s, or 20 sample intervals if longer, at most half a block."""
    w = max(60.0, 20.0 / rate_hz) if rate_hz > 0 else 60.0
    return min(w, 0.5 * block_s) if block_s else w


def purge_rule(tau_s: float, window_s: float, block_s: float | None) -> float:
    """``min(max(3 τ, window_s), block_s / 2)`` (no cap with whole runs as folds)."""
    p = max(3.0 * tau_s, window_s)
    return min(p, 0.5 * block_s) if block_s else p


@dataclass
class FoldPlan:
    """The folds of one split's pool: per pool run, each sample's fold (−1: not validated),
    and per fold a training mask (purged) per pool run.

    ``directions``: the directions of temperature change the pool holds (+1 heating, −1
    cooling; :func:`thermonet.scoring.folds.excursions`); ``rates``: each heating or cooling
    leg's ramp rate (:func:`leg_rates`, the signal's units a second); ``legs``: the excursions found, per
    pool run, with the fold that holds each out (−1: always trained); ``note``: why the folds
    are not the excursions where they could not be, or why they are fewer than
    ``selection.folds`` asked for."""

    fold_of: list[np.ndarray]
    train_masks: list[list[np.ndarray]]
    k: int
    kind: str                       # "leave-one-run-out", "excursions" or "blocks"
    block_s: float | None
    purge_s: float
    window_s: float
    block_of: list[np.ndarray] = field(default_factory=list)   # validation block ids
    directions: list[int] = field(default_factory=list)
    legs: list[dict[str, Any]] = field(default_factory=list)
    note: str = ""
    #: per fold, the directions of change its validation rows hold (excursion folds: their
    #: legs'; other folds: every direction of the pool)
    fold_directions: list[set[int]] = field(default_factory=list)
    rates: list[float] = field(default_factory=list)

    def describe(self) -> dict[str, Any]:
        return {"kind": self.kind, "folds": self.k, "block_s": self.block_s,
                "purge_s": self.purge_s, "window_s": self.window_s,
                "directions": [DIRECTION_NAMES[d] for d in self.directions],
                "excursions": self.legs, **({"note": self.note} if self.note else {}),
                "train_fraction": [float(np.mean([m.sum() for m in ms]) /
                                         max(np.mean([(f >= 0).sum() for f in self.fold_of]), 1))
                                   for ms in self.train_masks]}


#: The values of ``selection.hold_out``: what a cross-validation fold holds out of one run.
HOLD_OUT = ("auto", "excursions", "blocks")

#: A held-out excursion is usable where at least this share of its samples lies inside the
#: temperature range of the rest of the pool (a fold is not asked to extrapolate).
EXCURSION_INSIDE = 0.5


def _pool_legs(pool: Sequence[tuple[Any, np.ndarray]],
               temperatures: Sequence[np.ndarray | None] | None) -> list[list[Leg]]:
    """Per pool run, its excursions (one soak-leg where it has no temperature signal); a turn
    is :data:`~thermonet.scoring.folds.TURN_FRACTION` of the whole pool's range (two soaks at
    13 and 48 °C are two soaks, not their own wobbles)."""
    known = [np.asarray(x, dtype=np.float64) for x in (temperatures or []) if x is not None]
    allt = np.concatenate(known) if known else np.zeros(0)
    allt = allt[np.isfinite(allt)]
    turn = (TURN_FRACTION * float(np.subtract(*np.percentile(allt, [95.0, 5.0])))
            if allt.size >= 3 else None)
    out = []
    for j, (_, m) in enumerate(pool):
        temp = None if temperatures is None else temperatures[j]
        out.append(excursions(np.asarray(temp, dtype=np.float64), turn=turn, min_turn=True)
                   if temp is not None
                   else [Leg(0, int(np.asarray(m).size), 0, math.nan, math.nan)])
    return out


def _directions(pool: Sequence[tuple[Any, np.ndarray]], legs: list[list[Leg]]) -> list[int]:
    """The directions of temperature change with at least half a leg in the pool."""
    found = set()
    for (_, m), lj in zip(pool, legs, strict=True):
        for leg in lj:
            if leg.direction and np.asarray(m)[leg.start:leg.stop].mean() >= 0.5:
                found.add(leg.direction)
    return sorted(found, reverse=True)


def leg_rates(pool: Sequence[tuple[Any, np.ndarray]], legs: list[list[Leg]],
              temperatures: Sequence[np.ndarray | None] | None) -> list[float]:
    """The ramp rates the pool's heating and cooling legs move at (signal units a second, so a
    thermometer in raw counts serves as well): per leg (at least half in the pool), each
    tenth of its change from 5 % to 95 % of the way over the time it took (the soak that
    ends a leg, and its start, left out).  A linear ramp gives ten equal rates; a sinusoidal
    cycle rates from about half its peak to its peak; a fast and a slow cycle both."""
    out: list[float] = []
    if temperatures is None:
        return out
    for (r, m), lj, temp in zip(pool, legs, temperatures, strict=True):
        if temp is None:
            continue
        t = np.asarray(r.time_s, dtype=np.float64)
        x = np.asarray(temp, dtype=np.float64)
        for leg in lj:
            span = leg.to_value - leg.from_value
            if not leg.direction or not math.isfinite(span) or span == 0 or \
                    np.asarray(m)[leg.start:leg.stop].mean() < 0.5:
                continue
            with np.errstate(invalid="ignore"):
                done = (x[leg.start:leg.stop] - leg.from_value) / span
            if not (done >= 0.95).any():
                continue
            at = t[leg.start + np.array([int(np.argmax(done >= f))
                                         for f in np.linspace(0.05, 0.95, 11)])]
            out += [0.1 * abs(span) / dt for dt in np.diff(at) if dt > 0]
    return out


def rate_spread(rates: Sequence[float]) -> float:
    """How far apart the pool's ramp rates are: the 90th percentile of :func:`leg_rates` over
    the 10th (1 for one rate; NaN without a ramp)."""
    if not len(rates):
        return math.nan
    lo, hi = np.percentile(np.asarray(rates, dtype=np.float64), [10.0, 90.0])
    return float(hi / lo) if lo > 0 else math.nan


def _what_legs_hold(legs: list[list[Leg]]) -> str:
    kinds = [DIRECTION_NAMES[leg.direction] for lj in legs for leg in lj]
    counts = {k: kinds.count(k) for k in ("heating", "cooling", "soak") if k in kinds}
    return ", ".join(f"{v} {k} {'leg' if k != 'soak' else 'run'}{'s' if v > 1 else ''}"
                     for k, v in counts.items())


def _excursion_folds(pool: Sequence[tuple[Any, np.ndarray]], legs: list[list[Leg]],
                     temperatures: Sequence[np.ndarray | None] | None, folds: int
                     ) -> tuple[list[np.ndarray], list[np.ndarray], int, list[dict[str, Any]]] | str:
    """Leave excursions out: every usable leg — one that the rest of the pool spans (at least
    :data:`EXCURSION_INSIDE` of it inside their temperatures) and whose direction the rest
    also holds — is one unit, dealt round-robin (in time order) to ``min(folds, legs)``
    folds; its validation windows are grouped into ~8 bootstrap units by time.  Returns
    (fold_of, block_of, k, record) or the sentence saying why not.

    A leg alone in its direction (one cycle's heating) is not cut in two to be held out: that
    was tried, and the folds that asked for heating from mostly cooling data judged the cubic
    worse than raw out of fold on axes where it was 2× better than raw on the test (a
    hysteresis between the branches), leaving them raw (``bench_selection.py``: consumer-imu;
    a model with memory is held back at one ramp rate anyway, :func:`thermonet.scoring.gate.one_rate`)."""
    units = []       # (run, leg)
    for j, ((_, m), lj) in enumerate(zip(pool, legs, strict=True)):
        for leg in lj:
            if np.asarray(m)[leg.start:leg.stop].sum() >= 2 * MIN_FOLD_SAMPLES:
                units.append((j, leg))
    usable = []
    if temperatures is not None and len(units) >= 2:
        spans = [np.asarray(temperatures[j])[leg.start:leg.stop] for j, leg in units]
        with np.errstate(invalid="ignore"):
            lows = np.array([np.nanmin(x) for x in spans])
            highs = np.array([np.nanmax(x) for x in spans])
        dirs = np.array([leg.direction for _, leg in units])
        for u, (j, leg) in enumerate(units):
            others = np.arange(len(units)) != u
            lo, hi = np.nanmin(lows[others]), np.nanmax(highs[others])
            with np.errstate(invalid="ignore"):
                inside = float(np.mean((spans[u] >= lo) & (spans[u] <= hi)))
            # the rest must hold the leg's direction: a fold trained on cooling alone asks
            # every model with memory for a direction it never saw (and the static ones for
            # the other branch of the loop), which the shipped model, trained on both, is not
            same_way = leg.direction == 0 or bool((dirs[others] == leg.direction).any())
            if inside >= EXCURSION_INSIDE and same_way:
                usable.append((j, leg))
    if len(usable) < 2:
        held = _what_legs_hold(legs)
        return (f"{held}: {len(usable)} excursion(s) that the rest of the data spans in "
                "temperature and direction (two are needed to hold one out)")
    k = min(folds, len(usable))
    fold_of = [np.full(np.asarray(m).size, -1, dtype=np.int64) for _, m in pool]
    block_of = [np.zeros(np.asarray(m).size, dtype=np.int64) for _, m in pool]
    record: list[dict[str, Any]] = []
    for u, (j, leg) in enumerate(usable):
        m = np.asarray(pool[j][1])
        sl = slice(leg.start, leg.stop)
        fold_of[j][sl] = np.where(m[sl], u % k, -1)
        size = leg.stop - leg.start
        block_of[j][sl] = 8 * u + np.minimum((np.arange(size) * 8) // max(size, 1), 7)
    fold_of_leg = {(j, leg.start): u % k for u, (j, leg) in enumerate(usable)}
    for j, lj in enumerate(legs):
        for leg in lj:
            f = fold_of_leg.get((j, leg.start), -1)
            record.append({"run": j, "excursion": leg.describe(), "fold": f,
                           "direction": leg.direction})
    return fold_of, block_of, k, record


def _leave_one_run_out(pool: Sequence[tuple[Any, np.ndarray]], times: list[np.ndarray]
                       ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each run its own fold; bootstrap units inside a held-out run: ~8 blocks by time."""
    k = len(pool)
    fold_of = [np.where(m, deal(0, j, k), -1) for j, (_, m) in enumerate(pool)]
    block_of = []
    for j, t in enumerate(times):
        span = max(float(t[-1] - t[0]), 1e-9)
        block_of.append(np.minimum(((t - t[0]) / span * 8).astype(int), 7) + 8 * j)
    return fold_of, block_of


def _blocks(pool: Sequence[tuple[Any, np.ndarray]], times: list[np.ndarray], folds: int,
            blocks_per_fold: int) -> tuple[list[np.ndarray], list[np.ndarray], float] | None:
    """Every run cut into ``folds × blocks_per_fold`` contiguous blocks dealt round-robin
    (fold_of, block_of, the median block length), or None where a run is too short."""
    n_blocks = folds * blocks_per_fold
    spans = []
    for (_, m), t in zip(pool, times, strict=True):
        tm = t[m]
        if tm.size < n_blocks * 2:
            return None
        spans.append(max(float(tm[-1] - tm[0]), 1e-9))
    block_s = float(np.median(spans)) / n_blocks
    fold_of, block_of = [], []
    for j, ((_, m), t) in enumerate(zip(pool, times, strict=True)):
        tm = t[m]
        bs = spans[j] / n_blocks
        block = np.clip(((t - tm[0]) / bs).astype(int), 0, n_blocks - 1)
        # the one deal (thermonet.scoring.folds, the API's TimeBlockSplit's too): the
        # test_fold of scikit-learn's PredefinedSplit, checked against it in
        # tests/test_selection.py; -1 (not in the pool) is never validated
        test_fold = np.where(m, deal(block, j, folds), -1)
        if np.unique(test_fold[test_fold >= 0]).size != folds:
            return None
        fold_of.append(test_fold)
        block_of.append(block + n_blocks * j)
    return fold_of, block_of, block_s


def _train_masks(pool: Sequence[tuple[Any, np.ndarray]], fold_of: list[np.ndarray],
                 times: list[np.ndarray], k: int, purge: float, purge_runs: bool
                 ) -> list[list[np.ndarray]] | None:
    """Per fold, each pool run's training rows: not validated there, and (``purge_runs``)
    ``purge`` seconds away from its validation rows; None where a fold has too few."""
    out: list[list[np.ndarray]] = []
    for f in range(k):
        ms = []
        for (_, m), fo, t in zip(pool, fold_of, times, strict=True):
            val = fo == f
            ms.append(m & ~val & ~purged(t, val, purge) if purge_runs else m & ~val)
        n_train = sum(int(x.sum()) for x in ms)
        n_val = sum(int((fo == f).sum()) for fo in fold_of)
        if n_train < MIN_FOLD_SAMPLES or n_val < MIN_FOLD_SAMPLES:
            return None
        out.append(ms)
    return out


def plan_folds(pool: Sequence[tuple[Any, np.ndarray]], *, folds: int, blocks_per_fold: int,
               tau_s: float, purge_s: float | None = None, window_s: float | None = None,
               by_run: bool = True, hold_out: str = "auto",
               temperatures: Sequence[np.ndarray | None] | None = None,
               gate: bool = False) -> FoldPlan | None:
    """Folds of ``pool`` ((recording, row mask) pairs), or None where K folds cannot be made.

    ``by_run``: with several runs, leave one run out (the test is a run the model never
    saw; with two runs, two folds, on which the gate passes nothing: their excursions held
    out instead fitted a cubic on one run's legs and the other's whole, so each run's turn-on
    offset became a slope, worse than raw out of fold where the cubic was 3× better than raw
    on the next run — ``bench_selection.py --stress``).  Otherwise (one run, or a time-block
    split) ``hold_out`` says what a fold holds
    out: ``excursions`` — whole thermal excursions found in ``temperatures`` (per pool run,
    the temperature signal of every row; :func:`thermonet.scoring.folds.excursions`), the
    next warm-up or cool-down a user's test will be, purged by the longest memory of any
    candidate's inputs (``max(3 τ, window_s)``, uncapped); ``blocks`` — short contiguous
    blocks dealt round-robin (interpolation between training data); ``auto`` — excursions
    where two or more can be held out, else blocks (said in :attr:`FoldPlan.note`).
    ``hold_out="excursions"`` where none can be held out raises ``ValueError`` with what the
    data hold.  ``gate``: the gate will hold every model with memory back where the pool does
    not let it be judged (:func:`memory_judgeable`), so there the purge is not stretched to
    their memory: the static candidates' folds keep the data a 15-minute purge would take
    (``consumer-imu``: with it, the cubic came out worse than raw out of fold on an axis it
    cut 2× on the test).
    """
    if hold_out not in HOLD_OUT:
        raise ValueError(f"hold_out must be one of {', '.join(HOLD_OUT)}, got {hold_out!r}")
    if folds < 2 or not pool:
        return None
    times = [np.asarray(r.time_s, dtype=np.float64) for r, _ in pool]
    rate = float(np.median([r.effective_rate_hz for r, _ in pool]))
    legs = _pool_legs(pool, temperatures)
    directions = _directions(pool, legs)
    rates = leg_rates(pool, legs, temperatures)
    if gate and not memory_judgeable(directions, rates):
        tau_s = 0.0
    cut = _cut(pool, times, legs, temperatures, folds, blocks_per_fold, by_run, hold_out)
    if cut is None:
        return None
    kind, k, block_s, fold_of, block_of, record, note = cut
    win = window_s if window_s is not None else window_rule(rate, block_s)
    purge = purge_s if purge_s is not None else purge_rule(tau_s, win, block_s)
    train_masks = _train_masks(pool, fold_of, times, k, purge, kind != "leave-one-run-out")
    if train_masks is None:
        return None
    if kind == "excursions":
        fold_dirs: list[set[int]] = [set() for _ in range(k)]
        for leg in record:
            if leg["fold"] >= 0 and leg["direction"]:
                fold_dirs[leg["fold"]].add(leg["direction"])
    else:
        fold_dirs = [set(directions) for _ in range(k)]
    return FoldPlan(fold_of, train_masks, k, kind, block_s, purge, win, block_of,
                    directions, record, note, fold_dirs, rates)


def _cut(pool: Sequence[tuple[Any, np.ndarray]], times: list[np.ndarray],
         legs: list[list[Leg]], temperatures: Sequence[np.ndarray | None] | None, folds: int,
         blocks_per_fold: int, by_run: bool, hold_out: str) -> tuple[
        str, int, float | None, list[np.ndarray], list[np.ndarray], list[dict[str, Any]],
        str] | None:
    """What :func:`plan_folds` holds out: (kind, K, block_s, fold_of, block_of, the legs'
    record, the note), or None where blocks cannot be dealt.  The note says why the folds are
    not the excursions, or why there are fewer than ``folds`` (one per training run; fewer
    excursions that can be held out): never a silent reduction."""
    if len(pool) >= 2 and by_run:
        fold_of, block_of = _leave_one_run_out(pool, times)
        k = len(pool)
        note = "" if k == folds else (
            f"{k} folds, not {folds} (selection.folds): the split is by run, so each fold "
            f"leaves one whole run out, and the training data hold {counted(k, 'run')}")
        return "leave-one-run-out", k, None, fold_of, block_of, [], note
    note = ""
    if hold_out != "blocks":
        got = _excursion_folds(pool, legs, temperatures, folds)
        if not isinstance(got, str):
            fold_of, block_of, k, record = got
            usable = sum(1 for leg in record if leg["fold"] >= 0)
            if k < folds:
                note = (f"{k} folds, not {folds} (selection.folds): the training data hold "
                        f"{counted(usable, 'excursion')} that can be held out")
            return "excursions", k, None, fold_of, block_of, record, note
        if hold_out == "excursions":
            raise ValueError(got)
        note = f"blocks, not excursions: {got}"
    dealt = _blocks(pool, times, folds, blocks_per_fold)
    if dealt is None:
        return None
    return "blocks", folds, dealt[2], dealt[0], dealt[1], [], note


def validation_stretches(plan: FoldPlan, times: Sequence[np.ndarray]
                         ) -> tuple[list[int], list[float]]:
    """Per fold, the score windows of ``plan.window_s`` its validation rows fall into (all of
    them: before any candidate's domain) and its longest contiguous validation stretch in
    seconds.  A fold scores the spread of its window means: with one window it has none."""
    windows = [0] * plan.k
    longest = [0.0] * plan.k
    for fo, t in zip(plan.fold_of, times, strict=True):
        t = np.asarray(t, dtype=np.float64)
        for f in range(plan.k):
            tv = t[fo == f]
            if tv.size == 0:
                continue
            windows[f] += int(np.unique(window_labels(tv, plan.window_s)).size)
            longest[f] = max(longest[f], max(float(tv[s][-1] - tv[s][0])
                                             for s in contiguous_segments(tv) if tv[s].size))
    return windows, longest


def window_labels(time_s: np.ndarray, window_s: float) -> np.ndarray:
    """Window index of every sample: ``window_s`` windows inside each contiguous stretch."""
    t = np.asarray(time_s, dtype=np.float64)
    out = np.empty(t.size, dtype=np.int64)
    nxt = 0
    for seg in contiguous_segments(t):
        w = ((t[seg] - t[seg.start]) / max(window_s, 1e-12)).astype(np.int64)
        out[seg] = nxt + w
        nxt += int(w.max()) + 1 if w.size else 0
    return out
