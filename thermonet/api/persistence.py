"""Saving, loading, exporting and tracking a :class:`~thermonet.api.DriftEstimator`: its fitted
model as a thermonet checkpoint (what ``compare`` writes too), through the export registry,
and as an MLflow run (see :mod:`thermonet.api`)."""

from __future__ import annotations

import math
import os
from dataclasses import asdict
from pathlib import Path
from typing import Any

from ..core.trainconfig import TrainConfig
from ..exporting import ExportRequest, get_format
from ..exporting.source import onnx_of_checkpoint
from ..features.target import FOUR_POSITION, Target
from ..scoring.band import Band
from ..tracking import Tracker
from ..training.parameters import parameter_table, sealed_parameters, with_sealed
from .state import EstimatorState, State

__all__ = ["checkpoint_config", "extra", "fitted_hyper", "save", "load", "export", "track"]


def _family_of(est: EstimatorState) -> tuple[str, dict[str, Any]]:
    """The family's registry name and hyper-parameters (a name alone, such as a loaded
    per-axis model's ``per-axis``, has none of its own)."""
    if isinstance(est.family, str):
        return est.family, {}
    spec = est._family_spec()
    return spec.key, spec.hyper()


def checkpoint_config(est: EstimatorState) -> dict[str, Any]:
    """The family's resolved configuration, as a checkpoint stores it."""
    name, params = _family_of(est)
    return {
        "family": {"family": name, "inputs": list(est.spec_.inputs),
                   "params": params, "train_on": est.train_on},
        "train": asdict(est.train_config_),
        "features": {"t_ref": est.t_ref, "t_ref_window_min": est.t_ref_window_min,
                     "gap_s": est.gap_s},
        "target": est.target,
    }

def extra(est: EstimatorState) -> dict[str, Any]:
    extra: dict[str, Any] = {"units": est.units_, "signal_units": est.signal_units_,
                             "device_id": est.device_id_, "history": est.history_,
                             "mlflow_run_id": est.__dict__.get("mlflow_run_id_", "")}
    if est.__dict__.get("tuned_"):   # what the family chose itself (RBF: width, ridges)
        extra["tuned"] = dict(est.tuned_)
    if "parameters_" in est.__dict__:   # the standard errors the fit computed, sealed with it
        extra["parameters"] = sealed_parameters(est.parameters_, est.covariance_, est.stderr)
    if est.__dict__.get("val_score_") is not None:   # the validation metrics, as compare's
        extra.update(val_score=est.val_score_, val_ratios=dict(est.val_ratios_ or {}))
    if est.__dict__.get("band_") is not None:   # compare's band, kept through save
        extra["band"] = {"status": "ok", **est.band_.to_json()}
    source = getattr(est, "data_source_", None)  # an estimator made by load() has none
    if source is not None:  # provenance: what it was fitted on (as compare records it)
        extra.update(data_hash=source["data_hash"], provenance={"data": source})
    return extra

def fitted_hyper(hyper: dict[str, Any], tuned: dict[str, Any]) -> dict[str, Any]:
    """The family's hyper-parameters as the model was fitted with them: each value the family
    tuned itself (``tuned``: the RBF's ``width_scale``; its ``ridge`` where every axis chose the
    same finite one) replaces the configured one, so that ``get_params`` of a loaded estimator
    states what ``results.json`` says was chosen (``tuned_`` keeps the per-axis choices)."""
    out = dict(hyper)
    for key, value in tuned.items():
        if key not in out:
            continue
        if isinstance(value, list) and value and all(v == value[0] for v in value):
            value = value[0]
        if isinstance(value, (int, float)) and not isinstance(value, bool) \
                and math.isfinite(value):
            out[key] = value
    return out


def save(est: EstimatorState, path: str | os.PathLike[str]) -> Path:
    """Write the fitted model as a thermonet checkpoint (atomic; loads with
    ``weights_only=True``; ``thermonet export`` reads it)."""
    model = est._check_fitted("save")
    from ..training.checkpoint import save_checkpoint  # torch boundary

    return save_checkpoint(path, model, config=checkpoint_config(est), extra=extra(est),
                           epoch=est.best_epoch_, best_val=est.best_val_)

def load(cls: type[State], path: str | os.PathLike[str]) -> State:
    """An estimator fitted as the checkpoint at ``path`` (also one ``compare`` wrote)."""
    from ..training.checkpoint import load_checkpoint  # torch boundary
    from ..training.config import from_dict  # lazy: importing it loads yaml

    model, meta = load_checkpoint(path)
    config = meta.get("config") or {}
    fam = config.get("family") or {}
    features = config.get("features") or {}
    extra = meta.get("extra") or {}
    train = from_dict(TrainConfig, config.get("train") or {}, source=str(path),
                      prefix="config.train")
    stored = extra.get("tuned")
    tuned: dict[str, Any] = dict(stored) if isinstance(stored, dict) else {}
    est = cls(meta["family"], list(meta["inputs"]),
              t_ref=features.get("t_ref", "start"), target=config.get("target", "drift"),
              train=train, outputs=list(meta["outputs"]),
              train_on=fam.get("train_on", "all"),
              gap_s=features.get("gap_s", "auto"),
              t_ref_window_min=float(features.get("t_ref_window_min", 10.0)),
              **fitted_hyper(dict(meta["hyper"]), tuned))
    est.tuned_ = dict(tuned)
    est.model_ = model
    est.spec_ = model.spec
    est.outputs_ = list(meta["outputs"])
    est.units_ = dict(extra.get("units") or {})
    est.signal_units_ = dict(extra.get("signal_units") or {})
    est.device_id_ = str(extra.get("device_id", ""))
    est.train_config_ = train
    est.history_ = list(extra.get("history") or [])
    est.val_score_ = extra.get("val_score")
    est.val_ratios_ = extra.get("val_ratios")
    est.mlflow_run_id_ = str(extra.get("mlflow_run_id") or "")

    est.band_ = Band.from_json(extra["band"]) if isinstance(extra.get("band"), dict) else None
    prov = extra.get("provenance")
    source = prov.get("data") if isinstance(prov, dict) else None
    if isinstance(source, dict):  # kept, so that saving it again keeps the record
        est.data_source_ = {**source, "data_hash": str(extra.get("data_hash") or "")}
    est.n_features_in_ = len(model.spec.inputs)

    modes = model.target_modes
    est.targets_ = Target(list(meta["outputs"]), modes,
                          kind=FOUR_POSITION if FOUR_POSITION in modes else "drift")

    table, cov = parameter_table(model, est.units_, est.signal_units_)
    # the standard errors the fit computed on its training data (stored with the model)
    est.parameters_, est.covariance_, method = with_sealed(table, cov, extra.get("parameters"),
                                                           str(path))
    if method is not None:     # how they were computed, as get_params reports it
        est.stderr = method
    est.best_epoch_ = int(meta["epoch"]) if meta.get("epoch") is not None else 0
    est.best_val_ = meta.get("best_val")
    est.n_params_ = int(model.n_params)
    est.fit_seconds_ = float("nan")
    return est

def export(est: EstimatorState, path: str | os.PathLike[str], format: str = "onnx", *,
           device_id: int | None = None, instance: int | None = None) -> Path:
    """Export through the format registry (:data:`thermonet.exporting.FORMATS`).

    ``device_id``/``instance`` apply to the autopilot formats (see
    ``thermonet export --help``).
    """
    model = est._check_fitted("export")

    meta = {"config": checkpoint_config(est), "extra": extra(est)}
    return get_format(format).write(model, Path(path), ExportRequest(
        meta=meta, device_id=device_id, instance=instance))


def track(est: EstimatorState, uri: str | None, experiment: str) -> None:
    """Log this fit to MLflow (one run: parameters, history, metrics, the checkpoint)."""
    import json
    import tempfile

    tracker = Tracker(enabled=True, uri=uri, experiment=experiment)
    # the family by name and its hyper-parameters by their own names, as compare logs them
    name, hyper = _family_of(est)
    own = {k: v for k, v in est.get_params(deep=False).items() if k != "family"}
    params = json.loads(json.dumps({k: v for k, v in {"family": name, **own, **hyper}.items()
                                    if v is not None}, default=repr))
    tags = {"device": est.device_id_, "data_hash": est.data_source_["data_hash"],
            "family": name, "source": "thermonet.api"}
    with tracker.run(f"fit-{name}", params=params, tags=tags) as run_id:
        est.mlflow_run_id_ = run_id or ""
        tracker.log_history(list(est.history_))
        metrics = {"fit_seconds": est.fit_seconds_, "n_params": float(est.n_params_)}
        if est.val_score_ is not None:
            metrics["val/score"] = est.val_score_
            metrics.update({f"val/{a}/score_ratio": r
                            for a, r in (est.val_ratios_ or {}).items()})
        tracker.log_metrics(metrics)
        with tempfile.TemporaryDirectory() as tmp:
            ckpt = est.save(Path(tmp) / f"{name}.pt")
            tracker.log_artifact(ckpt, "model")
            # the MLflow model users load: runs:/<id>/model (ONNX, signature, input example)
            from ..exporting.onnx_mlflow import log_onnx_model  # lazy: only where a fit is tracked

            log_onnx_model(onnx_of_checkpoint(ckpt, Path(tmp) / f"{name}.onnx"),
                           run_id or "", tracker.uri)
