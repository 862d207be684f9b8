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
    assert "column 'temperature_c', row 2 (file line 3): not a number 'hot'" in proc.stderr
    assert not (tmp_path / "o.csv").exists()
    # a misaligned row (more cells than the header) and an output fed back in are refused
    src.write_text("temperature_c,gyro_x,gyro_y,gyro_z\n20,0,0,0,\n21,0,0,0,5\n")
    proc = _run_cli(str(model_path), str(src), "--out", str(tmp_path / "o.csv"))
    assert proc.returncode == 1 and "row 2 (file line 3): 5 cells, the header has 4" in proc.stderr
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
    assert err == (f"thermonet_runtime: {on}: column 'run', row 5 (file line 6): run 'run0' "
                   "again (its rows began at row 1 (file line 2)); a run's rows must be together "
                   "— the state restarts at each run")
    assert not out.exists()


# ---- the Python the runtime's docs promise (export/README.md: "Python ≥ 3.9") ----------------
#: What a 3.9 interpreter lacks and its parser does not see (the parser with feature_version
#: (3, 9) refuses match statements, parenthesised context managers, except*): keyword
#: arguments (function name -> keyword), names and attributes added in 3.10 or later.
_NEWER_KEYWORDS = {"zip": "strict", "dataclass": "slots", "field": "kw_only"}
_NEWER_NAMES = {"aiter", "anext", "EncodingWarning", "ExceptionGroup", "BaseExceptionGroup",
                "pairwise", "TypeAlias", "ParamSpec", "Concatenate", "TypeGuard", "Self",
                "Never", "LiteralString", "assert_never", "reveal_type", "StrEnum", "tomllib",
                "TypeVarTuple", "Unpack", "Required", "NotRequired", "override"}
_NEWER_ATTRIBUTES = {"bit_count", "add_note", "batched"}
_MIN_PYTHON = (3, 9)


def _newer_than_39(source: str) -> list[str]:
    """Every construct of ``source`` that a Python 3.9 interpreter refuses or lacks, as
    'line N: what' (empty when it runs there).  Annotations are not evaluated under
    ``from __future__ import annotations`` (PEP 563), so ``X | Y`` there is fine; anywhere
    else a ``|`` between types (``isinstance(x, int | float)``) raises TypeError on 3.9."""
    import ast

    found: list[str] = []
    try:
        tree = ast.parse(source, feature_version=_MIN_PYTHON)
    except SyntaxError as exc:
        return [f"line {exc.lineno}: {exc.msg}"]
    future = any(isinstance(n, ast.ImportFrom) and n.module == "__future__" and
                 any(a.name == "annotations" for a in n.names) for n in tree.body)
    annotations: set[int] = set()
    for node in ast.walk(tree):
        ann = [getattr(node, "returns", None), getattr(node, "annotation", None)]
        for a in ann:
            if a is not None and future:
                annotations.update(id(n) for n in ast.walk(a))

    def type_like(n: ast.AST) -> bool:
        return (isinstance(n, ast.Constant) and n.value is None) or isinstance(
            n, (ast.Name, ast.Attribute, ast.Subscript)) or (
            isinstance(n, ast.BinOp) and isinstance(n.op, ast.BitOr) and type_like(n.left)
            and type_like(n.right))

    for node in ast.walk(tree):
        if id(node) in annotations:
            continue
        line = getattr(node, "lineno", "?")
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr) and type_like(node):
            # numbers and arrays are or-ed too (flags | gap): a union is one of builtins' types,
            # None or a typing name on either side
            names = {n.id for n in ast.walk(node) if isinstance(n, ast.Name)} | {
                "None" for n in ast.walk(node) if isinstance(n, ast.Constant) and n.value is None}
            if names & {"int", "float", "str", "bytes", "bool", "complex", "list", "dict",
                        "tuple", "set", "frozenset", "type", "object", "None", "Any"}:
                found.append(f"line {line}: a union 'X | Y' evaluated at run time (3.10+)")
        elif isinstance(node, ast.Call):
            f = node.func
            fname = f.id if isinstance(f, ast.Name) else f.attr if isinstance(
                f, ast.Attribute) else ""
            kw = _NEWER_KEYWORDS.get(fname)
            if kw is not None and any(k.arg == kw for k in node.keywords):
                found.append(f"line {line}: {fname}({kw}=...) (3.10+)")
        elif isinstance(node, ast.Name) and node.id in _NEWER_NAMES:
            found.append(f"line {line}: {node.id} (3.10+)")
        elif isinstance(node, ast.Attribute) and node.attr in _NEWER_ATTRIBUTES | _NEWER_NAMES:
            found.append(f"line {line}: .{node.attr} (3.10+)")
        elif isinstance(node, ast.alias) and node.name.split(".")[0] in _NEWER_NAMES:
            found.append(f"line {line}: import {node.name} (3.10+)")
    return found


def test_the_checker_finds_what_a_39_interpreter_refuses():
    """The check itself, on known text: each construct that crashed the runtime on 3.9 (was
    ``isinstance(x, int | float)`` and ``zip(..., strict=True)``), a match statement, and
    the same union inside annotations (not evaluated: fine)."""
    head = "from __future__ import annotations\n"
    assert _newer_than_39(head + "ok = isinstance(1, int | float)\n") == [
        "line 2: a union 'X | Y' evaluated at run time (3.10+)"]
    assert _newer_than_39(head + "p = list(zip([1], [2], strict=True))\n") == [
        "line 2: zip(strict=...) (3.10+)"]
    assert "only supported in Python 3.10" in _newer_than_39(
        head + "match 1:\n    case 1:\n        pass\n")[0]
    assert _newer_than_39(head + "from itertools import pairwise\n") == [
        "line 2: import pairwise (3.10+)"]
    fine = head + ("def f(x: int | None) -> dict[str, int] | None:\n"
                   "    y: float | None = None\n    return isinstance(x, (int, float)) and "
                   "(x | 1)\n")
    assert _newer_than_39(fine) == []
    # without the __future__ import an annotation is evaluated: a union there fails on 3.9
    assert _newer_than_39("def f(x: int | None):\n    pass\n") == [
        "line 1: a union 'X | Y' evaluated at run time (3.10+)"]


def test_the_runtime_runs_on_the_python_its_docs_promise():
    """export/README.md promises "any Linux with Python ≥ 3.9": the runtime has nothing a 3.9
    interpreter refuses or lacks (was: ``isinstance(x, int | float)`` and ``zip(strict=)``
    crashed loading any file with a band, and running any recurrent model)."""
    source = RUNTIME.read_text(encoding="utf-8")
    readme = (RUNTIME.parent / "README.md").read_text(encoding="utf-8")
    assert "Python ≥ 3.9" in readme       # the promise checked here; change both together
    assert "from __future__ import annotations" in source
    assert _newer_than_39(source) == []


# ---- the CSV command's input: what `thermonet info` refuses or hints, the runtime too --------
def _cli(model: Path, src: Path, out: Path, capsys) -> tuple[int, str, str]:
    """``rt.main`` on ``src`` with every warning an error (a numpy warning is a leak)."""
    import warnings

    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code = rt.main([str(model), str(src), "--out", str(out)])
    got = capsys.readouterr()
    return code, got.out, got.err


def test_short_rows_and_duplicate_columns_are_refused_in_one_line(model_path, tmp_path, capsys):
    """A truncated row (fewer cells than the header) and a column named twice are refused,
    naming the file, the row or column and what was expected, nothing written (was: the
    missing cells read as NaN and the first of two columns used, exit 0)."""
    out = tmp_path / "o.csv"
    src = tmp_path / "short.csv"
    src.write_text("temperature_c,gyro_x,gyro_y,gyro_z\n20,1,2,3\n21,1\n")
    assert _cli(model_path, src, out, capsys)[::2] == (1, (
        f"thermonet_runtime: {src}: row 2 (file line 3): 2 cells, the header has 4: a truncated "
        "row (write an empty cell for a missing sample)\n"))
    # rows named as thermonet's readers name them: the data row, and the file line (a blank
    # line is skipped: they differ)
    src.write_text("temperature_c,gyro_x,gyro_y,gyro_z\n20,1,2,3\n\n21,1\n")
    assert f"{src}: row 2 (file line 4): 2 cells" in _cli(model_path, src, out, capsys)[2]
    src.write_text("temperature_c,gyro_x,gyro_y,gyro_z,gyro_x\n20,1,2,3,4\n")
    assert _cli(model_path, src, out, capsys)[::2] == (1, (
        f"thermonet_runtime: {src}: column 'gyro_x': duplicate column in the header (columns 2 "
        "and 5); rename or remove one\n"))
    assert not out.exists()
    # an empty cell is still a missing sample (NaN, flag set), and so is a trailing separator
    src.write_text("temperature_c,gyro_x,gyro_y,gyro_z,\n,1,2,3,\n20,1,2,3,\n")
    code, _, err = _cli(model_path, src, out, capsys)
    assert code == 0, err
    rows = list(csv.DictReader(out.open(newline="")))
    assert [r["out_of_range"] for r in rows] == ["1", "0"] and rows[0]["gyro_x_comp"] == "nan"


def test_other_separators_and_parquet_say_what_the_file_is(model_path, tmp_path, capsys):
    """A tab-separated file (was: "missing column 'temperature_c'") and a Parquet, HDF5 or
    ULog file (was: "not UTF-8 text (byte 11)") say what they are and how to get the CSV."""
    out = tmp_path / "o.csv"
    tsv = tmp_path / "rec.tsv"
    tsv.write_text("temperature_c\tgyro_x\tgyro_y\tgyro_z\n20\t1\t2\t3\n")
    assert _cli(model_path, tsv, out, capsys)[::2] == (1, (
        f"thermonet_runtime: {tsv}: the header is separated by tabs (a tab-separated file); "
        "this runtime reads comma-separated CSV: save it with ',' as the separator "
        f"(thermonet convert {tsv} --out {tmp_path / 'rec.csv'} writes one)\n"))
    semi = tmp_path / "rec.csv"
    semi.write_text("temperature_c;gyro_x;gyro_y;gyro_z\n20;1;2;3\n")
    err = _cli(model_path, semi, out, capsys)[2]
    assert "separated by ';'" in err and f"--out {tmp_path / 'rec_comma.csv'} writes one" in err
    for name, magic, what, args in (
            ("rec.parquet", b"PAR1\x15\x04", "a Parquet file", ""),
            ("rec.h5", b"\x89HDF\r\n\x1a\n\x00", "an HDF5 file", " --mapping MAP"),
            ("log.ulg", b"ULog\x01\x12", "a PX4 ULog flight log", "#<instance>")):
        path = tmp_path / name
        path.write_bytes(magic + bytes(range(128, 256)))
        code, _, err = _cli(model_path, path, out, capsys)
        assert (code, err) == (1, (
            f"thermonet_runtime: {path}: {what}, not CSV; this runtime reads CSV only (numpy "
            f"and onnxruntime, no other reader): thermonet convert {path}{args} --out "
            f"{path.with_suffix('.csv')} writes one\n"))
    assert not out.exists()


def test_kelvin_temperatures_get_infos_hint(model_path, tmp_path, capsys):
    """A temperature column in Kelvin runs (every row out of the trained range, flagged) and
    says so in one warning line with ``thermonet info``'s hint (was: silent, exit 0)."""
    from thermonet.data.diagnostics import TEMPERATURE_PLAUSIBLE_C, temperature_hint

    src = tmp_path / "kelvin.csv"
    # -20 … 150 °C in Kelvin (too hot for °F: 150 °C read as °F would still be 217 °C)
    src.write_text("temperature_c,gyro_x,gyro_y,gyro_z\n253.15,1,2,3\n423.15,1,2,3\n")
    code, printed, err = _cli(model_path, src, tmp_path / "o.csv", capsys)
    assert code == 0 and "2 out of range" in printed
    assert err == (f"thermonet_runtime: warning: {src}: column 'temperature_c' spans 253.2 … "
                   "423.1 °C, outside the plausible -100 … 200 °C (Kelvin? subtract 273.15)\n")
    # the runtime's copy of the rule is thermonet's (its own message where nothing fits)
    assert rt.TEMPERATURE_PLAUSIBLE_C == TEMPERATURE_PLAUSIBLE_C
    for lo, hi in ((283.15, 323.15), (14.0, 122.0), (-20e3, 60e3), (150.0, 400.0), (-300, 0),
                   (0.0, 1e39)):
        want = temperature_hint(lo, hi)
        got = rt.temperature_hint(lo, hi)
        assert got == want or (want.startswith("check the mapping") and
                               got == "check the temperature column's unit and scale")
    # a plausible column: no warning
    src.write_text("temperature_c,gyro_x,gyro_y,gyro_z\n-20,1,2,3\n60,1,2,3\n")
    assert _cli(model_path, src, tmp_path / "o.csv", capsys)[2] == ""


def test_time_in_milliseconds_gets_a_hint_with_the_share_of_gap_rows(tmp_path, capsys):
    """time_s written in milliseconds (0, 1000, 2000 …) against a model with dynamic inputs
    (gap_s 5 s): every step is a "gap", so the state restarts and 48 of 49 rows are flagged —
    it runs (exit 0, as before) and now says so in one warning line: the share of rows the
    gap rule flagged, the median step and the unit that fits (was: silent).  The same rows in
    seconds: no warning, nothing flagged; in microseconds: that unit's hint."""
    temp = np.linspace(0.0, 50.0, 2000)
    t = np.arange(temp.size) * 2.0
    spec = FeatureSpec(inputs=["dT", "lag_60"], t_ref=25.0, gap_s=5.0)
    from thermonet.features import dynamics

    lag = dynamics.compute(t, temp, ["lag_60"], 5.0)[0]["lag_60_c"]
    model = fit(family="poly", inputs=["dT", "lag_60"], outputs=AXES,
                train=[(np.column_stack([temp, lag]), _true_drift(temp))], val=None, spec=spec,
                hyper={"degree": 1}, config=TrainConfig(max_epochs=1)).model
    model.set_guard(None)     # no joint (T, lag) envelope: the flag is the range and the gaps
    path = export_onnx(model, tmp_path / "lag.onnx")
    assert rt.Compensator(path).dynamic["gap_s"] == 5.0
    src = tmp_path / "ms.csv"

    def write(scale: float) -> None:
        rows = [f"{k * scale!r},{20.0 + 0.01 * k!r},1,2,3" for k in range(49)]
        src.write_text("time_s,temperature_c,gyro_x,gyro_y,gyro_z\n" + "\n".join(rows) + "\n")

    write(1000.0)
    code, printed, err = _cli(path, src, tmp_path / "o.csv", capsys)
    assert code == 0 and "48 out of range" in printed
    assert err == (f"thermonet_runtime: warning: {src}: column 'time_s': the gap rule (a step "
                   "over the model's gap_s = 5 s restarts the state, flag set) flags 48 of 49 "
                   "rows (98 %); the median step is 1000 s (time_s in milliseconds? divide by "
                   "1000)\n")
    write(1.0)                                        # seconds: nothing to say
    code, printed, err = _cli(path, src, tmp_path / "o.csv", capsys)
    assert (code, err) == (0, "") and "0 out of range" in printed
    write(1e6)
    err = _cli(path, src, tmp_path / "o.csv", capsys)[2]
    assert "flags 48 of 49 rows (98 %)" in err and "time_s in microseconds? divide by 1e+06" in err
    # a model without a gap rule (no dynamic input) says nothing of time_s
    assert rt._time_warning(src, np.arange(49) * 1000.0, [slice(0, 49)], 5.0) is not None
    assert rt._input_warnings(rt.Compensator(path), src, {"time_s": np.arange(49.0)},
                              [slice(0, 49)]) == []


def test_a_temperature_beyond_float32_is_flagged_without_a_numpy_warning(model_path, tmp_path,
                                                                           capsys):
    """1e39 is a float64 but beyond float32 (the graph's signal type): read as +inf, so NaN
    drift and the flag, as the docs say of a non-finite signal — and no numpy
    ``RuntimeWarning: overflow`` on stderr (was leaked), in the command and the API."""
    import warnings

    src = tmp_path / "big.csv"
    src.write_text("temperature_c,gyro_x,gyro_y,gyro_z\n1e39,1,2,3\n-1e39,1,2,3\n20,1,2,3\n")
    code, _, err = _cli(model_path, src, tmp_path / "o.csv", capsys)
    assert code == 0 and "RuntimeWarning" not in err and "overflow" not in err
    rows = list(csv.DictReader((tmp_path / "o.csv").open(newline="")))
    assert [r["out_of_range"] for r in rows] == ["1", "1", "0"]
    assert all(r[f"{a}_drift"] == "nan" for r in rows[:2] for a in AXES)
    comp = rt.Compensator(model_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = comp.compensate(temperature_c=np.array([1e39, 20.0]), raw=np.zeros((2, 3)))
        one = comp.step(0.0, 1e39, np.zeros(3))
    assert res.out_of_range.tolist() == [True, False] and np.isnan(res.drift[0]).all()
    assert one.out_of_range and np.isnan(one.drift).all()
