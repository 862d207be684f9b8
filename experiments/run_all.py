"""Run every benchmark; results land in experiments/out/*.md and *.json."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

if __name__ == "__main__":
    names = sys.argv[1:] or ["bench_default", "bench_studies", "bench_anchor", "bench_rbf_speed",
                             "bench_export"]
    for name in names:
        print(f"== {name}", flush=True)
        runpy.run_path(str(HERE / f"{name}.py"), run_name="__main__")
