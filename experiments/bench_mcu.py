"""The C header on a microcontroller: instructions per evaluation on an emulated Cortex-M4F.

Every family fitted on the ``consumer-imu`` preset (6 axes: 3 gyro, 3 accelerometer) and
exported; each header is cross-compiled with Debian's ``arm-none-eabi-gcc`` (``-O2``,
strict warnings) and run under the ``unicorn`` emulator (``thermonet.exporting.mcu``):

* **Cortex-M4F** (``-mcpu=cortex-m4 -mfpu=fpv4-sp-d16 -mfloat-abi=hard``), the header's float
  path (its default there): Thumb instructions executed per ``<prefix>_compensate`` (median,
  min and max over a temperature sweep — exact counts, no timing), how many of them ran in
  soft-double and libm routines, code bytes (``.text`` of the object: instructions and their
  literal pools, where gcc puts the model's constants) and ``.rodata`` bytes, and the
  ``<prefix>_step`` of the streaming form;
* the same header with ``-DTHERMONET_USE_DOUBLE`` on the M4F: what the header computed before
  it selected its arithmetic (double raw/drift, libm ``expf``), for comparison;
* **Cortex-M0+** (no FPU; the ARMv6-M code runs on the emulated M4 core, a superset): the
  float path in soft-float, and **Cortex-M7** (``fpv5-d16``): built, code bytes;
* **x86-64**: the same header on the host (its double path), instructions per evaluation
  counted with callgrind as ``bench_export.py`` counts them;
* the emulated outputs against torch over the sweep (41 temperatures from 5 % below to 5 %
  above the trained range, the other signals inside it): worst error as a fraction of the
  export's parity tolerance (``float32_tolerance``: 1e-5 of the axis's largest drift, or 4×
  torch's own float32 rounding where the model is more sensitive) plus the float path's
  rounding of drift = c + r (``float_path_slack``); the forced-double build is checked too.

Goals: cubic ≤ 150 instructions per evaluation for 6 axes, 16-centre RBF ≤ 1,000,
no soft-double instruction on the M4F.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_export import DRIVER as X86_DRIVER  # noqa: E402
from bench_export import callgrind_ir  # noqa: E402
from common import OUT, git_rev, save, table  # noqa: E402
from thermonet.exporting import render_c_header  # noqa: E402
from thermonet.exporting.c_stream import float_path_slack  # noqa: E402
from thermonet.exporting.c_stream_render import stream_signature_has_proxies  # noqa: E402
from thermonet.exporting.mcu import Emulator, cross_compile, toolchain  # noqa: E402
from thermonet.exporting.parity import float32_tolerance  # noqa: E402
from thermonet.features import dynamics  # noqa: E402
from thermonet.features.inputs import FeatureSpec, signal_matrix, target_matrix  # noqa: E402
from thermonet.sim import simulate  # noqa: E402
from thermonet.training.train import TrainConfig, fit  # noqa: E402

FAMILIES = {
    "linear": ("linear", ["dT"], {}),
    "cubic": ("poly", ["dT"], {"degree": 3}),
    "poly, degree 6": ("poly", ["dT"], {"degree": 6}),
    "lorentz": ("lorentz", ["dT"], {}),
    "ts-fuzzy (6 sets)": ("ts-fuzzy", ["dT"], {"n_sets": 6}),
    "rbf, 16 centres [dT, dT2]": ("rbf", ["dT", "dT2"], {"n_centres": 16}),
    # the default family set's RBF: the cubic in ΔT as its unpenalised tail
    "rbf, 16 centres [dT, dT2], cubic tail": ("rbf", ["dT", "dT2"],
                                              {"n_centres": 16, "tail": 3}),
    "cubic + rate, cross terms": ("poly", ["dT", "rate"], {"degree": 3, "cross": True}),
    "rbf, 16 centres [dT, dT2, rate]": ("rbf", ["dT", "dT2", "rate"], {"n_centres": 16}),
}
N_SWEEP = 41
GOALS = {"cubic": 150, "rbf, 16 centres [dT, dT2]": 1000}


def fitted_models() -> dict:
    ds = simulate("consumer-imu", runs=1, seed=0)
    rec = ds[0]
    models = {}
    for label, (family, inputs, hyper) in FAMILIES.items():
        spec = FeatureSpec.from_recordings(inputs, [rec])
        s = signal_matrix(rec, spec.signals, spec.gap_s)
        y = target_matrix(rec, ds.axes)
        models[label] = fit(family=family, inputs=inputs, outputs=ds.axes, train=[(s, y)],
                            val=None, spec=spec, hyper=hyper,
                            config=TrainConfig(max_epochs=30, seed=0)).model
    return models


def sweep(model) -> np.ndarray:
    lo = model.sig_lo.numpy().astype(np.float64)
    hi = model.sig_hi.numpy().astype(np.float64)
    pts = np.tile(lo + 0.4 * (hi - lo), (N_SWEEP, 1))
    j = list(model.signals).index("temperature_c")
    pts[:, j] = np.linspace(lo[j] - 0.05 * (hi[j] - lo[j]), hi[j] + 0.05 * (hi[j] - lo[j]),
                            N_SWEEP)
    return pts.astype(np.float32)


def kinds(emu: Emulator, by_function: dict[str, int]) -> dict[str, int]:
    out = {"header": 0, "soft-double": 0, "libm": 0, "other": 0}
    for name, n in by_function.items():
        out[emu.function_kind(name)] += n
    return out


def measure(label: str, model, work: Path) -> dict:
    text = render_c_header(model)
    prox = stream_signature_has_proxies(model)
    n_sig, n_ax = len(model.signals), len(model.outputs)
    pts = sweep(model)
    const = model.constant().double().numpy()
    with torch.no_grad():
        want = model.relative(torch.from_numpy(pts)).double().numpy()
    raw = np.round(const)
    out: dict = {"label": label, "n_axes": n_ax}
    for name, target, extra in (("m4f", "cortex-m4f", ()),
                                ("m4f_double", "cortex-m4f", ("-DTHERMONET_USE_DOUBLE",)),
                                ("m0plus", "cortex-m0plus", ())):
        build = cross_compile(text, target, work / f"{name}", has_proxies=prox, extra=extra)
        emu = Emulator(build, n_sig, n_ax)
        runs = [emu.evaluate(p, raw, count=True) for p in pts]
        ins = np.array([r.instructions for r in runs])
        per_kind = [kinds(emu, r.by_function) for r in runs]
        drift = np.array([r.drift for r in runs]) - const
        tol = float32_tolerance(model, pts, want) + float_path_slack(const, want)
        worst = float(np.max(np.abs(drift - want) / tol))
        # the streaming step: steady state (after the first sample), 1 s apart
        t_us = 1_700_000_000_000_000
        temp_idx = list(model.signals).index("temperature_c")
        proxies = None
        if prox:
            dyn = {d.signal for d in dynamics.dynamic_signals(model.inputs)}
            proxies = np.array([pts[0][i] for i, s in enumerate(model.signals)
                                if s != "temperature_c" and s not in dyn])
        steps = []
        for k, temp in enumerate(pts[:, temp_idx]):
            time = t_us + k * 1_000_000 if build.flags and "-DTHERMONET_USE_DOUBLE" not in \
                build.flags else 1.7e9 + k
            steps.append(emu.step(time, float(temp), raw, proxies, count=True).instructions)
        out[name] = {
            "instructions": {"median": float(np.median(ins)), "min": int(ins.min()),
                             "max": int(ins.max())},
            "by_kind_median": {k: float(np.median([p[k] for p in per_kind]))
                               for k in per_kind[0]},
            "step_instructions_median": float(np.median(steps[1:])),
            "code_bytes": build.code_bytes, "const_bytes": build.const_bytes,
            "linked_library_bytes": emu.library_code_bytes,
            "undefined": build.undefined, "soft_double_symbols": build.soft_double,
            "worst_error_over_tolerance": worst,
        }
    out["x86"] = x86_instructions(model, text, work / "x86")
    m7 = cross_compile(text, "cortex-m7", work / "m7", has_proxies=prox)
    out["m7"] = {"code_bytes": m7.code_bytes, "const_bytes": m7.const_bytes,
                 "soft_double_symbols": m7.soft_double, "undefined": m7.undefined}
    return out


def x86_instructions(model, text: str, work: Path) -> float | None:
    """The same header on the host (x86-64, its double path, gcc -O2), counted with
    callgrind as ``bench_export.py`` counts it: (Ir(N) − Ir(0)) / N."""
    if shutil.which("valgrind") is None:
        return None
    work.mkdir(parents=True, exist_ok=True)
    (work / "model.h").write_text(text)
    (work / "driver.c").write_text(X86_DRIVER)
    subprocess.run(["gcc", "-std=c99", "-O2", "-o", str(work / "driver"),
                    str(work / "driver.c"), "-lm"], check=True, cwd=work)
    lo, hi = (float(v) for v in (model.sig_lo[0], model.sig_hi[0]))
    n = 1000
    return (callgrind_ir(work / "driver", n, lo, hi) - callgrind_ir(work / "driver", 0, lo, hi)) / n


def main() -> None:
    tools = toolchain()
    version = subprocess.run([tools["gcc"], "--version"], capture_output=True, text=True,
                             check=True).stdout.splitlines()[0]
    import unicorn

    torch.set_num_threads(1)
    models = fitted_models()
    work = OUT / "mcu"
    results = [measure(label, m, work / f"m{i}") for i, (label, m) in enumerate(models.items())]
    rows = []
    for r in results:
        m4, dbl, m0 = r["m4f"], r["m4f_double"], r["m0plus"]
        goal = GOALS.get(r["label"])
        rows.append([
            r["label"],
            f"{m4['instructions']['median']:,.0f} ({m4['instructions']['min']:,}–"
            f"{m4['instructions']['max']:,})" + (f" (goal ≤ {goal:,})" if goal else ""),
            f"{m4['by_kind_median']['soft-double']:,.0f}",
            f"{m4['step_instructions_median']:,.0f}",
            f"{m4['code_bytes']:,} + {m4['const_bytes']:,}",
            f"{dbl['instructions']['median']:,.0f} "
            f"({dbl['by_kind_median']['soft-double']:,.0f} soft-double, "
            f"{dbl['by_kind_median']['libm']:,.0f} libm)",
            f"{m0['instructions']['median']:,.0f}",
            f"{r['m7']['code_bytes']:,}",
            "n/a" if r["x86"] is None else f"{r['x86']:,.0f}",
            f"{max(b['worst_error_over_tolerance'] for b in (m4, m0, dbl)):.3f}",
        ])
    md = (f"Compiler: {version}, `-O2`; emulator: unicorn {unicorn.__version__} "
          f"(Cortex-M4 with FPU); code at {git_rev()}; 6 axes (consumer-imu).\n\n"
          + table(["model", "M4F instructions / evaluation, median (min–max)",
                   "of which soft-double", "M4F step()", "M4F code + .rodata bytes",
                   "M4F forced double (before)", "M0+ instructions (soft-float)",
                   "M7 code bytes", "x86-64 instructions (callgrind)",
                   "worst error / tolerance"], rows))
    save("mcu", {"compiler": version, "unicorn": unicorn.__version__, "results": results}, md)


if __name__ == "__main__":
    main()
