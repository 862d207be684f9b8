"""Targets: what the drift is relative to, per axis, through fit, checkpoint and every export.

Independent expectations: a level accelerometer keeps −9.81 m/s² on z after compensation
(the simulated truth), PX4's own accelerometer calibration writes X0 = 0 at TREF, and an
output with a 1e6 constant keeps its 1e-3 drift at the noise level (numbers from the
generating law, not from thermonet).
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import load_runtime
from oracles import px4_offsets
from thermonet.core.errors import ConfigError
from thermonet.exporting import (
    autopilot_coefficients,
    export_c_header,
    export_onnx,
    export_px4_params,
    read_px4_params,
)
from thermonet.exporting.c_driver import PARITY_DRIVER
from thermonet.features.inputs import FeatureSpec
from thermonet.features.target import resolve_targets
from thermonet.training.checkpoint import load_checkpoint, save_checkpoint, seal_checkpoint
from thermonet.training.train import TrainConfig, fit, predict

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

G = 9.80665
T_REF = 25.0
ROOT = Path(__file__).resolve().parents[1]


def _run_c(model, tmp_path: Path, sig: np.ndarray, raw: np.ndarray) -> np.ndarray:
    """Compile the exported header with the export's own driver; return rows (comp, drift, flag)."""
    export_c_header(model, tmp_path / "model.h")
    (tmp_path / "driver.c").write_text(PARITY_DRIVER.replace("PFX", "THERMONET")
                                       .replace("pfx", "thermonet"))
    exe = tmp_path / "driver"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-o", str(exe),
                    str(tmp_path / "driver.c"), "-lm"], check=True, capture_output=True, text=True)
    n, n_ax = raw.shape
    rows = np.zeros(n, dtype=[("s", np.float32, sig.shape[1]), ("raw", np.float64, n_ax)])
    rows["s"], rows["raw"] = sig, raw
    (tmp_path / "in.bin").write_bytes(np.int32(n).tobytes() + rows.tobytes())
    subprocess.run([str(exe), str(tmp_path / "in.bin"), str(tmp_path / "out.bin")], check=True)
    rec = np.dtype([("comp", np.float64, n_ax), ("drift", np.float64, n_ax), ("flag", np.int32)])
    return np.fromfile(tmp_path / "out.bin", dtype=rec)


# ------------------------------------------------------------------ resolution
def test_defaults_and_config_errors():
    outs = ["gyro_x", "acc_x", "acc_z", "mag_x", "out_x"]
    t = resolve_targets(None, outs, has_reference={"acc_z": True})
    assert t.as_dict() == {"gyro_x": "zero", "acc_x": "at-t-ref", "acc_z": "channel",
                           "mag_x": "at-t-ref", "out_x": "at-t-ref"}
    # a name wins over its kind
    t = resolve_targets({"acc": "zero", "acc_x": "at-t-ref"}, outs, has_reference={})
    assert t.mode("acc_x") == "at-t-ref" and t.mode("acc_z") == "zero"
    with pytest.raises(ConfigError, match=r"c.yaml: key 'target.acc': 'channel' needs a "
                                          r"reference column ref_acc_x"):
        resolve_targets({"acc": "channel"}, outs, has_reference={}, source="c.yaml")
    with pytest.raises(ConfigError, match=r"key 'target.baro': names no output"):
        resolve_targets({"baro": "zero"}, outs, has_reference={})
    with pytest.raises(ConfigError, match=r"key 'target.gyro': 'absolute' is not one of"):
        resolve_targets({"gyro": "absolute"}, outs, has_reference={})
    assert resolve_targets("four-position", ["acc_x.bias"], has_reference={}).kind == \
        "four-position"


# ------------------------------------------------------- gravity kept everywhere
def _level_accelerometer(seed: int = 0):
    """A level 3-axis accelerometer, no reference: tilt on x/y, −1 g on z, drift zero at T_REF."""
    rng = np.random.default_rng(seed)
    temp = np.concatenate([np.linspace(-10.0, 60.0, 3000), np.linspace(60.0, -10.0, 3000)])
    dt = temp - T_REF
    level = np.array([0.15, -0.10, -G])
    drift = np.stack([2e-3 * dt + 2e-5 * dt ** 2, -1.5e-3 * dt, 3e-3 * dt - 3e-5 * dt ** 2], 1)
    noise = rng.normal(0.0, 0.002, drift.shape)
    return temp, level, drift, level + drift + noise


def test_level_accelerometer_keeps_gravity_in_torch_onnx_c_and_px4(tmp_path):
    temp, level, drift, raw = _level_accelerometer()
    axes = ["acc_x", "acc_y", "acc_z"]
    spec = FeatureSpec(inputs=["dT"], t_ref=T_REF)
    model = fit(family="poly", inputs=["dT"], outputs=axes, train=[(temp[:, None], raw)],
                val=None, spec=spec, hyper={"degree": 3}, config=TrainConfig(max_epochs=5),
                target=["at-t-ref"] * 3).model
    assert model.target_modes == ["at-t-ref"] * 3
    # torch: the drift is zero at T_ref and the change with temperature is recovered
    at_ref = predict(model, np.array([[T_REF]]))[0]
    np.testing.assert_allclose(at_ref, 0.0, atol=1e-6)
    pred = predict(model, temp[:, None])
    np.testing.assert_allclose(pred, drift, atol=4e-4)
    comp = raw - pred
    np.testing.assert_allclose(comp.mean(axis=0), level, atol=1e-3)   # gravity and tilt kept
    np.testing.assert_allclose(comp[:, 2].std(), 0.002, rtol=0.1)     # only the noise left

    # onnxruntime, through the torch-free runtime
    rt = load_runtime()
    onnx_path = export_onnx(model, tmp_path / "acc.onnx")
    res = rt.Compensator(onnx_path).compensate(temperature_c=temp, raw=raw)
    np.testing.assert_allclose(res.compensated.mean(axis=0), level, atol=1e-3)
    np.testing.assert_allclose(res.compensated, comp, atol=1e-5)
    assert rt.Compensator(onnx_path).metadata["targets"] == \
        '{"acc_x": "at-t-ref", "acc_y": "at-t-ref", "acc_z": "at-t-ref"}'

    # the C header
    c_out = _run_c(model, tmp_path, temp[:, None].astype(np.float32), raw)
    np.testing.assert_allclose(c_out["comp"].mean(axis=0), level, atol=1e-3)
    np.testing.assert_allclose(c_out["comp"], comp, atol=1e-5)

    # PX4: X0 is zero at TREF (PX4's accel.cpp normalises it so), not −9.8
    p = read_px4_params(export_px4_params(model, tmp_path / "tc.params", output_units="m/s^2",
                                          device_id=1))
    assert p["TC_A0_TREF"] == pytest.approx(T_REF)
    for i in range(3):
        assert abs(p[f"TC_A0_X0_{i}"]) < 1e-5
    px4 = px4_offsets(p, "TC_A0_", temp)     # PX4's formula (tests/oracles.py)
    np.testing.assert_allclose((raw - px4).mean(axis=0), level, atol=1e-3)


@pytest.mark.slow   # an end-to-end run: native only (make test-cpus skips slow)
def test_consumer_imu_compare_keeps_gravity_and_gyro_bias(tmp_path):
    """Through `compare` on the consumer-imu preset: default targets, gravity kept on acc_z."""
    from thermonet.sim import simulate
    from thermonet.training.config import CompareConfig, from_dict
    from thermonet.workflows.compare import run_compare

    cfg = from_dict(CompareConfig, {
        "data": {"preset": "consumer-imu", "seed": 0},
        "features": {"t_ref": T_REF},
        "families": [{"family": "poly", "name": "cubic", "params": {"degree": 3}}],
        "train": {"max_epochs": 3}, "baseline": "cubic"})
    res = run_compare(cfg, tmp_path / "cmp", track=False, quiet=True)
    assert res["targets"] == {"gyro_x": "zero", "gyro_y": "zero", "gyro_z": "zero",
                              "acc_x": "at-t-ref", "acc_y": "at-t-ref", "acc_z": "at-t-ref"}
    model, _ = load_checkpoint(res["families"]["cubic"]["checkpoint"])
    test = simulate("consumer-imu", seed=0)["run1"]
    drift = predict(model, test.temperature_c[:, None])
    k = model.outputs.index("acc_z")
    comp_z = test.outputs["acc_z"] - drift[:, k]
    # the truth: −1 g plus the run's turn-on bias (σ 0.05 m/s²); 0 would mean gravity was lost
    truth = -G + float(test.meta["unit_bias_offset"])
    assert abs(comp_z.mean() - truth) < 0.02
    # a static gyro keeps its absolute bias in the drift (zero target): the constant is there
    # (on a gyro axis the model compensates: gyro_x's hysteresis makes the cubic worse than
    # raw there, gyro_z has no drift, so excursion folds may leave either raw)
    axes = res["families"]["cubic"]["axes"]
    g = model.outputs.index(next(a for a in ("gyro_y", "gyro_x") if axes[a]["compensate"]))
    assert model.y_offset[g].item() != 0.0 and model.constant()[g].item() != 0.0


# ------------------------------------------------------------ large offsets
def test_large_constant_keeps_drift_precision_through_fit_onnx_and_c(tmp_path):
    """1e6 counts + a 1e-3 drift: the drift error stays at the noise level everywhere."""
    rng = np.random.default_rng(1)
    temp = np.linspace(-20.0, 60.0, 4000)
    dt = temp - T_REF
    law = 1e-3 * np.stack([dt / 40 + (dt / 40) ** 2, -dt / 40], 1)     # counts
    sigma = 1e-4
    raw = 1e6 + np.array([0.0, 123.456]) + law + rng.normal(0, sigma, law.shape)
    axes = ["out_x", "out_y"]
    spec = FeatureSpec(inputs=["dT", "dT2"], t_ref=T_REF)
    # out_x: at-t-ref (the constant cancels); out_y: zero (the constant is drift, in float64)
    model = fit(family="poly", inputs=["dT", "dT2"], outputs=axes, train=[(temp[:, None], raw)],
                val=None, spec=spec, hyper={"degree": 1}, config=TrainConfig(max_epochs=5),
                target=["at-t-ref", "zero"]).model
    truth = np.stack([law[:, 0], 1e6 + 123.456 + law[:, 1]], 1)
    pred = predict(model, temp[:, None])
    # at-t-ref: the truth relative to T_ref is law (zero at T_REF by construction)
    err = pred - truth
    err[:, 1] -= err[:, 1].mean()   # the zero axis also carries the noise's mean: ≈ σ/√n
    assert np.sqrt(np.mean(err ** 2, axis=0)).max() < 0.2 * sigma
    assert abs(pred[:, 1].mean() - truth[:, 1].mean()) < 5 * sigma / np.sqrt(temp.size) + 1e-9

    comp = raw - pred
    rt = load_runtime()
    res = rt.Compensator(export_onnx(model, tmp_path / "big.onnx")).compensate(
        temperature_c=temp, raw=raw)
    assert res.compensated.dtype == np.float64
    np.testing.assert_allclose(res.compensated, comp, atol=0.05 * sigma)
    # not quantised to float32's 0.0625 steps at 1e6: the noise survives sample to sample
    resid = res.compensated[:, 0] - 1e6
    assert np.std(resid) == pytest.approx(sigma, rel=0.1)
    c_out = _run_c(model, tmp_path, temp[:, None].astype(np.float32), raw)
    np.testing.assert_allclose(c_out["comp"], comp, atol=0.05 * sigma)
    np.testing.assert_allclose(c_out["drift"], pred, atol=0.05 * sigma)


# ------------------------------------------------------------ uncompensated axes
def test_mask_leaves_an_axis_uncompensated_in_every_export(tmp_path):
    temp, level, drift, raw = _level_accelerometer(seed=2)
    axes = ["acc_x", "acc_y", "acc_z"]
    spec = FeatureSpec(inputs=["dT"], t_ref=T_REF)
    model = fit(family="poly", inputs=["dT"], outputs=axes, train=[(temp[:, None], raw)],
                val=None, spec=spec, hyper={"degree": 3}, config=TrainConfig(max_epochs=5),
                target=["at-t-ref"] * 3).model
    model.set_compensate([True, False, True])
    assert model.compensated_axes == [True, False, True]
    pred = predict(model, temp[:, None])
    assert np.all(pred[:, 1] == 0.0) and np.abs(pred[:, 0]).max() > 0.05

    rt = load_runtime()
    comp = rt.Compensator(export_onnx(model, tmp_path / "m.onnx"))
    assert comp.metadata["compensate"] == '{"acc_x": true, "acc_y": false, "acc_z": true}'
    res = comp.compensate(temperature_c=temp, raw=raw)
    # a masked axis is exactly 0 (its output row is zero) and the raw value passes unchanged
    assert np.all(res.drift[:, 1] == 0.0) and np.array_equal(res.compensated[:, 1], raw[:, 1])
    c_out = _run_c(model, tmp_path, temp[:, None].astype(np.float32), raw)
    assert np.all(c_out["drift"][:, 1] == 0.0)
    assert "acc_y at-t-ref (uncompensated: drift 0)" in (tmp_path / "model.h").read_text()
    co = autopilot_coefficients(model, output_units="m/s^2")
    assert np.all(co.coef["acc"][1] == 0.0) and np.any(co.coef["acc"][0] != 0.0)

    # the checkpoint carries the target and the mask; one written before targets still loads
    ckpt = save_checkpoint(tmp_path / "m.pt", model, config={})
    back, _ = load_checkpoint(ckpt)
    assert back.target_modes == ["at-t-ref"] * 3 and back.compensated_axes == [True, False, True]
    assert back.y_offset.dtype == torch.float64
    # saved and loaded: the same weights through the same computation, bit for bit
    np.testing.assert_array_equal(predict(back, temp[:, None]), pred)
    payload = torch.load(ckpt, weights_only=True)
    for name in ("y_offset", "y_ref", "sig_ref", "target_code", "compensate"):
        del payload["state_dict"][name]
    torch.save(payload, tmp_path / "old.pt")
    seal_checkpoint(tmp_path / "old.pt")  # edited on purpose: sealed again
    old, _ = load_checkpoint(tmp_path / "old.pt")
    assert old.target_modes == ["channel"] * 3 and old.compensated_axes == [True] * 3


def test_config_target_section_is_checked_before_anything_is_written(tmp_path):
    from thermonet.training.config import load_config
    from thermonet.workflows.compare import run_compare

    cfg_file = tmp_path / "c.yaml"
    cfg_file.write_text("data: {preset: accel-ramp}\ntarget: {acc: channel}\n")
    cfg = load_config(cfg_file)
    assert cfg.target == {"acc": "channel"}
    with pytest.raises(ConfigError, match=r"c.yaml: key 'target.acc': 'channel' needs a "
                                          r"reference column ref_acc_x and the data has none"):
        run_compare(cfg, tmp_path / "out", track=False, quiet=True)
    assert not (tmp_path / "out").exists()
    cfg_file.write_text("data: {preset: accel-ramp}\ntarget: [zero]\n")
    with pytest.raises(ConfigError, match=r"key 'target'"):
        load_config(cfg_file)
