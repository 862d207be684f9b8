"""``DIR/report.html``: one self-contained page per comparison, opened first.

The page needs nothing beside itself: inline CSS, no script, the plots
embedded as base64 PNG (``data:`` URIs).  Sections, in reading order:

1. the verdict — chosen family, why, axes left uncompensated;
2. warnings (the same sentences as ``results.json``'s ``"warnings"``);
3. the verdict table: one row per family, one cell per axis with the
   offset-free score ratio against raw, its 95 % block-bootstrap interval and
   the verdict, colour-coded (green better, red worse, grey
   indistinguishable), then the same against the baseline;
4. the data summary (runs, samples, duration, rate, temperature span, split);
5. the plots.

Every string taken from the results (family names, run ids, warnings) is
HTML-escaped.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..core.errors import counted
from ..core.fileio import atomic_write_text
from ..scoring.gate import reason_groups
from .results import ComparisonResult, Verdict, read_result

__all__ = ["render_report", "write_report", "VERDICT_COLOURS", "ratio_text"]

#: Cell background per verdict.
VERDICT_COLOURS = {"better": "#c8e6c9", "worse": "#ffcdd2", "indistinguishable": "#eeeeee",
                   "uncompensated": "#fff3c4"}

_CSS = """
body { font-family: system-ui, sans-serif; margin: 24px; color: #222; max-width: 1180px; }
h1 { font-size: 22px; margin-bottom: 4px; } h2 { font-size: 17px; margin-top: 28px; }
table { border-collapse: collapse; margin: 8px 0; font-size: 13px; max-width: 100%; }
th, td { border: 1px solid #bbb; padding: 4px 7px; text-align: left; vertical-align: top;
         overflow-wrap: anywhere; }
th { background: #f0f0f0; }
.chosen { font-size: 16px; padding: 10px; background: #e8f0fe; border-left: 5px solid #1f77b4; }
.warn { background: #fff3c4; border-left: 5px solid #e6ab02; padding: 6px 10px; margin: 4px 0; }
.none { color: #666; }
.small { font-size: 12px; color: #555; }
img { max-width: 100%; border: 1px solid #ddd; margin: 6px 0; }
"""


def _e(x: object) -> str:
    return html.escape(str(x), quote=True)


def _num(x: Any, fmt: str = ".3g") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return format(x, fmt) if isinstance(x, (int, float)) else _e(x)


def ratio_text(x: float) -> str:
    """A ratio to 3 significant digits, or as many more (up to 7) as it takes not to print a
    ratio that differs from 1 as "1": an interval [0.985, 0.99995] must not read [0.985, 1]
    beside a "better" verdict.  The console's table and this page print ratios alike."""
    for digits in range(3, 8):
        text = f"{x:.{digits}g}"
        if not math.isfinite(x) or x == 1.0 or float(text) != 1.0:
            return text
    return text


def _finite(x: Any) -> bool:
    """A number results.json writes as one (a non-finite float is written ``null``)."""
    return isinstance(x, (int, float)) and math.isfinite(x)


def _ratio(x: Any) -> str:
    """A ratio cell's number (:func:`ratio_text`); ``–`` where there is none."""
    if not isinstance(x, (int, float)) or not math.isfinite(x):
        return "–"
    return ratio_text(float(x))


def _cell(v: Verdict | None, compensate: bool | None = None) -> str:
    if v is None or not _finite(v.ratio):     # results.json: null
        return "<td class='none'>–</td>"
    verdict, lo, hi = v.verdict, v.low, v.high
    if compensate is False:
        # what the model file holds: drift exactly 0 on this axis, so the shipped output is
        # the raw output (ratio 1); the fit's own figure is what masking it avoided
        return (f"<td style='background:{VERDICT_COLOURS.get('indistinguishable', '#ffffff')}'>"
                f"<b>raw</b> (drift 0)<br>1<br><i>left uncompensated; the fit was "
                f"{_e(verdict)} {_ratio(v.ratio)}</i></td>")
    colour = VERDICT_COLOURS.get(verdict, "#ffffff")
    return (f"<td style='background:{colour}'><b>{_e(verdict)}</b><br>{_ratio(v.ratio)} "
            f"[{_ratio(lo)}, {_ratio(hi)}]</td>")


#: Axes one verdict table holds side by side: more (a six-axis IMU) are stacked as one table
#: per sensor (gyro, acc …), so that the page reads at 1,280 px without scrolling sideways.
MAX_TABLE_AXES = 3


def _sensor_groups(axes: list[str]) -> list[list[str]]:
    """The axes in groups of one sensor each (``gyro_x`` → ``gyro``; ``acc_x.bias`` → ``acc``),
    in order, each at most :data:`MAX_TABLE_AXES` wide; all together where they fit."""
    if len(axes) <= MAX_TABLE_AXES:
        return [axes]
    groups: dict[str, list[str]] = {}
    for a in axes:
        groups.setdefault(a.split(".")[0].split("_")[0], []).append(a)
    return [g[i:i + MAX_TABLE_AXES] for g in groups.values()
            for i in range(0, len(g), MAX_TABLE_AXES)]


def _verdict_table(res: ComparisonResult) -> str:
    groups = _sensor_groups(list(res.units))
    return "".join(_verdict_table_of(res, axes) for axes in groups)


def _verdict_table_of(res: ComparisonResult, axes: list[str]) -> str:
    base = res.baseline
    head = "".join(f"<th>{_e(a)}<br>vs raw</th>" for a in axes)
    if base:
        head += "".join(f"<th>{_e(a)}<br>vs {_e(base)}</th>" for a in axes)
    rows = []
    for name, f in res.families.items():
        label = _e(name) + (" <b>(chosen)</b>" if name == res.chosen else "") + \
            (" <i>(baseline)</i>" if name == base else "")
        if not f.ok:
            span = len(axes) * (2 if base else 1) + 2
            rows.append(f"<tr><td>{label}</td><td colspan='{span}' class='none'>not fitted: "
                        f"{_e(f.reason)}</td></tr>")
            continue
        cells = [_cell(f.axes[a].test, f.axes[a].compensate) for a in axes]
        if base:
            cells += [_cell(f.axes[a].vs_baseline) for a in axes]
        rows.append(f"<tr><td>{label}</td><td>{_num(f.n_params, 'd')}</td>"
                    f"<td>{_num(f.val_score)}</td>{''.join(cells)}</tr>")
    return ("<table><tr><th>family</th><th>params</th><th>validation score</th>" + head +
            "</tr>" + "".join(rows) + "</table>")


def _scores_table(res: ComparisonResult) -> str:
    """Absolute offset-free scores and offsets per axis, in the axis' unit."""
    rows = []
    for name, f in res.families.items():
        if not f.ok:
            continue
        for a, m in f.axes.items():
            unit = res.units.get(a, "")
            off = (f"{_num(m.offset_raw)} → {_num(m.offset_comp)}"
                   if m.offset_raw is not None else "<span class='none'>not meaningful</span>")
            rows.append(f"<tr><td>{_e(name)}</td><td>{_e(a)} [{_e(unit)}]</td>"
                        f"<td>{_num(m.score_raw)} → {_num(m.score_comp)}</td>"
                        f"<td>{_num(m.metrics.get('pp_raw'))} → {_num(m.metrics.get('pp_comp'))}"
                        f"</td><td>{off}</td><td>{'yes' if m.compensate else 'no'}</td></tr>")
    return ("<table><tr><th>family</th><th>axis</th><th>score raw → compensated</th>"
            "<th>pp of binned means raw → compensated</th><th>offset raw → compensated</th>"
            "<th>compensated</th></tr>" + "".join(rows) + "</table>")


def _selection_table(res: ComparisonResult) -> str:
    """The out-of-fold scores the choice rests on (thermonet.scoring.selection), per candidate."""
    sel = res.selection
    if not sel.get("candidates"):
        return f"<p class='small'>{_e(sel.get('note') or 'single validation part')}</p>"
    held = (sel.get("held_back") or {}).get("by_candidate") or {}
    rows = []
    for name, c in sel["candidates"].items():
        if c.get("status") != "ok":
            rows.append(f"<tr><td>{_e(name)}</td><td colspan='7'>not a candidate: "
                        f"{_e(c.get('reason'))}</td></tr>")
            continue
        lo, hi = c.get("interval", [None, None])
        left = max(c.get("left_out_fraction") or [0.0])
        raw_axes = [a for a, v in c.get("axes", {}).items() if not v.get("compensate")]
        why = c.get("not_eligible") or ""
        rows.append(f"<tr><td>{_e(name)}</td><td>{_e(c.get('n_params'))}</td>"
                    f"<td>{_num(c.get('score'), '.4g')} [{_num(lo, '.4g')}, {_num(hi, '.4g')}]"
                    f"</td><td>{_e(' '.join(_num(x) for x in c.get('fold_scores', [])))}</td>"
                    f"<td>{_num(c.get('diff_to_best'), '.2g')} ± {_num(c.get('se_of_diff'), '.2g')}"
                    f"</td><td>{_num(100 * left, '.2g')} %</td>"
                    f"<td>{_e(', '.join(raw_axes) or '—')}</td>"
                    f"<td>{_e('held back (below)' if why and why == held.get(name) else why or '—')}"
                    "</td></tr>")
    held_html = "".join(f"<li><b>{_e(', '.join(names))}</b>: {_e(why)}</li>"
                        for why, names in reason_groups(held).items())
    return (f"<p class='small'>{_e(sel.get('kind', ''))}, {_e(sel.get('folds', ''))} folds, "
            f"purge {_num(sel.get('purge_s'))} s, score windows {_num(sel.get('window_s'))} s: "
            "the low-frequency residual out of fold over raw on the same windows (&lt; 1 better), "
            "paired across candidates. " + _e(sel.get("rule", ""))
            + (f" Folds: {_e(sel['note'])}." if sel.get("note") else "") + "</p>"
            + (f"<p class='small'>The gate: {_e(sel['gate'])}</p>"
               if isinstance(sel.get("gate"), str) else "")
            + "<table><tr><th>candidate</th><th>params</th><th>out-of-fold score [95 %]</th>"
            "<th>per fold</th><th>paired difference to the best ± SE</th>"
            "<th>most left out of a fold (outside its trained domain)</th>"
            "<th>left raw</th><th>not eligible (why)</th></tr>" + "".join(rows) + "</table>"
            + (f"<p class='small'>Held back before any score was compared:</p><ul "
               f"class='small'>{held_html}</ul>" if held_html else ""))


def _per_axis_table(res: ComparisonResult) -> str:
    """Each axis its own model: per axis the candidate chosen and the rule's sentence."""
    sel = res.selection
    pa = sel.get("per_axis") or {}
    if not pa.get("chosen"):
        return ""
    whole = sel.get("whole_recording") or {}
    rows = "".join(f"<tr><td>{_e(a)}</td><td><b>{_e(k or 'raw')}</b></td>"
                   f"<td>{_e((pa.get('rule') or {}).get(a, ''))}</td></tr>"
                   for a, k in pa["chosen"].items())
    note = (f" One family for every axis would have been {_e(whole.get('chosen') or 'none')}"
            f" ({_e(whole.get('reason', ''))})." if whole else "")
    extra = f" {_e(pa['note'])}." if pa.get("note") else ""
    return ("<h3>Each axis its own model</h3><p class='small'>The same one-SE rule on each "
            "axis's paired out-of-fold scores; the baseline is the floor on every axis it "
            "compensates; an axis is compensated only where the residual's binned "
            f"peak-to-peak does not grow out of fold.{note}{extra}</p>"
            "<table><tr><th>axis</th><th>model</th><th>rule</th></tr>" + rows + "</table>")


def _band_table(res: ComparisonResult) -> str:
    """The shipped model's residual-drift band per axis (thermonet.scoring.band)."""
    band = res.band or {}
    if band.get("status") != "ok":
        shipped = res.families.get(res.chosen or "")
        note = ((shipped.band if shipped is not None else None) or {}).get("reason")
        return f"<p class='none'>no band{': ' + _e(note) if note else ''}</p>"
    units = res.units
    disp = band.get("display") or {}
    filt = band.get("filter") or {}
    rows = []
    per = "/°C" if band.get("signal") in ("temperature", "temperature_c") else \
        f" per {band.get('signal', 'signal')} unit"
    for a, t in band["axes"].items():
        bins = ", ".join(f"[{_num(lo)}, {_num(hi)}]: {_num(h)}" for lo, hi, h in
                         zip(t["edges"][:-1], t["edges"][1:], t["half_width"], strict=True))
        d = disp.get(a)
        shown = (", ".join(_num(h) for h in d["half_width"]) + f" {_e(d['unit'])}") if d else "-"
        f = filt.get(a) or {}
        rows.append(f"<tr><td>{_e(a)}</td><td>{_e(units.get(a, ''))}</td><td>{_e(bins)}</td>"
                    f"<td>{shown}</td><td>{_num(t['growth_below'])} / "
                    f"{_num(t['growth_above'])}</td>"
                    f"<td>{_num(f.get('bound'))} {_e(units.get(a, ''))}</td>"
                    f"<td>{_num(f.get('rate'))} {_e(units.get(a, '') + per)}</td></tr>")
    return (f"<p class='small'>{_e(band.get('meaning', ''))}. From the out-of-fold residuals "
            f"of the folds that chose {_e(band.get('model', ''))}; a function of "
            f"{_e(band.get('signal', ''))}, per bin the conformal quantile, growing linearly "
            "past the trained range (configs/README.md, 'The residual-drift band').</p>"
            + (f"<p class='small'><b>Where it holds:</b> {_e(held)}.</p>" if (held := (
                band.get("holds_for") or {}).get("meaning")) else "")
            + "<table><tr><th>axis</th><th>unit</th><th>bin: half-width</th><th>half-width "
            "(°/h or mg)</th><th>growth below / above (per signal unit)</th><th>bias bound"
            "</th><th>bias rate</th></tr>" + "".join(rows) + "</table>")


def tuned_text(tuned: dict[str, Any]) -> str:
    """A family's tuned hyper-parameters in one line: ``degree=2 (of degree=1 0.061,
    degree=2 0.0034, …)``; "" when it chose none."""
    def value(v: Any) -> str:
        if isinstance(v, list):             # per axis (the RBF's ridge)
            return "[" + " ".join(value(x) for x in v) + "]"
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    own = ", ".join(f"{k}={value(v)}" for k, v in tuned.items()
                    if k != "tuning" and not isinstance(v, dict))
    grid = (tuned.get("tuning") or {}).get("grid") or {}
    scores = ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} failed"
                       for k, v in grid.items())
    return own + (f" (out-of-fold score: {scores})" if scores else "")


def _tuning_list(res: ComparisonResult) -> str:
    """Per family, the hyper-parameters chosen on the training folds and the rule's sentence."""
    items = []
    for name, f in res.families.items():
        tuned = f.tuned
        rule = (tuned.get("tuning") or {}).get("rule", "")
        # the per-axis model's entry is {member: its tuned values}: each member that was tuned
        members = "; ".join(f"{k}: {t}" for k, v in tuned.items() if k != "tuning"
                            and isinstance(v, dict)
                            and (t := tuned_text({n: x for n, x in v.items() if n != "tuning"})))
        text = "; ".join(t for t in (tuned_text(tuned), members) if t)
        if not text and not rule:
            continue       # nothing was tuned: no line saying nothing
        items.append(f"<li><b>{_e(name)}</b>: {_e(text or 'not tuned')}"
                     + (f" — {_e(rule)}" if rule else "") + "</li>")
    if not items:
        return ""
    return ("<p class='small'>Hyper-parameters chosen by cross-validation on the training data "
            "(configs/README.md, \"Tuning\"):</p><ul class='small'>" + "".join(items) + "</ul>")


def _duration(seconds: float) -> str:
    if seconds >= 7200.0:
        return f"{seconds / 3600.0:.3g} h"
    if seconds >= 120.0:
        return f"{seconds / 60.0:.3g} min"
    return f"{seconds:.3g} s"


def _fold(fold: dict[str, Any]) -> str:
    def names(v: Any) -> str:
        return ", ".join(map(str, v)) if isinstance(v, list) else str(v)

    return "; ".join(f"{k}: {names(v)}" for k, v in fold.items())


def _data_table(res: ComparisonResult) -> str:
    rows = []
    for r in res.data.get("runs", []):
        span = (f"{_num(r.get('temperature_min_c'), '.1f')} … "
                f"{_num(r.get('temperature_max_c'), '.1f')} °C"
                if r.get("temperature_min_c") is not None else "no thermometer (proxy)")
        rows.append(f"<tr><td>{_e(r['run_id'])}</td><td>{_num(r['samples'], 'd')}</td>"
                    f"<td>{_duration(float(r['duration_s']))}</td><td>{_num(r['rate_hz'])} Hz</td>"
                    f"<td>{span}</td></tr>")
    outside = res.data.get("outside_trained_range", {})
    ext = ", ".join(f"{_e(k)}: {v:.0%}" for k, v in outside.items() if v is not None) or "–"
    split = res.split
    folds = "<br>".join(_e(_fold(f)) for f in split.get("folds", []))
    st = res.data.get("streamed")
    streamed = "" if not isinstance(st, dict) else (
        f"streamed: {_num(st.get('samples'), 'd')} samples read in chunks of "
        f"{_num(st.get('chunk_rows'), 'd')} rows and reduced to "
        f"{_num(st.get('rows'), 'd')} window means of {_num(st.get('window_s'))} s (the fit's "
        "own windows; scores over the samples from each window's count and sum of squares; "
        "temperatures above are window means)<br>")
    return ("<table><tr><th>run</th><th>samples</th><th>duration</th><th>rate</th>"
            "<th>temperature</th></tr>" + "".join(rows) + "</table>"
            f"<p class='small'>{streamed}split: {_e(split.get('strategy'))}<br>{folds}<br>"
            f"test samples outside the trained range: {ext}</p>")


def _provenance_html(prov: Any) -> str:
    """What the comparison actually used: data files with their SHA-256 (or the simulator's
    preset), tracking, the options given — those left at None (not given) are not listed
    (results.json ``provenance``)."""
    if not isinstance(prov, dict) or not isinstance(prov.get("data"), dict):
        return ""
    src = prov["data"]
    if src.get("kind") == "files":
        files = list(src.get("files") or []) + ([src["mapping"]] if src.get("mapping") else [])
        data = "data files: " + "; ".join(f"{_e(f.get('path'))} (sha256 {_e(f.get('sha256'))})"
                                          for f in files if isinstance(f, dict))
        if isinstance(src.get("skipped_rows"), int) and src["skipped_rows"] > 0:
            data += (f"; {counted(src['skipped_rows'], 'malformed row')} skipped "
                     "(the mapping's malformed_rows: skip)")
    elif src.get("kind") == "simulated":
        runs = src.get("runs")
        count = counted(runs, "run") if isinstance(runs, int) else f"{_e(runs)} runs"
        data = (f"data simulated: preset {_e(src.get('preset'))}, {count}, "
                f"seed {_e(src.get('seed'))}")
    else:
        data = f"data passed by the caller (device {_e(src.get('device'))})"
    t = prov.get("tracking") or {}
    track = f"MLflow at {_e(t.get('uri'))}" if t.get("enabled") else "off"
    # an option left at None was not given (the command's default applied)
    opts = ", ".join(f"{_e(k)}={_e(v)}" for k, v in (prov.get("options") or {}).items()
                     if v is not None)
    given = f"options as given: {opts}" if opts else "options: the defaults (none given)"
    return f"<p class='small'>{data}<br>tracking: {track}; {given}</p>"


def render_report(results: ComparisonResult | Mapping[str, Any],
                  plots: Sequence[Path] = ()) -> str:
    """The report page as one HTML string (plots read and embedded as base64 PNG), of the
    typed result, or of a ``results.json`` document read once (:func:`read_result`)."""
    res = read_result(results)
    chosen = res.chosen
    unc = res.uncompensated_axes
    boot = res.bootstrap
    shipped = res.families.get(chosen or "")
    worse = [a for a, m in (shipped.axes if shipped is not None else {}).items()
             if m.compensate and m.verdict == "worse"]
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>thermonet report — {_e(res.device)}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>thermonet comparison: {_e(res.device)}</h1>",
        f"<p class='small'>thermonet {_e(res.thermonet_version)}, "
        f"results schema {_e(res.schema)}, data hash "
        f"{_e(res.data_hash)}, target {_e(res.target)}</p>",
        _provenance_html(res.provenance),
        f"<div class='chosen'>Chosen: <b>{_e(chosen or 'none')}</b> — "
        f"{_e(res.chosen_reason)}"
        + (f"<br>Left uncompensated (drift 0): <b>{_e(', '.join(unc))}</b>" if unc else "")
        + (f"<br><span style='color:#b71c1c'>Worse than raw on the held-out test data: "
           f"<b>{_e(', '.join(worse))}</b></span>" if worse else "")
        + "</div>",
        "<h2>Warnings</h2>",
    ]
    warnings = res.warnings
    parts += [f"<div class='warn'>{_e(w)}</div>" for w in warnings] or \
        ["<p class='none'>none</p>"]
    parts += [
        "<h2>How the model was chosen (cross-validation on the training data)</h2>",
        _selection_table(res),
        _per_axis_table(res),
        _tuning_list(res),
        "<h2>Verdicts on the held-out test data</h2>",
        "<p class='small'>Score: the spread of the error about its mean on held-out data "
        "(the temperature-dependent error; offsets removed). Cells: score ratio family / raw "
        "(or / baseline) [" + _e(f"{boot.get('level', 0.95):.0%}") + " interval of a "
        + _e(boot.get("method", "block bootstrap")) + ", "
        + _e(boot.get("resamples", "")) + " resamples]; &lt; 1 is better. An axis is "
        "compensated only where the family beats raw out of fold (or on the validation data "
        "where cross-validation could not run).</p>",
        _verdict_table(res),
        "<h2>Scores and offsets (test data)</h2>", _scores_table(res),
        "<h2>How wrong the corrected output stays: the residual-drift band</h2>",
        _band_table(res),
        "<h2>Data</h2>", _data_table(res),
    ]
    if plots:
        parts.append("<h2>Plots (last fold's test data)</h2>")
    for p in plots:
        data = base64.b64encode(Path(p).read_bytes()).decode("ascii")
        parts.append(f"<div><img alt='{_e(Path(p).stem)}' src='data:image/png;base64,{data}'>"
                     "</div>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(path: str | Path, results: ComparisonResult | Mapping[str, Any],
                 plots: Sequence[Path] = ()) -> Path:
    """Write :func:`render_report` to ``path`` atomically; returns the path."""
    path = Path(path)
    atomic_write_text(path, render_report(results, plots))
    return path
