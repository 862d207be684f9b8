"""PX4 ULog (``.ulg``) reader, through pyulog.

Every ``sensor_gyro``, ``sensor_accel``, ``sensor_baro`` and ``sensor_mag``
multi-instance becomes a :class:`~thermonet.logs.base.SensorInstance` with its
``device_id`` (the median over the log, as PX4's ``Tools/process_sensor_caldata.py``
takes it) and its own ``temperature`` field.  Parameters come from the log's
initial parameters (``ULog.initial_parameters``).

Units.  ``sensor_gyro`` x/y/z are rad/s and ``sensor_accel`` m/s² (kept).
``sensor_baro.pressure`` is Pa in current PX4 (``msg/SensorBaro.msg``: "static
pressure measurement in Pascals"); logs from older releases (the sample log in
tests/data/real) hold hPa (mbar), which ``process_sensor_caldata.py`` still
assumes (it multiplies by 100).  thermonet decides per instance from the value
itself: a median below 2,000 can only be hPa (sea-level air is ≈101,325 Pa,
≈1,013 hPa; no flight controller works at 2 kPa) and is converted to Pa, with a
note.

Calibration already applied.  PX4's ``sensor_gyro`` / ``sensor_accel`` /
``sensor_baro`` are the drivers' output; the thermal offsets (``TC_*``,
``src/modules/temperature_compensation/TemperatureCompensation.cpp``) and the
ordinary offsets (``CAL_*``, ``src/lib/sensor_calibration``) are applied
downstream (``vehicle_angular_velocity``, ``vehicle_acceleration``,
``vehicle_air_data``).  So there is nothing to undo; when the log says
``TC_*_ENABLE = 1`` the instance carries a note saying so.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from .base import FlightLog, SensorInstance

__all__ = ["read_ulog", "TOPICS", "HPA_MAX"]

#: ULog topic -> (thermonet kind, fields).
TOPICS = {"sensor_gyro": ("gyro", ("x", "y", "z")), "sensor_accel": ("acc", ("x", "y", "z")),
          "sensor_baro": ("baro", ("pressure",)), "sensor_mag": ("mag", ("x", "y", "z"))}
#: A barometer median below this (in the logged unit) is hPa, not Pa.
HPA_MAX = 2000.0
_TC = {"gyro": "TC_G_ENABLE", "acc": "TC_A_ENABLE", "baro": "TC_B_ENABLE"}


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
    try:
        ulog = ULog(str(path), list(TOPICS))
    except Exception as err:  # noqa: BLE001 — pyulog raises anything on a corrupt file
        raise InputError.at(path, f"not a readable ULog ({type(err).__name__}: {err})") from None
    params = {str(k): float(v) for k, v in ulog.initial_parameters.items()}
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
        t = np.asarray(data["timestamp"], dtype=np.float64) * 1e-6
        values = np.column_stack([np.asarray(data[f], dtype=np.float64) for f in fields])
        temp = data.get("temperature")
        temperature = None
        if temp is not None:
            temperature = np.asarray(temp, dtype=np.float64)
            if not np.any(np.isfinite(temperature)):
                temperature = None
        dev = data.get("device_id")
        device_id = int(np.median(dev)) if dev is not None and len(dev) else 0
        notes: list[str] = []
        if kind == "baro" and values.size and np.median(values[:, 0]) < HPA_MAX:
            values = values * 100.0
            notes.append("pressure logged in hPa (an older PX4), converted to Pa")
        if kind in _TC and params.get(_TC[kind], 0.0) == 1.0:
            notes.append(f"{_TC[kind]}=1 in the log; {d.name} is logged before thermal "
                         "compensation, so nothing was undone")
        keep = np.isfinite(t) & np.all(np.isfinite(values), axis=1)
        if temperature is not None:
            keep &= np.isfinite(temperature)
        order = np.argsort(t[keep], kind="stable")
        instances.append(SensorInstance(
            kind=kind, instance=int(d.multi_id), device_id=device_id,
            time_s=t[keep][order], values=values[keep][order],
            temperature_c=None if temperature is None else temperature[keep][order], notes=notes))
    return FlightLog(path=path, autopilot="px4", instances=instances, params=params).check()
