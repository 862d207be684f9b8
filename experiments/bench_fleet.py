"""Fleet benchmarks: many units in one job against one unit, a process pool and Ray.

A. Study 000's accelerometer (``configs/accel.yaml``: Lorentz, linear, cubic on
   the four-position target): ``thermonet compare`` on one unit against
   ``thermonet fleet --units N`` (process pool, 2 workers), both as a user runs
   them (a fresh process, start-up included).  Goal: 20 units ≤ 4× one unit.
B. A gyro preset (``mems-gyro``, cubic + linear, 3 runs a unit): wall time and
   peak memory of the driver and of the largest worker for growing fleets, on
   the process pool and on a local Ray; the slope is the per-unit cost, from
   which 500 units (and M machines) are extrapolated.

Usage: ``python experiments/bench_fleet.py [--accel-runs R] [--accel-units N]
[--gyro-units 4,8,16] [--repeats K]``.  Writes ``experiments/out/bench_fleet.{md,json}``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import git_rev, save, table  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable

_HARNESS = r"""
import json, resource, sys, time
t0 = time.perf_counter()
from thermonet.training.config import load_config
from thermonet.workflows.fleet import FleetOptions, run_fleet
from thermonet.workflows.fleet_units import sources_from_simulation
cfg = load_config(sys.argv[1])
cfg.tracking.enabled = False
units, runs, ex = int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
workers, out = int(sys.argv[5]), sys.argv[6]
src = sources_from_simulation(cfg.data.preset, units=units, runs=runs, seed=0)
res = run_fleet(cfg, out, src, options=FleetOptions(executor=ex, workers=workers, folds=0),
                quiet=True)
wall = time.perf_counter() - t0
me = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
print(json.dumps({"wall_s": wall, "driver_peak_mib": me, "worker_peak_mib": kids,
                  "failed": res["fleet"]["n_failed"]}))
"""


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _wall(cmd: list[str], cwd: Path) -> float:
    t = time.perf_counter()
    r = subprocess.run(cmd, cwd=cwd, env=_env(), capture_output=True, text=True)
    if r.returncode not in (0, 3):
        raise RuntimeError(f"{' '.join(cmd)} failed: {r.stderr[-2000:]}")
    return time.perf_counter() - t


def bench_accel(runs: int, units: int, repeats: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        cfg = d / "accel.yaml"
        cfg.write_text((ROOT / "configs" / "accel.yaml").read_text()
                       + "\ntracking: {enabled: false}\n")
        text = cfg.read_text().replace("  seed: 0", f"  seed: 0\n  runs: {runs}")
        cfg.write_text(text)
        one, many, ratio = [], [], []
        for k in range(repeats):  # A B A B: the ratio pairs runs taken close in time
            a = _wall([PY, "-m", "thermonet.cli", "compare", str(cfg), "--out",
                       str(d / f"one{k}"), "-q"], d)
            b = _wall([PY, "-m", "thermonet.cli", "fleet", str(cfg), "--out", str(d / f"fleet{k}"),
                       "--units", str(units), "--workers", "2", "-q"], d)
            one.append(a)
            many.append(b)
            ratio.append(b / a)
    return {"runs": runs, "units": units, "one_unit_s": one, "fleet_s": many, "ratio": ratio}


def bench_gyro(sizes: list[int], executor: str, repeats: int) -> list[dict[str, Any]]:
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        cfg = d / "gyro.yaml"
        cfg.write_text("data: {preset: mems-gyro, seed: 0}\ntracking: {enabled: false}\n"
                       "families:\n"
                       "  - {name: cubic, family: poly, inputs: [dT], params: {degree: 3}}\n"
                       "  - {name: linear, family: linear, inputs: [dT]}\n")
        for n in sizes:
            rows = []
            for k in range(repeats):
                r = subprocess.run([PY, "-c", _HARNESS, str(cfg), str(n), "3", executor, "2",
                                    str(d / f"f{n}_{k}")], cwd=d, env=_env(), capture_output=True,
                                   text=True)
                if r.returncode != 0:
                    raise RuntimeError(r.stderr[-2000:])
                rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
            out.append({"units": n, "executor": executor, "runs": rows})
    return out


def _extrapolation(name: str, slope: float, icpt: float) -> str:
    """The per-unit cost (least-squares slope over the fleet sizes, 2 workers) and 500 units
    from it — or why none can be read (a slope within the run-to-run noise)."""
    if not slope > 0:
        return (f"{name}: no per-unit cost can be read (slope {slope:.2f} s/unit: start-up and "
                "run-to-run noise dominate at these sizes).")
    return (f"{name}: {slope:.2f} s/unit (+{icpt:.1f} s start-up); 500 units extrapolated "
            f"{icpt + 500 * slope:.0f} s on this machine, on M machines of c cores "
            f"≈ start-up + 500 · {2 * slope:.2f} s / (M · c).")


def _med(xs: list[float]) -> str:
    if len(xs) == 1:
        return f"{xs[0]:.1f}"
    return f"{statistics.median(xs):.1f} ({min(xs):.1f}–{max(xs):.1f})"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--accel-runs", type=int, default=10)
    ap.add_argument("--accel-units", type=int, default=20)
    ap.add_argument("--gyro-units", default="4,8,16")
    ap.add_argument("--ray-units", default="8,16")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--parts", default="accel,ray,gyro", help="which parts to run")
    args = ap.parse_args()
    parts = set(args.parts.split(","))
    load = os.getloadavg()
    partial = Path(__file__).resolve().parent / "out" / "bench_fleet.partial.json"
    partial.parent.mkdir(parents=True, exist_ok=True)
    done: dict[str, Any] = {}

    def keep(name: str, value: Any) -> Any:  # a long benchmark keeps what it has measured
        done[name] = value
        partial.write_text(json.dumps(done, indent=2))
        return value

    empty: dict[str, Any] = {"runs": 0, "units": 0, "one_unit_s": [0.0], "fleet_s": [0.0],
                             "ratio": [0.0]}
    accel = keep("accel", bench_accel(args.accel_runs, args.accel_units, args.repeats)
                 if "accel" in parts else empty)
    ray = keep("ray", bench_gyro([int(x) for x in args.ray_units.split(",")], "ray",
                                 args.repeats) if "ray" in parts else [])
    sizes = [int(x) for x in args.gyro_units.split(",")]
    gyro = keep("gyro", bench_gyro(sizes, "process", args.repeats) if "gyro" in parts else [])
    load_after = os.getloadavg()

    import numpy as np

    def fit(rows: list[dict[str, Any]]) -> tuple[float, float]:
        if not rows:
            return float("nan"), float("nan")
        n = np.array([r["units"] for r in rows], dtype=float)
        w = np.array([statistics.median(x["wall_s"] for x in r["runs"]) for r in rows])
        slope, icpt = np.polyfit(n, w, 1) if len(n) > 1 else (w[0] / n[0], 0.0)
        return float(slope), float(icpt)

    slope, icpt = fit(gyro)
    rslope, ricpt = fit(ray)
    md = [f"Load average before/after: {load[0]:.1f} / {load_after[0]:.1f}; wall seconds, "
          f"median of {args.repeats} (min–max).", "",
          f"### A. accel (study 000), {accel['runs']} runs a unit, Lorentz + linear + cubic", "",
          table(["job", "wall s (median, min–max)"],
                [["one unit: `thermonet compare`", _med(accel["one_unit_s"])],
                 [f"{accel['units']} units: `thermonet fleet --units {accel['units']} "
                  "--workers 2`", _med(accel["fleet_s"])],
                 ["ratio (paired)", _med(accel["ratio"])]]), "",
          "### B. mems-gyro, 3 runs a unit, cubic + linear", "",
          table(["executor", "units", "wall s", "driver peak MiB", "largest worker peak MiB"],
                [[r["executor"], r["units"], _med([x["wall_s"] for x in r["runs"]]),
                  _med([x["driver_peak_mib"] for x in r["runs"]]),
                  _med([x["worker_peak_mib"] for x in r["runs"]])] for r in gyro + ray]), "",
          _extrapolation("process pool", slope, icpt) + " " + _extrapolation("Ray local", rslope,
                                                                              ricpt)]
    save("bench_fleet", {"git": git_rev(), "load_before": load, "load_after": load_after,
                         "accel": accel, "gyro": gyro, "ray": ray,
                         "per_unit_s": {"process": slope, "ray": rslope},
                         "startup_s": {"process": icpt, "ray": ricpt}}, "\n".join(md))


if __name__ == "__main__":
    main()
