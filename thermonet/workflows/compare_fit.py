"""``thermonet compare``, step 2 — fitting: per family and fold, the one split pipeline
(:mod:`thermonet.training.pipeline`: parts → fit → score), the held-out block sums, the
cross-validated out-of-fold predictions of model selection, and the families fitted side by side
(:class:`FitQueue`, :func:`family_workers`).
"""

from __future__ import annotations

import math
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import FitError
from ..core.helpers import usable_cores
from ..core.profile import stage
from ..data.diagnostics import outside_distance, outside_fraction
from ..features.dynamics import dynamic_signals
from ..features.inputs import (
    RATE,
    TEMPERATURE,
    joint_columns,
    resolve_gap_s,
    signal_matrix,
)
from ..reporting.results import FamilyResult
from ..scoring.domain import Envelope, noise_widths
from ..scoring.fold_plan import memory_share
from ..scoring.oof_pool import CandidateOOF
from ..scoring.selection import point_label, select, tuning_choice
from ..scoring.verdicts import pool
from ..training.config import (
    CompareConfig,
    FamilyConfig,
    train_config_of,
    tune_points,
)
from ..training.parameters import parameter_rows
from ..training.parts import HEATING_MIN_RATE_C_PER_MIN, fit_arrays, rows_average_s
from .compare_judge import Fitted, judge_against_raw
from .compare_plan import PartCache, Plan

__all__ = ["Progress", "fit_family", "family_workers", "FitQueue"]


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


class _Cancelled(Exception):
    """Another family's fit failed or the run was interrupted: stop this one at its next epoch."""


@dataclass
class _SplitsSeen:
    """What the fits on the splits leave for the family's result."""

    vals: list[Any] = field(default_factory=list)      # held-out block sums per split
    tests: list[Any] = field(default_factory=list)
    fold_axes: list[dict[str, dict[str, float]]] = field(default_factory=list)
    outside: dict[str, list[tuple[float, int]]] = field(default_factory=dict)
    spec: Any = None                                    # the last split's feature spec


def fit_family(p: Plan, fam: FamilyConfig, progress: Progress, parts: PartCache,
               cancel: threading.Event | None = None) -> Fitted:
    """One family: tuned on the training folds (where asked), fitted on each split (refit on
    training + validation), cross-validated, judged against raw.  A family the data cannot
    carry comes back ``failed`` with its reason; the comparison goes on."""
    cfg = p.cfg
    res = FamilyResult(label=fam.label, family=fam.family, inputs=list(fam.inputs),
                       params=dict(fam.params), train_on=fam.train_on)
    out = Fitted(res)
    seen = _SplitsSeen()

    def on_epoch(epoch: int, train_loss: float, val_loss: float | None) -> None:
        if cancel is not None and cancel.is_set():
            raise _Cancelled(fam.label)
        progress.epoch(fam.label, epoch, train_loss, val_loss)

    try:
        tcfg = train_config_of(cfg, fam)
        fam, tuned, tuned_oof = _tune_step(p, fam, tcfg, parts, on_epoch)
        for split in p.splits:
            _fit_on_split(p, fam, tcfg, split, parts, on_epoch, out, seen)
    except FitError as err:  # this data cannot carry the family: reported, the comparison goes on
        res.status, res.reason, out.model = "failed", str(err), None
        return out
    # of the model compare keeps (the last split's), once — not again for every split
    res.tuned = {**tuned, **out.model.family.tuned()}
    res.cost = out.model.family.cost()
    out.parameters = _parameters(p, out.model, out.train_parts, tcfg.average_s)
    if p.folds is not None:
        with stage(f"{fam.label}: cross-validation (one fit per fold)"):
            _cross_validate(out, p, fam, tcfg, seen.spec, parts, on_epoch, tuned_oof)
    out.val, out.test = pool(seen.vals), pool(seen.tests)
    res.outside_trained_range = {s: sum(f * n for f, n in v) / max(sum(n for _, n in v), 1)
                                 for s, v in seen.outside.items()}
    metrics = {a: {k: float(np.mean([f[a][k] for f in seen.fold_axes]))
                   for k in seen.fold_axes[0][a]} for a in p.outputs}
    if len(seen.fold_axes) > 1:
        res.folds = seen.fold_axes
    judge_against_raw(out, metrics, p)
    return out


def _tune_step(p: Plan, fam: FamilyConfig, tcfg: Any, parts: PartCache, on_epoch: Any
               ) -> tuple[FamilyConfig, dict[str, Any], Any]:
    """The family's hyper-parameters chosen on the training folds (``tune:``): the tuned
    family, its record and the chosen point's out-of-fold predictions; the configured
    values with a note where there are no folds; the family unchanged without ``tune:``."""
    from ..training.pipeline import split_spec  # the torch boundary

    if fam.tune and p.folds is not None:
        cfg = p.cfg
        spec = split_spec(fam.inputs, p.splits[-1].train, t_ref=cfg.features.t_ref,
                          window_min=cfg.features.t_ref_window_min,
                          gap_s=cfg.features.gap_s, reference_for_targets=True)
        with stage(f"{fam.label}: tuning (folds x grid points)"):
            return _tune(p, fam, tcfg, spec, parts, on_epoch)
    if fam.tune:
        return fam, {"tuning": {"rule": "not tuned: no cross-validation folds "
                                f"({p.fold_note or 'selection.folds is 0'}); the configured "
                                "values are used"}}, None
    return fam, {}, None


def _fit_on_split(p: Plan, fam: FamilyConfig, tcfg: Any, split: Any, parts: PartCache,
                  on_epoch: Any, out: Fitted, seen: _SplitsSeen) -> None:
    """One split: the fit on its training part (then the refit on training + validation),
    scored on its validation and test parts; ``out`` keeps the last split's model."""
    from ..models.base import as_numpy  # the torch boundary
    from ..training.pipeline import (  # torch boundary
        block_sums,
        fit_split,
        residual_spread,
        score_part,
        split_parts,
        split_spec,
    )
    from ..training.train import predict  # torch boundary

    cfg, res = p.cfg, out.result
    spec = split_spec(fam.inputs, split.train, t_ref=cfg.features.t_ref,
                      window_min=cfg.features.t_ref_window_min, gap_s=cfg.features.gap_s,
                      reference_for_targets=True)
    seen.spec = spec
    fp = split_parts(spec, split.train, outputs=p.outputs, target=p.targets,
                     val=split.val, test=split.test, train_on=fam.train_on,
                     gap_s=cfg.features.gap_s, part=parts, whole=split.whole)
    with stage(f"{fam.label}: fit on the training part"):
        fitted = fit_split(fp, family=fam.family, outputs=p.outputs, hyper=fam.params,
                           config=tcfg, target_modes=p.targets.modes, on_epoch=on_epoch)
    res.fit_seconds = (0.0 if math.isnan(res.fit_seconds) else res.fit_seconds) \
        + fitted.fit_seconds
    held = fp.val or fp.train[-1]
    seen.vals.append(block_sums(held, predict(fitted.model, held.signals, held.time_s),
                                residual_spread(fitted.model, held)))
    history = list(fitted.history)
    train_parts = fp.train
    if p.folds is not None and split.pool and cfg.selection.refit:
        with stage(f"{fam.label}: refit on training + validation"):
            fitted, train_parts = _refit(p, fam, tcfg, split, parts, on_epoch)
        res.fit_seconds += fitted.fit_seconds
        # the learning curve of the first fit (train and validation loss), then the
        # refit's training loss (MLflow: refit/loss)
        history += [{"epoch": h["epoch"], "refit_loss": h["train_loss"]}
                    for h in fitted.history]
    test_part = fp.test
    assert test_part is not None
    spread = residual_spread(fitted.model, test_part)   # once, for both
    pred, axes = score_part(fitted.model, test_part, spread)
    seen.tests.append(block_sums(test_part, pred, spread))
    seen.fold_axes.append(axes)
    model = fitted.model
    lo = np.asarray(as_numpy(model.sig_lo))
    hi = np.asarray(as_numpy(model.sig_hi))
    frac = outside_fraction(test_part.signals, lo, hi)
    beyond = outside_distance(test_part.signals, lo, hi)
    for k, sig in enumerate(model.signals):
        seen.outside.setdefault(sig, []).append((float(frac[k]), test_part.signals.shape[0]))
        out.ranges[sig] = (float(lo[k]), float(hi[k]))
        out.excursion[sig] = max(out.excursion.get(sig, 0.0), float(beyond[k]))
    out.model, out.history = model, history
    out.train_parts = list(train_parts)
    out.best_val = fitted.best_val_loss
    out.test_parts.append(test_part)
    out.test_preds.append(pred)
    res.n_params, res.best_epoch = int(fitted.n_params), int(fitted.best_epoch)
    out.n_select = int(fitted.model.n_structural)


def _pool(p: Plan, fam: FamilyConfig, split: Any, spec: Any, parts: PartCache
          ) -> tuple[list[Any], list[np.ndarray]]:
    """A split's pool (every run that is not the test run, whole: dynamic inputs computed
    before any cut) as parts, and per run the rows a fit may use: not test rows, and for
    ``train_on: heating`` only the heating ones."""
    whole = [parts(rec, spec.signals, spec.gap_s) for rec, _ in split.pool]
    keep = [np.asarray(m, dtype=bool).copy() for _, m in split.pool]
    if fam.train_on == "heating":
        gap = resolve_gap_s(p.cfg.features.gap_s, [r for r, _ in split.pool], ["rate"])
        keep = [k & (signal_matrix(rec, [RATE], gap)[:, 0] > HEATING_MIN_RATE_C_PER_MIN)
                for k, (rec, _) in zip(keep, split.pool, strict=True)]
    return whole, keep


def _parameters(p: Plan, model: Any, train_parts: list[Any], average_s: float) -> Any:
    """The kept model's parameter table and covariance (``est.parameters_``,
    ``est.covariance_``) with least-squares standard errors on the rows it was fitted on —
    what ``DriftEstimator(...).fit`` of the same runs states; sealed into the checkpoint."""
    arrays = [fit_arrays(q, average_s) for q in train_parts]
    signal_units = {s: p.ds[0].units.get(s, "") for s in p.ds[0].proxies}
    # every family's table is made (in threads: no warnings filter is touched); a family's
    # implausible constants are its rows' note, and a warning only for the model that ships
    # (compare_judge.implausible_notes)
    return parameter_rows(model, p.units, signal_units,
                          train=(np.concatenate([a[0] for a in arrays]),
                                 np.concatenate([a[1] for a in arrays]),
                                 [a[0].shape[0] for a in arrays]), method="ols", warn=False)


def _refit(p: Plan, fam: FamilyConfig, tcfg: Any, split: Any, parts: PartCache,
           on_epoch: Any) -> tuple[Any, list[Any]]:
    """The family refitted on the split's training and validation data together (never a test
    row), without a validation part — as each cross-validation fold fits it (a gradient-trained
    family stops on its training loss): the model the test verdicts judge and the exports
    ship.  It is what ``DriftEstimator(...).fit(split.train + [split.val])`` fits (the API's
    equality tests): the feature references come from those runs, each run's part is built
    as for the first fit."""
    from ..training.pipeline import fit_split, split_parts, split_spec  # torch boundary

    cfg = p.cfg
    runs = [*split.train, split.val] if split.val is not None else list(split.train)
    spec = split_spec(fam.inputs, runs, t_ref=cfg.features.t_ref,
                     window_min=cfg.features.t_ref_window_min, gap_s=cfg.features.gap_s,
                     reference_for_targets=True)
    fp = split_parts(spec, runs, outputs=p.outputs, target=p.targets, train_on=fam.train_on,
                    gap_s=cfg.features.gap_s, part=parts)
    return fit_split(fp, family=fam.family, outputs=p.outputs, hyper=fam.params, config=tcfg,
                    target_modes=p.targets.modes, on_epoch=on_epoch), list(fp.train)


def _oof(p: Plan, fam: FamilyConfig, tcfg: Any, spec: Any, parts: PartCache,
         on_epoch: Any) -> tuple[Any, list[Any]]:
    """Out-of-fold predictions of one family (config ``fam``) on the last split's pool
    (:mod:`thermonet.scoring.selection`): one fit per fold on the purged training rows of the
    whole runs, predictions on the fold's validation rows, and which of them lie inside the
    fold's trained domain.  Returns the :class:`CandidateOOF` and the pool's whole parts."""
    from dataclasses import replace

    from ..training.train import fit, predict  # torch boundary

    plan = p.folds
    oof = CandidateOOF(fam.label, 0)
    whole, keep = _pool(p, fam, p.splits[-1], spec, parts)
    # a reduced recording's rows are the fit's windows already
    tcfg = replace(tcfg, average_s=rows_average_s(whole[0], tcfg.average_s))
    widen = [noise_widths(q.signals) for q in whole]
    t_col, joint = joint_columns(spec.signals)
    for f in range(plan.k):
        train = [(q.signals[m & h], q.target[m & h], q.time_s[m & h])
                 for q, m, h in zip(whole, plan.train_masks[f], keep, strict=True)
                 if (m & h).any()]
        if not train:
            oof.failed = f"cross-validation fold {f}: no training sample left after the purge"
            break
        try:
            fitted = fit(family=fam.family, inputs=list(fam.inputs), outputs=p.outputs,
                         train=train, val=None, spec=spec, hyper=dict(fam.params),
                         config=tcfg, on_epoch=on_epoch, target=p.targets.modes)
        except FitError as err:   # e.g. a fold's span too short for the family: said, left out
            oof.failed = f"cross-validation fold {f}: {err}"
            break
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as err:
            # a numerical failure inside one fold (a solver given no usable sample after the
            # family's own masking): this candidate is out of the choice, the comparison goes on
            oof.failed = f"cross-validation fold {f}: the fit failed ({type(err).__name__}: {err})"
            break
        oof.n_params = int(fitted.model.n_structural)
        # the fold's trained domain, the dynamic inputs jointly with temperature
        env = Envelope.of(np.vstack([x[0] for x in train]), t_col, joint)
        preds, inside = [], []
        for j, q in enumerate(whole):
            rows = np.flatnonzero(plan.fold_of[j] == f)
            x = q.signals[rows]
            preds.append(predict(fitted.model, x, q.time_s[rows]) if rows.size
                         else np.zeros((0, len(p.outputs))))
            inside.append(env.contains(x, widen[j]) & np.isfinite(preds[-1]).all(axis=1))
        oof.pred.append(preds)
        oof.inside.append(inside)
    return oof, whole


def _cross_validate(out: Fitted, p: Plan, fam: FamilyConfig, tcfg: Any, spec: Any,
                    parts: PartCache, on_epoch: Any, oof: Any = None) -> None:
    """The family's out-of-fold predictions (:func:`_oof`; ``oof``: already made by the
    tuning) and the per-axis mask its own cross-validation gives."""
    whole = [parts(rec, spec.signals, spec.gap_s) for rec, _ in p.splits[-1].pool]
    if oof is None:
        oof, whole = _oof(p, fam, tcfg, spec, parts, on_epoch)
    oof.label, oof.n_params = fam.label, out.n_select
    oof.directional = bool(dynamic_signals(fam.inputs))
    oof.memory_share = memory_share(fam.inputs, fam.params.get("mix"))
    out.oof = oof
    out.pool_targets = [q.target for q in whole]
    out.pool_times = [q.time_s for q in whole]
    out.pool_signals = {s: [q.signals[:, i] for q in whole] for i, s in enumerate(spec.signals)}
    if TEMPERATURE in spec.signals:
        col = spec.signals.index(TEMPERATURE)
        out.pool_temps = [q.signals[:, col] for q in whole]
    if oof.failed is None:
        # the baseline's own mask by its rule in the comparison (raw only where it is worse
        # than raw out of fold), on its own domain as there: its file ships what the
        # comparison and the per-axis model give it
        base = fam.label if fam.label == p.cfg.baseline else None
        own = select(p.folds, out.pool_targets, out.pool_times, {fam.label: oof}, p.outputs,
                     baseline=base, temperatures=out.pool_temps or None)
        out.cv_mask = own.compensate.get(fam.label)


def _tune(p: Plan, fam: FamilyConfig, tcfg: Any, spec: Any, parts: PartCache,
          on_epoch: Any) -> tuple[FamilyConfig, dict[str, Any], Any]:
    """Choose ``fam``'s hyper-parameters from its ``tune`` grid on the selection's folds
    (the training pool only: the test part is not seen), by the same rule that chooses
    between families (:func:`thermonet.scoring.selection.select`): paired out-of-fold
    scores, the fewest parameters within one standard error of the best, do no harm.

    Returns the family config with the chosen values, the record (``grid``: each point's
    out-of-fold score, ``rule``: the sentence) and the chosen point's out-of-fold
    predictions (reused by the family's own cross-validation).  Where no point beats raw
    the configured values stay."""
    from dataclasses import replace

    points = tune_points(fam)
    oofs: dict[str, Any] = {}
    whole: list[Any] = []
    for point in points:
        label = point_label(point)
        oofs[label], whole = _oof(p, replace(fam, params={**fam.params, **point}), tcfg, spec,
                                  parts, on_epoch)
        oofs[label].label = label
    sel = select(p.folds, [q.target for q in whole], [q.time_s for q in whole], oofs,
                 p.outputs)
    chosen, record = tuning_choice(sel, points)
    if chosen is None:
        return fam, {"tuning": record}, None
    return replace(fam, params={**fam.params, **chosen}), {**chosen, "tuning": record}, \
        oofs[point_label(chosen)]


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
        n = usable_cores()
    return max(1, min(n, len(cfg.families)))


class FitQueue:
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

    def __init__(self, p: Plan, progress: Progress, parts: PartCache, workers: int) -> None:
        self.p, self.progress, self.parts, self.workers = p, progress, parts, workers
        self.cancel = threading.Event()
        self.pool: Any = None
        self.futures: dict[str, Any] = {}

    def __enter__(self) -> FitQueue:
        if self.workers > 1:
            from concurrent.futures import ThreadPoolExecutor

            self.pool = ThreadPoolExecutor(max_workers=self.workers,
                                           thread_name_prefix="thermonet-fit")
            self.futures = {fam.label: self.pool.submit(fit_family, self.p, fam, self.progress,
                                                        self.parts, self.cancel)
                            for fam in self.p.cfg.families}
        return self

    def result(self, fam: FamilyConfig) -> Fitted:
        if self.pool is None:
            return fit_family(self.p, fam, self.progress, self.parts)
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
