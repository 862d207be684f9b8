"""Each preset reproduces its study's magnitudes within 10 %, computed independently here."""


import numpy as np
import pytest
from scipy.optimize import curve_fit

from thermonet.scoring.metrics import scale_factor_tempco_ppm_per_c
from thermonet.sim import PRESETS, four_position_estimates, simulate


def _lorentz(t, y0, a, xc, w):
    return y0 + 2 * a / np.pi * w / (4 * (t - xc) ** 2 + w ** 2)


def _best_lorentz_residual_pp(t, y):
    best = np.inf
    for xc0 in (-40.0, 0.0, 50.0, 70.0, 100.0):
        for w0 in (20.0, 40.0, 80.0):
            for sign in (1.0, -1.0):
                try:
                    p, _ = curve_fit(_lorentz, t, y, p0=[y.mean(), sign * np.ptp(y) * w0, xc0, w0],
                                     maxfev=5000)
                except RuntimeError:  # that start did not converge; others will
                    continue
                r = y - _lorentz(t, *p)
                if np.sum(r ** 2) < best:
                    best, best_pp = np.sum(r ** 2), np.ptp(r)
    return best_pp


def _within(value, target, rel=0.10):
    return abs(value - target) <= rel * abs(target)


def test_accel_bias_and_scale_factor_match_study_000():
    ds = simulate("accel", seed=0)
    assert len(ds) == 3
    for rec in ds:
        est = np.asarray(four_position_estimates(rec))
        temp, k0_mg, k1 = est[:, 0], est[:, 1] * 1e3, est[:, 2]
        np.testing.assert_allclose(temp, np.arange(-20, 61, 10), atol=0.1)
        assert _within(np.ptp(k0_mg), 14.0)
        lin = k0_mg - np.polyval(np.polyfit(temp, k0_mg, 1), temp)
        assert _within(np.ptp(lin), 6.91)
        assert _within(_best_lorentz_residual_pp(temp, k0_mg), 1.3)
        assert _within(np.polyfit(temp, k0_mg, 1)[0], -0.153)  # mg/°C, the paper's slope
        dk = np.ptp(k1) / k1.mean() * 1e6 / np.ptp(temp)
        assert _within(dk, 151.6)
        assert dk == pytest.approx(scale_factor_tempco_ppm_per_c(temp, k1))  # the one ΔK
        k1_lin = k1 - np.polyval(np.polyfit(temp, k1, 1), temp) + k1.mean()
        assert _within(np.ptp(k1_lin) / k1_lin.mean() * 1e6 / 80.0, 45.89)


def _soak_means(rec, x, y, tol_c_per_h=0.5):
    """Means of y over the settled second half of every stretch where x is steady."""
    dt = rec.time_s[1] - rec.time_s[0]
    rate = np.abs(np.gradient(x, dt)) * 3600
    steady = np.r_[0, (rate < tol_c_per_h).astype(int), 0]
    d = np.diff(steady)
    means = []
    for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=False):
        if (b - a) * dt >= 1800:
            mid = (a + b) // 2
            means.append((x[mid:b].mean(), y[mid:b].mean()))
    return np.asarray(means)


def test_hrg_bias_30_deg_per_h_and_frequency_proxy_match_study_001():
    ds = simulate("hrg", seed=0)
    rec = ds["run0"]
    f = rec.proxies["freq_hz"]
    temp_from_f = 25.0 + (f - 4517.0) / 0.4
    soaks = _soak_means(rec, temp_from_f, rec.drift_observed("gyro_x"))
    np.testing.assert_allclose(soaks[:, 0], [-10, 5, 25, 45, 60], atol=0.3)
    assert _within(np.ptp(soaks[:, 1]), 30.0)
    # 28 Hz over −10…60 °C
    assert _within(np.ptp(f), 28.0)
    # frequency quantised to 0.03 Hz
    steps = np.unique(np.round(np.abs(np.diff(f)), 6))
    assert steps[steps > 0].min() == pytest.approx(0.03, abs=1e-6)
    # a quadratic in Δf leaves ≈2.8 °/h (the paper's compensated drift)
    df = soaks[:, 0] * 0.4
    resid = soaks[:, 1] - np.polyval(np.polyfit(df, soaks[:, 1], 2), df)
    assert _within(np.ptp(resid), 2.8, rel=0.2)


def test_hrg_frequency_tracks_resonator_better_than_thermometer():
    rec = simulate("hrg", seed=1)["run1"]
    from thermonet.sim import get_preset, simulate_run
    _, truth = simulate_run(get_preset("hrg"), 1, seed=1)
    t_f = 25.0 + (rec.proxies["freq_hz"] - 4517.0) / 0.4
    err_f = np.sqrt(np.mean((t_f - truth.die_c) ** 2))
    err_th = np.sqrt(np.mean((rec.temperature_c - truth.die_c) ** 2))
    assert err_f < 0.05 < 0.3 < err_th


def test_mems_gyro_offset_at_65c_and_allan_stability_match_study_002():
    ds = simulate("mems-gyro", seed=0)
    assert [r.meta["procedure"] for r in ds][:2] == ["soaks 25/45/50/55/65/70 C",
                                                    "self-heating closed box 25 -> 45 C"]
    rec = ds["run0"]
    soaks = _soak_means(rec, rec.temperature_c, rec.drift["drift_gyro_x"], tol_c_per_h=0.5)
    by_t = dict(zip(np.round(soaks[:, 0]), soaks[:, 1], strict=True))
    t65 = min(by_t, key=lambda k: abs(k - 65))
    t25 = min(by_t, key=lambda k: abs(k - 25))
    assert _within(by_t[t65] - by_t[t25], 0.025)
    # self-heating: 25 → 45 °C over 2 h
    heat = ds["run1"]
    assert heat.duration_s == pytest.approx(7200.0)
    assert heat.temperature_c[0] == pytest.approx(25.0, abs=0.2)
    assert _within(heat.temperature_c[-1] - heat.temperature_c[0], 20.0)


def test_mems_gyro_allan_bias_stability():
    import allantools

    from thermonet.sim.device import sensor_noise
    noise = PRESETS["mems-gyro"].axes[0].noise
    mins = []
    for s in range(4):
        x = sensor_noise(noise, 20_000, 1.0, np.random.default_rng(s))
        taus, adev, _, _ = allantools.oadev(x, rate=1.0, data_type="freq",
                                            taus=np.array([1, 2, 4, 8, 16, 32, 64, 128, 256,
                                                           512, 1024]))
        mins.append(adev.min())
    assert _within(np.mean(mins), 0.0075)
    # white part: ARW 4.2 °/√h → 0.07 °/s per 1 Hz sample
    assert _within(adev[0], 0.07)


def test_patent_gyro_drift_is_100x_white_noise_and_msd_improves_1e4():
    ds = simulate("patent-gyro", seed=0)
    assert len(ds) == 5 and ds.axes == ["gyro_x", "gyro_y", "gyro_z"]
    ratios = []
    for rec in ds:
        assert rec.temperature_c[0] == pytest.approx(-20.0, abs=0.05)
        assert rec.temperature_c.max() == pytest.approx(50.0, abs=0.1)
        for ax in ds.axes:
            err = rec.outputs[ax] - rec.references[f"ref_{ax}"]
            msd_raw = np.mean(err ** 2)
            msd_ideal = np.mean((err - rec.drift[f"drift_{ax}"]) ** 2)
            ratios.append(msd_raw / msd_ideal)
    assert 3.6 <= np.log10(np.median(ratios)) <= 4.4
    # 18 °C/h ramp
    rec = ds["run0"]
    ramp = (rec.temperature_c > -10) & (rec.temperature_c < 40)
    slope = np.polyfit(rec.time_s[ramp], rec.temperature_c[ramp], 1)[0] * 3600
    assert _within(slope, 18.0, rel=0.02)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_simulates_and_validates(name):
    # (how long a preset takes is measured in experiments/, not asserted here)
    ds = simulate(name, seed=3)
    ds.validate()
    assert ds.device_id == name and ds.meta["preset"] == name
    for rec in ds:
        assert rec.meta["seed"] == "3"
        for ax in rec.outputs:
            assert f"drift_{ax}" in rec.drift
            assert rec.units[ax] == rec.units[f"drift_{ax}"]


def test_consumer_imu_climate_cycle_gravity_hysteresis_and_a_drift_free_axis():
    ds = simulate("consumer-imu", seed=0)
    assert len(ds) == 2
    r0, r1 = ds["run0"], ds["run1"]
    assert sorted(r0.outputs) == ["acc_x", "acc_y", "acc_z", "gyro_x", "gyro_y", "gyro_z"]
    assert r0.references == {}                       # no reference channel
    temp = r0.temperature_c
    # 50 → −20 → 75 → 35 °C at 1 °C/min
    assert temp[0] == pytest.approx(50.0, abs=0.5) and temp[-1] == pytest.approx(35.0, abs=0.5)
    assert temp.min() == pytest.approx(-20.0, abs=0.5) and temp.max() == pytest.approx(75.0, abs=0.5)
    ramp = np.abs(np.gradient(temp, r0.time_s))[(temp > 0) & (temp < 30)] * 60
    assert np.median(ramp) == pytest.approx(1.0, rel=0.1)
    # gravity on z, a small tilt on x and y (m/s²), kept in the raw output
    assert r0.outputs["acc_z"].mean() == pytest.approx(-9.80665, abs=0.15)
    assert 0.05 < abs(r0.outputs["acc_x"].mean()) < 0.3
    # consumer noise: 0.007 °/s and 160 µg per 1 Hz sample
    white = lambda y: np.std(np.diff(y)) / np.sqrt(2)  # noqa: E731
    assert white(r0.outputs["gyro_z"]) == pytest.approx(0.007, rel=0.1)
    assert white(r0.outputs["acc_x"]) == pytest.approx(160e-6 * 9.80665, rel=0.1)
    # gyro_z: no temperature drift, only a turn-on bias that differs per run
    d0, d1 = r0.drift["drift_gyro_z"], r1.drift["drift_gyro_z"]
    assert np.ptp(d0) == 0.0 and np.ptp(d1) == 0.0 and d0[0] != d1[0]
    # thermal history: a cubic in T fitted before the last cooling branch (which follows the
    # hotter 75 °C excursion) is worse than raw on gyro_x there, better on gyro_y
    last = np.flatnonzero(temp > 74.5)[-1]
    for axis, worse in (("gyro_x", True), ("gyro_y", False)):
        y = r0.outputs[axis]
        c = np.polyfit(temp[:last] - 25.0, y[:last], 3)
        ratio = np.std(y[last:] - np.polyval(c, temp[last:] - 25.0)) / np.std(y[last:])
        assert (ratio > 1.1) if worse else (ratio < 0.7)


def test_accel_ramp_is_noise_dominated():
    ds = simulate("accel-ramp", seed=0)
    assert len(ds) == 1
    rec = ds["run0"]
    temp = rec.temperature_c
    assert temp.min() == pytest.approx(15.0, abs=0.3) and temp.max() == pytest.approx(45.0, abs=0.3)
    drift = rec.drift["drift_acc_x"]
    noise = rec.outputs["acc_x"] - 1.0 - drift
    assert rec.outputs["acc_x"].mean() == pytest.approx(1.0, abs=0.01)     # +1 g, static
    assert np.ptp(drift) == pytest.approx(3.6e-3, rel=0.1)                 # ≈ 4 mg over 30 °C
    assert np.std(noise) == pytest.approx(0.02, rel=0.1)                   # 20 mg per sample
    assert np.std(noise) > 5 * np.ptp(drift)
