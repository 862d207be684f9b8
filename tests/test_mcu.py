"""Firmware-grade C: every family's header, plain and streaming, cross-compiled for Cortex-M0+,
M4F and M7 under -Werror, float-only where the FPU is single precision (no soft-double
routine), its fast expf/expm1f within their documented error (against numpy float64), the
float path against torch (host-compiled with -DTHERMONET_USE_FLOAT, and emulated on a
Cortex-M4F under unicorn), and a 1e6 offset kept to the noise level on the float path.

The toolchain is a prerequisite, not an option: `make test` installs it (`make
arm-toolchain`); without it these tests fail, they do not skip.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import pointwise_families
from thermonet.exporting import render_c_header
from thermonet.exporting.c_export import c_parity_check
from thermonet.exporting.c_stream import check_stream, float_path_slack, run_stream_c
from thermonet.exporting.c_stream_render import stream_signature_has_proxies
from thermonet.exporting.mcu import (
    FLOAT_TARGETS,
    TARGETS,
    Emulator,
    cross_compile,
    soft_double_symbols,
    toolchain,
)
from thermonet.features import dynamics
from thermonet.features.inputs import FeatureSpec
from thermonet.models import MODELS
from thermonet.models.cgen import (
    FAST_EXP_DOMAIN,
    FAST_EXPF_MAX_REL_ERR,
    FAST_EXPM1F_MAX_REL_ERR,
    c_target_prelude,
)
from thermonet.training.train import TrainConfig, fit
from tolerances import DEPTH, f32_atol

AXES = ["gyro_x", "acc_y"]
DYN_MULTI = ["dT", "rate", "lag_300", "play_0.5"]
GAP_S = 5.0


def _static_model(family: str):
    """Temperature (and a frequency proxy where the family takes several inputs)."""
    rng = np.random.default_rng(3)
    temp = np.linspace(-10.0, 60.0, 500)
    freq = 4517.0 + 0.4 * (temp - 20.0) + rng.normal(0, 0.05, temp.size)
    multi = MODELS[family].max_inputs is None
    inputs = ["dT", "d_freq_hz2"] if multi else ["dT"]
    spec = FeatureSpec(inputs=inputs, t_ref=20.0, proxy_ref={"freq_hz": 4517.0})
    dt = temp - 20.0
    y = np.stack([2e-3 * dt + 1e-4 * dt**2 + 0.003 * np.tanh(dt / 5) + 0.05,
                  -1e-3 * dt + 5e-5 * dt**2], 1)
    sig = np.stack([temp, freq], 1) if multi else temp[:, None]
    return fit(family=family, inputs=inputs, outputs=AXES, train=[(sig, y)], val=None,
               spec=spec, hyper={}, config=TrainConfig(max_epochs=20, seed=0)).model


def _dynamic_model(family: str):
    """The family on dynamic inputs (every kind where it takes several inputs, the lag else)."""
    t = np.arange(0.0, 30000.0, 2.0)
    phase = (t % 8000.0) / 8000.0
    temp = -10.0 + 70.0 * (1.0 - np.abs(2.0 * phase - 1.0))
    inputs = DYN_MULTI if MODELS[family].max_inputs is None else ["lag_300"]
    sig, _ = dynamics.compute(t, temp, inputs, GAP_S)
    spec = FeatureSpec(inputs=inputs, t_ref=20.0, gap_s=GAP_S)
    s = np.column_stack([temp] + [sig[x] for x in spec.signals[1:]])
    y = np.column_stack([0.01 * (temp - 20.0) + 0.02 * sig.get("rate_c_per_min", 0 * temp)
                         + 0.05, 0.001 * sig["lag_300_c"] + 1e-4 * (temp - 20.0)])
    return fit(family=family, inputs=inputs, outputs=AXES, train=[(s, y)], val=None, spec=spec,
               hyper={}, config=TrainConfig(max_epochs=5, seed=0)).model


@pytest.fixture(scope="module")
def models():
    out = {}
    for family in pointwise_families():
        out[family, "plain"] = _static_model(family)
        out[family, "stream"] = _dynamic_model(family)
    return out


# ------------------------------------------------------------------ cross-compilation
def test_toolchain_is_installed():
    """`make test` installs it first (`make arm-toolchain`): missing is a failure."""
    tools = toolchain()
    version = subprocess.run([tools["gcc"], "--version"], capture_output=True, text=True,
                             check=True).stdout
    assert "arm-none-eabi-gcc" in version


@pytest.mark.parametrize("kind", ["plain", "stream"])
@pytest.mark.parametrize("family", pointwise_families())
def test_every_header_cross_compiles_float_only_where_the_fpu_is(models, family, kind,
                                                                 tmp_path):
    model = models[family, kind]
    text = render_c_header(model)
    for target in TARGETS:
        # compensate and step instantiated; -Wshadow -Wconversion -Wdouble-promotion -Werror
        build = cross_compile(text, target, tmp_path / target,
                              has_proxies=stream_signature_has_proxies(model))
        assert build.code_bytes > 0
        # no double arithmetic in software anywhere: float on M0+/M4F, hardware double on M7
        assert build.soft_double == [], (target, build.soft_double)
        if target in FLOAT_TARGETS:
            assert build.libm == [], (target, build.libm)     # the fast expf/expm1f
        if target == "cortex-m4f":
            # everything in the FPU: no run-time routine at all
            assert build.undefined == [], build.undefined
    # the double path forced on the M4F is what the header was before: soft-double calls
    forced = cross_compile(text, "cortex-m4f", tmp_path / "forced",
                           has_proxies=stream_signature_has_proxies(model),
                           extra=("-DTHERMONET_USE_DOUBLE",))
    assert "__aeabi_dadd" in forced.soft_double


@pytest.mark.parametrize("family", pointwise_families())
def test_m4f_builds_call_no_fmaf_at_any_optimisation_level(models, family, tmp_path):
    """GCC expands a libm builtin called by its plain name (``fmaf``) inline only when
    optimising: at -O0 the M4F build called newlib's ``fmaf`` (software, through double)
    for every fused multiply-add.  The header's ``THERMONET_MAC`` is ``__builtin_fmaf`` under
    GCC/clang: one ``vfma`` at -O0, -Og and -Os as at -O2, no ``fmaf`` and no soft-double
    routine anywhere, and the same numbers (the emulated -O0 build is bit for bit the -O2
    build).  The tanh's sign copy is ``__builtin_copysignf`` likewise: nothing is called at
    any level."""
    import shutil

    objdump = shutil.which("arm-none-eabi-objdump")
    assert objdump is not None, "arm-none-eabi-objdump (binutils-arm-none-eabi) is needed"
    for kind in ("plain", "stream"):
        model = models[family, kind]
        text = render_c_header(model)
        how = {"has_proxies": stream_signature_has_proxies(model)}
        for opt in ("-O0", "-Og", "-Os"):
            build = cross_compile(text, "cortex-m4f", tmp_path / kind / opt, opt=opt, **how)
            assert "fmaf" not in build.undefined, (kind, opt, build.undefined)
            assert build.soft_double == [] and build.libm == [], (kind, opt, build.undefined)
            assert build.undefined == [], (kind, opt, build.undefined)
    # fused at -O0: vfma in the code (-std=c99 contracts nothing: only fmaf makes one) where
    # the header multiplies-and-adds (the fast expf every family's float path carries)
    asm = subprocess.run([objdump, "-d", str(tmp_path / "stream" / "-O0" / "mcu.o")],
                         capture_output=True, text=True, check=True).stdout
    assert "vfma.f32" in asm and "<fmaf>" not in asm
    # the same numbers: the -O0 build against the -O2 build on the emulated M4F, exactly
    model = models[family, "plain"]
    text = render_c_header(model)
    builds = [cross_compile(text, "cortex-m4f", tmp_path / f"emu{opt}", opt=opt,
                            has_proxies=stream_signature_has_proxies(model))
              for opt in ("-O0", "-O2")]
    emus = [Emulator(b, len(model.signals), len(model.outputs)) for b in builds]
    raw = np.round(model.constant().double().numpy())
    for p in _sweep(model)[::8]:
        o0, o2 = (e.evaluate(p, raw) for e in emus)
        assert np.array_equal(o0.drift, o2.drift) and o0.flag == o2.flag, p


def test_soft_double_names():
    names = ["__aeabi_dadd", "__aeabi_f2d", "__aeabi_d2f", "__aeabi_dcmpgt", "__aeabi_i2d",
             "__aeabi_ul2d", "__adddf3", "__extendsfdf2", "__aeabi_fadd", "__aeabi_f2iz",
             "__aeabi_i2f", "__aeabi_ul2f", "expf", "memcpy"]
    assert soft_double_symbols(names) == sorted(["__aeabi_dadd", "__aeabi_f2d", "__aeabi_d2f",
                                                 "__aeabi_dcmpgt", "__aeabi_i2d",
                                                 "__aeabi_ul2d", "__adddf3", "__extendsfdf2"])


def test_target_selection_by_fpu(tmp_path):
    """float where __ARM_FP lacks double (M0+, M4F), double on M7 and on the host."""
    src = tmp_path / "t.c"
    src.write_text("#include <math.h>\n" + "\n".join(c_target_prelude()) + "\n"
                   "int real_size = (int)sizeof(thermonet_real_t);\n"
                   "int time_size = (int)sizeof(thermonet_time_t);\n"
                   "int fast = THERMONET_FAST_EXP;\n")
    tools = toolchain()

    def real_type(cmd: list[str]) -> str:
        """The typedef the preprocessor keeps (the other branch is gone after -E)."""
        out = subprocess.run([*cmd, "-E", str(src)], capture_output=True, text=True,
                             check=True).stdout
        kept = [t for t in ("float", "double") if f"typedef {t} thermonet_real_t;" in out]
        assert len(kept) == 1, kept
        return kept[0]

    arm = tools["gcc"]
    assert real_type([arm, *TARGETS["cortex-m0plus"]]) == "float"      # no FPU
    assert real_type([arm, *TARGETS["cortex-m4f"]]) == "float"         # __ARM_FP 4
    assert real_type([arm, *TARGETS["cortex-m7"]]) == "double"         # __ARM_FP 14
    assert real_type(["gcc"]) == "double"                              # the host, as before
    assert real_type(["gcc", "-DTHERMONET_USE_FLOAT"]) == "float"
    assert real_type([arm, *TARGETS["cortex-m4f"], "-DTHERMONET_USE_DOUBLE"]) == "double"


# ------------------------------------------------------------------ the fast exponentials
_EXP_DRIVER = r"""
#include <stdio.h>
#include "pre.h"
int main(int argc, char **argv)
{
    FILE *in = fopen(argv[1], "rb"), *out = fopen(argv[2], "wb");
    float x, r[2];
    (void)argc;
    while (fread(&x, sizeof x, 1, in) == 1) {
        r[0] = thermonet_fast_expf(x);
        r[1] = thermonet_fast_expm1f(x);
        fwrite(r, sizeof r, 1, out);
    }
    fclose(in);
    fclose(out);
    return 0;
}
"""


def _exp_points() -> np.ndarray:
    """Every float32 near 0 (where expm1 is relative to a tiny value), a dense geometric
    sweep of both signs up to the domain's ends, and the reduction's seams k·ln2/2."""
    lo, hi = FAST_EXP_DOMAIN
    mag = np.geomspace(1e-30, 88.0, 600_000)
    seams = np.arange(-125, 127) * np.log(2) / 2
    near = seams[:, None] + np.linspace(-1e-4, 1e-4, 201)[None, :]
    x = np.concatenate([-mag, mag, near.ravel(), np.linspace(lo, hi, 400_001)])
    x = x[(x >= lo) & (x <= hi)].astype(np.float32)
    return np.unique(x)


@pytest.mark.numerics
def test_fast_exp_and_expm1_within_their_documented_error(tmp_path):
    """Measured against numpy float64 of the same float32 argument (independent); the
    compiled C is the header's own (host gcc, unfused: the emulated M4F test below runs the
    fused variant)."""
    (tmp_path / "pre.h").write_text("#include <math.h>\n" + "\n".join(c_target_prelude()))
    (tmp_path / "e.c").write_text(_EXP_DRIVER)
    subprocess.run(["gcc", "-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Wshadow",
                    "-Wdouble-promotion", "-Wconversion", "-Werror", "-DTHERMONET_USE_FLOAT",
                    "-o", str(tmp_path / "e"), str(tmp_path / "e.c"), "-lm"], check=True)
    x = _exp_points()
    specials = np.array([np.nan, -np.inf, np.inf, -1000.0, -87.5, 100.0], dtype=np.float32)
    (tmp_path / "x.bin").write_bytes(np.concatenate([x, specials]).tobytes())
    subprocess.run([str(tmp_path / "e"), str(tmp_path / "x.bin"), str(tmp_path / "y.bin")],
                   check=True)
    got = np.fromfile(tmp_path / "y.bin", dtype=np.float32).reshape(-1, 2).astype(np.float64)
    xs = x.astype(np.float64)
    err_exp = np.abs(got[: x.size, 0] - np.exp(xs)) / np.exp(xs)
    nz = xs != 0.0
    err_m1 = np.abs(got[: x.size, 1] - np.expm1(xs))[nz] / np.abs(np.expm1(xs[nz]))
    assert err_exp.max() <= FAST_EXPF_MAX_REL_ERR, (err_exp.max(), xs[err_exp.argmax()])
    assert err_m1.max() <= FAST_EXPM1F_MAX_REL_ERR, (err_m1.max(), xs[nz][err_m1.argmax()])
    assert np.all(got[: x.size][~nz, 1] == 0.0)     # expm1(±0) is exactly 0 (the polynomial)
    s = got[x.size:]
    assert np.isnan(s[0]).all()                              # NaN stays NaN
    assert s[1, 0] == 0.0 and s[1, 1] == -1.0                # -inf
    assert s[2, 0] == pytest.approx(np.exp(88.0), rel=FAST_EXPF_MAX_REL_ERR)   # capped
    assert s[3, 0] == 0.0 and s[4, 0] == 0.0 and s[3, 1] == -1.0
    assert np.isfinite(s[5, 0])


# ------------------------------------------------------------------ the float path on the host
@pytest.mark.numerics
@pytest.mark.parametrize("family", pointwise_families())
def test_float_path_matches_torch(models, family):
    """-DTHERMONET_USE_FLOAT on the host: float raw/drift/compensated, the fast expf and
    expm1f, microsecond time; the export's own checks (grid, random points, flags; the
    stream with a gap and a missing temperature) against torch."""
    for kind in ("plain", "stream"):
        model = models[family, kind]
        text = render_c_header(model)
        assert c_parity_check(model, text, real="float") is not None
        if kind == "stream":
            assert check_stream(model, text, real="float") is not None


@pytest.mark.numerics
def test_float_path_keeps_a_large_offset(tmp_path):
    """Raw counts ~1e6 with a 1e-3 drift: on the float path, compensated is (raw − hi) − (lo +
    r), exact in its first subtraction, so it keeps the drift at the noise level where a
    plain float sum would lose it to float's 0.0625 steps at 1e6."""
    temp = np.linspace(-20.0, 60.0, 4000)
    dt = temp - 25.0
    law = 1e-3 * (dt / 40 + (dt / 40) ** 2)
    sigma = 1e-4
    raw = 1e6 + 123.456 + law + np.random.default_rng(1).normal(0, sigma, law.shape)
    spec = FeatureSpec(inputs=["dT", "dT2"], t_ref=25.0)
    model = fit(family="poly", inputs=["dT", "dT2"], outputs=["out_x"],
                train=[(temp[:, None], raw[:, None])], val=None, spec=spec,
                hyper={"degree": 1}, config=TrainConfig(max_epochs=5), target=["zero"]).model
    const = float(model.constant()[0])
    assert abs(const - (1e6 + 123.456)) < 1e-2
    # integer counts around the constant, as an ADC gives them (exact in float below 2^24)
    counts = np.round(const + np.linspace(-5, 5, temp.size))
    header = render_c_header(model)
    got = run_stream_c(model, header, 1.7e9 + np.arange(temp.size, dtype=np.float64),
                       temp.astype(np.float32), counts[:, None],
                       cflags=("-O2", "-DTHERMONET_USE_FLOAT"))
    with torch.no_grad():
        d64 = model.drift64(torch.from_numpy(temp[:, None].astype(np.float32))).numpy()[:, 0]
    want = counts - d64                              # float64 throughout (torch's drift)
    comp = got["compensated"][:, 0]
    # bound: the float model's rounding at the drift's scale, float's rounding of the small
    # result, and hi + lo's representation of the constant (2^-24 of lo)
    r = d64 - const
    bound = (f32_atol(r, DEPTH["affine"], axis=None)[()] + 2 * np.finfo(np.float32).eps
             * (np.abs(want) + 0.06))
    assert np.all(np.abs(comp - want) <= bound), np.max(np.abs(comp - want) / bound)
    assert np.max(np.abs(comp - want)) < 0.05 * sigma       # the noise level, as in double
    # what a plain float evaluation (raw - (float)(c + r)) would have lost
    naive = counts - (np.float32(const) + r.astype(np.float32)).astype(np.float64)
    assert np.max(np.abs(naive - want)) > 100 * np.max(np.abs(comp - want))


# ------------------------------------------------------------------ emulated Cortex-M4F
def _sweep(model, n: int = 60) -> np.ndarray:
    lo = model.sig_lo.numpy().astype(np.float64)
    hi = model.sig_hi.numpy().astype(np.float64)
    span = hi - lo
    frac = np.linspace(-0.05, 1.05, n)[:, None]
    rng = np.random.default_rng(5)
    pts = lo + span * np.where(np.arange(lo.size) == 0, frac, rng.uniform(0, 1, (n, lo.size)))
    return pts.astype(np.float32)


@pytest.mark.parametrize("family", pointwise_families())
def test_emulated_cortex_m4f_matches_torch(models, family, tmp_path):
    """The code that runs on the part: built for the M4F (fused multiply-adds, the fast
    expf/expm1f), run under unicorn, compared with torch over a temperature sweep (and the
    streaming step over a heat/cool sequence with a gap)."""
    model = models[family, "plain"]
    build = cross_compile(render_c_header(model), "cortex-m4f", tmp_path / "plain",
                          has_proxies=stream_signature_has_proxies(model))
    emu = Emulator(build, len(model.signals), len(model.outputs))
    pts = _sweep(model)
    const = model.constant().double().numpy()
    with torch.no_grad():
        want = model.relative(torch.from_numpy(pts)).double().numpy()
        flag_want = model.out_of_range(torch.from_numpy(pts)).numpy()
    raw = np.round(const)                         # float-exact raw near the constant
    runs = [emu.evaluate(p, raw) for p in pts]
    drift = np.array([r.drift for r in runs]) - const
    # the float32 model (DEPTH['family']: its exp budget of 2 ulp covers the fast expf's
    # FAST_EXPF_MAX_REL_ERR = 1.26 ε32) plus the float path's rounding of drift = c + r
    tol = f32_atol(want, "family") + float_path_slack(const, want)
    assert np.all(np.abs(drift - want) <= tol), np.max(np.abs(drift - want) / tol)
    comp = np.array([r.compensated for r in runs])
    assert np.all(np.abs(comp - (raw - const - want)) <= tol)
    assert [bool(r.flag) for r in runs] == flag_want.tolist()
    assert flag_want.any() and not flag_want.all()

    # the streaming step with its dynamic inputs, microsecond time
    model = models[family, "stream"]
    build = cross_compile(render_c_header(model), "cortex-m4f", tmp_path / "stream",
                          has_proxies=stream_signature_has_proxies(model))
    emu = Emulator(build, len(model.signals), len(model.outputs))
    n = 240
    t = 1.7e9 + np.cumsum(np.full(n, 0.5 * GAP_S))
    t[n // 2:] += 2 * GAP_S                       # a gap: the state restarts, flag set
    if "temperature_c" in model.signals:      # else the model reads only the lag
        j = list(model.signals).index("temperature_c")
        lo, hi = float(model.sig_lo[j]), float(model.sig_hi[j])
    else:
        lo, hi = 0.0, 50.0
    temp = lo + (hi - lo) * (0.2 + 0.6 * np.abs(np.sin(np.arange(n) / 40.0)))
    sig, gap = dynamics.compute(t, temp, model.inputs, GAP_S)
    cols = {"temperature_c": temp, **sig}
    s = np.column_stack([cols[x] for x in model.signals])
    with torch.no_grad():
        want = model.relative(torch.from_numpy(s)).double().numpy()
    const = model.constant().double().numpy()
    us = np.round(t * 1e6).astype(np.uint64)
    runs = [emu.step(int(us[k]), float(temp[k]), np.zeros(len(const))) for k in range(n)]
    assert [r.ret for r in runs] == [0] * n
    drift = np.array([r.drift for r in runs]) - const
    # the float32 recursions over the whole sequence (DEPTH['dynamic']), the fast expm1f
    # (FAST_EXPM1F_MAX_REL_ERR = 2.5 ε32 per step, inside that budget) and drift = c + r
    tol = f32_atol(want, "dynamic") + float_path_slack(const, want)
    assert np.all(np.abs(drift - want) <= tol), np.max(np.abs(drift - want) / tol)
    flags = np.array([r.flag for r in runs], dtype=bool)
    assert flags[gap].all() and gap.any()
    # a time not after the previous one: refused, NaN, state unchanged
    bad = emu.step(int(us[-1]), float(temp[-1]), np.zeros(len(const)))
    assert bad.ret == -1 and np.isnan(bad.drift).all()


def test_emulated_fast_exp_fused_within_its_documented_error(tmp_path):
    """The M4F's fused variant of the fast expf (through the RBF header's exp) on points
    spread over the domain: an RBF of one centre with unit weight is exp(exponent)."""
    from thermonet.models.cgen import c_exp

    xs = np.linspace(FAST_EXP_DOMAIN[0], FAST_EXP_DOMAIN[1], 400).astype(np.float32)
    text = ("#include <math.h>\n" + "\n".join(c_target_prelude()) + "\n"
            "#define THERMONET_N_AXES 2\n#define THERMONET_N_SIGNALS 1\n"
            "#define THERMONET_N_PROXIES 0\n"
            "typedef struct { int unused; } thermonet_state;\n"
            "static inline void thermonet_init(thermonet_state *st) { st->unused = 0; }\n"
            "static inline int thermonet_step(thermonet_state *st, thermonet_time_t t,\n"
            "    float temp, const thermonet_real_t *raw, thermonet_real_t *c,\n"
            "    thermonet_real_t *d, int *flag)\n"
            "{ (void)st; (void)t; (void)temp; (void)raw; (void)c; (void)d; *flag = 0;"
            " return 0; }\n"
            "static inline int thermonet_compensate(const float *s, const thermonet_real_t *r,\n"
            "    thermonet_real_t *c, thermonet_real_t *d)\n"
            f"{{ (void)r; d[0] = {c_exp('s[0]')}; d[1] = thermonet_fast_expm1f(s[0]);"
            " c[0] = c[1] = 0.0f; return 0; }\n")
    build = cross_compile(text, "cortex-m4f", tmp_path)
    assert build.undefined == []
    emu = Emulator(build, 1, 2)
    got = np.array([emu.evaluate(np.array([x]), np.zeros(2)).drift for x in xs])
    x64 = xs.astype(np.float64)
    assert np.max(np.abs(got[:, 0] - np.exp(x64)) / np.exp(x64)) <= FAST_EXPF_MAX_REL_ERR
    nz = x64 != 0
    assert np.max(np.abs(got[nz, 1] - np.expm1(x64[nz])) / np.abs(np.expm1(x64[nz]))) \
        <= FAST_EXPM1F_MAX_REL_ERR


# ------------------------------------------------------------------ the README's example
README_EXAMPLE = r"""#include "thermonet_model.h"      /* thermonet export runs/demo --format c --out ... */
#define COUNTS_PER_UNIT ((thermonet_real_t)16.4)  /* per unit of THERMONET_AXIS_UNITS */
static thermonet_state tc;        /* thermonet_init(&tc) once, at start-up */
/* 0; 1 out of range (no temperature: out[] NaN); -1 a refused sample (out[] NaN) */
int imu_sample(uint64_t t_us, float temp_c, const int32_t counts[THERMONET_N_AXES],
               float out[THERMONET_N_AXES])
{
    thermonet_real_t raw[THERMONET_N_AXES], comp[THERMONET_N_AXES], drift[THERMONET_N_AXES];
    int a, out_of_range, ret;
    for (a = 0; a < THERMONET_N_AXES; ++a) raw[a] = (thermonet_real_t)counts[a] / COUNTS_PER_UNIT;
    ret = thermonet_step(&tc, THERMONET_TIME_FROM_US(t_us), temp_c, raw, comp, drift,
                         &out_of_range);
    for (a = 0; a < THERMONET_N_AXES; ++a) out[a] = (float)comp[a];
    return ret < 0 ? -1 : out_of_range;
}
"""


def test_readme_example_builds_for_every_target(models, tmp_path):
    """The README's sensor-driver example, verbatim, under the strict flags on each target
    and on the host (a model without proxies: step takes no proxies argument)."""
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert README_EXAMPLE in readme
    model = models["poly", "stream"]
    assert not stream_signature_has_proxies(model)
    (tmp_path / "thermonet_model.h").write_text(render_c_header(model))
    src = tmp_path / "driver.c"
    src.write_text(README_EXAMPLE.replace(
        "int imu_sample(", "int imu_sample(uint64_t t_us, float temp_c, "
        "const int32_t counts[THERMONET_N_AXES], float out[THERMONET_N_AXES]);\nint imu_sample(",
        1))
    tools = toolchain()
    strict = ["-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wshadow", "-Wdouble-promotion",
              "-Wconversion", "-Werror", "-O2", "-c", str(src)]
    for target, flags in TARGETS.items():
        subprocess.run([tools["gcc"], *flags, *strict, "-o", str(tmp_path / f"{target}.o")],
                       check=True, cwd=tmp_path)
    subprocess.run(["gcc", *strict, "-o", str(tmp_path / "host.o")], check=True, cwd=tmp_path)


def _markdown_c_block(path: Path, marker: str) -> str:
    """The fenced ```c block of ``path`` that holds ``marker`` (the test fails without one)."""
    text = path.read_text(encoding="utf-8")
    blocks = [b.split("```", 1)[0] for b in text.split("```c\n")[1:]]
    found = [b for b in blocks if marker in b]
    assert len(found) == 1, f"{path}: {len(found)} C blocks hold {marker!r}"
    return found[0]


HOST_RUN = r"""
#include <math.h>
#include <stdio.h>
int main(void)
{
    int32_t c1[THERMONET_N_AXES], c2[THERMONET_N_AXES];
    float o1[THERMONET_N_AXES], o2[THERMONET_N_AXES];
    int a, r1, r2, again, missing;
    for (a = 0; a < THERMONET_N_AXES; ++a) { c1[a] = 1000 * (a + 1); c2[a] = -328 * (a + 2); }
    thermonet_init(&tc);
    r1 = imu_sample(1000000u, 25.0f, c1, o1);
    again = imu_sample(1000000u, 25.0f, c1, o1);       /* the same time: refused */
    printf("%d %d %d\n", r1, again, isnan(o1[0]) != 0);
    thermonet_init(&tc);
    r2 = imu_sample(1000000u, 25.0f, c2, o2);
    missing = imu_sample(2000000u, (float)NAN, c2, o1);  /* a missing temperature */
    printf("%d %d %d\n", r2, missing, isnan(o1[0]) != 0);
    thermonet_init(&tc);
    r1 = imu_sample(1000000u, 25.0f, c1, o1);
    for (a = 0; a < THERMONET_N_AXES; ++a)   /* the same drift: out differs by counts/scale */
        printf("%.9g %.9g\n", (double)(o1[a] - o2[a]), (double)(c1[a] - c2[a]) / 16.4);
    return r1;
}
"""


def test_export_readmes_example_converts_counts_and_never_leaves_out_stale(models, tmp_path):
    """export/README.md's sensor-driver example (was: counts passed as the model's unit, and
    ``out[]`` left holding the previous sample's values when ``thermonet_step`` refused one)
    builds under the strict flags on every target, and on the host: a refused sample and a
    missing temperature give NaN ``out[]`` and say so by the return value, and ``out[]`` is
    in the model's unit (two samples in one state differ by their counts / 16.4)."""
    root = Path(__file__).resolve().parents[1]
    example = _markdown_c_block(root / "export" / "README.md", "int imu_sample(")
    assert "COUNTS_PER_UNIT" in example and "THERMONET_AXIS_UNITS" in example
    model = models["poly", "stream"]
    assert not stream_signature_has_proxies(model)
    (tmp_path / "thermonet_model.h").write_text(render_c_header(model))
    proto = ("int imu_sample(uint64_t t_us, float temp_c, const int32_t counts[THERMONET_N_AXES]"
             ", float out[THERMONET_N_AXES]);\n")
    src = tmp_path / "driver.c"
    src.write_text(example.replace("int imu_sample(", proto + "int imu_sample(", 1))
    tools = toolchain()
    strict = ["-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wshadow", "-Wdouble-promotion",
              "-Wconversion", "-Werror", "-O2"]
    for target, flags in TARGETS.items():
        subprocess.run([tools["gcc"], *flags, *strict, "-c", str(src), "-o",
                        str(tmp_path / f"{target}.o")], check=True, cwd=tmp_path)
    (tmp_path / "run.c").write_text(example + HOST_RUN)
    for real in ("", "-DTHERMONET_USE_FLOAT"):
        exe = tmp_path / f"run{real}"
        subprocess.run(["gcc", "-std=c99", "-O2", *([real] if real else []), "-o", str(exe),
                        "run.c", "-lm"], check=True, cwd=tmp_path)
        got = subprocess.run([str(exe)], capture_output=True, text=True, cwd=tmp_path)
        lines = got.stdout.splitlines()
        assert lines[0] == "0 -1 1" and lines[1] == "0 1 1", (real, got.stdout)
        diff = np.array([[float(v) for v in ln.split()] for ln in lines[2:]])
        assert diff.shape == (len(model.outputs), 2)
        # float path: raw and out are floats; counts / 16.4 ~ 100 units: a few float ulps
        np.testing.assert_allclose(diff[:, 0], diff[:, 1], rtol=1e-6)


def test_two_headers_in_one_translation_unit(models, tmp_path):
    """One header per IMU, different prefixes, included together: the shared type, time
    type and fast exponentials are defined once (THERMONET_REAL_T_DEFINED)."""
    from thermonet.exporting.c_header import render_c_header as render

    (tmp_path / "imu0.h").write_text(render(models["rbf", "plain"], prefix="imu0"))
    (tmp_path / "imu1.h").write_text(render(models["poly", "stream"], prefix="imu1"))
    src = tmp_path / "both.c"
    src.write_text('#include "imu0.h"\n#include "imu1.h"\n'
                   "int both(const float *s, const thermonet_real_t *raw, thermonet_real_t *c,\n"
                   "         thermonet_real_t *d);\n"
                   "int both(const float *s, const thermonet_real_t *raw, thermonet_real_t *c,\n"
                   "         thermonet_real_t *d)\n"
                   "{\n    return imu0_compensate(s, raw, c, d)"
                   " | imu1_compensate(s, raw, c, d);\n}\n")
    tools = toolchain()
    for target, flags in TARGETS.items():
        subprocess.run([tools["gcc"], *flags, "-std=c99", "-Wall", "-Wextra", "-Wpedantic",
                        "-Wshadow", "-Wdouble-promotion", "-Wconversion", "-Werror", "-O2",
                        "-c", str(src), "-o", str(tmp_path / f"{target}.o")], check=True,
                       cwd=tmp_path)


@pytest.fixture(scope="module")
def gru_model():
    """A small GRU (the recurrent family: its own header, tests/test_gru.py)."""
    t = np.arange(0.0, 1800.0, 2.0)
    temp = 5.0 + 40.0 * np.abs(((t / 900.0) % 2.0) - 1.0)
    y = np.stack([1e-3 * (temp - 25.0), -2e-3 * (temp - 25.0)], 1)
    spec = FeatureSpec(inputs=["dT"], t_ref=25.0)
    return fit(family="gru", inputs=["dT"], outputs=AXES, train=[(temp[:, None], y, t)],
               val=None, spec=spec, hyper={"hidden": 4},
               config=TrainConfig(max_epochs=2, seed=0)).model


def test_every_header_builds_strict_everywhere_and_links_bare(models, gru_model, tmp_path):
    """Every family's header (plain and streaming, and the GRU's), float and double paths,
    under -Wall -Wextra -Wpedantic -Wshadow -Wconversion -Wsign-conversion
    -Wdouble-promotion -Werror: on the host (x86-64, LP64: ``long`` and ``uint64_t`` are
    64 bits there, not on the Cortex-M) and for every Cortex-M target; each target's object
    links with -nostdlib, libm and libgcc only.  Where the header calls libm's expf/expm1f
    (M7's float path, every double path) newlib's libm needs one symbol of its libc: errno
    (``__errno``), set on overflow — nothing else."""
    from thermonet.exporting.mcu import STRICT_FLAGS, host_compile, link_bare

    assert {"-Wall", "-Wextra", "-Wshadow", "-Wconversion", "-Wsign-conversion",
            "-Wdouble-promotion", "-Werror"} <= set(STRICT_FLAGS)
    built = 0
    for (family, kind), model in [*models.items(), (("gru", "plain"), gru_model)]:
        text = render_c_header(model)
        how = {"has_proxies": stream_signature_has_proxies(model),
               "recurrent": family == "gru"}
        for real in ("-DTHERMONET_USE_FLOAT", "-DTHERMONET_USE_DOUBLE"):
            where = tmp_path / family / kind / real.rsplit("_", 1)[1]
            host_compile(text, where / "host", extra=(real,), **how)
            for target in TARGETS:
                build = cross_compile(text, target, where / target, extra=(real,), **how)
                left = link_bare(build, where / target / "bare.elf")
                assert set(left) <= {"__errno"}, (family, kind, real, target, left)
                assert build.libm or not left, (family, kind, real, target, left)
                built += 1
    assert built == (len(models) + 1) * 2 * len(TARGETS)
