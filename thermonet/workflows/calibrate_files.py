"""What ``thermonet calibrate`` writes (:mod:`thermonet.workflows.calibrate`): each instance's
record (:class:`InstanceResult`), the parameter file's text (PX4 ``px4.params`` or ArduPilot
``ardupilot.parm``, :func:`params_text`), the EKF recommendation beside it (:data:`EKF_FILE`,
:func:`ekf_text`) and ``results.json``'s document (:func:`results_doc`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.outdir import sha256_file
from ..core.version import __version__
from ..data.firmware import (
    PX4_LETTER,
    FirmwareFit,
    Px4Slot,
    ardupilot_calibration_text,
    px4_active_slots,
    px4_calibration_text,
    px4_slot_plan,
    px4_vehicle_id,
)
from ..data.logs import FlightLog
from ..scoring.band import shipped_band

__all__ = ["InstanceResult", "params_text", "not_written", "EKF_FILE", "ekf_text", "json_default",
           "results_doc"]


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


def params_text(log: FlightLog, fitted: list[InstanceResult], header: list[str]
                 ) -> tuple[str, str]:
    """The parameter file of ``fitted`` (text, file name).  PX4: only the kinds with a fitted
    instance are written (a kind absent from the log, or all of whose instances were left
    out, is not: the board keeps its own, :func:`not_written` says why in the header); within
    a written kind an instance left out keeps the slot the board has for it
    (:func:`_px4_plans`); the log's ``MAV_SYS_ID`` is the Vehicle-Id
    (:func:`~thermonet.data.firmware.px4_vehicle_id`)."""
    by_inst = {i.name: i for i in log.instances}
    header = [*header, *not_written(log, fitted)]
    if log.autopilot == "px4":
        fits: dict[str, list[FirmwareFit]] = {}
        for r in sorted(fitted, key=lambda r: (r.kind, by_inst[r.name].instance)):
            assert r.fit is not None
            fits.setdefault(r.kind, []).append(r.fit)
        return px4_calibration_text(fits, header=header, fitted_kinds_only=True,
                                    plans=_px4_plans(log, fits),
                                    vehicle_id=px4_vehicle_id(log.params)), "px4.params"
    imus: dict[int, dict[str, FirmwareFit]] = {}
    for r in fitted:
        assert r.fit is not None
        imus.setdefault(by_inst[r.name].instance, {})[r.kind] = r.fit
    # with the device ids each INS_TCAL<n> was fitted for (thermonet verify matches by them)
    return ardupilot_calibration_text(imus, header=header), "ardupilot.parm"


_KIND_WORD = {"gyro": "gyro", "acc": "accelerometer", "baro": "barometer", "mag": "magnetometer"}


def _px4_plans(log: FlightLog, fits: dict[str, list[FirmwareFit]]) -> dict[str, list[Px4Slot]]:
    """Per written kind, its slots (:func:`~thermonet.data.firmware.px4_slot_plan`): an
    instance of the log left out of the file keeps the slot the board's active ``TC_<k><s>_ID``
    (the log's parameters) give it — not written — and the fitted ones take the board's slots
    for them; without such a slot the kind is rewritten whole, as before."""
    plans = {}
    for kind, kind_fits in fits.items():
        done = {f.device_id for f in kind_fits}
        keep = {i.device_id for i in log.instances if i.kind == kind and i.device_id not in done}
        plans[kind] = px4_slot_plan(kind_fits, px4_active_slots(log.params, kind), keep)
    return plans


def not_written(log: FlightLog, fitted: list[InstanceResult]) -> list[str]:
    """PX4: one line per sensor kind the parameter file does not write — ``TC_B*: not written
    (no barometer in the log): the board keeps its own``, or naming the kind's instances left
    out — as ``learn`` says it; loaded, the file leaves the board's calibration of that kind as
    it is (neither disabled nor cleared).  ArduPilot: ``[]`` (its file names what it leaves
    alone in its own comment lines)."""
    if log.autopilot != "px4":
        return []
    done = {r.kind for r in fitted}
    out = []
    for kind, letter in PX4_LETTER.items():
        names = sorted(i.name for i in log.instances if i.kind == kind)
        if kind in done or (kind == "mag" and not names):   # TC_M*: PX4 v1.15+ only
            continue
        why = (f"no {_KIND_WORD[kind]} in the log" if not names else
               f"{', '.join(names)} not in the file")
        out.append(f"TC_{letter}*: not written ({why}): the board keeps its own")
    fits: dict[str, list[FirmwareFit]] = {}
    for r in fitted:
        if r.fit is not None:
            fits.setdefault(r.kind, []).append(r.fit)
    name_of = {(i.kind, i.device_id): i.name for i in log.instances}
    out += [f"TC_{PX4_LETTER[kind]}{s}_*: not written ({name_of.get((kind, x), x)} not in the "
            "file; the board's slot for it): the board keeps its own"
            for kind, plan in _px4_plans(log, fits).items()
            for s, x in enumerate(plan) if isinstance(x, int)]
    return out


#: The EKF noise recommendation written beside the parameter file (never loaded by it).
EKF_FILE = "ekf-recommendation.txt"


def ekf_text(autopilot: str, fitted: list[InstanceResult], params_name: str) -> str:
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


def json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(type(obj).__name__)


def results_doc(logs: list[FlightLog], results: list[InstanceResult], param_path: Path
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
            # the vehicle's MAVLink system id (px4.params' Vehicle-Id; export's from instances/)
            "mav_sys_id": logs[-1].params.get("MAV_SYS_ID"),
            "log_notes": [n for lg in logs for n in lg.notes],
            "log_damage": [d for lg in logs for d in lg.damage],
            "instances": inst_doc}
