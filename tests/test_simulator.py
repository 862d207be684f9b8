"""Simulator physics: reproducibility, each part switched on/off, noise recovered."""

import allantools
import numpy as np
import pytest

from thermonet.core.errors import ConfigError
from thermonet.scoring.metrics import noise_floor
from thermonet.sim import (
    AxisConfig,
    ChamberProfile,
    HysteresisConfig,
    NoiseConfig,
    Polynomial,
    Ramp,
    RateTermConfig,
    SelfHeatingConfig,
    SimConfig,
    Soak,
    Switches,
    ThermalConfig,
    ThermometerConfig,
    UnitSpreadConfig,
    cycle,
    get_preset,
    simulate,
    simulate_run,
)
from thermonet.sim.device import first_order_lag, flicker_noise, play_operator, white_noise

RAMP = ChamberProfile(name="ramp", start_c=0.0, segments=(
    Soak(temperature_c=0.0, duration_h=0.5), Ramp(to_c=40.0, rate_c_per_h=20.0),
    Soak(temperature_c=40.0, duration_h=0.5)))


def _cfg(**kw):
    base = dict(name="t", sample_rate_hz=1.0, procedures=(RAMP,),
                axes=(AxisConfig(name="gyro_x", unit="deg/s",
                                 bias=Polynomial(coefficients=(0.0, 0.01), reference_c=0.0),
                                 noise=NoiseConfig(white_density=0.02)),),
                thermal=ThermalConfig(die_lag_s=300.0, case_lag_s=600.0),
                thermometer=ThermometerConfig(lag_s=120.0, resolution_c=0.1))
    base.update(kw)
    return SimConfig(**base)


def test_same_seed_identical_different_seed_different_noise():
    a = simulate("patent-gyro", runs=2, seed=7)
    b = simulate("patent-gyro", runs=2, seed=7)
    c = simulate("patent-gyro", runs=2, seed=8)
    for ra, rb, rc in zip(a, b, c, strict=True):   # same seed, same computation: exact
        np.testing.assert_array_equal(ra.outputs["gyro_x"], rb.outputs["gyro_x"])
        np.testing.assert_array_equal(ra.temperature_c, rb.temperature_c)
        assert not np.array_equal(ra.outputs["gyro_x"], rc.outputs["gyro_x"])
    # runs of one dataset are different draws
    assert not np.array_equal(a[0].outputs["gyro_x"] - a[0].drift["drift_gyro_x"],
                              a[1].outputs["gyro_x"] - a[1].drift["drift_gyro_x"])


def test_output_is_reference_plus_drift_plus_noise_only():
    rec = simulate("accel", runs=1, white_noise=False, flicker_noise=False,
                   random_walk_noise=False)[0]
    np.testing.assert_allclose(rec.outputs["acc_x"],
                               rec.references["ref_acc_x"] + rec.drift["drift_acc_x"], atol=1e-15)


def test_lag_delays_die_temperature_by_tau_on_a_ramp():
    _, truth = simulate_run(_cfg(), 0)
    t = np.arange(truth.die_c.size)
    mid = (truth.chamber_c > 10) & (truth.chamber_c < 30)
    # on a 20 °C/h ramp a lag of τ = 300 s trails by 20·300/3600 °C
    lag_c = np.mean(truth.chamber_c[mid] - truth.die_c[mid])
    assert lag_c == pytest.approx(20.0 * 300.0 / 3600.0, rel=0.01)
    _, off = simulate_run(_cfg(switches=Switches(thermal_lag=False)), 0)
    np.testing.assert_allclose(off.die_c, off.chamber_c)
    assert t.size == 3 * 3600 + 1


def test_first_order_lag_step_response():
    x = np.r_[np.zeros(10), np.ones(2000)]
    y = first_order_lag(x, 100.0, 1.0)
    # 63 % of a step after τ (step spread over one sample by the first-order hold)
    assert y[9 + 100] == pytest.approx(1 - np.exp(-1), abs=0.01)


def test_thermometer_quantisation_and_lag():
    rec, truth = simulate_run(_cfg(), 0)
    steps = np.unique(np.round(rec.temperature_c / 0.1, 6))
    np.testing.assert_allclose(steps, np.round(steps))  # multiples of 0.1 °C
    rec2, _ = simulate_run(_cfg(switches=Switches(thermometer_quantisation=False)), 0)
    assert np.unique(rec2.temperature_c).size > 5 * steps.size
    mid = (truth.chamber_c > 10) & (truth.chamber_c < 30)
    # thermometer trails case (600 s) + its own lag (120 s) → 720 s on the ramp
    trail = np.mean(truth.chamber_c[mid] - rec2.temperature_c[mid])
    assert trail == pytest.approx(20.0 * 720.0 / 3600.0, rel=0.02)


def test_white_noise_sigma_and_allan_slope():
    x = white_noise(50_000, 1.0, 0.05, np.random.default_rng(1))
    assert noise_floor(x) == pytest.approx(0.05, rel=0.02)
    taus, adev, _, _ = allantools.oadev(x, rate=1.0, data_type="freq",
                                        taus=np.array([1, 2, 4, 8, 16, 32, 64]))
    slope = np.polyfit(np.log10(taus), np.log10(adev), 1)[0]
    assert slope == pytest.approx(-0.5, abs=0.05)
    assert adev[0] == pytest.approx(0.05, rel=0.03)


def test_flicker_floor_is_0664_b_and_recovered_from_simulated_output():
    floors = []
    for s in range(4):
        x = flicker_noise(40_000, 1.0, 0.01, np.random.default_rng(s))
        _, adev, _, _ = allantools.oadev(x, rate=1.0, data_type="freq",
                                         taus=np.array([4, 16, 64, 256]))
        floors.append(adev.mean())
    assert np.mean(floors) == pytest.approx(0.664 * 0.01, rel=0.1)
    rec = simulate("mems-gyro", runs=1, flicker_noise=False, random_walk_noise=False)[0]
    noise = rec.outputs["gyro_x"] - rec.drift["drift_gyro_x"]
    assert noise_floor(noise) == pytest.approx(0.07, rel=0.03)


def test_rate_random_walk_allan_slope_plus_half():
    cfg = NoiseConfig(rate_random_walk=1e-3)
    from thermonet.sim.device import sensor_noise
    x = sensor_noise(cfg, 100_000, 1.0, np.random.default_rng(2))
    taus, adev, _, _ = allantools.oadev(x, rate=1.0, data_type="freq",
                                        taus=np.array([16, 32, 64, 128, 256, 512]))
    assert np.polyfit(np.log10(taus), np.log10(adev), 1)[0] == pytest.approx(0.5, abs=0.1)
    assert adev[2] == pytest.approx(1e-3 * np.sqrt(64 / 3), rel=0.2)


def test_hysteresis_separates_heating_and_cooling():
    prof = ChamberProfile(name="cycle", start_c=0.0, segments=cycle(
        0.0, 40.0, rate_c_per_h=20.0, soak_h=0.5, cycles=1))
    ax = AxisConfig(name="gyro_x", hysteresis=HysteresisConfig(amplitude=0.01, width_c=1.0))
    cfg = _cfg(procedures=(prof,), axes=(ax,))
    rec, truth = simulate_run(cfg, 0)
    d = rec.drift["drift_gyro_x"]
    heating = np.gradient(truth.die_c) > 0.003
    cooling = np.gradient(truth.die_c) < -0.003
    assert d[heating].mean() == pytest.approx(0.01, rel=0.05)
    assert d[cooling].mean() == pytest.approx(-0.01, rel=0.05)
    off = simulate(cfg, hysteresis=False)[0]
    np.testing.assert_allclose(off.drift["drift_gyro_x"], 0.0)
    assert play_operator(np.array([0.0, 5.0, 5.0, 2.0]), 2.0).tolist() == [0.0, 1.0, 1.0, -1.0]


def test_rate_term_follows_temperature_rate():
    ax = AxisConfig(name="gyro_x", rate_term=RateTermConfig(coefficient_per_c_per_h=1e-3))
    cfg = _cfg(axes=(ax,))
    rec, truth = simulate_run(cfg, 0)
    mid = (truth.chamber_c > 10) & (truth.chamber_c < 30)
    assert rec.drift["drift_gyro_x"][mid].mean() == pytest.approx(20.0 * 1e-3, rel=0.01)
    assert np.abs(simulate(cfg, rate_term=False)[0].drift["drift_gyro_x"]).max() == 0.0


def test_scale_factor_term_scales_with_reference():
    on = simulate("patent-gyro", runs=1, seed=0)[0]
    off = simulate("patent-gyro", runs=1, seed=0, scale_factor=False)[0]
    diff = on.drift["drift_gyro_x"] - off.drift["drift_gyro_x"]
    dt = on.temperature_c - (-20.0)
    rate = on.references["ref_gyro_x"]
    # 0.3 ppm/°C · ΔT · rate (the unit's scale gain is within a few % of 1 and ΔT is the die's)
    end = slice(-600, None)
    assert diff[end].mean() == pytest.approx(0.3e-6 * 70.0 * rate[0], rel=0.05)
    assert np.all(dt[end] > 69)


def test_unit_spread_changes_law_per_run_and_switch_removes_it():
    ds = simulate("accel", runs=2, seed=0)
    d0, d1 = ds[0].drift["drift_acc_x"], ds[1].drift["drift_acc_x"]
    assert 1e-4 < np.abs(d0 - d1).max() < 5e-3
    ds_off = simulate("accel", runs=2, seed=0, unit_spread=False, white_noise=False,
                      flicker_noise=False)
    np.testing.assert_allclose(ds_off[0].drift["drift_acc_x"], ds_off[1].drift["drift_acc_x"])


def test_self_heating_raises_die_temperature():
    cfg = _cfg(self_heating=SelfHeatingConfig(rise_c=5.0, tau_s=600.0))
    _, on = simulate_run(cfg, 0)
    _, off = simulate_run(_cfg(switches=Switches(self_heating=False),
                               self_heating=cfg.self_heating), 0)
    assert (on.die_c - off.die_c)[-1] == pytest.approx(5.0, rel=1e-3)
    assert (on.die_c - off.die_c)[600] == pytest.approx(5.0 * (1 - np.exp(-1)), rel=1e-3)


def test_unknown_preset_and_setting_are_named():
    with pytest.raises(ValueError, match="valid: accel, accel-ramp, consumer-imu, hrg, imu-multiposition, mems-gyro,"
                       " patent-gyro"):
        simulate("gyro9000")
    with pytest.raises(ConfigError, match="unknown simulation setting 'hysterisis'"):
        simulate("accel", hysterisis=False)
    with pytest.raises(ConfigError, match="thermal__nope"):
        simulate("accel", thermal__nope=1.0)
    ds = simulate("hrg", runs=1, thermal__die_lag_s=0.0, sample_rate_hz=0.05)
    assert ds[0].sample_rate_hz == 0.05
    assert get_preset("HRG").name == "hrg"


def test_unit_spread_bias_offset_recorded_in_meta():
    cfg = _cfg(unit_spread=UnitSpreadConfig(bias_offset=0.1))
    rec, _ = simulate_run(cfg, 0, seed=5)
    off = float(rec.meta["unit_bias_offset"])
    # the law 0.01·T is 0 at the 0 °C start, so the first drift sample is the offset
    assert rec.drift["drift_gyro_x"][0] == pytest.approx(off, abs=1e-6)
    assert abs(off) > 1e-4
