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
from ..data.firmware import FirmwareFit, ardupilot_calibration_text, px4_calibration_text
from ..data.logs import FlightLog
from ..scoring.band import shipped_band

__all__ = ["InstanceResult", "params_text", "EKF_FILE", "ekf_text", "json_default",
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
    # with the device ids each INS_TCAL<n> was fitted for (thermonet verify matches by them)
    return ardupilot_calibration_text(imus, header=header), "ardupilot.parm"


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
            "log_notes": [n for lg in logs for n in lg.notes],
            "log_damage": [d for lg in logs for d in lg.damage],
            "instances": inst_doc}
