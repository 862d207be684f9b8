"""``thermonet calibrate LOG [LOG ...] --out DIR``: the autopilot's thermal calibration, judged.

For every sensor instance of PX4 ULogs or ArduPilot DataFlash logs of one board:

0. **A warm-up at rest** (:func:`refuse_moving`): a log in which the vehicle moves (verify's
   own test, :func:`thermonet.workflows.verify_motion.moving_log`: its gyros still in under
   80 % of their 10-s windows) is refused in one line naming the file, the share of time
   still and ``thermonet learn``, the path for flight logs: in flight every temperature bin
   holds the vehicle's turns and accelerations, which the fit would write as drift.
1. **Checks** (:func:`thermonet.workflows.firmware_fit.check_instance`).  An instance
   is left out, with one line saying why, only when it cannot be fitted: no
   thermometer, fewer than ``MIN_SAMPLES`` samples, a temperature span under
   ``MIN_SPAN_C``, fewer distinct temperatures than the polynomial needs.  A
   thermometer reporting whole degrees (or coarser) is calibrated: fitted on the
   means per reported temperature, as PX4's script bins, with its resolution and
   what it costs stated in the verdict, the report and the parameter file's header.
   Magnetometers (:mod:`thermonet.workflows.magnetometer`): one without a thermometer
   is lent one (named with ``mag_thermometers``, else the barometer's, else an IMU's),
   seen through a first-order lag chosen by held-out time blocks; one that moved during
   the soak (its field turns over :data:`~thermonet.workflows.firmware_fit.MAX_MOVE_DEG`
   within a minute, within each log) is left out with one line.  A sensor whose
   thermometer the log holds in kelvin is left out in one line saying so
   (:func:`thermonet.data.logs.base.flag_kelvin`: not converted, the autopilot reads the
   same kelvin).  PX4 ``TC_M*`` slots are written for
   magnetometers with their own thermometer; one on a lent thermometer, and every
   ArduPilot magnetometer (ArduPilot has no magnetometer temperature calibration), is
   ``model only``: fitted and judged the same way, its cubic in results.json, its
   models exportable as ONNX / C from ``instances/<name>``, not in the parameter file.
2. **The firmware's own form, fitted as the autopilots' scripts fit it**
   (:mod:`thermonet.workflows.firmware_fit`: PX4 ``process_sensor_caldata.py``'s
   2,000 temperature bins; ArduPilot ``tempcal_IMU.py``'s 2-s moving average), on all
   the data (heating and cooling).  Firmware (``TemperatureCompensation.cpp``;
   ``AP_InertialSensor_tempcal.cpp``): see :mod:`thermonet.data.firmware`; rad/s,
   m/s², **Pa** (the script's ×100 assumed hPa, PX4 issue #20051).
3. **Side by side with thermonet's families**
   (:mod:`thermonet.workflows.calibrate_compare`), by calling
   :func:`thermonet.workflows.compare.compare_result` on the instance (the firmware form as
   the baseline family, a line, an RBF on [ΔT, ΔT²] with the cubic tail, its centres at
   ΔT's quantiles); judged on held-out
   contiguous time blocks (``split: time-blocks``), never random samples.
   When the firmware form does not beat the raw output on the held-out blocks,
   the instance is left out of the parameter file (loading it would do harm).  With
   several CPUs, helper processes (``workers``) compare instances beside the command
   (:func:`~thermonet.workflows.calibrate_compare.compare_all`); the first reads the logs
   while the command imports torch, then imports it too; the result is the same.
4. **The held-out check is verify's test**
   (:mod:`thermonet.workflows.calibrate_held_out`): the firmware form is
   fitted without the held-out data, written as a parameter file, read back and applied
   to the held-out data by :func:`thermonet.workflows.verify.evaluate` — the same
   minimums, :class:`~thermonet.workflows.verify.Limits` and floors as ``thermonet
   verify``, NaN/inf a FAIL — and each axis graded by
   :func:`~thermonet.workflows.verify.axis_grade`: ``fine`` (passes with the margin
   :data:`~thermonet.workflows.verify.MARGIN`, and still would on a log running
   :data:`~thermonet.workflows.calibrate_held_out.BEYOND_RANGE_C` beyond the fitted range,
   where the firmware holds the correction at its edge), ``marginal`` (passes, not by that
   margin; the reason is reported) or ``fails``.  An instance whose held-out drift is
   not cut at all is left out.  Several logs (the same board: every log must have the
   same device ids and, where the logs hold one, the same board id — PX4's ``sys_uuid``,
   ArduPilot's system-id line — else refused naming both logs' ids; the same bytes twice
   — equal SHA-256 — refused in one line): the held-out data are the last log, and the exported
   files are then refitted on all the logs (the report says so); the logs are joined in
   the order given (time restarted after each), so the comparison's time blocks stay
   contiguous within a log (:func:`~thermonet.workflows.calibrate_logs.merge_logs`).  One
   log: a quarter of it in time blocks
   (:func:`~thermonet.workflows.calibrate_logs.held_out_blocks`).  Tested on simulated
   boards over several seeds: an axis called ``fine`` PASSes ``thermonet verify`` on the
   board's next warm-up.
5. **Files** (:mod:`thermonet.workflows.calibrate_files`): ``DIR/px4.params``
   (QGroundControl, every slot of each kind with a fitted instance — but the slot the
   board's active ``TC_*_ID`` in the log give an instance left out, which is kept, the fitted
   ones taking the board's slots for them; a kind with none — not
   in the log, or every instance left out — is not written at all, neither disabled nor
   cleared: the board keeps its own, one line per kind says so; the Vehicle-Id is the log's
   ``MAV_SYS_ID``, else 1, said in a comment) or ``DIR/ardupilot.parm`` (``INS_TCAL1..3_*``
   and a ``# device ids:`` comment per IMU, ``INS_TCAL_OPTIONS`` not written),
   ``DIR/results.json``, ``DIR/report.txt`` and ``DIR/report.html``, per instance
   ``DIR/instances/<name>/`` (the comparison).
6. **The advice** (:func:`~thermonet.workflows.calibrate_report.load_advice`, ``advice`` in
   ``results.json``): load the file, not yet (an axis in it fails the held-out check), or
   **not at all** where no instance in it could be judged on held-out data (each one
   ``not judged``: too short, too narrow).  Such a file is still written, for inspection —
   what was fitted and its header — but its header starts ``DO NOT LOAD``, the console,
   ``report.txt`` and ``report.html`` say not to load it and what a log needs to be checked:
   the held-out data need :data:`~thermonet.workflows.firmware_fit.MIN_SAMPLES` samples over
   :data:`~thermonet.workflows.firmware_fit.MIN_SPAN_C`, so one log of fewer than
   :data:`~thermonet.workflows.calibrate_logs.MIN_GRADED_LOG_SAMPLES` (800) samples per
   sensor can never be graded.  The exit status stays 0 (a file was written; the advice is
   the verdict).

After writing, the parameter file is read back and applied to the logs through the
autopilot's formula, the instance matched by device id (``firmware_check``): the
peak-to-peak of 1 °C-binned means before and after, per axis.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError, ThermonetError
from ..core.fileio import atomic_write_text, refuse_overwriting_inputs
from ..core.helpers import Helpers, usable_cores, value_or_none
from ..core.names import inside, path_components
from ..core.outdir import KINDS, check_target, sha256_file, staged_output
from ..core.profile import stage as profile_stage
from ..core.version import __version__
from ..data.firmware import PX4_SLOTS
from ..data.logs import FlightLog, SensorInstance, read_log, temperature_step
from .calibrate_compare import (
    HELPER_IMPORTS,
    MAX_WORKERS,
    compare_all,
    helper_count,
    import_comparison,
    verdict,
)
from .calibrate_files import (
    EKF_FILE,
    InstanceResult,
    ekf_text,
    json_default,
    not_written,
    params_text,
    results_doc,
)
from .calibrate_held_out import apply_firmware, check_held_out
from .calibrate_logs import MIN_GRADED_LOG_SAMPLES, merge_logs
from .calibrate_report import (
    format_report,
    format_summary,
    load_advice,
    render_calibration_report,
)
from .firmware_fit import (
    FIT_KINDS,
    MIN_SAMPLES,
    MIN_SPAN_C,
    check_instance,
    fit_firmware,
    resolution_effect,
    target,
)
from .magnetometer import (
    choose_lag,
    fit_correction,
    heading_error_deg,
    lend_thermometers,
    with_lag,
)
from .verify import Limits, evaluate, judge_axes, read_param_file
from .verify_motion import moving_log

__all__ = ["calibrate", "fit_firmware", "check_instance", "apply_firmware", "merge_logs",
           "format_report", "format_summary", "render_calibration_report", "MIN_SPAN_C", "MIN_SAMPLES",
           "InstanceResult"]

_FIT_KINDS = FIT_KINDS


def calibrate(log_path: str | Path | Sequence[str | Path], out_dir: str | Path, *,
              compare: bool = True, overwrite: bool = False,
              mag_thermometers: Mapping[str, str] | None = None,
              workers: int | None = None) -> dict[str, Any]:
    """Calibrate every instance of one board's log(s); write ``out_dir``; return results.

    ``log_path``: one log, or several logs of the same board (train on all but the
    last, verify on the last, export the refit on all: see the module).
    ``mag_thermometers``: ``{"mag1": "baro0"}``, the thermometer lent to a magnetometer
    without one (default: :data:`~thermonet.workflows.magnetometer.DEFAULT_THERMOMETERS`).
    ``workers``: processes comparing instances side by side — this one and ``workers − 1``
    helpers (:func:`~thermonet.workflows.calibrate_compare.compare_all`); None or 0: one per
    CPU this process may use, at most
    :data:`~thermonet.workflows.calibrate_compare.MAX_WORKERS`, where this process has not
    loaded torch yet (else this one alone:
    :func:`~thermonet.workflows.calibrate_compare.helper_count`); 1: this process alone.  The
    calibration does not depend on it.

    ``out_dir`` appears whole or not at all (:mod:`thermonet.core.outdir`,
    ``kind="calibration"``): it is built in a hidden staging directory beside it
    and moved into place at the end, so an interruption (Ctrl-C, SIGTERM, an
    error) leaves no half-written ``instances/``.  A non-empty ``out_dir`` that
    is not a previous calibration is refused; a previous one is replaced only
    with ``overwrite`` — whole, so an older ``ardupilot.parm`` never stays beside
    a new ``px4.params`` — and the user's own files beside it are kept.

    Raises
    ------
    InputError
        A bad log (one line naming the file and what is missing), or logs of two boards.
    ThermonetError
        No instance can be calibrated (each reason listed), or ``out_dir`` is refused.
    """
    paths = [log_path] if isinstance(log_path, (str, Path)) else list(log_path)
    if not paths:
        raise InputError("calibrate needs at least one log")
    out = Path(out_dir)
    refuse_overwriting_inputs(out, paths, owned=KINDS["calibration"])
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 0):
        raise InputError(f"workers {workers!r}: a whole number >= 0 (0: one per CPU)")
    most = max(usable_cores(), MAX_WORKERS)
    if workers is not None and workers > most:   # each one imports torch (~250 MB)
        raise InputError(f"--workers {workers}: more processes than this machine's "
                         f"{usable_cores()} usable CPUs (each loads torch, ~250 MB): give at "
                         f"most {most} (0: one per CPU, at most {MAX_WORKERS}; 1: this one "
                         "alone)")
    helpers = None
    n = helper_count(compare, workers)
    if n:
        # the first reads the logs before its imports (a light module), while this process
        # imports torch and the comparison: the logs off the way to the first comparison
        try:
            helpers = Helpers(n, HELPER_IMPORTS,
                              first=("thermonet.data.logs", "read_logs", {"paths": paths}))
        except OSError:                  # no process to be had (a limit, a sandbox)
            helpers = None
    with helpers if helpers is not None else contextlib.nullcontext():
        if helpers is not None:
            helpers.start()              # the imports queued behind the first call
        return _calibrate(paths, out, compare=compare, overwrite=overwrite,
                          mag_thermometers=mag_thermometers, helpers=helpers)


def _calibrate(paths: list[str | Path], out: Path, *, compare: bool, overwrite: bool,
               mag_thermometers: Mapping[str, str] | None, helpers: Helpers | None
               ) -> dict[str, Any]:
    """:func:`calibrate` once its helpers (if any) are started: the first reads the logs
    while this process imports the comparison, then they import it too."""
    logs = None
    if helpers is not None:
        with profile_stage("import torch and the comparison (a helper reads the log(s))"):
            import_comparison()
        with profile_stage("read the log(s) (in the helper)"):
            # one log per path, or None: read here, where a bad log is refused in its own words
            logs = value_or_none(helpers.first, lambda v: isinstance(v, list) and len(v) == len(
                paths) and all(isinstance(lg, FlightLog) for lg in v))
    if logs is None:
        with profile_stage("read the log(s)"):
            logs = [read_log(p) for p in paths]
    seen: dict[str, Path] = {}
    for lg in logs:               # the same bytes twice: counted twice, "held out" on itself
        digest = sha256_file(lg.path)
        if digest in seen:
            raise InputError(f"{lg.path}: the same log as {seen[digest]} (sha256 "
                             f"{digest[:16]}…); give each log once — a log given twice is "
                             "counted twice, and checked on its own training data")
        seen[digest] = lg.path
    for lg in logs:               # a flight: every bin holds the vehicle's motion (verify's test)
        refuse_moving(lg)
    merge_logs(logs)                              # same board? (refused before anything else)
    with profile_stage("magnetometers: lend thermometers, fit the lag"):
        logs, mags = _lend_and_lag(logs, mag_thermometers)   # a bad --mag-thermometer: refused
    check_target(out, overwrite, "calibration")   # before anything is fitted
    with staged_output(out, overwrite=overwrite, kind="calibration") as stage:
        doc = _calibrate_into(logs, stage.path, out, compare=compare, mags=mags,
                              helpers=helpers)
        stage.done()
    return doc


def refuse_moving(log: FlightLog) -> None:
    """Refuse (one line: the file, the share of time still, ``thermonet learn``) a log in which
    the vehicle moves — verify's own test (:func:`~thermonet.workflows.verify_motion.moving_log`):
    in flight the gyro reads the turns and the accelerometer the accelerations, which a fit
    against temperature would write into the parameter file as drift."""
    moving = moving_log(log)
    if moving:
        raise InputError(f"{log.path}: {moving} — calibrate fits a warm-up at rest (the vehicle "
                         "still while it warms, as verify judges one); for the drift of ordinary "
                         f"flight logs use `thermonet learn {log.path.parent} --out DIR` (no "
                         "chamber)")


def _lend_and_lag(logs: list[FlightLog], choice: Mapping[str, str] | None
                  ) -> tuple[list[FlightLog], dict[str, dict[str, Any]]]:
    """Every log with a thermometer lent to each magnetometer without one, and that
    thermometer lagged by the time constant chosen by held-out time blocks
    (:func:`~thermonet.workflows.magnetometer.choose_lag`) on the logs the held-out check
    does not judge: all but the last of several logs (the last is the held-out one); with one
    log, on the whole log (its held-out blocks included: one constant, chosen before the
    held-out check; said in the record).  Per such magnetometer, what was chosen and each
    lag's score."""
    lent = [lend_thermometers(lg, choice) for lg in logs]
    logs = [lg for lg, _ in lent]
    how = lent[0][1]
    info: dict[str, dict[str, Any]] = {}
    for name, chosen in how.items():
        parts = [next(i for i in lg.instances if i.name == name) for lg in logs]
        tau = 0.0
        scores: dict[float, float] = {}
        if all(check_instance(p, lg.autopilot) is None for p, lg in zip(parts, logs,
                                                                       strict=True)):
            # never on the held-out log: the lag is part of what the check judges
            tau, scores = choose_lag(parts[:-1] if len(parts) > 1 else parts)
        info[name] = {"name": parts[0].thermometer, "chosen": chosen, "lag_s": tau,
                      "lag_scores": {f"{k:g}": v for k, v in scores.items()},
                      "lag_chosen_on": ("every log but the last (the held-out one)"
                                        if len(parts) > 1 else
                                        "the whole log, its held-out blocks included")}
        logs = [FlightLog(lg.path, lg.autopilot, [with_lag(i, tau) if i.name == name else i
                                                  for i in lg.instances], lg.params,
                          lg.notes, lg.damage, lg.unread_fraction, lg.board_id) for lg in logs]
    return logs, info


def _exportable(r: InstanceResult, autopilot: str, inst: SensorInstance) -> str | None:
    """Why a fitted magnetometer cannot go into the parameter file (None: it can)."""
    if r.kind != "mag":
        return None
    if autopilot == "ardupilot":
        return ("ArduPilot has no magnetometer temperature-calibration parameters: the cubic "
                "is in results.json; export the comparison's model as ONNX or C (thermonet "
                f"export, from instances/{r.name}, written unless --no-compare)")
    if inst.thermometer:
        return (f"fitted on {inst.thermometer}'s thermometer (lent), which PX4's TC_M cannot "
                "use — the firmware applies TC_M* with the magnetometer's own temperature: "
                f"export the comparison's model as ONNX or C (instances/{r.name}, written "
                "unless --no-compare)")
    return None


def _calibrate_into(logs: list[FlightLog], stage: Path, out: Path, *, compare: bool,
                    mags: dict[str, dict[str, Any]] | None = None,
                    helpers: Helpers | None = None) -> dict[str, Any]:
    """The calibration, written into ``stage``; recorded paths name ``out``."""
    log = merge_logs(logs)
    source = ", ".join(str(lg.path) for lg in logs)
    dirs = path_components(i.name for i in log.instances)
    ok_kinds = [i.kind for i in log.instances if check_instance(i, log.autopilot) is None
                and not i.thermometer]
    per_kind = {k: ok_kinds.count(k) for k in _FIT_KINDS}
    if log.autopilot == "px4" and max(per_kind.values()) > PX4_SLOTS:
        raise ThermonetError(f"{log.path}: PX4 has {PX4_SLOTS} calibration slots per sensor "
                             f"kind; the log has {per_kind} calibratable instances")
    results = [_fit_instance(inst, log, mags=mags) for inst in log.instances]
    compared = compare_all([
        {"inst": inst, "autopilot": log.autopilot,
         "where": inside(stage, "instances", dirs[inst.name]), "source": source,
         "final": out / "instances" / dirs[inst.name]}
        for inst, r in zip(log.instances, results, strict=True)
        if compare and r.status == "fitted"], helpers)
    results = [_judge_instance(r, inst, log.autopilot, compared.get(inst.name))
               for inst, r in zip(log.instances, results, strict=True)]
    check_held_out(logs, log, results, stage)
    fitted = [r for r in results if r.status == "fitted"]
    if not fitted:
        reasons = "; ".join(f"{r.name}: {r.reason}" for r in results)
        raise ThermonetError(f"{source}: no sensor instance can be calibrated ({reasons})")
    names = ", ".join(lg.path.name for lg in logs)
    header = [f"thermonet {__version__} thermal calibration of {names}",
              "firmware form fitted on all samples (heating and cooling)"
              + (f" of all {len(logs)} logs (held-out check: fitted on the first "
                 f"{len(logs) - 1}, applied to {logs[-1].path.name})" if len(logs) > 1 else "")
              + "; see report.txt"]
    header += [f"board id: {log.board_id}"] if log.board_id else []   # verify matches by it
    advice = load_advice({"instances": {r.name: {"status": r.status, **r.summary}
                                        for r in results}, "board_id": log.board_id,
                          "held_out_log": len(logs) > 1}, min_log_samples=MIN_GRADED_LOG_SAMPLES)
    header += [] if advice["checked"] else [
        "DO NOT LOAD: nothing in this file could be checked on held-out data (see report.txt); "
        "written for inspection only"]
    header += [f"{r.name} (id {r.device_id}): {r.summary['resolution']['line']}"
               for r in fitted if "resolution" in r.summary]
    text, fname = params_text(log, fitted, header)
    param_path = stage / fname
    atomic_write_text(param_path, text)
    ekf = ekf_text(log.autopilot, fitted, fname)
    if ekf:
        atomic_write_text(stage / EKF_FILE, ekf)
    checked = evaluate(read_param_file(param_path), log)
    for r in fitted:
        c = checked[r.name]
        r.summary["slot"] = c["slot"]
        r.summary["firmware_check"] = {k: c[k] for k in ("pp_raw", "pp_corrected", "cut")}
    _check_magnetometers(results, log)
    doc = results_doc(logs, results, out / param_path.name)
    doc["advice"] = load_advice(doc, min_log_samples=MIN_GRADED_LOG_SAMPLES)
    doc["not_written"] = not_written(log, fitted)
    atomic_write_text(stage / "results.json", json.dumps(doc, indent=2, default=json_default))
    atomic_write_text(stage / "report.txt", format_report(doc))
    atomic_write_text(stage / "report.html", render_calibration_report(doc, out, staged=stage))
    return doc


def _fit_instance(inst: Any, log: FlightLog, *, mags: dict[str, dict[str, Any]] | None
                  ) -> InstanceResult:
    """One sensor instance checked and its firmware form fitted (``status`` "fitted"), or
    why it is left out; the comparison and the verdict follow (:func:`_judge_instance`)."""
    why = check_instance(inst, log.autopilot)
    r = InstanceResult(inst.name, inst.kind, inst.device_id, "skipped", why)
    r.summary = {"n_samples": inst.n_samples, "notes": list(inst.notes),
                 "temperature_step_c": temperature_step(inst.temperature_c)}
    if inst.temperature_c is not None and inst.n_samples:
        r.summary["temperature_c"] = [float(inst.temperature_c.min()),
                                      float(inst.temperature_c.max())]
    if inst.kind == "mag":
        r.summary["thermometer"] = (mags or {}).get(inst.name) or {
            "name": None, "chosen": "own" if inst.temperature_c is not None else None,
            "lag_s": 0.0}
    if why is None and log.autopilot == "ardupilot" and inst.kind == "baro":
        why = r.reason = "ArduPilot has no barometer temperature calibration parameters"
    if why is None:
        with profile_stage(f"{inst.name}: fit the firmware form"):
            r.fit = fit_firmware(inst, log.autopilot)
        r.status = "fitted"
        res = resolution_effect(inst, r.fit)
        if res is not None:
            r.summary["resolution"] = res
    return r


def _judge_instance(r: InstanceResult, inst: SensorInstance, autopilot: str,
                    cmp: dict[str, Any] | str | None) -> InstanceResult:
    """The verdict of the comparison ``cmp`` (None: not compared) on a fitted instance, and
    whether its model can go into the parameter file."""
    if r.status != "fitted":
        return r
    res = r.summary.get("resolution")
    if isinstance(cmp, str):
        r.status, r.reason, r.fit = "skipped", f"comparison failed: {cmp}", None
        return r
    if cmp is not None:
        ok, line = verdict(cmp)
        r.summary["compare"] = cmp
        r.summary["verdict"] = line + (f"; {res['line']}" if res else "")
        if not ok:
            r.status, r.reason = "skipped", ("the firmware form does not reduce the "
                                             "drift on held-out data: " + line)
            r.fit = None
    elif res is not None:
        r.summary["verdict"] = res["line"]
    why_not = _exportable(r, autopilot, inst)
    if r.status == "fitted" and why_not:
        r.status, r.reason = "model only", why_not
    return r


def _check_magnetometers(results: list[InstanceResult], log: FlightLog) -> None:
    """Magnetometers: PX4's cubic checked on the log (a model-only one judged here), and
    what it does to a heading."""
    by_inst = {i.name: i for i in log.instances}
    for r in results:
        inst = by_inst[r.name]
        if r.kind != "mag" or r.fit is None or r.status not in ("fitted", "model only"):
            continue
        temp = np.asarray(inst.temperature_c, dtype=np.float64)
        corr = fit_correction(r.fit, temp)
        if r.status == "model only":
            d = judge_axes(temp, target(inst, log.autopilot), corr, "mag", Limits())
            r.summary["firmware_check"] = {k: d[k] for k in ("pp_raw", "pp_corrected", "cut")}
        r.summary["heading"] = heading_error_deg(temp, inst.values, corr, r.fit.t_ref)
