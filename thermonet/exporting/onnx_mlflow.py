"""An exported ONNX file logged to MLflow as an MLflow ONNX model (``runs:/<id>/model``: its
``MLmodel`` descriptor, signature, an input example across the trained range and explicit pip
requirements; :func:`log_onnx_model`), optionally registered and aliased
:data:`CHOSEN_ALIAS`; :func:`log_onnx_to_mlflow` also logs the file itself as an artifact.
MLflow, onnx and onnxruntime are imported only when a model is logged.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ExportError
from ..tracking import global_tracking_uri

__all__ = ["MLFLOW_MODEL_NAME", "CHOSEN_ALIAS", "mlflow_input_example", "log_onnx_model",
           "log_onnx_to_mlflow"]

#: The MLflow model name a thermonet run's ONNX model is logged under: ``runs:/<id>/model``.
MLFLOW_MODEL_NAME = "model"
#: The alias a registered version gets when ``compare`` chose it (``models:/NAME@chosen``).
CHOSEN_ALIAS = "chosen"
#: Rows of the input example logged with the model.
_EXAMPLE_ROWS = 5


def mlflow_input_example(path: str | Path) -> dict[str, np.ndarray]:
    """An input the ONNX graph at ``path`` takes, as a dict of arrays: each signal across its
    trained range (metadata ``trained_range``; ``time_s`` 0, 1, 2 … s), raw outputs 0."""
    import onnx

    model = onnx.load(str(path), load_external_data=False)
    meta = {p.key: p.value for p in model.metadata_props}
    ranges = json.loads(meta.get("trained_range", "{}") or "{}")
    dtypes = {1: np.float32, 11: np.float64}
    feeds: dict[str, np.ndarray] = {}
    for inp in model.graph.input:
        t = inp.type.tensor_type
        dims = [d.dim_value if d.dim_value else _EXAMPLE_ROWS for d in t.shape.dim]
        dtype = dtypes.get(t.elem_type, np.float32)
        if inp.name in ranges:
            lo, hi = (float(v) for v in ranges[inp.name])
            col = np.linspace(lo, hi, _EXAMPLE_ROWS)
            feeds[inp.name] = np.broadcast_to(col.reshape(-1, *[1] * (len(dims) - 1)),
                                              dims).astype(dtype)
        elif inp.name == "time_s":
            feeds[inp.name] = np.arange(_EXAMPLE_ROWS, dtype=dtype).reshape(dims)
        else:
            feeds[inp.name] = np.zeros(dims, dtype=dtype)
    return feeds


def _pip_requirements() -> list[str]:
    """What the logged model needs to run (given, not inferred: MLflow's inference of them
    loads the model in a subprocess, which takes longer than the logging itself)."""
    from importlib.metadata import version

    return [f"{name}=={version(name)}" for name in ("onnx", "onnxruntime", "numpy")]


def log_onnx_model(path: str | Path, run_id: str, tracking_uri: str, *,
                   name: str = MLFLOW_MODEL_NAME, register: str | None = None) -> Any:
    """Log the exported graph at ``path`` to MLflow run ``run_id`` as an MLflow ONNX model
    named ``name`` (default ``model``: ``mlflow.pyfunc.load_model("runs:/<id>/model")`` loads
    it), with its signature and an input example (:func:`mlflow_input_example`, the graph's
    own outputs on it) and explicit pip requirements, served on the CPU.  ``register``:
    also register it under that name, the new version aliased :data:`CHOSEN_ALIAS`.  The run
    may be the active one (``compare``'s) or any other; the global tracking URI is restored.
    Returns MLflow's ``ModelInfo``."""
    import mlflow
    import mlflow.onnx
    import onnx
    import onnxruntime as ort
    from mlflow.models import infer_signature

    path = Path(path)
    if not path.is_file():
        raise ExportError(f"{path}: no such ONNX file to log")
    example = mlflow_input_example(path)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    outputs = dict(zip([o.name for o in session.get_outputs()],
                       session.run(None, example), strict=True))
    signature = infer_signature(example, outputs)
    with global_tracking_uri(tracking_uri):
        active = mlflow.active_run()
        own = active is None or active.info.run_id != run_id
        if own:
            mlflow.start_run(run_id=run_id, nested=active is not None)
        try:
            info = mlflow.onnx.log_model(
                onnx.load(str(path)), name=name, signature=signature, input_example=example,
                pip_requirements=_pip_requirements(),
                onnx_execution_providers=["CPUExecutionProvider"],
                registered_model_name=register)
        finally:
            if own:
                mlflow.end_run()
        if register:
            version = getattr(info, "registered_model_version", None)
            if version is not None:
                mlflow.MlflowClient(tracking_uri=tracking_uri).set_registered_model_alias(
                    register, CHOSEN_ALIAS, str(version))
        return info


def log_onnx_to_mlflow(path: str | Path, run_id: str, tracking_uri: str, *,
                       artifact_path: str = "onnx") -> None:
    """Log an exported file to an existing MLflow run, as a file and as an ONNX model.

    The file goes under ``<artifact_path>/`` as is; :func:`log_onnx_model` adds the MLflow
    model ``model`` (its ``MLmodel`` descriptor, signature and input example), so that
    ``mlflow.pyfunc.load_model("runs:/<run_id>/model")`` and ``mlflow.onnx.load_model`` read it.
    """
    import mlflow

    path = Path(path)
    if not path.is_file():
        raise ExportError(f"{path}: no such ONNX file to log")
    client = mlflow.MlflowClient(tracking_uri=tracking_uri)
    client.log_artifact(run_id, str(path), artifact_path=artifact_path)
    log_onnx_model(path, run_id, tracking_uri)
