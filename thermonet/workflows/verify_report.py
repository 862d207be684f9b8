"""What ``thermonet verify`` writes beside its results.json: ``report.txt``
(:func:`format_verify_report`: one block per instance, the binned drift before → after per
axis, PASS/FAIL, warnings) and ``report.html`` (:func:`render_verify_html`: the same as a
table), both from the results document :func:`thermonet.workflows.verify.verify` builds.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from ..data.firmware import PX4_LETTER
from ..reporting.report import _CSS, VERDICT_COLOURS
from .verify_params import KIND_UNITS

__all__ = ["verdict_line", "format_verify_report", "render_verify_html", "trained_note"]


def _g3(x: float | None) -> str:
    return "nan" if x is None else f"{x:.3g}"


def _cut(x: float | None) -> str:
    return "nan" if x is None or math.isnan(x) else "inf" if math.isinf(x) else f"{x:.1f}"


def _axis_text(d: dict[str, Any], j: int) -> str:
    """``before->after (cut PASS|FAIL)`` of axis ``j``, with the non-finite samples named."""
    ok = d["passed"][j]
    text = (f"{_g3(d['pp_raw'][j])}->{_g3(d['pp_corrected'][j])} "
            f"({_cut(d['cut'][j])}x {'PASS' if ok else 'FAIL'}")
    bad = (d.get("nonfinite") or [0] * len(d["passed"]))[j]
    if bad:
        text += f": {bad} corrected samples NaN/inf"
    return text + ")"


def format_verify_report(doc: dict[str, Any]) -> str:
    """One block per instance: the binned drift before → after per axis, PASS/FAIL, warnings."""
    lim = doc["limits"]
    lines = [f"thermonet verify: {doc['params_file']} on {doc['log']} ({doc['autopilot']})",
             f"limits: an axis passes when the binned drift is cut at least "
             f"{lim['min_cut']:g}x, or is left below "
             + ", ".join(f"{v:g} {KIND_UNITS.get(k, '')} ({k})" for k, v in lim["floor"].items()),
             *([f"warning: {trained_note(doc)}"] if doc.get("trained_on") else []), ""]
    for name, d in doc["instances"].items():
        head = f"{name:<6} id {d['device_id']:<9}"
        if d["status"] != "judged":
            lines.append(f"{head} {d['status']}: {d['reason']}")
            lines += [f"       FAIL: {w}" for w in d.get("offset_failures") or []]
            continue
        axes = ", ".join(_axis_text(d, j) for j in range(len(d["passed"])))
        unit = KIND_UNITS.get(d["kind"], "")
        lines.append(f"{head} {_slot_name(doc['autopilot'], d)}: binned drift p-p [{unit}] "
                     f"{axes}")
        lines += [f"       FAIL: {w}" for w in d.get("offset_failures") or []]
        lines += [f"       warning: {w}" for w in d["warnings"]]
    lines += ["", verdict_line(doc)]
    return "\n".join(lines) + "\n"


def _slot_name(autopilot: str, d: dict[str, Any]) -> str:
    """The parameters applied to an instance, named as the file names them: PX4's ``TC_G0``,
    ArduPilot's ``INS_TCAL1`` (the slot is 0-based, ArduPilot's IMU numbers 1-based)."""
    if autopilot == "ardupilot":
        return f"INS_TCAL{d['slot'] + 1}"
    return f"TC_{PX4_LETTER.get(d['kind'], '?')}{d['slot']}"


def _unjudged(insts: dict[str, dict[str, Any]]) -> str:
    """The instances the file calibrates that the log could not judge, grouped by why:
    ``not judged: gyro0, gyro1 (why)``; "" where there are none."""
    why: dict[str, list[str]] = {}
    for n, d in insts.items():
        if d["status"] == "not judged":
            why.setdefault(str(d.get("reason") or "no reason given"), []).append(n)
    return "; ".join(f"{', '.join(names)} ({reason})" for reason, names in why.items())


def verdict_line(doc: dict[str, Any]) -> str:
    """The verdict, with what it covers: PASS names the instances it was judged on, those the
    file calibrates that the log could not judge (and why) and those the file leaves
    uncorrected (a file may calibrate some sensors only); FAIL says whether an axis failed
    or a calibration the file holds is not applied (its ENABLE is not 1)."""
    insts = doc["instances"]
    names = lambda status: [n for n, d in insts.items() if d["status"] == status]  # noqa: E731
    unjudged = _unjudged(insts)
    if not doc["passed"]:
        off = names("not applied")
        why = ["see the axes marked FAIL"] if any(
            not all(d.get("passed", [True])) or d.get("offset_failures")
            for d in insts.values()) else []
        if off:
            why.append(f"{', '.join(off)}: calibrated by the file but not applied (ENABLE is "
                       "not 1)")
        if unjudged:
            why.append(f"not judged: {unjudged}")
        return "FAIL: " + "; ".join(why)
    text = "PASS" + (" (on its own training log)" if doc.get("trained_on") else "")
    left = names("not covered")
    if left or unjudged:
        text += f" for {', '.join(names('judged'))}"
    if unjudged:
        text += f"; not judged: {unjudged}"
    if left:
        text += (f"; not covered by this file: {', '.join(left)} "
                 f"({'its' if len(left) == 1 else 'their'} drift is not corrected)")
    return text


def trained_note(doc: dict[str, Any]) -> str:
    """Why a verdict on the calibration's own log is no verdict on a new excursion."""
    return (f"this log is {doc['trained_on']}, which the parameters were fitted on (the "
            "results.json of the calibrate or learn run beside the file says so): a check on "
            "training data, not on a new warm-up — verify on another log")


def render_verify_html(doc: dict[str, Any]) -> str:
    """``DIR/report.html``: the verification table (every string HTML-escaped)."""
    import html

    rows = []
    for name, d in doc["instances"].items():
        if d["status"] != "judged":
            rows.append(f"<tr><td>{html.escape(name)}</td><td>{d['device_id']}</td>"
                        f"<td colspan=\"3\">{html.escape(d['status'])}: "
                        f"{html.escape(str(d['reason']))}"
                        + "".join(f"<br>FAIL: {html.escape(w)}"
                                  for w in d.get("offset_failures") or []) + "</td></tr>")
            continue
        for j, (b, a, c, ok) in enumerate(zip(d["pp_raw"], d["pp_corrected"], d["cut"],
                                              d["passed"], strict=True)):
            colour = VERDICT_COLOURS["better" if ok else "worse"]
            warn = "; ".join([*(d.get("offset_failures") or []), *d["warnings"]]) \
                if j == 0 else ""
            rows.append(f"<tr><td>{html.escape(name)}[{j}]</td><td>{d['device_id']}</td>"
                        f"<td>{_g3(b)} → {_g3(a)} {html.escape(KIND_UNITS.get(d['kind'], ''))}"
                        f"</td><td style=\"background:{colour}\">"
                        f"{_cut(c)}× {'PASS' if ok else 'FAIL'}</td>"
                        f"<td>{html.escape(warn)}</td></tr>")
    verdict = verdict_line(doc)
    if doc.get("trained_on"):
        verdict += f" — {trained_note(doc)}"
    return ("<!DOCTYPE html><html><head><meta charset=\"utf-8\">"
            f"<title>thermonet verify: {html.escape(Path(doc['log']).name)}</title>"
            f"<style>{_CSS}</style></head><body>"
            f"<h1>{html.escape(Path(doc['params_file']).name)} on "
            f"{html.escape(Path(doc['log']).name)} ({html.escape(doc['autopilot'])}): "
            f"{verdict}</h1><table><tr><th>instance[axis]</th><th>device id</th>"
            "<th>binned drift p-p before → after</th><th>cut</th><th>warnings</th></tr>"
            + "".join(rows) + "</table>"
            f"<h2>Report</h2><pre>{html.escape(format_verify_report(doc))}</pre>"
            "</body></html>\n")
