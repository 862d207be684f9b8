"""Streams in chunks: a long recording processed block by block, the state carried
across block edges, gives the whole-array result.

* training's dynamic inputs (:class:`thermonet.features.dynamics.DynamicStream`) against
  :func:`~thermonet.features.dynamics.compute` on the whole array (float64: play bitwise, its
  recurrence is comparisons only; rate/lag to float64 rounding);
* the torch-free runtime's ``Compensator.step_block`` against one ``compensate`` call on the
  whole sequence (onnxruntime, float32 graph) and against ``step`` sample by sample;
* the C header's ``<prefix>_step_block`` against ``<prefix>_step`` sample by sample (gcc:
  the same float32 operations in the same order, so bit-identical).

Chunk sizes include 1, sizes that are not block multiples of the scans, and cuts placed
exactly at a gap (the restart is the chunk's first sample), one sample before and after it,
inside a run of missing temperatures and a chunk made only of missing temperatures.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import load_runtime
from thermonet.core.trainconfig import TrainConfig
from thermonet.exporting import export_onnx, render_c_header
from thermonet.exporting.c_stream import run_stream_c
from thermonet.features import dynamics
from thermonet.features.inputs import FeatureSpec
from thermonet.training.train import fit
from tolerances import assert_f32_close, assert_f64_close

pytestmark = pytest.mark.numerics

INPUTS = ["rate", "rate_30", "lag_20", "lag_900", "play_0.2", "play_3.5"]
MODEL_INPUTS = ["dT", "rate", "lag_300", "play_0.5"]
AXES = ["gyro_x", "gyro_y"]
GAP_S = 5.0
N = 3000
#: the gap (t jumps by 40 s before sample GAP_AT) and the missing temperatures of _sequence
GAP_AT, NAN_AT, NAN_RUN = 1200, 300, (2000, 2004)

rt = load_runtime()


def _sequence(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Jittered Unix-epoch times, heat/cool cycles with noise, a gap and missing temperatures."""
    rng = np.random.default_rng(seed)
    t = 1.7e9 + np.cumsum(rng.uniform(0.5, 1.5, N))
    t[GAP_AT:] += 40.0
    phase = ((t - t[0]) % 5000.0) / 5000.0
    temp = 5.0 + 40.0 * (1.0 - np.abs(2.0 * phase - 1.0)) + rng.normal(0.0, 0.005, N)
    temp[NAN_AT] = np.nan
    temp[NAN_RUN[0]:NAN_RUN[1]] = np.nan
    raw = rng.normal(0.0, 0.01, (N, len(AXES)))
    return t, temp, raw


def _cuts(size: int | str) -> list[int]:
    """Chunk edges: every ``size`` samples, or edges at the gap and in the missing samples."""
    if size == "at-gaps-and-nans":
        edges = [GAP_AT - 1, GAP_AT, GAP_AT + 1, NAN_AT, NAN_AT + 1, NAN_RUN[0], NAN_RUN[0] + 2,
                 NAN_RUN[1]]   # [2002, 2004) is a chunk of missing temperatures only
        return [0, *sorted(edges), N]
    return [*range(0, N, int(size)), N]


SIZES = [1, 7, 256, 1000, "at-gaps-and-nans"]


@pytest.mark.parametrize("size", SIZES)
def test_dynamic_inputs_chunk_by_chunk_equal_the_whole_array(size):
    t, temp, _ = _sequence()
    whole, gap_whole = dynamics.compute(t, temp, INPUTS, GAP_S)
    assert gap_whole.sum() == 1 and gap_whole[GAP_AT]
    stream = dynamics.DynamicStream(INPUTS, GAP_S)
    cuts = _cuts(size)
    parts = [stream.push(t[a:b], temp[a:b]) for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    assert np.array_equal(np.concatenate([p[1] for p in parts]), gap_whole)   # booleans
    for d in dynamics.dynamic_signals(INPUTS):
        got = np.concatenate([p[0][d.signal] for p in parts])
        if isinstance(d, dynamics.Play):
            np.testing.assert_array_equal(got, whole[d.signal])   # comparisons only: exact
        else:  # the blocked scan composes its block maps in another order: float64 rounding
            scale = float(np.nanmax(np.abs(whole[d.signal])))
            assert_f64_close(got, whole[d.signal], rtol=0, atol=1e-12 * scale, err_msg=d.signal)
    # the runtime's own copy of the recurrences, carried in its stream state
    block = dynamics.constants(INPUTS, GAP_S)
    state = rt._Stream(len(block["inputs"]))
    parts = [rt.dynamic_signals(t[a:b], temp[a:b], block, state)
             for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    assert np.array_equal(np.concatenate([p[1] for p in parts]), gap_whole)
    for d in dynamics.dynamic_signals(INPUTS):
        got = np.concatenate([p[0][d.signal] for p in parts])
        scale = float(np.nanmax(np.abs(whole[d.signal])))
        assert_f64_close(got, whole[d.signal], rtol=0, atol=1e-12 * scale, err_msg=d.signal)


def test_a_refused_chunk_leaves_the_state_unchanged():
    t, temp, _ = _sequence()
    whole, _ = dynamics.compute(t, temp, INPUTS, GAP_S)
    stream = dynamics.DynamicStream(INPUTS, GAP_S)
    stream.push(t[:100], temp[:100])
    with pytest.raises(dynamics.TimeError, match=r"sample 100: time repeated .*chunk edge"):
        stream.push(t[99:150], temp[99:150])
    bad = t[100:150].copy()
    bad[10] = np.nan
    with pytest.raises(dynamics.TimeError, match="sample 10: time is nan"):
        stream.push(bad, temp[100:150])
    got, _ = stream.push(t[100:150], temp[100:150])
    for name, col in got.items():
        assert_f64_close(col, whole[name][100:150], rtol=0,
                         atol=1e-12 * float(np.nanmax(np.abs(whole[name]))), err_msg=name)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A cross-term poly on every kind of dynamic input (as tests/test_dynamics.py fits it)."""
    t = np.arange(0.0, 30000.0, 2.0)
    phase = (t % 8000.0) / 8000.0
    temp = -10.0 + 70.0 * (1.0 - np.abs(2.0 * phase - 1.0))
    sig, _ = dynamics.compute(t, temp, MODEL_INPUTS, GAP_S)
    spec = FeatureSpec(inputs=MODEL_INPUTS, t_ref=20.0, gap_s=GAP_S)
    s = np.column_stack([temp] + [sig[x] for x in spec.signals[1:]])
    y = np.column_stack([0.01 * (temp - 20.0) + 0.02 * sig["rate_c_per_min"],
                         0.003 * sig["play_0.5_c"] + 0.001 * sig["lag_300_c"]])
    model = fit(family="poly", inputs=MODEL_INPUTS, outputs=AXES, train=[(s, y)], val=None,
                spec=spec, hyper={"degree": 2, "cross": True},
                config=TrainConfig(max_epochs=3)).model
    return model, export_onnx(model, tmp_path_factory.mktemp("stream") / "m.onnx")


@pytest.mark.parametrize("size", SIZES)
def test_runtime_step_block_equals_one_batch_call(trained, size):
    model, path = trained
    t, temp, raw = _sequence()
    comp = rt.Compensator(path)
    whole = comp.compensate(temperature_c=temp, raw=raw, time_s=t)
    assert whole.out_of_range[GAP_AT] and np.isnan(whole.drift[NAN_AT]).all()
    cuts = _cuts(size)
    parts = [comp.step_block(t[a:b], temp[a:b], raw[a:b])
             for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    drift = np.concatenate([p.drift for p in parts])
    # the same graph on float32 signals that differ by float64 rounding of the scans
    assert_f32_close(drift, whole.drift, "dynamic")
    assert_f32_close(np.concatenate([p.compensated for p in parts]), whole.compensated,
                     "dynamic", scale=whole.drift)
    assert np.array_equal(np.concatenate([p.out_of_range for p in parts]), whole.out_of_range)


def test_runtime_step_block_mixes_with_step_and_refuses_whole_blocks(trained):
    _, path = trained
    t, temp, raw = _sequence()
    comp = rt.Compensator(path)
    whole = comp.compensate(temperature_c=temp, raw=raw, time_s=t)
    first = comp.step_block(t[:500], temp[:500], raw[:500])
    one = [comp.step(t[k], temp[k], raw[k]) for k in range(500, 510)]
    # a block that goes back in time, or has a NaN time, is refused whole: state unchanged
    with pytest.raises(rt.RuntimeInputError, match="time_s: sample 0: time repeated"):
        comp.step_block(t[509:600], temp[509:600], raw[509:600])
    with pytest.raises(rt.RuntimeInputError, match="'raw' must have shape"):
        comp.step_block(t[510], temp[510], raw[510])
    rest = comp.step_block(t[510:], temp[510:], raw[510:])
    drift = np.concatenate([first.drift, np.array([r.drift for r in one]), rest.drift])
    assert_f32_close(drift, whole.drift, "dynamic")
    flags = np.concatenate([first.out_of_range, [r.out_of_range for r in one],
                            rest.out_of_range])
    assert np.array_equal(flags, whole.out_of_range)
    comp.reset()   # a fresh stream: the first block equals a fresh batch of it
    again = comp.step_block(t[:50], temp[:50], raw[:50])
    assert_f32_close(again.drift, whole.drift[:50], "dynamic")


@pytest.mark.parametrize("block", [1, 7, 1000])
def test_c_step_block_is_step_sample_by_sample(trained, block):
    model, _ = trained
    t, temp, raw = _sequence()
    header = render_c_header(model)
    assert "thermonet_step_block(thermonet_state *st, int n" in header
    one = run_stream_c(model, header, t, temp, raw)
    blk = run_stream_c(model, header, t, temp, raw, block=block)
    # step_block calls step on each sample in order: the same float32 operations, bitwise
    np.testing.assert_array_equal(blk["drift"], one["drift"])
    np.testing.assert_array_equal(blk["compensated"], one["compensated"])
    assert np.array_equal(blk["flag"], one["flag"]) and (blk["ret"] == 0).all()
    with torch.no_grad():   # and both are the model: torch on the float64 features
        sig, _ = dynamics.compute(t, temp, MODEL_INPUTS, GAP_S)
        s = np.column_stack([temp] + [sig[x] for x in model.signals[1:]])
        want = model(torch.from_numpy(s)).double().numpy()
    assert_f32_close(blk["drift"], want, "dynamic")
    # a refused sample inside a block: NaN and flag there, counted, the block goes on
    t_bad = t[:20].copy()
    t_bad[5] = t_bad[4]
    cb = run_stream_c(model, header, t_bad, temp[:20], raw[:20], block=block)
    assert cb["ret"][5] == 1 and np.isnan(cb["drift"][5]).all() and cb["flag"][5]
    assert cb["ret"].sum() == min(block, 20)  # ret repeats the block's count on its samples
    ref = run_stream_c(model, header, t_bad, temp[:20], raw[:20])   # step, one by one
    np.testing.assert_array_equal(cb["drift"], ref["drift"])
    assert (ref["ret"] != 0).tolist() == (np.arange(20) == 5).tolist()


def test_normal_equations_over_chunks_recover_known_coefficients():
    """A cubic in standardised ΔT with known coefficients, 200,000 rows: the normal equations
    accumulated over chunks (1, 7, 4,096 rows and two workers merged) give the whole-array
    least squares to float64 rounding, and both recover the coefficients to the noise's
    standard error (σ/√N per standardised term ≈ 2e-6 here: 1e-4 is ≥ 40 σ)."""
    from thermonet.models.base import NormalEquations, least_squares

    rng = np.random.default_rng(7)
    n = 200_000
    z = rng.uniform(-1.7, 1.7, n)                     # a standardised temperature
    design = np.column_stack([z, z ** 2, z ** 3, np.ones(n)])
    coef = np.array([[0.8, -0.3], [0.05, 0.2], [-0.01, 0.07], [0.4, -1.1]])
    y = design @ coef + rng.normal(0.0, 1e-3, (n, 2))
    whole = least_squares(design, y)
    np.testing.assert_allclose(whole, coef, rtol=0, atol=1e-4)
    for size in (1, 7, 4096):
        if size == 1:   # row by row (rank-one updates), on a 5,000-row prefix
            m = 5000
            ne = NormalEquations(4, 2)
            for k in range(m):
                ne.add(design[k:k + 1], y[k:k + 1])
            assert_f64_close(ne.solve(), least_squares(design[:m], y[:m]), rtol=1e-9)
            continue
        ne = NormalEquations(4, 2)
        for a in range(0, n, size):
            ne.add(design[a:a + size], y[a:a + size])
        assert ne.n_rows == n
        # the solve amplifies the sums' rounding by the Gram matrix's condition (≈ 1e3)
        assert_f64_close(ne.solve(), whole, rtol=1e-9)
    left = NormalEquations(4, 2).add(design[:123_457], y[:123_457])
    right = NormalEquations(4, 2).add(design[123_457:], y[123_457:])
    assert_f64_close(left.merge(right).solve(), whole, rtol=1e-9)


def test_blocks_with_a_proxy_runtime_and_c(tmp_path):
    """A model that also reads a proxy (``d_freq_hz``, passed by name, row-major in C): the
    runtime's blocks equal one batch call, the C blocks equal step() sample by sample."""
    inputs = ["dT", "d_freq_hz", "rate"]
    t, temp, raw = _sequence(seed=2)
    freq = 1000.0 + 2.0 * np.nan_to_num(temp, nan=20.0)
    tt = np.arange(0.0, 30000.0, 2.0)
    phase = (tt % 8000.0) / 8000.0
    T = -10.0 + 70.0 * (1.0 - np.abs(2.0 * phase - 1.0))
    sig, _ = dynamics.compute(tt, T, inputs, GAP_S)
    spec = FeatureSpec(inputs=inputs, t_ref=20.0, proxy_ref={"freq_hz": 1040.0}, gap_s=GAP_S)
    cols = {"temperature_c": T, "freq_hz": 1000.0 + 2.0 * T, **sig}
    s = np.column_stack([cols[x] for x in spec.signals])
    y = np.column_stack([0.01 * (T - 20.0) + 0.02 * sig["rate_c_per_min"], 0.001 * T])
    model = fit(family="linear", inputs=inputs, outputs=AXES, train=[(s, y)], val=None,
                spec=spec, hyper={}, config=TrainConfig(max_epochs=0)).model
    comp = rt.Compensator(export_onnx(model, tmp_path / "p.onnx"))
    whole = comp.compensate(temperature_c=temp, raw=raw, time_s=t, freq_hz=freq)
    cuts = _cuts("at-gaps-and-nans")
    parts = [comp.step_block(t[a:b], temp[a:b], raw[a:b], freq_hz=freq[a:b])
             for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    assert_f32_close(np.concatenate([p.drift for p in parts]), whole.drift, "dynamic")
    assert np.array_equal(np.concatenate([p.out_of_range for p in parts]), whole.out_of_range)
    header = render_c_header(model)
    assert "const float *proxies," in header.split("_step_block(")[1].split(")")[0]
    one = run_stream_c(model, header, t, temp, raw, freq[:, None])
    blk = run_stream_c(model, header, t, temp, raw, freq[:, None], block=7)
    np.testing.assert_array_equal(blk["drift"], one["drift"])   # step, sample by sample
    assert np.array_equal(blk["flag"], one["flag"])
    assert_f32_close(one["drift"], whole.drift, "dynamic")
