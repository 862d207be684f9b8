"""``thermonet prior``: a fleet's calibrated units into a fleet prior, and what it prints.

:func:`build_prior` fits every calibrated unit on its 1 °C-binned means
(:func:`unit_points`), leaves out the units whose curve is a robust outlier, their spread
never taken below a point's own error (:func:`_outlier_units`: a line does not build its
prior on faulty units)
and writes the population (:mod:`thermonet.scoring.prior`); :func:`prior_summary` and
:func:`format_prior` say how many points of a short test reach each expected error, and the
3-soak plan (:func:`~thermonet.scoring.prior_design.soak_plan`).  The station itself is
:mod:`thermonet.workflows.station`.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np

from ..core.errors import ConfigError, InputError, counted
from ..core.recording import Dataset, Recording, split_units
from ..features.target import FOUR_POSITION, output_units
from ..scoring.fleetstats import (
    MAD_TO_SIGMA,
    MIN_UNITS_FOR_OUTLIERS,
    ROBUST_Z_THRESHOLD,
    merged_limits,
    spread,
)
from ..scoring.prior import (
    FLAG_P,
    MIN_UNITS,
    AxisPrior,
    FleetPrior,
    StationLimit,
    fit_population,
    fit_unit,
    shape_p_values,
)
from ..scoring.prior_design import (
    design_errors,
    first_below,
    has_curve,
    plan_errors,
    point_error,
    typical_drift,
)
from ..scoring.prior_map import MIN_MAP_UNITS, TestMap, fit_test_map, map_window_s, window_means
from ..scoring.prior_points import (
    BIN_C,
    Points,
    bin_points,
    kind_of_test,
    motion_counts,
    shape_design,
)
from ..training.config import CompareConfig, outputs_of
from ..training.parts import build_part, targets_for

__all__ = ["build_prior", "prior_summary", "format_prior", "unit_points", "unit_test_kind",
           "unit_windows",
           "check_compatible", "axes_mismatch", "config_t_ref",
           "TARGET_FRACTIONS", "PLAN_SOAKS", "PLAN_STEP_C"]

#: The expected error :func:`points_needed` is asked for, as a fraction of the fleet's
#: median raw drift over the range (reported in the prior).
TARGET_FRACTIONS = (0.2, 0.1, 0.05)
#: Soaks in the one test for every axis the prior plans, and its candidates' spacing (°C).
PLAN_SOAKS = 3
PLAN_STEP_C = 2.5
#: Units named in the line that says which units were left out (the rest counted).
SHOWN_LEFT_OUT = 5


def config_t_ref(cfg: CompareConfig) -> float | None:
    """The config's ``features.t_ref`` in °C, None when it names none (``start``)."""
    t = cfg.features.t_ref
    return None if isinstance(t, str) else float(t)


def _t_ref(cfg: CompareConfig) -> float:
    t = config_t_ref(cfg)
    return 25.0 if t is None else t


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


def unit_test_kind(ds: Dataset) -> str:
    """What a unit's test is over its runs (:func:`~thermonet.scoring.prior_points.
    kind_of_test`): soaks, heating or cooling ramps, cycles, or fast ramps."""
    counts = sum((motion_counts(np.asarray(r.temperature_c, dtype=np.float64), r.time_s)
                  for r in ds if r.temperature_c is not None), np.zeros(4, dtype=np.int64))
    return kind_of_test(counts)


def axes_mismatch(fp: FleetPrior, axes: list[str], prior_name: str = "") -> str | None:
    """Why a unit of outputs ``axes`` cannot take the prior ``fp`` (their axes not the same
    both ways), naming the prior's file where ``prior_name`` is given; None where they are."""
    head = f"the prior{f' ({prior_name})' if prior_name else ''} is of axes " \
        f"{', '.join(fp.axis_names)}; the data"
    missing = [a for a in fp.axis_names if a not in axes]
    if missing:
        return f"{head} lack {', '.join(missing)} (a prior of another sensor kind?)"
    extra = [a for a in axes if a not in fp.axis_names]
    if extra:
        return (f"{head} also hold {', '.join(extra)}, which it says nothing about (a prior of "
                "another sensor kind? data.outputs selects the prior's axes)")
    return None


def check_compatible(fp: FleetPrior, axes: list[str], targets: dict[str, str],
                     where: str, units: dict[str, str] | None = None) -> None:
    """Refuse a unit whose axes, targets or units of measure are not the prior's (one line
    naming both; an :class:`InputError`: the unit's own data, which FAILs that unit — what
    the config fixes for every unit is checked before any runs,
    :func:`~thermonet.workflows.station_checks.check_config_channels`).  The axes must be
    the same both ways: an axis the prior lacks would be dropped from the unit's files
    without a word (a prior of another sensor kind); a unit calibrated on some of its axes
    selects them with ``data.outputs``."""
    why = axes_mismatch(fp, axes)
    if why is not None:
        raise InputError(f"{where}: {why}")
    other = [a for a in fp.axis_names if targets.get(a) != fp.targets[a]]
    if other:
        a = other[0]
        raise InputError(f"{where}: axis {a}: target '{targets.get(a)}' is not the prior's "
                         f"'{fp.targets[a]}'")
    other = [a for a in fp.axis_names if units is not None and units.get(a) != fp.units[a]]
    if other:
        a = other[0]
        raise InputError(f"{where}: axis {a} is in '{units.get(a) if units else ''}', the "
                         f"prior's in '{fp.units[a]}' (convert one of them first)")


def _range(spans: list[tuple[float, float]]) -> tuple[float, float]:
    """The range most units cover: the medians of their lows and highs, in whole °C."""
    lo = float(np.floor(np.median([s[0] for s in spans])))
    hi = float(np.ceil(np.median([s[1] for s in spans])))
    return lo, hi


def _point_errors(fits: dict[str, dict[str, Any]], pts: dict[str, dict[str, Points]]
                  ) -> dict[str, float]:
    """Per axis a point's own error over the fleet: √(median misfit variance + median
    sampling variance), what :func:`prior_summary` reports as ``point_error``."""
    axes = {a for f in fits.values() for a in f}
    return {a: math.sqrt(float(np.median([f[a].misfit_var for f in fits.values()])) +
                         float(np.median([np.median(pts[d][a].sampling_var) for d in fits])))
            for a in axes}


def _outlier_units(fits: dict[str, dict[str, Any]], floors: dict[str, float], t_ref: float,
                   scale: float, range_c: tuple[float, float], degree: int,
                   uom: dict[str, str] | None = None) -> dict[str, str]:
    """Units whose curve at five temperatures is a robust outlier on some axis: off the
    units' median by more than :data:`~thermonet.scoring.fleetstats.ROBUST_Z_THRESHOLD`
    times their spread (1.4826 × MAD, as fleets flag), the spread never taken below a
    point's own error on that axis (``floors``).  A point's error is the resolution of
    every test: units closer than it are alike in all a station measures.  On an axis whose
    drift is below it (no curve to learn) the units' curves are their estimation errors
    alone, made heavier-tailed than the MAD assumes by a correlated misfit (a bias that
    wanders, hysteresis), and the MAD of a few units is small: clean units were left out
    for differences under one point's error, narrowing the prior.  A unit with a curve
    where the fleet has none is still left out."""
    temps = np.linspace(range_c[0], range_c[1], 5)
    X = shape_design(temps, t_ref, scale, degree)
    quantities: dict[str, dict[str, float]] = {}
    for dev, axes in fits.items():
        for axis, fit in axes.items():
            for t, v in zip(temps, X @ fit.shape, strict=True):
                quantities.setdefault(f"{axis}@{t:g}C", {})[dev] = float(v)
    found: dict[str, tuple[float, str]] = {}
    for q, values in quantities.items():
        s = spread(values)
        floor = floors[q.split("@")[0]]
        if s["n"] < MIN_UNITS_FOR_OUTLIERS:
            continue
        sd = max(MAD_TO_SIGMA * s["mad"], floor)
        for dev, v in values.items():
            z = (v - s["median"]) / sd if sd > 0 else 0.0
            if abs(z) > ROBUST_Z_THRESHOLD and abs(z) > abs(found.get(dev, (0.0, ""))[0]):
                axis, _, at = q.partition("@")
                u = f" {(uom or {}).get(axis, '')}".rstrip()
                found[dev] = (z, f"robust outlier: {axis} at {at[:-1]} °C z={z:.1f}, "
                                 f"{v - s['median']:+.3g}{u} off the units' median (their "
                                 f"spread {sd:.3g}{u}, a point's own error {floor:.3g}{u})")
    return {dev: found[dev][1] for dev in sorted(found)}


def _left_out_line(excluded: dict[str, str]) -> str:
    """Which units were left out and why, in one line (the first few named)."""
    shown = [f"'{d}': {why}" for d, why in list(excluded.items())[:SHOWN_LEFT_OUT]]
    more = len(excluded) - len(shown)
    return "; ".join(shown) + (f"; and {more} more" if more > 0 else "")


def build_prior(cfg: CompareConfig, ds: Dataset, *, source: str = "",
                short: Dataset | None = None) -> FleetPrior:
    """The fleet prior of ``ds``'s units (see the module docstring); with ``short``, the
    same units' short tests (one run each), the map of that test
    (:mod:`thermonet.scoring.prior_map`)."""
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
    if fits:
        excluded.update(_outlier_units(fits, _point_errors(fits, pts), t_ref, scale, rng,
                                       degree, meta[next(iter(fits))][1]))
    kept = [d for d in fits if d not in excluded]
    if len(kept) < MIN_UNITS:
        raise InputError(f"{where}: a fleet prior needs at least {MIN_UNITS} calibrated units; "
                         f"{len(kept)} remain after leaving out {len(excluded)}: "
                         + _left_out_line(excluded))
    targets, uom = meta[kept[0]]
    axes = _population(targets, kept, fits, pts)
    # a unit the robust screen left out comes back where its shape is like a cluster of the
    # clean units' mixture on every axis (the station's own flag): the screen reads each
    # quantity as one population, and left out the far cluster's members
    back = [d for d in excluded if d in fits and all(
        shape_p_values(ap, fits[d][ap.axis].shape, fits[d][ap.axis].cov,
                       predictive=False).max() >= FLAG_P
        for ap in axes)]
    if back:
        kept = [d for d in fits if d not in excluded or d in back]
        excluded = {d: why for d, why in excluded.items() if d not in back}
        axes = _population(targets, kept, fits, pts)
    kinds = Counter(unit_test_kind(units[d]) for d in kept)
    test_map = None if short is None else _fit_map(cfg, short, {d: fits[d] for d in kept},
                                                  list(targets), uom, where)
    return FleetPrior(axes, degree, t_ref, scale, rng, uom, targets, len(kept), kept,
                      excluded, source, BIN_C, dict(kinds.most_common()), test_map)


def unit_windows(cfg: CompareConfig, run: Recording, axes: list[str], window_s: float,
                 n: int) -> tuple[np.ndarray, np.ndarray]:
    """A short test's window means (``(n, axes)``: each axis's target) and window
    temperatures (``(n,)``) from its first sample (:func:`~thermonet.scoring.prior_map.
    window_means`)."""
    target = targets_for(Dataset(runs=[run]), cfg.target, axes)
    part = build_part(run, signals=["temperature_c"], outputs=axes, target=target)
    temp = np.asarray(run.temperature_c, dtype=np.float64)
    got = window_means(np.asarray(run.time_s, dtype=np.float64),
                       np.column_stack([part.target, temp]), window_s, n)
    return got[:, :-1], got[:, -1]


def _fit_map(cfg: CompareConfig, short: Dataset, fits: dict[str, dict[str, Any]],
             axes: list[str], uom: dict[str, str], where: str) -> TestMap:
    """The fleet's short test (:mod:`thermonet.scoring.prior_map`) from the kept units'
    fits and their short tests (one run each, matched by device id)."""
    tests = split_units(short)
    pilots = [d for d in fits if d in tests]
    if len(pilots) < MIN_MAP_UNITS:
        raise InputError(f"{where}: the short tests hold {counted(len(pilots), 'unit')} of the "
                         f"prior's {len(fits)} (by device id; theirs: "
                         f"{', '.join(list(tests)[:3])}{', …' if len(tests) > 3 else ''}); a "
                         f"map of the test needs {MIN_MAP_UNITS}")
    several = [d for d in pilots if len(tests[d].runs) != 1]
    if several:
        raise InputError(f"{where}: unit '{several[0]}': its short test holds "
                         f"{len(tests[several[0]].runs)} runs; give each unit's test as one run")
    runs = [tests[d].runs[0] for d in pilots]
    for d, r in zip(pilots, runs, strict=True):
        its = output_units(axes, r.units)
        other = [a for a in axes if its.get(a) != uom.get(a)]
        if other:
            raise InputError(f"{where}: unit '{d}': its short test's {other[0]} is in "
                             f"'{its.get(other[0])}', its calibration's in "
                             f"'{uom.get(other[0])}' (convert one of them first)")
    durations = [float(np.ptp(np.asarray(r.time_s, dtype=np.float64))) for r in runs]
    window_s = map_window_s(float(np.median(durations)))
    n = int(np.median(durations) // window_s)
    got = [unit_windows(cfg, r, axes, window_s, n) for r in runs]
    shapes = {a: np.array([fits[d][a].shape for d in pilots]) for a in axes}
    try:
        return fit_test_map(shapes, np.stack([g[0] for g in got]),
                            np.stack([g[1] for g in got]), window_s, axes)
    except InputError as err:
        raise InputError(f"{where}: the short tests: {err}") from None


def _population(targets: dict[str, str], kept: list[str], fits: dict[str, dict[str, Any]],
                pts: dict[str, dict[str, Points]]) -> list[AxisPrior]:
    """Per axis the mixture over the kept units' shapes, their misfit and sampling variance."""
    axes: list[AxisPrior] = []
    for a in targets:
        w, means, covs = fit_population(np.array([fits[d][a].shape for d in kept]))
        axes.append(AxisPrior(a, w, means, covs,
                              float(np.median([fits[d][a].misfit_var for d in kept])),
                              float(np.median([np.median(pts[d][a].sampling_var)
                                               for d in kept])), len(kept)))
    return axes


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
                        "point_error": point_error(ap),
                        "points_needed": rows, "expected_error_after_2_to_12": errs}
    return out


def _points_text(row: dict[str, Any]) -> str:
    return f"{row['points']} points ({', '.join(f'{t:g}' for t in row['temperatures_c'])} °C)"


def _plan_line(fp: FleetPrior, summary: dict[str, Any], plan: list[float]) -> str:
    """The soak plan's line; a plan shorter than :data:`PLAN_SOAKS` says why."""
    head = (f"  a {len(plan)}-soak test for every axis: {', '.join(f'{t:g}' for t in plan)} "
            "°C, in that order")
    if len(plan) >= PLAN_SOAKS:
        errs = plan_errors(fp, plan, step_c=PLAN_STEP_C)
        return head + (" (the range's ends, and the interior temperature the prior tells most "
                       "by" + (f": expected error {100 * errs[0]:.2g} → {100 * errs[1]:.2g} % "
                               "of the drift, RMS over the axes)" if errs else ")"))
    if not any(has_curve(fp, axis) for axis in summary):
        why = ("no axis has a curve to learn (each one's drift is below a point's own error): "
               "the range's ends fix the offsets")
    else:
        why = (f"the range {fp.range_c[0]:g} to {fp.range_c[1]:g} °C holds no other "
               f"temperature {PLAN_STEP_C:g} °C from its ends")
    return head + f" (not {PLAN_SOAKS}: {why})"


def format_prior(fp: FleetPrior, summary: dict[str, Any], plan: list[float] | None = None
                 ) -> str:
    """What ``thermonet prior`` prints: the prior, a three-soak test for every axis
    (``plan``: :func:`~thermonet.scoring.prior_design.soak_plan`), then per axis its clusters
    and the points a test needs (:func:`prior_summary`)."""
    lines = [f"prior of {fp.n_units} units ({len(fp.excluded)} left out), axes "
             f"{', '.join(fp.axis_names)}, {fp.range_c[0]:g} to {fp.range_c[1]:g} °C"
             + (f"; their tests: {fp.kinds_text()}" if fp.test_kinds else "")]
    if fp.excluded:
        lines.append(f"  left out: {_left_out_line(fp.excluded)}")
    if (tm := fp.test_map) is not None:
        lines.append(f"  its short test, learned from {counted(tm.n_units, 'unit')} that ran it "
                     f"beside their calibration: {tm.n_windows * tm.window_s / 60.0:.3g} min "
                     f"({tm.trace_c.min():.0f} to {tm.trace_c.max():.0f} °C); a new unit that "
                     "runs it is calibrated through it")
    if plan:
        lines.append(_plan_line(fp, summary, plan))
        if why := fp.not_comparable("soaks"):    # a prior of fast ramps: said with the plan
            lines.append(f"  note: a soak test is not compared with this fleet ({why}); its "
                         "calibration and held-out check stand")
    for axis, s in summary.items():
        head = f"  {axis}: {counted(s['clusters'], 'cluster')}; "
        uom = fp.units.get(axis, "")
        if not has_curve(fp, axis):
            lines.append(head + f"its drift ({s['typical_drift_rms']:.3g} {uom} RMS over the "
                         f"range) is below a point's own error ({s['point_error']:.3g} {uom}): a "
                         "test fixes its offset, there is no curve to learn")
            continue
        need = s["points_needed"][0]
        lines.append(head + (_points_text(need) if need["points"] else "more than 12 points") +
                     f" for an expected error of 20 % of the fleet's drift "
                     f"({need['target']:.3g} {uom})")
        for row in s["points_needed"][len(TARGET_FRACTIONS):]:
            lines.append(f"    station.limits max_residual {row['target']:.3g} {uom}: " + (
                _points_text(row) if row["points"] else "not reachable within 12 points (the "
                "fleet's misfit alone is about that large)"))
    return "\n".join(lines)
