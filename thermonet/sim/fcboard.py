"""A simulated flight-controller board warmed from cold: the PX4 / ArduPilot calibration procedure.

Presets (``simulate_board(name, autopilot=..., seed=...)``):

``fc-board``
    The board is powered after a cold soak and left still while it warms
    (PX4's ``process_sensor_caldata.py`` steps 4–6; ArduPilot's "log while
    warming"): the board temperature rises as 52 − 45·exp(−t / 12 min) °C over
    45 minutes (7 → ≈49 °C), logged at 1 Hz (small, so tests are fast; the
    autopilots log at hundreds of Hz).  Three IMUs (gyro + accelerometer, each
    with its own thermometer, device id and drift law) and one barometer:

    * IMU 0 — gyro and accel drift a cubic in T plus a mild saturating term
      (a tanh), thermometer 0.01 °C resolution;
    * IMU 1 — a different law (quadratic-dominated, larger), thermometer 2 °C
      above the board, 0.001 °C resolution;
    * IMU 2 — the same kind of law, but its thermometer reports whole degrees
      (1 °C steps, as some sensors do): a calibration must refuse it;
    * baro 0 — pressure 101,325 Pa (constant weather) plus a drift of ≈40 Pa
      over the range (a smooth, order-5-friendly curve), 1 Pa noise.

``fc-board-cycle``
    The same board warmed for 45 minutes, then cooled by a fan for 45 minutes
    (heating and cooling both in the log).

Units as the autopilots log them: rad/s, m/s² (gravity on −z, board level),
Pa.  The simulated drift (``SensorInstance.truth``) travels with the instances
so tests can judge a calibration against the truth.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..data.logs.base import FlightLog, SensorInstance

__all__ = ["BOARD_PRESETS", "simulate_board", "board_params"]

BOARD_PRESETS = ("fc-board", "fc-board-cycle")
_G = 9.80665
_RATE_HZ = 1.0
_WARM_S = 45 * 60.0
# device ids: PX4-style ids for (gyro, accel) of each IMU, and the baro
_PX4_IDS = [(2424842, 2424842), (3670050, 3670058), (2621474, 2621482)]
_BARO_ID = 3997706


def _board_temperature(t: np.ndarray, cycle: bool) -> np.ndarray:
    warm = 52.0 - 45.0 * np.exp(-t / 720.0)
    if not cycle:
        return warm
    top = 52.0 - 45.0 * np.exp(-_WARM_S / 720.0)
    cool = 12.0 + (top - 12.0) * np.exp(-(t - _WARM_S) / 900.0)
    return np.where(t <= _WARM_S, warm, cool)


def _law(rng: np.random.Generator, k: int, dT: np.ndarray, scale: float) -> np.ndarray:
    """Three axes of drift for IMU ``k`` at ``dT`` = T − 25 °C (in units of ``scale``)."""
    out = np.zeros((dT.size, 3))
    for j in range(3):
        c = rng.uniform(-1.0, 1.0, 4)
        if k == 1:      # quadratic-dominated and larger
            poly = 0.3 * c[0] + 0.6 * c[1] * dT / 20 + 1.2 * (dT / 20) ** 2 * np.sign(c[2])
        else:
            poly = 0.3 * c[0] + c[1] * dT / 20 + 0.5 * c[2] * (dT / 20) ** 2 + 0.4 * c[3] * (
                dT / 20) ** 3
        out[:, j] = scale * (poly + 0.08 * np.tanh(dT / 8.0))
    return out


def board_params(autopilot: str) -> dict[str, float]:
    """The parameters the autopilot would log for this procedure (calibration off)."""
    if autopilot == "px4":
        p: dict[str, float] = {"SYS_CAL_TMIN": 5.0, "SYS_CAL_TMAX": 50.0, "SYS_CAL_TDEL": 24.0,
                               "SDLOG_PROFILE": 4.0, "SDLOG_MODE": 2.0, "TC_G_ENABLE": 0.0,
                               "TC_A_ENABLE": 0.0, "TC_B_ENABLE": 0.0}
        for i, (g, a) in enumerate(_PX4_IDS):
            p[f"CAL_GYRO{i}_ID"] = float(g)
            p[f"CAL_ACC{i}_ID"] = float(a)
        p["CAL_BARO0_ID"] = float(_BARO_ID)
        return p
    p = {"AHRS_ORIENTATION": 0.0, "INS_TCAL_OPTIONS": 0.0}
    for i, (g, a) in enumerate(_PX4_IDS):
        n = "" if i == 0 else str(i + 1)
        p[f"INS_GYR{n}_ID"] = float(g)
        p[f"INS_ACC{n}_ID"] = float(a)
        p[f"INS_TCAL{i + 1}_ENABLE"] = 0.0
        p[f"INS_GYR{i + 1}_CALTEMP"] = 25.0
        p[f"INS_ACC{i + 1}_CALTEMP"] = 25.0
    p["BARO1_DEVID"] = float(_BARO_ID)
    return p


def simulate_board(preset: str = "fc-board", *, autopilot: str = "px4", seed: int = 0,
                   rate_hz: float = _RATE_HZ, path: str | Path = "<simulated>") -> FlightLog:
    """Simulate the board's log (instances with their true drift, and the logged parameters).

    Parameters
    ----------
    preset : ``fc-board`` or ``fc-board-cycle``
    autopilot : ``px4`` or ``ardupilot``
        Which parameters are logged (the sensor data are the same).
    seed : int
        Same seed, same log.
    rate_hz : float
        Logging rate, Hz (default 1; tests use less).
    """
    if preset not in BOARD_PRESETS:
        raise InputError(f"unknown board preset '{preset}' (known: {', '.join(BOARD_PRESETS)})")
    if autopilot not in ("px4", "ardupilot"):
        raise InputError(f"autopilot must be 'px4' or 'ardupilot', got '{autopilot}'")
    if not (isinstance(rate_hz, (int, float)) and 0.01 <= rate_hz <= 1000.0):
        raise InputError(f"rate_hz must be within 0.01..1000 Hz, got {rate_hz!r}")
    cycle = preset == "fc-board-cycle"
    rng = np.random.default_rng(seed)
    duration = 2 * _WARM_S if cycle else _WARM_S
    t = np.arange(0.0, duration, 1.0 / rate_hz) + 1.0
    board = _board_temperature(t - t[0], cycle)
    instances: list[SensorInstance] = []
    for k in range(3):
        sensor_t = board + (0.0, 2.0, -1.0)[k] + rng.normal(0.0, 0.02, t.size)
        logged_t = np.round(sensor_t) if k == 2 else np.round(sensor_t, 2 if k == 0 else 3)
        dT = sensor_t - 25.0
        gyro_drift = _law(rng, k, dT, 0.01)                   # ~0.01 rad/s
        acc_drift = _law(rng, k, dT, 0.08)                    # ~0.08 m/s^2
        gyro = gyro_drift + rng.normal(0.0, 5e-4, (t.size, 3))
        acc = acc_drift + np.array([0.0, 0.0, -_G]) + rng.normal(0.0, 4e-3, (t.size, 3))
        gid, aid = _PX4_IDS[k]
        instances.append(SensorInstance("gyro", k, gid, t.copy(), logged_t, gyro,
                                        truth=gyro_drift))
        instances.append(SensorInstance("acc", k, aid, t.copy(), logged_t, acc, truth=acc_drift))
    baro_t = board + 1.0 + rng.normal(0.0, 0.02, t.size)
    x = (baro_t - 25.0) / 20.0
    baro_drift = (18.0 * x + 9.0 * x ** 2 - 6.0 * x ** 3 + 4.0 * np.tanh(2.0 * x))[:, None]
    baro = 101325.0 + baro_drift + rng.normal(0.0, 1.0, (t.size, 1))
    instances.append(SensorInstance("baro", 0, _BARO_ID, t.copy(), np.round(baro_t, 2), baro,
                                    truth=baro_drift))
    return FlightLog(path=Path(path), autopilot=autopilot, instances=instances,
                     params=board_params(autopilot),
                     notes=[f"simulated {preset}, seed {seed}"])
