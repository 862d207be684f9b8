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
* **One run**, or a time-block split (the test is blocks inside the runs): every run cut by
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
from typing import Any

import numpy as np

from ..core.recording import contiguous_segments
from .folds import deal, purged
from .metrics import binned_peak_to_peak
from .verdicts import LEVEL, above, below, draws, same

__all__ = ["FoldPlan", "CandidateOOF", "plan_folds", "purge_rule", "window_rule",
           "in_domain", "noise_widths", "window_labels", "select", "Selection",
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
    """The folds of one split's pool: per pool run, each sample's fold (−1: not in the pool),
    and per fold a training mask (purged) per pool run."""

    fold_of: list[np.ndarray]
    train_masks: list[list[np.ndarray]]
    k: int
    kind: str                       # "leave-one-run-out" or "blocks"
    block_s: float | None
    purge_s: float
    window_s: float
    block_of: list[np.ndarray] = field(default_factory=list)   # validation block ids

    def describe(self) -> dict[str, Any]:
        return {"kind": self.kind, "folds": self.k, "block_s": self.block_s,
                "purge_s": self.purge_s, "window_s": self.window_s,
                "train_fraction": [float(np.mean([m.sum() for m in ms]) /
                                         max(np.mean([(f >= 0).sum() for f in self.fold_of]), 1))
                                   for ms in self.train_masks]}


def plan_folds(pool: Sequence[tuple[Any, np.ndarray]], *, folds: int, blocks_per_fold: int,
               tau_s: float, purge_s: float | None = None, window_s: float | None = None,
               by_run: bool = True) -> FoldPlan | None:
    """Folds of ``pool`` ((recording, row mask) pairs), or None where K folds cannot be made.

    ``by_run``: with several runs, leave one run out (the test is a run the model never
    saw); False deals blocks inside every run (the test is blocks inside the runs: a
    time-block split), as with one run.
    """
    if folds < 2 or not pool:
        return None
    times = [np.asarray(r.time_s, dtype=np.float64) for r, _ in pool]
    rate = float(np.median([r.effective_rate_hz for r, _ in pool]))
    fold_of: list[np.ndarray] = []
    block_of: list[np.ndarray] = []
    if len(pool) >= 2 and by_run:
        kind, k, block_s = "leave-one-run-out", len(pool), None
        for j, (_, m) in enumerate(pool):
            fold_of.append(np.where(m, deal(0, j, k), -1))     # each run one block: its own fold
        win = window_s if window_s is not None else window_rule(rate, None)
        for j, t in enumerate(times):
            # bootstrap units inside a held-out run: windows grouped into ~8 blocks per run
            span = max(float(t[-1] - t[0]), 1e-9)
            block_of.append(np.minimum(((t - t[0]) / span * 8).astype(int), 7) + 8 * j)
    else:
        kind, k = "blocks", folds
        n_blocks = folds * blocks_per_fold
        spans = []
        for (_, m), t in zip(pool, times, strict=True):
            tm = t[m]
            if tm.size < n_blocks * 2:
                return None
            spans.append(max(float(tm[-1] - tm[0]), 1e-9))
        block_s = float(np.median(spans)) / n_blocks
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
        win = window_s if window_s is not None else window_rule(rate, block_s)
    purge = purge_s if purge_s is not None else purge_rule(tau_s, win, block_s)
    train_masks: list[list[np.ndarray]] = []
    for f in range(k):
        ms = []
        for (_, m), fo, t in zip(pool, fold_of, times, strict=True):
            val = fo == f
            ms.append(m & ~val & ~purged(t, val, purge) if kind == "blocks" else m & ~val)
        n_train = sum(int(x.sum()) for x in ms)
        n_val = sum(int((fo == f).sum()) for fo in fold_of)
        if n_train < MIN_FOLD_SAMPLES or n_val < MIN_FOLD_SAMPLES:
            return None
        train_masks.append(ms)
    return FoldPlan(fold_of, train_masks, k, kind, block_s, purge, win, block_of)


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


def choose_per_axis(axis_scores: Mapping[str, np.ndarray], axis_boots: Mapping[str, np.ndarray],
                    n_params: Mapping[str, int], outputs: Sequence[str], baseline: str | None,
                    k_folds: int) -> tuple[dict[str, str | None], dict[str, str]]:
    """Each axis its own candidate: the rule of :func:`select`, axis by axis.

    Per axis ``a``: every candidate's masked out-of-fold score ratio on that axis (1 where its
    own rule leaves the axis raw) and its paired bootstrap draws.  Raw stays unless the best
    beats it; among the candidates within one standard error of the best (the paired
    difference's), the fewest parameters win, then the lower score, then the candidate listed
    first — except that no candidate simpler than the baseline (the cubic) is taken when it is
    worse than the baseline on that axis.  So a candidate better than the cubic by less than
    one SE loses to the cubic there, and the cubic is the floor of every axis where it
    compensates.  Returns ``{axis: label or None}`` and ``{axis: the rule's sentence}``.
    """
    order = {k: i for i, k in enumerate(axis_scores)}
    chosen: dict[str, str | None] = {}
    reason: dict[str, str] = {}
    for a, axis in enumerate(outputs):
        sc = {k: float(v[a]) for k, v in axis_scores.items() if math.isfinite(float(v[a]))}
        if not sc:
            chosen[axis], reason[axis] = None, "no candidate has a finite out-of-fold score"
            continue
        low = min(sc.values())
        best = min((k for k, v in sc.items() if same(v, low)),
                   key=lambda k: (n_params[k], order[k]))
        if not below(sc[best], 1.0):
            chosen[axis] = None
            reason[axis] = (f"raw: no candidate beats the raw output out of fold (best {best}: "
                            f"{sc[best]:.4g} of raw)")
            continue
        base = sc.get(baseline or "")
        eligible = []
        for k, v in sc.items():
            se = float(np.nanstd(axis_boots[k][:, a] - axis_boots[best][:, a]))
            if k != best and base is not None and k != baseline and above(v, base):
                continue
            if below(v, 1.0) and (v - sc[best] <= se or same(v, sc[best])):
                eligible.append(k)
        fewest = min(n_params[k] for k in eligible)
        pick = min((k for k in eligible if n_params[k] == fewest),
                   key=lambda k: (sc[k], order[k]))
        chosen[axis] = pick
        if pick == best:
            others = [k for k in eligible if k != pick]
            reason[axis] = (f"{pick}: the best out of fold ({sc[pick]:.4g} of raw, {k_folds} "
                            "folds)" + (f"; within one SE: {', '.join(others)} (more "
                                        "parameters)" if others else ""))
        else:
            reason[axis] = (f"{pick}: within one SE of the best, {best} ({sc[pick]:.4g} vs "
                            f"{sc[best]:.4g} of raw, {k_folds} folds), with fewer parameters "
                            f"({n_params[pick]} vs {n_params[best]})")
    return chosen, reason


def select(plan: FoldPlan, targets: Sequence[np.ndarray], times: Sequence[np.ndarray],
           cands: Mapping[str, CandidateOOF], outputs: Sequence[str],
           baseline: str | None = None,
           temperatures: Sequence[np.ndarray] | None = None) -> Selection:
    """Choose among ``cands`` on their out-of-fold predictions (module docstring).

    ``baseline``: the candidate no simplification may fall below on any axis (the cubic).

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
    pooled = _pool(plan, targets, times, ok, len(outputs), temperatures)
    if not pooled.ns:
        return Selection(None, [], "no validation window inside every candidate's trained "
                         "domain", {}, record)
    sc = _score(pooled, ok, outputs, temperatures is not None, record)
    record["common_left_out_fraction"] = pooled.common_left
    per_axis, per_axis_reason = choose_per_axis(
        sc.axis_scores, sc.axis_boots, {k: c.n_params for k, c in ok.items()}, outputs,
        baseline, plan.k)
    record["per_axis"] = {"chosen": per_axis, "rule": per_axis_reason}
    chosen, tied, reason = _one_se(plan, ok, sc, outputs, baseline, record)
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
          temperatures: Sequence[np.ndarray] | None) -> _Pooled:
    """Every fold's validation rows pooled (:class:`_Pooled`), fold by fold."""
    pooled = _Pooled(ss={k: [] for k in ["<raw>", *ok]}, own_ss={k: [] for k in ok},
                     own_raw={k: [] for k in ok}, left_out={k: [] for k in ok},
                     pp_raw=np.zeros(n_axes), pp_cand={k: np.zeros(n_axes) for k in ok})
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
        _pool_fold(pooled, plan, f, parts, remap, targets, times, ok, temperatures)
    return pooled


def _pool_fold(pooled: _Pooled, plan: FoldPlan, f: int,
               parts: list[tuple[int, np.ndarray, np.ndarray]], remap: dict[int, int],
               targets: Sequence[np.ndarray], times: Sequence[np.ndarray],
               ok: Mapping[str, CandidateOOF],
               temperatures: Sequence[np.ndarray] | None) -> None:
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
class _Scores:
    """Per candidate: the whole-recording score (mean over axes, uncompensated axes at 1)
    and its paired bootstrap draws, the per-axis mask, and the per-axis scores and draws."""

    scores: dict[str, float] = field(default_factory=dict)
    boots: dict[str, np.ndarray] = field(default_factory=dict)
    compensate: dict[str, list[bool]] = field(default_factory=dict)
    axis_scores: dict[str, np.ndarray] = field(default_factory=dict)
    axis_boots: dict[str, np.ndarray] = field(default_factory=dict)


def _score(pooled: _Pooled, ok: Mapping[str, CandidateOOF], outputs: Sequence[str],
           guard: bool, record: dict[str, Any]) -> _Scores:
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
            sc.scores[k] = float(np.mean(sc.axis_scores[k]))
            sc.axis_boots[k] = np.where(keep[None, :], boot, 1.0)
            sc.boots[k] = sc.axis_boots[k].mean(axis=1)
            fold_scores = []
            lo_u = 0
            for nu in pooled.fold_units:
                sl = slice(lo_u, lo_u + nu)
                lo_u += nu
                r = np.sqrt(c_ss[sl].sum(0) / raw_ss[sl].sum(0))
                fold_scores.append(float(np.mean(np.where(keep, r, 1.0))))
            record["candidates"][k] = {
                "status": "ok", "n_params": ok[k].n_params, "score": sc.scores[k],
                "interval": [float(x) for x in np.nanpercentile(sc.boots[k], [q, 100 - q])],
                "fold_scores": fold_scores,
                "axes": {a: {"ratio": float(ratio[i]), "own_ratio": float(ratio_own[i]),
                             "own_interval": [float(iv[0, i]), float(iv[1, i])],
                             "own_se": float(se_own[i]),
                             **({"pp_ratio": float(pooled.pp_cand[k][i] / pooled.pp_raw[i])
                                 if pooled.pp_raw[i] > 0 else None,
                                 "pp_guard": bool(pp_ok[i])} if guard else {}),
                             "compensate": bool(mask[i])} for i, a in enumerate(outputs)},
                "left_out_fraction": pooled.left_out[k]}
    return sc


def _one_se(plan: FoldPlan, ok: Mapping[str, CandidateOOF], sc: _Scores,
            outputs: Sequence[str], baseline: str | None,
            record: dict[str, Any]) -> tuple[str | None, list[str], str]:
    """The whole recording's choice: (chosen or None, tied, reason) — do no harm, then the
    fewest parameters within one SE of the best (no candidate below the baseline's floor)."""
    order = {k: i for i, k in enumerate(ok)}
    finite = {k: v for k, v in sc.scores.items() if math.isfinite(v)}
    if not finite:
        return None, [], "no candidate has a finite out-of-fold score"
    low = min(finite.values())
    best = min((k for k, v in finite.items() if same(v, low)),
               key=lambda k: (ok[k].n_params, order[k]))
    if not below(finite[best], 1.0):
        reason = ("do no harm: no candidate beats the raw output on any axis out of fold "
                  f"(best {best}: score ratio {finite[best]:.4g})")
        record["rule"] = reason
        return None, [], reason
    eligible = []
    for k, v in finite.items():
        d = sc.boots[k] - sc.boots[best]
        se = float(np.nanstd(d)) if k != best else 0.0
        record["candidates"][k]["diff_to_best"] = v - finite[best]
        record["candidates"][k]["se_of_diff"] = se
        floor = "" if k == best else _below_baseline(k, baseline, sc.axis_scores, outputs)
        if floor:
            record["candidates"][k]["not_eligible"] = floor
        elif below(v, 1.0) and (v - finite[best] <= se or same(v, finite[best])):
            eligible.append(k)
    fewest = min(ok[k].n_params for k in eligible)
    cands_f = [k for k in eligible if ok[k].n_params == fewest]
    low_c = min(finite[k] for k in cands_f)
    chosen = min((k for k in cands_f if same(finite[k], low_c)), key=lambda k: order[k])
    tied = sorted(eligible, key=lambda k: (ok[k].n_params, finite[k], order[k]))
    tied = [chosen] + [k for k in tied if k != chosen] if len(eligible) > 1 else []
    c = record["candidates"][chosen]
    if not tied:
        reason = (f"chose {chosen}: lowest out-of-fold score ({finite[chosen]:.4g} of raw, "
                  f"{plan.k} folds)")
    elif chosen == best:
        reason = (f"tie: {', '.join(tied)} within one SE of the best out of fold; chose "
                  f"{chosen}: the best ({finite[chosen]:.4g} of raw, {plan.k} folds) and the "
                  f"fewest parameters ({ok[chosen].n_params})")
    else:
        reason = (f"tie: {', '.join(tied)} within one SE of the best out of fold; chose "
                  f"{chosen}: within one SE of {best} ({finite[chosen]:.4g} vs "
                  f"{finite[best]:.4g} of raw, paired difference {c['diff_to_best']:.2g} ≤ SE "
                  f"{c['se_of_diff']:.2g}, {plan.k} folds), the fewest parameters "
                  f"({ok[chosen].n_params} vs {ok[best].n_params})")
    record["rule"] = reason
    record["chosen"] = chosen
    return chosen, tied, reason
