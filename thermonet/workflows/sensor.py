"""``thermonet compare`` with ``model: sensor``: the full sensor model per family, judged.

The run is the five steps of every comparison (:class:`SensorSteps`, driven by
:func:`thermonet.workflows.steps.run_steps` from
:func:`thermonet.workflows.compare.run_compare`, in its staging directory and thread
limits): **plan** (:func:`_plan`: the data, its triads,
one train / validation / test split — never by random sample — and the bias comparison's
cross-validation folds of the split's pool), **fit** (:func:`_fit_family`, per configured
family), **judge** (:func:`_judge_test` per family on the held-out run, then
:func:`~thermonet.workflows.sensor_fit.choose_sensor` across families), **write**
(:func:`_write`: checkpoints, ONNX, results.json, report) and **track** (:func:`_track`).

Per family:

1. its ``tune`` grid, when it has one, chosen on the folds
   (:func:`~thermonet.workflows.sensor_fit.sensor_tune`);
2. the full sensor model (:func:`thermonet.training.sensor.fit_sensor`: bias, scale factor
   and misalignment, every element a function of the family's inputs) on the split's
   training runs, early stopping and do no harm on its validation run, and, on the same
   data and code path, the bias-only model (E = 0) it is judged against;
3. its out-of-fold predictions on the pool's folds
   (:func:`~thermonet.workflows.sensor_fit.sensor_oof`: one fit per fold);
4. on the held-out test run, per axis: the residual RMS of raw, bias-only and sensor model
   (output units) and the paired block-bootstrap verdicts of the sensor model against raw
   and against the bias-only model; per triad, the per-soak scale-factor tempco before and
   after (study 000's ppm/°C) and each misalignment with its spread over temperature (mrad)
   (:mod:`thermonet.scoring.sensor`); and the fleet's per-axis statistics of a bias model
   (``rms_raw``/``rms_comp``: the residuals' standard deviations, ``pp_raw``/``pp_comp``:
   the peak-to-peak of their 1 °C-binned means), which ``thermonet fleet`` summarises and
   judges against ``limits``.

The family that ships (``chosen``) is the out-of-fold choice
(:mod:`thermonet.scoring.selection`: the one-SE rule, fewest parameters, do no harm;
``selection`` in results.json as in a bias comparison); without folds, the lowest validation
residual.  Its checkpoint is ``models/<label>.pt``
(:func:`thermonet.training.sensor_checkpoint.save_sensor`) and its ONNX graph ``model.onnx``
(:mod:`thermonet.exporting.sensor_export`, parity-checked against torch).

Decisions: one split only (leave-one-run-out is refused: the verdicts would pool folds of
different models); MLflow tracking as for bias models (a parent run, a nested run per family
with its history, test metrics and checkpoint); one figure, the chosen family's per-soak
scale factors and misalignments; a family that cannot be fitted is reported and the others go
on, as in a bias comparison.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ConfigError, ThermonetError
from ..core.fileio import atomic_write_text
from ..core.recording import Dataset
from ..core.schema import to_dict
from ..core.version import __version__
from ..reporting.sensor_report import plot_sensor_soaks, write_sensor_report
from ..scoring.metrics import binned_peak_to_peak
from ..scoring.sensor import residual_verdicts, soak_matrices, triad_metrics
from ..tracking import Tracker
from ..training.config import (
    CompareConfig,
    FamilyConfig,
    check_families,
    outputs_of,
    train_config_of,
)
from ..training.parts import data_hash, load_data
from ..training.splits import make_splits
from .compare_plan import _check_baseline, _fold_plan
from .sensor_fit import choose_sensor, sensor_oof, sensor_pool, sensor_tune
from .steps import RunOptions

if TYPE_CHECKING:
    from ..reporting.plot_workers import PlotWorkers

__all__ = ["SensorSteps", "format_sensor_table"]


def _score(comp_err: np.ndarray, raw_err: np.ndarray) -> float:
    """Mean over axes of the squared residual, each axis scaled by its raw error's std."""
    scale = np.std(raw_err, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    return float(np.mean((comp_err / scale) ** 2))


@dataclass
class _Plan:
    """Everything decided before fitting (step 1)."""

    cfg: CompareConfig
    ds: Dataset
    outputs: list[str]
    triads: list[list[str]]
    split: Any                       # thermonet.training.splits.Split
    units: dict[str, str]
    doc: dict[str, Any]              # results.json, filled step by step
    folds: Any = None                # thermonet.scoring.fold_plan.FoldPlan of the pool
    fold_note: str = ""


@dataclass
class _Fitted:
    """One family's fit (step 2): what the choice, the figure and the tracking need."""

    history: list[dict] = field(default_factory=list)
    soaks: list[Any] = field(default_factory=list)
    oof: Any = None
    pool: Any = None


class SensorSteps:
    """The five steps of a whole-sensor comparison (``model: sensor``), run by
    :func:`thermonet.workflows.steps.run_steps` as a bias comparison's are (module
    docstring): its figure, one, is drawn in this process (``helpers`` False)."""

    helpers = False

    def __init__(self, cfg: CompareConfig, out: Path, *, drawers: PlotWorkers,
                 options: RunOptions) -> None:
        self.cfg, self.out, self.o = cfg, out, options
        self.say = (lambda s: None) if options.quiet else print

    @staticmethod
    def check(cfg: CompareConfig) -> None:
        """Nothing before the plan: its checks need the data (its triads, references)."""

    def plan(self) -> None:
        """1. The data, its triads, one split and the folds of its pool (:func:`_plan`)."""
        self.p = p = _plan(self.cfg, self.o.dataset)
        self.say(f"thermonet compare (model: sensor): {p.ds.device_id} ({len(p.ds)} runs, "
                 f"triads {p.triads}), split {p.split.label}, "
                 + (f"{p.folds.k} cross-validation folds ({p.folds.kind})"
                    if p.folds is not None else p.fold_note))
        (self.out / "models").mkdir(parents=True, exist_ok=True)

    def fit(self) -> None:
        """2. Every family fitted, judged on the test run and saved (:func:`_fit_family`)."""
        p = self.p
        self.fits: dict[str, _Fitted] = {}
        for fam in self.cfg.families:
            fitted = _fit_family(p, fam, self.out, self.say)
            if fitted is not None:
                self.fits[fam.label] = fitted
        if not self.fits:
            reasons = {str(v.get("reason")) for v in p.doc["families"].values()}
            raise ThermonetError("no family could be fitted as a sensor model: " + (
                reasons.pop() if len(reasons) == 1 else "; ".join(
                    f"{k}: {v.get('reason')}" for k, v in p.doc["families"].items())))

    def judge(self) -> None:
        """3. The choice across families (:func:`choose_sensor`)."""
        p, fits = self.p, self.fits
        pool = next((f.pool for f in fits.values() if f.pool is not None), None)
        choose_sensor(self.cfg, p.doc, p.folds, p.fold_note,
                      {k: f.oof for k, f in fits.items() if f.oof is not None}, pool,
                      p.outputs)
        self.say(f"  chosen: {p.doc['chosen'] or 'none'} ({p.doc['chosen_reason']})")

    def write(self) -> None:
        """4. The chosen family's ONNX graph, results.json, its figure and report.html."""
        doc = self.p.doc
        chosen = doc["families"].get(doc["chosen"]) if doc["chosen"] else None
        doc["onnx"] = _export_chosen(self.out, chosen) if chosen else {
            "status": "not written", "reason": doc["chosen_reason"]}
        _write(self.out, doc, self.fits, plots=self.o.plots)

    def track(self) -> dict[str, Any]:
        """5. MLflow (:func:`_track`), then results.json again with the run ids."""
        doc, o = self.p.doc, self.o
        doc["mlflow_run_id"] = _track(self.cfg, doc, {k: f.history for k, f in self.fits.items()},
                                      self.p.ds.device_id, track=o.track,
                                      tracking_uri=o.tracking_uri)
        atomic_write_text(self.out / "results.json", json.dumps(doc, indent=2))
        return doc

    def abort(self, err: BaseException) -> None:
        """Nothing to undo: its MLflow runs open and close within :meth:`track`."""


def _plan(cfg: CompareConfig, dataset: Dataset | None) -> _Plan:
    """Config and data checked (families, references, triads), the one split and the folds
    of its pool; results.json's head."""
    from ..models.sensor import triads_of  # torch boundary
    from ..training.sensor import sensor_run_refs  # torch boundary

    src = getattr(cfg, "_source", "config")
    check_families(cfg, source=src)
    _check_baseline(cfg, src)
    ds = dataset if dataset is not None else load_data(cfg.data, source=src)
    ds.validate()
    triads = triads_of(outputs_of(cfg, ds), source=src)
    outputs = [o for t in triads for o in t]
    splits = make_splits(ds, cfg.split, source=src)
    if len(splits) != 1:
        raise ConfigError(f"{src}: key 'split.strategy': model 'sensor' takes one train / "
                          f"validation / test split, got {len(splits)} folds")
    sp = splits[0]
    for rec in [*sp.train, *([sp.val] if sp.val is not None else []), sp.test]:
        sensor_run_refs(rec, outputs)  # a missing reference is the data's fault: refused now
    folds, note = _fold_plan(cfg, splits)
    units = {o: ds.runs[0].units.get(o, "") for o in outputs}
    doc: dict[str, Any] = {
        "model": "sensor", "thermonet_version": __version__, "device": ds.device_id,
        "data_hash": data_hash(ds), "config": to_dict(cfg), "units": units,
        "triads": triads, "split": {"strategy": sp.label, "describe": sp.describe},
        "baseline": cfg.baseline, "families": {}, "chosen": None, "chosen_reason": "",
        "tie": [], "selection": {}, "warnings": []}
    return _Plan(cfg, ds, outputs, triads, sp, units, doc, folds, note)


def _fit_family(p: _Plan, fam: FamilyConfig, out: Path, say: Any) -> _Fitted | None:
    """Step 2 for one family: tuned on the folds (a ``tune`` grid), fitted as a sensor and
    as a bias-only model, cross-validated, judged on the test run, written; its entry in
    results.json.  A family the data cannot carry is reported (None) and the others go on."""
    from ..training.pipeline import split_spec  # torch boundary
    from ..training.sensor import fit_sensor, sensor_run  # torch boundary

    cfg, sp = p.cfg, p.split
    entry: dict[str, Any] = {"family": fam.family, "inputs": list(fam.inputs),
                             "params": dict(fam.params)}
    p.doc["families"][fam.label] = entry
    kw: dict[str, Any] = {"outputs": p.outputs, "triads": p.triads}
    try:
        t0 = time.perf_counter()
        spec = split_spec(fam.inputs, sp.train, t_ref=cfg.features.t_ref,
                         window_min=cfg.features.t_ref_window_min, gap_s=cfg.features.gap_s)
        tcfg = train_config_of(cfg, fam)
        kw.update(spec=spec)
        fitted = _Fitted(pool=sensor_pool(sp.pool, spec, p.outputs)
                         if p.folds is not None else None)
        if fam.tune:
            fam, entry["tuned"], fitted.oof = sensor_tune(p.folds, fitted.pool, fam=fam,
                                                          tcfg=tcfg, **kw)
        tr = [sensor_run(r, spec, p.outputs) for r in sp.train]
        va = sensor_run(sp.val, spec, p.outputs) if sp.val is not None else None
        te = sensor_run(sp.test, spec, p.outputs)
        fit_kw = dict(family=fam.family, train=tr, val=va, hyper=fam.params, config=tcfg, **kw)
        full = fit_sensor(**fit_kw)
        bias = fit_sensor(**fit_kw, elements=False)
        if p.folds is not None and fitted.oof is None:
            fitted.oof = sensor_oof(p.folds, fitted.pool, fam=fam, tcfg=tcfg, **kw)
        fit_s = time.perf_counter() - t0
    except ThermonetError as err:
        entry.update(status="failed", reason=str(err))
        say(f"  {fam.label:<14} not fitted: {err}")
        return None
    fitted.history = full.history
    fitted.soaks = _judge_test(p, entry, full, bias, te, va)
    _save(p, fam, entry, full, bias, out)
    entry.update(status="ok", fit_seconds=fit_s, n_params=full.model.n_params,
                 best_epoch=full.best_epoch, n_estimates=full.n_estimates,
                 condition_max=full.condition, elements_kept=full.kept)
    if fitted.oof is not None and fitted.oof.failed is not None:
        entry["cross_validation"] = fitted.oof.failed
    worst = max(a["ratio_vs_bias"] for a in entry["axes"].values())
    say(f"  {fam.label:<14} fitted in {fit_s:.2f} s, {full.model.n_params} params, "
        f"{sum(full.kept.values())}/{len(full.kept)} elements kept, residual vs bias-only "
        f"at most {worst:.3g}")
    return fitted


def _judge_test(p: _Plan, entry: dict[str, Any], full: Any, bias: Any, te: Any,
                va: Any) -> list[Any]:
    """The family's held-out metrics into ``entry`` (axes, misalignment, triads, validation
    scores); returns the per-soak matrices of its figure."""
    test, outputs = p.split.test, p.outputs
    raw_err = te.raw - te.ref
    comp = full.model.compensate(te.signals, te.raw)
    comp_b = bias.model.compensate(te.signals, te.raw)
    axes = residual_verdicts(outputs, te.time_s, raw_err, comp - te.ref, comp_b - te.ref)
    temp = np.asarray(test.temperature_c if test.temperature_c is not None
                      else te.temperature)
    for j, a in enumerate(outputs):   # the fleet's statistics of a bias model's axis
        axes[a].update(rms_raw=axes[a]["residual_rms_raw"], rms_comp=axes[a]["residual_rms_comp"],
                       pp_raw=binned_peak_to_peak(temp, raw_err[:, j]),
                       pp_comp=binned_peak_to_peak(temp, comp[:, j] - te.ref[:, j]))
    elements: dict[str, Any] = {}
    soaks = []
    for t in p.triads:
        idx = [outputs.index(o) for o in t]
        temps, _, m_raw = soak_matrices(te.time_s, temp, te.raw[:, idx], te.ref[:, idx])
        _, _, m_comp = soak_matrices(te.time_s, temp, comp[:, idx], te.ref[:, idx])
        if temps.size:
            soaks.append((t, temps, m_raw, m_comp))
        _, _, m_bias = soak_matrices(te.time_s, temp, comp_b[:, idx], te.ref[:, idx])
        for key, m in triad_metrics(t, temps, m_raw, m_comp).items():
            if key in axes:
                axes[key].update(m)
                axes[key]["sf_ppm_per_c_bias_only"] = triad_metrics(
                    t, temps, m_raw, m_bias)[key]["sf_ppm_per_c_comp"]
            else:
                elements[key] = m
    val_score = val_bias = None
    if va is not None:
        v_raw = va.raw - va.ref
        val_score = _score(full.model.compensate(va.signals, va.raw) - va.ref, v_raw)
        val_bias = _score(bias.model.compensate(va.signals, va.raw) - va.ref, v_raw)
    entry.update(triads=_per_triad(p.triads, axes, elements), val_score=val_score,
                 val_score_bias_only=val_bias, axes=axes, misalignment=elements,
                 test_score=_score(comp - te.ref, raw_err))
    return soaks


def _per_triad(triads: list[list[str]], axes: dict[str, Any], elements: dict[str, Any]
               ) -> dict[str, Any]:
    """Per kind, the worst of its axes' and misalignments' metrics."""
    per_triad = {}
    for t in triads:
        kind = t[0].split("_", 1)[0]
        sf = [axes[a]["sf_ppm_per_c_comp"] for a in t if "sf_ppm_per_c_comp" in axes[a]]
        sf_raw = [axes[a]["sf_ppm_per_c_raw"] for a in t if "sf_ppm_per_c_raw" in axes[a]]
        mis = [m for k, m in elements.items() if k.startswith(f"{kind}_")]
        per_triad[kind] = {
            "sf_ppm_per_c_raw_max": max(sf_raw) if sf_raw else None,
            "sf_ppm_per_c_comp_max": max(sf) if sf else None,
            "misalignment_spread_mrad_raw_max": max(
                (m["misalignment_spread_mrad_raw"] for m in mis), default=None),
            "misalignment_spread_mrad_comp_max": max(
                (m["misalignment_spread_mrad_comp"] for m in mis), default=None),
            "residual_ratio_vs_bias_max": max(axes[a]["ratio_vs_bias"] for a in t)}
    return per_triad


def _save(p: _Plan, fam: FamilyConfig, entry: dict[str, Any], full: Any, bias: Any,
          out: Path) -> None:
    """The family's sensor checkpoint and its bias-only model as a plain bias checkpoint
    (what an autopilot can take)."""
    from ..exporting.sensor_export import bias_only_path  # torch boundary
    from ..training.checkpoint import save_checkpoint  # torch boundary
    from ..training.sensor_checkpoint import save_sensor  # torch boundary

    ckpt = out / "models" / f"{fam.label}.pt"
    info = {"label": fam.label, "device_id": p.ds.device_id, "units": p.units}
    save_sensor(ckpt, full, family=fam.family, hyper=fam.params,
                extra={**info, "val_score": entry["val_score"]})
    save_checkpoint(bias_only_path(ckpt), bias.model.bias, config=to_dict(p.cfg),
                    extra={**info, "label": f"{fam.label}.bias-only"})
    entry.update(checkpoint=str(ckpt), bias_only_checkpoint=f"models/{bias_only_path(ckpt).name}")


def _write(out: Path, doc: dict[str, Any], fits: dict[str, _Fitted], *, plots: bool) -> None:
    """results.json, the chosen family's figure and report.html."""
    atomic_write_text(out / "results.json", json.dumps(doc, indent=2))
    figs = []
    chosen = doc["chosen"]
    if plots and chosen and fits[chosen].soaks:
        figs.append(plot_sensor_soaks(out / "sensor_soaks.png", chosen, fits[chosen].soaks))
    write_sensor_report(out / "report.html", doc, figs)


def _track(cfg: CompareConfig, doc: dict[str, Any], histories: dict[str, list], device: str,
           *, track: bool | None, tracking_uri: str | None) -> str | None:
    """Log the comparison to MLflow as a bias comparison is: a parent run, one nested run per
    fitted family (its loss history, per-axis test metrics, its checkpoint); returns the
    parent's run id (None when tracking is off)."""
    tracker = Tracker(enabled=cfg.tracking.enabled if track is None else track,
                      uri=tracking_uri or cfg.tracking.uri, experiment=cfg.tracking.experiment)
    tags = {"device": device, "model": "sensor", "data_hash": doc["data_hash"]}
    with tracker.run(f"compare-sensor-{device}", params={"model": "sensor", "families": [
            f"{k}:{v['family']}" for k, v in doc["families"].items()]}, tags=tags) as parent:
        for label, f in doc["families"].items():
            if f.get("status") != "ok":
                continue
            with tracker.run(label, params={"family": f["family"], "inputs": f["inputs"],
                                            "params": f["params"]},
                             tags={**tags, "family": f["family"]}, nested=True) as run_id:
                f["mlflow_run_id"] = run_id
                tracker.log_history(histories.get(label, []))
                tracker.log_metrics({f"test/{a}/{k}": v for a, m in f["axes"].items()
                                     for k, v in m.items() if isinstance(v, float)})
                if f.get("val_score") is not None:
                    tracker.log_metrics({"val/score": f["val_score"]})
                tracker.log_artifact(f["checkpoint"], "model")
        tracker.set_tags({"chosen": doc.get("chosen") or "none"})
    return parent


def _export_chosen(out: Path, entry: dict[str, Any]) -> dict[str, Any]:
    from ..exporting.sensor_export import export_sensor_onnx  # torch boundary
    from ..training.sensor_checkpoint import load_sensor  # torch boundary

    model, payload = load_sensor(entry["checkpoint"])
    extra = payload.get("extra", {})
    try:
        return {**export_sensor_onnx(model, out / "model.onnx", metadata={
            "device_id": extra.get("device_id", ""), "output_units": extra.get("units", {}),
            "validation_metrics": {"val_score": extra.get("val_score")}}),
            "path": "model.onnx"}
    except ThermonetError as err:
        return {"status": "failed", "reason": str(err)}


def format_sensor_table(results: dict[str, Any]) -> str:
    """The sensor comparison as a text table: family × axis residuals and verdicts."""
    head = (f"{'family':<14} {'axis':<8} {'raw':>10} {'bias-only':>10} {'sensor':>10} "
            f"{'vs raw':>8} {'vs bias':>8} {'SF ppm/C raw':>13} {'comp':>8}")
    lines = [head, "-" * len(head)]
    mark = {"better": "+", "worse": "!", "indistinguishable": "="}
    for name, f in results["families"].items():
        if f.get("status") != "ok":
            lines.append(f"{name:<14} not fitted: {f.get('reason')}")
            continue
        for a, m in f["axes"].items():
            sf_r = m.get("sf_ppm_per_c_raw", float("nan"))
            sf_c = m.get("sf_ppm_per_c_comp", float("nan"))
            lines.append(
                f"{name:<14} {a:<8} {m['residual_rms_raw']:>10.4g} "
                f"{m['residual_rms_bias_only']:>10.4g} {m['residual_rms_comp']:>10.4g} "
                f"{m['ratio_vs_raw']:>7.3g}{mark[m['verdict_vs_raw']]} "
                f"{m['ratio_vs_bias']:>7.3g}{mark[m['verdict_vs_bias']]} "
                f"{sf_r:>13.4g} {sf_c:>8.4g}")
    lines.append(f"chosen: {results['chosen']}")
    return "\n".join(lines)
