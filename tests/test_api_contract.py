"""The researcher's API: scikit-learn's contract checked with scikit-learn's own
tools, parameters with standard errors against independent least squares and their coverage
over seeds, the guards, and ``thermonet.compare`` against the command line's workflow."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.linear_model import LinearRegression
from sklearn.model_selection import GridSearchCV, cross_val_score

import thermonet
from conftest import toy_dataset
from thermonet.core.errors import ConfigError, ThermonetError
from thermonet.core.recording import Dataset, Recording
from tolerances import assert_f64_close

C_TRUE = np.array([0.1, 0.02, -3e-4, 4e-6])     # deg/s / °C^k about 25 °C


def cubic_run(seed: int, *, n: int = 400, sigma: float = 0.01, t0: float = 0.0,
              t1: float = 50.0, run_id: str | None = None) -> Recording:
    """A 1 Hz ramp t0 → t1 °C with drift sum_k C_TRUE[k] (T − 25)^k + white noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    temp = t0 + (t1 - t0) * t / t[-1]
    drift = np.polynomial.polynomial.polyval(temp - 25.0, C_TRUE)
    return Recording(time_s=t, temperature_c=temp,
                     outputs={"gyro_x": drift + rng.normal(0.0, sigma, n)},
                     drift={"drift_gyro_x": drift},
                     units={"gyro_x": "deg/s", "temperature_c": "degC"}, device_id="syn",
                     run_id=run_id or f"s{seed}", sample_rate_hz=1.0)


def _one_line(call, exc=ValueError) -> str:
    with pytest.raises(exc) as info:
        call()
    msg = str(info.value)
    assert "\n" not in msg and isinstance(info.value, ThermonetError), (type(info.value), msg)
    return msg


# ------------------------------------------------------- scikit-learn's contract
def test_params_are_constructor_keywords_and_clone_round_trips():
    from thermonet.models.specs import Poly

    est = thermonet.DriftEstimator("poly", "dT", degree=2, seed=3, max_epochs=5)
    params = est.get_params()
    # the family's keywords fold into its spec; its hyper-parameters are nested parameters
    assert params["family"] == Poly(degree=2) and params["inputs"] == "dT"
    assert params["family__degree"] == 2 and params["family__cross"] is False
    assert params["seed"] == 3 and params["max_epochs"] == 5
    assert params["lr"] is None and est.family.degree == 2
    assert "degree" not in params and not hasattr(est, "hyper")
    twin = clone(est)                                          # scikit-learn's own clone
    assert twin is not est and twin.get_params() == params
    assert twin.family is not est.family                       # the spec is cloned too
    assert est.set_params(family__degree=4, max_epochs=7) is est
    assert (est.family.degree, est.max_epochs) == (4, 7) and twin.family.degree == 2
    assert est.set_params(degree=5).family.degree == 5          # a bare name: family__degree
    # set_params(**get_params()) is the identity, as scikit-learn requires
    same = twin.get_params()
    assert clone(twin).set_params(**same).get_params() == same
    assert same["family__degree"] == 2 and same["max_epochs"] == 5
    msg = _one_line(lambda: est.set_params(degre=3))
    assert "'degre'" in msg and "degree, cross" in msg
    msg = _one_line(lambda: est.set_params(family__degre=3))
    assert "'degre'" in msg and "degree, cross" in msg
    # a family given by name is stored as given, and becomes its spec when a nested value is set
    named = thermonet.DriftEstimator("poly", "dT")
    assert named.family == "poly" and named.get_params(deep=True)["family"] == "poly"
    assert named.set_params(family__degree=2).family == Poly(degree=2)
    assert thermonet.DriftEstimator(Poly(degree=2), "dT", seed=3, max_epochs=5).get_params() \
        == same
    # a fitted estimator clones unfitted, with the same parameters
    fitted = thermonet.DriftEstimator("poly", "dT", degree=2).fit(cubic_run(0))
    again = clone(fitted)
    assert hasattr(fitted, "model_") and not hasattr(again, "model_")
    assert again.get_params() == fitted.get_params()


def test_learned_state_ends_in_underscore_and_is_set_by_fit_only():
    est = thermonet.DriftEstimator("poly", "dT", degree=3)
    before = set(vars(est))
    est.fit(cubic_run(1))
    learned = set(vars(est)) - before
    assert learned and all(k.endswith("_") for k in learned), sorted(learned)
    assert {"model_", "spec_", "parameters_", "covariance_", "n_features_in_",
            "units_"} <= learned
    assert est.n_features_in_ == 1
    assert set(vars(est)) - learned == before                 # the parameters untouched


def test_training_settings_as_keywords_or_a_dict():
    rec = cubic_run(2)
    a = thermonet.DriftEstimator("poly", "dT", degree=3, train={"max_epochs": 5}).fit(rec)
    b = thermonet.DriftEstimator("poly", ["dT"], degree=3, max_epochs=5).fit(rec)
    c = thermonet.DriftEstimator("poly", ["dT"], degree=3,
                                 train=thermonet.TrainConfig(max_epochs=9), max_epochs=5).fit(rec)
    assert a.train_config_.max_epochs == b.train_config_.max_epochs == c.train_config_.max_epochs == 5
    # the same settings, the same computation: bit-identical (inputs "dT" is ["dT"])
    np.testing.assert_array_equal(a.predict(rec), b.predict(rec))
    np.testing.assert_array_equal(a.predict(rec), c.predict(rec))
    assert thermonet.DriftEstimator("poly", "dT", degree=3, seed=3).fit(rec) \
        .train_config_.seed == 3
    d = thermonet.DriftEstimator("poly", "dT", degree=3, outputs="gyro_x").fit(rec)
    assert d.outputs_ == ["gyro_x"]


@pytest.mark.parametrize("kwargs, patterns", [
    ({"train": {"max_epoch": 5}}, ("train.max_epoch", "unknown key")),
    ({"train": 5}, ("train: expected a TrainConfig or a dict", "got int")),
    ({"max_epochs": -1}, ("train.max_epochs", "-1")),
    ({"seed": "three"}, ("train.seed", "'three'")),
    ({"inputs": ["dT", 3]}, ("inputs: expected names", "3")),
    ({"inputs": []}, ("inputs: an empty list",)),
    ({"outputs": 7}, ("outputs: expected a name or a list of names", "7")),
    ({"family": 3}, ("family: expected a family name", "3")),
    ({"inputs": "dTT"}, ("dTT",)),
    ({"degree": 0}, ("degree", "0")),
])
def test_bad_arguments_are_one_line_naming_the_argument(kwargs, patterns):
    kwargs = {"family": "poly", "inputs": "dT", **kwargs}
    msg = _one_line(lambda: thermonet.DriftEstimator(**kwargs).fit(cubic_run(3)))
    for p in patterns:
        assert p in msg, msg


# ------------------------------------------------------------------------ guards
def test_scoring_data_in_another_unit_is_refused_naming_both():
    est = thermonet.DriftEstimator("poly", "dT", degree=3).fit(cubic_run(4))
    other = cubic_run(5)
    rad = replace(other, outputs={"gyro_x": np.deg2rad(other.outputs["gyro_x"])},
                  units={**other.units, "gyro_x": "rad/s"})
    for call in (est.score, est.compensate):
        msg = _one_line(lambda call=call: call(rad))
        assert "'rad/s'" in msg and "'deg/s'" in msg and "run 's5'" in msg
    msg = _one_line(lambda: thermonet.DriftEstimator("poly", "dT", degree=3)
                    .fit(cubic_run(4), val=rad))
    assert "fit(val)" in msg and "'rad/s'" in msg and "'deg/s'" in msg


def test_a_validation_run_that_is_also_a_training_run_is_refused():
    ds = Dataset([cubic_run(k) for k in range(3)])
    est = thermonet.DriftEstimator("poly", "dT", degree=3)
    msg = _one_line(lambda: est.fit(ds, val=ds[2]))
    assert "fit(val): run 's2' is also a training run" in msg
    # the same run read twice (another object, the same samples) is the same run
    _one_line(lambda: est.fit(ds[:2] if isinstance(ds[:2], list) else ds.runs[:2],
                              val=replace(ds[1])))
    assert not hasattr(est, "model_")
    assert est.fit(ds.runs[:2], val=ds[2]) is est


def test_too_narrow_a_temperature_span_is_refused_as_compare_refuses_it():
    soak = cubic_run(6, t0=24.9, t1=25.21)                    # a 0.31 °C soak
    msg = _one_line(lambda: thermonet.DriftEstimator("poly", "dT", degree=3).fit(soak))
    assert "fit(train)" in msg and "temperature spans only 0.31 °C" in msg
    # two soaks together span enough (the BMI270 case: one soak each, 13 and 49 °C)
    other = cubic_run(7, t0=30.0, t1=30.3, run_id="hot")
    assert thermonet.DriftEstimator("poly", "dT", degree=1).fit([soak, other]).n_params_ == 2


def test_compare_refuses_a_split_whose_training_runs_span_too_little(tmp_path):
    """compare checks the span of what each split trains on, as the API checks its training
    runs — not only the whole dataset's (a wide test run does not make a soak trainable)."""
    from thermonet.core.errors import InputError
    from thermonet.core.recording import Dataset
    from thermonet.training.config import config_from_mapping
    from thermonet.workflows.compare import run_compare

    soak = cubic_run(6, t0=24.9, t1=25.21, run_id="soak")
    ramp = cubic_run(8, t0=0.0, t1=50.0, run_id="ramp")
    cfg = config_from_mapping({"split": {"strategy": "train-then-verify"},
                               "families": [{"family": "poly", "params": {"degree": 1}}],
                               "tracking": {"enabled": False}})
    msg = _one_line(lambda: run_compare(cfg, tmp_path / "out", dataset=Dataset([soak, ramp]),
                                        quiet=True, plots=False), InputError)
    assert "the training data (runs soak[train]) span only 0.31 °C" in msg
    assert not (tmp_path / "out").exists()                    # nothing half-written


# ---------------------------------------------------------- parameters, stderr
def test_polynomial_coefficients_equal_least_squares_in_physical_units():
    rec = cubic_run(8)
    est = thermonet.DriftEstimator("poly", "dT", t_ref=25.0, degree=3, max_epochs=0).fit(rec)
    table = est.parameters_
    assert list(table.columns) == ["axis", "name", "value", "stderr", "unit", "note"]
    assert list(table["name"]) == ["c0", "c1", "c2", "c3"]
    assert list(table["unit"]) == ["deg/s", "deg/s/°C", "deg/s/°C^2", "deg/s/°C^3"]
    # oracle: scikit-learn's least squares on (T − 25)^k
    u = rec.temperature_c - 25.0
    x = np.column_stack([u, u ** 2, u ** 3])
    y = rec.outputs["gyro_x"]
    lr = LinearRegression().fit(x, y)
    oracle = np.concatenate([[lr.intercept_], lr.coef_])
    stderr = table["stderr"].to_numpy()
    # the model's coefficients are float32 (as exported): within 1e-3 standard errors
    assert np.all(np.abs(table["value"].to_numpy() - oracle) < 1e-3 * stderr)
    # stderr: residual variance × (XᵀX)⁻¹, by hand
    d = np.column_stack([np.ones_like(u), x])
    resid = y - d @ oracle
    cov = resid @ resid / (u.size - 4) * np.linalg.inv(d.T @ d)
    np.testing.assert_allclose(stderr, np.sqrt(np.diag(cov)), rtol=1e-4)
    got = est.covariance_["gyro_x"]
    scale = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    np.testing.assert_allclose(got / scale, cov / scale, rtol=0, atol=1e-6)   # correlations
    # a T model reports the same curve about T_ref (its coefficients are in T − T_ref)
    on_t = thermonet.DriftEstimator("poly", "T", t_ref=25.0, degree=3, max_epochs=0).fit(rec)
    np.testing.assert_allclose(on_t.parameters_["value"], oracle, rtol=1e-4,
                               atol=1e-3 * stderr.min())
    assert "c3" in est.report() and "+/-" in est.report()


def test_stated_uncertainties_cover_the_true_coefficients_over_100_seeds():
    values, errors, oracle = [], [], []
    for seed in range(100):
        rec = cubic_run(1000 + seed, n=200)
        est = thermonet.DriftEstimator("poly", "dT", t_ref=25.0, degree=3,
                                       max_epochs=0).fit(rec)
        values.append(est.parameters_["value"].to_numpy())
        errors.append(est.parameters_["stderr"].to_numpy())
        # numpy's least squares and covariance on the same data, by hand
        d = np.vander(rec.temperature_c - 25.0, 4, increasing=True)
        c = np.linalg.lstsq(d, rec.outputs["gyro_x"], rcond=None)[0]
        r = rec.outputs["gyro_x"] - d @ c
        oracle.append(np.abs(c - C_TRUE) <= 2.0 * np.sqrt(np.diag(
            r @ r / (d.shape[0] - 4) * np.linalg.inv(d.T @ d))))
    v, e = np.array(values), np.array(errors)
    inside = np.abs(v - C_TRUE) <= 2.0 * e                    # (100 seeds, 4 coefficients)
    # the same calls as numpy's, seed by seed and coefficient by coefficient
    np.testing.assert_array_equal(inside, np.array(oracle))
    # ±2 standard errors hold 95.4 % for white noise (t, 196 dof): these 100 seeds give
    # 92.5 % (0.91-0.94 per coefficient; numpy alike; 95.2 % over 4000 seeds); the four
    # coefficients of one seed are correlated, so the binomial sd (1.1 %) is a lower bound
    assert 0.90 <= inside.mean() <= 0.99, inside.mean(axis=0)
    assert np.all(inside.mean(axis=0) >= 0.88), inside.mean(axis=0)
    # the stated error is the spread over seeds (sd of a sd from 100 draws: 7 %)
    np.testing.assert_allclose(v.std(axis=0, ddof=1), e.mean(axis=0), rtol=0.2)


def ar1_run(seed: int, *, n: int = 2000, phi: float = 0.8, sigma: float = 0.01) -> Recording:
    """The cubic law of :func:`cubic_run` on a 0 → 50 °C ramp with AR(1) noise
    (correlation time (1 + phi) / (1 − phi) = 9 samples at phi 0.8)."""
    rng = np.random.default_rng(seed)
    e = rng.normal(0.0, sigma, n)
    noise = np.empty(n)
    noise[0] = e[0]
    for i in range(1, n):
        noise[i] = phi * noise[i - 1] + e[i]
    t = np.arange(n, dtype=float)
    temp = 50.0 * t / t[-1]
    drift = np.polynomial.polynomial.polyval(temp - 25.0, C_TRUE)
    return Recording(time_s=t, temperature_c=temp, outputs={"gyro_x": drift + noise},
                     units={"gyro_x": "deg/s", "temperature_c": "degC"}, run_id=f"a{seed}",
                     sample_rate_hz=1.0)


def test_the_block_bootstrap_states_the_uncertainty_of_correlated_residuals():
    values, ols, boot = [], [], []
    for seed in range(40):
        rec = ar1_run(2000 + seed)
        a = thermonet.DriftEstimator("poly", "dT", t_ref=25.0, degree=3, max_epochs=0).fit(rec)
        b = thermonet.DriftEstimator("poly", "dT", t_ref=25.0, degree=3, max_epochs=0,
                                     stderr="block-bootstrap", seed=seed).fit(rec)
        np.testing.assert_array_equal(a.parameters_["value"], b.parameters_["value"])
        values.append(a.parameters_["value"].to_numpy())
        ols.append(a.parameters_["stderr"].to_numpy())
        boot.append(b.parameters_["stderr"].to_numpy())
    v, e_ols, e_boot = np.array(values), np.array(ols), np.array(boot)
    spread = v.std(axis=0, ddof=1)                # the truth, over 40 seeds (sd of it: 11 %)
    # least squares assumes white residuals: about 1/3 of the spread here (measured 0.32-0.35)
    assert np.all(e_ols.mean(axis=0) / spread < 0.5)
    # the bootstrap keeps the correlation (measured 0.84-0.91 of the spread over 60 seeds)
    np.testing.assert_allclose(e_boot.mean(axis=0) / spread, 1.0, atol=0.35)
    assert (np.abs(v - C_TRUE) <= 2.0 * e_boot).mean() >= 0.85
    # white residuals: the bootstrap agrees with least squares
    white = [thermonet.DriftEstimator("poly", "dT", t_ref=25.0, degree=3, max_epochs=0,
                                      stderr=m).fit(cubic_run(3000 + k, n=1000))
             .parameters_["stderr"].to_numpy() for k in range(10) for m in ("ols", "block-bootstrap")]
    ratio = np.array(white[1::2]).mean(axis=0) / np.array(white[0::2]).mean(axis=0)
    np.testing.assert_allclose(ratio, 1.0, atol=0.15)
    msg = _one_line(lambda: thermonet.DriftEstimator("poly", "dT", stderr="hac").fit(cubic_run(0)))
    assert "stderr: 'hac'" in msg


@pytest.mark.parametrize("method", ["ols", "block-bootstrap"])
def test_the_note_names_the_stderr_method_and_coefficients_within_2_se_of_zero(method):
    """``parameters_`` says which method made each standard error (``note``), and notes a
    coefficient within 2 SE of zero: a drift with no cubic term fitted by a cubic has c3 within
    them, the large c1 not; a loaded estimator (and one sealed before the note named the
    method: notes '') says the same."""
    from thermonet.api.parameters import NEAR_ZERO
    from thermonet.training.parameters import with_sealed

    rec = cubic_run(3, sigma=0.05)
    flat = replace(rec, outputs={"gyro_x": rec.outputs["gyro_x"]
                                 - C_TRUE[3] * (rec.temperature_c - 25.0) ** 3})
    est = thermonet.DriftEstimator("poly", "dT", degree=3, t_ref=25.0, stderr=method,
                                   max_epochs=0).fit(flat)
    p = est.parameters_.set_index("name")
    near = (p["value"].abs() < 2 * p["stderr"])
    assert near["c3"] and not near["c1"]
    for name, row in p.iterrows():
        assert row["note"] == (f"{method}; {NEAR_ZERO}" if near[name] else method), name
    # an older checkpoint's sealed notes ('' where computed) name the method on load
    old = {"method": method, "covariance": {},
           "rows": [{"axis": "gyro_x", "name": n, "stderr": float(e), "note": ""}
                    for n, e in zip(p.index, p["stderr"], strict=True)]}
    table, _, got = with_sealed(est.parameters_.assign(note=""), {}, old, "old.pt")
    assert got == method and list(table["note"]) == list(est.parameters_["note"])


def test_linear_and_lorentz_parameters_in_physical_units():
    rec = cubic_run(9)
    lin = thermonet.DriftEstimator("linear", "T", t_ref=25.0, max_epochs=0).fit(rec)
    u = rec.temperature_c - 25.0
    slope, icpt = np.polyfit(u, rec.outputs["gyro_x"], 1)
    np.testing.assert_allclose(lin.parameters_["value"], [icpt, slope], rtol=1e-5)
    assert list(lin.parameters_["unit"]) == ["deg/s", "deg/s/°C"]
    assert lin.parameters_["stderr"].notna().all()
    # a Lorentz peak: y0 + 2A/pi w / (4 (T - xc)^2 + w^2), y0 0.01 deg/s, A 2 deg/s °C,
    # centre 32 °C, width 8 °C
    t = np.arange(600.0)
    temp = 10.0 + 40.0 * t / t[-1]
    y0, amp, xc, w = 0.01, 2.0, 32.0, 8.0
    peak = y0 + 2 * amp / np.pi * w / (4 * (temp - xc) ** 2 + w * w)
    noise = np.random.default_rng(0).normal(0, 1e-4, t.size)
    lor = Recording(time_s=t, temperature_c=temp, outputs={"gyro_x": peak + noise},
                    units={"gyro_x": "deg/s", "temperature_c": "degC"}, run_id="lor",
                    sample_rate_hz=1.0)
    for inputs in ("T", "dT"):
        est = thermonet.DriftEstimator("lorentz", inputs, max_epochs=300).fit(lor)
        p = est.parameters_.set_index("name")
        np.testing.assert_allclose(p.loc[["y0", "amplitude", "centre", "width"], "value"],
                                   [y0, amp, xc, w], rtol=2e-2, atol=1e-3)
        assert p.loc["centre", "unit"] == "°C" and p.loc["amplitude", "unit"] == "deg/s*°C"
        assert p["stderr"].isna().all()


def proxy_run(unit: str) -> Recording:
    """cubic_run's ramp with a proxy ``temp_raw`` (10 per °C) in ``unit`` beside it."""
    rec = cubic_run(12)
    return replace(rec, proxies={"temp_raw": 10.0 * rec.temperature_c},
                   units={**rec.units, "temp_raw": unit})


@pytest.mark.parametrize(("unit", "expected"), [("1", ["deg/s", "deg/s", "deg/s"]),
                                                ("counts", ["deg/s", "deg/s/counts",
                                                            "deg/s/counts^2"])])
def test_a_coefficient_per_proxy_unit_names_the_proxys_unit_or_none(unit, expected):
    """A coefficient per unit of a proxy without a unit (``1``) is in the output's unit alone
    (was 'deg/s/1'); a proxy with a unit (``counts``) is named."""
    est = thermonet.DriftEstimator("poly", "d_temp_raw", degree=2, max_epochs=0).fit(
        proxy_run(unit))
    assert list(est.parameters_["unit"]) == expected
    assert not any(u.endswith(("/1", "/1^2")) for u in est.parameters_["unit"])


def test_rbf_and_lorentz_tables_reproduce_the_models_curve():
    """The physical parameters are the model: the curve rebuilt from the table alone (numpy,
    float64) is the model's prediction, so the units and references in the table are right."""
    rec = cubic_run(11, n=600)
    t = rec.temperature_c
    rbf = thermonet.DriftEstimator("rbf", "dT", n_centres=6).fit(rec)
    p = rbf.parameters_.set_index("name")["value"]
    x = t - rbf.spec_.t_ref                                    # dT, °C about T_ref
    curve = p["bias"] + sum(p[f"w{c}"] * np.exp(-(x - p[f"centre{c}"]) ** 2
                                                / (2.0 * p[f"sigma{c}"] ** 2)) for c in range(6))
    scale = np.ptp(rbf.predict(rec))
    np.testing.assert_allclose(curve, rbf.predict(rec)[:, 0], atol=1e-5 * scale)
    assert set(rbf.parameters_["unit"]) == {"deg/s", "°C"}
    lor = thermonet.DriftEstimator("lorentz", "T", max_epochs=50).fit(rec)
    q = lor.parameters_.set_index("name")["value"]
    curve = q["y0"] + 2 * q["amplitude"] / np.pi * q["width"] / (
        4 * (t - q["centre"]) ** 2 + q["width"] ** 2)
    np.testing.assert_allclose(curve, lor.predict(rec)[:, 0], atol=1e-5 * np.ptp(lor.predict(rec)))


def test_parameters_survive_save_and_load(tmp_path):
    """The standard errors and covariance a fit computed travel in its sealed checkpoint: the
    loaded estimator states the fresh fit's, bit for bit (values copied, not recomputed), and
    how they were computed (``stderr``); a checkpoint without them says why they are NaN."""
    from thermonet.api.parameters import NO_SE
    from thermonet.core.errors import InputError
    from thermonet.training.checkpoint import load_checkpoint, save_checkpoint

    for method in ("ols", "block-bootstrap"):
        est = thermonet.DriftEstimator("poly", "dT", degree=3, stderr=method,
                                       seed=1).fit(cubic_run(10))
        back = thermonet.DriftEstimator.load(est.save(tmp_path / f"{method}.pt"))
        np.testing.assert_allclose(back.parameters_["value"], est.parameters_["value"],
                                   rtol=1e-12)
        # copied through the checkpoint: exactly the fit's
        np.testing.assert_array_equal(back.parameters_["stderr"], est.parameters_["stderr"])
        assert est.parameters_["stderr"].gt(0).all()
        assert list(back.parameters_["note"]) == list(est.parameters_["note"])
        assert set(back.parameters_["note"].str.split(";").str[0]) == {method}
        np.testing.assert_array_equal(back.covariance_["gyro_x"], est.covariance_["gyro_x"])
        assert back.get_params()["family__degree"] == 3 and back.get_params()["stderr"] == method
    # a checkpoint written without them (as before they were stored): NaN, with the reason
    model, meta = load_checkpoint(tmp_path / "ols.pt")
    bare = thermonet.DriftEstimator.load(save_checkpoint(tmp_path / "bare.pt", model,
                                                         config={}))
    assert bare.parameters_["stderr"].isna().all() and bare.covariance_ == {}
    assert set(bare.parameters_["note"]) == {NO_SE["unstored"]}
    # stored rows that are not the model's are refused, naming the key
    extra = dict(meta["extra"])
    extra["parameters"] = {**extra["parameters"], "rows": extra["parameters"]["rows"][:2]}
    save_checkpoint(tmp_path / "bad.pt", model, config={}, extra=extra)
    with pytest.raises(InputError, match="extra.parameters"):
        thermonet.DriftEstimator.load(tmp_path / "bad.pt")
    # a nonlinear fit's parameters say why they have no standard error
    lor = thermonet.DriftEstimator("lorentz", "T", max_epochs=20).fit(cubic_run(10))
    assert set(lor.parameters_["note"]) == {NO_SE["nonlinear"]}
    # a network's weights say plainly that they are no physical quantity
    mlp = thermonet.DriftEstimator("mlp", "dT", max_epochs=2).fit(cubic_run(10))
    assert set(mlp.parameters_["note"]) == {NO_SE["standardised"]}
    assert "not a physical parameter" in NO_SE["standardised"]


# --------------------------------------------- scikit-learn's model selection
def test_time_blocks_and_the_splitter_never_mix_a_block():
    ds = toy_dataset(n_runs=2, noise=0.002)
    blocks = thermonet.time_blocks(ds, n_blocks=20, purge_s=60)
    assert len(blocks) == 40 and blocks[0].run_id == "run0[b0]"
    for b in blocks:                                           # contiguous: 1 s steps inside
        assert np.all(np.diff(b.time_s) == 1.0)
    # adjacent blocks are 60 s apart (30 s cut from each side of each boundary)
    assert blocks[1].time_s[0] - blocks[0].time_s[-1] == pytest.approx(61.0, abs=1.0)
    cv = thermonet.TimeBlockSplit(n_splits=5)
    seen = np.zeros(len(blocks), int)
    for train, val in cv.split(blocks):
        assert not set(train) & set(val)
        seen[val] += 1
        temps = np.concatenate([blocks[i].temperature_c for i in val])
        # every fold's blocks reach within one fold's share (70 / 5 °C) of both ends
        assert temps.min() < -20 + 14 and temps.max() > 50.2 - 14
    assert np.all(seen == 1) and cv.get_n_splits() == 5
    # whole runs: one fold per run
    assert [list(v) for _, v in thermonet.TimeBlockSplit(2).split(ds.runs)] == [[0], [1]]
    _one_line(lambda: list(thermonet.TimeBlockSplit(5).split(ds.runs)))   # 2 runs, 5 folds


def test_cross_val_score_and_grid_search_over_time_blocks():
    ds = toy_dataset(n_runs=1, noise=0.002)
    blocks = thermonet.time_blocks(ds, n_blocks=20)
    cv = thermonet.TimeBlockSplit(n_splits=4)
    est = thermonet.DriftEstimator("poly", "T", degree=1, max_epochs=0)
    scores = cross_val_score(est, blocks, cv=cv)
    # oracle: numpy's least squares on the same folds, scored as DriftEstimator.score (the
    # error's spread about its mean over the fold's blocks of the one run, as compare's)
    expected = []
    for train, val in cv.split(blocks):
        t = np.concatenate([blocks[i].temperature_c for i in train])
        y = np.concatenate([blocks[i].outputs["gyro_x"] for i in train])
        coef = np.polyfit(t, y, 1)
        # evaluated as on board: clamped to the trained range
        tv = np.clip(np.concatenate([blocks[i].temperature_c for i in val]), t.min(), t.max())
        yv = np.concatenate([blocks[i].outputs["gyro_x"] for i in val])
        ev = yv - np.polyval(coef, tv)
        expected.append(1.0 - np.sum((ev - ev.mean()) ** 2) / np.sum((yv - yv.mean()) ** 2))
    np.testing.assert_allclose(scores, expected, atol=1e-6)
    search = GridSearchCV(est, {"degree": [1, 2, 3]}, cv=cv).fit(blocks)
    means = search.cv_results_["mean_test_score"]
    # the toy drift is quadratic: a line leaves its curvature, degree 2 and 3 do not
    assert means[0] < means[1] - 1e-3 and search.best_params_["degree"] in (2, 3)
    assert search.best_estimator_.family.degree == search.best_params_["degree"]
    assert search.best_estimator_.score(ds[0]) > 0.99


# --------------------------------------------------------------- compare()
def test_compare_from_python_is_the_command_lines_comparison(tmp_path, monkeypatch):
    from thermonet.training.config import config_from_mapping
    from thermonet.workflows.compare import run_compare

    monkeypatch.chdir(tmp_path)
    ds = toy_dataset(n_runs=3, noise=0.002)
    config = {"families": [{"name": "line", "family": "poly", "inputs": ["dT"],
                            "params": {"degree": 1}},
                           {"name": "cubic", "family": "poly", "inputs": ["dT"],
                            "params": {"degree": 3}}],
              "baseline": "cubic"}
    res = thermonet.compare(config, data=ds)
    assert list(tmp_path.iterdir()) == []                      # nothing written without out
    assert set(res.families) == {"line", "cubic"} and res.chosen in res.families
    assert res.families["cubic"].ok and res.families["cubic"].axes["gyro_x"].score_ratio < 0.5
    assert isinstance(res.warnings, list) and "chosen" in res.table()
    # the workflow itself, as the command line runs it: the same numbers
    cli = run_compare(config_from_mapping(config), tmp_path / "cli", dataset=ds, quiet=True,
                      plots=False, track=False)
    # every number but the wall-clock time and where the checkpoint was written: identical
    skip = ("checkpoint", "checkpoint_sha256", "fit_seconds")

    def same(doc):
        return json.loads(json.dumps({k: {f: x for f, x in v.items() if f not in skip}
                                      for k, v in doc["families"].items()}))

    assert same(cli) == same(res.results)
    for key in ("chosen", "chosen_reason", "selection", "warnings", "data_hash", "split"):
        assert cli[key] == res.results[key], key
    est = res.estimator("cubic")
    from_cli = thermonet.DriftEstimator.load(tmp_path / "cli" / "models" / "cubic.pt")
    np.testing.assert_array_equal(est.predict(ds[2]), from_cli.predict(ds[2]))
    scores = res.scores()
    assert list(scores["family"]) == ["line", "cubic"]
    # with out, the files are there
    kept = thermonet.compare(config, data=ds, out=tmp_path / "kept", plots=False)
    assert (tmp_path / "kept" / "results.json").is_file() and kept.out == tmp_path / "kept"
    with pytest.raises(ThermonetError, match="no family named 'quartic'"):
        res.estimator("quartic")
    with pytest.raises(ConfigError, match="compare\\(config\\): expected"):
        thermonet.compare(42)
    with pytest.raises(ConfigError, match="compare\\(config\\): key 'famiiles'"):
        thermonet.compare({"famiiles": []}, data=ds)


# ------------------------------------------------------------------ the README
def test_readme_api_section_runs_and_shows_what_it_prints(tmp_path, monkeypatch, capsys):
    """Every python block of the README's "Python API" section, run in order in one
    namespace; the ``text`` block is what the coefficient table prints."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    section = text[text.index("## Python API"):]
    section = section[:section.index("\n## ", 5)]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 5
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    from thermonet.models import FAMILIES, unregister_family
    try:
        for code in blocks:
            exec(compile(code, "README.md", "exec"), namespace)
    finally:      # the family of one's own is the README's to register and unregister
        if "hinge" in FAMILIES:
            unregister_family("hinge")
    out = capsys.readouterr().out
    res, search = namespace["res"], namespace["search"]
    assert res.chosen in ("quadratic", "cubic") and "chosen: " + res.chosen in out
    assert set(res.scores()["family"]) == {"line", "quadratic", "cubic"}
    # the simulated drift is quadratic: a line does not find it, degree 2 and up do
    means = search.cv_results_["mean_test_score"]
    assert means[0] < min(means[1:]) and search.best_params_["family__degree"] >= 2
    shown = re.search(r"```text\n(.*?)```", section, re.S).group(1).strip().splitlines()
    printed = [line.strip() for line in out.splitlines()]
    for line in shown:
        assert line.strip() in printed, (line, out[-2000:])
    assert namespace["est"].parameters_["stderr"].notna().all()
    # one class and one registration: a family by name, fitted, checked by its own rule, gone
    # again; on patent-gyro (a smooth drift) the hinge's two slopes cut most of it
    hinge, test = namespace["hinge"], namespace["test"]
    assert "hinge" not in FAMILIES and hinge.family.knee == 30.0
    assert 0.5 < hinge.score(test) <= 1.0


# ---------------------------------------- the API and the command line agree
def test_api_fit_is_compares_model_gravity_included(tmp_path):
    """consumer-imu (gyros and accelerometers, no reference channels): the estimator fitted
    as compare fits it (runs split: train run0, validate run1) is compare's model — the same
    drift on every axis compare compensates, its score is compare's test ratio, and the PX4
    file is the same once the API model carries compare's per-axis mask.  Gravity is no
    drift: the accelerometers' curves are zero at T_ref (the issue's TC_A0_X0_2 −9.81)."""
    from thermonet.exporting import read_px4_params

    ds = thermonet.simulate("consumer-imu", runs=3, seed=0)
    res = thermonet.compare({"families": [{"name": "cubic", "family": "poly",
                                           "inputs": ["dT"], "params": {"degree": 3}}]},
                            data=ds)
    cli = res.estimator("cubic")
    # compare refits on training + validation (selection.refit): the API fits both runs
    est = thermonet.DriftEstimator("poly", "dT", degree=3).fit(ds.runs[:2])
    assert est.targets_.as_dict() == res.results["targets"]
    mask = [res.families["cubic"].axes[a].compensate for a in est.outputs_]
    assert mask == cli.model_.compensated_axes and mask.count(False) == 1   # gyro_z left raw
    api, ref = est.predict(ds[2]), cli.predict(ds[2])
    # the same fit of the same parts: bit-identical where compare compensates, 0 where not
    np.testing.assert_array_equal(api[:, mask], ref[:, mask])
    assert np.all(ref[:, ~np.array(mask)] == 0.0)
    ratios = np.array([res.families["cubic"].axes[a].score_ratio for a in est.outputs_])
    assert est.score(ds[2]) == pytest.approx(1.0 - np.mean(ratios ** 2), rel=1e-9)
    table = est.parameters_.set_index(["axis", "name"])
    for axis in ("acc_x", "acc_y", "acc_z"):
        assert abs(table.loc[(axis, "c0"), "value"]) < 1e-6                 # not −9.81
        assert table.loc[(axis, "c0"), "stderr"] == 0.0
        assert table.loc[(axis, "c1"), "stderr"] > 0.0
    est.model_.set_compensate(mask)
    ours = read_px4_params(est.export(tmp_path / "api.params", format="px4-params",
                                      device_id=1234))
    theirs = read_px4_params(cli.export(tmp_path / "cli.params", format="px4-params",
                                        device_id=1234))
    assert ours == theirs and abs(ours["TC_A0_X0_2"]) < 1e-6
    # the standard errors compare states are the fresh fit's (the same least squares on the
    # same rows, sealed in its checkpoint), on every axis it compensates; the accelerometers'
    # c0 is fixed (0 by definition), the axis left raw has none, with the reason
    from thermonet.api.parameters import FIXED, NO_SE

    mine, theirs_t = est.parameters_, cli.parameters_
    keep = np.repeat(mask, 4)
    assert_f64_close(theirs_t["stderr"][keep], mine["stderr"][keep])
    assert list(theirs_t["note"][keep]) == list(mine["note"][keep])
    assert theirs_t["stderr"][~keep].isna().all()
    assert set(theirs_t["note"][~keep]) == {NO_SE["raw"]}
    fixed = mine.set_index(["axis", "name"]).loc[[(a, "c0") for a in ("acc_x", "acc_y",
                                                                       "acc_z")], "note"]
    assert set(fixed) == {FIXED}
    for axis, compensated in zip(est.outputs_, mask, strict=True):
        assert (axis in cli.covariance_) == compensated
        if compensated:
            assert_f64_close(cli.covariance_[axis], est.covariance_[axis])


# ------------------------------------------------------ provenance and tracking
def test_exports_carry_the_data_digest_validation_metrics_and_the_tracked_run(tmp_path,
                                                                              monkeypatch):
    import onnx

    monkeypatch.chdir(tmp_path)
    ds = Dataset([cubic_run(20 + k) for k in range(3)])
    est = thermonet.DriftEstimator("poly", "dT", degree=3).fit(
        ds.runs[:2], val=ds[2], tracking_uri=f"sqlite:///{tmp_path / 'ml.db'}")
    # compare's validation score: the offset-free RMS ratio on the validation run, by hand
    y = ds[2].outputs["gyro_x"]
    e = y - est.predict(ds[2])[:, 0]
    ratio = np.sqrt(np.sum((e - e.mean()) ** 2) / np.sum((y - y.mean()) ** 2))
    assert est.val_score_ == pytest.approx(ratio, rel=1e-9)
    assert est.val_ratios_ == {"gyro_x": pytest.approx(ratio, rel=1e-9)}
    assert len(est.mlflow_run_id_) == 32
    meta = {p.key: p.value for p in onnx.load(str(est.export(tmp_path / "m.onnx"))).metadata_props}
    assert meta["training_run_id"] == est.mlflow_run_id_         # strings are written as is
    assert meta["data_hash"] == est.data_source_["data_hash"] and len(meta["data_hash"]) == 16
    assert json.loads(meta["validation_metrics"])["val_score"] == pytest.approx(ratio, rel=1e-9)
    back = thermonet.DriftEstimator.load(est.save(tmp_path / "m.pt"))
    assert (back.val_score_, back.mlflow_run_id_) == (est.val_score_, est.mlflow_run_id_)
    # the run in the store: the parameters, the validation score and the model
    import mlflow

    mlflow.set_tracking_uri(f"sqlite:///{tmp_path / 'ml.db'}")
    run = mlflow.get_run(est.mlflow_run_id_)
    assert run.data.params["family"] == "poly" and run.data.params["degree"] == "3"
    assert run.data.metrics["val/score"] == pytest.approx(ratio, rel=1e-9)
    assert run.data.tags["data_hash"] == est.data_source_["data_hash"]
    artifacts = mlflow.tracking.MlflowClient().list_artifacts(est.mlflow_run_id_, "model")
    # the checkpoint beside the MLflow model's files (MLmodel, model.onnx …)
    assert {"model/poly.pt", "model/MLmodel", "model/model.onnx"} <= {a.path for a in artifacts}
    # and the MLflow model users load from the run: the estimator's drift, to float32
    from tolerances import assert_f32_close

    logged = mlflow.pyfunc.load_model(f"runs:/{est.mlflow_run_id_}/model")
    rec = ds[2]
    got = logged.predict({"temperature_c": rec.temperature_c.astype(np.float32),
                          "raw": rec.outputs["gyro_x"][:, None].astype(np.float64)})
    assert_f32_close(got["drift"], est.predict(rec), "family")
    assert logged.metadata.signature is not None
    # untracked: no run, and nothing written
    plain = thermonet.DriftEstimator("poly", "dT", degree=3).fit(ds.runs[:2])
    assert plain.mlflow_run_id_ == "" and plain.val_score_ is None


def test_api_fit_is_compares_model_on_a_real_recording(tmp_path):
    """The BMI270's two soaks at 50 Hz, split by time blocks: the estimator fitted on
    compare's training blocks (validated on its validation blocks) is compare's model — the
    same trained range (from 1-s averages, not raw samples: the issue's 0.730 vs 0.533),
    bit-identical predictions, compare's test score, the same PX4, ArduPilot and C files."""
    from pathlib import Path

    from conftest import REAL_DATA
    from thermonet.exporting import read_ardupilot_params, read_px4_params
    from thermonet.training.config import config_from_mapping
    from thermonet.training.parts import make_splits

    d = REAL_DATA / "bmi270_two_soaks"
    ds = thermonet.read([d / "BMI_270_cold_test_.csv", d / "BMI_270_hot_test.csv"],
                        mapping=Path(__file__).resolve().parents[1] / "configs" / "data"
                        / "bmi270.yaml")
    config = {"families": [{"name": "cubic", "family": "poly", "inputs": ["dT"],
                            "params": {"degree": 3}}], "split": {"strategy": "time-blocks"}}
    res = thermonet.compare(config, data=ds)
    cli = res.estimator("cubic")
    split = make_splits(ds, config_from_mapping(config).split)[-1]
    est = thermonet.DriftEstimator("poly", "dT", degree=3).fit([*split.train, split.val])
    for buf in ("sig_lo", "sig_hi", "x_mean", "x_std", "y_mean", "y_std"):
        assert torch_equal(getattr(est.model_, buf), getattr(cli.model_, buf)), buf
    assert cli.model_.compensated_axes == [True] * 6
    np.testing.assert_array_equal(est.predict(split.test), cli.predict(split.test))
    ratios = np.array([res.families["cubic"].axes[a].score_ratio for a in est.outputs_])
    assert est.score(split.test) == pytest.approx(1.0 - np.mean(ratios ** 2), rel=1e-7)
    for fmt, read in (("px4-params", read_px4_params),
                      ("ardupilot-params", read_ardupilot_params)):
        ours = read(est.export(tmp_path / f"api.{fmt}", format=fmt, device_id=1234))
        assert ours == read(cli.export(tmp_path / f"cli.{fmt}", format=fmt, device_id=1234))
    c_api = est.export(tmp_path / "api.h", format="c").read_text()
    c_cli = cli.export(tmp_path / "cli.h", format="c").read_text()
    # compare's checkpoint also carries the residual-drift band (from its out-of-fold
    # residuals, which an API fit has not): its block, before the include guard, set aside
    start, end = c_cli.index("/* Residual-drift band"), c_cli.index("#endif /* THERMONET_MODEL_H")
    assert "thermonet_band(" in c_cli[start:end] and "thermonet_band(" not in c_api
    c_cli = c_cli[:start] + c_cli[end:]
    code = [line for line in c_api.splitlines() if not line.lstrip().startswith(("//", "*", "/*"))]
    assert code == [line for line in c_cli.splitlines()
                    if not line.lstrip().startswith(("//", "*", "/*"))]


def torch_equal(a, b) -> bool:
    return bool((a == b).all())


_FAMILIES = [("linear", ["dT"]), ("poly", ["dT"]), ("lorentz", ["T"]), ("ts-fuzzy", ["dT"]),
             ("rbf", ["dT"]), ("mlp", ["dT"])]


@pytest.fixture(scope="module")
def bmi270_every_family():
    """One comparison of every built-in family on the BMI270's soaks (time-block split)."""
    from pathlib import Path

    from conftest import REAL_DATA
    from thermonet.training.config import config_from_mapping
    from thermonet.training.parts import make_splits

    d = REAL_DATA / "bmi270_two_soaks"
    ds = thermonet.read([d / "BMI_270_cold_test_.csv", d / "BMI_270_hot_test.csv"],
                        mapping=Path(__file__).resolve().parents[1] / "configs" / "data"
                        / "bmi270.yaml")
    config = {"families": [{"name": f, "family": f, "inputs": i} for f, i in _FAMILIES],
              "split": {"strategy": "time-blocks"}, "baseline": None}
    res = thermonet.compare(config, data=ds)
    return res, make_splits(ds, config_from_mapping(config).split)[-1]


@pytest.mark.parametrize("family, inputs", _FAMILIES)
def test_every_family_fits_through_the_api_as_compare_fits_it(bmi270_every_family, family,
                                                             inputs):
    """Each built-in family, fitted by the API on compare's training blocks, is compare's
    model on every axis compare compensates (bit-identical); a family compare could not fit
    is refused by the API with compare's reason (the RBF's 16 centres on 5 levels of dT)."""
    from thermonet.core.errors import FitError

    res, split = bmi270_every_family
    summary = res.families[family]
    est = thermonet.DriftEstimator(family, inputs)
    if not summary.ok:
        with pytest.raises(FitError) as info:
            est.fit([*split.train, split.val])
        assert str(info.value) == summary.reason
        return
    est.fit([*split.train, split.val])      # compare refits on training + validation
    cli = res.estimator(family)
    mask = np.array(cli.model_.compensated_axes)
    assert mask.any()
    assert torch_equal(est.model_.sig_lo, cli.model_.sig_lo)
    np.testing.assert_array_equal(est.predict(split.test)[:, mask],
                                  cli.predict(split.test)[:, mask])


# ------------------------------------------------------------- score(multioutput=...)
def _two_axis_run(seed: int, sign_y: float) -> Recording:
    """gyro_x: the cubic law; gyro_y: the same law times ``sign_y`` (a test run with −1 has
    gyro_y's drift reversed: a model trained with +1 doubles its error there)."""
    rec = cubic_run(seed)
    drift = rec.drift["drift_gyro_x"]
    noise = np.random.default_rng(seed + 100).normal(0.0, 0.01, drift.size)
    return Recording(time_s=rec.time_s, temperature_c=rec.temperature_c,
                     outputs={"gyro_x": rec.outputs["gyro_x"], "gyro_y": sign_y * drift + noise},
                     units={"gyro_x": "deg/s", "gyro_y": "deg/s", "temperature_c": "degC"},
                     run_id=rec.run_id, sample_rate_hz=1.0)


def test_score_multioutput_as_scikit_learn_aggregates():
    """One axis worse than raw: the uniform mean hides part of it, ``raw_values`` shows it;
    every rule equals the numbers computed by hand from the predictions (each run about its
    own mean, as the docstring says), and scikit-learn's ``r2_score`` agrees on one run."""
    from sklearn.metrics import r2_score

    est = thermonet.DriftEstimator("poly", "dT", degree=3, max_epochs=0).fit(
        [_two_axis_run(1, 1.0), _two_axis_run(2, 1.0)])
    test = [_two_axis_run(3, 1.0), _two_axis_run(4, -1.0)]     # gyro_y reversed in one run
    comp, raw = np.zeros(2), np.zeros(2)
    for rec in test:                                           # by hand
        y = np.column_stack([rec.outputs["gyro_x"], rec.outputs["gyro_y"]])
        e = y - est.predict(rec)
        comp += ((e - e.mean(0)) ** 2).sum(0)
        raw += ((y - y.mean(0)) ** 2).sum(0)
    per_axis = est.score(test, multioutput="raw_values")
    assert per_axis.shape == (2,)
    assert_f64_close(per_axis, 1.0 - comp / raw, rtol=1e-9)
    assert per_axis[0] > 0.9 and per_axis[1] < 0.0             # gyro_y made worse than raw
    assert est.score(test) == pytest.approx(np.mean(1.0 - comp / raw), rel=1e-9)
    assert est.score(test, multioutput="uniform_average") == est.score(test)
    assert est.score(test, multioutput="variance_weighted") == pytest.approx(
        1.0 - comp.sum() / raw.sum(), rel=1e-9)
    assert est.score(test, multioutput=[3.0, 1.0]) == pytest.approx(
        1.0 - np.average(comp / raw, weights=[3.0, 1.0]), rel=1e-9)
    # on one run the per-axis scores are scikit-learn's R² of the prediction with the
    # error's mean added back (the score is offset-free: a constant is no error)
    one = test[0]
    y = np.column_stack([one.outputs["gyro_x"], one.outputs["gyro_y"]])
    pred = est.predict(one)
    for rule in ("raw_values", "uniform_average", "variance_weighted"):
        assert_f64_close(est.score(one, multioutput=rule),
                         r2_score(y, pred + (y - pred).mean(0), multioutput=rule), rtol=1e-9)
    for bad in ("mean", [1.0], [1.0, -1.0], [0.0, 0.0]):
        msg = _one_line(lambda b=bad: est.score(test, multioutput=b), ConfigError)
        assert "score(multioutput)" in msg


def test_implausible_lorentz_constants_are_warned():
    """A near-straight drift over 30 °C: the Lorentz fits the flank of a peak far outside the
    data (xc_margin 4 lets the centre go there) — the curve is fine, the constants are not
    physical, and the fit says so (a warning and the rows' note), judged from the table's own
    width against the recording's span; the issue's numbers trip both rules."""
    import warnings

    from thermonet.training.parameters import implausible_lorentz

    t = np.arange(600.0)
    temp = 10.0 + 30.0 * t / t[-1]
    y = 0.002 * (temp - 10) - 1e-6 * (temp - 10) ** 2 \
        + np.random.default_rng(0).normal(0, 1e-4, t.size)
    rec = Recording(time_s=t, temperature_c=temp, outputs={"gyro_x": y}, run_id="r",
                    units={"gyro_x": "deg/s", "temperature_c": "degC"}, sample_rate_hz=1.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        est = thermonet.DriftEstimator("lorentz", "T", max_epochs=300, xc_margin=4.0).fit(rec)
    p = est.parameters_.set_index("name")
    span = np.ptp(temp)
    assert p.loc["width", "value"] > 10 * span                  # measured 492 °C over 30 °C
    assert any("implausible" in str(w.message) for w in caught)
    assert p["note"].str.startswith("implausible as physical constants: width").all()
    # a peak inside the data (test_linear_and_lorentz_parameters_in_physical_units): no note
    assert implausible_lorentz(2.0, 8.0, 40.0, 0.08, "°C", "deg/s") == ""
    # the reported cycle: amplitude −14,627 °/s·°C, width 1,831 °C over 35 °C, drift 0.2 °/s
    why = implausible_lorentz(-14627.0, 1831.0, 35.0, 0.2, "°C", "deg/s")
    assert "width 1831 °C is 52× the trained span" in why and "amplitude -1.463e+04" in why
