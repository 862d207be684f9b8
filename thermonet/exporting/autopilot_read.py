"""PX4 and ArduPilot parameter files read back into ``{name: value}``: a QGroundControl
``.params`` file (:func:`read_px4_params`: ``Vehicle-Id Component-Id Name Value Type`` lines)
or ArduPilot's ``NAME,VALUE`` / ``NAME VALUE`` lines (:func:`read_ardupilot_params`), comments
skipped, a line or value that is not one refused naming the file, the line and the parameter.
What :mod:`thermonet.exporting.autopilot` writes; torch-free.  :func:`stamp_unit` names the
unit a per-unit file of a fleet is for in a ``# unit <id>`` comment line (both formats take
``#`` comments, and both readers skip them).  :func:`recorded_sensor` reads which sensor a
model of a ``calibrate`` / ``learn`` instance directory was fitted on, and
:func:`recorded_defaults` makes it ``export``'s default ``--device-id`` / ``--instance``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from ..core.errors import ExportError, InputError
from ..core.fileio import atomic_write_text
from . import is_device_id

__all__ = ["read_px4_params", "read_ardupilot_params", "stamp_unit", "unit_comment",
           "recorded_sensor", "recorded_defaults", "recorded_slot"]

#: Characters of a unit id a comment line keeps (the rest of a long id is cut).
UNIT_ID_CHARS = 120


def unit_comment(unit_id: str) -> str:
    """``# unit <id>``: the id's printable ASCII kept, anything else (a line break that would
    end the comment) as ``?``."""
    safe = "".join(ch if " " <= ch <= "~" else "?" for ch in str(unit_id)[:UNIT_ID_CHARS])
    return f"# unit {safe}"


def stamp_unit(path: str | Path, unit_id: str) -> Path:
    """Put :func:`unit_comment` first in the parameter file at ``path`` (rewritten whole)."""
    text = _text(path)
    return atomic_write_text(Path(path), unit_comment(unit_id) + "\n" + text)


def read_px4_params(path: str | Path) -> dict[str, float]:
    """Parse a QGC ``.params`` file into ``{name: value}`` (comments skipped)."""
    out: dict[str, float] = {}
    for no, line in enumerate(_text(path).splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 5:
            raise ExportError(f"{path}: line {no}: expected 5 fields "
                              f"(Vehicle-Id Component-Id Name Value Type), got {len(parts)}")
        out[parts[2]] = _number(path, no, parts[2], parts[3])
    return out


def read_ardupilot_params(path: str | Path) -> dict[str, float]:
    """Parse ArduPilot ``NAME,VALUE`` or ``NAME VALUE`` lines into ``{name: value}``."""
    out: dict[str, float] = {}
    for no, line in enumerate(_text(path).splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) != 2:
            raise ExportError(f"{path}: line {no}: expected NAME,VALUE, got {line!r}")
        out[parts[0]] = _number(path, no, parts[0], parts[1])
    return out


def _text(path: str | Path) -> str:
    """The file's text; a UTF-8 byte-order mark (Windows Notepad writes one) is dropped."""
    return Path(path).read_text(encoding="utf-8-sig")


def _number(path: str | Path, no: int, name: str, value: str) -> float:
    """``value`` as a float; otherwise an error naming the file, the line and the parameter."""
    try:
        return float(value)
    except ValueError:
        raise ExportError(f"{path}: line {no}: parameter {name}: value {value[:40]!r} is not a "
                          "number") from None


_INSTANCE_NAME = re.compile(r"(gyro|acc|baro|mag)(\d)")


def recorded_sensor(source: str | Path) -> dict[str, Any] | None:
    """The sensor a model of a ``calibrate`` / ``learn`` instance directory was fitted on
    (``DIR/instances/<name>``, or a checkpoint in its ``models/``): ``name``, ``kind``,
    ``index`` (the autopilot's instance: gyro1 → 1), ``device_id``, ``slot`` (the PX4 slot
    calibrate's ``px4.params`` gave it, or None) and ``mav_sys_id`` (the vehicle's MAVLink
    system id as its log recorded it, or None), as ``DIR/results.json`` records them and the
    instance's own ``results.json`` confirms (its ``device``).  None for anything else — a
    plain compare directory records no autopilot instance."""
    p = Path(source)
    where = p if p.is_dir() else p.parent.parent if p.parent.name == "models" else None
    if where is None or where.parent.name != "instances":
        return None
    m = _INSTANCE_NAME.fullmatch(where.name)
    try:
        rec = json.loads((where.parent.parent / "results.json").read_text(encoding="utf-8"))
        own = json.loads((where / "results.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    d = (rec.get("instances") or {}).get(where.name) if isinstance(rec, dict) and isinstance(
        rec.get("instances"), dict) else None
    if m is None or not isinstance(d, dict) or not isinstance(own, dict):
        return None
    dev = d.get("device_id")
    if isinstance(dev, bool) or not isinstance(dev, int) or not is_device_id(dev) or str(
            own.get("device")) != str(dev) or d.get("kind", m.group(1)) != m.group(1):
        return None
    slot, sys_id = d.get("slot"), rec.get("mav_sys_id")
    return {"name": where.name, "kind": m.group(1), "index": int(m.group(2)),
            "device_id": dev, "slot": slot if isinstance(slot, int) and not isinstance(
                slot, bool) else None, "dir": where,
            "mav_sys_id": sys_id if isinstance(sys_id, (int, float)) else None}


def recorded_defaults(source: str, fmt: str, device_id: int | None, instance: int | None
                       ) -> tuple[int | None, int | None]:
    """``--device-id`` and ``--instance`` for an autopilot file of a model whose sensor is
    recorded (:func:`recorded_sensor`): by default the recorded ones (PX4: its device id and
    calibrate's slot, else its instance number; ArduPilot: IMU instance + 1); one given that
    contradicts them is refused in one line naming both.  There is no override: the model is
    that sensor's drift, and written for another it would correct that one with it."""
    rec = recorded_sensor(source) if fmt in ("px4-params", "ardupilot-params") else None
    if rec is None:
        return device_id, instance
    name, dev, where = rec["name"], rec["device_id"], rec["dir"]
    if device_id is not None and int(device_id) != dev:
        raise InputError(f"--device-id {device_id}: {where} is {name}'s model, fitted on device "
                         f"{dev} (its calibration's results.json): it is that sensor's drift — "
                         f"leave --device-id out (it defaults to {dev})")
    want = recorded_slot(rec, fmt)
    if fmt == "px4-params":
        what = f"slot {want}" + (" (its slot in the calibration's px4.params: another would "
                                 "leave two slots naming one device)"
                                 if rec["slot"] is not None else "")
    else:
        what = f"IMU {want} (INS_TCAL{want})"
    if instance is not None and int(instance) != want and (fmt != "px4-params"
                                                           or rec["slot"] is not None):
        raise InputError(f"--instance {instance}: {where} is {name}'s model, {what}: it is that "
                         f"sensor's drift — leave --instance out (it defaults to {want})")
    return dev, want if instance is None else instance


def recorded_slot(rec: dict[str, Any], fmt: str) -> int:
    """The slot an autopilot file of a recorded sensor (:func:`recorded_sensor`) is written
    to: PX4, calibrate's slot, else its instance number; ArduPilot, IMU instance + 1."""
    if fmt == "px4-params":
        return int(rec["slot"]) if rec["slot"] is not None else int(rec["index"])
    return int(rec["index"]) + 1
