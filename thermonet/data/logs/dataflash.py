"""ArduPilot DataFlash (``.bin``) reader, through pymavlink's ``DFReader_binary``.

Messages read (``libraries/AP_InertialSensor/AP_InertialSensor_Logging.cpp``,
``libraries/AP_Baro/AP_Baro_Logging.cpp``): ``IMU`` (multi-instance form with an
``I`` field, or the older ``IMU``/``IMU2``/``IMU3``), ``BARO`` (``I`` field or
``BARO``/``BAR2``/``BAR3``), each with its own temperature (``T``, ``Temp``).
``TCLR`` (``TimeUS, I, SType, Temp, X, Y, Z``: the sensor-frame samples
ArduPilot logs while it learns a calibration on board, ``SType`` 0 accel, 1 gyro)
is used for an IMU that has no ``IMU`` messages, as ``tempcal_IMU.py --tclr``
does; it is logged before any temperature correction, so nothing is undone.
Units as logged: gyro rad/s, accel m/s², pressure Pa.  Device ids from
``INS_GYR_ID`` / ``INS_GYR2_ID`` / ``INS_GYR3_ID`` (``INS_ACC*_ID``, ``BARO*_DEVID``,
``COMPASS_DEV_ID`` / ``COMPASS_DEV_ID2`` / ``COMPASS_DEV_ID3``).  The board's own id
(``FlightLog.board_id``, which two boards of one model do not share) from the system-id
``MSG`` line every log starts with (:data:`SYSTEM_ID`).

Magnetometers (``libraries/AP_Compass/AP_Compass.cpp``, ``Compass::Log_Write``):
``MAG`` (``I`` field) or ``MAG``/``MAG2``/``MAG3``, ``MagX..Z`` in milligauss (the
format's multiplier, 1e-3 gauss), converted to µT (× 0.1).  The logged field is
after the compass calibration (``Compass::correct_field``: ``(raw + offsets) ·
scale``, the soft-iron matrix of ``COMPASS_DIA*`` / ``COMPASS_ODI*``, then ``+ motor
offsets``); thermonet undoes it with the offsets the message carries (``OfsX..Z``,
``MOX..Z``, ``MOfsX..Z`` in older logs) and the ``COMPASS_SCALE*`` / ``DIA*`` / ``ODI*`` parameters, so the
instance is the field as the driver gave it (already rotated to the board frame by
``COMPASS_ORIENT``, which is not undone).  ``MAG`` has no temperature: an ArduPilot
magnetometer is always calibrated against a lent thermometer, and only as ONNX / C —
ArduPilot has no magnetometer temperature-calibration parameters.

Calibration already applied, undone as ArduPilot's own
``Tools/scripts/tempcal_IMU.py`` does (``IMUfit``): the logged ``IMU`` values
are in the board frame after the offset/scale calibration and, where
``INS_TCALn_ENABLE = 1``, after the temperature correction
(``AP_InertialSensor_tempcal.cpp``, ``TCal::correct_sensor``: ``v -= P(T-35) -
P(T_cal-35)``, T and T_cal clamped to TMIN..TMAX).  thermonet rotates back by
the inverse of ``AHRS_ORIENTATION`` (pymavlink's ``Vector3.rotate_by_inverse_id``,
as tempcal_IMU.py), then adds the temperature correction back — so the
instance is the raw sensor-frame output.  Constant offsets (``INS_GYROFFS``,
``INS_ACCOFFS``) only shift the drift by a constant, which the fits absorb (and
ArduPilot's polynomial has no constant term), so they are left; an
accelerometer scale other than 1 is undone (the drift is fitted before it).
"""

from __future__ import annotations

import contextlib
import io
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import InputError, counted
from ..firmware import ardupilot_correction
from .base import (
    FlightLog,
    SensorInstance,
    byte_ranges_note,
    clock_jump_back,
    drop_phantoms,
    flag_kelvin,
    screen_samples,
    time_gaps,
)

__all__ = ["read_dataflash", "ardupilot_tcal_correction", "orientation_matrix", "system_id",
           "SYSTEM_ID"]

_IMU_NAMES = {"IMU": 0, "IMU2": 1, "IMU3": 2}
_BARO_NAMES = {"BARO": 0, "BAR2": 1, "BAR3": 2}
_MAG_NAMES = {"MAG": 0, "MAG2": 1, "MAG3": 2}
#: µT per logged unit of ``MAG.MagX`` (milligauss).
_UT_PER_MGAUSS = 0.1
_TEMP_REF = 35.0


def orientation_matrix(orientation: int) -> np.ndarray:
    """Matrix R with ``R @ v`` = ``v.rotate_by_inverse_id(orientation)`` (board → sensor frame)."""
    from pymavlink.rotmat import Vector3

    cols = []
    for e in np.eye(3):
        v = Vector3(*e).rotate_by_inverse_id(int(orientation))
        if v is None:
            raise InputError(f"AHRS_ORIENTATION {orientation} is not a rotation pymavlink knows")
        cols.append([v.x, v.y, v.z])
    return np.array(cols).T


def ardupilot_tcal_correction(params: dict[str, float], imu: int, kind: str,
                              temperature_c: np.ndarray) -> np.ndarray | None:
    """What ``TCal::correct_sensor`` subtracted, (n, 3) SI, or None when the slot is off.

    ``imu`` is 1-based (``INS_TCAL1``); ``kind`` ``gyro`` or ``acc``; T_cal is
    ``INS_GYR<n>_CALTEMP`` / ``INS_ACC<n>_CALTEMP`` (the offset calibration's temperature).
    """
    pre = f"INS_TCAL{imu}_"
    if params.get(pre + "ENABLE", 0.0) != 1.0:
        return None
    stype = "GYR" if kind == "gyro" else "ACC"
    names = [pre + "TMIN", pre + "TMAX"] + [f"{pre}{stype}{k}_{ax}" for k in (1, 2, 3)
                                            for ax in "XYZ"]
    full = {n: params.get(n, 0.0) for n in names}
    tcal = params.get(f"INS_{stype}{imu}_CALTEMP", _TEMP_REF)
    return ardupilot_correction(full, kind, temperature_c, tcal, imu=imu)


def _id(params: dict[str, float], kind: str, idx: int) -> int:
    n = "" if idx == 0 else str(idx + 1)
    name = {"gyro": f"INS_GYR{n}_ID", "acc": f"INS_ACC{n}_ID", "baro": f"BARO{idx + 1}_DEVID",
            "mag": f"COMPASS_DEV_ID{n}"}
    return int(params.get(name[kind], 0))


def _mag_raw(params: dict[str, float], idx: int, field: np.ndarray, ofs: np.ndarray,
             motor: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """The driver's field from the logged one: ``Compass::correct_field`` undone (see the
    module), (n, 3) in the logged unit; with a note of what was undone."""
    n = "" if idx == 0 else str(idx + 1)
    dia = np.array([params.get(f"COMPASS_DIA{n}_{a}", 1.0) for a in "XYZ"])
    odi = np.array([params.get(f"COMPASS_ODI{n}_{a}", 0.0) for a in "XYZ"])
    scale = params.get(f"COMPASS_SCALE{n}", 1.0) or 1.0
    v = field - motor
    undone = []
    if np.any(motor != 0):
        undone.append("motor offsets (MOX..Z)")
    if np.all(dia != 0) and (np.any(dia != 1.0) or np.any(odi != 0.0)):
        mat = np.array([[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]],
                        [odi[1], odi[2], dia[2]]])
        v = v @ np.linalg.inv(mat).T
        undone.append(f"soft-iron matrix (COMPASS_DIA{n}/ODI{n})")
    if scale != 1.0 and 0.0 < scale:
        v = v / scale
        undone.append(f"COMPASS_SCALE{n}")
    if np.any(ofs != 0):
        undone.append("offsets (OfsX..Z)")
    v = v - ofs
    return v, ([f"compass calibration undone: {', '.join(undone)}"] if undone else [])


def _ranges(offsets: list[int]) -> list[tuple[int, int]]:
    """Consecutive byte offsets grouped into [start, end) ranges."""
    out: list[tuple[int, int]] = []
    for o in sorted(set(offsets)):
        if out and o == out[-1][1]:
            out[-1] = (out[-1][0], o + 1)
        else:
            out.append((o, o + 1))
    return out


def _merge(ranges: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Byte ranges, touching or overlapping ones joined."""
    out: list[tuple[int, int]] = []
    for a, b in sorted(ranges):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def _open_reader(path: Path) -> tuple[Any, str]:
    """pymavlink's reader with its index built in Python (its warnings are then Python
    prints, captured and returned: the C indexer writes them to the process's stderr)."""
    from pymavlink import DFReader

    class Reader(DFReader.DFReader_binary):
        def init_arrays_fast(self, progress_callback: Any = None) -> None:
            self.init_arrays(progress_callback)

    chatter = io.StringIO()
    with contextlib.redirect_stderr(chatter), contextlib.redirect_stdout(chatter):
        reader = Reader(str(path), zero_time_base=True)
    return reader, chatter.getvalue()


def _messages(reader: Any, types: list[str], sequential: bool, chatter: io.StringIO) -> Any:
    """Yield the messages of ``types``: through pymavlink's index, or — when the index
    stopped at a damaged message — by parsing every message in order, which resynchronises
    on the next message header after damage."""
    wanted = set(types)
    while True:
        with contextlib.redirect_stderr(chatter), contextlib.redirect_stdout(chatter):
            m = reader.recv_msg() if sequential else reader.recv_match(type=types)
        if m is None:
            return
        if not sequential or m.get_type() in wanted:
            yield m


def read_dataflash(path: str | Path) -> FlightLog:
    """Read an ArduPilot DataFlash log into its sensor instances and parameters.

    Raises
    ------
    InputError
        Not a DataFlash log, truncated before any sensor data, no IMU/BARO
        messages, no temperature, only zeros (one line naming the file).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError.at(path, "file not found")
    with open(path, "rb") as fh:
        head = fh.read(3)
    if len(head) < 3 or head[:2] != b"\xa3\x95":
        hint = ": it starts as a PX4 ULog does (name it .ulg)" if head == b"ULo" else ""
        raise InputError.at(path, f"not an ArduPilot DataFlash log (no 0xA3 0x95 header){hint}")
    size = path.stat().st_size
    try:
        reader, index_chatter = _open_reader(path)
    except Exception as err:  # noqa: BLE001 — pymavlink raises anything on a corrupt file
        # the 0xA3 0x95 header is there: what follows is a damaged DataFlash log
        raise InputError.at(path, "damaged: a DataFlash header followed by messages that cannot "
                            f"be parsed ({type(err).__name__}: "
                            f"{str(err).splitlines()[0] if str(err) else ''})") from None
    # pymavlink's index stops at the first message of an unknown type (a damaged type byte),
    # silently dropping the rest of the log: read every message in order instead
    stop = re.search(r"unknown msg type \S+ \(\d+\) at (\d+)", index_chatter)
    chatter = io.StringIO()
    got = _read_messages(path, reader, stop is not None, chatter)
    cut = _cut_short(reader, stop is not None)
    damage, unread = _damage(index_chatter, chatter.getvalue(), stop, got.skipped, size, cut)
    instances = _instances(got.rows, got.params, path)
    have_imu = {idx for (group, idx) in got.rows if group == "imu"}
    instances += _tclr_instances(got.tclr, got.params, have_imu)
    instances, phantoms = drop_phantoms(instances, "ardupilot")
    damage += phantoms
    names = sorted(got.params)
    if names and not any(re.match(r"^(INS_|AHRS_)", n) for n in names):
        raise InputError.at(path, "no INS_* parameters: " + (
            f"damaged ({'; '.join(damage)})" if damage else "not an ArduPilot log"))
    return FlightLog(path=path, autopilot="ardupilot", instances=instances, params=got.params,
                     notes=time_gaps(instances), damage=damage, unread_fraction=unread,
                     board_id=got.board_id).check()


#: ArduPilot's system-id line (``Util::get_system_id``, logged as a ``MSG`` at the start of
#: every log by ``LoggerMessageWriter_WriteSysInfo``): the board's short name, then its MCU's
#: 12-byte unique id in three eight-digit hex words.
SYSTEM_ID = re.compile(r"^\s*(\S+) ([0-9A-Fa-f]{8}) ([0-9A-Fa-f]{8}) ([0-9A-Fa-f]{8})\s*$")


def system_id(message: str) -> str | None:
    """The board's own id (name and unique id, as logged) where ``message`` is ArduPilot's
    system-id line, else None."""
    m = SYSTEM_ID.match(message.replace("\x00", ""))
    return " ".join(m.groups()) if m else None


@dataclass
class _Messages:
    """What a DataFlash log's messages hold: sensor rows per (group, instance), TCLR rows per
    (kind, instance), the parameters, and how many messages did not parse."""

    rows: dict[tuple[str, int], list[list[float]]] = field(default_factory=dict)
    tclr: dict[tuple[str, int], list[list[float]]] = field(default_factory=dict)
    params: dict[str, float] = field(default_factory=dict)
    skipped: int = 0
    board_id: str | None = None


def _read_messages(path: Path, reader: Any, sequential: bool, chatter: io.StringIO
                   ) -> _Messages:
    """Every PARM, TCLR, IMU, BARO and MAG message, in log order, and the first system-id
    MSG line (a corrupt message that stops the reader is an :class:`InputError` naming its
    byte)."""
    got = _Messages()
    types = ["PARM", "TCLR", "MSG"] + list(_IMU_NAMES) + list(_BARO_NAMES) + list(_MAG_NAMES)
    messages = _messages(reader, types, sequential, chatter)
    while True:
        try:
            m = next(messages, None)
        except Exception as err:  # noqa: BLE001
            raise InputError.at(path, f"corrupt DataFlash message at byte "
                                f"{getattr(reader, 'offset', 0):,} ({type(err).__name__}: "
                                f"{str(err).splitlines()[0] if str(err) else ''})") from None
        if m is None:
            return got
        mtype = m.get_type()
        try:
            if mtype == "PARM":
                got.params[str(m.Name)] = float(m.Value)
                continue
            if mtype == "MSG":
                got.board_id = got.board_id or system_id(str(m.Message))
                continue
            d = m.to_dict()
            _ = [float(d[k]) for k in ("TimeUS", "I") if k in d]
        except (AttributeError, KeyError, TypeError, ValueError, UnicodeDecodeError):
            got.skipped += 1    # a message whose fields do not parse: damaged, skipped
            continue
        _add_row(got, mtype, d)


def _add_row(got: _Messages, mtype: str, d: dict[str, Any]) -> None:
    """One parsed TCLR, IMU, MAG or BARO message's row (time in s first)."""
    if mtype == "TCLR":
        kind = "acc" if int(d["SType"]) == 0 else "gyro"
        got.tclr.setdefault((kind, int(d["I"])), []).append(
            [d["TimeUS"] * 1e-6, d["X"], d["Y"], d["Z"], d["Temp"]])
    elif mtype in _IMU_NAMES:
        idx = int(d["I"]) if "I" in d else _IMU_NAMES[mtype]
        got.rows.setdefault(("imu", idx), []).append(
            [d["TimeUS"] * 1e-6, d["GyrX"], d["GyrY"], d["GyrZ"], d["AccX"], d["AccY"],
             d["AccZ"], d.get("T", np.nan)])
    elif mtype in _MAG_NAMES:
        idx = int(d["I"]) if "I" in d else _MAG_NAMES[mtype]
        got.rows.setdefault(("mag", idx), []).append(
            [d["TimeUS"] * 1e-6] + [d.get(k, 0.0) for k in (
                "MagX", "MagY", "MagZ", "OfsX", "OfsY", "OfsZ")]
            + [d.get(k, d.get(f"MOfs{k[-1]}", 0.0)) for k in ("MOX", "MOY", "MOZ")]
            + [np.nan])         # motor offsets: MOX..Z (MOfsX..Z in older logs)
    else:
        idx = int(d["I"]) if "I" in d else _BARO_NAMES[mtype]
        got.rows.setdefault(("baro", idx), []).append(
            [d["TimeUS"] * 1e-6, d["Press"], d.get("Temp", np.nan)])


def _cut_short(reader: Any, sequential: bool) -> tuple[int, int] | None:
    """The [start, end of file) bytes of a last message the file ends inside (a log cut
    short, as a download or a power loss leaves it), else None.

    pymavlink stops there without a word (it takes the last 528 bytes of a log for
    padding).  Through its index: the message that starts last, where it would end.  Read
    message by message: the reader stops just past the cut message's header, or before the
    last one or two bytes of a header.  A tail of a byte or two that starts no header is
    padding, not a cut."""
    size = int(reader.data_len)
    data = reader.data_map
    head = bytes([reader.HEAD1, reader.HEAD2])
    if sequential:
        at = int(reader.offset)
        if at >= size:
            return None
        if at >= 3 and bytes(data[at - 3:at - 1]) == head and data[at - 1] in reader.formats:
            return at - 3, size
        return (at, size) if head.startswith(bytes(data[at:size])) else None
    last = max(((offs[-1], t) for t, offs in enumerate(reader.offsets)
                if offs and t in reader.formats), default=None)
    if last is None:
        return None
    end = last[0] + int(reader.formats[last[1]].len)
    if end > size:
        return last[0], size
    if end < size and size - end < len(head) + 1 and head.startswith(bytes(data[end:size])):
        return end, size
    return None


def _damage(index_chatter: str, read_chatter: str, stop: re.Match[str] | None, skipped: int,
            size: int, cut: tuple[int, int] | None = None) -> tuple[list[str], float]:
    """The damage notes from pymavlink's chatter and a last message cut short (``cut``:
    :func:`_cut_short`), and the fraction of the file unread."""
    damage: list[str] = []
    if stop is not None:   # the sequential pass reports every damaged stretch itself
        bad = _merge([(int(o), int(o) + int(n)) for n, o in re.findall(
            r"Skipped (\d+) bad bytes in log at offset (\d+)", read_chatter)])
        damage.append(f"a message of unknown type at byte {int(stop.group(1)):,} (pymavlink's "
                      "index stops there; the rest was read message by message)")
    else:
        bad = _ranges([int(o) for o in re.findall(r"bad header .* at (\d+)",
                                                  index_chatter + read_chatter)])
    if cut is not None:
        bad = _merge([*bad, cut])
    if bad:
        damage.append(byte_ranges_note(bad, size))
    if skipped:
        damage.append(f"{counted(skipped, 'message')} whose fields do not parse skipped")
    return damage, sum(b - a for a, b in bad) / max(size, 1)


def _instances(rows: dict[tuple[str, int], list[list[float]]],
               params: dict[str, float], path: Path) -> list[SensorInstance]:
    """The sensor instances of the IMU, BARO and MAG rows, damaged samples dropped and
    counted, sorted in time."""
    orient = int(params.get("AHRS_ORIENTATION", 0))
    instances: list[SensorInstance] = []
    for (group, idx), data in sorted(rows.items()):
        a = np.asarray(data, dtype=np.float64)
        n_read = a.shape[0]
        has_temp = bool(np.any(np.isfinite(a[:, -1])))  # NaN throughout: no thermometer
        if group == "mag":
            raw, mag_notes = _mag_raw(params, idx, a[:, 1:4], a[:, 4:7], a[:, 7:10])
            raw = raw * _UT_PER_MGAUSS
            keep, dropped = screen_samples("mag", a[:, 0], raw, None)
            _refuse_jump(path, a[keep, 0], f"MAG instance {idx}")
            order = np.argsort(a[keep, 0], kind="stable")
            inst = SensorInstance("mag", idx, _id(params, "mag", idx), a[keep, 0][order], None,
                                  raw[keep][order], notes=[
                                      "field logged in milligauss, converted to µT"] + mag_notes)
            inst.mark_damage(n_read, dropped)
            instances.append(inst)
            continue
        kind0 = "baro" if group == "baro" else "gyro"
        keep, dropped = screen_samples(kind0, a[:, 0], a[:, 1:-1] if group == "baro"
                                       else a[:, 1:4], a[:, -1] if has_temp else None)
        if group != "baro":   # the accelerometer's values of the same IMU messages
            keep2, dropped2 = screen_samples("acc", a[:, 0], a[:, 4:7], None)
            dropped += [x for x in dropped2 if x not in dropped]
            keep &= keep2
        a = a[keep]
        _refuse_jump(path, a[:, 0], f"{'BARO' if group == 'baro' else 'IMU'} instance {idx}")
        a = a[np.argsort(a[:, 0], kind="stable")]
        t, temp = a[:, 0], a[:, -1]
        temperature = temp if has_temp and a.shape[0] else None
        if group == "baro":
            inst = SensorInstance("baro", idx, _id(params, "baro", idx), t, temperature,
                                  a[:, 1:2], notes=[])
            inst.mark_damage(n_read, dropped)
            flag_kelvin(inst)
            instances.append(inst)
            continue
        for inst in _imu_instances(params, idx, a, temperature, orient):
            inst.mark_damage(n_read, dropped)
            flag_kelvin(inst)
            instances.append(inst)
    return instances


def _refuse_jump(path: Path, time_s: np.ndarray, what: str) -> None:
    """Refuse (one line naming the log) a clock that steps back (:func:`clock_jump_back`)."""
    jump = clock_jump_back(time_s, what)
    if jump:
        raise InputError.at(path, jump)


def _imu_instances(params: dict[str, float], idx: int, a: np.ndarray,
                   temperature: np.ndarray | None, orient: int) -> list[SensorInstance]:
    """An IMU's gyro and accelerometer, in the sensor frame, with the log's accelerometer
    scale and temperature corrections undone."""
    rot = orientation_matrix(orient) if orient else None
    t = a[:, 0]
    out = []
    for kind, cols in (("gyro", slice(1, 4)), ("acc", slice(4, 7))):
        v = a[:, cols].copy()
        notes: list[str] = []
        if rot is not None:
            v = v @ rot.T
            notes.append(f"rotated back to the sensor frame (AHRS_ORIENTATION {orient})")
        if kind == "acc":
            n = "" if idx == 0 else str(idx + 1)
            scale = np.array([params.get(f"INS_ACC{n}SCAL_{ax}", 1.0) for ax in "XYZ"])
            if np.all(scale > 0) and np.any(scale != 1.0):
                v = v / scale
                notes.append("accelerometer scale calibration (INS_ACC*SCAL) undone")
        if temperature is not None:
            corr = ardupilot_tcal_correction(params, idx + 1, kind, temperature)
            if corr is not None:
                v = v + corr
                notes.append(f"INS_TCAL{idx + 1}_ENABLE=1: the temperature correction the "
                             "log applied was added back")
        out.append(SensorInstance(kind, idx, _id(params, kind, idx), t, temperature, v,
                                  notes=notes))
    return out


def _tclr_instances(tclr: dict[tuple[str, int], list[list[float]]], params: dict[str, float],
                    have_imu: set[int]) -> list[SensorInstance]:
    """Instances from TCLR messages, for IMUs that logged no IMU messages."""
    out = []
    for (kind, idx), data in sorted(tclr.items()):
        if idx in have_imu:
            continue
        a = np.asarray(data, dtype=np.float64)
        a = a[np.all(np.isfinite(a), axis=1)]
        a = a[np.argsort(a[:, 0], kind="stable")]
        out.append(SensorInstance(kind, idx, _id(params, kind, idx), a[:, 0], a[:, -1],
                                  a[:, 1:4], notes=["from TCLR (sensor frame, before "
                                                    "temperature correction)"]))
    return out
