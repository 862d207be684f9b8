"""The fleet prior: a new unit from a short test against its full-sweep calibration.

A structured fleet of the consumer IMU (``simulate_fleet(..., clusters=3)``: three clusters
of drift shapes, correlated coefficients).  Each unit has two runs: its **full sweep** (a
staircase of 11 soaks of 20 min, −20 … 75 °C, 3.7 h: the production calibration the prior
is built from) and a **climate cycle** 50 → −20 → 75 → 35 °C at 1 °C/min (5.4 h, hysteresis
and lag included: how the unit is used), never fitted.  Leave units out (5 groups, unit *i*
in group *i* mod 5): the prior is built from the other groups' full sweeps; each held-out
unit is calibrated

- **full**: its own cubic on its full sweep (no prior) — the reference;
- **3 soaks + prior**: a short test of three 20-min soaks and the prior, at −15, 25, 65 °C
  and at −20, 25, 75 °C (the range's ends and t_ref);
- **3 soaks at the prior's plan + prior**: the three temperatures ``soak_plan`` chooses from
  the fold's prior (the range's ends, and the middle that lowers most the expected error of
  every axis, by simulation under the mixture), soaked in rising order; and **at the free
  plan** (``soak_plan(..., ends=False)``: all three by the expected error, the plan before);
- **3 soaks alone**: the first test's points without the prior (its own cubic);
- **ramp + prior**: 10 minutes of ramp at 1 °C/min (20 → 30 °C) and the prior;
- **up-and-down ramp + prior**: 10 minutes of chamber cycle −20 → 75 → −20 °C (5 min each
  way; the thermometer, lagging, sees about −20 → 55 → 12 °C), its fast samples paired
  heating with cooling where the ramp is steady
  (:func:`thermonet.scoring.prior_points.bin_points`), and the prior; and the same cycle in
  40 min (20 min each way, 4.75 °C/min), long enough for the thermometer's rate to settle;

- **through the fleet's test**: the prior's units ran the short test too (the 3 soaks, the
  10-min ramp, the 10-min up-and-down) beside their sweep, and the prior learns how that
  test reads a unit's drift curve (:mod:`thermonet.scoring.prior_map`: regression
  calibration); each held-out unit is calibrated through that map from its own run of it;

and every calibration is judged on the unit's climate cycle: the RMS of its 1 °C-binned
compensated error, offset-free.  Reported per axis: the median over
units of (short / full) and its 90th percentile, worst axis first.

Outliers: a second fleet of the same draw with its last units 10 σ off
(:func:`thermonet.sim.fleet.outlier_config`); the prior from its normal units, the station's
"unlike its fleet" flag (any axis) on new units' 3-soak tests, their climate cycle (a long
test: hundreds of points, judged on the unit's own shape) and their 40-min up-and-down, the
prior built from the units' full sweeps or from their climate cycles, and the 3 soaks and
the 10-min up-and-down through the fleet's map of them (the prior from the units' sweeps and
those tests): the share of units
the prior can compare (a moving test against a prior of soaks is not compared), recall on
the outliers, false flags on the normal ones, and both as if every unit were compared.

Station: ``thermonet station --units N`` (each worker simulates its own unit's 3-soak test),
process pool of 2, in a fresh process per size: wall time, units/min, and the peak RSS of the
driver and of the largest worker, for two sizes (memory bounded per unit: the same for both).

Usage: ``python experiments/bench_prior.py [--units 50,100] [--new-outliers 20]
[--station-units 100,400]``.  Writes ``experiments/out/bench_prior.{md,json}``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import git_rev, save, table  # noqa: E402
from thermonet.core.recording import Dataset, split_units  # noqa: E402
from thermonet.scoring.prior import fit_unit, posterior, posterior_from_stats  # noqa: E402
from thermonet.scoring.prior_design import soak_plan  # noqa: E402
from thermonet.scoring.prior_points import shape_design  # noqa: E402
from thermonet.sim import simulate_fleet  # noqa: E402
from thermonet.sim.fleet import short_test  # noqa: E402
from thermonet.sim.presets import get_preset  # noqa: E402
from thermonet.training.config import config_from_mapping  # noqa: E402
from thermonet.workflows.station import build_prior, map_windows, unit_points  # noqa: E402
from thermonet.workflows.station_prior import unit_test_kind  # noqa: E402

PRESET, SEED, CLUSTERS, FOLDS = "consumer-imu", 5, 3, 5
SOAKS, SOAKS_ENDS, RAMP = "soaks:-15,25,65", "soaks:-20,25,75", "ramp:20,30,10"
#: up and down, 5 min each way (the chamber at 19 °C/min), and 20 min each way (4.75 °C/min)
CYCLE, CYCLE_LONG = "cycle:-20,75,10", "cycle:-20,75,40"
FULL = "soaks:-20,-10,0,10,20,30,40,50,60,70,75"
CFG = config_from_mapping({"data": {"preset": PRESET},
                           "target": {"gyro": "zero", "acc": "at-t-ref"},
                           "features": {"t_ref": 25.0}}, source="bench")


def _binned_rms(temp: np.ndarray, err: np.ndarray) -> float:
    """RMS of the 1 °C-binned error about its mean (offset-free)."""
    idx = np.floor(temp + 0.5).astype(int)
    _, inv, n = np.unique(idx, return_inverse=True, return_counts=True)
    m = np.bincount(inv, err) / n
    return float(np.sqrt(np.mean((m - m.mean()) ** 2)))


def _judge(fp: Any, shape: np.ndarray, run: Any, axis: str, j: int) -> float:
    from thermonet.training.parts import build_part, targets_for

    ds = Dataset(runs=[run])
    tg = targets_for(ds, CFG.target, list(fp.axis_names))
    part = build_part(run, signals=["temperature_c"], outputs=list(fp.axis_names), target=tg)
    t = np.asarray(run.temperature_c, dtype=np.float64)
    f = shape_design(t, fp.t_ref, fp.scale, fp.degree) @ shape
    return _binned_rms(t, part.target[:, j] - f)


def _own(fp: Any, pts: Any) -> np.ndarray | None:
    try:
        return fit_unit(pts, t_ref=fp.t_ref, scale=fp.scale, degree=fp.degree).shape
    except Exception:          # too few points for a cubic alone
        return None


def _through_map(fp: Any, run: Any) -> dict[str, Any]:
    """Each axis's posterior of a unit's short test through the fleet's map of it
    (:func:`thermonet.workflows.station.map_windows`, as the station reads it); the test must
    be the map's."""
    windows, why = map_windows(CFG, fp, Dataset(runs=[run]))
    if why is not None:
        raise SystemExit(f"bench_prior: a unit's test is not the map's: {why}")
    tm = fp.test_map
    return {a: posterior_from_stats(fp.axis(a), *tm.stats(a, f)) for a, f in windows.items()}


#: the short tests the fleet's map is learned for (the prior's units ran each beside their
#: sweep): column name -> test
MAPPED = {"3 soaks through the fleet's test": SOAKS, "10-min ramp through the fleet's test": RAMP,
          "10-min up-and-down through the fleet's test": CYCLE}


PLANS: dict[str, list[str]] = {}   # the prior's 3-soak plans per fold: '<units> <plan>'


def _fleet(n_units: int, seed: int, **kw: Any) -> Dataset:
    """Units with their full sweep (run0) and a climate cycle (run1)."""
    cycle = get_preset(PRESET).procedures[0]
    return simulate_fleet(PRESET, units=n_units, runs=2, seed=seed, clusters=CLUSTERS,
                          procedures=(short_test(FULL), cycle), **kw)


def _sweeps(ds: Dataset) -> Dataset:
    return Dataset(runs=[r for r in ds if r.run_id == "run0"])


def leave_units_out(n_units: int) -> dict[str, Any]:
    units = split_units(_fleet(n_units, SEED))
    ids = list(units)
    short = {k: split_units(simulate_fleet(PRESET, units=n_units, seed=SEED, clusters=CLUSTERS,
                                           test=k, unit_indices=list(range(n_units))))
             for k in (SOAKS, SOAKS_ENDS, RAMP, CYCLE, CYCLE_LONG)}
    ratios: dict[str, dict[str, list[float]]] = {}
    for g in range(FOLDS):
        held = [d for i, d in enumerate(ids) if i % FOLDS == g]
        train = _sweeps(Dataset(runs=[r for d in ids if d not in held for r in units[d]]))
        fp = build_prior(CFG, train, source="bench")
        mapped = {name: build_prior(CFG, train, source="bench", short=Dataset(
                      runs=[r for d in ids if d not in held for r in short[key][d]]))
                  for name, key in MAPPED.items()}
        for key, ends in (("plan", True), ("free plan", False)):
            plan = "soaks:" + ",".join(f"{t:g}" for t in soak_plan(fp, 3, ends=ends))
            PLANS.setdefault(f"{n_units} {key}", []).append(plan)
            short[key] = split_units(simulate_fleet(
                PRESET, units=n_units, seed=SEED, clusters=CLUSTERS, test=plan,
                unit_indices=[ids.index(d) for d in held]))
        for d in held:
            cal, test = units[d].runs
            cal_pts, _, _, _ = unit_points(CFG, Dataset(runs=[cal]), d)
            through = {name: _through_map(fpm, short[MAPPED[name]][d].runs[0])
                       for name, fpm in mapped.items()}
            for j, a in enumerate(fp.axis_names):
                full = _own(fp, cal_pts[a])
                e_full = _judge(fp, full, test, a, j)
                row = ratios.setdefault(a, {})
                for name, key, use_prior in (("3 soaks + prior", SOAKS, True),
                                             ("3 soaks at the ends + prior", SOAKS_ENDS, True),
                                             ("3 soaks at the plan + prior", "plan", True),
                                             ("3 soaks at the free plan + prior", "free plan",
                                              True),
                                             ("3 soaks alone", SOAKS, False),
                                             ("ramp + prior", RAMP, True),
                                             ("up-and-down ramp + prior", CYCLE, True),
                                             ("40-min up-and-down + prior", CYCLE_LONG,
                                              True)):
                    pts, _, _, _ = unit_points(CFG, short[key][d], d)
                    shape = posterior(fp.axis(a), pts[a], t_ref=fp.t_ref,
                                      scale=fp.scale).shape if use_prior else _own(fp, pts[a])
                    e = _judge(fp, shape, test, a, j) if shape is not None else np.inf
                    row.setdefault(name, []).append(e / e_full if e_full > 0 else np.nan)
                for name, posts in through.items():
                    e = _judge(fp, posts[a].shape, test, a, j)
                    row.setdefault(name, []).append(e / e_full if e_full > 0 else np.nan)
                row.setdefault("full (error)", []).append(e_full)
    return {a: {k: {"median": float(np.nanmedian(v)), "p90": float(np.nanpercentile(v, 90))}
                for k, v in r.items()} for a, r in ratios.items()}


def outliers(n_units: int, n_new: int, n_out: int, test: str | None = SOAKS,
             prior_from: str = "run0", mapped: bool = False) -> dict[str, Any]:
    """The flag "unlike its fleet" on new units' ``test`` (None: the preset's own climate
    cycle, 5.4 h, hundreds of points: the shape test), the prior from the units' full sweeps
    (``run0``), their climate cycles (``run1``) or a short test of theirs (its name).  A unit whose test the prior cannot judge
    (:meth:`~thermonet.scoring.prior.FleetPrior.not_comparable`) is not compared; the flag
    it would have raised is counted apart (``*_if_compared``)."""
    total = n_units + n_new
    if prior_from.startswith("run"):
        fleet = _fleet(total, SEED + 1, outliers=n_out, unit_indices=list(range(n_units)))
        fleet = Dataset(runs=[r for r in fleet if r.run_id == prior_from])
    else:      # the units' short test of that name
        fleet = simulate_fleet(PRESET, units=total, seed=SEED + 1, clusters=CLUSTERS,
                               outliers=n_out, test=prior_from,
                               unit_indices=list(range(n_units)))
    fp = build_prior(CFG, fleet, source="bench", short=simulate_fleet(
        PRESET, units=total, seed=SEED + 1, clusters=CLUSTERS, outliers=n_out, test=test,
        unit_indices=list(range(n_units))) if mapped else None)
    new = split_units(simulate_fleet(PRESET, units=total, seed=SEED + 1, clusters=CLUSTERS,
                                     outliers=n_out, test=test,
                                     unit_indices=list(range(n_units, total))))
    flagged, compared = {}, {}
    for d, uds in new.items():
        pts, _, _, _ = unit_points(CFG, uds, d)
        posts = _through_map(fp, uds.runs[0]) if mapped else {
            a: posterior(fp.axis(a), pts[a], t_ref=fp.t_ref, scale=fp.scale)
            for a in fp.axis_names}
        flagged[d] = any(p.flagged for p in posts.values())
        compared[d] = mapped or fp.not_comparable(unit_test_kind(uds)) is None
    out_ids = [d for d, u in new.items() if u.runs[0].meta.get("outlier") == "1"]
    normal = [d for d in new if d not in out_ids]

    def share(ids: list[str], rule: bool) -> float:
        return sum(flagged[d] and (compared[d] or not rule) for d in ids) / max(len(ids), 1)

    return {"new_units": n_new, "outliers": len(out_ids), "prior_tests": fp.test_kinds,
            "compared": sum(compared.values()) / max(len(compared), 1),
            "recall": share(out_ids, True), "false_flags": share(normal, True),
            "recall_if_compared": share(out_ids, False),
            "false_flags_if_compared": share(normal, False),
            "prior_excluded": len(fp.excluded)}


_STATION = r"""
import json, resource, sys, time
from thermonet.cli import main
t0 = time.perf_counter()
rc = main(["station", sys.argv[1], "--prior", sys.argv[2], "--units", sys.argv[3], "--clusters",
           sys.argv[4], "--test", sys.argv[5], "--out", sys.argv[6], "--workers", "2", "-q"])
# the driver's own peak (VmHWM: ru_maxrss would keep the forking parent's from before exec)
hwm = next(int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmHWM"))
kids = resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"rc": rc, "wall_s": time.perf_counter() - t0, "driver_maxrss_mb": hwm / 1024,
                  "worker_maxrss_mb": kids.ru_maxrss / 1024}))
"""


def station(n_units: int, fp: Any, tmp: Path) -> dict[str, Any]:
    """``thermonet station --units N`` in a fresh process (its peak memory its own)."""
    (tmp / "prior.json").write_text(json.dumps(fp.to_dict()))
    (tmp / "cfg.yaml").write_text(f"data: {{preset: {PRESET}, seed: {SEED + 2}}}\n"
                                  "target: {gyro: zero, acc: at-t-ref}\nfeatures: {t_ref: 25.0}\n")
    out = tmp / f"station{n_units}"
    r = subprocess.run([sys.executable, "-c", _STATION, str(tmp / "cfg.yaml"),
                        str(tmp / "prior.json"), str(n_units), str(CLUSTERS), SOAKS, str(out)],
                       capture_output=True, text=True, check=True)
    res = json.loads(r.stdout.strip().splitlines()[-1])
    return {"units": n_units, **res, "units_per_min": 60 * n_units / res["wall_s"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--units", default="50,100")
    ap.add_argument("--new-units", type=int, default=60)
    ap.add_argument("--new-outliers", type=int, default=20)
    ap.add_argument("--station-units", default="100,400")
    a = ap.parse_args()
    data: dict[str, Any] = {"rev": git_rev(), "lou": {}, "station": []}
    md = []
    for n in (int(v) for v in a.units.split(",")):
        t0 = time.perf_counter()
        res = leave_units_out(n)
        data["lou"][n] = res
        rows = sorted(([ax, r["3 soaks + prior"]["median"], r["3 soaks + prior"]["p90"],
                        r["3 soaks at the ends + prior"]["median"],
                        r["3 soaks at the ends + prior"]["p90"],
                        r["3 soaks at the plan + prior"]["median"],
                        r["3 soaks at the plan + prior"]["p90"],
                        r["3 soaks at the free plan + prior"]["median"],
                        r["3 soaks at the free plan + prior"]["p90"],
                        r["3 soaks alone"]["median"], r["ramp + prior"]["median"],
                        r["ramp + prior"]["p90"], r["up-and-down ramp + prior"]["median"],
                        r["up-and-down ramp + prior"]["p90"],
                        r["40-min up-and-down + prior"]["median"],
                        r["40-min up-and-down + prior"]["p90"],
                        *[r[name][q] for name in MAPPED for q in ("median", "p90")],
                        r["full (error)"]["median"]]
                       for ax, r in res.items()), key=lambda row: -row[1])
        data["plans"] = PLANS
        md.append(f"### Leave units out, {n} units ({time.perf_counter() - t0:.0f} s)\n\n"
                  f"the prior's plans: {'; '.join(PLANS.get(f'{n} plan', []))}; "
                  f"free: {'; '.join(PLANS.get(f'{n} free plan', []))}\n\n" +
                  table(["axis", "3 soaks+prior / full (median)", "p90",
                         "3 soaks at the ends+prior / full", "p90",
                         "3 soaks at the prior's plan+prior / full", "p90",
                         "3 soaks at the free plan+prior / full", "p90",
                         "3 soaks alone / full",
                         "10-min ramp+prior / full", "p90",
                         "10-min up-and-down ramp+prior / full", "p90",
                         "40-min up-and-down ramp+prior / full", "p90",
                         *[h for name in MAPPED for h in (f"{name} / full", "p90")],
                         "full: error (median)"], rows))
    n0 = int(a.units.split(",")[0])
    cases = {"3 soaks, prior of sweeps": (SOAKS, "run0"),
             "climate cycle, prior of sweeps": (None, "run0"),
             "40-min up-and-down, prior of sweeps": (CYCLE_LONG, "run0"),
             "3 soaks, prior of climate cycles": (SOAKS, "run1"),
             "climate cycle, prior of climate cycles": (None, "run1"),
             "3 soaks, prior of 40-min up-and-downs": (SOAKS, CYCLE_LONG),
             "climate cycle, prior of 40-min up-and-downs": (None, CYCLE_LONG),
             "40-min up-and-down, prior of 40-min up-and-downs": (CYCLE_LONG, CYCLE_LONG),
             "3 soaks through the fleet's test": (SOAKS, "run0", True),
             "10-min up-and-down through the fleet's test": (CYCLE, "run0", True)}
    data["outliers"] = {k: outliers(n0, a.new_units, a.new_outliers, test=c[0], prior_from=c[1],
                                    mapped=len(c) > 2) for k, c in cases.items()}
    md.append(f"### Outliers\n\nprior of {n0} units; {a.new_units} new units of which "
              f"{a.new_outliers} are 10 σ off\n\n" + table(
                  ["test, prior", "compared", "recall", "false flags",
                   "if compared: recall", "false flags"],
                  [[k, o["compared"], o["recall"], o["false_flags"], o["recall_if_compared"],
                    o["false_flags_if_compared"]] for k, o in data["outliers"].items()]))
    fp = build_prior(CFG, _sweeps(_fleet(n0, SEED)), source="bench")
    with tempfile.TemporaryDirectory() as tmp:
        for n in (int(v) for v in a.station_units.split(",")):
            data["station"].append(station(n, fp, Path(tmp)))
    md.append("### Station (process pool, 2 workers)\n\n" + table(
        ["units", "wall s", "units/min", "driver peak RSS MB", "largest worker peak RSS MB"],
        [[s["units"], s["wall_s"], s["units_per_min"], s["driver_maxrss_mb"],
          s["worker_maxrss_mb"]] for s in data["station"]]))
    save("bench_prior", data, "\n\n".join(md))


if __name__ == "__main__":
    main()
