"""The pages of ``thermonet calibrate``: ``report.txt`` (:func:`format_report`: one line per
instance, then each one's detail), the console's summary (:func:`format_summary`) and
``report.html`` (:func:`render_calibration_report`), all from the results document."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..reporting.colours import GRADE_COLOURS
from ..reporting.report import _CSS, VERDICT_COLOURS
from .firmware_fit import MIN_SAMPLES, MIN_SPAN_C

__all__ = ["format_report", "format_summary", "summary_table", "render_calibration_report",
           "load_advice"]

_AXES = {"gyro": ("x", "y", "z"), "acc": ("x", "y", "z"), "baro": ("p",),
         "mag": ("x", "y", "z")}


def _mag_lines(d: dict[str, Any]) -> list[str]:
    """A magnetometer's thermometer (own, or lent: which, named or the default, the fitted
    lag and its held-out score against none) and its heading error before / after."""
    out = []
    th = d.get("thermometer") or {}
    if th.get("name"):
        scores = th.get("lag_scores") or {}
        best = scores.get(f"{th['lag_s']:g}")
        none = scores.get("0")
        score = (f" (held-out time blocks: {best:.3g} µT² mean squared residual, "
                 f"{none:.3g} with no lag)" if best is not None and none is not None else "")
        how = f"thermometer: {th['name']}'s, lent (" + (
            "as named" if th["chosen"] == "named" else "the default") + ")"
        out.append(f"{how}, through a fitted lag of {th['lag_s']:g} s{score}" if scores
                   else f"{how}; no lag fitted (the magnetometer cannot be calibrated)")
    elif th.get("chosen") == "own":
        out.append("thermometer: its own")
    if d.get("heading"):
        out.append(d["heading"]["line"])
    return out


def _g3(x: float | None) -> str:
    return "nan" if x is None or x != x else f"{x:.3g}"


def _cut(x: float | None) -> str:
    return "nan" if x is None or x != x else "inf" if x in (float("inf"), float("-inf")) \
        else f"{x:.1f}"


def _held_out_data(h: dict[str, Any]) -> str:
    """What the held-out check was judged on (older results name only the log)."""
    return str(h.get("data") or Path(h["log"]).name)


#: The calibration page's own rules: ids, counts and spans on one line (the result column
#: wraps instead), and the text report wrapped at the page's width, never scrolled sideways.
_CALIBRATE_CSS = """
table.instances td:nth-child(-n+5) { white-space: nowrap; overflow-wrap: normal; }
pre { white-space: pre-wrap; overflow-wrap: anywhere; font-size: 12px; }
"""


def _grade_colour(grades: list[str]) -> str:
    """A fitted instance's result colour: its worst held-out grade's (:data:`GRADE_COLOURS`);
    the comparison's "better" green where it was not judged."""
    for grade in ("fails", "marginal"):
        if grade in grades:
            return GRADE_COLOURS[grade]
    return GRADE_COLOURS["fine"] if grades else VERDICT_COLOURS["better"]


def render_calibration_report(doc: dict[str, Any], out: Path, *, staged: Path | None = None
                              ) -> str:
    """``DIR/report.html``: the calibration page a person opens first.

    One self-contained page (inline CSS, no script): a table of every sensor
    instance — fitted with the cut of the autopilot's own correction read back
    from the written file, or left out with its reason — colour-coded like the
    comparison report, the full text report, and a link to each instance's own
    comparison report (``instances/<name>/report.html``, itself self-contained,
    with the verdict table, warnings and plots).  Every string is HTML-escaped.
    ``staged``: where ``out``'s files are while it is being built (links are checked there).
    """
    import html

    names = ", ".join(Path(p).name for p in (doc.get("logs") or [doc["log"]]))
    rows = []
    for name, d in doc["instances"].items():
        span = d.get("temperature_c")
        where = f"{span[0]:.1f} … {span[1]:.1f} °C" if span else "no temperature"
        if d["status"] in ("fitted", "model only"):
            cuts = ", ".join(f"{c:.1f}×" for c in d["firmware_check"]["cut"])
            what = (f"fitted, slot {d['slot']}" if d["status"] == "fitted" else
                    f"model only ({d['reason']})") + f"; binned drift cut {cuts}"
            h = d.get("held_out") or {}
            if h.get("status") == "judged":
                grades = h.get("grades") or [""] * len(h["cut"])
                what += (f"; held out ({_held_out_data(h)}), verify's test: "
                         + ", ".join(f"{_cut(c)}× {g}" for c, g in zip(h["cut"], grades,
                                                                       strict=True)))
            if d.get("resolution"):
                what += f"; {d['resolution']['line']}"
            what += "".join(f"; {x}" for x in _mag_lines(d))
            colour = _grade_colour((h.get("grades") or []) if h.get("status") == "judged" else [])
        else:
            what = f"left out: {d['reason']}"
            colour = VERDICT_COLOURS["worse"]
        cmp = d.get("compare") or {}
        sub = Path(str(cmp.get("dir", ""))) / "report.html" if cmp.get("dir") else None
        link = ""
        rel = None if sub is None else sub.relative_to(out) if sub.is_relative_to(out) else sub
        found = rel if rel is None or staged is None or rel.is_absolute() else staged / rel
        if rel is not None and found is not None and found.is_file():
            link = f'<a href="{html.escape(str(rel))}">comparison</a>'
        rows.append(f"<tr><td>{html.escape(name)}</td><td>{html.escape(str(d['kind']))}</td>"
                    f"<td>{html.escape(str(d['device_id']))}</td><td>{d['n_samples']}</td>"
                    f"<td>{html.escape(where)}</td><td style=\"background:{colour}\">"
                    f"{html.escape(what)}</td><td>{link}</td></tr>")
    return ("<!DOCTYPE html><html><head><meta charset=\"utf-8\">"
            f"<title>thermonet calibrate: {html.escape(names)}</title>"
            f"<style>{_CSS}{_CALIBRATE_CSS}</style></head><body>"
            f"<h1>Thermal calibration of {html.escape(names)} "
            f"({html.escape(doc['autopilot'])})</h1>"
            f"<p class=\"chosen\">Parameter file: {html.escape(Path(doc['params_file']).name)}"
            + (" — do not load it: nothing in it could be checked on held-out data (see the "
               "report below)." if (doc.get("advice") or {}).get("load") == "no" else
               " — load it only on the board whose device ids are listed below.") + "</p>"
            "<h2>Sensor instances</h2><table class=\"instances\"><tr><th>instance</th><th>kind</th>"
            "<th>device id</th><th>samples</th><th>temperature</th><th>result</th>"
            "<th>details</th></tr>" + "".join(rows) + "</table>"
            "<p class=\"small\">Result colours: every fitted axis passes the held-out check "
            f"with margin <span style=\"background:{GRADE_COLOURS['fine']}\">(fine)</span>, "
            f"one is marginal <span style=\"background:{GRADE_COLOURS['marginal']}\">"
            "(a new log may FAIL it)</span>, one fails or the instance is left out "
            f"<span style=\"background:{GRADE_COLOURS['fails']}\">(red)</span>.</p>"
            f"<h2>Report</h2><pre>{html.escape(format_report(doc))}</pre></body></html>\n")


def _header(doc: dict[str, Any]) -> list[str]:
    """The logs calibrated (and their SHA-256), the parameter file, the held-out log."""
    logs = doc.get("logs") or [doc["log"]]
    lines = [f"thermonet calibrate: {', '.join(logs)} ({doc['autopilot']})",
             *([f"log sha256: {doc['log_sha256']}"] if doc.get("log_sha256")
               and len(logs) == 1 else []),
             *[f"log sha256: {h} ({Path(p).name})" for p, h in zip(
                 logs, doc.get("logs_sha256") or [], strict=False) if len(logs) > 1],
             *([f"board id: {doc['board_id']}"] if doc.get("board_id") else []),
             f"parameter file: {doc['params_file']}"]
    if doc.get("held_out_log"):
        lines += [f"{len(logs)} logs of one board: held-out check fitted on the first "
                  f"{len(logs) - 1} and applied to {doc['held_out_log']} through the "
                  "autopilot's own formula; the parameter file is the refit on all "
                  f"{len(logs)} logs"]
    return lines


def _short(reason: str | None, width: int = 72) -> str:
    """A left-out reason's first clause, at most ``width`` characters (the detail has it
    whole)."""
    text = str(reason or "")
    for sep in ("; ", " — ", " ("):
        text = text.split(sep, 1)[0]
    return text if len(text) <= width else text[:width - 1].rstrip() + "…"


def _summary_row(name: str, d: dict[str, Any]) -> list[str]:
    """One instance in the summary: result, the comparison's chosen model, the held-out cut
    of the parameter file's form (verify's test, against raw), the chosen model's
    out-of-fold score against the firmware form's, and the verdict."""
    cmp = d.get("compare") or {}
    fams = cmp.get("families") or {}
    fw, chosen = cmp.get("firmware_family"), cmp.get("chosen")
    try:
        ratio = float(fams[chosen]["val_score"]) / float(fams[fw]["val_score"])
        versus = "same" if chosen == fw else f"{ratio:.2f}x"
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        versus = "-"
    if d["status"] not in ("fitted", "model only"):
        return [name, "left out", "-", "-", "-", f"LEFT OUT: {_short(d.get('reason'))}"]
    result = f"fitted, slot {d['slot']}" if d["status"] == "fitted" else "model only"
    h = d.get("held_out") or {}
    if h.get("status") != "judged":
        return [name, result, chosen or "-", "-", versus,
                f"not judged: {_short(h.get('reason') or 'no held-out data')}"]
    cuts = [c for c in h["cut"] if c == c]
    cut = "-" if not cuts else f"{_cut(min(cuts))}x" if min(cuts) == max(cuts) else (
        f"{_cut(min(cuts))}x..{_cut(max(cuts))}x")
    grades = list(h.get("grades") or [])
    axes = _AXES.get(d["kind"], ())
    for grade, word in (("fails", "FAIL"), ("marginal", "MARGINAL")):
        weak = [a for a, g in zip(axes, grades, strict=False) if g == grade]
        if weak:
            return [name, result, chosen or "-", cut, versus, f"{word} ({', '.join(weak)})"]
    return [name, result, chosen or "-", cut, versus, "PASS" if grades else "not graded"]


def summary_table(doc: dict[str, Any]) -> list[str]:
    """One line per sensor instance (indented two spaces under a heading): what a drone
    owner reads first; :func:`format_report` gives each instance's detail."""
    head = ["instance", "device id", "result", "chosen model", "held-out cut", "chosen vs firmware",
            "verdict"]
    rows = [[r[0], str(d["device_id"]), *r[1:]] for r, d in (
        (_summary_row(name, d), d) for name, d in doc["instances"].items())]
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
    return ["  " + "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
            for r in [head] + rows] + [
        "  (held-out cut: raw / corrected binned drift, the parameter file's form on data it "
        "was not fitted on — verify's test; chosen vs firmware: the comparison's best model's "
        "out-of-fold score over the firmware form's, under 1 better, ONNX / C only)"]


def _unjudged(doc: dict[str, Any]) -> dict[str, str]:
    """The parameter file's instances the held-out check could not judge, with why."""
    return {n: str((d.get("held_out") or {}).get("reason") or "no held-out data")
            for n, d in doc["instances"].items() if d["status"] == "fitted"
            and (d.get("held_out") or {}).get("status") != "judged"}


def _why_unjudged(unjudged: dict[str, str]) -> str:
    """``acc0, gyro0: too few samples: 65 (need at least 200)``: the names per reason."""
    by: dict[str, list[str]] = {}
    for name, why in unjudged.items():
        by.setdefault(why, []).append(name)
    return "; ".join(f"{', '.join(names)}: {why}" for why, names in by.items())


def load_advice(doc: dict[str, Any], *, min_log_samples: int | None = None) -> dict[str, Any]:
    """Whether to load the parameter file, from the held-out check: ``load`` ``yes``, ``not
    yet`` (an axis in the file fails the check) or ``no`` (nothing in the file could be
    checked: every instance of it ``not judged`` — the file is still written, for inspection,
    but must not be loaded before a longer warm-up is logged), ``checked`` (an axis of the
    file was graded) and the console's ``lines``.  ``min_log_samples``: the fewest samples one
    log needs to be graded at all (:data:`~thermonet.workflows.calibrate_logs.MIN_GRADED_LOG_SAMPLES`)."""
    lines: list[str] = []
    graded = [g for d in doc["instances"].values() if d["status"] in ("fitted", "model only")
              for g in (d.get("held_out") or {}).get("grades") or []]
    fails = sum(1 for d in doc["instances"].values() if d["status"] == "fitted"
                for g in (d.get("held_out") or {}).get("grades") or [] if g == "fails")
    unjudged = _unjudged(doc)
    in_file = sum(1 for d in doc["instances"].values() if d["status"] == "fitted")
    if graded and len(unjudged) < in_file:
        weak = []
        if "marginal" in graded:
            weak.append(f"{graded.count('marginal')} marginal — `thermonet verify` on a new log "
                        "may FAIL them")
        if "fails" in graded:
            weak.append(f"{graded.count('fails')} fail it — `thermonet verify` on a new log "
                        "will FAIL them too")
        if unjudged:
            weak.append(f"not judged, so unchecked: {_why_unjudged(unjudged)}")
        lines += ["", f"held-out check (verify's test, limits and floors): {graded.count('fine')} "
                  f"of {len(graded)} fitted axes pass with margin" + (
                      "; " + "; ".join(weak) + " (see 'held out' in the detail)" if weak else "")]
    board = f"on board {doc['board_id']}, whose sensors are" if doc.get("board_id") else \
        "for a board whose sensors are"
    if in_file and len(unjudged) == in_file:
        return {"load": "no", "checked": False, "lines": [
            "", "held-out check (verify's test): nothing could be checked — no instance in the "
            f"parameter file could be judged on data it was not fitted on ({_why_unjudged(unjudged)})",
            "", "Do not load the parameter file: nothing in it was checked (it is written for "
            f"inspection only). Log a longer warm-up at rest and calibrate again: {_need(doc, min_log_samples)}."]}
    if fails:
        lines += ["", f"The parameter file holds {fails} "
                  f"{'axis that fails' if fails == 1 else 'axes that fail'} the held-out "
                  "check (corrected, less than verify asks): log a warm-up "
                  "over a wider range (colder start, hotter end) and calibrate again with it "
                  "before loading. If you load this one, load it only "
                  f"{board} the device ids above; reboot after loading; re-run the ordinary "
                  "gyro/accel calibration."]
        return {"load": "not yet", "checked": True, "lines": lines}
    lines += ["", f"Load the parameter file only {board} the device ids above; reboot after "
              "loading; re-run the ordinary gyro/accel calibration."]
    return {"load": "yes", "checked": True, "lines": lines}


def _need(doc: dict[str, Any], min_log_samples: int | None) -> str:
    """What the held-out check needs to judge an instance, in the words of the run's logs."""
    each = f"at least {MIN_SAMPLES} samples per sensor over at least {MIN_SPAN_C:g} °C"
    if doc.get("held_out_log"):
        return f"the last log given is held out whole and needs {each}"
    whole = f"about {min_log_samples} samples per sensor or more, logged evenly" \
        if min_log_samples else "four times that"
    return (f"one log is judged on a quarter of it, which needs {each} — {whole} (a shorter "
            "log can never be checked); or give a second warm-up log of the board, held out "
            f"whole ({each})")


def _totals(doc: dict[str, Any]) -> list[str]:
    """How many fitted axes pass the held-out check with margin, and the loading advice —
    which, where an axis in the file fails that check, says so first, and where nothing in the
    file could be checked, says not to load it (:func:`load_advice`, as ``results.json``'s
    ``advice`` records it).  Then each PX4 kind the file leaves as the board has it."""
    advice = doc.get("advice") or load_advice(doc)
    kept = doc.get("not_written") or []
    return [*advice["lines"], *([""] + list(kept) if kept else [])]


def format_summary(doc: dict[str, Any], detail: str = "") -> str:
    """The console's default: the header, one line per instance (:func:`summary_table`), the
    held-out totals and the loading advice; ``detail`` names where each instance's detail
    is (report.txt, ``--detail``)."""
    lines = [*_header(doc), "", *summary_table(doc), *_totals(doc)]
    if detail:
        lines += [f"detail per instance: {detail}"]
    return "\n".join(lines) + "\n"


def format_report(doc: dict[str, Any]) -> str:
    """The summary (:func:`summary_table`), then one block per instance: fitted (with verdict
    and check) or left out (with the reason)."""
    logs = doc.get("logs") or [doc["log"]]
    lines = [*_header(doc), "", *summary_table(doc), ""]
    # what the log reader found damaged and where, and the log's own notes (gaps)
    lines += [f"log: {n}" for n in doc.get("log_damage", []) + doc.get("log_notes", [])]
    if doc.get("log_damage") or doc.get("log_notes"):
        lines.append("")
    for name, d in doc["instances"].items():
        span = d.get("temperature_c")
        where = f"{span[0]:.1f}..{span[1]:.1f} °C" if span else "no temperature"
        head = f"{name:<6} id {d['device_id']:<9} {d['n_samples']:>7} samples, {where}"
        if d["status"] == "model only":
            cuts = ", ".join(f"{c:.1f}x" for c in d["firmware_check"]["cut"])
            lines.append(f"{head}: MODEL ONLY, not in the parameter file — {d['reason']}; "
                         f"on the log{'s' if len(logs) > 1 else ''} PX4's cubic cuts the "
                         f"binned drift p-p {cuts}")
            if d.get("verdict"):
                lines.append(f"       {d['verdict']}")
        elif d["status"] != "fitted":
            lines.append(f"{head}: LEFT OUT — {d['reason']}")
        else:
            chk = d["firmware_check"]
            cuts = ", ".join(f"{c:.1f}x" for c in chk["cut"])
            lines.append(f"{head}: fitted, slot {d['slot']}; on the log"
                         f"{'s' if len(logs) > 1 else ''} the autopilot's "
                         f"correction cuts the binned drift p-p {cuts}")
            if d.get("verdict"):
                lines.append(f"       {d['verdict']}")
        lines += [f"       {x}" for x in _mag_lines(d)]
        lines += _held_out_lines(name, d)
        for note in d.get("notes", []):
            lines.append(f"       note: {note}")
    return "\n".join(lines + _totals(doc)) + "\n"


def _held_out_lines(name: str, d: dict[str, Any]) -> list[str]:
    """An instance's held-out check in the detail: the binned drift before -> after per axis
    with its grade, and why an axis is not fine."""
    lines: list[str] = []
    h = d.get("held_out")
    if h and h.get("status") == "judged":
        grades = h.get("grades") or [""] * len(h["cut"])
        lines.append(f"       held out ({_held_out_data(h)}, fitted on the rest; verify's "
                     "test): binned drift p-p " + ", ".join(
                         f"{_g3(b)}->{_g3(a)} ({_cut(c)}x {g})" for b, a, c, g in zip(
                             h["pp_raw"], h["pp_corrected"], h["cut"], grades, strict=True)))
        for axis, g, why in zip(_AXES.get(d["kind"], ()), grades,
                                h.get("grade_reasons") or [], strict=False):
            if g != "fine":
                lines.append(f"       held out: {name} {axis} {g.upper()}: {why}")
        lines += [f"       held-out warning: {w}" for w in h.get("warnings") or []]
    elif h:
        lines.append(f"       held out: not judged ({h.get('reason')})")
    return lines
