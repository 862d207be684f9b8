"""ONNX export: in-graph features/clamp/flag, metadata, parity, refusals, atomic write, MLflow."""

from __future__ import annotations

import json

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from conftest import pointwise_families
from thermonet.core.errors import ExportError
from thermonet.exporting import export_onnx, log_onnx_to_mlflow, onnx_file_size, parity_check
from thermonet.features.inputs import FeatureSpec
from thermonet.models import MODELS
from thermonet.training.train import TrainConfig, fit
from tolerances import assert_f32_close

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

T_REF = 25.0
AXES = ["gyro_x", "gyro_y", "gyro_z"]


def _drift(temp: np.ndarray) -> np.ndarray:
    """Known smooth drift (deg/s) per axis: a cubic in ΔT plus a bump, different per axis."""
    dt = temp - T_REF
    base = 1e-3 * dt + 2e-5 * dt ** 2 - 1e-7 * dt ** 3
    return np.stack(
        [base + 0.01, -0.5 * base + 0.004 * np.exp(-((dt / 15) ** 2)), 2 * base - 0.02], 1
    )


def _fit(family: str, inputs: list[str], epochs: int = 10, hyper: dict | None = None):
    temp = np.linspace(-20.0, 60.0, 600)
    spec = FeatureSpec(inputs=inputs, t_ref=T_REF)
    return fit(family=family, inputs=inputs, outputs=AXES, train=[(temp[:, None], _drift(temp))],
               val=None, spec=spec, hyper=hyper or {}, config=TrainConfig(max_epochs=epochs, seed=0)
               ).model


def _inputs_for(family: str) -> list[str]:
    return ["dT", "dT2"] if MODELS[family].max_inputs is None else ["dT"]


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """Every registered family, trained briefly and exported (parity checked on export)."""
    out = {}
    d = tmp_path_factory.mktemp("onnx")
    for name in pointwise_families():
        model = _fit(name, _inputs_for(name))
        path = export_onnx(
            model,
            d / f"{name}.onnx",
            metadata={
                "device_id": "IMU-7",
                "training_run_id": "run42",
                "validation_metrics": {"val/rms": 0.0012},
                "data_hash": "sha256:abc",
                "output_units": {a: "deg/s" for a in AXES},
            },
        )
        out[name] = (model, path)
    return out


@pytest.mark.parametrize("family", pointwise_families())
def test_onnx_matches_torch_and_recovers_drift(exported, family):
    model, path = exported[family]
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    assert [i.name for i in sess.get_inputs()] == ["temperature_c", "raw"]
    assert [o.name for o in sess.get_outputs()] == ["compensated", "drift", "out_of_range"]
    temp = np.linspace(-20.0, 60.0, 1001, dtype=np.float32)
    raw = _drift(temp.astype(np.float64))
    comp, drift, flag = sess.run(None, {"temperature_c": temp, "raw": raw})
    with torch.no_grad():
        ref = model(torch.from_numpy(temp[:, None])).numpy()
    scale = np.abs(ref).max(axis=0)
    err = np.abs(drift - ref)
    assert (err <= 1e-5 * scale).all(), (
        err.max(axis=0),
        scale,
        np.unravel_index(err.argmax(), err.shape),
    )
    np.testing.assert_allclose(comp, raw - drift, rtol=0, atol=1e-6 * scale.max())
    assert not flag.any()
    # the compensated output is much flatter than the raw one (the model learnt the drift)
    assert (np.ptp(comp, axis=0) < 0.3 * np.ptp(raw, axis=0)).all()


@pytest.mark.parametrize("family", pointwise_families())
def test_clamp_flag_and_nan_inside_graph(exported, family):
    model, path = exported[family]
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    temp = np.array([-40.0, -20.0, 60.0, 90.0, np.nan, np.inf, 20.0], dtype=np.float32)
    raw = np.ones((7, 3))
    comp, drift, flag = sess.run(None, {"temperature_c": temp, "raw": raw})
    assert flag.tolist() == [True, False, False, True, True, True, False]
    # clamped: the input becomes the edge value itself, so the same batch with the edges
    # given directly is bit-identical at the same positions (a promise of the graph) ...
    at_edges = temp.copy()
    at_edges[[0, 3]] = [-20.0, 60.0]
    _, same, _ = sess.run(None, {"temperature_c": at_edges, "raw": raw})
    np.testing.assert_array_equal(drift[[0, 3]], same[[0, 3]])
    # ... and equal to the edge samples at other positions to float32 rounding
    assert_f32_close(drift[[0, 3]], drift[[1, 2]], "family")
    assert np.isnan(drift[4]).all() and np.isnan(comp[4]).all()
    assert np.isnan(drift[5]).all() and np.isnan(comp[5]).all()
    assert np.isfinite(drift[[0, 1, 2, 3, 6]]).all()


def test_metadata_props(exported):
    model, path = exported["rbf"]
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert meta["thermonet_format"] == "2"
    assert meta["family"] == "rbf"
    # what the drift is relative to: the fixture's gyro axes are plain drift (channel)
    assert json.loads(meta["targets"]) == {a: "channel" for a in AXES}
    assert json.loads(meta["compensate"]) == {a: True for a in AXES}
    const = json.loads(meta["drift_constant"])
    np.testing.assert_allclose([const[a] for a in AXES], model.y_offset.numpy(), rtol=1e-15)
    assert json.loads(meta["rest_signals"]) == {"temperature_c": pytest.approx(T_REF)}
    assert meta["onnx_opset"] == "18"
    assert json.loads(meta["signals"]) == ["temperature_c"]
    assert json.loads(meta["inputs"]) == ["dT", "dT2"]
    assert json.loads(meta["outputs"]) == AXES
    assert json.loads(meta["output_units"]) == {a: "deg/s" for a in AXES}
    assert json.loads(meta["signal_units"]) == {"temperature_c": "degC"}
    assert float(meta["t_ref"]) == T_REF
    lo, hi = json.loads(meta["trained_range"])["temperature_c"]
    assert (lo, hi) == pytest.approx((-20.0, 60.0), abs=1e-4)
    assert meta["device_id"] == "IMU-7"
    assert meta["training_run_id"] == "run42"
    assert json.loads(meta["validation_metrics"]) == {"val/rms": 0.0012}
    assert meta["data_hash"] == "sha256:abc"
    assert meta["thermonet_version"]
    proto = onnx.load(str(path))
    assert [o.version for o in proto.opset_import if o.domain in ("", "ai.onnx")] == [18]
    assert not any(
        init.data_location == onnx.TensorProto.EXTERNAL for init in proto.graph.initializer
    )


def test_rbf_16_centres_is_small(exported):
    model, path = exported["rbf"]
    assert model.family.n_centres == 16
    assert onnx_file_size(path) <= 16 * 1024


def test_dynamic_batch(exported):
    _, path = exported["poly"]
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    for n in (1, 7, 5000):
        out = sess.run(None, {"temperature_c": np.full(n, 30.0, np.float32),
                              "raw": np.zeros((n, 3))})
        assert out[0].shape == (n, 3) and out[2].shape == (n,)


def test_parity_failure_names_the_worst_point(exported):
    # Two real one-input models: the fuzzy model checked against the Lorentz model's file.
    lorentz, lorentz_path = exported["lorentz"]
    fuzzy, _ = exported["ts-fuzzy"]
    with pytest.raises(ExportError, match=r"parity check failed at temperature_c=.*axis 'gyro_.'.*"
                                          r"onnxruntime .* vs torch"):
        parity_check(fuzzy, lorentz_path)
    stats = parity_check(lorentz, lorentz_path)
    assert stats["n_points"] == 201 + 10_000
    assert stats["max_rel_diff"] <= 1e-5


def test_nan_parameter_refused_and_nothing_written(exported, tmp_path):
    model = _fit("linear", ["dT"], epochs=0)
    target = tmp_path / "m.onnx"
    target.write_bytes(b"previous file")
    with torch.no_grad():
        model.family.weight[0, 0] = float("nan")
    with pytest.raises(ExportError, match="family.weight.*NaN"):
        export_onnx(model, target, metadata={})
    assert target.read_bytes() == b"previous file"          # untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.onnx"]   # no temp left behind


def test_unknown_exporter_refused(exported, tmp_path):
    model, _ = exported["linear"]
    with pytest.raises(ExportError, match="exporter must be"):
        export_onnx(model, tmp_path / "x.onnx", exporter="tensorrt")
    assert list(tmp_path.iterdir()) == []


def test_torchscript_exporter_gives_same_numbers(exported, tmp_path):
    model, dyn_path = exported["ts-fuzzy"]
    ts_path = export_onnx(model, tmp_path / "ts.onnx", exporter="torchscript")
    meta = {p.key: p.value for p in onnx.load(str(ts_path)).metadata_props}
    assert meta["exporter"] == "torchscript"
    temp = np.linspace(-25.0, 65.0, 301, dtype=np.float32)
    feeds = {"temperature_c": temp, "raw": np.zeros((301, 3))}
    a = ort.InferenceSession(str(dyn_path), providers=["CPUExecutionProvider"]).run(None, feeds)
    b = ort.InferenceSession(str(ts_path), providers=["CPUExecutionProvider"]).run(None, feeds)
    assert_f32_close(a[1], b[1], "family")      # two exporters: two graphs, float32 rounding
    np.testing.assert_array_equal(a[2], b[2])   # flags: booleans


@pytest.mark.slow   # an end-to-end run: native only (make test-cpus skips slow)
def test_log_to_mlflow_sqlite(exported, tmp_path):
    import mlflow
    import mlflow.onnx
    import mlflow.pyfunc

    _, path = exported["linear"]
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = mlflow.MlflowClient(tracking_uri=uri)
    exp = client.create_experiment("export-test", artifact_location=(tmp_path / "art").as_uri())
    run = client.create_run(exp)
    log_onnx_to_mlflow(path, run.info.run_id, uri)
    files = [f.path for f in client.list_artifacts(run.info.run_id, "onnx")]
    assert files == ["onnx/linear.onnx"]
    mlflow.set_tracking_uri(uri)
    try:
        loaded = mlflow.onnx.load_model(f"runs:/{run.info.run_id}/model")
    finally:
        mlflow.set_tracking_uri(None)
    assert {p.key: p.value for p in loaded.metadata_props}["family"] == "linear"
    # the requirements are the ones given (never inferred by loading the model in a
    # subprocess): MLflow's own pin, then onnx, onnxruntime and numpy at their installed versions
    from importlib.metadata import version

    mlflow.set_tracking_uri(uri)
    try:
        req = mlflow.pyfunc.get_model_dependencies(f"runs:/{run.info.run_id}/model")
    finally:
        mlflow.set_tracking_uri(None)
    lines = [ln for ln in open(req).read().splitlines() if ln.strip()]
    assert lines[1:] == [f"{n}=={version(n)}" for n in ("onnx", "onnxruntime", "numpy")]
    assert lines[0].startswith("mlflow")


def test_parity_check_catches_a_graph_without_the_clamp(tmp_path):
    """A graph that evaluates outside the trained range (no clamp) must be refused."""
    import torch

    from thermonet.core.errors import ExportError
    from thermonet.exporting.parity import parity_check

    model = _fit("poly", ["dT"], hyper={"degree": 3})
    good = export_onnx(model, tmp_path / "good.onnx")
    lo, hi = model.sig_lo.clone(), model.sig_hi.clone()
    with torch.no_grad():  # the same model, its range opened wide: the graph no longer clamps
        model.sig_lo.fill_(-1e6)
        model.sig_hi.fill_(1e6)
    unclamped = export_onnx(model, tmp_path / "unclamped.onnx", check=False)
    with torch.no_grad():
        model.sig_lo.copy_(lo)
        model.sig_hi.copy_(hi)
    parity_check(model, good)
    with pytest.raises(ExportError, match="out_of_range flag not set|not the clamped value"):
        parity_check(model, unclamped)
