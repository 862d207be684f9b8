"""Run every benchmark (``make bench``); results land in experiments/out/*.md and *.json.

Each benchmark runs in its own child process: thread settings made before
numpy is imported (bench_export pins numpy's BLAS to one thread) take effect,
and one benchmark's memory or thread pools do not leak into the next.
``python experiments/run_all.py NAME ...`` runs only those.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: Every benchmark whose figures experiments/README.md (and the README's headline table) quotes, the quick and most-quoted first.
ALL = ["bench_export", "bench_averaging", "bench_default", "bench_threads", "bench_scaling",
       "bench_studies", "bench_anchor", "bench_rbf_speed", "bench_dynamic", "bench_imports",
       "bench_fleet", "bench_fleet_files", "bench_mcu", "bench_selection", "bench_neural",
       "bench_magnetometers", "bench_learn", "bench_uncertainty", "bench_pipeline", "bench_rbf_centres"]

if __name__ == "__main__":
    env = dict(os.environ)
    env["PYTHONPATH"] = str(HERE.parent) + os.pathsep + env.get("PYTHONPATH", "")
    failed = []
    for name in sys.argv[1:] or ALL:
        print(f"== {name}", flush=True)
        if subprocess.run([sys.executable, str(HERE / f"{name}.py")], env=env).returncode:
            failed.append(name)
    if failed:
        print("failed: " + ", ".join(failed), file=sys.stderr)
        sys.exit(1)
