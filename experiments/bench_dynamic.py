"""Dynamic inputs: accuracy on heat/cool data, cost in training, in the runtime and in C.

* **Heat/cool presets with hysteresis** — the `patent-gyro` device through heat/cool cycles
  with a heating/cooling hysteresis (``bench_anchor.cycling_device``), and every other
  heat/cool preset registered (``consumer-imu`` when present): thermonet's default family set
  (no ``families`` in the config), the chosen model against the PX4/ArduPilot cubic and against
  the raw output on every axis of the held-out (verification) run.  Goal: better than the cubic
  on every axis, never worse than raw.
* **Training cost** — :func:`thermonet.features.dynamics.compute` on 2 M samples (100 Hz, 5.6 h):
  median of 5 with min–max, per kind of input (O(N), no window factor).
* **Runtime** — ``export/thermonet_runtime.py`` on the default dynamic model: batch
  (100,000 samples with ``time_s``, dynamic inputs computed by the runtime) and streaming
  ``step()`` (one call per sample), median of repeats.
* **C** — instructions per ``<prefix>_step`` (dynamic inputs + model, 3 axes) counted with
  ``valgrind --tool=callgrind``: (Ir(N) − Ir(0)) / N, against the same model's stateless
  ``_compensate``.  Target ≤ 1,500 for the 16-centre RBF with a dynamic input.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT / "export"))
from bench_anchor import cycling_device  # noqa: E402
from common import OUT, save, table  # noqa: E402
from thermonet.exporting import export_onnx, render_c_header  # noqa: E402
from thermonet.features import dynamics  # noqa: E402
from thermonet.features.inputs import FeatureSpec, signal_matrix, target_matrix  # noqa: E402
from thermonet.sim import PRESETS, simulate  # noqa: E402
from thermonet.training.config import CompareConfig  # noqa: E402
from thermonet.training.train import TrainConfig, fit  # noqa: E402
from thermonet.workflows.compare import run_compare  # noqa: E402
from thermonet_runtime import Compensator  # noqa: E402

N_TRAINING = 2_000_000
N_CALLGRIND = 1000
STEP_DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "model.h"
int main(int argc, char **argv) {
    int n = atoi(argv[1]), mode = atoi(argv[2]), flag = 0, i, a;
    (void)argc;
    double raw[THERMONET_N_AXES], comp[THERMONET_N_AXES], drift[THERMONET_N_AXES];
    float sig[THERMONET_N_SIGNALS];
    volatile double sink = 0.0;
    thermonet_state st;
    thermonet_init(&st);
    for (a = 0; a < THERMONET_N_AXES; a++) raw[a] = 0.0;
    for (i = 0; i < THERMONET_N_SIGNALS; i++) sig[i] = 0.0f;
    for (i = 0; i < n; i++) {
        /* 0.1 s steps; a 25 <-> 35 degC triangle at 1 degC/min */
        double t = 1.7e9 + 0.1 * i;
        float temp = 25.0f + (float)((i / 6000) % 2 ? 10 - (i % 6000) / 600.0 : (i % 6000) / 600.0);
        if (mode == 0) {
            thermonet_step(&st, t, temp, raw, comp, drift, &flag);
        } else {
            sig[0] = temp;
            flag = thermonet_compensate(sig, raw, comp, drift);
        }
        sink += (double)flag + drift[0];
    }
    printf("%f\n", (double)sink);
    return 0;
}
"""


def _spread(times: list[float]) -> tuple[float, float, float]:
    return float(np.median(times)), float(np.min(times)), float(np.max(times))


def heat_cool_presets() -> dict:
    devices = {"patent-gyro cycling (bench_anchor)": (cycling_device(), 0)}
    if "consumer-imu" in PRESETS:
        devices["consumer-imu"] = ("consumer-imu", 0)
    return devices


def accuracy() -> tuple[list[list], dict]:
    rows, data = [], {}
    for label, (device, seed) in heat_cool_presets().items():
        ds = simulate(device, seed=seed)
        cfg = CompareConfig()                                  # the default family set
        res = run_compare(cfg, OUT / "dynamic" / label.split()[0], track=False, quiet=True,
                          dataset=ds)
        chosen = res["chosen"]
        data[label] = {"chosen": chosen, "families": {k: v.get("axes") for k, v in
                                                      res["families"].items()}}
        for axis, m in res["families"]["cubic"]["axes"].items():
            c = res["families"][chosen]["axes"][axis]
            key = "drift_error_rms" if "drift_error_rms" in m else "rms_comp"
            rows.append([label, chosen, axis, m["pp_raw"], m["pp_comp"], c["pp_comp"],
                         m.get("drift_error_rms", float("nan")),
                         c.get("drift_error_rms", float("nan")),
                         c[key] / m[key], c["msd_comp"] / c["msd_raw"]])
    return rows, data


def training_cost() -> list[list]:
    rng = np.random.default_rng(0)
    t = np.arange(N_TRAINING) * 0.01
    temp = 25.0 + 10.0 * np.sin(t / 3600.0) + rng.normal(0.0, 0.01, N_TRAINING)
    rows = []
    for names in (["rate"], ["lag_300"], ["play_1"], ["rate", "lag_300", "play_1"]):
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            dynamics.compute(t, temp, names, 0.05)
            times.append(time.perf_counter() - t0)
        med, lo, hi = _spread(times)
        rows.append([", ".join(names), med, lo, hi, N_TRAINING / med / 1e6])
    return rows


def _fit(inputs: list[str], family: str, hyper: dict):
    ds = simulate(cycling_device(), runs=1, seed=1)
    rec = ds[0]
    spec = FeatureSpec.from_recordings(inputs, [rec])
    s = signal_matrix(rec, spec.signals, spec.gap_s)
    y = target_matrix(rec, ds.axes)
    res = fit(family=family, inputs=inputs, outputs=ds.axes, train=[(s, y)], val=None,
              spec=spec, hyper=hyper, config=TrainConfig(max_epochs=20))
    return res.model, rec


def runtime_cost(model, rec) -> list[list]:
    path = export_onnx(model, OUT / "dynamic" / "poly3-hyst.onnx")
    comp = Compensator(path)
    n = 100_000
    t = rec.time_s[:n].astype(np.float64)
    temp = rec.temperature_c[:n]
    raw = np.zeros((t.size, len(comp.outputs)), dtype=np.float32)
    times = []
    for _ in range(7):
        t0 = time.perf_counter()
        comp.compensate(temperature_c=temp, raw=raw, time_s=t)
        times.append(time.perf_counter() - t0)
    med, lo, hi = _spread(times)
    rows = [["batch of 100,000 with time_s (dynamic inputs computed)", t.size / med / 1e6,
             t.size / hi / 1e6, t.size / lo / 1e6]]
    steps = []
    for _ in range(5):
        comp.reset()
        t0 = time.perf_counter()
        for k in range(2000):
            comp.step(t[k], temp[k], raw[k])
        steps.append((time.perf_counter() - t0) / 2000)
    med, lo, hi = _spread(steps)
    rows.append(["streaming step() per sample", 1.0 / med / 1e6, 1.0 / hi / 1e6,
                 1.0 / lo / 1e6])
    return rows


def callgrind_ir(binary: Path, n: int, mode: int) -> int:
    out = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null",
                          str(binary), str(n), str(mode)],
                         capture_output=True, text=True, check=True)
    m = re.search(r"Collected\s*:\s*(\d+)", out.stderr)
    if not m:
        raise RuntimeError("callgrind printed no 'Collected' line:\n" + out.stderr[-500:])
    return int(m.group(1))


def c_cost(models: dict) -> list[list]:
    rows = []
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None or shutil.which("valgrind") is None:
        return [[name, "no cc/valgrind", ""] for name in models]
    for name, model in models.items():
        work = OUT / "dynamic" / f"c_{name}"
        work.mkdir(parents=True, exist_ok=True)
        (work / "model.h").write_text(render_c_header(model))
        (work / "driver.c").write_text(STEP_DRIVER)
        subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-o",
                        str(work / "driver"), str(work / "driver.c"), "-lm"], check=True)
        per = {}
        for mode in (0, 1):
            per[mode] = (callgrind_ir(work / "driver", N_CALLGRIND, mode)
                         - callgrind_ir(work / "driver", 0, mode)) / N_CALLGRIND
        rows.append([name, ", ".join(model.inputs), round(per[0]), round(per[1])])
    return rows


def main(parts: list[str]) -> None:
    """``accuracy`` and/or ``cost`` (default both); each saves its own result file."""
    torch.set_num_threads(1)
    (OUT / "dynamic").mkdir(parents=True, exist_ok=True)
    if "accuracy" in parts:
        acc_rows, acc = accuracy()
        md = ("### Default family set on heat/cool presets with hysteresis (held-out run)\n\n"
              + table(["preset", "chosen", "axis", "pp raw", "pp cubic", "pp chosen",
                       "drift err cubic", "drift err chosen", "chosen / cubic",
                       "msd chosen / raw"], acc_rows))
        save("dynamic_accuracy", {"accuracy": acc, "rows": acc_rows}, md)
    if "cost" in parts:
        train_rows = training_cost()
        poly, rec = _fit(["dT", "rate", "play_1"], "poly", {"degree": 3, "cross": True})
        rbf, _ = _fit(["dT", "dT2", "rate"], "rbf", {"n_centres": 16})
        rt_rows = runtime_cost(poly, rec)
        c_rows = c_cost({"poly3-hyst": poly, "rbf16 [dT, dT2, rate]": rbf})
        md = ("### dynamics.compute on 2 M samples (s; median, min, max of 5)\n\n"
              + table(["inputs", "median s", "min s", "max s", "M samples/s"], train_rows)
              + "\n\n### Runtime, poly3-hyst (one thread; M samples/s: median, min, max)\n\n"
              + table(["form", "M samples/s", "min", "max"], rt_rows)
              + "\n\n### C instructions per call (callgrind, x86-64, gcc -O2, 3 axes)\n\n"
              + table(["model", "inputs", "step()", "compensate() alone"], c_rows))
        save("dynamic_cost", {"training": train_rows, "runtime": rt_rows, "c": c_rows}, md)


if __name__ == "__main__":
    main(sys.argv[1:] or ["accuracy", "cost"])
