"""The README's main job: the default comparison (all families) and its wall time.

Runs ``thermonet compare configs/default.yaml`` in-process, tracking on (a
throw-away SQLite store in experiments/out), as ``make demo`` does; target:
under 60 s on the 2-core development machine, simulation included.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import OUT, save, table  # noqa: E402
from thermonet.compare import run_compare  # noqa: E402
from thermonet.config import load_config  # noqa: E402

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "default.yaml"


def main() -> None:
    out = OUT / "default"
    t0 = time.perf_counter()
    res = run_compare(load_config(CONFIG), out, overwrite=True,
                      tracking_uri=f"sqlite:///{OUT / 'mlflow.db'}",
                      quiet=True)
    total = time.perf_counter() - t0
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
        f"### Default comparison (patent-gyro, all families): {total:.1f} s wall, tracking on\n\n"
        + table(["family", "axis", "fit s", "pp cut ×", "msd cut ×", "drift err rms [deg/s]"], rows)
    )
    save("default", {"wall_seconds": total, "chosen": res["chosen"],
                     "families": res["families"]}, md)


if __name__ == "__main__":
    main()
