"""``thermonet compare``: every configured family fitted, judged on held-out data, reported.

Three steps:

* **plan** — check the config against the data before anything is fitted or
  written (a ``baseline`` that names no family is an error; inputs the data
  cannot supply are errors), make the splits, collect warnings about
  implausible inputs (:mod:`thermonet.data.diagnostics`);
* **fit** — per family and fold: fit, predict the validation and test data,
  sum the offset-free score per contiguous held-out block
  (:mod:`thermonet.scoring.verdicts`), set the per-axis mask from the validation
  verdict, save the checkpoint;
* **report** — choose (per-axis masked validation score, ties → fewest
  parameters, do no harm), verdicts against raw and the baseline from a
  paired block bootstrap, warnings, ``results.json`` (schema in
  :mod:`thermonet.reporting.results`), plots, ``report.html`` (:mod:`thermonet.reporting.report`).

:func:`run_compare` returns the ``results.json`` document as a dict.  With
leave-one-run-out the per-axis metrics are means over folds, ``folds`` under
each family holds the per-fold values, the verdicts pool every fold's
held-out blocks, and the checkpoint is the last fold's model.
"""

from __future__ import annotations

import json
import math
import os
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..core.errors import ConfigError, FitError, ThermonetError
from ..core.fileio import atomic_write_text
from ..core.recording import Dataset
from ..features.target import CHANNEL, FOUR_POSITION, ZERO, Target
from ..reporting.results import AxisResult, ComparisonResult, FamilyResult, Verdict
from ..scoring.verdicts import BlockStats
from ..training.config import (
    CompareConfig,
    FamilyConfig,
    outputs_of,
    to_dict,
    train_config_of,
)
from ..training.parts import (
    Part,
    Split,
    build_part,
    data_hash,
    load_data,
    make_splits,
    targets_for,
)

__all__ = ["run_compare", "format_table", "Progress"]


class Progress:
    """One status line per family on stderr (rewritten in place on a terminal); silent if quiet."""

    def __init__(self, quiet: bool = False, stream: Any = None) -> None:
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._last = 0.0

    def epoch(self, label: str, epoch: int, train_loss: float, val_loss: float | None) -> None:
        if self.quiet or not self.tty:
            return
        now = time.monotonic()
        if now - self._last < 0.2:
            return
        self._last = now
        val = f"{val_loss:.4g}" if val_loss is not None else "-"
        self.stream.write(f"\r  {label:<14} epoch {epoch:5d}  train {train_loss:.4g}  val {val}   ")
        self.stream.flush()

    def line(self, text: str) -> None:
        if self.quiet:
            return
        if self.tty:
            self.stream.write("\r" + " " * 78 + "\r")
        self.stream.write(text + "\n")
        self.stream.flush()


class _Parts:
    """Signals and targets of each (run, signals) pair, built once for all families."""

    def __init__(self, cfg: CompareConfig, outputs: list[str], targets: Any = None) -> None:
        self.cfg, self.outputs = cfg, outputs
        # thermonet.features.target.Target, or the config's plain kind ("drift" / "four-position")
        self.targets: Any = targets if targets is not None else cfg.target
        self._cache: dict[tuple[int, tuple[str, ...], float | None], Part] = {}
        # families fitted side by side ask for the same parts: each is built once
        self._lock = threading.Lock()

    def __call__(self, rec: Any, signals: list[str], gap_s: float | None = None) -> Part:
        key = (id(rec), tuple(signals), gap_s)
        with self._lock:
            if key not in self._cache:
                self._cache[key] = build_part(rec, signals=signals, outputs=self.outputs,
                                              target=self.targets, gap_s=gap_s)
            return self._cache[key]


# ------------------------------------------------------------------------------------ plan
@dataclass
class _Plan:
    """Everything decided before fitting."""

    cfg: CompareConfig
    ds: Dataset
    outputs: list[str]
    targets: Target
    splits: list[Split]
    units: dict[str, str]
    source: str
    warnings: list[str] = field(default_factory=list)
    folds: Any = None                # thermonet.scoring.selection.FoldPlan of the last split's pool
    fold_note: str = ""              # why there is none (the single validation part decides)


def _baseline_named(cfg: CompareConfig) -> bool:
    """Whether the config file names ``baseline`` itself (rather than taking the default)."""
    import yaml

    src = getattr(cfg, "_source", None)
    if not src or not Path(src).is_file():
        return cfg.baseline != _DEFAULT_BASELINE
    try:
        data = yaml.safe_load(Path(src).read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError):  # load_config read it already; be conservative
        return True
    return isinstance(data, dict) and "baseline" in data


_DEFAULT_BASELINE = CompareConfig.__dataclass_fields__["baseline"].default


def _check_baseline(cfg: CompareConfig, source: str) -> None:
    """A ``baseline`` the config names must be one of its families (an error before fitting);
    the default (``cubic``, PX4/ArduPilot's anchor) applies only where such a family exists."""
    labels = [f.label for f in cfg.families]
    if cfg.baseline is not None and cfg.baseline not in labels and not _baseline_named(cfg):
        cfg.baseline = None
        return
    if cfg.baseline is not None and cfg.baseline not in labels:
        raise ConfigError(f"{source}: key 'baseline': no family named '{cfg.baseline}' "
                          f"(families: {', '.join(labels)}); name one of them or set "
                          "'baseline: null'")


def plan(cfg: CompareConfig, dataset: Dataset | None = None) -> _Plan:
    """Check ``cfg`` against the data, make the splits, collect input warnings (no fitting)."""
    from ..data.diagnostics import input_warnings
    from ..features.inputs import dynamic_signal, signals_for
    from ..training.config import check_families

    source = getattr(cfg, "_source", "config")
    check_families(cfg, source=source)
    _check_baseline(cfg, source)
    ds = dataset if dataset is not None else load_data(cfg.data, source=source)
    signals: set[str] = set()
    for i, fam in enumerate(cfg.families):
        for sig in signals_for(fam.inputs):
            signals.add(sig)
            if sig == "temperature_c" or dynamic_signal(sig) is not None:
                if any(r.temperature_c is None for r in ds):
                    raise ConfigError(f"{source}: key 'families[{i}].inputs': {fam.inputs} need "
                                      "a thermometer in °C and the data has none (proxies: "
                                      f"{', '.join(sorted(ds[0].proxies)) or 'none'})")
            elif sig not in ds[0].proxies:
                raise ConfigError(f"{source}: key 'families[{i}].inputs': no proxy channel "
                                  f"'{sig}' in the data (proxies: "
                                  f"{', '.join(sorted(ds[0].proxies)) or 'none'})")
    outputs = outputs_of(cfg, ds)
    targets = targets_for(ds, cfg.target, outputs, source=source)
    splits = make_splits(ds, cfg.split, source=source)
    units = {o: ds[0].units.get(o.split(".")[0], "") for o in outputs}
    for o in outputs:
        if o.endswith(".scale"):
            units[o] = "1"
    from ..features.dynamics import RATE_TAU_S

    warns = input_warnings(ds, signals=signals, rate_window_s=RATE_TAU_S)
    folds, note = _fold_plan(cfg, splits)
    return _Plan(cfg, ds, outputs, targets, splits, units, source, warns, folds, note)


def _fold_plan(cfg: CompareConfig, splits: list[Split]) -> tuple[Any, str]:
    """The cross-validation folds of the last split's pool (thermonet.scoring.selection), or why not."""
    from ..features.dynamics import dynamic_signals
    from ..scoring.selection import plan_folds

    sel = cfg.selection
    if sel.folds == 0:
        return None, "selection.folds is 0: chosen on the split's validation part"
    if cfg.target == "four-position":
        return None, ("the four-position target has one sample per soak: chosen on the "
                      "split's validation part")
    tau = max((d.param for fam in cfg.families for d in dynamic_signals(fam.inputs)
               if d.kind in ("rate", "lag")), default=0.0)
    # the folds look like the test: whole runs left out where the test is a run of its own,
    # blocks inside the runs where the test is blocks inside them (a time-block split)
    plan = plan_folds(splits[-1].pool, folds=sel.folds, blocks_per_fold=sel.blocks_per_fold,
                      tau_s=tau, purge_s=sel.purge_s, window_s=sel.window_s,
                      by_run=splits[-1].label != "time-blocks")
    if plan is None:
        return None, (f"too little training data for {sel.folds} cross-validation folds: "
                      "chosen on the split's validation part")
    return plan, ""


def _data_summary(ds: Dataset) -> list[dict[str, Any]]:
    rows = []
    for r in ds:
        t = r.temperature_c
        rows.append({"run_id": r.run_id, "samples": int(r.n_samples),
                     "duration_s": float(r.duration_s), "rate_hz": float(r.effective_rate_hz),
                     "temperature_min_c": None if t is None else float(np.nanmin(t)),
                     "temperature_max_c": None if t is None else float(np.nanmax(t))})
    return rows


# ------------------------------------------------------------------------------------- fit
@dataclass
class _Fitted:
    """One family after fitting: its record, last model, and its held-out block sums."""

    result: FamilyResult
    model: Any = None
    history: list[Any] | None = None
    val: BlockStats | None = None
    test: BlockStats | None = None
    test_parts: list[Part] = field(default_factory=list)
    test_preds: list[np.ndarray] = field(default_factory=list)
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    val_draws: np.ndarray | None = None  # bootstrap draws of the masked validation score
    best_val: float | None = None        # the last fold's best validation loss
    oof: Any = None                      # thermonet.scoring.selection.CandidateOOF (cross-validation)
    cv_mask: list[bool] | None = None    # per-axis compensate decision out of fold
    single: Any = None                   # (score, draws, mask) by the single validation part
    pool_targets: list[np.ndarray] = field(default_factory=list)
    pool_times: list[np.ndarray] = field(default_factory=list)


class _Cancelled(Exception):
    """Another family's fit failed or the run was interrupted: stop this one at its next epoch."""


def _fit_family(p: _Plan, fam: FamilyConfig, progress: Progress, parts: _Parts,
                cancel: threading.Event | None = None) -> _Fitted:
    from ..data.diagnostics import outside_fraction
    from ..models.base import as_numpy
    from ..scoring.verdicts import pool
    from ..training.fold import block_sums, fit_fold, fold_parts, fold_spec, score_part
    from ..training.train import predict

    cfg = p.cfg
    res = FamilyResult(label=fam.label, family=fam.family, inputs=list(fam.inputs),
                       params=dict(fam.params), train_on=fam.train_on)
    out = _Fitted(res)
    fold_axes: list[dict[str, dict[str, float]]] = []
    vals, tests = [], []
    outside: dict[str, list[tuple[float, int]]] = {}

    def on_epoch(epoch: int, train_loss: float, val_loss: float | None) -> None:
        if cancel is not None and cancel.is_set():
            raise _Cancelled(fam.label)
        progress.epoch(fam.label, epoch, train_loss, val_loss)

    try:
        tcfg = train_config_of(cfg, fam)
        for split in p.splits:
            spec = fold_spec(fam.inputs, split.train, t_ref=cfg.features.t_ref,
                             window_min=cfg.features.t_ref_window_min, gap_s=cfg.features.gap_s,
                             reference_for_targets=True)
            fp = fold_parts(spec, split.train, outputs=p.outputs, target=p.targets,
                            val=split.val, test=split.test, train_on=fam.train_on,
                            gap_s=cfg.features.gap_s, part=parts)
            fitted = fit_fold(fp, family=fam.family, outputs=p.outputs, hyper=fam.params,
                              config=tcfg, target_modes=p.targets.modes, on_epoch=on_epoch)
            res.fit_seconds = (0.0 if math.isnan(res.fit_seconds) else res.fit_seconds) \
                + fitted.fit_seconds
            held = fp.val or fp.train[-1]
            vals.append(block_sums(held, predict(fitted.model, held.signals)))
            test_part = fp.test
            assert test_part is not None
            pred, axes = score_part(fitted.model, test_part)
            tests.append(block_sums(test_part, pred))
            fold_axes.append(axes)
            model = fitted.model
            lo = np.asarray(as_numpy(model.sig_lo))
            hi = np.asarray(as_numpy(model.sig_hi))
            frac = outside_fraction(test_part.signals, lo, hi)
            for k, sig in enumerate(model.signals):
                outside.setdefault(sig, []).append((float(frac[k]), test_part.signals.shape[0]))
                out.ranges[sig] = (float(lo[k]), float(hi[k]))
            out.model, out.history = model, fitted.history
            out.best_val = fitted.best_val_loss
            out.test_parts.append(test_part)
            out.test_preds.append(pred)
            res.n_params, res.best_epoch = int(fitted.n_params), int(fitted.best_epoch)
    except FitError as err:  # this data cannot carry the family: reported, the comparison goes on
        res.status, res.reason, out.model = "failed", str(err), None
        return out
    if p.folds is not None:
        _cross_validate(out, p, fam, tcfg, spec, parts, on_epoch)
    out.val, out.test = pool(vals), pool(tests)
    res.outside_trained_range = {s: sum(f * n for f, n in v) / max(sum(n for _, n in v), 1)
                                 for s, v in outside.items()}
    metrics = {a: {k: float(np.mean([f[a][k] for f in fold_axes])) for k in fold_axes[0][a]}
               for a in p.outputs}
    if len(fold_axes) > 1:
        res.folds = fold_axes
    _judge_against_raw(out, metrics, p)
    return out


def _cross_validate(out: _Fitted, p: _Plan, fam: FamilyConfig, tcfg: Any, spec: Any,
                    parts: _Parts, on_epoch: Any) -> None:
    """Out-of-fold predictions of one family on the last split's pool (thermonet.scoring.selection):
    one fit per fold on the purged training rows of the whole runs, predictions on the
    fold's validation rows, and which of them lie inside the fold's trained domain."""
    from ..features.inputs import RATE, resolve_gap_s, signal_matrix
    from ..scoring.selection import CandidateOOF, in_domain, noise_widths, select
    from ..training.parts import HEATING_MIN_RATE_C_PER_MIN
    from ..training.train import fit, predict

    plan = p.folds
    split = p.splits[-1]
    oof = CandidateOOF(fam.label, out.result.n_params)
    whole = [parts(rec, spec.signals, spec.gap_s) for rec, _ in split.pool]
    keep = [np.ones(q.target.shape[0], dtype=bool) for q in whole]
    if fam.train_on == "heating":
        gap = resolve_gap_s(p.cfg.features.gap_s, [r for r, _ in split.pool], ["rate"])
        keep = [signal_matrix(rec, [RATE], gap)[:, 0] > HEATING_MIN_RATE_C_PER_MIN
                for rec, _ in split.pool]
    widen = [noise_widths(q.signals) for q in whole]
    for f in range(plan.k):
        train = [(q.signals[m & h], q.target[m & h], q.time_s[m & h])
                 for q, m, h in zip(whole, plan.train_masks[f], keep, strict=True)
                 if (m & h).any()]
        try:
            fitted = fit(family=fam.family, inputs=list(fam.inputs), outputs=p.outputs,
                         train=train, val=None, spec=spec, hyper=dict(fam.params),
                         config=tcfg, on_epoch=on_epoch, target=p.targets.modes)
        except FitError as err:   # e.g. a fold's span too short for the family: said, left out
            oof.failed = f"cross-validation fold {f}: {err}"
            break
        sig = np.vstack([x[0] for x in train])
        with np.errstate(invalid="ignore"):
            lo, hi = np.nanmin(sig, axis=0), np.nanmax(sig, axis=0)
        preds, inside = [], []
        for j, q in enumerate(whole):
            rows = np.flatnonzero(plan.fold_of[j] == f)
            x = q.signals[rows]
            preds.append(predict(fitted.model, x) if rows.size
                         else np.zeros((0, len(p.outputs))))
            inside.append(in_domain(x, lo, hi, widen[j]) & np.isfinite(preds[-1]).all(axis=1))
        oof.pred.append(preds)
        oof.inside.append(inside)
    out.oof = oof
    out.pool_targets = [q.target for q in whole]
    out.pool_times = [q.time_s for q in whole]
    if oof.failed is None:
        own = select(plan, out.pool_targets, out.pool_times, {fam.label: oof}, p.outputs)
        out.cv_mask = own.compensate.get(fam.label)


def family_workers(cfg: CompareConfig, workers: int | None = None) -> int:
    """How many families are fitted side by side: ``workers`` (the caller's: a fleet runs
    units side by side and passes 1), else the config's ``workers``; 0 is automatic —
    one per CPU this process may use, at most one per family.  Each fit runs its own
    ``train.threads`` torch threads (default 1); a family that overrides ``threads``
    makes the comparison serial (torch's thread count is one setting per process)."""
    n = cfg.workers if workers is None else workers
    if any("threads" in fam.train for fam in cfg.families):
        return 1
    if n == 0:
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:            # not on Linux
            cores = os.cpu_count() or 1
        n = cores
    return max(1, min(n, len(cfg.families)))


class _FitQueue:
    """Every family of the plan, fitted ``workers`` at a time (threads: torch and numpy
    release the GIL in their kernels, and the fits share the built parts and their
    window means); :meth:`result` hands them out in config order.

    With one worker each fit runs when asked for (inside its MLflow run, as before);
    with more, all are submitted on entry and :meth:`result` waits for the one asked
    for.  Results do not depend on ``workers`` (each fit is seeded by its own config and
    draws from no shared random state).  A fit that raises (anything but a FitError,
    which is a reported result) is re-raised at once, and on any error or interrupt
    the other fits stop at their next epoch before the queue closes.
    """

    def __init__(self, p: _Plan, progress: Progress, parts: _Parts, workers: int) -> None:
        self.p, self.progress, self.parts, self.workers = p, progress, parts, workers
        self.cancel = threading.Event()
        self.pool: Any = None
        self.futures: dict[str, Any] = {}

    def __enter__(self) -> _FitQueue:
        if self.workers > 1:
            from concurrent.futures import ThreadPoolExecutor

            self.pool = ThreadPoolExecutor(max_workers=self.workers,
                                           thread_name_prefix="thermonet-fit")
            self.futures = {fam.label: self.pool.submit(_fit_family, self.p, fam, self.progress,
                                                        self.parts, self.cancel)
                            for fam in self.p.cfg.families}
        return self

    def result(self, fam: FamilyConfig) -> _Fitted:
        if self.pool is None:
            return _fit_family(self.p, fam, self.progress, self.parts)
        from concurrent.futures import FIRST_COMPLETED, wait

        target = self.futures[fam.label]
        while True:
            pending = [f for f in self.futures.values() if not f.done()]
            done = [f for f in self.futures.values() if f.done()]
            for f in done:          # another family's error, raised now, not at its turn
                err = f.exception()
                if err is not None:
                    raise err
            if target.done():
                return target.result()
            wait(pending, return_when=FIRST_COMPLETED)

    def __exit__(self, *exc: Any) -> None:
        if self.pool is not None:
            if exc[0] is not None:
                self.cancel.set()
            self.pool.shutdown(wait=True, cancel_futures=True)


_DRAWS: dict[int, np.ndarray] = {}


def _draws(n_blocks: int) -> np.ndarray:
    from ..scoring.verdicts import draws

    if n_blocks not in _DRAWS:
        _DRAWS[n_blocks] = draws(n_blocks)
    return _DRAWS[n_blocks]


def _verdicts(num: np.ndarray, den: np.ndarray) -> tuple[list[Verdict], np.ndarray, np.ndarray]:
    from ..scoring.verdicts import ratio_interval, verdict_of

    ratio, boot, iv = ratio_interval(num, den, _draws(num.shape[0]))
    return ([Verdict(float(ratio[j]), float(iv[0, j]), float(iv[1, j]),
                     verdict_of(float(iv[0, j]), float(iv[1, j]))) for j in range(ratio.size)],
            ratio, boot)


def _offset_meaningful(targets: Target, axis: str) -> bool:
    """Whether the absolute offset of ``axis`` is an error (not an unknown constant).

    Where the target mode makes the true input known — a reference channel
    (``channel``), a static gyro's true rate 0 (``zero``), study 000's per-soak
    bias K0 — the offset is an error; ``at-t-ref`` axes (gravity's or the
    field's projection, a pressure) and scale factors have none
    (:mod:`thermonet.features.target`).
    """
    mode = targets.mode(axis)
    if mode == FOUR_POSITION:
        return axis.endswith(".bias")
    return mode in (CHANNEL, ZERO)


def _judge_against_raw(f: _Fitted, metrics: dict[str, dict[str, float]], p: _Plan) -> None:
    """Validation and test verdicts against raw, the per-axis mask, the masked scores."""
    from ..scoring.verdicts import masked_scores

    assert f.val is not None and f.test is not None
    res = f.result
    val, val_ratio, val_boot = _verdicts(f.val.ss_comp, f.val.ss_raw)
    test, test_ratio, test_boot = _verdicts(f.test.ss_comp, f.test.ss_raw)
    single = np.array([v.verdict == "better" for v in val])   # the single-part rule's mask
    mask = single if f.cv_mask is None else np.array(f.cv_mask)   # out of fold where it ran
    f.single = (*masked_scores(val_ratio, val_boot, single), single.tolist())
    res.val_score, draws_ = masked_scores(val_ratio, val_boot, mask)
    q = [2.5, 97.5]
    lo_hi = np.nanpercentile(draws_, q) if np.isfinite(draws_).any() else [math.nan] * 2
    res.val_interval = (float(lo_hi[0]), float(lo_hi[1]))
    res.test_score = float(np.mean(np.where(mask, test_ratio, 1.0)))
    f.val_draws = draws_
    sr, sc = f.test.score_raw, f.test.score_comp
    orw, ocp = f.test.offset_raw, f.test.offset_comp
    for j, axis in enumerate(p.outputs):
        meaningful = _offset_meaningful(p.targets, axis)
        res.axes[axis] = AxisResult(
            score_raw=float(sr[j]), score_comp=float(sc[j]), test=test[j], val=val[j],
            compensate=bool(mask[j]), offset_raw=float(orw[j]) if meaningful else None,
            offset_comp=float(ocp[j]) if meaningful else None, metrics=metrics[axis])


def _family_config(cfg: CompareConfig, fam: FamilyConfig,
                   tracking: dict[str, Any] | None = None) -> dict[str, Any]:
    """What a family's checkpoint carries: its own resolved config, not the whole comparison's
    (the same layout :meth:`thermonet.DriftEstimator.save` writes); ``tracking`` as it was
    actually used (:func:`resolved_config`)."""
    return {"family": to_dict(fam), "train": to_dict(train_config_of(cfg, fam)),
            "features": to_dict(cfg.features), "target": cfg.target,
            "tracking": to_dict(cfg.tracking) if tracking is None else dict(tracking)}


def data_source(cfg: CompareConfig, ds: Dataset | None, *, given: bool) -> dict[str, Any]:
    """Where the data of a comparison actually came from, for ``results.json``'s
    ``provenance`` and each checkpoint: the files with their SHA-256 (and the mapping's),
    or the simulator's preset, run count and seed, or a dataset the caller passed in."""
    from ..core.outdir import sha256_file

    def file(path: str | Path) -> dict[str, Any]:
        p = Path(path)
        return {"path": str(path), "sha256": sha256_file(p) if p.is_file() else None}

    if given and ds is not None:
        sources = sorted({r.meta.get("source", "") for r in ds} - {""})
        return {"kind": "dataset", "device": ds.device_id, "runs": [r.run_id for r in ds],
                "preset": ds.meta.get("preset") or None, "sources": sources[:20]}
    if cfg.data.paths:
        return {"kind": "files", "files": [file(p) for p in cfg.data.paths],
                "mapping": None if cfg.data.mapping is None else file(cfg.data.mapping)}
    return {"kind": "simulated", "preset": cfg.data.preset,
            "runs": cfg.data.runs if ds is None else len(ds), "seed": cfg.data.seed}


def resolved_config(cfg: CompareConfig, ds: Dataset | None, *, given: bool,
                    tracking_enabled: bool,
                    tracking_uri: str | None, workers: int) -> dict[str, Any]:
    """The config as the comparison actually used it — ``config.resolved.yaml``, results.json's
    ``config``, the MLflow params — and still a config ``load_config`` reads back.

    Not the config's defaults where they did not apply: a comparison on files has no
    ``preset``, ``runs`` or ``seed``, nor has one on a dataset the caller passed (a
    calibrate instance) unless the data say which preset made them; ``tracking.enabled``
    is false under ``--no-track``
    and ``tracking.uri`` is the store written to (None when none was); ``workers`` is the
    number of families actually fitted side by side; a simulated comparison names the runs
    simulated.
    """
    d = to_dict(cfg)
    if cfg.data.paths:
        d["data"] = {"preset": None, "paths": list(cfg.data.paths), "mapping": cfg.data.mapping,
                     "outputs": list(cfg.data.outputs)}
    elif given:  # the caller's dataset (a fleet unit, a calibrate instance): not the default
        preset = None if ds is None else (ds.meta.get("preset") or ds[0].meta.get("preset"))
        d["data"] = {"preset": preset or None, "outputs": list(cfg.data.outputs)}
        if preset and ds is not None:
            d["data"]["runs"] = len(ds)
    elif ds is not None:
        d["data"]["runs"] = len(ds)
    d["tracking"] = {"enabled": bool(tracking_enabled),
                     "uri": tracking_uri if tracking_enabled else None,
                     "experiment": cfg.tracking.experiment}
    d["workers"] = int(workers)
    return d


def _resolved_yaml(resolved: dict[str, Any], provenance: dict[str, Any]) -> str:
    """``config.resolved.yaml``: the resolved config, headed by comments saying where the
    data came from (with digests) and the options as given."""
    src = provenance["data"]
    lines = [f"# thermonet {provenance['thermonet_version']}: the configuration this comparison "
             "actually used"]
    if src["kind"] == "files":
        lines.append("# data files (sha256  path):")
        lines += [f"#   {f['sha256'] or 'missing'}  {f['path']}" for f in src["files"]]
        if src["mapping"]:
            lines.append(f"# mapping: {src['mapping']['sha256'] or 'missing'}  "
                         f"{src['mapping']['path']}")
    elif src["kind"] == "simulated":
        lines.append(f"# data: simulated, preset {src['preset']}, {src['runs']} runs, "
                     f"seed {src['seed']}")
    else:
        lines.append(f"# data: a dataset passed by the caller (device {src['device']}, "
                     f"runs {', '.join(src['runs'])})")
    t = provenance["tracking"]
    lines.append("# tracking: " + (f"MLflow at {t['uri']}" if t["enabled"] else "off"))
    lines.append("# options as given: " + ", ".join(f"{k}={v!r}" for k, v in
                                                     provenance["options"].items()))
    return "\n".join(lines) + "\n" + _yaml(resolved)


# ---------------------------------------------------------------------------------- report
def _choose_and_judge(fitted: dict[str, _Fitted], result: ComparisonResult, p: _Plan) -> None:
    """Choice with ties, verdicts against the baseline, warnings about the chosen model."""
    from ..scoring.verdicts import choose

    ok = {k: f for k, f in fitted.items() if f.result.ok and f.val_draws is not None}
    cv = {k: f for k, f in ok.items() if f.oof is not None}
    if p.folds is not None and cv:
        from ..scoring.selection import select

        first = next(iter(cv.values()))
        sel = select(p.folds, first.pool_targets, first.pool_times,
                     {k: f.oof for k, f in cv.items()}, p.outputs)
        chosen, tied, why = sel.chosen, sel.tied, sel.reason
        result.selection = sel.record
        # what the single validation part would have chosen: how close the call was
        alt = choose({k: (f.single[0], f.single[1]) for k, f in ok.items()},
                     {k: f.result.n_params for k, f in ok.items()})
        result.selection["single_split"] = {
            "chosen": alt[0], "reason": alt[2],
            "compensate": {k: dict(zip(p.outputs, f.single[2], strict=True))
                           for k, f in ok.items()}}
        if alt[0] != chosen:
            result.warn(f"the split's single validation part would have chosen "
                        f"{alt[0] or 'nothing'} instead of {chosen or 'nothing'}: the call rests "
                        "on the cross-validation (see 'How the model was chosen')")
        for k, f in cv.items():
            if f.oof.failed is not None:
                result.warn(f"{k}: not a candidate: {f.oof.failed}")
    else:
        scores = {k: (f.result.val_score, f.val_draws) for k, f in ok.items()
                  if f.val_draws is not None}
        chosen, tied, why = choose(scores, {k: f.result.n_params for k, f in ok.items()})
        result.selection = {"method": "single validation part", "note": p.fold_note}
    result.chosen, result.chosen_reason, result.tie = chosen, why, tied
    if tied:
        result.warn(why)
    base = ok.get(p.cfg.baseline or "")
    if base is not None and base.test is not None:
        for f in ok.values():
            assert f.test is not None
            vs, _, _ = _verdicts(f.test.ss_comp, base.test.ss_comp)
            for j, axis in enumerate(p.outputs):
                ax = f.result.axes[axis]
                ax.vs_baseline = vs[j]
                b = base.result.axes[axis].metrics.get("pp_comp", math.nan)
                ax.metrics["pp_ratio_vs_baseline"] = (
                    ax.metrics.get("pp_comp", math.nan) / b if b > 0 else math.nan)
    if chosen is None:
        return
    fam = result.families[chosen]
    for axis, ax in fam.axes.items():
        if not ax.compensate:
            result.uncompensated_axes.append(axis)
            result.warn(f"{axis}: left uncompensated by the chosen model {chosen} (drift 0 on "
                        f"this axis): it does not beat the raw output on the validation data "
                        f"(score ratio {ax.val.ratio:.3g}, interval {ax.val.low:.3g} … "
                        f"{ax.val.high:.3g})")
        elif ax.test.verdict == "worse":
            result.warn(f"{axis}: the chosen model {chosen} is worse than raw on the held-out "
                        f"test data (score ratio {ax.test.ratio:.3g}, 95 % interval "
                        f"{ax.test.low:.3g} … {ax.test.high:.3g}); the drift may depend on "
                        "more than temperature (thermal history, hysteresis)")
    if not fam.compensate_in_model and result.uncompensated_axes:
        result.warn(f"the model file of {chosen} does not carry the per-axis mask yet; export "
                    f"it with care: {', '.join(result.uncompensated_axes)} should stay "
                    "uncompensated")


def _extrapolation(fitted: dict[str, _Fitted], result: ComparisonResult) -> None:
    from ..data.diagnostics import extrapolation_warnings

    fractions: dict[str, float] = {}
    ranges: dict[str, tuple[float, float]] = {}
    for f in fitted.values():
        if not f.result.ok:
            continue
        for sig, frac in f.result.outside_trained_range.items():
            fractions[sig] = max(fractions.get(sig, 0.0), frac)
            ranges.setdefault(sig, f.ranges[sig])
    result.data["outside_trained_range"] = fractions
    result.data["trained_range"] = {k: list(v) for k, v in ranges.items()}
    for w in extrapolation_warnings(fractions, ranges):
        result.warn(w)


def run_compare(cfg: CompareConfig, out_dir: str | Path, *, overwrite: bool = False,
                track: bool | None = None, tracking_uri: str | None = None,
                quiet: bool = False, progress: Progress | None = None,
                dataset: Dataset | None = None, plots: bool = True,
                workers: int | None = None) -> dict[str, Any]:
    """Fit every family of ``cfg``, judge on held-out data, write ``out_dir``; return results.

    ``dataset`` replaces the configured data (benchmarks feed variants of one
    simulation this way); the config's ``data`` section is then ignored.
    ``plots=False`` writes no PNG files (the report then has no figures).
    ``workers`` overrides the config's ``workers`` (families fitted side by side,
    :func:`family_workers`).
    Returns the ``results.json`` document (:meth:`ComparisonResult.to_json`).

    The output appears whole or not at all (:mod:`thermonet.core.outdir`): it is
    built in a staging directory beside ``out_dir`` and moved into place when
    complete; ``results.json`` records each checkpoint's SHA-256.  A non-empty
    ``out_dir`` that is not a complete comparison is refused; a previous
    comparison is replaced only with ``overwrite=True``.
    """
    from ..core.outdir import staged_output
    from ..training.train import thread_limits

    # torch's and the native pools (BLAS, OpenMP) capped at train.threads for the whole
    # comparison, data preparation and evaluation included: the cap is process-wide, so
    # fits side by side must not lift it when one of them ends
    with thread_limits(cfg.train.threads), staged_output(out_dir, overwrite=overwrite) as stage:
        results = _run_compare_in(cfg, stage.path, track=track, tracking_uri=tracking_uri,
                                  quiet=quiet, progress=progress, dataset=dataset,
                                  plots=plots, workers=workers)
        stage.finish(results, lambda doc: doc)
    return results


def _run_compare_in(cfg: CompareConfig, out_dir: str | Path, *, track: bool | None = None,
                    tracking_uri: str | None = None, quiet: bool = False,
                    progress: Progress | None = None, dataset: Dataset | None = None,
                    plots: bool = True, workers: int | None = None) -> dict[str, Any]:
    """The comparison itself, written into ``out_dir`` (a staging directory)."""
    from ..scoring.verdicts import LEVEL, MIN_BLOCKS, RESAMPLES, SEED, apply_compensate_mask
    from ..tracking import Tracker
    from ..training.checkpoint import save_checkpoint

    progress = progress or Progress(quiet)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: --out must be a directory, and this is a file")
    p = plan(cfg, dataset)
    ds, outputs, units = p.ds, p.outputs, p.units
    out.mkdir(parents=True, exist_ok=True)
    dhash = data_hash(ds)
    tracker = Tracker(enabled=cfg.tracking.enabled if track is None else track,
                      uri=tracking_uri or cfg.tracking.uri, experiment=cfg.tracking.experiment)
    preset = ds.runs[0].meta.get("preset", "") if dataset is not None or not cfg.data.paths \
        else ""
    tags = {"device": ds.device_id, "preset": preset, "data_hash": dhash,
            "target": p.targets.kind}
    resolved = resolved_config(cfg, ds, given=dataset is not None, workers=family_workers(
        cfg, workers), tracking_enabled=tracker.enabled, tracking_uri=tracker.uri)
    provenance = {"thermonet_version": __version__,
                  "data": data_source(cfg, ds, given=dataset is not None),
                  "tracking": resolved["tracking"],
                  "options": {"track": track, "tracking_uri": tracking_uri, "workers": workers,
                              "plots": plots}}
    splits = p.splits
    result = ComparisonResult(
        config=resolved, device=ds.device_id, data_hash=dhash, target=p.targets.kind,
        split={"strategy": splits[0].label if len(splits) == 1 else "leave-one-run-out",
               "folds": [s.describe for s in splits]},
        units=units, targets=p.targets.as_dict(), baseline=cfg.baseline,
        data={"runs": _data_summary(ds)},
        thermonet_version=__version__)
    for w in p.warnings:
        result.warn(w)
    progress.line(f"thermonet compare: {ds.device_id} ({len(ds)} runs, outputs "
                  f"{', '.join(outputs)}), split {result.split['strategy']}")
    fitted: dict[str, _Fitted] = {}
    parts = _Parts(cfg, outputs, p.targets)
    n_workers = family_workers(cfg, workers)
    if n_workers > 1:
        progress.line(f"fitting {len(cfg.families)} families, {n_workers} side by side")
    with tracker.run(f"compare-{ds.device_id}", params=resolved, tags=tags) as parent_id, \
            _FitQueue(p, progress, parts, n_workers) as queue:
        result.mlflow_run_id = parent_id
        for fam in cfg.families:
            with tracker.run(fam.label, params={"family": fam.family, "inputs": fam.inputs,
                                                "params": fam.params},
                             tags={**tags, "family": fam.family}, nested=True) as run_id:
                f = queue.result(fam)
                r = f.result
                r.mlflow_run_id = run_id
                if r.ok:
                    mask = [r.axes[a].compensate for a in outputs]
                    r.compensate_in_model = apply_compensate_mask(f.model, mask)
                    tracker.log_history(list(f.history or []))
                    tracker.log_metrics({f"test/{a}/{k}": v for a, m in r.axes.items()
                                         for k, v in {**m.metrics, "score_ratio": m.test.ratio,
                                                      "score_raw": m.score_raw,
                                                      "score_comp": m.score_comp}.items()})
                    tracker.log_metrics({"val/score": r.val_score,
                                         "fit_seconds": r.fit_seconds})
                    ckpt = out / "models" / f"{fam.label}.pt"
                    try:
                        save_checkpoint(ckpt, f.model, config=_family_config(
                                            cfg, fam, resolved["tracking"]),
                                        epoch=r.best_epoch, best_val=f.best_val,
                                        extra={"label": fam.label, "device_id": ds.device_id,
                                               "data_hash": dhash, "units": units,
                                               "signal_units": {s: ds[0].units.get(s, "")
                                                                for s in ds[0].proxies},
                                               "val_score": r.val_score,
                                               "compensate": dict(zip(outputs, mask, strict=True)),
                                               "test_metrics": r.to_json()["axes"],
                                               "mlflow_run_id": run_id or "",
                                               "provenance": provenance})
                        r.checkpoint = str(ckpt)
                        tracker.log_artifact(ckpt, "model")
                    except ThermonetError as err:  # a NaN model is never saved
                        r.status, r.reason = "failed", str(err)
                    kept = sum(mask)
                    progress.line(f"  {fam.label:<14} fitted in {r.fit_seconds:.2f} s, "
                                  f"{r.n_params} params, val score {r.val_score:.3g} "
                                  f"({kept}/{len(mask)} axes compensated)")
                else:
                    tracker.set_tags({"status": "failed"})
                    progress.line(f"  {fam.label:<14} not fitted: {r.reason}")
                result.families[fam.label] = r
                fitted[fam.label] = f
        n_val = next((f.val.n.size for f in fitted.values() if f.val is not None), 0)
        n_test = next((f.test.n.size for f in fitted.values() if f.test is not None), 0)
        result.bootstrap = {
            "method": "non-overlapping block bootstrap over contiguous held-out blocks "
                      "(paired across families), percentile interval",
            "resamples": RESAMPLES, "level": LEVEL, "seed": SEED, "min_blocks": MIN_BLOCKS,
            "blocks": {"val": n_val, "test": n_test}}
        _choose_and_judge(fitted, result, p)
        # the out-of-fold scores the choice rests on, in the comparison's own run
        tracker.log_metrics({f"cv/{k}/score": c["score"] for k, c in
                             result.selection.get("candidates", {}).items() if "score" in c})
        _extrapolation(fitted, result)
        doc = result.to_json()
        doc["provenance"] = provenance
        plot_paths = _plots(out, fitted, doc, ds) if plots else []
        from ..reporting.report import write_report

        atomic_write_text(out / "results.json", json.dumps(doc, indent=2))
        atomic_write_text(out / "config.resolved.yaml", _resolved_yaml(resolved, provenance))
        write_report(out / "report.html", doc, plot_paths)
        tracker.set_tags({"chosen": result.chosen or "none"})
        tracker.log_artifact(out / "results.json")
        tracker.log_artifact(out / "config.resolved.yaml")
        tracker.log_artifact(out / "report.html")
        for path in plot_paths:
            tracker.log_artifact(path, "plots")
    for w in result.warnings:
        progress.line(f"warning: {w}")
    return doc


def _plots(out: Path, fitted: dict[str, _Fitted], results: dict[str, Any],
           ds: Dataset) -> list[Path]:
    """PNG figures of the last fold's test data, every fitted family in its own colour."""
    from ..core.names import path_component
    from ..reporting.plots import (
        family_colours,
        plot_allan,
        plot_drift_vs_temperature,
        plot_residual_vs_temperature,
        plot_residual_vs_time,
    )

    ok = {k: f for k, f in fitted.items() if f.model is not None and f.test_parts}
    if not ok:
        return []
    paths: list[Path] = []
    part = next(iter(ok.values())).test_parts[-1]
    colours = family_colours(list(fitted))
    style: dict[str, Any] = {"chosen": results.get("chosen"), "baseline": results.get("baseline"),
             "colours": colours}
    x_label = "temperature (°C)" if ds[0].temperature_c is not None else \
        f"{sorted(ds[0].proxies)[0]} ({ds[0].units.get(sorted(ds[0].proxies)[0], '') or 'proxy'})"
    pdir = out / "plots"
    for j, axis in enumerate(part.outputs):
        unit = results["units"].get(axis, "")
        curves = {label: (part.bin_by, f.test_preds[-1][:, j]) for label, f in ok.items()}
        safe = path_component(axis.replace(".", "_"))  # a name from data, made a file name
        paths.append(plot_drift_vs_temperature(
            pdir / f"drift_vs_temperature_{safe}.png", temperature_c=part.bin_by,
            observed_drift=part.target[:, j], curves=curves, axis=axis, units=unit,
            bin_width=part.bin_width, x_label=x_label, **style))
        if results["target"] == "drift":
            resid = {label: part.target[:, j] - f.test_preds[-1][:, j] for label, f in ok.items()}
            paths.append(plot_residual_vs_time(
                pdir / f"residual_vs_time_{safe}.png", time_s=part.time_s,
                raw_error=part.target[:, j], compensated=resid, axis=axis, units=unit, **style))
            paths.append(plot_residual_vs_temperature(
                pdir / f"residual_vs_temperature_{safe}.png", temperature_c=part.bin_by,
                raw_error=part.target[:, j], compensated=resid, axis=axis, units=unit,
                bin_width=part.bin_width, x_label=x_label, **style))
            paths.append(plot_allan(pdir / f"allan_{safe}.png", rate_hz=part.rate_hz,
                                    raw_error=part.target[:, j], compensated=resid,
                                    axis=axis, units=unit, **style))
    return paths


def _yaml(data: Any) -> str:
    import yaml

    return yaml.safe_dump(data, sort_keys=False)


_METRIC_COLS = ("pp_raw", "pp_comp", "drift_error_rms", "ppm_per_c_raw", "ppm_per_c_comp")


def _ratio_cell(v: dict[str, Any] | None) -> str:
    if not v or v.get("ratio") is None:
        return f"{'-':>22}"
    lo, hi = (x if x is not None else math.nan for x in v["interval"])
    mark = {"better": "+", "worse": "!", "indistinguishable": "="}[v["verdict"]]
    return f"{v['ratio']:6.3g} [{lo:5.3g},{hi:5.3g}] {mark}"


def format_table(results: dict[str, Any]) -> str:
    """The comparison as a text table: family × axis, scores, verdicts, the ratio to the baseline.

    ``vs raw`` and ``vs baseline`` are offset-free score ratios on the test
    data with their 95 % bootstrap interval and verdict (+ better, ! worse,
    = indistinguishable); ``comp`` says whether the axis is compensated.
    """
    fams = results["families"]
    axes = list(results["units"])
    cols = [c for c in _METRIC_COLS
            if any(c in f.get("axes", {}).get(a, {}) for f in fams.values() for a in axes)]
    base = results.get("baseline")
    head = (f"{'family':<14} {'axis':<14} {'fit s':>6} {'params':>6} {'val':>6} {'comp':>4} "
            f"{'vs raw':>22} {'vs ' + (base or 'baseline'):>22} "
            + " ".join(f"{c:>12}" for c in cols))
    lines = [head, "-" * len(head)]
    for name, f in fams.items():
        if f["status"] != "ok":
            lines.append(f"{name:<14} not fitted: {f['reason']}")
            continue
        val = f.get("val_score")
        for i, a in enumerate(axes):
            m = f["axes"][a]
            pre = (f"{name:<14} {a:<14} {f['fit_seconds']:6.2f} {f['n_params']:6d} "
                   f"{(val if val is not None else math.nan):6.3g} ") if i == 0 else \
                f"{'':<14} {a:<14} {'':>6} {'':>6} {'':>6} "
            vs_raw = {"ratio": m.get("score_ratio"), "interval": m.get("interval", [None, None]),
                      "verdict": m.get("verdict", "indistinguishable")}
            metrics = " ".join(f"{(m.get(c) if m.get(c) is not None else math.nan):12.4g}"
                               for c in cols)
            lines.append(pre + f"{'yes' if m.get('compensate') else 'no':>4} "
                         f"{_ratio_cell(vs_raw)} {_ratio_cell(m.get('vs_baseline'))} " + metrics)
    lines.append("")
    sel = results.get("selection") or {}
    if sel.get("candidates"):
        lines.append(f"selection: {sel.get('kind')}, {sel.get('folds')} folds, purge "
                     f"{sel.get('purge_s', 0):.0f} s, score windows {sel.get('window_s', 0):.0f} s "
                     "(out-of-fold low-frequency residual / raw, [95 % interval], per fold)")
        for name, c in sel["candidates"].items():
            if c.get("status") != "ok":
                lines.append(f"  {name:<14} not a candidate: {c.get('reason')}")
                continue
            lo, hi = c["interval"]
            folds = " ".join(f"{x:.3g}" for x in c["fold_scores"])
            lines.append(f"  {name:<14} {c['score']:.4g} [{lo:.4g}, {hi:.4g}]  folds {folds}")
    elif sel.get("note"):
        lines.append(f"selection: {sel['note']}")
    lines.append(f"chosen: {results.get('chosen') or 'none'} — {results.get('chosen_reason', '')}")
    if results.get("uncompensated_axes"):
        lines.append(f"left uncompensated: {', '.join(results['uncompensated_axes'])}")
    lines.append("scores: spread of the error about its mean on held-out data, family / raw "
                 "(< 1 better); [95 % block-bootstrap interval]")
    lines.append("units: " + ", ".join(f"{a} [{u}]" for a, u in results["units"].items()))
    return "\n".join(lines)
