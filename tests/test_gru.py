"""The GRU family: thermal history from the temperature alone, the state carried in
time through torch, onnxruntime and C.

The GRU learns a drift that depends on the die's lag behind the thermometer (a first-order
lag the test writes itself), which no function of the present temperature can follow: on a
held-out run with other ramp rates it beats numpy's cubic on the same samples.  The stream
(windows of ``step_s``, running means, restart after a gap, a NaN sample that changes
nothing) is checked against an independent numpy implementation written here from the
parameters, then torch = onnxruntime (batch and ``step()``) = C (``_step``, double and float
paths) over one sequence with a gap and a NaN.  Costs are counted by hand; the autopilot
exports refuse it in one line; bad hyper-parameters likewise."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import load_runtime
from thermonet.core.errors import ConfigError, ExportError, InputError
from thermonet.exporting import export_c_header, export_onnx
from thermonet.exporting.autopilot import autopilot_coefficients
from thermonet.exporting.c_stream import REAL_FLAGS, run_stream_c
from thermonet.features.inputs import FeatureSpec
from thermonet.models import build_family
from thermonet.models.sequence import stream_relative
from thermonet.training.recurrent import padded
from thermonet.training.train import TrainConfig, fit, predict

pytestmark = pytest.mark.numerics

T_REF = 25.0
AXES = ["gyro_x", "gyro_y"]
TAU_S = 600.0


def _run(seed: int, period_s: float, hours: float = 3.0):
    """Triangles between 5 and 45 °C, samples 1.5–2.5 s apart; the drift follows the die,
    a first-order lag (τ = 600 s) of the thermometer: 1e-3 (T − 25) + 4e-3 (T − die)."""
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 / 2.0)
    t = np.cumsum(rng.uniform(1.5, 2.5, n))
    phase = (t / period_s) % 1.0
    temp = 5.0 + 40.0 * (1.0 - np.abs(2.0 * phase - 1.0))
    die = np.empty(n)
    die[0] = temp[0]
    for k in range(1, n):
        a = np.exp(-(t[k] - t[k - 1]) / TAU_S)
        die[k] = a * die[k - 1] + (1 - a) * temp[k]
    lag = temp - die
    y = np.stack([1e-3 * (temp - T_REF) + 4e-3 * lag, -2e-3 * lag], 1)
    return temp[:, None], y + rng.normal(0.0, 2e-5, y.shape), t


def _fit(hyper=None, seed=0, **cfg):
    spec = FeatureSpec(inputs=["dT"], t_ref=T_REF)
    cfg = {"max_epochs": 40, "patience": 40, **cfg}
    return fit(family="gru", inputs=["dT"], outputs=AXES, train=[_run(0, 5400.0), _run(1, 9000.0)],
               val=_run(2, 7200.0), spec=spec, hyper={"hidden": 6, **(hyper or {})},
               config=TrainConfig(seed=seed, **cfg))


@pytest.fixture(scope="module")
def fitted():
    return _fit()


# ------------------------------------------------------------------ what it learns
def test_learns_the_thermal_lag_a_cubic_cannot_follow(fitted):
    temp, y, t = _run(3, 6300.0)                      # held out: another ramp rate
    pred = predict(fitted.model, temp, t)
    warm = t > t[0] + 30 * 10.0                        # the first warm-up windows aside
    gru = np.sqrt(np.mean((pred - y)[warm] ** 2, axis=0))
    # the independent baseline: numpy's least-squares cubic in ΔT on the training samples
    tr_t = np.concatenate([_run(0, 5400.0)[0][:, 0], _run(1, 9000.0)[0][:, 0]])
    tr_y = np.concatenate([_run(0, 5400.0)[1], _run(1, 9000.0)[1]])
    cubic = np.stack([np.polyval(np.polyfit(tr_t - T_REF, tr_y[:, a], 3), temp[:, 0] - T_REF)
                      for a in range(2)], 1)
    cub = np.sqrt(np.mean((cubic - y)[warm] ** 2, axis=0))
    assert np.all(gru < 0.5 * cub), (gru, cub)
    losses = [h["val_loss"] for h in fitted.history]
    assert losses[fitted.best_epoch] < 0.5 * losses[0]    # training added to the start


def test_same_seed_same_model_another_seed_another():
    a = _fit(max_epochs=3).model.family.state_dict()
    b = _fit(max_epochs=3).model.family.state_dict()
    c = _fit(max_epochs=3, seed=1).model.family.state_dict()
    for key in a:        # the same computation on the same inputs: bit for bit
        assert torch.equal(a[key], b[key]), key
    assert any(not torch.equal(a[k], c[k]) for k in a)


def test_warm_up_windows_are_left_out_of_the_loss():
    z = [(torch.ones(7, 1), torch.ones(7, 2)), (torch.ones(3, 1), torch.ones(3, 2))]
    _, _, mask = padded(z, warmup=2)
    assert mask.tolist() == [[False, False, True, True, True, True, True],
                             [False, False, True, False, False, False, False]]


# ------------------------------------------------------------------ the stream, independently
def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


def _numpy_stream(model, t, temp):
    """The stream written out in float64 from the model's parameters: one sample at a time,
    as a board would (windows from the restart time, running mean, restart after a gap,
    a NaN sample skipped), the GRU cell in PyTorch's gate order r, u, n."""
    fam = model.family
    w_ih, w_hh, b_ih, b_hh = (p.detach().double().numpy() for p in fam._params())
    wo, bo = fam.weight.detach().double().numpy(), fam.bias.detach().double().numpy()
    H = fam.hidden
    lo, hi = float(model.sig_lo[0]), float(model.sig_hi[0])
    xm, xs = float(model.x_mean[0]), float(model.x_std[0])
    ym, ys = model.y_mean.double().numpy(), model.y_std.double().numpy()
    out = np.full((t.size, len(model.outputs)), np.nan)
    h = np.zeros(H)
    h_next = h
    started, t_prev, t0, k_cur, acc = False, 0.0, 0.0, 0, []
    for i in range(t.size):
        if not np.isfinite(temp[i]):
            continue
        restart = not started or t[i] - t_prev > fam.gap_s
        k = 0 if restart else int(np.floor((t[i] - t0) / fam.step_s))
        if restart:
            h, t0, acc = np.zeros(H), t[i], []
        elif k != k_cur:
            h, acc = h_next, []
        k_cur, started, t_prev = k, True, t[i]
        acc.append(temp[i])
        z = (np.clip(np.mean(acc), lo, hi) - T_REF - xm) / xs
        gi, gh = w_ih[:, 0] * z + b_ih, w_hh @ h + b_hh
        r = _sigmoid(gi[:H] + gh[:H])
        u = _sigmoid(gi[H:2 * H] + gh[H:2 * H])
        n = np.tanh(gi[2 * H:] + r * gh[2 * H:])
        h_next = n + u * (h - n)
        out[i] = (wo @ h_next + bo) * ys + ym + model.y_offset.numpy()
    return out


def _sequence(model, seed=7):
    """A jittered sequence inside the trained range with a gap (3 × gap_s) and a NaN."""
    fam = model.family
    rng = np.random.default_rng(seed)
    n = 1500
    t = 1.7e9 + np.cumsum(rng.uniform(0.5, 3.5, n))
    t[900:] += 3.0 * fam.gap_s
    temp = 25.0 + 15.0 * np.sin((t - t[0]) / 900.0)
    temp[333] = np.nan
    return t, temp


def test_stream_matches_an_independent_numpy_stream(fitted):
    model = fitted.model
    t, temp = _sequence(model)
    rel, flag = stream_relative(model, t, temp[:, None])
    want = _numpy_stream(model, t, temp)
    got = rel + model.constant().double().numpy()
    assert np.array_equal(np.isnan(got), np.isnan(want))
    scale = np.nanmax(np.abs(want), axis=0)
    # float32 GRU (PyTorch's fused kernel and the batched cell) against float64: a few
    # float32 roundings of the standardised state, carried through ~150 windows
    assert np.nanmax(np.abs(got - want) / scale) < 1e-5
    assert flag[333] and flag[900] and not flag[899] and not flag[0]
    # a gap restarts the state: the sequence after it is the same as a fresh stream
    rel_after, _ = stream_relative(model, t[900:], temp[900:, None])
    np.testing.assert_allclose(rel[900:], rel_after, rtol=0, atol=1e-6 * scale.max())


# ------------------------------------------------------------------ torch = onnxruntime = C
@pytest.fixture(scope="module")
def exported(fitted, tmp_path_factory):
    d = tmp_path_factory.mktemp("gru")
    return export_onnx(fitted.model, d / "m.onnx"), export_c_header(fitted.model, d / "model.h")


def test_onnx_runtime_and_c_carry_the_state_like_torch(fitted, exported):
    model = fitted.model
    onnx_path, header = exported
    t, temp = _sequence(model)
    rel, flag = stream_relative(model, t, temp[:, None])
    const = model.constant().double().numpy()
    want = rel + const
    scale = np.nanmax(np.abs(rel), axis=0)
    rt = load_runtime()
    comp = rt.Compensator(onnx_path)
    assert comp.recurrent["hidden"] == model.family.hidden and comp.needs[0] == "time_s"
    raw = np.random.default_rng(1).normal(size=(t.size, 2)) + const
    batch = comp.compensate(temperature_c=temp, raw=raw, time_s=t)
    comp.reset()
    steps = [comp.step(t[k], temp[k], raw[k]) for k in range(t.size)]
    step_drift = np.array([s.drift for s in steps])
    c_out = {real: run_stream_c(model, header.read_text(), t, temp, raw,
                                cflags=("-O2", *REAL_FLAGS[real])) for real in ("auto", "float")}
    for who, drift, fl in (("batch", batch.drift, batch.out_of_range),
                           ("step", step_drift, np.array([s.out_of_range for s in steps])),
                           ("C", c_out["auto"]["drift"], c_out["auto"]["flag"]),
                           ("C float", c_out["float"]["drift"], c_out["float"]["flag"])):
        assert np.array_equal(np.isnan(drift), np.isnan(want)), who
        # float32 step arithmetic against torch's: 1e-5 of the axis's largest drift (the
        # export's parity rule); the C running mean is a float32 sum (1e-4, as check_stream)
        rtol = 1e-4 if who.startswith("C") else 1e-5
        err = np.nanmax(np.abs(drift - want), axis=0)
        assert np.all(err <= rtol * scale), (who, err, scale)
        assert np.array_equal(np.asarray(fl, dtype=bool), flag), who
    np.testing.assert_array_equal(batch.compensated, raw - batch.drift)
    # blocks (step_block) carry the state as step does: the same numbers, for
    # blocks that cut inside windows, at the gap and at the NaN
    comp.reset()
    cuts = [0, 1, 8, 57, t.size // 2, t.size - 3, t.size]
    blocks = [comp.step_block(t[a:b], temp[a:b], raw[a:b]) for a, b in zip(cuts[:-1], cuts[1:],
                                                                          strict=True)]
    np.testing.assert_array_equal(np.vstack([b.drift for b in blocks]), step_drift)
    np.testing.assert_array_equal(np.concatenate([b.out_of_range for b in blocks]),
                                  np.array([s.out_of_range for s in steps]))
    # the runtime's window bookkeeping is the reference's
    idx, restart, window = rt.recurrent_windows(t, np.isfinite(temp), model.family.step_s,
                                                model.family.gap_s)
    from thermonet.models.sequence import stream_windows
    lay = stream_windows(t, np.isfinite(temp), model.family.step_s, model.family.gap_s)
    assert np.array_equal(idx, lay.index) and np.array_equal(restart, lay.restart)
    assert np.array_equal(window, lay.window)


def test_the_runtimes_csv_of_two_runs_restarts_the_hidden_state_at_each(exported, tmp_path):
    """The runtime's command on a CSV with a ``run`` column (what ``convert --out x.csv``
    writes from several runs, time restarting in each): run 2's drift is run 2's alone, the
    GRU's hidden state restarted at its first row, never carried from run 1's end (the state
    carried across the boundary gives other numbers, far beyond float32 precision)."""
    import csv

    rt = load_runtime()
    runs = [_run(5, 5400.0, hours=1.0), _run(6, 9000.0, hours=1.0)]

    def write(path: Path, parts: list[int]) -> Path:
        with path.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["run", "time_s", "temperature_c", *AXES])
            for k in parts:
                temp, y, t = runs[k]
                for i in range(t.size):
                    w.writerow([f"r{k}", repr(float(t[i])), repr(float(temp[i, 0])),
                                *(repr(float(v)) for v in y[i])])
        return path

    def drift(src: Path) -> np.ndarray:
        out = src.with_suffix(".out.csv")
        assert rt.main([str(exported[0]), str(src), "--out", str(out)]) == 0
        with out.open(newline="") as fh:
            return np.array([[float(r[f"{a}_drift"]) for a in AXES] for r in csv.DictReader(fh)])

    both = drift(write(tmp_path / "both.csv", [0, 1]))
    alone = drift(write(tmp_path / "alone.csv", [1]))
    n1 = runs[0][2].size
    tol = 4 * float(np.finfo(np.float32).eps) * float(np.max(np.abs(alone)))
    np.testing.assert_allclose(both[n1:], alone, rtol=0, atol=tol)
    comp = rt.Compensator(exported[0])
    (temp0, y0, t0), (temp1, y1, t1) = runs
    comp.step_block(t0, temp0[:, 0], y0)
    carried = comp.step_block(t0[-1] + 2.0 + t1, temp1[:, 0], y1).drift
    assert float(np.max(np.abs(carried - alone))) > 100 * tol


def test_runtime_needs_time(exported):
    comp = load_runtime().Compensator(exported[0])
    with pytest.raises(ValueError, match="missing 'time_s'"):
        comp.compensate(temperature_c=[25.0], raw=[[0.0, 0.0]])


# ------------------------------------------------------------------ refusals and cost
def test_autopilot_exports_refuse_it_in_one_line(fitted):
    with pytest.raises(ExportError) as err:
        autopilot_coefficients(fitted.model, output_units="deg/s")
    assert "\n" not in str(err.value) and "carries a state in time" in str(err.value)


def test_predict_needs_time_and_dynamic_inputs_are_refused(fitted):
    with pytest.raises(InputError, match="needs time_s"):
        predict(fitted.model, np.array([[25.0]]))
    spec = FeatureSpec(inputs=["dT", "rate"], t_ref=T_REF, gap_s=10.0)
    temp, y, t = _run(0, 5400.0, hours=0.5)
    with pytest.raises(ConfigError, match="drop the dynamic inputs"):
        fit(family="gru", inputs=["dT", "rate"], outputs=AXES,
            train=[(np.column_stack([temp[:, 0], np.zeros(len(t))]), y, t)], val=None,
            spec=spec, hyper={}, config=TrainConfig(max_epochs=1))


@pytest.mark.parametrize("hyper,key,shown", [
    ({"hidden": 0}, "hidden", "0"), ({"hidden": 8.0}, "hidden", "8.0"),
    ({"hidden": True}, "hidden", "True"), ({"step_s": 0.0}, "step_s", "0.0"),
    ({"gap_s": float("nan")}, "gap_s", "nan"), ({"chunk": 1}, "chunk", "1"),
    ({"warmup": -1}, "warmup", "-1"), ({"lr": "1e-3"}, "lr", "'1e-3'"),
    ({"weight_decay": -1.0}, "weight_decay", "-1.0"),
])
def test_bad_hyper_parameters_refused_in_one_line(hyper, key, shown):
    with pytest.raises(ConfigError) as err:
        build_family("gru", n_inputs=1, n_outputs=1, hyper=hyper)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"gru: {key} must be ") and msg.endswith(
        f"got {shown}"), msg


def test_cost_counted_by_hand():
    fam = build_family("gru", n_inputs=1, n_outputs=1)          # the default: 8 units
    assert fam.hyper()["hidden"] == 8
    # gates: 3H (F + H) multiply-adds = 216; per unit r, u (add + expf, 1 + e, division:
    # 4 each), n (r·gh + gi, then −2|x|, expm1, e + 2, division: 5), h' (2): 15 × 8 = 120;
    # read-out H × A = 8
    cost = fam.cost()
    assert (cost["ops_per_sample"], cost["transcendentals"]) == (216 + 120 + 8, 24)
    # float constants: w_ih 24, b_ih 24, w_hh 64 × 3 = 192, b_hh 24, read-out 8 + 1
    assert cost["c_bytes"] == 4 * (24 + 24 + 192 + 24 + 8 + 1)


def test_checkpoint_round_trip_keeps_the_stream(fitted, tmp_path):
    from thermonet.training.checkpoint import load_checkpoint, save_checkpoint

    path = save_checkpoint(tmp_path / "gru.pt", fitted.model, config={"family": "gru"})
    loaded, _ = load_checkpoint(path)
    assert loaded.family.recurrent and loaded.family.hyper() == fitted.model.family.hyper()
    t, temp = _sequence(fitted.model)
    a, fa = stream_relative(fitted.model, t, temp[:, None])
    b, fb = stream_relative(loaded, t, temp[:, None])
    np.testing.assert_array_equal(a, b)        # the same parameters, the same arithmetic
    np.testing.assert_array_equal(fa, fb)


def test_header_cross_compiles_for_every_microcontroller(fitted, tmp_path):
    """The GRU header under the strict Cortex-M flags (-Wdouble-promotion -Wconversion
    -Werror): no double arithmetic in software anywhere, no libm on the float targets, and
    on the M4F no arithmetic run-time routine (the window count needs no 64-bit division)."""
    from thermonet.exporting import render_c_header
    from thermonet.exporting.mcu import FLOAT_TARGETS, TARGETS, cross_compile

    text = render_c_header(fitted.model)
    for target in TARGETS:
        build = cross_compile(text, target, tmp_path / target, recurrent=True)
        assert build.code_bytes > 0
        assert build.soft_double == [], (target, build.soft_double)
        if target in FLOAT_TARGETS:
            assert build.libm == [], (target, build.libm)
        if target == "cortex-m4f":
            # no arithmetic routine; libc's memset is what gcc makes of the zeroing loops of
            # _init and of a restart
            assert set(build.undefined) <= {"memset"}, build.undefined


def test_fleet_coefficients_summarise_its_soaked_curve(fitted):
    """A fleet's per-unit c0..c3 of a GRU: the cubic through its steady-state curve (the
    drift after a long soak at each temperature), finite."""
    from thermonet.workflows.fleet_units import physical_coefficients

    coef = physical_coefficients(fitted.model)
    assert sorted(coef) == sorted(f"{a}.c{k}" for a in AXES for k in range(4))
    assert all(np.isfinite(v) for v in coef.values())


@pytest.mark.slow
def test_judged_like_every_family_in_a_comparison(tmp_path):
    """A comparison with the GRU beside the cubic: the same cross-validated selection,
    per-axis verdicts and cost columns; a GRU trained 5 epochs does not beat the cubic on
    a device whose drift is a function of temperature alone, and is not chosen."""
    import json

    from thermonet.sim import simulate
    from thermonet.training.config import CompareConfig, FamilyConfig
    from thermonet.workflows.compare import run_compare

    ds = simulate("patent-gyro", seed=0, runs=4)
    cfg = CompareConfig(families=[
        FamilyConfig(family="poly", name="cubic", inputs=["dT"], params={"degree": 3}),
        FamilyConfig(family="gru", name="gru", inputs=["dT"], params={"hidden": 4})],
        baseline="cubic")
    cfg.train.max_epochs = 5
    run_compare(cfg, tmp_path / "cmp", track=False, quiet=True, dataset=ds, plots=False)
    res = json.loads((tmp_path / "cmp" / "results.json").read_text())
    gru = res["families"]["gru"]
    assert gru["status"] == "ok" and res["chosen"] == "cubic"
    # 4 units, 1 input, 3 axes: gates 3H(F + H), 15 per unit, read-out A·H; float constants
    # w_ih 12, b_ih 12, w_hh 48, b_hh 12, read-out 12 + 3
    assert gru["cost"] == {"ops_per_sample": 3 * 4 * 5 + 15 * 4 + 3 * 4,
                           "transcendentals": 12, "c_bytes": 4 * (12 + 12 + 48 + 12 + 12 + 3)}
    assert res["selection"]["candidates"]["gru"]["status"] == "ok"
    assert all("verdict" in m for m in gru["axes"].values())
    assert gru["test_score"] > res["families"]["cubic"]["test_score"]
