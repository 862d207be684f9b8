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
           "px4_calibration_text", "ardupilot_calibration_text", "px4_slot_plan", "px4_vehicle_id",
           "PX4_DEFAULT_VEHICLE_ID", "Px4Slot", "px4_active_slots", "EKF_PARAMS", "EKF_DEFAULTS", "EKF_FIRMWARE",
           "ekf_bound_line"]

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


#: QGroundControl's ``ParameterManager::readParametersFromStream`` refuses a whole file at
#: its first line whose Vehicle-Id is not the connected vehicle's MAVLink system id ("The
#: parameters in the stream have been saved from System Id …"): the id the file is written
#: with when no log records ``MAV_SYS_ID`` (PX4's default system id, 1).
PX4_DEFAULT_VEHICLE_ID = 1


def px4_vehicle_id(params: Mapping[str, float | None] | None, where: str = "the log"
                   ) -> tuple[int, str]:
    """The Vehicle-Id a QGC ``.params`` file is written with, and the comment saying why: the
    log's ``MAV_SYS_ID`` (a MAVLink system id, 1..255) where ``params`` records one, else
    :data:`PX4_DEFAULT_VEHICLE_ID`.  ``where``: what ``params`` are, in the comment."""
    v = (params or {}).get("MAV_SYS_ID")
    if v is not None and math.isfinite(v) and v == int(v) and 1 <= v <= 255:
        return int(v), (f"Vehicle-Id {int(v)}: the vehicle's MAV_SYS_ID as the log records it "
                        "(QGroundControl loads the file only onto that system id)")
    said = "records no MAV_SYS_ID" if v is None else \
        f"records MAV_SYS_ID {v:g}, not a MAVLink system id (1..255)"
    return PX4_DEFAULT_VEHICLE_ID, (
        f"Vehicle-Id {PX4_DEFAULT_VEHICLE_ID}: {where} {said} (PX4's default is 1); "
        "QGroundControl refuses the whole file on a vehicle with another system id: set the "
        "first column to yours")


def px4_active_slots(params: Mapping[str, float], kind: str) -> list[int] | None:
    """The device ids of the board's **active** PX4 slots of ``kind`` as a log's parameters
    record them (``TC_<k><s>_ID``, s = 0..3; all 0 where ``TC_<k>_ENABLE`` is not 1: the
    firmware applies none of them), or None where the log records no ``TC_<k>*``."""
    t = _PX4_TYPE[kind]
    if not any(k.startswith(f"TC_{t}") for k in params):
        return None
    on = params.get(f"TC_{t}_ENABLE", 1.0) == 1.0
    return [int(params.get(f"TC_{t}{s}_ID", 0)) & 0xFFFFFFFF if on else 0
            for s in range(PX4_SLOTS)]


#: One PX4 slot of a kind's plan (:func:`px4_slot_plan`): the fit written there, a device id
#: (int) whose slot is not written (the board keeps its own), or None (written cleared, ID 0).
Px4Slot = FirmwareFit | int | None


def px4_slot_plan(fits: list[FirmwareFit], board: list[int] | None = None,
                  keep: set[int] | frozenset[int] = frozenset()) -> list[Px4Slot]:
    """Which of PX4's :data:`PX4_SLOTS` slots of one kind each fit takes.

    PX4 applies the first slot whose ``TC_*_ID`` equals a sensor's device id
    (``TemperatureCompensation::set_sensor_id``).  With nothing to ``keep`` (the kind's
    sensors all in ``fits``) the slots are rewritten whole: the fits in order, the rest
    cleared.  Where sensors of the kind are ``keep`` (device ids left out of the file) and
    ``board`` gives the slots' device ids as the board has them (the log's active
    ``TC_<k><s>_ID``), a slot holding a kept id is not written (the board keeps its own), each
    fit takes the slot the board already has for its id, else a free one, and the others are
    cleared — so no two slots can name one device after loading.  Without ``board`` the slots
    are rewritten whole (where a kept sensor's slot is is unknown: writing part of them could
    leave a fitted sensor's old slot before its new one)."""
    if len(fits) > PX4_SLOTS:
        raise ExportError(f"PX4 has {PX4_SLOTS} calibration slots of a kind; {len(fits)} "
                          "instances were fitted")
    if not keep or board is None:
        return [*fits, *[None] * (PX4_SLOTS - len(fits))]
    ids = [int(d) for d in list(board)[:PX4_SLOTS]] + [0] * max(0, PX4_SLOTS - len(board))
    plan: list[Px4Slot] = [d if d and d in keep else None for d in ids]
    rest = []
    for fit in fits:
        s = next((s for s, d in enumerate(ids) if d == fit.device_id and plan[s] is None), None)
        if s is None:
            rest.append(fit)
        else:
            plan[s] = fit
    for fit in rest:
        s = next((s for s in range(PX4_SLOTS) if plan[s] is None), None)
        if s is None:
            raise ExportError(f"PX4 has {PX4_SLOTS} calibration slots of a kind: no free one "
                              f"for device {fit.device_id} beside the slots the board keeps")
        plan[s] = fit
    return plan


def _px4_slot_rows(kind: str, pre: str, fit: FirmwareFit | None) -> list[tuple[str, str, int]]:
    """One slot's rows (``pre`` = ``TC_<k><s>_``): the fit's, or cleared (ID 0, zeros)."""
    rows = [(pre + "ID", str(int(fit.device_id)) if fit else "0", 6),
            (pre + "TMAX", _g(fit.t_max if fit else 0.0), 9),
            (pre + "TMIN", _g(fit.t_min if fit else 0.0), 9),
            (pre + "TREF", _g(fit.t_ref if fit else 0.0), 9)]
    if kind == "baro":
        rows += [(f"{pre}X{k}", _g(fit.coef[0, k] if fit is not None else 0.0), 9)
                 for k in range(6)]
        return rows
    for k in range(4):
        for i in range(3):
            v = fit.coef[i, k] / PX4_PARAM_UNIT[kind] if fit is not None else 0.0
            rows.append((f"{pre}X{k}_{i}", _g(v), 9))
    return rows


def px4_calibration_text(fits: Mapping[str, list[FirmwareFit]], *, header: list[str],
                         fitted_kinds_only: bool = False,
                         plans: Mapping[str, list[Px4Slot]] | None = None,
                         vehicle_id: tuple[int, str] | None = None) -> str:
    """A QGC ``.params`` file of ``TC_G*``, ``TC_A*``, ``TC_B*`` (and ``TC_M*`` when ``fits``
    has a ``mag`` entry) slots.  ``fitted_kinds_only``: a kind with no fit is not written at
    all — neither ``TC_<k>_ENABLE`` nor a slot: the board keeps its own (``calibrate`` and
    ``learn``: a kind absent from the log, or all of whose sensors were left out, would
    otherwise be disabled and cleared, wiping the board's calibration of it); without it
    (``export``'s tests, older callers) such a kind is written disabled, every slot cleared.

    ``fits[kind]`` lists the fitted instances in slot order, the remaining slots (up to 4)
    written with ID 0 and zero coefficients, so that a calibration left over from an earlier
    board can never be applied — unless ``plans[kind]`` (:func:`px4_slot_plan`) places them
    and names the slots not to write.  ``TC_<k>_ENABLE`` is 1 where at least one instance of
    the kind was fitted.  Magnetometer coefficients (µT) are written in gauss, as the
    firmware applies them to ``sensor_mag``.  ``vehicle_id``: (id, comment) of
    :func:`px4_vehicle_id` (default: 1, said so in the file).
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
        plan = (plans or {}).get(kind) or px4_slot_plan(kind_fits)
        rows.append((f"TC_{t}_ENABLE", "1" if kind_fits else "0", 6))
        for slot, what in enumerate(plan):
            if not isinstance(what, int):          # a device id: its slot is not written
                rows += _px4_slot_rows(kind, f"TC_{t}{slot}_", what)
    for _, value, ptype in rows:
        if ptype == 9 and not math.isfinite(float(value)):
            raise ExportError("a PX4 coefficient is not finite; nothing written")
    vid, why = vehicle_id or px4_vehicle_id(None)
    lines = [f"# {h}" for h in header] + [f"# {why}", "#",
                                          "# Vehicle-Id Component-Id Name Value Type"]
    lines += [f"{vid}\t1\t{name}\t{value}\t{ptype}" for name, value, ptype in rows]
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


#: The navigation filter's bias settings a band suggests, per autopilot and sensor kind:
#: (bias process noise: the bias's rate of change, SI/s; initial bias uncertainty, SI).
#: PX4 v1.14 EKF2 (``EKF2_GYR_B_NOISE`` rad/s², ``EKF2_ACC_B_NOISE`` m/s³: process noise for
#: the IMU bias prediction, ``bias_sig = dt * value`` per step; ``EKF2_GBIAS_INIT`` rad/s,
#: ``EKF2_ABIAS_INIT`` m/s²: initial bias uncertainty); ArduPilot 4.5 EKF3
#: (``EK3_GBIAS_P_NSE`` rad/s/s, ``EK3_ABIAS_P_NSE`` m/s³: rate gyro / accelerometer bias
#: stability; no initial-uncertainty parameter).
EKF_PARAMS: dict[str, dict[str, tuple[str, str | None]]] = {
    "px4": {"gyro": ("EKF2_GYR_B_NOISE", "EKF2_GBIAS_INIT"),
            "acc": ("EKF2_ACC_B_NOISE", "EKF2_ABIAS_INIT")},
    "ardupilot": {"gyro": ("EK3_GBIAS_P_NSE", None), "acc": ("EK3_ABIAS_P_NSE", None)}}
EKF_FIRMWARE = {"px4": "PX4 v1.14 EKF2", "ardupilot": "ArduPilot 4.5 EKF3"}
#: The autopilots' defaults of :data:`EKF_PARAMS`, in the same SI units, from their parameter
#: definitions: PX4-Autopilot ``src/modules/ekf2/params_gyro_bias.yaml`` (``EKF2_GBIAS_INIT``
#: 0.1 rad/s, ``EKF2_GYR_B_NOISE`` 0.001 rad/s²) and ``params_accel_bias.yaml``
#: (``EKF2_ABIAS_INIT`` 0.2 m/s², ``EKF2_ACC_B_NOISE`` 0.003 m/s³), commit 15c4f088 (both
#: real PX4 logs of ``tests/data/real``, 2019 hardware and 2024 SITL, record the gyro's two
#: at these values); ArduPilot
#: ``libraries/AP_NavEKF3/AP_NavEKF3.cpp`` (``GBIAS_P_NSE_DEFAULT`` 1.0E-03 rad/s²,
#: ``ABIAS_P_NSE_DEFAULT`` 2.0E-02 m/s³, the same for every vehicle type), commit 003d2135.
#: A recommendation is a lower bound: where the default already meets it, it says so.
EKF_DEFAULTS: dict[str, float] = {
    "EKF2_GBIAS_INIT": 0.1, "EKF2_GYR_B_NOISE": 1.0e-3,
    "EKF2_ABIAS_INIT": 0.2, "EKF2_ACC_B_NOISE": 3.0e-3,
    "EK3_GBIAS_P_NSE": 1.0e-3, "EK3_ABIAS_P_NSE": 2.0e-2}


def ekf_bound_line(name: str, bound: float, unit: str, autopilot: str) -> str:
    """``#   NAME >= bound (unit)`` (a line of ``thermonet.exporting.autopilot``'s
    ``ekf_recommendation``) with the autopilot's default beside it and whether it already
    satisfies the bound (:data:`EKF_DEFAULTS`)."""
    default = EKF_DEFAULTS[name]
    who = "PX4" if autopilot == "px4" else "ArduPilot"
    verdict = ("no bound to check it against" if not math.isfinite(bound) else
               "no change needed" if bound <= default else f"raise it to at least {_g(bound)}")
    return f"#   {name} >= {_g(bound)} ({unit}); {who}'s default {default:g}: {verdict}"
