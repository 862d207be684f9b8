"""A production line's station: a fleet prior, and new units calibrated from a short test.

``thermonet prior CONFIG --out prior.json`` (:func:`build_prior`) fits every calibrated
unit of a fleet (the data ``thermonet fleet`` takes: a file with a device id per run, or
``--units N`` simulated) on its 1 °C-binned means, leaves out the units whose curve is a
robust outlier (their spread never taken below a point's own error: a line does not build
its prior on faulty units) and writes the population (:mod:`thermonet.scoring.prior`):
per axis a Gaussian mixture over the curve's shape, the misfit variance, the temperature
range, and how many points of a short test reach each expected error (that part lives in
:mod:`thermonet.workflows.station_prior`, re-exported here).

``thermonet station CONFIG --prior prior.json --out DIR`` (:func:`run_station`) takes new
units measured briefly (a few soaks, a short ramp) and, per unit and axis, gives:

- the **posterior** curve (the prior updated by the unit's points) and its 90 % band;
- a **held-out** residual: the unit's points sorted by temperature are dealt into
  :data:`HELD_OUT_GROUPS` contiguous groups, each predicted from the prior and the others
  (its run's constant from the others of its run) — a short test is judged on
  temperatures it did not fit, like every model;
- the **distance from the fleet** (:attr:`thermonet.scoring.prior.Posterior.p_value`): a unit
  unlike every cluster is flagged, and FAILs, even if it fits its own points — where its
  test is of a kind the prior can judge (:meth:`~thermonet.scoring.prior.FleetPrior.
  not_comparable`: a fast ramp against a prior of slow tests, or the reverse, is not
  compared, and says why);
- PASS/FAIL against ``station.limits`` (held-out residual, tempco at t_ref, noise); a
  residual that cannot be judged (one point, or no run with points at two temperatures)
  is "not judged (why)", and fails ``max_residual`` where that limit is set;
- a **dead or stuck axis** (constant, or piled up at an extreme:
  :mod:`thermonet.workflows.station_checks`) FAILs its unit, and gets no firmware file;
- the **next temperatures** to measure for a unit that failed its residual limit (a soak
  plan's separation from those it measured);
- ``DIR/units/<id>/calibration.json`` and ``thermonet_cal.h`` (the firmware's file: the
  polynomial per axis in (T − t_ref), evaluated by Horner in float) — written for every
  unit, with its verdict in both, as the unit finishes (``results.json`` keeps each unit's
  verdicts, held-out residuals and flags: the driver's memory does not grow with the detail).

Units run on the process pool, in this process, or on Ray (``--executor``); with ``--units N``
each worker simulates its own unit, so a worker holds one unit at a time.  The driver writes
``DIR`` in a staging directory moved into place at the end.  A unit whose own data the prior
cannot judge (temperatures outside the fleet's range, no points, data that fail validation — a
dead thermometer, no rows —, axes, targets or units of measure its file gives otherwise than
the prior) FAILs with that reason (``error`` in its calibration.json, no firmware file, the
reason on its console line) and the other units finish: exit 3.  Refused before any unit runs,
one line naming the key and both values, exit 1, nothing written: what the config fixes of
every unit against the prior (the axes of ``data.outputs``, of the preset or of the mapping —
the prior's and the units' must be the same —, the preset's or the mapping's units of
measure, a target mode it names, ``features.t_ref``, ``station.degree``); so are two units of
identical outputs (one unit's data under two serial numbers), two runs of one unit with
identical outputs, and a top-level ``limits`` section (the station's are ``station.limits``).
A unit's task that fails otherwise (a bug, a worker that died) stops the batch: exit 1,
nothing written.  Exit 3: some unit failed.  What
``results.json`` keeps and the console prints: :mod:`thermonet.workflows.station_report`.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, InputError, counted, failures_line
from ..core.executors import TaskFailure, run_tasks
from ..core.fileio import atomic_write_text
from ..core.names import c_comment, inside, path_components
from ..core.outdir import check_target, install, make_stage
from ..core.recording import Dataset, output_kind
from ..core.schema import from_dict
from ..features.target import AT_T_REF
from ..scoring.fleetstats import merged_limits
from ..scoring.prior import (
    FLAG_P,
    AxisPrior,
    FleetPrior,
    StationLimit,
    posterior,
    posterior_from_stats,
)
from ..scoring.prior_design import next_temperatures
from ..scoring.prior_map import TestMap
from ..scoring.prior_points import Points, shape_design
from ..training.config import CompareConfig
from .fleet_units import UnitSource
from .station_checks import (
    check_config_channels,
    check_station_config,
    dead_axes,
    identical_runs,
    identical_units,
    run_sources,
)
from .station_prior import (
    build_prior,
    check_compatible,
    config_t_ref,
    format_prior,
    prior_summary,
    unit_points,
    unit_test_kind,
    unit_windows,
)
from .station_report import (
    DEAD_AXIS,
    failed_unit,
    format_station,
    station_summary,
    unit_summary,
)

__all__ = ["build_prior", "run_station", "prior_summary", "parse_station_limits",
           "format_station", "format_prior", "unit_points", "StationOptions",
           "HELD_OUT_GROUPS", "EXIT_STATION_FAILED", "BAND_Z", "map_windows"]

#: Contiguous temperature groups a unit's points are dealt into for its held-out residual.
HELD_OUT_GROUPS = 3
#: Exit code of ``thermonet station`` when a unit failed.
EXIT_STATION_FAILED = 3
#: The band's half-width in posterior standard deviations (90 %, two-sided, Gaussian).
BAND_Z = 1.6449

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


def _held_out(fp: FleetPrior, ap: AxisPrior, p: Points) -> tuple[float | None, str | None]:
    """RMS of each temperature group's points predicted from the prior and the others, or
    None and why it cannot be judged: a point is judged only against its own run's other
    points (the run's constant is free), so a unit needs a run with points in two groups."""
    if p.value.size < 2:
        return None, counted(int(p.value.size), "point")
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
    if not res:
        return None, f"{p.value.size} points, no run with points at two temperatures"
    return float(np.sqrt(np.mean(np.concatenate(res) ** 2))), None


def _held_out_map(tm: TestMap, ap: AxisPrior, f: np.ndarray) -> tuple[float | None, str | None]:
    """The short test's windows dealt into :data:`HELD_OUT_GROUPS` contiguous stretches of
    time, each predicted through the fleet's map from the prior and the other windows (a
    constant from the others): RMS of the held-out windows' residuals."""
    idx = np.flatnonzero(np.isfinite(f))
    if idx.size < HELD_OUT_GROUPS + 2:
        return None, f"{idx.size} windows of the short test"
    res: list[np.ndarray] = []
    for g in np.array_split(idx, HELD_OUT_GROUPS):
        train = f.copy()
        train[g] = np.nan
        pred = tm.predict(ap.axis, posterior_from_stats(ap, *tm.stats(ap.axis, train)).shape)
        rest = np.setdiff1d(idx, g)
        res.append(f[g] - pred[g] - float(np.mean(f[rest] - pred[rest])))
    return float(np.sqrt(np.mean(np.concatenate(res) ** 2))), None


def map_windows(cfg: CompareConfig, fp: FleetPrior, ds: Dataset
                 ) -> tuple[dict[str, np.ndarray], str | None]:
    """A unit's centred window means per axis where its test is the fleet's short test
    (:meth:`~thermonet.scoring.prior_map.TestMap.mismatch`), or why it is not (``{}``
    and None: the prior has no map)."""
    tm = fp.test_map
    if tm is None:
        return {}, None
    if len(ds) != 1:
        return {}, f"its data hold {len(ds)} runs, the fleet's short test is one"
    run = ds.runs[0]
    why = tm.mismatch(np.asarray(run.time_s), np.asarray(run.temperature_c, dtype=np.float64))
    if why is not None:
        return {}, why
    values, _ = unit_windows(cfg, run, fp.axis_names, tm.window_s, tm.n_windows)
    return {a: tm.centred(values[:, j]) for j, a in enumerate(fp.axis_names)}, None


def _axis_result(fp: FleetPrior, axis: str, p: Points, lim: StationLimit,
                 flag: bool, unlike_kind: str | None = None,
                 f_map: np.ndarray | None = None, dead: str | None = None) -> dict[str, Any]:
    """One axis of a unit; ``unlike_kind``: why its test cannot be compared with the fleet
    (:meth:`~thermonet.scoring.prior.FleetPrior.not_comparable`): the flag is then not judged
    and fails nothing; ``f_map``: its centred window means where its test is the fleet's
    short test (the posterior and the held-out residual are then through its map);
    ``dead``: why the axis is dead or stuck (:func:`~thermonet.workflows.station_checks.
    dead_axes`): it fails, and gets no next temperatures (more points will not revive it)."""
    ap = fp.axis(axis)
    tm = fp.test_map
    post = (posterior_from_stats(ap, *tm.stats(axis, f_map)) if tm is not None and
            f_map is not None else posterior(ap, p, t_ref=fp.t_ref, scale=fp.scale))
    resid = p.value - shape_design(p.temperature_c, fp.t_ref, fp.scale, fp.degree) @ post.shape
    consts = [float(np.mean(resid[p.run == r])) for r in np.unique(p.run)]
    c0 = 0.0 if fp.targets[axis] == AT_T_REF else float(np.mean(consts))
    coeffs = [c0] + fp.physical(post.shape)
    grid_t = np.arange(fp.range_c[0], fp.range_c[1] + 1e-9, 5.0)
    G = shape_design(grid_t, fp.t_ref, fp.scale, fp.degree)
    G -= G.mean(axis=0)
    half = BAND_Z * np.sqrt(np.einsum("ij,jk,ik->i", G, post.cov, G) + ap.misfit_var)
    held, unjudged = (_held_out_map(tm, ap, f_map) if tm is not None and f_map is not None
                      else _held_out(fp, ap, p))
    noise = float(np.sqrt(np.median(p.sampling_var * p.n_samples)))
    checks = lim.checks(held, coeffs[1] if fp.degree >= 1 else 0.0, noise,
                        not_judged=unjudged)
    flagged = post.flagged and unlike_kind is None
    if flag and flagged:
        checks.append({"limit": "like_its_fleet", "value": post.p_value, "min": FLAG_P,
                       "ok": False})
    if dead is not None:
        checks.insert(0, {"limit": DEAD_AXIS, "value": None, "ok": False, "why": dead})
    ok = all(c["ok"] for c in checks)
    return {"coefficients": coeffs, "posterior_std": [0.0] + fp.physical(
                np.sqrt(np.diag(post.cov))),
            "cluster_weights": post.weights.tolist(), "p_value": post.p_value,
            "flagged_unlike_fleet": flagged, "fleet_not_compared": unlike_kind,
            "held_out_rms": held,
            "held_out_not_judged": unjudged, "noise_std": noise,
            "points": int(p.value.size), "band_90": {"temperature_c": grid_t.tolist(),
                                                     "half_width": half.tolist()},
            "checks": checks, "verdict": "PASS" if ok else "FAIL", "dead_axis": dead,
            "next_temperatures_c": None if ok or dead is not None else next_temperatures(
                fp, axis, p.temperature_c.tolist(), 2)}


def station_task(item: StationItem) -> dict[str, Any]:
    """One new unit in a worker: its posterior, held-out check and files, as plain data.  A
    unit whose own data fail a check (an :class:`InputError`: outside the prior's range, no
    point, a dead thermometer, axes or units not the prior's…) is a FAIL with that reason
    (:func:`~thermonet.workflows.station_report.failed_unit`) on every executor; any other
    error is raised (the batch stops: a bug is not a unit's verdict)."""
    ds: Dataset | None = None
    try:
        ds = item.source.load(item.cfg)
        return _calibrate(item, ds)
    except InputError as err:
        return failed_unit(item.source.device_id, str(err), ds)


def _calibrate(item: StationItem, ds: Dataset) -> dict[str, Any]:
    fp, dev = item.prior, item.source.device_id
    where = f"unit '{dev}'"
    if ds.is_fleet:
        raise InputError(f"{where}: its data hold several devices")
    pts, targets, uom, span = unit_points(item.cfg, ds, where)
    check_compatible(fp, list(pts), targets, where, uom)
    for a in fp.axis_names:
        _check_range(fp, pts[a], where, a)
    kind = unit_test_kind(ds)
    windows, not_map = map_windows(item.cfg, fp, ds)
    unlike = None if windows else fp.not_comparable(kind)   # the map is the fleet's own test
    dead = dead_axes(ds, fp.axis_names)
    axes = {a: _axis_result(fp, a, pts[a], merged_limits(item.limits, a, StationLimit),
                            item.cfg.station.flag_unlike_fleet, unlike, windows.get(a),
                            dead.get(a))
            for a in fp.axis_names}
    verdict = "PASS" if all(r["verdict"] == "PASS" for r in axes.values()) else "FAIL"
    # a dead axis's curve is no calibration: no firmware file claims one
    header = None if dead else c_header(fp, dev, axes, verdict)
    return {"device_id": dev, "verdict": verdict, "axes": axes, "temperature_span_c": span,
            "test_kind": kind, "short_test_map": "used" if windows else
            (f"not used: {not_map}" if not_map else None),
            "runs": len(ds), "run_sources": run_sources(ds),
            "firmware_header": "thermonet_cal.h" if header is not None else
            "not written: " + "; ".join(dead.values()), "header": header}


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
                        "compensated = raw - drift(T); drift in the axis's unit ("
                        + ", ".join(f"{a} {fp.units.get(a, '?')}" for a in axes)
                        + f"), T in degC, valid {fp.range_c[0]:g} to {fp.range_c[1]:g} degC"])
             + " */",
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
    prior_file: str = ""        # the prior's file, named in a refusal


def parse_station_limits(cfg: CompareConfig) -> dict[str, StationLimit]:
    where = getattr(cfg, "_source", "config")
    out = {}
    for axis, spec in (cfg.station.limits or {}).items():
        out[str(axis)] = from_dict(StationLimit, spec, source=where,
                                   prefix=f"station.limits.{axis}")
    return out


def _station_checks(cfg: CompareConfig, prior: FleetPrior, prior_file: str = ""
                    ) -> dict[str, StationLimit]:
    """The config against the prior, before any unit runs (one line naming the key and both
    values): the limits' axes, the degree and t_ref; returns the limits."""
    where, of = getattr(cfg, "_source", "config"), prior_file or prior.source or "its file"
    check_station_config(cfg)
    limits = parse_station_limits(cfg)
    unknown = [a for a in limits if a != "*" and a not in prior.axis_names]
    if unknown:
        raise ConfigError(f"{where}: key 'station.limits.{unknown[0]}': not an axis of the "
                          f"prior ({', '.join(prior.axis_names)})")
    if cfg.station.degree != prior.degree:
        raise ConfigError(f"{where}: key 'station.degree': {cfg.station.degree}, and the prior "
                          f"({of}) is of degree {prior.degree}: build the prior with the "
                          "station's degree")
    spec = cfg.target if isinstance(cfg.target, Mapping) else {}
    for a in prior.axis_names:     # a mode the config names (the default rests on the data)
        key = a if a in spec else output_kind(a)
        if key in spec and spec[key] != prior.targets[a]:
            raise ConfigError(f"{where}: key 'target.{key}': '{spec[key]}', and the prior "
                              f"({of}) is of target '{prior.targets[a]}' on {a}: build the "
                              "prior with the station's targets, or set this one to the prior's")
    t_ref = config_t_ref(cfg)
    if t_ref is not None and t_ref != prior.t_ref:
        raise ConfigError(f"{where}: key 'features.t_ref': {t_ref:g} °C, and the prior ({of}) "
                          f"is of t_ref {prior.t_ref:g} °C (its curves, and an at-t-ref axis's "
                          "zero, are there): build the prior with the station's t_ref, or "
                          "set this one to the prior's")
    return limits


def run_station(cfg: CompareConfig, prior: FleetPrior, sources: list[UnitSource], out: Path,
                *, overwrite: bool = False, opts: StationOptions | None = None,
                say: Any = print) -> dict[str, Any]:
    """Calibrate every unit of ``sources`` with ``prior``; write ``out`` (module docstring)."""
    opts = opts or StationOptions()
    limits = _station_checks(cfg, prior, opts.prior_file)
    check_config_channels(cfg, prior, sources, opts.prior_file or prior.source or "its file")
    _check_units_data(sources)
    check_target(out, overwrite, "station")
    stage = make_stage(out)     # before any unit runs: an --out that cannot be made, named
    try:
        t0 = time.perf_counter()
        units = _run_units(cfg, prior, sources, limits, stage, opts, say)
        results = station_summary(prior, units, time.perf_counter() - t0, opts.prior_file)
        atomic_write_text(stage / "results.json", json.dumps(results, indent=2))
        install(stage, out, overwrite, "station")
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return results


def _check_units_data(sources: list[UnitSource]) -> None:
    """The units' data read before any unit runs (a simulated unit is its own): one test
    filed twice under a unit, one unit's data under two serial numbers — each refused in
    one line naming both (:mod:`thermonet.workflows.station_checks`)."""
    read = [(s.device_id, s.dataset) for s in sources
            if s.dataset is not None and s.error is None]
    for dev, ds in read:
        identical_runs(dev, ds)
    identical_units(read)


def _run_units(cfg: CompareConfig, prior: FleetPrior, sources: list[UnitSource],
               limits: dict[str, StationLimit], stage: Path, opts: StationOptions,
               say: Any) -> dict[str, dict[str, Any]]:
    """Every unit on the executor; each unit's files written into ``stage`` as it finishes
    and only its summary kept (the driver's memory does not grow with the units' detail).  A
    unit whose data failed a check is a FAIL result (:func:`station_task`); a task that
    raised anything else (a bug) or whose worker died stops the batch, naming the units."""
    dirs = path_components([s.device_id for s in sources])
    items = [StationItem(cfg, prior, s, limits) for s in sources]
    done = [0]

    def finished(i: int, r: Any) -> None:
        done[0] += 1
        if not isinstance(r, TaskFailure):
            rel = ("units", dirs[r["device_id"]])
            udir = inside(stage, *rel)
            udir.mkdir(parents=True)
            header = r.pop("header")
            if header is not None:
                atomic_write_text(udir / "thermonet_cal.h", header)
            atomic_write_text(udir / "calibration.json", json.dumps(r, indent=2))
            summary = unit_summary(r, "/".join(rel))
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
