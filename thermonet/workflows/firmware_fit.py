"""The autopilots' own polynomial fitted on a log, as their scripts fit it (``thermonet calibrate``).

Followed, file and commit:

* PX4 ``Tools/process_sensor_caldata.py`` (PX4/PX4-Autopilot @ 00f5c319563d): per axis
  a cubic in T − TREF, TREF the centre of [TMIN, TMAX] (the logged range); baro an
  order-5 polynomial; gyro fitted on the output (its constant ``X0`` kept), accel
  and baro on output − median.  The script averages the samples into 2,000 equal
  temperature bins over [TMIN, TMAX] (``resampleWithDeltaX``: the mean temperature
  and the mean output of each occupied bin) and fits the bin means, unweighted:
  every temperature counts once, however long the board stayed there.  Before
  binning it runs a 31-sample median filter over each output (``median_filter``:
  ``scipy.signal.medfilt(data, 31)``).  thermonet does the same (:func:`bin_means`,
  :func:`running_median`), with one difference: the script's ``medfilt`` pads the
  ends with zeros, which pulls the first and last 15 samples toward zero (by
  about two noise sigmas on a gyro, and on an accelerometer toward the extreme of
  its window); thermonet pads with the nearest value (as ``scipy.ndimage.median_filter``
  with ``mode="nearest"``).  A thermometer that reports whole degrees gives one bin per
  reported value — the script "bins to the resolution" — so the same fit serves it.
  Not followed: its ×100 on the baro
  (it assumes hPa; current PX4 logs ``sensor_baro.pressure`` in Pa, so the script
  writes baro coefficients 100× too large — PX4 issue #20051; thermonet reads the
  unit from the value, :mod:`thermonet.data.logs.ulog`).
* ArduPilot ``Tools/scripts/tempcal_IMU.py`` (ArduPilot/ardupilot @ d420971136c6):
  a 2-second moving average on every column (``IMUData.FilterArray``: window
  ``int(n / seconds) · 2`` samples, none below 2), then ``np.polyfit`` of order 3
  on T − 35 °C over every sample, accel as output − mean; the constant is dropped
  (the firmware has none), c1..c3 written × 1e6.  thermonet does exactly that, so
  its coefficients equal the script's to the script's printed precision — except
  for a thermometer coarser than :data:`COARSE_STEP_C`, fitted on the means per
  reported temperature as PX4's bins do (a moving average over a staircase still
  is a staircase).

Coarse thermometers.  The firmware applies the correction with the same coarse
reading, so inside one step the correction cannot follow the drift: the error
is up to max |P'(T)| · step / 2.  :func:`resolution_effect` computes it and the
verdict, the report and the parameter file's header say it.  Only what cannot be
fitted is refused (:func:`check_instance`): too few distinct temperatures for the
polynomial (fewer than ``order + 3``), too little span, no thermometer.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.errors import ThermonetError
from ..data.firmware import ARDUPILOT_TEMP_REFERENCE, FirmwareFit
from ..data.logs import SensorInstance, temperature_step
from .verify_params import KIND_UNITS

__all__ = ["check_instance", "fit_firmware", "target", "bin_means", "moving_average",
           "running_median", "PX4_MEDIAN_SAMPLES",
           "resolution_effect", "poly_order", "MIN_SPAN_C", "MIN_SAMPLES", "COARSE_STEP_C",
           "PX4_BINS", "FIT_KINDS", "MAX_MOVE_DEG", "MOVE_WINDOW_S", "motion"]

#: Least temperature span (°C) an instance needs to be calibrated (PX4's ``SYS_CAL_TDEL``
#: defaults to 24 °C; 10 °C is the least a cubic can be trusted on).
MIN_SPAN_C = 10.0
#: Least samples per instance.
MIN_SAMPLES = 200
#: A thermometer stepping this coarsely (°C) or more is "coarse": fitted on the means per
#: reported value, and its resolution's effect is stated.
COARSE_STEP_C = 0.25
#: PX4's ``resampleWithDeltaX`` bins (``nbInterval``).
PX4_BINS = 2000
#: PX4's median-filter length, samples (``medfilt(data, 31)``).
PX4_MEDIAN_SAMPLES = 31
#: ArduPilot's moving-average width, s (``data.Filter(2)``).
ARDUPILOT_FILTER_S = 2
FIT_KINDS = ("gyro", "acc", "baro", "mag")
#: A magnetometer whose field direction turns more than this (degrees) within
#: :data:`MOVE_WINDOW_S` moved during the soak: thermal drift turns it by a fraction of a
#: degree a minute (10 µT over a 30-minute warm-up on a 50 µT field).
MAX_MOVE_DEG = 5.0
MOVE_WINDOW_S = 60.0


def poly_order(kind: str, autopilot: str) -> int:
    """The firmware polynomial's order: PX4 baro 5, everything else 3."""
    return 5 if (autopilot == "px4" and kind == "baro") else 3


def motion(inst: SensorInstance) -> str | None:
    """Why a magnetometer's log is not a still soak (one phrase), or None: the direction of
    its field (31-sample running median) turns more than :data:`MAX_MOVE_DEG` within
    :data:`MOVE_WINDOW_S` somewhere in the log.  Several logs joined
    (:attr:`~thermonet.data.logs.base.SensorInstance.starts`) are looked at one by one: a
    board set down again between two logs points another way, and that is no motion during
    a soak."""
    several = len(inst.segments()) > 1
    for n, seg in enumerate(inst.segments(), start=1):
        t = np.asarray(inst.time_s[seg], dtype=np.float64)
        why = _turn(t - t[0] if several else t, inst.values[seg])   # t: within that log
        if why:
            return f"log {n}: {why}" if several else why
    return None


def _turn(t: np.ndarray, values: np.ndarray) -> str | None:
    """:func:`motion` within one log."""
    if t.size < 3:
        return None
    v = running_median(values)
    u = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    j = np.minimum(np.searchsorted(t, t + MOVE_WINDOW_S), t.size - 1)
    ang = np.degrees(np.arccos(np.clip(np.sum(u * u[j], axis=1), -1.0, 1.0)))
    k = int(np.argmax(ang))
    if ang[k] <= MAX_MOVE_DEG:
        return None
    return (f"the field direction turns {ang[k]:.0f}° between t = {t[k]:.0f} s and "
            f"{t[j[k]]:.0f} s (more than {MAX_MOVE_DEG:g}° within {MOVE_WINDOW_S:g} s): the "
            "magnetometer moved during the soak — keep the board still while it warms")


def _thermometer(inst: SensorInstance) -> str:
    """Whose thermometer ``inst`` reads, in words (empty for its own)."""
    if not inst.thermometer:
        return ""
    return (f" ({inst.thermometer}'s thermometer, lent"
            + (f", through a {inst.lag_s:g} s lag" if inst.lag_s else "") + ")")


def check_instance(inst: SensorInstance, autopilot: str = "px4") -> str | None:
    """Why ``inst`` cannot be calibrated (one phrase), or None when it can."""
    if inst.kind not in FIT_KINDS:
        return f"{inst.kind}: neither autopilot compensates it for temperature (listed only)"
    if inst.temperature_c is None:
        if inst.kind == "mag":
            return ("no thermometer: the magnetometer has none, and no barometer or IMU "
                    "thermometer in the log can be lent to it")
        return "no temperature: the sensor has no thermometer in the log"
    if inst.untrusted:   # too many of its samples damaged (thermonet.data.logs.base.screen_samples)
        return inst.untrusted
    if inst.n_samples < MIN_SAMPLES:
        return f"too few samples: {inst.n_samples} (need at least {MIN_SAMPLES})"
    if not np.any(inst.values != 0):
        return "every sample is exactly zero (a simulator or a dead sensor)"
    span = float(np.ptp(inst.temperature_c))
    if span < MIN_SPAN_C:
        return (f"temperature{_thermometer(inst)} spans only {span:.2f} °C (need at least "
                f"{MIN_SPAN_C:g} °C: cold-soak the board, then log while it warms)")
    if inst.kind == "mag":
        moved = motion(inst)
        if moved:
            return moved
    levels = int(np.unique(np.round(np.asarray(inst.temperature_c, dtype=np.float64), 6)).size)
    need = poly_order(inst.kind, autopilot) + 3
    if levels < need:
        step = temperature_step(inst.temperature_c)
        return (f"its thermometer gives only {levels} distinct temperatures ({step:g} °C steps "
                f"over {span:.1f} °C): an order-{need - 3} polynomial needs at least {need}")
    return None


def target(inst: SensorInstance, autopilot: str) -> np.ndarray:
    """What the script fits: gyro as logged; accel, baro and magnetometer minus the log's
    median (PX4; a magnetometer always) or mean (ArduPilot) — the constant is gravity, the
    weather or the Earth's field, not drift."""
    v = inst.values.astype(np.float64)
    if inst.kind == "gyro":
        return v
    centre = np.median(v, axis=0) if autopilot == "px4" or inst.kind == "mag" \
        else np.mean(v, axis=0)
    return v - centre


def bin_means(x: np.ndarray, y: np.ndarray, n_bins: int = PX4_BINS
              ) -> tuple[np.ndarray, np.ndarray]:
    """PX4's ``resampleWithDeltaX``, vectorised: ``n_bins`` equal bins over [min x, max x]
    (the maximum in the last), the mean x and mean y (rows) of every occupied bin."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64).reshape(x.size, -1)
    lo, hi = float(x.min()), float(x.max())
    width = (hi - lo) / n_bins
    idx = np.full(x.size, n_bins - 1) if width <= 0 else np.minimum(
        ((x - lo) / width).astype(np.int64), n_bins - 1)
    idx = np.where(x < hi, idx, n_bins - 1)
    count = np.bincount(idx, minlength=n_bins)
    keep = count > 0
    mx = np.bincount(idx, weights=x, minlength=n_bins)[keep] / count[keep]
    my = np.column_stack([np.bincount(idx, weights=y[:, j], minlength=n_bins)[keep]
                          for j in range(y.shape[1])]) / count[keep, None]
    return mx, my


#: Rows of :func:`running_median`'s windows taken at once: its working copy is at most this
#: many rows × 31 samples × 8 bytes per column (16 MB).
_MEDIAN_CHUNK = 65_536


def running_median(y: np.ndarray, size: int = PX4_MEDIAN_SAMPLES) -> np.ndarray:
    """Each column's ``size``-sample running median (``size`` odd), ends padded with the
    nearest value: ``scipy.ndimage.median_filter(column, size, mode="nearest")`` value for
    value (``tests/test_calibrate.py`` checks it against SciPy), computed with numpy's
    sliding windows instead — importing ``scipy.ndimage`` cost a calibration 0.12 s, a
    median of 31 samples per row microseconds."""
    if size < 1 or size % 2 == 0:
        raise ValueError(f"running_median: size {size} (an odd number of samples)")
    y = np.asarray(y, dtype=np.float64)
    y = y.reshape(y.shape[0], -1) if y.ndim != 2 else y
    half = size // 2
    padded = np.pad(y, ((half, half), (0, 0)), mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, size, axis=0)  # (n, cols, size)
    out = np.empty_like(y)
    for a in range(0, y.shape[0], _MEDIAN_CHUNK):   # an odd window's median: its middle value
        out[a:a + _MEDIAN_CHUNK] = np.partition(windows[a:a + _MEDIAN_CHUNK], half,
                                                axis=-1)[..., half]
    return out


def moving_average(time_s: np.ndarray, columns: np.ndarray, width_s: float
                   ) -> np.ndarray:
    """ArduPilot's ``IMUData.FilterArray``: a ``int(n / seconds) · width_s``-sample moving
    average (``np.cumsum`` differences, the first window − 1 samples dropped); unchanged
    when the window is 1 or less.  ``columns`` (n, k)."""
    n = columns.shape[0]
    seconds = float(time_s[-1] - time_s[0])
    window = int(n / seconds) * int(width_s) if seconds > 0 else 0
    if window <= 1:
        return columns
    c = np.cumsum(columns, axis=0)
    c[window:] = c[window:] - c[:-window]
    return c[window - 1:] / window


def fit_firmware(inst: SensorInstance, autopilot: str,
                 median_samples: int = PX4_MEDIAN_SAMPLES) -> FirmwareFit:
    """The autopilot's own polynomial fitted on ``inst`` as its script does (SI units);
    ``median_samples``: PX4's running median (``learn`` on merged windows: as long in time).

    A magnetometer is fitted in PX4's form whatever the autopilot (ArduPilot has none):
    as the accelerometer (less the filtered median, 2,000 bins, a cubic in T − TREF), then
    ``X0 = 0`` as PX4's on-board ``temperature_calibration/mag.cpp`` writes it — the
    correction is the change from the value at TREF, the Earth's field stays."""
    if inst.kind == "mag":
        autopilot = "px4"
    temp = np.asarray(inst.temperature_c, dtype=np.float64)
    order = poly_order(inst.kind, autopilot)
    y = target(inst, autopilot)
    step = temperature_step(temp)
    coarse = step is not None and step >= COARSE_STEP_C
    if autopilot == "px4":
        t_min, t_max = float(temp.min()), float(temp.max())
        t_ref = 0.5 * (t_min + t_max)
        # as the script: filtered first, then accel / baro less the filtered median
        y = running_median(inst.values, median_samples)
        if inst.kind != "gyro":
            y = y - np.median(y, axis=0)
        x, yy = bin_means(temp - t_ref, y)
    else:
        t_ref = ARDUPILOT_TEMP_REFERENCE
        if coarse:
            x, yy = bin_means(temp - t_ref, y)
            t_min, t_max = float(temp.min()), float(temp.max())
        else:
            cols = moving_average(np.asarray(inst.time_s, dtype=np.float64),
                                  np.column_stack([temp, y]), ARDUPILOT_FILTER_S)
            x, yy = cols[:, 0] - t_ref, cols[:, 1:]
            t_min, t_max = float(cols[:, 0].min()), float(cols[:, 0].max())
    coef = np.zeros((y.shape[1], order + 1))
    for j in range(y.shape[1]):
        coef[j] = np.polyfit(x, yy[:, j], order)[::-1]      # the scripts' own np.polyfit
    if autopilot == "ardupilot" or inst.kind == "mag":
        coef[:, 0] = 0.0           # no constant term on board; a magnetometer: zero at TREF
    if not np.all(np.isfinite(coef)):
        raise ThermonetError(f"{inst.name}: the firmware fit is not finite")
    return FirmwareFit(kind=inst.kind, device_id=inst.device_id, t_ref=float(t_ref),
                       t_min=t_min, t_max=t_max, coef=coef, thermometer=inst.thermometer,
                       lag_s=inst.lag_s)


def resolution_effect(inst: SensorInstance, fit: FirmwareFit) -> dict[str, Any] | None:
    """For a coarse thermometer (step ≥ :data:`COARSE_STEP_C`): its step, the number of
    reported temperatures, and per axis the most the correction can be off inside one
    step (max |P'(T)| · step / 2 over [TMIN, TMAX]) absolute and as a fraction of the
    fitted drift's peak-to-peak; with a one-line statement.  None for a fine one."""
    temp = np.asarray(inst.temperature_c, dtype=np.float64)
    step = temperature_step(temp)
    if step is None or step < COARSE_STEP_C:
        return None
    grid = np.linspace(fit.t_min, fit.t_max, 401) - fit.t_ref
    err, rel = [], []
    for c in fit.coef:
        p = np.polynomial.Polynomial(c)
        e = float(np.max(np.abs(p.deriv()(grid)))) * step / 2
        pp = float(np.ptp(p(grid)))
        err.append(e)
        rel.append(e / pp if pp > 0 else float("nan"))
    levels = int(np.unique(np.round(temp, 6)).size)
    worst = int(np.nanargmax(rel)) if np.any(np.isfinite(rel)) else 0
    line = (f"thermometer reports {step:g} °C steps: fitted on the means of its {levels} "
            f"reported temperatures; the firmware reads the same steps, so inside one the "
            f"correction can be off by up to {err[worst]:.3g} {KIND_UNITS.get(fit.kind, '')} "
            f"({100 * rel[worst]:.1f} % of the "
            "fitted drift) — a warning, not a refusal")
    return {"step_c": step, "levels": levels, "max_error": err, "relative_error": rel,
            "line": line}
