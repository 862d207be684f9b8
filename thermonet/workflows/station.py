"""A production line's station: a fleet prior, and new units calibrated from a short test.

``thermonet prior CONFIG --out prior.json`` (:func:`build_prior`) fits every calibrated
unit of a fleet (the data ``thermonet fleet`` takes: a file with a device id per run, or
``--units N`` simulated) on its 1 °C-binned means, leaves out the units whose curve is a
robust outlier (:func:`thermonet.scoring.fleetstats.flag_outliers`: a line does not build
its prior on faulty units) and writes the population (:mod:`thermonet.scoring.prior`):
per axis a Gaussian mixture over the curve's shape, the misfit variance, the temperature
range, and how many points of a short test reach each expected error.

``thermonet station CONFIG --prior prior.json --out DIR`` (:func:`run_station`) takes new
units measured briefly (a few soaks, a short ramp) and, per unit and axis, gives:

- the **posterior** curve (the prior updated by the unit's points) and its 90 % band;
- a **held-out** residual: the unit's points sorted by temperature are dealt into
  :data:`HELD_OUT_GROUPS` contiguous groups, each predicted from the prior and the others
  (its run's constant from the others of its run) — a short test is judged on
  temperatures it did not fit, like every model;
- the **distance from the fleet** (:attr:`thermonet.scoring.prior.Posterior.p_value`): a unit
  unlike every cluster is flagged, and FAILs, even if it fits its own points;
- PASS/FAIL against ``station.limits`` (held-out residual, tempco at t_ref, noise);
- the **next temperatures** to measure for a unit that failed its residual limit;
- ``DIR/units/<id>/calibration.json`` and ``thermonet_cal.h`` (the firmware's file: the
  polynomial per axis in (T − t_ref), evaluated by Horner in float) — written for every
  unit, with its verdict in both, as the unit finishes (``results.json`` keeps each unit's
  verdicts, held-out residuals and flags: the driver's memory does not grow with the detail).

Units run on the process pool, in this process, or on Ray (``--executor``); with ``--units N``
each worker simulates its own unit, so a worker holds one unit at a time.  The driver writes
``DIR`` in a staging directory moved into place at the end: a unit whose data the prior
cannot judge (other axes or targets, temperatures outside the fleet's range, no points) is
one line naming it, exit 1, nothing written.  Exit 3: some unit failed.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, InputError, failures_line
from ..core.executors import TaskFailure, run_tasks
from ..core.fileio import _umask, atomic_write_text
from ..core.names import c_comment, inside, path_components
from ..core.outdir import check_target, install
from ..core.recording import Dataset, split_units
from ..core.schema import from_dict
from ..features.target import AT_T_REF, FOUR_POSITION, output_units
from ..scoring.fleetstats import flag_outliers, merged_limits
from ..scoring.prior import (
    FLAG_P,
    MIN_UNITS,
    AxisPrior,
    FleetPrior,
    StationLimit,
    check_compatible,
    fit_population,
    fit_unit,
    posterior,
)
from ..scoring.prior_design import design_errors, first_below, next_temperatures, typical_drift
from ..scoring.prior_points import BIN_C, Points, bin_points, shape_design
from ..training.config import CompareConfig, outputs_of
from ..training.parts import build_part, targets_for
from .fleet_units import UnitSource

__all__ = ["build_prior", "run_station", "prior_summary", "parse_station_limits", "format_station", "format_prior", "unit_points", "StationOptions", "HELD_OUT_GROUPS",
           "EXIT_STATION_FAILED", "BAND_Z"]

#: Contiguous temperature groups a unit's points are dealt into for its held-out residual.
HELD_OUT_GROUPS = 3
#: Exit code of ``thermonet station`` when a unit failed.
EXIT_STATION_FAILED = 3
#: The band's half-width in posterior standard deviations (90 %, two-sided, Gaussian).
BAND_Z = 1.6449
#: The expected error :func:`points_needed` is asked for, as a fraction of the fleet's
#: median raw drift over the range (reported in the prior).
TARGET_FRACTIONS = (0.2, 0.1, 0.05)


def _t_ref(cfg: CompareConfig) -> float:
    t = cfg.features.t_ref
    return 25.0 if isinstance(t, str) else float(t)


def unit_points(cfg: CompareConfig, ds: Dataset, where: str
                ) -> tuple[dict[str, Points], dict[str, str], dict[str, str], float]:
    """Each axis's binned points over a unit's runs (a run's index is its points' run), the
    axes' target modes, their units of measure, and the unit's temperature span (°C)."""
    if cfg.target == FOUR_POSITION:
        raise ConfigError(f"{where}: the fleet prior models a per-sample target (channel, zero, "
                          "at-t-ref); 'four-position' is not supported")
    outputs = outputs_of(cfg, ds)
    target = targets_for(ds, cfg.target, outputs, source=where)
    per_axis: dict[str, list[Points]] = {o: [] for o in outputs}
    lo, hi = math.inf, -math.inf
    for r, rec in enumerate(ds):
        if rec.temperature_c is None:
            raise InputError(f"{where}: run '{rec.run_id}' has no temperature")
        part = build_part(rec, signals=["temperature_c"], outputs=outputs, target=target)
        t = np.asarray(rec.temperature_c, dtype=np.float64)
        if np.isfinite(t).any():
            lo, hi = min(lo, float(np.nanmin(t))), max(hi, float(np.nanmax(t)))
        for j, o in enumerate(outputs):
            per_axis[o].append(bin_points(t, part.target[:, j], run=r, time_s=rec.time_s))
    units = output_units(outputs, ds.runs[0].units)
    return ({o: Points.join(p) for o, p in per_axis.items()},
            {o: target.mode(o) for o in outputs}, units, hi - lo if hi >= lo else 0.0)


# ------------------------------------------------------------------ the prior
def _range(spans: list[tuple[float, float]]) -> tuple[float, float]:
    """The range most units cover: the medians of their lows and highs, in whole °C."""
    lo = float(np.floor(np.median([s[0] for s in spans])))
    hi = float(np.ceil(np.median([s[1] for s in spans])))
    return lo, hi


def _outlier_units(fits: dict[str, dict[str, Any]], t_ref: float, scale: float,
                   range_c: tuple[float, float], degree: int) -> dict[str, str]:
    """Units whose curve at five temperatures is a robust outlier on some axis."""
    temps = np.linspace(range_c[0], range_c[1], 5)
    X = shape_design(temps, t_ref, scale, degree)
    quantities: dict[str, dict[str, float]] = {}
    for dev, axes in fits.items():
        for axis, fit in axes.items():
            for t, v in zip(temps, X @ fit.shape, strict=True):
                quantities.setdefault(f"{axis}@{t:g}C", {})[dev] = float(v)
    return {dev: f"robust outlier: {hits[0]['quantity']} z={hits[0]['z']:.1f}"
            for dev, hits in flag_outliers(quantities).items()}


def build_prior(cfg: CompareConfig, ds: Dataset, *, source: str = "") -> FleetPrior:
    """The fleet prior of ``ds``'s units (see the module docstring)."""
    where = getattr(cfg, "_source", "config")
    units = split_units(ds)
    if len(units) < MIN_UNITS:
        raise InputError(f"{where}: a fleet prior needs at least {MIN_UNITS} calibrated units; "
                         f"the data hold {len(units)}")
    degree, t_ref = cfg.station.degree, _t_ref(cfg)
    pts: dict[str, dict[str, Points]] = {}
    meta: dict[str, tuple[dict[str, str], dict[str, str]]] = {}
    for dev, uds in units.items():
        p, targets, uom, _ = unit_points(cfg, uds, f"unit '{dev}'")
        pts[dev], meta[dev] = p, (targets, uom)
    spans = [(float(p.temperature_c.min()), float(p.temperature_c.max()))
             for d in pts.values() for p in d.values() if p.value.size]
    rng = _range(spans)
    scale = max(abs(rng[1] - t_ref), abs(t_ref - rng[0]), 1.0)
    fits: dict[str, dict[str, Any]] = {}
    excluded: dict[str, str] = {}
    for dev, unit_pts in pts.items():
        try:
            fits[dev] = {a: fit_unit(p, t_ref=t_ref, scale=scale, degree=degree)
                         for a, p in unit_pts.items()}
        except InputError as err:
            excluded[dev] = str(err)
    excluded.update(_outlier_units(fits, t_ref, scale, rng, degree))
    kept = [d for d in fits if d not in excluded]
    if len(kept) < MIN_UNITS:
        raise InputError(f"{where}: a fleet prior needs at least {MIN_UNITS} calibrated units; "
                         f"{len(kept)} remain after leaving out {len(excluded)} "
                         "(outliers or too few points)")
    targets, uom = meta[kept[0]]
    axes: list[AxisPrior] = []
    for a in targets:
        shapes = np.array([fits[d][a].shape for d in kept])
        w, means, covs = fit_population(shapes)
        axes.append(AxisPrior(a, w, means, covs,
                              float(np.median([fits[d][a].misfit_var for d in kept])),
                              float(np.median([np.median(pts[d][a].sampling_var)
                                               for d in kept]))))
    return FleetPrior(axes, degree, t_ref, scale, rng, uom, targets, len(kept), kept,
                      excluded, source, BIN_C)


def prior_summary(fp: FleetPrior, limits: dict[str, StationLimit] | None = None
                  ) -> dict[str, Any]:
    """Per axis: clusters, and points of a short test for an expected error of a fraction
    of the fleet's typical drift (the fleet's mean curve's offset-free RMS over the range)
    and, where ``station.limits`` sets ``max_residual``, for that limit (a point's own error,
    the misfit variance, taken out of it first)."""
    out: dict[str, Any] = {}
    limits = limits or {}
    for ap in fp.axes:
        typical = typical_drift(fp, ap.axis)
        temps, errs = design_errors(fp, ap.axis)
        rows: list[dict[str, Any]] = []
        for frac in TARGET_FRACTIONS:
            n = first_below(errs, frac * typical)
            rows.append({"target": frac * typical, "fraction_of_drift": frac, "points": n,
                         "temperatures_c": temps[:n] if n else None})
        lim = merged_limits(limits, ap.axis, StationLimit).max_residual
        if lim is not None:
            room = lim ** 2 - ap.misfit_var
            n = first_below(errs, math.sqrt(room)) if room > 0 else None
            rows.append({"target": lim, "limit": "max_residual", "points": n,
                         "temperatures_c": temps[:n] if n else None})
        out[ap.axis] = {"clusters": ap.n_clusters, "typical_drift_rms": typical,
                        "point_error": math.sqrt(ap.misfit_var + ap.sampling_var),
                        "points_needed": rows, "expected_error_after_2_to_12": errs}
    return out


def _points_text(row: dict[str, Any]) -> str:
    return f"{row['points']} points ({', '.join(f'{t:g}' for t in row['temperatures_c'])} °C)"


def format_prior(fp: FleetPrior, summary: dict[str, Any], plan: list[float] | None = None
                 ) -> str:
    """What ``thermonet prior`` prints: the prior, a three-soak test for every axis
    (``plan``: :func:`~thermonet.scoring.prior_design.soak_plan`), then per axis its clusters
    and the points a test needs (:func:`prior_summary`)."""
    lines = [f"prior of {fp.n_units} units ({len(fp.excluded)} left out), axes "
             f"{', '.join(fp.axis_names)}, {fp.range_c[0]:g} to {fp.range_c[1]:g} °C"]
    if plan:
        lines.append(f"  a 3-soak test for every axis: {', '.join(f'{t:g}' for t in plan)} °C, "
                     "in that order (the range's ends, the middle the prior tells most by)")
    for axis, s in summary.items():
        head = f"  {axis}: {s['clusters']} cluster(s); "
        if s["typical_drift_rms"] < s["point_error"]:
            lines.append(head + f"its drift ({s['typical_drift_rms']:.3g} RMS over the range) is "
                         f"below a point's own error ({s['point_error']:.3g}): a test fixes its "
                         "offset, there is no curve to learn")
            continue
        need = s["points_needed"][0]
        lines.append(head + (_points_text(need) if need["points"] else "more than 12 points") +
                     f" for an expected error of 20 % of the fleet's drift ({need['target']:.3g})")
        for row in s["points_needed"][len(TARGET_FRACTIONS):]:
            lines.append(f"    station.limits max_residual {row['target']:.3g}: " + (
                _points_text(row) if row["points"] else "not reachable within 12 points (the "
                "fleet's misfit alone is about that large)"))
    return "\n".join(lines)


# ------------------------------------------------------------------ one new unit
@dataclass
class StationItem:
    cfg: CompareConfig
    prior: FleetPrior
    source: UnitSource
    limits: dict[str, StationLimit] = field(default_factory=dict)


def _check_range(fp: FleetPrior, p: Points, where: str, axis: str) -> None:
    if p.value.size == 0:
        raise InputError(f"{where}: axis {axis}: no 1 °C bin holds enough samples to be a point")
    lo, hi = float(p.temperature_c.min()), float(p.temperature_c.max())
    margin = fp.bin_c
    if lo < fp.range_c[0] - margin or hi > fp.range_c[1] + margin:
        raise InputError(f"{where}: measured {lo:.1f} to {hi:.1f} °C, outside the fleet "
                         f"prior's range {fp.range_c[0]:g} to {fp.range_c[1]:g} °C (the prior "
                         "says nothing there)")


def _held_out(fp: FleetPrior, ap: AxisPrior, p: Points) -> float | None:
    """RMS of each temperature group's points predicted from the prior and the others."""
    order = np.argsort(p.temperature_c, kind="stable")
    groups = np.array_split(order, min(HELD_OUT_GROUPS, p.value.size))
    res: list[np.ndarray] = []
    for g in groups:
        test = np.zeros(p.value.size, bool)
        test[g] = True
        train = p.take(~test)
        if train.value.size == 0:
            continue
        post = posterior(ap, train, t_ref=fp.t_ref, scale=fp.scale)
        f = shape_design(p.temperature_c, fp.t_ref, fp.scale, fp.degree) @ post.shape
        for r in np.unique(p.run[test]):
            tr, te = (~test) & (p.run == r), test & (p.run == r)
            if tr.any():   # its run's constant from the run's other points
                const = float(np.mean(p.value[tr] - f[tr]))
                res.append(p.value[te] - f[te] - const)
    return float(np.sqrt(np.mean(np.concatenate(res) ** 2))) if res else None


def _axis_result(fp: FleetPrior, axis: str, p: Points, lim: StationLimit,
                 flag: bool) -> dict[str, Any]:
    ap = fp.axis(axis)
    post = posterior(ap, p, t_ref=fp.t_ref, scale=fp.scale)
    resid = p.value - shape_design(p.temperature_c, fp.t_ref, fp.scale, fp.degree) @ post.shape
    consts = [float(np.mean(resid[p.run == r])) for r in np.unique(p.run)]
    c0 = 0.0 if fp.targets[axis] == AT_T_REF else float(np.mean(consts))
    coeffs = [c0] + fp.physical(post.shape)
    grid_t = np.arange(fp.range_c[0], fp.range_c[1] + 1e-9, 5.0)
    G = shape_design(grid_t, fp.t_ref, fp.scale, fp.degree)
    G -= G.mean(axis=0)
    half = BAND_Z * np.sqrt(np.einsum("ij,jk,ik->i", G, post.cov, G) + ap.misfit_var)
    held = _held_out(fp, ap, p)
    noise = float(np.sqrt(np.median(p.sampling_var * p.n_samples)))
    checks = lim.checks(held, coeffs[1] if fp.degree >= 1 else 0.0, noise)
    if flag and post.flagged:
        checks.append({"limit": "like_its_fleet", "value": post.p_value, "min": FLAG_P,
                       "ok": False})
    ok = all(c["ok"] for c in checks)
    return {"coefficients": coeffs, "posterior_std": [0.0] + fp.physical(
                np.sqrt(np.diag(post.cov))),
            "cluster_weights": post.weights.tolist(), "p_value": post.p_value,
            "flagged_unlike_fleet": post.flagged, "held_out_rms": held, "noise_std": noise,
            "points": int(p.value.size), "band_90": {"temperature_c": grid_t.tolist(),
                                                     "half_width": half.tolist()},
            "checks": checks, "verdict": "PASS" if ok else "FAIL",
            "next_temperatures_c": None if ok else next_temperatures(
                fp, axis, p.temperature_c.tolist(), 2)}


def station_task(item: StationItem) -> dict[str, Any]:
    """One new unit in a worker: its posterior, held-out check and files, as plain data."""
    fp, dev = item.prior, item.source.device_id
    where = f"unit '{dev}'"
    ds = item.source.load(item.cfg)
    if ds.is_fleet:
        raise InputError(f"{where}: its data hold several devices")
    pts, targets, uom, span = unit_points(item.cfg, ds, where)
    check_compatible(fp, list(pts), targets, where, uom)
    for a in fp.axis_names:
        _check_range(fp, pts[a], where, a)
    axes = {a: _axis_result(fp, a, pts[a], merged_limits(item.limits, a, StationLimit),
                            item.cfg.station.flag_unlike_fleet) for a in fp.axis_names}
    verdict = "PASS" if all(r["verdict"] == "PASS" for r in axes.values()) else "FAIL"
    return {"device_id": dev, "verdict": verdict, "axes": axes, "temperature_span_c": span,
            "runs": len(ds), "header": c_header(fp, dev, axes, verdict)}


def _c_idents(axes: list[str]) -> dict[str, str]:
    """A C identifier per axis name (distinct: a clash gets the axis's index appended)."""
    out: dict[str, str] = {}
    for i, axis in enumerate(axes):
        s = "".join(ch if ch.isascii() and ch.isalnum() else "_" for ch in axis).upper()
        s = s if s and not s[0].isdigit() else f"A_{s}"
        out[axis] = f"{s}_{i}" if s in out.values() else s
    return out


def c_header(fp: FleetPrior, dev: str, axes: dict[str, Any], verdict: str) -> str:
    """The firmware's file: per axis the drift polynomial in (T − t_ref), Horner in float."""
    lines = ["/* thermonet station: temperature drift of one unit, posterior of the fleet prior",
             c_comment([f"unit {dev}: {verdict}",
                        f"compensated = raw - drift(T); drift in the axis's unit, T in degC, "
                        f"valid {fp.range_c[0]:g} to {fp.range_c[1]:g} degC"]) + " */",
             "#ifndef THERMONET_CAL_H", "#define THERMONET_CAL_H",
             f"#define THERMONET_CAL_T_REF {fp.t_ref!r}f",
             f"#define THERMONET_CAL_T_MIN {fp.range_c[0]!r}f",
             f"#define THERMONET_CAL_T_MAX {fp.range_c[1]!r}f"]
    idents = _c_idents(list(axes))
    for axis, r in axes.items():
        name = idents[axis]
        cs = ", ".join(f"{c!r}f" for c in r["coefficients"])
        lines += [f"static const float THERMONET_CAL_{name}[{len(r['coefficients'])}] = {{{cs}}};",
                  f"static inline float thermonet_cal_{name.lower()}(float t) {{",
                  "    float x, y = 0.0f;",
                  "    int k;",
                  "    if (t < THERMONET_CAL_T_MIN) t = THERMONET_CAL_T_MIN;",
                  "    if (t > THERMONET_CAL_T_MAX) t = THERMONET_CAL_T_MAX;",
                  "    x = t - THERMONET_CAL_T_REF;",
                  f"    for (k = {len(r['coefficients']) - 1}; k >= 0; --k) "
                  f"y = y * x + THERMONET_CAL_{name}[k];",
                  "    return y;", "}"]
    return "\n".join(lines + ["#endif", ""])


# ------------------------------------------------------------------ the driver
@dataclass
class StationOptions:
    executor: str = "process"
    workers: int | None = None
    ray_address: str | None = None


def parse_station_limits(cfg: CompareConfig) -> dict[str, StationLimit]:
    where = getattr(cfg, "_source", "config")
    out = {}
    for axis, spec in (cfg.station.limits or {}).items():
        out[str(axis)] = from_dict(StationLimit, spec, source=where,
                                   prefix=f"station.limits.{axis}")
    return out


def run_station(cfg: CompareConfig, prior: FleetPrior, sources: list[UnitSource], out: Path,
                *, overwrite: bool = False, opts: StationOptions | None = None,
                say: Any = print) -> dict[str, Any]:
    """Calibrate every unit of ``sources`` with ``prior``; write ``out`` (module docstring)."""
    opts = opts or StationOptions()
    limits = parse_station_limits(cfg)
    unknown = [a for a in limits if a != "*" and a not in prior.axis_names]
    if unknown:
        raise ConfigError(f"{getattr(cfg, '_source', 'config')}: key 'station.limits.{unknown[0]}'"
                          f": not an axis of the prior ({', '.join(prior.axis_names)})")
    if cfg.station.degree != prior.degree:
        raise ConfigError(f"{getattr(cfg, '_source', 'config')}: key 'station.degree': "
                          f"{cfg.station.degree}, and the prior ({prior.source or 'its file'}) "
                          f"is of degree {prior.degree}: build the prior with the station's "
                          "degree")
    check_target(out, overwrite, "station")
    out.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial",
                                  dir=out.absolute().parent))
    try:
        os.chmod(stage, 0o777 & ~_umask())
        t0 = time.perf_counter()
        units = _run_units(cfg, prior, sources, limits, stage, opts, say)
        results = _summary(prior, units, time.perf_counter() - t0)
        atomic_write_text(stage / "results.json", json.dumps(results, indent=2))
        install(stage, out, overwrite, "station")
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return results


def _run_units(cfg: CompareConfig, prior: FleetPrior, sources: list[UnitSource],
               limits: dict[str, StationLimit], stage: Path, opts: StationOptions,
               say: Any) -> dict[str, dict[str, Any]]:
    """Every unit on the executor; each unit's files written into ``stage`` as it finishes
    and only its summary kept (the driver's memory does not grow with the units' detail)."""
    dirs = path_components([s.device_id for s in sources])
    items = [StationItem(cfg, prior, s, limits) for s in sources]
    done = [0]

    def finished(i: int, r: Any) -> None:
        done[0] += 1
        if not isinstance(r, TaskFailure):
            rel = ("units", dirs[r["device_id"]])
            udir = inside(stage, *rel)
            udir.mkdir(parents=True)
            atomic_write_text(udir / "thermonet_cal.h", r.pop("header"))
            atomic_write_text(udir / "calibration.json", json.dumps(r, indent=2))
            summary = _unit_summary(r, "/".join(rel))
            r.clear()
            r.update(summary)
        if done[0] % max(1, len(items) // 10) == 0 or done[0] == len(items):
            say(f"station: {done[0]}/{len(items)} units")

    payloads = run_tasks(station_task, items, executor=opts.executor,  # type: ignore[arg-type]
                         workers=opts.workers, ray_address=opts.ray_address, on_done=finished)
    bad = [(s.device_id, p.reason) for s, p in zip(sources, payloads, strict=True)
           if isinstance(p, TaskFailure)]
    if bad:
        raise InputError(failures_line(bad, "unit"))
    return {p["device_id"]: p for p in payloads}



def _unit_summary(r: dict[str, Any], rel: str) -> dict[str, Any]:
    """What results.json keeps of a unit: verdicts, held-out residuals, flags, its files."""
    return {"device_id": r["device_id"], "verdict": r["verdict"], "runs": r["runs"],
            "temperature_span_c": r["temperature_span_c"], "files": rel,
            "axes": {a: {"verdict": x["verdict"], "held_out_rms": x["held_out_rms"],
                         "p_value": x["p_value"],
                         "flagged_unlike_fleet": x["flagged_unlike_fleet"],
                         "failed": [c["limit"] for c in x["checks"] if not c["ok"]]}
                     for a, x in r["axes"].items()}}


def _summary(prior: FleetPrior, units: dict[str, dict[str, Any]],
             seconds: float) -> dict[str, Any]:
    n_fail = sum(u["verdict"] != "PASS" for u in units.values())
    return {"schema": 1, "kind": "station", "prior": prior.source,
            "prior_units": prior.n_units, "units": units,
            "summary": {"n_units": len(units), "passed": len(units) - n_fail,
                        "failed": n_fail,
                        "flagged_unlike_fleet": sorted(
                            d for d, u in units.items()
                            if any(a["flagged_unlike_fleet"] for a in u["axes"].values())),
                        "seconds": seconds,
                        "units_per_minute": 60.0 * len(units) / max(seconds, 1e-9)}}


def format_station(results: dict[str, Any]) -> str:
    """One line per unit: verdict, worst held-out residual, flags; then the totals."""
    lines = []
    for dev, u in results["units"].items():
        worst = max(u["axes"].items(), key=lambda kv: kv[1]["held_out_rms"] or 0.0)
        fails = [f"{a}: {lim}" for a, r in u["axes"].items() for lim in r["failed"]]
        lines.append(f"{dev}: {u['verdict']}  worst held-out residual {worst[0]} "
                     f"{worst[1]['held_out_rms'] or 0.0:.3g}" +
                     (f"  [{'; '.join(fails[:3])}]" if fails else ""))
    s = results["summary"]
    lines.append(f"{s['passed']} of {s['n_units']} units passed; "
                 f"{len(s['flagged_unlike_fleet'])} unlike their fleet; "
                 f"{s['units_per_minute']:.0f} units/min")
    return "\n".join(lines)
