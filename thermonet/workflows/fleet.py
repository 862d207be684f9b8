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

Exit code of ``thermonet fleet``: 0 every unit passed (or no limits were set and
every unit was calibrated), :data:`EXIT_LIMITS_FAILED` (3) some unit failed its
limits or could not be calibrated, 1 bad input, 2 usage error.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from ..core.errors import ConfigError, InputError
from ..core.executors import TaskFailure, run_tasks
from ..core.recording import Dataset, split_units
from ..scoring.fleetstats import (
    MIN_UNITS_FOR_OUTLIERS,
    ROBUST_Z_THRESHOLD,
    flag_outliers,
    judge_unit,
    parse_limits,
    spread,
)
from ..training.config import CompareConfig, FamilyConfig, check_families

__all__ = ["FleetOptions", "UnitSource", "run_fleet", "sources_from_dataset",
           "physical_coefficients",
           "sources_from_simulation", "format_fleet_table", "plot_coefficient_spread",
           "EXIT_LIMITS_FAILED", "COEF_T0_C"]

#: Exit code of ``thermonet fleet`` when some unit failed its limits or its calibration.
EXIT_LIMITS_FAILED = 3
#: Reference temperature of the fleet's physical coefficients (°C).
COEF_T0_C = 25.0


@dataclass
class UnitSource:
    """Where a worker finds one unit's data: the runs themselves, or simulator arguments."""

    device_id: str
    dataset: Dataset | None = None
    sim: dict[str, Any] | None = None   # simulate_fleet kwargs with unit_indices=[k]
    error: str | None = None            # why this unit's data cannot be used (it fails alone)

    def load(self) -> Dataset:
        if self.error is not None:
            raise InputError(self.error)
        if self.dataset is not None:
            return self.dataset
        from ..sim import simulate_fleet

        if self.sim is None:
            raise InputError(f"unit '{self.device_id}': no data")
        return simulate_fleet(**self.sim)


@dataclass
class FleetOptions:
    """How a fleet runs (see the module docstring)."""

    executor: str = "process"
    workers: int | None = None
    ray_address: str | None = None
    family: str | None = None          # fleet family label (default: baseline, else first)
    folds: int = 5                     # leave-units-out groups (0: skip)
    fleet_units_max: int = 20          # units per fleet fit


def sources_from_dataset(ds: Dataset, source: str = "") -> list[UnitSource]:
    """One source per unit of a dataset, each unit validated on its own.

    A unit whose runs fail validation (too few samples, no temperature span,
    bad time stamps …) becomes a source that fails with the reason, naming the
    unit, so the fleet goes on without it; the units left must agree with each
    other (same outputs, proxies and units of measure), else one line names both.
    """
    by_unit: dict[str, list[Any]] = {}
    for r in ds.runs:
        by_unit.setdefault(r.device_id, []).append(r)
    bad: dict[str, str] = {}
    for dev, runs in by_unit.items():
        try:
            Dataset(runs=runs, meta=dict(ds.meta)).validate(source)
        except InputError as err:
            bad[dev] = f"unit '{dev}': {err}"
    good = [r for r in ds.runs if r.device_id not in bad]
    units = split_units(Dataset(runs=good, meta=dict(ds.meta)).validate(source)) if good else {}
    return [UnitSource(dev, error=bad[dev]) if dev in bad else UnitSource(dev, dataset=units[dev])
            for dev in by_unit]


def sources_from_simulation(preset: str, *, units: int, runs: int | None = None, seed: int = 0,
                            outliers: int = 0, **overrides: Any) -> list[UnitSource]:
    """Sources for a simulated fleet: each worker simulates its own unit.

    ``overrides`` go to the simulator (``sample_rate_hz=0.1``, ``white_noise=False``).
    """
    from ..sim.fleet import simulate_fleet, unit_device_id

    simulate_fleet(preset, units=units, runs=1, seed=seed, outliers=outliers,
                   unit_indices=[])  # checks the arguments here, before any worker starts
    return [UnitSource(unit_device_id(preset, k, units),
                       sim={"preset": preset, "units": units, "runs": runs, "seed": seed,
                            "outliers": outliers, "unit_indices": [k], **overrides})
            for k in range(units)]


# ------------------------------------------------------------------ workers
def _family(cfg: CompareConfig, label: str) -> FamilyConfig:
    return next(f for f in cfg.families if f.label == label)


def _buffer(model: Any, name: str) -> np.ndarray:
    """A model buffer as float64 NumPy (the trained signal range ``sig_lo``/``sig_hi``)."""
    return np.asarray(getattr(model, name).detach().cpu().numpy(), dtype=np.float64)


def physical_coefficients(model: Any, t0_c: float = COEF_T0_C) -> dict[str, float]:
    """Polynomial coefficients of a temperature-only model's drift in (T − t0), per axis.

    ``{"<axis>.c<k>": value}`` in output unit / °C^k; empty when the model takes
    other signals than the temperature.  Degree: the family's own
    (:meth:`thermonet.models.Family.coefficient_degree`: a polynomial's degree on ``T`` or
    ``dT`` alone, else 3 — then a summary of the curve, not its parameters).
    """
    from ..training.train import predict

    if list(model.signals) != ["temperature_c"]:
        return {}
    lo, hi = (float(v) for v in np.concatenate([_buffer(model, "sig_lo")[:1],
                                                 _buffer(model, "sig_hi")[:1]]))
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        return {}
    degree = int(model.family.coefficient_degree(list(model.inputs)))  # the family's own say
    grid = np.linspace(lo, hi, 201)
    drift = predict(model, grid[:, None])
    out: dict[str, float] = {}
    for j, axis in enumerate(model.outputs):
        c = np.polynomial.polynomial.polyfit(grid - t0_c, drift[:, j].astype(np.float64), degree)
        out.update({f"{axis}.c{k}": float(v) for k, v in enumerate(c)})
    return out


def _residual_std(model: Any, part: Any) -> np.ndarray:
    from ..training.train import predict

    return np.std(part.target - predict(model, part.signals), axis=0)


def _test_part(cfg: CompareConfig, ds: Dataset, model: Any) -> Any:
    from ..training.parts import build_part, make_splits, targets_for

    where = f"unit '{ds.device_id}'"
    split = make_splits(ds, cfg.split, source=where)[-1]
    outputs = list(model.outputs)
    return build_part(split.test, signals=list(model.signals), outputs=outputs,
                      target=targets_for(ds, cfg.target, outputs, source=where),
                      gap_s=model.spec.gap_s)


@dataclass
class _UnitItem:
    cfg: CompareConfig
    source: UnitSource
    family: str
    plots: bool = True


def _unit_task(item: _UnitItem) -> dict[str, Any]:
    """One unit in a worker: compare in a private temp dir, return plain data."""
    from ..training.checkpoint import load_checkpoint
    from .compare import run_compare

    ds = item.source.load()
    if ds.is_fleet:
        raise InputError(f"unit '{item.source.device_id}': its data holds several devices")
    tmp = Path(tempfile.mkdtemp(prefix="thermonet-unit-"))
    try:
        udir = tmp / "unit"
        results = run_compare(item.cfg, udir, dataset=ds, track=False, quiet=True,
                              plots=item.plots,
                              workers=1)   # units run side by side, not families
        files = {p.relative_to(udir).as_posix(): p.read_bytes()
                 for p in sorted(udir.rglob("*")) if p.is_file()}
        temps = [r.temperature_c for r in ds if r.temperature_c is not None]
        span = float(max(t.max() for t in temps) - min(t.min() for t in temps)) \
            if temps and len(temps) == len(ds) else None
        payload: dict[str, Any] = {"results": results, "files": files, "root": str(udir),
                                   "temperature_span_c": span, "coefficients": {},
                                   "n_runs": len(ds), "temperature_range_c": None,
                                   "own_model": None}
        fam = results["families"].get(item.family)
        if fam and fam.get("status") == "ok" and fam.get("checkpoint"):
            own, _ = load_checkpoint(fam["checkpoint"])
            payload["own_model"] = own  # for leave-units-out, evaluated by the fold tasks
            payload["coefficients"] = physical_coefficients(own)
            lo, hi = float(_buffer(own, "sig_lo")[0]), float(_buffer(own, "sig_hi")[0])
            if list(own.signals) == ["temperature_c"] and np.isfinite([lo, hi]).all():
                payload["temperature_range_c"] = [lo, hi]
        return payload
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@dataclass
class _FoldItem:
    cfg: CompareConfig
    family: str
    fold: int
    sources: list[UnitSource] = field(default_factory=list)       # the fleet model's units
    held_out: list[tuple[UnitSource, Any]] = field(default_factory=list)  # (unit, own model)


def _fold_task(item: _FoldItem) -> dict[str, Any]:
    """Fit one fleet model of the fleet family on other units' calibration runs, and
    evaluate it on each held-out unit's test run next to the unit's own model."""
    from ..training.config import outputs_of, train_config_of
    from ..training.fold import fit_fold, fold_parts, fold_spec
    from ..training.parts import make_splits, targets_for

    cfg, fam = item.cfg, _family(item.cfg, item.family)
    train, val = [], []
    outputs: list[str] = []
    target: Any = cfg.target
    for src in item.sources:
        ds = src.load()
        split = make_splits(ds, cfg.split, source=f"unit '{src.device_id}'")[-1]
        outputs = outputs_of(cfg, ds)   # the same outputs and train section as a unit's
        target = targets_for(ds, cfg.target, outputs, source=f"unit '{src.device_id}'")
        train += split.train
        if split.val is not None:
            val.append(split.val)
    spec = fold_spec(fam.inputs, train, t_ref=cfg.features.t_ref,
                     window_min=cfg.features.t_ref_window_min, gap_s=cfg.features.gap_s)
    parts = fold_parts(spec, train, outputs=outputs, target=target)
    vparts = fold_parts(spec, val, outputs=outputs, target=target).train
    v = (np.concatenate([p.signals for p in vparts]), np.concatenate([p.target for p in vparts])) \
        if vparts else None
    fitted = fit_fold(parts, family=fam.family, outputs=outputs, hyper=fam.params,
                      config=train_config_of(cfg, fam), val=v, windows=False)
    evaluations = {}
    for src, own in item.held_out:  # one unit's data at a time
        test = _test_part(cfg, src.load(), own)
        s_own, s_fleet = _residual_std(own, test), _residual_std(fitted.model, test)
        s_raw = np.std(test.target, axis=0)
        evaluations[src.device_id] = {
            "fold": item.fold, "family": item.family,
            "fitted_on": [s.device_id for s in item.sources], "axes": {
                a: {"std_raw": float(s_raw[j]), "std_own": float(s_own[j]),
                    "std_fleet": float(s_fleet[j]),
                    "ratio": float(s_fleet[j] / s_own[j]) if s_own[j] > 0 else None}
                for j, a in enumerate(own.outputs)}}
    return {"units": [s.device_id for s in item.sources], "fold": item.fold,
            "evaluations": evaluations}


def _fold_items(cfg: CompareConfig, family: str, sources: list[UnitSource], k: int,
                per_fit: int, own: dict[str, Any], excluded: set[str]) -> list[_FoldItem]:
    """Unit *i* is in group *i* mod k; each group's fleet model is fitted on up to
    ``per_fit`` units of the other groups (evenly spaced), leaving out ``excluded`` units
    (flagged outliers, failed units)."""
    items = []
    for f in range(k):
        others = [s for i, s in enumerate(sources)
                  if i % k != f and s.device_id not in excluded]
        if len(others) > per_fit:  # evenly spaced, deterministic
            pick = np.linspace(0, len(others) - 1, per_fit).round().astype(int)
            others = [others[i] for i in sorted(set(pick.tolist()))]
        held = [(s, own[s.device_id]) for i, s in enumerate(sources)
                if i % k == f and own.get(s.device_id) is not None]
        if others and held:
            items.append(_FoldItem(cfg=cfg, family=family, fold=f, sources=others,
                                   held_out=held))
    return items


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
    ``plots=False`` writes no PNG files, per unit or for the fleet.

    Returns the fleet results (the dict written to ``out_dir/results.json``).
    """
    from ..core.fileio import _umask, atomic_write_text
    from ..core.names import inside, path_components
    from ..core.outdir import check_target, install

    t_start = time.perf_counter()
    opts = options or FleetOptions()
    source = getattr(cfg, "_source", "config")
    check_families(cfg, source=source)
    limits = parse_limits(getattr(cfg, "limits", None), source=source)
    family = _fleet_family(cfg, opts.family, source)
    if not sources:
        raise InputError("fleet: no units in the data")
    ids = [s.device_id for s in sources]
    dup = sorted({d for d in ids if ids.count(d) > 1})
    if dup:
        raise InputError(f"fleet: device id '{dup[0]}' given twice (device ids must be unique)")
    if opts.folds < 0 or opts.fleet_units_max < 1:
        raise ConfigError(f"fleet: folds must be ≥ 0 and fleet_units_max ≥ 1, got "
                          f"{opts.folds}, {opts.fleet_units_max}")
    out = Path(out_dir)
    check_target(out, overwrite, "fleet")  # before any unit is fitted
    dirs = path_components(ids)            # a device id never becomes a path as it is
    out.absolute().parent.mkdir(parents=True, exist_ok=True)

    def say(msg: str) -> None:
        if not quiet:
            print(msg, flush=True)

    k = min(opts.folds, len(sources)) if len(sources) >= 2 else 0
    say(f"thermonet fleet: {len(sources)} units, executor {opts.executor}, fleet family "
        f"{family}, leave-units-out in {k} groups")

    def run(fn: Any, todo: list[Any], on_done: Any = None) -> list[Any]:
        return run_tasks(fn, todo, executor=cast(Any, opts.executor), workers=opts.workers,
                         ray_address=opts.ray_address, on_done=on_done)

    items = [_UnitItem(cfg=cfg, source=s, family=family, plots=plots) for s in sources]

    def progress(i: int, res: Any) -> None:
        status = f"failed: {res.reason}" if isinstance(res, TaskFailure) else \
            f"chosen {res['results'].get('chosen') or 'none'}"
        say(f"  {ids[i]:<20} {status}")

    payloads = run(_unit_task, items, progress)

    stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial",
                                  dir=out.absolute().parent))
    try:
        os.chmod(stage, 0o777 & ~_umask())
        units: dict[str, Any] = {}
        own: dict[str, Any] = {}
        for dev, res in zip(ids, payloads, strict=True):
            if isinstance(res, TaskFailure):
                units[dev] = {"device": dev, "status": "failed", "reason": res.reason}
                continue
            udir = inside(stage, "units", dirs[dev])
            for rel, data in res["files"].items():
                p = udir / rel
                if not p.resolve().is_relative_to(udir.resolve()):
                    raise InputError(f"unit '{dev}': its worker returned a file outside its "
                                     f"directory ({rel!r})")
                p.parent.mkdir(parents=True, exist_ok=True)
                p.write_bytes(data)
            r = _relocate(res["results"], res["root"], str(out / "units" / dirs[dev]))
            r.update(status="ok", temperature_span_c=res["temperature_span_c"],
                     coefficients=res["coefficients"], leave_units_out=None,
                     n_runs=res["n_runs"], temperature_range_c=res["temperature_range_c"])
            r["device"] = dev
            r["dir"] = f"units/{dirs[dev]}"
            units[dev] = r
            own[dev] = res["own_model"]
        # leave units out, after the units: flagged outliers and failed units stay out of
        # every fleet model (a production line would not build its fleet model on them)
        flagged = set(_summary(units, family, {}, limits)["outliers"])
        fold_info: dict[str, Any] = {}
        if k:
            excluded = flagged | {d for d, u in units.items() if u["status"] != "ok"}
            folds = _fold_items(cfg, family, sources, k, opts.fleet_units_max, own, excluded)
            say(f"  leave-units-out: {len(folds)} fleet fits (outliers left out: "
                f"{', '.join(sorted(flagged)) or 'none'})")
            for item, fres in zip(folds, run(_fold_task, folds), strict=True):
                if isinstance(fres, TaskFailure):
                    fold_info[str(item.fold)] = {"status": "failed", "reason": fres.reason}
                    continue
                fold_info[str(item.fold)] = {"status": "ok", "fitted_on": fres["units"]}
                for dev, ev in fres["evaluations"].items():
                    units[dev]["leave_units_out"] = ev
        for dev, u in units.items():
            u["limits"] = judge_unit(u, limits)
            if u["status"] == "ok":
                atomic_write_text(inside(stage, "units", dirs[dev]) / "results.json",
                                  json.dumps(_clean(u), indent=2))
        summary = _summary(units, family, fold_info, limits)
        summary["seconds"] = time.perf_counter() - t_start
        from ..tracking import default_tracking_uri
        from .compare import data_source, resolved_config

        tracking = cfg.tracking.enabled if track is None else track
        results = {"schema": 1, "kind": "fleet", "fleet_family": family,
                   "config": resolved_config(  # as used: tracking, no preset for files
                       cfg, None, given=False, tracking_enabled=tracking, workers=1,
                       tracking_uri=tracking_uri or cfg.tracking.uri or default_tracking_uri()),
                   "provenance": {"data": data_source(cfg, None, given=False),
                                  "options": {"track": track, "tracking_uri": tracking_uri,
                                              "plots": plots}},
                   "options": dataclasses.asdict(opts), "units": units, "fleet": summary}
        plot = plot_coefficient_spread(stage / "plots" / "coefficient_spread.png", results) \
            if plots else None
        summary["spread_plot"] = None if plot is None else "plots/coefficient_spread.png"
        results = _clean(results)
        atomic_write_text(stage / "results.json", json.dumps(results, indent=2))
        from ..scoring.fleetstats import fleet_html_fragment

        atomic_write_text(stage / "fleet.html", "<!doctype html><meta charset=utf-8>"
                          "<title>thermonet fleet</title>\n"
                          + fleet_html_fragment(results, summary["spread_plot"]))
        _track(cfg, results, track, tracking_uri, stage)
        install(stage, out, overwrite, "fleet")
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    say(format_fleet_table(results))
    return results


def _curve_points(ok: dict[str, Any], family: str) -> dict[str, dict[str, float]]:
    """The fleet family's curve of every unit at five temperatures of the range all units
    were trained on (from the physical coefficients)."""
    ranges = [u["temperature_range_c"] for u in ok.values() if u.get("temperature_range_c")]
    if len(ranges) < len(ok) or not ranges:
        return {}
    lo, hi = max(r[0] for r in ranges), min(r[1] for r in ranges)
    if not hi > lo:
        return {}
    out: dict[str, dict[str, float]] = {}
    for t in np.round(np.linspace(lo, hi, 5), 1):
        for dev, u in ok.items():
            coefs: dict[str, dict[int, float]] = {}
            for name, v in u["coefficients"].items():
                axis, _, k = name.rpartition(".c")
                coefs.setdefault(axis, {})[int(k)] = v
            for axis, c in coefs.items():
                value = sum(v * (t - COEF_T0_C) ** k for k, v in c.items())
                out.setdefault(f"{family}.{axis}.drift@{t:g}C", {})[dev] = float(value)
    return out


def _summary(units: dict[str, Any], family: str, folds: dict[str, Any],
             limits: dict[str, Any]) -> dict[str, Any]:
    ok = {d: u for d, u in units.items() if u.get("status") == "ok"}
    coefficients: dict[str, dict[str, float]] = {}
    for dev, u in ok.items():
        for name, v in u.get("coefficients", {}).items():
            coefficients.setdefault(f"{family}.{name}", {})[dev] = v
    quantities = _curve_points(ok, family)
    errors: set[str] = set()
    for dev, u in ok.items():
        fam = u["families"].get(family, {})
        for axis, m in fam.get("axes", {}).items():
            for metric in ("rms_comp", "pp_comp"):
                if metric in m:
                    errors.add(f"{family}.{axis}.{metric}")
                    quantities.setdefault(f"{family}.{axis}.{metric}", {})[dev] = m[metric]
    luo_ratios: dict[str, list[float]] = {}
    for u in ok.values():
        for axis, a in ((u.get("leave_units_out") or {}).get("axes") or {}).items():
            if a.get("ratio") is not None:
                luo_ratios.setdefault(axis, []).append(a["ratio"])
    verdicts: dict[str, int] = {}
    for u in units.values():
        if "limits" in u:
            v = u["limits"]["verdict"]
            verdicts[v] = verdicts.get(v, 0) + 1
    n_failed = len(units) - len(ok)
    all_passed = n_failed == 0 and verdicts.get("FAIL", 0) == 0
    return {
        "n_units": len(units), "n_failed": n_failed, "family": family,
        "spread": {q: spread(v) for q, v in {**coefficients, **quantities}.items()},
        "outliers": flag_outliers(quantities, high_only=errors),
        "outlier_rule": f"robust z = |x - median| / (1.4826 * MAD) > {ROBUST_Z_THRESHOLD} on the "
                        "fleet family's curve at five temperatures of the common range, or "
                        "above the median on its held-out rms_comp / pp_comp (at least "
                        f"{MIN_UNITS_FOR_OUTLIERS} units; coefficients are reported, not "
                        "flagged: the higher ones are ill-conditioned)",
        "leave_units_out": {
            "family": family, "folds": folds,
            "median_ratio": {a: float(np.median(r)) for a, r in luo_ratios.items()},
            "meaning": "std of the compensated held-out error with a fleet model fitted on "
                       "other units / with the unit's own calibration of the same family"},
        "limits_configured": bool(limits), "verdicts": verdicts, "all_passed": all_passed,
    }


def _track(cfg: CompareConfig, results: dict[str, Any], track: bool | None,
           tracking_uri: str | None, stage: Path) -> None:
    """The driver's MLflow record: a parent run per fleet, a nested run per unit."""
    from ..tracking import Tracker

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
                    tracker.log_metrics({f"test/{a}/{k}": v for a, m in
                                         u["families"][chosen]["axes"].items()
                                         for k, v in m.items()})
        (stage / "results.json").write_text(json.dumps(results, indent=2))
        tracker.log_artifact(stage / "results.json")


def format_fleet_table(results: dict[str, Any]) -> str:
    """Unit × verdict table, then the fleet summary, as text."""
    fleet = results["fleet"]
    lines = [f"{'unit':<22} {'status':<7} {'chosen':<10} {'verdict':<10} "
             f"{'fleet/own':>9}  outlier"]
    for dev, u in results["units"].items():
        luo = (u.get("leave_units_out") or {}).get("axes") or {}
        ratios = [a["ratio"] for a in luo.values() if a.get("ratio") is not None]
        r = f"{max(ratios):9.3g}" if ratios else f"{'—':>9}"
        flag = ", ".join(f"{f['quantity']} z={f['z']:.1f}" for f in
                         fleet["outliers"].get(dev, [])[:2])
        lines.append(f"{dev:<22} {u.get('status', ''):<7} {str(u.get('chosen') or 'none'):<10} "
                     f"{u['limits']['verdict']:<10} {r}  {flag}")
        if u.get("status") == "failed":
            lines.append(f"{'':<22} reason: {u['reason']}")
    lines.append("")
    lines.append(f"{fleet['n_units']} units, {fleet['n_failed']} failed to calibrate; verdicts "
                 + ", ".join(f"{k} {v}" for k, v in sorted(fleet["verdicts"].items()))
                 + f"; outliers: {', '.join(fleet['outliers']) or 'none'}")
    med = fleet["leave_units_out"]["median_ratio"]
    if med:
        lines.append(f"leave-units-out ({fleet['family']}): median std ratio fleet/own "
                     + ", ".join(f"{a} {v:.3g}" for a, v in med.items()))
    return "\n".join(lines)


def plot_coefficient_spread(path: Path, results: dict[str, Any]) -> Path | None:
    """Strip plot: each coefficient's per-unit values as robust z, outliers in red."""
    from ..scoring.fleetstats import robust_z

    quantities: dict[str, dict[str, float]] = {}
    for dev, u in results["units"].items():
        for name, v in (u.get("coefficients") or {}).items():
            quantities.setdefault(name, {})[dev] = v
    zs = {q: robust_z(v) for q, v in quantities.items()}
    zs = {q: z for q, z in zs.items() if z}
    if not zs:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    signed = zs
    fig, ax = plt.subplots(figsize=(max(4.0, 0.8 * len(signed) + 2), 4.0))
    for i, z in enumerate(signed.values()):
        vals = np.array(list(z.values()))
        jitter = np.linspace(-0.15, 0.15, len(vals)) if len(vals) > 1 else np.zeros(1)
        out = np.abs(vals) > ROBUST_Z_THRESHOLD
        ax.scatter(i + jitter[~out], vals[~out], s=12, color="tab:blue")
        ax.scatter(i + jitter[out], vals[out], s=24, color="tab:red")
    for y in (-ROBUST_Z_THRESHOLD, ROBUST_Z_THRESHOLD):
        ax.axhline(y, color="grey", lw=0.8, ls="--")
    ax.set_xticks(range(len(signed)), list(signed), rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("signed robust z = (x − median) / (1.4826·MAD)")
    ax.set_title(f"Coefficient spread over {len(results['units'])} units "
                 f"({results['fleet_family']}, T0 = {COEF_T0_C:g} °C)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _clean(obj: Any) -> Any:
    """JSON-safe plain data: non-finite floats become null, NumPy scalars Python ones."""
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    return obj
