"""PX4 / ArduPilot parameter files: written, parsed back, evaluated with the autopilots'
formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from oracles import ardupilot_offsets, px4_offsets
from thermonet.core.errors import ExportError
from thermonet.exporting import (
    autopilot_coefficients,
    export_ardupilot_params,
    export_px4_params,
    read_ardupilot_params,
    read_px4_params,
)
from thermonet.features.inputs import FeatureSpec
from thermonet.training.train import TrainConfig, fit

AXES = ["gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"]
UNITS = {"gyro_x": "deg/s", "gyro_y": "deg/s", "gyro_z": "deg/s", "acc_x": "mg", "acc_y": "mg",
         "acc_z": "mg"}
T_REF = 22.0
# drift per axis = c0 + c1 dT + c2 dT^2 + c3 dT^3 (deg/s for gyro, mg for accel), dT = T - 22
COEF = np.array([[0.05, 1e-3, 2e-5, -1e-7], [-0.02, -5e-4, 1e-5, 3e-8], [0.01, 2e-3, 0.0, 1e-7],
                 [3.0, 0.2, -4e-3, 2e-5], [-1.0, 0.1, 1e-3, 0.0], [0.5, -0.3, 2e-3, -1e-5]])
SI = np.array([math.pi / 180] * 3 + [9.80665e-3] * 3)


def _drift(temp: np.ndarray) -> np.ndarray:
    dt = np.asarray(temp, dtype=np.float64)[:, None] - T_REF
    return sum(COEF[:, k] * dt ** k for k in range(4))


def _model(inputs=("dT",), degree=3, family="poly", temp=None):
    temp = np.linspace(-10.0, 55.0, 300) if temp is None else temp
    spec = FeatureSpec(inputs=list(inputs), t_ref=T_REF)
    hyper = {"degree": degree} if family == "poly" else {}
    return fit(
        family=family,
        inputs=list(inputs),
        outputs=AXES,
        train=[(temp[:, None], _drift(temp))],
        val=None,
        spec=spec,
        hyper=hyper,
        config=TrainConfig(max_epochs=0),
    ).model


@pytest.fixture(scope="module")
def model():
    return _model()


def _thermonet_si(model, temp: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return model(torch.tensor(temp[:, None], dtype=torch.float32)).double().numpy() * SI


def test_coefficients_recovered_in_si(model):
    co = autopilot_coefficients(model, output_units=UNITS)
    assert co.t_ref == T_REF and (co.t_min, co.t_max) == pytest.approx((-10.0, 55.0), abs=1e-4)
    np.testing.assert_allclose(co.coef["gyro"], COEF[:3] * SI[:3, None], rtol=2e-3, atol=1e-11)
    np.testing.assert_allclose(co.coef["acc"], COEF[3:] * SI[3:, None], rtol=2e-3, atol=1e-9)


def test_px4_file_reproduces_drift_and_clamp(model, tmp_path):
    path = export_px4_params(model, tmp_path / "tc.params", output_units=UNITS, device_id=2490378)
    lines = path.read_text().splitlines()
    assert "# Vehicle-Id Component-Id Name Value Type" in lines
    assert "1\t1\tTC_G0_ID\t2490378\t6" in lines and "1\t1\tTC_A_ENABLE\t1\t6" in lines
    p = read_px4_params(path)
    assert p["TC_G0_TREF"] == T_REF and p["TC_A0_TMIN"] == pytest.approx(-10.0, abs=1e-4)
    temp = np.concatenate([np.linspace(-10.0, 55.0, 131), [-30.0, 80.0]])
    want = _thermonet_si(model, temp)
    for t, cols in (("G", slice(0, 3)), ("A", slice(3, 6))):
        # PX4's calc_thermal_offsets_3D in the firmware's float32 (tests/oracles.py)
        offs = px4_offsets(p, f"TC_{t}0_", temp, dtype=np.float32)
        scale = np.abs(want[:, cols]).max(axis=0)
        np.testing.assert_allclose(offs, want[:, cols], rtol=0, atol=1e-5 * scale.max())
        # clamp: below TMIN / above TMAX the offset is the edge value, for both
        np.testing.assert_allclose(offs[-2], offs[0], rtol=1e-12)
        np.testing.assert_allclose(offs[-1], offs[130], rtol=1e-12)


def test_ardupilot_file_reproduces_drift_and_clamp(model, tmp_path):
    path = export_ardupilot_params(model, tmp_path / "tcal.param", output_units=UNITS)
    text = path.read_text()
    assert "INS_TCAL1_ENABLE,1" in text and "INS_TCAL1_GYR3_Z," in text
    p = read_ardupilot_params(path)
    cal_temp = 30.0           # temperature of the ordinary offset calibration
    temp = np.concatenate([np.linspace(-10.0, 55.0, 131), [-40.0, 79.0]])
    want = _thermonet_si(model, temp) - _thermonet_si(model, np.array([cal_temp]))
    for kind, cols in (("gyro", slice(0, 3)), ("acc", slice(3, 6))):
        # ArduPilot's TCal::correct_sensor + polynomial_eval (tests/oracles.py)
        subtracted = ardupilot_offsets(p, 0, kind, temp, cal_temp)
        scale = np.abs(_thermonet_si(model, temp)[:, cols]).max()
        np.testing.assert_allclose(subtracted, want[:, cols], rtol=0, atol=1e-5 * scale)
        np.testing.assert_allclose(subtracted[-2], subtracted[0], rtol=1e-12)
        np.testing.assert_allclose(subtracted[-1], subtracted[130], rtol=1e-12)
    spaced = read_ardupilot_params(export_ardupilot_params(model, tmp_path / "b.parm",
                                                           output_units=UNITS, sep=" "))
    assert spaced == p


def test_absolute_temperature_input(tmp_path):
    model = _model(inputs=("T",))
    co = autopilot_coefficients(model, output_units=UNITS)
    # the model's T_ref (where at-t-ref axes are zero), even for an input on T
    assert co.t_ref == pytest.approx(model.spec.t_ref)
    dt = np.linspace(-30, 30, 7)
    got = sum(co.coef["gyro"][:, k][None] * dt[:, None] ** k for k in range(4))
    want = _drift(co.t_ref + dt)[:, :3] * SI[:3]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6 * np.abs(want).max())


def test_a_linear_model_exports_as_a_degree_one_polynomial():
    temp = np.linspace(-10.0, 55.0, 300)
    line = COEF[:, :2].copy()               # drift c0 + c1 dT, known coefficients
    spec = FeatureSpec(inputs=["dT"], t_ref=T_REF)
    drift = line[:, 0] + line[:, 1] * (temp[:, None] - T_REF)
    model = fit(family="linear", inputs=["dT"], outputs=AXES, train=[(temp[:, None], drift)],
                val=None, spec=spec, hyper={}, config=TrainConfig(max_epochs=0)).model
    co = autopilot_coefficients(model, output_units=UNITS)
    want = np.zeros((6, 4))
    want[:, :2] = line
    np.testing.assert_allclose(co.coef["gyro"], want[:3] * SI[:3, None], rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(co.coef["acc"], want[3:] * SI[3:, None], rtol=1e-4, atol=1e-10)


def test_refusals(model, tmp_path):
    with pytest.raises(ExportError, match="this model is 'lorentz', which has no polynomial form"):
        export_px4_params(_model(family="lorentz"), tmp_path / "x.params", output_units=UNITS)
    with pytest.raises(ExportError, match="evaluate a cubic; this poly model has degree 4"):
        export_px4_params(_model(degree=4), tmp_path / "x.params", output_units=UNITS)
    with pytest.raises(ExportError, match=r"one input, dT or T; this model reads \['dT', 'dT2'\]"):
        export_ardupilot_params(_model(inputs=("dT", "dT2")), tmp_path / "x.param",
                                output_units=UNITS)
    with pytest.raises(ExportError, match="unit 'furlong' cannot be converted"):
        export_px4_params(model, tmp_path / "x.params", output_units={**UNITS, "acc_y": "furlong"})
    with pytest.raises(ExportError, match="'gyro_x' has unit 'mg', which is not a gyro unit"):
        export_px4_params(model, tmp_path / "x.params", output_units="mg")
    wide = _model(temp=np.linspace(-40.0, 95.0, 300))
    with pytest.raises(ExportError, match="outside ArduPilot's INS_TCAL TMIN/TMAX range"):
        export_ardupilot_params(wide, tmp_path / "x.param", output_units=UNITS)
    assert list(tmp_path.iterdir()) == []


def test_px4_baro_order5_in_pascals(tmp_path):
    """TC_B0_X0..X5 in Pa, evaluated as PX4's calc_thermal_offsets_1D (tests/oracles.py)."""
    temp = np.linspace(5.0, 55.0, 400)
    x = temp - T_REF
    coef_hpa = np.array([0.1, 0.02, -1e-3, 2e-5, 3e-7, -1e-8])         # the model is in hPa
    drift = sum(c * x ** k for k, c in enumerate(coef_hpa))[:, None]
    spec = FeatureSpec(inputs=["dT"], t_ref=T_REF)
    m = fit(family="poly", inputs=["dT"], outputs=["baro_p"], train=[(temp[:, None], drift)],
            val=None, spec=spec, hyper={"degree": 5}, config=TrainConfig(max_epochs=0)).model
    path = export_px4_params(m, tmp_path / "b.params", output_units={"baro_p": "hPa"},
                             device_id=3997706, instance=1)
    p = read_px4_params(path)
    assert p["TC_B_ENABLE"] == 1 and p["TC_B1_ID"] == 3997706 and p["TC_B1_TREF"] == T_REF
    np.testing.assert_allclose([p[f"TC_B1_X{k}"] for k in range(6)], 100.0 * coef_hpa,
                               rtol=5e-3, atol=1e-9)
    t = np.concatenate([temp, [-20.0, 90.0]])
    offs = px4_offsets(p, "TC_B1_", t, dtype=np.float32)
    np.testing.assert_allclose(offs[:400], 100.0 * drift[:, 0], atol=1e-3 * np.ptp(drift) * 100)
    assert offs[-2] == pytest.approx(offs[0]) and offs[-1] == pytest.approx(offs[399])
    with pytest.raises(ExportError, match="no barometer"):
        export_ardupilot_params(m, tmp_path / "b.parm", output_units={"baro_p": "Pa"})
