"""How the default comparison scales: 5 / 50 runs at 10 / 100 Hz, wall time and peak memory.

The patent-gyro preset (5.9 h runs, 3 axes) is simulated at the given rate and
written to Parquet; then ``thermonet compare`` runs in a child process on the
default config's families (tracking off) and the child's wall time, CPU time
and peak resident memory (``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``,
the largest child so far — each size runs in a fresh helper process so the
figure is its own) are recorded.  Medians of ``REPEATS`` runs with min–max.
50 runs at 100 Hz (106 M samples, ≈ 9 GB of float64 columns before any work, on
a 23 GB machine, and ≈ 10 minutes of simulation alone) is not run: the 50 × 10 Hz
and 5 × 100 Hz rows (10.6 M samples each) show how time and memory grow.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import COMPARE_CHILD, fmt_spread, save, spread, table  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: (runs, rate): the default (5 runs at 1 Hz) and the issue's grid of 5 / 50 runs at 10 / 100 Hz
#: but 50 × 100 Hz (see the module docstring)
SIZES = [(5, 1.0), (5, 10.0), (50, 10.0), (5, 100.0)]
REPEATS = int(os.environ.get("BENCH_SCALING_REPEATS", "2"))



def simulate_file(runs: int, rate_hz: float, path: Path) -> int:
    code = ("import sys; from thermonet.sim import simulate; "
            "from thermonet.data.io import write_parquet; "
            f"ds = simulate('patent-gyro', runs={runs}, seed=0, sample_rate_hz={rate_hz});"
            "write_parquet(ds, sys.argv[1]); print(sum(r.n_samples for r in ds.runs))")
    out = subprocess.run([sys.executable, "-c", code, str(path)], check=True, text=True,
                         capture_output=True, env=_env()).stdout
    return int(out.strip().splitlines()[-1])


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def compare_once(data: Path, work: Path) -> dict:
    cfg = work / "config.yaml"
    cfg.write_text((ROOT / "configs" / "default.yaml").read_text().replace(
        "data:\n  preset: patent-gyro\n  seed: 0\n", f"data:\n  paths: [{data}]\n"))
    out = subprocess.run([sys.executable, "-c", COMPARE_CHILD, str(cfg), str(work / "out")],
                         check=True, text=True, capture_output=True, env=_env(), cwd=work)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    if res["rc"] != 0:
        raise RuntimeError(f"compare failed on {data}: {out.stderr[-500:]}")
    return res


def main() -> None:
    rows, data = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for runs, rate in SIZES:
            f = Path(tmp) / f"pg_{runs}_{rate:g}.parquet"
            n = simulate_file(runs, rate, f)
            results = []
            for k in range(REPEATS):
                work = Path(tmp) / f"w_{runs}_{rate:g}_{k}"
                work.mkdir()
                results.append(compare_once(f, work))
            wall = spread([r["wall_s"] for r in results])
            cpu = spread([r["cpu_s"] for r in results])
            mem = spread([r["maxrss_mb"] for r in results])
            data[f"{runs}x{rate:g}Hz"] = {"samples": n, "wall_s": wall, "cpu_s": cpu,
                                          "maxrss_mb": mem}
            rows.append([runs, f"{rate:g}", f"{n:,}", fmt_spread(wall), fmt_spread(cpu),
                         fmt_spread(mem, digits=4)])
            f.unlink()
            _save(rows, data)      # after each size: a long run still leaves what it measured


def _save(rows: list, data: dict) -> None:
    md = ("### Scaling of the default comparison (patent-gyro, the default families, tracking off)"
          f"\n\nMedians of {REPEATS} child processes (min–max).\n\n"
          + table(["runs", "rate Hz", "samples", "wall s", "CPU s", "peak RSS MB"], rows))
    save("scaling", dict(data), md)


if __name__ == "__main__":
    main()
