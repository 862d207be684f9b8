"""The fleet's short test (:mod:`thermonet.scoring.prior_map`): how a station's fixed test
reads a unit's drift curve, learned from pilot units that ran it beside their calibration.

Window means against hand counts; a known linear response recovered; the update through the
map equal to the points' conjugate update where the map *is* the points' design (an
independent route to the same posterior); a sensor lagging its thermometer on a fast ramp,
whose drift the thermometer's points get wrong and the map gets right; the map read back from
a prior file exactly, and every bad key named; a unit on another test said so; end to end,
`thermonet prior --short-test` and a station that calibrates through it, falling back to a
unit's points (and saying why) where its test is not the fleet's.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from thermonet.cli import main
from thermonet.core.errors import InputError
from thermonet.scoring.prior import AxisPrior, FleetPrior, posterior, posterior_from_stats
from thermonet.scoring.prior_io import prior_from_dict
from thermonet.scoring.prior_map import (
    AxisMap,
    TestMap,
    fit_test_map,
    map_from_dict,
    map_window_s,
    window_means,
)
from thermonet.scoring.prior_points import Points, shape_design

T_REF, SCALE, D = 25.0, 50.0, 3


def test_window_means_by_hand() -> None:
    t = np.arange(0.0, 100.0, 1.0)                    # 100 s at 1 Hz
    v = np.column_stack([t, 2 * t])
    v[5:25, 1] = np.nan                               # window 0 keeps 5 of 20, window 1 15
    got = window_means(t, v, 20.0, 6)
    assert got[:5, 0] == pytest.approx([9.5, 29.5, 49.5, 69.5, 89.5], abs=1e-12)
    assert np.isnan(got[0, 1])                        # under half its samples finite
    assert got[1, 1] == pytest.approx(2 * np.mean(np.arange(25.0, 40.0)), abs=1e-12)
    assert np.isnan(got[5]).all()                     # the record ends before window 5
    assert map_window_s(600.0) == 30.0 and map_window_s(3600.0) == 60.0


def test_a_window_half_finite_is_a_value() -> None:
    t = np.arange(0.0, 40.0, 1.0)
    v = t.copy()
    v[:10] = np.nan                                   # exactly half of window 0
    got = window_means(t, v, 20.0, 2)[:, 0]
    assert got[0] == pytest.approx(np.mean(np.arange(10.0, 20.0)), abs=1e-12)


def _pilots(rng: np.random.Generator, n_units: int, A: np.ndarray, f0: np.ndarray,
            noise: float) -> tuple[np.ndarray, np.ndarray]:
    """Units' shapes and their raw window means f = f0 + A β + a turn-on offset + noise
    (n windows: A and f0 given for all n)."""
    B = rng.normal([0.1, -0.05, 0.02], [0.03, 0.02, 0.01], size=(n_units, D))
    F = f0 + B @ A.T + rng.normal(0, 5.0, size=(n_units, 1)) + \
        rng.normal(0, noise, size=(n_units, A.shape[0]))
    return B, F


@pytest.mark.numerics
def test_a_known_linear_response_is_recovered() -> None:
    rng = np.random.default_rng(1)
    n = 12
    A = rng.normal(size=(n, D))
    f0 = rng.normal(size=n)
    B, F = _pilots(rng, 400, A, f0, noise=1e-3)
    tm = fit_test_map({"x": B}, F[:, :, None], np.zeros((400, n)) + np.arange(n), 30.0, ["x"])
    # what the map can know: A and f0 about their window mean (an offset is free), last dropped
    Ac, f0c = (A - A.mean(0))[:-1], (f0 - f0.mean())[:-1]
    m = tm.axes["x"]
    se = 1e-3 / np.sqrt(400 * 0.01 ** 2)              # noise / √(units · var β), the loosest axis
    assert m.A == pytest.approx(Ac, abs=6 * se)
    assert m.f0 - m.A @ m.beta_mean == pytest.approx(f0c, abs=6 * se * 0.2)
    assert tm.n_units == 400 and tm.n_windows == n
    assert np.diag(m.cov) == pytest.approx(1e-6 * (1 - 1 / n), rel=0.3)


@pytest.mark.numerics
def test_the_map_update_is_the_points_update_where_the_map_is_their_design() -> None:
    """A map whose response is the points' own design (A = their shape rows, f0 = 0, β̄ = 0,
    independent windows of the points' error) must give the points' posterior exactly: the
    same conjugate update reached by two routes (the map profiles a constant, as a run's
    constant is profiled for points)."""
    rng = np.random.default_rng(2)
    temps = np.linspace(-20.0, 70.0, 9)
    X = shape_design(temps, T_REF, SCALE, D)
    ap = AxisPrior("x", np.array([0.4, 0.6]), np.array([[0.1, 0.0, 0.0], [0.2, -0.1, 0.05]]),
                   np.array([np.eye(D) * 4e-3, np.eye(D) * 2e-3]), 1e-4, 0.0, 30)
    y = X @ np.array([0.15, -0.04, 0.03]) + 3.0 + rng.normal(0, 0.01, temps.size)
    pts = Points(temps, y, np.zeros(temps.size), np.zeros(temps.size, int),
                 np.full(temps.size, 100))
    ref = posterior(ap, pts, t_ref=T_REF, scale=SCALE)
    tm = TestMap(30.0, np.zeros(temps.size + 1), np.zeros(temps.size + 1),
                 {"x": AxisMap(np.zeros(temps.size), X, np.zeros(D),
                               np.eye(temps.size) * ap.misfit_var)}, 30)
    got = posterior_from_stats(ap, *tm.stats("x", y))
    assert got.shape == pytest.approx(ref.shape, rel=1e-9, abs=1e-12)
    assert got.cov == pytest.approx(ref.cov, rel=1e-9, abs=1e-15)
    assert got.weights == pytest.approx(ref.weights, rel=1e-9)
    assert got.dof == ref.dof


def _lagging_units(rng: np.random.Generator, n_units: int, tau_s: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Units on a 10-min up-and-down (−20 → 70 → −20 °C, 1 Hz) whose die lags the
    thermometer by ``tau_s``: shapes, raw readings, thermometer trace, time."""
    t = np.arange(0.0, 600.0)
    thermo = np.where(t < 300, -20 + 90 * t / 300, 70 - 90 * (t - 300) / 300)
    die = np.empty_like(thermo)
    die[0] = thermo[0]
    a = 1 - np.exp(-1.0 / tau_s)
    for i in range(1, t.size):
        die[i] = die[i - 1] + a * (thermo[i] - die[i - 1])
    B = rng.normal([0.1, -0.05, 0.02], [0.03, 0.02, 0.01], size=(n_units, D))
    R = B @ shape_design(die, T_REF, SCALE, D).T + rng.normal(0, 2.0, (n_units, 1)) + \
        rng.normal(0, 1e-3, (n_units, t.size))
    return B, R, thermo, t


@pytest.mark.numerics
def test_a_lagging_sensor_is_calibrated_through_the_map_not_by_its_points() -> None:
    """The thermometer leads the die by 40 s on a 18 °C/min ramp: a curve fitted against the
    thermometer is off by the lag; the map, learned from pilot units whose shapes are known,
    recovers the new unit's shape."""
    rng = np.random.default_rng(3)
    B, R, thermo, t = _lagging_units(rng, 61, tau_s=40.0)
    ws = map_window_s(600.0)
    win = np.stack([window_means(t, r, ws, 20)[:, 0] for r in R])
    temps = np.tile(window_means(t, thermo, ws, 20)[:, 0], (61, 1))
    tm = fit_test_map({"x": B[:60]}, win[:60, :, None], temps[:60], ws, ["x"])
    mu, S = B[:60].mean(0), np.cov(B[:60].T)
    ap = AxisPrior("x", np.ones(1), mu[None], S[None], 1e-8, 0.0, 60)
    through = posterior_from_stats(ap, *tm.stats("x", tm.centred(win[60])))
    # the same unit from its window means read against the thermometer (points)
    pts = Points(temps[60], win[60], np.zeros(20), np.zeros(20, int), np.full(20, 30))
    naive = posterior(AxisPrior("x", np.ones(1), mu[None], S[None], 1e-6, 0.0, 60), pts,
                      t_ref=T_REF, scale=SCALE)
    grid = shape_design(np.linspace(-20, 70, 10), T_REF, SCALE, D)
    err = lambda s: np.ptp(grid @ (s - B[60]))                       # noqa: E731
    drift = np.ptp(grid @ B[60])
    assert err(through.shape) < 0.02 * drift
    assert err(naive.shape) > 5 * err(through.shape)


def _one_map(n: int = 5) -> TestMap:
    rng = np.random.default_rng(4)
    c = rng.normal(size=(n - 1, n - 1))
    return TestMap(30.0, np.linspace(-20, 20, n), np.full(n, 0.3),
                   {"gyro_x": AxisMap(rng.normal(size=n - 1), rng.normal(size=(n - 1, D)),
                                      rng.normal(size=D), c @ c.T + np.eye(n - 1))}, 12)


@pytest.mark.numerics
def test_the_map_reads_back_exactly_and_every_bad_key_is_named() -> None:
    tm = _one_map()
    data = json.loads(json.dumps(tm.to_dict()))
    back = map_from_dict(data, "p.json", ["gyro_x"], D)
    for a, b in ((tm.trace_c, back.trace_c), (tm.axes["gyro_x"].A, back.axes["gyro_x"].A),
                 (tm.axes["gyro_x"].cov, back.axes["gyro_x"].cov)):
        assert np.array_equal(a, b)          # JSON keeps a float64 to the bit (repr round trip)
    bad = {"window_s": ("window_s", -1), "n_units": ("n_units", 3),
           "trace_c": ("trace_c", [1.0]), "axes.gyro_x.A": ("A", [[1.0]]),
           "axes.gyro_x.cov": ("cov", (-np.eye(4)).tolist())}
    for key, (field, value) in bad.items():
        d = json.loads(json.dumps(tm.to_dict()))
        (d["axes"]["gyro_x"] if key.startswith("axes") else d)[field] = value
        with pytest.raises(InputError, match=f"p.json: key 'short_test.{key}'"):
            map_from_dict(d, "p.json", ["gyro_x"], D)
    with pytest.raises(InputError, match="short_test.axes': expected one map per axis"):
        map_from_dict(data, "p.json", ["gyro_x", "gyro_y"], D)


def test_a_prior_file_carries_its_map() -> None:
    ap = AxisPrior("gyro_x", np.ones(1), np.zeros((1, D)), np.eye(D)[None], 1e-4, 0.0, 12)
    fp = FleetPrior([ap], D, T_REF, SCALE, (-20.0, 70.0), {"gyro_x": "deg/s"},
                    {"gyro_x": "zero"}, 12, [f"u{i}" for i in range(12)], test_map=_one_map())
    back = prior_from_dict(json.loads(json.dumps(fp.to_dict())), "p.json")
    assert back.test_map is not None
    assert np.array_equal(back.test_map.axes["gyro_x"].f0, fp.test_map.axes["gyro_x"].f0)
    plain = prior_from_dict({**fp.to_dict(), "short_test": None}, "p.json")
    assert plain.test_map is None


def test_a_unit_on_another_test_is_told_why() -> None:
    tm = _one_map()
    t = np.arange(0.0, 150.0)
    trace = tm.trace_c[(t // 30).astype(int)]
    assert tm.mismatch(t, trace) is None
    assert "lasts 1.98 min, the fleet's short test 2.5 min" in tm.mismatch(t[:120], trace[:120])
    hot = trace + np.where(t >= 60, 3.0, 0.0)
    why = tm.mismatch(t, hot)
    assert why is not None and why.startswith("at 1–1.5 min it reads") and \
        "not the same test" in why


FLEET = """data: {preset: consumer-imu, seed: 0, runs: 1}
target: {gyro: zero, acc: at-t-ref}
features: {t_ref: 25.0}
"""


def test_prior_with_a_short_test_and_a_station_through_it(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    (tmp_path / "f.yaml").write_text(FLEET)
    p = tmp_path / "prior.json"
    assert main(["prior", str(tmp_path / "f.yaml"), "--units", "16", "--out", str(p),
                 "--short-test", "cycle:-20,75,10"]) == 0
    assert "its short test, learned from" in capsys.readouterr().out
    data = json.loads(p.read_text())
    assert len(data["short_test"]["trace_c"]) == 24 and data["short_test"]["window_s"] == 30
    main(["station", str(tmp_path / "f.yaml"), "--prior", str(p), "--units", "4",
          "--test", "cycle:-20,75,10", "--out", str(tmp_path / "st"), "--executor", "serial"])
    out = capsys.readouterr().out
    assert "4 of 4 calibrated through the fleet's short test" in out
    res = json.loads((tmp_path / "st" / "results.json").read_text())
    assert {u["short_test_map"] for u in res["units"].values()} == {"used"}
    main(["station", str(tmp_path / "f.yaml"), "--prior", str(p), "--units", "2",
          "--test", "cycle:-20,70,10", "--out", str(tmp_path / "st2"), "--executor", "serial"])
    out = capsys.readouterr().out
    assert "0 of 2 calibrated through the fleet's short test; " in out
    assert "from their points (at " in out and "not the same test)" in out


def _twelve_units() -> tuple[Any, Any]:
    """A config and 12 simulated units' 3-soak calibrations (a prior's data)."""
    from thermonet.sim import simulate_fleet
    from thermonet.training.config import config_from_mapping

    cfg = config_from_mapping({"data": {"preset": "consumer-imu"},
                               "target": {"gyro": "zero", "acc": "at-t-ref"},
                               "features": {"t_ref": 25.0}}, source="c.yaml")
    return cfg, simulate_fleet("consumer-imu", units=12, seed=0, test="soaks:-20,25,75",
                               sample_rate_hz=0.2)


def test_too_few_pilot_units_are_refused_with_their_count() -> None:
    from thermonet.core.recording import Dataset
    from thermonet.sim import simulate_fleet
    from thermonet.workflows.station_prior import build_prior

    cfg, ds = _twelve_units()
    short = simulate_fleet("consumer-imu", units=12, seed=0, test="cycle:-20,75,10",
                           unit_indices=list(range(4)))
    with pytest.raises(InputError, match="the short tests hold 4 units of the prior's 1[0-2] "
                                         r"\(by device id"):
        build_prior(cfg, ds, source="c.yaml", short=Dataset(runs=list(short)))


def test_a_pilot_unit_on_another_test_is_left_out_of_the_map() -> None:
    rng = np.random.default_rng(5)
    n = 8
    A, f0 = rng.normal(size=(n, D)), rng.normal(size=n)
    B, F = _pilots(rng, 30, A, f0, noise=1e-3)
    temps = np.tile(np.linspace(-20.0, 60.0, n), (30, 1))
    temps[3] += np.where(np.arange(n) == 5, 6.0, 0.0)      # one window 6 °C off: another test
    temps[4] += 4.0                                         # 4 °C off throughout: within 5
    tm = fit_test_map({"x": B}, F[:, :, None], temps, 30.0, ["x"])
    assert tm.n_units == 29


def test_a_short_test_in_other_units_than_the_calibration_is_refused() -> None:
    from thermonet.core.recording import Dataset
    from thermonet.sim import simulate_fleet
    from thermonet.workflows.station_prior import build_prior

    cfg, ds = _twelve_units()
    runs = list(simulate_fleet("consumer-imu", units=12, seed=0, test="cycle:-20,75,10"))
    runs[0].units = {**runs[0].units, "gyro_x": "rad/s"}
    with pytest.raises(InputError, match=r"unit 'consumer-imu-u000': its short test's gyro_x "
                                         r"is in 'rad/s', its calibration's in 'deg/s'"):
        build_prior(cfg, ds, source="c.yaml", short=Dataset(runs=runs))


def test_prior_reads_the_short_tests_from_a_file(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """A line's real route: the pilots' calibrations in one file, their short tests in
    another (a device id per run), matched by device id; a missing file named."""
    from thermonet.data.io import write_parquet
    from thermonet.sim import simulate_fleet

    write_parquet(simulate_fleet("consumer-imu", units=14, seed=3, test="soaks:-20,0,25,50,75"),
                  tmp_path / "sweeps.parquet")
    write_parquet(simulate_fleet("consumer-imu", units=14, seed=3, test="cycle:-20,75,10"),
                  tmp_path / "tests.parquet")
    (tmp_path / "p.yaml").write_text(f"data: {{paths: ['{tmp_path / 'sweeps.parquet'}']}}\n"
                                     "target: {gyro: zero, acc: at-t-ref}\n"
                                     "features: {t_ref: 25.0}\n")
    assert main(["prior", str(tmp_path / "p.yaml"), "--short-test",
                 str(tmp_path / "tests.parquet"), "--out", str(tmp_path / "p.json")]) == 0
    data = json.loads((tmp_path / "p.json").read_text())
    # every unit the prior kept ran the test: the map holds them all, matched by device id
    assert data["short_test"]["n_units"] == data["n_units"] >= 10
    assert f"its short test, learned from {data['n_units']} units" in capsys.readouterr().out
    assert main(["prior", str(tmp_path / "p.yaml"), "--short-test", str(tmp_path / "no.parquet"),
                 "--out", str(tmp_path / "q.json")]) == 1
    assert f"{tmp_path / 'no.parquet'}: --short-test: no such file" in capsys.readouterr().err
    assert not (tmp_path / "q.json").exists()
