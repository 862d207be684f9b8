"""``thermonet compare``, step 3 — judging: verdicts against raw from a paired block bootstrap
of the held-out blocks, the per-axis mask, the choice (per-axis masked validation score, ties →
fewest parameters, do no harm), the verdicts against the baseline and the extrapolation
warnings; :class:`Fitted` is one family after fitting, what is judged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..data.diagnostics import extrapolation_warnings
from ..features.target import CHANNEL, FOUR_POSITION, ZERO, Target
from ..models.registry import PER_AXIS
from ..reporting.results import AxisResult, ComparisonResult, FamilyResult, Verdict
from ..scoring.selection import select
from ..scoring.verdicts import BlockStats, choose, draws, masked_scores, ratio_interval, verdict_of
from ..training.parts import (
    Part,
)
from .compare_plan import Plan

__all__ = ["Fitted", "judge_against_raw", "choose_and_judge", "extrapolation",
           "per_axis_choice", "per_axis_result"]


# ------------------------------------------------------------------------------------- fit
@dataclass
class Fitted:
    """One family after fitting: its record, last model, and its held-out block sums."""

    result: FamilyResult
    model: Any = None
    history: list[Any] | None = None
    val: BlockStats | None = None
    test: BlockStats | None = None
    test_parts: list[Part] = field(default_factory=list)
    test_preds: list[np.ndarray] = field(default_factory=list)
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    excursion: dict[str, float] = field(default_factory=dict)  # farthest test sample outside
    val_draws: np.ndarray | None = None  # bootstrap draws of the masked validation score
    best_val: float | None = None        # the last fold's best validation loss
    oof: Any = None                      # thermonet.scoring.selection.CandidateOOF (cross-validation)
    cv_mask: list[bool] | None = None    # per-axis compensate decision out of fold
    single: Any = None                   # (score, draws, mask) by the single validation part
    pool_targets: list[np.ndarray] = field(default_factory=list)
    pool_times: list[np.ndarray] = field(default_factory=list)
    pool_temps: list[np.ndarray] = field(default_factory=list)   # temperature of every row
    train_parts: list[Part] = field(default_factory=list)  # what the kept model was fitted on
    n_select: int = 0   # the kept model's structural parameter count: what ties prefer fewer of
    parameters: Any = None   # (table, covariance) of the kept model (thermonet.api.parameters)
    #: every signal the family reads, per pool run (the band's signal: thermonet.scoring.band)
    pool_signals: dict[str, list[np.ndarray]] = field(default_factory=dict)


def _verdicts(num: np.ndarray, den: np.ndarray) -> tuple[list[Verdict], np.ndarray, np.ndarray]:
    ratio, boot, iv = ratio_interval(num, den, draws(num.shape[0]))
    return ([Verdict(float(ratio[j]), float(iv[0, j]), float(iv[1, j]),
                     verdict_of(float(iv[0, j]), float(iv[1, j]))) for j in range(ratio.size)],
            ratio, boot)


def _offset_meaningful(targets: Target, axis: str) -> bool:
    """Whether the absolute offset of ``axis`` is an error (not an unknown constant).

    Where the target mode makes the true input known — a reference channel
    (``channel``), a static gyro's true rate 0 (``zero``), study 000's per-soak
    bias K0 — the offset is an error; ``at-t-ref`` axes (gravity's or the
    field's projection, a pressure) and scale factors have none
    (:mod:`thermonet.features.target`).
    """
    mode = targets.mode(axis)
    if mode == FOUR_POSITION:
        return axis.endswith(".bias")
    return mode in (CHANNEL, ZERO)


def judge_against_raw(f: Fitted, metrics: dict[str, dict[str, float]], p: Plan) -> None:
    """Validation and test verdicts against raw, the per-axis mask, the masked scores."""
    assert f.val is not None and f.test is not None
    res = f.result
    val, val_ratio, val_boot = _verdicts(f.val.ss_comp, f.val.ss_raw)
    test, test_ratio, test_boot = _verdicts(f.test.ss_comp, f.test.ss_raw)
    single = np.array([v.verdict == "better" for v in val])   # the single-part rule's mask
    mask = single if f.cv_mask is None else np.array(f.cv_mask)   # out of fold where it ran
    f.single = (*masked_scores(val_ratio, val_boot, single), single.tolist())
    res.val_score, draws_ = masked_scores(val_ratio, val_boot, mask)
    q = [2.5, 97.5]
    lo_hi = np.nanpercentile(draws_, q) if np.isfinite(draws_).any() else [math.nan] * 2
    res.val_interval = (float(lo_hi[0]), float(lo_hi[1]))
    res.test_score = float(np.mean(np.where(mask, test_ratio, 1.0)))
    f.val_draws = draws_
    sr, sc = f.test.score_raw, f.test.score_comp
    orw, ocp = f.test.offset_raw, f.test.offset_comp
    for j, axis in enumerate(p.outputs):
        meaningful = _offset_meaningful(p.targets, axis)
        res.axes[axis] = AxisResult(
            score_raw=float(sr[j]), score_comp=float(sc[j]), test=test[j], val=val[j],
            compensate=bool(mask[j]), offset_raw=float(orw[j]) if meaningful else None,
            offset_comp=float(ocp[j]) if meaningful else None, metrics=metrics[axis])


# ---------------------------------------------------------------------------------- report
def choose_and_judge(fitted: dict[str, Fitted], result: ComparisonResult, p: Plan) -> None:
    """Choice with ties, verdicts against the baseline, warnings about the chosen model."""
    ok = {k: f for k, f in fitted.items() if f.result.ok and f.val_draws is not None}
    cv = {k: f for k, f in ok.items() if f.oof is not None}
    if p.folds is not None and cv:
        first = next(iter(cv.values()))
        temps = next((f.pool_temps for f in cv.values() if f.pool_temps), None)
        sel = select(p.folds, first.pool_targets, first.pool_times,
                     {k: f.oof for k, f in cv.items()}, p.outputs, baseline=p.cfg.baseline,
                     temperatures=temps, gate=p.cfg.selection.gate)
        chosen, tied, why = sel.chosen, sel.tied, sel.reason
        result.selection = sel.record
        # what the single validation part would have chosen: how close the call was
        alt = choose({k: (f.single[0], f.single[1]) for k, f in ok.items()},
                     {k: f.n_select for k, f in ok.items()})
        result.selection["single_split"] = {
            "chosen": alt[0], "reason": alt[2],
            "compensate": {k: dict(zip(p.outputs, f.single[2], strict=True))
                           for k, f in ok.items()}}
        if alt[0] != chosen:
            result.warn(f"the split's single validation part would have chosen "
                        f"{alt[0] or 'nothing'} instead of {chosen or 'nothing'}: the call rests "
                        "on the cross-validation (see 'How the model was chosen')")
        for k, f in cv.items():
            if f.oof.failed is not None:
                result.warn(f"{k}: not a candidate: {f.oof.failed}")
        if p.cfg.selection.per_axis is not False and len(cv) >= 2:
            shipped = per_axis_choice(sel, cv, p, temps)
            # the same family on every axis as the whole-recording rule: its sentence and tie
            # stand (the per-axis table is in the record either way)
            if shipped is not None and shipped[0] != chosen:
                result.selection["whole_recording"] = {"chosen": chosen, "reason": why,
                                                       "tie": tied}
                chosen, tied, why = shipped
    else:
        scores = {k: (f.result.val_score, f.val_draws) for k, f in ok.items()
                  if f.val_draws is not None}
        chosen, tied, why = choose(scores, {k: f.n_select for k, f in ok.items()})
        result.selection = {"method": "single validation part", "note": p.fold_note}
        base = p.cfg.baseline
        if p.cfg.selection.gate and base in ok and chosen not in (None, base):
            # no folds: nothing can be shown to beat the baseline everywhere (the gate)
            result.selection["gate"] = (f"the single validation part would have chosen "
                                        f"{chosen}; without cross-validation folds nothing "
                                        f"can beat the baseline everywhere: {base} stays")
            chosen, tied, why = base, [], f"{base}: {result.selection['gate']}"
    result.chosen, result.chosen_reason, result.tie = chosen, why, tied
    if tied:
        result.warn(why)
    _judge_against_baseline(ok, p)
    if chosen == PER_AXIS:
        result.families[PER_AXIS] = per_axis_result(result, p, ok)
    if chosen is None:
        return
    _warn_about_chosen(result, chosen)
    for line in implausible_notes(ok, chosen, result.selection):
        result.warn(line)


def implausible_notes(ok: dict[str, Fitted], chosen: str, selection: Any) -> list[str]:
    """The shipped model's parameters whose constants are implausible (a Lorentz's width far
    beyond the data: :func:`~thermonet.training.parameters.implausible_lorentz`), one line
    per axis: every family's table carries the note, only the shipped one warns."""
    parts: dict[str, set[str] | None] = {chosen: None}
    if chosen == PER_AXIS:      # each axis from the family that owns it (None: left raw)
        owners = (selection or {}).get("per_axis", {}).get("chosen", {})
        owned: dict[str, set[str]] = {}
        for axis, fam in owners.items():
            if fam is not None:
                owned.setdefault(str(fam), set()).add(axis)
        parts = {**owned}
    lines = []
    for fam, axes in parts.items():
        f = ok.get(fam)
        if f is None or f.parameters is None:
            continue
        seen: set[str] = set()
        for row in f.parameters[0]:
            axis, note = row.get("axis", ""), str(row.get("note", ""))
            if note.startswith("implausible") and axis not in seen and \
                    (axes is None or axis in axes):
                seen.add(axis)
                lines.append(f"{fam} on {axis}: {note.split(';')[0]}")
    return lines


def _judge_against_baseline(ok: dict[str, Fitted], p: Plan) -> None:
    """Each family's verdict against the baseline on the test data, per axis, and its
    binned peak-to-peak as a ratio of the baseline's."""
    base = ok.get(p.cfg.baseline or "")
    if base is not None and base.test is not None:
        for f in ok.values():
            assert f.test is not None
            vs, _, _ = _verdicts(f.test.ss_comp, base.test.ss_comp)
            for j, axis in enumerate(p.outputs):
                ax = f.result.axes[axis]
                ax.vs_baseline = vs[j]
                b = base.result.axes[axis].metrics.get("pp_comp", math.nan)
                ax.metrics["pp_ratio_vs_baseline"] = (
                    ax.metrics.get("pp_comp", math.nan) / b if b > 0 else math.nan)


def _warn_about_chosen(result: ComparisonResult, chosen: str) -> None:
    """The chosen model's axes left uncompensated, worse than raw, or no better on test."""
    fam = result.families[chosen]
    for axis, ax in fam.axes.items():
        if not ax.compensate:
            result.uncompensated_axes.append(axis)
            result.warn(f"{axis}: left uncompensated by the chosen model {chosen} (drift 0 on "
                        f"this axis): {_left_raw_why(result, chosen, axis, ax)}")
        elif ax.test.verdict == "worse":
            result.warn(f"{axis}: the chosen model {chosen} is worse than raw on the held-out "
                        f"test data (score ratio {ax.test.ratio:.3g}, 95 % interval "
                        f"{ax.test.low:.3g} … {ax.test.high:.3g}); the drift may depend on "
                        "more than temperature (thermal history, hysteresis)")
        elif ax.test.verdict == "indistinguishable":
            result.warn(f"{axis}: compensated by {chosen}, but on the held-out test data it is "
                        f"the same as raw (score ratio {ax.test.ratio:.3g}, 95 % interval "
                        f"{ax.test.low:.3g} … {ax.test.high:.3g}): the out-of-fold gain did not "
                        "show on the test part")
    if not fam.compensate_in_model and result.uncompensated_axes:
        result.warn(f"the model file of {chosen} does not carry the per-axis mask yet; export "
                    f"it with care: {', '.join(result.uncompensated_axes)} should stay "
                    "uncompensated")


def _left_raw_why(result: ComparisonResult, chosen: str, axis: str, ax: AxisResult) -> str:
    """Why the chosen model leaves ``axis`` raw, by the rule that decided it: the per-axis
    rule's sentence, the out-of-fold mask (its score, or its binned peak-to-peak guard), or
    the single validation part's verdict."""
    sel = result.selection or {}
    if chosen == PER_AXIS and (rule := sel.get("per_axis", {}).get("rule", {}).get(axis)):
        return f"per-axis rule: {rule}"
    rec = sel.get("candidates", {}).get(chosen, {}).get("axes", {}).get(axis)
    if rec is None:
        return (f"it does not beat the raw output on the validation data (score ratio "
                f"{ax.val.ratio:.3g}, interval {ax.val.low:.3g} … {ax.val.high:.3g})")
    if rec.get("pp_guard") is False:
        return (f"its out-of-fold residual has a larger binned peak-to-peak than raw's "
                f"({rec['pp_ratio']:.3g}x; score ratio {rec['own_ratio']:.3g} of raw)")
    lo, hi = rec["own_interval"]
    return (f"it does not beat the raw output out of fold by one standard error (score ratio "
            f"{rec['own_ratio']:.3g}, interval {lo:.3g} … {hi:.3g})")


def per_axis_choice(sel: Any, cv: dict[str, Fitted], p: Plan,
                    temps: Any) -> tuple[str | None, list[str], str] | None:
    """The per-axis choice as ``(chosen, tied, sentence)``: a family's label where every
    compensated axis chose it, :data:`PER_AXIS` where the axes chose several, None where the
    per-axis models cannot be shipped as one (the whole-recording choice then stands).

    Candidates whose models cannot be combined with others (a recurrent family's state) are
    left out of the per-axis choice when they would share the artifact with another
    candidate, and the choice is made again without them (said in the record)."""
    from ..models.composite import composable  # torch boundary (pyproject.toml): loads torch

    if "per_axis" not in sel.record:     # no choice was made at all (no common window)
        return None
    owners = sel.per_axis
    labels = sorted({v for v in owners.values() if v is not None}, key=list(cv).index)
    if len(labels) > 1:
        why = composable([cv[k].model for k in labels])
        if why:
            solo = {k: f for k, f in cv.items() if composable([f.model]) is None}
            again = select(p.folds, next(iter(cv.values())).pool_targets,
                           next(iter(cv.values())).pool_times, {k: f.oof for k, f in solo.items()},
                           p.outputs, baseline=p.cfg.baseline, temperatures=temps,
                           gate=p.cfg.selection.gate)
            owners = again.per_axis
            labels = sorted({v for v in owners.values() if v is not None}, key=list(cv).index)
            sel.record["per_axis"] = {**again.record["per_axis"],
                                      "note": f"chosen again without what cannot be combined "
                                              f"({why})"}
            if len(labels) > 1 and composable([cv[k].model for k in labels]):
                return None
    sel.record["per_axis"]["candidates"] = labels
    if not labels:
        return None, [], ("do no harm: no candidate beats the raw output out of fold on any "
                          "axis (per-axis choice)")
    rules = sel.record["per_axis"]["rule"]
    sentence = "; ".join(f"{a}: {rules[a]}" for a in p.outputs)
    if len(labels) == 1:
        k = labels[0]
        mask = [owners[a] == k for a in p.outputs]
        if mask == list(cv[k].result.axes[a].compensate for a in p.outputs):
            return k, [], f"every compensated axis chose {k} (per-axis rule: {sentence})"
    return PER_AXIS, [], f"each axis its own model (per-axis rule: {sentence})"


def per_axis_result(result: ComparisonResult, p: Plan,
                    fitted: dict[str, Fitted] | None = None) -> FamilyResult:
    """The shipped per-axis model as one family of results.json: per axis the owning
    candidate's held-out record (its drift is that candidate's exactly), and on an axis left
    raw the raw output's own (score ratio 1: the shipped drift is exactly 0 there).  Its
    ``val_score`` is the families' measure (:func:`_per_axis_val`)."""
    import copy

    owners: dict[str, str | None] = result.selection["per_axis"]["chosen"]
    labels: list[str] = result.selection["per_axis"]["candidates"]
    fams = {k: result.families[k] for k in labels}
    axes: dict[str, AxisResult] = {}
    for a in p.outputs:
        k = owners[a]
        if k is not None:
            axes[a] = copy.deepcopy(fams[k].axes[a])
            axes[a].compensate = True
            continue
        src = copy.deepcopy(next(iter(fams.values())).axes[a])
        one = Verdict(1.0, 1.0, 1.0, "indistinguishable")
        src.test, src.val, src.compensate, src.vs_baseline = one, one, False, None
        src.score_comp, src.offset_comp = src.score_raw, src.offset_raw
        src.metrics = {m: (src.metrics.get(m[:-5] + "_raw", v) if m.endswith("_comp") else v)
                       for m, v in src.metrics.items() if m != "drift_error_rms"}
        axes[a] = src
    first = next(iter(fams.values()))
    inputs: list[str] = []
    for f in fams.values():
        inputs += [i for i in f.inputs if i not in inputs]
    test = [axes[a].test.ratio if axes[a].compensate else 1.0 for a in p.outputs]
    val_score, val_interval = _per_axis_val(axes, owners, p.outputs, fitted or {})
    return FamilyResult(
        label=PER_AXIS, family=PER_AXIS, inputs=inputs,
        params={"axes": dict(owners)}, train_on=first.train_on,
        fit_seconds=float(sum(f.fit_seconds for f in fams.values())),
        n_params=int(sum(f.n_params for f in fams.values())),
        val_score=val_score, val_interval=val_interval,
        test_score=float(np.mean(test)), compensate_in_model=True,
        outside_trained_range={s: max(f.outside_trained_range.get(s, 0.0)
                                      for f in fams.values())
                               for f0 in fams.values() for s in f0.outside_trained_range},
        axes=axes, tuned={k: dict(f.tuned) for k, f in fams.items()})


def _per_axis_val(axes: dict[str, AxisResult], owners: dict[str, str | None],
                  outputs: list[str], fitted: dict[str, Fitted]
                  ) -> tuple[float, tuple[float, float]]:
    """The per-axis model's validation score, the measure of every family's ``val_score``
    (:func:`judge_against_raw`): the mean over axes of the validation part's ratio, the
    owner's on each axis it compensates, 1 on an axis left raw; its 95 % interval from the
    owners' validation block sums drawn together (paired, as a family's axes are), where the
    owners share the validation blocks (NaN otherwise).  (It was the mean of the out-of-fold
    ratios on the windows every candidate was judged on: another quantity, 1.32 beside
    families at 0.70.)"""
    point = float(np.mean([axes[a].val.ratio if owners[a] is not None else 1.0
                           for a in outputs]))
    nan = (math.nan, math.nan)
    vals = {a: fitted[o].val for a, o in owners.items() if o is not None and o in fitted}
    shapes = {None if v is None else v.ss_raw.shape for v in vals.values()}
    if len(vals) != sum(o is not None for o in owners.values()) or len(shapes) != 1 \
            or None in shapes:
        return point, nan
    ss_comp = np.ones(shapes.pop() or ())
    ss_raw = np.ones_like(ss_comp)
    for j, a in enumerate(outputs):
        v = vals.get(a)
        if v is not None:
            ss_comp[:, j], ss_raw[:, j] = v.ss_comp[:, j], v.ss_raw[:, j]
    _, ratio, boot = _verdicts(ss_comp, ss_raw)
    _, per_draw = masked_scores(ratio, boot, np.array([owners[a] is not None for a in outputs]))
    if not np.isfinite(per_draw).any():
        return point, nan
    lo, hi = np.nanpercentile(per_draw, [2.5, 97.5])
    return point, (float(lo), float(hi))


def extrapolation(fitted: dict[str, Fitted], result: ComparisonResult) -> None:
    fractions: dict[str, float] = {}
    ranges: dict[str, tuple[float, float]] = {}
    excursions: dict[str, float] = {}
    for f in fitted.values():
        if not f.result.ok:
            continue
        for sig, frac in f.result.outside_trained_range.items():
            fractions[sig] = max(fractions.get(sig, 0.0), frac)
            ranges.setdefault(sig, f.ranges[sig])
            excursions[sig] = max(excursions.get(sig, 0.0), f.excursion.get(sig, 0.0))
    result.data["outside_trained_range"] = fractions
    result.data["trained_range"] = {k: list(v) for k, v in ranges.items()}
    result.data["outside_trained_range_max"] = excursions
    for w in extrapolation_warnings(fractions, ranges, excursions):
        result.warn(w)
