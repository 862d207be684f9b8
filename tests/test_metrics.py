"""Metrics against independent expectations: identities, known coefficients, known noise."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from thermonet.scoring.axis_metrics import AXIS_METRIC_KEYS, axis_metrics
from thermonet.scoring.metrics import (
    IEEE952_FLICKER_FACTOR,
    MIN_ALLAN_SAMPLES,
    allan,
    bias_instability,
    bias_instability_detail,
    binned_means,
    binned_peak_to_peak,
    drift_error_rms,
    msd,
    noise_floor,
    rms,
    scale_factor_tempco_ppm_per_c,
)

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics


def _flicker(rng: np.random.Generator, n: int) -> np.ndarray:
    """Unit-variance 1/f noise by spectral shaping of white noise."""
    spec = np.fft.rfft(rng.normal(size=n))
    f = np.fft.rfftfreq(n)
    f[0] = f[1]
    y = np.fft.irfft(spec / np.sqrt(f), n)
    return (y - y.mean()) / y.std()


def test_rms_removes_offset_msd_keeps_it():
    rng = np.random.default_rng(1)
    e = 0.3 + 0.05 * rng.normal(size=10_000)
    ref = np.linspace(-1.0, 1.0, e.size)
    x = ref + e
    # Identity msd = rms² + mean², computed independently of the metrics module.
    expected = np.var(e) + np.mean(e) ** 2
    assert msd(x, ref) == pytest.approx(expected, rel=1e-12)
    assert msd(x, ref) == pytest.approx(rms(e) ** 2 + 0.3 ** 2, rel=0.02)
    assert rms(e + 100.0) == pytest.approx(0.05, rel=0.03)
    assert drift_error_rms(ref + 0.2, ref) == pytest.approx(0.2, rel=1e-12)
    assert math.isnan(rms(np.array([])))


def test_msd_refuses_mismatched_lengths():
    with pytest.raises(ValueError, match="'x_ref' has 3 samples"):
        msd(np.zeros(4), np.zeros(3))


def test_binned_peak_to_peak_recovers_a_step():
    rng = np.random.default_rng(2)
    t = np.linspace(-20.0, 59.99, 40_000)
    step_mg = 7.0
    y = np.where(t >= 20.0, step_mg, 0.0) + 0.5 * rng.normal(size=t.size)
    centres, means = binned_means(t, y, 1.0)
    assert centres[0] == pytest.approx(-19.5)
    assert centres.size == 80
    # 500 samples per bin: the means scatter by 0.5/sqrt(500) ≈ 0.022 mg.
    assert binned_peak_to_peak(t, y) == pytest.approx(step_mg, abs=0.15)


def test_binned_means_refuses_bad_width_and_nan_temperature():
    with pytest.raises(ValueError, match="bin width"):
        binned_means(np.arange(5.0), np.arange(5.0), 0.0)
    t = np.arange(5.0)
    t[3] = np.nan
    with pytest.raises(ValueError, match="'temperature_c'.*index 3"):
        binned_means(t, np.arange(5.0))


def test_scale_factor_tempco_recovers_150_ppm_per_c():
    t = np.arange(-20.0, 60.0 + 1e-9, 10.0)  # study 000's points, every 10 °C
    k0, t0 = 1.2345, 25.0
    k = k0 * (1.0 + 150e-6 * (t - t0))
    assert scale_factor_tempco_ppm_per_c(t, k) == pytest.approx(150.0, rel=0.01)
    # An inverted axis (negative K) has the same coefficient.
    assert scale_factor_tempco_ppm_per_c(t, -k) == pytest.approx(150.0, rel=0.01)
    # Study 000's raw figure: a 151.6 ppm/°C device over −20…60 °C.
    k_paper = 1.0 + 151.6e-6 * (t - 20.0)
    assert scale_factor_tempco_ppm_per_c(t, k_paper) == pytest.approx(151.6, rel=1e-9)


def test_scale_factor_tempco_refuses_degenerate_input():
    with pytest.raises(ValueError, match="span is zero"):
        scale_factor_tempco_ppm_per_c(np.full(3, 25.0), np.ones(3))
    with pytest.raises(ValueError, match="at least 2"):
        scale_factor_tempco_ppm_per_c(np.array([25.0]), np.ones(1))
    with pytest.raises(ValueError, match="mean scale factor"):
        scale_factor_tempco_ppm_per_c(np.array([0.0, 10.0]), np.array([-1.0, 1.0]))


def test_white_noise_floor_and_allan_slope():
    rng = np.random.default_rng(3)
    sigma, rate_hz = 0.02, 50.0
    y = 5.0 + sigma * rng.normal(size=100_000) + np.linspace(0.0, 0.5, 100_000)
    assert noise_floor(y) == pytest.approx(sigma, rel=0.03)
    taus, adev = allan(y - np.linspace(0.0, 0.5, y.size), rate_hz)
    assert taus[0] == pytest.approx(1.0 / rate_hz)
    # Long taus have few independent clusters and scatter beyond 10 %.
    usable = taus * rate_hz <= y.size / 256
    assert usable.sum() >= 8
    expected = sigma / np.sqrt(taus[usable] * rate_hz)
    np.testing.assert_allclose(adev[usable], expected, rtol=0.10)
    slope = np.polyfit(np.log(taus[usable]), np.log(adev[usable]), 1)[0]
    assert slope == pytest.approx(-0.5, abs=0.05)


def test_allan_short_series_and_bad_rate():
    taus, adev = allan(np.array([1.0, 2.0]), 10.0)
    assert taus.size == 0 and adev.size == 0
    with pytest.raises(ValueError, match="rate_hz"):
        allan(np.ones(100), 0.0)


def test_bias_instability_white_plus_random_walk_matches_theory():
    # ADEV² = σ²/(τ f) + K²τ/3: minimum where both terms are equal,
    # τ* = sqrt(3σ²/(f K²)), σ_min = sqrt(2 K² τ*/3).
    rng = np.random.default_rng(4)
    sigma, rate_hz, tau_star = 1.0, 10.0, 10.0
    k_rw = math.sqrt(3 * sigma**2 / (rate_hz * tau_star**2))
    n = 400_000
    y = sigma * rng.normal(size=n) + np.cumsum(k_rw / math.sqrt(rate_hz) * rng.normal(size=n))
    expected = math.sqrt(2 * k_rw**2 * tau_star / 3)
    detail = bias_instability_detail(y, rate_hz)
    assert detail["bias_instability_adev_min"] == pytest.approx(expected, rel=0.15)
    assert 3.0 < detail["tau_at_min_s"] < 30.0
    assert detail["reason"] == ""


def test_bias_instability_flicker_random_walk_mixture_is_finite_positive():
    rng = np.random.default_rng(5)
    n, rate_hz = 100_000, 20.0
    y = 0.01 * rng.normal(size=n) + 0.002 * _flicker(rng, n) \
        + np.cumsum(2e-5 * rng.normal(size=n))
    bi = bias_instability(y, rate_hz)
    assert math.isfinite(bi) and bi > 0
    # White noise dominates short taus and random walk long ones, so the floor
    # lies strictly inside the curve, below the one-sample deviation.
    detail = bias_instability_detail(y, rate_hz)
    assert detail["reason"] == ""
    assert 1.0 < detail["tau_at_min_s"] < 500.0
    assert bi < 0.2 * allan(y, rate_hz)[1][0]
    assert IEEE952_FLICKER_FACTOR == pytest.approx(0.664, abs=1e-3)


def test_pure_flicker_gives_a_flat_allan_curve():
    rng = np.random.default_rng(8)
    n, rate_hz = 100_000, 20.0
    y = _flicker(rng, n)
    taus, adev = allan(y, rate_hz)
    mid = (taus * rate_hz >= 4) & (taus * rate_hz <= n / 64)
    slope = np.polyfit(np.log(taus[mid]), np.log(adev[mid]), 1)[0]
    assert abs(slope) < 0.1  # flicker: σ(τ) independent of τ
    # The floor is the flat level, read low only by the scatter of the estimates.
    assert bias_instability(y, rate_hz) == pytest.approx(np.median(adev[mid]), rel=0.3)


def test_bias_instability_short_gappy_and_monotone_series():
    short = bias_instability_detail(np.ones(MIN_ALLAN_SAMPLES - 1), 1.0)
    assert math.isnan(short["bias_instability_adev_min"])
    assert "samples" in short["reason"]
    assert math.isnan(bias_instability(np.arange(5.0), 1.0))
    # Non-finite samples (a gap written as NaN) are dropped and counted.
    rng = np.random.default_rng(6)
    y = rng.normal(size=5000)
    y[1000:1200] = np.nan
    detail = bias_instability_detail(y, 1.0)
    assert detail["n_dropped_nonfinite"] == 200
    assert detail["n_samples"] == 4800
    # Pure white noise never turns up: the value is flagged as an upper bound
    # and equals σ/sqrt(m_max) for m_max = n/8 = 600 samples.
    assert "upper bound" in detail["reason"]
    assert detail["bias_instability_adev_min"] == pytest.approx(1 / math.sqrt(600), rel=0.3)


def _axis_data(n: int = 20_000, rate_hz: float = 10.0, noise: float = 0.01):
    rng = np.random.default_rng(7)
    time_s = np.arange(n) / rate_hz
    # Stops short of 60 °C so the last 1 °C bin is as full as the others.
    temperature_c = -20.0 + 80.0 * np.arange(n) / n
    true_drift = 0.002 * (temperature_c - 25.0) + 1e-4 * (temperature_c - 25.0) ** 2
    reference = np.where(np.arange(n) % 5000 < 2500, 0.0, 10.0)  # turntable steps
    raw = reference + true_drift + noise * rng.normal(size=n)
    return time_s, temperature_c, true_drift, reference, raw


def test_axis_metrics_perfect_model():
    noise = 0.01
    time_s, temp, drift, ref, raw = _axis_data(noise=noise)
    m = axis_metrics(bin_by=temp, time_s=time_s, raw=raw, reference=ref,
                     predicted_drift=drift, true_drift=drift)
    assert set(m) == set(AXIS_METRIC_KEYS) | {"drift_error_rms"}
    assert all(type(v) is float for v in m.values())
    assert m["rms_comp"] == pytest.approx(noise, rel=0.03)
    assert m["noise_floor"] == pytest.approx(noise, rel=0.03)
    assert m["drift_error_rms"] == pytest.approx(0.0, abs=1e-15)
    assert m["msd_comp"] == pytest.approx(noise**2, rel=0.05)
    # The raw error's bin means are the true drift's, up to noise/sqrt(250).
    pp_true = np.ptp(binned_means(temp, drift)[1])
    assert m["pp_raw"] == pytest.approx(pp_true, abs=5 * noise / math.sqrt(250))
    # 250 samples per bin: pp of pure-noise bin means is a few σ/sqrt(250).
    assert m["pp_comp"] < 8 * noise / math.sqrt(250)
    assert m["msd_raw"] == pytest.approx(np.mean(drift**2) + noise**2, rel=0.02)
    # After compensation only white noise remains: the floor is below the raw one.
    assert m["bias_instability_comp"] < m["bias_instability_raw"]
    json.dumps(m)


def test_axis_metrics_constant_offset_model_and_rate_inference():
    time_s, temp, drift, ref, raw = _axis_data()
    offset = 0.05
    m = axis_metrics(bin_by=temp, time_s=time_s, raw=raw, reference=ref,
                     predicted_drift=drift + offset, true_drift=drift, rate_hz=10.0)
    assert "drift_error_rms" in m and m["drift_error_rms"] == pytest.approx(offset)
    # rms ignores the offset, msd counts it: msd = rms² + offset².
    assert m["msd_comp"] == pytest.approx(m["rms_comp"] ** 2 + offset**2, rel=0.01)
    inferred = axis_metrics(bin_by=temp, time_s=time_s, raw=raw, reference=ref,
                            predicted_drift=drift + offset)
    assert "drift_error_rms" not in inferred
    assert inferred["bias_instability_raw"] == pytest.approx(m["bias_instability_raw"], rel=1e-9)


def test_axis_metrics_names_the_bad_argument():
    time_s, temp, drift, ref, raw = _axis_data(n=200)
    bad = drift.copy()
    bad[17] = np.nan
    with pytest.raises(ValueError, match="'predicted_drift'.*index 17"):
        axis_metrics(bin_by=temp, time_s=time_s, raw=raw, reference=ref, predicted_drift=bad)
    with pytest.raises(ValueError, match="'reference' has 199 samples"):
        axis_metrics(bin_by=temp, time_s=time_s, raw=raw, reference=ref[:-1],
                     predicted_drift=drift)
    backwards = time_s.copy()
    backwards[50] = 0.0
    with pytest.raises(ValueError, match="'time_s' decreases at index 50"):
        axis_metrics(bin_by=temp, time_s=backwards, raw=raw, reference=ref,
                     predicted_drift=drift)
