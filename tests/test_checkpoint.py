"""Checkpoint round trip (weights_only) and ONNX parity, for every registered family."""

import os

import numpy as np
import onnxruntime as ort
import pytest
import torch

from conftest import pointwise_families
from thermonet.core.errors import ExportError, InputError
from thermonet.features.inputs import FeatureSpec
from thermonet.models import MODELS
from thermonet.training.checkpoint import load_checkpoint, save_checkpoint
from thermonet.training.train import TrainConfig, fit, predict

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

# a heating-then-cooling run: temperature and rate both vary
_t = np.linspace(0.0, 3.0, 300)
TEMP = 20.0 + 40.0 * np.sin(_t)
RATE = np.gradient(TEMP, _t) / 60.0
DRIFT = np.stack([0.01 * np.sin(TEMP / 20.0), 0.004 * np.cos(TEMP / 30.0)], 1)


def _inputs(name):
    return ["dT"] if MODELS[name].max_inputs == 1 else ["dT", "dT2", "rate"]


def _trained(name):
    inputs = _inputs(name)
    spec = FeatureSpec(inputs=inputs, t_ref=25.0)
    sig = np.stack([TEMP, RATE], 1)[:, :len(spec.signals)]
    hyper = {"n_centres": 6} if name == "rbf" else {}
    res = fit(family=name, inputs=inputs, outputs=["gyro_x", "gyro_y"], train=[(sig, DRIFT)],
              val=None, spec=spec, hyper=hyper, config=TrainConfig(max_epochs=10))
    return res, sig


def spec_dict(inputs):
    """What the checkpoint stores: references, and the dynamic inputs' constants."""
    out = {"inputs": inputs, "t_ref": 25.0, "proxy_ref": {}}
    if "rate" in inputs:
        out["dynamic"] = {"version": 1, "gap_s": 10.0,
                          "start": "E = T (lag 0, rate 0), P = T (play 0)",
                          "gap": "dt since the last finite-temperature sample > gap_s: "
                                 "restart, flag set",
                          "inputs": [{"name": "rate", "kind": "rate", "signal": "rate_c_per_min",
                                      "unit": "degC/min", "tau_s": 60.0}]}
    return out


@pytest.mark.parametrize("name", pointwise_families())
def test_checkpoint_round_trip_identical_predictions(name, tmp_path):
    res, sig = _trained(name)
    path = save_checkpoint(tmp_path / "sub" / "model.pt", res.model,
                           config={"family": name, "lr": np.float64(0.01), "runs": ("a", "b")},
                           extra={"rms": np.array([1.0, 2.0])}, epoch=res.best_epoch,
                           best_val=res.history[res.best_epoch]["train_loss"])
    assert os.listdir(path.parent) == ["model.pt"]           # no temp file left behind
    raw = torch.load(path, weights_only=True)                 # plain data only
    assert raw["family"] == name and raw["outputs"] == ["gyro_x", "gyro_y"]
    model, meta = load_checkpoint(path)
    # saved and loaded: the same weights through the same computation, bit for bit
    np.testing.assert_array_equal(predict(model, sig), predict(res.model, sig))
    assert meta["config"] == {"family": name, "lr": 0.01, "runs": ["a", "b"]}
    assert meta["extra"] == {"rms": [1.0, 2.0]}
    assert meta["spec"] == spec_dict(_inputs(name))
    assert model.spec.to_dict() == res.model.spec.to_dict()
    assert meta["inputs"] == _inputs(name) and meta["signals"] == model.signals
    assert meta["hyper"] == res.model.family.hyper()
    assert meta["epoch"] == res.best_epoch


def test_nan_parameter_and_non_plain_config_are_refused(tmp_path):
    res, _ = _trained("linear")
    with pytest.raises(ExportError, match="holds a object"):
        save_checkpoint(tmp_path / "a.pt", res.model, config={"x": object()})
    with torch.no_grad():
        res.model.family.weight[0, 0] = float("nan")
    with pytest.raises(ExportError, match="'family.weight' holds NaN"):
        save_checkpoint(tmp_path / "b.pt", res.model, config={})
    assert not any(tmp_path.iterdir())


def test_loading_a_non_checkpoint_is_an_input_error(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="not a readable checkpoint"):
        load_checkpoint(bad)
    torch.save({"state_dict": {}}, tmp_path / "partial.pt")
    with pytest.raises(InputError, match="missing family"):
        load_checkpoint(tmp_path / "partial.pt")
    with pytest.raises(InputError, match="checkpoint file not found"):
        load_checkpoint(tmp_path / "missing.pt")


@pytest.mark.parametrize("name", pointwise_families())
def test_onnx_export_dynamic_batch_matches_torch(name, tmp_path):
    res, sig = _trained(name)
    model = res.model
    program = torch.onnx.export(model, (torch.as_tensor(sig[:3], dtype=torch.float32),),
                                dynamo=True, opset_version=18, input_names=["signals"],
                                output_names=["drift"],
                                dynamic_shapes={"signals": {0: torch.export.Dim("batch")}},
                                verbose=False)
    program.save(str(tmp_path / "m.onnx"))
    sess = ort.InferenceSession(str(tmp_path / "m.onnx"), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    # 1000 points, 10 % beyond the trained range on each side (exercises the clamp)
    lo, hi = sig.min(0), sig.max(0)
    pts = rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo),
                      size=(1000, sig.shape[1])).astype(np.float32)
    got = sess.run(None, {"signals": pts})[0]
    with torch.no_grad():
        want = model(torch.as_tensor(pts)).numpy()
    assert got.shape == (1000, 2) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5 * np.abs(want).max())


def test_parameters_of_another_shape_name_the_parameter_and_both_shapes(tmp_path):
    from thermonet.training.checkpoint import seal_checkpoint

    res, _ = _trained("poly")
    path = save_checkpoint(tmp_path / "p.pt", res.model, config={})
    payload = torch.load(path, weights_only=True)
    degree = payload["hyper"]["degree"]
    payload["hyper"]["degree"] = degree - 1       # rebuilt with one coefficient fewer
    torch.save(payload, path)
    seal_checkpoint(path)
    with pytest.raises(InputError) as info:
        load_checkpoint(path)
    msg = str(info.value)
    assert "\n" not in msg and "parameters do not match the stored family 'poly'" in msg
    assert "is stored with shape (" in msg and ", the family rebuilt from the checkpoint " \
        "has (" in msg, msg
    assert "Error(s) in loading state_dict" not in msg
