"""The fleet prior: a new unit from a short test against its full-sweep calibration.

A structured fleet of the consumer IMU (``simulate_fleet(..., clusters=3)``: three clusters
of drift shapes, correlated coefficients; 2 climate cycles a unit, 50 → −20 → 75 → 35 °C).
Leave units out (5 groups, unit *i* in group *i* mod 5): the prior is built from the other
groups' units; each held-out unit is calibrated

- **full**: its own cubic on its first climate cycle (no prior) — the reference;
- **3 soaks + prior**: a short test of three 20-min soaks (−15, 25, 65 °C) and the prior;
- **3 soaks alone**: the same points without the prior (its own cubic: what they say alone);
- **ramp + prior**: 10 minutes of ramp at 1 °C/min (20 → 30 °C) and the prior;

and every calibration is judged on the unit's **second** climate cycle (never fitted): the
RMS of its 1 °C-binned compensated error, offset-free.  Reported per axis: the median over
units of (short / full) and its 90th percentile, worst axis first.

Outliers: a second fleet of the same draw with its last units 10 σ off
(:func:`thermonet.sim.fleet.outlier_config`); the prior from its normal units, the station's
"unlike its fleet" flag (any axis) on new units' 3-soak tests: recall on the outliers, false
flags on the normal ones.

Station: ``run_station`` on ``--station-units`` simulated units (each worker simulates its
own), process pool of 2: wall time, units/min, and the peak RSS of the driver and of the
largest worker, for two sizes (memory bounded per unit: the same for both).

Usage: ``python experiments/bench_prior.py [--units 50,100] [--new-outliers 20]
[--station-units 100,400]``.  Writes ``experiments/out/bench_prior.{md,json}``.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import git_rev, save, table  # noqa: E402
from thermonet.core.recording import Dataset, split_units  # noqa: E402
from thermonet.scoring.prior import fit_unit, posterior, shape_design  # noqa: E402
from thermonet.sim import simulate_fleet  # noqa: E402
from thermonet.training.config import config_from_mapping  # noqa: E402
from thermonet.workflows.fleet_units import sources_from_simulation  # noqa: E402
from thermonet.workflows.station import build_prior, run_station, unit_points  # noqa: E402

PRESET, SEED, CLUSTERS, FOLDS = "consumer-imu", 5, 3, 5
SOAKS, RAMP = "soaks:-15,25,65", "ramp:20,30,10"
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


def leave_units_out(n_units: int) -> dict[str, Any]:
    fleet = simulate_fleet(PRESET, units=n_units, runs=2, seed=SEED, clusters=CLUSTERS)
    units = split_units(fleet)
    ids = list(units)
    short = {k: split_units(simulate_fleet(PRESET, units=n_units, seed=SEED, clusters=CLUSTERS,
                                           test=k, unit_indices=list(range(n_units))))
             for k in (SOAKS, RAMP)}
    ratios: dict[str, dict[str, list[float]]] = {}
    for g in range(FOLDS):
        held = [d for i, d in enumerate(ids) if i % FOLDS == g]
        train = Dataset(runs=[r for d in ids if d not in held for r in units[d]])
        fp = build_prior(CFG, train, source="bench")
        for d in held:
            cal, test = units[d].runs
            cal_pts, _, _, _ = unit_points(CFG, Dataset(runs=[cal]), d)
            for j, a in enumerate(fp.axis_names):
                full = _own(fp, cal_pts[a])
                e_full = _judge(fp, full, test, a, j)
                row = ratios.setdefault(a, {})
                for name, key, use_prior in (("3 soaks + prior", SOAKS, True),
                                             ("3 soaks alone", SOAKS, False),
                                             ("ramp + prior", RAMP, True)):
                    pts, _, _, _ = unit_points(CFG, short[key][d], d)
                    shape = posterior(fp.axis(a), pts[a], t_ref=fp.t_ref,
                                      scale=fp.scale).shape if use_prior else _own(fp, pts[a])
                    e = _judge(fp, shape, test, a, j) if shape is not None else np.inf
                    row.setdefault(name, []).append(e / e_full if e_full > 0 else np.nan)
                row.setdefault("full (error)", []).append(e_full)
    return {a: {k: {"median": float(np.nanmedian(v)), "p90": float(np.nanpercentile(v, 90))}
                for k, v in r.items()} for a, r in ratios.items()}


def outliers(n_units: int, n_new: int, n_out: int) -> dict[str, Any]:
    total = n_units + n_new
    fleet = simulate_fleet(PRESET, units=total, runs=1, seed=SEED + 1, clusters=CLUSTERS,
                           outliers=n_out, unit_indices=list(range(n_units)))
    fp = build_prior(CFG, fleet, source="bench")
    new = split_units(simulate_fleet(PRESET, units=total, seed=SEED + 1, clusters=CLUSTERS,
                                     outliers=n_out, test=SOAKS,
                                     unit_indices=list(range(n_units, total))))
    flagged = {}
    for d, uds in new.items():
        pts, _, _, _ = unit_points(CFG, uds, d)
        flagged[d] = any(posterior(fp.axis(a), pts[a], t_ref=fp.t_ref, scale=fp.scale).flagged
                         for a in fp.axis_names)
    out_ids = [d for d, u in new.items() if u.runs[0].meta.get("outlier") == "1"]
    normal = [d for d in new if d not in out_ids]
    return {"new_units": n_new, "outliers": len(out_ids),
            "recall": sum(flagged[d] for d in out_ids) / max(len(out_ids), 1),
            "false_flags": sum(flagged[d] for d in normal) / max(len(normal), 1),
            "prior_excluded": len(fp.excluded)}


def station(n_units: int, fp: Any) -> dict[str, Any]:
    src = sources_from_simulation(PRESET, units=n_units, seed=SEED + 2, clusters=CLUSTERS,
                                  test=SOAKS)
    out = Path(tempfile.mkdtemp(prefix="bench-station-")) / "s"
    t0 = time.perf_counter()
    try:
        res = run_station(CFG, fp, src, out, say=lambda *_: None)
    finally:
        shutil.rmtree(out.parent, ignore_errors=True)
    wall = time.perf_counter() - t0
    return {"units": n_units, "wall_s": wall, "units_per_min": 60 * n_units / wall,
            "driver_maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "worker_maxrss_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
            "passed": res["summary"]["passed"]}


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
                        r["3 soaks alone"]["median"], r["ramp + prior"]["median"],
                        r["ramp + prior"]["p90"]] for ax, r in res.items()),
                      key=lambda row: -row[1])
        md.append(f"### Leave units out, {n} units ({time.perf_counter() - t0:.0f} s)\n\n" +
                  table(["axis", "3 soaks+prior / full (median)", "p90", "3 soaks alone / full",
                         "10-min ramp+prior / full (median)", "p90"], rows))
    n0 = int(a.units.split(",")[0])
    data["outliers"] = outliers(n0, a.new_units, a.new_outliers)
    o = data["outliers"]
    md.append(f"### Outliers\n\nprior of {n0} units; {o['new_units']} new units of which "
              f"{o['outliers']} are 10 σ off: recall {o['recall']:.0%}, false flags "
              f"{o['false_flags']:.1%}")
    fp = build_prior(CFG, simulate_fleet(PRESET, units=n0, runs=1, seed=SEED,
                                         clusters=CLUSTERS), source="bench")
    for n in (int(v) for v in a.station_units.split(",")):
        data["station"].append(station(n, fp))
    md.append("### Station (process pool, 2 workers)\n\n" + table(
        ["units", "wall s", "units/min", "driver peak RSS MB", "largest worker peak RSS MB"],
        [[s["units"], s["wall_s"], s["units_per_min"], s["driver_maxrss_mb"],
          s["worker_maxrss_mb"]] for s in data["station"]]))
    save("bench_prior", data, "\n\n".join(md))


if __name__ == "__main__":
    main()
