"""The full sensor model (``model: sensor``) streamed: the C header's ``step()`` and
``step_block()`` and the torch-free runtime's ``step``/``step_block`` on a sensor-model ONNX
file, against torch.

Two models are fitted on the ``imu-multiposition`` preset through the training function
(:func:`thermonet.training.sensor.fit_sensor`): a cubic in ΔT (no state: ``step`` is
``compensate`` behind the time guard) and a quadratic in ΔT and the dynamic input ``rate``
(``step`` keeps the rate's state). Every stream is the held-out recording itself (its raw
outputs, its temperature), moved to Unix-epoch time, with a gap and a missing temperature
put in. The reference is torch's :meth:`~thermonet.models.sensor.SensorModel.columns` on the
float64 dynamic inputs of :func:`thermonet.features.dynamics.compute`; onnxruntime runs the
exported graph on the same stream. Tolerances are :mod:`tolerances`': float32 depth × ε32 at
the magnitude of what the drift sums (|b| + Σ|E||x| per axis, x = M⁻¹(raw − b)), plus on the
float path the 3 × 3 solve's float rounding at raw's magnitude (``affine`` depth).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import load_runtime
from thermonet.core.errors import ExportError
from thermonet.core.trainconfig import TrainConfig
from thermonet.exporting.c_stream import REAL_FLAGS, run_stream_c
from thermonet.exporting.c_stream_render import step_signature_c
from thermonet.exporting.sensor_c import (
    export_sensor_c,
    render_sensor_c,
    sample_terms,
    sensor_c_parity,
    sensor_stream_parity,
)
from thermonet.exporting.sensor_export import export_sensor_onnx
from thermonet.features import dynamics
from thermonet.models.sensor import triads_of
from thermonet.sim import simulate
from thermonet.training.pipeline import split_spec
from thermonet.training.sensor import fit_sensor, sensor_run
from tolerances import assert_f32_close, f32_atol

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

rt = load_runtime()

#: the two models: name -> (inputs, hyper-parameters of the poly family)
MODELS = {"static": (["dT"], {"degree": 3}),
          "rate": (["dT", "rate"], {"degree": 2, "cross": True})}
T0 = 1.7e9          # Unix-epoch seconds: a step of 5 s on it needs double (or integer µs)


@pytest.fixture(scope="module")
def data():
    return simulate("imu-multiposition", runs=3, seed=0)


@pytest.fixture(scope="module", params=list(MODELS))
def fitted(request, data, tmp_path_factory):
    """(name, model, ONNX path) of one of :data:`MODELS`, fitted on runs 0-1 (run 2 the
    validation run), exported through the checked ONNX export."""
    inputs, hyper = MODELS[request.param]
    outputs = [o for t in triads_of(sorted(data.runs[0].outputs)) for o in t]
    spec = split_spec(inputs, data.runs[:2])
    runs = [sensor_run(r, spec, outputs) for r in data.runs]
    fit = fit_sensor(family="poly", spec=spec, outputs=outputs, triads=triads_of(outputs),
                     train=runs[:2], val=runs[2], hyper=hyper,
                     config=TrainConfig(max_epochs=5, seed=0))
    path = tmp_path_factory.mktemp(f"sensor_{request.param}") / "sensor.onnx"
    export_sensor_onnx(fit.model, path)
    return request.param, fit.model, path


def _stream(model, data):
    """The held-out run as a stream: time from T0, a gap of 3 gap_s half-way, the
    temperature missing at a third; raw = its recorded outputs (the model's axis order)."""
    rec = data.runs[2]
    gap_s = float(model.bias.spec.gap_s or dynamics.DEFAULT_GAP_S)
    n = rec.n_samples
    t = T0 + rec.time_s.astype(np.float64)
    t[n // 2:] += 3.0 * gap_s
    temp = rec.temperature_c.astype(np.float64).copy()
    temp[n // 3] = np.nan
    raw = np.stack([rec.outputs[o] for o in model.outputs], 1).astype(np.float64)
    return t, temp, raw


def _torch(model, t, temp, raw):
    """Torch on the stream: compensated (N, O), the out-of-range flag, the gap flags of the
    dynamic inputs and, per sample and axis, |b| + Σ_c |E_ac| |x_c| (x = compensated)."""
    gap_s = float(model.bias.spec.gap_s or dynamics.DEFAULT_GAP_S)
    dyn, gap = dynamics.compute(t, temp, model.bias.inputs, gap_s)
    cols = {"temperature_c": temp, **dyn}
    s = np.column_stack([cols[x] for x in model.signals])
    with torch.no_grad():
        s32 = torch.as_tensor(s, dtype=torch.float32)
        comp, flag = model.columns(s32.unbind(1), torch.as_tensor(raw))
        b = model.bias.drift64(s32).numpy()
        e = model.elements.drift64(s32).numpy()
    comp = comp.numpy()
    terms = sample_terms(model, b, e, comp)
    has_state = bool(dynamics.dynamic_signals(model.bias.inputs))
    return {"compensated": comp, "drift": raw - comp, "flag": flag.numpy(), "signals": s,
            "gap": gap if has_state else np.zeros(t.size, dtype=bool),
            "terms": np.where(np.isfinite(terms), terms, 0.0)}


def _assert_close(got, want, tol, what):
    """NaN at the same places, elsewhere |got − want| ≤ tol (per axis)."""
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want), err_msg=f"NaN places {what}")
    err = np.where(np.isnan(want), 0.0, np.abs(got - want))
    assert (err <= tol).all(), (what, float((err / tol).max()))


def _away_from_edges(model, s):
    """Samples whose every signal is finite and more than 1e-3 of its trained span from an
    edge: there a float32 recursion and a float64 one decide the range flag alike."""
    lo, hi = model.bias.sig_lo.double().numpy(), model.bias.sig_hi.double().numpy()
    margin = 1e-3 * np.maximum(hi - lo, 1e-12)
    near = (np.abs(s - lo) <= margin) | (np.abs(s - hi) <= margin)
    return np.isfinite(s).all(axis=1) & ~near.any(axis=1)


# -- the header's text ----------------------------------------------------------------------
def test_header_has_the_interface_of_every_header(fitted):
    """One state, init, step and step_block under the prefix, with the bias model's step
    signature (no proxies here); the two bodies keep no stream of their own."""
    name, model, _ = fitted
    text = render_sensor_c(model, prefix="imu")
    assert text.count("} imu_state;") == 1 and text.count("_state;") == 1
    assert "\n".join(step_signature_c("imu", False)) in text
    assert "static inline int imu_step_block(imu_state *st, int n, const thermonet_time_t " \
           "*time_s," in text
    assert "static inline void imu_init(imu_state *st)" in text
    assert "imu_bias_step" not in text and "imu_elem_step" not in text
    assert "*flag = imu_compensate(s, raw, compensated, drift) | gap;" in text
    assert f"#define IMU_N_DYNAMIC {1 if name == 'rate' else 0}" in text
    assert "#define IMU_N_PROXIES 0" in text
    with pytest.raises(ExportError, match="not a C identifier"):
        render_sensor_c(model, prefix="9imu")


# -- C step() and step_block() against torch, onnxruntime and the runtime ---------------------
@pytest.mark.parametrize("real", ["double", "float"])
def test_c_step_matches_torch_onnxruntime_and_the_runtime(fitted, data, real):
    name, model, path = fitted
    t, temp, raw = _stream(model, data)
    want = _torch(model, t, temp, raw)
    text = render_sensor_c(model)
    flags = ("-O2", "-Wshadow", *REAL_FLAGS[real])
    one = run_stream_c(model.bias, text, t, temp, raw, cflags=flags)
    blk = run_stream_c(model.bias, text, t, temp, raw, cflags=flags, block=7)
    # step_block calls step on each sample in order: the same operations, bitwise
    np.testing.assert_array_equal(blk["compensated"], one["compensated"])
    np.testing.assert_array_equal(blk["drift"], one["drift"])
    assert np.array_equal(blk["flag"], one["flag"]) and (one["ret"] == 0).all()
    assert (blk["ret"] == 0).all()
    # the drift b + E x: float32 b and E on float32 dynamic inputs (DEPTH['dynamic']) at the
    # terms' magnitude; on the float path the solve's float rounding at raw's magnitude
    tol = f32_atol(want["terms"], "dynamic")
    if real == "float":
        tol = tol + f32_atol(raw, "affine")
    _assert_close(one["drift"], want["drift"], tol, f"C {real} drift vs torch")
    _assert_close(one["compensated"], want["compensated"], tol, f"C {real} comp vs torch")
    # drift = raw − compensated: one subtraction in the header's arithmetic
    dt = np.float32 if real == "float" else np.float64
    np.testing.assert_array_equal(
        one["drift"], (raw.astype(dt) - one["compensated"].astype(dt)).astype(np.float64))
    # the flags: the gap (a model with dynamic inputs), the missing temperature, and the
    # range where no signal sits on an edge (booleans)
    n = t.size
    assert one["flag"][n // 3] and np.isnan(one["compensated"][n // 3]).all()
    assert one["flag"][want["gap"]].all()
    assert want["gap"].any() == (name == "rate")
    away = _away_from_edges(model, want["signals"])
    assert away.sum() > n // 2        # the soaks at the range's ends sit on its edges
    np.testing.assert_array_equal(one["flag"][away], want["flag"][away] | want["gap"][away])

    # onnxruntime (the runtime's batch call) and the runtime's step/step_block
    comp = rt.Compensator(path)
    assert comp.metadata["model"] == "sensor"
    kw = {"time_s": t} if comp.dynamic else {}
    whole = comp.compensate(temperature_c=temp, raw=raw, **kw)
    # the same float32 graph on the same float32 signals: the family's depth
    _assert_close(whole.drift, want["drift"], f32_atol(want["terms"], "family"),
                  "onnxruntime vs torch")
    steps = [comp.step(t[k], temp[k], raw[k]) for k in range(500)]
    rest = comp.step_block(t[500:], temp[500:], raw[500:])
    drift = np.concatenate([np.array([r.drift for r in steps]), rest.drift])
    assert_f32_close(drift, want["drift"], "dynamic", scale=want["terms"],
                     err_msg="runtime step vs torch")
    flag_rt = np.concatenate([[r.out_of_range for r in steps], rest.out_of_range])
    if name == "rate":
        # the runtime's stream and its batch call flag alike, and as the C step where no
        # signal is on an edge
        np.testing.assert_array_equal(flag_rt, whole.out_of_range)
        np.testing.assert_array_equal(flag_rt[away], one["flag"][away])
    # C = runtime, through torch: both within their bounds of it (above); directly, the two
    # float32 paths within the sum of those bounds
    _assert_close(one["drift"], drift, tol + f32_atol(want["terms"], "dynamic"),
                  f"C {real} vs runtime step")


@pytest.mark.parametrize("real", ["double", "float"])
def test_c_time_guard_refuses_and_keeps_the_state(fitted, data, real):
    """A repeated and a decreasing time (and on the double path a NaN time): -1, NaN out,
    flag set; every other sample bit-identical to the stream without them (state kept)."""
    _, model, _ = fitted
    t, temp, raw = _stream(model, data)
    t, temp, raw = t[:400], temp[:400], raw[:400]
    text = render_sensor_c(model)
    flags = ("-O2", *REAL_FLAGS[real])
    good = run_stream_c(model.bias, text, t, temp, raw, cflags=flags)
    bad_times = [t[200], t[199] - 1.0] + ([np.nan] if real == "double" else [])
    t_bad = np.insert(t, 201, bad_times)
    temp_bad = np.insert(temp, 201, [temp[200]] * len(bad_times))
    raw_bad = np.insert(raw, 201, [raw[200]] * len(bad_times), axis=0)
    for block in (None, 5):
        got = run_stream_c(model.bias, text, t_bad, temp_bad, raw_bad, cflags=flags,
                           block=block)
        refused = np.arange(201, 201 + len(bad_times))
        assert np.isnan(got["compensated"][refused]).all() and got["flag"][refused].all()
        assert np.isnan(got["drift"][refused]).all()
        kept = np.setdiff1d(np.arange(t_bad.size), refused)
        if block is None:
            assert (got["ret"][refused] == -1).all() and (got["ret"][kept] == 0).all()
        # the same operations on the same state: bitwise
        np.testing.assert_array_equal(got["compensated"][kept], good["compensated"])
        np.testing.assert_array_equal(got["flag"][kept], good["flag"])


def test_runtime_step_refuses_a_bad_time_and_keeps_the_state(fitted, data):
    _, model, path = fitted
    t, temp, raw = _stream(model, data)
    comp = rt.Compensator(path)
    first = [comp.step(t[k], temp[k], raw[k]) for k in range(50)]
    with pytest.raises(rt.RuntimeInputError, match="time_s repeated"):
        comp.step(t[49], temp[49], raw[49])
    with pytest.raises(rt.RuntimeInputError, match="must be finite"):
        comp.step(float("nan"), temp[50], raw[50])
    with pytest.raises(rt.RuntimeInputError, match="step_block.*'raw' must have shape"):
        comp.step_block(t[50], temp[50], raw[50])
    nxt = comp.step_block(t[50:60], temp[50:60], raw[50:60])
    comp.reset()
    again = comp.step_block(t[:60], temp[:60], raw[:60])
    # the refusals left the state as it was: the stream equals one fresh block of it (the
    # per-sample and the vectorised recursions: float64 rounding of the dynamic inputs)
    got = np.concatenate([np.array([r.drift for r in first]), nxt.drift])
    assert_f32_close(got, again.drift, "dynamic",
                     scale=_torch(model, t[:60], temp[:60], raw[:60])["terms"])


# -- the export checks the step before it writes ----------------------------------------------
def test_export_checks_step_on_both_paths_and_catches_a_broken_one(fitted, tmp_path):
    name, model, _ = fitted
    out = export_sensor_c(model, tmp_path / "imu.h", prefix="imu")
    text = out.read_text()
    assert text == render_sensor_c(model, prefix="imu", file_name="imu.h")
    for real in ("double", "float"):
        stats = sensor_stream_parity(model, text, prefix="imu", real=real)
        assert stats["max_error_over_tolerance"] <= 1.0
        assert sensor_c_parity(model, text, prefix="imu", real=real)[
            "max_error_over_tolerance"] <= 1.0
    # a step that feeds the model a temperature 0.5 degC off, and for the rate model one
    # that forgets to flag a gap (twice: the flag, the restart's gap), or whose rate is 1 % off
    broken = [text.replace("    s[0] = temperature_c;", "    s[0] = temperature_c + 0.5f;", 1)]
    if name == "rate":
        broken += [text.replace(" | gap;\n    return 0;", " | (gap && 0);\n    return 0;", 1),
                   text.replace("gap = st->started && restart;", "gap = 0;", 1),
                   text.replace("60.0f * v / c", "60.6f * v / c", 1)]
    for bad in broken:
        assert bad != text
        with pytest.raises(ExportError, match="step\\(\\) parity failed"):
            sensor_stream_parity(model, bad, prefix="imu", real="double")


# -- on a microcontroller (tests/test_mcu.py's builds and emulator) -----------------------------
def test_header_builds_strict_for_every_cortex_m_and_links_bare(fitted, tmp_path):
    """compensate and step instantiated, -Wpedantic -Wshadow -Wconversion -Wdouble-promotion
    -Werror, float and double paths, on the host and each target: float-only (no soft-double
    routine, no libm) where the FPU is single precision; each object links with -nostdlib,
    libm and libgcc only (errno where libm's expm1f is called)."""
    from thermonet.exporting.mcu import (
        FLOAT_TARGETS,
        TARGETS,
        cross_compile,
        host_compile,
        link_bare,
    )

    _, model, _ = fitted
    text = render_sensor_c(model)
    for target in TARGETS:
        build = cross_compile(text, target, tmp_path / "auto" / target)
        assert build.soft_double == [], (target, build.soft_double)
        if target in FLOAT_TARGETS:
            assert build.libm == [], (target, build.libm)
        if target == "cortex-m4f":
            assert build.undefined == [], build.undefined
    for real in ("-DTHERMONET_USE_FLOAT", "-DTHERMONET_USE_DOUBLE"):
        host_compile(text, tmp_path / real / "host", extra=(real,))
        for target in TARGETS:
            build = cross_compile(text, target, tmp_path / real / target, extra=(real,))
            assert set(link_bare(build, tmp_path / real / target / "bare.elf")) <= {"__errno"}


def test_two_sensor_headers_and_a_bias_header_in_one_translation_unit(fitted, tmp_path):
    """One header per IMU, different prefixes, a sensor model's beside a bias model's (its
    own bias body, exported alone), included together and their steps called: every name is
    under its prefix, the shared types are defined once; strict, on the host."""
    import subprocess

    from thermonet.exporting import render_c_header
    from thermonet.exporting.mcu import STRICT_FLAGS

    _, model, _ = fitted
    (tmp_path / "imu0.h").write_text(render_sensor_c(model, prefix="imu0"))
    (tmp_path / "imu1.h").write_text(render_sensor_c(model, prefix="imu1"))
    (tmp_path / "imu2.h").write_text(render_c_header(model.bias, prefix="imu2"))
    src = tmp_path / "all.c"
    calls = " | ".join(f"imu{k}_step(&s{k}, t, temp, raw, c, d, &f)" for k in range(3))
    src.write_text('#include "imu0.h"\n#include "imu1.h"\n#include "imu2.h"\n'
                   "imu0_state s0;\nimu1_state s1;\nimu2_state s2;\n"
                   "int all(thermonet_time_t t, float temp, const thermonet_real_t *raw,\n"
                   "        thermonet_real_t *c, thermonet_real_t *d);\n"
                   "int all(thermonet_time_t t, float temp, const thermonet_real_t *raw,\n"
                   "        thermonet_real_t *c, thermonet_real_t *d)\n"
                   f"{{\n    int f;\n    return {calls} | f;\n}}\n")
    for real in ("-DTHERMONET_USE_FLOAT", "-DTHERMONET_USE_DOUBLE"):
        done = subprocess.run(["gcc", *STRICT_FLAGS, "-O2", real, "-c", str(src), "-o",
                               str(tmp_path / "all.o")], capture_output=True, text=True,
                              cwd=tmp_path)
        assert done.returncode == 0, done.stderr


def test_emulated_cortex_m4f_step_matches_torch(fitted, data, tmp_path):
    """The M4F build (float path: fused multiply-adds, the header's expm1f, microsecond time)
    run under unicorn, step by step over the first 240 samples of the stream and across its
    gap, against torch; a repeated time is refused with NaN."""
    from thermonet.exporting.mcu import Emulator, cross_compile

    _, model, _ = fitted
    build = cross_compile(render_sensor_c(model), "cortex-m4f", tmp_path / "m4f")
    emu = Emulator(build, len(model.signals), len(model.outputs))
    t, temp, raw = _stream(model, data)
    half = t.size // 2
    idx = np.r_[0:120, half - 60:half + 60]            # the start, and 60 samples each side
    t, temp, raw = t[idx], temp[idx], raw[idx]          # of the gap (a gap of its own at 120)
    want = _torch(model, t, temp, raw)
    raw32 = raw.astype(np.float32).astype(np.float64)   # what the part holds
    us = np.round(t * 1e6).astype(np.uint64)
    runs = [emu.step(int(us[k]), float(temp[k]), raw32[k]) for k in range(t.size)]
    assert [r.ret for r in runs] == [0] * t.size
    got = np.array([r.compensated for r in runs])
    tol = f32_atol(want["terms"], "dynamic") + f32_atol(raw, "affine")
    _assert_close(got, want["compensated"], tol, "emulated M4F vs torch")
    flags = np.array([r.flag for r in runs], dtype=bool)
    assert flags[want["gap"]].all()
    bad = emu.step(int(us[-1]), float(temp[-1]), raw32[-1])
    assert bad.ret == -1 and np.isnan(bad.compensated).all() and bad.flag
