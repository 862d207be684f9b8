"""``compare`` with ``model: sensor``, the choice: the sensor model cross-validated as every
bias family is (:mod:`thermonet.workflows.compare_fit`).

* **Folds** — the bias comparison's own plan (:func:`thermonet.workflows.compare_plan._fold_plan`
  → :func:`thermonet.scoring.fold_plan.plan_folds`): the split's pool (every run that is not
  the test run, whole), whole runs left out where the test is a run of its own, blocks inside
  the runs with the purge where the test is blocks inside them (``time-blocks``).
* **Out of fold** (:func:`sensor_oof`) — per fold, the sensor model (``fit_sensor``, no
  validation part: every element kept, as a bias fold fit keeps every axis) is fitted on the
  fold's purged training rows of the whole runs and compensates the fold's validation rows.
  Its "predicted error" there is ``raw − compensated``, so that the selection's residual
  ``target − prediction`` with the target ``raw − ref`` is the sensor model's own residual
  ``compensated − ref``; the raw candidate is ``raw − ref`` (no compensation at all).  A
  validation row counts only inside the fold's trained signal range (widened by the signals'
  noise), as for a bias family.
* **Choice** — :func:`thermonet.scoring.selection.select` unchanged: paired block-bootstrap
  out-of-fold scores, the per-axis one-SE rule against raw, the one-SE rule between
  candidates (fewest structural parameters of b and E together), the configured baseline
  as the floor, do no harm.  The temperature peak-to-peak guard is not applied: with
  positions and turntable rates in the data, a temperature bin's mean error mixes
  excitations, so it says nothing about a scale factor.
* **Tuning** (:func:`sensor_tune`) — a family's ``tune`` grid, each point cross-validated and
  chosen by the same rule (``compare_fit._tune``'s record); the chosen point's out-of-fold
  predictions are the family's own.

Without folds (``selection.folds: 0``, or too little data) the lowest validation residual
chooses, as before cross-validation, and a ``tune`` grid is recorded as not tuned.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ThermonetError
from ..scoring.domain import in_domain, noise_widths
from ..scoring.oof_pool import CandidateOOF
from ..scoring.selection import point_label, select, tuning_choice
from ..scoring.verdicts import one_se
from ..training.config import CompareConfig, FamilyConfig, tune_points

if TYPE_CHECKING:
    from ..training.sensor import SensorRun

__all__ = ["SensorPool", "sensor_pool", "subset", "sensor_oof", "sensor_tune",
           "choose_sensor"]


@dataclass
class SensorPool:
    """The split's pool as the sensor model reads it: per pool run its whole arrays for one
    family's signals, and the targets ``raw − ref`` and times that every candidate shares."""

    runs: list[SensorRun]
    targets: list[np.ndarray] = field(default_factory=list)
    times: list[np.ndarray] = field(default_factory=list)


def sensor_pool(pool: Sequence[tuple[Any, np.ndarray]], spec: Any, outputs: Sequence[str]
                ) -> SensorPool:
    """Each pool run whole (dynamic inputs computed before any cut) as a :class:`SensorRun`."""
    from ..training.sensor import sensor_run  # torch boundary

    runs = [sensor_run(rec, spec, outputs) for rec, _ in pool]
    return SensorPool(runs, [r.raw - r.ref for r in runs], [r.time_s for r in runs])


def subset(run: SensorRun, rows: np.ndarray) -> SensorRun:
    """The rows ``rows`` (a mask or indices) of ``run``."""
    from ..training.sensor import SensorRun  # the torch boundary (the sensor model's fit)

    return SensorRun(run.signals[rows], run.raw[rows], run.ref[rows], run.time_s[rows],
                     run.temperature[rows], run.run_id)


def n_structural(model: Any) -> int:
    """Structural parameters of a sensor model: its bias model's and its element model's."""
    return int(model.bias.n_structural) + int(model.elements.n_structural)


def sensor_oof(plan: Any, pool: SensorPool, *, fam: FamilyConfig, spec: Any,
               outputs: Sequence[str], triads: Sequence[Sequence[str]], tcfg: Any) -> Any:
    """One family's out-of-fold predicted errors ``raw − compensated`` on the pool's
    validation rows (a :class:`~thermonet.scoring.selection.CandidateOOF`)."""
    from ..training.sensor import fit_sensor  # torch boundary

    oof = CandidateOOF(fam.label, 0)
    widen = [noise_widths(r.signals) for r in pool.runs]
    for f in range(plan.k):
        train = [subset(r, m) for r, m in zip(pool.runs, plan.train_masks[f], strict=True)
                 if m.any()]
        try:
            fitted = fit_sensor(family=fam.family, spec=spec, outputs=outputs, triads=triads,
                                train=train, val=None, hyper=dict(fam.params), config=tcfg)
        except ThermonetError as err:   # a fold that cannot carry it: said, left out
            oof.failed = f"cross-validation fold {f}: {err}"
            break
        oof.n_params = n_structural(fitted.model)
        sig = np.vstack([r.signals for r in train])
        with np.errstate(invalid="ignore"):
            lo, hi = np.nanmin(sig, axis=0), np.nanmax(sig, axis=0)
        preds, inside = [], []
        for j, r in enumerate(pool.runs):
            rows = np.flatnonzero(plan.fold_of[j] == f)
            if rows.size:
                pred = r.raw[rows] - fitted.model.compensate(r.signals[rows], r.raw[rows])
            else:
                pred = np.zeros((0, len(outputs)))
            preds.append(pred)
            inside.append(in_domain(r.signals[rows], lo, hi, widen[j])
                          & np.isfinite(pred).all(axis=1))
        oof.pred.append(preds)
        oof.inside.append(inside)
    return oof


def sensor_tune(plan: Any, pool: SensorPool, *, fam: FamilyConfig, spec: Any,
                outputs: Sequence[str], triads: Sequence[Sequence[str]], tcfg: Any
                ) -> tuple[FamilyConfig, dict[str, Any], Any]:
    """``fam``'s hyper-parameters from its ``tune`` grid, chosen on the folds by the rule that
    chooses between families; returns the family with the chosen values, the record
    (``{point..., "tuning": {"grid", "rule"}}``, as a bias family's ``tuned``) and the chosen
    point's out-of-fold predictions (None where the configured values stay)."""
    if plan is None:
        return fam, {"tuning": {"rule": "not tuned: no cross-validation folds; the "
                                "configured values are used"}}, None
    points = tune_points(fam)
    oofs: dict[str, Any] = {}
    for point in points:
        label = point_label(point)
        oofs[label] = sensor_oof(plan, pool, fam=replace(fam, params={**fam.params, **point}),
                                 spec=spec, outputs=outputs, triads=triads, tcfg=tcfg)
        oofs[label].label = label
    sel = select(plan, pool.targets, pool.times, oofs, list(outputs))
    chosen, record = tuning_choice(sel, points)
    if chosen is None:
        return fam, {"tuning": record}, None
    return replace(fam, params={**fam.params, **chosen}), {**chosen, "tuning": record}, \
        oofs[point_label(chosen)]


def _lowest(scored: dict[str, float], n_params: dict[str, int]) -> str | None:
    """The single validation part's pick: the one rule (:func:`one_se`) without draws — the
    lowest residual, scores within the decision margin one score (the fewest parameters,
    then the first listed).  The residuals are scaled by raw's spread, not ratios to raw
    (the sensor model is not masked per axis): no do-no-harm step (``raw=None``)."""
    return one_se(scored, None, n_params, raw=None).chosen


def choose_sensor(cfg: CompareConfig, doc: dict[str, Any], plan: Any, note: str,
                  oofs: dict[str, Any], pool: SensorPool | None, outputs: Sequence[str]
                  ) -> None:
    """The family that ships: ``doc``'s ``chosen``, ``chosen_reason``, ``tie`` and
    ``selection`` (the bias comparison's keys).  With folds, the out-of-fold choice
    (:func:`~thermonet.scoring.selection.select`) and, under ``selection.single_split``,
    what the lowest validation residual would have chosen; without, that choice."""
    ok = {k: f for k, f in doc["families"].items() if f.get("status") == "ok"}
    on_val = all(f.get("val_score") is not None for f in ok.values())
    scored = {k: f["val_score"] if on_val else f["test_score"] for k, f in ok.items()}
    single = _lowest(scored, {k: int(f.get("n_params") or 0) for k, f in ok.items()})
    single_why = (f"chose {single}: lowest {'validation' if on_val else 'test (no validation part)'}"
                  f" residual ({scored[single]:.4g}, each axis scaled by its raw error's standard"
                  " deviation)") if single is not None else "no family was fitted"
    cv = {k: o for k, o in oofs.items() if k in ok}
    if plan is None or pool is None or not cv:
        doc.update(chosen=single, chosen_reason=single_why, tie=[],
                   selection={"method": "single validation part",
                              "note": note or "no family was cross-validated"})
        return

    sel = select(plan, pool.targets, pool.times, cv, list(outputs),
                 baseline=cfg.baseline if cfg.baseline in cv else None)
    doc.update(chosen=sel.chosen, chosen_reason=sel.reason, tie=list(sel.tied),
               selection={**sel.record, "single_split": {"chosen": single,
                                                          "reason": single_why}})
    if single != sel.chosen:
        doc["warnings"].append(
            f"the split's single validation part would have chosen {single or 'nothing'} "
            f"instead of {sel.chosen or 'nothing'}: the call rests on the cross-validation")
    for k, o in cv.items():
        if o.failed is not None:
            doc["warnings"].append(f"{k}: not a candidate: {o.failed}")
