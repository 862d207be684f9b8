"""``thermonet learn``: the drift learned from flights, against the truth and a chamber.

``python experiments/bench_learn.py [accuracy] [--seeds 0,1,2,3] [--flights 20,40]``
    Simulated vehicles (:mod:`thermonet.sim.flights`: the fc-board board of each seed flown
    across the seasons, PX4 ``.ulg`` and ArduPilot ``.bin``): ``thermonet learn`` on the first
    N flights (``--no-compare``: the firmware form, what the parameter file carries), then
    applied to 5 new flights of the same vehicle.  Per instance the estimator runs on
    (gyro0/1, acc0/1) and axis, on each new flight: the 1 °C-binned peak-to-peak of the true
    drift left after the learned correction, over the raw drift's, and over what a chamber
    calibration of the same board leaves (``fit_firmware`` on ``simulate_board(seed)``, the
    fc-board warm-up 7 → 52 °C).  Axes whose raw drift is under verify's floor are left out.
``python experiments/bench_learn.py scaling [--logs 25,50,100] [--workers 1,2] [--dir D]``
    Reading K logs of 15–40 minutes on the process pool: wall time, logs per second, and the
    driver's peak resident memory (the reduced logs, not the logs, are held).
``python experiments/bench_learn.py coverage``
    From 10 flights: how many 1 °C bins are supported, and what the report says is missing.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from common import machine, save, table  # noqa: E402
from thermonet.data.firmware import FirmwareFit  # noqa: E402
from thermonet.data.logs.flight_writers import write_flight  # noqa: E402
from thermonet.sim.fcboard import simulate_board  # noqa: E402
from thermonet.sim.flights import simulate_flights  # noqa: E402
from thermonet.workflows.firmware_fit import fit_firmware  # noqa: E402
from thermonet.workflows.learn import binned_pp, learn  # noqa: E402
from thermonet.workflows.magnetometer import fit_correction  # noqa: E402
from thermonet.workflows.verify import Limits  # noqa: E402

EKF = ("gyro0", "gyro1", "acc0", "acc1")
NEW_FLIGHTS = 5


def _fit(d: dict[str, Any]) -> FirmwareFit:
    f = d["firmware"]
    return FirmwareFit(d["kind"], d["device_id"], f["t_ref"], f["t_min"], f["t_max"],
                       np.asarray(f["coef"]))


def _one(seed: int, n: int, autopilot: str, tmp: Path) -> dict[str, Any]:
    """Learn on n flights, judge on NEW_FLIGHTS more: ratios per instance and axis."""
    ext = ".ulg" if autopilot == "px4" else ".bin"
    flights = simulate_flights(n + NEW_FLIGHTS, seed=seed, autopilot=autopilot)
    logs = tmp / f"{autopilot}-{seed}-{n}"
    logs.mkdir()
    paths = [write_flight(f.log, f.biases, logs / f"f{k:03d}{ext}")
             for k, f in enumerate(flights[:n])]
    t0 = time.perf_counter()
    doc = learn(paths, tmp / f"out-{autopilot}-{seed}-{n}", executor="serial", compare=False)
    wall = time.perf_counter() - t0
    board = simulate_board(seed=seed, autopilot=autopilot, rate_hz=0.2)
    floor = Limits().floor
    vs_raw, vs_chamber, resid = [], [], []
    for f in flights[n:]:
        for inst in f.log.instances:
            if inst.name not in EKF or doc["instances"][inst.name].get("firmware") is None:
                continue
            temp, truth = inst.temperature_c, f.truth[inst.name]
            learned = truth - fit_correction(_fit(doc["instances"][inst.name]), temp)
            ch = next(i for i in board.instances if i.name == inst.name)
            chamber = truth - fit_correction(fit_firmware(ch, autopilot), temp)
            for raw, got, cal in zip(binned_pp(temp, truth), binned_pp(temp, learned),
                                     binned_pp(temp, chamber), strict=True):
                if raw > floor[inst.kind]:
                    vs_raw.append(got / raw)
                    vs_chamber.append(got / cal)
                    resid.append(got / floor[inst.kind])
    return {"seed": seed, "flights": n, "autopilot": autopilot, "learn_s": wall,
            "vs_raw": vs_raw, "vs_chamber": vs_chamber, "in_floors": resid,
            "lags": {k: doc["instances"][k]["lag_s"] for k in EKF},
            "rejected": sum(doc["instances"][k]["rejected_windows"] for k in EKF)}


def accuracy(seeds: list[int], counts: list[int]) -> None:
    rows, data = [], []
    with tempfile.TemporaryDirectory() as d:
        for autopilot in ("px4", "ardupilot"):
            for n in counts:
                for seed in seeds:
                    r = _one(seed, n, autopilot, Path(d))
                    data.append(r)
                    q = np.percentile
                    rows.append([autopilot, n, seed, len(r["vs_raw"]),
                                 f"{q(r['vs_raw'], 50):.3f} / {max(r['vs_raw']):.3f}",
                                 f"{q(r['vs_chamber'], 50):.2f} / {max(r['vs_chamber']):.2f}",
                                 f"{q(r['in_floors'], 50):.2f} / {max(r['in_floors']):.2f}",
                                 " ".join(f"{v:g}" for v in r["lags"].values()),
                                 r["rejected"], f"{r['learn_s']:.1f}"])
                    print(rows[-1], flush=True)
    md = table(["autopilot", "flights", "seed", "axes", "left / raw (median / worst)",
                "left / chamber (median / worst)", "left in floors (median / worst)",
                "lags s (g0 g1 a0 a1)", "windows rejected", "learn s"], rows)
    print(md)
    save("bench_learn_accuracy", {"machine": machine(), "runs": data}, md)


#: ``python -c LEARN_CHILD OUT WORKERS LOG...``: ``learn`` in a fresh process; prints its wall
#: seconds and its own peak resident memory (the driver's: the workers are its children).
LEARN_CHILD = """
import json, resource, sys, time
from thermonet.workflows.learn import learn
t0 = time.perf_counter()
learn(sys.argv[3:], sys.argv[1], workers=int(sys.argv[2]), compare=False)
print(json.dumps({"wall_s": time.perf_counter() - t0,
                  "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}))
"""


def scaling(counts: list[int], workers: list[int], logs_dir: str | None) -> None:
    import json
    import subprocess

    rows = []
    with tempfile.TemporaryDirectory() as d:
        root = Path(logs_dir) if logs_dir else Path(d) / "logs"
        root.mkdir(exist_ok=True)
        have = len(list(root.glob("*.ulg")))
        for k in range(have, max(counts)):   # one flight at a time: the bench holds none
            f = simulate_flights(k + 1, seed=1, first=k)[0]
            write_flight(f.log, f.biases, root / f"f{k:04d}.ulg")
        paths = sorted(str(p) for p in root.glob("*.ulg"))[:max(counts)]
        minutes = 27.0   # the mean length of seed 1's flights (measured on its first 100)
        for n in counts:
            for w in workers:
                out = Path(d) / f"out-{n}-{w}"
                res = subprocess.run([sys.executable, "-c", LEARN_CHILD, str(out), str(w),
                                      *paths[:n]], capture_output=True, text=True, check=True)
                got = json.loads(res.stdout.strip().splitlines()[-1])
                rows.append([n, w, f"{got['wall_s']:.1f}", f"{n / got['wall_s']:.2f}",
                             f"{got['maxrss_mb']:.0f}"])
                print(rows[-1], flush=True)
    md = table(["logs", "workers", "wall s", "logs / s", "driver peak RSS MB"], rows)
    md += f"\n\n{max(counts)} flights, about {minutes:.0f} min each on average."
    print(md)
    save("bench_learn_scaling", {"machine": machine(), "rows": rows}, md)


def coverage() -> None:
    with tempfile.TemporaryDirectory() as d:
        flights = simulate_flights(10, seed=0)
        paths = [write_flight(f.log, f.biases, Path(d) / f"f{k:02d}.ulg")
                 for k, f in enumerate(flights)]
        doc = learn(paths, Path(d) / "out", executor="serial", compare=False)
    lines = []
    for name, inst in doc["instances"].items():
        ok = [c for c in inst["coverage"] if c["flights"] >= 2 and c["minutes"] >= 2]
        lines.append(f"{name}: {len(ok)} of {len(inst['coverage'])} bins supported, "
                     f"{inst['supported_c']}; " + "; ".join(inst["missing"]))
    print("\n".join(lines))
    save("bench_learn_coverage", {"machine": machine(), "lines": lines}, "\n".join(lines))


def ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",")]


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("what", nargs="?", default="accuracy",
                   choices=["accuracy", "scaling", "coverage"])
    p.add_argument("--seeds", default="0,1,2,3")
    p.add_argument("--flights", default="20,40")
    p.add_argument("--logs", default="25,50,100")
    p.add_argument("--workers", default="1,2")
    p.add_argument("--dir", default=None, help="scaling: reuse (and fill) this folder of logs")
    a = p.parse_args()
    if a.what == "accuracy":
        accuracy(ints(a.seeds), ints(a.flights))
    elif a.what == "scaling":
        scaling(ints(a.logs), ints(a.workers), a.dir)
    else:
        coverage()


if __name__ == "__main__":
    main()
