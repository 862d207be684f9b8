"""``thermonet calibrate LOG --out DIR``: the autopilot's thermal calibration, judged.

For every sensor instance of a PX4 ULog or ArduPilot DataFlash log:

1. **Checks.**  An instance is left out, with one line saying why, when it has
   no thermometer, fewer than :data:`MIN_SAMPLES` samples, a temperature span
   under :data:`MIN_SPAN_C` (PX4's ``SYS_CAL_TDEL`` defaults to 24 °C; 10 °C is
   the least a cubic can be trusted on), or a thermometer that reports whole
   degrees or coarser (:data:`MAX_STEP_C`: a cubic through a staircase, whose
   error inside each step is the quantisation; half-degree steps still pass).
   Magnetometers are listed only: neither autopilot has a thermal model for them.
2. **The firmware's own form on all the data** (heating and cooling; both
   autopilots' scripts use what the log has — the procedure only heats):

   * PX4 (``Tools/process_sensor_caldata.py``): per axis a cubic in
     T − TREF, TREF the centre of [TMIN, TMAX] (the logged range); baro an
     order-5 polynomial; the gyro fit keeps its constant (``X0``), accel and
     baro are fitted as output − median (the script subtracts the median: the
     constant is gravity or the weather).  Firmware
     (``TemperatureCompensation.cpp``, ``calc_thermal_offsets_3D/1D``):
     T clamped to [TMIN, TMAX], offset = Σ X_k (T − TREF)^k, corrected = raw −
     offset; rad/s, m/s², **Pa** (the current ``sensor_baro.pressure`` unit;
     the script's ×100 assumed hPa).
   * ArduPilot (``Tools/scripts/tempcal_IMU.py``): a cubic in T − 35 °C fitted
     with a constant, the constant dropped (``AP_InertialSensor_tempcal.cpp``
     has none), coefficients × 1e6; accel fitted as output − mean.
     Firmware: corrected = raw − P(T − 35) + P(T_cal − 35), T clamped.

   Plain least squares over every sample (PX4's script averages into
   temperature bins first; with a log that heats at a steady rate the two
   agree).
3. **Side by side with thermonet's families**, by calling
   :func:`thermonet.workflows.compare.run_compare` on the instance (the firmware form as
   the baseline family, a line, an RBF on [ΔT, ΔT²]); judged on held-out
   contiguous time blocks (``split: time-blocks``), never random samples.
   The firmware form is what the parameter file can carry; when a thermonet
   family does better, the report says by how much.  When the firmware form
   does not beat the raw output on the held-out blocks, the instance is left
   out of the parameter file (loading it would do harm).
4. **Files**: ``DIR/px4.params`` (QGroundControl, every TC_G/A/B slot) or
   ``DIR/ardupilot.parm`` (``INS_TCAL1..3_*``, ``INS_TCAL_OPTIONS`` not
   written), ``DIR/results.json``, ``DIR/report.txt`` and ``DIR/report.html``, per instance
   ``DIR/instances/<name>/`` (the comparison's results, plots, checkpoints).

After writing, the parameter file is read back and the autopilot's formula is
applied to the log (``firmware_check``): the peak-to-peak of 1 °C-binned
means before and after, per axis.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..core.errors import ThermonetError
from ..core.fileio import atomic_write_text
from ..data.firmware import (
    ARDUPILOT_TEMP_REFERENCE,
    PX4_SLOTS,
    FirmwareFit,
    ardupilot_calibration_text,
    ardupilot_correction,
    px4_calibration_text,
    px4_offsets_1d,
    px4_offsets_3d,
)
from ..data.logs import FlightLog, SensorInstance, read_log, temperature_step
from ..exporting.autopilot import read_ardupilot_params, read_px4_params
from ..scoring.metrics import binned_peak_to_peak
from ..scoring.verdicts import below

__all__ = ["calibrate", "fit_firmware", "check_instance", "apply_firmware",
           "MIN_SPAN_C", "MAX_STEP_C", "MIN_SAMPLES", "InstanceResult"]

#: Least temperature span (°C) an instance needs to be calibrated.
MIN_SPAN_C = 10.0
#: A thermometer reporting in steps this coarse (°C, whole degrees) or coarser is refused.
MAX_STEP_C = 1.0
#: A thermonet family is reported as better only when its validation score ratio is below
#: this fraction of the firmware form's (smaller differences are within the noise of a split).
BETTER_BY = 0.8
#: Least samples per instance.
MIN_SAMPLES = 200
_FIT_KINDS = ("gyro", "acc", "baro")


@dataclass
class InstanceResult:
    """What happened to one instance."""

    name: str
    kind: str
    device_id: int
    status: str                        # "fitted" | "skipped"
    reason: str | None = None
    fit: FirmwareFit | None = None
    summary: dict[str, Any] = field(default_factory=dict)


def check_instance(inst: SensorInstance) -> str | None:
    """Why ``inst`` cannot be calibrated (one phrase), or None when it can."""
    if inst.kind not in _FIT_KINDS:
        return f"{inst.kind}: neither autopilot compensates it for temperature (listed only)"
    if inst.temperature_c is None:
        return "no temperature: the sensor has no thermometer in the log"
    if inst.untrusted:   # too many of its samples damaged (thermonet.data.logs.base.screen_samples)
        return inst.untrusted
    if inst.n_samples < MIN_SAMPLES:
        return f"too few samples: {inst.n_samples} (need at least {MIN_SAMPLES})"
    if not np.any(inst.values != 0):
        return "every sample is exactly zero (a simulator or a dead sensor)"
    span = float(np.ptp(inst.temperature_c))
    if span < MIN_SPAN_C:
        return (f"temperature spans only {span:.2f} °C (need at least {MIN_SPAN_C:g} °C: "
                "cold-soak the board, then log while it warms)")
    step = temperature_step(inst.temperature_c)
    if step is not None and step >= 0.999 * MAX_STEP_C:
        return (f"its thermometer reports in {step:g} °C steps: a fit through that staircase "
                "is not a thermal model (use the sensor's raw temperature, if it has one)")
    return None


def _target(inst: SensorInstance, autopilot: str) -> np.ndarray:
    v = inst.values.astype(np.float64)
    if inst.kind == "gyro":
        return v
    centre = np.median(v, axis=0) if autopilot == "px4" else np.mean(v, axis=0)
    return v - centre


def fit_firmware(inst: SensorInstance, autopilot: str) -> FirmwareFit:
    """The autopilot's own polynomial fitted on every sample of ``inst`` (SI units)."""
    temp = np.asarray(inst.temperature_c, dtype=np.float64)
    t_min, t_max = float(temp.min()), float(temp.max())
    if autopilot == "px4":
        t_ref = 0.5 * (t_min + t_max)
        order = 5 if inst.kind == "baro" else 3
    else:
        t_ref, order = ARDUPILOT_TEMP_REFERENCE, 3
    x = temp - t_ref
    y = _target(inst, autopilot)
    coef = np.zeros((y.shape[1], order + 1))
    for j in range(y.shape[1]):
        coef[j] = np.polynomial.polynomial.polyfit(x, y[:, j], order)
    if autopilot == "ardupilot":
        coef[:, 0] = 0.0           # no constant term on board
    if not np.all(np.isfinite(coef)):
        raise ThermonetError(f"{inst.name}: the firmware fit is not finite")
    return FirmwareFit(kind=inst.kind, device_id=inst.device_id, t_ref=float(t_ref),
                       t_min=t_min, t_max=t_max, coef=coef)


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


def _compare(inst: SensorInstance, autopilot: str, out: Path, source: str,
             final: Path | None = None) -> dict[str, Any]:
    """Compare the families on ``inst`` into ``out`` (inside the staging directory); paths
    recorded in its results name ``final``, where ``out`` will be once the output is moved."""
    from ..core.outdir import relocate_json
    from ..training.config import CompareConfig, FamilyConfig, SplitConfig, TrackingConfig
    from .compare import run_compare

    fw = ("px4-poly5" if inst.kind == "baro" else "px4-cubic") if autopilot == "px4" \
        else "ardupilot-cubic"
    cfg = CompareConfig(
        split=SplitConfig(strategy="time-blocks", n_blocks=20),
        families=[
            FamilyConfig(family="poly", name=fw, inputs=["dT"],
                         params={"degree": 5 if fw == "px4-poly5" else 3}),
            FamilyConfig(family="linear", name="linear", inputs=["dT"]),
            FamilyConfig(family="rbf", name="rbf", inputs=["dT", "dT2"],
                         params={"n_centres": 8}),
        ],
        tracking=TrackingConfig(enabled=False), baseline=fw)
    ds = inst.to_dataset(source).validate(source)
    # built inside calibrate's own staging directory (a fresh one on every run)
    res = run_compare(cfg, out, overwrite=True, track=False, quiet=True, dataset=ds)
    if final is not None:
        relocate_json(out / "results.json", out, final)
    fams = res["families"]
    summary: dict[str, Any] = {"dir": str(final or out), "chosen": res.get("chosen"),
                               "chosen_reason": res.get("chosen_reason"), "firmware_family": fw,
                               "families": {}}
    for label, fr in fams.items():
        if fr.get("status") != "ok":
            summary["families"][label] = {"status": fr.get("status"), "reason": fr.get("reason")}
            continue
        axes = fr["axes"]
        summary["families"][label] = {
            "status": "ok", "val_score": fr["val_score"],
            "held_out_pp_raw": {a: m["pp_raw"] for a, m in axes.items()},
            "held_out_pp_comp": {a: m["pp_comp"] for a, m in axes.items()}}
    return summary


def _verdict(summary: dict[str, Any]) -> tuple[bool, str]:
    """Whether the firmware form helps on held-out data, and a one-line verdict."""
    fw = summary["firmware_family"]
    f = summary["families"].get(fw, {})
    if f.get("status") != "ok":
        return False, f"the firmware form could not be fitted ({f.get('reason')})"
    raw = np.array(list(f["held_out_pp_raw"].values()))
    comp = np.array(list(f["held_out_pp_comp"].values()))
    cut = raw / np.maximum(comp, 1e-300)
    line = (f"{fw} on held-out blocks: binned drift p-p cut {', '.join(f'{c:.1f}x' for c in cut)}"
            f" (val score ratio {f['val_score']:.3g})")
    chosen = summary.get("chosen")
    if chosen and chosen != fw:
        other = summary["families"][chosen]
        if other["val_score"] < BETTER_BY * f["val_score"]:
            line += (f"; thermonet's {chosen} does better on validation "
                     f"({other['val_score']:.3g}), which the parameter file cannot carry — "
                     f"export it as ONNX or C from {summary['dir']}")
        else:
            line += (f"; thermonet's best ({chosen}, {other['val_score']:.3g}) is within "
                     f"{100 * (1 - BETTER_BY):.0f} % of it: the firmware form is enough")
    # "helps" beyond the decision margin (thermonet.scoring.verdicts.DECISION_RTOL), never by rounding
    helps = below(f["val_score"], 1.0) and all(below(c, r) for c, r in zip(comp, raw, strict=True))
    return helps, line


def calibrate(log_path: str | Path, out_dir: str | Path, *, compare: bool = True,
              overwrite: bool = False) -> dict[str, Any]:
    """Calibrate every instance of a flight-controller log; write ``out_dir``; return results.

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
        A bad log (one line naming the file and what is missing).
    ThermonetError
        No instance can be calibrated (each reason listed), or ``out_dir`` is refused.
    """
    from ..core.outdir import check_target, staged_output

    log: FlightLog = read_log(log_path)
    out = Path(out_dir)
    check_target(out, overwrite, "calibration")   # before anything is fitted
    with staged_output(out, overwrite=overwrite, kind="calibration") as stage:
        doc = _calibrate_into(log, stage.path, out, compare=compare)
        stage.done()
    return doc


def _calibrate_into(log: FlightLog, stage: Path, out: Path, *, compare: bool
                    ) -> dict[str, Any]:
    """The calibration, written into ``stage``; recorded paths name ``out``."""
    from ..core.names import inside, path_components

    dirs = path_components(i.name for i in log.instances)
    ok_kinds = [i.kind for i in log.instances if check_instance(i) is None]
    per_kind = {k: ok_kinds.count(k) for k in _FIT_KINDS}
    if log.autopilot == "px4" and max(per_kind.values()) > PX4_SLOTS:
        raise ThermonetError(f"{log.path}: PX4 has {PX4_SLOTS} calibration slots per sensor "
                             f"kind; the log has {per_kind} calibratable instances")
    results: list[InstanceResult] = []
    for inst in log.instances:
        why = check_instance(inst)
        r = InstanceResult(inst.name, inst.kind, inst.device_id, "skipped", why)
        r.summary = {"n_samples": inst.n_samples, "notes": list(inst.notes),
                     "temperature_step_c": temperature_step(inst.temperature_c)}
        if inst.temperature_c is not None and inst.n_samples:
            r.summary["temperature_c"] = [float(inst.temperature_c.min()),
                                          float(inst.temperature_c.max())]
        if why is None and log.autopilot == "ardupilot" and inst.kind == "baro":
            why = r.reason = "ArduPilot has no barometer temperature calibration parameters"
        if why is None:
            r.fit = fit_firmware(inst, log.autopilot)
            r.status = "fitted"
            if compare:
                try:
                    cmp = _compare(inst, log.autopilot,
                                   inside(stage, "instances", dirs[inst.name]), str(log.path),
                                   final=out / "instances" / dirs[inst.name])
                except ThermonetError as err:   # this instance cannot be judged: reported, skipped
                    r.status, r.reason, r.fit = "skipped", f"comparison failed: {err}", None
                    results.append(r)
                    continue
                ok, line = _verdict(cmp)
                r.summary["compare"] = cmp
                r.summary["verdict"] = line
                if not ok:
                    r.status, r.reason = "skipped", ("the firmware form does not reduce the "
                                                     "drift on held-out data: " + line)
                    r.fit = None
        results.append(r)
    fitted = [r for r in results if r.status == "fitted"]
    if not fitted:
        reasons = "; ".join(f"{r.name}: {r.reason}" for r in results)
        raise ThermonetError(f"{log.path}: no sensor instance can be calibrated ({reasons})")
    header = [f"thermonet {__version__} thermal calibration of {log.path.name}",
              "firmware form fitted on all samples (heating and cooling); see report.txt"]
    by_inst = {i.name: i for i in log.instances}
    slots: dict[str, int] = {}
    if log.autopilot == "px4":
        fits: dict[str, list[FirmwareFit]] = {}
        for r in sorted(fitted, key=lambda r: (r.kind, by_inst[r.name].instance)):
            assert r.fit is not None
            slots[r.name] = len(fits.setdefault(r.kind, []))
            fits[r.kind].append(r.fit)
        text = px4_calibration_text(fits, header=header)
        param_path = stage / "px4.params"
    else:
        imus: dict[int, dict[str, FirmwareFit]] = {}
        for r in fitted:
            assert r.fit is not None
            idx = by_inst[r.name].instance
            imus.setdefault(idx, {})[r.kind] = r.fit
            slots[r.name] = idx
        text = ardupilot_calibration_text(imus, header=header)
        param_path = stage / "ardupilot.parm"
    atomic_write_text(param_path, text)
    params = (read_px4_params(param_path) if log.autopilot == "px4"
              else read_ardupilot_params(param_path))
    for r in results:
        if r.status != "fitted":
            continue
        inst = by_inst[r.name]
        corr = apply_firmware(params, log.autopilot, inst, slots[r.name])
        y = _target(inst, log.autopilot)
        temp = np.asarray(inst.temperature_c)
        before = [binned_peak_to_peak(temp, y[:, j]) for j in range(y.shape[1])]
        after = [binned_peak_to_peak(temp, y[:, j] - corr[:, j]) for j in range(y.shape[1])]
        r.summary["slot"] = slots[r.name]
        r.summary["firmware_check"] = {"pp_raw": before, "pp_corrected": after,
                                       "cut": [b / a if a > 0 else math.inf
                                               for b, a in zip(before, after, strict=True)]}
    doc = _results_doc(log, results, out / param_path.name)
    atomic_write_text(stage / "results.json", json.dumps(doc, indent=2, default=_json_default))
    atomic_write_text(stage / "report.txt", format_report(doc))
    atomic_write_text(stage / "report.html", render_calibration_report(doc, out, staged=stage))
    return doc


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(type(obj).__name__)


def _results_doc(log: FlightLog, results: list[InstanceResult], param_path: Path
                 ) -> dict[str, Any]:
    inst_doc: dict[str, Any] = {}
    for r in results:
        d: dict[str, Any] = {"kind": r.kind, "device_id": r.device_id, "status": r.status,
                             "reason": r.reason, **r.summary}
        if r.fit is not None:
            d["firmware"] = {"t_ref": r.fit.t_ref, "t_min": r.fit.t_min, "t_max": r.fit.t_max,
                             "coef": r.fit.coef.tolist()}
        inst_doc[r.name] = d
    from ..core.outdir import sha256_file

    return {"schema": 1, "thermonet_version": __version__, "log": str(log.path),
            "log_sha256": sha256_file(log.path),  # provenance: the very bytes calibrated
            "autopilot": log.autopilot, "params_file": str(param_path),
            "log_notes": list(log.notes), "log_damage": list(log.damage),
            "instances": inst_doc}


def render_calibration_report(doc: dict[str, Any], out: Path, *, staged: Path | None = None
                              ) -> str:
    """``DIR/report.html``: the calibration page a person opens first.

    One self-contained page (inline CSS, no script): a table of every sensor
    instance — fitted with the cut of the autopilot's own correction read back
    from the written file, or left out with its reason — colour-coded like the
    comparison report, the full text report, and a link to each instance's own
    comparison report (``instances/<name>/report.html``, itself self-contained,
    with the verdict table, warnings and plots).  Every string is HTML-escaped.
    ``staged``: where ``out``'s files are while it is being built (links are checked there).
    """
    import html

    from ..reporting.report import _CSS, VERDICT_COLOURS

    rows = []
    for name, d in doc["instances"].items():
        span = d.get("temperature_c")
        where = f"{span[0]:.1f} … {span[1]:.1f} °C" if span else "no temperature"
        if d["status"] == "fitted":
            cuts = ", ".join(f"{c:.1f}×" for c in d["firmware_check"]["cut"])
            what = f"fitted, slot {d['slot']}; binned drift cut {cuts}"
            colour = VERDICT_COLOURS["better"]
        else:
            what = f"left out: {d['reason']}"
            colour = VERDICT_COLOURS["worse"]
        cmp = d.get("compare") or {}
        sub = Path(str(cmp.get("dir", ""))) / "report.html" if cmp.get("dir") else None
        link = ""
        rel = None if sub is None else sub.relative_to(out) if sub.is_relative_to(out) else sub
        found = rel if rel is None or staged is None or rel.is_absolute() else staged / rel
        if rel is not None and found is not None and found.is_file():
            link = f'<a href="{html.escape(str(rel))}">comparison</a>'
        rows.append(f"<tr><td>{html.escape(name)}</td><td>{html.escape(str(d['kind']))}</td>"
                    f"<td>{html.escape(str(d['device_id']))}</td><td>{d['n_samples']}</td>"
                    f"<td>{html.escape(where)}</td><td style=\"background:{colour}\">"
                    f"{html.escape(what)}</td><td>{link}</td></tr>")
    return ("<!DOCTYPE html><html><head><meta charset=\"utf-8\">"
            f"<title>thermonet calibrate: {html.escape(Path(doc['log']).name)}</title>"
            f"<style>{_CSS}</style></head><body>"
            f"<h1>Thermal calibration of {html.escape(Path(doc['log']).name)} "
            f"({html.escape(doc['autopilot'])})</h1>"
            f"<p class=\"chosen\">Parameter file: {html.escape(Path(doc['params_file']).name)}"
            " — load it only on the board whose device ids are listed below.</p>"
            "<h2>Sensor instances</h2><table><tr><th>instance</th><th>kind</th>"
            "<th>device id</th><th>samples</th><th>temperature</th><th>result</th>"
            "<th>details</th></tr>" + "".join(rows) + "</table>"
            f"<h2>Report</h2><pre>{html.escape(format_report(doc))}</pre></body></html>\n")


def format_report(doc: dict[str, Any]) -> str:
    """One block per instance: fitted (with verdict and check) or left out (with the reason)."""
    lines = [f"thermonet calibrate: {doc['log']} ({doc['autopilot']})",
             *([f"log sha256: {doc['log_sha256']}"] if doc.get("log_sha256") else []),
             f"parameter file: {doc['params_file']}", ""]
    # what the log reader found damaged and where, and the log's own notes (gaps)
    lines += [f"log: {n}" for n in doc.get("log_damage", []) + doc.get("log_notes", [])]
    if doc.get("log_damage") or doc.get("log_notes"):
        lines.append("")
    for name, d in doc["instances"].items():
        span = d.get("temperature_c")
        where = f"{span[0]:.1f}..{span[1]:.1f} °C" if span else "no temperature"
        head = f"{name:<6} id {d['device_id']:<9} {d['n_samples']:>7} samples, {where}"
        if d["status"] != "fitted":
            lines.append(f"{head}: LEFT OUT — {d['reason']}")
        else:
            chk = d["firmware_check"]
            cuts = ", ".join(f"{c:.1f}x" for c in chk["cut"])
            lines.append(f"{head}: fitted, slot {d['slot']}; on the log the autopilot's "
                         f"correction cuts the binned drift p-p {cuts}")
            if d.get("verdict"):
                lines.append(f"       {d['verdict']}")
        for note in d.get("notes", []):
            lines.append(f"       note: {note}")
    lines += ["", "Load the parameter file only for a board whose sensors are the device ids "
              "above; reboot after loading; re-run the ordinary gyro/accel calibration."]
    return "\n".join(lines) + "\n"
