"""Every dynamic input, one definition: :mod:`thermonet.features.dynamics` against its mirrors.

For each kind of dynamic input (``rate`` and ``rate_<tau>``, ``lag_<tau>``, ``play_<w>``, at
several constants) the plain per-sample loop of the definition
(``tests/oracles.py``'s :func:`dynamic_inputs_loop`) is the oracle for

* the training computation (:func:`~thermonet.features.dynamics.compute`, a blocked scan),
* the torch-free runtime's batch computation (``export/thermonet_runtime.py``: its own blocked
  scan) and its streaming state (``_Stream``, one sample at a time, what ``Compensator.step``
  runs), and
* the C header's ``step()`` (float32, :mod:`thermonet.exporting.c_stream`).

The blocked scans cut a sequence into √N blocks and carry the state from one block into the
next; the sequences here put restarts (gaps), missing temperatures and the sequence's end on
and next to those block edges, at lengths one short of, at and one past a block multiple.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import load_runtime
from oracles import dynamic_inputs_loop
from thermonet.core.trainconfig import TrainConfig
from thermonet.exporting import render_c_header
from thermonet.exporting.c_stream import run_stream_c
from thermonet.features import dynamics
from thermonet.features.inputs import FeatureSpec
from thermonet.training.train import fit

pytestmark = pytest.mark.numerics

#: every kind, each at its default and at other constants
INPUTS = ["rate", "rate_30", "rate_600", "lag_20", "lag_60", "lag_900", "play_0.2", "play_1",
          "play_3.5"]
GAP_S = 5.0

rt = load_runtime()


def _block(n: int) -> int:
    """The block length both scans use for ``n`` samples."""
    return min(256, max(16, math.isqrt(max(n, 1))))


def _sequence(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Jittered Unix-epoch times and a heat/cool temperature with noise; gaps (> gap_s) and
    missing temperatures on and next to the scans' block edges."""
    rng = np.random.default_rng(seed)
    dt = rng.uniform(0.5, 1.5, n)
    b = _block(n)
    edges = np.arange(b, n, b)
    for k in edges[::3]:
        dt[k] += 3.0 * GAP_S                  # a restart exactly at a block edge
    for k in edges[1::3]:
        if k + 1 < n:
            dt[k + 1] += 3.0 * GAP_S          # ... and one sample past one
    t = 1.7e9 + np.cumsum(dt)
    phase = ((t - t[0]) % 4000.0) / 4000.0
    temp = 10.0 + 40.0 * (1.0 - np.abs(2.0 * phase - 1.0)) + rng.normal(0.0, 0.01, n)
    for k in edges[2::3]:
        temp[k - 1:k + 1] = np.nan            # missing temperatures across a block edge
    return t, temp


def _assert_same(got: dict, gap_got: np.ndarray, ref: dict, gap_ref: np.ndarray,
                 *, exact_play: bool) -> None:
    assert np.array_equal(gap_got, gap_ref)
    for d in dynamics.dynamic_signals(INPUTS):
        g, r = np.asarray(got[d.signal]), ref[d.signal]
        assert np.array_equal(np.isnan(g), np.isnan(r)), d.signal
        if isinstance(d, dynamics.Play) and exact_play:
            np.testing.assert_array_equal(g, r, err_msg=d.signal)   # comparisons only
        else:
            scale = max(float(np.nanmax(np.abs(r))), 1e-3)
            np.testing.assert_allclose(g, r, rtol=0, atol=1e-12 * scale, err_msg=d.signal)


@pytest.mark.parametrize("n", [1, 2, 15, 16, 17, 255, 256, 257, 3000, 65535, 65536, 65537])
def test_every_input_training_and_runtime_match_the_definition(n):
    t, temp = _sequence(n)
    ref, gap_ref = dynamic_inputs_loop(t, temp, INPUTS, GAP_S)
    if n > 1000:   # the sequence does restart and miss samples on the block edges
        assert gap_ref.sum() >= 3 and np.isnan(temp).sum() >= 2
        assert np.nanmax(np.abs(ref["rate_30_c_per_min"])) > 0.5        # ≈ 1.2 °C/min ramps
    # training: the vectorised blocked scan
    got, gap = dynamics.compute(t, temp, INPUTS, GAP_S)
    _assert_same(got, gap, ref, gap_ref, exact_play=True)
    # the runtime, batch: its own blocked scan from the model's stored constants
    block = dynamics.constants(INPUTS, GAP_S)
    got, gap = rt.dynamic_signals(t, temp, block)
    _assert_same(got, gap, ref, gap_ref, exact_play=True)
    # the runtime, streaming: one state carried from sample to sample
    stream = rt._Stream(len(block["inputs"]))
    rows = [stream.update(float(t[k]), float(temp[k]), block) for k in range(n)]
    got = {d.signal: np.array([r[0][d.signal] for r in rows])
           for d in dynamics.dynamic_signals(INPUTS)}
    _assert_same(got, np.array([r[1] for r in rows]), ref, gap_ref, exact_play=True)


def test_every_input_c_step_matches_the_definition():
    """The C header's step() on one model whose output k is dynamic input k (a linear fit of
    each signal to itself: identity weights), over a sequence with restarts and missing
    temperatures on block edges: float32 arithmetic, within float32 rounding of each signal."""
    n = 3000
    t, temp = _sequence(n, seed=1)
    ref, gap_ref = dynamic_inputs_loop(t, temp, INPUTS, GAP_S)
    spec = FeatureSpec(inputs=INPUTS, gap_s=GAP_S)
    dyn = dynamics.dynamic_signals(INPUTS)
    outputs = [f"out_{k}" for k in range(len(dyn))]
    ok = np.isfinite(temp)
    s = np.column_stack([ref[x] for x in spec.signals])[ok]
    y = np.column_stack([ref[d.signal] for d in dyn])[ok]
    model = fit(family="linear", inputs=INPUTS, outputs=outputs, train=[(s, y)], val=None,
                spec=spec, hyper={}, config=TrainConfig(max_epochs=0)).model
    c = run_stream_c(model, render_c_header(model), t, temp, np.zeros((n, len(outputs))))
    assert (c["ret"] == 0).all()
    # trained on this very sequence: flagged after a gap and where the temperature is missing,
    # and else only where a float32 signal lands a rounding past the trained range's edge
    want = gap_ref | np.isnan(temp)
    assert c["flag"][want].all()
    extra = np.flatnonzero(c["flag"] & ~want)
    lo, hi = model.sig_lo.double().numpy(), model.sig_hi.double().numpy()
    sig = np.column_stack([ref[x] for x in model.signals])
    at_edge = np.isclose(sig[extra], lo, rtol=1e-5, atol=0) | np.isclose(sig[extra], hi,
                                                                         rtol=1e-5, atol=0)
    assert extra.size <= 5 and at_edge.any(axis=1).all(), extra
    # the temperature arrives as float32: a play (T − P) is exact to a few of its ulps
    t_ulps = 4 * np.finfo(np.float32).eps * float(np.nanmax(np.abs(temp)))
    for k, d in enumerate(dyn):
        r = ref[d.signal]
        assert np.array_equal(np.isnan(c["drift"][:, k]), np.isnan(r)), d.signal
        scale = float(np.nanmax(np.abs(r)))
        assert scale > 0.05, d.signal
        # float32 state and arithmetic in C; the fit itself is exact to ~1e-9 of the scale
        np.testing.assert_allclose(c["drift"][:, k], r, rtol=0, atol=2e-5 * scale + t_ulps,
                                   err_msg=d.signal)


def test_an_input_twice_and_an_input_that_acts_as_a_clock_are_warned():
    """rate_τ = 60·lag_τ/τ exactly (one EMA's lag error): a family reading both reads one
    signal twice; a τ over a third of the shortest run never settles there (a clock)."""
    from thermonet.features.dynamics import SETTLE_TIME_CONSTANTS, input_set_warnings

    runs = {"soak": 3600.0, "short": 900.0}
    warns = input_set_warnings({"twice": ["dT", "rate_120", "lag_120", "play_1"],
                                "rate-and-default": ["dT", "rate", "rate_60"],
                                "fine": ["dT", "rate", "lag_300", "play_0.5"],
                                "clock": ["dT", "lag_600"]}, runs)
    assert warns == [
        "family 'twice': inputs 'rate_120' and 'lag_120' are the same signal up to a constant "
        "factor (one lag error of τ = 120 s): drop one",
        "family 'rate-and-default': inputs 'rate' and 'rate_60' are the same signal up to a "
        "constant factor (one lag error of τ = 60 s): drop one",
        "family 'clock': input 'lag_600' has a time constant of 600 s, and run 'short' lasts "
        "900 s (< 3 τ): it never settles there and acts as a clock (time since the start), "
        "which a longer run will not repeat"]
    assert SETTLE_TIME_CONSTANTS == 3.0
    # the identity behind the first warning, on the real recursion: rate_τ = 60·lag_τ/τ
    t = np.arange(0.0, 2000.0, 1.0)
    temp = 20.0 + 10.0 * np.sin(t / 300.0)
    sig, _ = dynamics.compute(t, temp, ["rate_120", "lag_120"], gap_s=10.0)
    rate, lag = sig["rate_120_c_per_min"], sig["lag_120_c"]
    assert np.ptp(lag) > 1.0
    np.testing.assert_allclose(rate, 60.0 * lag / 120.0, rtol=1e-12, atol=1e-12 * np.ptp(rate))
