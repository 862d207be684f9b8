"""The fleet prior's mathematics (thermonet.scoring.prior) against independent formulations.

Known population parameters recovered from their draws; the conjugate posterior against the
same problem solved as one stacked least-squares system (prior rows + data rows,
``numpy.linalg.lstsq``); the flag's distance and the clusters' evidence against scipy's
multivariate normal in the space of within-run contrasts; the design against the textbook
I-optimal answer for a line; the prior file's checks.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.linalg import null_space
from scipy.stats import chi2, multivariate_normal

from thermonet.core.errors import InputError
from thermonet.scoring.prior import (
    FLAG_P,
    MIN_UNITS,
    AxisPrior,
    FleetPrior,
    fit_population,
    fit_unit,
    posterior,
)
from thermonet.scoring.prior_design import next_temperatures, points_needed, soak_plan
from thermonet.scoring.prior_io import prior_from_dict
from thermonet.scoring.prior_points import Points, bin_points, shape_design

T_REF, SCALE = 25.0, 50.0


def _points(temps: np.ndarray, values: np.ndarray, runs: np.ndarray,
            sampling_var: float = 0.0) -> Points:
    return Points(np.asarray(temps, float), np.asarray(values, float),
                  np.full(len(temps), sampling_var), np.asarray(runs), np.full(len(temps), 100))


def test_population_recovers_a_known_single_gaussian() -> None:
    rng = np.random.default_rng(0)
    mu = np.array([0.5, -0.2, 0.1])
    A = np.array([[0.10, 0.0, 0.0], [0.05, 0.04, 0.0], [-0.02, 0.01, 0.03]])
    cov = A @ A.T
    n = 400
    z = rng.multivariate_normal(mu, cov, size=n)
    w, means, covs = fit_population(z, max_clusters=1)
    assert w.tolist() == [1.0]
    se = np.sqrt(np.diag(cov) / n)
    assert np.all(np.abs(means[0] - mu) < 4 * se)
    # a variance's relative standard error is sqrt(2/n) = 7 %: 4 of them, plus shrinkage
    assert np.allclose(np.diag(covs[0]), np.diag(cov), rtol=0.35)
    corr = covs[0][0, 1] / np.sqrt(covs[0][0, 0] * covs[0][1, 1])
    true = cov[0, 1] / np.sqrt(cov[0, 0] * cov[1, 1])
    assert abs(corr - true) < 0.2


def test_population_finds_two_known_clusters() -> None:
    rng = np.random.default_rng(1)
    centres = np.array([[1.0, 0.0, 0.2], [-1.0, 0.5, -0.2]])
    sd = 0.05
    z = np.vstack([rng.normal(centres[0], sd, (180, 3)), rng.normal(centres[1], sd, (120, 3))])
    w, means, covs = fit_population(z)
    assert len(w) == 2
    order = np.argsort(-w)
    assert np.allclose(w[order], [0.6, 0.4], atol=0.05)
    assert np.allclose(means[order], centres, atol=4 * sd / np.sqrt(100))
    assert np.allclose(np.sqrt(np.diagonal(covs[order], axis1=1, axis2=2)), sd, rtol=0.3)


def test_population_refuses_a_fleet_too_small() -> None:
    with pytest.raises(InputError, match=f"at least {MIN_UNITS} calibrated units, got 4"):
        fit_population(np.zeros((4, 3)))


def _one_cluster(mu: np.ndarray, cov: np.ndarray, misfit: float) -> AxisPrior:
    return AxisPrior("gyro_x", np.ones(1), mu[None], cov[None], misfit, 0.0)


def test_posterior_equals_the_stacked_least_squares_solution() -> None:
    rng = np.random.default_rng(2)
    mu, cov = np.array([0.3, -0.1, 0.05]), np.diag([0.04, 0.02, 0.01])
    temps = np.array([-10.0, 5.0, 25.0, 40.0, 60.0, 0.0, 30.0])
    runs = np.array([0, 0, 0, 0, 1, 1, 1])
    sv = 1e-4
    y = rng.normal(size=7) * 0.01 + np.array([0, 0, 0, 0, 0.5, 0.5, 0.5])
    ap = _one_cluster(mu, cov, 4e-4)
    post = posterior(ap, _points(temps, y, runs, sv), t_ref=T_REF, scale=SCALE)
    # oracle: unknowns (β, one constant per run); prior rows L⁻¹β = L⁻¹μ, data rows weighted
    X = shape_design(temps, T_REF, SCALE, 3)
    D = np.column_stack([X, runs == 0, runs == 1]).astype(float)
    sw = 1.0 / np.sqrt(4e-4 + sv)
    Li = np.linalg.inv(np.linalg.cholesky(cov))
    P = np.hstack([Li, np.zeros((3, 2))])
    sol, *_ = np.linalg.lstsq(np.vstack([P, sw * D]), np.r_[Li @ mu, sw * y], rcond=None)
    assert np.allclose(post.shape, sol[:3], rtol=1e-9, atol=1e-12)
    G = np.vstack([P, sw * D])
    cov_oracle = np.linalg.inv(G.T @ G)[:3, :3]      # flat constants marginalised
    assert np.allclose(post.cov, cov_oracle, rtol=1e-8, atol=1e-14)


def test_distance_and_evidence_agree_with_scipy_in_the_contrast_space() -> None:
    rng = np.random.default_rng(3)
    mus = np.array([[0.3, -0.1, 0.05], [-0.2, 0.2, 0.0]])
    covs = np.array([np.diag([0.04, 0.02, 0.01]), np.diag([0.01, 0.03, 0.02])])
    ap = AxisPrior("acc_x", np.array([0.7, 0.3]), mus, covs, 2e-4, 0.0)
    temps = np.array([-15.0, 0.0, 25.0, 50.0, 70.0, 10.0, 60.0])
    runs = np.array([0, 0, 0, 0, 0, 1, 1])
    y = rng.normal(size=7) * 0.05
    post = posterior(ap, _points(temps, y, runs), t_ref=T_REF, scale=SCALE)
    # the contrasts: y projected on the null space of the run indicators (constants gone)
    R = np.column_stack([runs == 0, runs == 1]).astype(float)
    Q = null_space(R.T)                                   # 7 × 5, orthonormal
    X = shape_design(temps, T_REF, SCALE, 3)
    logpdf = []
    for k in range(2):
        C = Q.T @ (X @ covs[k] @ X.T + 2e-4 * np.eye(7)) @ Q
        r = Q.T @ (y - X @ mus[k])
        d2 = float(r @ np.linalg.solve(C, r))
        assert post.p_values[k] == pytest.approx(chi2.sf(d2, 5), rel=1e-7)
        logpdf.append(multivariate_normal(Q.T @ X @ mus[k], C).logpdf(Q.T @ y))
    lw = np.log(ap.weights) + np.array(logpdf)
    assert np.allclose(post.weights, np.exp(lw - lw.max()) / np.exp(lw - lw.max()).sum(),
                       rtol=1e-7)
    assert post.dof == 5


def _curve_error(grid: np.ndarray, b: np.ndarray, beta: np.ndarray) -> float:
    e = grid @ (b - beta)
    return float(np.sqrt(np.mean((e - e.mean()) ** 2)))


def test_three_points_and_the_prior_beat_the_prior_alone_and_flag_a_stranger() -> None:
    rng = np.random.default_rng(4)
    mu, cov = np.array([0.5, 0.2, -0.1]), np.diag([0.02, 0.01, 0.004])
    ap = _one_cluster(mu, cov, 1e-5)
    grid = shape_design(np.linspace(-20, 70, 91), T_REF, SCALE, 3)
    gains = []
    for _ in range(20):
        beta = rng.multivariate_normal(mu, cov)
        temps = np.array([-15.0, 25.0, 65.0])
        y = shape_design(temps, T_REF, SCALE, 3) @ beta + 0.7 + rng.normal(size=3) * 3e-3
        pts = _points(temps, y, np.zeros(3, int))
        post = posterior(ap, pts, t_ref=T_REF, scale=SCALE)

        gains.append(_curve_error(grid, post.shape, beta) / _curve_error(grid, mu, beta))
        with pytest.raises(InputError, match="cannot fit a degree-3 curve"):
            fit_unit(pts, t_ref=T_REF, scale=SCALE, degree=3)   # alone they cannot
    assert np.median(gains) < 0.5
    stranger = shape_design(np.array([-15.0, 25.0, 65.0]), T_REF, SCALE, 3) @ (mu + 10 *
                                                                            np.sqrt(np.diag(cov)))
    post = posterior(ap, _points([-15.0, 25.0, 65.0], stranger, np.zeros(3, int)),
                     t_ref=T_REF, scale=SCALE)
    assert post.flagged and post.p_value is not None and post.p_value < 1e-6


def test_a_long_test_is_flagged_on_its_shape_not_on_its_scatter() -> None:
    """200 points (a climate cycle's worth): a unit of the fleet whose points scatter 30 %
    more than the fleet's median misfit is not flagged (over 199 degrees of freedom the whole
    prior predictive would: χ² of 1.69 × 199 has p ≈ 4e-9), a stranger 10 σ off is; the
    shape's p-value equals the one computed independently — the unit's own least squares
    (numpy's lstsq on its centred points), its residual variance, and scipy's χ² with d
    degrees of freedom of its distance under N(μ, Σ + s²·(XᵀX/v)⁻¹)."""
    rng = np.random.default_rng(11)
    mu, cov, v = np.array([0.5, 0.2, -0.1]), np.diag([0.02, 0.01, 0.004]), 1e-5
    ap = _one_cluster(mu, cov, v)
    temps = np.linspace(-20.0, 70.0, 200)
    X = shape_design(temps, T_REF, SCALE, 3)
    assert chi2.sf(1.69 * 199, 199) < FLAG_P
    flagged = 0
    for _ in range(20):
        beta = rng.multivariate_normal(mu, cov)
        y = X @ beta + 0.3 + rng.normal(size=temps.size) * 1.3 * np.sqrt(v)
        post = posterior(ap, _points(temps, y, np.zeros(temps.size, int)), t_ref=T_REF,
                         scale=SCALE)
        flagged += post.flagged
        # the independent computation of the same p-value
        Xc, yc = X - X.mean(axis=0), y - y.mean()
        bhat, rss, *_ = np.linalg.lstsq(Xc, yc, rcond=None)
        s2 = max(float(rss[0]) / v / (temps.size - 1 - 3), 1.0)
        C = cov + s2 * v * np.linalg.inv(Xc.T @ Xc)
        d2 = float((bhat - mu) @ np.linalg.solve(C, bhat - mu))
        assert post.p_value == pytest.approx(chi2.sf(d2, 3), rel=1e-6)
    assert flagged <= 1                       # 20 units of the fleet: none or one by chance
    stranger = X @ (mu + 10 * np.sqrt(np.diag(cov))) + rng.normal(size=temps.size) * 1.3 * \
        np.sqrt(v)
    post = posterior(ap, _points(temps, stranger, np.zeros(temps.size, int)), t_ref=T_REF,
                     scale=SCALE)
    assert post.flagged and post.p_value is not None and post.p_value < 1e-6


def test_bin_points_keeps_a_passes_direction_and_drops_fast_changes() -> None:
    t = np.arange(0, 7200.0)                         # 2 h at 1 Hz
    temp = np.where(t < 3600, 20 + t / 360.0, 30 - (t - 3600) / 360.0)   # 1/6 °C/min up, down
    y = np.where(t < 3600, 1.0, 2.0)                 # a branch offset: the hysteresis
    pts = bin_points(temp, y, time_s=t)
    at25 = pts.value[np.abs(pts.temperature_c - 25) < 0.5]
    assert sorted(at25.tolist()) == [1.0, 2.0]       # heating and cooling: two points
    jump = np.where(t < 3600, 20.0, 60.0 - 40.0 * np.exp(-(t - 3600) / 60.0))
    pts = bin_points(jump, np.zeros_like(t), time_s=t)
    # the jump's first minutes (faster than 1.2 °C/min) are no points; the soaks are
    assert pts.temperature_c.min() == pytest.approx(20.0)
    assert pts.temperature_c.max() == pytest.approx(60.0, abs=0.5)
    assert not np.any((pts.temperature_c > 25) & (pts.temperature_c < 55))


def _prior_for_design(degree: int) -> FleetPrior:
    ap = AxisPrior("gyro_x", np.ones(1), np.zeros((1, degree)), np.eye(degree)[None] * 0.01,
                   1e-4, 0.0)
    return FleetPrior([ap], degree, T_REF, SCALE, (-20.0, 70.0), {"gyro_x": "deg/s"},
                      {"gyro_x": "zero"}, 20, [f"u{i}" for i in range(20)])


def test_design_of_a_line_measures_the_ends_of_the_range() -> None:
    # a slope and a free constant: the I-optimal pair is the two ends of the range
    assert next_temperatures(_prior_for_design(1), "gyro_x", [], 2) == [-20.0, 70.0]


def test_one_test_for_every_axis_leaves_out_an_axis_without_drift() -> None:
    fp = _prior_for_design(3)
    flat = AxisPrior("gyro_z", np.ones(1), np.zeros((1, 3)), np.eye(3)[None] * 1e-12, 1e-4, 0.0)
    with_flat = FleetPrior([fp.axes[0], flat], 3, T_REF, SCALE, fp.range_c,
                           {"gyro_x": "deg/s", "gyro_z": "deg/s"},
                           {"gyro_x": "zero", "gyro_z": "zero"}, 20, fp.unit_ids)
    # gyro_x's mean curve is flat too: its typical drift is zero, so nothing is left to plan
    assert soak_plan(with_flat, 3) == [-20.0, 70.0]
    drifting = AxisPrior("gyro_x", np.ones(1), np.array([[0.5, 0.2, -0.1]]),
                         np.eye(3)[None] * 0.01, 1e-4, 0.0)
    one = FleetPrior([drifting, flat], 3, T_REF, SCALE, fp.range_c, with_flat.units,
                     with_flat.targets, 20, fp.unit_ids)
    solo = FleetPrior([drifting], 3, T_REF, SCALE, fp.range_c, {"gyro_x": "deg/s"},
                      {"gyro_x": "zero"}, 20, fp.unit_ids)
    # by the expected error alone, the plan is the one drifting axis's own design
    assert soak_plan(one, 3, ends=False) == sorted(next_temperatures(solo, "gyro_x", [], 3))
    # by default the range's ends are soaked and the middle chosen given them
    mid = next_temperatures(solo, "gyro_x", [-20.0, 70.0], 1)
    assert soak_plan(one, 3) == sorted([-20.0, 70.0] + mid) and -20.0 < mid[0] < 70.0
    # an end already measured is not planned again
    assert soak_plan(one, 2, measured_c=[-20.0]) == sorted(
        [70.0] + next_temperatures(solo, "gyro_x", [-20.0, 70.0], 1))


def test_points_needed_decrease_and_meet_their_target() -> None:
    fp = _prior_for_design(3)
    n, temps, errs = points_needed(fp, "gyro_x", 0.02)
    assert all(b <= a + 1e-12 for a, b in zip(errs, errs[1:], strict=False))
    assert n is not None and errs[n - 2] <= 0.02 and (n == 2 or errs[n - 3] > 0.02)
    assert all(-20.0 <= t <= 70.0 for t in temps)
    assert points_needed(fp, "gyro_x", 1e-9)[0] is None


def test_prior_file_round_trip_and_refusals() -> None:
    fp = _prior_for_design(3)
    data = fp.to_dict()
    back = prior_from_dict(data, "p.json")
    assert np.array_equal(back.axes[0].covs, fp.axes[0].covs) and back.range_c == fp.range_c
    for key, value, words in (
            ("kind", "fleet", "not a thermonet fleet prior"),
            ("degree", 9, "key 'degree'"),
            ("n_units", 3, "key 'n_units'"),
            ("range_c", [70.0, -20.0], "key 'range_c'")):
        with pytest.raises(InputError, match=words):
            prior_from_dict({**data, key: value}, "p.json")
    bad = {**data, "axes": {"gyro_x": {**data["axes"]["gyro_x"],
                                       "covs": [[[1.0, 2.0, 0], [2.0, 1.0, 0], [0, 0, 1.0]]]}}}
    with pytest.raises(InputError, match="p.json: key 'axes.gyro_x.covs': .*positive definite"):
        prior_from_dict(bad, "p.json")
    nan = {**data, "axes": {"gyro_x": {**data["axes"]["gyro_x"], "misfit_var": float("nan")}}}
    with pytest.raises(InputError, match="misfit_var"):
        prior_from_dict(nan, "p.json")


def test_a_prior_edited_by_hand_is_refused_naming_the_key() -> None:
    """A string where a number belongs (NumPy would read "0.11" as 0.11), a unit count that
    is not the units listed, and a content that no longer matches its digest."""
    from thermonet.scoring.prior_io import check_digest, prior_digest

    data = json.loads(json.dumps(_prior_for_design(3).to_dict()))
    means = [[["0.11", 0.0, 0.0]]]
    with pytest.raises(InputError, match=r"^p\.json: key 'axes\.gyro_x\.means': not an array "
                                         r"of numbers \(a value is '0\.11'\)$"):
        prior_from_dict({**data, "axes": {"gyro_x": {**data["axes"]["gyro_x"],
                                                     "means": means[0]}}}, "p.json")
    with pytest.raises(InputError, match="key 'range_c': not an array of numbers"):
        prior_from_dict({**data, "range_c": ["-40", 85.0]}, "p.json")
    with pytest.raises(InputError, match=r"^p\.json: key 'n_units': 500, and 'unit_ids' lists "
                                         r"20 units"):
        prior_from_dict({**data, "n_units": 500}, "p.json")
    # the digest: sealed content reads back; one edit (a widened range) does not
    sealed = {**data, "sha256": prior_digest(data)}
    assert check_digest(sealed, "p.json") is None
    assert prior_digest(sealed) == prior_digest(data)        # the digest is not its own input
    with pytest.raises(InputError, match=r"^p\.json: its content does not match its sha256 "
                                         r"\(edited by hand\?\)"):
        check_digest({**sealed, "range_c": [-40.0, 85.0]}, "p.json")
    assert "p.json: no sha256 of its content" in str(check_digest(data, "p.json"))


def test_next_temperatures_never_repeat_a_measured_one() -> None:
    """A unit that soaked at −20 °C was told to measure −20 °C twice: the next temperatures
    keep soak_plan's separation from the measured ones and from each other."""
    fp = _prior_for_design(3)
    measured = [-20.0] * 5 + [25.0] * 5
    nxt = next_temperatures(fp, "gyro_x", measured, 2)
    assert len(nxt) == 2 and abs(nxt[0] - nxt[1]) >= 2.5
    assert all(abs(t - m) >= 2.5 for t in nxt for m in measured), nxt


def test_a_mixture_design_is_judged_on_telling_its_clusters_apart() -> None:
    """Two clusters: a slope, or a cubic of the same values at u = −1, 0, 1 (u³ = u there).
    Points at those three temperatures cannot tell them apart; points at u = −1, 0.5, 1 can,
    so the simulated expected error of the first design is several times the second's."""
    from thermonet.scoring.prior_design import _axis_error

    covs = np.array([np.eye(3) * 1e-6] * 2)
    ap = AxisPrior("gyro_x", np.array([0.5, 0.5]), np.array([[0.1, 0, 0], [0, 0, 0.1]]), covs,
                   1e-6, 0.0)
    fp = FleetPrior([ap], 3, T_REF, SCALE, (T_REF - SCALE, T_REF + SCALE), {"gyro_x": "deg/s"},
                    {"gyro_x": "zero"}, 20, [f"u{i}" for i in range(20)])
    err = _axis_error(fp, "gyro_x", 2.5)
    blind = err([T_REF - SCALE, T_REF, T_REF + SCALE])
    sharp = err([T_REF - SCALE, T_REF + SCALE / 2, T_REF + SCALE])
    assert blind > 5 * sharp
    # blind: half the draws get the wrong cluster's curve, an error of half their gap
    grid = shape_design(np.arange(T_REF - SCALE, T_REF + SCALE + 1e-9, 2.5), T_REF, SCALE, 3)
    gap = grid @ (ap.means[0] - ap.means[1])
    assert blind == pytest.approx(0.5 * np.sqrt(np.mean((gap - gap.mean()) ** 2)), rel=0.25)
