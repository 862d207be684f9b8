"""``thermonet learn``'s fit of one sensor instance (:func:`instance_doc`): the estimator's lag
chosen and the outliers left out (:mod:`thermonet.workflows.learn_data`), the coverage map,
the autopilot's own cubic on every flight and judged on the last flight it was not fitted on,
and — with :data:`MIN_COMPARE_FLIGHTS` flights or more — the same comparison, choice and
exports as the chamber path (``compare`` on whole flights), its outputs relocated into the
job's directory."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, cast

import numpy as np

from ..core.errors import ThermonetError
from ..core.outdir import relocate_json
from ..core.recording import Dataset, Recording
from ..data.firmware import FirmwareFit
from ..data.logs import SensorInstance
from ..reporting.results import ComparisonResult as TypedResult
from ..reporting.results import clean
from .firmware_fit import fit_firmware
from .learn_data import (
    MIN_BIN_FLIGHTS,
    MIN_BIN_MINUTES,
    MIN_SUPPORTED_SPAN_C,
    InstanceWindows,
    choose_lag,
    coverage,
    median_within_flights,
    missing_words,
    reject_outliers,
)
from .magnetometer import fit_correction
from .verify import Limits

__all__ = ["instance_doc", "binned_pp", "MIN_COMPARE_FLIGHTS", "MIN_RUN_WINDOWS", "UNITS"]

#: Flights an instance needs for the comparison (train, validate, test by flight).
MIN_COMPARE_FLIGHTS = 3
#: Windows a flight needs to be a run of the comparison.
MIN_RUN_WINDOWS = 10
UNITS = {"gyro": "rad/s", "acc": "m/s^2"}

def _target(inst: InstanceWindows, drift: np.ndarray) -> np.ndarray:
    """The chamber path's target: the gyro as it is, the accelerometer less its median."""
    return drift if inst.kind == "gyro" else drift - np.median(inst.drift[inst.keep], axis=0)


def binned_pp(temp: np.ndarray, y: np.ndarray) -> list[float]:
    """Per axis, the peak-to-peak of the 1 °C-binned means of ``y`` (NaN with < 2 bins)."""
    bins = np.floor(temp).astype(np.int64)
    u = np.unique(bins)
    if u.size < 2:
        return [math.nan] * y.shape[1]
    means = np.array([y[bins == b].mean(axis=0) for b in u])
    return [float(v) for v in np.ptp(means, axis=0)]


def _asinstance_doc(inst: InstanceWindows, sel: np.ndarray) -> SensorInstance:
    """Selected windows as one sensor instance (flights one after another in time, a
    window's length apart)."""
    order = np.lexsort((inst.time_s[sel], inst.flight[sel]))
    t = np.arange(int(sel.sum()), dtype=np.float64)[order.argsort()] * inst.window_s
    return SensorInstance(inst.kind, int(inst.name[-1]) if inst.name[-1].isdigit() else 0,
                          inst.device_id, np.sort(t), inst.temp[sel][order],
                          inst.drift[sel][order], notes=list(inst.notes))


def _firmware(inst: InstanceWindows, autopilot: str) -> dict[str, Any]:
    """The firmware form on every kept window, and its check on the last flight.  The windows
    are already each flight's running median (:func:`median_within_flights`: PX4's filter,
    within flights), so PX4's form filters no further."""
    keep = np.asarray(inst.keep)
    flights = np.unique(inst.flight[keep])
    out: dict[str, Any] = {"fit": fit_firmware(_asinstance_doc(inst, keep), autopilot, 1)}
    if flights.size < 2:
        out["held_out"] = {"status": "not judged", "reason": "one flight: nothing to hold out"}
        return out
    last = keep & (inst.flight == flights[-1])
    train = keep & ~last
    fit = fit_firmware(_asinstance_doc(inst, train), autopilot, 1)
    temp = inst.temp[last]
    y = _target(inst, inst.drift[last])
    after = y - fit_correction(fit, temp)
    before_pp, after_pp = binned_pp(temp, y), binned_pp(temp, after)
    # the firmware holds its edge value outside what the other flights covered: there the
    # correction is a constant and cuts no binned drift (said, not hidden)
    outside = float(np.mean((temp < fit.t_min) | (temp > fit.t_max))) if temp.size else 0.0
    out["held_out"] = {"status": "judged", "flight": inst.flights[int(flights[-1])],
                       "trained_c": [fit.t_min, fit.t_max], "outside_trained": outside,
                       "pp_raw": before_pp, "pp_corrected": after_pp,
                       "cut": [b / a if a > 0 else math.inf for b, a in zip(
                           before_pp, after_pp, strict=True)]}
    return out


def _dataset(inst: InstanceWindows) -> Dataset | None:
    """One run per flight with enough windows (None: too few flights to compare)."""
    keep = np.asarray(inst.keep)
    axes = ("x", "y", "z")
    runs = []
    for f in np.unique(inst.flight[keep]):
        sel = keep & (inst.flight == f)
        if sel.sum() < MIN_RUN_WINDOWS:
            continue
        order = np.argsort(inst.time_s[sel], kind="stable")
        y = inst.drift[sel][order]
        outputs = {f"{inst.kind}_{a}": y[:, j] for j, a in enumerate(axes)}
        refs = {} if inst.kind == "gyro" else {
            f"ref_{inst.kind}_{a}": np.full(y.shape[0], float(np.median(inst.drift[keep, j])))
            for j, a in enumerate(axes)}
        units = {"time_s": "s", "temperature_c": "degC",
                 **{c: UNITS[inst.kind] for c in outputs}}
        runs.append(Recording(time_s=inst.time_s[sel][order], temperature_c=inst.temp[sel][
            order], outputs=outputs, references=refs, units=units,
            device_id=str(inst.device_id), sensor_kind=inst.kind, run_id=f"flight{int(f) + 1}",
            meta={"source": inst.flights[int(f)], "instance": inst.name}))
    return Dataset(runs=runs) if len(runs) >= MIN_COMPARE_FLIGHTS else None


def _compare(inst: InstanceWindows, autopilot: str, where: Path) -> dict[str, Any]:
    """The chamber path's comparison on the flights (see the module); its summary."""
    from ..training.config import (  # lazy: importing it loads yaml
        CompareConfig,
        FamilyConfig,
        SplitConfig,
        TrackingConfig,
    )
    from .compare import compare_result  # lazy: importing it loads yaml and the fit

    ds = _dataset(inst)
    if ds is None:
        return {"status": "not compared", "reason": f"fewer than {MIN_COMPARE_FLIGHTS} flights "
                f"with {MIN_RUN_WINDOWS} windows each"}
    fw = "px4-cubic" if autopilot == "px4" else "ardupilot-cubic"
    cfg = CompareConfig(
        split=SplitConfig(strategy="runs"), tracking=TrackingConfig(enabled=False),
        baseline=fw, workers=1, families=[
            FamilyConfig(family="poly", name=fw, inputs=["dT"], params={"degree": 3}),
            FamilyConfig(family="linear", name="linear", inputs=["dT"]),
            FamilyConfig(family="rbf", name="rbf", inputs=["dT", "dT2"],
                         params={"n_centres": 8, "tail": 3, "init": "quantiles"})])
    res = cast(TypedResult, compare_result(   # model: bias: the typed result
        cfg, where, overwrite=True, track=False, quiet=True, dataset=ds.validate(inst.name),
        plots=False))
    fams = res.families
    summary: dict[str, Any] = {"status": "ok", "chosen": res.chosen,
                               "chosen_reason": res.chosen_reason, "baseline": fw,
                               "flights": len(ds), "test_flight": ds.run_ids[-1],
                               "families": {}}
    band = (fams[fw].band if fw in fams else None) or {}
    if band.get("status") == "ok":
        summary["band"] = band
    for label, fr in fams.items():
        if fr.ok:     # as results.json holds them (clean: a non-finite score is None)
            summary["families"][label] = {
                "val_score": clean(fr.val_score),
                "held_out_pp_raw": {a: m.metrics["pp_raw"] for a, m in fr.axes.items()},
                "held_out_pp_comp": {a: m.metrics["pp_comp"] for a, m in fr.axes.items()}}
    return summary


def _export(where: Path) -> dict[str, str]:
    """ONNX and C of the comparison's chosen model (what could not be exported, said); the
    paths relative to the output directory."""
    from ..exporting import export_source  # the registry; torch only inside, to load

    out: dict[str, str] = {}
    for fmt, name in (("onnx", "model.onnx"), ("c", "model.h")):
        try:
            export_source(str(where), fmt=fmt, out=where / name)
            out[fmt] = f"instances/{where.name}/{name}"
        except ThermonetError as err:
            out[fmt] = f"not exported: {err}"
    return out


def instance_doc(inst: InstanceWindows, autopilot: str, stage: Path, do_compare: bool,
              do_export: bool) -> dict[str, Any]:
    """One instance learned: lag, rejection, coverage, firmware form, comparison, export."""
    scores = choose_lag(inst)
    dropped = reject_outliers(inst)
    median_within_flights(inst)
    cov = coverage(inst)
    span, words = missing_words(cov)
    keep = np.asarray(inst.keep)
    d: dict[str, Any] = {
        "kind": inst.kind, "device_id": inst.device_id, "status": "skipped", "reason": None,
        "flights": int(np.unique(inst.flight[keep]).size), "windows": int(keep.sum()),
        "still_windows": int((inst.still & keep).sum()), "window_s": inst.window_s,
        "lag_s": inst.lag_s,
        "lag_scores": scores, "rejected_windows": dropped,
        "minutes": round(float(inst.weight[keep].sum()) / 60.0, 1),
        "coverage": cov, "supported_c": list(span) if span else None, "missing": words}
    if keep.sum() < MIN_RUN_WINDOWS or np.unique(np.round(inst.temp[keep])).size < 4:
        d["reason"] = "too few windows or temperatures to fit a cubic"
        return d
    fw = _firmware(inst, autopilot)
    fit: FirmwareFit = fw["fit"]
    d["firmware"] = {"t_ref": fit.t_ref, "t_min": fit.t_min, "t_max": fit.t_max,
                     "coef": fit.coef.tolist()}
    d["held_out"] = fw["held_out"]
    d["status"] = "fitted"
    h = fw["held_out"]
    # harm is more drift left than there was, by over verify's floor (a drift that small no
    # longer matters; the held-out flight's own windows are estimates, not the truth)
    floor = Limits().floor[inst.kind]
    if h["status"] == "judged" and not all(a <= b + floor for a, b in zip(
            h["pp_corrected"], h["pp_raw"], strict=True)):
        d["status"], d["reason"] = "skipped", (
            "fitted on the other flights, the firmware form does not cut the drift of the "
            f"last flight ({Path(h['flight']).name}): left out of the parameter file")
    elif span is None:      # nothing supports the fit: it would ship what no data stand for
        d["status"], d["reason"] = "skipped", (
            "left out of the parameter file: no 1 °C bin has "
            f"{MIN_BIN_FLIGHTS} flights and {MIN_BIN_MINUTES:g} minutes yet (coverage below)")
    elif span[1] - span[0] < MIN_SUPPORTED_SPAN_C:
        d["status"], d["reason"] = "skipped", (
            f"left out of the parameter file: supported only at {span[0]}..{span[1]} °C "
            f"(under {MIN_SUPPORTED_SPAN_C:g} °C): a cubic there is an offset's guess that "
            "the autopilot would carry across its clamp (coverage below)")
    if do_compare:
        where = stage / "instances" / inst.name
        try:
            d["compare"] = _compare(inst, autopilot, where)
            if d["compare"].get("status") == "ok":
                if do_export:
                    d["export"] = _export(where)
                # its results.json names where it will be once installed, not the staging
                relocate_json(where / "results.json", where,
                              stage.parent / "instances" / inst.name)
        except ThermonetError as err:
            d["compare"] = {"status": "failed", "reason": str(err)}
    return d
