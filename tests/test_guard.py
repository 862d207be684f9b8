"""The joint guard: a shipped model holds each dynamic input (rate, lag, play) inside what it
was trained on *near the current temperature* (issue 48, item 4) — identically in torch, the
ONNX graph (direct and traced), the runtime's batch and step calls and the C header's
compensate and step, with the out-of-range flag raised where it acted.

The oracle for the bounds is a plain loop over the training rows (bins of the trained
temperature range, a bin and its two neighbours, linear between the bins' centres), written
here from the definition in :class:`thermonet.scoring.domain.Envelope`'s docstring."""

from __future__ import annotations

import math

import numpy as np
import onnxruntime as ort
import pytest
import torch

from conftest import load_runtime
from thermonet.exporting import export_onnx, render_c_header
from thermonet.exporting.c_driver import PARITY_DRIVER, c_compiler, run_c_driver
from thermonet.exporting.c_stream import run_stream_c
from thermonet.features import dynamics
from thermonet.features.inputs import FeatureSpec
from thermonet.scoring.domain import GUARD_REL_TOL, JOINT_BINS, noise_widths
from thermonet.training.checkpoint import load_checkpoint, save_checkpoint
from thermonet.training.train import TrainConfig, fit
from tolerances import assert_f32_close

pytestmark = pytest.mark.numerics

INPUTS = ["dT", "rate"]
AXES = ["gyro_x", "gyro_y"]
GAP_S = 5.0
rt = load_runtime()


def _heating(t_end: float = 7000.0, step: float = 2.0):
    """One heating ramp from −10 to 60 °C that slows as it heats: 1.2 °C/min when cold, near 0
    at the top (T = −10 + 70·(1 − (1 − t/t_end)²)), so a rate's trained range depends on the
    temperature and no cooling rate is ever trained."""
    t = np.arange(0.0, t_end, step)
    temp = -10.0 + 70.0 * (1.0 - (1.0 - t / t_end) ** 2)
    return t, temp


def _drift(temp: np.ndarray, rate: np.ndarray) -> np.ndarray:
    return np.column_stack([0.01 * (temp - 20.0) + 0.05 * rate,
                            2e-4 * (temp - 20.0) ** 2 - 0.03 * rate * (temp - 20.0) / 40.0])


@pytest.fixture(scope="module")
def guarded(tmp_path_factory):
    t, temp = _heating()
    sig, _ = dynamics.compute(t, temp, INPUTS, GAP_S)
    s = np.column_stack([temp, sig["rate_c_per_min"]])
    spec = FeatureSpec(inputs=INPUTS, t_ref=20.0, gap_s=GAP_S)
    model = fit(family="poly", inputs=INPUTS, outputs=AXES,
                train=[(s, _drift(temp, sig["rate_c_per_min"]), t)], val=None, spec=spec,
                hyper={"degree": 2, "cross": True}, config=TrainConfig(max_epochs=3)).model
    return model, s, tmp_path_factory.mktemp("guard")


def _oracle_bounds(train: np.ndarray, t_query: float, col: int) -> tuple[float, float]:
    """The bounds of column ``col`` at ``t_query`` from the definition, in plain loops: bins
    over the trained temperature range, each bin's bounds over its rows and its two
    neighbours', widened by max(noise, GUARD_REL_TOL · range), linear between centres."""
    temp = train[:, 0]
    t_lo, t_hi = float(temp.min()), float(temp.max())
    width = (t_hi - t_lo) / JOINT_BINS
    rows: list[list[float]] = [[] for _ in range(JOINT_BINS)]
    for tt, v in zip(temp, train[:, col], strict=True):
        rows[min(int((tt - t_lo) / width), JOINT_BINS - 1)].append(float(v))
    near = [[v for j in (b - 1, b, b + 1) if 0 <= j < JOINT_BINS for v in rows[j]]
            for b in range(JOINT_BINS)]
    widen = max(float(noise_widths(train)[col]),
                GUARD_REL_TOL * float(train[:, col].max() - train[:, col].min()))
    u = (min(max(t_query, t_lo), t_hi) - t_lo) / width - 0.5
    i = min(max(math.floor(u), 0), JOINT_BINS - 2)
    w = min(max(u - i, 0.0), 1.0)
    lo = [min(v) - widen for v in near[i:i + 2]]
    hi = [max(v) + widen for v in near[i:i + 2]]
    return lo[0] + w * (lo[1] - lo[0]), hi[0] + w * (hi[1] - hi[0])


def _unguarded(model):
    import copy

    plain = copy.deepcopy(model)
    plain.set_guard(None)
    return plain


def test_training_rows_are_untouched_and_an_untrained_rate_is_held_at_the_trained_bound(guarded):
    """Every training row is inside (no flag, the drift bit-identical to the model without its
    guard); a hot row cooling at −1 °C/min (never trained: hot rows heated at ≤ 0.3 °C/min)
    is flagged and evaluated at the lowest rate trained near that temperature (the oracle's
    bound), not extrapolated."""
    model, s, _ = guarded
    plain = _unguarded(model)
    x = torch.from_numpy(s.astype(np.float32))
    with torch.no_grad():
        assert not model.out_of_range(x).any()
        np.testing.assert_array_equal(model(x).numpy(), plain(x).numpy())
    rows = np.array([[55.0, -1.0], [55.0, 3.0], [0.0, 0.9], [25.0, -0.5], [-10.0, 1.0]])
    with torch.no_grad():
        got = model(torch.from_numpy(rows.astype(np.float32))).double().numpy()
        flags = model.out_of_range(torch.from_numpy(rows.astype(np.float32))).numpy()
    held = rows.copy()
    for k, (temp, rate) in enumerate(rows):
        lo, hi = _oracle_bounds(s, temp, 1)
        held[k, 1] = min(max(rate, lo), hi)
    assert flags.tolist() == [True, True, False, True, False]
    assert held[0, 1] > 0.0 and held[3, 1] > 0.0         # a cooling rate held at a heating one
    assert held[2, 1] == rows[2, 1] and held[4, 1] == rows[4, 1]
    with torch.no_grad():
        want = plain(torch.from_numpy(held.astype(np.float32))).double().numpy()
        free = plain(torch.from_numpy(rows.astype(np.float32))).double().numpy()
    # the bound in float64 (oracle) and float32 (model) differ by float32 rounding of the
    # interpolation, amplified by the rate's weight
    assert_f32_close(got, want, 8, scale=np.abs(want).max(axis=0))
    # unguarded, the per-signal clamp alone evaluates 25 °C at rate 0, never trained there
    # (training passed 25 °C heating at 0.72-0.98 °C/min): 0.05 x 0.72 apart on gyro_x
    assert np.abs(free[3] - got[3])[0] > 0.03


def test_guard_parity_torch_onnx_runtime_and_c(guarded):
    """The guard in the direct and the traced ONNX graph, the runtime (batch and step) and the
    C header (compensate and step): flags identical to torch's, drifts to float32 rounding,
    on rows inside and outside the joint envelope and a cooling stream it never trained."""
    model, s, tmp = guarded
    rng = np.random.default_rng(4)
    rows = np.column_stack([rng.uniform(-10.0, 60.0, 4000),
                            rng.uniform(-1.5, 1.5, 4000)]).astype(np.float32)
    rows[:50] = s[::len(s) // 50][:50]                   # training rows: inside
    rows[50, 0] = np.nan
    rows[51, 1] = np.nan
    with torch.no_grad():
        want = model(torch.from_numpy(rows)).double().numpy()
        flag = model.out_of_range(torch.from_numpy(rows)).numpy()
    assert 0.3 < flag.mean() < 0.97                      # both sides of the guard are tested
    scale = np.nanmax(np.abs(want), axis=0)
    raw = np.zeros((len(rows), len(AXES)))
    for exporter in ("direct", "dynamo"):
        path = export_onnx(model, tmp / f"{exporter}.onnx", exporter=exporter)
        sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        _, drift, f_ort = sess.run(None, {"temperature_c": rows[:, 0],
                                          "rate_c_per_min": rows[:, 1], "raw": raw})
        assert np.array_equal(f_ort, flag), exporter
        assert_f32_close(drift, want, 8, scale=scale, err_msg=exporter)
    cc = c_compiler()
    assert cc is not None, "the C parity needs a compiler (gcc is a test dependency)"
    header = render_c_header(model)
    c_rows = np.zeros(len(rows), dtype=[("s", np.float32, 2), ("raw", np.float64, 2)])
    c_rows["s"] = rows
    const = model.constant().double().numpy()
    c_rows["raw"] = const
    out = run_c_driver(cc, header, PARITY_DRIVER, c_rows,
                       [("comp", np.float64, 2), ("drift", np.float64, 2), ("flag", np.int32)])
    assert np.array_equal(out["flag"].astype(bool), flag)
    assert_f32_close(out["drift"], want, 8, scale=scale, err_msg="C")
    # a cooling stream from 60 °C: the runtime's batch and step calls and the C step
    t = 1.7e9 + np.arange(0.0, 3000.0, 2.0)
    temp = 60.0 - 0.8 * (t - t[0]) / 60.0
    raw_s = np.zeros((t.size, 2))
    sig, gap = dynamics.compute(t, temp, INPUTS, GAP_S)
    sig_s = np.column_stack([temp, sig["rate_c_per_min"]])
    with torch.no_grad():
        want_s = model(torch.from_numpy(sig_s)).double().numpy()
        flag_s = model.out_of_range(torch.from_numpy(sig_s)).numpy() | gap
    assert flag_s[100:].all()                            # cooling at 0.8 °C/min: never trained
    comp = rt.Compensator(tmp / "direct.onnx")
    batch = comp.compensate(temperature_c=temp, raw=raw_s, time_s=t)
    assert np.array_equal(batch.out_of_range, flag_s)
    assert_f32_close(batch.drift, want_s, 8, scale=np.abs(want_s).max(axis=0))
    steps = [comp.step(t[k], temp[k], raw_s[k]) for k in range(0, t.size, 50)]
    assert [r.out_of_range for r in steps] == flag_s[::50].tolist()
    c = run_stream_c(model, header, t, temp, raw_s)
    assert np.array_equal(c["flag"].astype(bool), flag_s)
    assert_f32_close(c["drift"], want_s, 8, scale=np.abs(want_s).max(axis=0))


def test_the_guard_round_trips_and_a_checkpoint_without_it_loads_unguarded(guarded):
    model, s, tmp = guarded
    path = save_checkpoint(tmp / "m.pt", model, config={})
    back, _ = load_checkpoint(path)
    assert back.guarded
    for name in ("guard_knots", "guard_lo", "guard_hi"):
        assert torch.equal(getattr(back, name), getattr(model, name))
    # a model written before the guard: its state without the three buffers
    old = _unguarded(model)
    state = {k: v for k, v in model.state_dict().items() if not k.startswith("guard_")}
    fresh = _unguarded(model)
    fresh.load_state_dict(state)
    assert not fresh.guarded and fresh.guard_lo.shape == (0, 1)
    rows = torch.tensor([[55.0, -1.0]])
    with torch.no_grad():
        assert torch.equal(fresh(rows), old(rows))
