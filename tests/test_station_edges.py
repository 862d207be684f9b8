"""The fleet prior's and the station's edge cases, on hand-made priors and fits (no simulation).

A mixture design judged on a unit's whole climate cycle (hundreds of points) against the
exact conjugate error of its identified cluster; a soak plan's temperatures distinct (a
slope-only prior, whose error has a closed form, wants an end soaked twice); a plan too
narrow for a middle says why; the units left out of a prior: not for differences under a
point's own error on an axis with no curve, still for a curve where the fleet has none and
for a robust outlier where the units do differ; a unit's axes the prior lacks refused; a
held-out residual that cannot be judged says why; a soak test that repeats a temperature in a
row refused.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from thermonet.core.errors import ConfigError, InputError
from thermonet.scoring.prior import AxisPrior, FleetPrior, StationLimit, UnitFit
from thermonet.scoring.prior_design import (
    _axis_error,
    expected_error,
    next_temperatures,
    plan_errors,
    soak_plan,
)
from thermonet.scoring.prior_io import prior_from_dict
from thermonet.scoring.prior_points import Points, shape_design
from thermonet.sim.fleet import short_test
from thermonet.workflows.station import _held_out
from thermonet.workflows.station_prior import (
    _outlier_units,
    check_compatible,
    format_prior,
    prior_summary,
)

T_REF, SCALE = 25.0, 50.0
IDS = [f"u{i:03d}" for i in range(20)]


def _fleet(axes: list[AxisPrior], range_c: tuple[float, float] = (-25.0, 75.0)) -> FleetPrior:
    return FleetPrior(axes, 3, T_REF, SCALE, range_c, {a.axis: "deg/s" for a in axes},
                      {a.axis: "zero" for a in axes}, 20, IDS)


def test_a_mixture_design_takes_a_whole_climate_cycle() -> None:
    """200 points (a climate cycle's bins) once broke the simulated design (noise drawn for
    64); with the clusters far apart they identify the unit's cluster, so the simulated
    error is the exact conjugate error of one Gaussian with that cluster's covariance."""
    covs = np.array([np.eye(3) * 1e-4] * 2)
    ap = AxisPrior("gyro_x", np.array([0.5, 0.5]), np.array([[0.1, 0, 0], [0, 0, 0.1]]), covs,
                   1e-4, 0.0)
    fp = _fleet([ap])
    temps = [float(t) for t in np.linspace(-25.0, 75.0, 200)]
    simulated = _axis_error(fp, "gyro_x", 2.5)(temps)
    X = shape_design(np.array(temps), T_REF, SCALE, 3)
    Xc = X - X.mean(axis=0)
    grid = shape_design(np.arange(-25.0, 75.0 + 1e-9, 2.5), T_REF, SCALE, 3)
    one = AxisPrior("gyro_x", np.ones(1), ap.means[:1], covs[:1], 1e-4, 0.0)
    exact = expected_error(one, 1e4 * Xc.T @ Xc, grid)       # w0 = 1 / misfit_var
    assert simulated == pytest.approx(exact, rel=0.1)          # 400 draws: ~4 % MC error
    nxt = next_temperatures(fp, "gyro_x", temps, 2, apart_c=0.0)   # the design alone
    assert len(nxt) == 2 and all(-25.0 <= t <= 75.0 for t in nxt)
    # a point every 0.5 °C over the range: no temperature 2.5 °C from a measured one is left
    assert next_temperatures(fp, "gyro_x", temps, 2) == []


def _slope_only(range_c: tuple[float, float], misfit: float = 1e-4) -> FleetPrior:
    """Units differ in their slope alone: the curve's error after one run at temperatures
    T_i is ∝ 1 / √(1/σ² + w0 Σ (u_i − ū)²), so the third point goes where Σ (u_i − ū)² is
    largest — on an end again, by the prior's arithmetic."""
    ap = AxisPrior("gyro_x", np.ones(1), np.array([[0.2, 0.0, 0.0]]),
                   np.diag([0.01, 1e-10, 1e-10])[None], misfit, 0.0)
    return _fleet([ap], range_c)


def test_a_soak_plan_never_repeats_a_temperature() -> None:
    fp = _slope_only((-20.0, 70.0))
    plan = soak_plan(fp, 3)
    assert len(plan) == 3 and plan[0] == -20.0 and plan[2] == 70.0      # was -20, -20, 70
    # the middle: the interior candidate (2.5 °C grid, ≥ 2.5 °C from both ends) with the
    # largest Σ (u − ū)², computed here directly
    cand = np.arange(-17.5, 67.5 + 1e-9, 2.5)
    spread = [np.var((np.array([-20.0, t, 70.0]) - T_REF) / SCALE) for t in cand]
    best = {float(t) for t, s in zip(cand, spread, strict=True) if s >= max(spread) - 1e-12}
    assert plan[1] in best and best == {-17.5, 67.5}
    # what the middle adds is printed: the closed form's error ratio, ends alone → all three
    before, after = plan_errors(fp, plan) or (0.0, 0.0)
    var = [np.var((np.array(p) - T_REF) / SCALE) * len(p) for p in ([-20.0, 70.0], plan)]
    ratio = np.sqrt((1 / 0.01 + 1e4 * var[0]) / (1 / 0.01 + 1e4 * var[1]))
    assert after / before == pytest.approx(ratio, rel=1e-4)
    # and the plan is distinct from what was measured too
    assert all(abs(t - 30.0) >= 2.5 for t in soak_plan(fp, 3, measured_c=[30.0]))


def test_a_range_too_narrow_for_a_middle_gives_two_soaks_and_says_why() -> None:
    # candidates 20, 22.5: none 2.5 °C from both ends (a point's error small enough for the
    # slope over 4 °C to be a curve to learn)
    fp = _slope_only((20.0, 24.0), misfit=1e-8)
    plan = soak_plan(fp, 3)
    assert plan == [20.0, 24.0]
    text = format_prior(fp, prior_summary(fp), plan)
    assert "a 2-soak test for every axis: 20, 24 °C" in text
    assert "not 3: the range 20 to 24 °C holds no other temperature 2.5 °C from its ends" in text
    # every figure in the axis's unit of measure
    assert re.search(r"gyro_x: 1 cluster; .*\(\d[\d.e+-]* deg/s( RMS)?", text), text


def _fit(a1: float) -> UnitFit:
    return UnitFit(np.array([a1, 0.0, 0.0]), np.eye(3) * 1e-12, 0.0, 200, (-20.0, 75.0))


def test_units_are_left_out_for_what_a_point_can_see() -> None:
    """gyro_z: no drift, the units' curves tiny (a spread of ~1e-4) against a point's own
    error of 2.5e-3.  A unit 1.5 point errors off was left out by the robust z alone (z in
    the tens); now only a curve where the fleet has none is.  acc_x: the units differ
    (spread 0.05 ≫ its point error 1e-3) and a unit 10 spreads off is left out as before."""
    rng = np.random.default_rng(0)
    slopes_z = list(rng.normal(0.0, 1e-4, 13)) + [1.5 * 2.5e-3, 20 * 2.5e-3]
    slopes_x = list(rng.normal(0.5, 0.05, 13)) + [0.5, 1.0]
    ids = [f"u{i:03d}" for i in range(15)]
    slopes_x[12], slopes_x[14] = slopes_x[14], slopes_x[12]      # the acc_x outlier: u012
    fits = {d: {"gyro_z": _fit(z), "acc_x": _fit(x)}
            for d, z, x in zip(ids, slopes_z, slopes_x, strict=True)}
    out = _outlier_units(fits, {"gyro_z": 2.5e-3, "acc_x": 1e-3}, T_REF, SCALE,
                         (-15.0, 75.0), 3, {"gyro_z": "deg/s", "acc_x": "m/s^2"})
    assert set(out) == {"u012", "u014"}                    # u013 (1.5 point errors) kept
    # u014 at 75 °C (u = 1, the largest |u| of the range -15 … 75 °C): its z is its
    # distance from the median over a point's error
    z = (slopes_z[14] - np.median(slopes_z)) / 2.5e-3
    assert out["u014"].startswith(f"robust outlier: gyro_z at 75 °C z={z:.1f}, ")
    # every figure in the axis's unit of measure
    assert out["u014"].endswith("deg/s off the units' median (their spread 0.0025 deg/s, a "
                                "point's own error 0.0025 deg/s)"), out["u014"]
    assert "acc_x at " in out["u012"] and "m/s^2" in out["u012"]


def test_a_unit_with_axes_the_prior_lacks_is_refused() -> None:
    ap = AxisPrior("gyro_x", np.ones(1), np.zeros((1, 3)), np.eye(3)[None], 0.0, 0.0)
    fp = _fleet([ap])
    # a unit's own data: an InputError, which FAILs that unit alone (station_task)
    with pytest.raises(InputError, match="the prior is of axes gyro_x; the data also hold "
                                         "acc_x, which it says nothing about"):
        check_compatible(fp, ["gyro_x", "acc_x"], {"gyro_x": "zero", "acc_x": "at-t-ref"},
                         "unit 'u1'", {"gyro_x": "deg/s", "acc_x": "m/s^2"})
    check_compatible(fp, ["gyro_x"], {"gyro_x": "zero"}, "unit 'u1'", {"gyro_x": "deg/s"})


def _pts(temps: list[float], runs: list[int]) -> Points:
    n = len(temps)
    return Points(np.array(temps), 1e-3 * np.array(temps), np.full(n, 1e-8),
                  np.array(runs), np.full(n, 100))


def test_a_residual_that_cannot_be_judged_says_why_and_fails_its_limit() -> None:
    ap = AxisPrior("gyro_x", np.ones(1), np.zeros((1, 3)), np.eye(3)[None] * 1e-4, 1e-6, 0.0)
    fp = _fleet([ap])
    assert _held_out(fp, ap, _pts([25.0], [0])) == (None, "1 point")
    assert _held_out(fp, ap, _pts([0.0, 50.0], [0, 1])) == (
        None, "2 points, no run with points at two temperatures")
    held, why = _held_out(fp, ap, _pts([0.0, 25.0, 50.0], [0, 0, 0]))
    assert why is None and held is not None and held >= 0.0
    check = StationLimit(max_residual=0.02).checks(None, 0.0, 0.0, not_judged="1 point")
    assert check == [{"limit": "max_residual", "value": None, "max": 0.02, "ok": False,
                      "not_judged": "1 point"}]


def test_a_soak_test_repeating_a_temperature_in_a_row_is_refused() -> None:
    for spec in ("soaks:30,30,30", "soaks:-10,25,25"):
        with pytest.raises(ConfigError, match="twice in a row is one longer soak"):
            short_test(spec)
    # a return to a temperature after another is a second visit: allowed, three soaks
    assert [s.temperature_c for s in short_test("soaks:25,60,25").segments] == [25.0, 60.0, 25.0]


def test_the_far_clusters_units_come_back_and_outliers_stay_out(monkeypatch):
    """Consumer-imu fleets of three clusters, each unit an 11-soak sweep. The robust screen
    reads each quantity as one population, so alone it leaves out clean members of a far
    cluster. Checked against the mixture of the units it kept, a unit comes back where its
    shape is like a cluster on every axis (the station's own flag). On bench_prior's
    outlier-test prior (50 clean units) the screen alone left out 5 and at most 1 stays out
    now; on a fleet of 50 + 5 units planted 10 σ off, the planted 5 stay out."""
    from thermonet.sim import simulate_fleet
    from thermonet.training.config import config_from_mapping
    from thermonet.workflows import station_prior

    cfg = config_from_mapping({"data": {"preset": "consumer-imu"},
                               "target": {"gyro": "zero", "acc": "at-t-ref"},
                               "features": {"t_ref": 25.0}}, source="test")
    sweep = (short_test("soaks:-20,-10,0,10,20,30,40,50,60,70,75"),)
    clean = simulate_fleet("consumer-imu", units=110, runs=1, seed=6, clusters=3, outliers=20,
                           procedures=sweep, unit_indices=list(range(50)))
    assert len(station_prior.build_prior(cfg, clean).excluded) <= 1
    planted_ds = simulate_fleet("consumer-imu", units=55, runs=1, seed=6, clusters=3,
                                outliers=5, procedures=sweep)
    planted = {f"consumer-imu-u{k:03d}" for k in range(50, 55)}
    fp = station_prior.build_prior(cfg, planted_ds)
    assert planted <= set(fp.excluded) and len(set(fp.excluded) - planted) <= 1
    monkeypatch.setattr(station_prior, "shape_p_values", lambda *a, **k: np.zeros(1))
    assert len(station_prior.build_prior(cfg, clean).excluded) == 5   # the screen alone


def _trace(legs: list[tuple[float, float]], dt: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """A temperature trace of linear legs (°C/min, minutes) from 25 °C."""
    temps, t = [25.0], 25.0
    for rate, minutes in legs:
        for _ in range(int(minutes * 60 / dt)):
            t += rate * dt / 60.0
            temps.append(t)
    return np.arange(len(temps)) * dt, np.array(temps)


@pytest.mark.numerics
@pytest.mark.parametrize("legs, kind", [
    ([(0.0, 30), (1.0, 10), (0.0, 30), (1.0, 10), (0.0, 30)], "soaks"),
    ([(0.5, 100)], "heating ramps"),
    ([(-1.0, 40), (0.0, 5)], "cooling ramps"),
    ([(-1.0, 45), (1.0, 90), (-1.0, 45)], "cycles"),
    ([(-1.0, 45), (1.0, 90), (-1.0, 45), (0.0, 200)], "soaks"),
    ([(-4.75, 20), (4.75, 20)], "fast ramps"),    # steady, so its points pair both ways
])
def test_a_tests_kind_is_the_motion_of_its_points(legs: list[tuple[float, float]],
                                                 kind: str) -> None:
    from thermonet.scoring.prior_points import kind_of_test, motion_counts

    time_s, temp = _trace(legs)
    assert kind_of_test(motion_counts(temp, time_s)) == kind


def test_what_a_prior_compares_by_its_units_tests() -> None:
    """A fast test only against a prior that holds fast tests, a slow one (soaks, slow ramps,
    cycles) only against a prior that holds slow ones; a prior file that does not record its
    tests compares every unit (files written before); a kind the prior cannot hold is
    refused naming the key."""
    fp = _fleet([AxisPrior("gyro_x", np.ones(1), np.zeros((1, 3)), np.eye(3)[None], 1e-4, 0.0)])
    assert all(fp.not_comparable(k) is None for k in ("soaks", "fast ramps"))   # none recorded
    fp.test_kinds = {"soaks": 20}
    assert all(fp.not_comparable(k) is None for k in ("soaks", "cycles", "heating ramps"))
    assert "a test of fast ramps, where the prior's units ran soaks (20 units)" in str(
        fp.not_comparable("fast ramps"))
    fp.test_kinds = {"fast ramps": 20}
    assert fp.not_comparable("fast ramps") is None
    assert all(fp.not_comparable(k) is not None for k in ("soaks", "cycles"))
    fp.test_kinds = {"cycles": 19, "fast ramps": 1}
    assert all(fp.not_comparable(k) is None for k in ("soaks", "cycles", "fast ramps"))
    doc = fp.to_dict()
    assert prior_from_dict(doc, "p.json").test_kinds == {"cycles": 19, "fast ramps": 1}
    for kinds, named in (({"wobbles": 3}, "'wobbles': 3"), ({"soaks": 0}, "'soaks': 0"),
                         ({"cycles": 2.0}, "'cycles': 2.0"), (["soaks"], "['soaks']")):
        doc["test_kinds"] = kinds
        with pytest.raises(InputError) as err:
            prior_from_dict(doc, "p.json")
        assert str(err.value).startswith(f"p.json: key 'test_kinds': {named} is not a test "
                                         "kind (soaks, "), str(err.value)
    # a prior of fast ramps plans soaks all the same, and says they are not compared with it
    fp.test_kinds = {"fast ramps": 20}
    text = format_prior(fp, prior_summary(fp), [-25.0, 25.0, 75.0])
    assert "  note: a soak test is not compared with this fleet (a test of soaks, where the " \
           "prior's units ran fast ramps (20 units)" in text
    # the units it left out are named with why (the first line only counted them)
    fp.excluded = {"u9": "robust outlier: gyro_x at 75 °C z=9.1, …"}
    assert "  left out: 'u9': robust outlier: gyro_x at 75 °C z=9.1, …" in \
        format_prior(fp, prior_summary(fp)).splitlines()


@pytest.mark.numerics
def test_a_shape_is_judged_on_hotellings_predictive_not_chi2() -> None:
    """A cluster's mean and covariance are estimated from its units, so a new unit's D² has
    Hotelling's predictive law, n(n − d)/(d(n − 1)(n + 1))·D² ~ F(d, n − d), checked against a Monte
    Carlo of the very situation (n units drawn, mean and covariance estimated, one more unit
    judged); a prior of unknown size, and a unit the prior would take back, on χ²."""
    from scipy.stats import chi2

    from thermonet.scoring.prior import shape_p_values

    n, d, reps = 16, 3, 20000
    rng = np.random.default_rng(0)
    units = rng.standard_normal((reps, n, d))
    mean = units.mean(axis=1)
    diff = units - mean[:, None]
    cov = np.einsum("rni,rnj->rij", diff, diff) / (n - 1)
    new = rng.standard_normal((reps, d)) - mean
    d2 = np.einsum("ri,ri->r", new, np.linalg.solve(cov, new[..., None])[..., 0])
    ap = AxisPrior("gyro_x", np.ones(1), np.zeros((1, d)), np.eye(d)[None], 1e-4, 0.0, n)
    for q in (8.0, 20.0, 40.0):
        p_mc = float((d2 > q).mean())
        shape = np.array([np.sqrt(q), 0.0, 0.0])
        p = float(shape_p_values(ap, shape, np.zeros((d, d)))[0])
        assert abs(p - p_mc) < 4 * np.sqrt(p * (1 - p) / reps) + 1e-4
        assert float(shape_p_values(ap, shape, np.zeros((d, d)), predictive=False)[0]) == \
            pytest.approx(chi2.sf(q, d), rel=1e-9)
    # D² = 30: χ² would flag it (p ≈ 1e-6), the predictive does not (p ≈ 0.003)
    ap.n_units = 0
    shape = np.array([np.sqrt(30.0), 0.0, 0.0])
    assert shape_p_values(ap, shape, np.zeros((d, d)))[0] < 1e-3
    ap.n_units = n
    assert shape_p_values(ap, shape, np.zeros((d, d)))[0] > 1e-3


def test_units_not_compared_for_two_reasons_get_a_line_each() -> None:
    """The console's "not compared" line per reason with its count (it gave the first unit's
    reason for all)."""
    from thermonet.workflows.station import format_station

    def unit(why: str | None) -> dict[str, object]:
        return {"verdict": "PASS", "axes": {"gyro_x": {
            "held_out_rms": 0.001, "held_out_not_judged": None, "p_value": 0.5,
            "flagged_unlike_fleet": False, "fleet_not_compared": why, "failed": []}}}
    units = {"u0": unit("a test of soaks, where …"), "u1": unit("a test of heating ramps, …"),
             "u2": unit("a test of soaks, where …"), "u3": unit(None)}
    res = {"units_of_measure": {"gyro_x": "deg/s"}, "units": units, "summary": {
        "n_units": 4, "passed": 4, "flagged_unlike_fleet": [], "units_per_minute": 60.0,
        "not_compared_with_fleet": ["u0", "u1", "u2"]}}
    tail = format_station(res).splitlines()[-2:]
    assert tail == ["2 units not compared with the fleet: a test of soaks, where …",
                    "1 unit not compared with the fleet: a test of heating ramps, …"]


def test_a_dead_or_stuck_axis_and_what_is_not_one() -> None:
    """Constant (std 0), piled up at an extreme (≥ 5 % of the samples at the max, held over
    consecutive samples, its most frequent value): dead or stuck.  Not: noise, a coarsely
    quantised noisy axis (its extremes are its rarest values), a clip on fewer than 5 %."""
    from thermonet.workflows.station_checks import STUCK_SHARE, axis_dead

    rng = np.random.default_rng(0)
    x = rng.normal(0.0, 0.01, 4000)
    assert axis_dead([np.zeros(4000)]) == ("constant at 0 over the whole test (a dead or "
                                          "saturated axis)")
    assert axis_dead([np.full(10, 32.767), np.full(5, 32.767)]).startswith("constant at 32.767")
    assert axis_dead([x]) is None
    assert axis_dead([np.round(x / 0.01) * 0.01]) is None      # ±3 LSB of quantised noise
    coarse = np.round(rng.normal(0.0, 0.4, 4000))   # 0.4 LSB: ~10 % at +1, held in a row,
    assert (coarse == coarse.max()).mean() > STUCK_SHARE      # but 0 is its commonest value
    assert axis_dead([coarse]) is None
    clip = np.minimum(x, np.quantile(x, 0.9))
    why = axis_dead([clip])
    assert why is not None and why.startswith(f"stuck at {clip.max():.6g}, its maximum, on 10% "
                                              "of the samples (") and "stuck axis)" in why
    low = np.maximum(x, np.quantile(x, 0.08))
    assert "its minimum, on 8% of the samples" in str(axis_dead([low]))
    few = np.minimum(x, np.quantile(x, 1 - STUCK_SHARE / 2))   # 2.5 % clipped: not judged stuck
    assert axis_dead([few]) is None


def test_next_temperatures_keep_a_soak_plans_separation() -> None:
    """A slope-only prior rates an end measured again best (its arithmetic takes points as
    independent): the station's next temperature is then another, 2.5 °C away at least."""
    fp = _slope_only((-20.0, 70.0))
    assert next_temperatures(fp, "gyro_x", [-20.0, 70.0], 1, apart_c=0.0)[0] in (-20.0, 70.0)
    nxt = next_temperatures(fp, "gyro_x", [-20.0, 70.0], 2)
    assert len(nxt) == 2 and all(-17.5 <= t <= 67.5 for t in nxt)


def test_a_failed_axis_says_where_to_measure_next_on_its_line() -> None:
    from thermonet.workflows.station import format_station

    def axis(nxt: list[float] | None, failed: list[str]) -> dict[str, object]:
        return {"verdict": "FAIL" if failed else "PASS", "held_out_rms": 0.03,
                "held_out_not_judged": None, "p_value": 0.5, "flagged_unlike_fleet": False,
                "fleet_not_compared": None, "failed": failed, "next_temperatures_c": nxt}
    units = {"u0": {"verdict": "FAIL", "runs": 1, "axes": {
        "gyro_x": axis([-17.5, 47.5], ["max_residual"]), "gyro_y": axis([-17.5, 47.5],
                                                                       ["max_residual"]),
        "gyro_z": axis([], ["max_residual"]), "acc_x": axis(None, [])}}}
    res = {"units_of_measure": {}, "units": units, "summary": {
        "n_units": 1, "passed": 0, "flagged_unlike_fleet": [], "units_per_minute": 60.0}}
    line = format_station(res).splitlines()[0]
    assert line.endswith("  next -17.5, 47.5 °C (gyro_x, gyro_y); no temperature left to "
                         "measure (its test covers the range) (gyro_z)"), line


def test_a_unit_not_calibrated_is_counted_failed_and_says_why() -> None:
    """A unit whose data failed a check (no axes): FAIL in the summary, listed as not
    calibrated, left out of the flags and the short-test count, its reason on its line."""
    from thermonet.workflows.station_report import (
        failed_unit,
        format_station,
        station_summary,
        unit_summary,
    )

    fp = _fleet([AxisPrior("gyro_x", np.ones(1), np.zeros((1, 3)), np.eye(3)[None], 0.0, 0.0)])
    bad = failed_unit("u1", "unit 'u1': measured -45.0 to 34.9 °C, outside the fleet prior's "
                      "range -25 to 75 °C (the prior says nothing there)")
    assert bad.pop("header") is None and bad["axes"] == {} and bad["runs"] is None
    assert bad["firmware_header"] == "not written: " + bad["error"]
    good = {"device_id": "u0", "verdict": "PASS", "runs": 1, "temperature_span_c": 50.0,
            "test_kind": "soaks", "short_test_map": "used", "axes": {"gyro_x": {
                "verdict": "PASS", "held_out_rms": 0.001, "held_out_not_judged": None,
                "p_value": 0.5, "flagged_unlike_fleet": False, "fleet_not_compared": None,
                "checks": []}}}
    res = station_summary(fp, {"u0": unit_summary(good, "units/u0"),
                               "u1": unit_summary(bad, "units/u1")}, 1.0)
    s = res["summary"]
    assert (s["n_units"], s["passed"], s["failed"]) == (2, 1, 1)
    assert s["not_calibrated"] == ["u1"] and s["several_runs"] == [] and \
        s["flagged_unlike_fleet"] == [] and s["dead_axes"] == []
    assert res["units"]["u1"]["error"] == bad["error"] and res["units"]["u0"]["error"] is None
    lines = format_station(res).splitlines()
    assert lines[1] == ("u1: FAIL  not calibrated: measured -45.0 to 34.9 °C, outside the fleet "
                        "prior's range -25 to 75 °C (the prior says nothing there)")
    assert lines[2].startswith("1 of 2 units passed (1 not calibrated: their data failed a "
                               "check); 0 unlike their fleet; ")
    assert lines[3] == "1 of 1 calibrated through the fleet's short test"
