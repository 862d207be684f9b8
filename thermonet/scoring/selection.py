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
baseline unless it is worse than raw out of fold (:func:`~thermonet.scoring.gate.gate_axis`),
then raw; a candidate replaces it only if it was judged on at least :data:`MIN_GATE_FOLDS`
folds (on two, 10 % better on each: :func:`~thermonet.scoring.gate.clear_on_each`), is
lower overall, and its worst fold is
no worse than the reference's worst fold (each fold scored on the windows inside both domains);
a candidate reading the direction of change (rate, lag, delayed temperature, hysteresis) must
have been judged on held-out excursions of both directions and is held back where the pool
holds one (:func:`one_direction`) or ramps at one rate (:func:`one_rate`: a lag and a
hysteresis are the same correction there); on interleaved blocks (no excursion to hold out) nothing replaces the
baseline.  The worst-fold (minimax) test was chosen over "better in every fold" on the stress
bench (``bench_selection.py --stress``): the same axes never worse than the cubic, four times
as many axes ≤ 0.8 of it.

Each axis its own model
-----------------------
:func:`choose_per_axis` runs the same rule axis by axis on the same paired draws: per axis the
best masked ratio must beat raw; the fewest parameters among the candidates within one SE of
the best on that axis win; the baseline is the floor on that axis (a candidate better than the
cubic by less than one SE loses to it: fewer parameters; a simpler one worse than the cubic
there is not taken; with the gate, a simpler one within one SE of the cubic does not replace
it either: ``one_se(..., keep=baseline)``).  With the pool's temperatures, :func:`pp_guard` leaves raw every axis
whose out-of-fold residual has a larger binned peak-to-peak than the raw output's (summed over
the folds, on the candidate's own domain as its score: a mask is the same alone as beside any
other candidates, so a family's own file compensates the axes the comparison gives it): the
figure a user reads off the compensated signal must not get worse — but for the baseline where
its score beats raw out of fold (it stays the reference there, :func:`gate_axis`).

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

from .fold_plan import FoldPlan
from .gate import (
    GATE_RULE,
    Gate,
    base_worse_than_raw,
    gate_axis,
    gate_note,
    held_back,
    held_back_record,
    pp_not_worse_note,
)
from .oof_pool import CandidateOOF, Pooled, pool
from .verdicts import LEVEL, above, below, draws, one_se

__all__ = ["select", "Selection",
           "choose_per_axis", "pp_guard", "point_label", "tuning_choice"]

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


def pp_guard(pp_candidate: np.ndarray, pp_raw: np.ndarray) -> list[bool]:
    """Per axis: False where the candidate's out-of-fold residual has a larger binned
    peak-to-peak (summed over the folds) than the raw output's — what a user reads off the
    compensated signal; such an axis is left raw whatever its score."""
    return [not above(float(c), float(r)) for c, r in zip(pp_candidate, pp_raw, strict=True)]


def _finite_or_none(x: float) -> float | None:
    """A figure for results.json: None where it is not finite (a fold without a window)."""
    return float(x) if math.isfinite(float(x)) else None


def choose_per_axis(axis_scores: Mapping[str, np.ndarray], axis_boots: Mapping[str, np.ndarray],
                    n_params: Mapping[str, int], outputs: Sequence[str], baseline: str | None,
                    k_folds: int, *, gate: Gate | None = None,
                    base_own: np.ndarray | None = None,
                    base_mask: Sequence[bool] | None = None,
                    base_pp: np.ndarray | None = None,
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
            sc, gated = gate_axis(sc, a, gate, baseline, directional,
                                   None if base_own is None else float(base_own[a]),
                                   base_kept=bool(base_mask is not None and base_mask[a]))
        note = gate_note(gated, directional)
        if not sc:
            chosen[axis], reason[axis] = None, "no candidate has a finite out-of-fold score"
            base_a = axis_scores.get(baseline or "")
            if base_a is not None and not below(float(base_a[a]), 1.0):
                reason[axis] = "raw: " + base_worse_than_raw(
                    str(baseline), base_a if base_own is None else base_own, base_pp, a) + note
            elif gated:
                reason[axis] = "raw: no candidate passes the gate against raw" + note
            continue
        c = one_se(sc, {k: v[:, a] for k, v in axis_boots.items() if k in sc}, n_params,
                   floor=partial(_worse_than, sc, baseline),
                   keep=baseline if gate is not None else None)
        best = str(c.best)
        if c.chosen is None and gate is not None and baseline in sc:
            chosen[axis] = baseline          # the reference stays: nothing beat it, nor raw
            reason[axis] = (f"{baseline}: the baseline stays — not worse than raw out of fold "
                            f"({sc[baseline]:.4g} of raw), nothing passes the gate against it"
                            ) + note
            continue
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
        elif pick == baseline and gate is not None:
            reason[axis] = (f"{pick}: the baseline stays — the best out of fold, {best}, beats "
                            f"it by less than one SE ({sc[best]:.4g} vs {sc[pick]:.4g} of raw, "
                            f"{k_folds} folds)")
        else:
            reason[axis] = (f"{pick}: within one SE of the best, {best} ({sc[pick]:.4g} vs "
                            f"{sc[best]:.4g} of raw, {k_folds} folds), with fewer parameters "
                            f"({n_params[pick]} vs {n_params[best]})")
        reason[axis] += note
    for a, axis in enumerate(outputs):      # the baseline kept by its score, not its guard
        if base_pp is not None and baseline is not None and chosen[axis] == baseline:
            reason[axis] += pp_not_worse_note(baseline, float(base_pp[a]))
    return chosen, reason


def _worse_than(sc: Mapping[str, float], baseline: str | None, k: str) -> str:
    """The per-axis floor of :func:`choose_per_axis`: a candidate other than the baseline
    scoring above it on the axis is not taken for its simplicity."""
    base = sc.get(baseline or "")
    return ("worse than the baseline" if base is not None and k != baseline
            and above(sc[k], base) else "")


def select(plan: FoldPlan, targets: Sequence[np.ndarray], times: Sequence[np.ndarray],
           cands: Mapping[str, CandidateOOF], outputs: Sequence[str],
           baseline: str | None = None,
           temperatures: Sequence[np.ndarray] | None = None, gate: bool = True) -> Selection:
    """Choose among ``cands`` on their out-of-fold predictions (module docstring).

    ``baseline``: the candidate no simplification may fall below on any axis (the cubic);
    ``gate``: it stays until beaten everywhere (:data:`GATE_RULE`, :class:`Gate`), and a
    direction-carrying candidate is held back where the pool holds one direction only
    (:func:`one_direction`) or one ramp rate (:func:`one_rate`).

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
    pooled = pool(plan, targets, times, ok, len(outputs), temperatures,
                   baseline if baseline in ok else None)
    while not pooled.ns and len(ok) > 1:
        # no window inside every candidate's domain: the candidate that covers the least is
        # no candidate (a model with memory whose joint envelope no held-out excursion enters)
        worst = max(ok, key=lambda k: float(np.mean(pooled.left_out[k])))
        record["candidates"][worst] = {
            "status": "failed", "reason": "no validation window inside its trained domain "
            f"on any fold where the others have one (left out: {np.mean(pooled.left_out[worst]):.0%})"}
        ok = {k: c for k, c in ok.items() if k != worst}
        pooled = pool(plan, targets, times, ok, len(outputs), temperatures,
                       baseline if baseline in ok else None)
    if not pooled.ns:
        return Selection(None, [], "no validation window inside every candidate's trained "
                         "domain", {}, record)
    sc = _score(pooled, ok, outputs, temperatures is not None, record,
                baseline if baseline in ok else None, plan.fold_directions)
    record["common_left_out_fraction"] = pooled.common_left
    if not gate:
        sc.gate = None
    held = held_back(ok, baseline, plan, gate)
    if sc.gate is not None:
        sc.gate.directional = {k for k, c in ok.items() if c.directional}
    if held:
        record["held_back"] = held_back_record(held)
    per_axis, per_axis_reason = choose_per_axis(
        sc.axis_scores, sc.axis_boots, {k: c.n_params for k, c in ok.items()}, outputs,
        baseline, plan.k, gate=sc.gate, directional=set(held),
        base_own=sc.own_ratio.get(baseline or ""), base_mask=sc.compensate.get(baseline or ""),
        base_pp=pooled.pp_cand[baseline] / np.where(pooled.pp_own_raw[baseline] > 0,
                                                    pooled.pp_own_raw[baseline], np.nan)
        if baseline in ok and temperatures is not None else None)
    record["per_axis"] = {"chosen": per_axis, "rule": per_axis_reason,
                          "gate": GATE_RULE if gate else None}
    chosen, tied, reason = _one_se(plan, ok, sc, outputs, baseline, record, held)
    return Selection(chosen, tied, reason, sc.compensate, record, per_axis, per_axis_reason)


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


def _score(pooled: Pooled, ok: Mapping[str, CandidateOOF], outputs: Sequence[str],
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
            # paired improvement 1 − ratio exceeds one standard error (the one-SE rule) —
            # but for the baseline, which stays until it is worse than raw (its interval
            # above 1): a cubic within the noise of raw is the autopilots' correction and
            # what the user's test is measured against (a drift smaller than the turn-on
            # spread cannot be told from raw out of fold, and is there on the next run)
            pp_ok = pp_guard(pooled.pp_cand[k], pooled.pp_own_raw[k]) if guard else [True] * A
            if k == baseline:
                # its binned peak-to-peak alone does not set aside a baseline whose score
                # beats raw out of fold: the per-axis rule's reference (gate.gate_axis), so
                # `--family cubic` compensates the axes the per-axis model gives the cubic
                mask = [not above(float(iv[0, a]), 1.0)
                        and (pp_ok[a] or bool(below(float(ratio_own[a]), 1.0)))
                        for a in range(A)]
            else:
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
                             **({"pp_ratio": float(pooled.pp_cand[k][i]
                                                   / pooled.pp_own_raw[k][i])
                                 if pooled.pp_own_raw[k][i] > 0 else None,
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
            elif why := sc.gate.refusal(k, None, True):
                gated[k] = f"gate: not better than the baseline {baseline} everywhere: {why}"
    c = one_se(scores, sc.boots, {k: o.n_params for k, o in ok.items()}, held=gated,
               floor=lambda k: _below_baseline(k, baseline, sc.axis_scores, outputs),
               keep=baseline if sc.gate is not None else None)
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
    elif chosen == baseline and sc.gate is not None:
        reason = (f"tie: {', '.join(tied)} within one SE of the best out of fold; the baseline "
                  f"{chosen} stays: {best} beats it by less than one SE ({scores[best]:.4g} vs "
                  f"{scores[chosen]:.4g} of raw, {plan.k} folds)")
    else:
        reason = (f"tie: {', '.join(tied)} within one SE of the best out of fold; chose "
                  f"{chosen}: within one SE of {best} ({scores[chosen]:.4g} vs "
                  f"{scores[best]:.4g} of raw, paired difference {c.diff[chosen]:.2g} ≤ SE "
                  f"{c.se[chosen]:.2g}, {plan.k} folds), the fewest parameters "
                  f"({ok[chosen].n_params} vs {ok[best].n_params})")
    record["rule"] = reason
    record["chosen"] = chosen
    return chosen, tied, reason
