"""Experiment tracking: the one module that calls MLflow.

Every ``compare`` / ``train`` run is recorded in an embedded store in the
working directory (``sqlite:///mlflow.db``, artifacts under ``mlruns/``; no
server).  A comparison is a parent run with one nested run per family.
Metric keys are namespaced: ``train/loss``, ``val/loss`` per epoch;
``test/<axis>/<metric>`` at the end.  ``--no-track`` gives a :class:`Tracker`
whose methods do nothing; ``--tracking-uri`` points at a team server.

Open the runs with ``mlflow ui --backend-store-uri sqlite:///mlflow.db``.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["Tracker", "default_tracking_uri", "flatten_params"]

_log = logging.getLogger(__name__)

# MLflow refuses param values over this many characters.
_MAX_PARAM_LEN = 6000
# Characters MLflow refuses in a param name (a limits key "*", say) become "_".
_BAD_PARAM_CHARS = re.compile(r"[^\w\-. :/]")


def default_tracking_uri(workdir: str | Path | None = None) -> str:
    """``sqlite:///<workdir>/mlflow.db`` (absolute, so a later ``cd`` does not move it)."""
    root = Path(workdir or os.getcwd()).resolve()
    return f"sqlite:///{root / 'mlflow.db'}"


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

    # ------------------------------------------------------------- set-up
    def _client(self) -> Any:
        if self._mlflow is None:
            import mlflow  # imported lazily: it costs ~2 s and --no-track never needs it

            logging.getLogger("mlflow").setLevel(logging.WARNING)
            logging.getLogger("alembic").setLevel(logging.WARNING)
            mlflow.set_tracking_uri(self.uri)
            if mlflow.get_experiment_by_name(self.experiment) is None:
                artifact_location = None
                if self.uri.startswith("sqlite:///"):
                    store = Path(self.uri[len("sqlite:///"):])
                    artifact_location = (store.parent / "mlruns").resolve().as_uri()
                mlflow.create_experiment(self.experiment, artifact_location=artifact_location)
            mlflow.set_experiment(self.experiment)
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
        with mlflow.start_run(run_name=name, nested=nested) as active:
            if params:
                mlflow.log_params(flatten_params(params))
            if tags:
                mlflow.set_tags({k: str(v) for k, v in tags.items()})
            yield active.info.run_id

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
            for key, name in (("train_loss", "train/loss"), ("val_loss", "val/loss")):
                value = row.get(key)
                if value is not None and math.isfinite(value):
                    batch.append(Metric(name, float(value), now, step))
            if len(batch) >= 900:
                client.log_batch(run_id, metrics=batch)
                batch = []
        if batch:
            client.log_batch(run_id, metrics=batch)

    def log_metrics(self, metrics: Mapping[str, float]) -> None:
        """Final metrics; non-finite values are skipped (MLflow cannot store NaN usefully)."""
        if not self.enabled:
            return
        clean = {k: float(v) for k, v in metrics.items()
                 if isinstance(v, (int, float)) and math.isfinite(float(v))}
        if clean:
            self._client().log_metrics(clean)

    def set_tags(self, tags: Mapping[str, Any]) -> None:
        if self.enabled:
            self._client().set_tags({k: str(v) for k, v in tags.items()})

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        if self.enabled:
            self._client().log_artifact(str(path), artifact_path=artifact_path)
