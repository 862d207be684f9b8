"""The autopilots' thermal-compensation formulas and their full calibration files.

Used by ``thermonet calibrate`` (:mod:`thermonet.workflows.calibrate`), which fits the
firmware's own polynomial directly on a log; :mod:`thermonet.exporting.autopilot`
turns a fitted thermonet model into the same parameters.

PX4 (``src/modules/temperature_compensation/TemperatureCompensation.cpp``,
``calc_thermal_offsets_3D`` / ``calc_thermal_offsets_1D``)::

    T clamped to [TMIN, TMAX];  dT = T - TREF
    gyro / accel / mag:  offset_i = X0_i + X1_i dT + X2_i dT^2 + X3_i dT^3
                         (rad/s, m/s^2, gauss)
    baro:                offset   = X0 + X1 dT + ... + X5 dT^5          (Pa)
    corrected = raw - offset

A slot applies to the sensor whose device id equals ``TC_*_ID``
(``set_sensor_id``); ``TC_G/A/B/M_ENABLE`` switch each kind on.  Four slots per kind
(``GYRO_COUNT_MAX`` …, ``MAG_COUNT_MAX``).

Magnetometers (``TC_M*``: ``temp_comp_params_mag.yaml`` / ``temp_comp_params_mag_0.yaml``
…, ``TemperatureCompensation::update_offsets_mag``; PX4-Autopilot after v1.14 (v1.15+:
the user guide's Thermal Calibration page, "Releases up to PX4 v1.14, do not support thermal
calibration of the magnetometer"), read at main): the same cubic as the gyro's, on
``sensor_mag`` in **gauss** (the unit the driver publishes and the on-board calibrator
``temperature_calibration/mag.cpp`` fits), with the magnetometer's **own**
``sensor_mag.temperature`` — ``TemperatureCompensationModule.cpp`` polls each sensor's own
report and, as for the gyro, accel and baro, skips it while its temperature is not finite,
so a magnetometer without a thermometer cannot be compensated on board.  thermonet keeps
magnetometers in µT; :data:`PX4_PARAM_UNIT` converts.  The on-board calibrator writes
``X0 = 0`` ("normalise the correction to be zero at the reference temperature"): the
correction is the change from the value at TREF, so the Earth's field stays in the
signal; thermonet fits it so too.  File: QGroundControl ``Vehicle-Id Component-Id Name
Value Type`` lines (type 6 INT32, 9 REAL32), as ``Tools/process_sensor_caldata.py``
writes it.

ArduPilot (``libraries/AP_InertialSensor/AP_InertialSensor_tempcal.cpp``,
``TCal::correct_sensor``)::

    T, T_cal clamped to [TMIN, TMAX];  P(x) = (c1 x + c2 x^2 + c3 x^3) * 1e-6
    corrected = raw - P(T - 35) + P(T_cal - 35)

File: ``NAME,VALUE`` lines (Mission Planner).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..core.errors import ExportError

__all__ = ["FirmwareFit", "PX4_SLOTS", "PX4_PARAM_UNIT", "PX4_LETTER", "ARDUPILOT_TEMP_REFERENCE", "ARDUPILOT_SCALE",
           "px4_offsets_3d", "px4_offsets_1d", "ardupilot_correction",
           "px4_calibration_text", "ardupilot_calibration_text"]

#: PX4's slots per sensor kind (GYRO_COUNT_MAX, ACCEL_COUNT_MAX, BARO_COUNT_MAX = 4).
PX4_SLOTS = 4
#: ArduPilot's fixed reference temperature (°C) and coefficient scale.
ARDUPILOT_TEMP_REFERENCE = 35.0
ARDUPILOT_SCALE = 1.0e6
_PX4_TYPE = {"gyro": "G", "acc": "A", "baro": "B", "mag": "M"}
#: PX4's parameter letter per sensor kind (``TC_<letter>*``).
PX4_LETTER = _PX4_TYPE
#: thermonet units per PX4 parameter unit, per kind (``TC_M*`` are gauss, thermonet µT).
PX4_PARAM_UNIT = {"gyro": 1.0, "acc": 1.0, "baro": 1.0, "mag": 100.0}
_AP_TYPE = {"gyro": "GYR", "acc": "ACC"}
_AXES = ("x", "y", "z")


@dataclass
class FirmwareFit:
    """One sensor instance's drift in the autopilot's own form, SI units.

    Attributes
    ----------
    kind : ``gyro`` | ``acc`` | ``baro`` | ``mag``
    device_id : int
    t_ref, t_min, t_max : float
        °C; PX4: TREF, TMIN, TMAX; ArduPilot: 35 °C, TMIN, TMAX.
    coef : array (axes, order + 1)
        Column k multiplies :math:`(T - T_{ref})^k`; rad/s, m/s², Pa, µT.
    thermometer : str or None
        None: the sensor's own thermometer; else the instance whose thermometer was lent
        (a magnetometer without one), seen through a first-order lag of ``lag_s``.
    lag_s : float
        The lag's time constant, s (0: none): T is ``EMA_lag(T_thermometer)``.
    """

    kind: str
    device_id: int
    t_ref: float
    t_min: float
    t_max: float
    coef: np.ndarray
    thermometer: str | None = None
    lag_s: float = 0.0


def _g(v: float) -> str:
    return f"{float(v):.9g}"


def _px4_dt(params: Mapping[str, float], pre: str, temperature_c: np.ndarray) -> np.ndarray:
    temp = np.asarray(temperature_c, dtype=np.float64)
    return np.clip(temp, params[pre + "TMIN"], params[pre + "TMAX"]) - params[pre + "TREF"]


def px4_offsets_3d(params: Mapping[str, float], kind: str, temperature_c: np.ndarray,
                   slot: int = 0) -> np.ndarray:
    """``calc_thermal_offsets_3D`` (gyro/accel/mag) on parameters read back: (N, 3) in
    thermonet's units (a magnetometer's gauss coefficients give µT)."""
    pre = f"TC_{_PX4_TYPE[kind]}{slot}_"
    dt = _px4_dt(params, pre, temperature_c)
    out = np.zeros((dt.size, 3))
    for i in range(3):
        for k in range(4):
            out[:, i] += params[f"{pre}X{k}_{i}"] * dt ** k
    return out * PX4_PARAM_UNIT[kind]


def px4_offsets_1d(params: Mapping[str, float], temperature_c: np.ndarray,
                   slot: int = 0) -> np.ndarray:
    """``calc_thermal_offsets_1D`` (baro, order 5, Pa) on parameters read back: (N,)."""
    pre = f"TC_B{slot}_"
    dt = _px4_dt(params, pre, temperature_c)
    out = np.zeros_like(dt)
    for k in range(6):
        out = out + params[f"{pre}X{k}"] * dt ** k
    return out


def ardupilot_correction(params: Mapping[str, float], kind: str, temperature_c: np.ndarray,
                         cal_temp_c: float, imu: int = 1) -> np.ndarray:
    """What ``TCal::correct_sensor`` subtracts: P(T−35) − P(T_cal−35), (N, 3) SI; ``imu`` 1..3."""
    pre = f"INS_TCAL{imu}_"
    lo, hi = params[pre + "TMIN"], params[pre + "TMAX"]
    x = np.clip(np.asarray(temperature_c, dtype=np.float64), lo, hi) - ARDUPILOT_TEMP_REFERENCE
    xc = float(np.clip(cal_temp_c, lo, hi)) - ARDUPILOT_TEMP_REFERENCE
    out = np.zeros((x.size, 3))
    for i, ax in enumerate(_AXES):
        c1, c2, c3 = (params[f"{pre}{_AP_TYPE[kind]}{k}_{ax.upper()}"] / ARDUPILOT_SCALE
                      for k in (1, 2, 3))
        out[:, i] = ((c1 + (c2 + c3 * x) * x) * x) - ((c1 + (c2 + c3 * xc) * xc) * xc)
    return out


def px4_calibration_text(fits: Mapping[str, list[FirmwareFit]], *, header: list[str],
                         fitted_kinds_only: bool = False) -> str:
    """A QGC ``.params`` file with every ``TC_G*``, ``TC_A*``, ``TC_B*`` slot, and every
    ``TC_M*`` slot when ``fits`` has a ``mag`` entry (the log has magnetometers; an empty
    list writes ``TC_M_ENABLE`` 0 and cleared slots).  ``fitted_kinds_only``: a kind with no
    fit is not written at all (``thermonet learn``, which never learns a barometer: its
    ``TC_B*`` are left as the board has them, not disabled and cleared).

    ``fits[kind]`` lists the fitted instances in slot order; the remaining
    slots (up to 4) are written with ID 0 and zero coefficients, so that a
    calibration left over from an earlier board can never be applied.
    ``TC_<k>_ENABLE`` is 1 where at least one instance of the kind was fitted.
    Magnetometer coefficients (µT) are written in gauss, as the firmware applies them
    to ``sensor_mag``.
    """
    rows: list[tuple[str, str, int]] = []
    kinds = [("acc", "A"), ("baro", "B"), ("gyro", "G")] + ([("mag", "M")] if "mag" in fits
                                                            else [])
    if fitted_kinds_only:
        kinds = [(kind, t) for kind, t in kinds if fits.get(kind)]
    for kind, t in kinds:
        kind_fits = list(fits.get(kind, []))
        if any(f.thermometer for f in kind_fits):
            raise ExportError(f"a {kind} fitted on a lent thermometer cannot be a PX4 slot "
                              "(the firmware reads the sensor's own temperature)")
        if len(kind_fits) > PX4_SLOTS:
            raise ExportError(f"PX4 has {PX4_SLOTS} {kind} calibration slots; {len(kind_fits)} "
                              "instances were fitted")
        rows.append((f"TC_{t}_ENABLE", "1" if kind_fits else "0", 6))
        for slot in range(PX4_SLOTS):
            fit = kind_fits[slot] if slot < len(kind_fits) else None
            pre = f"TC_{t}{slot}_"
            rows.append((pre + "ID", str(int(fit.device_id)) if fit else "0", 6))
            rows += [(pre + "TMAX", _g(fit.t_max if fit else 0.0), 9),
                     (pre + "TMIN", _g(fit.t_min if fit else 0.0), 9),
                     (pre + "TREF", _g(fit.t_ref if fit else 0.0), 9)]
            if kind == "baro":
                for k in range(6):
                    v = fit.coef[0, k] if fit is not None else 0.0
                    rows.append((f"{pre}X{k}", _g(v), 9))
            else:
                for k in range(4):
                    for i in range(3):
                        v = fit.coef[i, k] / PX4_PARAM_UNIT[kind] if fit is not None else 0.0
                        rows.append((f"{pre}X{k}_{i}", _g(v), 9))
    for _, value, ptype in rows:
        if ptype == 9 and not math.isfinite(float(value)):
            raise ExportError("a PX4 coefficient is not finite; nothing written")
    lines = [f"# {h}" for h in header] + ["#", "# Vehicle-Id Component-Id Name Value Type"]
    lines += [f"1\t1\t{name}\t{value}\t{ptype}" for name, value, ptype in rows]
    return "\n".join(lines) + "\n"


def ardupilot_calibration_text(imus: Mapping[int, Mapping[str, FirmwareFit]], *,
                               header: list[str]) -> str:
    """ArduPilot ``INS_TCAL<n>_*`` lines (``NAME,VALUE``) for each fitted IMU (0-based keys).

    ``INS_TCAL_OPTIONS`` is not written (left as the board has it).  Only the sensors fitted
    are written: ``INS_TCAL<n>`` holds one IMU's gyro *and* accelerometer, and zeros for the
    one not fitted would wipe the calibration the board holds for it when the file is loaded
    (as ``thermonet export`` writes a gyro-only model); a comment line names what is left
    alone.  After the header, one ``# device ids: INS_TCAL<n> gyro G acc A`` line per IMU (0:
    that sensor is not in the file), which ``thermonet verify`` matches the log's sensors by.
    """
    lines = [f"# {h}" for h in header]
    lines += [f"# device ids: INS_TCAL{idx + 1} gyro "
              f"{imus[idx]['gyro'].device_id if 'gyro' in imus[idx] else 0} acc "
              f"{imus[idx]['acc'].device_id if 'acc' in imus[idx] else 0}" for idx in sorted(imus)]
    for idx in sorted(imus):
        pair = imus[idx]
        if not 0 <= idx <= 2:
            raise ExportError(f"ArduPilot has INS_TCAL1..3; IMU index {idx} has no slot")
        lines += [f"# INS_TCAL{idx + 1}_{_AP_TYPE[k]}*: not written ({k} of IMU {idx + 1} not "
                  "fitted): the board keeps its own values" for k in ("acc", "gyro")
                  if k not in pair]
    for idx in sorted(imus):
        pair = imus[idx]
        first = next(iter(pair.values()))
        t_min = min(f.t_min for f in pair.values())
        t_max = max(f.t_max for f in pair.values())
        if t_min < -70.0 or t_max > 80.0:
            raise ExportError(f"IMU {idx + 1}: range [{t_min:g}, {t_max:g}] degC is outside "
                              "ArduPilot's INS_TCAL TMIN/TMAX range -70..80 degC")
        if first.t_ref != ARDUPILOT_TEMP_REFERENCE:
            raise ExportError("ArduPilot coefficients must be relative to 35 degC")
        pre = f"INS_TCAL{idx + 1}_"
        lines += [f"{pre}ENABLE,1", f"{pre}TMIN,{_g(t_min)}", f"{pre}TMAX,{_g(t_max)}"]
        for kind in (k for k in ("acc", "gyro") if k in pair):
            fit = pair[kind]
            for k in (1, 2, 3):
                for i, ax in enumerate(_AXES):
                    v = fit.coef[i, k] * ARDUPILOT_SCALE
                    if not math.isfinite(v):
                        raise ExportError("an ArduPilot coefficient is not finite; nothing written")
                    lines.append(f"{pre}{_AP_TYPE[kind]}{k}_{ax.upper()},{_g(v)}")
    return "\n".join(lines) + "\n"
