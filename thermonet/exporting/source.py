"""``thermonet export SOURCE``: find the model, write the requested form, log it to its run.

SOURCE is one of

* a ``compare`` output directory — its chosen family, or ``--family NAME``;
  a comparison that chose none ("do no harm") refuses unless a family is named; one that
  chose a model per axis (``"chosen": "per-axis"``) gives its composite checkpoint
  ``models/per-axis.pt`` (:class:`~thermonet.models.composite.AxisModels`), recorded in
  ``results.json`` as the family ``"per-axis"`` (``checkpoint``, ``checkpoint_sha256``,
  ``params.axes``: {axis: label or null}) with its candidates in
  ``selection.per_axis.candidates`` (schema 3; a schema-2 file holds the same there);
* a checkpoint file (``models/<family>.pt``);
* an MLflow run id of a family's nested run (its ``model/<family>.pt``
  artifact is downloaded from the tracking store).

The ONNX file is also logged to the training run (as an artifact and as an
MLflow ONNX model) when the checkpoint names one and the store is reachable —
the store named by ``--tracking-uri``, ``MLFLOW_TRACKING_URI`` or the working
directory's ``mlflow.db``, never a URI read from the checkpoint (a local store that does
not exist is said in one warning line, never created).  Every argument is checked, and the
source found, before torch or MLflow is imported (:func:`check_export_request`; MLflow only
for a run id, or to log the file to a store that exists).  A compare
directory's checkpoint is verified against the SHA-256 in its
``results.json`` before it is loaded.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core.errors import ExportError, InputError, first_line
from ..core.fileio import check_out_file, not_a_file, refuse_overwriting_inputs
from ..core.names import AXIS, LABEL, check_name
from ..core.outdir import sha256_file
from ..models.registry import PER_AXIS
from ..tracking import (
    check_store,
    default_tracking_uri,
    global_tracking_uri,
    missing_store,
    store_problem,
)
from . import MAX_DEVICE_ID, ExportFormat, ExportRequest, get_format, is_device_id
from .autopilot_read import recorded_defaults, recorded_sensor

if TYPE_CHECKING:
    from ..models.composite import DriftModels
    from . import ExportRequest

__all__ = ["resolve_checkpoint", "export_source", "check_export_request", "check_prefix",
           "check_out_file",
           "write_onnx", "write_c", "write_px4_params", "write_ardupilot_params"]

_RUN_ID = re.compile(r"[0-9a-f]{32}")


def _from_compare_dir(path: Path, family: str | None) -> Path:
    """The checkpoint of a family of a compare directory, verified against ``results.json``
    (or the per-axis composite's, :func:`_per_axis_checkpoint`).

    The checkpoint is always ``<dir>/models/<family>.pt`` (the path recorded
    in ``results.json`` is informational: a file does not choose what else is
    read), and its SHA-256 must equal ``checkpoint_sha256`` recorded when the
    comparison was written.
    """
    results_file = path / "results.json"
    if not results_file.is_file():
        raise InputError(f"{path}: not a compare output directory (no results.json)")
    try:
        results = json.loads(results_file.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise InputError(f"{results_file}: not valid JSON ({err.msg}, line {err.lineno})") from None
    except UnicodeDecodeError as err:
        raise InputError(f"{results_file}: not UTF-8 text (byte {err.start})") from None
    if isinstance(results, dict) and family in (None, PER_AXIS) and (
            family or results.get("chosen")) == PER_AXIS:
        return _per_axis_checkpoint(path, results_file, results)
    if isinstance(results, dict) and results.get("kind") == "fleet":
        raise InputError(f"{path}: a fleet directory, not one comparison: export every unit "
                         f"with --all-units (--out a directory), or one unit from "
                         f"{path / 'units'}/<device id>")
    fams = results.get("families") if isinstance(results, dict) else None
    if isinstance(results, dict) and fams is None and isinstance(results.get("instances"), dict):
        raise InputError(_calibration_dir(path, results))
    if not isinstance(fams, dict) or not all(isinstance(v, dict) for v in fams.values()):
        raise InputError(f"{results_file}: key 'families': not a mapping of family results")
    listed = ", ".join(str(k)[:64] for k in fams)
    name = family or results.get("chosen")
    if name is None:
        raise ExportError(f"{results_file}: the comparison chose no family "
                          f"({str(results.get('chosen_reason', 'do no harm'))[:200]}); pass "
                          f"--family NAME to export one anyway (families: {listed})")
    check_name(name, LABEL, f"{results_file}: key 'chosen'" if family is None else "--family")
    if name not in fams:
        raise InputError(f"{results_file}: no family '{name}' (families: {listed})")
    if not fams[name].get("checkpoint"):
        raise ExportError(f"{results_file}: family '{name}' has no checkpoint "
                          f"({str(fams[name].get('reason') or 'not fitted')[:200]})")
    if family is not None:
        _warn_held_back(results, name, results_file)
    return _verified(path / "models" / f"{name}.pt", fams[name].get("checkpoint_sha256"),
                     results_file, f"family '{name}'", "written by an older thermonet? re-run "
                     "compare")


def _warn_held_back(results: dict[str, Any], name: str, results_file: Path) -> None:
    """One warning where ``--family`` names a family the comparison's gate held back (it
    could not be judged on these data: one direction or one rate of temperature change):
    its file is written as asked, but its joint guard (the ``out_of_range`` flag) was set
    wherever the training never went, and nothing showed it is better than the cubic."""
    sel = results.get("selection")
    held = sel.get("held_back") if isinstance(sel, dict) else None
    by = held.get("by_candidate") if isinstance(held, dict) else None
    why = by.get(name) if isinstance(by, dict) else None
    if not isinstance(why, str) or not why:
        return
    text = "".join(ch if ch.isprintable() else "?" for ch in why)[:300]
    warnings.warn(f"{results_file}: family '{name}' was held back by the comparison ({text}); "
                  "exported as asked, but nothing showed it beats the baseline there, and its "
                  "out_of_range flag is set wherever its dynamic inputs leave what training "
                  "held", UserWarning, stacklevel=2)


def _calibration_dir(path: Path, results: dict[str, Any]) -> str:
    """Why a ``calibrate`` / ``learn`` directory is not one comparison, and what to export:
    its parameter file as it is, or one instance's comparison with the firmware family."""
    what = "a learn" if results.get("kind") == "learn" else "a calibrate"
    params = results.get("params_file")
    name = Path(str(params)).name if params else None
    use = f"load its parameter file {path / name} as it is" if name else ""
    insts = sorted(p.name for p in (path / "instances").glob("*") if p.is_dir())[:12]
    family = "ardupilot-cubic" if results.get("autopilot") == "ardupilot" else "px4-cubic"
    head = f"{path}: {what} directory (one parameter file for every sensor), not one comparison"
    if not insts:
        return (f"{head}: {use + '; ' if use else ''}it holds no per-instance comparison to "
                "export (run it without --no-compare for instances/<name>/)")
    return (f"{head}: {use + ', or ' if use else ''}export one instance's comparison: "
            f"thermonet export {path / 'instances' / insts[0]} --family {family} (instances: "
            f"{', '.join(insts)})")


def _verified(p: Path, recorded: Any, results_file: Path, what: str, hint: str) -> Path:
    """``p`` when it exists and its SHA-256 is the one ``results_file`` recorded for ``what``
    (a family, the per-axis model): a file does not choose what else is read."""
    if not p.is_file():
        raise InputError(f"{p}: checkpoint listed in {results_file} is missing")
    if not isinstance(recorded, str) or not recorded:
        raise ExportError(f"{results_file}: {what} records no checkpoint_sha256, so {p} cannot "
                          f"be verified ({hint})")
    if sha256_file(p) != recorded:
        raise ExportError(f"{p}: content does not match the SHA-256 in {results_file} (replaced "
                          "or modified after the comparison); refusing to export it")
    return p


def _per_axis_checkpoint(path: Path, results_file: Path, results: dict) -> Path:
    """The per-axis composite of a compare directory (``models/per-axis.pt``), verified
    against its family record in ``results.json`` (module docstring) as a family's
    checkpoint is: the path is fixed, the SHA-256 must match the recorded one."""
    fams = results.get("families")
    block = fams.get(PER_AXIS) if isinstance(fams, dict) else None
    if not isinstance(block, dict):
        raise InputError(f"{results_file}: 'chosen' is '{PER_AXIS}' but there is no "
                         f"'families.{PER_AXIS}' mapping (checkpoint, checkpoint_sha256, "
                         "params.axes)")
    sel = results.get("selection")
    per_axis = sel.get("per_axis") if isinstance(sel, dict) else None
    params = block.get("params")
    axes = params.get("axes") if isinstance(params, dict) else None
    candidates = per_axis.get("candidates") if isinstance(per_axis, dict) else None
    if not isinstance(candidates, list) or not isinstance(axes, dict):
        raise InputError(f"{results_file}: keys 'families.{PER_AXIS}.params.axes' {{axis: "
                         "label or null}} and 'selection.per_axis.candidates' [labels] expected")
    for c in candidates:
        check_name(c, LABEL, f"{results_file}: key 'selection.per_axis.candidates'")
    for axis, label in axes.items():
        check_name(axis, AXIS, f"{results_file}: key 'families.{PER_AXIS}.params.axes'")
        if label is not None and label not in candidates:
            raise InputError(f"{results_file}: key 'families.{PER_AXIS}.params.axes': axis "
                             f"'{axis}' names '{str(label)[:64]}', not a candidate "
                             f"({', '.join(candidates)})")
    if not block.get("checkpoint"):
        raise ExportError(f"{results_file}: the per-axis model has no checkpoint")
    return _verified(path / "models" / f"{PER_AXIS}.pt", block.get("checkpoint_sha256"),
                     results_file, "the per-axis model", "re-run compare")


def _from_run_id(run_id: str, tracking_uri: str | None, workdir: Path) -> Path:
    uri = tracking_uri or os.environ.get("MLFLOW_TRACKING_URI") or default_tracking_uri()
    why = store_problem(uri)
    if why is None and missing_store(uri) is not None:
        why = f"no tracking store there ({missing_store(uri)} does not exist)"
    if why is not None:
        raise InputError(f"MLflow run '{run_id}' at {uri}: {why}")
    import mlflow  # lazy: ~2 s, and only a run id needs it

    client = mlflow.MlflowClient(tracking_uri=uri)
    # MLflow resolves a run's logged model ('model') through the global tracking URI: a store
    # used earlier in this process would otherwise answer "Logged model ... not found"
    with global_tracking_uri(uri):
        try:
            arts = [a.path for a in client.list_artifacts(run_id, "model")]
        except Exception as err:  # noqa: BLE001 - MLflow raises its own exception types
            raise InputError(f"MLflow run '{run_id}' at {uri}: {err}".splitlines()[0]) from None
        pts = [a for a in arts if a.endswith(".pt")]
        if not pts:
            raise InputError(f"MLflow run '{run_id}' at {uri}: no model/*.pt checkpoint "
                             "artifact (give the run id of a family's nested run)")
        local = mlflow.artifacts.download_artifacts(run_id=run_id, artifact_path=pts[0],
                                                    dst_path=str(workdir), tracking_uri=uri)
    return Path(local)


def resolve_checkpoint(source: str, *, family: str | None = None,
                       tracking_uri: str | None = None, workdir: Path | None = None) -> Path:
    """The checkpoint file that SOURCE designates (downloaded when SOURCE is a run id)."""
    p = Path(source)
    if p.is_dir():
        return _from_compare_dir(p, family)
    if p.is_file():
        kind = next((k for k, sx in NOT_CHECKPOINTS.items() if p.suffix.lower() in sx), None)
        if kind:   # torch's own words were "Unsupported operand 80"
            raise InputError(f"{source}: {kind}, not a compare directory, checkpoint (.pt) or "
                             "MLflow run id" + (": run 'thermonet compare' on it first"
                                                if kind == "a data file" else ""))
        return p
    if p.exists():  # a FIFO, a device: say what it is (and never open a FIFO)
        raise InputError(f"{source}: {not_a_file(p, 'checkpoint file')}")
    if _RUN_ID.fullmatch(source):
        return _from_run_id(source, tracking_uri, workdir or Path(tempfile.mkdtemp()))
    raise InputError(f"{source}: no such compare directory, checkpoint file or MLflow run id")


#: Files an export cannot start from, by suffix: what each is instead.
NOT_CHECKPOINTS = {"a data file": (".parquet", ".pq", ".csv", ".tsv", ".txt", ".ulg", ".bin"),
                   "an exported model": (".onnx", ".h", ".params", ".parm"),
                   "a config or results file": (".yaml", ".yml", ".json")}


_C_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def check_prefix(fmt: str, prefix: str | None) -> None:
    """``--prefix``: for ``c`` only (refused for another format, not ignored), a C
    identifier (what every symbol and the include guard start with)."""
    if prefix is None:
        return
    if fmt != "c":
        raise InputError(f"--prefix applies to --format c only (the C symbols' prefix); "
                         f"{fmt} has no symbols")
    if not isinstance(prefix, str) or _C_IDENT.fullmatch(prefix) is None:
        raise InputError(f"--prefix {str(prefix)[:64]!r} is not a C identifier (letters, "
                         "digits and '_', not starting with a digit), e.g. imu0")


#: The calibration slot ``--instance`` names, by format: PX4's slot, ArduPilot's IMU number.
_INSTANCES = {"px4-params": (0, 3, "PX4 calibration instance"),
              "ardupilot-params": (1, 3, "ArduPilot IMU number")}


def check_export_request(*, fmt: str, out: str | Path, family: str | None = None,
                         tracking_uri: str | None = None, device_id: int | None = None,
                         instance: int | None = None, prefix: str | None = None
                         ) -> ExportFormat:
    """Every argument of an export checked, in one line naming it, before the source is read
    and before torch or MLflow is imported; returns the format.

    The format (a name in :data:`FORMATS`), ``--out`` (:func:`check_out_file`), ``--family``
    (a family name), ``--tracking-uri`` (a store :func:`thermonet.tracking.check_store`
    accepts), ``--device-id`` (1..:data:`~thermonet.exporting.MAX_DEVICE_ID`; required for
    ``px4-params``), ``--instance`` (PX4 0..3, ArduPilot 1..3) and ``--prefix`` (``c``
    only: a C identifier).
    """
    export_format = get_format(fmt)
    check_prefix(fmt, prefix)
    check_out_file(out)
    if family is not None:
        check_name(family, LABEL, "--family")
    if tracking_uri is not None:
        check_store(tracking_uri)   # the line compare and fleet say
    if device_id is not None and not is_device_id(device_id):
        raise InputError(f"--device-id must be the sensor's positive device id, got "
                         f"{device_id}: PX4 and ArduPilot device ids are 32-bit, "
                         f"1..{MAX_DEVICE_ID}")
    if instance is not None and fmt in _INSTANCES:
        lo, hi, what = _INSTANCES[fmt]
        if isinstance(instance, bool) or not lo <= int(instance) <= hi:
            raise InputError(f"--instance: {what} must be {lo}..{hi}, got {instance}")
    if device_id is None and fmt == "px4-params":
        raise InputError("--device-id is required with --format px4-params: PX4 applies the "
                         "TC_* parameters only to the sensor whose device id equals TC_*_ID "
                         "(read it with 'listener sensor_gyro' / 'listener sensor_accel')")
    return export_format


def export_source(source: str, *, fmt: str, out: str | Path, family: str | None = None,
                  tracking_uri: str | None = None, device_id: int | None = None,
                  instance: int | None = None, prefix: str | None = None) -> Path:
    """Export the model SOURCE designates as ``fmt`` to ``out``; return the written path.

    ``fmt`` is a name in :data:`thermonet.exporting.FORMATS`.  ``device_id``
    (PX4's ``TC_*_ID``) and ``instance`` (PX4 slot 0–3, default 0; ArduPilot
    IMU 1–3, default 1) apply to the autopilot formats — from an instance directory of
    ``calibrate`` / ``learn`` (``DIR/instances/gyro1``) they default to the sensor it records,
    and one that contradicts it is refused
    (:func:`~thermonet.exporting.autopilot_read.recorded_defaults`); ``prefix`` (default
    ``thermonet``) to ``c``: every symbol's prefix, one per header in a program.
    """
    # every argument, then the source, before anything heavy is imported: torch only to load
    # the model, MLflow only to fetch a run id's checkpoint (check_export_request); an
    # instance directory's own sensor and slot by default, another refused
    device_id, instance = recorded_defaults(source, fmt, device_id, instance)
    export_format = check_export_request(fmt=fmt, out=out, family=family,
                                         tracking_uri=tracking_uri, device_id=device_id,
                                         instance=instance, prefix=prefix)
    with tempfile.TemporaryDirectory() as tmp:
        ckpt = resolve_checkpoint(source, family=family, tracking_uri=tracking_uri,
                                  workdir=Path(tmp))
        # never written over what it reads: the checkpoint, the compare directory's results
        refuse_overwriting_inputs(out, [ckpt, source, Path(source) / "results.json"])
        from ..training.sensor_checkpoint import load_shipped  # torch boundary

        model, meta = load_shipped(ckpt)     # any model kind, by its checkpoint's format
        named = str(ckpt) if Path(source).exists() else f"MLflow run '{source}' ({ckpt.name})"
    return export_format.write(model, out, ExportRequest(
        meta=meta, device_id=device_id, instance=instance, tracking_uri=tracking_uri,
        source=named, prefix=prefix))


# ----------------------------------------------------- the built-in exporters
def write_onnx(model: DriftModels, out: Path, request: ExportRequest) -> Path:
    """``onnx``: the graph with the checkpoint's metadata, logged to its training run."""
    path = _onnx_with_metadata(model, out, request)
    run_id = request.extra.get("mlflow_run_id")
    if run_id:
        _log_to_run(path, run_id, request.tracking_uri, request.meta)
    return path


def onnx_of_checkpoint(ckpt: str | os.PathLike[str], out: str | os.PathLike[str]) -> Path:
    """The ONNX graph ``thermonet export CKPT --format onnx`` writes (metadata included),
    without logging it anywhere: what ``compare`` logs as its run's model."""
    from ..training.checkpoint import load_checkpoint  # torch boundary

    model, meta = load_checkpoint(ckpt)
    return _onnx_with_metadata(model, Path(out), ExportRequest(meta=meta, source=str(ckpt)))


def _onnx_with_metadata(model: DriftModels, out: Path, request: ExportRequest) -> Path:
    from ..scoring.band import shipped_band  # lazy: importing it loads numpy
    from .onnx_export import export_onnx  # torch boundary (pyproject.toml): loads torch

    extra, meta = request.extra, request.meta
    prov = extra.get("provenance")
    source = prov.get("data") if isinstance(prov, dict) else None
    band = shipped_band(extra)
    path = export_onnx(model, out, metadata={
        # the residual-drift band's tables, evaluated by the runtime (Compensator.band)
        **({"band": band} if band is not None else {}),
        "device_id": extra.get("device_id", ""),
        "training_run_id": extra.get("mlflow_run_id", ""),
        "validation_metrics": {"val_score": extra.get("val_score"),
                               "test": extra.get("test_metrics", {})},
        "data_hash": extra.get("data_hash", ""),
        "output_units": request.output_units,
        "signal_units": extra.get("signal_units", {}) or {},
        # provenance: the verified digest of the checkpoint it came from, and its data's
        "checkpoint_sha256": str(meta.get("sha256") or ""),
        "data_source": source if isinstance(source, dict) else {},
    })
    return path


def write_c(model: DriftModels, out: Path, request: ExportRequest) -> Path:
    """``c``: the C99 header."""
    from ..scoring.band import shipped_band  # lazy: importing it loads numpy
    from .c_export import export_c_header  # torch boundary (pyproject.toml): loads torch

    return export_c_header(model, out, band=shipped_band(request.extra),
                           units=request.output_units, prefix=request.prefix or "thermonet")


def write_px4_params(model: DriftModels, out: Path, request: ExportRequest) -> Path:
    """``px4-params``: PX4's TC_* parameter file (slot ``request.instance``, default 0)."""
    from ..scoring.band import shipped_band  # lazy: importing it loads numpy
    from .autopilot import (  # torch boundary (pyproject.toml): loads torch
        check_offset_outputs,
        export_px4_params,
    )

    check_offset_outputs(model.outputs, "px4-params", request.source)
    rec = recorded_sensor(request.source) if request.source else None   # the vehicle's id
    return export_px4_params(model, out, output_units=request.output_units,
                             band=shipped_band(request.extra),
                             device_id=request.device_id,
                             instance=0 if request.instance is None else request.instance,
                             mav_sys_id=rec["mav_sys_id"] if rec else None)


def write_ardupilot_params(model: DriftModels, out: Path, request: ExportRequest) -> Path:
    """``ardupilot-params``: ArduPilot's INS_TCAL* file (IMU ``request.instance``, default 1)."""
    from ..scoring.band import shipped_band  # lazy: importing it loads numpy
    from .autopilot import (  # torch boundary (pyproject.toml): loads torch
        check_offset_outputs,
        export_ardupilot_params,
    )

    check_offset_outputs(model.outputs, "ardupilot-params", request.source)
    return export_ardupilot_params(model, out, output_units=request.output_units,
                                   band=shipped_band(request.extra),
                                   imu=1 if request.instance is None else request.instance)


def _log_to_run(path: Path, run_id: str, tracking_uri: str | None, meta: dict) -> None:
    """Log the ONNX file to its training run; a store that is gone is reported, not fatal.

    The store is the one the user names (``--tracking-uri``, else
    ``MLFLOW_TRACKING_URI``, else ``sqlite:///mlflow.db`` in the working
    directory), never the URI recorded in the checkpoint's config.
    """
    import logging

    from .onnx_mlflow import log_onnx_to_mlflow  # lazy: only where a file is logged to MLflow

    # Only where the user says: the flag, MLFLOW_TRACKING_URI, or the working directory's store.
    # Never a URI stored in the checkpoint: a file must not choose where thermonet connects.
    uri = tracking_uri or os.environ.get("MLFLOW_TRACKING_URI") or default_tracking_uri()
    if missing_store(uri) is not None:   # said without importing MLflow or creating a store
        logging.getLogger(__name__).warning(
            "wrote %s; not logged to MLflow run %s: no tracking store at %s (give "
            "--tracking-uri)", path, run_id, uri)
        return
    try:
        check_store(uri)
        log_onnx_to_mlflow(path, run_id, uri)
    except Exception as err:  # noqa: BLE001 - the file is written; tracking is best effort here
        logging.getLogger(__name__).warning(
            "wrote %s but could not log it to MLflow run %s at %s: %s",
            path, run_id, uri, first_line(err))
