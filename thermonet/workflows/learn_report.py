"""``thermonet learn``'s console summary and ``report.txt`` (:func:`format_learn_report`),
from the results document :func:`thermonet.workflows.learn.learn` builds: what was used and
refused, per instance its fit, held-out check, coverage and what is missing, the sensors not
learned, the warnings, and what changed."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core.errors import counted
from .learn_data import supported_spans
from .learn_fit import UNITS

__all__ = ["format_learn_report"]


def _outside_note(h: dict[str, Any]) -> str:
    """Where the held-out flight left the other flights' range (the firmware clamps there)."""
    share, span = h.get("outside_trained") or 0.0, h.get("trained_c")
    if share < 0.01 or not span:
        return ""
    return (f" ({share:.0%} of it outside the other flights' {span[0]:.1f}..{span[1]:.1f} °C, "
            "where the firmware holds its edge value)")


def _band_line(c: dict[str, Any], unit: str) -> list[str]:
    """The firmware form's residual-drift band (judged on whole flights held out) in one
    line, in ``unit`` as the instance's other lines (results.json also holds it in °/h or
    mg): its half-widths over the flown range and how fast it grows outside it."""
    b = c.get("band")
    if not isinstance(b, dict) or not b.get("axes"):
        return []
    axes = b["axes"].values()
    widths = [float(w) for a in axes for w in a["half_width"]]
    edges = next(iter(axes))["edges"]
    grow = max(max(float(a["growth_below"]), float(a["growth_above"])) for a in axes)
    return [f"  band ({float(b['level']):.0%}, {c['baseline']}, whole flights held out): "
            f"±{min(widths):.3g}..{max(widths):.3g} {unit} over {edges[0]:.0f}..{edges[-1]:.0f} "
            f"°C, growing by up to {grow:.3g} {unit} per °C outside (not yet flown)"]


def _supported(d: dict[str, Any]) -> str:
    """The supported 1 °C bins as spans ("10..13, 36..39 °C"), or "" where none is."""
    spans = supported_spans(d.get("coverage") or [])
    return ", ".join(f"{a}..{b + 1}" for a, b in spans) + " °C" if spans else ""


def format_learn_report(doc: dict[str, Any], out_dir: str | Path | None = None) -> str:
    """The console summary: what was used and refused, per instance its fit, held-out check,
    coverage and what is missing, and what changed."""
    lines = [f"thermonet learn: {counted(len(doc['logs']), 'log')} used, "
             f"{len(doc['refused'])} refused "
             f"({doc['autopilot']})"]
    lines += [f"  refused {r['log']}: {r['reason']}" for r in doc["refused"]]
    lines += [f"warning: {w}" for w in doc.get("warnings", [])]
    for name, d in doc["instances"].items():
        unit = UNITS[d["kind"]]
        lines.append(f"{name} (id {d['device_id']}): {d['status']}, "
                     f"{counted(d['flights'], 'flight')}, "
                     f"{d['minutes']:g} min, lag {d['lag_s']:g} s, "
                     f"{counted(d['rejected_windows'], 'window')} rejected (diverged)")
        h = d.get("held_out") or {}
        if h.get("status") == "judged":
            lines.append(f"  held-out flight {Path(h['flight']).name}: binned drift p-p "
                         + ", ".join(f"{b:.3g} -> {a:.3g}" for b, a in zip(
                             h["pp_raw"], h["pp_corrected"], strict=True)) + f" {unit}"
                         + _outside_note(h))
        c = d.get("compare") or {}
        if c.get("status") == "ok":
            chosen = c.get("chosen") or f"nothing ({c.get('chosen_reason')})"
            lines.append(f"  comparison on whole flights: chosen {chosen} "
                         f"(baseline {c['baseline']}, test {c['test_flight']})")
            lines += _band_line(c, unit)
        elif c:
            lines.append(f"  comparison: {c.get('status')} ({c.get('reason')})")
        if d.get("reason"):
            lines.append(f"  {d['reason']}")
        if d.get("parameter_file"):
            lines.append(f"  {d['parameter_file']}")
        spans = _supported(d)
        lines.append(f"  coverage: supported {spans}" if spans else
                     "  coverage: no 1 °C bin supported yet")
        lines += [f"  {w}" for w in d.get("missing", [])]
    lines += [f"{x['name']} (id {x['device_id']}): not learned — {x['reason']}; "
              f"{x['parameter_file']}" for x in doc.get("not_learned", [])]
    if doc.get("params_file"):
        lines.append(f"parameter file: {Path(out_dir or '') / doc['params_file']}")
    else:   # exit 0 all the same: the logs were read and kept (cache) for the next run
        lines.append("parameter file: none yet (no sensor could be fitted: fly more and run "
                     "learn again)")
    lines += [f"changed: {c}" for c in doc.get("changes", [])]
    return "\n".join(lines) + "\n"
