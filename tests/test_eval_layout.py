"""The evaluation layout: for every registered family, the fast path that the ONNX
graph and the C header run is the training-path function, propagates NaN/±inf, clamps and
flags; the graph holds no Where/IsNaN; every family owns its C emitter with constants from
Python.  Averaging instead of thinning, threads per fit, the O(N) Allan deviation and the
fast-length simulator noise are checked here too.  No timing assertions (experiments/)."""

from __future__ import annotations

import copy

import allantools
import numpy as np
import onnx
import pytest
import torch

from conftest import pointwise_families
from thermonet.core.errors import ConfigError, InputError
from thermonet.exporting import export_onnx, render_c_header
from thermonet.features.inputs import FeatureSpec
from thermonet.models import MODELS, Family
from thermonet.scoring import metrics
from thermonet.sim.device import flicker_noise
from thermonet.training.train import TrainConfig, average_windows, fit, predict
from tolerances import assert_f32_close

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

AXES = ["gyro_x", "gyro_y", "gyro_z"]
T_REF = 25.0


def _drift(temp: np.ndarray) -> np.ndarray:
    dt = temp - T_REF
    base = 1e-3 * dt + 2e-5 * dt ** 2 - 1e-7 * dt ** 3
    return np.stack([base + 0.01, -0.5 * base + 0.004 * np.exp(-(dt / 15) ** 2),
                     2 * base - 0.02], 1)


def _inputs(family: str) -> list[str]:
    return ["dT", "dT2"] if MODELS[family].max_inputs is None else ["dT"]


@pytest.fixture(scope="module")
def models():
    temp = np.linspace(-20.0, 60.0, 400)
    out = {}
    for name in pointwise_families():
        spec = FeatureSpec(inputs=_inputs(name), t_ref=T_REF)
        out[name] = fit(family=name, inputs=_inputs(name), outputs=AXES,
                        train=[(temp[:, None], _drift(temp))], val=None, spec=spec, hyper={},
                        config=TrainConfig(max_epochs=5, seed=0)).model
    return out


def _training_path(model, temp: np.ndarray) -> np.ndarray:
    """float64 drift the way training sees it: stacked features, family forward, de-standardise,
    plus the float64 constant removed before standardisation (``channel`` targets)."""
    # a float64 copy: .double() then .float() would round the float64 y_offset buffer
    m = copy.deepcopy(model).double()
    with torch.no_grad():
        s = torch.clamp(torch.as_tensor(temp[:, None]), m.sig_lo, m.sig_hi)
        z = (m.features(s) - m.x_mean) / m.x_std
        return (m.family(z) * m.y_std + m.y_mean + m.y_offset).numpy()


@pytest.mark.parametrize("family", pointwise_families())
def test_evaluation_path_is_the_trained_function(models, family):
    model = models[family]
    temp = np.linspace(-20.0, 60.0, 997)
    want = _training_path(model, temp)
    got = predict(model, temp[:, None])
    scale = np.abs(want).max(axis=0)
    # float32 against float64: a few ulps of the drift's scale, never a formula error (≥ 1e-3)
    assert (np.abs(got - want) <= 2e-5 * scale).all(), np.abs(got - want).max(axis=0) / scale
    # the same function evaluated in float64 agrees to float64 rounding
    with torch.no_grad():
        d64 = copy.deepcopy(model).double()(torch.as_tensor(temp[:, None])).numpy()
    np.testing.assert_allclose(d64, want, rtol=0, atol=1e-9 * scale.max())


@pytest.mark.parametrize("family", pointwise_families())
def test_nan_inf_and_clamp_without_branches(models, family):
    model = models[family]
    lo, hi = float(model.sig_lo[0]), float(model.sig_hi[0])
    sig = torch.tensor([lo - 10.0, hi + 10.0, np.nan, np.inf, -np.inf, 0.5 * (lo + hi)],
                       dtype=torch.float32)
    with torch.no_grad():
        drift, flag = model.evaluate([sig])
    drift = drift.T                                # evaluate is axis-major (A, N)
    assert flag.tolist() == [True, True, True, True, True, False]
    # the clamp makes the input the edge value itself: the same computation on the same batch
    # shape and position with the edges given directly is bit-identical (a promise of the code)
    at_edges = sig.clone()
    at_edges[:2] = torch.tensor([lo, hi])
    with torch.no_grad():
        same, _ = model.evaluate([at_edges])
    np.testing.assert_array_equal(drift[:2].numpy(), same.T[:2].numpy())
    with torch.no_grad():   # evaluate gives the drift relative to the float64 constant
        edges = model.relative(torch.tensor([[lo], [hi]]))
    # another computation (a batch of 2): equal to float32 rounding, not bit for bit
    assert_f32_close(drift[:2].numpy(), edges.numpy(), "family", axis=None)
    assert torch.isnan(drift[2:5]).all()          # every axis, never the clamped edge value
    assert torch.isfinite(drift[5]).all()
    np.testing.assert_array_equal(flag.numpy(), model.out_of_range(sig[:, None]).numpy())


@pytest.mark.parametrize("family", pointwise_families())
def test_set_target_evaluates_at_rest_in_float64_and_leaves_the_rest_untouched(models, family):
    """set_target's value at rest is the float64 model's without a mode or a mask — what a
    float64 deep copy computes, to the bit — and every other parameter and buffer keeps its
    tensor object, dtype and values (its float64 evaluation swaps copies in and back)."""
    model = copy.deepcopy(models[family])
    model.set_compensate([True, False, True])
    before = {k: (v, v.dtype, v.clone()) for k, v in model.state_dict(keep_vars=True).items()}
    oracle = copy.deepcopy(model).double()
    oracle.target_code.zero_()
    oracle.compensate.fill_(1.0)
    with torch.no_grad():
        want = oracle.relative(torch.tensor([[T_REF + 3.0]], dtype=torch.float64))[0]
    model.set_target(modes=["at-t-ref", "channel", "zero"], offset=np.array([1.0, 2.0, 3.0]),
                     rest=np.array([T_REF + 3.0]))
    assert torch.equal(model.y_ref, want.to(model.y_ref.dtype))
    assert model.target_code.tolist() == [2, 0, 1]       # MODE_CODES
    after = model.state_dict(keep_vars=True)
    for k, (obj, dtype, values) in before.items():
        assert after[k] is obj and after[k].dtype == dtype, k
        if k.split(".")[-1] not in ("y_offset", "y_ref", "sig_ref", "target_code"):
            assert torch.equal(after[k], values), k


@pytest.mark.parametrize("family", pointwise_families())
def test_mask_and_at_t_ref_folded_into_the_output_layer(models, family, tmp_path):
    """The per-axis target (at-t-ref) and the uncompensated mask are folded into each family's
    last product (DriftModel.output_scaling): the same drift as applying them afterwards,
    exactly 0 on a masked axis for every finite signal, NaN there for NaN, in torch,
    onnxruntime and C."""
    import onnxruntime as ort

    from thermonet.exporting.c_export import c_parity_check

    plain = models[family]
    model = copy.deepcopy(plain)
    model.set_target(modes=["at-t-ref", "channel", "channel"],
                     offset=plain.y_offset.numpy(), rest=np.array([T_REF]))
    model.set_compensate([True, True, False])
    temp = np.linspace(-30.0, 70.0, 201)              # beyond the trained range on both sides
    sig = torch.tensor(np.append(temp, np.nan), dtype=torch.float32)
    with torch.no_grad():
        rel = model.evaluate([sig])[0].T               # axis-major (A, N)
        want = plain.relative(sig[:-1, None]).double()
        want_rest = copy.deepcopy(plain).double().relative(torch.tensor([[T_REF]]))[0]
    scale = want.abs().max(dim=0).values
    assert (rel[:-1, 2] == 0).all()                   # exactly, not nearly
    assert torch.isnan(rel[-1]).all()                 # NaN × 0 is still NaN
    np.testing.assert_allclose(rel[:-1, 1], want[:, 1], rtol=0, atol=2e-6 * float(scale[1]))
    np.testing.assert_allclose(rel[:-1, 0], want[:, 0] - want_rest[0], rtol=0,
                               atol=2e-6 * float(scale[0]))
    # the at-t-ref axis is 0 at rest, its constant cancels; the masked axis has none either
    with torch.no_grad():
        at_rest = float(model.relative(torch.tensor([[T_REF]]))[0, 0])
    assert abs(at_rest) <= 2e-6 * float(scale[0])
    const = model.constant().numpy()
    assert const[0] == 0.0 and const[2] == 0.0 and const[1] == plain.y_offset.numpy()[1]
    path = export_onnx(model, tmp_path / "m.onnx")    # parity: a masked axis has tolerance 0
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    raw = np.full((sig.shape[0], 3), 5.0)
    comp, drift, _ = sess.run(None, {"temperature_c": sig.numpy(), "raw": raw})
    assert (drift[:-1, 2] == 0.0).all() and (comp[:-1, 2] == 5.0).all()
    assert np.isnan(drift[-1]).all()
    # the C header, the same exactness (compiled: None would mean no compiler was found)
    assert c_parity_check(model, render_c_header(model)) is not None


@pytest.mark.parametrize("family", pointwise_families())
def test_graph_has_no_where_and_rbf_is_two_matrix_products(models, family, tmp_path):
    path = export_onnx(models[family], tmp_path / "m.onnx")   # parity-checked on export
    ops = [n.op_type for n in onnx.load(str(path)).graph.node]
    for banned in ("Where", "IsNaN", "IsInf", "Gather"):
        assert banned not in ops, (banned, ops)
    if family == "rbf":
        assert ops.count("Gemm") + ops.count("MatMul") == 2 and ops.count("Exp") == 1, ops


@pytest.mark.parametrize("family", pointwise_families())
def test_each_family_owns_its_c_emitter_and_restates_no_constant(models, family):
    cls = MODELS[family]
    assert cls.emit_c is not Family.emit_c, f"{family} has no C emitter of its own"
    text = render_c_header(models[family])
    for literal in ("60.0", "1e-6", "0.636619772", "y_std", "y_mean"):
        assert literal not in text, literal


def test_average_windows_means_and_gaps():
    # 4 Hz (exact in binary floating point), a gap from 3 s to 10 s
    t = np.concatenate([np.arange(0.0, 3.0, 0.25), np.arange(10.0, 11.5, 0.25)])
    s = np.stack([t, 2 * t], 1)
    y = (t ** 2)[:, None]
    sa, ya, ta = average_windows(s, y, t, 1.0)
    # 3 one-second windows before the gap, 2 after (1 s and 0.5 s): none straddles the gap
    assert ta.size == 5
    assert (np.sort(ta) == ta).all() and not ((ta > 3.0) & (ta < 10.0)).any()
    first = t < 1.0
    assert sa[0, 1] == pytest.approx(2 * t[first].mean())
    assert ya[0, 0] == pytest.approx((t[first] ** 2).mean())
    last = t >= 11.0
    assert ya[-1, 0] == pytest.approx((t[last] ** 2).mean())
    # window_s = 0 with min_samples: groups of k consecutive samples, within each segment
    _, _, tk = average_windows(s, y, t, 0.0, min_samples=4)
    assert tk.size == 3 + 2
    assert tk[3] == pytest.approx(t[12:16].mean())


def _noisy_100hz(seed: int, hours: float = 0.5):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, 0.01)
    temp = -10.0 + 60.0 * t / t[-1]
    y = _drift(temp)[:, :1] + rng.normal(0, 0.05, (t.size, 1))
    return t, temp, y


def test_averaging_fits_a_noisy_100hz_recording_no_worse_than_thinning():
    spec = FeatureSpec(inputs=["dT"], t_ref=T_REF)
    t, temp, y = _noisy_100hz(0)
    kw = dict(family="poly", inputs=["dT"], outputs=["gyro_x"], val=None, spec=spec,
              hyper={"degree": 3})
    cfg = TrainConfig(max_epochs=0, max_train_samples=2000)
    averaged = fit(train=[(temp[:, None], y, t)], config=cfg, **kw).model
    thinned = fit(train=[(temp[:, None], y)], config=cfg, **kw).model
    grid = np.linspace(-10.0, 50.0, 200)[:, None]
    truth = _drift(grid[:, 0])[:, 0]
    err_avg = np.sqrt(np.mean((predict(averaged, grid)[:, 0] - truth) ** 2))
    err_thin = np.sqrt(np.mean((predict(thinned, grid)[:, 0] - truth) ** 2))
    # same number of fitted samples; averaging keeps 90 times the information
    assert err_avg < 0.5 * err_thin, (err_avg, err_thin)


def test_threads_are_set_for_the_fit_and_restored():
    spec = FeatureSpec(inputs=["dT"], t_ref=T_REF)
    temp = np.linspace(-20.0, 60.0, 200)
    from threadpoolctl import threadpool_info

    def native() -> set[int]:
        """Threads of every native pool numpy / scikit-learn loaded (BLAS, OpenMP)."""
        return {int(p["num_threads"]) for p in threadpool_info()}

    import sklearn.cluster  # noqa: F401  loads scikit-learn's OpenMP runtime before the check

    before, before_native = torch.get_num_threads(), native()
    seen, seen_native = [], []

    def on_epoch(*a):
        seen.append(torch.get_num_threads())
        seen_native.append(native())

    fit(family="linear", inputs=["dT"], outputs=AXES, train=[(temp[:, None], _drift(temp))],
        val=None, spec=spec, hyper={}, config=TrainConfig(max_epochs=1, threads=1),
        on_epoch=on_epoch)
    assert seen and set(seen) == {1}
    assert seen_native and all(s == {1} for s in seen_native), seen_native
    assert torch.get_num_threads() == before and native() == before_native
    with pytest.raises(ConfigError, match="train.threads"):
        TrainConfig(threads=-1)
    with pytest.raises(ConfigError, match="train.average_s"):
        TrainConfig(average_s=-1.0)
    with pytest.raises(InputError, match="time_s"):
        fit(family="linear", inputs=["dT"], outputs=AXES,
            train=[(temp[:, None], _drift(temp), temp[::-1])], val=None, spec=spec, hyper={},
            config=TrainConfig(max_epochs=1))


def test_allan_long_series_matches_white_noise_theory_and_short_matches_allantools():
    rng = np.random.default_rng(5)
    n = metrics.ALLAN_EXACT_MAX + 50_000
    y = rng.normal(0.0, 0.02, n)
    taus, adev = metrics.allan(y, 100.0)
    usable = taus * 100.0 <= n / 256
    assert usable.sum() >= 8
    np.testing.assert_allclose(adev[usable], 0.02 / np.sqrt(taus[usable] * 100.0), rtol=0.10)
    short = y[:20_000]
    t_ref, a_ref, _, _ = allantools.oadev(short, rate=100.0, data_type="freq", taus="octave")
    t_got, a_got = metrics.allan(short, 100.0)
    # below ALLAN_EXACT_MAX metrics.allan does allantools' operations in its order: exact
    np.testing.assert_array_equal(t_got, t_ref)
    np.testing.assert_array_equal(a_got, a_ref)
    # the grid bias_instability_detail asks for (arrays, duplicates and out-of-range τ
    # dropped as allantools drops them), and allantools' other named grids
    grid = np.array([0.01, 0.013, 0.5, 0.5, 2.0, 33.3, 99.99, 1e5])
    for taus in (grid, "decade"):
        t_ref, a_ref, _, _ = allantools.oadev(short[:997], rate=100.0, data_type="freq",
                                              taus=taus)
        t_got, a_got = metrics.allan(short[:997], 100.0, taus=taus)
        np.testing.assert_array_equal(t_got, t_ref)
        np.testing.assert_array_equal(a_got, a_ref)


def test_an_allan_deviation_does_not_import_allantools():
    import subprocess
    import sys

    code = ("import sys, numpy as np\n"
            "from thermonet.scoring import metrics\n"
            "metrics.bias_instability(np.random.default_rng(0).normal(size=5000), 10.0)\n"
            "metrics.allan(np.ones(100) + np.arange(100) * 1e-3, 10.0)\n"
            "print('allantools' in sys.modules, 'scipy.stats' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["False", "False"]


def test_flicker_noise_on_a_fast_length_is_deterministic_and_has_the_asked_floor():
    n = 100_003                                     # a prime: the slowest length for an FFT
    a = flicker_noise(n, 10.0, 0.01, np.random.default_rng(2))
    b = flicker_noise(n, 10.0, 0.01, np.random.default_rng(2))
    assert a.shape == (n,)
    np.testing.assert_array_equal(a, b)              # same seed, same computation: exact
    floor = metrics.bias_instability(a, 10.0)
    assert floor == pytest.approx(0.664 * 0.01, rel=0.25)
