"""``thermonet info LOG``: every sensor instance of a flight-controller log at a glance."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import InputError, counted
from . import read_log, split_instance, temperature_step
from .base import UNITS

__all__ = ["summarize_log", "format_log_summary", "AUTOPILOT_NAMES", "autopilot_article"]

#: How each autopilot is written in prose.
AUTOPILOT_NAMES = {"px4": "PX4", "ardupilot": "ArduPilot"}


def autopilot_article(name: str) -> str:
    """An autopilot's name in prose with its article: "a PX4", "an ArduPilot"."""
    return {"px4": "a PX4", "ardupilot": "an ArduPilot"}.get(name, f"a {name}")


def summarize_log(path: str | Path) -> dict[str, Any]:
    """Per instance: kind, device id, samples, rate, temperature span and step, notes.

    ``LOG#instance`` (``b.ulg#gyro0``) summarises that one instance of the log.

    Returns
    -------
    dict
        ``log``, ``autopilot``, ``board_id`` (the board's own id, None where the log
        holds none), ``instances`` (list of dicts: ``name``, ``kind``,
        ``device_id``, ``samples``, ``duration_s``, ``rate_hz``, ``temperature_min_c``
        / ``temperature_max_c`` / ``temperature_step_c`` (None without a
        thermometer), ``unit``, ``notes``), ``params`` (the thermal-calibration
        parameters the log carries: ``TC_*``, ``SYS_CAL_*``, ``INS_TCAL*``,
        ``AHRS_ORIENTATION``).
    """
    file, name = split_instance(path)
    log = read_log(file)
    insts = [i for i in log.instances if i.name == name] if name else log.instances
    if not insts:
        raise InputError.at(file, f"no sensor instance '{name}' (instances: "
                            f"{', '.join(i.name for i in log.instances)})")
    rows: list[dict[str, Any]] = []
    for inst in insts:
        t = inst.time_s
        temp = inst.temperature_c if inst.temperature_c is not None and inst.n_samples else None
        rows.append({
            "name": inst.name, "kind": inst.kind, "device_id": inst.device_id,
            "samples": inst.n_samples,
            "duration_s": float(t[-1] - t[0]) if inst.n_samples > 1 else 0.0,
            "rate_hz": float(1.0 / np.median(np.diff(t))) if inst.n_samples > 1 else None,
            "temperature_min_c": None if temp is None else float(temp.min()),
            "temperature_max_c": None if temp is None else float(temp.max()),
            "temperature_step_c": temperature_step(temp),
            "unit": UNITS[inst.kind], "notes": list(inst.notes),
            "damaged_samples": inst.damaged, "untrusted": inst.untrusted})
    keep = ("TC_", "SYS_CAL_", "INS_TCAL", "AHRS_ORIENTATION")
    params = {k: v for k, v in sorted(log.params.items()) if k.startswith(keep)}
    still = [r["name"] for r in rows if r["samples"] > 1 and r["temperature_min_c"] is not None
             and r["temperature_max_c"] == r["temperature_min_c"]]
    flat = ([f"{', '.join(still)}: the temperature never changes (the same value on every "
             "sample: a SITL log, or a thermometer stuck at one value): nothing to calibrate "
             "from"] if still else [])
    return {"log": str(log.path), "autopilot": log.autopilot, "board_id": log.board_id,
            "instances": rows,
            "params": params, "log_notes": list(log.notes) + flat, "damage": list(log.damage)}


def format_log_summary(s: dict[str, Any]) -> str:
    """Render :func:`summarize_log` as a table, then the notes and calibration parameters."""
    head = ["instance", "device id", "samples", "rate Hz", "temperature °C", "T step °C", "unit"]
    rows = []
    for r in s["instances"]:
        span = ("none (no thermometer)" if r["temperature_min_c"] is None
                else f"{r['temperature_min_c']:.2f}..{r['temperature_max_c']:.2f} "
                     f"(span {r['temperature_max_c'] - r['temperature_min_c']:.2f})")
        step = "n/a" if r["temperature_step_c"] is None else f"{r['temperature_step_c']:.3g}"
        rate = "n/a" if r["rate_hz"] is None else f"{r['rate_hz']:.3g}"
        rows.append([r["name"], str(r["device_id"]), str(r["samples"]), rate, span, step,
                     r["unit"]])
    widths = [max(len(h), *(len(x[i]) for x in rows)) for i, h in enumerate(head)]
    board = f", board {s['board_id']}" if s.get("board_id") else ""
    who = AUTOPILOT_NAMES.get(s["autopilot"], s["autopilot"])
    out = [f"{s['log']}: {who} log{board}, {counted(len(rows), 'sensor instance')}", ""]
    out += ["  ".join(c.ljust(w) for c, w in zip(line, widths, strict=True)).rstrip()
            for line in [head, ["-" * w for w in widths]] + rows]
    notes = list(s.get("log_notes", [])) + [f"{r['name']}: {n}" for r in s["instances"]
                                            for n in r["notes"]]
    if notes:
        out += ["", "notes:"] + [f"  {n}" for n in notes]
    untrusted = [f"{r['name']}: {r['untrusted']}" for r in s["instances"] if r.get("untrusted")]
    if s.get("damage") or untrusted:
        out += ["", "damaged (what could not be read or trusted, and where):"]
        out += [f"  {n}" for n in s.get("damage", [])]
        out += [f"  not trusted — {n}" for n in untrusted]
    if s["params"]:
        out += ["", "calibration parameters in the log: " + ", ".join(
            f"{k}={v:g}" for k, v in s["params"].items())]
    return "\n".join(out)
