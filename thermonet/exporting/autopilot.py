"""PX4 and ArduPilot thermal-calibration parameter files for the cubic-on-temperature model.

Both autopilots compensate IMU offsets with a polynomial of degree 3 in the
sensor temperature; thermonet's ``poly`` family of degree ≤ 3 on one input
(``dT`` or ``T``) is exactly that model, so it can be written in their own
parameter format.  Every other family is refused.  Reading the files back:
:mod:`thermonet.exporting.autopilot_read`.

PX4 (``src/modules/temperature_compensation/TemperatureCompensation.cpp``,
``TemperatureCompensation::calc_thermal_offsets_3D``, PX4-Autopilot commit
09f282b2; parameter names from ``initialize_parameter_handles`` in the same
file; the offset is *subtracted* in ``src/lib/sensor_calibration/Gyroscope.hpp``
/ ``Accelerometer.hpp``, ``Correct()``: ``data - _thermal_offset - _offset``)::

    dT = clamp(T, TC_G0_TMIN, TC_G0_TMAX) - TC_G0_TREF
    offset[i] = X0_i + X1_i dT + X2_i dT^2 + X3_i dT^3       (rad/s; accel m/s^2)
    corrected = raw - offset

ArduPilot (``libraries/AP_InertialSensor/AP_InertialSensor_tempcal.cpp``,
``TCal::polynomial_eval`` and ``TCal::correct_sensor``, ardupilot commit
025810d3; ``SCALE_FACTOR 1.0e6``, ``TEMP_REFERENCE 35.0`` at the top of that
file)::

    P(x) = (c1 x + c2 x^2 + c3 x^3) * 1e-6,  x = T - 35 degC     (no constant term)
    T, T_cal clamped to [INS_TCALn_TMIN, INS_TCALn_TMAX]
    corrected = raw - P(T - 35) + P(T_cal - 35)                   (rad/s; m/s^2)

``T_cal`` is the temperature at which the ordinary offset calibration
(``INS_GYROFFS``/``INS_ACCOFFS``) was made, so that calibration absorbs the
constant term: thermonet's drift :math:`d(T)` is written as
:math:`c_k = 10^6 a_k` where :math:`d(T) = a_0 + a_1 x + a_2 x^2 + a_3 x^3`,
and ``raw - P(T-35) + P(T_cal-35) = raw - d(T) + d(T_cal)``.

Targets (:mod:`thermonet.features.target`).  The file says what the model says: a
``zero``-target gyro keeps its absolute bias in ``X0`` (PX4's gyro calibration
fits the static rate and keeps ``X0``: ``temperature_calibration/gyro.cpp``,
``finish_sensor_instance``); an ``at-t-ref`` accelerometer is normalised to
zero at ``TREF`` = the model's :math:`T_{ref}` — exactly what PX4's own
accelerometer calibration writes (``temperature_calibration/accel.cpp``,
``finish_sensor_instance``: ``res[i][3] = 0.0; // normalise the correction to
be zero at the reference temperature``, PX4-Autopilot commit 25ed6b67), so a
level vehicle still reads 1 g; an axis the model leaves uncompensated is all
zeros.  ArduPilot subtracts the polynomial's value at the calibration
temperature anyway (above), i.e. it applies every axis "at T_cal".

Conversion.  thermonet's polynomial lives in standardised units
(:math:`z = (x - \\bar x)/s_x`, :math:`d = s_y\\,p(z) + \\bar y`); it is expanded
in float64 into a plain polynomial of :math:`T - T_{ref}` (PX4: ``TREF`` = the
model's :math:`T_{ref}` for input ``dT``, the centre of the trained range for
input ``T``; ArduPilot: 35 °C), then scaled to SI units (rad/s, m/s²) from the
axis units given (``deg/s``, ``deg/h``, ``rad/s``, ``g``, ``mg``, ``m/s^2``).
``TMIN``/``TMAX`` are the trained temperature range — the same clamp the
thermonet model applies.

File formats.  PX4: QGroundControl parameter file, tab-separated
``Vehicle-Id Component-Id Name Value Type`` (type 6 = INT32, 9 = REAL32), as PX4's
``Tools/process_sensor_caldata.py`` writes it.  ArduPilot: Mission Planner
``NAME,VALUE`` lines (``sep=" "`` gives MAVProxy's ``NAME VALUE``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.polynomial import polynomial as P

from ..core.errors import ExportError
from ..core.fileio import atomic_write_text
from ..core.recording import output_kind
from ..data.firmware import EKF_DEFAULTS, EKF_FIRMWARE, EKF_PARAMS, ekf_bound_line, px4_vehicle_id
from ..features.target import FOURPOS_SUFFIXES
from ..models import DriftModel
from ..models.composite import AxisModels, DriftModels
from ..scoring.band import Band
from . import MAX_DEVICE_ID, is_device_id
from .onnx_export import family_name

__all__ = [
    "SI_FACTOR",
    "ARDUPILOT_TEMP_REFERENCE",
    "ARDUPILOT_SCALE",
    "AutopilotCoefficients",
    "autopilot_coefficients",
    "check_offset_outputs",
    "export_px4_params",
    "export_ardupilot_params",
    "ekf_recommendation",
    "EKF_DEFAULTS",
    "EKF_PARAMS",
]

#: Multiply a value in this unit by the factor to get rad/s (gyro), m/s² (accel), Pa (baro) or
#: gauss (magnetometer: PX4's ``TC_M*`` act on ``sensor_mag`` in gauss).
SI_FACTOR = {
    "rad/s": 1.0, "deg/s": math.pi / 180.0, "deg/h": math.pi / 180.0 / 3600.0,
    "m/s^2": 1.0, "g": 9.80665, "mg": 9.80665e-3, "Pa": 1.0, "hPa": 100.0,
    "gauss": 1.0, "mgauss": 1e-3, "uT": 0.01, "nT": 1e-5,
}
_SI_UNIT = {"gyro": "rad/s", "acc": "m/s^2", "baro": "Pa", "mag": "gauss"}
_UNIT_KIND = {"rad/s": "gyro", "deg/s": "gyro", "deg/h": "gyro",
              "m/s^2": "acc", "g": "acc", "mg": "acc", "Pa": "baro", "hPa": "baro",
              "gauss": "mag", "mgauss": "mag", "uT": "mag", "nT": "mag"}
#: PX4 evaluates a cubic for gyro/accel/mag (``calc_thermal_offsets_3D``), order 5 for baro
#: (``_1D``).
_PX4_ORDER = {"gyro": 3, "acc": 3, "baro": 5, "mag": 3}
#: ArduPilot's fixed reference temperature (°C) and coefficient scale.
ARDUPILOT_TEMP_REFERENCE = 35.0
ARDUPILOT_SCALE = 1.0e6
_AXES = ("x", "y", "z")
_PX4_TYPE = {"gyro": "G", "acc": "A", "baro": "B", "mag": "M"}
_AP_TYPE = {"gyro": "GYR", "acc": "ACC"}


@dataclass
class AutopilotCoefficients:
    """Drift as a cubic in :math:`T - T_{ref}`, per sensor kind, in SI units.

    Attributes
    ----------
    t_ref : float
        Reference temperature, °C.
    t_min, t_max : float
        Valid (trained) temperature range, °C; outside it the autopilot clamps.
    coef : dict
        ``{"gyro" | "acc": array (3 axes, 4)}`` — column k multiplies
        :math:`(T - T_{ref})^k`; rad/s for gyro, m/s² for accel.  Axes the
        model does not have are zero.
    present : dict
        ``{kind: [axis letters the model provides]}``.
    """

    t_ref: float
    t_min: float
    t_max: float
    coef: dict[str, np.ndarray] = field(default_factory=dict)
    present: dict[str, list[str]] = field(default_factory=dict)


def check_offset_outputs(outputs: list[str], fmt: str = "PX4/ArduPilot parameters",
                         source: str | None = None) -> None:
    """Refuse a four-position model (``<axis>.bias`` and ``<axis>.scale``) in one line."""
    both = [o for o in outputs if o.endswith(FOURPOS_SUFFIXES)]
    if both:
        raise ExportError(f"{source + ': ' if source else ''}a four-position model (bias and "
                          f"scale factor per axis: {', '.join(both)}) cannot be written as {fmt}: "
                          "PX4/ArduPilot files hold a per-axis offset polynomial in temperature; "
                          "export it as ONNX or C (--format onnx or --format c)")


def _unit_of(axis: str, units: str | Mapping[str, str]) -> str:
    unit = units if isinstance(units, str) else units.get(axis)
    if unit is None:
        raise ExportError(f"no unit given for output '{axis}' (units: {units})")
    if unit not in SI_FACTOR:
        raise ExportError(f"output '{axis}': unit '{unit}' cannot be converted for an autopilot "
                          f"(known: {', '.join(SI_FACTOR)})")
    return unit


def _not_temperature(inputs: list[str]) -> str | None:
    """Why a model's inputs are not what the autopilots read (their temperature sensor, as
    ``dT`` or ``T``): ``"reads [...] — why"``, naming a proxy input as one; None where the
    inputs are ``dT`` or ``T`` alone."""
    if inputs in (["dT"], ["T"]):
        return None
    proxies = [i for i in inputs if i.startswith("d_") and len(i) > 2]
    said = "; ".join(f"'{i}' is the proxy '{i[2:].removesuffix('2') if i.endswith('2') else i[2:]}'"
                     ", not the temperature" for i in proxies)
    return (f"reads {inputs}" + (f" — {said}, and" if said else " —")
            + " PX4/ArduPilot read only the sensor's temperature: export it as ONNX or C, "
            "or fit a family on dT")


def _firmware_form(part: DriftModel) -> bool:
    """Whether a part is what the parameter files hold: a polynomial of degree <= 3 on dT or T."""
    form = None if part.family.recurrent else part.family.polynomial_form()
    return form is not None and form.shape[1] <= 4 and list(part.inputs) in (["dT"], ["T"])


def _axis_models_coefficients(model: AxisModels, *, output_units: str | Mapping[str, str],
                              t_ref: float | None) -> AutopilotCoefficients:
    """A per-axis model as parameter files: only when every part that owns an axis is a
    polynomial of degree <= 3 on dT or T (each axis then takes its owner's cubic; an axis
    left raw is zero), else refused in one line."""
    for a, k in enumerate(model.owner):
        if k is not None and not _firmware_form(model.parts[k]):
            part = model.parts[k]
            why = None if part.family.recurrent else _not_temperature(list(part.inputs))
            if why is not None:   # the input is the reason, not the family
                raise ExportError(
                    f"PX4/ArduPilot parameter files need one input, dT or T, on every axis; "
                    f"this per-axis model computes '{model.outputs[a]}' with "
                    f"'{model.labels[k]}', which {why} (or the cubic/baseline family with "
                    "--family NAME)")
            raise ExportError(
                f"PX4/ArduPilot parameter files need the firmware-form cubic (a polynomial of "
                f"degree <= 3 in dT or T) on every axis; this per-axis model computes "
                f"'{model.outputs[a]}' with '{model.labels[k]}' ({part.family_name} on "
                f"{list(part.inputs)}) — export the cubic/baseline family with --family NAME")
    if t_ref is None:
        t_ref = model.spec.t_ref
    done = [autopilot_coefficients(p, output_units=output_units, t_ref=t_ref)
            for p in model.parts]
    first = done[0]
    for k, co in enumerate(done[1:], start=1):
        if (co.t_ref, co.t_min, co.t_max) != (first.t_ref, first.t_min, first.t_max):
            raise ExportError(
                f"PX4/ArduPilot parameter files hold one temperature range; this per-axis "
                f"model's parts '{model.labels[0]}' and '{model.labels[k]}' were trained on "
                f"[{first.t_min:g}, {first.t_max:g}] and [{co.t_min:g}, {co.t_max:g}] degC — "
                "export one family with --family NAME")
    out = AutopilotCoefficients(t_ref=first.t_ref, t_min=first.t_min, t_max=first.t_max,
                                coef={kind: c.copy() for kind, c in first.coef.items()},
                                present={kind: list(v) for kind, v in first.present.items()})
    for a, k in enumerate(model.owner):   # a masked axis is zero in every part's file
        if k is None:
            continue
        axis = model.outputs[a]
        kind, letter = output_kind(axis), axis.split("_", 1)[1]
        row = 0 if kind == "baro" else _AXES.index(letter)
        out.coef[kind][row] = done[k].coef[kind][row]
    return out


def _polynomial_form(model: Any) -> np.ndarray:
    """The model's polynomial in its one normalised input (rows: axes, ascending), refused
    (:class:`ExportError`) where the autopilots cannot evaluate it: a recurrent family,
    another input than ``dT`` or ``T``, no polynomial form, a degree above 3 (5 for a
    barometer-only model)."""
    family = family_name(model)
    if model.family.recurrent:  # before the input check: its reason is the state, not dT
        raise ExportError(f"PX4/ArduPilot parameter files hold a polynomial in temperature; this "
                          f"model is '{family}', which carries a state in time — export it as "
                          "ONNX or C (state, _init, _step)")
    why = _not_temperature(list(model.inputs))
    if why is not None:   # the input, not the family, is what the autopilots cannot read
        raise ExportError(f"PX4/ArduPilot parameter files need one input, dT or T; this "
                          f"model {why}")
    form = model.family.polynomial_form()  # the family says whether it is a polynomial
    if form is None:
        raise ExportError(f"PX4/ArduPilot parameter files need a polynomial in dT or T; this "
                          f"model is '{family}', which has no polynomial form "
                          "— export it as ONNX or C")
    degree = form.shape[1] - 1
    baro_only = {output_kind(a) for a in model.outputs} == {"baro"}
    if degree > (5 if baro_only else 3):
        what = "an order-5 polynomial (baro)" if baro_only else "a cubic"
        raise ExportError(f"PX4/ArduPilot evaluate {what}; this {family} model has degree "
                          f"{degree}")
    return form


def autopilot_coefficients(model: DriftModels, *, output_units: str | Mapping[str, str],
                           t_ref: float | None = None) -> AutopilotCoefficients:
    """Expand a polynomial model (degree ≤ 3, one input ``dT`` or ``T``) into SI cubic coefficients.

    The family supplies its coefficients through
    :meth:`~thermonet.models.base.Family.polynomial_form` (``poly``, and ``linear``
    as a degree-1 polynomial); a family without one is refused.

    Parameters
    ----------
    model : DriftModel
    output_units : str or dict axis -> unit
        Units of the model's outputs (``deg/s``, ``deg/h``, ``rad/s``, ``g``,
        ``mg``, ``m/s^2``).
    t_ref : float, optional
        Reference temperature of the expansion (°C); default the model's
        :math:`T_{ref}` (where ``at-t-ref`` axes are zero), or the centre of the
        trained range for a model on ``T`` with no :math:`T_{ref}`.

    Raises
    ------
    ExportError
        A family without a polynomial form, a degree above 3, another input; a four-position
        model; an axis that is not gyro/acc x/y/z; a unit that does not match the axis kind.
    """
    check_offset_outputs(list(model.outputs))
    if isinstance(model, AxisModels):
        return _axis_models_coefficients(model, output_units=output_units, t_ref=t_ref)
    form = _polynomial_form(model)
    lo = float(model.sig_lo[0])
    hi = float(model.sig_hi[0])
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        raise ExportError(
            f"trained temperature range [{lo}, {hi}] is not usable (model not fitted?)"
        )
    t_model = float(model.spec.t_ref or 0.0) if model.inputs == ["dT"] else 0.0
    if t_ref is None:  # the model's T_ref: where at-t-ref axes are zero, as PX4's accel X0
        spec_t_ref = model.spec.t_ref
        t_ref = float(spec_t_ref) if spec_t_ref is not None else round((lo + hi) / 2.0, 1)
    # x = T - t_model = u + (t_ref - t_model); z = (x - x_mean)/x_std = alpha*u + beta
    x_mean, x_std = float(model.x_mean[0]), float(model.x_std[0])
    alpha = 1.0 / x_std
    beta = (t_ref - t_model - x_mean) / x_std
    y_mean = model.y_mean.detach().double().numpy()
    y_std = model.y_std.detach().double().numpy()
    # the target (thermonet.models.base): at-t-ref axes minus their value at rest, the
    # float64 constant on channel/zero axes, and zero on an uncompensated axis
    y_ref = model.y_ref.detach().double().numpy()
    at_t_ref = model._at_t_ref(model.y_ref.dtype).detach().double().numpy()
    mask = model.compensate.detach().double().numpy()
    const = model.constant().detach().double().numpy()
    out = AutopilotCoefficients(t_ref=float(t_ref), t_min=lo, t_max=hi)
    for a, axis in enumerate(model.outputs):
        kind = output_kind(axis)
        letter = axis.split("_", 1)[1]
        if kind not in _SI_UNIT or (letter not in _AXES and kind != "baro"):
            raise ExportError(f"output '{axis}' is not a gyro, accelerometer or magnetometer "
                              "x/y/z axis or a barometer; autopilots compensate only those")
        unit = _unit_of(axis, output_units)
        if _UNIT_KIND[unit] != kind:
            raise ExportError(f"output '{axis}' has unit '{unit}', which is not a {kind} unit")
        pz = form[a]                                    # coefficients in z, ascending
        pu = np.zeros(1)
        for k, c in enumerate(pz):                      # p(alpha*u + beta), ascending in u
            pu = P.polyadd(pu, c * P.polypow([beta, alpha], k))
        pu = pu * y_std[a]
        pu[0] += y_mean[a] - at_t_ref[a] * y_ref[a]
        pu = pu * mask[a]
        pu[0] += const[a]
        n = _PX4_ORDER[kind] + 1
        if kind == "baro":      # one pressure output: row 0, order 5 (TC_B*_X0..X5)
            if kind in out.coef:
                raise ExportError(f"one barometer output per model, got {model.outputs}")
            coef = out.coef.setdefault(kind, np.zeros((1, n)))
            coef[0, :pu.size] = pu[:n] * SI_FACTOR[unit]
        else:
            coef = out.coef.setdefault(kind, np.zeros((3, n)))
            coef[_AXES.index(letter), :pu.size] = pu[:n] * SI_FACTOR[unit]
        out.present.setdefault(kind, []).append(letter)
    return out


def _g(v: float) -> str:
    return f"{float(v):.9g}"


def ekf_recommendation(band: Mapping[str, Any] | None, output_units: str | Mapping[str, str],
                       autopilot: str) -> list[str]:
    """Comment lines recommending the EKF's bias noise settings from the residual-drift
    band (:mod:`thermonet.scoring.band`), per sensor kind the largest over its axes:
    process noise = the band's rate (unit per °C) × the training runs' 95th-percentile
    temperature rate (°C/s), in SI units per second; initial uncertainty = the band's bias
    bound.  Never loaded: ``#`` lines the autopilots' loaders skip."""
    if not band:
        return []
    b = Band.from_json(band)
    nums = b.filter_numbers()
    rate = b.signal_rate
    best: dict[str, tuple[float, float]] = {}
    for axis, v in nums.items():
        unit = _unit_of(axis, output_units)
        kind = _UNIT_KIND.get(unit)
        if kind not in ("gyro", "acc"):
            continue
        si = SI_FACTOR[unit]
        noise = v["rate"] * si * rate if rate is not None else math.nan
        old = best.get(kind, (0.0, 0.0))
        best[kind] = (max(old[0], noise), max(old[1], v["bound"] * si))
    if not best:
        return []
    lines = ["#", f"# Recommendation only (not loaded; {EKF_FIRMWARE[autopilot]} parameter "
                  "names): the residual drift left after this",
             f"# compensation, {b.level:.0%} band of {b.window_s:g} s window means out of fold "
             "(drift like the training runs', not shocks or aging).",
             f"# Bias rate = band slope x temperature rate "
             f"{'n/a' if rate is None else f'{rate * 60:.3g} degC/min'} (95th percentile in "
             "training).",
             "# Each is a lower bound, not a value to set: a setting below it makes the EKF "
             "too confident in its bias."]
    for kind, (noise, bound) in best.items():
        pn, init = EKF_PARAMS[autopilot][kind]
        si_unit = "rad/s" if kind == "gyro" else "m/s^2"
        lines.append(ekf_bound_line(pn, noise, f"{si_unit}/s", autopilot))
        if init:
            lines.append(ekf_bound_line(init, bound, si_unit, autopilot))
        else:
            lines.append(f"#   residual {kind} bias bound {_g(bound)} {si_unit}")
    return lines


def export_px4_params(model: DriftModels, path: str | Path, *, output_units: str | Mapping[str, str],
                      device_id: int | None = None, instance: int = 0,
                      band: Mapping[str, Any] | None = None,
                      mav_sys_id: float | None = None) -> Path:
    """Write PX4 ``TC_G<i>_*`` / ``TC_A<i>_*`` / ``TC_B<i>_*`` / ``TC_M<i>_*`` (magnetometer,
    gauss; PX4 v1.15+) parameters as a QGC ``.params`` file.

    Parameters
    ----------
    model : DriftModel
        ``poly`` of degree ≤ 3 on ``dT`` or ``T`` (gyro and/or accel axes).
    path : str or Path
    output_units : str or dict
        Units of the model's outputs (converted to rad/s, m/s²).
    device_id : int
        The sensor's PX4 device id (``TC_G0_ID``), which PX4 matches at boot:
        a slot whose ID matches no sensor is never applied, silently, so it is
        required (read it with ``listener sensor_gyro`` / ``sensor_accel``).
    instance : int
        Calibration slot 0..3.
    mav_sys_id : float, optional
        The vehicle's ``MAV_SYS_ID`` as its log recorded it (an instance directory of
        ``calibrate`` / ``learn`` keeps it): the file's Vehicle-Id, which QGroundControl
        requires to be the vehicle's; else 1, said in the file
        (:func:`thermonet.data.firmware.px4_vehicle_id`).

    Returns
    -------
    Path
    """
    if not 0 <= int(instance) <= 3:
        raise ExportError(f"PX4 calibration instance must be 0..3, got {instance}")
    co = autopilot_coefficients(model, output_units=output_units)
    if device_id is None:
        raise ExportError("PX4 applies TC_* parameters only to the sensor whose device id "
                          "equals TC_*_ID: give the sensor's device id (--device-id; read it "
                          "with 'listener sensor_gyro')")
    if not is_device_id(device_id):
        raise ExportError(f"device id {device_id!r} is not a sensor device id (PX4 device ids "
                          f"are 32-bit: 1..{MAX_DEVICE_ID})")
    int32_id = int(device_id) - (1 << 32 if int(device_id) >= 1 << 31 else 0)  # as PX4's INT32
    vid, why = px4_vehicle_id({"MAV_SYS_ID": mav_sys_id}, "the model's calibration")
    lines = ["# Sensor thermal compensation parameters (thermonet, poly on temperature)",
             f"# family poly, T_ref {co.t_ref:g} degC, range [{co.t_min:g}, {co.t_max:g}] degC",
             f"# {why}", "#", "# Vehicle-Id Component-Id Name Value Type"]
    rows: list[tuple[str, str, int]] = []
    for kind, coef in co.coef.items():
        t = _PX4_TYPE[kind]
        rows.append((f"TC_{t}_ENABLE", "1", 6))
        pre = f"TC_{t}{instance}_"
        rows.append((pre + "ID", str(int32_id), 6))
        rows += [(pre + "TMAX", _g(co.t_max), 9), (pre + "TMIN", _g(co.t_min), 9),
                 (pre + "TREF", _g(co.t_ref), 9)]
        if kind == "baro":          # TC_B<i>_X0..X5, Pa (calc_thermal_offsets_1D)
            rows += [(f"{pre}X{k}", _g(coef[0, k]), 9) for k in range(6)]
            continue
        for k in range(4):
            for i in range(3):
                rows.append((f"{pre}X{k}_{i}", _g(coef[i, k]), 9))
    lines += [f"{vid}\t1\t{name}\t{value}\t{ptype}" for name, value, ptype in rows]
    lines += ekf_recommendation(band, output_units, "px4")
    return atomic_write_text(Path(path), "\n".join(lines) + "\n")


def export_ardupilot_params(model: DriftModels, path: str | Path, *,
                            output_units: str | Mapping[str, str], imu: int = 1,
                            sep: str = ",", band: Mapping[str, Any] | None = None) -> Path:
    """Write ArduPilot ``INS_TCAL<n>_*`` parameters (``NAME,VALUE`` lines).

    The constant term of the drift is not written (ArduPilot's polynomial has
    none; the ordinary offset calibration at ``T_cal`` absorbs it, see the
    module docstring).  ``INS_TCALn_TMIN``/``TMAX`` must lie in ArduPilot's
    documented −70…80 °C.
    """
    if not 1 <= int(imu) <= 3:
        raise ExportError(f"ArduPilot IMU number must be 1..3, got {imu}")
    if sep not in (",", " ", "\t"):
        raise ExportError(f"separator must be ',', ' ' or a tab, got {sep!r}")
    co = autopilot_coefficients(model, output_units=output_units,
                                t_ref=ARDUPILOT_TEMP_REFERENCE)
    if "baro" in co.coef:
        raise ExportError("ArduPilot has no barometer temperature-calibration parameters "
                          "(INS_TCAL covers gyros and accelerometers); export PX4 params, "
                          "ONNX or C")
    if "mag" in co.coef:
        raise ExportError("ArduPilot has no magnetometer temperature-calibration parameters "
                          "(INS_TCAL covers gyros and accelerometers); export PX4 params "
                          "(TC_M*), ONNX or C")
    if co.t_min < -70.0 or co.t_max > 80.0:
        raise ExportError(f"trained range [{co.t_min:g}, {co.t_max:g}] degC is outside "
                          "ArduPilot's INS_TCAL TMIN/TMAX range -70..80 degC")
    pre = f"INS_TCAL{imu}_"
    rows = [(pre + "ENABLE", "1"), (pre + "TMIN", _g(co.t_min)), (pre + "TMAX", _g(co.t_max))]
    # only the sensor kinds the model covers: writing zeros for the other would wipe an
    # existing calibration of that sensor when the file is loaded
    for kind in (k for k in ("acc", "gyro") if k in co.coef):
        coef = co.coef[kind]
        for k in (1, 2, 3):
            for i, ax in enumerate(_AXES):
                rows.append((f"{pre}{_AP_TYPE[kind]}{k}_{ax.upper()}",
                             _g(coef[i, k] * ARDUPILOT_SCALE)))
    header = ["# ArduPilot IMU temperature calibration (thermonet, poly on temperature)",
              "# axes the model does not cover are written as 0 (no correction on that axis)",
              f"# drift constant at {ARDUPILOT_TEMP_REFERENCE:g} degC is left to the offset "
              "calibration at INS_*_CALTEMP"]
    return atomic_write_text(
        Path(path), "\n".join(header + [f"{n}{sep}{v}" for n, v in rows]
                              + ekf_recommendation(band, output_units, "ardupilot")) + "\n"
    )
