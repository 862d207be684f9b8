"""Dynamic inputs (rate, lag_<tau>, delayed_<tau>, play_<w>): one definition, computed identically in training
(vectorised), by the plain loop, by the torch-free runtime (batch and streaming) and by the C
header's step(); constants round-trip through checkpoint, ONNX metadata and C header."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys

import numpy as np
import onnx
import pytest
import torch

from conftest import RUNTIME, load_runtime
from oracles import dynamic_inputs_loop
from thermonet.core.errors import ConfigError
from thermonet.exporting import export_onnx, render_c_header
from thermonet.exporting.c_stream import run_stream_c
from thermonet.features import dynamics
from thermonet.features.inputs import FeatureSpec, parse_feature, signals_for
from thermonet.sim.device import play_operator
from thermonet.training.checkpoint import load_checkpoint, save_checkpoint, seal_checkpoint
from thermonet.training.config_sections import FeatureConfig
from thermonet.training.train import TrainConfig, fit
from tolerances import assert_f32_close, assert_f64_close

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

INPUTS = ["dT", "rate", "lag_300", "play_0.5"]
AXES = ["gyro_x", "gyro_y"]
GAP_S = 5.0




rt = load_runtime()


def _triangle(t: np.ndarray, lo: float, hi: float, period_s: float) -> np.ndarray:
    phase = (t % period_s) / period_s
    return lo + (hi - lo) * (1.0 - np.abs(2.0 * phase - 1.0))


def _drift(sig: dict[str, np.ndarray], temp: np.ndarray) -> np.ndarray:
    return np.column_stack([0.01 * (temp - 20.0) + 0.02 * sig["rate_c_per_min"],
                            0.003 * sig["play_0.5_c"] + 0.001 * sig["lag_300_c"]])


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A cross-term poly on every kind of dynamic input, fitted on wide heat/cool cycles."""
    t = np.arange(0.0, 30000.0, 2.0)
    temp = _triangle(t, -10.0, 60.0, 8000.0)          # ±1.05 °C/min
    sig, _ = dynamics.compute(t, temp, INPUTS, GAP_S)
    spec = FeatureSpec(inputs=INPUTS, t_ref=20.0, gap_s=GAP_S)
    s = np.column_stack([temp] + [sig[x] for x in spec.signals[1:]])
    model = fit(family="poly", inputs=INPUTS, outputs=AXES, train=[(s, _drift(sig, temp))],
                val=None, spec=spec, hyper={"degree": 2, "cross": True},
                config=TrainConfig(max_epochs=3)).model
    path = export_onnx(model, tmp_path_factory.mktemp("dyn") / "m.onnx")
    return model, path


def _sequence(seed: int = 0):
    """Jittered sampling, heat/cool inside the trained range, a gap, NaN temperatures."""
    rng = np.random.default_rng(seed)
    n = 3000
    t = 1.7e9 + np.cumsum(rng.uniform(0.5, 1.5, n))   # Unix-epoch seconds: float32 cannot hold
    t[1200:] += 40.0                                    # a 40 s gap (> gap_s)
    temp = _triangle(t - t[0], 5.0, 45.0, 5000.0) + rng.normal(0.0, 0.005, n)
    temp[300] = np.nan
    temp[2000:2004] = np.nan                           # 4 missing samples: ≈ 4 s, no gap
    raw = rng.normal(0.0, 0.01, (n, len(AXES)))
    return t, temp, raw


def test_names_signals_and_constants():
    assert parse_feature("lag_300") == ("lag_300_c", False, False)
    assert signals_for(["d_freq_hz", "play_0.5", "rate", "dT", "lag_30"]) == \
        ["temperature_c", "rate_c_per_min", "lag_30_c", "play_0.5_c", "freq_hz"]
    d = dynamics.parse_dynamic("rate_12.5")
    assert (d.kind, d.param, d.signal) == ("rate", 12.5, "rate_12.5_c_per_min")
    assert dynamics.parse_dynamic("rate").param == dynamics.RATE_TAU_S == 60.0
    with pytest.raises(ConfigError, match="'lag_0'.*positive"):
        FeatureSpec(inputs=["lag_0"])
    with pytest.raises(ConfigError, match="unknown model input 'lag_x'"):
        FeatureSpec(inputs=["lag_x"])
    with pytest.raises(ConfigError, match="rate_window_s' was removed.*rate_<tau>"):
        FeatureConfig(rate_window_s=60.0)


def test_the_unknown_input_error_lists_every_accepted_form():
    """The list of valid inputs comes from one source (the registry): each form it names is
    accepted with a number in place of its constant, delayed_<tau> included (was left out)."""
    with pytest.raises(ConfigError) as err:
        FeatureSpec(inputs=["foo"])
    listed = str(err.value).split("(valid: ", 1)[1].rstrip(")").split(", ")
    assert listed == ["T", "dT", "dT2", "rate", "rate_<tau>", "lag_<tau>", "delayed_<tau>",
                      "play_<w>", "d_<proxy>", "d_<proxy>2"]
    for form in listed:
        name = form.replace("<tau>", "30").replace("<w>", "0.5").replace("<proxy>", "freq_hz")
        parse_feature(name)                                  # accepted: no error


def test_known_values_exact_for_any_sample_interval():
    """On a ramp of slope r from rest: lag = rτ(1 − e^(−t/τ)) exactly, even with jittered dt
    (T is linear between samples); rate = 60·lag/τ; play = ±w once T moved 2w, memory in a soak."""
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.1, 3.0, 4000)) - 0.5
    t -= t[0]
    r = 0.02                                             # °C/s
    sig, gap = dynamics.compute(t, 10.0 + r * t, ["lag_100", "rate_50"], 10.0)
    np.testing.assert_allclose(sig["lag_100_c"], r * 100 * (1 - np.exp(-t / 100)), rtol=1e-9,
                               atol=1e-13)
    np.testing.assert_allclose(sig["rate_50_c_per_min"], 60 * r * (1 - np.exp(-t / 50)),
                               rtol=1e-9, atol=1e-13)
    assert not gap.any()
    temp = np.concatenate([np.linspace(20, 30, 101), np.full(50, 30.0), np.linspace(30, 25, 51)])
    play = dynamics.compute(np.arange(temp.size, dtype=float), temp, ["play_2"], 5.0)[0]
    p = play["play_2_c"]
    assert p[0] == 0.0 and p[20] == pytest.approx(2.0) and p[100] == pytest.approx(2.0)
    assert p[120] == pytest.approx(2.0)                  # soak: memory of the heating branch
    assert p[-1] == pytest.approx(-2.0)                  # cooled by 5 > 2w: the cooling branch
    # the simulator's hysteresis is the same operator (width = 2w), normalised to ±1
    # only correctly rounded elementwise operations (±, min, max, ÷2) on both sides: exact on
    # every CPU
    np.testing.assert_array_equal(play_operator(temp, 4.0), p / 2.0)


def test_vectorised_equals_the_plain_loop_with_gaps_and_nan():
    """Many blocks of the O(N) scan, jitter, gaps and NaN: same as one-sample-at-a-time."""
    rng = np.random.default_rng(1)
    n = 70_000
    dt = rng.uniform(0.05, 0.15, n)
    dt[[5000, 40000, 40002]] += [3.0, 50.0, 2.0]       # three gaps over 1 s
    t = np.cumsum(dt)
    temp = 20 + np.cumsum(rng.normal(0, 0.01, n))
    temp[[0, 17, 39999]] = np.nan
    temp[60000:60100] = np.nan                          # 10 s without temperature: a gap
    names = ["rate", "lag_300", "play_0.2", "rate_5", "delayed_300"]
    fast, gap = dynamics.compute(t, temp, names, 1.0)
    slow, gap_ref = dynamic_inputs_loop(t, temp, names, 1.0)
    for name in fast:
        np.testing.assert_allclose(fast[name], slow[name], rtol=1e-9, atol=1e-12)
        assert np.array_equal(np.isnan(fast[name]), np.isnan(temp))
    assert np.array_equal(gap, gap_ref)
    assert np.flatnonzero(gap).tolist() == [5000, 40000, 40002, 60100]
    assert fast["rate_c_per_min"][1] == 0.0              # start-up at the first finite sample
    assert fast["lag_300_c"][60100] == 0.0 and fast["play_0.2_c"][60100] == 0.0  # restart
    # the delayed temperature is T − e of the same EMA, to the last bit of the subtraction
    np.testing.assert_array_equal(fast["delayed_300_c"], temp - fast["lag_300_c"])
    # the runtime's own copy of the recurrences
    const = dynamics.constants(names, 1.0)
    mirror, gap_rt = rt.dynamic_signals(t, temp, const)
    for name in fast:
        np.testing.assert_allclose(mirror[name], fast[name], rtol=1e-9, atol=1e-12)
    assert np.array_equal(gap_rt, gap)


@pytest.mark.parametrize("bad, what", [([0.0, 1.0, 1.0, 2.0], "sample 2: time repeated"),
                                       ([0.0, 2.0, 1.0], "sample 2: time decreasing"),
                                       ([0.0, np.nan, 2.0], "sample 1: time is nan")])
def test_bad_time_is_refused_everywhere(trained, bad, what, tmp_path):
    _, path = trained
    temp = np.full(len(bad), 20.0)
    with pytest.raises(dynamics.TimeError, match=what):
        dynamics.compute(np.array(bad), temp, ["rate"], 5.0)
    comp = rt.Compensator(path)
    with pytest.raises(rt.RuntimeInputError, match=what):
        comp.compensate(temperature_c=temp, raw=np.zeros((len(bad), 2)), time_s=bad)
    # CSV: one line naming the column, the data row and its file line; nothing written
    src, out = tmp_path / "in.csv", tmp_path / "out.csv"
    with src.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "temperature_c", *AXES])
        for v in bad:
            w.writerow(["" if np.isnan(v) else v, 20.0, 0.0, 0.0])
    proc = subprocess.run([sys.executable, str(RUNTIME), str(path), str(src), "--out", str(out)],
                          capture_output=True, text=True)
    row = int(re.search(r"sample (\d+)", what).group(1)) + 1     # the data row, 1-based
    assert proc.returncode == 1 and \
        f"column 'time_s', row {row} (file line {row + 1})" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and not out.exists()


def test_runtime_needs_time_and_refuses_computed_signals(trained):
    _, path = trained
    comp = rt.Compensator(path)
    assert comp.needs == ["time_s", "temperature_c"]
    assert comp.dynamic_signals == ["rate_c_per_min", "lag_300_c", "play_0.5_c"]
    with pytest.raises(rt.RuntimeInputError, match=r"missing 'time_s'.*\['rate_c_per_min', "
                                                   r"'lag_300_c', 'play_0.5_c'\]"):
        comp.compensate(temperature_c=[20.0, 21.0], raw=np.zeros((2, 2)))
    with pytest.raises(rt.RuntimeInputError, match="computed by the runtime from time_s"):
        comp.compensate(temperature_c=20.0, raw=np.zeros(2), time_s=0.0, rate=0.3)
    comp.step(10.0, 20.0, np.zeros(2))
    with pytest.raises(rt.RuntimeInputError, match="time_s repeated"):
        comp.step(10.0, 20.0, np.zeros(2))
    with pytest.raises(rt.RuntimeInputError, match="time_s decreasing"):
        comp.step(9.0, 20.0, np.zeros(2))
    assert comp.step(11.0, 20.0, np.zeros(2)).out_of_range is False  # state survived refusals


def test_training_runtime_and_c_match_sample_by_sample(trained):
    """Whole sequence with jitter, a gap, NaN temperatures and a restart: training features →
    torch, onnxruntime batch, onnxruntime streaming and the C header's step() agree."""
    model, path = trained
    t, temp, raw = _sequence()
    sig, gap = dynamics.compute(t, temp, INPUTS, GAP_S)
    s = np.column_stack([temp] + [sig[x] for x in model.signals[1:]])
    with torch.no_grad():
        want = model(torch.from_numpy(s)).double().numpy()
        flag_want = model.out_of_range(torch.from_numpy(s)).numpy() | gap
    scale = np.nanmax(np.abs(want), axis=0)
    nan_rows = np.isnan(temp)
    assert np.isnan(want[nan_rows]).all() and np.isfinite(want[~nan_rows]).all()
    assert np.flatnonzero(gap).tolist() == [1200]

    comp = rt.Compensator(path)
    batch = comp.compensate(temperature_c=temp, raw=raw, time_s=t)
    np.testing.assert_allclose(batch.drift, want, atol=1e-5 * scale.max(), rtol=0)
    assert np.array_equal(batch.out_of_range, flag_want)
    np.testing.assert_allclose(batch.compensated, raw - want, atol=1e-5 * scale.max(), rtol=0)

    stream = [comp.step(t[k], temp[k], raw[k]) for k in range(len(t))]
    np.testing.assert_allclose(np.array([r.drift for r in stream]), batch.drift,
                               atol=1e-6 * scale.max(), rtol=0)
    assert [r.out_of_range for r in stream] == batch.out_of_range.tolist()
    # a restart (reset) is a fresh stream: the same numbers as the first samples again
    comp.reset()
    again = [comp.step(t[k], temp[k], raw[k]).drift for k in range(20)]
    # the same stream of the same computation again: bit-identical
    np.testing.assert_array_equal(np.array(again), np.array([r.drift for r in stream[:20]]))

    header = render_c_header(model)
    c = run_stream_c(model, header, t, temp, raw)
    assert (c["ret"] == 0).all()
    np.testing.assert_allclose(c["drift"], want, atol=1e-5 * scale.max(), rtol=0)
    assert np.array_equal(np.isnan(c["drift"]), nan_rows[:, None].repeat(2, 1))
    assert np.array_equal(c["flag"], flag_want)
    # the same C, restarted by a second init: run it on the tail as a new sequence
    tail = run_stream_c(model, header, t[1500:], temp[1500:], raw[1500:])
    fresh = comp.compensate(temperature_c=temp[1500:], raw=raw[1500:], time_s=t[1500:])
    np.testing.assert_allclose(tail["drift"], fresh.drift, atol=1e-5 * scale.max(), rtol=0)
    # bad time in C: refused (NaN, flag, -1), state unchanged for the next sample
    t_bad = t[:10].copy()
    t_bad[5] = t_bad[4]
    cb = run_stream_c(model, header, t_bad, temp[:10], raw[:10])
    assert cb["ret"].tolist() == [0] * 5 + [-1] + [0] * 4
    assert np.isnan(cb["drift"][5]).all() and cb["flag"][5]
    np.testing.assert_allclose(cb["drift"][6:], c["drift"][6:10], atol=1e-5 * scale.max())


def test_constants_round_trip_checkpoint_onnx_c(trained, tmp_path):
    model, path = trained
    const = model.spec.dynamic
    assert const["gap_s"] == GAP_S and [d["name"] for d in const["inputs"]] == INPUTS[1:]
    ckpt = save_checkpoint(tmp_path / "m.pt", model, config={})
    loaded, meta = load_checkpoint(ckpt)
    assert loaded.spec.dynamic == const and meta["spec"]["dynamic"] == const
    props = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert json.loads(props["dynamic_inputs"]) == json.loads(json.dumps(const))
    assert json.loads(props["signal_units"])["rate_c_per_min"] == "degC/min"
    header = render_c_header(loaded)
    assert "#define THERMONET_GAP_S 5.0 " in header
    assert "thermonet_dyn_kind[THERMONET_N_DYNAMIC] = {0, 1, 2};" in header
    assert re.search(r"dyn_param\[THERMONET_N_DYNAMIC\] = \{6\.0+e\+01f, 3\.0+e\+02f, "
                     r"5\.0+e-01f\};", header)
    # a checkpoint whose stored constants disagree with the definition is refused
    payload = torch.load(ckpt, weights_only=True)
    payload["spec"]["dynamic"]["inputs"][0]["tau_s"] = 30.0
    torch.save(payload, tmp_path / "bad.pt")
    seal_checkpoint(tmp_path / "bad.pt")  # sealed again: the check below, not the digest
    with pytest.raises(Exception, match="differ from the definitions"):
        load_checkpoint(tmp_path / "bad.pt")


def test_csv_command_from_time_and_temperature_alone(trained, tmp_path):
    _, path = trained
    t, temp, raw = _sequence(1)
    src, out = tmp_path / "in.csv", tmp_path / "out.csv"
    with src.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "temperature_c", *AXES])
        for k in range(len(t)):
            w.writerow([repr(float(t[k])), "" if np.isnan(temp[k]) else repr(float(temp[k])),
                        *(repr(float(v)) for v in raw[k])])
    proc = subprocess.run([sys.executable, str(RUNTIME), str(path), str(src), "--out", str(out)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    got = np.array([[float(r[f"{a}_drift"]) for a in AXES] for r in rows])
    want = rt.Compensator(path).compensate(temperature_c=temp, raw=raw, time_s=t).drift
    # the same Compensator behind the command line, floats written with repr: bit-identical
    # on one CPU, but the command runs in its own process — under qemu-user natively, on
    # another CPU than this emulated one — so compared to float32 rounding
    assert_f32_close(got, want, "dynamic")
    assert rows[1200]["out_of_range"] == "1" and rows[300]["out_of_range"] == "1"


@pytest.mark.slow   # an end-to-end run: native only (make test-cpus skips slow)
def test_runtime_and_c_reproduce_compare_on_held_out_heat_cool(tmp_path):
    """compare → checkpoint → ONNX / C; the runtime and the C step compensate the held-out run
    from time + temperature + raw alone and give the msd compare reported for it."""
    import dataclasses

    from thermonet.exporting import export_source
    from thermonet.sim import PRESETS, simulate
    from thermonet.sim.chamber import ChamberProfile, cycle
    from thermonet.sim.device import HysteresisConfig
    from thermonet.training.config import CompareConfig, FamilyConfig
    from thermonet.workflows.compare import run_compare

    base = PRESETS["patent-gyro"]
    profile = ChamberProfile(name="heat/cool", start_c=-10.0,
                             segments=cycle(-10.0, 40.0, rate_c_per_h=30.0, soak_h=0.5))
    axes = tuple(dataclasses.replace(a, hysteresis=HysteresisConfig(amplitude=0.02, width_c=2.0))
                 for a in base.axes)
    device = dataclasses.replace(base, name="heat-cool", procedures=(profile,), axes=axes,
                                 sample_rate_hz=0.2, default_runs=3)
    ds = simulate(device, seed=2)
    cfg = CompareConfig(families=[
        FamilyConfig(family="poly", name="cubic", inputs=["dT"], params={"degree": 3}),
        FamilyConfig(family="poly", name="poly3-hyst", inputs=["dT", "rate", "play_1"],
                     params={"degree": 3, "cross": True})])
    res = run_compare(cfg, tmp_path / "cmp", track=False, quiet=True, dataset=ds)
    fam = res["families"]["poly3-hyst"]
    assert fam["status"] == "ok"
    onnx_path = export_source(tmp_path / "cmp", fmt="onnx", out=tmp_path / "m.onnx",
                              family="poly3-hyst")
    test = ds["run2"]                                   # 3 runs: train run0, val run1, test run2
    raw = np.column_stack([test.outputs[a] for a in ds.axes])
    ref = np.column_stack([test.reference(a) for a in ds.axes])
    comp = rt.Compensator(onnx_path)
    out = comp.compensate(temperature_c=test.temperature_c, raw=raw, time_s=test.time_s)
    model, _ = load_checkpoint(fam["checkpoint"])
    c = run_stream_c(model, render_c_header(model), test.time_s, test.temperature_c, raw)
    for name, compensated in (("runtime", out.compensated), ("C", c["compensated"])):
        msd = np.mean((compensated.astype(np.float64) - ref) ** 2, axis=0)
        want = [fam["axes"][a]["msd_comp"] for a in ds.axes]
        np.testing.assert_allclose(msd, want, rtol=1e-3, err_msg=name)
    # the dynamic model beats the cubic on every axis of this held-out heat/cool run
    for a in ds.axes:
        assert fam["axes"][a]["msd_comp"] < res["families"]["cubic"]["axes"][a]["msd_comp"]


def test_c_export_checks_step_and_refuses_a_wrong_recurrence(trained, tmp_path):
    from thermonet.core.errors import ExportError
    from thermonet.exporting import export_c_header
    from thermonet.exporting.c_stream import check_stream

    model, _ = trained
    path = export_c_header(model, tmp_path / "m.h")
    assert "thermonet_step(thermonet_state *st, thermonet_time_t time_s" in path.read_text()
    report = check_stream(model, path.read_text())
    assert report is not None and report["n_samples"] == 3000
    # the float path (float outputs, microsecond time, the fast expm1f): the same check
    assert check_stream(model, path.read_text(), real="float") is not None
    # a header whose lag recurrence uses the wrong step (g replaced by 1) is refused
    broken = path.read_text().replace("const float g = -THERMONET_EXPM1F(-h) / h;",
                                      "const float g = 1.0f;")
    assert broken != path.read_text()
    for real in ("auto", "float"):
        with pytest.raises(ExportError, match=r"step\(\) parity check failed"):
            check_stream(model, broken, real=real)


def test_stacked_held_out_blocks_restart_the_state_at_each_block():
    """Blocks stacked by splits.stack_blocks are computed as separate streams: the signals of the
    stack equal each block's own signals, although the stacked time has no gap between them."""
    from thermonet.core.errors import InputError
    from thermonet.core.recording import Recording
    from thermonet.features.inputs import signal_matrix
    from thermonet.training.splits import stack_blocks

    t = np.arange(0.0, 6000.0, 1.0)
    temp = _triangle(t, 10.0, 40.0, 3000.0)
    blocks = [Recording(time_s=t[a:b], temperature_c=temp[a:b],
                        outputs={"gyro_x": np.zeros(b - a)}, run_id=f"b{k}", sample_rate_hz=1.0)
              for k, (a, b) in enumerate([(0, 1000), (2500, 4000), (4800, 6000)])]
    stacked = stack_blocks(blocks, "test")
    assert stacked.meta["segment_starts"] == "0,1000,2500"
    signals = ["rate_c_per_min", "lag_300_c", "play_0.5_c"]
    want = np.vstack([signal_matrix(b, signals, GAP_S) for b in blocks])
    # the recursions over the stacked blocks and over each block: float64 rounding
    assert_f64_close(signal_matrix(stacked, signals, GAP_S), want, atol=1e-12)
    # every block starts afresh: rate, lag and play are 0 at its first sample
    assert not want[[0, 1000, 2500]].any()
    bad = Recording(time_s=t[:10], temperature_c=temp[:10], outputs={"gyro_x": np.zeros(10)},
                    meta={"segment_starts": "0,five"})
    with pytest.raises(InputError, match="segment_starts"):
        signal_matrix(bad, signals, GAP_S)


def test_at_t_ref_target_rests_with_dynamic_inputs_at_zero(trained):
    """At rest (T = T_ref after a soak) every dynamic input is 0 — rate, T − EMA(T) and T − P(T)
    by their definitions — and an at-t-ref axis has zero drift there."""
    from thermonet.training.train import rest_signals

    model, _ = trained
    spec = model.spec
    assert spec.signals == ["temperature_c", "rate_c_per_min", "lag_300_c", "play_0.5_c"]
    np.testing.assert_array_equal(rest_signals(spec), [20.0, 0.0, 0.0, 0.0])
    t = np.arange(0.0, 30000.0, 2.0)
    temp = _triangle(t, -10.0, 60.0, 8000.0)
    sig, _ = dynamics.compute(t, temp, INPUTS, GAP_S)
    s = np.column_stack([temp] + [sig[x] for x in spec.signals[1:]])
    # axis 0 read with an unknown constant (+5): at-t-ref removes it, the slope stays
    y = _drift(sig, temp) + np.array([5.0, 0.0])
    at_ref = fit(family="poly", inputs=INPUTS, outputs=AXES, train=[(s, y)],
                 val=None, spec=spec, hyper={"degree": 2, "cross": True},
                 config=TrainConfig(max_epochs=3), target=["at-t-ref", "channel"]).model
    # soaks at T_ref and at T_ref + 20 °C, the dynamic inputs computed by the recurrences
    soak_t = np.arange(0.0, 4000.0, 2.0)
    rest = []
    for temp_c in (20.0, 40.0):
        soak, _ = dynamics.compute(soak_t, np.full(soak_t.size, temp_c), INPUTS, GAP_S)
        rest.append([temp_c] + [soak[x][-1] for x in spec.signals[1:]])
    np.testing.assert_array_equal(rest, [[20.0, 0.0, 0.0, 0.0], [40.0, 0.0, 0.0, 0.0]])
    with torch.no_grad():
        d = at_ref.drift64(torch.tensor(rest, dtype=torch.float64)).numpy()
    assert abs(d[0, 0]) < 1e-6           # zero at rest (float32 rounding), the +5 removed
    assert d[1, 0] == pytest.approx(0.01 * 20.0, abs=0.01)  # 0.01 /degC above T_ref


def test_a_cubic_at_the_delayed_temperature_recovers_a_lagging_sensor_everywhere(tmp_path):
    """A sensing element that lags its thermometer by a first-order τ = 300 s: its drift is a
    cubic of E = EMA_τ(T).  ``poly`` on ``delayed_300`` alone, fitted on a fast cycle, recovers
    that cubic's coefficients (polyfit of the truth in E as the independent oracle) and
    corrects a slow cycle the fit never saw (heating and cooling at another rate) to the noise,
    where the cubic in T is off by the lag times the slope; its domain is E's range alone (no
    joint guard); torch, onnxruntime (batch, step) and the C header's step() agree."""
    rng = np.random.default_rng(3)
    coef = np.array([2e-6, -3e-4, 0.01, 0.05])          # drift = polyval(coef, E − 20)

    def cycle(rate_c_per_min: float, n_cycles: int = 2):
        period = 2 * 70.0 / rate_c_per_min * 60.0
        t = np.arange(0.0, n_cycles * period, 5.0)
        temp = _triangle(t, -10.0, 60.0, period)
        e_t = dynamics.compute(t, temp, ["delayed_300"], 60.0)[0]["delayed_300_c"]
        y = np.polyval(coef, e_t - 20.0) + rng.normal(0.0, 1e-4, t.size)
        return t, temp, e_t, y

    t, temp, e_t, y = cycle(1.5)
    spec = FeatureSpec(inputs=["delayed_300"], t_ref=20.0, gap_s=60.0)
    assert spec.signals == ["delayed_300_c"]
    model = fit(family="poly", inputs=["delayed_300"], outputs=["gyro_x"],
                train=[(e_t[:, None], y[:, None])], val=None, spec=spec,
                hyper={"degree": 3}, config=TrainConfig(max_epochs=3)).model
    assert not model.guarded and model.joint == []       # no joint envelope: E alone
    oracle = np.polyfit(e_t - 20.0, y, 3)
    grid = np.linspace(e_t.min(), e_t.max(), 61) - 20.0   # E's trained range (clamped past it)
    with torch.no_grad():
        got = model(torch.from_numpy(grid[:, None] + 20.0)).double().numpy()[:, 0]
    np.testing.assert_allclose(got, np.polyval(oracle, grid), atol=2e-5, rtol=0)
    np.testing.assert_allclose(oracle, coef, rtol=0.05, atol=5e-5)

    t2, temp2, e2, y2 = cycle(0.5, 1)                   # a slow cycle: new rates, both ways
    path = export_onnx(model, tmp_path / "d.onnx")
    comp = rt.Compensator(path)
    assert comp.needs == ["time_s", "temperature_c"]
    batch = comp.compensate(temperature_c=temp2, raw=y2[:, None], time_s=t2)
    inside = ~batch.out_of_range
    assert inside.mean() > 0.9
    left = batch.compensated[inside, 0]
    in_t = np.polyval(np.polyfit(temp - 20.0, y, 3), temp2 - 20.0)
    cubic_left = (y2 - in_t)[inside]
    assert np.std(left) < 2e-4 < 0.2 * np.std(cubic_left)
    stream = np.array([comp.step(t2[k], temp2[k], y2[k:k + 1]).drift[0] for k in range(500)])
    np.testing.assert_allclose(stream, batch.drift[:500, 0], atol=1e-6, rtol=0)
    header = render_c_header(model)
    assert "thermonet_dyn_kind[THERMONET_N_DYNAMIC] = {3};" in header
    c = run_stream_c(model, header, t2, temp2, y2[:, None])
    np.testing.assert_allclose(c["drift"][:, 0], batch.drift[:, 0], atol=1e-5, rtol=0)
    assert np.array_equal(c["flag"], batch.out_of_range)
