"""Write a :class:`~thermonet.data.logs.base.FlightLog` as a PX4 ULog or an ArduPilot DataFlash log.

Used by the simulator (``thermonet simulate fc-board --out FILE.ulg|.bin``) so
that simulated boards go through the same readers — and the autopilots' own
tools (pyulog, pymavlink) — as real logs.

ULog (PX4 ``docs``: "ULog File Format"): the 16-byte header (``ULog`` magic
``55 4c 6f 67 01 12 35``, version 1, start timestamp µs), a flag-bits
message ``B``, format messages ``F`` (``sensor_gyro:uint64_t timestamp;...``),
info messages ``I`` (``sys_name``; ``sys_uuid``, the board's own id), parameters
``P`` (``int32_t`` / ``float``), subscriptions ``A`` (multi id, msg id, topic) and data
``D``.  Fields as in PX4's ``msg/SensorGyro.msg`` / ``SensorAccel.msg`` / ``SensorBaro.msg`` /
``SensorMag.msg`` (``timestamp``, ``timestamp_sample``, ``device_id``, values,
``temperature``; the magnetometer's ``error_count`` and ``is_external`` too); pressure
in Pa, the field in gauss (NaN temperature for a magnetometer without a thermometer),
as current PX4.  The ``sensor_mag`` format is written only into a log with magnetometers.

DataFlash (``libraries/AP_Logger/LogStructure.h``): every message starts
``A3 95 <type>``; type 128 is ``FMT`` (``BBnNZ``: type, length, name, format,
columns), then the ``PARM`` (``QNf``), ``IMU`` (``QBfffffff``: TimeUS, I, GyrX,
GyrY, GyrZ, AccX, AccY, AccZ, T — the multi-instance form with an ``I`` field)
and ``BARO`` (``QBff``: TimeUS, I, Press, Temp) formats, packed little-endian; a log
with magnetometers also ``MAG`` (``QBhhhhhhhhhBI``: TimeUS, I, MagX..Z, OfsX..Z, MOX..Z
in milligauss, Health, S — ``AP_Compass``'s own layout; offsets written as zero); a log
with a board id also ``MSG`` (``QZ``: TimeUS, Message), its system-id line.
"""

from __future__ import annotations

import heapq
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import InputError
from ...core.fileio import atomic_path
from .base import UT_PER_GAUSS, FlightLog, SensorInstance

__all__ = ["write_ulog", "write_dataflash", "write_log"]

_ULOG_MAGIC = b"ULog\x01\x12\x35"
_INT_PARAMS = ("_ID", "_ENABLE", "SDLOG_", "_DEVID", "ORIENTATION", "_OPTIONS")


def _is_int_param(name: str) -> bool:
    return any(tag in name for tag in _INT_PARAMS)


def _umsg(mtype: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), mtype[0]) + payload


def _ulog_start() -> bytearray:
    """The ULog header and its flag-bits message (what every log starts with)."""
    out = bytearray(_ULOG_MAGIC + bytes([1]) + struct.pack("<Q", 0))
    out += _umsg(b"B", bytes(16) + struct.pack("<QQQ", 0, 0, 0))
    return out


def _ulog_info(log: FlightLog) -> bytes:
    """The info messages: ``sys_name``, and ``sys_uuid`` where PX4's logger writes the board's
    own id."""
    key = b"char[6] sys_name"
    out = _umsg(b"I", bytes([len(key)]) + key + b"PX4sim")
    if log.board_id:
        uuid = log.board_id.encode()
        key = f"char[{len(uuid)}] sys_uuid".encode()
        out += _umsg(b"I", bytes([len(key)]) + key + uuid)
    return out


def _ulog_bytes(log: FlightLog) -> bytes:
    out = _ulog_start()
    formats = {
        "gyro": ("sensor_gyro", "uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;"
                 "float x;float y;float z;float temperature;", "<QQIffff"),
        "acc": ("sensor_accel", "uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;"
                "float x;float y;float z;float temperature;", "<QQIffff"),
        "baro": ("sensor_baro", "uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;"
                 "float pressure;float temperature;", "<QQIff"),
    }
    if any(i.kind == "mag" for i in log.instances):
        formats["mag"] = ("sensor_mag", "uint64_t timestamp;uint64_t timestamp_sample;"
                          "uint32_t device_id;float x;float y;float z;float temperature;"
                          "uint32_t error_count;bool is_external;", "<QQIffffI?")
    for topic, fields, _ in formats.values():
        out += _umsg(b"F", f"{topic}:{fields}".encode())
    out += _ulog_info(log)
    for name, value in sorted(log.params.items()):
        if _is_int_param(name):
            k = f"int32_t {name}".encode()
            out += _umsg(b"P", bytes([len(k)]) + k + struct.pack("<i", int(value)))
        else:
            k = f"float {name}".encode()
            out += _umsg(b"P", bytes([len(k)]) + k + struct.pack("<f", float(value)))
    streams: list[list[tuple[int, bytes]]] = []
    for msg_id, inst in enumerate(log.instances):
        if inst.kind not in formats:
            continue
        topic, _, fmt = formats[inst.kind]
        out += _umsg(b"A", struct.pack("<BH", inst.instance, msg_id) + topic.encode())
        temp = inst.temperature_c if inst.temperature_c is not None else np.full(
            inst.n_samples, np.nan)
        us = np.round(inst.time_s * 1e6).astype(np.int64)
        values = inst.values / UT_PER_GAUSS if inst.kind == "mag" else inst.values
        extra: tuple[int | bool, ...] = (0, False) if inst.kind == "mag" else ()
        records: list[tuple[int, bytes]] = []
        for i in range(inst.n_samples):
            body = struct.pack(fmt, int(us[i]), int(us[i]), inst.device_id,
                               *[float(v) for v in values[i]], float(temp[i]), *extra)
            records.append((int(us[i]), _umsg(b"D", struct.pack("<H", msg_id) + body)))
        streams.append(records)
    for _, rec in _in_time(streams):
        out += rec
    return bytes(out)


def _in_time(streams: list[list[Any]]) -> Iterator[Any]:
    """The records of every stream (one per sensor instance, each in its own order) merged
    by time, as a logger writes them: a stream whose clock steps back keeps its own order
    (the file shows the jump, as a real log does), where sorting every record would
    interleave the stretches before and after it.  On streams in time order it is that sort
    (stable: a tie keeps the streams' order)."""
    return heapq.merge(*streams, key=lambda r: r[:-1])


def _df(mtype: int, payload: bytes) -> bytes:
    return b"\xa3\x95" + bytes([mtype]) + payload


#: A DataFlash format: (name, format letters, columns, the struct that packs its payload).
DfFormat = tuple[str, str, str, str]
_DF_FMT: DfFormat = ("FMT", "BBnNZ", "Type,Length,Name,Format,Columns", "<BB4s16s64s")
_DF_PARM: DfFormat = ("PARM", "QNf", "TimeUS,Name,Value", "<Q16sf")
_DF_IMU: DfFormat = ("IMU", "QBfffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,T", "<QB7f")
_DF_MSG: DfFormat = ("MSG", "QZ", "TimeUS,Message", "<Q64s")


def _df_head(formats: dict[int, DfFormat], log: FlightLog) -> bytearray:
    """``FMT`` (type 128) first, then every other format, the ``PARM`` lines and, with a board
    id, the system-id ``MSG`` line ArduPilot writes at the start of every log."""
    out = bytearray()
    for mtype, (name, fmt, cols, pack) in sorted({128: _DF_FMT, **formats}.items(),
                                                 key=lambda d: d[0] != 128):
        out += _df(128, struct.pack("<BB4s16s64s", mtype, struct.calcsize(pack) + 3,
                                    name.encode(), fmt.encode(), cols.encode()))
    for name, value in sorted(log.params.items()):
        out += _df(64, struct.pack("<Q16sf", 0, name.encode()[:16], float(value)))
    if log.board_id:
        out += _df(91, struct.pack("<Q64s", 0, log.board_id.encode()[:64]))
    return out


def _df_imu_records(log: FlightLog) -> list[list[tuple[int, int, bytes]]]:
    """``IMU`` records (type 65) of every gyro/accelerometer pair: (µs, instance, bytes), one
    stream per IMU."""
    streams: list[list[tuple[int, int, bytes]]] = []
    imus: dict[int, dict[str, SensorInstance]] = {}
    for inst in log.instances:
        if inst.kind in ("gyro", "acc"):
            imus.setdefault(inst.instance, {})[inst.kind] = inst
    for k, pair in sorted(imus.items()):
        if set(pair) != {"gyro", "acc"}:
            raise InputError(f"IMU {k} needs both a gyro and an accelerometer for a DataFlash IMU")
        g, a = pair["gyro"], pair["acc"]
        temp = g.temperature_c if g.temperature_c is not None else np.zeros(g.n_samples)
        us = np.round(g.time_s * 1e6).astype(np.int64)
        streams.append([(int(us[i]), k, _df(65, struct.pack(
            "<QB7f", int(us[i]), k, *[float(v) for v in g.values[i]],
            *[float(v) for v in a.values[i]], float(temp[i])))) for i in range(g.n_samples)])
    return streams


def _dataflash_bytes(log: FlightLog) -> bytes:
    defs: dict[int, DfFormat] = {64: _DF_PARM, 65: _DF_IMU,
                                 66: ("BARO", "QBff", "TimeUS,I,Press,Temp", "<QBff")}
    if any(i.kind == "mag" for i in log.instances):
        defs[67] = ("MAG", "QBhhhhhhhhhBI", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,"
                    "Health,S", "<QB9hBI")
    if log.board_id:
        defs[91] = _DF_MSG
    out = _df_head(defs, log)
    streams = _df_imu_records(log)
    for inst in log.instances:
        if inst.kind != "baro":
            continue
        temp = inst.temperature_c if inst.temperature_c is not None else np.zeros(inst.n_samples)
        us = np.round(inst.time_s * 1e6).astype(np.int64)
        streams.append([(int(us[i]), 10 + inst.instance, _df(66, struct.pack(
            "<QBff", int(us[i]), inst.instance, float(inst.values[i, 0]), float(temp[i]))))
            for i in range(inst.n_samples)])
    for inst in log.instances:
        if inst.kind != "mag":
            continue
        mgauss = np.round(inst.values * 10.0).astype(np.int64)   # µT -> milligauss
        us = np.round(inst.time_s * 1e6).astype(np.int64)
        streams.append([(int(us[i]), 20 + inst.instance, _df(67, struct.pack(
            "<QB9hBI", int(us[i]), inst.instance, *[int(v) for v in mgauss[i]],
            0, 0, 0, 0, 0, 0, 1, 0))) for i in range(inst.n_samples)])
    for _, _, rec in _in_time(streams):
        out += rec
    return bytes(out)


def _write_bytes(path: Path, data: bytes) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def write_ulog(log: FlightLog, path: str | Path) -> Path:
    """Write ``log`` as a PX4 ULog (atomically)."""
    return _write_bytes(Path(path), _ulog_bytes(log))


def write_dataflash(log: FlightLog, path: str | Path) -> Path:
    """Write ``log`` as an ArduPilot DataFlash ``.bin`` (atomically)."""
    return _write_bytes(Path(path), _dataflash_bytes(log))


def write_log(log: FlightLog, path: str | Path) -> Path:
    """By suffix: ``.ulg`` → ULog, ``.bin`` → DataFlash."""
    ext = Path(path).suffix.lower()
    if ext == ".ulg":
        return write_ulog(log, path)
    if ext == ".bin":
        return write_dataflash(log, path)
    raise InputError.at(path, "a flight-controller log is written as .ulg (PX4) or .bin "
                        "(ArduPilot)")
