"""Threads: the default comparison on a busy machine, default vs OMP_NUM_THREADS=1 vs torch's own.

``train.threads`` (default 1) sets torch's intra-op threads inside each fit.
Three ways to run ``thermonet compare configs/default.yaml --no-track`` in a
child process, interleaved, while a CPU hog (a busy loop in another process)
keeps one core of the machine busy:

* ``default``: thermonet as shipped (``train.threads: 1``; families fitted side by
  side, ``workers: 0`` = one per core);
* ``workers: 1``: the same with the families fitted one after another;
* ``OMP_NUM_THREADS=1``: the same with every thread pool pinned by the environment;
* ``torch's default``: ``train.threads: 0``, ``workers: 1`` (torch picks one thread per core, families one after another —
  what thermonet did before).

Wall and CPU seconds of each child (medians of ``REPEATS`` with min–max) and
the per-repeat ratio to ``OMP_NUM_THREADS=1``.  Done when the default is no
slower than ``OMP_NUM_THREADS=1``.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import COMPARE_CHILD, fmt_spread, ratio_spread, save, spread, table  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
REPEATS = int(os.environ.get("BENCH_THREADS_REPEATS", "3"))



def _hog(stop) -> None:  # noqa: ANN001 - a multiprocessing.Event
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x += 1


def run(config: Path, out: Path, env_extra: dict[str, str]) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        env.pop(var, None)
    env.update(env_extra)
    p = subprocess.run([sys.executable, "-c", COMPARE_CHILD, str(config), str(out)], check=True,
                       text=True, capture_output=True, env=env, cwd=ROOT)
    res = json.loads(p.stdout.strip().splitlines()[-1])
    if res["rc"] != 0:
        raise RuntimeError(p.stderr[-500:])
    return res


def main() -> None:
    base = (ROOT / "configs" / "default.yaml").read_text()
    with tempfile.TemporaryDirectory() as tmp:
        cfg_default = Path(tmp) / "default.yaml"
        cfg_default.write_text(base)
        cfg_torch = Path(tmp) / "torch_threads.yaml"
        cfg_torch.write_text(base + "train:\n  threads: 0\nworkers: 1\n")   # as before
        cfg_serial = Path(tmp) / "serial.yaml"
        cfg_serial.write_text(base + "workers: 1\n")
        variants = {
            "default (train.threads: 1, families side by side)": (cfg_default, {}),
            "families one after another (workers: 1)": (cfg_serial, {}),
            "OMP_NUM_THREADS=1": (cfg_default, {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                                                "OPENBLAS_NUM_THREADS": "1"}),
            "torch's default threads (train.threads: 0, before)": (cfg_torch, {}),
        }
        stop = multiprocessing.Event()
        hog = multiprocessing.Process(target=_hog, args=(stop,), daemon=True)
        hog.start()
        try:
            res: dict[str, list[dict]] = {k: [] for k in variants}
            for k in range(REPEATS):
                for v, (name, (cfg, env)) in enumerate(variants.items()):
                    res[name].append(run(cfg, Path(tmp) / f"out_{k}_{v}", env))
                _save(res)      # after each round: a long run still leaves what it measured
        finally:
            stop.set()
            hog.join(timeout=10)


def _save(res: dict[str, list[dict]]) -> None:
    ref = [r["wall_s"] for r in res["OMP_NUM_THREADS=1"]]
    done = len(ref)
    rows, data = [], {"cores": os.cpu_count(), "repeats": done, "variants": {}}
    for name, rs in res.items():
        wall, cpu = [r["wall_s"] for r in rs], [r["cpu_s"] for r in rs]
        ratio = ratio_spread(wall, ref)
        data["variants"][name] = {"wall_s": spread(wall), "cpu_s": spread(cpu),
                                  "wall_over_omp1": ratio}
        rows.append([name, fmt_spread(spread(wall)), fmt_spread(spread(cpu)),
                     fmt_spread(ratio)])
    md = ("### Threads: default comparison with one core kept busy by a CPU hog\n\n"
          f"`thermonet compare configs/default.yaml --no-track`, {done} interleaved repeats "
          "per variant (median, min–max).\n\n"
          + table(["variant", "wall s", "CPU s", "wall / OMP_NUM_THREADS=1 (paired)"], rows))
    save("threads", data, md)


if __name__ == "__main__":
    main()
