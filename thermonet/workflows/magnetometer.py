"""Magnetometers in ``thermonet calibrate``: a thermometer lent where the magnetometer has
none, its lag fitted by cross-validation, and the heading error the drift makes.

PX4 compensates a magnetometer's offset with the gyro's cubic (``TC_M*``,
:mod:`thermonet.data.firmware`), evaluated at the magnetometer's *own* temperature;
ArduPilot has no magnetometer temperature calibration at all.  Most magnetometers
report no temperature (PX4 logs NaN; ArduPilot's ``MAG`` has no temperature field), so:

* **A lent thermometer** (:func:`lend_thermometers`).  The user names one per
  magnetometer (``--mag-thermometer mag1=baro0``); otherwise the default is the first
  of :data:`DEFAULT_THERMOMETERS` the log has with a thermometer — the barometer's
  (``baro0``: on the board, not heated by an IMU heater, and every PX4 / ArduPilot
  board has one), then ``gyro0``, then ``acc0``.  The report names the thermometer and
  whether it was named or the default.
* **Its lag** (:func:`choose_lag`).  The magnetometer's die follows the lent
  thermometer late (another package, often another board), so the temperature the
  cubic is evaluated at is the lent one through a first-order lag,
  :math:`T_{mag} = \\mathrm{EMA}_\\tau(T)` — :math:`T - ` ``lag_<tau>`` of
  :mod:`thermonet.features.dynamics`, the same recurrence.  τ is chosen from
  :data:`LAG_GRID_S` (0 = no lag) by the held-out score of contiguous time blocks, as
  every choice in thermonet is (``split: time-blocks``): :data:`CV_BLOCKS` blocks, every
  :data:`CV_FOLDS`-th held out in turn, first and last never scored (no extrapolation);
  the score is the mean squared held-out residual of the cubic over the three axes.
* A magnetometer calibrated on a lent thermometer cannot be a PX4 ``TC_M`` slot (the
  firmware would read its own — missing — temperature): its cubic and lag are in the
  results and the comparison's models (ONNX / C export) carry it.

The heading error (:func:`heading_error_deg`) is what the drift does to a level board's
compass heading, ψ = atan2(−B_y, B_x): the largest change of the heading of the
1 °C-binned mean field from its value at TREF, before and after the correction.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..core.errors import InputError
from ..data.firmware import FirmwareFit
from ..data.logs import FlightLog, SensorInstance
from ..data.logs.base import lend_thermometer
from ..features.recurrences import lag_error
from .firmware_fit import bin_means, running_median

__all__ = ["DEFAULT_THERMOMETERS", "LAG_GRID_S", "CV_BLOCKS", "CV_FOLDS",
           "parse_thermometers", "lend_thermometers", "lagged", "choose_lag", "with_lag",
           "fit_correction", "heading_error_deg"]

#: Thermometers lent to a magnetometer without one, in order of preference.
DEFAULT_THERMOMETERS = ("baro0", "gyro0", "acc0")
#: Lag time constants tried (s; 0: the lent thermometer as it is).
LAG_GRID_S = (0.0, 30.0, 60.0, 120.0, 180.0, 240.0, 300.0, 420.0, 600.0, 900.0)
#: The lag's cross-validation: contiguous time blocks, every CV_FOLDS-th held out in turn.
CV_BLOCKS = 20
CV_FOLDS = 4


def parse_thermometers(specs: Sequence[str]) -> dict[str, str]:
    """``["mag1=baro0", …]`` as ``{"mag1": "baro0"}``; refuses a malformed item in one line."""
    out: dict[str, str] = {}
    for spec in specs:
        mag, sep, donor = spec.partition("=")
        if not sep or not mag.strip().startswith("mag") or not donor.strip():
            raise InputError(f"--mag-thermometer {spec!r}: expected MAG=THERMOMETER, e.g. "
                             "mag1=baro0 (a magnetometer instance and the instance whose "
                             "thermometer it borrows)")
        if mag.strip() in out and out[mag.strip()] != donor.strip():
            raise InputError(f"--mag-thermometer {spec!r}: {mag.strip()} is already lent "
                             f"{out[mag.strip()]}'s thermometer (--mag-thermometer "
                             f"{mag.strip()}={out[mag.strip()]}): name one thermometer per "
                             "magnetometer")
        out[mag.strip()] = donor.strip()
    return out


def lend_thermometers(log: FlightLog, choice: Mapping[str, str] | None = None
                      ) -> tuple[FlightLog, dict[str, str]]:
    """``log`` with a thermometer lent to every magnetometer that has none; and, per
    magnetometer lent one, how it was chosen (``named`` or ``default``).

    A named thermometer must be an instance of the log with a thermometer of its own,
    else the log is refused in one line naming the file, the magnetometer and the name.
    A magnetometer with no thermometer to borrow keeps none (calibrate says why)."""
    choice = dict(choice or {})
    by_name = {i.name: i for i in log.instances}
    for mag in choice:
        if mag not in by_name or by_name[mag].kind != "mag":
            mags = [i.name for i in log.instances if i.kind == "mag"]
            raise InputError.at(log.path, f"--mag-thermometer {mag}={choice[mag]}: the log has "
                                f"no magnetometer {mag} (magnetometers: "
                                f"{', '.join(mags) or 'none'})")
    how: dict[str, str] = {}
    instances = []
    for inst in log.instances:
        if inst.kind != "mag" or (inst.temperature_c is not None and inst.name not in choice):
            instances.append(inst)
            continue
        if inst.name in choice:
            name = choice[inst.name]
            donor = by_name.get(name)
            if donor is None or donor.kind == "mag" or donor.temperature_c is None \
                    or not donor.n_samples:
                have = [i.name for i in log.instances
                        if i.kind != "mag" and i.temperature_c is not None and i.n_samples]
                raise InputError.at(log.path, f"--mag-thermometer {inst.name}={name}: "
                                    f"{name} is not a sensor of the log with a thermometer "
                                    f"(those with one: {', '.join(have) or 'none'})")
            how[inst.name] = "named"
        else:
            donor = next((by_name[n] for n in DEFAULT_THERMOMETERS if n in by_name
                          and by_name[n].temperature_c is not None and by_name[n].n_samples),
                         None)
            if donor is None:
                instances.append(inst)
                continue
            how[inst.name] = "default"
        instances.append(lend_thermometer(inst, donor))
    return dataclasses.replace(log, instances=instances), how   # the rest as read (board id …)


def lagged(time_s: np.ndarray, temperature_c: np.ndarray, tau_s: float) -> np.ndarray:
    """``temperature_c`` through a first-order lag of ``tau_s`` (0: unchanged), started
    settled: :math:`\\mathrm{EMA}_\\tau(T) = T - \\mathrm{lag}_\\tau` of
    :func:`thermonet.features.recurrences.lag_error` (the recurrence the runtime and the C
    header compute)."""
    temp = np.asarray(temperature_c, dtype=np.float64)
    if tau_s <= 0 or temp.size == 0:
        return temp.copy()
    t = np.asarray(time_s, dtype=np.float64)
    restart = np.zeros(t.size, dtype=bool)
    restart[0] = True
    return temp - lag_error(t, temp, restart, float(tau_s))


def _cv_score(temp: np.ndarray, y: np.ndarray) -> float:
    """Mean squared held-out residual of the cubic, contiguous time blocks (see module)."""
    n = temp.size
    block = np.minimum(np.arange(n) * CV_BLOCKS // max(n, 1), CV_BLOCKS - 1)
    sse, count = 0.0, 0
    for fold in range(CV_FOLDS):
        held = (block % CV_FOLDS == fold) & (block > 0) & (block < CV_BLOCKS - 1)
        if not held.any():
            continue
        x, yy = bin_means(temp[~held], y[~held])
        if x.size < 5:
            continue
        for j in range(y.shape[1]):
            c = np.polyfit(x, yy[:, j], 3)
            r = y[held, j] - np.polyval(c, temp[held])
            sse += float(np.sum(r * r))
            count += int(r.size)
    return sse / count if count else math.inf


def choose_lag(parts: Sequence[SensorInstance], grid: Sequence[float] = LAG_GRID_S
               ) -> tuple[float, dict[float, float]]:
    """The lag (s) of ``grid`` whose lagged thermometer the cubic fits best on held-out
    time blocks, over the magnetometer's logs ``parts`` (each with its lent thermometer,
    lagged per log); and every candidate's score (mean squared residual, µT²)."""
    scores: dict[float, float] = {}
    ys = []
    for p in parts:
        y = running_median(p.values)
        ys.append(y - np.median(y, axis=0))
    y_all = np.concatenate(ys)
    for tau in grid:
        temp = np.concatenate([lagged(p.time_s, np.asarray(p.temperature_c), tau)
                               for p in parts])
        scores[float(tau)] = _cv_score(temp, y_all)
    best = min(scores, key=lambda k: (scores[k], k))
    return best, scores


def with_lag(inst: SensorInstance, tau_s: float) -> SensorInstance:
    """``inst`` (a lent thermometer) with its temperature through the lag ``tau_s``."""
    temp = lagged(inst.time_s, np.asarray(inst.temperature_c), tau_s)
    return SensorInstance(inst.kind, inst.instance, inst.device_id, inst.time_s, temp,
                          inst.values, notes=list(inst.notes), truth=inst.truth,
                          damaged=inst.damaged, untrusted=inst.untrusted,
                          thermometer=inst.thermometer, lag_s=float(tau_s),
                          unlagged_c=np.asarray(inst.temperature_c, dtype=np.float64))


def fit_correction(fit: FirmwareFit, temperature_c: np.ndarray) -> np.ndarray:
    """What PX4's ``calc_thermal_offsets_3D`` subtracts with ``fit`` loaded, in µT:
    T clamped to [TMIN, TMAX], Σ X_k (T − TREF)^k per axis (for a fit that is not in a
    parameter file: a lent thermometer, or an ArduPilot log)."""
    x = np.clip(np.asarray(temperature_c, dtype=np.float64), fit.t_min, fit.t_max) - fit.t_ref
    return np.column_stack([np.polynomial.polynomial.polyval(x, c) for c in fit.coef])


def heading_error_deg(temperature_c: np.ndarray, values: np.ndarray, correction: np.ndarray,
                      t_ref: float) -> dict[str, Any]:
    """A level board's heading error from the drift, degrees: the largest change of the
    heading atan2(−B_y, B_x) of the 1 °C-binned mean field from the heading of the bin
    holding TREF, before and after subtracting ``correction``."""
    temp = np.asarray(temperature_c, dtype=np.float64)
    bins = np.floor(temp)
    ref_bin = math.floor(t_ref)
    out: dict[str, Any] = {}
    for key, v in (("before", values), ("after", values - correction)):
        means = np.array([v[bins == b].mean(axis=0) for b in np.unique(bins)])
        heads = np.degrees(np.arctan2(-means[:, 1], means[:, 0]))
        ub = np.unique(bins)
        ref = heads[int(np.argmin(np.abs(ub - ref_bin)))]
        err = (heads - ref + 180.0) % 360.0 - 180.0
        out[key] = float(np.max(np.abs(err)))
    out["line"] = (f"heading error of a level board from the drift: ±{out['before']:.2f}° "
                   f"before, ±{out['after']:.2f}° after")
    return out
