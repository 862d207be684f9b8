"""The parameter file ``thermonet verify`` (and ``calibrate``'s held-out check) applies: a
PX4 ``px4.params`` or an ArduPilot ``ardupilot.parm`` read (:func:`read_param_file`, the
format told from its first parameter line) and checked whole before anything is applied —
every rule :mod:`thermonet.workflows.verify`'s docstring lists, refused in one line naming the
file, the line and the parameter — into a :class:`ParamFile`: the values, which slot or IMU
applies to which device id, what is enabled, the board it was fitted on.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fileio import not_a_file
from ..data.firmware import PX4_LETTER, PX4_SLOTS
from ..data.logs.base import TEMPERATURE_RANGE_C

__all__ = ["ParamFile", "read_param_file", "KIND_UNITS", "RANGE_SLACK_C", "PLAUSIBLE_C",
           "FLOAT32_MAX", "AP_SENSOR"]

_PX4_LETTER = PX4_LETTER

#: How far (°C) a log may leave [TMIN, TMAX] before a warning (the scripts round TMIN/TMAX).
RANGE_SLACK_C = 0.5
#: The units the autopilots' formulas use, per sensor kind (what verify prints; a
#: magnetometer in µT, its TC_M* coefficients in gauss).
KIND_UNITS = {"gyro": "rad/s", "acc": "m/s²", "baro": "Pa", "mag": "µT"}
_AP_ID = {"gyro": "INS_GYR{}_ID", "acc": "INS_ACC{}_ID"}
#: ArduPilot's coefficient group of each sensor kind within ``INS_TCAL<n>_``.
AP_SENSOR = {"gyro": "GYR", "acc": "ACC"}
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
    #: ArduPilot: the sensor kinds each enabled ``INS_TCAL<n>`` writes ("imu<n>" -> gyro,
    #: acc): a file may hold one of an IMU's two (``export`` of a gyro model), leaving the
    #: other's parameters as the board has them.
    kinds: dict[str, set[str]] = field(default_factory=dict)

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
    try:   # utf-8-sig: a byte-order mark (Windows Notepad saves one) is not a character
        text = p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{p}: cannot be read as a parameter file ({err})") from err
    first = _first_param_line(text)
    if first is None:
        raise InputError(f"{p}: no parameter lines")
    autopilot = "px4" if len(first.split()) == 5 else "ardupilot"
    if autopilot == "ardupilot" and len(first.replace(",", " ").split()) != 2:
        no = text.splitlines().index(first) + 1
        raise InputError(f"{p}: line {no}: {first.strip()[:80]!r} is neither a PX4 parameter "
                         "line (Vehicle-Id Component-Id Name Value Type, tab-separated) nor an "
                         "ArduPilot one (NAME,VALUE or NAME VALUE)")
    params, line_of = _parse(p, text, autopilot)
    board = next((m.group(1) for m in map(_BOARD_LINE.match, text.splitlines()) if m), None)
    pf = ParamFile(p, autopilot, params, {}, {}, line_of, board)
    for name, v in params.items():
        if _is_calibration(name, autopilot) and not math.isfinite(v):
            raise InputError(f"{pf.where(name)}: parameter {name} is {v}: not a finite number "
                             "(the firmware would turn every corrected sample into NaN or inf)")
    if autopilot == "px4":
        _px4_slots(pf)
    else:
        _ardupilot_imus(pf, text)
    return pf


def _px4_slots(pf: ParamFile) -> None:
    """A PX4 file's slots: which device each applies to (``by_id``), what is enabled, each
    slot the firmware applies checked (:func:`_check_slot`)."""
    p, params, line_of = pf.path, pf.params, pf.line_of
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


def _ardupilot_imus(pf: ParamFile, text: str) -> None:
    """An ArduPilot file's IMUs: which devices each applies to (``by_id``: a dump's
    ``INS_*_ID``, thermonet's ``# device ids:`` lines), what is enabled, the sensors each
    enabled IMU writes (``kinds``), each checked (:func:`_check_slot`)."""
    p, params, line_of = pf.path, pf.params, pf.line_of
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
            pf.kinds[f"imu{n}"] = _ardupilot_kinds(pf, n)
            pre = f"INS_TCAL{n}_"
            _check_slot(pf, pre, [f"{pre}{AP_SENSOR[kind]}{k}_{a}"
                                  for kind in sorted(pf.kinds[f"imu{n}"])
                                  for k in (1, 2, 3) for a in "XYZ"], reference=False)
    for no, line in enumerate(text.splitlines(), start=1):
        m = _AP_IDS_LINE.match(line.strip())
        if m:
            n = int(m.group(1))
            for kind, dev in (("gyro", int(m.group(2))), ("acc", int(m.group(3)))):
                if dev:
                    claim(kind, dev, n, f"line {no} (# device ids)")
                    pf.by_id[(kind, dev)] = n - 1


def _ardupilot_kinds(pf: ParamFile, n: int) -> set[str]:
    """The sensors ``INS_TCAL<n>`` writes: a kind with any of its nine coefficients (the
    rest then required by :func:`_check_slot`); refused where it writes neither."""
    pre = f"INS_TCAL{n}_"
    kinds = {kind for kind, s in AP_SENSOR.items()
             if any(f"{pre}{s}{k}_{a}" in pf.params for k in (1, 2, 3) for a in "XYZ")}
    if not kinds:
        raise InputError(f"{pf.where(pre + 'ENABLE')}: parameter {pre}ENABLE = 1 but the file "
                         f"has none of {pre}GYR* / {pre}ACC* (the coefficients it enables): "
                         "the board would apply whatever values it has")
    return kinds


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
