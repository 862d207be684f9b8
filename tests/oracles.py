"""The autopilots' own formulas and parameter files, re-implemented once for every test.

Each function is written from the firmware's source, independently of thermonet (none of
:mod:`thermonet.exporting.autopilot`, :mod:`thermonet.data.firmware` or
:mod:`thermonet.workflows.verify` is used), so a test that applies a file thermonet wrote
through these functions checks thermonet against the vehicle, not against itself:

* **PX4** ``src/modules/temperature_compensation/TemperatureCompensation.cpp`` at
  PX4/PX4-Autopilot commit b8ad9bdbe5adcf6d6b8bbc78f0ab3f6ad895cc7a (with ``TC_M*``, v1.15+):
  ``calc_thermal_offsets_3D`` / ``_1D`` (:func:`px4_offsets`) and ``set_sensor_id``
  (:func:`px4_slot`); the vehicle subtracts the offset from the raw output, in the sensor's
  own unit (rad/s, m/s², Pa, and gauss for ``sensor_mag``).
* **ArduPilot** ``libraries/AP_InertialSensor/AP_InertialSensor_tempcal.cpp`` at
  ArduPilot/ardupilot commit b44478217fa4d7c33db9547391a912c5ffec71c8:
  ``TCal::correct_sensor`` with ``polynomial_eval`` (:func:`ardupilot_offsets`).
* **Parameter files** (:func:`read_params`): PX4's QGroundControl file (``Vehicle-Id
  Component-Id Name Value Type``, tab-separated) and ArduPilot's ``NAME,VALUE`` (or
  ``NAME VALUE``) lines, read as a vehicle loads them: in order, the last value of a name wins.

The peers' *calibration scripts* (``process_sensor_caldata.py``, ``tempcal_IMU.py``) are
re-implemented in ``tests/test_autopilot_parity.py`` and ``experiments/px4_caldata_anchor.py``.

Beside them, the dynamic inputs one sample at a time (:func:`dynamic_inputs_loop`): the
recurrences of ``configs/README.md`` ("Dynamic inputs") in a plain loop, the names parsed here,
none of :mod:`thermonet.features.dynamics` used — the oracle of its vectorised scans.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

#: PX4's letter for each kind of sensor in ``TC_<letter><slot>_*``
PX4_LETTER = {"gyro": "G", "acc": "A", "baro": "B", "mag": "M"}

#: ArduPilot's ``TEMP_REFERENCE``: its polynomials are in T − 35 °C
AP_TREF = 35.0


def read_params(path: Path, *, strict: bool = True) -> dict[str, float]:
    """The parameters of a PX4 or ArduPilot file, the last value of a name winning.

    ``strict`` (for files thermonet wrote): every line but comments and blank ones is
    well formed — PX4: five tab-separated fields, vehicle and component 1, type 6 (int32) or
    9 (float); ArduPilot: a name and a value.  ``strict=False`` reads a damaged file as far
    as a vehicle would (what ``tests/test_verify_damaged.py`` needs).
    """
    out: dict[str, float] = {}
    for line in path.read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        f = line.split("\t") if "\t" in line else line.replace(",", " ").split()
        if strict:
            if "\t" in line:
                assert len(f) == 5 and (f[0], f[1]) == ("1", "1") and f[4] in ("6", "9"), line
            else:
                assert len(f) == 2, line
        name, value = (f[2], f[3]) if len(f) == 5 else (f[0], f[1])
        out[name] = float(value)
    return out


def px4_slot(p: Mapping[str, float], letter: str, device_id: int) -> str | None:
    """``set_sensor_id``: the prefix ``TC_<letter><s>_`` of the slot whose ID is the sensor's
    device id (the int32 parameter compared as uint32), or None where no slot names it."""
    for s in range(4):
        slot_id = p.get(f"TC_{letter}{s}_ID")
        if slot_id is not None and int(slot_id) & 0xFFFFFFFF == device_id:
            return f"TC_{letter}{s}_"
    return None


def px4_offsets(p: Mapping[str, float], pre: str, temp: np.ndarray, *,
                dtype: type = np.float64) -> np.ndarray:
    """``calc_thermal_offsets_3D`` (``pre`` ``TC_G0_``, ``TC_A1_``, ``TC_M0_`` …: (n, 3)) or
    ``_1D`` (``TC_B<s>_``: (n,), X0…X5): T clamped to [TMIN, TMAX], offset = Σ_k X_k (T − TREF)^k.

    ``dtype`` np.float32 computes as the firmware does (parameters and arithmetic in float);
    the default float64 is the formula exact, for comparisons finer than float32 holds.
    The clamp is ``min(max(T, TMIN), TMAX)``: the firmware's ``if T > TMAX … else if T < TMIN``
    for every TMIN ≤ TMAX; where TMIN or TMAX is NaN it gives NaN, where the firmware's
    comparisons (false with NaN) would leave T − TREF — ``tests/test_verify_damaged.py``'s
    NaN-range files are judged by this clamp.
    """
    with np.errstate(all="ignore"):      # a damaged file's NaN, inf or 1e39 goes through
        c = {k: dtype(v) for k, v in p.items() if k.startswith(pre)}
        x = np.minimum(np.maximum(np.asarray(temp).astype(dtype), c[pre + "TMIN"]),
                       c[pre + "TMAX"]) - c[pre + "TREF"]
        if pre[3] == "B":
            return sum((c[f"{pre}X{k}"] * x ** k for k in range(6)), np.zeros_like(x))
        return np.column_stack([sum((c[f"{pre}X{k}_{i}"] * x ** k for k in range(4)),
                                    np.zeros_like(x)) for i in range(3)])


def ardupilot_offsets(p: Mapping[str, float], imu: int, kind: str, temp: np.ndarray,
                      t_cal: float, *, dtype: type = np.float64) -> np.ndarray:
    """``TCal::correct_sensor`` for IMU ``imu`` (0-based; ``INS_TCAL<imu + 1>_*``), ``kind``
    "gyro" or "acc": what the vehicle subtracts, (n, 3) — P(T − 35) − P(T_cal − 35), T and
    T_cal clamped to [TMIN, TMAX] (``constrain_float``), P(x) = (c1 + (c2 + c3 x) x) x · 1e-6
    (``polynomial_eval``).  ``dtype`` as in :func:`px4_offsets`."""
    pre = f"INS_TCAL{imu + 1}_"
    s = "GYR" if kind == "gyro" else "ACC"
    with np.errstate(all="ignore"):
        lo, hi, ref = dtype(p[pre + "TMIN"]), dtype(p[pre + "TMAX"]), dtype(AP_TREF)
        x = np.minimum(np.maximum(np.asarray(temp).astype(dtype), lo), hi) - ref
        xc = np.minimum(np.maximum(dtype(t_cal), lo), hi) - ref
        cols = []
        for ax in "XYZ":
            c1, c2, c3 = (dtype(p[f"{pre}{s}{k}_{ax}"]) for k in (1, 2, 3))
            cols.append((c1 + (c2 + c3 * x) * x) * x * dtype(1e-6)
                        - (c1 + (c2 + c3 * xc) * xc) * xc * dtype(1e-6))
    return np.column_stack(cols)


def dynamic_inputs_loop(time_s, temperature_c, names, gap_s):
    """Every dynamic input of ``names`` (``rate``, ``rate_<τ>``, ``lag_<τ>``, ``delayed_<τ>``,
    ``play_<w>``) one sample at a time: with e = T − EMA_τ(T) (T linear between samples),
    e_k = e_{k−1} + g(h)·[(T_k − T_{k−1}) − h·e_{k−1}], h = Δt/τ, g = (1 − e^−h)/h; rate
    60·e/τ (°C/min), lag e, delayed T − e; play T − P, P_k = min(max(P_{k−1}, T_k − w), T_k + w).
    The first sample and the first after a gap (> ``gap_s`` since the last finite temperature)
    restart (e = 0, P = T); a NaN temperature gives NaN and leaves the state.  Returns
    ({signal name: values}, gap flags)."""
    import math

    specs = []
    for name in names:
        kind, _, value = name.partition("_")
        if kind not in ("rate", "lag", "delayed", "play"):
            continue
        c = float(value) if value else 60.0
        signal = ("rate_c_per_min" if name == "rate" else f"{name}_c_per_min") \
            if kind == "rate" else f"{name}_c"
        specs.append((kind, c, signal))
    n = len(time_s)
    out = {sig: np.full(n, np.nan) for _, _, sig in specs}
    gap = np.zeros(n, dtype=bool)
    started, t_prev, T_prev = False, 0.0, 0.0
    state = [0.0] * len(specs)
    for k in range(n):
        t, T = float(time_s[k]), float(temperature_c[k])
        if not math.isfinite(T):
            continue
        restart = not started or (t - t_prev) > gap_s
        gap[k] = started and restart
        for j, (kind, c, sig) in enumerate(specs):
            if kind == "play":
                state[j] = T if restart else min(max(state[j], T - c), T + c)
                out[sig][k] = T - state[j]
                continue
            if restart:
                state[j] = 0.0
            else:
                h = (t - t_prev) / c
                state[j] += -math.expm1(-h) / h * ((T - T_prev) - h * state[j])
            e = state[j]
            out[sig][k] = {"rate": 60.0 * e / c, "lag": e, "delayed": T - e}[kind]
        started, t_prev, T_prev = True, t, T
    return out, gap
