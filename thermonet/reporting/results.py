"""Typed records of a comparison and the ``results.json`` schema they serialise to.

``results.json`` schema, version 3 (:data:`SCHEMA`)::

    {
      "schema": 3,
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
      "selection": {...},               # how the choice was made (thermonet.scoring.selection):
                                        # folds, candidates, gate, "held_back": {"candidates",
                                        # "why", "by_candidate"}, "per_axis": {"chosen": {axis:
                                        # label | null}, "rule", "candidates", "gate"}
      "band": {"model": name, ...} | absent,   # the shipped model's band (= its family's)
      "mlflow_run_id": str | null,
      "provenance": {                   # what was actually used (thermonet.workflows.compare)
        "data": {"kind": "files", "files": [{"path", "sha256"}], "mapping": {...} | null}
              | {"kind": "simulated", "preset", "runs", "seed"}
              | {"kind": "dataset", "device", "runs", "preset", "sources"},
        "tracking": {"enabled", "uri", "experiment"}, "options": {...as given...},
        "thermonet_version": str}
    }

Non-finite floats are written as ``null``.  Schema 1 (before the offset-free
score) had ``val_score`` as an msd ratio and no verdicts.  Schema 2 also named the per-axis
model a third time, a top-level ``per_axis`` block (checkpoint, axes, candidates): schema 3
names it once, ``families["per-axis"]`` (its checkpoint, ``checkpoint_sha256`` and
``params.axes``) with ``selection.per_axis`` (the choice per axis, the candidates).
:meth:`ComparisonResult.from_json` reads schemas 2 and 3 into the same typed objects (a
schema-2 ``per_axis`` block is read and dropped: everything in it is in the other two).

The typed result is the one source: a comparison builds a :class:`ComparisonResult`, its
consumers in the same process (the console's table, the report, the figures, calibrate,
learn, fleet, the API) read it as objects, and ``results.json`` is :meth:`~ComparisonResult.to_json`,
written at the edge; a document from elsewhere (a file, a hand-written dict) is parsed once
where it enters (:func:`read_result`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["SCHEMA", "READABLE_SCHEMAS", "Verdict", "AxisResult", "FamilyResult", "ComparisonResult",
           "clean", "read_result"]

#: Version of the ``results.json`` layout written by this module.
SCHEMA = 3
#: The versions :meth:`ComparisonResult.from_json` reads.
READABLE_SCHEMAS = (2, 3)


def _num(v: Any) -> float:
    """A float read back from results.json (``null``: a non-finite value was written)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return float("nan")
    return float(v)


def _count(v: Any) -> int:
    """A count read back from results.json (0 where it is missing or not a number)."""
    x = _num(v)
    return int(x) if math.isfinite(x) else 0


def _pair(v: Any) -> tuple[float, float]:
    lo, hi = ((list(v) if isinstance(v, (list, tuple)) else []) + [None, None])[:2]
    return _num(lo), _num(hi)


def _dict(v: Any) -> dict[str, Any]:
    return dict(v) if isinstance(v, dict) else {}


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

    @classmethod
    def from_json(cls, d: Any) -> Verdict:
        d = _dict(d)
        lo, hi = _pair(d.get("interval"))
        return cls(_num(d.get("ratio")), lo, hi, str(d.get("verdict") or ""))


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

    #: The keys :meth:`to_json` writes from the typed fields (the rest are ``metrics``).
    _TYPED = ("score_raw", "score_comp", "score_ratio", "interval", "verdict", "val_ratio",
              "val_interval", "val_verdict", "compensate", "vs_baseline", "offset_raw",
              "offset_comp")

    @classmethod
    def from_json(cls, d: Any) -> AxisResult:
        d = _dict(d)
        lo, hi = _pair(d.get("interval"))
        vlo, vhi = _pair(d.get("val_interval"))
        vs = d.get("vs_baseline")
        return cls(score_raw=_num(d.get("score_raw")), score_comp=_num(d.get("score_comp")),
                   test=Verdict(_num(d.get("score_ratio")), lo, hi, str(d.get("verdict") or "")),
                   val=Verdict(_num(d.get("val_ratio")), vlo, vhi,
                               str(d.get("val_verdict") or "")),
                   compensate=bool(d.get("compensate")),
                   vs_baseline=Verdict.from_json(vs) if isinstance(vs, dict) else None,
                   # present (null: not finite) where the reference makes offsets meaningful
                   offset_raw=_num(d["offset_raw"]) if "offset_raw" in d else None,
                   offset_comp=_num(d.get("offset_comp")) if "offset_raw" in d else None,
                   metrics={k: v for k, v in d.items() if k not in cls._TYPED})

    @property
    def score_ratio(self) -> float:
        """The held-out test score, this family / raw (< 1 better)."""
        return self.test.ratio

    @property
    def interval(self) -> tuple[float, float]:
        """Its 95 % block-bootstrap interval."""
        return (self.test.low, self.test.high)

    @property
    def verdict(self) -> str:
        """``better``, ``worse`` or ``indistinguishable`` against raw on the test data."""
        return self.test.verdict


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
    checkpoint_sha256: str | None = None  # added where the output directory is finished

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def name(self) -> str:
        """The family's label in the comparison (``families[name]``)."""
        return self.label

    @classmethod
    def from_json(cls, label: str, d: Any) -> FamilyResult:
        d = _dict(d)
        folds = d.get("folds")
        cost = d.get("cost")
        band = d.get("band")
        sha = d.get("checkpoint_sha256")
        return cls(label=label, family=str(d.get("family") or ""),
                   inputs=[str(x) for x in d.get("inputs") or []], params=_dict(d.get("params")),
                   train_on=str(d.get("train_on") or ""), status=str(d.get("status") or ""),
                   reason=None if d.get("reason") is None else str(d.get("reason")),
                   fit_seconds=_num(d.get("fit_seconds")),
                   n_params=_count(d.get("n_params")), best_epoch=_count(d.get("best_epoch")),
                   val_score=_num(d.get("val_score")), val_interval=_pair(d.get("val_interval")),
                   test_score=_num(d.get("test_score")),
                   compensate_in_model=bool(d.get("compensate_in_model")),
                   checkpoint=None if d.get("checkpoint") is None else str(d.get("checkpoint")),
                   mlflow_run_id=d.get("mlflow_run_id") or None,
                   outside_trained_range={k: _num(v) for k, v in
                                          _dict(d.get("outside_trained_range")).items()},
                   axes={a: AxisResult.from_json(x) for a, x in _dict(d.get("axes")).items()},
                   folds=list(folds) if isinstance(folds, list) else None,
                   tuned=_dict(d.get("tuned")), cost=dict(cost) if isinstance(cost, dict) else None,
                   band=dict(band) if isinstance(band, dict) else None,
                   checkpoint_sha256=str(sha) if isinstance(sha, str) else None)

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
        if self.checkpoint_sha256 is not None:
            d["checkpoint_sha256"] = self.checkpoint_sha256
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
    band: dict[str, Any] | None = None          # the shipped model's: {"model": name, ...}
    provenance: dict[str, Any] = field(default_factory=dict)  # what was actually used
    schema: int = SCHEMA                        # the version read (from_json), else written

    def warn(self, text: str) -> None:
        """Add one warning (a plain sentence naming the axis, signal or key), once."""
        if text not in self.warnings:
            self.warnings.append(text)

    def settle(self) -> None:
        """The free-form parts as ``results.json`` holds them (:func:`clean`: lists, Python
        numbers, ``None`` for a non-finite one): the config, split, data, bootstrap, selection,
        band and provenance, each family's params, tuned values, cost, band and folds and each
        axis's metrics.  Once the comparison is judged, what a consumer reads of the result in
        the same process is what it would read back from the file."""
        for name in ("config", "split", "data", "bootstrap", "selection", "provenance"):
            setattr(self, name, clean(getattr(self, name)))
        self.band = clean(self.band)
        for f in self.families.values():
            f.params, f.tuned, f.cost = clean(f.params), clean(f.tuned), clean(f.cost)
            f.band, f.folds = clean(f.band), clean(f.folds)
            for a in f.axes.values():
                a.metrics = clean(a.metrics)

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
            **({"band": self.band} if self.band is not None else {}),
            **({"provenance": self.provenance} if self.provenance else {}),
        })

    @classmethod
    def from_json(cls, doc: Any, source: str = "results.json") -> ComparisonResult:
        """The typed result of a ``results.json`` document of schema 2 or 3 (module
        docstring); anything else raises :class:`ValueError` naming ``source`` and the key."""
        if not isinstance(doc, dict):
            raise ValueError(f"{source}: not a comparison's results (a JSON object expected)")
        schema = doc.get("schema")
        if schema not in READABLE_SCHEMAS:
            raise ValueError(f"{source}: key 'schema': {schema!r} is not a results.json schema "
                             f"this version reads ({', '.join(map(str, READABLE_SCHEMAS))})")
        fams = doc.get("families")
        if not isinstance(fams, dict):
            raise ValueError(f"{source}: key 'families': expected a mapping of family results")
        band = doc.get("band")
        chosen = doc.get("chosen")
        return cls(config=_dict(doc.get("config")), device=str(doc.get("device") or ""),
                   data_hash=str(doc.get("data_hash") or ""), target=str(doc.get("target") or ""),
                   split=_dict(doc.get("split")),
                   units={str(k): str(v) for k, v in _dict(doc.get("units")).items()},
                   baseline=doc.get("baseline") if isinstance(doc.get("baseline"), str) else None,
                   targets={str(k): str(v) for k, v in _dict(doc.get("targets")).items()},
                   data=_dict(doc.get("data")), bootstrap=_dict(doc.get("bootstrap")),
                   families={str(k): FamilyResult.from_json(str(k), v) for k, v in fams.items()},
                   chosen=chosen if isinstance(chosen, str) else None,
                   chosen_reason=str(doc.get("chosen_reason") or ""),
                   selection=_dict(doc.get("selection")),
                   tie=[str(x) for x in doc.get("tie") or []],
                   uncompensated_axes=[str(x) for x in doc.get("uncompensated_axes") or []],
                   warnings=[str(x) for x in doc.get("warnings") or []],
                   mlflow_run_id=doc.get("mlflow_run_id") or None,
                   thermonet_version=str(doc.get("thermonet_version") or ""),
                   band=dict(band) if isinstance(band, dict) else None,
                   provenance=_dict(doc.get("provenance")), schema=int(schema))


def read_result(doc: ComparisonResult | Mapping[str, Any],
                source: str = "results.json") -> ComparisonResult:
    """``doc`` as the typed result: itself, or a ``results.json`` document parsed once
    (:meth:`ComparisonResult.from_json`; one written by hand without ``schema`` or
    ``families`` is read as this version's, with none)."""
    if isinstance(doc, ComparisonResult):
        return doc
    return ComparisonResult.from_json({"schema": SCHEMA, "families": {}, **doc}, source)
