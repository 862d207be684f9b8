"""``thermonet calibrate``'s held-out check (:mod:`thermonet.workflows.calibrate`, step 4):
verify's own test on data the fit never saw — the last of several logs, or one log's held-out
time blocks (:func:`~thermonet.workflows.calibrate_logs.held_out_blocks`).  The firmware form
is fitted on the rest, written as a parameter file, read back and applied to the held-out data
by :func:`thermonet.workflows.verify.evaluate`; each axis is graded by
:func:`~thermonet.workflows.verify.axis_grade` and called ``fine`` only if it would still pass
on a log running :data:`BEYOND_RANGE_C` beyond the fitted range, where the firmware holds the
correction at its edge (what the autopilot applies: :func:`apply_firmware`).  A fitted
instance whose held-out drift is not cut is skipped (:func:`check_held_out`)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..core.fileio import atomic_write_text
from ..core.profile import stage as profile_stage
from ..data.firmware import (
    ARDUPILOT_TEMP_REFERENCE,
    PX4_LETTER,
    FirmwareFit,
    ardupilot_correction,
    px4_offsets_1d,
    px4_offsets_3d,
)
from ..data.logs import FlightLog, SensorInstance
from ..scoring.verdicts import below
from .calibrate_files import InstanceResult, params_text
from .calibrate_logs import HELD_OUT_BLOCKS, HELD_OUT_EVERY, held_out_blocks, merge_logs
from .firmware_fit import check_instance, fit_firmware, target
from .magnetometer import fit_correction
from .verify import (
    KIND_UNITS,
    Limits,
    ParamFile,
    axis_grade,
    evaluate,
    judge_axes,
    read_param_file,
)

__all__ = ["apply_firmware", "BEYOND_RANGE_C", "check_held_out"]


def apply_firmware(params: dict[str, float], autopilot: str, inst: SensorInstance,
                   slot: int) -> np.ndarray:
    """What the autopilot subtracts from ``inst`` with ``params`` loaded: (n, axes) SI."""
    temp = np.asarray(inst.temperature_c, dtype=np.float64)
    if autopilot == "px4":
        if inst.kind == "baro":
            return px4_offsets_1d(params, temp, slot)[:, None]
        return px4_offsets_3d(params, inst.kind, temp, slot)
    cal = params.get(f"INS_{'GYR' if inst.kind == 'gyro' else 'ACC'}{slot + 1}_CALTEMP",
                     ARDUPILOT_TEMP_REFERENCE)
    return ardupilot_correction(params, inst.kind, temp, cal, imu=slot + 1)


#: How far (°C) beyond the fitted range a later log of the board may run for calibrate to
#: call an axis fine (a new warm-up starts and levels off a few degrees apart: the
#: simulated board's by up to ±3 °C, more with the ambient).
BEYOND_RANGE_C = 4.0


def _beyond_range(pf: ParamFile, r: InstanceResult, slot: int, before: list[float],
                  after: list[float], limits: Limits) -> dict[str, Any]:
    """What a later log running :data:`BEYOND_RANGE_C` beyond the fitted TMIN..TMAX would
    leave, per axis: there the firmware holds the correction at its edge value while the
    drift goes on (taken as the fitted polynomial's own continuation).  The held-out
    residual plus that edge error, against the held-out drift widened by the same
    continuation, must still pass verify's test; ``reasons`` say why not."""
    assert r.fit is not None
    if pf.autopilot == "px4":
        pre = f"TC_{PX4_LETTER[r.kind]}{slot}_"
    else:
        pre = f"INS_TCAL{slot + 1}_"
    lo, hi = pf.params[pre + "TMIN"], pf.params[pre + "TMAX"]
    grid = np.linspace(lo - BEYOND_RANGE_C, hi + BEYOND_RANGE_C, 401)
    probe = SensorInstance(r.kind, slot, r.device_id, grid, grid,
                           np.zeros((grid.size, 1 if r.kind == "baro" else 3)))
    wide = dict(pf.params, **{pre + "TMIN": lo - BEYOND_RANGE_C, pre + "TMAX": hi + BEYOND_RANGE_C})
    drift = apply_firmware(wide, pf.autopilot, probe, slot)       # the polynomial continued
    held = apply_firmware(pf.params, pf.autopilot, probe, slot)   # what the firmware applies
    unit = KIND_UNITS.get(r.kind, "")
    out: dict[str, Any] = {"extend_c": BEYOND_RANGE_C, "edge_error": [], "cut": [],
                           "passed": [], "reasons": []}
    for j in range(drift.shape[1]):
        edge = float(np.ptp(drift[:, j] - held[:, j]))
        b = max(before[j], float(np.ptp(drift[:, j])))
        a = after[j] + edge
        cut = b / a if a > 0 else math.inf
        ok = cut >= limits.min_cut or a <= limits.floor[r.kind]
        out["edge_error"].append(edge)
        out["cut"].append(cut)
        out["passed"].append(bool(ok))
        out["reasons"].append("" if ok else (
            f"a log running {BEYOND_RANGE_C:g} °C beyond the fitted {lo:.1f}..{hi:.1f} °C "
            f"(the firmware holds the correction at its edge there) would leave about "
            f"{a:.3g} {unit}, a cut of {cut:.1f}x: log a wider range (colder start, hotter "
            "end) or keep the vehicle inside it"))
    return out


def _held_out(logs: list[FlightLog], results: list[InstanceResult], stage: Path, what: str
              ) -> dict[str, dict[str, Any]]:
    """Fit on all logs but the last, apply the written file to the last through verify's own
    :func:`~thermonet.workflows.verify.evaluate` — the same test, limits and floors as
    ``thermonet verify`` — and grade each axis (:func:`~thermonet.workflows.verify.axis_grade`).
    ``what`` names the held-out data in the results."""
    limits = Limits()
    train = merge_logs(logs[:-1])
    by_name = {i.name: i for i in train.instances}
    fitted: list[InstanceResult] = []
    out: dict[str, dict[str, Any]] = {}
    held = {i.name: i for i in logs[-1].instances}
    for r in results:
        inst = by_name.get(r.name)
        why = None if inst is None else check_instance(inst, train.autopilot)
        if r.fit is None or inst is None or why is not None:
            out[r.name] = {"status": "not judged", "data": what,
                           "reason": why or "not fitted on all the data either"}
            continue
        fit = fit_firmware(inst, train.autopilot)
        if r.status == "model only":     # not in a parameter file: the same test, directly
            out[r.name] = _judge_model_only(fit, held.get(r.name), train.autopilot, what,
                                            logs[-1], limits)
            continue
        fitted.append(InstanceResult(r.name, r.kind, r.device_id, "fitted", fit=fit))
    if not fitted:
        return out
    text, name = params_text(train, fitted, header=["held-out check"])
    tmp = stage / f".held-out.{name}"
    atomic_write_text(tmp, text)
    try:
        pf = read_param_file(tmp)
        checked = evaluate(pf, logs[-1], limits, refuse_unjudged=False)
    finally:
        tmp.unlink()
    for r in fitted:
        d: dict[str, Any] = checked.get(r.name) or {"status": "not judged",
                                                    "reason": "not in the held-out data"}
        h = {"log": str(logs[-1].path), "data": what, **{k: d.get(k) for k in (
            "status", "reason", "pp_raw", "pp_corrected", "cut", "passed", "warnings")}}
        if d.get("status") == "judged":
            graded = [axis_grade(c, a, ok, r.kind, limits) for c, a, ok in zip(
                d["cut"], d["pp_corrected"], d["passed"], strict=True)]
            wider = _beyond_range(pf, r, int(d["slot"]), d["pp_raw"], d["pp_corrected"],
                                  limits)
            h["beyond_range"] = wider
            for j, (grade, _) in enumerate(graded):
                if grade == "fine" and not wider["passed"][j]:
                    graded[j] = ("marginal", wider["reasons"][j])
            h["grades"] = [g for g, _ in graded]
            h["grade_reasons"] = [why for _, why in graded]
        out[r.name] = h
    return out


def _judge_model_only(fit: FirmwareFit, inst: SensorInstance | None, autopilot: str, what: str,
                      log: FlightLog, limits: Limits) -> dict[str, Any]:
    """verify's test (:func:`~thermonet.workflows.verify.judge_axes`) of a fit that is in no
    parameter file, applied through PX4's cubic (:func:`fit_correction`) to ``inst``."""
    h: dict[str, Any] = {"log": str(log.path), "data": what, "warnings": []}
    why = None if inst is None else check_instance(inst, autopilot)
    if inst is None or why is not None:
        h.update(status="not judged", reason=why or "not in the held-out data")
        return h
    temp = np.asarray(inst.temperature_c, dtype=np.float64)
    d = judge_axes(temp, target(inst, autopilot), fit_correction(fit, temp), inst.kind, limits)
    h.update(status="judged", reason=None, **{k: d[k] for k in (
        "pp_raw", "pp_corrected", "cut", "passed")})
    graded = [axis_grade(c, a, ok, inst.kind, limits) for c, a, ok in zip(
        d["cut"], d["pp_corrected"], d["passed"], strict=True)]
    h["grades"] = [g for g, _ in graded]
    h["grade_reasons"] = [w for _, w in graded]
    return h


def check_held_out(logs: list[FlightLog], log: FlightLog, results: list[InstanceResult],
                    stage: Path) -> None:
    """Verify's own test on data the fit never saw — the last log, or (one log) a quarter of
    it in time blocks: a fitted instance whose firmware form does not cut that drift is
    skipped."""
    if len(logs) > 1:
        held_logs, what = logs, f"the last log, {logs[-1].path.name}"
    else:
        held_logs = list(held_out_blocks(log))
        blocks = [b + 1 for b in range(HELD_OUT_BLOCKS)
                  if b % HELD_OUT_EVERY == HELD_OUT_EVERY // 2]
        what = (f"time blocks {', '.join(map(str, blocks))} of {HELD_OUT_BLOCKS} of "
                f"{logs[0].path.name}")
    with profile_stage("held-out check (verify's test)"):
        held = _held_out(held_logs, results, stage, what)
    for name, h in held.items():
        r = next(x for x in results if x.name == name)
        r.summary["held_out"] = h
        if r.status in ("fitted", "model only") and h.get("status") == "judged" and not all(
                math.isfinite(a) and below(a, b)
                for a, b in zip(h["pp_corrected"], h["pp_raw"], strict=True)):
            r.status, r.fit = "skipped", None
            r.reason = (f"fitted on the rest, the firmware form does not cut the drift of "
                        f"the held-out data ({what})")
