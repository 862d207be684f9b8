"""Write a flight: its sensors *and* its estimator's biases, as PX4 ULog or ArduPilot DataFlash.

The simulator of flights (:mod:`thermonet.sim.flights`) writes through here so that
``thermonet learn`` reads simulated flights with the same readers — and the autopilots' own
tools, pyulog and pymavlink — as real ones.  (:mod:`thermonet.data.logs.writers` writes the
sensor topics of a chamber log; this module adds the estimator's topics, so it writes every
ULog topic itself — a ULog's formats must all precede its data — and shares that module's
ULog header and info messages, DataFlash head and ``IMU`` records.)

ULog: ``sensor_gyro`` / ``sensor_accel`` as :mod:`~thermonet.data.logs.writers` writes them,
and ``estimator_sensor_bias`` per estimator instance in PX4's current form
(``msg/EstimatorSensorBias.msg``: ``gyro_device_id``, ``float[3] gyro_bias``,
``gyro_bias_limit``, ``float[3] gyro_bias_variance``, ``bool gyro_bias_valid``,
``gyro_bias_stable``, the same for the accelerometer) or — ``old_firmware`` — the older form
of the real fixture (device ids and biases only, with ``mag_*`` as it had); the board's own
id (``FlightLog.board_id``) as the info field ``sys_uuid``.

DataFlash: ``PARM``, ``IMU`` (``QBfffffff``) and, per EKF3 core ``C``, ``XKF1``
(``QBccCfffffffccce``: TimeUS, C, Roll, Pitch, Yaw, VN, VE, VD, dPD, PN, PE, PD, GX, GY, GZ,
OH; the gyro bias in centi-degrees per second as int16, as ``NavEKF3_core::Log_Write_XKF1``)
and ``XKF2`` (``QBccccchhhhhhhhh``: TimeUS, C, AX, AY, AZ, VWN, VWE, MN, ME, MD, MX, MY, MZ,
IDX, IDY, IS; the accelerometer bias in centi-m/s² as int16), and the board's id as the
system-id ``MSG`` line.  Fields the simulator does not model are written as zero.
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.errors import InputError
from ...core.fileio import atomic_path
from .base import FlightLog, SensorInstance
from .writers import (
    _DF_IMU,
    _DF_MSG,
    _DF_PARM,
    DfFormat,
    _df,
    _df_head,
    _df_imu_records,
    _in_time,
    _ulog_info,
    _ulog_start,
    _umsg,
)

__all__ = ["EstimatorBias", "write_flight"]

_CTYPES = {"uint64_t": "Q", "uint32_t": "I", "int32_t": "i", "float": "f", "bool": "?",
           "uint8_t": "B", "int16_t": "h", "uint16_t": "H"}
_INT_PARAMS = ("_ID", "_ENABLE", "SDLOG_", "_DEVID", "ORIENTATION", "_OPTIONS", "_ROT",
               "_MASK", "_PRIME", "_EN")


@dataclass
class EstimatorBias:
    """What one estimator instance (PX4 EKF2 instance, ArduPilot EKF3 core) logged: its
    biases in the body frame (rad/s, m/s²), with variances and validity (None: not logged)."""

    estimator: int
    gyro_device_id: int
    accel_device_id: int
    time_s: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    gyro_variance: np.ndarray | None = None
    accel_variance: np.ndarray | None = None
    gyro_valid: np.ndarray | None = None
    accel_valid: np.ndarray | None = None


def _struct(fields: str) -> str:
    """The struct format of a ULog field list (``uint64_t timestamp;float[3] x;``)."""
    out = "<"
    for decl in filter(None, fields.split(";")):
        ctype, _ = decl.split(" ")
        m = re.fullmatch(r"(\w+)(?:\[(\d+)\])?", ctype)
        assert m is not None
        out += (m.group(2) or "") + _CTYPES[m.group(1)]
    return out


def _bias_fields(old: bool) -> str:
    if old:
        return "".join(f"uint32_t {k}_device_id;float[3] {k}_bias;"
                       for k in ("gyro", "accel", "mag"))
    return "uint64_t timestamp_sample;" + "".join(
        f"uint32_t {k}_device_id;float[3] {k}_bias;float {k}_bias_limit;"
        f"float[3] {k}_bias_variance;bool {k}_bias_valid;bool {k}_bias_stable;"
        for k in ("gyro", "accel", "mag"))


def _bias_rows(b: EstimatorBias, old: bool) -> list[tuple[int, tuple[float | int | bool, ...]]]:
    """(µs, field values after the timestamp) per sample of one estimator's biases."""
    n = b.time_s.size
    us = np.round(b.time_s * 1e6).astype(np.int64)
    gv = b.gyro_variance if b.gyro_variance is not None else np.full((n, 3), 1e-8)
    av = b.accel_variance if b.accel_variance is not None else np.full((n, 3), 1e-4)
    gok = b.gyro_valid if b.gyro_valid is not None else np.ones(n, dtype=bool)
    aok = b.accel_valid if b.accel_valid is not None else np.ones(n, dtype=bool)
    rows = []
    for i in range(n):
        g, a = [float(v) for v in b.gyro_bias[i]], [float(v) for v in b.accel_bias[i]]
        if old:
            vals: tuple[float | int | bool, ...] = (b.gyro_device_id, *g, b.accel_device_id,
                                                    *a, 0, 0.0, 0.0, 0.0)
        else:
            vals = (int(us[i]), b.gyro_device_id, *g, 0.4, *[float(v) for v in gv[i]],
                    bool(gok[i]), bool(gok[i]), b.accel_device_id, *a, 0.4,
                    *[float(v) for v in av[i]], bool(aok[i]), bool(aok[i]),
                    0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, False)
        rows.append((int(us[i]), vals))
    return rows


def _sensor_rows(inst: SensorInstance) -> list[tuple[int, tuple[float | int | bool, ...]]]:
    us = np.round(inst.time_s * 1e6).astype(np.int64)
    temp = np.asarray(inst.temperature_c if inst.temperature_c is not None
                      else np.full(inst.n_samples, np.nan), dtype=np.float64)
    return [(int(us[i]), (int(us[i]), int(us[i]), inst.device_id, *[float(v) for v in inst.values[i]],
                          float(temp[i]))) for i in range(inst.n_samples)]


def _param_bytes(params: dict[str, float]) -> bytes:
    out = bytearray()
    for name, value in sorted(params.items()):
        if any(tag in name for tag in _INT_PARAMS) and float(value).is_integer():
            k = f"int32_t {name}".encode()
            out += _umsg(b"P", bytes([len(k)]) + k + struct.pack("<i", int(value)))
        else:
            k = f"float {name}".encode()
            out += _umsg(b"P", bytes([len(k)]) + k + struct.pack("<f", float(value)))
    return bytes(out)


def _ulog_bytes(log: FlightLog, biases: list[EstimatorBias], old: bool) -> bytes:
    out = _ulog_start()
    sensor = ("uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float x;"
              "float y;float z;float temperature;")
    formats = {"sensor_gyro": sensor, "sensor_accel": sensor,
               "estimator_sensor_bias": "uint64_t timestamp;" + _bias_fields(old)}
    for topic, fields in formats.items():
        out += _umsg(b"F", f"{topic}:{fields}".encode())
    out += _ulog_info(log)
    out += _param_bytes(log.params)
    streams: list[tuple[str, int, list[tuple[int, tuple[float | int | bool, ...]]]]] = []
    for inst in log.instances:
        if inst.kind in ("gyro", "acc"):
            streams.append(("sensor_gyro" if inst.kind == "gyro" else "sensor_accel",
                            inst.instance, _sensor_rows(inst)))
    streams += [("estimator_sensor_bias", b.estimator, _bias_rows(b, old)) for b in biases]
    written: list[list[tuple[int, int, bytes]]] = []
    for msg_id, (topic, multi, rows) in enumerate(streams):
        out += _umsg(b"A", struct.pack("<BH", multi, msg_id) + topic.encode())
        fmt = _struct(formats[topic])
        records = []
        for us, vals in rows:
            body = struct.pack(fmt, us, *vals) if topic == "estimator_sensor_bias" else \
                struct.pack(fmt, *vals)
            records.append((us, msg_id, _umsg(b"D", struct.pack("<H", msg_id) + body)))
        written.append(records)
    out += b"".join(r[2] for r in _in_time(written))
    return bytes(out)


_DF_FORMATS: dict[int, DfFormat] = {
    64: _DF_PARM,
    65: _DF_IMU,
    66: ("XKF1", "QBccCfffffffccce",
         "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH", "<QBhhH7fhhhi"),
    67: ("XKF2", "QBccccchhhhhhhhh",
         "TimeUS,C,AX,AY,AZ,VWN,VWE,MN,ME,MD,MX,MY,MZ,IDX,IDY,IS", "<QB5h9h"),
    91: _DF_MSG,
}


def _centi(v: float) -> int:
    """A value as ArduPilot's int16 ``c`` field holds it (× 100, saturated)."""
    return int(max(-32768, min(32767, round(100.0 * v))))


def _dataflash_bytes(log: FlightLog, biases: list[EstimatorBias]) -> bytes:
    out = _df_head(_DF_FORMATS, log)
    streams = _df_imu_records(log)
    deg = 180.0 / math.pi
    for b in biases:
        us = np.round(b.time_s * 1e6).astype(np.int64)
        xkf1, xkf2 = [], []
        for i in range(b.time_s.size):
            gx, gy, gz = (_centi(float(v) * deg) for v in b.gyro_bias[i])
            ax, ay, az = (_centi(float(v)) for v in b.accel_bias[i])
            xkf1.append((int(us[i]), 10 + b.estimator, _df(66, struct.pack(
                "<QBhhH7fhhhi", int(us[i]), b.estimator, 0, 0, 0, *([0.0] * 7), gx, gy, gz, 0))))
            xkf2.append((int(us[i]), 20 + b.estimator, _df(67, struct.pack(
                "<QB5h9h", int(us[i]), b.estimator, ax, ay, az, 0, 0, *([0] * 9)))))
        streams += [xkf1, xkf2]
    out += b"".join(r[2] for r in _in_time(streams))
    return bytes(out)


def write_flight(log: FlightLog, biases: list[EstimatorBias], path: str | Path, *,
                 old_firmware: bool = False) -> Path:
    """Write ``log``'s gyros and accelerometers and ``biases`` to ``path`` (atomically):
    ``.ulg`` PX4 (``old_firmware``: the older ``estimator_sensor_bias`` without variance and
    validity), ``.bin`` ArduPilot."""
    path = Path(path)
    ext = path.suffix.lower()
    if ext == ".ulg":
        data = _ulog_bytes(log, biases, old_firmware)
    elif ext == ".bin":
        data = _dataflash_bytes(log, biases)
    else:
        raise InputError.at(path, "a flight log is written as .ulg (PX4) or .bin (ArduPilot)")
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path
