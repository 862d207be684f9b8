"""A firmware engineer's edges of the C header: the band of a model on the delayed
temperature (``cubic-delayed-2min``), whose signal ``<prefix>_step`` computes and the firmware
cannot read from its thermometer — ``<prefix>_band_signal`` gives it, and the band on it is the
runtime's — and the finite-math refusal in the sensor header (the model and per-axis headers:
tests/test_c_header.py, tests/test_axis_models.py)."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from conftest import load_runtime
from thermonet.exporting import export_onnx
from thermonet.exporting.c_driver import c_compiler, run_c_driver
from thermonet.exporting.c_export import export_c_header
from thermonet.exporting.mcu import STRICT_FLAGS, TARGETS, toolchain
from thermonet.features import dynamics
from thermonet.features.inputs import FeatureSpec
from thermonet.training.train import TrainConfig, fit
from tolerances import f32_atol

rt = load_runtime()

AXES = ["gyro_x", "acc_y"]
GAP_S = 5.0
T0 = 1_700_000_000          # Unix-epoch seconds (integer: exact in microseconds)

#: step, then the band on the signal the header offers (and, for contrast, on the
#: thermometer's temperature: what firmware passed before); a sample's time in microseconds
_DRIVER = r"""
#include <stdio.h>
#include "model.h"
/* in: int n, then n (uint64 us, float temperature); out: per sample the band on
 * pfx_band_signal, that signal, the band on the temperature, step's return */
int main(int argc, char **argv) {
    FILE *in, *out;
    int n, i, a, flag, ret;
    pfx_state st;
    if (argc < 3) return 2;
    in = fopen(argv[1], "rb");
    out = fopen(argv[2], "wb");
    if (!in || !out || fread(&n, sizeof n, 1, in) != 1) return 3;
    pfx_init(&st);
    for (i = 0; i < n; ++i) {
        uint64_t us;
        float temp, x, b[PFX_N_AXES], bt[PFX_N_AXES];
        thermonet_real_t raw[PFX_N_AXES], comp[PFX_N_AXES], drift[PFX_N_AXES];
        if (fread(&us, sizeof us, 1, in) != 1 || fread(&temp, sizeof temp, 1, in) != 1)
            return 4;
        for (a = 0; a < PFX_N_AXES; ++a) raw[a] = 0;
        if (i == 0) {                         /* before the first step: no signal yet */
            x = pfx_band_signal(&st, temp);
            if (x == x) return 5;
        }
        ret = pfx_step(&st, THERMONET_TIME_FROM_US(us), temp, raw, comp, drift, &flag);
        x = pfx_band_signal(&st, temp);
        pfx_band(x, b);
        pfx_band(temp, bt);
        fwrite(b, sizeof(float), PFX_N_AXES, out);
        fwrite(&x, sizeof x, 1, out);
        fwrite(bt, sizeof(float), PFX_N_AXES, out);
        fwrite(&ret, sizeof ret, 1, out);
    }
    fclose(in);
    fclose(out);
    return 0;
}
"""


@pytest.fixture(scope="module")
def delayed(tmp_path_factory):
    """``cubic-delayed-2min``'s model (a cubic in delayed_120 alone: its only signal, so the
    band's, as :func:`thermonet.workflows.compare_band` chooses it), a band on that signal
    with bins narrower than the delay moves it on a ramp, and the C header and ONNX file
    exported with that band."""
    t = np.arange(0.0, 30000.0, 2.0)
    phase = (t % 8000.0) / 8000.0
    temp = -10.0 + 70.0 * (1.0 - np.abs(2.0 * phase - 1.0))
    sig, _ = dynamics.compute(t, temp, ["delayed_120"], GAP_S)
    e = sig["delayed_120_c"]
    y = np.column_stack([2e-3 * (e - 20.0) + 3e-5 * (e - 20.0) ** 2 + 0.05,
                         -1e-3 * (e - 20.0) + 1e-6 * (e - 20.0) ** 3])
    spec = FeatureSpec(inputs=["delayed_120"], t_ref=20.0, gap_s=GAP_S)
    model = fit(family="poly", inputs=["delayed_120"], outputs=AXES, train=[(e[:, None], y)],
                val=None, spec=spec, hyper={"degree": 3},
                config=TrainConfig(max_epochs=5, seed=0)).model
    assert list(model.signals) == ["delayed_120_c"]
    lo, hi = float(model.sig_lo[0]), float(model.sig_hi[0])
    edges = [float(v) for v in np.linspace(lo, hi, 15)]
    band = {"level": 0.9, "signal": "delayed_120_c", "window_s": 60.0, "axes": {
        a: {"edges": edges, "half_width": [float(v) for v in
                                           np.linspace(0.002, 0.009, 14) * (k + 1)],
            "growth_below": 1e-3, "growth_above": 2e-3}
        for k, a in enumerate(AXES)},
        "holds_for": {"heating_c_per_min": 1.0, "cooling_c_per_min": 1.0}}
    out = tmp_path_factory.mktemp("delayed")
    header = export_c_header(model, out / "delayed.h", band=band)      # checked on export
    onnx = export_onnx(model, out / "delayed.onnx", metadata={"band": band})
    return model, header.read_text(), onnx, edges


def _stream() -> tuple[np.ndarray, np.ndarray]:
    """A soak, a 3 °C/min heating ramp, a soak, a cooling ramp, a gap (3 gap_s) and a
    missing temperature, at 1 s: integer microseconds."""
    temp = np.concatenate([np.full(60, 5.0), 5.0 + 0.05 * np.arange(800),
                           np.full(300, 45.0), 45.0 - 0.04 * np.arange(600)])
    us = (T0 + np.arange(temp.size, dtype=np.int64)) * 1_000_000
    us[1500:] += int(3 * GAP_S * 1e6)
    temp[1200] = np.nan
    return us, temp


@pytest.mark.parametrize("real", ["auto", "float"])
def test_the_c_band_on_band_signal_is_the_runtimes_band_of_a_delayed_model(delayed, real):
    """Firmware steps the header with the thermometer's temperature; the band's signal is
    the model's delayed temperature, which it cannot read: ``<prefix>_band_signal(st, T)``
    returns it from the step's state (NaN for a missing temperature and before the first
    step).  ``thermonet_band`` on it equals the runtime's ``res.band`` over a sequence with
    ramps, a gap and a NaN, on the double and the float path (within float32 rounding of the
    delayed recursion: an equal half-width wherever the signal is not at a bin edge), where
    the band on the temperature (what firmware would pass without it) is wrong on the
    ramps."""
    model, text, onnx, edges = delayed
    assert "static inline float thermonet_band_signal(const thermonet_state *st" in text
    assert "x: thermonet_band_signal(st, temperature_c) after thermonet_step(): the step" in text
    us, temp = _stream()
    cc = c_compiler()
    assert cc is not None, "the C band needs a C compiler (gcc: the README's set-up)"
    rows = np.zeros(us.size, dtype=[("us", np.uint64), ("temp", np.float32)])
    rows["us"], rows["temp"] = us, temp
    n_a = len(AXES)
    got = run_c_driver(cc, text, _DRIVER, rows,
                       [("b", np.float32, n_a), ("x", np.float32), ("bt", np.float32, n_a),
                        ("ret", np.int32)],
                       cflags=("-O2",) + (("-DTHERMONET_USE_FLOAT",) if real == "float" else ()))
    assert (got["ret"] == 0).all()
    # the runtime on the same stream: the band on the delayed temperature it computes
    comp = rt.Compensator(onnx)
    t = us.astype(np.float64) / 1e6
    res = comp.compensate(temperature_c=temp, raw=np.zeros((temp.size, n_a)), time_s=t)
    want = np.asarray(res.band, dtype=np.float64)
    x_rt = rt.dynamic_signals(t, temp.astype(np.float32).astype(np.float64),
                              comp.dynamic)[0]["delayed_120_c"]
    x_c = got["x"].astype(np.float64)
    # the signal: the runtime's, to the float32 recursion's rounding; NaN at the same rows
    np.testing.assert_array_equal(np.isnan(x_c), np.isnan(x_rt))
    assert np.isnan(x_c[1200]) and np.isnan(x_c).sum() == 1
    ok = ~np.isnan(x_rt)
    tol = float(f32_atol(x_rt[ok], "dynamic", axis=None))
    assert np.max(np.abs(x_c[ok] - x_rt[ok])) <= tol
    # the band: equal (float32 tables) wherever the signal is not within tol of an edge
    b_c = got["b"].astype(np.float64)
    np.testing.assert_array_equal(np.isnan(b_c), np.isnan(want))
    clear = ok & (np.min(np.abs(x_rt[:, None] - np.asarray(edges)[None, :]), axis=1) > tol)
    assert clear.sum() > 0.9 * temp.size
    np.testing.assert_allclose(b_c[clear], want[clear], rtol=1e-6, atol=0)
    # the thermometer's temperature in its place: another bin on the ramps (2 min behind)
    wrong = np.abs(got["bt"].astype(np.float64) - want) > 1e-6 * np.abs(want)
    assert wrong[clear].any(axis=1).sum() > 0.3 * clear.sum()


def test_band_signal_builds_strict_on_the_host_and_the_m4f(delayed, tmp_path):
    """The accessor under the strict warnings (-Wconversion, -Wdouble-promotion …, -Werror)
    on the host's double path and the M4F's float path."""
    _, text, _, _ = delayed
    (tmp_path / "model.h").write_text(text)
    (tmp_path / "use.c").write_text(
        '#include "model.h"\nfloat use(const thermonet_state *st, float t, float *out);\n'
        "float use(const thermonet_state *st, float t, float *out)\n"
        "{ const float x = thermonet_band_signal(st, t); thermonet_band(x, out); return x; }\n")
    for cmd in (["gcc"], [toolchain()["gcc"], *TARGETS["cortex-m4f"]]):
        done = subprocess.run([*cmd, *STRICT_FLAGS, "-O2", "-c", "use.c", "-o", "use.o"],
                              capture_output=True, text=True, cwd=tmp_path)
        assert done.returncode == 0, done.stderr


def test_the_sensor_header_refuses_finite_math_only_once(tmp_path):
    """The sensor header (two model bodies, one refusal said once): -ffinite-math-only, which
    folds the NaN test away without defining __FAST_MATH__, is an #error naming the flag
    (was: compiled, and a NaN temperature gave a plausible clamped correction); -Ofast the
    fast-math one; plain -O2 compiles."""
    from thermonet.exporting.sensor_c import render_sensor_c
    from thermonet.models.sensor import triads_of
    from thermonet.sim import simulate
    from thermonet.training.pipeline import split_spec
    from thermonet.training.sensor import fit_sensor, sensor_run

    data = simulate("imu-multiposition", runs=2, seed=0)
    outputs = [o for t in triads_of(sorted(data.runs[0].outputs)) for o in t]
    spec = split_spec(["dT"], data.runs[:1])
    runs = [sensor_run(r, spec, outputs) for r in data.runs]
    model = fit_sensor(family="poly", spec=spec, outputs=outputs, triads=triads_of(outputs),
                       train=runs[:1], val=runs[1], hyper={"degree": 2},
                       config=TrainConfig(max_epochs=1, seed=0)).model
    (tmp_path / "imu.h").write_text(render_sensor_c(model, prefix="imu"))
    (tmp_path / "use.c").write_text('#include "imu.h"\nint main(void) { return 0; }\n')

    def build(*flags: str) -> tuple[int, list[str]]:
        done = subprocess.run(["gcc", "-std=c99", *flags, "-c", "use.c", "-o", "use.o"],
                              capture_output=True, text=True, cwd=tmp_path)
        return done.returncode, [ln for ln in done.stderr.splitlines()
                                 if "#error" in ln and "error:" in ln]

    assert build("-O2") == (0, [])
    code, errors = build("-O2", "-ffinite-math-only")
    assert code != 0 and len(errors) == 1, errors
    assert "must not be compiled with -ffinite-math-only" in errors[0]
    code, errors = build("-Ofast")
    assert code != 0 and len(errors) == 1 and "-ffast-math / -Ofast" in errors[0], errors
