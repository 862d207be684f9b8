"""``thermonet learn``: the drift learned from flights, against the truth and a chamber.

``python experiments/bench_learn.py [accuracy] [--seeds 0,1,2,3] [--flights 20,40]``
    Simulated vehicles (:mod:`thermonet.sim.flights`: the fc-board board of each seed flown
    across the seasons, PX4 ``.ulg`` and ArduPilot ``.bin``): ``thermonet learn`` on the first
    N flights, then applied to 5 new flights of the same vehicle: the firmware form (what
    the parameter file carries) and the comparison's shipped model (``model.onnx`` through
    ``export/thermonet_runtime.py``, torch-free).  Per instance the estimator runs on
    (gyro0/1, acc0/1) and axis, on each new flight: the 1 °C-binned peak-to-peak of the true
    drift left after the learned correction, over the raw drift's, and over what a chamber
    calibration of the same board leaves (``fit_firmware`` on ``simulate_board(seed)``, the
    fc-board warm-up 7 → 52 °C).  Axes whose raw drift is under verify's floor are left out.
``python experiments/bench_learn.py scaling [--logs 25,50,100] [--workers 1,2] [--repeat 3]
[--executor process] [--dir D]``
    Reading K logs of 15–40 minutes (``learn --no-compare`` in a fresh process): wall time
    (median and spread of interleaved repeats), logs per second, each worker count's wall over
    the first's, and the driver's peak resident memory (VmHWM).
``python experiments/bench_learn.py memory [--logs 50,200,1000] [--dir D]``
    The same on 2 workers, once per count: the driver's peak memory against the logs read.
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
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "export"))
from common import machine, save, table  # noqa: E402
from thermonet.data.firmware import FirmwareFit  # noqa: E402
from thermonet.data.logs.bias import read_bias_log  # noqa: E402
from thermonet.data.logs.flight_writers import write_flight  # noqa: E402
from thermonet.sim.fcboard import simulate_board  # noqa: E402
from thermonet.sim.flights import simulate_flights  # noqa: E402
from thermonet.workflows.firmware_fit import fit_firmware  # noqa: E402
from thermonet.workflows.learn import learn  # noqa: E402
from thermonet.workflows.learn_fit import binned_pp  # noqa: E402
from thermonet.workflows.magnetometer import fit_correction  # noqa: E402
from thermonet.workflows.verify import Limits  # noqa: E402
from thermonet_runtime import Compensator  # noqa: E402

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
    out = tmp / f"out-{autopilot}-{seed}-{n}"
    t0 = time.perf_counter()
    doc = learn(paths, out, executor="serial")
    wall = time.perf_counter() - t0
    board = simulate_board(seed=seed, autopilot=autopilot, rate_hz=0.2)
    floor = Limits().floor
    r: dict[str, list[float]] = {k: [] for k in ("vs_raw", "vs_chamber", "in_floors", "model_vs_raw",
                                                 "model_vs_chamber", "model_in_floors")}
    for f in flights[n:]:
        for inst in f.log.instances:
            d = doc["instances"].get(inst.name, {})
            if inst.name not in EKF or d.get("firmware") is None:
                continue
            temp, truth = inst.temperature_c, f.truth[inst.name]
            learned = truth - fit_correction(_fit(d), temp)
            onnx = out / "instances" / inst.name / "model.onnx"
            model = truth - Compensator(onnx).compensate(
                np.asarray(temp, dtype=np.float64), np.zeros((temp.size, 3))).drift \
                if onnx.exists() else np.full_like(truth, np.nan)
            ch = next(i for i in board.instances if i.name == inst.name)
            chamber = truth - fit_correction(fit_firmware(ch, autopilot), temp)
            for raw, got, mod, cal in zip(binned_pp(temp, truth), binned_pp(temp, learned),
                                          binned_pp(temp, model), binned_pp(temp, chamber),
                                          strict=True):
                if raw > floor[inst.kind]:
                    for key, v in (("", got), ("model_", mod)):
                        r[key + "vs_raw"].append(v / raw)
                        r[key + "vs_chamber"].append(v / cal)
                        r[key + "in_floors"].append(v / floor[inst.kind])
    return {"seed": seed, "flights": n, "autopilot": autopilot, "learn_s": wall, **r,
            "chosen": {k: (doc["instances"][k].get("compare") or {}).get("chosen")
                       for k in EKF},
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
                                 f"{np.nanmedian(r['model_vs_chamber']):.2f} / "
                                 f"{np.nanmax(r['model_vs_chamber']):.2f}",
                                 " ".join(str(v) for v in r["chosen"].values()),
                                 " ".join(f"{v:g}" for v in r["lags"].values()),
                                 r["rejected"], f"{r['learn_s']:.1f}"])
                    print(rows[-1], flush=True)
    md = table(["autopilot", "flights", "seed", "axes", "left / raw (median / worst)",
                "left / chamber (median / worst)", "left in floors (median / worst)",
                "comparison's model: left / chamber (median / worst)",
                "chosen (g0 g1 a0 a1)", "lags s (g0 g1 a0 a1)", "windows rejected",
                "learn s"], rows)
    md = _summary(data) + "\n\n" + md
    print(md)
    save("bench_learn_accuracy", {"machine": machine(), "runs": data}, md)


def _summary(data: list[dict[str, Any]]) -> str:
    """Per autopilot and flight count, both forms over every seed: the share of axes
    ≤ 0.3× raw, and ≤ 1.5× the chamber calibration or under verify's floor."""
    rows = []
    for ap in dict.fromkeys(r["autopilot"] for r in data):
        for n in dict.fromkeys(r["flights"] for r in data):
            runs = [r for r in data if r["autopilot"] == ap and r["flights"] == n]
            for form, key in (("firmware form", ""), ("comparison (ONNX)", "model_")):
                raw, ch, fl = (np.concatenate([r[key + k] for r in runs])
                               for k in ("vs_raw", "vs_chamber", "in_floors"))
                ok = np.isfinite(raw)
                rows.append([ap, n, form, int(ok.sum()),
                             f"{np.mean(raw[ok] <= 0.3):.1%}",
                             f"{np.median(raw[ok]):.3f}, {np.percentile(raw[ok], 90):.3f}",
                             f"{np.mean((ch[ok] <= 1.5) | (fl[ok] <= 1)):.1%}",
                             f"{np.median(ch[ok]):.2f}, {np.percentile(ch[ok], 90):.2f}"])
    return table(["autopilot", "flights", "form", "axes", "≤ 0.3× raw",
                  "left / raw: median, 90th pct", "≤ 1.5× chamber or under the floor",
                  "left / chamber: median, 90th pct"], rows)


#: ``python -c LEARN_CHILD OUT EXECUTOR WORKERS LOG...``: ``learn`` (``--no-compare``) in a
#: fresh process; prints its wall seconds, its own peak resident memory, VmHWM of
#: /proc/self/status, before ``learn`` (imports done) and after, and the CPU seconds of the
#: driver and of its pool workers (its children, joined when the pool closes).  Not ``ru_maxrss``: a child's
#: starts from the forking parent's peak (Linux keeps it across exec), which here holds the
#: simulator's flights.  The pool's workers are other processes: the driver's memory is this.
LEARN_CHILD = """
import json, resource, sys, time
from thermonet.workflows.learn import learn
def hwm():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
def cpu(who):
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime
before, c0 = hwm(), cpu(resource.RUSAGE_SELF)
t0 = time.perf_counter()
learn(sys.argv[4:], sys.argv[1], executor=sys.argv[2], workers=int(sys.argv[3]),
      compare=False)
print(json.dumps({"wall_s": time.perf_counter() - t0, "hwm_before_mb": before,
                  "hwm_mb": hwm(), "driver_cpu_s": cpu(resource.RUSAGE_SELF) - c0,
                  "workers_cpu_s": cpu(resource.RUSAGE_CHILDREN)}))
"""


def _logs(root: Path, n: int) -> list[str]:
    """The first ``n`` flights of seed 1 in ``root`` (written one at a time, those missing:
    the bench holds none)."""
    root.mkdir(parents=True, exist_ok=True)
    for k in range(n):
        if not (root / f"f{k:04d}.ulg").exists():
            f = simulate_flights(k + 1, seed=1, first=k)[0]
            write_flight(f.log, f.biases, root / f"f{k:04d}.ulg")
    return [str(root / f"f{k:04d}.ulg") for k in range(n)]


def _learn_child(paths: list[str], out: Path, executor: str, workers: int) -> dict[str, float]:
    import json
    import shutil
    import subprocess

    shutil.rmtree(out, ignore_errors=True)       # a fresh directory: every log is read
    res = subprocess.run([sys.executable, "-c", LEARN_CHILD, str(out), executor, str(workers),
                          *paths], capture_output=True, text=True, check=True)
    shutil.rmtree(out, ignore_errors=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def scaling(counts: list[int], workers: list[int], logs_dir: str | None, repeat: int,
            executor: str, name: str = "bench_learn_scaling") -> None:
    """Per count of logs, ``learn`` on each number of workers, interleaved (1, 2, 1, 2, ...)
    ``repeat`` times: median wall time with its spread, the driver's peak memory, and the
    ratio of each worker count's wall to the first's (the median of the per-repeat ratios)."""
    rows, data = [], []
    with tempfile.TemporaryDirectory() as d:
        root = Path(logs_dir) if logs_dir else Path(d) / "logs"
        paths = _logs(root, max(counts))
        for n in counts:
            walls: dict[int, list[float]] = {w: [] for w in workers}
            hwm: dict[int, list[float]] = {w: [] for w in workers}
            start: dict[int, list[float]] = {w: [] for w in workers}
            cpus: dict[int, list[tuple[float, float]]] = {w: [] for w in workers}
            for _ in range(repeat):
                for w in workers:
                    got = _learn_child(paths[:n], Path(d) / f"out-{n}-{w}", executor, w)
                    walls[w].append(got["wall_s"])
                    hwm[w].append(got["hwm_mb"])
                    start[w].append(got["hwm_before_mb"])
                    cpus[w].append((got["driver_cpu_s"], got["workers_cpu_s"]))
                    data.append({"logs": n, "workers": w, "executor": executor, **got})
                    print(data[-1], flush=True)
            for w in workers:
                ratio = np.median([a / b for a, b in zip(walls[w], walls[workers[0]],
                                                         strict=True)])
                med = float(np.median(walls[w]))
                rows.append([n, w, f"{med:.1f} ({min(walls[w]):.1f}–{max(walls[w]):.1f})",
                             f"{n / med:.2f}", f"{ratio:.2f}",
                             f"{max(hwm[w]):.0f}", f"{max(start[w]):.0f}",
                             f"{np.median([c[0] for c in cpus[w]]):.1f}",
                             f"{np.median([c[1] for c in cpus[w]]):.1f}"])
        minutes = float(np.mean([read_bias_log(p).duration_s for p in paths[:20]])) / 60.0
    md = table(["logs", "workers", "wall s: median (min–max)", "logs / s",
                f"wall / {workers[0]} worker(s)'s", "driver peak MB (VmHWM)",
                "of which at start (imports)", "driver CPU s", "workers CPU s"], rows)
    md += (f"\n\n{executor} executor, {repeat} repeat(s) interleaved; flights of seed 1, "
           f"about {minutes:.0f} min each on average (the first 20).")
    print(md)
    save(name, {"machine": machine(), "runs": data}, md)


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
                   choices=["accuracy", "scaling", "memory", "coverage"])
    p.add_argument("--seeds", default="0,1,2,3")
    p.add_argument("--flights", default="20,40")
    p.add_argument("--logs", default=None)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--executor", default="process", choices=["process", "ray", "serial"])
    p.add_argument("--workers", default="1,2")
    p.add_argument("--dir", default=None, help="scaling: reuse (and fill) this folder of logs")
    a = p.parse_args()
    if a.what == "accuracy":
        accuracy(ints(a.seeds), ints(a.flights))
    elif a.what == "scaling":
        scaling(ints(a.logs or "25,50,100"), ints(a.workers), a.dir, a.repeat, a.executor)
    elif a.what == "memory":
        scaling(ints(a.logs or "50,200,1000"), [2], a.dir, 1, a.executor, "bench_learn_memory")
    else:
        coverage()


if __name__ == "__main__":
    main()
