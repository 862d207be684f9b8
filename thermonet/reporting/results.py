"""Typed records of a comparison and the ``results.json`` schema they serialise to.

``results.json`` schema, version 2 (:data:`SCHEMA`)::

    {
      "schema": 2,
      "thermonet_version": str,
      "config": {...resolved config...},
      "device": str, "data_hash": str, "target": "drift" | "four-position",
      "split": {"strategy": str, "folds": [{"train": ..., "val": ..., "test": ...}]},
      "units": {axis: unit},
      "targets": {axis: "channel" | "zero" | "at-t-ref" | "four-position"},  # thermonet.features.target
      "data": {"runs": [{"run_id", "samples", "duration_s", "rate_hz",
                         "temperature_min_c", "temperature_max_c",
                         "rows", "window_s"}],     # rows, window_s: streamed runs only
               "outside_trained_range": {signal: fraction of test samples},
               "trained_range": {signal: [lo, hi]},
               "streamed": {"samples", "rows", "window_s", "chunk_rows", "method"}},
               # "streamed": only where the files were streamed (thermonet.features.windows)
      "bootstrap": {"method": str, "resamples": int, "level": 0.95, "seed": int,
                    "blocks": {"val": int, "test": int}},
      "chosen": name | null,          # by validation score (per-axis masked), ties → fewest params
      "chosen_reason": str,           # why (or why none: "do no harm")
      "tie": [names],                 # families tied with the best (empty: no tie)
      "uncompensated_axes": [axis],   # axes the chosen model leaves alone (drift 0)
      "baseline": name | null,        # PX4/ArduPilot's cubic by default
      "warnings": [str],              # plain sentences, also printed
      "families": {
        name: {
          "family": registry key, "inputs": [...], "params": {...}, "train_on": str,
          "status": "ok" | "failed", "reason": str | null,
          "fit_seconds": s, "n_params": k, "best_epoch": int,
          "tuned": {...},              # hyper-parameters the family chose on its training
                                       # data (the RBF tail's width and ridge per axis)
          "cost": {"ops_per_sample", "transcendentals", "c_bytes"},   # on board, per sample
                                       # (thermonet.models.base.Family.cost; null: unknown)
          "val_score": float,          # mean over axes of the validation score ratio, 1 where
                                       # the axis is left uncompensated (< 1 beats raw)
          "val_interval": [lo, hi],    # its 95 % block-bootstrap interval
          "test_score": float,         # the same on the test data
          "compensate_in_model": bool, # the model carries the per-axis mask itself
          "checkpoint": path | null, "mlflow_run_id": str | null,
          "outside_trained_range": {signal: fraction},
          "axes": {axis: {
              "score_raw", "score_comp",        # offset-free test scores, units of the axis
              "score_ratio", "interval": [lo, hi], "verdict": "better"|"worse"|"indistinguishable",
              "val_ratio", "val_interval", "val_verdict",
              "compensate": bool,               # validation verdict was "better"
              "vs_baseline": {"ratio", "interval", "verdict"} | null,
              "offset_raw", "offset_comp" (only where the reference makes them meaningful),
              ...the field's metrics as information: "rms_raw", "rms_comp", "pp_raw", "pp_comp",
              "msd_raw", "msd_comp", "noise_floor", "bias_instability_raw",
              "bias_instability_comp", "drift_error_rms" (simulated data), "ppm_per_c_raw",
              "ppm_per_c_comp" (scale-factor outputs), "pp_ratio_vs_baseline"}},
          "folds": [per-fold metrics] (leave-one-run-out only)
        }
      },
      "mlflow_run_id": str | null,
      "provenance": {                   # what was actually used (thermonet.workflows.compare)
        "data": {"kind": "files", "files": [{"path", "sha256"}], "mapping": {...} | null}
              | {"kind": "simulated", "preset", "runs", "seed"}
              | {"kind": "dataset", "device", "runs", "preset", "sources"},
        "tracking": {"enabled", "uri", "experiment"}, "options": {...as given...},
        "thermonet_version": str}
    }

Non-finite floats are written as ``null``.  Schema 1 (before the offset-free
score) had ``val_score`` as an msd ratio and no verdicts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["SCHEMA", "Verdict", "AxisResult", "FamilyResult", "ComparisonResult", "clean"]

#: Version of the ``results.json`` layout written by this module.
SCHEMA = 2


def clean(obj: Any) -> Any:
    """JSON-ready copy: non-finite floats → None, numpy scalars → Python."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return clean(obj.tolist())
    if isinstance(obj, np.generic):
        return clean(obj.item())
    return obj


@dataclass
class Verdict:
    """Score ratio of a family against raw (or the baseline), with its bootstrap interval."""

    ratio: float
    low: float
    high: float
    verdict: str

    def to_json(self) -> dict[str, Any]:
        return {"ratio": self.ratio, "interval": [self.low, self.high], "verdict": self.verdict}


@dataclass
class AxisResult:
    """One family on one axis of the held-out data."""

    score_raw: float
    score_comp: float
    test: Verdict
    val: Verdict
    compensate: bool
    vs_baseline: Verdict | None = None
    offset_raw: float | None = None
    offset_comp: float | None = None
    metrics: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = dict(self.metrics)
        d.update(score_raw=self.score_raw, score_comp=self.score_comp,
                 score_ratio=self.test.ratio, interval=[self.test.low, self.test.high],
                 verdict=self.test.verdict, val_ratio=self.val.ratio,
                 val_interval=[self.val.low, self.val.high], val_verdict=self.val.verdict,
                 compensate=self.compensate,
                 vs_baseline=self.vs_baseline.to_json() if self.vs_baseline else None)
        if self.offset_raw is not None:
            d.update(offset_raw=self.offset_raw, offset_comp=self.offset_comp)
        return d


@dataclass
class FamilyResult:
    """One configured family: how it was fitted and how it did, per axis."""

    label: str
    family: str
    inputs: list[str]
    params: dict[str, Any]
    train_on: str
    status: str = "ok"
    reason: str | None = None
    fit_seconds: float = float("nan")
    n_params: int = 0
    best_epoch: int = 0
    val_score: float = float("nan")
    val_interval: tuple[float, float] = (float("nan"), float("nan"))
    test_score: float = float("nan")
    compensate_in_model: bool = False
    checkpoint: str | None = None
    mlflow_run_id: str | None = None
    outside_trained_range: dict[str, float] = field(default_factory=dict)
    axes: dict[str, AxisResult] = field(default_factory=dict)
    folds: list[dict[str, dict[str, float]]] | None = None
    tuned: dict[str, Any] = field(default_factory=dict)   # what the family chose itself
    cost: dict[str, int | None] | None = None             # Family.cost(): per sample on board
    band: dict[str, Any] | None = None   # the residual-drift band (thermonet.scoring.band)

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"family": self.family, "inputs": list(self.inputs),
                             "params": dict(self.params), "train_on": self.train_on,
                             "status": self.status, "reason": self.reason,
                             "checkpoint": self.checkpoint, "mlflow_run_id": self.mlflow_run_id}
        if not self.ok:
            return d
        d.update(fit_seconds=self.fit_seconds, n_params=self.n_params,
                 best_epoch=self.best_epoch, val_score=self.val_score,
                 val_interval=list(self.val_interval), test_score=self.test_score,
                 compensate_in_model=self.compensate_in_model,
                 outside_trained_range=dict(self.outside_trained_range),
                 tuned=dict(self.tuned), cost=None if self.cost is None else dict(self.cost),
                 axes={a: r.to_json() for a, r in self.axes.items()})
        if self.folds is not None:
            d["folds"] = self.folds
        if self.band is not None:
            d["band"] = self.band
        return d


@dataclass
class ComparisonResult:
    """A whole comparison; :meth:`to_json` gives the ``results.json`` document."""

    config: dict[str, Any]
    device: str
    data_hash: str
    target: str
    split: dict[str, Any]
    units: dict[str, str]
    baseline: str | None
    targets: dict[str, str] = field(default_factory=dict)
    data: dict[str, Any] = field(default_factory=dict)
    bootstrap: dict[str, Any] = field(default_factory=dict)
    families: dict[str, FamilyResult] = field(default_factory=dict)
    chosen: str | None = None
    chosen_reason: str = ""
    selection: dict[str, Any] = field(default_factory=dict)   # thermonet.scoring.selection's record
    tie: list[str] = field(default_factory=list)
    uncompensated_axes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    mlflow_run_id: str | None = None
    thermonet_version: str = ""

    def warn(self, text: str) -> None:
        """Add one warning (a plain sentence naming the axis, signal or key), once."""
        if text not in self.warnings:
            self.warnings.append(text)

    def to_json(self) -> dict[str, Any]:
        return clean({
            "schema": SCHEMA, "thermonet_version": self.thermonet_version,
            "config": self.config, "device": self.device, "data_hash": self.data_hash,
            "target": self.target, "split": self.split, "units": self.units,
            "targets": dict(self.targets), "data": self.data, "bootstrap": self.bootstrap,
            "chosen": self.chosen,
            "chosen_reason": self.chosen_reason, "tie": list(self.tie),
            "selection": self.selection,
            "uncompensated_axes": list(self.uncompensated_axes), "baseline": self.baseline,
            "warnings": list(self.warnings),
            "families": {k: f.to_json() for k, f in self.families.items()},
            "mlflow_run_id": self.mlflow_run_id,
        })
