"""Feature layer: ΔT/ΔT² values, proxy features, rate from a known ramp, T_ref 'start'."""

import numpy as np
import pytest
import torch

from thermonet.core.errors import ConfigError, InputError
from thermonet.core.recording import Recording
from thermonet.features.inputs import FeatureSpec, reference_values, signal_matrix, target_matrix
from thermonet.features.module import Features
from thermonet.training.parts import build_part


def _recording(temperature, rate_hz=1.0, **kw):
    n = len(temperature)
    t = np.arange(n) / rate_hz
    outputs = kw.pop("outputs", {"gyro_x": np.zeros(n)})
    return Recording(time_s=t, temperature_c=np.asarray(temperature, float), outputs=outputs,
                     sample_rate_hz=rate_hz, **kw).validate()


def test_temperature_features_values():
    spec = FeatureSpec(inputs=["T", "dT", "dT2"], t_ref=25.0)
    assert spec.signals == ["temperature_c"]
    x = Features(spec)(torch.tensor([[-20.0], [25.0], [60.0]]))
    expected = np.array([[-20.0, -45.0, 2025.0], [25.0, 0.0, 0.0], [60.0, 35.0, 1225.0]])
    np.testing.assert_allclose(x.numpy(), expected, rtol=1e-6)


def test_proxy_features_and_signal_order():
    spec = FeatureSpec(inputs=["d_freq_hz2", "rate", "d_freq_hz", "dT"], t_ref=20.0,
                       proxy_ref={"freq_hz": 4517.0})
    assert spec.signals == ["temperature_c", "rate_c_per_min", "freq_hz"]
    s = torch.tensor([[30.0, 0.5, 4521.0]])
    x = Features(spec)(s).numpy()[0]
    # Δf = 4 Hz, Δf² = 16 Hz², rate passes through, ΔT = 10 °C
    np.testing.assert_allclose(x, [16.0, 0.5, 4.0, 10.0], rtol=1e-6)


def test_rate_from_known_ramp_in_c_per_min():
    """A first-order filtered derivative (τ = 60 s) started at rest: slope·(1 − e^(−t/τ))."""
    slope = 0.3  # °C/min = 18 °C/h, study 003's ramp
    t = np.arange(3600.0)
    rec = _recording(-20.0 + slope * t / 60.0)
    rate = signal_matrix(rec, ["rate_c_per_min"])[:, 0]
    np.testing.assert_allclose(rate, slope * (1.0 - np.exp(-t / 60.0)), rtol=1e-9, atol=1e-12)


def test_rate_smooths_noise_and_follows_a_sine():
    rng = np.random.default_rng(1)
    t = np.arange(7200.0)
    period_s, tau = 3600.0, 60.0
    w = 2 * np.pi / period_s
    temp = 20 + 10 * np.sin(w * t) + rng.normal(0, 0.01, t.size)
    rec = _recording(temp)
    rate = signal_matrix(rec, ["rate_c_per_min"])[:, 0]
    # first-order filter 1/(1 + jωτ) then d/dt: gain ω/√(1+ω²τ²), phase lag atan(ωτ)
    true = 60.0 * 10 * w / np.hypot(1.0, w * tau) * np.cos(w * t - np.arctan(w * tau))
    inner = slice(600, None)                       # after 10 τ the start-up has died out
    # amplitude 1.04 °C/min; thermometer noise 0.01 °C gives ≈ 60·0.01/τ = 0.01 °C/min
    assert np.max(np.abs(rate[inner] - true[inner])) < 0.05


def test_t_ref_start_is_mean_of_first_window():
    rng = np.random.default_rng(0)
    soak = 10.0 + rng.normal(0, 0.05, 600)          # 10 min stable at 10 °C (1 Hz)
    ramp = 10.0 + np.arange(1, 1801) * 0.3 / 60.0   # then +0.3 °C/min
    rec = _recording(np.concatenate([soak, ramp]),
                     proxies={"freq_hz": 4517.0 + 0.4 * (np.concatenate([soak, ramp]) - 10.0)})
    t_ref, proxy_ref = reference_values([rec], ["dT", "dT2", "d_freq_hz"], t_ref="start",
                                        window_min=10.0)
    window = np.concatenate([soak, ramp])[:601]       # samples with t - t0 <= 600 s
    assert t_ref == pytest.approx(window.mean(), abs=1e-12)
    assert t_ref == pytest.approx(10.0, abs=0.02)
    assert proxy_ref["freq_hz"] == pytest.approx(4517.0 + 0.4 * (window.mean() - 10.0), abs=1e-9)
    # a given value is taken as is; no relative input -> no t_ref
    assert reference_values(rec, ["dT"], t_ref=25.0) == (25.0, {})
    assert reference_values(rec, ["T", "rate"]) == (None, {})
    spec = FeatureSpec.from_recordings(["dT"], [rec])
    assert spec.t_ref == pytest.approx(t_ref)


def test_target_matrix_is_output_minus_reference():
    n = 50
    temp = np.linspace(0, 10, n)
    rec = _recording(temp, outputs={"gyro_x": 5.0 + temp, "gyro_y": 2 * temp},
                     references={"ref_gyro_x": np.full(n, 5.0)})
    y = target_matrix(rec, ["gyro_x", "gyro_y"])
    np.testing.assert_allclose(y, np.stack([temp, 2 * temp], 1))
    part = build_part(rec, signals=FeatureSpec(inputs=["dT"], t_ref=0.0).signals,
                      outputs=["gyro_y"], target="drift")
    np.testing.assert_allclose(part.signals[:, 0], temp)
    np.testing.assert_allclose(part.target[:, 0], 2 * temp)


def test_errors_name_the_offending_item():
    with pytest.raises(ConfigError, match="'dTT'"):
        FeatureSpec(inputs=["dTT"])
    with pytest.raises(ConfigError, match="t_ref"):
        Features(FeatureSpec(inputs=["dT"]))
    rec = _recording(np.linspace(0, 10, 20))
    with pytest.raises(InputError, match="column 'freq_hz'"):
        signal_matrix(rec, ["freq_hz"])
    with pytest.raises(InputError, match="column 'acc_z'"):
        target_matrix(rec, ["acc_z"])


def test_rate_restarts_after_a_gap():
    """A ramp cut into blocks (as a held-out split does): the state restarts after each gap
    (rate 0, then the ramp's slope·(1 − e^(−t/τ)) again); the 7 °C step across the gap is
    never differentiated."""
    from thermonet.features.inputs import contiguous_segments

    t = np.arange(0.0, 3600.0, 1.0)
    temp = 20.0 + 0.5 * t / 60.0                      # 0.5 °C/min
    keep = (t < 1000) | ((t >= 1500) & (t < 2500)) | (t >= 3000)
    rec = Recording(time_s=t[keep], temperature_c=temp[keep] + 7.0 * (t[keep] >= 1500),
                    outputs={"gyro_x": np.zeros(keep.sum())}, sample_rate_hz=1.0)
    assert [(s.start, s.stop) for s in contiguous_segments(rec.time_s)] == \
        [(0, 1000), (1000, 2000), (2000, 2600)]
    rate = signal_matrix(rec, ["rate_c_per_min"])[:, 0]
    start = np.select([rec.time_s >= 3000, rec.time_s >= 1500], [3000.0, 1500.0], 0.0)
    np.testing.assert_allclose(rate, 0.5 * (1 - np.exp(-(rec.time_s - start) / 60.0)),
                               rtol=1e-9, atol=1e-12)


def test_rate_is_causal_no_look_ahead():
    """A ramp starting at t = 150 s: no rate before it starts, then 1 − e^(−(t−150)/τ)."""
    t = np.arange(0.0, 600.0, 1.0)
    temp = 20.0 + np.clip(t - 150.0, 0.0, None) / 60.0          # 1 °C/min from t = 150 s
    rec = Recording(time_s=t, temperature_c=temp, outputs={"gyro_x": np.zeros(t.size)},
                    sample_rate_hz=1.0)
    rate = signal_matrix(rec, ["rate_c_per_min"])[:, 0]
    np.testing.assert_allclose(rate[:151], 0.0, atol=1e-12)
    np.testing.assert_allclose(rate[150:], 1 - np.exp(-(t[150:] - 150.0) / 60.0), rtol=1e-9)
