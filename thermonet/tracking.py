"""Experiment tracking: the one module that calls MLflow.

Every ``compare`` / ``train`` run is recorded in an embedded store in the
working directory (``sqlite:///mlflow.db``, artifacts under ``mlruns/``; no
server).  A comparison is a parent run with one nested run per family.
Metric keys are namespaced: ``train/loss``, ``val/loss`` per epoch;
``test/<axis>/<metric>`` at the end.  ``--no-track`` gives a :class:`Tracker`
whose methods do nothing; ``--tracking-uri`` points at a team server.

Open the runs with ``mlflow ui --backend-store-uri sqlite:///mlflow.db`` (it
binds to 127.0.0.1 unless given ``--host``).

Robustness:

* Interrupted runs: a run interrupted by SIGINT/SIGTERM (the CLI turns both
  into :class:`~thermonet.core.errors.Interrupted` / ``KeyboardInterrupt``) is
  ended as ``KILLED``; any other exception ends it ``FAILED``.
* Runs left ``RUNNING`` by a process that died without unwinding (SIGKILL,
  power cut): every run is tagged ``thermonet.host`` and ``thermonet.pid``; when
  a :class:`Tracker` opens a store it marks ``KILLED`` every ``RUNNING`` run of
  its experiment tagged with *this* host whose process no longer exists
  (:func:`tidy_orphaned_runs`, also callable by hand).  Runs of other hosts
  are left alone (their processes cannot be checked from here); a reused pid
  keeps a dead run ``RUNNING`` until that pid is gone too.
* Concurrent processes on a new SQLite store: creating the store (schema
  migrations) and the experiment is serialised by an ``fcntl`` lock on
  ``<db>.lock`` beside the database, and writes are retried briefly on
  SQLite's ``database is locked``.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import socket
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .core.errors import Interrupted, ThermonetError

__all__ = ["Tracker", "default_tracking_uri", "flatten_params", "tidy_orphaned_runs",
           "end_runs_of", "global_tracking_uri", "store_problem", "check_store",
           "KNOWN_SCHEMES"]

#: Tags identifying the process that owns a run (for :func:`tidy_orphaned_runs`).
HOST_TAG, PID_TAG = "thermonet.host", "thermonet.pid"
#: Attempts and first pause (doubled each time) when SQLite says ``database is locked``.
_LOCK_RETRIES, _LOCK_PAUSE_S = 8, 0.1

_log = logging.getLogger(__name__)

# MLflow refuses param values over this many characters.
_MAX_PARAM_LEN = 6000
# Characters MLflow refuses in a param name (a limits key "*", say) become "_".
_BAD_PARAM_CHARS = re.compile(r"[^\w\-. :/]")


def default_tracking_uri(workdir: str | Path | None = None) -> str:
    """``sqlite:///<workdir>/mlflow.db`` (absolute, so a later ``cd`` does not move it)."""
    root = Path(workdir or os.getcwd()).resolve()
    return f"sqlite:///{root / 'mlflow.db'}"


#: The first 16 bytes of every SQLite 3 database (https://www.sqlite.org/fileformat.html).
_SQLITE_MAGIC = b"SQLite format 3\x00"


def _local_store(uri: str) -> tuple[str, Path] | None:
    """``("sqlite", path)`` for a ``sqlite:///`` URI, ``("file", path)`` for a ``file:`` URI
    or a bare path (MLflow's file store), None for anything else (a server, in-memory)."""
    from urllib.parse import unquote, urlparse

    if uri.startswith("sqlite:///"):
        rest = uri[len("sqlite:///"):].split("?", 1)[0]
        return ("sqlite", Path(rest)) if rest and rest != ":memory:" else None
    parsed = urlparse(uri)
    if parsed.scheme == "file":
        return "file", Path(unquote(parsed.path))
    if parsed.scheme == "" or (len(parsed.scheme) == 1 and os.name == "nt"):  # C:\...
        return "file", Path(uri)
    return None


def _is_sqlite(path: Path) -> bool:
    try:
        with path.open("rb") as f:
            return f.read(len(_SQLITE_MAGIC)) == _SQLITE_MAGIC
    except OSError:
        return False


#: The tracking URI schemes MLflow's own stores take (a server, a SQL database, Databricks);
#: anything else failed inside MLflow after the whole fit.
KNOWN_SCHEMES = ("sqlite", "http", "https", "postgresql", "mysql", "mssql", "databricks",
                 "databricks-uc", "uc")
_STORE_HINT = "a SQLite store is sqlite:///PATH, a server http://HOST:PORT"


def store_problem(uri: str) -> str | None:
    """Why the tracking store ``uri`` names cannot be one (None: it may be; MLflow has the
    last word).  Without importing MLflow, before any work: a scheme MLflow has no store for
    (:data:`KNOWN_SCHEMES`); a bare path or ``file:`` URI (MLflow's file store, which MLflow
    3 refuses as "in maintenance mode" — after the fit, where it was asked for); a
    ``sqlite:///`` path that is a directory, a FIFO or a device, or a file that is not a
    SQLite database."""
    import stat
    from urllib.parse import urlparse

    local = None if uri in KNOWN_SCHEMES else _local_store(uri)   # "databricks": a profile
    if local is None:
        scheme = urlparse(uri).scheme.split("+", 1)[0]
        if scheme not in KNOWN_SCHEMES and uri not in KNOWN_SCHEMES:
            return f"no MLflow store takes the scheme '{scheme}' ({_STORE_HINT})"
        return None
    kind, path = local
    try:
        mode: int | None = path.stat().st_mode
    except OSError:
        mode = None   # not there yet (a new store), or MLflow's own words
    if kind == "file":
        if mode is not None and not stat.S_ISDIR(mode):
            hint = f" (a SQLite database: give sqlite:///{path})" if _is_sqlite(path) else \
                f" ({_STORE_HINT})"
            return f"{path} is a file, not a tracking store{hint}"
        hint = f"give sqlite:///{path}" if path.suffix in (".db", ".sqlite") else _STORE_HINT
        return (f"{path} names MLflow's file store (a bare path or file: URI), which this "
                f"MLflow no longer writes ({hint})")
    if mode is None:
        return None
    if stat.S_ISDIR(mode):
        return f"{path} is a directory, not a SQLite database (give sqlite:///DIR/mlflow.db)"
    if not stat.S_ISREG(mode):
        return f"{path} is not a regular file, not a SQLite database"
    if path.stat().st_size and not _is_sqlite(path):
        return f"{path} is a file but not a SQLite database (its first bytes say otherwise)"
    return None


def missing_store(uri: str) -> Path | None:
    """The path of the local store ``uri`` names when nothing is there yet, else None (a
    server, or a path that exists).  No run can be in it, and MLflow would create an empty
    store there only to say so: what reads a run asks this first, without importing MLflow."""
    local = _local_store(uri)
    if local is None or os.path.lexists(local[1]):
        return None
    return local[1]


def check_store(uri: str) -> None:
    """Refuse, in one line naming the URI, a tracking store :func:`store_problem` refuses."""
    why = store_problem(uri)
    if why is not None:
        raise ThermonetError(f"MLflow tracking ({uri}): {why}")


def _retry(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """Call ``fn``, retrying briefly while SQLite reports ``database is locked``."""
    for attempt in range(_LOCK_RETRIES):
        try:
            return fn(*args, **kwargs)
        except Exception as err:  # noqa: BLE001 - MLflow wraps SQLAlchemy's OperationalError
            if "database is locked" not in str(err) or attempt == _LOCK_RETRIES - 1:
                raise
            time.sleep(_LOCK_PAUSE_S * 2 ** attempt)
    raise AssertionError("unreachable")


@contextmanager
def _store_lock(uri: str) -> Iterator[None]:
    """An exclusive ``fcntl`` lock on ``<db>.lock`` for a SQLite URI (nothing otherwise)."""
    if not uri.startswith("sqlite:///"):
        yield
        return
    import fcntl

    lock = Path(uri[len("sqlite:///"):] + ".lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    with open(lock, "a") as fh:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def _running_here(client: Any, experiment: str) -> list[tuple[Any, int | None]]:
    """The runs of ``experiment`` left ``RUNNING`` by thermonet processes of this host, each
    with the pid it is tagged with (None: not a number)."""
    exp = client.get_experiment_by_name(experiment)
    if exp is None:
        return []
    runs = client.search_runs([exp.experiment_id], filter_string=(
        f"attributes.status = 'RUNNING' and tags.`{HOST_TAG}` = '{socket.gethostname()}'"),
        max_results=1000)
    out: list[tuple[Any, int | None]] = []
    for run in runs:
        try:
            out.append((run, int(run.data.tags.get(PID_TAG, ""))))
        except ValueError:
            out.append((run, None))
    return out


def tidy_orphaned_runs(uri: str | None = None, experiment: str = "thermonet") -> list[str]:
    """Mark ``KILLED`` the runs left ``RUNNING`` by dead thermonet processes of this host.

    Returns the ids of the runs it ended.  Called by :class:`Tracker` when it
    opens a store; call it by hand to tidy a store without running anything::

        python -c "from thermonet.tracking import tidy_orphaned_runs as t; print(t())"
    """
    import mlflow

    client = mlflow.MlflowClient(tracking_uri=uri or default_tracking_uri())
    ended = []
    for run, pid in _running_here(client, experiment):
        if pid is not None and pid != os.getpid() and not _pid_alive(pid):
            _retry(client.set_terminated, run.info.run_id, "KILLED")
            ended.append(run.info.run_id)
    if ended:
        _log.warning("marked %d run(s) KILLED: left RUNNING by dead process(es) on %s",
                     len(ended), socket.gethostname())
    return ended


def end_runs_of(uri: str, experiment: str, pid: int, status: str) -> list[str]:
    """End with ``status`` the runs of this host still ``RUNNING`` that the process ``pid``
    opened (its tag): a failing comparison's, ended by the command once its tracking
    worker is stopped.  Returns their ids."""
    import mlflow

    client = mlflow.MlflowClient(tracking_uri=uri)
    ended = []
    for run, tagged in _running_here(client, experiment):
        if tagged == pid:
            _retry(client.set_terminated, run.info.run_id, status)
            ended.append(run.info.run_id)
    return ended


def flatten_params(data: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Flatten a nested config into MLflow params ``a.b.c -> value``."""
    out: dict[str, str] = {}
    for key, value in data.items():
        name = _BAD_PARAM_CHARS.sub("_", f"{prefix}{key}")
        if isinstance(value, Mapping):
            out.update(flatten_params(value, name + "."))
        elif isinstance(value, list) and value and all(isinstance(v, Mapping) for v in value):
            for i, item in enumerate(value):
                out.update(flatten_params(item, f"{name}.{i}."))
        else:
            text = json.dumps(value) if not isinstance(value, str) else value
            out[name] = text[:_MAX_PARAM_LEN]
    return out


class Tracker:
    """Thin wrapper over MLflow's fluent API, a no-op when disabled.

    Parameters
    ----------
    enabled : bool
        False gives a tracker that records nothing (``--no-track``).
    uri : str or None
        Tracking URI; None uses :func:`default_tracking_uri`.
    experiment : str
        Experiment name (created on first use, artifacts beside the store).
    """

    def __init__(self, *, enabled: bool = True, uri: str | None = None,
                 experiment: str = "thermonet") -> None:
        self.enabled = enabled
        self.uri = uri or default_tracking_uri()
        self.experiment = experiment
        self._mlflow: Any = None
        if enabled:   # a store that cannot be one, refused before any work
            check_store(self.uri)

    # ------------------------------------------------------------- set-up
    def _client(self) -> Any:
        if self._mlflow is None:
            import mlflow  # imported lazily: it costs ~2 s and --no-track never needs it

            logging.getLogger("mlflow").setLevel(logging.WARNING)
            logging.getLogger("alembic").setLevel(logging.WARNING)
            mlflow.set_tracking_uri(self.uri)
            # Two processes creating a new SQLite store at once race in its schema
            # migrations ("table already exists"): one creates, the other waits.
            with _store_lock(self.uri):
                if _retry(mlflow.get_experiment_by_name, self.experiment) is None:
                    artifact_location = None
                    if self.uri.startswith("sqlite:///"):
                        store = Path(self.uri[len("sqlite:///"):])
                        artifact_location = (store.parent / "mlruns").resolve().as_uri()
                    _retry(mlflow.create_experiment, self.experiment,
                           artifact_location=artifact_location)
            _retry(mlflow.set_experiment, self.experiment)
            try:
                tidy_orphaned_runs(self.uri, self.experiment)
            except Exception as err:  # noqa: BLE001 - tidying is best effort, never fatal
                _log.warning("could not tidy orphaned runs: %s", str(err).splitlines()[0])
            self._mlflow = mlflow
        return self._mlflow

    # --------------------------------------------------------------- runs
    @contextmanager
    def run(self, name: str, *, params: Mapping[str, Any] | None = None,
            tags: Mapping[str, str] | None = None, nested: bool = False) -> Iterator[str | None]:
        """Open a (nested) run; yields its run id (None when disabled)."""
        if not self.enabled:
            yield None
            return
        mlflow = self._client()
        active = _retry(mlflow.start_run, run_name=name, nested=nested,
                        tags={HOST_TAG: socket.gethostname(), PID_TAG: str(os.getpid())})
        # Not ``with start_run``: its exit ends whichever run is active as FAILED, which
        # after an interrupted nested run would be the parent.
        status = "FINISHED"
        try:
            if params:
                _retry(mlflow.log_params, flatten_params(params))
            if tags:
                _retry(mlflow.set_tags, {k: str(v) for k, v in tags.items()})
            yield active.info.run_id
        except (KeyboardInterrupt, Interrupted):
            status = "KILLED"
            raise
        except BaseException:
            status = "FAILED"
            raise
        finally:
            _retry(mlflow.end_run, status)

    def log_history(self, history: list[Mapping[str, float]]) -> None:
        """Per-epoch losses, sent in batches (one call per 1000 values, not one per epoch)."""
        if not self.enabled or not history:
            return
        mlflow = self._client()
        from mlflow.entities import Metric

        run_id = mlflow.active_run().info.run_id
        client = mlflow.tracking.MlflowClient()
        batch: list[Any] = []
        now = 0
        for row in history:
            step = int(row["epoch"])
            for key, name in (("train_loss", "train/loss"), ("val_loss", "val/loss"),
                              ("refit_loss", "refit/loss")):
                value = row.get(key)
                if value is not None and math.isfinite(value):
                    batch.append(Metric(name, float(value), now, step))
            if len(batch) >= 900:
                _retry(client.log_batch, run_id, metrics=batch)
                batch = []
        if batch:
            _retry(client.log_batch, run_id, metrics=batch)

    def log_metrics(self, metrics: Mapping[str, float]) -> None:
        """Final metrics; non-finite values are skipped (MLflow cannot store NaN usefully)."""
        if not self.enabled:
            return
        clean = {k: float(v) for k, v in metrics.items()
                 if isinstance(v, (int, float)) and math.isfinite(float(v))}
        if clean:
            _retry(self._client().log_metrics, clean)

    def set_tags(self, tags: Mapping[str, Any]) -> None:
        if self.enabled:
            _retry(self._client().set_tags, {k: str(v) for k, v in tags.items()})

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        if self.enabled:
            _retry(self._client().log_artifact, str(path), artifact_path=artifact_path)


@contextmanager
def global_tracking_uri(uri: str) -> Iterator[None]:
    """MLflow's global tracking URI set to ``uri`` meanwhile, then restored.  MLflow's fluent
    API, and its resolution of a run's logged model, go through the global URI (which MLflow
    also keeps in ``MLFLOW_TRACKING_URI``) whatever store a client was given."""
    import mlflow

    previous = mlflow.get_tracking_uri()
    mlflow.set_tracking_uri(uri)
    try:
        yield
    finally:
        mlflow.set_tracking_uri(previous)
