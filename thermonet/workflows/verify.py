"""``thermonet verify PARAMS LOG --out DIR``: a thermal calibration already on a vehicle, checked
on a new log through the autopilot's own formula.

PARAMS is a ``px4.params`` (QGroundControl ``Vehicle-Id Component-Id Name Value
Type`` lines: thermonet's, ``Tools/process_sensor_caldata.py``'s, or a full QGC
parameter dump) or an ``ardupilot.parm`` (``NAME,VALUE`` or ``NAME VALUE`` lines:
thermonet's, ``Tools/scripts/tempcal_IMU.py``'s, or a Mission Planner dump).  The
format is told from the first parameter line (five fields: PX4).  LOG is a ULog
(PX4) or a DataFlash log (ArduPilot) of the same autopilot.

The firmware's formula (:mod:`thermonet.data.firmware`):

* PX4 ``TemperatureCompensation.cpp`` (gyro ``TC_G*``, accel ``TC_A*``, baro ``TC_B*``,
  magnetometer ``TC_M*`` — PX4 after v1.14 (v1.15+), coefficients in gauss on ``sensor_mag``,
  applied only with the magnetometer's own temperature): ``TC_<k>_ENABLE`` must be 1 (a file without it,
  as ``process_sensor_caldata.py`` writes, is applied as enabled, with a warning); the slot whose
  ``TC_<k><s>_ID`` equals the instance's device id applies; T clamped to
  [TMIN, TMAX]; offset = Σ X_k (T − TREF)^k subtracted.
* ArduPilot ``AP_InertialSensor_tempcal.cpp``: ``INS_TCAL<n>_ENABLE`` = 1; T and the
  calibration temperature (``INS_GYR<n>_CALTEMP`` / ``INS_ACC<n>_CALTEMP`` from the
  file, else from the log, else 35 °C) clamped; P(T − 35) − P(T_cal − 35)
  subtracted.  IMU n is matched by device id when the file names the ids (a full
  dump's ``INS_GYR_ID``/``INS_ACC2_ID``…, or thermonet's ``# device ids:`` line);
  ``tempcal_IMU.py`` writes none, and then IMU n is the log's IMU n (said in the report).
  A group may hold one of its IMU's two sensors (``export`` of a gyro model): the other is
  ``not covered`` (loaded, the file leaves its calibration as the board has it).

The log must be a warm-up at rest (:func:`~thermonet.workflows.verify_motion.moving_log`,
learn's test of stillness): in flight every 1 °C bin holds the vehicle's motion and every
axis reads uncorrected, so a log whose gyros are still in under 80 % of their windows is
refused in one line.

Judged per instance and axis on the log: the binned drift (peak-to-peak of the
1 °C-binned means of the output; accel and baro less their median) before and
after the correction (:func:`judge_axes`).  An axis PASSes when every corrected
sample is finite (a NaN, an inf, or a value beyond a float32 — what the firmware
would output as inf — anywhere in the axis is a FAIL) and the correction cuts
the drift at least :attr:`Limits.min_cut` times, or what is left is below the
kind's floor (:attr:`Limits.floor`: a drift that small no longer matters and its
cut is noise).  Defaults: cut 3×; floors 5e-4 rad/s (0.03 °/s), 5e-3 m/s² (0.5 mg),
1 Pa (≈8 cm), 0.5 µT (a magnetometer: about 1° of heading on a 25 µT horizontal
field) — about the bias stability of a good MEMS IMU, a baro's and a magnetometer's
noise; set them for your sensors (``--gyro-floor`` …).  The binned drift of pure noise is not
zero (the spread of ~50 bin means), so a floor far below the sensor's noise makes
quiet axes FAIL.

The binned drift cannot see a constant, so verify also judges what the file adds at the
reference temperature (PX4's ``X0``: the firmware subtracts it from every sample while the
sensor sits at TREF; :func:`offset_failures`): an axis whose ``|X0|`` is beyond
:data:`MAX_OFFSET_AT_REF` FAILs, with a line naming the parameter and why — 0.35 rad/s
(20 °/s: the largest zero-rate offset MEMS gyro datasheets allow; the scripts fit the gyro
at rest, so X0 is its bias at TREF), 2 m/s² (0.2 g: the scripts fit the accelerometer less
its median, so X0 is a drift), 1000 Pa (≈ 80 m: the pressure less its median) and 65 µT
(0.65 gauss, the strongest geomagnetic field: PX4's on-board calibrator writes X0 = 0).  A
slot that applies to an instance the log cannot judge is checked too (the value is the
file's, whatever the log).  ArduPilot's correction is zero at its calibration temperature
by construction.

An instance the file applies to but the log cannot judge is ``not judged``, with
why, never PASS: the same minimums as ``calibrate``'s
(:func:`thermonet.workflows.firmware_fit.check_instance`: at least
:data:`~thermonet.workflows.firmware_fit.MIN_SAMPLES` = 200 samples and a
:data:`~thermonet.workflows.firmware_fit.MIN_SPAN_C` = 10 °C temperature span, a
thermometer, not every sample zero, not too damaged).  A sensor of the log that
the file does not cover is ``not covered`` (listed, not judged, and named beside a PASS);
one the file holds a slot for but does not apply (its kind's ENABLE is not 1) is ``not
applied``, and FAILs: loaded, the file leaves it uncorrected.

The file is checked whole before anything is applied, and refused in one line
naming the file, the line and the parameter: a value that is not a number; a
name set twice (the autopilot would load the last; verify does not guess); a
NaN or inf in any thermal-calibration parameter (``TC_*``; ``INS_TCAL*``,
``INS_GYR/ACC<n>_ID``/``_CALTEMP``); and for every slot the firmware applies (a
PX4 slot with a non-zero ``TC_*_ID``, an ArduPilot IMU with ``INS_TCAL<n>_ENABLE``
= 1): a missing parameter, a coefficient beyond a float32, TMIN not below TMAX,
TMIN/TMAX outside :data:`~thermonet.workflows.verify_params.PLAUSIBLE_C`, (PX4) TREF outside
[TMIN, TMAX] by more than :data:`RANGE_SLACK_C`, a device id that is not a 32-bit integer or that
two slots share.  Also refused in one line: a file from another board (no device
id of the log in the file: both lists named; or thermonet's ``# board id:`` line naming
another board than the log's own id, ``FlightLog.board_id``: two boards of one model share
their sensors' device ids), a file of the other autopilot, a
file with no thermal calibration, an output directory that is or holds an input,
and a log of which nothing can be judged (each instance's reason listed).  A log
that leaves the calibrated range [TMIN, TMAX] by more than :data:`RANGE_SLACK_C`
gets a warning per instance (the firmware holds the correction constant there).

Exit status: 0 PASS (every judged axis of every judged instance passes, at least one
instance was judged, none ``not applied``); 3 FAIL (:data:`EXIT_FAILED`: some judged axis
fails, or a calibration is not applied; the report marks it); 1 refused (bad input: the one line on stderr says
why; nothing is written).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError, ThermonetError
from ..core.fileio import atomic_write_text, refuse_overwriting_inputs
from ..core.outdir import KINDS, check_target, sha256_file, staged_output
from ..core.version import __version__
from ..data.firmware import (
    ARDUPILOT_TEMP_REFERENCE,
    PX4_LETTER,
    PX4_PARAM_UNIT,
    ardupilot_correction,
    px4_offsets_1d,
    px4_offsets_3d,
)
from ..data.logs import FlightLog, SensorInstance, read_log
from ..data.logs.info import autopilot_article
from ..scoring.metrics import binned_peak_to_peak
from .firmware_fit import check_instance, target
from .verify_motion import moving_log
from .verify_params import (
    AP_SENSOR,
    FLOAT32_MAX,
    KIND_UNITS,
    RANGE_SLACK_C,
    ParamFile,
    read_param_file,
)
from .verify_report import format_verify_report, render_verify_html

# ParamFile, read_param_file, KIND_UNITS and format_verify_report are verify's own
# vocabulary (calibrate and the command line import them from here)
__all__ = ["Limits", "ParamFile", "read_param_file", "evaluate", "verify",
           "format_verify_report", "RANGE_SLACK_C", "EXIT_FAILED", "KIND_UNITS"]

#: Exit status of ``thermonet verify`` when an axis fails its limits (as ``fleet``).
EXIT_FAILED = 3
#: An axis passes "with margin" (``calibrate``: fine, not marginal) when its cut is at least
#: MARGIN times ``min_cut`` or its residual at most the floor divided by MARGIN.
MARGIN = 1.5
_PX4_LETTER = PX4_LETTER


#: Largest offset at the reference temperature (PX4's ``X0``: what the firmware subtracts
#: from every sample while the sensor sits at TREF, a constant the binned drift cannot see)
#: a thermal calibration may hold, per kind, in :data:`KIND_UNITS`, and why (module
#: docstring).  An axis whose offset is beyond it FAILs, whatever its cut.
MAX_OFFSET_AT_REF = {"gyro": 0.35, "acc": 2.0, "baro": 1000.0, "mag": 65.0}
_OFFSET_WHY = {
    "gyro": "20 °/s, the largest zero-rate offset MEMS gyro datasheets allow (MPU-6000: "
            "±20 °/s); the scripts fit the gyro at rest, so X0 is its bias at TREF",
    "acc": "0.2 g: the scripts fit the accelerometer less its median (gravity), so X0 is the "
           "drift at TREF, which no MEMS accelerometer's zero-g drift reaches",
    "baro": "≈ 80 m of altitude: the scripts fit the pressure less its median, so X0 is the "
            "drift at TREF, far below this for any barometer",
    "mag": "0.65 gauss, the strongest geomagnetic field: PX4's on-board calibrator writes "
           "X0 = 0 and the scripts fit the field less its median",
}


@dataclass
class Limits:
    """PASS/FAIL of one axis: ``cut ≥ min_cut`` or ``after ≤ floor[kind]`` (SI units), and
    (PX4) the offset at TREF within ``max_offset[kind]`` (:data:`MAX_OFFSET_AT_REF`)."""

    min_cut: float = 3.0
    floor: dict[str, float] = field(default_factory=lambda: {
        "gyro": 5e-4, "acc": 5e-3, "baro": 1.0, "mag": 0.5})
    max_offset: dict[str, float] = field(default_factory=lambda: dict(MAX_OFFSET_AT_REF))

    def check(self) -> Limits:
        if not (math.isfinite(self.min_cut) and self.min_cut > 1.0):
            raise InputError(f"--min-cut {self.min_cut}: must be a number above 1")
        for kind, v in self.floor.items():
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"the {kind} floor {v}: must be a non-negative number")
        for kind, v in self.max_offset.items():
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"the {kind} largest offset {v}: must be a positive number")
        return self


#: An instance the file holds a calibration for that the firmware does not apply (its
#: ENABLE is not 1): the file, loaded, leaves it uncorrected, so the verification FAILs.
DISABLED = "not applied"


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
            return None, (f"{DISABLED}: TC_{_PX4_LETTER[inst.kind]}{slot}_* apply to it, but "
                          f"TC_{_PX4_LETTER[inst.kind]}_ENABLE is not 1: the firmware applies "
                          "none")
        return slot, None
    if inst.kind == "baro":
        return None, "ArduPilot has no barometer temperature calibration"
    if inst.kind == "mag":
        return None, "ArduPilot has no magnetometer temperature calibration"
    if pf.by_id:
        imu = pf.by_id.get((inst.kind, inst.device_id))
        if imu is None and inst.kind not in pf.kinds.get(f"imu{inst.instance + 1}", {inst.kind}):
            imu = inst.instance           # its IMU's group is there, without this sensor
        if imu is None:
            return None, "no IMU of the file has its device id"
    else:
        imu = inst.instance
    if f"imu{imu + 1}" not in pf.enabled:
        return None, f"the file has no INS_TCAL{imu + 1}_*"
    if not pf.enabled[f"imu{imu + 1}"]:
        return None, (f"{DISABLED}: INS_TCAL{imu + 1}_* apply to it, but INS_TCAL{imu + 1}_"
                      "ENABLE is not 1: the firmware applies none")
    if inst.kind not in pf.kinds.get(f"imu{imu + 1}", {inst.kind}):
        return None, (f"the file has no INS_TCAL{imu + 1}_{AP_SENSOR[inst.kind]}*: loaded, it "
                      "leaves this sensor's calibration as the board has it")
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


def offset_failures(pf: ParamFile, kind: str, slot: int, limits: Limits
                    ) -> dict[int, str]:
    """Per axis whose offset at TREF (PX4's ``X0``) is beyond ``limits.max_offset[kind]``:
    which parameter, its value and why it cannot be a thermal calibration.  ArduPilot's
    correction is zero at its calibration temperature by construction: nothing to judge."""
    if pf.autopilot != "px4":
        return {}
    pre = f"TC_{_PX4_LETTER[kind]}{slot}_"
    names = [f"{pre}X0"] if kind == "baro" else [f"{pre}X0_{i}" for i in range(3)]
    bound, unit = limits.max_offset[kind], KIND_UNITS[kind]
    out = {}
    for j, name in enumerate(names):
        raw = pf.params[name]
        v = raw * PX4_PARAM_UNIT[kind]
        if abs(v) > bound:
            given = f"{raw:g} gauss ({v:g} {unit})" if kind == "mag" else f"{raw:g} {unit}"
            out[j] = (f"{name} = {given}: the firmware would subtract it from every sample at "
                      f"TREF; beyond the {bound:g} {unit} an offset at TREF can be "
                      f"({_OFFSET_WHY[kind]})")
    return out


def judge_axes(temperature_c: np.ndarray, y: np.ndarray, correction: np.ndarray, kind: str,
               limits: Limits) -> dict[str, list[Any]]:
    """verify's test of one instance, per axis (``calibrate``'s held-out check is this too).

    ``y`` (n, axes) the output as the script fits it (gyro as logged; accel and baro less
    their centre), ``correction`` (n, axes) what the firmware subtracts.  Per axis:
    ``pp_raw`` / ``pp_corrected`` (binned drift p-p before / after), ``cut`` (their ratio;
    inf when nothing is left, NaN when the corrected axis is not finite), ``nonfinite``
    (samples of the corrected axis that are NaN, inf or beyond a float32 — what the
    firmware would output as NaN/inf) and ``passed``: no such sample, and
    ``cut >= limits.min_cut`` or ``pp_corrected <= limits.floor[kind]``.
    """
    temp = np.asarray(temperature_c, dtype=np.float64)
    out: dict[str, list[Any]] = {"pp_raw": [], "pp_corrected": [], "cut": [], "nonfinite": [],
                                 "passed": []}
    floor = limits.floor[kind]
    with np.errstate(over="ignore", invalid="ignore"):
        for j in range(y.shape[1]):
            corrected = y[:, j] - correction[:, j]
            bad = int(np.count_nonzero(~np.isfinite(corrected)
                                       | (np.abs(corrected) > FLOAT32_MAX)))
            before = binned_peak_to_peak(temp, y[:, j])
            after = math.nan if bad else binned_peak_to_peak(temp, corrected)
            cut = math.nan if not math.isfinite(after) else (
                before / after if after > 0 else math.inf)
            ok = bad == 0 and math.isfinite(after) and (cut >= limits.min_cut or after <= floor)
            for key, v in (("pp_raw", before), ("pp_corrected", after), ("cut", cut),
                           ("nonfinite", bad), ("passed", bool(ok))):
                out[key].append(v)
    return out


def axis_grade(cut: float, after: float, passed: bool, kind: str, limits: Limits
               ) -> tuple[str, str]:
    """How safely an axis passes verify's test: ``fine`` (by :data:`MARGIN`: a cut at least
    ``MARGIN × min_cut``, or a residual at most ``floor / MARGIN``), ``marginal`` (passes,
    but within that margin: a new log's noise can tip it) or ``fails``; with why."""
    floor = limits.floor[kind]
    unit = KIND_UNITS.get(kind, "")
    if not passed:
        if not math.isfinite(after):
            return "fails", "the corrected axis is not finite"
        return "fails", (f"cut {cut:.1f}x < {limits.min_cut:g}x and {after:.3g} {unit} left "
                         f"> the {floor:g} {unit} floor")
    if cut >= MARGIN * limits.min_cut or after <= floor / MARGIN:
        return "fine", ""
    return "marginal", (f"cut {cut:.1f}x is within {MARGIN:g}x of verify's {limits.min_cut:g}x "
                        f"and {after:.3g} {unit} left is within {MARGIN:g}x of the {floor:g} "
                        f"{unit} floor: a new log may FAIL it")


def evaluate(pf: ParamFile, log: FlightLog, limits: Limits | None = None, *,
             refuse_unjudged: bool = True) -> dict[str, dict[str, Any]]:
    """Apply ``pf`` to every instance of ``log`` through the firmware's formula.

    Per instance: ``status`` (``judged`` | ``not covered`` | ``not judged``), ``reason``,
    ``slot``, per axis ``pp_raw`` / ``pp_corrected`` / ``cut`` / ``nonfinite`` / ``passed``
    (:func:`judge_axes`), ``range`` (TMIN, TMAX), ``log_range`` and ``warnings``.  An
    instance too short or too narrow to judge (calibrate's own minimums,
    :func:`thermonet.workflows.firmware_fit.check_instance`) is ``not judged``.  Refuses
    (ThermonetError) a file of the other autopilot, one whose device ids are none of the
    log's, and (unless ``refuse_unjudged`` is false: each instance then says why) a log of
    which no instance can be judged.
    """
    limits = limits or Limits()
    if pf.autopilot != log.autopilot:
        raise ThermonetError(f"{pf.path} is {autopilot_article(pf.autopilot)} parameter "
                             f"file; {log.path} is {autopilot_article(log.autopilot)} log "
                             "(verify needs the same autopilot)")
    insts = [i for i in log.instances if i.kind in _PX4_LETTER]
    log_ids = sorted({i.device_id for i in insts})
    if pf.by_id and not any((i.kind, i.device_id) in pf.by_id for i in insts):
        raise ThermonetError(f"{pf.path} belongs to another board: its device ids "
                             f"{', '.join(map(str, pf.ids))} are none of {log.path.name}'s "
                             f"({', '.join(map(str, log_ids))})")
    if pf.board_id and log.board_id and pf.board_id != log.board_id:
        raise ThermonetError(f"{pf.path} belongs to another board: fitted on board "
                             f"{pf.board_id!r}, {log.path.name} is board {log.board_id!r} (two "
                             "boards of one model share their sensors' device ids; a thermal "
                             "calibration is one board's)")
    out: dict[str, dict[str, Any]] = {}
    for inst in insts:
        slot, why = _slot(pf, inst)
        d: dict[str, Any] = {"kind": inst.kind, "device_id": inst.device_id,
                             "n_samples": inst.n_samples, "warnings": []}
        if inst.temperature_c is not None and inst.n_samples:
            temp = np.asarray(inst.temperature_c, dtype=np.float64)
            d["log_range"] = [float(temp.min()), float(temp.max())]
        if slot is None:
            status, _, reason = str(why).partition(": ") if str(why).startswith(DISABLED) \
                else ("not covered", "", why)
            d.update(status=status, reason=reason)
            out[inst.name] = d
            continue
        bad_offsets = offset_failures(pf, inst.kind, slot, limits)  # whatever the log
        d["offset_failures"] = list(bad_offsets.values())
        why = check_instance(inst, log.autopilot)   # the same minimums as calibrate's
        if inst.kind == "mag" and inst.temperature_c is None:
            why = ("no temperature of its own: PX4 applies TC_M* with the magnetometer's own "
                   "temperature, and applies nothing to this one")
        if why is not None:
            d.update(status="not judged", reason=why, slot=slot)
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
        judged = judge_axes(temp, y, corr, inst.kind, limits)
        for j in bad_offsets:     # a constant the binned drift cannot see: FAILs the axis
            judged["passed"][j] = False
        d["warnings"] += _range_warnings(temp, t_min, t_max)
        d.update(status="judged", reason=None, slot=slot, range=[t_min, t_max], **judged)
        out[inst.name] = d
    if refuse_unjudged and not any(d["status"] == "judged" for d in out.values()):
        reasons = "; ".join(f"{n}: {d['status']}, {d['reason']}" for n, d in out.items())
        raise ThermonetError(f"{pf.path}: nothing of {log.path.name} can be judged "
                             f"({reasons or 'no gyro, accelerometer, barometer or magnetometer'})")
    return out


def _range_warnings(temp: np.ndarray, t_min: float, t_max: float) -> list[str]:
    """The log's span past the calibrated [t_min, t_max] by more than RANGE_SLACK_C, naming
    only the side (or sides) it passes."""
    past = [f"{v:.1f} °C {side}" for v, side in ((t_min - float(temp.min()), "below"),
                                                  (float(temp.max()) - t_max, "above"))
            if v > RANGE_SLACK_C]
    return [f"the log spans {temp.min():.1f}..{temp.max():.1f} °C, outside the calibrated "
            f"{t_min:.1f}..{t_max:.1f} °C (by {' and '.join(past)}): the firmware holds the "
            "correction constant there"] if past else []


def verify(params_path: str | Path, log_path: str | Path, out_dir: str | Path, *,
           limits: Limits | None = None, overwrite: bool = False) -> dict[str, Any]:
    """Check ``params_path`` on ``log_path``; write ``out_dir`` (results.json, report.txt,
    report.html) whole or not at all; return the results (``passed``: every judged axis)."""
    limits = (limits or Limits()).check()
    pf = read_param_file(params_path)
    log = read_log(log_path)
    out = Path(out_dir)
    refuse_overwriting_inputs(out, [pf.path, log.path], owned=KINDS["verification"])
    check_target(out, overwrite, "verification")
    digest = sha256_file(log.path)
    moving = moving_log(log)
    if moving:
        fitted = trained_on(pf.path, digest)
        raise InputError(f"{log.path}: {moving}"
                         + (" (and the file was fitted on it)" if fitted else "")
                         + " — verify judges a warm-up at rest (the drift against temperature, "
                         "which motion hides): give a log of the vehicle still while it warms "
                         "up, e.g. powered on from cold on the bench")
    insts = evaluate(pf, log, limits)
    judged = [d for d in insts.values() if d["status"] == "judged"]
    doc = {"kind": "verification", "schema": 1, "thermonet_version": __version__,
           "params_file": str(pf.path), "log": str(log.path),
           "log_sha256": digest, "trained_on": trained_on(pf.path, digest),
           "autopilot": log.autopilot,
           "limits": asdict(limits), "instances": insts,
           "passed": all(all(d["passed"]) for d in judged)
           and not any(d.get("offset_failures") or d["status"] == DISABLED
                       for d in insts.values())}
    with staged_output(out, overwrite=overwrite, kind="verification") as stage:
        atomic_write_text(stage.path / "results.json",
                          json.dumps(_json_safe(doc), indent=2, allow_nan=False))
        atomic_write_text(stage.path / "report.txt", format_verify_report(doc))
        atomic_write_text(stage.path / "report.html", render_verify_html(doc))
        stage.done()
    return doc


def trained_on(params_path: Path, digest: str) -> str | None:
    """The log, by the name ``calibrate`` or ``learn`` recorded, whose bytes (SHA-256
    ``digest``) the parameter file was fitted on, where that run's results.json lies beside it
    (None: not one of them, or no readable record there — nothing read is trusted: a record
    without matching ``logs`` and ``logs_sha256`` lists is ignored)."""
    try:
        rec = json.loads((params_path.parent / "results.json").read_text())
    except (OSError, ValueError):
        return None
    names, sums = (rec.get(k) if isinstance(rec, dict) else None
                   for k in ("logs", "logs_sha256"))
    if not (isinstance(names, list) and isinstance(sums, list) and len(names) == len(sums)
            and all(isinstance(x, str) for x in names + sums)):
        return None
    return next((n for n, h in zip(names, sums, strict=True) if h == digest), None)


def _json_safe(obj: Any) -> Any:
    """``obj`` with every non-finite float as None (JSON has no NaN or Infinity)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj
