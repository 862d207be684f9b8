"""The README's main job: the default comparison (all families) and its wall time.

Runs ``thermonet compare configs/default.yaml`` in-process, tracking on (a new
throw-away SQLite store in experiments/out each time, as a first ``make demo``
does), ``REPEATS`` times: median wall time with min–max; target: under 60 s
on the 2-core development machine, simulation included.
"""

from __future__ import annotations

import os
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import OUT, fmt_spread, save, spread, table  # noqa: E402
from thermonet.training.config import load_config  # noqa: E402
from thermonet.workflows.compare import run_compare  # noqa: E402

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "default.yaml"
REPEATS = int(os.environ.get("BENCH_DEFAULT_REPEATS", "3"))


def main() -> None:
    out = OUT / "default"
    walls = []
    for k in range(REPEATS):
        store = OUT / f"mlflow_default_{k}"
        shutil.rmtree(store, ignore_errors=True)
        store.mkdir(parents=True)
        t0 = time.perf_counter()
        uri = f"sqlite:///{store / 'mlflow.db'}"
        res = run_compare(load_config(CONFIG), out, overwrite=True, tracking_uri=uri,
                          quiet=True)
        walls.append(time.perf_counter() - t0)
        shutil.rmtree(store, ignore_errors=True)
    wall = spread(walls)
    total = wall["median"]
    rows = []
    for name, fam in res["families"].items():
        if fam["status"] != "ok":
            rows.append([name, "not fitted", "", "", "", fam["reason"]])
            continue
        for axis, m in fam["axes"].items():
            rows.append(
                [
                    name + (" (chosen)" if name == res["chosen"] else ""),
                    axis,
                    fam["fit_seconds"],
                    m["pp_raw"] / m["pp_comp"],
                    m["msd_raw"] / m["msd_comp"],
                    m["drift_error_rms"],
                ]
            )
    md = (
        f"### Default comparison (patent-gyro, all families): {fmt_spread(wall)} s wall "
        f"(median of {REPEATS}, min–max), tracking on\n\n"
        + table(["family", "axis", "fit s", "pp cut ×", "msd cut ×", "drift err rms [deg/s]"], rows)
    )
    save("default", {"wall_seconds": total, "wall_spread": wall, "chosen": res["chosen"],
                     "families": res["families"]}, md)


if __name__ == "__main__":
    main()
