"""``thermonet verify PARAMS LOG --out DIR``: a thermal calibration already on a vehicle, checked
on a new log through the autopilot's own formula.

PARAMS is a ``px4.params`` (QGroundControl ``Vehicle-Id Component-Id Name Value
Type`` lines: thermonet's, ``Tools/process_sensor_caldata.py``'s, or a full QGC
parameter dump) or an ``ardupilot.parm`` (``NAME,VALUE`` or ``NAME VALUE`` lines:
thermonet's, ``Tools/scripts/tempcal_IMU.py``'s, or a Mission Planner dump).  The
format is told from the first parameter line (five fields: PX4).  LOG is a ULog
(PX4) or a DataFlash log (ArduPilot) of the same autopilot.

The firmware's formula (:mod:`thermonet.data.firmware`):

* PX4 ``TemperatureCompensation.cpp``: ``TC_<k>_ENABLE`` must be 1 (a file without it,
  as ``process_sensor_caldata.py`` writes, is applied as enabled, with a warning); the slot whose
  ``TC_<k><s>_ID`` equals the instance's device id applies; T clamped to
  [TMIN, TMAX]; offset = Σ X_k (T − TREF)^k subtracted.
* ArduPilot ``AP_InertialSensor_tempcal.cpp``: ``INS_TCAL<n>_ENABLE`` = 1; T and the
  calibration temperature (``INS_GYR<n>_CALTEMP`` / ``INS_ACC<n>_CALTEMP`` from the
  file, else from the log, else 35 °C) clamped; P(T − 35) − P(T_cal − 35)
  subtracted.  IMU n is matched by device id when the file names the ids (a full
  dump's ``INS_GYR_ID``/``INS_ACC2_ID``…, or thermonet's ``# device ids:`` line);
  ``tempcal_IMU.py`` writes none, and then IMU n is the log's IMU n (said in the report).

Judged per instance and axis on the log: the binned drift (peak-to-peak of the
1 °C-binned means of the output; accel and baro less their median) before and
after the correction.  An axis PASSes when the correction cuts it at least
:attr:`Limits.min_cut` times, or when what is left is below the kind's floor
(:attr:`Limits.floor`: a drift that small no longer matters and its cut is noise).
Defaults: cut 3×; floors 5e-4 rad/s (0.03 °/s), 5e-3 m/s² (0.5 mg), 1 Pa (≈8 cm) —
about the bias stability of a good MEMS IMU and a baro's noise; set them for your
sensors (``--gyro-floor`` …).  The binned drift of pure noise is not zero (the spread
of ~50 bin means), so a floor far below the sensor's noise makes quiet axes FAIL.

Refused in one line: a file from another board (no device id of the log in the
file: both lists named), a file of the other autopilot, a file with no thermal
calibration.  A log that leaves the calibrated range [TMIN, TMAX] by more than
:data:`RANGE_SLACK_C` gets a warning per instance (the firmware holds the
correction constant outside it).  A sensor of the log that the file does not
cover is listed, not judged.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..core.errors import InputError, ThermonetError
from ..core.fileio import atomic_write_text
from ..data.firmware import (
    ARDUPILOT_TEMP_REFERENCE,
    PX4_SLOTS,
    ardupilot_correction,
    px4_offsets_1d,
    px4_offsets_3d,
)
from ..data.logs import FlightLog, SensorInstance, read_log
from ..exporting.autopilot import read_ardupilot_params, read_px4_params
from ..scoring.metrics import binned_peak_to_peak
from .firmware_fit import target

__all__ = ["Limits", "ParamFile", "read_param_file", "evaluate", "verify",
           "format_verify_report", "RANGE_SLACK_C", "EXIT_FAILED"]

#: How far (°C) a log may leave [TMIN, TMAX] before a warning (the scripts round TMIN/TMAX).
RANGE_SLACK_C = 0.5
#: Exit status of ``thermonet verify`` when an axis fails its limits (as ``fleet``).
EXIT_FAILED = 3
_PX4_LETTER = {"gyro": "G", "acc": "A", "baro": "B"}
#: The SI units the autopilots' logs and formulas use, per sensor kind (what verify prints).
KIND_UNITS = {"gyro": "rad/s", "acc": "m/s²", "baro": "Pa"}
_AP_ID = {"gyro": "INS_GYR{}_ID", "acc": "INS_ACC{}_ID"}
_AP_IDS_LINE = re.compile(r"^#\s*device ids:\s*INS_TCAL(\d)\s+gyro\s+(\d+)\s+acc\s+(\d+)")


@dataclass
class Limits:
    """PASS/FAIL of one axis: ``cut ≥ min_cut`` or ``after ≤ floor[kind]`` (SI units)."""

    min_cut: float = 3.0
    floor: dict[str, float] = field(default_factory=lambda: {
        "gyro": 5e-4, "acc": 5e-3, "baro": 1.0})

    def check(self) -> Limits:
        if not (math.isfinite(self.min_cut) and self.min_cut > 1.0):
            raise InputError(f"--min-cut {self.min_cut}: must be a number above 1")
        for kind, v in self.floor.items():
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"the {kind} floor {v}: must be a non-negative number")
        return self


@dataclass
class ParamFile:
    """A parameter file read for verification."""

    path: Path
    autopilot: str
    params: dict[str, float]
    #: (kind, device id) -> PX4 slot 0..3 or ArduPilot IMU 0..2; empty for an ArduPilot
    #: file that names no device ids.
    by_id: dict[tuple[str, int], int]
    enabled: dict[str, bool]            # PX4: per kind; ArduPilot: "imu<n>"

    @property
    def ids(self) -> list[int]:
        return sorted({i for _, i in self.by_id})


def _first_param_line(text: str) -> str | None:
    for line in text.splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            return line
    return None


def read_param_file(path: str | Path) -> ParamFile:
    """Read a PX4 or ArduPilot parameter file (format told from its first parameter line)."""
    from ..core.errors import ExportError
    from ..core.fileio import not_a_file

    p = Path(path)
    why = not_a_file(p)
    if why:
        raise InputError(f"{p}: {why}")
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{p}: cannot be read as a parameter file ({err})") from err
    first = _first_param_line(text)
    if first is None:
        raise InputError(f"{p}: no parameter lines")
    autopilot = "px4" if len(first.split()) == 5 else "ardupilot"
    try:
        params = read_px4_params(p) if autopilot == "px4" else read_ardupilot_params(p)
    except (ExportError, ValueError) as err:
        raise InputError(str(err).splitlines()[0]) from err
    by_id: dict[tuple[str, int], int] = {}
    enabled: dict[str, bool] = {}
    if autopilot == "px4":
        if not any(k.startswith("TC_") for k in params):
            raise InputError(f"{p}: no PX4 thermal calibration (TC_*) parameters")
        for kind, t in _PX4_LETTER.items():
            # process_sensor_caldata.py writes no TC_<k>_ENABLE (its procedure sets them to 1
            # on the board first): absent means enabled, said per instance
            enabled[kind] = params.get(f"TC_{t}_ENABLE", 1.0) == 1.0
            for s in range(PX4_SLOTS):
                dev = int(params.get(f"TC_{t}{s}_ID", 0))
                if dev:
                    by_id[(kind, dev)] = s
    else:
        imus = [n for n in (1, 2, 3) if f"INS_TCAL{n}_ENABLE" in params]
        if not imus:
            raise InputError(f"{p}: no ArduPilot thermal calibration (INS_TCAL<n>_*) parameters")
        for n in imus:
            enabled[f"imu{n}"] = params[f"INS_TCAL{n}_ENABLE"] == 1.0
            for kind, fmt in _AP_ID.items():
                dev = int(params.get(fmt.format("" if n == 1 else n), 0))
                if dev:
                    by_id[(kind, dev)] = n - 1
        for line in text.splitlines():
            m = _AP_IDS_LINE.match(line.strip())
            if m:
                n = int(m.group(1))
                for kind, dev in (("gyro", int(m.group(2))), ("acc", int(m.group(3)))):
                    if dev:
                        by_id[(kind, dev)] = n - 1
    return ParamFile(p, autopilot, params, by_id, enabled)


def _need(pf: ParamFile, *names: str) -> None:
    for n in names:
        if n not in pf.params:
            raise InputError(f"{pf.path}: parameter {n} is missing")


def _slot(pf: ParamFile, inst: SensorInstance) -> tuple[int | None, str | None]:
    """The slot/IMU applying to ``inst`` and, when it applies nothing, why."""
    if pf.autopilot == "px4":
        slot = pf.by_id.get((inst.kind, inst.device_id))
        if slot is None:
            return None, f"no TC_{_PX4_LETTER[inst.kind]}*_ID equals its device id"
        if not pf.enabled[inst.kind]:
            return None, f"TC_{_PX4_LETTER[inst.kind]}_ENABLE is not 1: the firmware applies none"
        return slot, None
    if inst.kind == "baro":
        return None, "ArduPilot has no barometer temperature calibration"
    if pf.by_id:
        imu = pf.by_id.get((inst.kind, inst.device_id))
        if imu is None:
            return None, "no IMU of the file has its device id"
    else:
        imu = inst.instance
    if f"imu{imu + 1}" not in pf.enabled:
        return None, f"the file has no INS_TCAL{imu + 1}_*"
    if not pf.enabled[f"imu{imu + 1}"]:
        return None, f"INS_TCAL{imu + 1}_ENABLE is not 1: the firmware applies none"
    return imu, None


def _correction(pf: ParamFile, inst: SensorInstance, slot: int, log: FlightLog
                ) -> tuple[np.ndarray, float, float]:
    """What the firmware subtracts (n, axes), and the file's TMIN, TMAX."""
    temp = np.asarray(inst.temperature_c, dtype=np.float64)
    if pf.autopilot == "px4":
        pre = f"TC_{_PX4_LETTER[inst.kind]}{slot}_"
        if inst.kind == "baro":
            _need(pf, *(pre + s for s in ("TMIN", "TMAX", "TREF", *(f"X{k}" for k in range(6)))))
            corr = px4_offsets_1d(pf.params, temp, slot)[:, None]
        else:
            _need(pf, *(pre + s for s in ("TMIN", "TMAX", "TREF",
                                          *(f"X{k}_{i}" for k in range(4) for i in range(3)))))
            corr = px4_offsets_3d(pf.params, inst.kind, temp, slot)
        return corr, pf.params[pre + "TMIN"], pf.params[pre + "TMAX"]
    pre = f"INS_TCAL{slot + 1}_"
    s = "GYR" if inst.kind == "gyro" else "ACC"
    _need(pf, pre + "TMIN", pre + "TMAX",
          *(f"{pre}{s}{k}_{a}" for k in (1, 2, 3) for a in "XYZ"))
    cal_name = f"INS_{s}{slot + 1}_CALTEMP"
    cal = pf.params.get(cal_name, log.params.get(cal_name, ARDUPILOT_TEMP_REFERENCE))
    corr = ardupilot_correction(pf.params, inst.kind, temp, cal, imu=slot + 1)
    return corr, pf.params[pre + "TMIN"], pf.params[pre + "TMAX"]


def evaluate(pf: ParamFile, log: FlightLog, limits: Limits | None = None
             ) -> dict[str, dict[str, Any]]:
    """Apply ``pf`` to every instance of ``log`` through the firmware's formula.

    Per instance: ``status`` (``judged`` | ``not covered``), ``reason``, ``slot``,
    ``pp_raw`` / ``pp_corrected`` / ``cut`` per axis, ``pass`` per axis, ``range``
    (TMIN, TMAX), ``log_range`` and ``warnings``.  Refuses (ThermonetError) a file of
    the other autopilot and one whose device ids are none of the log's.
    """
    limits = limits or Limits()
    if pf.autopilot != log.autopilot:
        name = {"px4": "PX4", "ardupilot": "ArduPilot"}
        raise ThermonetError(f"{pf.path} is a {name[pf.autopilot]} parameter file; {log.path} "
                             f"is a {name[log.autopilot]} log (verify needs the same autopilot)")
    insts = [i for i in log.instances if i.kind in _PX4_LETTER and i.temperature_c is not None
             and i.n_samples]
    log_ids = sorted({i.device_id for i in insts})
    if pf.by_id and not any((i.kind, i.device_id) in pf.by_id for i in insts):
        raise ThermonetError(f"{pf.path} belongs to another board: its device ids "
                             f"{', '.join(map(str, pf.ids))} are none of {log.path.name}'s "
                             f"({', '.join(map(str, log_ids))})")
    out: dict[str, dict[str, Any]] = {}
    for inst in insts:
        slot, why = _slot(pf, inst)
        temp = np.asarray(inst.temperature_c, dtype=np.float64)
        d: dict[str, Any] = {"kind": inst.kind, "device_id": inst.device_id,
                             "n_samples": inst.n_samples,
                             "log_range": [float(temp.min()), float(temp.max())],
                             "warnings": []}
        if slot is None:
            d.update(status="not covered", reason=why)
            out[inst.name] = d
            continue
        if pf.autopilot == "px4" and f"TC_{_PX4_LETTER[inst.kind]}_ENABLE" not in pf.params:
            d["warnings"].append(f"the file has no TC_{_PX4_LETTER[inst.kind]}_ENABLE "
                                 "(process_sensor_caldata.py writes none): applied as the board "
                                 "has it set to 1 — check it")
        if pf.autopilot == "ardupilot" and not pf.by_id:
            d["warnings"].append(f"the file names no device ids (tempcal_IMU.py writes none): "
                                 f"INS_TCAL{slot + 1} applied to the log's IMU {slot + 1}")
        corr, t_min, t_max = _correction(pf, inst, slot, log)
        y = target(inst, log.autopilot)
        before = [binned_peak_to_peak(temp, y[:, j]) for j in range(y.shape[1])]
        after = [binned_peak_to_peak(temp, y[:, j] - corr[:, j]) for j in range(y.shape[1])]
        cut = [b / a if a > 0 else math.inf for b, a in zip(before, after, strict=True)]
        floor = limits.floor[inst.kind]
        ok = [bool(c >= limits.min_cut or a <= floor) for c, a in zip(cut, after, strict=True)]
        below = t_min - float(temp.min())
        above = float(temp.max()) - t_max
        if below > RANGE_SLACK_C or above > RANGE_SLACK_C:
            d["warnings"].append(
                f"the log spans {temp.min():.1f}..{temp.max():.1f} °C, outside the calibrated "
                f"{t_min:.1f}..{t_max:.1f} °C (by {max(below, 0):.1f} °C below, "
                f"{max(above, 0):.1f} °C above): the firmware holds the correction constant "
                "there")
        d.update(status="judged", reason=None, slot=slot, range=[t_min, t_max],
                 pp_raw=before, pp_corrected=after, cut=cut, passed=ok)
        out[inst.name] = d
    if not any(d["status"] == "judged" for d in out.values()):
        reasons = "; ".join(f"{n}: {d['reason']}" for n, d in out.items())
        raise ThermonetError(f"{pf.path}: applies to no sensor of {log.path.name} ({reasons})")
    return out


def verify(params_path: str | Path, log_path: str | Path, out_dir: str | Path, *,
           limits: Limits | None = None, overwrite: bool = False) -> dict[str, Any]:
    """Check ``params_path`` on ``log_path``; write ``out_dir`` (results.json, report.txt,
    report.html) whole or not at all; return the results (``passed``: every judged axis)."""
    from ..core.outdir import check_target, sha256_file, staged_output

    limits = (limits or Limits()).check()
    pf = read_param_file(params_path)
    log = read_log(log_path)
    out = Path(out_dir)
    check_target(out, overwrite, "verification")
    insts = evaluate(pf, log, limits)
    judged = [d for d in insts.values() if d["status"] == "judged"]
    doc = {"kind": "verification", "schema": 1, "thermonet_version": __version__,
           "params_file": str(pf.path), "log": str(log.path),
           "log_sha256": sha256_file(log.path), "autopilot": log.autopilot,
           "limits": asdict(limits), "instances": insts,
           "passed": all(all(d["passed"]) for d in judged)}
    with staged_output(out, overwrite=overwrite, kind="verification") as stage:
        atomic_write_text(stage.path / "results.json", json.dumps(doc, indent=2))
        atomic_write_text(stage.path / "report.txt", format_verify_report(doc))
        atomic_write_text(stage.path / "report.html", render_verify_html(doc))
        stage.done()
    return doc


def format_verify_report(doc: dict[str, Any]) -> str:
    """One block per instance: the binned drift before → after per axis, PASS/FAIL, warnings."""
    lim = doc["limits"]
    lines = [f"thermonet verify: {doc['params_file']} on {doc['log']} ({doc['autopilot']})",
             f"limits: an axis passes when the binned drift is cut at least "
             f"{lim['min_cut']:g}x, or is left below "
             + ", ".join(f"{v:g} {KIND_UNITS.get(k, '')} ({k})" for k, v in lim["floor"].items()),
             ""]
    for name, d in doc["instances"].items():
        head = f"{name:<6} id {d['device_id']:<9}"
        if d["status"] != "judged":
            lines.append(f"{head} not covered: {d['reason']}")
            continue
        axes = ", ".join(f"{b:.3g}->{a:.3g} ({c:.1f}x {'PASS' if ok else 'FAIL'})"
                         for b, a, c, ok in zip(d["pp_raw"], d["pp_corrected"], d["cut"],
                                                d["passed"], strict=True))
        unit = KIND_UNITS.get(d["kind"], "")
        lines.append(f"{head} slot {d['slot']}: binned drift p-p [{unit}] {axes}")
        lines += [f"       warning: {w}" for w in d["warnings"]]
    lines += ["", "PASS" if doc["passed"] else "FAIL: see the axes marked FAIL"]
    return "\n".join(lines) + "\n"


def render_verify_html(doc: dict[str, Any]) -> str:
    """``DIR/report.html``: the verification table (every string HTML-escaped)."""
    import html

    from ..reporting.report import _CSS, VERDICT_COLOURS

    rows = []
    for name, d in doc["instances"].items():
        if d["status"] != "judged":
            rows.append(f"<tr><td>{html.escape(name)}</td><td>{d['device_id']}</td>"
                        f"<td colspan=\"3\">not covered: {html.escape(str(d['reason']))}</td>"
                        "</tr>")
            continue
        for j, (b, a, c, ok) in enumerate(zip(d["pp_raw"], d["pp_corrected"], d["cut"],
                                              d["passed"], strict=True)):
            colour = VERDICT_COLOURS["better" if ok else "worse"]
            warn = "; ".join(d["warnings"]) if j == 0 else ""
            rows.append(f"<tr><td>{html.escape(name)}[{j}]</td><td>{d['device_id']}</td>"
                        f"<td>{b:.3g} → {a:.3g} {html.escape(KIND_UNITS.get(d['kind'], ''))}"
                        f"</td><td style=\"background:{colour}\">"
                        f"{c:.1f}× {'PASS' if ok else 'FAIL'}</td>"
                        f"<td>{html.escape(warn)}</td></tr>")
    verdict = "PASS" if doc["passed"] else "FAIL"
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
