"""PX4 ULog (``.ulg``) reader, through pyulog.

Every ``sensor_gyro``, ``sensor_accel``, ``sensor_baro`` and ``sensor_mag``
multi-instance becomes a :class:`~thermonet.data.logs.base.SensorInstance` with its
``device_id`` (the median over the log, as PX4's ``Tools/process_sensor_caldata.py``
takes it) and its own ``temperature`` field.  Parameters come from the log's
initial parameters (``ULog.initial_parameters``); the board's own id from the info field
``sys_uuid`` (``FlightLog.board_id``).

Units.  ``sensor_gyro`` x/y/z are rad/s and ``sensor_accel`` m/s² (kept).
``sensor_baro.pressure`` is Pa in current PX4 (``msg/SensorBaro.msg``: "static
pressure measurement in Pascals"); logs from older releases (the sample log in
tests/data/real) hold hPa (mbar), which ``process_sensor_caldata.py`` still
assumes (it multiplies by 100).  thermonet decides per instance from the value
itself: a median below 2,000 can only be hPa (sea-level air is ≈101,325 Pa,
≈1,013 hPa; no flight controller works at 2 kPa) and is converted to Pa, with a
note.

``sensor_mag`` x/y/z are gauss (``msg/SensorMag.msg``: "magnetic field in the FRD
board frame X-axis in Gauss"), converted to µT (× 100); its ``temperature`` is NaN
for a magnetometer without a thermometer (then read as none).

Calibration already applied.  PX4's ``sensor_gyro`` / ``sensor_accel`` /
``sensor_baro`` / ``sensor_mag`` are the drivers' output; the thermal offsets (``TC_*``,
``src/modules/temperature_compensation/TemperatureCompensation.cpp``) and the
ordinary offsets (``CAL_*``, ``src/lib/sensor_calibration``) are applied
downstream (``vehicle_angular_velocity``, ``vehicle_acceleration``,
``vehicle_air_data``, ``vehicle_magnetometer``; the magnetometer's ``CAL_MAG*``
offsets and soft-iron matrix and ``TC_M*`` likewise).  So there is nothing to undo; when the log says
``TC_*_ENABLE = 1`` the instance carries a note saying so.
"""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import InputError
from .base import (
    UT_PER_GAUSS,
    FlightLog,
    SensorInstance,
    byte_ranges_note,
    clock_jump_back,
    drop_phantoms,
    flag_kelvin,
    screen_samples,
    time_gaps,
)

__all__ = ["read_ulog", "TOPICS", "HPA_MAX"]

#: ULog topic -> (thermonet kind, fields).
TOPICS = {"sensor_gyro": ("gyro", ("x", "y", "z")), "sensor_accel": ("acc", ("x", "y", "z")),
          "sensor_baro": ("baro", ("pressure",)), "sensor_mag": ("mag", ("x", "y", "z"))}
#: The first bytes of every ULog file ("ULog", then 0x01 0x12 0x35).
ULOG_MAGIC = b"ULog\x01\x12\x35"
#: A barometer median below this (in the logged unit) is hPa, not Pa.
HPA_MAX = 2000.0
_TC = {"gyro": "TC_G_ENABLE", "acc": "TC_A_ENABLE", "baro": "TC_B_ENABLE",
       "mag": "TC_M_ENABLE"}


class _Watched:
    """The log file as pyulog reads it, noting the byte ranges it could not read as messages.

    pyulog reads a message as a 3-byte header (size: uint16, type: uint8) and
    its body.  After a damaged message it moves on without a word: one byte at a
    time after an unknown type, to the next sync marker (or the end of the file
    when the log has none), or — for a size field past the end — it stops, as at
    the end of a cut file.  Every header read that does not start where the
    previous message ended therefore marks bytes pyulog skipped.
    """

    def __init__(self, fh: Any, size: int) -> None:
        self._fh, self._size = fh, size
        self._prev: tuple[int, int] | None = None    # (header offset, end of its message)
        self.skipped: list[tuple[int, int]] = []      # [start, end) byte ranges not read

    def read(self, n: int = -1) -> bytes:
        pos = self._fh.tell()
        data = bytes(self._fh.read(n))
        if n == 3:
            if self._prev is not None:
                start, end = self._prev
                if pos > end:        # searched forward (for a sync marker) from the message end
                    self.skipped.append((end, pos))
                elif pos < end:      # the previous message was rejected: pyulog stepped back
                    self.skipped.append((start, pos))
            if len(data) == 3:
                self._prev = (pos, pos + 3 + int.from_bytes(data[:2], "little"))
            else:
                self._prev = None
                if len(data) < self._size - pos:   # (never: a short read is the end)
                    self.skipped.append((pos, self._size))
        elif self._prev is not None and len(data) < n and pos == self._prev[0] + 3:
            self.skipped.append((self._prev[0], self._size))   # a body past the end of file
            self._prev = None
        return data

    def finish(self) -> list[tuple[int, int]]:
        """The skipped ranges, merged (a search still open ran to the end of the file)."""
        if self._prev is not None and self._prev[1] < self._size:
            self.skipped.append((self._prev[1], self._size))
        out: list[tuple[int, int]] = []
        for a, b in sorted(self.skipped):
            if b <= a:
                continue
            if out and a <= out[-1][1]:
                out[-1] = (out[-1][0], max(out[-1][1], b))
            else:
                out.append((a, b))
        return out

    def __getattr__(self, name: str) -> Any:
        return getattr(self._fh, name)


def _pyulog_damage(chatter: str, ulog: Any, skipped: list[tuple[int, int]], size: int
                   ) -> list[str]:
    """What pyulog met (its printed warnings, its corruption flag, skipped bytes), in words."""
    notes = []
    ids = sorted({int(m) for m in re.findall(r"no subscription found for message id (\d+)",
                                                chatter)})
    if ids:
        notes.append(f"data messages with unknown ids ({', '.join(map(str, ids[:5]))}"
                     f"{', …' if len(ids) > 5 else ''}) skipped")
    if "reading file definitions" in chatter:
        notes.append("corrupt message definitions in the file header")
    if skipped:
        notes.append(byte_ranges_note(skipped, size))
    if not notes and getattr(ulog, "file_corruption", False):
        notes.append("pyulog found corrupt data and skipped it")
    return notes


def _instance(d: Any, kind: str, fields: tuple[str, ...],
              params: dict[str, float], path: Path) -> SensorInstance:
    """One logged instance of a sensor topic: SI units (hPa and gauss converted), damaged
    samples dropped and counted, its most frequent device id, sorted in time."""
    data = d.data
    t = np.asarray(data["timestamp"], dtype=np.float64) * 1e-6
    values = np.column_stack([np.asarray(data[f], dtype=np.float64) for f in fields])
    temp = data.get("temperature")
    temperature = None
    if temp is not None:
        temperature = np.asarray(temp, dtype=np.float64)
        if not np.any(np.isfinite(temperature)):
            temperature = None
    dev = data.get("device_id")
    dev = None if dev is None or not len(dev) else np.asarray(dev)
    notes: list[str] = []
    finite = values[np.all(np.isfinite(values), axis=1)]
    if kind == "baro" and finite.size and np.median(finite[:, 0]) < HPA_MAX:
        values = values * 100.0
        notes.append("pressure logged in hPa (an older PX4), converted to Pa")
    if kind == "mag":
        values = values * UT_PER_GAUSS
        notes.append("field logged in gauss, converted to µT")
    if kind in _TC and params.get(_TC[kind], 0.0) == 1.0:
        notes.append(f"{_TC[kind]}=1 in the log; {d.name} is logged before thermal "
                     "compensation, so nothing was undone")
    # damaged samples (a flipped byte: a time out of order, a value or a temperature
    # that no sensor reports, another sensor's device id) are dropped and counted
    keep, dropped = screen_samples(kind, t, values, temperature, dev)
    device_id = 0
    if dev is not None:
        ids, counts = np.unique(dev[keep] if keep.any() else dev, return_counts=True)
        device_id = int(ids[np.argmax(counts)])
    jump = clock_jump_back(t[keep], f"{d.name} instance {d.multi_id}")
    if jump:
        raise InputError.at(path, jump)
    order = np.argsort(t[keep], kind="stable")
    inst = SensorInstance(
        kind=kind, instance=int(d.multi_id), device_id=device_id,
        time_s=t[keep][order], values=values[keep][order],
        temperature_c=None if temperature is None else temperature[keep][order], notes=notes)
    inst.mark_damage(t.shape[0], dropped)
    flag_kelvin(inst)
    return inst


def read_ulog(path: str | Path) -> FlightLog:
    """Read a PX4 ULog into its sensor instances and parameters.

    Raises
    ------
    InputError
        The file cannot be parsed as a ULog (truncated, corrupt), or has no
        sensor topics / no temperature / only zeros (one line naming the file).
    """
    from pyulog import ULog

    path = Path(path)
    if not path.is_file():
        raise InputError.at(path, "file not found")
    size = path.stat().st_size
    chatter = io.StringIO()   # pyulog prints its warnings; they become the damage notes
    try:
        with open(path, "rb") as fh, contextlib.redirect_stdout(chatter):
            watched = _Watched(fh, size)
            ulog = ULog(watched, list(TOPICS))
            skipped = watched.finish()
    except Exception as err:  # noqa: BLE001 — pyulog raises anything on a corrupt file
        why = f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}"
        with open(path, "rb") as fh:
            magic = fh.read(len(ULOG_MAGIC))
        if magic == ULOG_MAGIC:  # a ULog header, then what pyulog cannot parse
            raise InputError.at(path, "damaged: a ULog header followed by data that cannot be "
                                f"parsed as ULog messages ({why})") from None
        hint = ("; it starts as an ArduPilot DataFlash log does (name it .bin)"
                if magic[:2] == b"\xa3\x95" else "")
        raise InputError.at(path, f"not a readable ULog ({why}){hint}") from None
    damage = _pyulog_damage(chatter.getvalue(), ulog, skipped, size)
    unread = sum(b - a for a, b in skipped) / max(size, 1)
    params = {}
    for k, v in ulog.initial_parameters.items():
        try:
            params[str(k)] = float(v)
        except (TypeError, ValueError):  # a damaged parameter value: left out, said
            damage.append(f"parameter {str(k)[:40]!r} has no numeric value")
    instances: list[SensorInstance] = []
    for d in sorted(ulog.data_list, key=lambda d: (d.name, d.multi_id)):
        if d.name not in TOPICS:
            continue
        kind, fields = TOPICS[d.name]
        data = d.data
        missing = [f for f in ("timestamp",) + fields if f not in data]
        if missing:
            raise InputError.at(path, f"topic {d.name} instance {d.multi_id} has no field "
                                f"'{missing[0]}'")
        instances.append(_instance(d, kind, fields, params, path))
    instances, phantoms = drop_phantoms(instances, "px4")
    return FlightLog(path=path, autopilot="px4", instances=instances, params=params,
                     notes=time_gaps(instances), damage=damage + phantoms,
                     unread_fraction=unread, board_id=_board_id(ulog)).check()


def _board_id(ulog: Any) -> str | None:
    """The board's own id: the logger's ``sys_uuid`` info field (the MCU's unique id, as
    ``board_get_px4_guid_formated`` writes it), or None where the log has none."""
    value = getattr(ulog, "msg_info_dict", {}).get("sys_uuid")
    text = value.decode("ascii", "replace") if isinstance(value, bytes) else str(value or "")
    text = "".join(c for c in text if c.isprintable()).strip()[:80]  # damage: no control bytes
    return text or None
