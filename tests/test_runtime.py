"""The torch-free runtime: loading checks, compensate(), NaN/empty/shape handling, CLI."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from conftest import RUNTIME, load_runtime
from thermonet.exporting import export_onnx
from thermonet.features.inputs import FeatureSpec
from thermonet.training.train import TrainConfig, fit

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

AXES = ["gyro_x", "gyro_y", "gyro_z"]
# deg/s per degC, degC^2, degC^3: recovered by the cubic model
COEF = np.array([[1e-3, 2e-5, -1e-7], [-5e-4, 1e-5, 0.0], [2e-3, -3e-5, 2e-7]])




rt = load_runtime()


def _true_drift(temp: np.ndarray) -> np.ndarray:
    dt = np.asarray(temp, dtype=np.float64)[..., None] - 25.0
    return (COEF[:, 0] * dt + COEF[:, 1] * dt ** 2 + COEF[:, 2] * dt ** 3) + 0.01


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    temp = np.linspace(-20.0, 60.0, 400)
    spec = FeatureSpec(inputs=["dT"], t_ref=25.0)
    model = fit(
        family="poly",
        inputs=["dT"],
        outputs=AXES,
        train=[(temp[:, None], _true_drift(temp))],
        val=None,
        spec=spec,
        hyper={"degree": 3},
        config=TrainConfig(max_epochs=5),
    ).model
    path = export_onnx(model, tmp_path_factory.mktemp("rt") / "poly.onnx",
                       metadata={"output_units": {a: "deg/s" for a in AXES}, "device_id": "X1"})
    return path


def test_batch_and_single_sample(model_path):
    comp = rt.Compensator(model_path)
    assert comp.signals == ["temperature_c"] and comp.outputs == AXES
    temp = np.linspace(-20.0, 60.0, 81)            # float64 on purpose: cast by the runtime
    raw = _true_drift(temp) + 0.5
    res = comp.compensate(temp, raw)
    assert res.compensated.dtype == np.float64 and res.compensated.shape == (81, 3)
    np.testing.assert_allclose(res.drift, _true_drift(temp), atol=2e-6)
    np.testing.assert_allclose(res.compensated, 0.5, atol=2e-6)
    assert not res.out_of_range.any()
    one = comp.compensate(temperature_c=41.0, raw=_true_drift(np.array(41.0)))
    assert one.drift.shape == (3,) and one.out_of_range is False
    np.testing.assert_allclose(one.compensated, 0.0, atol=2e-6)
    assert set(one.as_dict()) == {"compensated", "drift", "out_of_range"}
    assert one["drift"] is one.drift


def test_static_model_stream_has_no_gap(model_path):
    """A model without dynamic inputs keeps no state: a pause in its stream (any Δt) is not
    flagged, as in its batch call and its C header's step."""
    comp = rt.Compensator(model_path)
    t = np.array([0.0, 0.5, 1.0, 3.0, 8.0, 3600.0])
    temp = np.linspace(10.0, 40.0, t.size)
    raw = _true_drift(temp) + 0.5
    steps = [comp.step(t[k], temp[k], raw[k]) for k in range(t.size)]
    assert not any(s.out_of_range for s in steps)
    comp.reset()
    block = comp.step_block(t, temp, raw)
    assert not block.out_of_range.any()
    np.testing.assert_allclose(block.compensated, 0.5, atol=2e-6)
    np.testing.assert_array_equal(block.compensated, comp.compensate(temp, raw).compensated)


def test_out_of_range_nan_inf_and_empty(model_path):
    comp = rt.Compensator(model_path)
    temp = np.array([-30.0, 75.0, np.nan, np.inf, 10.0])
    res = comp.compensate(temp, np.zeros((5, 3)))
    assert res.out_of_range.tolist() == [True, True, True, True, False]
    np.testing.assert_allclose(res.drift[0], _true_drift(np.array(-20.0)), atol=2e-6)   # clamped
    np.testing.assert_allclose(res.drift[1], _true_drift(np.array(60.0)), atol=2e-6)
    assert np.isnan(res.drift[2:4]).all() and np.isnan(res.compensated[2:4]).all()
    empty = comp.compensate(np.zeros(0), np.zeros((0, 3)))
    assert empty.compensated.shape == (0, 3) and empty.out_of_range.shape == (0,)


def test_refuses_bad_inputs(model_path):
    comp = rt.Compensator(model_path)
    with pytest.raises(rt.RuntimeInputError, match=r"'raw' has shape \(4, 2\); expected"):
        comp.compensate(np.zeros(4), np.zeros((4, 2)))
    with pytest.raises(rt.RuntimeInputError, match=r"signal 'temperature_c' has shape \(3,\)"):
        comp.compensate(np.zeros(3), np.zeros((4, 3)))
    with pytest.raises(rt.RuntimeInputError, match="dtype <U"):
        comp.compensate(np.array(["a", "b"]), np.zeros((2, 3)))
    with pytest.raises(rt.RuntimeInputError, match=r"missing signal\(s\) \['temperature_c'\]"):
        comp.compensate(raw=np.zeros(3))
    with pytest.raises(rt.RuntimeInputError, match=r"unknown signal\(s\) \['freq_hz'\]"):
        comp.compensate(20.0, np.zeros(3), freq_hz=4517.0)
    with pytest.raises(rt.RuntimeInputError, match="input 'raw' is not a rectangular array"):
        comp.compensate([20.0, 21.0], [[0.0, 0.0, 0.0], [0.0, 0.0]])
    masked = comp.compensate(np.ma.masked_array([20.0, 21.0], mask=[False, True]),
                             np.zeros((2, 3)))
    assert np.isnan(masked.drift[1]).all() and bool(masked.out_of_range[1])
    assert np.isfinite(masked.drift[0]).all()
    with pytest.raises(rt.RuntimeInputError, match="signal 'rate_c_per_min' given twice"):
        comp.compensate(20.0, np.zeros(3), rate=0.1, rate_c_per_min=5.0)


def _rewrite(src: Path, dst: Path, edit) -> Path:
    proto = onnx.load(str(src))
    edit(proto)
    onnx.save(proto, str(dst))
    return dst


def test_refuses_foreign_and_tampered_files(model_path, tmp_path):
    plain = tmp_path / "plain.onnx"
    torch.onnx.export(torch.nn.Linear(1, 1), (torch.zeros(2, 1),), str(plain), dynamo=False)
    with pytest.raises(rt.RuntimeInputError, match="not a thermonet model"):
        rt.Compensator(plain)

    def set_meta(key, value):
        def edit(proto):
            for p in proto.metadata_props:
                if p.key == key:
                    p.value = value
        return edit

    bad_opset = _rewrite(model_path, tmp_path / "o.onnx", set_meta("onnx_opset", "9"))
    with pytest.raises(rt.RuntimeInputError, match="opset 9 is not supported"):
        rt.Compensator(bad_opset)
    bad_fmt = _rewrite(model_path, tmp_path / "f.onnx", set_meta("thermonet_format", "9"))
    with pytest.raises(rt.RuntimeInputError, match="thermonet_format .9. is not supported"):
        rt.Compensator(bad_fmt)
    renamed = _rewrite(model_path, tmp_path / "r.onnx",
                       set_meta("signals", '["freq_hz"]'))
    with pytest.raises(rt.RuntimeInputError, match="graph inputs .* do not match the metadata"):
        rt.Compensator(renamed)
    with pytest.raises(rt.RuntimeInputError, match="no such model file"):
        rt.Compensator(tmp_path / "missing.onnx")
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"not an onnx file")
    with pytest.raises(rt.RuntimeInputError, match="onnxruntime cannot load it"):
        rt.Compensator(garbage)


def test_time_batch(model_path):
    seconds = rt.time_batch(rt.Compensator(model_path), 1000, repeats=2)
    assert 0 < seconds < float("inf")  # figures belong to experiments/bench_export.py


# Importing torch or thermonet inside the runtime would raise ImportError: both are
# set to None in sys.modules before the runtime file runs.
_NO_TORCH = (
    "import sys, runpy; sys.modules['torch'] = None; sys.modules['thermonet'] = None; "
    "sys.argv = ['thermonet_runtime'] + sys.argv[1:]; "
    "runpy.run_path({runtime!r}, run_name='__main__')"
)


def _run_cli(*args: str) -> subprocess.CompletedProcess:
    code = _NO_TORCH.format(runtime=str(RUNTIME))
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          timeout=60)


def test_cli_without_torch(model_path, tmp_path):
    temp = [-25.0, 0.0, 25.0, 50.0]
    rows = [{"time_s": i, "temperature_c": t,
             **dict(zip(AXES, _true_drift(np.array(t)) + 1.0, strict=False))}
            for i, t in enumerate(temp)]
    src = tmp_path / "in.csv"
    with src.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    out = tmp_path / "out.csv"
    proc = _run_cli(str(model_path), str(src), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    with out.open() as fh:
        got = list(csv.DictReader(fh))
    assert list(got[0]) == ["time_s", "temperature_c", *AXES, *(f"{a}_comp" for a in AXES),
                            *(f"{a}_drift" for a in AXES), "out_of_range"]
    assert [r["out_of_range"] for r in got] == ["1", "0", "0", "0"]
    for r in got[1:]:
        for a in AXES:
            assert float(r[f"{a}_comp"]) == pytest.approx(1.0, abs=5e-6)


def test_cli_bad_input_exits_1(model_path, tmp_path):
    src = tmp_path / "bad.csv"
    src.write_text("temperature_c,gyro_x,gyro_y\n20,0,0\n")
    proc = _run_cli(str(model_path), str(src), "--out", str(tmp_path / "o.csv"))
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [
        f"thermonet_runtime: {src}: missing column 'gyro_z' "
        "(needs temperature_c, gyro_x, gyro_y, gyro_z)"
    ]
    src.write_text("temperature_c,gyro_x,gyro_y,gyro_z\n20,0,0,0\nhot,0,0,0\n")
    proc = _run_cli(str(model_path), str(src), "--out", str(tmp_path / "o.csv"))
    assert proc.returncode == 1
    assert "column 'temperature_c', row 3: not a number 'hot'" in proc.stderr
    assert not (tmp_path / "o.csv").exists()
    # a misaligned row (more cells than the header) and an output fed back in are refused
    src.write_text("temperature_c,gyro_x,gyro_y,gyro_z\n20,0,0,0,\n21,0,0,0,5\n")
    proc = _run_cli(str(model_path), str(src), "--out", str(tmp_path / "o.csv"))
    assert proc.returncode == 1 and "row 3: 5 cells, the header has 4" in proc.stderr
    src.write_text("temperature_c,gyro_x,gyro_y,gyro_z,gyro_x_comp\n20,0,0,0,1\n")
    proc = _run_cli(str(model_path), str(src), "--out", str(tmp_path / "o.csv"))
    assert proc.returncode == 1 and "already has output column(s) ['gyro_x_comp']" in proc.stderr
    # a trailing separator alone is fine: the output stays aligned with its header
    src.write_text("temperature_c,gyro_x,gyro_y,gyro_z\n20,1,0,0,\n")
    proc = _run_cli(str(model_path), str(src), "--out", str(tmp_path / "o.csv"))
    assert proc.returncode == 0, proc.stderr
    import csv
    row, = csv.DictReader((tmp_path / "o.csv").open())
    assert row["out_of_range"] in ("0", "1") and float(row["gyro_x_comp"]) == pytest.approx(
        1.0 - float(row["gyro_x_drift"]), abs=1e-6)


def test_a_mapped_recording_converted_to_csv_is_the_runtimes_input(tmp_path, capsys):
    """A mapped recording (the real BMI270 soaks, configs/data/bmi270.yaml) reaches the
    runtime from the command line: ``thermonet convert --out x.csv`` (was refused: 'ends in
    .parquet') writes thermonet's column names, which the runtime reads; its compensated
    columns are the model's own on the same data (``DriftEstimator.compensate``)."""
    import thermonet
    from thermonet.cli import main
    from thermonet.data.io import read_datasets

    root = Path(__file__).resolve().parents[1]
    files = sorted(str(p) for p in (root / "tests/data/real/bmi270_two_soaks").glob("*.csv"))
    mapping = str(root / "configs/data/bmi270.yaml")
    assert main(["convert", *files, "--mapping", mapping, "--out", str(tmp_path / "x.csv")]) == 0
    assert "2 run(s)" in capsys.readouterr().out
    ds = read_datasets(files, mapping=mapping)
    axes = ["gyro_x", "gyro_y", "gyro_z"]
    est = thermonet.DriftEstimator("linear", "dT", outputs=axes, max_epochs=0).fit(ds)
    model = est.export(tmp_path / "m.onnx")
    assert rt.main([str(model), str(tmp_path / "x.csv"), "--out", str(tmp_path / "c.csv")]) == 0
    with (tmp_path / "c.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == sum(r.n_samples for r in ds)
    want = np.concatenate([np.column_stack([est.compensate(r).outputs[a] for a in axes])
                           for r in ds])
    got = np.array([[float(r[f"{a}_comp"]) for a in axes] for r in rows])
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def _runtime_csv(model: Path, src: Path, out: Path, axes: list[str]) -> tuple[np.ndarray, ...]:
    """The runtime's command on ``src``: (drift, compensated, out_of_range) per row."""
    assert rt.main([str(model), str(src), "--out", str(out)]) == 0
    with out.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    return (np.array([[float(r[f"{a}_drift"]) for a in axes] for r in rows]),
            np.array([[float(r[f"{a}_comp"]) for a in axes] for r in rows]),
            np.array([r["out_of_range"] == "1" for r in rows]))


def test_a_multi_run_csv_restarts_the_state_at_each_run(tmp_path, capsys):
    """The CSV ``thermonet convert --out x.csv`` writes from several runs (a ``run`` column,
    time restarting in each run) is read run by run: a model with dynamic inputs (a lag, a
    rate, a play state) starts each run's state afresh, as in training, so run 2's output is
    run 2's alone — never carried from run 1's hot end into run 2's cold start (was: the rows
    read as one sequence, refused where time restarts).  The same with run 2's time going on
    after run 1's.  A run whose rows are not together is refused in one line."""
    import thermonet
    from thermonet.core.recording import Dataset
    from thermonet.data.io import write_csv
    from thermonet.sim import simulate

    ds = simulate("accel", runs=2, seed=0)
    axes = list(ds.axes)
    est = thermonet.DriftEstimator("linear", ["dT", "lag_600", "rate", "play_1"], outputs=axes,
                                   max_epochs=0).fit(ds)
    model = est.export(tmp_path / "m.onnx")
    comp = rt.Compensator(model)
    assert comp.dynamic_signals
    both = write_csv(ds, tmp_path / "both.csv")
    alone = write_csv(Dataset(runs=[ds[1]]), tmp_path / "alone.csv")
    drift, comped, flag = _runtime_csv(model, both, tmp_path / "o_both.csv", axes)
    drift2, comped2, flag2 = _runtime_csv(model, alone, tmp_path / "o_alone.csv", axes)
    n1 = ds[0].n_samples
    assert drift.shape == (n1 + ds[1].n_samples, len(axes))
    # float32 graph arithmetic on the same inputs: equal within a few float32 ulps
    tol = 4 * float(np.finfo(np.float32).eps) * float(np.max(np.abs(drift2)))
    np.testing.assert_allclose(drift[n1:], drift2, rtol=0, atol=tol)
    np.testing.assert_allclose(comped[n1:], comped2, rtol=0, atol=tol)
    assert np.array_equal(flag[n1:], flag2)
    # run 1 is run 1 alone too; the drift the model gives (DriftEstimator.compensate) per run
    want = [np.column_stack([est.compensate(r).outputs[a] for a in axes]) for r in ds]
    np.testing.assert_allclose(comped, np.concatenate(want), rtol=1e-5, atol=1e-5)
    # run 2's time going on after run 1's: still a sequence of its own
    t = np.concatenate([ds[0].time_s, ds[0].time_s[-1] + 5.0 + ds[1].time_s])
    on = tmp_path / "on.csv"
    with on.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["run", "time_s", "temperature_c", *axes])
        for k, r in enumerate(ds):
            rows = slice(0, n1) if k == 0 else slice(n1, None)
            for ti, temp, *v in zip(t[rows], r.temperature_c, *(r.outputs[a] for a in axes),
                                    strict=True):
                w.writerow([r.run_id, repr(float(ti)), repr(float(temp)),
                            *(repr(float(x)) for x in v)])
    drift_on, _, _ = _runtime_csv(model, on, tmp_path / "o_on.csv", axes)
    np.testing.assert_allclose(drift_on[n1:], drift2, rtol=0, atol=tol)
    # what carrying the state across the boundary gives instead: far outside that tolerance
    comp.reset()
    comp.step_block(t[:n1], ds[0].temperature_c, np.column_stack(
        [ds[0].outputs[a] for a in axes]))
    carried = comp.step_block(t[n1:], ds[1].temperature_c, np.column_stack(
        [ds[1].outputs[a] for a in axes])).drift
    assert float(np.max(np.abs(carried - drift2))) > 100 * tol
    # a run whose rows come back after another run's: refused, naming the row
    lines = on.read_text().splitlines()
    on.write_text("\n".join([lines[0], *lines[1:3], *lines[n1 + 1:n1 + 3], lines[3]]) + "\n")
    out = tmp_path / "o_bad.csv"
    capsys.readouterr()
    assert rt.main([str(model), str(on), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert err == (f"thermonet_runtime: {on}: column 'run', row 6: run 'run0' again (its rows "
                   "began at row 2); a run's rows must be together — the state restarts at "
                   "each run")
    assert not out.exists()
