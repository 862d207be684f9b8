"""Choosing the model that ships: purged, blocked cross-validation that looks like the test.

One validation part decides badly: its bootstrap interval describes the noise inside that
part, not how the choice changes with the part chosen, and on one recording a few contiguous
folds reward extrapolation (a fold trained on the cold half is validated on the hot half,
while the real test lies inside the trained range).  thermonet therefore chooses on K folds
of the training data that look like the test:

Folds
-----
The *pool* is every run that is not the test run, whole, minus any test rows
(:attr:`thermonet.training.splits.Split.pool`).  Dynamic inputs are computed on each whole run before
any cut: a board does not restart at a fold boundary.

* **Several runs** in the pool, where the test is a run of its own (split by runs,
  train-then-verify, leave-one-run-out): leave one run out (K = the number of runs).
* **One run**, or a time-block split (the test is blocks inside the runs): whole thermal
  **excursions** held out (``selection.hold_out: auto``, the default; :func:`_excursion_folds`:
  the legs of :func:`thermonet.scoring.folds.excursions` that the rest of the pool spans in
  temperature and direction, dealt round-robin to ``min(folds, legs)`` folds, purged by
  ``max(3 τ, window_s)`` uncapped) — a user's test is the next warm-up, not a block between
  training data.  Where fewer than two legs can be held out, every run is cut by
  time into ``folds × blocks_per_fold`` short contiguous blocks (5 × 8 = 40 by default: tens
  of blocks, not K slabs) dealt round-robin to the K folds by the one deal of
  :mod:`thermonet.scoring.folds` (scikit-learn's :class:`~sklearn.model_selection.PredefinedSplit`
  over the block's fold; the API's ``TimeBlockSplit`` deals the same way), so every fold's
  validation blocks sample the whole temperature history.  Two isothermal soaks (the BMI270
  recording) validated by leaving one soak out would ask the model for a temperature it never
  saw, which the time-block test never does.

**Purge.**  Training samples within ``purge_s`` of a validation block (on either side, same
run) are left out of that fold's training, so validation does not leak into training through
the dynamic inputs' memory.  The rule: ``purge_s = min(max(3 τ, window_s), block_s / 2)``
with τ the longest time constant of any candidate's dynamic inputs (rate, lag; 0 without
any) — three time constants forget 95 % of the state, and at most half a block is purged on
each side, so each fold keeps at least three quarters of its training data.  On a one-hour
cycle at 1 Hz (40 blocks of 90 s) that is 45 s on each side, not half an hour.

**Inside the training data only.**  A validation sample is scored only where it lies inside
the fold's training data *in the candidate's own input space*: every signal the candidate
reads (temperature and, for a dynamic model, rate, lag, hysteresis state) within the range the
fold trained on, widened by that signal's own sample-to-sample noise (3 σ of its first
differences / √2), so that thermometer noise at the edge is not called extrapolation.  The
fraction left out is reported per candidate and fold.  Candidates are compared on the
*common* samples: those inside every candidate's domain.

Score the drift, not the noise
------------------------------
White noise cannot be compensated and dominates a sample-by-sample score at high rates.  The
score is the low-frequency residual: residual means over windows of ``window_s`` inside each
contiguous validation stretch (rule: 60 s, or 20 sample intervals if longer, at most half a
block), their spread about the fold's mean (offset-free, as every thermonet score:
:mod:`thermonet.scoring.verdicts`) weighted by the samples in each window.  The ratio of a
candidate's score to the raw output's on the same windows is its score ratio.

Decisions from paired out-of-fold errors
----------------------------------------
Every candidate is scored on the same windows.  A block bootstrap over the validation blocks
(:func:`thermonet.scoring.verdicts.draws`, seeded) resamples all candidates together, so differences
are paired:

* **per axis**, raw is the simplest candidate (no parameters) and the one-standard-error rule
  decides against it: a candidate compensates an axis only where its paired improvement on
  raw, ``1 − ratio``, exceeds one standard error (the bootstrap standard deviation of the
  ratio); elsewhere it leaves the axis raw (ratio 1).  (A 95 % interval below 1 — two
  standard errors — left axes raw that the cubic improved on the held-out data: the
  cubesat's gyro_z, out-of-fold 0.78 ± 0.14, test 0.945 of raw; ``tests/test_never_worse.py``);
* a candidate's score is the mean over axes of those masked ratios;
* **the one-standard-error rule**: with ``best`` the lowest score, every candidate whose
  paired difference to the best, ``score − score_best``, is within one standard error *of
  that difference* (the bootstrap standard deviation of the paired difference) is eligible,
  and the one with the fewest parameters is chosen (then the lower score, then the family
  listed first; scores within :data:`thermonet.scoring.verdicts.DECISION_RTOL` count as
  equal) — except that simplicity never buys a model worse than the **baseline** (the
  autopilots' cubic) on any axis out of fold: such a candidate is not eligible unless it is
  the best (the cubesat's quadratic, within one SE of the cubic overall but worse on gyro_x,
  was 1.6 % worse than the cubic there on the held-out data);
* **do no harm**: when no candidate beats raw on any axis, none is chosen.

The gate: the baseline stays until beaten everywhere
----------------------------------------------------
Before the one-SE rule (:data:`GATE_RULE`, :class:`Gate`): per axis the reference is the
baseline wherever its out-of-fold ratio is below 1, else raw; a candidate replaces it only if
it was judged on at least :data:`MIN_GATE_FOLDS` folds, is lower overall, and its worst fold is
no worse than the reference's worst fold (each fold scored on the windows inside both domains);
a candidate reading the direction of change (rate, lag, hysteresis) must have been judged on
held-out excursions of both directions and is held back where the pool holds one
(:func:`one_direction`); on interleaved blocks (no excursion to hold out) nothing replaces the
baseline.  The worst-fold (minimax) test was chosen over "better in every fold" on the stress
bench (``bench_selection.py --stress``): the same axes never worse than the cubic, four times
as many axes ≤ 0.8 of it.

Each axis its own model
-----------------------
:func:`choose_per_axis` runs the same rule axis by axis on the same paired draws: per axis the
best masked ratio must beat raw; the fewest parameters among the candidates within one SE of
the best on that axis win; the baseline is the floor on that axis (a candidate better than the
cubic by less than one SE loses to it: fewer parameters; a simpler one worse than the cubic
there is not taken).  With the pool's temperatures, :func:`pp_guard` leaves raw every axis
whose out-of-fold residual has a larger binned peak-to-peak than the raw output's (summed over
the folds): the figure a user reads off the compensated signal must not get worse.

Where cross-validation cannot run (``selection.folds: 0``, the four-position target's one
sample per soak, too little data for K folds) the split's single validation part decides, as
before, and the result says so.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from ..core.recording import contiguous_segments
from .folds import DIRECTION_NAMES, TURN_FRACTION, Leg, deal, excursions, purged
from .metrics import binned_peak_to_peak
from .verdicts import DECISION_RTOL, LEVEL, above, below, draws, one_se

__all__ = ["FoldPlan", "CandidateOOF", "plan_folds", "purge_rule", "window_rule",
           "window_labels", "select", "Selection",
           "choose_per_axis", "pp_guard", "point_label", "tuning_choice"]

#: Samples a fold needs in training and in validation.
MIN_FOLD_SAMPLES = 20


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
    cooling; :func:`thermonet.scoring.folds.excursions`); ``legs``: the excursions found, per
    pool run, with the fold that holds each out (−1: always trained); ``note``: why the folds
    are not the excursions where they could not be."""

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
    (fold_of, block_of, k, record) or the sentence saying why not."""
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


def plan_folds(pool: Sequence[tuple[Any, np.ndarray]], *, folds: int, blocks_per_fold: int,
               tau_s: float, purge_s: float | None = None, window_s: float | None = None,
               by_run: bool = True, hold_out: str = "auto",
               temperatures: Sequence[np.ndarray | None] | None = None) -> FoldPlan | None:
    """Folds of ``pool`` ((recording, row mask) pairs), or None where K folds cannot be made.

    ``by_run``: with several runs, leave one run out (the test is a run the model never
    saw).  Otherwise (one run, or a time-block split) ``hold_out`` says what a fold holds
    out: ``excursions`` — whole thermal excursions found in ``temperatures`` (per pool run,
    the temperature signal of every row; :func:`thermonet.scoring.folds.excursions`), the
    next warm-up or cool-down a user's test will be, purged by the longest memory of any
    candidate's inputs (``max(3 τ, window_s)``, uncapped); ``blocks`` — short contiguous
    blocks dealt round-robin (interpolation between training data); ``auto`` — excursions
    where two or more can be held out, else blocks (said in :attr:`FoldPlan.note`).
    ``hold_out="excursions"`` where none can be held out raises ``ValueError`` with what the
    data hold.
    """
    if hold_out not in HOLD_OUT:
        raise ValueError(f"hold_out must be one of {', '.join(HOLD_OUT)}, got {hold_out!r}")
    if folds < 2 or not pool:
        return None
    times = [np.asarray(r.time_s, dtype=np.float64) for r, _ in pool]
    rate = float(np.median([r.effective_rate_hz for r, _ in pool]))
    legs = _pool_legs(pool, temperatures)
    directions = _directions(pool, legs)
    fold_of: list[np.ndarray] = []
    block_of: list[np.ndarray] = []
    note = ""
    record: list[dict[str, Any]] = []
    exc = None
    if not (len(pool) >= 2 and by_run) and hold_out != "blocks":
        got = _excursion_folds(pool, legs, temperatures, folds)
        if isinstance(got, str):
            if hold_out == "excursions":
                raise ValueError(got)
            note = f"blocks, not excursions: {got}"
        else:
            exc = got
    if len(pool) >= 2 and by_run:
        kind, k, block_s = "leave-one-run-out", len(pool), None
        fold_of, block_of = _leave_one_run_out(pool, times)
        win = window_s if window_s is not None else window_rule(rate, None)
    elif exc is not None:
        kind, block_s = "excursions", None
        fold_of, block_of, k, record = exc
        win = window_s if window_s is not None else window_rule(rate, None)
    else:
        kind, k = "blocks", folds
        dealt = _blocks(pool, times, folds, blocks_per_fold)
        if dealt is None:
            return None
        fold_of, block_of, block_s = dealt
        win = window_s if window_s is not None else window_rule(rate, block_s)
    purge = purge_s if purge_s is not None else purge_rule(tau_s, win, block_s)
    train_masks: list[list[np.ndarray]] = []
    for f in range(k):
        ms = []
        for (_, m), fo, t in zip(pool, fold_of, times, strict=True):
            val = fo == f
            ms.append(m & ~val & ~purged(t, val, purge) if kind != "leave-one-run-out"
                      else m & ~val)
        n_train = sum(int(x.sum()) for x in ms)
        n_val = sum(int((fo == f).sum()) for fo in fold_of)
        if n_train < MIN_FOLD_SAMPLES or n_val < MIN_FOLD_SAMPLES:
            return None
        train_masks.append(ms)
    if kind == "excursions":
        fold_dirs: list[set[int]] = [set() for _ in range(k)]
        for leg in record:
            if leg["fold"] >= 0 and leg["direction"]:
                fold_dirs[leg["fold"]].add(leg["direction"])
    else:
        fold_dirs = [set(directions) for _ in range(k)]
    return FoldPlan(fold_of, train_masks, k, kind, block_s, purge, win, block_of,
                    directions, record, note, fold_dirs)


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


@dataclass
class Selection:
    """The outcome: chosen label (or None), per-candidate scores and masks, the rule's
    sentence, and what results.json records."""

    chosen: str | None
    tied: list[str]
    reason: str
    compensate: dict[str, list[bool]]
    record: dict[str, Any]
    #: per output axis, the candidate chosen for it alone (None: left raw), and the sentence
    per_axis: dict[str, str | None] = field(default_factory=dict)
    per_axis_reason: dict[str, str] = field(default_factory=dict)


def point_label(point: Mapping[str, Any]) -> str:
    """A tuning grid point's candidate label for :func:`select` (``degree=3,tail=2``)."""
    return ",".join(f"{k}={v}" for k, v in point.items())


def tuning_choice(sel: Selection, points: Sequence[dict[str, Any]]
                  ) -> tuple[dict[str, Any] | None, dict[str, Any]]:
    """What :func:`select` over a tuning grid (candidates labelled by :func:`point_label`)
    chose: the grid point (None where no point beats raw: the configured values stay) and the
    ``tuning`` record — each point's out-of-fold score or why it failed, and the rule's
    sentence."""
    cands = sel.record.get("candidates", {})
    record: dict[str, Any] = {
        "grid": {k: (c.get("score") if c.get("status") == "ok" else c.get("reason"))
                 for k, c in cands.items()},
        "rule": sel.reason}
    if sel.chosen is None:
        record["rule"] = f"kept the configured values: {sel.reason}"
        return None, record
    return points[[point_label(q) for q in points].index(sel.chosen)], record


def _window_ss(e: np.ndarray, wl: np.ndarray, units: np.ndarray, n_units: int
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


def _below_baseline(k: str, baseline: str | None, axis_scores: Mapping[str, np.ndarray],
                    outputs: Sequence[str]) -> str:
    """Why ``k`` may not be chosen for its simplicity: an axis on which its out-of-fold score
    is worse than the baseline's ("" when none, or without a baseline)."""
    if baseline is None or baseline not in axis_scores or k == baseline:
        return ""
    worse = [a for a, c, b in zip(outputs, axis_scores[k], axis_scores[baseline], strict=True)
             if above(float(c), float(b))]
    return (f"worse than the baseline {baseline} out of fold on {', '.join(worse)}"
            if worse else "")


def _binned_pp(temperature: np.ndarray, e: np.ndarray) -> np.ndarray:
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


def pp_guard(pp_candidate: np.ndarray, pp_raw: np.ndarray) -> list[bool]:
    """Per axis: False where the candidate's out-of-fold residual has a larger binned
    peak-to-peak (summed over the folds) than the raw output's — what a user reads off the
    compensated signal; such an axis is left raw whatever its score."""
    return [not above(float(c), float(r)) for c, r in zip(pp_candidate, pp_raw, strict=True)]


def _finite_or_none(x: float) -> float | None:
    """A figure for results.json: None where it is not finite (a fold without a window)."""
    return float(x) if math.isfinite(float(x)) else None


#: Folds a candidate must have been judged on (and beaten its reference on, each) to replace
#: it: "better in every one of two folds" happens by chance one time in four.
MIN_GATE_FOLDS = 3

#: The gate, as results.json and the report state it.
GATE_RULE = ("the baseline stays until beaten everywhere: a candidate replaces it on an axis "
             f"only if it was judged on at least {MIN_GATE_FOLDS} folds, its out-of-fold ratio "
             "is lower overall, and its worst fold is no worse than the baseline's worst fold "
             f"(on the same folds; ties within {DECISION_RTOL:g} are not worse); a model reading "
             "the direction of change must also have been judged on held-out excursions of both "
             "directions; where the folds are interleaved blocks (no excursion could be held "
             "out) the baseline is not replaced; where the baseline is worse than raw out of "
             "fold, raw is the reference")


def one_direction(directions: Sequence[int]) -> str:
    """Why a direction-carrying candidate cannot be judged ("" where the pool holds heating
    and cooling)."""
    if len(set(directions)) >= 2:
        return ""
    if not directions:
        return ("the training data hold no heating or cooling excursion (soaks only): a model "
                "reading the rate, a lag or a hysteresis memory cannot be judged on one")
    held, other = DIRECTION_NAMES[directions[0]], DIRECTION_NAMES[-directions[0]]
    return (f"the training data hold only {held}: a model reading the rate, a lag or a "
            f"hysteresis memory cannot be judged on {other}, so it does not ship over a static "
            "model")


def worst_fold_not_worse(cand: np.ndarray, ref: np.ndarray) -> bool:
    """On the folds where both are finite (at least one), ``cand``'s worst fold is no worse
    than ``ref``'s worst fold (ties within the decision margin are not worse): the minimax
    reading of "beaten everywhere" — a challenger may trade one excursion against another, but
    its worst held-out excursion must be no worse than the baseline's."""
    both = np.isfinite(cand) & np.isfinite(ref)
    if not both.any():
        return False
    return not above(float(np.max(cand[both])), float(np.max(ref[both])))


def beats_in_every_fold(cand: np.ndarray, ref: np.ndarray) -> bool:
    """``cand`` (per-fold ratios) is nowhere above ``ref`` (ties within the decision margin
    are not worse) on the folds where both are finite, and there is at least one."""
    both = np.isfinite(cand) & np.isfinite(ref)
    if not both.any():
        return False
    return not any(above(float(c), float(r)) for c, r in zip(cand[both], ref[both], strict=True))


def choose_per_axis(axis_scores: Mapping[str, np.ndarray], axis_boots: Mapping[str, np.ndarray],
                    n_params: Mapping[str, int], outputs: Sequence[str], baseline: str | None,
                    k_folds: int, *, gate: Gate | None = None,
                    base_own: np.ndarray | None = None,
                    directional: set[str] | frozenset[str] = frozenset()
                    ) -> tuple[dict[str, str | None], dict[str, str]]:
    """Each axis its own candidate: the rule of :func:`select`, axis by axis.

    Per axis ``a``: every candidate's masked out-of-fold score ratio on that axis (1 where its
    own rule leaves the axis raw) and its paired bootstrap draws.  Raw stays unless the best
    beats it; among the candidates within one standard error of the best (the paired
    difference's), the fewest parameters win, then the lower score, then the candidate listed
    first — except that no candidate simpler than the baseline (the cubic) is taken when it is
    worse than the baseline on that axis.  So a candidate better than the cubic by less than
    one SE loses to the cubic there, and the cubic is the floor of every axis where it
    compensates.  Returns ``{axis: label or None}`` and ``{axis: the rule's sentence}``.

    With ``gate`` (:class:`Gate`: per candidate, its per-fold masked ratios) the gate
    (:data:`GATE_RULE`) comes first: the reference of the axis is the baseline where it
    compensates it, else raw; a candidate stays in the choice only if it passes
    :meth:`Gate.passes` against the reference.  Candidates in ``directional`` are held back
    (:func:`select` records why once, ``held_back``: the training data hold one direction of
    change only, or no excursion could be held out); an axis's sentence names them only.
    """
    chosen: dict[str, str | None] = {}
    reason: dict[str, str] = {}
    for a, axis in enumerate(outputs):
        sc = {k: float(v[a]) for k, v in axis_scores.items() if math.isfinite(float(v[a]))}
        gated: list[str] = []
        if gate is not None and sc:
            sc, gated = _gate_axis(sc, a, gate, baseline, directional,
                                   None if base_own is None else float(base_own[a]))
        note = _gate_note(gated, directional)
        if not sc:
            chosen[axis], reason[axis] = None, "no candidate has a finite out-of-fold score"
            base_a = axis_scores.get(baseline or "")
            if base_a is not None and not below(float(base_a[a]), 1.0):
                reason[axis] = (f"raw: the baseline {baseline} does not beat raw out of fold "
                                f"({float(base_a[a]):.4g} of raw) and no "
                                "candidate passes the gate against raw") + note
            elif gated:
                reason[axis] = "raw: no candidate passes the gate against raw" + note
            continue
        c = one_se(sc, {k: v[:, a] for k, v in axis_boots.items() if k in sc}, n_params,
                   floor=partial(_worse_than, sc, baseline))
        best = str(c.best)
        if c.chosen is None:
            chosen[axis] = None
            reason[axis] = (f"raw: no candidate beats the raw output out of fold (best {best}: "
                            f"{sc[best]:.4g} of raw)") + note
            continue
        pick = chosen[axis] = c.chosen
        if pick == best:
            others = c.tied[1:]
            reason[axis] = (f"{pick}: the best out of fold ({sc[pick]:.4g} of raw, {k_folds} "
                            "folds)" + (f"; within one SE: {', '.join(others)} (more "
                                        "parameters)" if others else ""))
        else:
            reason[axis] = (f"{pick}: within one SE of the best, {best} ({sc[pick]:.4g} vs "
                            f"{sc[best]:.4g} of raw, {k_folds} folds), with fewer parameters "
                            f"({n_params[pick]} vs {n_params[best]})")
        reason[axis] += note
    return chosen, reason


def _worse_than(sc: Mapping[str, float], baseline: str | None, k: str) -> str:
    """The per-axis floor of :func:`choose_per_axis`: a candidate other than the baseline
    scoring above it on the axis is not taken for its simplicity."""
    base = sc.get(baseline or "")
    return ("worse than the baseline" if base is not None and k != baseline
            and above(sc[k], base) else "")


def _gate_axis(sc: dict[str, float], a: int, gate: Gate, baseline: str | None,
               directional: set[str] | frozenset[str], base_ratio: float | None = None
               ) -> tuple[dict[str, float], list[str]]:
    """The candidates of axis ``a`` that pass the gate (the reference among them where it
    compensates), and those it held back.  ``base_ratio``: the baseline's unmasked
    out-of-fold ratio on the axis — it is the reference wherever it is below 1 (raw stays
    the floor only where the cubic is worse than raw out of fold, not where it merely fails
    to beat raw by one standard error)."""
    base = baseline or ""
    if base_ratio is not None and base in sc and below(base_ratio, 1.0):
        sc = {**sc, base: min(sc[base], base_ratio)}
    base_on = base in sc and below(sc[base], 1.0)
    ref_score = sc[base] if base_on else 1.0
    kept: dict[str, float] = {}
    gated: list[str] = []
    for k, v in sc.items():
        if base_on and k == baseline:
            kept[k] = v
        elif k in directional:
            gated.append(k)
        elif k in gate.own and below(v, ref_score) and gate.passes(k, a, base_on):
            kept[k] = v
        elif k != baseline:
            gated.append(k)
    return kept, gated


def _gate_note(gated: list[str], directional: set[str] | frozenset[str]) -> str:
    """What the gate held back on an axis, for the rule's sentence (the reason for the held
    back ones is said once, in the selection's ``held_back``)."""
    if not gated:
        return ""
    held = [k for k in gated if k not in directional]
    parts = []
    if held:
        parts.append(f"not better everywhere: {', '.join(held)}")
    dirs = [k for k in gated if k in directional]
    if dirs:
        parts.append(f"held back: {', '.join(dirs)}")
    return " [gate: " + "; ".join(parts) + "]"


def _held_back(ok: Mapping[str, CandidateOOF], baseline: str | None, plan: FoldPlan,
               gate: bool) -> dict[str, str]:
    """Per candidate the gate holds back before any score is compared, why: one reading the
    direction of change where the pool holds one direction only (:func:`one_direction`);
    every challenger where the folds are interleaved blocks."""
    if baseline is None or not gate:
        return {}
    one_way = one_direction(plan.directions)
    held = {k: one_way for k, c in ok.items() if c.directional} if one_way else {}
    if baseline in ok and plan.kind == "blocks":
        # interleaved blocks judge interpolation between training data, never the next
        # excursion: on a heating-only ramp, static candidates that beat the cubic in five of
        # five such folds were 5–10 % worse than it on the cooling after (bench_selection.py
        # --stress); so no excursion to hold out, no challenger
        blocks = ("no excursion could be held out (the folds are interleaved blocks, which "
                  "judge interpolation, not the next warm-up): the baseline stays")
        for k in ok:
            if k != baseline:
                held[k] = f"{held[k]}; {blocks}" if k in held else blocks
    return held


def _held_back_record(held: Mapping[str, str]) -> dict[str, Any]:
    """results.json's ``held_back``: the candidates, each reason once with the candidates it
    holds (``why``, one sentence per reason) and each candidate's (``by_candidate``)."""
    groups: dict[str, list[str]] = {}
    for k, why in held.items():
        groups.setdefault(why, []).append(k)
    if len(groups) == 1:
        why = next(iter(groups))
    else:
        why = " | ".join(f"{', '.join(sorted(ks))}: {w}" for w, ks in groups.items())
    return {"candidates": sorted(held), "why": why, "by_candidate": dict(held)}


def select(plan: FoldPlan, targets: Sequence[np.ndarray], times: Sequence[np.ndarray],
           cands: Mapping[str, CandidateOOF], outputs: Sequence[str],
           baseline: str | None = None,
           temperatures: Sequence[np.ndarray] | None = None, gate: bool = True) -> Selection:
    """Choose among ``cands`` on their out-of-fold predictions (module docstring).

    ``baseline``: the candidate no simplification may fall below on any axis (the cubic);
    ``gate``: it stays until beaten everywhere (:data:`GATE_RULE`, :class:`Gate`), and a
    direction-carrying candidate is held back where the pool holds one direction only
    (:func:`one_direction`).

    ``targets`` and ``times``: per pool run, the target (n, A) and time of every row;
    ``temperatures``: per pool run, the temperature of every row — with them, an axis is
    compensated only where the candidate also does not raise the binned peak-to-peak out of
    fold (:func:`pp_guard`).  The whole-recording choice is :attr:`Selection.chosen`; the
    choice of each axis alone (:func:`choose_per_axis`) is :attr:`Selection.per_axis`.

    Steps: pool the folds' validation windows (:func:`_pool`), score every candidate and
    set its per-axis mask (:func:`_score`), choose each axis alone
    (:func:`choose_per_axis`), then the whole recording's one-SE choice (:func:`_one_se`).
    """
    ok = {k: c for k, c in cands.items() if c.failed is None}
    record: dict[str, Any] = {"method": "purged blocked cross-validation", **plan.describe(),
                              "candidates": {}}
    for k, c in cands.items():
        if c.failed is not None:
            record["candidates"][k] = {"status": "failed", "reason": c.failed}
    if not ok:
        return Selection(None, [], "no candidate could be fitted on every fold", {}, record)
    pooled = _pool(plan, targets, times, ok, len(outputs), temperatures,
                   baseline if baseline in ok else None)
    if not pooled.ns:
        return Selection(None, [], "no validation window inside every candidate's trained "
                         "domain", {}, record)
    sc = _score(pooled, ok, outputs, temperatures is not None, record,
                baseline if baseline in ok else None, plan.fold_directions)
    record["common_left_out_fraction"] = pooled.common_left
    if not gate:
        sc.gate = None
    held = _held_back(ok, baseline, plan, gate)
    if sc.gate is not None:
        sc.gate.directional = {k for k, c in ok.items() if c.directional}
    if held:
        record["held_back"] = _held_back_record(held)
    per_axis, per_axis_reason = choose_per_axis(
        sc.axis_scores, sc.axis_boots, {k: c.n_params for k, c in ok.items()}, outputs,
        baseline, plan.k, gate=sc.gate, directional=set(held),
        base_own=sc.own_ratio.get(baseline or ""))
    record["per_axis"] = {"chosen": per_axis, "rule": per_axis_reason,
                          "gate": GATE_RULE if gate else None}
    chosen, tied, reason = _one_se(plan, ok, sc, outputs, baseline, record, held)
    return Selection(chosen, tied, reason, sc.compensate, record, per_axis, per_axis_reason)


@dataclass
class _Pooled:
    """The folds' validation rows pooled per bootstrap unit (a validation block, numbered
    across folds): per-unit offset-free sums of squares of the window means on the windows
    common to every candidate (``ss``: ``"<raw>"`` and each candidate) and on each
    candidate's own domain (``own_ss``, ``own_raw``), binned peak-to-peak sums, and the
    fractions of rows left out of the domains."""

    ss: dict[str, list[np.ndarray]]
    own_ss: dict[str, list[np.ndarray]]
    own_raw: dict[str, list[np.ndarray]]
    left_out: dict[str, list[float]]
    pp_raw: np.ndarray
    pp_cand: dict[str, np.ndarray]
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


def _pool(plan: FoldPlan, targets: Sequence[np.ndarray], times: Sequence[np.ndarray],
          ok: Mapping[str, CandidateOOF], n_axes: int,
          temperatures: Sequence[np.ndarray] | None, baseline: str | None = None) -> _Pooled:
    """Every fold's validation rows pooled (:class:`_Pooled`), fold by fold."""
    pooled = _Pooled(ss={k: [] for k in ["<raw>", *ok]}, own_ss={k: [] for k in ok},
                     own_raw={k: [] for k in ok}, left_out={k: [] for k in ok},
                     pp_raw=np.zeros(n_axes), pp_cand={k: np.zeros(n_axes) for k in ok},
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
        _pool_fold(pooled, plan, f, parts, remap, targets, times, ok, temperatures, baseline)
    return pooled


def _pool_fold(pooled: _Pooled, plan: FoldPlan, f: int,
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
    _gate_sums(pooled, y, wl, un, {k: np.concatenate(v) for k, v in e_c.items()}, inside,
               baseline)
    for k in ok:
        pooled.left_out[k].append(float(1.0 - inside[k].mean()) if inside[k].size else 1.0)
    if common.sum() < 2:
        return
    n_units = pooled.n_units
    # every score is offset-free: window means about the fold's mean (_window_ss)
    s_raw, n = _window_ss(y[common], wl[common], un[common], n_units)
    pooled.ss["<raw>"].append(s_raw)
    pooled.ns.append(n)
    tf = np.concatenate(t_all)[common] if t_all else None
    if tf is not None:
        pooled.pp_raw += _binned_pp(tf, y[common])
    for k in ok:
        e = np.concatenate(e_c[k])
        s, _ = _window_ss(e[common], wl[common], un[common], n_units)
        pooled.ss[k].append(s)
        if tf is not None:
            pooled.pp_cand[k] += _binned_pp(tf, e[common])
        # the candidate's own domain, for its per-axis compensate decision
        m = inside[k]
        if m.sum() >= 2:
            so, _ = _window_ss(e[m], wl[m], un[m], n_units)
            sr, _ = _window_ss(y[m], wl[m], un[m], n_units)
            pooled.own_ss[k].append(so)
            pooled.own_raw[k].append(sr)


@dataclass
class Gate:
    """What the gate (:data:`GATE_RULE`) reads, per candidate and fold: ``own`` (K, A), its
    masked ratio to raw on its own domain; ``pair`` (K, A, 2), its and the baseline's masked
    ratios to raw on the windows inside both domains; NaN where it was not judged on the fold
    (fewer than two rows there); ``base_judged`` (K,): the baseline was judged on the fold."""

    own: dict[str, np.ndarray]
    pair: dict[str, np.ndarray]
    base_judged: np.ndarray
    fold_directions: list[set[int]] = field(default_factory=list)
    directional: set[str] = field(default_factory=set)

    @staticmethod
    def of(pooled: _Pooled, masks: Mapping[str, list[bool]], baseline: str | None,
           fold_directions: Sequence[set[int]] = ()) -> Gate:
        """The baseline's column is unmasked: on an axis where it is the reference it ships
        (it is the reference only where it is not worse than raw out of fold)."""
        A = pooled.pp_raw.size
        K = len(pooled.base_judged)
        own: dict[str, np.ndarray] = {}
        pair: dict[str, np.ndarray] = {}
        bmask = np.ones(A, dtype=bool)
        with np.errstate(divide="ignore", invalid="ignore"):
            for k, mask in masks.items():
                keep = np.array(mask)
                o = np.full((K, A), np.nan)
                pr = np.full((K, A, 2), np.nan)
                for f in range(K):
                    g = pooled.gate_own[k][f]
                    if g is not None:
                        o[f] = np.where(keep, np.sqrt(g[0] / g[1]), 1.0)
                    h = pooled.gate_pair[k][f]
                    if h is not None:
                        pr[f, :, 0] = np.where(keep, np.sqrt(h[0] / h[2]), 1.0)
                        pr[f, :, 1] = np.where(bmask, np.sqrt(h[1] / h[2]), 1.0)
                own[k], pair[k] = o, pr
        return Gate(own, pair, np.array(pooled.base_judged, dtype=bool), list(fold_directions))

    def passes(self, k: str, a: int | None, against_baseline: bool) -> bool:
        """``k`` judged on at least :data:`MIN_GATE_FOLDS` folds and nowhere worse than its
        reference on the folds where both were judged; a candidate reading the direction of
        change also judged on a held-out excursion of every direction its reference was
        judged on (a model reading the rate is not judged on heating where no fold trained it
        on heating; ``a``: one axis; None: the mean over axes)."""
        if against_baseline:
            p = self.pair[k] if a is None else self.pair[k][:, a:a + 1]
            c, b = p[:, :, 0].mean(axis=1), p[:, :, 1].mean(axis=1)
            ref_judged = self.base_judged
        else:
            c = self.own[k].mean(axis=1) if a is None else self.own[k][:, a]
            b = np.ones_like(c)
            ref_judged = np.ones(c.size, dtype=bool)
        judged = np.isfinite(c) & np.isfinite(b)
        if int(judged.sum()) < MIN_GATE_FOLDS:
            return False
        if k in self.directional and self.fold_directions:
            need = set().union(*(d for d, r in zip(self.fold_directions, ref_judged,
                                                   strict=True) if r))
            have = set().union(*(d for d, j in zip(self.fold_directions, judged, strict=True)
                                 if j))
            if not need <= have:
                return False
        return worst_fold_not_worse(c, b)


def _gate_sums(pooled: _Pooled, y: np.ndarray, wl: np.ndarray, un: np.ndarray,
               e: Mapping[str, np.ndarray], inside: Mapping[str, np.ndarray],
               baseline: str | None) -> None:
    """One fold's sums of squares for the gate (:attr:`_Pooled.gate_own`, ``gate_pair``):
    each candidate judged where it can be — on its own domain against raw, and on the
    windows inside both its and the baseline's domain against the baseline."""
    n_units = pooled.n_units

    def total(x: np.ndarray, m: np.ndarray) -> np.ndarray:
        return _window_ss(x[m], wl[m], un[m], n_units)[0].sum(0)

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


@dataclass
class _Scores:
    """Per candidate: the whole-recording score (mean over axes, uncompensated axes at 1)
    and its paired bootstrap draws, the per-axis mask, and the per-axis scores and draws."""

    scores: dict[str, float] = field(default_factory=dict)
    boots: dict[str, np.ndarray] = field(default_factory=dict)
    compensate: dict[str, list[bool]] = field(default_factory=dict)
    axis_scores: dict[str, np.ndarray] = field(default_factory=dict)
    axis_boots: dict[str, np.ndarray] = field(default_factory=dict)
    #: per candidate, (folds, axes) masked ratio to raw on each fold's common windows (NaN:
    #: the fold had no common window), and its mean over axes
    fold_axis: dict[str, np.ndarray] = field(default_factory=dict)
    fold_scores: dict[str, np.ndarray] = field(default_factory=dict)
    gate: Gate | None = None
    #: per candidate, its unmasked out-of-fold ratio to raw per axis on its own domain
    own_ratio: dict[str, np.ndarray] = field(default_factory=dict)


def _score(pooled: _Pooled, ok: Mapping[str, CandidateOOF], outputs: Sequence[str],
           guard: bool, record: dict[str, Any], baseline: str | None = None,
           fold_directions: Sequence[set[int]] = ()) -> _Scores:
    """Every candidate scored on the common windows against raw, its axes masked by the
    one-SE rule on its own domain (and the peak-to-peak guard where ``guard``); each
    candidate's entry of ``record``."""
    A = len(outputs)
    raw_ss = pooled.total(pooled.ss["<raw>"])
    counts = draws(pooled.n_units)             # (R, B) paired: one set of draws for all
    sc = _Scores()
    with np.errstate(divide="ignore", invalid="ignore"):
        raw_boot = counts @ raw_ss
        q = 100.0 * (1.0 - LEVEL) / 2.0
        for k in ok:
            own_c, own_r = pooled.total(pooled.own_ss[k]), pooled.total(pooled.own_raw[k])
            ratio_own = np.sqrt(own_c.sum(0) / own_r.sum(0))
            boot_own = np.sqrt((counts @ own_c) / (counts @ own_r))
            iv = np.nanpercentile(boot_own, [q, 100 - q], axis=0)
            se_own = np.nanstd(boot_own, axis=0)
            # raw is the simplest candidate of every axis: it stays unless the candidate's
            # paired improvement 1 − ratio exceeds one standard error (the one-SE rule)
            pp_ok = pp_guard(pooled.pp_cand[k], pooled.pp_raw) if guard else [True] * A
            mask = [bool(below(float(ratio_own[a]) + float(se_own[a]), 1.0)) and pp_ok[a]
                    for a in range(A)]
            sc.compensate[k] = mask
            c_ss = pooled.total(pooled.ss[k])
            ratio = np.sqrt(c_ss.sum(0) / raw_ss.sum(0))
            boot = np.sqrt((counts @ c_ss) / raw_boot)
            keep = np.array(mask)
            sc.axis_scores[k] = np.where(keep, ratio, 1.0)
            sc.own_ratio[k] = ratio_own
            sc.scores[k] = float(np.mean(sc.axis_scores[k]))
            sc.axis_boots[k] = np.where(keep[None, :], boot, 1.0)
            sc.boots[k] = sc.axis_boots[k].mean(axis=1)
            fold_axis = []
            lo_u = 0
            for nu in pooled.fold_units:
                sl = slice(lo_u, lo_u + nu)
                lo_u += nu
                r = np.sqrt(c_ss[sl].sum(0) / raw_ss[sl].sum(0))
                fold_axis.append(np.where(keep, r, np.where(np.isfinite(r), 1.0, np.nan)))
            sc.fold_axis[k] = np.array(fold_axis).reshape(len(pooled.fold_units), A)
            sc.fold_scores[k] = sc.fold_axis[k].mean(axis=1)
            fold_scores = [_finite_or_none(x) for x in sc.fold_scores[k]]
            record["candidates"][k] = {
                "status": "ok", "n_params": ok[k].n_params, "score": sc.scores[k],
                "interval": [float(x) for x in np.nanpercentile(sc.boots[k], [q, 100 - q])],
                "fold_scores": fold_scores,
                "axes": {a: {"ratio": float(ratio[i]), "own_ratio": float(ratio_own[i]),
                             "own_interval": [float(iv[0, i]), float(iv[1, i])],
                             "own_se": float(se_own[i]),
                             "fold_ratios": [_finite_or_none(x)
                                             for x in sc.fold_axis[k][:, i]],
                             **({"pp_ratio": float(pooled.pp_cand[k][i] / pooled.pp_raw[i])
                                 if pooled.pp_raw[i] > 0 else None,
                                 "pp_guard": bool(pp_ok[i])} if guard else {}),
                             "compensate": bool(mask[i])} for i, a in enumerate(outputs)},
                "left_out_fraction": pooled.left_out[k]}
    sc.gate = Gate.of(pooled, sc.compensate, baseline, fold_directions)
    return sc


def _one_se(plan: FoldPlan, ok: Mapping[str, CandidateOOF], sc: _Scores,
            outputs: Sequence[str], baseline: str | None,
            record: dict[str, Any], held: Mapping[str, str] | None = None
            ) -> tuple[str | None, list[str], str]:
    """The whole recording's choice: (chosen or None, tied, reason) — do no harm, then the
    fewest parameters within one SE of the best (no candidate below the baseline's floor).

    With a baseline, the gate first (:data:`GATE_RULE` on the mean over axes): a candidate
    not better than the baseline everywhere, or one held back before any score (``held``:
    candidate -> why, :func:`_held_back`), is not eligible."""
    scores = {k: float(sc.scores[k]) for k in ok if k in sc.scores}
    gated: dict[str, str] = {}
    if baseline is not None and math.isfinite(scores.get(baseline, math.nan)) and \
            sc.gate is not None:
        for k, v in scores.items():
            if k == baseline or not math.isfinite(v):
                continue
            if held and k in held:
                gated[k] = held[k]
            elif not sc.gate.passes(k, None, True):
                gated[k] = (f"gate: not better than the baseline {baseline} everywhere (judged "
                            f"on < {MIN_GATE_FOLDS} folds, or its worst fold is worse)")
    c = one_se(scores, sc.boots, {k: o.n_params for k, o in ok.items()}, held=gated,
               floor=lambda k: _below_baseline(k, baseline, sc.axis_scores, outputs))
    if c.status == "no candidate":
        return None, [], "no candidate has a finite out-of-fold score"
    for k in c.diff:
        record["candidates"][k]["diff_to_best"] = c.diff[k]
        record["candidates"][k]["se_of_diff"] = c.se[k]
    for k, why in c.blocked.items():
        record["candidates"][k]["not_eligible"] = why
    best = str(c.best)
    if c.chosen is None:
        reason = ("do no harm: no candidate beats the raw output on any axis out of fold "
                  f"(best {best}: score ratio {scores[best]:.4g})")
        record["rule"] = reason
        return None, [], reason
    chosen, tied = c.chosen, c.tied
    if not tied:
        reason = (f"chose {chosen}: lowest out-of-fold score ({scores[chosen]:.4g} of raw, "
                  f"{plan.k} folds)")
    elif chosen == best:
        reason = (f"tie: {', '.join(tied)} within one SE of the best out of fold; chose "
                  f"{chosen}: the best ({scores[chosen]:.4g} of raw, {plan.k} folds) and the "
                  f"fewest parameters ({ok[chosen].n_params})")
    else:
        reason = (f"tie: {', '.join(tied)} within one SE of the best out of fold; chose "
                  f"{chosen}: within one SE of {best} ({scores[chosen]:.4g} vs "
                  f"{scores[best]:.4g} of raw, paired difference {c.diff[chosen]:.2g} ≤ SE "
                  f"{c.se[chosen]:.2g}, {plan.k} folds), the fewest parameters "
                  f"({ok[chosen].n_params} vs {ok[best].n_params})")
    record["rule"] = reason
    record["chosen"] = chosen
    return chosen, tied, reason
