"""C99 header: compiled with gcc -Werror, run on 10,000 points, compared with onnxruntime."""

from __future__ import annotations

import subprocess

import numpy as np
import onnxruntime as ort
import pytest
import torch

from conftest import pointwise_families
from thermonet.core.errors import ExportError
from thermonet.exporting import export_c_header, export_onnx, render_c_header
from thermonet.exporting.c_driver import PARITY_DRIVER
from thermonet.exporting.parity import float32_tolerance
from thermonet.features.inputs import FeatureSpec
from thermonet.models import MODELS
from thermonet.training.train import TrainConfig, fit

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

AXES = ["acc_x", "acc_y"]
# the export's own parity driver, with the default prefix
DRIVER = PARITY_DRIVER.replace("PFX", "THERMONET").replace("pfx", "thermonet")


def _model(family: str):
    """Two signals (temperature and a frequency proxy) where the family allows several inputs."""
    rng = np.random.default_rng(3)
    temp = np.linspace(-10.0, 60.0, 500)
    freq = 4517.0 + 0.4 * (temp - 20.0) + rng.normal(0, 0.05, temp.size)
    multi = MODELS[family].max_inputs is None
    inputs = ["dT", "d_freq_hz2"] if multi else ["d_freq_hz"]
    spec = FeatureSpec(inputs=inputs, t_ref=20.0, proxy_ref={"freq_hz": 4517.0})
    df = freq - 4517.0
    y = np.stack([2e-3 * df + 1e-4 * df**2 + 0.003 * np.tanh(df / 5), -1e-3 * df + 5e-5 * df**2], 1)
    sig = np.stack([temp, freq], 1) if multi else freq[:, None]
    return fit(family=family, inputs=inputs, outputs=AXES, train=[(sig, y)], val=None, spec=spec,
               hyper={}, config=TrainConfig(max_epochs=20, seed=0)).model


@pytest.mark.parametrize("family", pointwise_families())
def test_header_matches_onnxruntime(family, tmp_path):
    model = _model(family)
    onnx_path = export_onnx(model, tmp_path / "m.onnx")
    export_c_header(model, tmp_path / "model.h")
    (tmp_path / "driver.c").write_text(DRIVER)
    exe = tmp_path / "driver"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-o", str(exe),
                    str(tmp_path / "driver.c"), "-lm"], check=True, capture_output=True, text=True)

    n_sig, n_ax = len(model.signals), len(AXES)
    lo = model.sig_lo.numpy().astype(np.float64)
    hi = model.sig_hi.numpy().astype(np.float64)
    rng = np.random.default_rng(0)
    span = hi - lo
    sig = rng.uniform(lo - 0.1 * span, hi + 0.1 * span, size=(10_000, n_sig)).astype(np.float32)
    sig[:9000] = rng.uniform(lo, hi, size=(9000, n_sig))       # mostly inside the range
    sig[-3, 0] = np.nan
    sig[-2, 0] = np.inf
    sig[-1, -1] = -np.inf
    raw = rng.normal(0, 0.01, size=(10_000, n_ax))
    rows = np.zeros(10_000, dtype=[("s", np.float32, n_sig), ("raw", np.float64, n_ax)])
    rows["s"], rows["raw"] = sig, raw
    (tmp_path / "in.bin").write_bytes(np.int32(10_000).tobytes() + rows.tobytes())
    subprocess.run([str(exe), str(tmp_path / "in.bin"), str(tmp_path / "out.bin")], check=True)
    rec = np.dtype([("comp", np.float64, n_ax), ("drift", np.float64, n_ax), ("flag", np.int32)])
    c_out = np.fromfile(tmp_path / "out.bin", dtype=rec)

    sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    feeds = {s: np.ascontiguousarray(sig[:, i]) for i, s in enumerate(model.signals)}
    comp, drift, flag = sess.run(None, {**feeds, "raw": raw})
    np.testing.assert_array_equal(c_out["flag"].astype(bool), flag)
    assert flag[9000:].sum() > 100 and not flag[:9000].any()
    finite = np.isfinite(sig).all(axis=1)
    assert np.isnan(c_out["drift"][~finite]).all() and np.isnan(c_out["comp"][~finite]).all()
    # Tolerance: the ONNX parity check's — 1e-5 of the axis's largest drift, or 4x what
    # float32 rounding costs torch itself against a float64 evaluation, whichever is larger.
    with torch.no_grad():
        d_torch = model.relative(torch.from_numpy(sig[finite])).double().numpy()
    tol = float32_tolerance(model, sig[finite], d_torch)
    err = np.abs(c_out["drift"][finite] - drift[finite])
    assert (err <= tol).all(), (err.max(axis=0), tol)
    err_c = np.abs(c_out["comp"][finite] - comp[finite])
    assert (err_c <= tol + 1e-15 * np.abs(raw[finite])).all()


def test_header_text_and_refusals():
    model = _model("poly")
    text = render_c_header(model, prefix="imu0")
    assert ("static inline int imu0_compensate(const float *signals, const thermonet_real_t *raw"
            in text)
    assert "#define IMU0_N_AXES 2" in text and '#define IMU0_AXIS_NAMES {"acc_x", "acc_y"}' in text
    assert "malloc" not in text
    # only the per-axis constant and raw/compensated/drift are double (on a double FPU; float
    # and the constant split in two floats on a single-precision one); the model is float32
    assert "static const double IMU0_DRIFT_CONSTANT[2]" in text
    assert "static const float IMU0_DRIFT_HI[2]" in text and "IMU0_DRIFT_LO[2]" in text
    assert "typedef double thermonet_real_t;" in text and "typedef float thermonet_real_t;" in text
    assert "drift relative to (per axis): acc_x channel, acc_y channel." in text
    # the streaming form keeps its timestamps in double seconds or integer microseconds (a
    # difference of two Unix-epoch seconds would lose the step in float); its dynamic inputs
    # are float32
    assert "static inline int imu0_step(imu0_state *st, thermonet_time_t time_s," in text
    assert "typedef double thermonet_time_t;" in text and "typedef uint64_t thermonet_time_t;" \
        in text
    assert "thermonet_time_t t_last;    /* time of the last accepted call (s, or us) */" in text
    with pytest.raises(ExportError, match="not a C identifier"):
        render_c_header(model, prefix="9bad-name")


def test_header_refuses_fast_math(tmp_path):
    """-ffast-math (or -ffinite-math-only alone) would fold away the NaN test: the header
    must not compile that way."""
    header = export_c_header(_model("poly"), tmp_path / "thermonet_model.h")
    src = tmp_path / "use.c"
    src.write_text('#include "thermonet_model.h"\nint main(void) { return 0; }\n')
    ok = subprocess.run(["gcc", "-std=c99", "-O2", "-c", str(src), "-o", str(tmp_path / "a.o")],
                        capture_output=True, text=True, cwd=tmp_path)
    assert ok.returncode == 0, ok.stderr
    fast = subprocess.run(
        ["gcc", "-std=c99", "-Ofast", "-c", str(src), "-o", str(tmp_path / "b.o")],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert fast.returncode != 0 and "fast-math" in fast.stderr
    # -ffinite-math-only alone (no __FAST_MATH__; __FINITE_MATH_ONLY__ is 1) folds the same
    # test away: a NaN temperature gave a plausible clamped drift (was: compiled silently)
    finite = subprocess.run(["gcc", "-std=c99", "-O2", "-ffinite-math-only", "-c", str(src),
                             "-o", str(tmp_path / "c.o")], capture_output=True, text=True,
                            cwd=tmp_path)
    errors = [ln for ln in finite.stderr.splitlines() if "#error" in ln and "error:" in ln]
    assert finite.returncode != 0 and len(errors) == 1, finite.stderr
    assert "must not be compiled with -ffinite-math-only" in errors[0]
    # -Ofast defines both: one #error, the fast-math one
    assert "finite-math-only" not in fast.stderr
    # and the flag turned off again is accepted (the refusal reads the macro's value)
    off = subprocess.run(["gcc", "-std=c99", "-O2", "-ffinite-math-only",
                          "-fno-finite-math-only", "-c", str(src), "-o", str(tmp_path / "d.o")],
                         capture_output=True, text=True, cwd=tmp_path)
    assert off.returncode == 0, off.stderr
    assert header.name == "thermonet_model.h"
    # the first line names the file written (was "thermonet.h" whatever --out was); the
    # refusal names none (a per-axis header's named "thermonet_part0.h", no such file)
    text = header.read_text()
    assert text.startswith("/* thermonet_model.h: temperature-drift compensation")
    assert "#error \"a thermonet header must not be compiled with -ffast-math" in text
    assert "thermonet.h" not in text


def test_export_compiles_and_checks_the_header_before_writing(tmp_path):
    """A header that does not evaluate the model is refused and nothing is written."""
    from thermonet.exporting.c_export import c_parity_check

    model = _model("rbf")
    stats = c_parity_check(model, render_c_header(model))
    assert stats is not None and stats["n_points"] >= 10_000
    stale = render_c_header(model)
    with torch.no_grad():
        model.y_mean += 1.0  # the model moved on; the header text did not
    with pytest.raises(ExportError, match="C header parity check failed"):
        c_parity_check(model, stale)
    out = export_c_header(model, tmp_path / "ok.h")  # a fresh header passes its own check
    assert out.is_file()


UNITS_DRIVER = r"""
#include <stdio.h>
#include "imu.h"
int main(void) {
    static const char *const names[] = THERMONET_AXIS_NAMES;
    static const char *const units[] = THERMONET_AXIS_UNITS;
    int a;
    for (a = 0; a < THERMONET_N_AXES; ++a) printf("%s=%s\n", names[a], units[a]);
    return 0;
}
"""


def test_header_states_each_axis_unit(tmp_path):
    """raw, drift and compensated are in the model's unit, which only the ONNX metadata said
    (``output_units``): the header says it per axis in its comment and as
    ``<PREFIX>_AXIS_UNITS`` (a string per axis, the order of ``_AXIS_NAMES``), from the
    checkpoint's units through the format registry, as ``thermonet export`` writes it."""
    from thermonet.exporting import FORMATS, ExportRequest

    model = _model("poly")
    units = {"acc_x": "m/s^2", "acc_y": "g"}
    path = FORMATS["c"].write(model, tmp_path / "imu.h",
                              ExportRequest(meta={"extra": {"units": units}}))
    text = path.read_text()
    assert '#define THERMONET_AXIS_UNITS {"m/s^2", "g"}' in text
    assert ("units of raw, drift and compensated (THERMONET_AXIS_UNITS): acc_x m/s^2, acc_y g;"
            in text)
    (tmp_path / "units.c").write_text(UNITS_DRIVER)
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-o", "units", "units.c",
                    "-lm"], check=True, cwd=tmp_path, capture_output=True)
    got = subprocess.run([str(tmp_path / "units")], capture_output=True, text=True, check=True)
    assert got.stdout.splitlines() == ["acc_x=m/s^2", "acc_y=g"]
    # a model without recorded units: empty strings, and the comment says so
    bare = render_c_header(model)
    assert '#define THERMONET_AXIS_UNITS {"", ""}' in bare
    assert "acc_x (not recorded), acc_y (not recorded)" in bare


def _compile_together(tmp_path, *headers: str) -> subprocess.CompletedProcess:
    src = tmp_path / "both.c"
    src.write_text("".join(f'#include "{h}"\n' for h in headers) + "int main(void) { return 0; }\n")
    return subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wundef",
                           "-Werror", "-O2", "-c", "both.c", "-o", "both.o"], cwd=tmp_path,
                          capture_output=True, text=True)


def test_two_models_under_one_prefix_are_a_compile_error(tmp_path):
    """Two exported headers with the default prefix share the include guard
    ``THERMONET_MODEL_H``: the second was skipped without a word (its model silently not
    there).  Another model under the same prefix is now an ``#error`` naming the prefix and
    what to do; the same header twice, or the same model in two files, still compiles (read
    once); another prefix (``ExportRequest.prefix``, what ``export_source(prefix=)`` passes)
    compiles beside it."""
    from thermonet.exporting import FORMATS, ExportRequest

    poly, linear = _model("poly"), _model("linear")
    export_c_header(poly, tmp_path / "a.h")
    export_c_header(poly, tmp_path / "a_copy.h")
    export_c_header(linear, tmp_path / "b.h")
    FORMATS["c"].write(linear, tmp_path / "imu1.h", ExportRequest(prefix="imu1"))
    for pair in (("a.h", "a.h"), ("a.h", "a_copy.h"), ("a.h", "imu1.h"), ("b.h", "imu1.h")):
        ok = _compile_together(tmp_path, *pair)
        assert ok.returncode == 0, (pair, ok.stderr)
    clash = _compile_together(tmp_path, "a.h", "b.h")
    assert clash.returncode != 0
    errors = [ln for ln in clash.stderr.splitlines() if "error:" in ln]
    assert len(errors) == 1 and errors[0].startswith("b.h:"), clash.stderr
    assert ("#error \"two thermonet headers of different models use the prefix 'thermonet': "
            "export one of them again under another prefix (thermonet export ... --format c "
            "--prefix NAME, or export_c_header(prefix=...))" in errors[0])
    assert "static inline int imu1_compensate(" in (tmp_path / "imu1.h").read_text()


def test_prefix_is_for_c_only_and_a_c_identifier(tmp_path):
    """``prefix`` of an export (``export_source``; the CLI's ``--prefix``) is refused for a
    format without C symbols, and where it is not a C identifier, in one line, before
    anything is read."""
    from thermonet.core.errors import InputError
    from thermonet.exporting.source import check_export_request, export_source

    with pytest.raises(InputError, match=r"^--prefix applies to --format c only \(the C "
                                         r"symbols' prefix\); onnx has no symbols$"):
        check_export_request(fmt="onnx", out=tmp_path / "m.onnx", prefix="imu0")
    with pytest.raises(InputError, match=r"^--prefix '9imu' is not a C identifier"):
        export_source(str(tmp_path / "nothing"), fmt="c", out=tmp_path / "m.h", prefix="9imu")
    assert check_export_request(fmt="c", out=tmp_path / "m.h", prefix="imu0").name == "c"


def test_the_c_formats_description_says_what_the_header_holds():
    """``thermonet export --help`` lists each format's description: the C one said "float32,
    no heap, only expf from libm" where raw/drift are double on a host and expm1f is used
    too.  Each claim of the description is checked against a written header."""
    from thermonet.exporting import FORMATS

    text = FORMATS["c"].description
    assert "only expf" not in text
    for claim in ("float32", "no heap", "double", "expf/expm1f", "float on a single-precision"):
        assert claim in text, claim
    header = render_c_header(_model("rbf"))
    assert "typedef double thermonet_real_t;" in header and "typedef float thermonet_real_t;" \
        in header
    assert "expm1f(" in header and "expf(" in header and "malloc" not in header
