"""A fleet of long recordings on a local Ray: what each worker reads and what
crosses the network, driver-read units against one file per unit.

``U`` patent-gyro units (5 runs of 5.9 h each, 3 axes) at ``RATE`` Hz, written once as one
thermonet Parquet file per unit.  ``thermonet fleet``'s two ways on a local Ray (2 workers,
no leave-units-out, tracking off, cubic + linear on ``dT``), each in a fresh process:

* **driver reads**: the driver reads every file (``read_datasets``) and each unit's
  :class:`~thermonet.workflows.fleet_units.UnitSource` carries its runs to the worker;
* **worker reads**: :func:`~thermonet.workflows.fleet_units.sources_from_files` (footers
  only) — the source carries the path, the worker reads its own file.

Measured: wall seconds, the driver's peak resident memory (``VmHWM``), the bytes sent to the
workers (the pickled tasks, what Ray puts in its object store and ships to a node) and the
bytes that come back (the files each unit's comparison wrote: report, plots, checkpoints,
which the worker returns as bytes; its results dict and model are a few kB more).

``python experiments/bench_fleet_files.py [UNITS] [RATE_HZ]`` (default 4 units at 5 Hz:
530,000 samples a unit).  Writes ``experiments/out/fleet_files.{md,json}``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import save, table  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

_HARNESS = r"""
import json, pickle, sys, time
t0 = time.perf_counter()
from thermonet.data.io import read_datasets
from thermonet.training.config import load_config
from thermonet.workflows.fleet import FleetOptions, run_fleet
from thermonet.workflows.fleet_units import (UnitItem, sources_from_dataset,
                                             sources_from_files)
cfg = load_config(sys.argv[1])
cfg.tracking.enabled = False
mode, out, paths = sys.argv[2], sys.argv[3], sys.argv[4:]
src = sources_from_files(paths) if mode == "worker" else sources_from_dataset(
    read_datasets(paths, validate=False))
sent = sum(len(pickle.dumps(UnitItem(cfg=cfg, source=s, family="cubic"))) for s in src)
res = run_fleet(cfg, out, src, options=FleetOptions(executor="ray", workers=2, folds=0),
                quiet=True)
wall = time.perf_counter() - t0
back = sum(p.stat().st_size for p in (__import__("pathlib").Path(out) / "units").rglob("*")
           if p.is_file())
hwm = next(int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmHWM"))
print(json.dumps({"wall_s": wall, "driver_peak_mib": hwm / 1024, "sent_bytes": sent,
                  "back_bytes": back, "failed": res["fleet"]["n_failed"],
                  "units": len(src)}))
"""

CONFIG = """\
data: {paths: []}
families:
  - {name: cubic, family: poly, inputs: [dT], params: {degree: 3}}
  - {name: linear, family: linear, inputs: [dT]}
"""


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def main() -> None:
    units = int(sys.argv[1]) if len(sys.argv) > 1 else 4
    rate = float(sys.argv[2]) if len(sys.argv) > 2 else 5.0
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        code = ("import sys; from pathlib import Path; from thermonet.sim import simulate_fleet;"
                "from thermonet.core.recording import split_units;"
                "from thermonet.data.io import write_parquet;"
                f"ds = simulate_fleet('patent-gyro', units={units}, runs=5, seed=0, "
                f"sample_rate_hz={rate!r});"
                "[print(write_parquet(u, Path(sys.argv[1]) / f'{d}.parquet')) "
                "for d, u in split_units(ds).items()]")
        paths = subprocess.run([sys.executable, "-c", code, str(tmp)], check=True, text=True,
                               capture_output=True, env=_env()).stdout.split()
        cfg = tmp / "fleet.yaml"
        cfg.write_text(CONFIG)
        rows, data = [], {"units": units, "rate_hz": rate,
                          "file_bytes": sum(Path(p).stat().st_size for p in paths)}
        for mode in ("driver", "worker"):
            out = subprocess.run([sys.executable, "-c", _HARNESS, str(cfg), mode,
                                  str(tmp / f"out_{mode}"), *paths], check=True, text=True,
                                 capture_output=True, env=_env()).stdout
            res = json.loads(out.strip().splitlines()[-1])
            data[mode] = res
            rows.append([f"{mode} reads", f"{res['wall_s']:.1f}", f"{res['driver_peak_mib']:.0f}",
                         f"{res['sent_bytes'] / res['units'] / 1e6:.3f}",
                         f"{res['back_bytes'] / res['units'] / 1e6:.3f}", res["failed"]])
    n = int(units * 5 * 21_200 * rate)
    md = (f"### A fleet of {units} units × {n // units:,} samples on a local Ray (2 workers)\n\n"
          + table(["units read by", "wall s", "driver peak MiB", "MB to each worker",
                   "MB back from each worker", "failed"], rows)
          + f"\n\nThe unit files hold {data['file_bytes'] / 1e6:.1f} MB on disk.")
    save("fleet_files", data, md)


if __name__ == "__main__":
    main()
