"""Export benchmarks: ONNX size per family, runtime throughput and latency, C instructions.

Every family is fitted on the `patent-gyro` preset (3 axes; inputs as in
`configs/default.yaml`) and exported.  Then:

* ONNX file size per family (target ≤ 16 KB for the RBF of 16 centres);
* one thread, a 100,000-sample batch: samples/s of onnxruntime (raw session),
  of the shipped runtime (`export/thermonet_runtime.py`, with its checks), of
  torch, and of numpy evaluating the same RBF (target ≥ 2 M samples/s for
  onnxruntime); single-sample call latency of each;
* instructions per evaluation of the C header, counted with
  ``valgrind --tool=callgrind`` (repeatable, unlike seconds): a driver
  evaluates N points; (Ir(N) − Ir(0)) / N.  Target ≤ 2,000 for the RBF of 16
  centres; study 002 quotes ≈3,200 cycles for its fuzzy model and ≈46,800 for
  a 6th-order polynomial on a 160 MHz DSP.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT / "export"))
from common import OUT, save, table  # noqa: E402
from thermonet.api import DriftEstimator  # noqa: E402
from thermonet.config import SplitConfig  # noqa: E402
from thermonet.evaluate import make_splits  # noqa: E402
from thermonet.exporting import export_c_header, export_onnx  # noqa: E402
from thermonet.sim import simulate  # noqa: E402
from thermonet.trainconfig import TrainConfig  # noqa: E402
from thermonet_runtime import Compensator  # noqa: E402

FAMILIES = {
    "linear": ("linear", ["dT"], {}),
    "cubic": ("poly", ["dT"], {"degree": 3}),
    "poly6": ("poly", ["dT"], {"degree": 6}),
    "lorentz": ("lorentz", ["dT"], {}),
    "ts-fuzzy": ("ts-fuzzy", ["dT"], {"n_sets": 6}),
    "rbf16": ("rbf", ["dT", "dT2"], {"n_centres": 16}),
}
BATCH = 100_000
N_CALLGRIND = 1000

DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "model.h"
int main(int argc, char **argv) {
    int n = atoi(argv[1]);
    float lo = (float)atof(argv[2]), hi = (float)atof(argv[3]);
    float sig[THERMONET_N_SIGNALS];
    double raw[THERMONET_N_AXES], comp[THERMONET_N_AXES], drift[THERMONET_N_AXES];
    volatile double sink = 0.0;
    for (int a = 0; a < THERMONET_N_AXES; a++) raw[a] = 0.0;
    for (int i = 0; i < n; i++) {
        for (int s = 0; s < THERMONET_N_SIGNALS; s++) sig[s] = lo + (hi - lo) * (float)i / (float)(n + 1);
        sink += (double)thermonet_compensate(sig, raw, comp, drift) + drift[0];
    }
    printf("%f\n", (double)sink);
    return 0;
}
"""


def fitted_models() -> dict:
    ds = simulate("patent-gyro", runs=3, seed=0)
    split = make_splits(ds, SplitConfig())[0]
    models = {}
    for label, (family, inputs, hyper) in FAMILIES.items():
        est = DriftEstimator(family, inputs, train=TrainConfig(max_epochs=100, patience=20),
                             **hyper)
        models[label] = est.fit(split.train, val=split.val).model_
    return models


def rbf_numpy(model):
    """The same RBF in numpy (float32), for the throughput comparison."""
    p = {k: v.detach().numpy().astype(np.float32) for k, v in model.state_dict().items()}
    lo, hi = p["sig_lo"], p["sig_hi"]
    ref, square = p["features.ref"], p["features.square"]
    idx = model.features.index.numpy()
    c, sigma2 = p["family.centres"], np.exp(2 * p["family.log_sigma"])
    w, b = p["family.weight"], p["family.bias"]
    const = model.constant().detach().numpy().astype(np.float32)   # the target's constant

    def run(signals: np.ndarray) -> np.ndarray:
        s = np.clip(signals, lo, hi)
        d = s[:, idx] - ref
        x = d * (d * square + (1 - square))
        z = (x - p["x_mean"]) / p["x_std"]
        d2 = ((z[:, None, :] - c[None, :, :]) ** 2).sum(-1)
        phi = np.exp(-d2 / (2 * sigma2))
        return (phi @ w.T + b) * p["y_std"] + p["y_mean"] + const
    return run


def rate(fn, *args, repeats: int = 20) -> float:
    fn(*args)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def callgrind_ir(binary: Path, n: int, lo: float, hi: float) -> int:
    out = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null",
                          str(binary), str(n), repr(lo), repr(hi)],
                         capture_output=True, text=True, check=True)
    m = re.search(r"Collected\s*:\s*(\d+)", out.stderr)
    if not m:
        raise RuntimeError("callgrind printed no 'Collected' line:\n" + out.stderr[-500:])
    return int(m.group(1))


def main() -> None:
    torch.set_num_threads(1)
    work = OUT / "export"
    work.mkdir(parents=True, exist_ok=True)
    models = fitted_models()
    rows, data = [], {}
    have_valgrind = shutil.which("valgrind") is not None
    for label, model in models.items():
        path = export_onnx(model, work / f"{label}.onnx", metadata={"device_id": "patent-gyro"})
        size = path.stat().st_size
        lo, hi = (float(v) for v in (model.sig_lo[0], model.sig_hi[0]))
        ir = None
        if have_valgrind:
            hdir = work / f"c_{label}"
            hdir.mkdir(exist_ok=True)
            export_c_header(model, hdir / "model.h")
            (hdir / "driver.c").write_text(DRIVER)
            subprocess.run(["gcc", "-std=c99", "-O2", "-o", str(hdir / "driver"),
                            str(hdir / "driver.c"), "-lm"], check=True, cwd=hdir)
            ir = (callgrind_ir(hdir / "driver", N_CALLGRIND, lo, hi)
                  - callgrind_ir(hdir / "driver", 0, lo, hi)) / N_CALLGRIND
        data[label] = {"onnx_bytes": size, "c_instructions_per_eval": ir,
                       "n_params": model.n_params}
        rows.append([label, model.n_params, size, "n/a" if ir is None else f"{ir:.0f}"])
    md = ["### Export size and C cost per family (patent-gyro, 3 axes)\n",
          table(["family", "params", "ONNX bytes", "C instructions / eval (callgrind)"], rows),
          "\nStudy 002 (TMS320VC5416 at 160 MHz, one axis): fuzzy ≈3,200 cycles, 6th-order "
          "polynomial ≈46,800 cycles per evaluation.\n"]

    # throughput and latency for the RBF of 16 centres
    model = models["rbf16"]
    rng = np.random.default_rng(0)
    lo, hi = float(model.sig_lo[0]), float(model.sig_hi[0])
    temps = rng.uniform(lo, hi, BATCH).astype(np.float32)
    raw = np.zeros((BATCH, len(model.outputs)))   # float64 (ONNX format 2)
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    sess = ort.InferenceSession(str(work / "rbf16.onnx"), opts, providers=["CPUExecutionProvider"])
    feeds = {"temperature_c": temps, "raw": raw}
    comp = Compensator(work / "rbf16.onnx", threads=1)
    npf = rbf_numpy(model)
    sig_t = torch.as_tensor(temps[:, None])
    sig_n = temps[:, None]

    def torch_eval(s):
        with torch.no_grad():
            return model(s)

    # the numpy evaluator is only a fair competitor if it computes the same drift
    ref = torch_eval(sig_t[:1000]).numpy()
    worst = float(np.max(np.abs(npf(sig_n[:1000]) - ref)) / np.max(np.abs(ref)))
    if worst > 1e-5:
        raise RuntimeError(f"numpy RBF differs from torch by {worst:.3g} (relative)")

    res = {
        "onnxruntime (session)": (rate(sess.run, None, feeds),
                                  rate(sess.run, None, {"temperature_c": temps[:1], "raw": raw[:1]},
                                       repeats=2000)),
        "thermonet runtime": (rate(lambda: comp.compensate(temperature_c=temps, raw=raw)),
                              rate(lambda: comp.compensate(temperature_c=temps[0], raw=raw[0]),
                                   repeats=2000)),
        "torch": (rate(torch_eval, sig_t), rate(torch_eval, sig_t[:1], repeats=2000)),
        "numpy": (rate(npf, sig_n), rate(npf, sig_n[:1], repeats=2000)),
    }
    base = res["torch"][0]
    trows = [[name, BATCH / t_batch / 1e6, base / t_batch, t_one * 1e6]
             for name, (t_batch, t_one) in res.items()]
    md += ["### RBF (16 centres, 3 axes) evaluation on one thread\n",
           table(["evaluator", "M samples/s (100k batch)", "× torch", "single-sample µs"], trows)]
    data["throughput"] = {
        k: {"batch_seconds": v[0], "single_seconds": v[1]} for k, v in res.items()
    }
    save("export", data, "\n".join(md))


if __name__ == "__main__":
    main()
