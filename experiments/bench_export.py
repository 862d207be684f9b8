"""Export benchmarks: ONNX size per family, runtime throughput and latency, C instructions.

Every family is fitted on the `patent-gyro` preset (3 axes; inputs as in
`configs/default.yaml`) and exported.  Then:

* ONNX file size per family (target ≤ 16 KB for the RBF of 16 centres);
* one thread everywhere — onnxruntime (intra/inter-op 1), torch
  (``set_num_threads(1)``) and numpy's BLAS (``OPENBLAS_NUM_THREADS`` etc. set
  before numpy is imported, and threadpoolctl) — on a 100,000-sample batch:
  samples/s of onnxruntime (raw session), of the shipped runtime
  (`export/thermonet_runtime.py`, with its checks), of torch, of the graph
  layout thermonet exported before (per-input broadcasts, ``Where`` for NaN)
  and of numpy evaluating the same RBF three ways (the best is the
  competitor); all timed interleaved, medians of repeats with min–max, the
  ratio onnxruntime / best numpy as the median of per-repeat ratios.  Targets:
  onnxruntime ≥ the best numpy and ≥ 15 M samples/s.  Single-sample call
  latency of each;
* instructions per evaluation of the C header, counted with
  ``valgrind --tool=callgrind`` (repeatable, unlike seconds, and independent of
  the machine's load): a driver evaluates N points; (Ir(N) − Ir(0)) / N.
  Target ≤ 2,000 for the RBF of 16 centres and no more than the previous
  header's (README); study 002 quotes ≈3,200 cycles for its fuzzy model and
  ≈46,800 for a 6th-order polynomial on a 160 MHz DSP.
"""

from __future__ import annotations

import os

# numpy's BLAS reads these when numpy is first imported: one thread, like the others
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import re  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import onnxruntime as ort  # noqa: E402
import torch  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT / "export"))
from common import OUT, fmt_spread, interleaved, ratio_spread, save, spread, table  # noqa: E402
from thermonet.api import DriftEstimator  # noqa: E402
from thermonet.core.trainconfig import TrainConfig  # noqa: E402
from thermonet.exporting import export_c_header, export_onnx  # noqa: E402
from thermonet.models.base import output_layer  # noqa: E402
from thermonet.sim import simulate  # noqa: E402
from thermonet.training.config import SplitConfig  # noqa: E402
from thermonet.training.parts import make_splits  # noqa: E402
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
REPEATS_BATCH = 30
#: Instructions per evaluation of the header before each family owned its emitter
#: (callgrind, README at commit 3b8e19b; callgrind counts do not depend on the load).
PREVIOUS_IR = {"linear": 79, "cubic": 155, "poly6": 256, "lorentz": 122, "ts-fuzzy": 350,
               "rbf16": 1024}
REPEATS_SINGLE = 2000

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


def _consts(model) -> dict:
    """The float32 constants of the RBF's evaluation path, as numpy arrays."""
    with torch.no_grad():
        fam = model.family
        m, b = fam.exponent()
        # the target normalisation and mask folded in, as in the graph; the float64
        # constant is added in float64, as in the graph (``c64``)
        w, c = output_layer(fam.weight, fam.bias, *model.output_scaling())
        w = w.T                                   # (J, A): the (N, K) numpy variants' side
        g = fam.inv_two_sigma2()
        out = {"lo": model.sig_lo, "hi": model.sig_hi, "ref": model.features.ref,
               "mean": model.x_mean, "inv_std": 1.0 / model.x_std, "m": m, "b": b, "w": w,
               "c": c, "centres": fam.centres, "g": g}
        return {**{k: v.numpy().astype(np.float32) for k, v in out.items()},
                "c64": model.constant().numpy().astype(np.float64)}


def rbf_numpy(model, variant: str):
    """The same RBF evaluation in numpy, float32, the graph's outputs (compensated, drift,
    flag, NaN for a non-finite signal; format 2: the float32 drift plus the float64
    constant, and ``raw − drift``, in float64 — what the graph returns) on one signal: ``broadcast`` computes
    ‖z − c‖² by an (N, J, F) broadcast, ``expanded`` by one (N, F+1) × (F+1, J) matrix
    product, ``inplace`` the same with preallocated buffers and in-place operations,
    ``axis-major`` the exported graph's layout ((F+2, N) rows, bias in the product) in
    place."""
    k = _consts(model)
    layout = model.features._layout
    lo, hi = float(k["lo"][0]), float(k["hi"][0])

    def finish(rel: np.ndarray, raw: np.ndarray, s: np.ndarray, t: np.ndarray):
        """float32 (N, A) relative drift (any strides) → the graph's float64 outputs."""
        drift = np.empty(rel.shape, np.float64)
        np.add(rel, k["c64"], out=drift)
        return np.subtract(raw, drift), drift, s != t

    def features(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = np.clip(t, lo, hi)
        cols = []
        for f, (_, squared, relative) in enumerate(layout):
            d = s - k["ref"][f] if relative else s
            x = d * d if squared else d
            cols.append((x - k["mean"][f]) * k["inv_std"][f])
        return s, np.stack(cols, axis=1)

    def broadcast(t: np.ndarray, raw: np.ndarray):
        s, z = features(t)
        d2 = ((z[:, None, :] - k["centres"][None, :, :]) ** 2).sum(-1)
        rel = np.exp(-d2 * k["g"]) @ k["w"] + k["c"] + (t - t)[:, None]
        return finish(rel, raw, s, t)

    def expanded(t: np.ndarray, raw: np.ndarray):
        s, z = features(t)
        u = np.concatenate([z, (z * z).sum(1, keepdims=True)], axis=1)
        rel = np.exp(u @ k["m"] + k["b"]) @ k["w"] + k["c"] + (t - t)[:, None]
        return finish(rel, raw, s, t)

    def features_into(s: np.ndarray, cols: list[np.ndarray], tmp: np.ndarray) -> None:
        """The standardised features of the clamped signal ``s``, in place, into ``cols``."""
        for f, (_, squared, relative) in enumerate(layout):
            np.subtract(s, k["ref"][f] if relative else 0.0, out=tmp)
            if squared:
                np.multiply(tmp, tmp, out=tmp)
            np.subtract(tmp, k["mean"][f], out=tmp)
            np.multiply(tmp, k["inv_std"][f], out=cols[f])

    def inplace(t: np.ndarray, raw: np.ndarray):
        n, nf = t.shape[0], len(layout)
        s = np.clip(t, lo, hi)
        u = np.empty((n, nf + 1), np.float32)
        tmp = np.empty(n, np.float32)
        features_into(s, [u[:, f] for f in range(nf)], tmp)
        np.einsum("nf,nf->n", u[:, :nf], u[:, :nf], out=u[:, nf])
        np.subtract(t, t, out=tmp)
        u[:, 0] += tmp                     # NaN for a non-finite signal, as in the graph
        e = u @ k["m"]
        e += k["b"]
        np.exp(e, out=e)
        drift = e @ k["w"]
        drift += k["c"]
        return finish(drift, raw, s, t)

    m4 = np.concatenate([k["m"].T, k["b"][:, None]], axis=1)     # (J, F + 2)
    wt, ct = np.ascontiguousarray(k["w"].T), k["c"][:, None]      # (A, J), (A, 1)

    def axis_major(t: np.ndarray, raw: np.ndarray):
        n, nf = t.shape[0], len(layout)
        s = np.clip(t, lo, hi)
        u = np.empty((nf + 2, n), np.float32)     # rows z_1..z_F, ‖z‖², 1: the graph's layout
        tmp = np.empty(n, np.float32)
        features_into(s, list(u[:nf]), tmp)
        np.multiply(u[0], u[0], out=u[nf])
        for f in range(1, nf):
            np.multiply(u[f], u[f], out=tmp)
            u[nf] += tmp
        u[nf + 1] = 1.0
        np.subtract(t, t, out=tmp)
        u[0] += tmp                        # NaN for a non-finite signal, as in the graph
        e = m4 @ u
        np.exp(e, out=e)
        drift = wt @ e
        drift += ct
        return finish(drift.T, raw, s, t)

    return {"broadcast": broadcast, "expanded": expanded, "inplace": inplace,
            "axis-major": axis_major}[variant]


class _PreviousLayout(torch.nn.Module):
    """The graph thermonet exported before this layout, for comparison in the same run:
    stacked (N, S) signals, isnan/isinf + ``Where`` for NaN, (N, 1) feature columns, one
    (N, J) broadcast per input for the RBF distance, de-standardisation after the matmul."""

    def __init__(self, model) -> None:
        super().__init__()
        self.m = model

    def forward(self, t: torch.Tensor, raw: torch.Tensor):
        m, fam = self.m, self.m.family
        sig = torch.stack([t], dim=1)
        nonfinite = (torch.isnan(sig) | torch.isinf(sig)).any(dim=1)
        flag = ~((sig >= m.sig_lo) & (sig <= m.sig_hi)).all(dim=1) | nonfinite
        s = torch.minimum(torch.maximum(sig, m.sig_lo), m.sig_hi)
        d = s.index_select(1, m.features.index) - m.features.ref
        x = d * (d * m.features.square + (1.0 - m.features.square))
        z = (x - m.x_mean) / m.x_std
        diff = z[:, 0:1] - fam.centres[:, 0]
        d2 = diff * diff
        for f in range(1, fam.n_inputs):
            diff = z[:, f:f + 1] - fam.centres[:, f]
            d2 = d2 + diff * diff
        two_sigma2 = 2.0 * torch.exp(torch.clamp(2.0 * fam.log_sigma, min=-60.0, max=60.0))
        yz = torch.exp(-d2 / two_sigma2) @ fam.weight.T + fam.bias
        rel = yz * m.y_std + m.y_mean
        rel = torch.where(nonfinite.unsqueeze(1), torch.full_like(rel, float("nan")), rel)
        drift = rel.to(torch.float64) + m.constant()   # format 2: the constant in float64
        return raw.to(torch.float64) - drift, drift, flag


def export_previous_layout(model, path: Path) -> Path:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prog = torch.onnx.export(
            _PreviousLayout(model).eval(), (torch.zeros(4), torch.zeros(4, 3, dtype=torch.float64)),
            None,
            input_names=["temperature_c", "raw"], output_names=["compensated", "drift", "flag"],
            opset_version=18, dynamo=True, external_data=False, optimize=True,
            dynamic_shapes=({0: torch.export.Dim("N")}, {0: torch.export.Dim("N")}))
    prog.save(str(path))
    return path


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
        rows.append([label, model.n_params, size, "n/a" if ir is None else f"{ir:.0f}",
                     PREVIOUS_IR[label]])
    md = ["### Export size and C cost per family (patent-gyro, 3 axes)\n",
          table(["family", "params", "ONNX bytes", "C instructions / eval (callgrind)",
                 "before (3b8e19b)"], rows),
          "\nStudy 002 (TMS320VC5416 at 160 MHz, one axis): fuzzy ≈3,200 cycles, 6th-order "
          "polynomial ≈46,800 cycles per evaluation.\n"]

    md.append(throughput(models["rbf16"], work, data))
    save("export", data, "\n".join(md))


def throughput(model, work: Path, data: dict) -> str:
    """One thread, 100k batch, interleaved: onnxruntime vs the runtime, torch, the previous
    graph layout and numpy; single-sample latency of each."""
    rng = np.random.default_rng(0)
    lo, hi = float(model.sig_lo[0]), float(model.sig_hi[0])
    temps = rng.uniform(lo, hi, BATCH).astype(np.float32)
    raw = np.zeros((BATCH, len(model.outputs)))   # float64 (ONNX format 2)
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    sess = ort.InferenceSession(str(work / "rbf16.onnx"), opts,
                                providers=["CPUExecutionProvider"])
    prev = ort.InferenceSession(str(export_previous_layout(model, work / "rbf16_previous.onnx")),
                                opts, providers=["CPUExecutionProvider"])
    comp = Compensator(work / "rbf16.onnx", threads=1)
    numpys = {v: rbf_numpy(model, v) for v in ("broadcast", "expanded", "inplace", "axis-major")}

    def torch_eval(t: np.ndarray, r: np.ndarray):
        with torch.no_grad():     # the graph's outputs: float64 drift and compensated
            d = model.drift64(torch.from_numpy(t)[:, None])
            return torch.from_numpy(r) - d, d

    # every competitor must compute the same drift (and NaN) as the exported graph
    check = np.concatenate([temps[:1000], np.float32([np.nan, np.inf])])
    zeros = np.zeros((check.size, 3))    # float64 raw (ONNX format 2)
    raw_check = rng.normal(0.0, 1.0, (check.size, 3))
    c_ref, d_ref, _ = sess.run(None, {"temperature_c": check, "raw": raw_check})
    scale = np.abs(d_ref[:-2]).max()
    for name, fn in {**{f"numpy '{k}'": f for k, f in numpys.items()}, "torch": torch_eval}.items():
        c_got, got = (np.asarray(v) for v in fn(check, raw_check)[:2])
        if got.dtype != np.float64 or c_got.dtype != np.float64 \
                or np.abs(got[:-2] - d_ref[:-2]).max() > 1e-5 * scale \
                or np.abs(c_got[:-2] - c_ref[:-2]).max() > 1e-5 * scale \
                or not np.isnan(got[-2:]).all():
            raise RuntimeError(f"{name} does not compute the exported float64 outputs")
    d_prev = prev.run(None, {"temperature_c": check[:-2], "raw": zeros[:-2]})[1]
    if np.abs(d_prev - d_ref[:-2]).max() > 1e-5 * scale:
        raise RuntimeError("the previous layout does not compute the same drift")

    def feeds(n: int) -> dict:
        return {"temperature_c": temps[:n], "raw": raw[:n]}

    def evaluators(n: int) -> dict:
        return {
            "onnxruntime session (this layout)": lambda: sess.run(None, feeds(n)),
            "onnxruntime session (previous layout)": lambda: prev.run(None, feeds(n)),
            "thermonet runtime (checks included)":
                lambda: comp.compensate(temperature_c=temps[:n], raw=raw[:n]),
            "torch": lambda: torch_eval(temps[:n], raw[:n]),
            **{f"numpy, {v}": (lambda f=fn: f(temps[:n], raw[:n])) for v, fn in numpys.items()},
        }

    cpu: dict[str, list[float]] = {}
    cpu1: dict[str, list[float]] = {}
    with threadpool_limits(1):
        batch = interleaved(evaluators(BATCH), repeats=REPEATS_BATCH, warmup=2, cpu=cpu)
        single = interleaved(evaluators(1), repeats=REPEATS_SINGLE, warmup=20, cpu=cpu1)
    ort_name = "onnxruntime session (this layout)"
    numpy_names = [k for k in batch if k.startswith("numpy")]
    best_numpy = min(numpy_names, key=lambda k: spread(cpu[k])["median"])
    vs_numpy = ratio_spread(cpu[best_numpy], cpu[ort_name])
    vs_numpy_wall = ratio_spread(batch[best_numpy], batch[ort_name])
    vs_prev = ratio_spread(cpu["onnxruntime session (previous layout)"], cpu[ort_name])
    rows = []
    for name in batch:
        rows.append([name + (" — best numpy" if name == best_numpy else ""),
                     fmt_spread(spread([BATCH / t / 1e6 for t in cpu[name]])),
                     fmt_spread(spread([BATCH / t / 1e6 for t in batch[name]])),
                     fmt_spread(spread(cpu1[name]), 1e6), fmt_spread(spread(single[name]), 1e6)])
    data["throughput"] = {
        "batch": BATCH, "repeats": REPEATS_BATCH,
        "evaluators": {k: {"batch_wall_seconds": spread(batch[k]),
                           "batch_cpu_seconds": spread(cpu[k]),
                           "msamples_per_cpu_s": spread([BATCH / t / 1e6 for t in cpu[k]]),
                           "msamples_per_wall_s": spread([BATCH / t / 1e6 for t in batch[k]]),
                           "single_cpu_seconds": spread(cpu1[k]),
                           "single_wall_seconds": spread(single[k])} for k in batch},
        "best_numpy": best_numpy,
        "onnxruntime_over_best_numpy_cpu": vs_numpy,
        "onnxruntime_over_best_numpy_wall": vs_numpy_wall,
        "onnxruntime_over_previous_layout_cpu": vs_prev,
    }
    return ("### RBF (16 centres, 3 axes) evaluation on one thread, 100k batch\n\n"
            f"Medians of {REPEATS_BATCH} interleaved repeats (min–max); single-sample calls: "
            f"{REPEATS_SINGLE} repeats.  Per CPU second (the process's CPU time: the work, "
            "nearly independent of other load) and per wall second.\n\n"
            + table(["evaluator", "M samples / CPU s", "M samples / wall s",
                     "single-sample CPU µs", "single-sample wall µs"], rows)
            + f"\n\nonnxruntime / best numpy ({best_numpy}), per-repeat ratios: "
            f"**{fmt_spread(vs_numpy)}×** in CPU time, {fmt_spread(vs_numpy_wall)}× in wall "
            f"time; this layout / previous layout: **{fmt_spread(vs_prev)}×** (CPU time).\n")


if __name__ == "__main__":
    main()
