"""The console's text of a comparison (:mod:`thermonet.workflows.compare`): the table of
``results.json`` that ``thermonet compare`` prints (:func:`format_table`) — family × axis,
scores, verdicts against raw and the baseline, the cross-validation block and the choice; a
whole-sensor comparison's own table (:func:`thermonet.workflows.sensor.format_sensor_table`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from ..reporting.report import ratio_text
from ..reporting.results import ComparisonResult, FamilyResult, Verdict, read_result
from ..scoring.gate import reason_groups
from .sensor import format_sensor_table
from .steps import Outcome

__all__ = ["format_table"]


_METRIC_COLS = ("pp_raw", "pp_comp", "drift_error_rms", "ppm_per_c_raw", "ppm_per_c_comp")


def _ratio_cell(v: Verdict | None) -> str:
    if v is None or not _finite(v.ratio):    # results.json: null
        return f"{'-':>22}"
    mark = {"better": "+", "worse": "!", "indistinguishable": "="}[v.verdict or
                                                                   "indistinguishable"]
    return f"{ratio_text(v.ratio):>6} [{ratio_text(v.low):>5},{ratio_text(v.high):>5}] {mark}"


def _finite(x: Any) -> bool:
    """A number results.json writes as one (a non-finite float is written ``null``)."""
    return isinstance(x, (int, float)) and math.isfinite(x)


def _fold_text(x: float | None, fmt: str = ".3g") -> str:
    """A score for the table; ``–`` where a fold had no window inside the trained domain."""
    return "–" if x is None or not math.isfinite(x) else format(x, fmt)


def _name_width(names: Any) -> int:
    """A name column's width: 14, or the longest name's (a long family name never shifts the
    columns after it)."""
    return max([14, *(len(str(n)) for n in names)])


def _selection_lines(sel: dict[str, Any], width: int = 14) -> list[str]:
    """The console's cross-validation block: each candidate's out-of-fold score, its folds and
    why the gate held it back (names ``width`` wide, or the longest candidate's)."""
    width = max(width, _name_width(sel["candidates"]))
    held_by: dict[str, str] = dict((sel.get("held_back") or {}).get("by_candidate") or {})
    lines: list[str] = []
    lines.append(f"selection: {sel.get('kind')}, {sel.get('folds')} folds, purge "
                 f"{sel.get('purge_s', 0):.0f} s, score windows {sel.get('window_s', 0):.0f} s "
                 "(out-of-fold low-frequency residual / raw, [95 % interval], per fold)")
    if sel.get("note"):
        lines.append(f"  folds: {sel['note']}")
    for name, c in sel["candidates"].items():
        if c.get("status") != "ok":
            lines.append(f"  {name:<{width}} not a candidate: {c.get('reason')}")
            continue
        lo, hi = c["interval"]
        folds = " ".join(_fold_text(x) for x in c["fold_scores"])
        why = c.get("not_eligible")
        held = ("  (held back, below)" if why and why == held_by.get(name)
                else f"  ({why})" if why else "")
        lines.append(f"  {name:<{width}} {_fold_text(c['score'], '.4g')} "
                     f"[{_fold_text(lo, '.4g')}, {_fold_text(hi, '.4g')}]  folds {folds}{held}")
    groups = reason_groups(held_by)
    if not groups and sel.get("held_back"):     # a results.json written before by_candidate
        groups[sel["held_back"]["why"]] = sorted(sel["held_back"]["candidates"])
    for why, names in groups.items():
        lines.append(f"  held back: {', '.join(names)}: {why}")
    return lines


def format_table(results: Outcome | Mapping[str, Any]) -> str:
    """The comparison as a text table, its model kind's (:data:`TABLES`): a bias comparison's,
    :func:`format_bias_table` (of the typed result, or of a ``results.json`` document read
    once), or the whole-sensor model's :func:`~thermonet.workflows.sensor.format_sensor_table`
    (its document, whose ``model`` names the kind; a bias comparison's names none)."""
    if isinstance(results, ComparisonResult):
        return format_bias_table(results)
    return TABLES[results.get("model", "bias")](results)


def format_bias_table(results: ComparisonResult | Mapping[str, Any]) -> str:
    """The comparison as a text table: family × axis, scores, verdicts, the ratio to the baseline.

    ``vs raw`` and ``vs baseline`` are offset-free score ratios on the test
    data with their 95 % bootstrap interval and verdict (+ better, ! worse,
    = indistinguishable); ``comp`` says whether the axis is compensated.
    """
    res = read_result(results)
    fams = res.families
    axes = list(res.units)
    cols = [c for c in _METRIC_COLS
            if any(c in a.metrics for f in fams.values()
                   for a in (f.axes[x] for x in axes if x in f.axes))]
    base = res.baseline
    sel = res.selection
    per_axis = sel.get("per_axis") or {}
    # the name columns as wide as the longest family (or candidate) and axis name
    nw = _name_width([*fams, *(sel.get("candidates") or {}),
                      *((per_axis.get("chosen") or {}).values())])
    aw = _name_width(axes)
    head = (f"{'family':<{nw}} {'axis':<{aw}} {'fit s':>6} {'params':>6} {'val':>6} {'comp':>4} "
            f"{'vs raw':>22} {'vs ' + (base or 'baseline'):>22} "
            + " ".join(f"{c:>12}" for c in cols))
    lines = [head, "-" * len(head)]
    for name, f in fams.items():
        if not f.ok:
            lines.append(f"{name:<{nw}} not fitted: {f.reason}")
            continue
        lines += _family_rows(name, f, axes, cols, nw, aw)
    lines.append("")
    if sel.get("candidates"):
        lines += _selection_lines(sel, nw)
    elif sel.get("note"):
        lines.append(f"selection: {sel['note']}")
    if per_axis.get("chosen") and res.chosen is not None and "whole_recording" in sel:
        lines.append("per axis (each axis its own model; the one-SE rule on that axis's paired "
                     "out-of-fold scores, the baseline as the floor):")
        for a, k in per_axis["chosen"].items():
            lines.append(f"  {a:<{aw}} {k or 'raw':<{nw}} {per_axis['rule'].get(a, '')}")
        whole = sel["whole_recording"]
        lines.append(f"chosen: {res.chosen} (one family for every axis would have "
                     f"been {whole.get('chosen') or 'none'}: {whole.get('reason', '')})")
    else:
        lines.append(f"chosen: {res.chosen or 'none'} — {res.chosen_reason}")
        owners = {k for k in (per_axis.get("chosen") or {}).values() if k}
        if res.chosen is not None and owners == {res.chosen}:
            lines.append(f"per axis: every compensated axis chose {res.chosen} on its "
                         "own too (the same rule, axis by axis)")
    if res.uncompensated_axes:
        lines.append(f"left uncompensated: {', '.join(res.uncompensated_axes)}")
    lines.append("scores: spread of the error about its mean on held-out data, family / raw "
                 "(< 1 better); [95 % block-bootstrap interval]")
    lines.append("units: " + ", ".join(f"{a} [{u}]" for a, u in res.units.items()))
    return "\n".join(lines)


def _family_rows(name: str, f: FamilyResult, axes: list[str], cols: list[str], nw: int,
                 aw: int) -> list[str]:
    """A fitted family's rows of the table, one per axis."""
    lines = []
    for i, a in enumerate(axes):
        m = f.axes[a]
        pre = (f"{name:<{nw}} {a:<{aw}} {f.fit_seconds:6.2f} {f.n_params:6d} "
               f"{f.val_score:6.3g} ") if i == 0 else \
            f"{'':<{nw}} {a:<{aw}} {'':>6} {'':>6} {'':>6} "
        raw_cell = None
        if not m.compensate and _finite(m.score_ratio):
            # the model file's drift is 0 here: the shipped output is raw (ratio 1)
            raw_cell = f"{'raw (fit ' + ratio_text(m.score_ratio) + ')':>22}"
        metrics = " ".join(f"{_or_nan(m.metrics.get(c)):12.4g}" for c in cols)
        lines.append(pre + f"{'yes' if m.compensate else 'no':>4} "
                     f"{raw_cell or _ratio_cell(m.test)} {_ratio_cell(m.vs_baseline)} "
                     + metrics)
    return lines


def _or_nan(x: Any) -> float:
    """A number of the table (``nan`` where results.json has null)."""
    return math.nan if x is None else x


#: The console's table per model kind, by results.json's ``model`` (a bias comparison's
#: results.json has none: ``bias``).
TABLES: dict[str, Callable[[Any], str]] = {"bias": format_bias_table,
                                           "sensor": format_sensor_table}
