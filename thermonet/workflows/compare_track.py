"""A comparison's MLflow record, made at its edge by a helper process.

``compare`` fits, judges and writes without calling MLflow.  Tracking is one step at the
edge, run in a helper process (:class:`thermonet.core.helpers.Helpers`: the standard
library's process pool, one worker, as the figures' drawers and calibrate's helpers) so
that its cost — importing MLflow (~0.7 s), opening the store (~1 s), exporting the chosen
model to ONNX and logging it (~3-4 s) — overlaps the comparison instead of delaying its
report:

1. :meth:`TrackingSession.start` (before the plan) starts the worker: it imports MLflow
   while the data load;
2. :meth:`TrackingSession.open` (after the plan) calls :func:`open_runs` there: the parent
   run and one nested run per family, ``RUNNING``; their ids go into the checkpoints and
   ``results.json`` (:meth:`TrackingSession.ids` waits for them only when first needed);
   then the worker imports what logging the chosen model needs (:func:`prewarm`);
3. :meth:`TrackingSession.log` (once ``results.json`` is written) calls :func:`log_runs`
   with the record — ``results.json``'s document, the run directory, and per family what
   the fit logged (its per-epoch history and test metrics as fitted, before the judge
   rewrites the uncompensated axes' metrics) — which logs families, checkpoints, the
   out-of-fold scores, the ``chosen`` tag, the chosen model (ONNX,
   :func:`log_chosen_model`), ``results.json`` and ``config.resolved.yaml`` while the
   plots are drawn;
4. :meth:`TrackingSession.finish` (once the report is written) calls :func:`finish_runs`
   with the report and plots, which ends the runs ``FINISHED`` and returns its warnings.

The runs' content is what the in-line tracking of earlier versions logged: the same
params, metrics, tags (``mlflow.source.name`` is the command's, not the worker's) and
artifacts.  Robustness: the worker is the helpers' (its own session, Ctrl-C ignored: the
command alone stops); when the command fails or is interrupted,
:meth:`TrackingSession.abort` ends the worker, then the command ends its own runs still
``RUNNING`` — ``KILLED`` when interrupted, ``FAILED`` otherwise
(:func:`thermonet.tracking.end_runs_of`, by the command's pid tag); a command killed
outright takes its worker with it and leaves the runs ``RUNNING``, tagged with its pid,
for :func:`thermonet.tracking.tidy_orphaned_runs`, as before.  An MLflow failure in the
worker fails the comparison as an in-line one did, as one line (:class:`TrackingFailed`,
exit 1), and the staged output is then removed: nothing half-written.  Where no helper
process can be had (a script run by path without a ``__main__`` guard, a process limit),
the same calls run in the command, in turn.

Until issue 51 the worker was a child process of its own speaking JSON lines over its
standard input and output (framing, replies, signal handling: ~110 lines more).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from concurrent.futures import Future
from pathlib import Path
from typing import Any

from ..core.errors import ThermonetError, first_line
from ..core.helpers import Helpers
from ..models.registry import PER_AXIS
from ..tracking import HOST_TAG, PID_TAG, Tracker, _retry, end_runs_of, flatten_params

__all__ = ["TrackingFailed", "TrackingSession", "family_record", "log_chosen_model",
           "open_runs", "log_runs", "finish_runs", "prewarm", "shipped_metrics"]

#: The module whose functions the worker runs (by name: the command need not import them).
_HERE = __name__


class TrackingFailed(ThermonetError):
    """MLflow refused or failed a step of the comparison's tracking (the message is MLflow's
    first line)."""


def family_record(fitted: bool, history: list[Mapping[str, Any]] | None,
                  metrics: Mapping[str, float], checkpoint: str | None) -> dict[str, Any]:
    """What one family's nested run logs: ``fitted`` (False: tagged ``status=failed``), the
    per-epoch ``history``, the final ``metrics`` and the ``checkpoint`` file (``model/``)."""
    return {"fitted": fitted, "history": list(history or []), "metrics": dict(metrics),
            "checkpoint": checkpoint}


def shipped_metrics(doc: Mapping[str, Any]) -> dict[str, float]:
    """The shipped per-axis model's held-out figures for the parent run,
    ``shipped/test/<axis>/<metric>``: it has no run of its own, where each family's are on
    its run as ``test/<axis>/<metric>`` (every number of its axes' records in results.json)."""
    axes = ((doc.get("families") or {}).get(PER_AXIS) or {}).get("axes") or {}
    return {f"shipped/test/{a}/{k}": float(v) for a, m in axes.items() for k, v in m.items()
            if isinstance(v, (int, float)) and not isinstance(v, bool)}


class _InCommand:
    """The helpers' ``submit`` where no helper process can be had: each call now, here."""

    def submit(self, module: str, function: str, **kwargs: Any) -> Future[Any]:
        f: Future[Any] = Future()
        try:
            f.set_result((getattr(sys.modules[module], function)(**kwargs), []))
        except Exception as err:  # noqa: BLE001 - raised where the future is read
            f.set_exception(err)
        return f

    def kill(self) -> None:
        """Nothing runs elsewhere."""


class TrackingSession:
    """The command's side of the tracking worker (nothing at all when tracking is off)."""

    def __init__(self, *, enabled: bool, uri: str, experiment: str,
                 register: str | None) -> None:
        self.enabled, self.uri, self.experiment, self.register = (enabled, uri, experiment,
                                                                   register)
        self._worker: Helpers | _InCommand | None = None
        self._elsewhere = False                  # the worker is a process of its own
        self._opened: Future[Any] | None = None
        self._logged: Future[Any] | None = None
        self._ids: tuple[str | None, dict[str, str]] | None = None

    def start(self) -> TrackingSession:
        """Start the worker (it imports MLflow meanwhile); nothing when tracking is off."""
        if not self.enabled:
            return self
        try:
            self._worker, self._elsewhere = Helpers(1, preload=("mlflow",)), True
        except OSError:                  # no helper process to be had: the command does it
            self._worker = _InCommand()
        return self

    def open(self, name: str, params: Mapping[str, Any], tags: Mapping[str, str],
             families: list[tuple[str, Mapping[str, Any], Mapping[str, str]]]) -> None:
        """Ask for the parent run and one nested run per family (label, params, tags)."""
        if self._worker is None:
            return
        elsewhere = self._elsewhere
        self._opened = self._worker.submit(_HERE, "open_runs", req={
            "uri": self.uri, "experiment": self.experiment, "name": name,
            "params": dict(params), "tags": dict(tags),
            "families": [[k, dict(p), dict(t)] for k, p, t in families],
            "argv": list(sys.argv), "pid": os.getpid(), "elsewhere": elsewhere})
        if elsewhere:                    # while the command fits: what logging needs
            self._worker.submit(_HERE, "prewarm")

    def ids(self) -> tuple[str | None, dict[str, str]]:
        """(parent run id, {family label: nested run id}); (None, {}) when tracking is off."""
        if self._ids is None:
            if self._opened is None:
                self._ids = (None, {})
            else:
                reply = self._value(self._opened)
                self._ids = (reply["parent"], dict(reply["families"]))
        return self._ids

    def log(self, out: Path, doc: Mapping[str, Any],
            families: Mapping[str, dict[str, Any]]) -> None:
        """Hand over the record (``results.json``'s document, the run directory, the
        families' :func:`family_record`); the worker logs it while the command goes on."""
        if self._worker is None:
            return
        self.ids()
        self._logged = self._worker.submit(_HERE, "log_runs", req={
            "out": str(out), "doc": dict(doc), "families": dict(families),
            "register": self.register})

    def finish(self, report: Path | None, plots: list[Path]) -> list[str]:
        """Hand over the report and plots; wait for the runs to end; the worker's warnings."""
        if self._worker is None:
            return []
        warnings: list[str] = []
        if self._logged is not None:
            warnings = list(self._value(self._logged))
        files = ([[str(report), None]] if report else []) + [[str(p), "plots"] for p in plots]
        self._value(self._worker.submit(_HERE, "finish_runs", files=files))
        worker, self._worker = self._worker, None
        worker.kill()
        return warnings

    def abort(self, interrupted: bool) -> None:
        """End the worker, then the command's runs still ``RUNNING`` (``KILLED`` when
        interrupted, ``FAILED`` otherwise); never raises (the command is already failing)."""
        worker, self._worker = self._worker, None
        if worker is None:
            return
        worker.kill()
        try:
            end_runs_of(self.uri, self.experiment, os.getpid(),
                        "KILLED" if interrupted else "FAILED")
        except Exception:  # noqa: BLE001, S110 - left for tidy_orphaned_runs
            pass

    def _value(self, future: Future[Any]) -> Any:
        """A call's value; its failure ends the tracking and is one :class:`TrackingFailed`."""
        try:
            value, _logged = future.result()
        except Exception as err:  # noqa: BLE001 - MLflow's, the pool's: one line
            self.abort(interrupted=False)
            raise TrackingFailed(f"MLflow tracking ({self.uri}): {first_line(err)}"
                                 ) from None
        return value


# ------------------------------------------------------------------ the worker's side
class _Runs:
    """The runs this worker opened, and the calls that fill and end them."""

    def __init__(self, req: Mapping[str, Any]) -> None:
        self.tracker = Tracker(enabled=True, uri=req["uri"], experiment=req["experiment"])
        self.mlflow: Any = self.tracker._client()
        self.parent: str | None = None
        self.families: dict[str, str] = {}
        self.open_runs: list[str] = []

    def open(self, req: Mapping[str, Any]) -> dict[str, Any]:
        """The parent run (fluent, active in this process) and the nested runs, created as
        MLflow's ``start_run`` creates them (same system tags), all left ``RUNNING``."""
        import socket

        from mlflow.entities import Param, RunTag
        from mlflow.tracking.context import registry

        mlflow = self.mlflow
        owner = {HOST_TAG: socket.gethostname(), PID_TAG: str(req["pid"])}
        run = _retry(mlflow.start_run, run_name=req["name"], tags=owner)
        self.parent = run.info.run_id
        self.open_runs.append(self.parent)
        _retry(mlflow.log_params, flatten_params(req["params"]))
        _retry(mlflow.set_tags, {k: str(v) for k, v in req["tags"].items()})
        client = mlflow.MlflowClient()
        for label, params, tags in req["families"]:
            child = _retry(client.create_run, run.info.experiment_id, run_name=label,
                           tags=registry.resolve_tags({
                               **owner, "mlflow.parentRunId": self.parent,
                               "mlflow.runName": label}))
            cid = child.info.run_id
            self.families[label] = cid
            self.open_runs.append(cid)
            _retry(client.log_batch, cid, params=[
                Param(k, v) for k, v in flatten_params(params).items()])
            _retry(client.log_batch, cid, tags=[RunTag(k, str(v)) for k, v in tags.items()])
        return {"parent": self.parent, "families": self.families}

    def log(self, req: Mapping[str, Any]) -> list[str]:
        """Each family's run filled and ended, then the parent's record bar report and
        plots; the warnings (the chosen model not logged)."""
        tr, mlflow, doc = self.tracker, self.mlflow, req["doc"]
        for label, rec in req["families"].items():
            cid = self.families[label]
            mlflow.start_run(run_id=cid, nested=True)
            try:
                if rec["fitted"]:
                    tr.log_history(rec["history"])
                    tr.log_metrics(rec["metrics"])
                    if rec["checkpoint"]:
                        tr.log_artifact(rec["checkpoint"], "model")
                else:
                    tr.set_tags({"status": "failed"})
            finally:
                mlflow.end_run("FINISHED")
                self.open_runs.remove(cid)
        per_axis = (doc["families"].get(PER_AXIS) or {}).get("checkpoint") \
            if doc.get("chosen") == PER_AXIS else None
        if per_axis:
            tr.log_artifact(per_axis, "model")
            tr.log_metrics(shipped_metrics(doc))
        tr.log_metrics({f"cv/{k}/score": c["score"] for k, c in
                        (doc.get("selection") or {}).get("candidates", {}).items()
                        if "score" in c})
        tr.set_tags({"chosen": doc.get("chosen") or "none"})
        warning = log_chosen_model(doc, tr.uri, self.parent, req["register"]) \
            if self.parent else None
        out = Path(req["out"])
        tr.log_artifact(out / "results.json")
        tr.log_artifact(out / "config.resolved.yaml")
        return [warning] if warning else []

    def finish(self, files: list[list[str | None]]) -> None:
        """The report and plots logged; every run still open ended ``FINISHED``."""
        for path, folder in files:
            self.tracker.log_artifact(str(path), folder)
        client = self.mlflow.MlflowClient()
        for rid in [r for r in self.open_runs if r != self.parent]:
            _retry(client.set_terminated, rid, "FINISHED")
        if self.parent in self.open_runs:
            _retry(self.mlflow.end_run, "FINISHED")
        self.open_runs.clear()


#: The worker's runs (one comparison per worker: its :func:`open_runs` made them).
_RUNS: list[_Runs] = []


def open_runs(req: Mapping[str, Any]) -> dict[str, Any]:
    """In the worker: open the comparison's runs (:meth:`TrackingSession.open`).  A worker
    of its own (``elsewhere``) takes the command's ``sys.argv`` (``mlflow.source.name``) and
    sends what MLflow prints to standard error, as the in-line tracking's was shown."""
    if req["elsewhere"]:
        sys.argv = list(req["argv"])
        sys.stdout.flush()
        os.dup2(2, 1)
    _RUNS[:] = [_Runs(req)]
    return _RUNS[0].open(req)


def log_runs(req: Mapping[str, Any]) -> list[str]:
    """In the worker: fill and end the families' runs (:meth:`TrackingSession.log`)."""
    return _RUNS[0].log(req)


def finish_runs(files: list[list[str | None]]) -> None:
    """In the worker: the last artifacts, and every run ended (:meth:`TrackingSession.finish`)."""
    _RUNS.pop().finish(files)


def log_chosen_model(doc: Mapping[str, Any], uri: str, run_id: str,
                     register: str | None) -> str | None:
    """The chosen model as the comparison run's MLflow model ``model`` (ONNX, signature,
    input example: ``runs:/<run id>/model``), registered under ``tracking.register`` with
    the alias ``chosen``.  Returns a warning when it fails (the files are written), never
    raises."""
    import tempfile

    from ..exporting.onnx_export import log_onnx_model  # torch boundary
    from ..exporting.source import onnx_of_checkpoint  # torch boundary

    chosen = doc.get("chosen") or ""
    ckpt = (doc["families"].get(chosen) or {}).get("checkpoint")
    if not ckpt:
        return None
    try:
        with tempfile.TemporaryDirectory() as tmp:
            path = onnx_of_checkpoint(ckpt, Path(tmp) / f"{chosen}.onnx")
            log_onnx_model(path, run_id, uri, register=register)
    except Exception as err:  # noqa: BLE001 - tracking is best effort; the files are written
        return f"the chosen model could not be logged to MLflow: {first_line(err)}"
    return None


def prewarm() -> None:
    """In the worker: import what exporting and logging the chosen model needs (torch,
    onnx, onnxruntime, MLflow's ONNX flavour: ~2 s) while the command is still fitting, not
    after it wrote its results; a module that cannot be imported is left to fail where it
    is used."""
    import importlib

    for name in ("torch", "onnx", "onnxruntime", "mlflow.onnx", "mlflow.models",
                 "thermonet.exporting.onnx_export", "thermonet.exporting.source"):
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001, S112 - reported where it is used, if it is
            continue
