"""Flights of one vehicle across the seasons: the fc-board board flown, with its estimator.

``simulate_flights(n, seed=...)`` gives ``n`` :class:`SimFlight` of the **same board** as
``simulate_board("fc-board", seed=seed)`` (:mod:`thermonet.sim.fcboard`: the same device ids
and the same true drift laws of its three IMUs, drawn from ``seed`` alone), and the same board id
(:func:`~thermonet.sim.fcboard.board_id`), so a chamber calibration of that board and what
``thermonet learn`` makes of its flights can be judged against one truth.

Each flight (its own random stream ``[seed, 1000 + k]``):

* **ambient** — flight ``k`` of ``n`` sits at a season's point: ambient ``−8 … 35 °C``
  spread over the flights (a golden-ratio sequence: every prefix of the flights spans the
  seasons), ± 2 °C;
* **warm-up on the ground** (3–8 min, still: the board self-heats towards ambient + 12 °C,
  time constant 5 min), **the flight** (10–25 min, turning and accelerating: the board heats
  towards ambient + 22 °C, 7 min), **cooling** after landing (2–6 min, still, motors off:
  towards ambient + 6 °C, 4 min); each IMU's die is the board plus its fc-board offset;
* **the sensors** — raw output = body motion + the board's true drift at the die
  temperature + noise (fc-board's), logged at ``rate_hz``; the thermometers as fc-board logs
  them (IMU 2 in whole degrees);
* **what the autopilot applied** — PX4: ``CAL_GYRO<n>_*OFF`` / ``CAL_ACC<n>_*OFF`` from a
  calibration at 25 °C (the drift there, plus a small error), and from the middle flight on a
  partial thermal calibration (``TC_G_ENABLE`` / ``TC_A_ENABLE`` = 1, a line through the
  drift at 15 and 35 °C); ArduPilot: ``INS_ACCOFFS`` likewise, ``INS_GYROFFS`` measured at
  every boot (the drift at the boot temperature: a new value each flight), ``INS_TCAL1/2``
  from the middle flight on;
* **the estimator** — per EKF2 instance / EKF3 core on IMUs 0 and 1: its bias is the true
  drift less what was applied (the bias it must find), seen through a first-order lag of
  :data:`EKF_TAU_S` (gyro 60 s, accelerometer 120 s) from zero at start-up, plus noise; its
  variance falls from its initial value as it converges (``valid`` once under
  :data:`VALID_VARIANCE_RATIO` times the settled variance); in :data:`DIVERGE_FRACTION` of
  the flights one estimator wanders off for 1–3 minutes in flight (a maneuver, a bad
  magnetometer: up to ±0.02 rad/s, ±0.3 m/s²) without its variance saying so.

Units as the autopilots log them (rad/s, m/s², body frame = sensor frame: no board
rotation).  ``SimFlight.truth`` holds each sensor's true drift, by instance name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..data.logs.base import FlightLog, SensorInstance
from ..data.logs.flight_writers import EstimatorBias
from .fcboard import _PX4_IDS, _law, board_id, board_params

__all__ = ["SimFlight", "simulate_flights", "true_drift", "EKF_TAU_S", "DIVERGE_FRACTION",
           "MAX_FLIGHTS", "VALID_VARIANCE_RATIO"]

#: Most flights one call simulates.
MAX_FLIGHTS = 2000
#: The estimator's lag behind the true bias (s), per kind.
EKF_TAU_S = {"gyro": 60.0, "acc": 120.0}
#: Fraction of flights in which one estimator diverges for a while.
DIVERGE_FRACTION = 0.15
#: ``valid`` once the variance is under this multiple of its settled value.
VALID_VARIANCE_RATIO = 4.0
_G = 9.80665
_DIE = (0.0, 2.0, -1.0)           # fc-board's die offsets from the board, °C
_NOISE = {"gyro": 5e-4, "acc": 4e-3}
_EKF_NOISE = {"gyro": 1e-4, "acc": 2e-3}
_SETTLED_VAR = {"gyro": 1e-8, "acc": 1e-5}
_ESTIMATORS = (0, 1)


@dataclass
class SimFlight:
    """One simulated flight: the log (sensors with their truth), what each estimator logged,
    and the true drift per instance name (``gyro0``, ``acc1`` …)."""

    log: FlightLog
    biases: list[EstimatorBias]
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    ambient_c: float = 0.0


def true_drift(seed: int, kind: str, imu: int, temperature_c: np.ndarray) -> np.ndarray:
    """The board's true drift (n, 3) of IMU ``imu``'s ``kind`` at its die temperature: the
    fc-board law of ``seed`` (the same as ``simulate_board``'s ``truth``)."""
    laws = np.random.default_rng(seed).uniform(-1.0, 1.0, (3, 2, 3, 4))
    k = 0 if kind == "gyro" else 1
    return _law(laws[imu, k], imu, np.asarray(temperature_c, dtype=np.float64) - 25.0,
                0.01 if kind == "gyro" else 0.08)


def _timeline(rng: np.random.Generator, ambient: float, rate_hz: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time s, board °C, in-flight mask) of one flight."""
    ground, air, cool = rng.uniform(180, 480), rng.uniform(600, 1500), rng.uniform(120, 360)
    t = np.arange(0.0, ground + air + cool, 1.0 / rate_hz) + 1.0
    rel = t - t[0]
    flying = (rel >= ground) & (rel < ground + air)
    phase = np.where(rel < ground, 0, np.where(flying, 1, 2))
    goal = np.array([ambient + 12.0, ambient + 22.0, ambient + 6.0])[phase]
    tau = np.array([300.0, 420.0, 240.0])
    board = np.empty_like(t)
    board[0] = ambient
    for k in range(1, t.size):
        a = math.exp(-(t[k] - t[k - 1]) / tau[phase[k]])
        board[k] = goal[k] + (board[k - 1] - goal[k]) * a
    return t, board, flying


def _motion(rng: np.random.Generator, t: np.ndarray, flying: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Body rates (rad/s) and specific force (m/s²) of the flight: still on the ground."""
    rates = np.zeros((t.size, 3))
    force = np.tile([0.0, 0.0, -_G], (t.size, 1))
    for j in range(3):
        for _ in range(3):
            amp, per, ph = rng.uniform(0.05, 0.3), rng.uniform(4.0, 40.0), rng.uniform(0, 6.3)
            rates[:, j] += amp * np.sin(2 * math.pi * t / per + ph)
            force[:, j] += 0.5 * amp * np.cos(2 * math.pi * t / per + ph)
    return rates * flying[:, None], np.where(flying[:, None], force, [0.0, 0.0, -_G])


def _applied(seed: int, kind: str, imu: int, temp: np.ndarray, late: bool,
             autopilot: str, boot_c: float, rng: np.random.Generator
             ) -> tuple[np.ndarray, dict[str, float]]:
    """What the autopilot subtracts from IMU ``imu``'s ``kind`` (n, 3), and its parameters."""
    params: dict[str, float] = {}
    at = boot_c if (autopilot == "ardupilot" and kind == "gyro") else 25.0
    offset = true_drift(seed, kind, imu, np.array([at]))[0] + rng.normal(
        0.0, 0.05 * _NOISE[kind] * 10, 3)
    n = "" if imu == 0 else str(imu + 1)
    for j, a in enumerate("XYZ"):
        if autopilot == "px4":
            params[f"CAL_{'GYRO' if kind == 'gyro' else 'ACC'}{imu}_{a}OFF"] = float(offset[j])
        else:
            params[f"INS_{'GYR' if kind == 'gyro' else 'ACC'}{n}OFFS_{a}"] = float(offset[j])
    corr = np.tile(offset, (temp.size, 1))
    if late:
        lo, hi = true_drift(seed, kind, imu, np.array([15.0, 35.0]))
        slope = (hi - lo) / 20.0
        ref = 25.0 if autopilot == "px4" else 35.0
        if autopilot == "px4":
            letter = "G" if kind == "gyro" else "A"
            pre = f"TC_{letter}{imu}_"
            params.update({f"TC_{letter}_ENABLE": 1.0, pre + "ID": float(_PX4_IDS[imu][
                0 if kind == "gyro" else 1]), pre + "TREF": ref, pre + "TMIN": -20.0,
                pre + "TMAX": 70.0})
            for j in range(3):
                c = {0: float(true_drift(seed, kind, imu, np.array([ref]))[0][j] - offset[j]),
                     1: float(slope[j]), 2: 0.0, 3: 0.0}
                params.update({f"{pre}X{k}_{j}": v for k, v in c.items()})
            corr = corr + c0_line(temp, ref, slope, true_drift(
                seed, kind, imu, np.array([ref]))[0] - offset)
        else:
            pre = f"INS_TCAL{imu + 1}_"
            params.update({pre + "ENABLE": 1.0, pre + "TMIN": -20.0, pre + "TMAX": 70.0})
            stype = "GYR" if kind == "gyro" else "ACC"
            for j, a in enumerate("XYZ"):
                params[f"{pre}{stype}1_{a}"] = float(slope[j]) * 1e6
                for k in (2, 3):
                    params[f"{pre}{stype}{k}_{a}"] = 0.0
            params[f"INS_{stype}{imu + 1}_CALTEMP"] = at
            corr = corr + (np.clip(temp, -20, 70) - at)[:, None] * slope
    return corr, params


def c0_line(temp: np.ndarray, ref: float, slope: np.ndarray, c0: np.ndarray) -> np.ndarray:
    """PX4's ``calc_thermal_offsets_3D`` of a line: ``c0 + slope·(T − TREF)`` (T clamped to
    the written −20 … 70 °C)."""
    return c0 + (np.clip(temp, -20.0, 70.0) - ref)[:, None] * slope


def _estimator(rng: np.random.Generator, t: np.ndarray, target: np.ndarray, kind: str,
               flying: np.ndarray, diverge: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(bias, variance, valid) an estimator logs chasing ``target`` (see the module)."""
    tau = EKF_TAU_S[kind]
    est = np.empty_like(target)
    state = np.zeros(3)
    est[0] = state
    for k in range(1, t.size):
        a = math.exp(-(t[k] - t[k - 1]) / tau)
        state = target[k] + (state - target[k]) * a
        est[k] = state
    est = est + rng.normal(0.0, _EKF_NOISE[kind], est.shape)
    if diverge and flying.any():
        air = np.flatnonzero(flying)
        start = t[rng.integers(air[0], max(air[0] + 1, air[-1] - 200))]
        length = rng.uniform(60.0, 180.0)
        size = rng.uniform(0.5, 1.0) * (0.02 if kind == "gyro" else 0.3)
        bump = np.clip((t - start) / length, 0.0, None)
        shape = np.where(bump <= 1.0, np.sin(math.pi * bump), 0.0)
        est = est + size * shape[:, None] * rng.choice([-1.0, 1.0], 3)
    var0 = 1e4 * _SETTLED_VAR[kind]
    variance = _SETTLED_VAR[kind] + var0 * np.exp(-2.0 * (t - t[0]) / tau)
    valid = variance < VALID_VARIANCE_RATIO * _SETTLED_VAR[kind]
    return est, np.tile(variance[:, None], (1, 3)), valid


def _flight(seed: int, k: int, n: int, autopilot: str, rate_hz: float) -> SimFlight:
    rng = np.random.default_rng([seed, 1000 + k])
    ambient = -8.0 + 43.0 * ((k * 0.6180339887) % 1.0) + rng.uniform(-2.0, 2.0)
    t, board, flying = _timeline(rng, ambient, rate_hz)
    rates, force = _motion(rng, t, flying)
    late = k >= n // 2
    params = board_params(autopilot)
    params["EKF2_MULTI_IMU" if autopilot == "px4" else "EK3_IMU_MASK"] = 2.0 if \
        autopilot == "px4" else 3.0
    instances, truth, targets = [], {}, {}
    for imu in range(3):
        die = board + _DIE[imu] + rng.normal(0.0, 0.02, t.size)
        logged = np.round(die) if imu == 2 else np.round(die, 2 if imu == 0 else 3)
        for kind, motion in (("gyro", rates), ("acc", force)):
            drift = true_drift(seed, kind, imu, die)
            corr, p = _applied(seed, kind, imu, die, late, autopilot, float(die[0]), rng)
            params.update(p)
            raw = motion + drift + rng.normal(0.0, _NOISE[kind], drift.shape)
            # ArduPilot's IMU is logged after the offsets and INS_TCAL (its reader adds INS_TCAL
            # back); PX4's sensor_* is the driver's raw output
            logged_v = raw - corr if autopilot == "ardupilot" else raw
            dev = _PX4_IDS[imu][0 if kind == "gyro" else 1]
            instances.append(SensorInstance(kind, imu, dev, t.copy(), logged, logged_v,
                                            truth=drift))
            truth[f"{kind}{imu}"] = drift
            targets[(kind, imu)] = drift - corr
    diverging = rng.uniform() < DIVERGE_FRACTION
    which = int(rng.integers(0, len(_ESTIMATORS)))
    biases = []
    for e in _ESTIMATORS:
        g = _estimator(rng, t, targets[("gyro", e)], "gyro", flying, diverging and which == e)
        a = _estimator(rng, t, targets[("acc", e)], "acc", flying, diverging and which == e)
        biases.append(EstimatorBias(e, _PX4_IDS[e][0], _PX4_IDS[e][1], t.copy(), g[0], a[0],
                                    g[1], a[1], g[2], a[2]))
    log = FlightLog(path=Path(f"flight{k + 1:04d}"), autopilot=autopilot, instances=instances,
                    params=params, notes=[f"simulated flight {k + 1} of {n}, seed {seed}, "
                                          f"ambient {ambient:.1f} °C"],
                    board_id=board_id(seed, autopilot))
    return SimFlight(log, biases, truth, ambient)


def simulate_flights(n: int, *, seed: int = 0, autopilot: str = "px4", rate_hz: float = 1.0,
                     first: int = 0) -> list[SimFlight]:
    """``n`` flights of the fc-board vehicle of ``seed`` (see the module); ``first`` skips
    to flight ``first`` of the same sequence (flight ``k`` is the same whatever ``n``, but
    the calibration loaded from the middle flight on follows ``n``)."""
    if not (isinstance(n, int) and 1 <= n <= MAX_FLIGHTS):
        raise InputError(f"--flights {n!r}: a whole number in 1..{MAX_FLIGHTS}")
    if autopilot not in ("px4", "ardupilot"):
        raise InputError(f"autopilot must be 'px4' or 'ardupilot', got '{autopilot}'")
    if not (isinstance(rate_hz, (int, float)) and 0.1 <= rate_hz <= 100.0):
        raise InputError(f"rate_hz must be within 0.1..100 Hz, got {rate_hz!r}")
    return [_flight(seed, k, n, autopilot, float(rate_hz)) for k in range(first, n)]
