"""``thermonet calibrate LOG [LOG ...] --out DIR``: the autopilot's thermal calibration, judged.

For every sensor instance of PX4 ULogs or ArduPilot DataFlash logs of one board:

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
   :func:`thermonet.workflows.compare.run_compare` on the instance (the firmware form as
   the baseline family, a line, an RBF on [ΔT, ΔT²] with the cubic tail, its centres at
   ΔT's quantiles); judged on held-out
   contiguous time blocks (``split: time-blocks``), never random samples.
   When the firmware form does not beat the raw output on the held-out blocks,
   the instance is left out of the parameter file (loading it would do harm).  With
   several CPUs, helper processes (``workers``) compare instances beside the command
   (:func:`~thermonet.workflows.calibrate_compare.compare_all`); the first reads the logs
   while the command imports torch, then imports it too; the result is the same.
4. **The held-out check is verify's test** (:func:`_held_out`): the firmware form is
   fitted without the held-out data, written as a parameter file, read back and applied
   to the held-out data by :func:`thermonet.workflows.verify.evaluate` — the same
   minimums, :class:`~thermonet.workflows.verify.Limits` and floors as ``thermonet
   verify``, NaN/inf a FAIL — and each axis graded by
   :func:`~thermonet.workflows.verify.axis_grade`: ``fine`` (passes with the margin
   :data:`~thermonet.workflows.verify.MARGIN`, and still would on a log running
   :data:`BEYOND_RANGE_C` beyond the fitted range, where the firmware holds the
   correction at its edge: :func:`_beyond_range`), ``marginal`` (passes, not by that
   margin; the reason is reported) or ``fails``.  An instance whose held-out drift is
   not cut at all is left out.  Several logs (the same board: every log must have the
   same device ids and, where the logs hold one, the same board id — PX4's ``sys_uuid``,
   ArduPilot's system-id line — else refused naming both logs' ids; the same bytes twice
   — equal SHA-256 — refused in one line): the held-out data are the last log, and the exported
   files are then refitted on all the logs (the report says so); the logs are joined in
   the order given (time restarted after each), so the comparison's time blocks stay
   contiguous within a log.  One log: a quarter of it in time blocks
   (:func:`held_out_blocks`).  Tested on simulated boards over several seeds: an axis
   called ``fine`` PASSes ``thermonet verify`` on the board's next warm-up.
5. **Files**: ``DIR/px4.params`` (QGroundControl, every TC_G/A/B slot) or
   ``DIR/ardupilot.parm`` (``INS_TCAL1..3_*`` and a ``# device ids:`` comment per IMU,
   ``INS_TCAL_OPTIONS`` not written), ``DIR/results.json``, ``DIR/report.txt`` and
   ``DIR/report.html``, per instance ``DIR/instances/<name>/`` (the comparison).

After writing, the parameter file is read back and applied to the logs through the
autopilot's formula, the instance matched by device id (``firmware_check``): the
peak-to-peak of 1 °C-binned means before and after, per axis.
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError, ThermonetError
from ..core.fileio import atomic_write_text, refuse_overwriting_inputs
from ..core.helpers import Helpers, value_or_none
from ..core.names import inside, path_components
from ..core.outdir import KINDS, check_target, sha256_file, staged_output
from ..core.profile import stage as profile_stage
from ..core.recording import GAP_FACTOR
from ..core.version import __version__
from ..data.firmware import (
    ARDUPILOT_TEMP_REFERENCE,
    PX4_LETTER,
    PX4_SLOTS,
    FirmwareFit,
    ardupilot_calibration_text,
    ardupilot_correction,
    px4_calibration_text,
    px4_offsets_1d,
    px4_offsets_3d,
)
from ..data.logs import FlightLog, SensorInstance, read_log, temperature_step
from ..scoring.band import shipped_band
from ..scoring.verdicts import below
from .calibrate_compare import (
    HELPER_IMPORTS,
    compare_all,
    helper_count,
    import_comparison,
    verdict,
)
from .calibrate_report import format_report, format_summary, render_calibration_report
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
from .verify import (
    KIND_UNITS,
    Limits,
    ParamFile,
    axis_grade,
    evaluate,
    judge_axes,
    read_param_file,
)

__all__ = ["calibrate", "fit_firmware", "check_instance", "apply_firmware", "merge_logs",
           "format_report", "format_summary", "render_calibration_report", "MIN_SPAN_C", "MIN_SAMPLES",
           "InstanceResult"]

_FIT_KINDS = FIT_KINDS


@dataclass
class InstanceResult:
    """What happened to one instance."""

    name: str
    kind: str
    device_id: int
    status: str                        # "fitted" | "model only" | "skipped"
    reason: str | None = None
    fit: FirmwareFit | None = None
    summary: dict[str, Any] = field(default_factory=dict)


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


def _board_ids(log: FlightLog) -> list[tuple[str, int]]:
    return sorted((i.name, i.device_id) for i in log.instances if i.kind in _FIT_KINDS)


def _join_gap(t: np.ndarray) -> float:
    """Seconds between one log's last sample and the next log's first, joined: a gap (over
    :data:`~thermonet.core.recording.GAP_FACTOR` median steps) at which the dynamic inputs
    (a lag, a rate) restart, as after any pause, instead of running through the jump from
    one log's end to the next one's start; at least 1 s."""
    step = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    return max(1.0, 2.0 * GAP_FACTOR * step)


def merge_logs(logs: Sequence[FlightLog]) -> FlightLog:
    """Several logs of one board as one: the instances joined in the order given (time
    restarted after a gap, :func:`_join_gap`, past the previous log's end; each log's first
    sample recorded in ``starts``).  Refuses logs of another autopilot or
    board (different instances or device ids; or, where both logs hold the board's own id,
    ``FlightLog.board_id``, different ones), naming both logs' ids."""
    first = logs[0]
    for log in logs[1:]:
        if log.autopilot != first.autopilot:
            raise InputError(f"{log.path}: a {log.autopilot} log; {first.path} is "
                             f"{first.autopilot} (one board, one autopilot)")
        if _board_ids(log) != _board_ids(first):
            def ids(lg: FlightLog) -> str:
                return ", ".join(f"{n} {d}" for n, d in _board_ids(lg))
            raise InputError(f"{log.path}: not the same board as {first.path} (device ids "
                             f"{ids(log)} vs {ids(first)})")
        if log.board_id and first.board_id and log.board_id != first.board_id:
            raise InputError(f"{log.path}: not the same board as {first.path} (board id "
                             f"{log.board_id!r} vs {first.board_id!r}: two boards of one model, "
                             "with the same sensors' device ids); calibrate each board's logs "
                             "on their own")
    if len(logs) == 1:
        return first
    instances = []
    for inst in first.instances:
        parts = [next(i for i in lg.instances if i.name == inst.name
                      and i.device_id == inst.device_id) for lg in logs]
        times, t0 = [], 0.0
        for part in parts:
            t = np.asarray(part.time_s, dtype=np.float64)
            times.append(t - (t[0] if t.size else 0.0) + t0)
            t0 = (times[-1][-1] + _join_gap(t)) if t.size else t0
        temps = None if any(p.temperature_c is None for p in parts) else np.concatenate(
            [np.asarray(p.temperature_c) for p in parts])
        truth = None if any(p.truth is None for p in parts) else np.concatenate(
            [np.asarray(p.truth) for p in parts])
        notes = [f"{lg.path.name}: {n}" for lg, p in zip(logs, parts, strict=True)
                 for n in p.notes]
        untrusted = "; ".join(p.untrusted for p in parts if p.untrusted) or None
        unlagged = None if any(p.unlagged_c is None for p in parts) else np.concatenate(
            [np.asarray(p.unlagged_c) for p in parts])
        sizes = np.cumsum([p.n_samples for p in parts])[:-1]
        instances.append(SensorInstance(inst.kind, inst.instance, inst.device_id,
                                        np.concatenate(times), temps,
                                        np.concatenate([p.values for p in parts]),
                                        notes=notes, truth=truth,
                                        damaged=sum(p.damaged for p in parts),
                                        untrusted=untrusted, thermometer=inst.thermometer,
                                        lag_s=inst.lag_s, unlagged_c=unlagged,
                                        starts=tuple(int(k) for k in sizes)))
    return FlightLog(path=first.path, autopilot=first.autopilot, instances=instances,
                     params=dict(logs[-1].params),
                     notes=[f"{lg.path.name}: {n}" for lg in logs for n in lg.notes],
                     damage=[f"{lg.path.name}: {d}" for lg in logs for d in lg.damage],
                     board_id=next((lg.board_id for lg in logs if lg.board_id), None))


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
    merge_logs(logs)                              # same board? (refused before anything else)
    with profile_stage("magnetometers: lend thermometers, fit the lag"):
        logs, mags = _lend_and_lag(logs, mag_thermometers)   # a bad --mag-thermometer: refused
    check_target(out, overwrite, "calibration")   # before anything is fitted
    with staged_output(out, overwrite=overwrite, kind="calibration") as stage:
        doc = _calibrate_into(logs, stage.path, out, compare=compare, mags=mags,
                              helpers=helpers)
        stage.done()
    return doc


#: The EKF noise recommendation written beside the parameter file (never loaded by it).
EKF_FILE = "ekf-recommendation.txt"


def _ekf_text(autopilot: str, fitted: list[InstanceResult], params_name: str) -> str:
    """Per fitted gyro and accelerometer, the EKF bias-noise settings its firmware form's
    residual-drift band suggests (:func:`thermonet.exporting.autopilot.ekf_recommendation`);
    "" where no instance has a band."""
    lines: list[str] = []
    for r in fitted:
        band = (r.summary.get("compare") or {}).get("band")
        if not isinstance(band, dict):
            continue
        # only with a band: the exporter imports torch (about a second), which a
        # calibration without its comparison (--no-compare) never needs
        from ..exporting.autopilot import ekf_recommendation  # torch boundary

        doc = shipped_band({"band": band})
        rec = ekf_recommendation(doc, band.get("units", {}), autopilot) if doc and band else []
        if rec:
            lines += [f"# {r.name} (id {r.device_id})", *rec[1:]]
    if not lines:
        return ""
    return "\n".join([f"# thermonet {__version__}: EKF settings the residual drift after "
                      f"{params_name} suggests (not a parameter file: copy by hand)",
                      *lines]) + "\n"


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


def _params_text(log: FlightLog, fitted: list[InstanceResult], header: list[str]
                 ) -> tuple[str, str]:
    """The parameter file of ``fitted`` (text, file name)."""
    by_inst = {i.name: i for i in log.instances}
    if log.autopilot == "px4":
        fits: dict[str, list[FirmwareFit]] = {}
        if any(i.kind == "mag" for i in log.instances):
            fits["mag"] = []      # TC_M*: written (and the unused slots cleared) on a mag board
        for r in sorted(fitted, key=lambda r: (r.kind, by_inst[r.name].instance)):
            assert r.fit is not None
            fits.setdefault(r.kind, []).append(r.fit)
        return px4_calibration_text(fits, header=header), "px4.params"
    imus: dict[int, dict[str, FirmwareFit]] = {}
    for r in fitted:
        assert r.fit is not None
        imus.setdefault(by_inst[r.name].instance, {})[r.kind] = r.fit
    # the device ids each INS_TCAL<n> was fitted for (thermonet verify matches by them)
    ids = [f"device ids: INS_TCAL{k + 1} gyro {pair['gyro'].device_id if 'gyro' in pair else 0}"
           f" acc {pair['acc'].device_id if 'acc' in pair else 0}"
           for k, pair in sorted(imus.items())]
    return ardupilot_calibration_text(imus, header=header + ids), "ardupilot.parm"


#: One log: its samples in this many equal time blocks, every :data:`HELD_OUT_EVERY`-th
#: held out (blocks 3, 7, 11, 15, 19 of 20 counted from 1: a quarter of the log, never its
#: first or last block, so the fit is not extrapolated to them).
HELD_OUT_BLOCKS = 20
HELD_OUT_EVERY = 4
#: How far (°C) beyond the fitted range a later log of the board may run for calibrate to
#: call an axis fine (a new warm-up starts and levels off a few degrees apart: the
#: simulated board's by up to ±3 °C, more with the ambient).
BEYOND_RANGE_C = 4.0


def held_out_blocks(log: FlightLog) -> tuple[FlightLog, FlightLog]:
    """One log as (training, held-out): per instance, the samples of the held-out time
    blocks (:data:`HELD_OUT_BLOCKS`, :data:`HELD_OUT_EVERY`) and the rest."""
    train: list[SensorInstance] = []
    test: list[SensorInstance] = []
    for inst in log.instances:
        t = np.asarray(inst.time_s, dtype=np.float64)
        span = float(t[-1] - t[0]) if t.size else 0.0
        block = np.zeros(t.size, dtype=np.int64) if span <= 0 else np.minimum(
            ((t - t[0]) / span * HELD_OUT_BLOCKS).astype(np.int64), HELD_OUT_BLOCKS - 1)
        held = block % HELD_OUT_EVERY == HELD_OUT_EVERY // 2
        for part, keep in ((train, ~held), (test, held)):
            part.append(SensorInstance(
                inst.kind, inst.instance, inst.device_id, t[keep],
                None if inst.temperature_c is None else np.asarray(inst.temperature_c)[keep],
                np.asarray(inst.values)[keep], notes=list(inst.notes),
                truth=None if inst.truth is None else np.asarray(inst.truth)[keep],
                damaged=inst.damaged, untrusted=inst.untrusted, thermometer=inst.thermometer,
                lag_s=inst.lag_s,
                unlagged_c=None if inst.unlagged_c is None else inst.unlagged_c[keep]))
    return (FlightLog(log.path, log.autopilot, train, dict(log.params), board_id=log.board_id),
            FlightLog(log.path, log.autopilot, test, dict(log.params), board_id=log.board_id))


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
    text, name = _params_text(train, fitted, header=["held-out check"])
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
    _check_held_out(logs, log, results, stage)
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
    header += [f"{r.name} (id {r.device_id}): {r.summary['resolution']['line']}"
               for r in fitted if "resolution" in r.summary]
    text, fname = _params_text(log, fitted, header)
    param_path = stage / fname
    atomic_write_text(param_path, text)
    ekf = _ekf_text(log.autopilot, fitted, fname)
    if ekf:
        atomic_write_text(stage / EKF_FILE, ekf)
    checked = evaluate(read_param_file(param_path), log)
    for r in fitted:
        c = checked[r.name]
        r.summary["slot"] = c["slot"]
        r.summary["firmware_check"] = {k: c[k] for k in ("pp_raw", "pp_corrected", "cut")}
    _check_magnetometers(results, log)
    doc = _results_doc(logs, results, out / param_path.name)
    atomic_write_text(stage / "results.json", json.dumps(doc, indent=2, default=_json_default))
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


def _check_held_out(logs: list[FlightLog], log: FlightLog, results: list[InstanceResult],
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


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(type(obj).__name__)


def _results_doc(logs: list[FlightLog], results: list[InstanceResult], param_path: Path
                 ) -> dict[str, Any]:
    inst_doc: dict[str, Any] = {}
    for r in results:
        d: dict[str, Any] = {"kind": r.kind, "device_id": r.device_id, "status": r.status,
                             "reason": r.reason, **r.summary}
        if r.fit is not None:
            d["firmware"] = {"t_ref": r.fit.t_ref, "t_min": r.fit.t_min, "t_max": r.fit.t_max,
                             "coef": r.fit.coef.tolist()}
            if r.kind == "mag":
                d["firmware"].update(unit="uT", thermometer=r.fit.thermometer,
                                     lag_s=r.fit.lag_s)
        inst_doc[r.name] = d

    log = logs[0]
    return {"schema": 1, "thermonet_version": __version__, "log": str(log.path),
            "log_sha256": sha256_file(log.path),  # provenance: the very bytes calibrated
            "logs": [str(lg.path) for lg in logs],
            "logs_sha256": [sha256_file(lg.path) for lg in logs],
            "held_out_log": str(logs[-1].path) if len(logs) > 1 else None,
            "autopilot": log.autopilot, "board_id": log.board_id, "params_file": str(param_path),
            "log_notes": [n for lg in logs for n in lg.notes],
            "log_damage": [d for lg in logs for d in lg.damage],
            "instances": inst_doc}
