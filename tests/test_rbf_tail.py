"""The RBF's polynomial tail: the patent's network that is at worst the cubic.

Independent oracles:

* ``scipy.interpolate.RBFInterpolator`` (scipy 1.x, ``scipy/interpolate/_rbfinterp.py``):
  with the samples at the centres, the penalised least-squares fit
  ``min ‖Φw + Pt − y‖² + λ wᵀKw`` has the stationarity conditions ``(K + λI)w + Pt = y,
  Pᵀw = 0`` — exactly the linear system ``RBFInterpolator(kernel="gaussian", degree=d,
  smoothing=λ)`` solves.  Its Gaussian is ``exp(−(εr)²)``, so ``ε = 1 / (σ√2)``.
* ``numpy.polynomial.Polynomial.fit``: the limit λ → ∞ is the least-squares polynomial.

Both centre placements that allow the tail are checked (``kmeans``, ``quantiles``), and the
quantile centres on their own: where the data are, never two on one dwell temperature, on
the data's curve, without scikit-learn.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import torch
from numpy.polynomial import Polynomial
from scipy.interpolate import RBFInterpolator

from thermonet.core.errors import ConfigError
from thermonet.models.rbf import RBF
from thermonet.models.rbf_fit import RIDGE_GRID, quantile_centres
from tolerances import DEPTH, EPS32, assert_f32_close

pytestmark = pytest.mark.numerics


def _fit(x: np.ndarray, y: np.ndarray, **hyper) -> RBF:
    fam = RBF(n_inputs=x.shape[1], n_outputs=y.shape[1], **hyper)
    fam.initialize(torch.as_tensor(x), torch.as_tensor(y), seed=0)
    return fam


def _predict(fam: RBF, x: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return fam(torch.as_tensor(x, dtype=torch.float32)).double().numpy()


@pytest.mark.parametrize("tail", [1, 2, 3])
@pytest.mark.parametrize("lam", [1e-3, 1e-1, 10.0])
def test_samples_at_the_centres_give_scipys_smoothing_rbf(tail, lam):
    rng = np.random.default_rng(tail)
    x = np.sort(rng.uniform(-2.0, 2.0, 12))[:, None]
    y = np.column_stack([np.sin(2.0 * x[:, 0]) + 0.3 * x[:, 0] ** 3,
                         np.exp(-x[:, 0] ** 2) - 0.5 * x[:, 0]])
    fam = _fit(x, y, n_centres=12, tail=tail, ridge=lam)      # k-means on 12 points: the points
    np.testing.assert_allclose(np.sort(fam.centres.detach().double().numpy()[:, 0]), x[:, 0],
                               rtol=0, atol=1e-6)            # float32 storage of the points
    sigma = math.exp(float(fam.log_sigma.detach()[0]))
    assert np.allclose(fam.log_sigma.detach().numpy(), math.log(sigma))   # one shared width
    k = np.exp(-((x - x.T) ** 2) / (2.0 * sigma * sigma))
    smoothing = lam * float((k * k).sum()) / 12             # λ relative to tr(ΦᵀΦ)/J
    oracle = RBFInterpolator(x, y, kernel="gaussian", epsilon=1.0 / (sigma * math.sqrt(2.0)),
                             degree=tail, smoothing=smoothing)
    xt = np.linspace(-2.5, 2.5, 61)[:, None]                # between and beyond the centres
    assert_f32_close(_predict(fam, xt), oracle(xt), "family")


@pytest.mark.parametrize("init", ["kmeans", "quantiles"])
def test_infinite_ridge_is_the_least_squares_cubic(init):
    rng = np.random.default_rng(0)
    x = rng.uniform(-1.5, 1.5, 400)[:, None]
    y = (0.2 * x - 0.1 * x ** 3 + 0.3 * np.sin(3 * x)) + 0.01 * rng.standard_normal(x.shape)
    fam = _fit(x, y, n_centres=16, tail=3, ridge=1e12, init=init)
    xt = np.linspace(-1.5, 1.5, 31)[:, None]
    cubic = Polynomial.fit(x[:, 0], y[:, 0], 3)(xt[:, 0])
    # the Gaussian part's weights are penalised to ~1e-12 of the data: float32 rounding only
    assert_f32_close(_predict(fam, xt)[:, 0], cubic, "family")


@pytest.mark.parametrize("init", ["kmeans", "quantiles"])
def test_cv_keeps_the_cubic_when_the_law_is_cubic_and_bends_when_it_is_not(init):
    """``ridge: cv``: white noise about a cubic → the tail alone (λ = ∞, the one-SE rule
    prefers the smoother model); a resonance the cubic cannot follow (study 000's Lorentz
    curve) → a finite λ, and on held-out samples the network beats the cubic clearly."""
    rng = np.random.default_rng(1)
    x = np.linspace(-1.7, 1.7, 2000)[:, None]
    cubic_law = 0.4 * x - 0.2 * x ** 3
    bump = 0.5 / (1.0 + ((x - 0.4) / 0.15) ** 2)
    noise = 0.02 * rng.standard_normal(x.shape)
    y = np.hstack([cubic_law + noise, cubic_law + bump + noise])
    # every other 50-sample block held out (contiguous, like time)
    held = (np.arange(x.shape[0]) // 50) % 2 == 1
    fam = _fit(x[~held], y[~held], n_centres=16, tail=3, ridge="cv", init=init)
    tuned = fam.tuned()
    assert tuned["ridge"][0] == "inf"
    assert tuned["ridge"][1] != "inf" and tuned["ridge"][1] in RIDGE_GRID
    assert tuned["width_scale"] in (0.5, 1.0, 2.0)
    assert not fam.trainable()                               # the penalised fit is final
    pred = _predict(fam, x[held])
    cubic = np.column_stack([Polynomial.fit(x[~held, 0], y[~held, a], 3)(x[held, 0])
                             for a in range(2)])
    truth = np.hstack([cubic_law, cubic_law + bump])[held]
    rms = lambda p: np.sqrt(((p - truth) ** 2).mean(axis=0))  # noqa: E731
    # axis 0: the cubic itself (to float32 rounding of the fit at the data's scale)
    assert_f32_close(pred[:, 0], cubic[:, 0], "family", scale=np.abs(y[:, 0]).max())
    assert rms(pred)[1] < 0.5 * rms(cubic)[1]               # measured 0.26 of the cubic's error


def test_quantile_centres_follow_the_data_one_per_dwell_temperature():
    """A warm-up that dwells at 20 °C for 60 % of the log, then ramps evenly to 60 °C: the
    ramp's centres sit at its quantiles (evenly spaced there), the dwell holds one centre,
    none closer than half an even grid step, all inside the data; the ΔT² input is
    interpolated on the curve (within the chord error of its sample spacing)."""
    t = np.concatenate([np.full(600, 20.0), np.linspace(20.0, 60.0, 401)[1:]])
    x = np.column_stack([t - 25.0, (t - 25.0) ** 2])
    c = quantile_centres(x, 8)
    gap = 40.0 / (2 * 7)
    assert np.all(np.diff(c[:, 0]) >= gap - 1e-9)
    assert c[0, 0] == pytest.approx(-5.0) and np.sum(np.abs(c[:, 0] + 5.0) < gap) == 1
    assert -5.0 <= c[:, 0].min() and c[:, 0].max() <= 35.0
    # ramp samples 0.1 °C apart: chord error of x² at most (0.1)² / 4
    np.testing.assert_allclose(c[:, 1], c[:, 0] ** 2, rtol=0, atol=0.1 ** 2 / 4 + 1e-9)
    # evenly spread data: the centres are its quantiles (k + 1/2) / n
    u = np.linspace(0.0, 1.0, 10_001)[:, None]
    np.testing.assert_allclose(quantile_centres(u, 5)[:, 0], [0.1, 0.3, 0.5, 0.7, 0.9],
                               rtol=0, atol=1e-12)


def test_quantile_centres_depend_on_the_data_alone_and_need_no_scikit_learn():
    """The same centres whatever the seed, and fitting imports no scikit-learn (its import
    was most of a calibration's comparison: thermonet.workflows.calibrate)."""
    rng = np.random.default_rng(3)
    x = np.sort(rng.uniform(-2.0, 2.0, 300))[:, None]
    y = np.column_stack([np.sin(2.0 * x[:, 0])])
    a = RBF(n_inputs=1, n_outputs=1, n_centres=8, tail=3, init="quantiles")
    b = RBF(n_inputs=1, n_outputs=1, n_centres=8, tail=3, init="quantiles")
    a.initialize(torch.as_tensor(x), torch.as_tensor(y), seed=0)
    b.initialize(torch.as_tensor(x), torch.as_tensor(y), seed=7)
    assert torch.equal(a.centres, b.centres) and torch.equal(a.weight, b.weight)
    code = ("import sys, numpy as np, torch\n"
            "from thermonet.models.rbf import RBF\n"
            "x = np.linspace(-2, 2, 300)[:, None]\n"
            "f = RBF(n_inputs=1, n_outputs=1, n_centres=8, tail=3, init='quantiles')\n"
            "f.initialize(torch.as_tensor(x), torch.as_tensor(np.sin(x)))\n"
            "print('sklearn' in sys.modules, f.tuned()['width_scale'] > 0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.split() == ["False", "True"]


def test_quantile_centres_refuse_a_first_input_that_never_changes():
    x = np.column_stack([np.zeros(200), np.linspace(-1.0, 1.0, 200)])
    fam = RBF(n_inputs=2, n_outputs=1, n_centres=4, init="quantiles")
    assert "init 'quantiles'" in fam.check_fittable(torch.as_tensor(x))


@pytest.mark.parametrize("hyper, pattern", [
    ({"tail": 4}, "tail must be an integer in 0..3"),
    ({"tail": True}, "tail must be an integer"),
    ({"tail": 3, "init": "random"}, "needs init 'kmeans' or 'quantiles'"),
    ({"tail": 3, "ridge": -1.0}, "ridge must be 'cv' or a finite number >= 0"),
    ({"tail": 3, "ridge": math.inf}, "ridge must be 'cv' or a finite number >= 0"),
    ({"tail": 3, "ridge": "auto"}, "ridge must be 'cv'"),
])
def test_bad_tail_hyper_parameters_are_refused(hyper, pattern):
    with pytest.raises(ConfigError, match=pattern):
        RBF(n_inputs=2, n_outputs=1, **hyper)


def test_without_a_tail_nothing_changes():
    """``tail: 0`` (the default) keeps the original network, hyper-parameters and state."""
    fam = RBF(n_inputs=2, n_outputs=3, n_centres=4)
    assert fam.hyper() == {"n_centres": 4, "init": "kmeans", "width_scale": 1.0}
    assert set(fam.state_dict()) == {"centres", "log_sigma", "weight", "bias"}
    assert fam.trainable() and fam.tuned() == {}


def test_a_comparison_records_what_the_tail_network_chose_and_costs(tmp_path):
    """results.json carries the inner cross-validation's choice and the cost per sample; the
    closed-form fit records no gradient epoch; an axis whose ridge went to ∞ is the cubic."""
    from thermonet.sim import simulate
    from thermonet.training.config import CompareConfig, FamilyConfig
    from thermonet.workflows.compare import run_compare

    cfg = CompareConfig(families=[
        FamilyConfig(family="poly", name="cubic", inputs=["dT"], params={"degree": 3}),
        FamilyConfig(family="rbf", name="rbf", inputs=["dT", "dT2"],
                     params={"n_centres": 16, "tail": 3})])
    ds = simulate("patent-gyro", runs=4, seed=0, sample_rate_hz=0.05)
    res = run_compare(cfg, tmp_path / "out", dataset=ds, track=False, quiet=True, plots=False)
    rbf, cubic = res["families"]["rbf"], res["families"]["cubic"]
    axes = list(rbf["axes"])
    assert rbf["best_epoch"] == 0 and cubic["tuned"] == {}
    assert rbf["tuned"]["width_scale"] in (0.5, 1.0, 2.0) and len(rbf["tuned"]["ridge"]) == 3
    assert all(r == "inf" or r in RIDGE_GRID for r in rbf["tuned"]["ridge"])
    # F + J(F+1) + J + (d−1) + A(J+d) = 2 + 48 + 16 + 2 + 3·19 (tests/test_mlp.py derives it)
    assert rbf["cost"] == {"ops_per_sample": 125, "transcendentals": 16, "c_bytes": 496}
    assert cubic["cost"]["transcendentals"] == 0
    assert "inf" in rbf["tuned"]["ridge"]      # measured: gyro_x ∞, gyro_y 1, gyro_z 0.1
    for axis, ridge in zip(axes, rbf["tuned"]["ridge"], strict=True):
        if ridge == "inf":   # the tail alone: the cubic's test score to float32 rounding
            assert rbf["axes"][axis]["score_comp"] == pytest.approx(
                cubic["axes"][axis]["score_comp"], rel=DEPTH["family"] * EPS32)


def _three_cubics(n: int = 1200) -> object:
    """Three axes, each a cubic law in T − 25 °C (no Gaussian structure) + white noise."""
    from thermonet.core.recording import Recording

    coef = np.array([[0.1, 0.02, -3e-4, 4e-6], [-0.05, 0.01, 2e-4, -3e-6],
                     [0.02, -0.015, 1e-4, 5e-6]])
    rng = np.random.default_rng(0)
    t = np.arange(n, dtype=float)
    temp = -10.0 + 60.0 * t / t[-1]
    outs = {f"gyro_{a}": np.polynomial.polynomial.polyval(temp - 25.0, coef[j])
            + rng.normal(0.0, 0.01, n) for j, a in enumerate("xyz")}
    return Recording(time_s=t, temperature_c=temp, outputs=outs, run_id="r",
                     units={**{k: "deg/s" for k in outs}, "temperature_c": "degC"},
                     sample_rate_hz=1.0)


def test_a_tail_alone_reports_what_it_computes(tmp_path):
    """Ridge ∞ on every axis: the network *is* its cubic tail, and says so — the cubic's
    parameter and operation counts (no exp), the cubic's coefficients with their standard
    errors in physical units, a C header without the Gaussian part that still evaluates the
    model; loaded back, it states the same and the width it tuned."""
    from thermonet import DriftEstimator
    from thermonet.exporting.c_export import c_parity_check
    from thermonet.exporting.c_header import render_c_header

    rec = _three_cubics()
    rbf = DriftEstimator("rbf", ["dT", "dT2"], n_centres=16, tail=3, t_ref=25.0).fit(rec)
    cubic = DriftEstimator("poly", ["dT"], degree=3, t_ref=25.0, max_epochs=0).fit(rec)
    assert rbf.tuned_["ridge"] == ["inf"] * 3 and rbf.model_.family.gaussian_off()
    # 3 axes × (3 tail weights + bias) = the cubic's 3 × 4; ops: 2 powers + 3 × 3 terms
    assert rbf.n_params_ == cubic.n_params_ == 12
    assert rbf.model_.family.cost() == cubic.model_.family.cost() == {
        "ops_per_sample": 11, "transcendentals": 0, "c_bytes": 48}
    assert rbf.model_.n_structural == 2 * 16 + 16 + 3 * 16 + 3 + 3 * 3   # as built: 108
    # the same least squares (the tail alone is the cubic's solve): the same table
    got, want = rbf.parameters_, cubic.parameters_
    assert list(got["name"]) == list(want["name"]) and list(got["unit"]) == list(want["unit"])
    assert np.all(np.abs(got["value"] - want["value"]) < 1e-3 * want["stderr"])
    np.testing.assert_allclose(got["stderr"], want["stderr"], rtol=1e-6)
    text = render_c_header(rbf.model_)
    assert "exp" not in text.split("_rbf_w")[1] and "RBF_CENTRES" not in text
    assert c_parity_check(rbf.model_, text) is not None            # compiled and compared
    back = DriftEstimator.load(rbf.save(tmp_path / "rbf.pt"))
    assert back.n_params_ == 12 and back.tuned_ == rbf.tuned_
    assert back.get_params()["family__width_scale"] == rbf.tuned_["width_scale"] != 1.0
    assert back.get_params()["family__ridge"] == "cv"  # per-axis ∞: not one finite value
    np.testing.assert_array_equal(back.parameters_["stderr"], got["stderr"])
