"""A comparison's MLflow record, made at its edge by a child process.

``compare`` fits, judges and writes without calling MLflow.  Tracking is one step at the
edge, run by a child process (``python -m thermonet.workflows.compare_track``) so that its
cost — importing MLflow (~0.7 s), opening the store (~1 s), exporting the chosen model to
ONNX and logging it (~3-4 s) — overlaps the comparison instead of delaying its report:

1. :meth:`TrackingSession.start` (before the plan) starts the child: it imports MLflow
   while the data load;
2. :meth:`TrackingSession.open` (after the plan) asks it to create the parent run and one
   nested run per family, ``RUNNING``: their ids go into the checkpoints and
   ``results.json`` (:meth:`TrackingSession.ids` waits for them only when first needed);
3. :meth:`TrackingSession.log` (once ``results.json`` is written) hands it the record —
   ``results.json``'s document, the run directory, and per family what the fit logged
   (its per-epoch history and test metrics as fitted, before the judge rewrites the
   uncompensated axes' metrics) — and it logs families, checkpoints, the out-of-fold
   scores, the ``chosen`` tag, the chosen model (ONNX, :func:`log_chosen_model`),
   ``results.json`` and ``config.resolved.yaml`` while the plots are drawn;
4. :meth:`TrackingSession.finish` (once the report is written) hands it the report and
   plots, waits for the runs to end ``FINISHED`` and returns its warnings.

The runs' content is what the in-line tracking of earlier versions logged: the same
params, metrics, tags (``mlflow.source.name`` is the command's, not the child's) and
artifacts.  Robustness: the child runs in its own session (Ctrl-C reaches the command,
not it); the command ends it on any failure (:meth:`TrackingSession.abort`: ``KILLED``
when interrupted, ``FAILED`` otherwise); a child whose command was killed outright (its
requests' pipe closed) exits and leaves the runs ``RUNNING``, tagged with the command's
pid, for :func:`thermonet.tracking.tidy_orphaned_runs`, as before.  An MLflow failure in the child fails the
comparison as an in-line one did, as one line (:class:`TrackingFailed`, exit 1), and the
staged output is then removed: nothing half-written.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

from ..core.errors import Interrupted, ThermonetError
from ..models.registry import PER_AXIS
from ..tracking import HOST_TAG, PID_TAG, Tracker, _retry, flatten_params

__all__ = ["TrackingFailed", "TrackingSession", "family_record", "log_chosen_model"]

#: Seconds an aborted child gets to end its runs before it is stopped.
_ABORT_WAIT_S = 30.0


class TrackingFailed(ThermonetError):
    """MLflow refused or failed a step of the comparison's tracking (the message is MLflow's
    first line)."""


def family_record(fitted: bool, history: list[Mapping[str, Any]] | None,
                  metrics: Mapping[str, float], checkpoint: str | None) -> dict[str, Any]:
    """What one family's nested run logs: ``fitted`` (False: tagged ``status=failed``), the
    per-epoch ``history``, the final ``metrics`` and the ``checkpoint`` file (``model/``)."""
    return {"fitted": fitted, "history": list(history or []), "metrics": dict(metrics),
            "checkpoint": checkpoint}


class TrackingSession:
    """The command's side of the tracking child (nothing at all when tracking is off)."""

    def __init__(self, *, enabled: bool, uri: str, experiment: str,
                 register: str | None) -> None:
        self.enabled, self.uri, self.experiment, self.register = (enabled, uri, experiment,
                                                                   register)
        self._proc: subprocess.Popen[str] | None = None
        self._ids: tuple[str | None, dict[str, str]] | None = None
        self._open_sent = False

    # ------------------------------------------------------------ command side
    def start(self) -> TrackingSession:
        """Start the child (it imports MLflow meanwhile); nothing when tracking is off."""
        if not self.enabled:
            return self
        root = str(Path(__file__).resolve().parents[2])   # this thermonet, not another
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            [root, *filter(None, [os.environ.get("PYTHONPATH")])])}
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "thermonet.workflows.compare_track"], env=env,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            start_new_session=True)   # Ctrl-C goes to the command, which ends the child
        return self

    def open(self, name: str, params: Mapping[str, Any], tags: Mapping[str, str],
             families: list[tuple[str, Mapping[str, Any], Mapping[str, str]]]) -> None:
        """Ask for the parent run and one nested run per family (label, params, tags)."""
        if self._proc is None:
            return
        self._send({"op": "open", "uri": self.uri, "experiment": self.experiment,
                    "name": name, "params": params, "tags": dict(tags),
                    "families": [[k, p, dict(t)] for k, p, t in families],
                    "argv": list(sys.argv), "pid": os.getpid()})
        self._open_sent = True

    def ids(self) -> tuple[str | None, dict[str, str]]:
        """(parent run id, {family label: nested run id}); (None, {}) when tracking is off."""
        if self._ids is None:
            if self._proc is None or not self._open_sent:
                self._ids = (None, {})
            else:
                reply = self._receive()
                self._ids = (reply["parent"], dict(reply["families"]))
        return self._ids

    def log(self, out: Path, doc: Mapping[str, Any],
            families: Mapping[str, dict[str, Any]]) -> None:
        """Hand over the record (``results.json``'s document, the run directory, the
        families' :func:`family_record`); the child logs it while the command goes on."""
        if self._proc is None:
            return
        self.ids()
        self._send({"op": "log", "out": str(out), "doc": doc, "families": dict(families),
                    "register": self.register})

    def finish(self, report: Path | None, plots: list[Path]) -> list[str]:
        """Hand over the report and plots; wait for the runs to end; the child's warnings."""
        if self._proc is None:
            return []
        files = ([[str(report), None]] if report else []) + [[str(p), "plots"] for p in plots]
        self._send({"op": "finish", "files": files})
        reply = self._receive()
        self._proc.wait()
        self._proc = None
        return list(reply.get("warnings", []))

    def abort(self, interrupted: bool) -> None:
        """End the child's runs (``KILLED`` when interrupted, ``FAILED`` otherwise) and the
        child; never raises (the command is already failing)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        try:
            if interrupted:
                proc.send_signal(signal.SIGTERM)   # now, even mid-export: ends its runs KILLED
            else:
                self._write(proc, {"op": "abort", "status": "FAILED"})
            if proc.stdin is not None:
                proc.stdin.close()
            proc.wait(timeout=_ABORT_WAIT_S)
        except (OSError, ValueError, subprocess.TimeoutExpired):
            proc.kill()
            proc.wait()

    def _send(self, message: Mapping[str, Any]) -> None:
        assert self._proc is not None
        try:
            self._write(self._proc, message)
        except OSError:   # the child died: its reply (none) says so
            pass

    @staticmethod
    def _write(proc: subprocess.Popen[str], message: Mapping[str, Any]) -> None:
        assert proc.stdin is not None
        proc.stdin.write(json.dumps(message) + "\n")
        proc.stdin.flush()

    def _receive(self) -> dict[str, Any]:
        assert self._proc is not None and self._proc.stdout is not None
        line = self._proc.stdout.readline()
        if not line:
            code = self._proc.wait()
            self._proc = None
            raise TrackingFailed(f"MLflow tracking: the tracking process ended (exit {code})")
        reply: dict[str, Any] = json.loads(line)
        if not reply.get("ok"):
            self.abort(interrupted=False)
            raise TrackingFailed(f"MLflow tracking ({self.uri}): {reply.get('error')}")
        return reply


# ------------------------------------------------------------------ child side
class _Child:
    """The tracking child: the runs it opened, and the requests that fill and end them."""

    def __init__(self) -> None:
        self.tracker_type = Tracker
        self.tracker: Any = None
        self.mlflow: Any = None
        self.parent: str | None = None
        self.families: dict[str, str] = {}
        self.open_runs: list[str] = []
        self.warnings: list[str] = []

    def open(self, req: Mapping[str, Any]) -> dict[str, Any]:
        """The parent run (fluent, active in this process) and the nested runs, created as
        MLflow's ``start_run`` creates them (same system tags), all left ``RUNNING``."""
        from mlflow.tracking.context import registry

        sys.argv = list(req["argv"])   # mlflow.source.name: the command's, not this child's
        self.tracker = self.tracker_type(enabled=True, uri=req["uri"],
                                         experiment=req["experiment"])
        mlflow = self.mlflow = self.tracker._client()
        import socket

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
            from mlflow.entities import Param, RunTag

            _retry(client.log_batch, cid, params=[
                Param(k, v) for k, v in flatten_params(params).items()])
            _retry(client.log_batch, cid, tags=[RunTag(k, str(v)) for k, v in tags.items()])
        return {"parent": self.parent, "families": self.families}

    def log(self, req: Mapping[str, Any]) -> None:
        """Each family's run filled and ended, then the parent's record bar report and plots."""
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
        tr.log_metrics({f"cv/{k}/score": c["score"] for k, c in
                        (doc.get("selection") or {}).get("candidates", {}).items()
                        if "score" in c})
        tr.set_tags({"chosen": doc.get("chosen") or "none"})
        if self.parent:
            warning = log_chosen_model(doc, tr.uri, self.parent, req["register"])
            if warning:
                self.warnings.append(warning)
        out = Path(req["out"])
        tr.log_artifact(out / "results.json")
        tr.log_artifact(out / "config.resolved.yaml")

    def finish(self, req: Mapping[str, Any]) -> dict[str, Any]:
        for path, folder in req["files"]:
            self.tracker.log_artifact(path, folder)
        self.end("FINISHED")
        return {"warnings": self.warnings}

    def end(self, status: str) -> None:
        """End every run still open with ``status`` (the nested ones first)."""
        if self.mlflow is None:
            return
        client = self.mlflow.MlflowClient()
        for rid in [r for r in self.open_runs if r != self.parent]:
            _retry(client.set_terminated, rid, status)
        if self.parent in self.open_runs:
            _retry(self.mlflow.end_run, status)
        self.open_runs.clear()


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
        return (f"the chosen model could not be logged to MLflow: "
                f"{str(err).splitlines()[0] if str(err) else type(err).__name__}")
    return None


def _prewarm() -> None:
    """Import what exporting and logging the chosen model needs (torch, onnx, onnxruntime,
    MLflow's ONNX flavour: ~2 s) while the command is still fitting, not after it wrote its
    results; a module that cannot be imported is left to fail where it is used."""
    import importlib

    for name in ("torch", "onnx", "onnxruntime", "mlflow.onnx", "mlflow.models",
                 "thermonet.exporting.onnx_export", "thermonet.exporting.source"):
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001, S112 - reported where it is used, if it is
            continue


#: SIGTERMs the child received (its handler's exception can be swallowed where it lands in a
#: garbage-collection callback, as the command's can: :func:`thermonet.core.errors.check_interrupted`)
_SIGNALS: list[int] = []


def _raise_interrupted(signum: int, frame: object) -> None:
    _SIGNALS.append(signum)
    raise Interrupted(signum)


def _quiet_unraisable(hook: Any) -> Any:
    """``sys.unraisablehook`` that stays silent on a swallowed :class:`Interrupted` (recorded
    in :data:`_SIGNALS` already: the runs still end ``KILLED``) and hands on the rest."""
    def unraisable(info: Any) -> None:
        if not isinstance(info.exc_value, Interrupted):
            hook(info)
    return unraisable


def _serve(requests: IO[str], replies: IO[str]) -> int:
    """The child's loop: one JSON request a line, one JSON reply for ``open`` and ``finish``.
    Any failure is replied (its first line) and ends the runs ``FAILED``; SIGTERM (the
    command was interrupted) ends them ``KILLED``; a closed request pipe (the command was
    killed without unwinding) leaves them ``RUNNING``, as the command's own runs were left,
    for :func:`thermonet.tracking.tidy_orphaned_runs` (they carry the command's pid)."""
    child: _Child | None = None
    reply: dict[str, Any] | None
    status: str | None = None   # the requests' pipe closed: the command died without unwinding
    try:
        child = _Child()
        for line in requests:
            req = json.loads(line)
            try:
                if req["op"] == "open":
                    reply = child.open(req)
                    replies.write(json.dumps({"ok": True, **reply}) + "\n")
                    replies.flush()
                    _prewarm()   # while the command fits: what logging the model imports
                    reply = None
                elif req["op"] == "log":
                    child.log(req)
                    reply = None
                elif req["op"] == "finish":
                    reply = child.finish(req)
                else:   # abort
                    status = req.get("status", "FAILED")
                    break
            except Exception as err:  # noqa: BLE001 - replied to the command, which fails
                text = str(err).splitlines()[0] if str(err) else type(err).__name__
                replies.write(json.dumps({"ok": False, "error": text}) + "\n")
                replies.flush()
                status = "FAILED"
                break
            if reply is not None:
                replies.write(json.dumps({"ok": True, **reply}) + "\n")
                replies.flush()
            if req["op"] == "finish":
                return 0
    except Interrupted:
        status = "KILLED"
    finally:
        if _SIGNALS and status != "FAILED":   # a SIGTERM whose exception was swallowed
            status = "KILLED"
        if child is not None and status is not None:
            try:
                child.end(status)
            except Exception:  # noqa: BLE001, S110 - the command is failing already
                pass
    return 0


def main() -> None:
    """Entry point of the child: replies on a private copy of stdout; stdout itself (what
    MLflow may print) goes to stderr, shown as the in-line tracking's was."""
    signal.signal(signal.SIGTERM, _raise_interrupted)
    sys.unraisablehook = _quiet_unraisable(sys.unraisablehook)
    replies = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    code = _serve(sys.stdin, replies)
    sys.stdout.flush()
    sys.stderr.flush()
    # no exit handlers: MLflow's would end a run left RUNNING (its command was killed) as
    # FINISHED; every other run has been ended explicitly
    os._exit(code)


if __name__ == "__main__":
    main()
