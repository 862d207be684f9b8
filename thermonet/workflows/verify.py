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
the file does not cover is ``not covered`` (listed, not judged).

The file is checked whole before anything is applied, and refused in one line
naming the file, the line and the parameter: a value that is not a number; a
name set twice (the autopilot would load the last; verify does not guess); a
NaN or inf in any thermal-calibration parameter (``TC_*``; ``INS_TCAL*``,
``INS_GYR/ACC<n>_ID``/``_CALTEMP``); and for every slot the firmware applies (a
PX4 slot with a non-zero ``TC_*_ID``, an ArduPilot IMU with ``INS_TCAL<n>_ENABLE``
= 1): a missing parameter, a coefficient beyond a float32, TMIN not below TMAX,
TMIN/TMAX outside :data:`PLAUSIBLE_C`, (PX4) TREF outside [TMIN, TMAX] by more
than :data:`RANGE_SLACK_C`, a device id that is not a 32-bit integer or that
two slots share.  Also refused in one line: a file from another board (no device
id of the log in the file: both lists named; or thermonet's ``# board id:`` line naming
another board than the log's own id, ``FlightLog.board_id``: two boards of one model share
their sensors' device ids), a file of the other autopilot, a
file with no thermal calibration, an output directory that is or holds an input,
and a log of which nothing can be judged (each instance's reason listed).  A log
that leaves the calibrated range [TMIN, TMAX] by more than :data:`RANGE_SLACK_C`
gets a warning per instance (the firmware holds the correction constant there).

Exit status: 0 PASS (every judged axis of every judged instance passes, and at
least one instance was judged); 3 FAIL (:data:`EXIT_FAILED`: some judged axis
fails; the report marks it); 1 refused (bad input: the one line on stderr says
why; nothing is written).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError, ThermonetError
from ..core.fileio import atomic_write_text, not_a_file, refuse_overwriting_inputs
from ..core.outdir import KINDS, check_target, sha256_file, staged_output
from ..core.version import __version__
from ..data.firmware import (
    ARDUPILOT_TEMP_REFERENCE,
    PX4_LETTER,
    PX4_PARAM_UNIT,
    PX4_SLOTS,
    ardupilot_correction,
    px4_offsets_1d,
    px4_offsets_3d,
)
from ..data.logs import FlightLog, SensorInstance, read_log
from ..data.logs.base import TEMPERATURE_RANGE_C
from ..reporting.report import _CSS, VERDICT_COLOURS
from ..scoring.metrics import binned_peak_to_peak
from .firmware_fit import check_instance, target

__all__ = ["Limits", "ParamFile", "read_param_file", "evaluate", "verify",
           "format_verify_report", "RANGE_SLACK_C", "EXIT_FAILED"]

#: How far (°C) a log may leave [TMIN, TMAX] before a warning (the scripts round TMIN/TMAX).
RANGE_SLACK_C = 0.5
#: Exit status of ``thermonet verify`` when an axis fails its limits (as ``fleet``).
EXIT_FAILED = 3
#: An axis passes "with margin" (``calibrate``: fine, not marginal) when its cut is at least
#: MARGIN times ``min_cut`` or its residual at most the floor divided by MARGIN.
MARGIN = 1.5
_PX4_LETTER = PX4_LETTER
#: The units the autopilots' formulas use, per sensor kind (what verify prints; a
#: magnetometer in µT, its TC_M* coefficients in gauss).
KIND_UNITS = {"gyro": "rad/s", "acc": "m/s²", "baro": "Pa", "mag": "µT"}
_AP_ID = {"gyro": "INS_GYR{}_ID", "acc": "INS_ACC{}_ID"}
_AP_IDS_LINE = re.compile(r"^#\s*device ids:\s*INS_TCAL(\d)\s+gyro\s+(\d+)\s+acc\s+(\d+)")
#: thermonet's header line naming the board a file was fitted on (``FlightLog.board_id``).
_BOARD_LINE = re.compile(r"^#\s*board id:\s*(\S.*?)\s*$")
#: A parameter value: a decimal number as QGroundControl and Mission Planner write them.
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")
#: ArduPilot parameters the correction reads besides INS_TCAL<n>_*: the ids and CALTEMPs.
_AP_CAL_PARAM = re.compile(r"INS_(GYR|ACC)\d?_(ID|CALTEMP)")
#: Largest magnitude of the firmware's ``float`` parameters (float32).
FLOAT32_MAX = float(np.finfo(np.float32).max)
#: TMIN / TMAX outside this range (°C) are no sensor's: the range a log's thermometer
#: reading must be in to be trusted (:data:`thermonet.data.logs.base.TEMPERATURE_RANGE_C`).
PLAUSIBLE_C = TEMPERATURE_RANGE_C


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
    #: name -> line number in the file
    line_of: dict[str, int] = field(default_factory=dict)
    #: The board the file was fitted on (thermonet's ``# board id:`` line), else None.
    board_id: str | None = None

    def where(self, name: str) -> str:
        """``FILE: line N`` of parameter ``name`` (the file alone when it has no line)."""
        no = self.line_of.get(name)
        return f"{self.path}: line {no}" if no else str(self.path)

    @property
    def ids(self) -> list[int]:
        return sorted({i for _, i in self.by_id})


def _first_param_line(text: str) -> str | None:
    for line in text.splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            return line
    return None


def _parse(p: Path, text: str, autopilot: str) -> tuple[dict[str, float], dict[str, int]]:
    """``{name: value}`` and ``{name: line number}``; a line that is not a parameter, a value
    that is not a number and a name set twice are refused naming the file, line and name."""
    params: dict[str, float] = {}
    line_of: dict[str, int] = {}
    for no, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        if autopilot == "px4":
            parts = line.split()
            if len(parts) != 5:
                raise InputError(f"{p}: line {no}: expected 5 fields (Vehicle-Id Component-Id "
                                 f"Name Value Type), got {len(parts)}")
            name, value = parts[2], parts[3]
        else:
            parts = line.replace(",", " ").split()
            if len(parts) != 2:
                raise InputError(f"{p}: line {no}: expected NAME,VALUE, got {line.strip()!r}"[:300])
            name, value = parts
        if name in line_of:
            raise InputError(f"{p}: line {no}: parameter {name} is set again (first on line "
                             f"{line_of[name]}); the autopilot would load the last value, "
                             "verify refuses to guess which one the vehicle has")
        if _NUMBER.fullmatch(value):
            v = float(value)
        elif value.lower().lstrip("+-") in ("nan", "inf", "infinity"):
            v = float(value)                  # refused below where the firmware reads it
        else:
            raise InputError(f"{p}: line {no}: parameter {name}: value {value[:40]!r} is not "
                             "a number")
        params[name] = v
        line_of[name] = no
    return params, line_of


def _is_calibration(name: str, autopilot: str) -> bool:
    """A parameter the thermal correction reads (its value must be a finite number)."""
    if autopilot == "px4":
        return name.startswith("TC_")
    return name.startswith("INS_TCAL") or bool(_AP_CAL_PARAM.fullmatch(name))


def _device_id(pf: ParamFile, name: str) -> int:
    """``TC_*_ID`` as the firmware compares it: an int32 parameter read as the uint32 device
    id (a negative value is a device id with its top bit set)."""
    v = pf.params[name]
    if v != int(v) or not -2 ** 31 <= v < 2 ** 32:
        raise InputError(f"{pf.where(name)}: parameter {name} = {v:g} is not a device id "
                         "(a 32-bit integer)")
    return int(v) & 0xFFFFFFFF


def read_param_file(path: str | Path) -> ParamFile:
    """Read a PX4 or ArduPilot parameter file (format told from its first parameter line),
    every thermal-calibration parameter checked (:func:`check_params`)."""
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
    params, line_of = _parse(p, text, autopilot)
    board = next((m.group(1) for m in map(_BOARD_LINE.match, text.splitlines()) if m), None)
    pf = ParamFile(p, autopilot, params, {}, {}, line_of, board)
    for name, v in params.items():
        if _is_calibration(name, autopilot) and not math.isfinite(v):
            raise InputError(f"{pf.where(name)}: parameter {name} is {v}: not a finite number "
                             "(the firmware would turn every corrected sample into NaN or inf)")
    if autopilot == "px4":
        if not any(k.startswith("TC_") for k in params):
            raise InputError(f"{p}: no PX4 thermal calibration (TC_*) parameters")
        for kind, t in _PX4_LETTER.items():
            # process_sensor_caldata.py writes no TC_<k>_ENABLE (its procedure sets them to 1
            # on the board first): absent means enabled, said per instance
            pf.enabled[kind] = params.get(f"TC_{t}_ENABLE", 1.0) == 1.0
            for s in range(PX4_SLOTS):
                if f"TC_{t}{s}_ID" not in params:
                    continue
                dev = _device_id(pf, f"TC_{t}{s}_ID")
                if not dev:
                    continue                       # ID 0: the firmware applies the slot to none
                if (kind, dev) in pf.by_id:
                    other = f"TC_{t}{pf.by_id[(kind, dev)]}_ID"
                    raise InputError(f"{pf.where(f'TC_{t}{s}_ID')}: parameter TC_{t}{s}_ID names "
                                     f"device {dev}, as {other} (line {line_of[other]}) does: "
                                     "which slot applies is ambiguous")
                pf.by_id[(kind, dev)] = s
                _check_slot(pf, f"TC_{t}{s}_", _px4_coefficients(t, s), reference=True)
    else:
        imus = [n for n in (1, 2, 3) if f"INS_TCAL{n}_ENABLE" in params]
        if not imus:
            raise InputError(f"{p}: no ArduPilot thermal calibration (INS_TCAL<n>_*) parameters")
        owner: dict[tuple[str, int], tuple[int, str]] = {}

        def claim(kind: str, dev: int, imu: int, what: str) -> None:
            if (kind, dev) in owner and owner[(kind, dev)][0] != imu:
                raise InputError(f"{p}: {what} names {kind} device {dev} for IMU {imu}, "
                                 f"{owner[(kind, dev)][1]} for IMU {owner[(kind, dev)][0]}: "
                                 "which IMU applies is ambiguous")
            owner[(kind, dev)] = (imu, what)

        for n in imus:
            pf.enabled[f"imu{n}"] = params[f"INS_TCAL{n}_ENABLE"] == 1.0
            for kind, fmt in _AP_ID.items():
                name = fmt.format("" if n == 1 else n)
                if name not in params:
                    continue
                dev = _device_id(pf, name)
                if dev:
                    claim(kind, dev, n, f"{name} (line {line_of[name]})")
                    pf.by_id[(kind, dev)] = n - 1
            if pf.enabled[f"imu{n}"]:
                pre = f"INS_TCAL{n}_"
                _check_slot(pf, pre, [f"{pre}{s}{k}_{a}" for s in ("GYR", "ACC")
                                      for k in (1, 2, 3) for a in "XYZ"], reference=False)
        for no, line in enumerate(text.splitlines(), start=1):
            m = _AP_IDS_LINE.match(line.strip())
            if m:
                n = int(m.group(1))
                for kind, dev in (("gyro", int(m.group(2))), ("acc", int(m.group(3)))):
                    if dev:
                        claim(kind, dev, n, f"line {no} (# device ids)")
                        pf.by_id[(kind, dev)] = n - 1
    return pf


def _px4_coefficients(t: str, s: int) -> list[str]:
    pre = f"TC_{t}{s}_"
    if t == "B":
        return [f"{pre}X{k}" for k in range(6)]
    return [f"{pre}X{k}_{i}" for k in range(4) for i in range(3)]


def _check_slot(pf: ParamFile, pre: str, coefficients: list[str], *, reference: bool) -> None:
    """A slot the firmware applies: every parameter present, finite (checked before), a
    coefficient a float32 can hold, TMIN < TMAX inside :data:`PLAUSIBLE_C`, and (PX4) TREF
    within [TMIN, TMAX] give or take :data:`RANGE_SLACK_C`."""
    need = [pre + "TMIN", pre + "TMAX", *([pre + "TREF"] if reference else []), *coefficients]
    for name in need:
        if name not in pf.params:
            raise InputError(f"{pf.path}: parameter {name} is missing (the slot {pre}* applies to "
                             "a sensor, and the board would keep whatever value it has)")
    for name in coefficients:
        if abs(pf.params[name]) > FLOAT32_MAX:
            raise InputError(f"{pf.where(name)}: parameter {name} = {pf.params[name]:g} does not "
                             "fit the firmware's float32 (it would load as inf)")
    lo, hi = pf.params[pre + "TMIN"], pf.params[pre + "TMAX"]
    for name, v in ((pre + "TMIN", lo), (pre + "TMAX", hi)):
        if not PLAUSIBLE_C[0] <= v <= PLAUSIBLE_C[1]:
            raise InputError(f"{pf.where(name)}: parameter {name} = {v:g} °C is not a "
                             f"temperature a sensor works at ({PLAUSIBLE_C[0]:g}..."
                             f"{PLAUSIBLE_C[1]:g} °C)")
    if not lo < hi:
        raise InputError(f"{pf.where(pre + 'TMIN')}: parameter {pre}TMIN = {lo:g} is not below "
                         f"{pre}TMAX = {hi:g} (line {pf.line_of[pre + 'TMAX']}): the calibrated "
                         "range is empty or reversed")
    if reference:
        ref = pf.params[pre + "TREF"]
        if not lo - RANGE_SLACK_C <= ref <= hi + RANGE_SLACK_C:
            raise InputError(f"{pf.where(pre + 'TREF')}: parameter {pre}TREF = {ref:g} is "
                             f"outside {pre}TMIN..TMAX = {lo:g}..{hi:g} °C (the polynomial's "
                             "reference lies inside the range it was fitted on)")


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
    if inst.kind == "mag":
        return None, "ArduPilot has no magnetometer temperature calibration"
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
        name = {"px4": "PX4", "ardupilot": "ArduPilot"}
        raise ThermonetError(f"{pf.path} is a {name[pf.autopilot]} parameter file; {log.path} "
                             f"is a {name[log.autopilot]} log (verify needs the same autopilot)")
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
            d.update(status="not covered", reason=why)
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
        below = t_min - float(temp.min())
        above = float(temp.max()) - t_max
        if below > RANGE_SLACK_C or above > RANGE_SLACK_C:
            d["warnings"].append(
                f"the log spans {temp.min():.1f}..{temp.max():.1f} °C, outside the calibrated "
                f"{t_min:.1f}..{t_max:.1f} °C (by {max(below, 0):.1f} °C below, "
                f"{max(above, 0):.1f} °C above): the firmware holds the correction constant "
                "there")
        d.update(status="judged", reason=None, slot=slot, range=[t_min, t_max], **judged)
        out[inst.name] = d
    if refuse_unjudged and not any(d["status"] == "judged" for d in out.values()):
        reasons = "; ".join(f"{n}: {d['status']}, {d['reason']}" for n, d in out.items())
        raise ThermonetError(f"{pf.path}: nothing of {log.path.name} can be judged "
                             f"({reasons or 'no gyro, accelerometer, barometer or magnetometer'})")
    return out


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
    insts = evaluate(pf, log, limits)
    judged = [d for d in insts.values() if d["status"] == "judged"]
    doc = {"kind": "verification", "schema": 1, "thermonet_version": __version__,
           "params_file": str(pf.path), "log": str(log.path),
           "log_sha256": sha256_file(log.path), "autopilot": log.autopilot,
           "limits": asdict(limits), "instances": insts,
           "passed": all(all(d["passed"]) for d in judged)
           and not any(d.get("offset_failures") for d in insts.values())}
    with staged_output(out, overwrite=overwrite, kind="verification") as stage:
        atomic_write_text(stage.path / "results.json",
                          json.dumps(_json_safe(doc), indent=2, allow_nan=False))
        atomic_write_text(stage.path / "report.txt", format_verify_report(doc))
        atomic_write_text(stage.path / "report.html", render_verify_html(doc))
        stage.done()
    return doc


def _json_safe(obj: Any) -> Any:
    """``obj`` with every non-finite float as None (JSON has no NaN or Infinity)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


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
             ""]
    for name, d in doc["instances"].items():
        head = f"{name:<6} id {d['device_id']:<9}"
        if d["status"] != "judged":
            lines.append(f"{head} {d['status']}: {d['reason']}")
            lines += [f"       FAIL: {w}" for w in d.get("offset_failures") or []]
            continue
        axes = ", ".join(_axis_text(d, j) for j in range(len(d["passed"])))
        unit = KIND_UNITS.get(d["kind"], "")
        lines.append(f"{head} slot {d['slot']}: binned drift p-p [{unit}] {axes}")
        lines += [f"       FAIL: {w}" for w in d.get("offset_failures") or []]
        lines += [f"       warning: {w}" for w in d["warnings"]]
    lines += ["", "PASS" if doc["passed"] else "FAIL: see the axes marked FAIL"]
    return "\n".join(lines) + "\n"


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
