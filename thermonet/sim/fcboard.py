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
      (1 °C steps, as some sensors do; PX4 issue #13551): a calibration fits it on
      the per-degree means and says what the resolution costs;
    * baro 0 — pressure 101,325 Pa (constant weather) plus a drift of ≈40 Pa
      over the range (a smooth, order-5-friendly curve), 1 Pa noise;
    * mag 0 — a magnetometer with its own thermometer (0.01 °C), the board level and
      still, so the Earth's field (:data:`EARTH_FIELD_UT`: 24 µT north, 46 µT down,
      ≈52 µT, heading 30°) stays in its output; its die follows the board with a
      first-order lag of :data:`MAG_LAG_S` [0] s, and its offset drifts with the die
      temperature by ≈3–11 µT per axis over the warm-up (a cubic in T), 0.3 µT noise;
    * mag 1 — a magnetometer without a thermometer (PX4 logs NaN, as for most
      magnetometers), lagging the board by :data:`MAG_LAG_S` [1] = 300 s: calibrated
      against a lent thermometer (the barometer's, by default) and a fitted lag.

    The magnetometers draw from their own random streams (``[seed, 40]`` for their
    laws, ``[seed, run, 40]`` for their noise), so every other sensor's samples are
    the same as a board without them.

``fc-board-cycle``
    The same board warmed for 45 minutes, then cooled by a fan for 45 minutes
    (heating and cooling both in the log).

Several logs of the same board (``simulate_board(..., run=k)``, ``thermonet simulate
fc-board --runs N``): run 0 is the warm-up above; every run keeps the board — device
ids, drift laws (drawn from ``seed`` alone), the weather — and draws its own warm-up
(cold-soak start 7 ± 3 °C, plateau 52 ± 3 °C, time constant 12 ± 2 min, a uniform
draw per run) and its own noise from ``(seed, run)``.  A later run can therefore
start below or end above the range of an earlier one (a verification then warns
that the firmware clamps there).

Every board has its own id (``FlightLog.board_id``, :func:`board_id`), drawn from ``seed``
alone and written where the firmware writes it: a 12-byte MCU unique id, as PX4's
``sys_uuid`` info field or ArduPilot's system-id ``MSG`` line.  Two seeds are two boards of
one model: the same sensor device ids, two board ids.

Units as the autopilots log them: rad/s, m/s² (gravity on −z, board level),
Pa.  The simulated drift (``SensorInstance.truth``) travels with the instances
so tests can judge a calibration against the truth.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..data.logs.base import FlightLog, SensorInstance

__all__ = ["BOARD_PRESETS", "MAX_BOARD_RUNS", "simulate_board", "board_params",
           "EARTH_FIELD_UT", "MAG_LAG_S", "MAG_IDS", "first_order_lag", "board_id"]

BOARD_PRESETS = ("fc-board", "fc-board-cycle")
#: Most logs ``simulate fc-board --runs N`` writes (one file per warm-up).
MAX_BOARD_RUNS = 100
_G = 9.80665
_RATE_HZ = 1.0
_WARM_S = 45 * 60.0
# device ids: PX4-style ids for (gyro, accel) of each IMU, and the baro
_PX4_IDS = [(2424842, 2424842), (3670050, 3670058), (2621474, 2621482)]
_BARO_ID = 3997706
#: Device ids of the simulated magnetometers (mag 0 with a thermometer, mag 1 without).
MAG_IDS = (396825, 466441)
#: The Earth's field where the board sits: north, east, down (µT), and the board's heading.
EARTH_FIELD_UT = (24.0, 0.0, 46.0)
_HEADING_DEG = 30.0
#: Time constant (s) of each magnetometer die's lag behind the board temperature.
MAG_LAG_S = (120.0, 300.0)
_MAG_NOISE_UT = 0.3


def _warm_up(run: int, seed: int) -> tuple[float, float, float]:
    """(start °C, plateau °C, time constant s) of run ``run``: run 0 the procedure's own."""
    if run == 0:
        return 7.0, 52.0, 720.0
    r = np.random.default_rng([seed, run, 7])
    return (7.0 + r.uniform(-3.0, 3.0), 52.0 + r.uniform(-3.0, 3.0),
            720.0 + r.uniform(-120.0, 120.0))


def _board_temperature(t: np.ndarray, cycle: bool,
                       profile: tuple[float, float, float] = (7.0, 52.0, 720.0)
                       ) -> np.ndarray:
    start, plateau, tau = profile
    warm = plateau - (plateau - start) * np.exp(-t / tau)
    if not cycle:
        return warm
    top = plateau - (plateau - start) * np.exp(-_WARM_S / tau)
    cool = 12.0 + (top - 12.0) * np.exp(-(t - _WARM_S) / 900.0)
    return np.where(t <= _WARM_S, warm, cool)


def _law(coefs: np.ndarray, k: int, dT: np.ndarray, scale: float) -> np.ndarray:
    """Three axes of drift for IMU ``k`` at ``dT`` = T − 25 °C (in units of ``scale``);
    ``coefs`` (3, 4): the board's draws for this sensor."""
    out = np.zeros((dT.size, 3))
    for j in range(3):
        c = coefs[j]
        if k == 1:      # quadratic-dominated and larger
            poly = 0.3 * c[0] + 0.6 * c[1] * dT / 20 + 1.2 * (dT / 20) ** 2 * np.sign(c[2])
        else:
            poly = 0.3 * c[0] + c[1] * dT / 20 + 0.5 * c[2] * (dT / 20) ** 2 + 0.4 * c[3] * (
                dT / 20) ** 3
        out[:, j] = scale * (poly + 0.08 * np.tanh(dT / 8.0))
    return out


def first_order_lag(t: np.ndarray, x: np.ndarray, tau_s: float) -> np.ndarray:
    """``x`` through a first-order lag of time constant ``tau_s`` (exact for ``x`` linear
    between samples; starts settled at ``x[0]``)."""
    out = np.empty_like(x)
    out[0] = x[0]
    for k in range(1, x.size):
        h = (t[k] - t[k - 1]) / tau_s
        a = math.exp(-h)
        g = (1.0 - a) / h
        # E_k = a E_{k-1} + (1 - g) x_k + (g - a) x_{k-1}  (ramp-exact)
        out[k] = a * out[k - 1] + (1.0 - g) * x[k] + (g - a) * x[k - 1]
    return out


def _magnetometers(t: np.ndarray, board: np.ndarray, seed: int, run: int
                   ) -> list[SensorInstance]:
    """Mag 0 (own thermometer) and mag 1 (none), from their own random streams."""
    laws = np.random.default_rng([seed, 40]).uniform(-1.0, 1.0, (2, 3, 4))
    rng = np.random.default_rng([seed, run, 40])
    north, east, down = EARTH_FIELD_UT
    psi = math.radians(_HEADING_DEG)
    earth = np.array([north * math.cos(psi) + east * math.sin(psi),
                      -north * math.sin(psi) + east * math.cos(psi), down])
    out = []
    for m in range(2):
        die = first_order_lag(t, board + (0.5, 1.5)[m], MAG_LAG_S[m])
        x = (die - 25.0) / 20.0
        drift = np.zeros((t.size, 3))
        for j in range(3):
            c = laws[m, j]
            lead = (6.0 if j == m else 2.0) * (0.6 + 0.4 * abs(c[0])) * np.sign(c[0] or 1.0)
            drift[:, j] = lead * x + 1.0 * c[1] * x ** 2 + 0.6 * c[2] * x ** 3
        values = earth + drift + rng.normal(0.0, _MAG_NOISE_UT, (t.size, 3))
        temp = np.round(die + rng.normal(0.0, 0.02, t.size), 2) if m == 0 else None
        out.append(SensorInstance("mag", m, MAG_IDS[m], t.copy(), temp, values, truth=drift))
    return out


#: The simulated board's short name in ArduPilot's system-id line.
BOARD_NAME = "SimFCBoard"


def board_id(seed: int, autopilot: str) -> str:
    """The board's own id as the autopilot logs it: a 12-byte MCU unique id drawn from
    ``[seed, 52]`` (the same for every run of the board), as PX4's ``sys_uuid`` (hex, after
    the STM32 GUID's ``000600000000`` prefix) or ArduPilot's ``Util::get_system_id`` line
    (the board's name and three words, each word's bytes high to low)."""
    uid = np.random.default_rng([seed, 52]).integers(0, 256, 12).astype(np.uint8).tobytes()
    if autopilot == "px4":
        return "000600000000" + uid.hex()
    words = " ".join(uid[4 * k:4 * k + 4][::-1].hex().upper() for k in range(3))
    return f"{BOARD_NAME} {words}"


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
        p["TC_M_ENABLE"] = 0.0
        for m, dev in enumerate(MAG_IDS):
            p[f"CAL_MAG{m}_ID"] = float(dev)
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
    for m, dev in enumerate(MAG_IDS):
        p[f"COMPASS_DEV_ID{'' if m == 0 else m + 1}"] = float(dev)
    return p


def simulate_board(preset: str = "fc-board", *, autopilot: str = "px4", seed: int = 0,
                   rate_hz: float = _RATE_HZ, path: str | Path = "<simulated>",
                   run: int = 0) -> FlightLog:
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
    run : int
        Which warm-up of the same board (0: the procedure's own; see the module).
    """
    if preset not in BOARD_PRESETS:
        raise InputError(f"unknown board preset '{preset}' (known: {', '.join(BOARD_PRESETS)})")
    if autopilot not in ("px4", "ardupilot"):
        raise InputError(f"autopilot must be 'px4' or 'ardupilot', got '{autopilot}'")
    if not (isinstance(rate_hz, (int, float)) and 0.01 <= rate_hz <= 1000.0):
        raise InputError(f"rate_hz must be within 0.01..1000 Hz, got {rate_hz!r}")
    if not (isinstance(run, int) and run >= 0):
        raise InputError(f"run must be a non-negative integer, got {run!r}")
    cycle = preset == "fc-board-cycle"
    # the board's drift laws come from the seed alone (the same for every run, any rate);
    # the noise and the warm-up from (seed, run)
    laws = np.random.default_rng(seed).uniform(-1.0, 1.0, (3, 2, 3, 4))
    rng = np.random.default_rng([seed, run])
    duration = 2 * _WARM_S if cycle else _WARM_S
    t = np.arange(0.0, duration, 1.0 / rate_hz) + 1.0
    board = _board_temperature(t - t[0], cycle, _warm_up(run, seed))
    instances: list[SensorInstance] = []
    for k in range(3):
        sensor_t = board + (0.0, 2.0, -1.0)[k] + rng.normal(0.0, 0.02, t.size)
        logged_t = np.round(sensor_t) if k == 2 else np.round(sensor_t, 2 if k == 0 else 3)
        dT = sensor_t - 25.0
        gyro_drift = _law(laws[k, 0], k, dT, 0.01)            # ~0.01 rad/s
        acc_drift = _law(laws[k, 1], k, dT, 0.08)             # ~0.08 m/s^2
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
    instances += _magnetometers(t, board, seed, run)
    return FlightLog(path=Path(path), autopilot=autopilot, instances=instances,
                     params=board_params(autopilot),
                     notes=[f"simulated {preset}, seed {seed}, run {run}"],
                     board_id=board_id(seed, autopilot))
