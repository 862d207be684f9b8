"""Neural families beside the others: held-out error against cost on board.

* **Accuracy** — one comparison (``run_compare``: the same splits, verdicts and selection
  for every family) per data set: the `patent-gyro` device through heat/cool cycles with a
  2 °C-wide hysteresis (``bench_anchor.cycling_device``; 4 runs: train 2, validate 1,
  test 1), the `consumer-imu` preset (its own hysteresis, 4 runs), and the real BMI270
  recording (two isothermal soaks, tests/data/real, interleaved time blocks: its
  config's split).  Families: the cubic in ΔT, the dynamic-input polynomial (cubic in
  [ΔT, rate, play_1] with cross terms), the 16-centre RBF on [ΔT, ΔT²] and on
  [ΔT, ΔT², rate], the MLP ([8, 8] tanh) on ΔT and on [ΔT, rate, play_1], and the GRU
  (8 units) on ΔT alone.  On the BMI270 soaks (65 s and 131 s) the GRU steps every 1 s
  with a 10-window warm-up (its default 10 s / 30 windows would leave no training window).
  Held-out error: the test run's compensated rms (mean over axes) and, on simulations,
  the rms error against the true drift; ``test_score`` is the selection's own score on
  the test data.  Cost from results.json (``ops_per_sample``, ``c_bytes``), fit time
  (``fit_seconds``, one fit, 2-core VM shared with other jobs: indicative only).
* **C instructions** — each family fitted on one cycling run, its header's ``_step``
  called 1,000 times (3 axes, x86-64, gcc -O2, double path) under
  ``valgrind --tool=callgrind``: (Ir(1000) − Ir(0)) / 1000 per sample, beside the counted
  ``ops_per_sample`` (the count excludes the shared part: clamp, features, standardise,
  dynamic inputs, ``raw − drift``, and integer work).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_anchor import cycling_device  # noqa: E402
from bench_dynamic import callgrind_ir  # noqa: E402
from common import OUT, save, table  # noqa: E402
from thermonet.exporting import render_c_header  # noqa: E402
from thermonet.features.inputs import FeatureSpec, signal_matrix, target_matrix  # noqa: E402
from thermonet.sim import PRESETS, simulate  # noqa: E402
from thermonet.training.config import CompareConfig, FamilyConfig, load_config  # noqa: E402
from thermonet.training.train import TrainConfig, fit  # noqa: E402
from thermonet.workflows.compare import run_compare  # noqa: E402

N_CALLGRIND = 1000
DYN = ["dT", "rate", "play_1"]


def families(gru_params: dict[str, Any] | None = None) -> list[FamilyConfig]:
    return [
        FamilyConfig(family="poly", name="cubic", inputs=["dT"], params={"degree": 3}),
        FamilyConfig(family="poly", name="poly-dyn", inputs=DYN,
                     params={"degree": 3, "cross": True}),
        FamilyConfig(family="rbf", name="rbf", inputs=["dT", "dT2"], params={"n_centres": 16}),
        FamilyConfig(family="rbf", name="rbf-rate", inputs=["dT", "dT2", "rate"],
                     params={"n_centres": 16}),
        FamilyConfig(family="mlp", name="mlp", inputs=["dT"]),
        FamilyConfig(family="mlp", name="mlp-dyn", inputs=DYN),
        FamilyConfig(family="gru", name="gru", inputs=["dT"], params=dict(gru_params or {})),
    ]


def datasets() -> list[tuple[str, CompareConfig, Any]]:
    from thermonet.training.parts import load_data

    items = [("patent-gyro cycling", CompareConfig(families=families(), baseline="cubic"),
              simulate(cycling_device(), seed=0))]
    if "consumer-imu" in PRESETS:
        items.append(("consumer-imu", CompareConfig(families=families(), baseline="cubic"),
                      simulate("consumer-imu", seed=0)))
    cfg = load_config(ROOT / "configs" / "bmi270.yaml")
    cfg.data.paths = [str(ROOT / p) for p in cfg.data.paths]   # repository-relative
    cfg.data.mapping = str(ROOT / str(cfg.data.mapping))
    cfg.families = families({"step_s": 1.0, "warmup": 10, "gap_s": 5.0})
    cfg.baseline = "cubic"
    items.append(("real: BMI270 two soaks", cfg, load_data(cfg.data)))
    return items


def accuracy() -> tuple[list[list], dict]:
    rows, data = [], {}
    for label, cfg, ds in datasets():
        t0 = time.perf_counter()
        res = run_compare(cfg, OUT / "neural" / label.split()[0].strip(":"), overwrite=True,
                          track=False, quiet=True, dataset=ds, plots=False)
        data[label] = {"chosen": res["chosen"], "seconds": time.perf_counter() - t0,
                       "families": res["families"]}
        for name, fam in res["families"].items():
            axes = fam.get("axes") or {}
            rms = [m["rms_comp"] for m in axes.values() if "rms_comp" in m]
            truth = [m["drift_error_rms"] for m in axes.values() if "drift_error_rms" in m]
            cost = fam.get("cost") or {}
            rows.append([label, name + (" (chosen)" if name == res["chosen"] else ""),
                         float(np.mean(rms)) if rms else "failed",
                         float(np.mean(truth)) if truth else "n/a",
                         fam.get("test_score", float("nan")),
                         cost.get("ops_per_sample"), cost.get("c_bytes"),
                         fam.get("fit_seconds", float("nan"))])
        print(f"{label}: chosen {res['chosen']} ({data[label]['seconds']:.0f} s)", flush=True)
    return rows, data


STEP_DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "model.h"
int main(int argc, char **argv) {
    int n = atoi(argv[1]), flag = 0, i, a;
    double raw[THERMONET_N_AXES], comp[THERMONET_N_AXES], drift[THERMONET_N_AXES];
    volatile double sink = 0.0;
    thermonet_state st;
    (void)argc;
    thermonet_init(&st);
    for (a = 0; a < THERMONET_N_AXES; a++) raw[a] = 0.0;
    for (i = 0; i < n; i++) {
        /* 1 s steps; a 0 <-> 40 degC triangle at 1 degC/min */
        double t = 1.7e9 + i;
        float temp = (float)((i / 2400) % 2 ? 40 - (i % 2400) / 60.0 : (i % 2400) / 60.0);
        thermonet_step(&st, t, temp, raw, comp, drift, &flag);
        sink += (double)flag + drift[0];
    }
    printf("%f\n", (double)sink);
    return 0;
}
"""


def c_cost() -> list[list]:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None or shutil.which("valgrind") is None:
        return [["(no cc or valgrind: not measured)", "", "", "", ""]]
    ds = simulate(cycling_device(), runs=1, seed=1)
    rec = ds[0]
    rows = []
    for fc in families():
        spec = FeatureSpec.from_recordings(fc.inputs, [rec])
        s = signal_matrix(rec, spec.signals, spec.gap_s)
        res = fit(family=fc.family, inputs=list(fc.inputs), outputs=ds.axes,
                  train=[(s, target_matrix(rec, ds.axes), rec.time_s)], val=None, spec=spec,
                  hyper=dict(fc.params), config=TrainConfig(max_epochs=5))
        work = OUT / "neural" / f"c_{fc.name}"
        work.mkdir(parents=True, exist_ok=True)
        (work / "model.h").write_text(render_c_header(res.model))
        (work / "driver.c").write_text(STEP_DRIVER)
        subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-o",
                        str(work / "driver"), str(work / "driver.c"), "-lm"], check=True)
        per = (callgrind_ir(work / "driver", N_CALLGRIND, 0)
               - callgrind_ir(work / "driver", 0, 0)) / N_CALLGRIND
        cost = res.model.family.cost()
        rows.append([fc.name, ", ".join(fc.inputs), cost["ops_per_sample"],
                     cost["transcendentals"], round(per),
                     round(per / max(cost["ops_per_sample"] or 1, 1), 2)])
    return rows


def main(parts: list[str]) -> None:
    """``accuracy`` and/or ``cost`` (default both); each saves its own result file."""
    torch.set_num_threads(1)
    (OUT / "neural").mkdir(parents=True, exist_ok=True)
    if "accuracy" in parts:
        rows, data = accuracy()
        md = ("### Held-out error against cost on board (one comparison per data set)\n\n"
              + table(["data", "family", "rms comp (mean of axes)", "rms vs true drift",
                       "test_score", "ops/sample", "c_bytes", "fit s"], rows))
        save("neural_accuracy", {"rows": rows, "results": data}, md)
    if "cost" in parts:
        rows = c_cost()
        md = ("### Counted operations against measured C instructions per `_step` "
              "(callgrind, x86-64, gcc -O2, 3 axes)\n\n"
              + table(["family", "inputs", "ops/sample (counted)", "of which exp calls",
                       "instructions/step (measured)", "instructions / op"], rows))
        save("neural_cost", {"rows": rows}, md)


if __name__ == "__main__":
    main(sys.argv[1:] or ["accuracy", "cost"])
