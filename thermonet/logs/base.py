"""What a flight-controller log holds for thermal calibration: sensor instances and parameters.

One :class:`SensorInstance` per physical sensor (a gyro, an accelerometer, a
barometer, a magnetometer), identified by the autopilot's device id, with its
own thermometer.  Units are SI as both autopilots log and compensate them:
gyro rad/s (kept in rad/s: the parameters PX4 and ArduPilot load are in rad/s),
accelerometer m/s², barometer Pa, magnetometer gauss (PX4) — magnetometers are
listed but not calibrated (neither autopilot has a thermal model for them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..recording import Dataset, Recording

__all__ = ["SensorInstance", "FlightLog", "AXES", "UNITS", "temperature_step"]

#: Output channels per sensor kind.
AXES = {"gyro": ("x", "y", "z"), "acc": ("x", "y", "z"), "mag": ("x", "y", "z"), "baro": ("p",)}
#: thermonet unit per sensor kind (SI, as the autopilots log and compensate them).
UNITS = {"gyro": "rad/s", "acc": "m/s^2", "baro": "Pa", "mag": "1"}


def temperature_step(temperature_c: np.ndarray | None) -> float | None:
    """The quantisation step of a thermometer, °C: the most common spacing of its distinct values.

    A sensor that reports whole degrees gives 1.0; a float thermometer gives a
    tiny value.  None when fewer than two distinct values exist.
    """
    if temperature_c is None:
        return None
    u = np.unique(np.round(np.asarray(temperature_c, dtype=np.float64), 6))
    if u.size < 2:
        return None
    d = np.round(np.diff(u), 6)
    vals, counts = np.unique(d, return_counts=True)
    return float(vals[np.argmax(counts)])


@dataclass
class SensorInstance:
    """One sensor of a flight-controller log.

    Attributes
    ----------
    kind : str
        ``gyro``, ``acc``, ``baro`` or ``mag``.
    instance : int
        The autopilot's instance number (PX4 multi id; ArduPilot IMU index, 0-based).
    device_id : int
        The sensor's device id (PX4 ``device_id``; ArduPilot ``INS_GYR_ID`` …; 0 if unknown).
    time_s : array (n,)
        Seconds since the log started.
    temperature_c : array (n,) or None
        The sensor's own thermometer, °C (None: the sensor has none).
    values : array (n, axes)
        The output in :data:`UNITS`.
    notes : list of str
        What was done to the data (unit conversion, calibration undone, …).
    truth : array (n, axes) or None
        The simulated drift (simulator logs only, not read from files).
    """

    kind: str
    instance: int
    device_id: int
    time_s: np.ndarray
    temperature_c: np.ndarray | None
    values: np.ndarray
    notes: list[str] = field(default_factory=list)
    truth: np.ndarray | None = None

    @property
    def name(self) -> str:
        """``gyro0``, ``acc1``, ``baro0`` …"""
        return f"{self.kind}{self.instance}"

    @property
    def n_samples(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def channels(self) -> list[str]:
        return [f"{self.kind}_{a}" for a in AXES[self.kind]]

    def to_dataset(self, source: str = "") -> Dataset:
        """One run of this sensor as a thermonet :class:`Dataset` (not validated).

        Gyro drift is the output itself (the board is still: the true rate is
        zero, the autopilots fit the whole offset).  Accelerometer and baro
        outputs carry gravity and the weather: their reference is the median
        of the log, as PX4's ``process_sensor_caldata.py`` subtracts it, so that
        only the change with temperature is drift.
        """
        outputs = {c: self.values[:, j].astype(np.float64) for j, c in enumerate(self.channels)}
        refs: dict[str, np.ndarray] = {}
        if self.kind in ("acc", "baro"):
            refs = {f"ref_{c}": np.full(self.n_samples, float(np.median(v)))
                    for c, v in outputs.items()}
        drift = {} if self.truth is None else {
            f"drift_{c}": self.truth[:, j] - float(np.median(self.truth[:, j]))
            if self.kind in ("acc", "baro") else self.truth[:, j]
            for j, c in enumerate(self.channels)}
        units = {"time_s": "s", "temperature_c": "degC",
                 **{c: UNITS[self.kind] for c in self.channels}}
        meta = {"source": source, "instance": self.name, "log_notes": "; ".join(self.notes)}
        rec = Recording(time_s=self.time_s.astype(np.float64), temperature_c=self.temperature_c,
                        outputs=outputs, references=refs, drift=drift, units=units,
                        device_id=str(self.device_id), sensor_kind=self.kind,
                        run_id=self.name, meta=meta)
        return Dataset(runs=[rec], meta={"source": source, "log_notes": "; ".join(self.notes)})


@dataclass
class FlightLog:
    """A flight-controller log: its sensor instances and the parameters it recorded."""

    path: Path
    autopilot: str                     # "px4" or "ardupilot"
    instances: list[SensorInstance]
    params: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def check(self) -> FlightLog:
        """Refuse a log with no usable sensor data: one line naming the file and what is missing."""
        if not self.instances:
            raise InputError.at(self.path, "no sensor topics (sensor_gyro / sensor_accel / "
                                "sensor_baro; DataFlash IMU / BARO) in the log")
        if all(i.temperature_c is None for i in self.instances):
            raise InputError.at(self.path, "no sensor reports a temperature: nothing to "
                                "calibrate against")
        live = [i for i in self.instances if i.n_samples and np.any(i.values != 0)]
        if not live:
            raise InputError.at(self.path, "every sensor reads exactly zero (a SITL log?): "
                                "no real sensor data")
        return self
