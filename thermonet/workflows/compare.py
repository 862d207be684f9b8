"""``thermonet compare``: every configured family fitted, judged on held-out data, reported.

The steps (:mod:`thermonet.workflows.compare_plan`, :mod:`thermonet.workflows.compare_fit`,
:mod:`thermonet.workflows.compare_judge`; provenance: :mod:`thermonet.workflows.provenance`):

* **plan** — check the config against the data before anything is fitted or
  written (a ``baseline`` that names no family is an error; inputs the data
  cannot supply are errors), make the splits, collect warnings about
  implausible inputs (:mod:`thermonet.data.diagnostics`);
* **fit** — per family and fold: fit, predict the validation and test data,
  sum the offset-free score per contiguous held-out block
  (:mod:`thermonet.scoring.verdicts`), set the per-axis mask from the validation
  verdict, save the checkpoint;
* **judge** — choose (per-axis masked validation score, ties → fewest
  parameters, do no harm), verdicts against raw and the baseline from a
  paired block bootstrap, warnings;
* **write** — ``results.json`` (schema in :mod:`thermonet.reporting.results`),
  plots (:mod:`thermonet.workflows.compare_plots`), ``report.html``
  (:mod:`thermonet.reporting.report`); the console's table, :func:`format_table`, is
  :mod:`thermonet.workflows.compare_table`'s;
* **track** — at the edge: MLflow is called by a child process only
  (:mod:`thermonet.workflows.compare_track`), which logs from what was written
  while the plots are drawn; no tracker call is woven through the steps above.

The steps are a model kind's (:mod:`thermonet.workflows.steps`): :data:`PIPELINES` maps the
config's ``model:`` to its class — ``bias``, the steps above; ``sensor``, the whole-sensor
model's (:class:`thermonet.workflows.sensor.SensorSteps`) — and :func:`run_compare` runs
whichever it names through the one driver, in the same staging directory, thread limits and
figure helpers.

:func:`compare_result` returns the typed result
(:class:`~thermonet.reporting.results.ComparisonResult`; the whole-sensor model, its
document), which the console's table, the report, calibrate, fleet, learn and the API read;
``results.json`` is written from it at the edge (:meth:`ComparisonResult.to_json`), and
:func:`run_compare` returns that document as a dict, for scripts that want it.  With
leave-one-run-out the per-axis metrics are means over folds, ``folds`` under
each family holds the per-fold values, the verdicts pool every fold's
held-out blocks, and the checkpoint is the last fold's model.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ..core.errors import ConfigError, Interrupted, ThermonetError, counted
from ..core.fileio import atomic_write_text
from ..core.helpers import usable_cores
from ..core.outdir import Stage, staged_output
from ..core.profile import stage
from ..core.recording import Dataset
from ..core.version import __version__
from ..models.registry import PER_AXIS
from ..reporting.plot_workers import PlotWorkers
from ..reporting.report import tuned_text, write_report
from ..reporting.results import ComparisonResult
from ..scoring.verdicts import LEVEL, MIN_BLOCKS, RESAMPLES, SEED, apply_compensate_mask
from ..tracking import Tracker, check_store, default_tracking_uri
from ..training.config import (
    CompareConfig,
)
from ..training.parameters import parameter_rows, sealed_parameters
from ..training.parts import (
    data_hash,
)
from .compare_band import family_band, per_axis_band
from .compare_fit import FitQueue, Progress, family_workers
from .compare_judge import Fitted, choose_and_judge, extrapolation
from .compare_plan import PartCache, Plan, check_plan, data_summary, plan
from .compare_plots import plot_jobs
from .compare_table import format_table
from .compare_track import TrackingSession, family_record
from .provenance import data_source, family_config, resolved_config, resolved_yaml
from .sensor import SensorSteps
from .steps import Outcome, RunOptions, Steps, run_steps

__all__ = ["run_compare", "compare_result", "format_table"]


def run_compare(cfg: CompareConfig, out_dir: str | Path, *, overwrite: bool = False,
                track: bool | None = None, tracking_uri: str | None = None,
                quiet: bool = False, progress: Progress | None = None,
                dataset: Dataset | None = None, plots: bool = True,
                workers: int | None = None) -> dict[str, Any]:
    """:func:`compare_result`, returned as the ``results.json`` document (a dict, as written;
    :meth:`ComparisonResult.to_json`): the same arguments, the same files."""
    res = compare_result(cfg, out_dir, overwrite=overwrite, track=track,
                         tracking_uri=tracking_uri, quiet=quiet, progress=progress,
                         dataset=dataset, plots=plots, workers=workers)
    return res.to_json() if isinstance(res, ComparisonResult) else res


def compare_result(cfg: CompareConfig, out_dir: str | Path, *, overwrite: bool = False,
                   track: bool | None = None, tracking_uri: str | None = None,
                   quiet: bool = False, progress: Progress | None = None,
                   dataset: Dataset | None = None, plots: bool = True,
                   workers: int | None = None, command: str = "compare") -> Outcome:
    """Fit every family of ``cfg``, judge on held-out data, write ``out_dir``; return the
    typed result (:class:`~thermonet.reporting.results.ComparisonResult`; ``model: sensor``:
    its ``results.json`` document, a dict).

    ``dataset`` replaces the configured data (benchmarks feed variants of one
    simulation this way); the config's ``data`` section is then ignored.
    ``plots=False`` writes no PNG files (the report then has no figures).
    ``command``: the command the progress banner names (``thermonet train: …``).
    ``workers`` overrides the config's ``workers`` (families fitted side by side,
    :func:`family_workers`); ``workers=1`` also draws the figures in this process (else
    two child processes draw them, :mod:`thermonet.reporting.plot_workers`).

    The output appears whole or not at all (:mod:`thermonet.core.outdir`): it is
    built in a staging directory beside ``out_dir`` and moved into place when
    complete; ``results.json`` records each checkpoint's SHA-256.  A non-empty
    ``out_dir`` that is not a complete comparison is refused; a previous
    comparison is replaced only with ``overwrite=True``.
    """
    if cfg.tracking.enabled if track is None else track:   # a store that cannot be one,
        check_store(tracking_uri or cfg.tracking.uri or default_tracking_uri())  # at once
    kind = PIPELINES[cfg.model]   # the model kind's five steps (thermonet.workflows.steps)
    kind.check(cfg)  # a config error said before any process starts (torch-free)
    # the figures' drawers import matplotlib while the families fit (a core the fits leave
    # idle), then draw side by side — unless the comparison is to stay in one process
    # (workers=1: a fleet's units, run side by side) or its kind draws in this process; the
    # first starts now and reads the config's own data, before its imports, while this
    # process imports torch: the reading off the way to the fits; the other starts once
    # torch is imported
    one_process = (cfg.workers if workers is None else workers) == 1 or not kind.helpers
    first = None if dataset is not None or not kind.helpers else (
        "thermonet.training.loader", "load_compare_data",
        {"cfg": cfg, "source": getattr(cfg, "_source", "config")})
    options = RunOptions(track=track, tracking_uri=tracking_uri, quiet=quiet,
                         progress=progress, dataset=dataset, plots=plots, workers=workers,
                         command=command)
    with PlotWorkers(min(2, usable_cores()) if plots and not one_process else 0,
                     first=first) as drawers:
        from ..training.train import thread_limits  # torch boundary

        drawers.start_rest()          # the other drawers: importing beside torch slowed it
        # torch's and the native pools (BLAS, OpenMP) capped at train.threads for the whole
        # comparison, data preparation and evaluation included: the cap is process-wide, so
        # fits side by side must not lift it when one of them ends
        with thread_limits(cfg.train.threads), \
                staged_output(out_dir, overwrite=overwrite) as stage:
            out = Path(stage.path)
            if out.exists() and not out.is_dir():
                raise ConfigError(f"{out}: --out must be a directory, and this is a file")
            with drawers:
                results = run_steps(kind(cfg, out, drawers=drawers, options=options))
            _finish(stage, results)
    return results


def _finish(stage: Stage, results: Outcome) -> None:
    """The checkpoints' final paths and SHA-256 in the result (the per-axis model's among
    them), and ``results.json`` written from it once more (:meth:`Stage.finish`)."""
    if isinstance(results, ComparisonResult):
        for fam in results.families.values():
            if fam.checkpoint:
                fam.checkpoint, fam.checkpoint_sha256 = stage.final_checkpoint(fam.checkpoint)
        stage.finish(results.to_json())
        return
    for doc in results.get("families", {}).values():    # a kind without a typed result
        if doc.get("checkpoint"):
            doc["checkpoint"], doc["checkpoint_sha256"] = stage.final_checkpoint(
                doc["checkpoint"])
    stage.finish(results)


class _BiasSteps:
    """The five steps of a comparison of bias models (``model: bias``): plan, fit, judge,
    write, then the MLflow record from what was written (the tracking child,
    :mod:`thermonet.workflows.compare_track`, works while the plots are drawn); the figures
    drawn by ``drawers``, whose first may have read the data."""

    helpers = True

    def __init__(self, cfg: CompareConfig, out: Path, *, drawers: PlotWorkers,
                 options: RunOptions) -> None:
        self.cfg, self.out, self.drawers, self.o = cfg, out, drawers, options
        tracker = Tracker(enabled=cfg.tracking.enabled if options.track is None
                          else options.track,
                          uri=options.tracking_uri or cfg.tracking.uri,
                          experiment=cfg.tracking.experiment)
        self.tracking = TrackingSession(enabled=tracker.enabled, uri=tracker.uri,
                                        experiment=tracker.experiment,
                                        register=cfg.tracking.register).start()

    @staticmethod
    def check(cfg: CompareConfig) -> None:
        check_plan(cfg, build=False)

    def plan(self) -> None:
        o = self.o
        self.run = _plan_step(self.cfg, self.out, self.tracking, o.progress or Progress(o.quiet),
                              dataset=o.dataset,
                              options={"track": o.track, "tracking_uri": o.tracking_uri,
                                       "workers": o.workers, "plots": o.plots},
                              reader=self.drawers, command=o.command)

    def fit(self) -> None:
        self.fitted, self.records = _fit_step(self.run, self.o.workers)

    def judge(self) -> None:
        _judge_step(self.run, self.fitted)

    def write(self) -> None:
        self.plot_paths = _write_step(self.run, self.fitted, self.records,
                                      drawers=self.drawers if self.o.plots else None)

    def track(self) -> ComparisonResult:
        result = self.run.result
        with stage("MLflow: the tracking step's remainder"):
            # the tracking's own warnings are printed, not written: results.json (and the
            # result, which is the file's) was logged before they could be known
            late = [w for w in self.run.tracking.finish(self.out / "report.html",
                                                        self.plot_paths)
                    if w not in result.warnings]
        for w in [*result.warnings, *dict.fromkeys(late)]:
            self.run.progress.line(f"warning: {w}")
        return result

    def abort(self, err: BaseException) -> None:
        self.tracking.abort(interrupted=isinstance(err, (KeyboardInterrupt, Interrupted)))


#: Each model kind's five steps, by the config's ``model:`` value.
PIPELINES: dict[str, type[Steps]] = {"bias": _BiasSteps, "sensor": SensorSteps}


@dataclass
class _Run:
    """What the steps of one comparison share: its plan, where it writes, what it records."""

    cfg: CompareConfig
    p: Plan
    out: Path
    result: ComparisonResult
    resolved: dict[str, Any]
    provenance: dict[str, Any]
    tags: dict[str, str]
    progress: Progress
    tracking: TrackingSession


def _plan_step(cfg: CompareConfig, out: Path, tracking: TrackingSession, progress: Progress,
               *, dataset: Dataset | None, options: dict[str, Any],
               reader: PlotWorkers | None = None, command: str = "compare") -> _Run:
    """Plan (data, targets, splits; :func:`plan`), the result's frame, the provenance, and
    the MLflow runs asked for (their ids are needed by the checkpoints); the data as the
    helper read it where ``reader`` was given that first call (read here if it could not)."""
    loaded = None
    if reader is not None and reader.has_first:
        with stage("read the data (in a helper)"):
            # None where it could not: read here, where a bad file is refused in its own words
            loaded = reader.first_result(lambda ds: isinstance(ds, Dataset))
    with stage("plan: load the data, targets, splits and folds"):
        p = plan(cfg, dataset, loaded=loaded)
    ds = p.ds
    out.mkdir(parents=True, exist_ok=True)
    dhash = data_hash(ds)
    preset = ds.runs[0].meta.get("preset", "") if dataset is not None or not cfg.data.paths \
        else ""
    tags = {"device": ds.device_id, "preset": preset, "data_hash": dhash,
            "target": p.targets.kind}
    resolved = resolved_config(cfg, ds, given=dataset is not None, workers=family_workers(
        cfg, options["workers"]), tracking_enabled=tracking.enabled, tracking_uri=tracking.uri)
    provenance = {"thermonet_version": __version__,
                  "data": data_source(cfg, ds, given=dataset is not None),
                  "tracking": resolved["tracking"], "options": options}
    splits = p.splits
    result = ComparisonResult(
        config=resolved, device=ds.device_id, data_hash=dhash, target=p.targets.kind,
        split={"strategy": splits[0].label if len(splits) == 1 else "leave-one-run-out",
               "folds": [s.describe for s in splits]},
        units=p.units, targets=p.targets.as_dict(), baseline=cfg.baseline,
        data={"runs": data_summary(ds)},
        thermonet_version=__version__)
    for w in p.warnings:
        result.warn(w)
    if cfg.tracking.register is not None and not tracking.enabled:  # off for this run only
        result.warn(f"tracking.register {cfg.tracking.register!r} is ignored: tracking is off "
                    f"for this comparison (--no-track), so no model is registered")
    progress.line(f"thermonet {command}: {ds.device_id} ({counted(len(ds), 'run')}, outputs "
                  f"{', '.join(p.outputs)}), split {result.split['strategy']}")
    _note_streamed(cfg, ds, result, progress)
    tracking.open(f"compare-{ds.device_id}", resolved, tags, [
        (fam.label, {"family": fam.family, "inputs": fam.inputs, "params": fam.params},
         {**tags, "family": fam.family}) for fam in cfg.families])
    return _Run(cfg, p, out, result, resolved, provenance, tags, progress, tracking)


def _note_streamed(cfg: CompareConfig, ds: Dataset, result: ComparisonResult,
                   progress: Progress) -> None:
    """``data.streamed`` of the results: how recordings read in chunks were reduced."""
    reduced = [r.windows for r in ds if r.windows is not None]
    if not reduced:
        return
    result.data["streamed"] = {
        "samples": sum(w.source_samples for w in reduced),
        "rows": sum(int(w.n.size) for w in reduced), "window_s": reduced[0].window_s,
        "chunk_rows": cfg.data.chunk_rows,
        "method": "read in chunks and reduced to window means with per-window counts and "
                  "sums of squares (thermonet.features.windows); dynamic inputs computed "
                  "on the samples"}
    progress.line(f"streamed {result.data['streamed']['samples']} samples in chunks of "
                  f"{cfg.data.chunk_rows} rows into {result.data['streamed']['rows']} "
                  f"{reduced[0].window_s:g} s window means")


def _fit_step(run: _Run, workers: int | None) -> tuple[dict[str, Fitted], dict[str, Any]]:
    """Every family fitted (side by side where configured), its checkpoint saved; returns
    the fits and, per family, what its MLflow run logs (:func:`family_record`)."""
    cfg, p = run.cfg, run.p
    fitted: dict[str, Fitted] = {}
    records: dict[str, Any] = {}
    parts = PartCache(cfg, p.outputs, p.targets)
    n_workers = family_workers(cfg, workers)
    if n_workers > 1:
        run.progress.line(f"fitting {len(cfg.families)} families, {n_workers} side by side")
    with FitQueue(p, run.progress, parts, n_workers) as queue:
        for fam in cfg.families:
            f = queue.result(fam)
            run_id = run.tracking.ids()[1].get(fam.label)
            f.result.mlflow_run_id = run_id
            records[fam.label] = _fitted_family(run, fam, f, run_id)
            run.result.families[fam.label] = f.result
            fitted[fam.label] = f
    return fitted, records


def _fitted_family(run: _Run, fam: Any, f: Fitted, run_id: str | None) -> dict[str, Any]:
    """One family's fit: the per-axis mask set in the model, the band, the checkpoint, one
    progress line; returns its MLflow record."""
    r, outputs = f.result, run.p.outputs
    if not r.ok:
        run.progress.line(f"  {fam.label:<14} not fitted: {r.reason}")
        return family_record(False, None, {}, None)
    mask = [r.axes[a].compensate for a in outputs]
    r.compensate_in_model = apply_compensate_mask(f.model, mask)
    metrics = {f"test/{a}/{k}": v for a, m in r.axes.items()
               for k, v in {**m.metrics, "score_ratio": m.test.ratio,
                            "score_raw": m.score_raw, "score_comp": m.score_comp}.items()}
    metrics.update({"val/score": r.val_score, "fit_seconds": r.fit_seconds})
    r.band = family_band(run.p, f, mask)
    try:
        _save_family(run, fam, f, mask, run_id)
    except ThermonetError as err:  # a NaN model is never saved
        r.status, r.reason = "failed", str(err)
    tuned = tuned_text({k: v for k, v in r.tuned.items() if k != "tuning"})
    run.progress.line(f"  {fam.label:<14} fitted in {r.fit_seconds:.2f} s, "
                      f"{r.n_params} params, val score {r.val_score:.3g} "
                      f"({sum(mask)}/{len(mask)} axes compensated)"
                      + (f", tuned {tuned}" if tuned else ""))
    return family_record(True, f.history, metrics, r.checkpoint)


def _save_family(run: _Run, fam: Any, f: Fitted, mask: list[bool], run_id: str | None) -> None:
    """``models/<label>.pt``, sealed; its family config holds the tuned values as params."""
    from ..training.checkpoint import save_checkpoint  # torch boundary

    r, ds, outputs, band = f.result, run.p.ds, run.p.outputs, f.result.band or {}
    ckpt = run.out / "models" / f"{fam.label}.pt"
    chosen_point = {k: r.tuned[k] for k in fam.tune if k in r.tuned}
    save_checkpoint(ckpt, f.model, config=family_config(
                        run.cfg, replace(fam, params={**fam.params, **chosen_point}),
                        run.resolved["tracking"]),
                    epoch=r.best_epoch, best_val=f.best_val,
                    extra={"label": fam.label, "device_id": ds.device_id,
                           "data_hash": run.result.data_hash, "units": run.p.units,
                           "signal_units": {s: ds[0].units.get(s, "") for s in ds[0].proxies},
                           "val_score": r.val_score,
                           "compensate": dict(zip(outputs, mask, strict=True)),
                           "test_metrics": r.to_json()["axes"],
                           "mlflow_run_id": run_id or "",
                           "provenance": run.provenance,
                           "tuned": {k: v for k, v in r.tuned.items() if k != "tuning"},
                           **_sealed(f.parameters),
                           **({"band": band} if band.get("status") == "ok" else {})})
    r.checkpoint = str(ckpt)


def _judge_step(run: _Run, fitted: dict[str, Fitted]) -> None:
    """Choose and judge (:func:`choose_and_judge`), the per-axis model where chosen, the
    extrapolation warnings: ``run.result`` complete."""
    result = run.result
    result.mlflow_run_id = run.tracking.ids()[0]
    n_val = next((f.val.n.size for f in fitted.values() if f.val is not None), 0)
    n_test = next((f.test.n.size for f in fitted.values() if f.test is not None), 0)
    result.bootstrap = {
        "method": "non-overlapping block bootstrap over contiguous held-out blocks "
                  "(paired across families), percentile interval",
        "resamples": RESAMPLES, "level": LEVEL, "seed": SEED, "min_blocks": MIN_BLOCKS,
        "blocks": {"val": n_val, "test": n_test}}
    with stage("choose and judge"):
        choose_and_judge(fitted, result, run.p)
    if result.chosen == PER_AXIS:
        with stage("write the per-axis model"):
            _save_per_axis(run.out, fitted, result, run.p, run.resolved, run.provenance,
                           run.p.units)
    extrapolation(fitted, result)
    result.provenance = run.provenance
    shipped = result.families.get(result.chosen) if result.chosen else None
    if shipped is not None and shipped.band is not None:
        result.band = {"model": result.chosen, **shipped.band}
    result.settle()   # its free-form parts as results.json will hold them


def _write_step(run: _Run, fitted: dict[str, Fitted], records: dict[str, Any], *,
                drawers: PlotWorkers | None) -> list[Path]:
    """``results.json`` (the result's document, :meth:`ComparisonResult.to_json`: the edge)
    and ``config.resolved.yaml``, the document handed to the tracking child, then the plots
    and ``report.html`` from the result while it logs; returns the figures' paths."""
    out, result = run.out, run.result
    with stage("write results.json"):
        doc = result.to_json()
        atomic_write_text(out / "results.json", json.dumps(doc, indent=2))
        atomic_write_text(out / "config.resolved.yaml",
                          resolved_yaml(run.resolved, run.provenance))
    run.tracking.log(out, doc, records)   # a child process's: the document, picklable
    with stage("plots"):
        plot_paths = drawers.draw(plot_jobs(out, fitted, result, run.p.ds)) if drawers else []
    with stage("write the report"):
        write_report(out / "report.html", result, plot_paths)
    return plot_paths


def _sealed(parameters: Any) -> dict[str, Any]:
    """``extra.parameters`` of a checkpoint: the fit's standard errors and covariance
    (least squares), so that the loaded model states them (none where not computed)."""
    if parameters is None:
        return {}
    table, cov = parameters
    return {"parameters": sealed_parameters(table, cov, "ols")}


def _per_axis_parameters(model: Any, fitted: dict[str, Fitted], labels: list[str],
                         units: dict[str, str]) -> Any:
    """The per-axis model's table: each axis's rows from the fit of the part that owns it."""
    tables = [fitted[k].parameters for k in labels]
    if any(t is None for t in tables):
        return None
    return parameter_rows(model, units, {}, parts=tables)


def _save_per_axis(out: Path, fitted: dict[str, Fitted], result: ComparisonResult,
                   p: Any, resolved: dict[str, Any], provenance: dict[str, Any],
                   units: dict[str, str]) -> None:
    """``models/per-axis.pt``: the candidates the axes chose, one model
    (:class:`thermonet.models.composite.AxisModels`), sealed like every checkpoint."""
    import copy

    from ..models.composite import AxisModels  # torch boundary
    from ..training.checkpoint import save_checkpoint  # torch boundary

    cfg = p.cfg
    owners: dict[str, str | None] = result.selection["per_axis"]["chosen"]
    labels: list[str] = result.selection["per_axis"]["candidates"]
    outputs = list(owners)
    model = AxisModels([copy.deepcopy(fitted[k].model) for k in labels],
                       [None if (o := owners[a]) is None else labels.index(o) for a in outputs],
                       labels)
    r = result.families[PER_AXIS]
    ckpt = out / "models" / f"{PER_AXIS}.pt"
    r.band = per_axis_band(p, fitted, owners, model)
    fams = {f.label: f for f in cfg.families}
    try:
        save_checkpoint(ckpt, model, config={
            "parts": {k: family_config(cfg, replace(fams[k], params={
                **fams[k].params, **{n: v for n, v in result.families[k].tuned.items()
                                     if n in fams[k].tune}}), resolved["tracking"])
                      for k in labels}},
            epoch=0, best_val=None,
            extra={"label": PER_AXIS, "device_id": result.device, "data_hash": result.data_hash,
                   "units": units, "axes": dict(owners),
                   "compensate": {a: owners[a] is not None for a in outputs},
                   "test_metrics": r.to_json()["axes"], "provenance": provenance,
                   **_sealed(_per_axis_parameters(model, fitted, labels, units)),
                   **({"band": r.band} if r.band.get("status") == "ok" else {})})
        r.checkpoint = str(ckpt)
    except ThermonetError as err:   # a NaN model is never saved
        r.status, r.reason = "failed", str(err)
        result.warn(f"the per-axis model could not be written: {err}")
