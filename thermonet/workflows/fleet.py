"""Fleets: many units calibrated in one job, per unit and across the fleet.

``thermonet fleet CONFIG --out DIR`` (or :func:`run_fleet`) takes a dataset
holding several devices (a per-run device id: the Parquet ``device`` column, a
mapping's ``device_column``, or :func:`thermonet.sim.simulate_fleet`) and:

1. **Per unit** runs exactly the single-device comparison
   (:func:`thermonet.workflows.compare.run_compare` on that unit's runs: same families,
   split by run *within* the unit, same choice and verdicts).  Its output
   directory is ``DIR/units/<device_id>/`` (results.json, checkpoints, plots),
   so ``thermonet export DIR/units/<id>`` works as for one device, and
   ``thermonet export DIR --all-units`` exports every unit.
2. **Across the fleet**: for the *fleet family* (``--family``; default the
   config's baseline, else its first family) the physical coefficients of every
   unit's fitted curve — the model's drift on a grid over its trained
   temperature range fitted by a polynomial in (T − 25 °C), of the family's degree for
   ``poly``/``linear`` (exact for those families) and cubic otherwise — and the
   held-out error of each axis: spread (median, MAD, min, max) and robust
   outlier flags (:mod:`thermonet.scoring.fleetstats`: robust z > 3.5).
3. **Leave units out** (after the units): the units are dealt into ``folds``
   groups (unit *i* in group *i* mod k); for each group, one fleet model of the
   fleet family is fitted on the calibration runs (train + validation part of
   each unit's own split) of up to ``fleet_units_max`` units of the *other*
   groups — flagged outliers and failed units left out — and
   evaluated on each held-out unit's test run next to that unit's own
   calibration of the same family.  Reported per unit and axis: the standard
   deviation of the compensated error with the fleet model and with its own
   model and their ratio (> 1: the unit needs its own calibration), and the
   median ratio over the fleet.
4. **Limits** (the config's ``limits:`` section): PASS/FAIL per unit and axis
   on held-out data (:func:`thermonet.scoring.fleetstats.judge_unit`).

Execution (:mod:`thermonet.core.executors`): units run in parallel on a process
pool (default), in this process, or on Ray.  Workers get a unit's data (or
simulate their own unit, so a worker's memory holds one unit), run the
comparison in a private temporary directory and return plain data: the
results dict, the files it wrote (bytes) and the fitted models.  The driver
alone writes ``DIR`` (built in a temporary sibling and moved into place at
the end, so a failed fleet leaves no half-written directory) and MLflow: a
parent run per fleet, a nested run per unit (params, tags and metrics in a
few batched calls), so SQLite never sees concurrent writers.  A unit whose
task fails or whose worker dies is reported ``failed`` with its reason and
fails its limits; the fleet finishes.

``results.json`` of a fleet::

    {"schema": 1, "kind": "fleet", "config": {...}, "fleet_family": "cubic",
     "units": {device_id: {...run_compare's results..., "status", "temperature_span_c",
                           "coefficients": {...}, "leave_units_out": {...},
                           "limits": {"verdict": "PASS"|"FAIL"|"NOT JUDGED", ...}}},
     "fleet": {"n_units", "n_failed", "spread": {quantity: {median, mad, min, max, n}},
               "outliers": {device_id: [{quantity, value, z}]}, "outlier_rule",
               "leave_units_out": {...}, "verdicts": {"PASS": n, "FAIL": n, ...},
               "all_passed": bool, "seconds": float}}

**Sensor models** (``model: sensor``, :mod:`thermonet.workflows.sensor`): each unit is a
sensor comparison (cross-validated as one device's); the fleet family's physical
coefficients are those of its bias curve per axis (``gyro_x.c0`` …) and of each element of
``E`` (``gyro.m_xx.c0`` …: scale factor on the diagonal, misalignment off it) over the
trained temperature range, both flagged as outliers at five temperatures of the common
range; held-out ``rms_comp``/``pp_comp`` per axis are those of ``compensated − ref``, and
``limits`` judge them as a bias model's.  Leave units out fits one sensor model on the
other units' training runs pooled (no validation part: every element kept) and compares
the held-out unit's ``compensated − ref`` spread with it and with its own.

Exit code of ``thermonet fleet``: 0 every unit passed (or no limits were set and
every unit was calibrated), :data:`EXIT_LIMITS_FAILED` (3) some unit failed its
limits or could not be calibrated, 1 bad input, 2 usage error.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from dataclasses import dataclass
from numbers import Integral
from pathlib import Path
from typing import Any, cast

from ..core.errors import ConfigError, InputError
from ..core.executors import TaskFailure, run_tasks
from ..core.fileio import atomic_write_text
from ..core.names import inside, path_components
from ..core.outdir import check_target, install, make_stage
from ..features.target import modelled_outputs
from ..models.shipped import MODEL_KINDS
from ..scoring.fleetstats import (
    check_limit_axes,
    fleet_html_fragment,
    judge_unit,
    parse_limits,
)
from ..tracking import Tracker, check_store, default_tracking_uri
from ..training.config import CompareConfig, check_families
from .fleet_summary import clean, fleet_summary, format_fleet_table, plot_coefficient_spread
from .fleet_units import UnitItem, UnitSource, fold_items, fold_task, unit_task
from .provenance import data_source, resolved_config

__all__ = ["FleetOptions", "run_fleet", "EXIT_LIMITS_FAILED"]


#: Exit code of ``thermonet fleet`` when some unit failed its limits or its calibration.
EXIT_LIMITS_FAILED = 3


@dataclass
class FleetOptions:
    """How a fleet runs (see the module docstring)."""

    executor: str = "process"
    workers: int | None = None         # processes (None or 0: one per CPU)
    ray_address: str | None = None
    family: str | None = None          # fleet family label (default: baseline, else first)
    folds: int = 5                     # leave-units-out groups (0: skip)
    fleet_units_max: int = 20          # units per fleet fit

    def __post_init__(self) -> None:   # before any unit is read: as compare's --workers
        w = self.workers
        if w is not None and (isinstance(w, bool) or not isinstance(w, Integral) or w < 0):
            raise ConfigError(f"--workers {w}: must be an integer >= 0 (0: one per CPU)")


# ------------------------------------------------------------------- driver
def _relocate(obj: Any, old: str, new: str) -> Any:
    if isinstance(obj, str):
        return new + obj[len(old):] if obj.startswith(old) else obj
    if isinstance(obj, dict):
        return {k: _relocate(v, old, new) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_relocate(v, old, new) for v in obj]
    return obj


def _fleet_family(cfg: CompareConfig, name: str | None, source: str) -> str:
    labels = [f.label for f in cfg.families]
    if name is not None:
        if name not in labels:
            raise ConfigError(f"{source}: --family '{name}' is not a family of the config "
                              f"(families: {', '.join(labels)})")
        return name
    return cfg.baseline if cfg.baseline in labels else labels[0]


@dataclass
class _Plan:
    """What :func:`run_fleet` decided before any unit is fitted (step 1)."""

    out: Path
    family: str
    limits: dict[str, Any]
    ids: list[str]
    dirs: dict[str, str]            # device id -> its directory's name under units/
    k: int                          # leave-units-out groups
    opts: FleetOptions


def run_fleet(cfg: CompareConfig, out_dir: str | Path, sources: list[UnitSource], *,
              options: FleetOptions | None = None, track: bool | None = None,
              tracking_uri: str | None = None, quiet: bool = False, overwrite: bool = False,
              plots: bool = True) -> dict[str, Any]:
    """Calibrate every unit of ``sources``, summarise the fleet, judge limits; write ``out_dir``.

    ``out_dir`` follows :mod:`thermonet.core.outdir` (``kind="fleet"``): a non-empty
    directory that is not a previous fleet is refused, a previous fleet is replaced
    only with ``overwrite`` (the user's own files beside it are kept).  Each unit's
    directory is ``units/<component>``, the device id made a safe file name
    (:func:`thermonet.core.names.path_component`; recorded as the unit's ``dir``).
    ``plots=False`` writes no PNG files, per unit or for the fleet.  With ``model: sensor``
    every unit is a sensor comparison (:mod:`thermonet.workflows.sensor`) and the fleet's
    statistics are those of its sensor models (the module docstring).

    Five steps: plan (:func:`_plan`), fit (the unit tasks), judge (:func:`_judge`: leave
    units out, limits, the summary), write (:func:`_write`) and track (:func:`_track`).

    Returns the fleet results (the dict written to ``out_dir/results.json``).
    """
    t_start = time.perf_counter()
    if cfg.tracking.enabled if track is None else track:   # refused before any unit is fitted
        check_store(tracking_uri or cfg.tracking.uri or default_tracking_uri())
    p = _plan(cfg, out_dir, sources, options or FleetOptions(), overwrite)    # 1. plan
    stage = make_stage(p.out)   # before any unit is fitted: an --out that cannot be made

    def say(msg: str) -> None:
        if not quiet:
            print(msg, flush=True)

    def progress(i: int, res: Any) -> None:
        status = f"failed: {res.reason}" if isinstance(res, TaskFailure) else \
            f"chosen {res['results'].get('chosen') or 'none'}"
        say(f"  {p.ids[i]:<20} {status}")

    items = [UnitItem(cfg=cfg, source=s, family=p.family, plots=plots) for s in sources]
    try:
        say(f"thermonet fleet: {len(sources)} units{MODEL_KINDS[cfg.model].banner}"
            f", executor {p.opts.executor}, fleet family {p.family}, leave-units-out in {p.k} "
            "groups")
        payloads = _tasks(p.opts, unit_task, items, progress)                # 2. fit
        units, own = _collect(p, payloads, stage)
        summary = _judge(cfg, p, sources, units, own, stage, say)             # 3. judge
        summary["seconds"] = time.perf_counter() - t_start
        results = _write(cfg, p, units, summary, stage, track=track,          # 4. write
                         tracking_uri=tracking_uri, plots=plots)
        _track(cfg, results, track, tracking_uri, stage)                      # 5. track
        install(stage, p.out, overwrite, "fleet")
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    say(format_fleet_table(results))
    return results


def _tasks(opts: FleetOptions, fn: Any, todo: list[Any], on_done: Any = None) -> list[Any]:
    """``fn`` over ``todo`` on the configured executor (``workers`` 0: one per CPU this
    process may use, :func:`~thermonet.core.executors.run_tasks`)."""
    return run_tasks(fn, todo, executor=cast(Any, opts.executor), workers=opts.workers,
                     ray_address=opts.ray_address, on_done=on_done)


def _plan(cfg: CompareConfig, out_dir: str | Path, sources: list[UnitSource],
          opts: FleetOptions, overwrite: bool) -> _Plan:
    """Everything checked before any unit is fitted: families, limits, the fleet family,
    unique device ids, the options and the output directory."""
    source = getattr(cfg, "_source", "config")
    check_families(cfg, source=source)
    limits = parse_limits(getattr(cfg, "limits", None), source=source)
    family = _fleet_family(cfg, opts.family, source)
    if not sources:
        raise InputError("fleet: no units in the data")
    known = [s.axes for s in sources if s.axes is not None]
    if known:   # the limits' axes against the outputs the units' models will fit
        check_limit_axes(limits, list(dict.fromkeys(
            o for axes in known for o in modelled_outputs(cfg.data.outputs or axes,
                                                          cfg.target))), source=source)
    ids = [s.device_id for s in sources]
    dup = sorted({d for d in ids if ids.count(d) > 1})
    if dup:
        raise InputError(f"fleet: device id '{dup[0]}' given twice (device ids must be unique)")
    if opts.folds < 0:
        raise ConfigError(f"fleet: --folds {opts.folds}: must be ≥ 0 (0: no leave-units-out)")
    if opts.fleet_units_max < 1:
        raise ConfigError(f"fleet: fleet_units_max {opts.fleet_units_max}: must be ≥ 1")
    out = Path(out_dir)
    check_target(out, overwrite, "fleet")  # before any unit is fitted
    dirs = path_components(ids)            # a device id never becomes a path as it is
    k = min(opts.folds, len(sources)) if len(sources) >= 2 else 0
    return _Plan(out, family, limits, ids, dirs, k, opts)


def _collect(p: _Plan, payloads: list[Any], stage: Path
             ) -> tuple[dict[str, Any], dict[str, Any]]:
    """Each unit's files into ``stage/units/<dir>`` and its results (paths relocated to
    ``out``); returns the units' results and their own models (for leave-units-out)."""
    units: dict[str, Any] = {}
    own: dict[str, Any] = {}
    for dev, res in zip(p.ids, payloads, strict=True):
        if isinstance(res, TaskFailure):
            units[dev] = {"device": dev, "status": "failed", "reason": res.reason}
            continue
        udir = inside(stage, "units", p.dirs[dev])
        for rel, data in res["files"].items():
            f = udir / rel
            if not f.resolve().is_relative_to(udir.resolve()):
                raise InputError(f"unit '{dev}': its worker returned a file outside its "
                                 f"directory ({rel!r})")
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_bytes(data)
        r = _relocate(res["results"], res["root"], str(p.out / "units" / p.dirs[dev]))
        r.update(status="ok", temperature_span_c=res["temperature_span_c"],
                 coefficients=res["coefficients"], leave_units_out=None,
                 n_runs=res["n_runs"], temperature_range_c=res["temperature_range_c"])
        r["device"] = dev
        r["dir"] = f"units/{p.dirs[dev]}"
        units[dev] = r
        own[dev] = res["own_model"]
    return units, own


def _judge(cfg: CompareConfig, p: _Plan, sources: list[UnitSource], units: dict[str, Any],
           own: dict[str, Any], stage: Path, say: Any) -> dict[str, Any]:
    """Leave units out (after the units: flagged outliers and failed units stay out of every
    fleet model — a production line would not build its fleet model on them), each unit's
    limits (its results.json rewritten with them) and the fleet summary."""
    fitted = [o for u in units.values() if u["status"] == "ok" for o in u.get("units") or {}]
    if fitted:   # where the plan could not tell the outputs (nothing is installed yet)
        check_limit_axes(p.limits, list(dict.fromkeys(fitted)),
                         source=getattr(cfg, "_source", "config"))
    flagged = set(fleet_summary(units, p.family, {}, p.limits)["outliers"])
    fold_info: dict[str, Any] = {}
    if p.k:
        excluded = flagged | {d for d, u in units.items() if u["status"] != "ok"}
        folds = fold_items(cfg, p.family, sources, p.k, p.opts.fleet_units_max, own, excluded)
        say(f"  leave-units-out: {len(folds)} fleet fits (outliers left out: "
            f"{', '.join(sorted(flagged)) or 'none'})")
        for item, fres in zip(folds, _tasks(p.opts, fold_task, folds), strict=True):
            if isinstance(fres, TaskFailure):
                fold_info[str(item.fold)] = {"status": "failed", "reason": fres.reason}
                continue
            fold_info[str(item.fold)] = {"status": "ok", "fitted_on": fres["units"]}
            for dev, ev in fres["evaluations"].items():
                units[dev]["leave_units_out"] = ev
    for dev, u in units.items():
        u["limits"] = judge_unit(u, p.limits)
        if u["status"] == "ok":
            atomic_write_text(inside(stage, "units", p.dirs[dev]) / "results.json",
                              json.dumps(clean(u), indent=2))
    return fleet_summary(units, p.family, fold_info, p.limits)


def _write(cfg: CompareConfig, p: _Plan, units: dict[str, Any], summary: dict[str, Any],
           stage: Path, *, track: bool | None, tracking_uri: str | None, plots: bool
           ) -> dict[str, Any]:
    """The fleet's results.json, its coefficient-spread figure and fleet.html in ``stage``."""
    tracking = cfg.tracking.enabled if track is None else track
    results = {"schema": 1, "kind": "fleet", "fleet_family": p.family,
               "config": resolved_config(  # as used: tracking, no preset for files
                   cfg, None, given=False, tracking_enabled=tracking, workers=1,
                   tracking_uri=tracking_uri or cfg.tracking.uri or default_tracking_uri()),
               "provenance": {"data": data_source(cfg, None, given=False),
                              "options": {"track": track, "tracking_uri": tracking_uri,
                                          "plots": plots}},
               "options": dataclasses.asdict(p.opts), "units": units, "fleet": summary}
    plot = plot_coefficient_spread(stage / "plots" / "coefficient_spread.png", results) \
        if plots else None
    summary["spread_plot"] = None if plot is None else "plots/coefficient_spread.png"
    results = clean(results)
    atomic_write_text(stage / "results.json", json.dumps(results, indent=2))
    atomic_write_text(stage / "fleet.html", "<!doctype html><meta charset=utf-8>"
                      "<title>thermonet fleet</title>\n"
                      + fleet_html_fragment(results, summary["spread_plot"]))
    return results


def _track(cfg: CompareConfig, results: dict[str, Any], track: bool | None,
           tracking_uri: str | None, stage: Path) -> None:
    """The driver's MLflow record: a parent run per fleet, a nested run per unit."""
    tracker = Tracker(enabled=cfg.tracking.enabled if track is None else track,
                      uri=tracking_uri or cfg.tracking.uri, experiment=cfg.tracking.experiment)
    if not tracker.enabled:
        return
    fleet = results["fleet"]
    with tracker.run(f"fleet-{len(results['units'])}-units", params=results["config"],
                     tags={"kind": "fleet", "fleet_family": results["fleet_family"]}) as pid:
        results["mlflow_run_id"] = pid
        tracker.log_metrics({"fleet/n_units": fleet["n_units"], "fleet/n_failed":
                             fleet["n_failed"], "fleet/seconds": fleet["seconds"],
                             **{f"fleet/verdict/{k}": v for k, v in fleet["verdicts"].items()}})
        for dev, u in results["units"].items():
            chosen = u.get("chosen")
            tags = {"device": dev, "status": u.get("status"), "chosen": chosen or "none",
                    "verdict": u["limits"]["verdict"], "outlier": str(dev in fleet["outliers"])}
            with tracker.run(dev, tags=tags, nested=True) as rid:
                u["mlflow_run_id"] = rid
                if u.get("status") == "ok" and chosen:
                    # a kind whose axes carry verdicts and intervals too (the sensor model's):
                    # numbers only (MODEL_KINDS: a bias comparison's results name no kind)
                    numeric = MODEL_KINDS[u.get("model", "bias")].metrics_numeric_only
                    tracker.log_metrics({f"test/{a}/{k}": v for a, m in
                                         u["families"][chosen]["axes"].items()
                                         for k, v in m.items()
                                         if not numeric or isinstance(v, float)})
        (stage / "results.json").write_text(json.dumps(results, indent=2))
        tracker.log_artifact(stage / "results.json")
