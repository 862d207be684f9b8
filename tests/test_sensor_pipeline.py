"""The sensor model (``model: sensor``) through the same pipeline as a bias model:
cross-validated choice and tuning, ``DriftEstimator(model="sensor")``, fleets.

Expectations are independent of the code under test: the preset's own laws
(:mod:`thermonet.sim.multiposition`, evaluated directly; every unit of a simulated fleet
shares them, an outlier unit's bias and scale-factor laws × (1 + 10 × 1 %)), numpy's
least squares per soak (:func:`thermonet.scoring.sensor.soak_matrices`) as the noise-limited
uncertainty of an element, and numpy's variances for the score.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from thermonet.api import DriftEstimator
from thermonet.core.errors import ConfigError
from thermonet.scoring.sensor import soak_matrices
from thermonet.sim import PRESETS, simulate, simulate_fleet
from thermonet.sim.fleet import MIN_GAIN_SIGMA, OUTLIER_SIGMAS
from thermonet.training.config import config_from_mapping
from thermonet.training.sensor import sensor_run
from thermonet.training.sensor_checkpoint import load_sensor
from thermonet.training.splits import make_splits
from thermonet.workflows.compare import run_compare

AXES = {a.name: a for a in PRESETS["imu-multiposition"].axes}
GYRO = ["gyro_x", "gyro_y", "gyro_z"]


def _truth_m(triad: list[str], temps: np.ndarray, gain: float = 1.0) -> np.ndarray:
    """M(T) of the preset's laws (scale factor × ``gain``, an outlier unit's)."""
    m = np.zeros((temps.size, len(triad), len(triad)))
    for i, a in enumerate(triad):
        m[:, i, i] = 1.0 + gain * AXES[a].scale_factor_ppm(temps) * 1e-6
        for other, law in AXES[a].cross_axis_urad:
            m[:, i, triad.index(other)] = law(temps) * 1e-6
    return m


def _soak_scatter(runs, triad: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Per-soak least-squares M about the laws: temperatures (G,) and errors (G, 3, 3)."""
    temps, errs = [], []
    for rec in runs:
        y = np.stack([rec.outputs[a] for a in triad], 1)
        x = np.stack([rec.references[f"ref_{a}"] for a in triad], 1)
        t, _, m = soak_matrices(rec.time_s, rec.temperature_c, y, x)
        temps.append(t)
        errs.append(m - _truth_m(triad, t))
    return np.concatenate(temps), np.concatenate(errs)


@pytest.fixture(scope="module")
def data():
    return simulate("imu-multiposition", runs=4, seed=0)


# ------------------------------------------------------------ cross-validated choice
@pytest.fixture(scope="module")
def degrees(data, tmp_path_factory):
    """A comparison of polynomial degrees on the preset (whose laws are cubic) and a
    family tuned over the degree."""
    cfg = config_from_mapping({"model": "sensor", "tracking": {"enabled": False}, "families": [
        {"family": "linear", "name": "linear"},
        {"family": "poly", "name": "quadratic", "params": {"degree": 2}},
        {"family": "poly", "name": "cubic", "params": {"degree": 3}},
        {"family": "poly", "name": "quintic", "params": {"degree": 5}},
        {"family": "poly", "name": "tuned", "tune": {"degree": [1, 3, 5]}}]})
    return run_compare(cfg, tmp_path_factory.mktemp("degrees") / "out", quiet=True,
                       dataset=data, plots=False)


@pytest.mark.numerics
def test_cross_validation_chooses_the_true_degree(degrees):
    res = degrees
    sel = res["selection"]
    # the bias comparison's fold plan: 3 pool runs (train + validation), one left out each
    assert sel["method"] == "purged blocked cross-validation"
    assert sel["kind"] == "leave-one-run-out" and sel["folds"] == 3
    assert res["chosen"] == sel["chosen"] == "cubic"
    assert res["chosen_reason"] == sel["rule"] and "cubic" in res["chosen_reason"]
    c = sel["candidates"]
    assert all(v["status"] == "ok" and len(v["fold_scores"]) == 3 for v in c.values())
    # the laws are cubic: a lower degree leaves the curvature, clearly beyond one SE
    for low in ("linear", "quadratic"):
        assert c[low]["diff_to_best"] > 3 * c[low]["se_of_diff"], low
        assert c[low]["score"] > 3 * c["cubic"]["score"]
    # more parameters than the laws need buy nothing: the quintic is no better than the cubic
    assert c["quintic"]["score"] >= c["cubic"]["score"] * (1 - 1e-9)
    assert c["quintic"]["n_params"] > c["cubic"]["n_params"]
    # the single validation part agreed, and said so
    assert sel["single_split"]["chosen"] == "cubic"
    page = (Path(res["families"]["cubic"]["checkpoint"]).parents[1] / "report.html").read_text()
    assert f"choice: {html.escape(res['chosen_reason'])}</p>" in page
    assert "out-of-fold score (leave-one-run-out, 3 folds)" in page


@pytest.mark.numerics
def test_a_tune_grid_is_chosen_on_the_folds_not_ignored(degrees):
    tuned = degrees["families"]["tuned"]
    assert tuned["tuned"]["degree"] == 3
    grid = tuned["tuned"]["tuning"]["grid"]
    assert set(grid) == {"degree=1", "degree=3", "degree=5"}
    # each grid point's out-of-fold score is the family's own at that degree (same folds,
    # same procedure): the grid is the comparison's candidates again.  The two are separate
    # float32 fits run beside other families' threads, so they agree to float32's precision
    # amplified by the iterative fit, not bit for bit (on an Intel Xeon: 1.2e-6 relative)
    cands = degrees["selection"]["candidates"]
    rel = 100 * float(np.finfo(np.float32).eps)
    assert grid["degree=1"] == pytest.approx(cands["linear"]["score"], rel=rel)
    assert grid["degree=3"] == pytest.approx(cands["cubic"]["score"], rel=rel)
    assert grid["degree=5"] == pytest.approx(cands["quintic"]["score"], rel=rel)
    # the tuned family ships the cubic: same checkpoint parameters as the cubic's
    a, _ = load_sensor(tuned["checkpoint"])
    b, _ = load_sensor(degrees["families"]["cubic"]["checkpoint"])
    for (ka, va), (kb, vb) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert ka == kb and torch.equal(va, vb), ka


def test_without_folds_the_validation_residual_chooses(data, tmp_path):
    cfg = config_from_mapping({"model": "sensor", "tracking": {"enabled": False},
                               "selection": {"folds": 0}, "families": [
                                   {"family": "linear", "name": "linear"},
                                   {"family": "poly", "name": "cubic", "params": {"degree": 3},
                                    "tune": {"degree": [2, 3]}}]})
    res = run_compare(cfg, tmp_path / "out", quiet=True, dataset=data, plots=False)
    assert res["selection"] == {"method": "single validation part",
                                "note": "selection.folds is 0: chosen on the split's "
                                        "validation part"}
    fams = res["families"]
    assert res["chosen"] == min(fams, key=lambda k: fams[k]["val_score"]) == "cubic"
    assert fams["cubic"]["tuned"]["tuning"]["rule"].startswith("not tuned")
    written = json.loads((tmp_path / "out" / "results.json").read_text())
    assert written["chosen_reason"] == res["chosen_reason"]


# ------------------------------------------------------------ DriftEstimator(model="sensor")
@pytest.fixture(scope="module")
def estimator(data):
    return DriftEstimator("poly", ["dT"], model="sensor", degree=3).fit(data.runs[:2],
                                                                         data.runs[2])


@pytest.mark.numerics
def test_estimator_recovers_scale_factor_and_misalignment_tempcos(estimator, data):
    """Every element of M(T) within 3 σ of the per-soak least-squares scatter about the law,
    and each element's temperature coefficient (slope over −40…85 °C) within 3 standard
    errors of a slope through that scatter."""
    grid = np.linspace(-40.0, 85.0, 26)
    fitted = estimator.model_.matrices(torch.as_tensor(grid[:, None]))
    for t, triad in enumerate(estimator.triads_):
        temps, err = _soak_scatter(data.runs[:2], triad)
        sigma = err.std(axis=0)                                   # (3, 3)
        truth = _truth_m(triad, grid)
        assert np.all(np.abs(fitted[t] - truth) <= 3 * sigma), triad
        se_slope = sigma / np.sqrt(np.sum((temps - temps.mean()) ** 2))
        slope_fit = np.polyfit(grid, fitted[t].reshape(grid.size, -1), 1)[0].reshape(3, 3)
        slope_true = np.polyfit(grid, truth.reshape(grid.size, -1), 1)[0].reshape(3, 3)
        assert np.all(np.abs(slope_fit - slope_true) <= 3 * se_slope), triad
        # the laws' own magnitudes: ≈140 ppm/°C scale factor, tens of µrad/°C off-diagonal
        off = ~np.eye(3, dtype=bool)
        sf = np.abs(np.diag(slope_true))
        assert np.all((1e-4 < sf) & (sf < 2e-4))
        assert np.all(np.abs(slope_true[off]) > 1e-5)


@pytest.mark.numerics
def test_estimator_predicts_as_the_workflows_fitted_model(data, estimator, tmp_path):
    """compare's checkpoint and the estimator fitted on the same split are the same model;
    score is numpy's variance ratio of compensated − ref over raw − ref."""
    cfg = config_from_mapping({"model": "sensor", "tracking": {"enabled": False},
                               "families": [{"family": "poly", "name": "cubic",
                                             "params": {"degree": 3}}]})
    res = run_compare(cfg, tmp_path / "out", quiet=True, dataset=data, plots=False)
    split = make_splits(data, cfg.split)[0]
    assert [r.run_id for r in split.train] == ["run0", "run1"] and split.val.run_id == "run2"
    model, _ = load_sensor(res["families"]["cubic"]["checkpoint"])
    test = split.test
    run = sensor_run(test, model.bias.spec, estimator.outputs_)
    comp = model.compensate(run.signals, run.raw)
    np.testing.assert_allclose(run.raw - estimator.predict(test), comp, rtol=0, atol=1e-9)
    back = estimator.compensate(test)
    for j, a in enumerate(estimator.outputs_):
        # a Recording holds its outputs as float32: 100 °/s to 1e-5 °/s
        np.testing.assert_allclose(back.outputs[a], comp[:, j], rtol=0,
                                   atol=4 * np.finfo(np.float32).eps * 100)
        # the same fit to float rounding: ≤ 1e-9 of the compensated output (above)
        assert res["families"]["cubic"]["axes"][a]["residual_rms_comp"] == pytest.approx(
            np.std(comp[:, j] - run.ref[:, j]), rel=0, abs=1e-10)
    want = 1 - np.var(comp - run.ref, axis=0) / np.var(run.raw - run.ref, axis=0)
    np.testing.assert_allclose(estimator.score(test, multioutput="raw_values"), want, rtol=1e-9)
    assert estimator.score(test) == pytest.approx(want.mean(), rel=1e-9)
    # the same fit to float rounding (≤ 1e-9 in the compensated output, above): the
    # validation residual, ~1e-2 of the raw error, agrees to 1e-5 of itself
    assert estimator.val_score_ == pytest.approx(res["families"]["cubic"]["val_score"],
                                                 rel=1e-5)
    # save / load, and compare's own checkpoint loaded as an estimator
    for path in (estimator.save(tmp_path / "est.pt"), res["families"]["cubic"]["checkpoint"]):
        again = DriftEstimator.load(path)
        assert again.model == "sensor" and again.get_params()["family__degree"] == 3
        np.testing.assert_allclose(again.predict(test), estimator.predict(test), rtol=0,
                                   atol=1e-12)


def test_estimator_model_argument_is_checked_and_cloned(data):
    from sklearn.base import clone

    est = DriftEstimator("poly", model="sensor", degree=3)
    assert est.get_params()["model"] == "sensor" and clone(est).model == "sensor"
    assert DriftEstimator("poly").get_params()["model"] == "bias"
    with pytest.raises(ConfigError, match=r"^model: 'full' is not one of bias, sensor$"):
        DriftEstimator("poly", model="full").fit(data.runs[:1])
    with pytest.raises(ConfigError, match=r"^target: 'four-position' with model='sensor'"):
        DriftEstimator("poly", model="sensor", target="four-position").fit(data.runs[:1])


# ------------------------------------------------------------ fleets
@pytest.mark.numerics
def test_fleet_of_three_sensor_units_with_an_outlier(tmp_path):
    """Three units of the preset, the last an outlier (bias and scale-factor laws × 1.1):
    each unit's scale-factor curve is its own law; leave-units-out shows that a fleet model
    of the two normal units leaves the outlier its scale-factor excess."""
    from thermonet.workflows.fleet import FleetOptions, run_fleet
    from thermonet.workflows.fleet_units import sources_from_dataset

    ds = simulate_fleet("imu-multiposition", units=3, runs=3, seed=1, outliers=1)
    cfg = config_from_mapping({"model": "sensor", "tracking": {"enabled": False},
                               "families": [{"family": "poly", "name": "cubic",
                                             "params": {"degree": 3}}],
                               "limits": {f"gyro_{a}": {"max_std": 0.01} for a in "xyz"}})
    res = run_fleet(cfg, tmp_path / "fleet", sources_from_dataset(ds), quiet=True, plots=False,
                    options=FleetOptions(executor="serial", folds=3))
    units = res["units"]
    ids = list(units)
    gain = {ids[0]: 1.0, ids[1]: 1.0, ids[2]: 1.0 + OUTLIER_SIGMAS * MIN_GAIN_SIGMA}
    grid = np.linspace(-40.0, 85.0, 11)
    for dev, u in units.items():
        assert u["status"] == "ok" and u["model"] == "sensor" and u["chosen"] == "cubic"
        assert u["selection"]["kind"] == "leave-one-run-out"    # each unit cross-validated
        assert u["limits"]["verdict"] == "PASS"
        assert (tmp_path / "fleet" / u["dir"] / "model.onnx").is_file()
        truth = _truth_m(GYRO, grid, gain[dev])
        for i, a in enumerate(GYRO):
            c = [u["coefficients"][f"gyro.m_{a[-1]}{a[-1]}.c{k}"] for k in range(4)]
            curve = np.polynomial.polynomial.polyval(grid - 25.0, c)
            # 2e-5: a pooled curve is better than one soak's 5e-5 (test_sensor_model)
            assert np.abs(curve - (truth[:, i, i] - 1.0)).max() < 2e-5, (dev, a)
            # the compensated residual is the sensor's noise: 0.0022 °/s white + flicker
            assert 0.0022 < u["families"]["cubic"]["axes"][a]["rms_comp"] < 0.0035
    # the outlier's gyro error with a fleet model of the two normal units: its own residual
    # and the excess law 0.1 · (bias(T) + sf(T) · 1e-6 · ref) together
    out = units[ids[2]]["leave_units_out"]
    assert out["fitted_on"] == ids[:2]
    test = [r for r in ds if r.device_id == ids[2]][-1]
    for a in GYRO:
        ax = AXES[a]
        excess = (gain[ids[2]] - 1.0) * (ax.bias(test.temperature_c) + ax.scale_factor_ppm(
            test.temperature_c) * 1e-6 * test.references[f"ref_{a}"])
        want = np.hypot(out["axes"][a]["std_own"], np.std(excess))
        assert out["axes"][a]["std_fleet"] == pytest.approx(want, rel=0.1), a
        assert out["axes"][a]["ratio"] > 5
    spread = res["fleet"]["spread"]
    assert spread["cubic.gyro.m_xx.c1"]["n"] == 3
    assert res["fleet"]["verdicts"] == {"PASS": 3}


@pytest.mark.numerics
def test_estimator_exports_the_sensor_model_as_thermonet_export_does(data, estimator, tmp_path):
    """DriftEstimator(model="sensor").export writes the sensor model's ONNX through the
    writer `thermonet export` uses (parity-checked): the torch-free runtime compensates as the
    estimator does; the autopilot formats and report() are one line each."""
    from conftest import load_runtime
    from thermonet.core.errors import ThermonetError

    path = estimator.export(tmp_path / "s.onnx", "onnx")
    comp = load_runtime().Compensator(str(path))
    assert comp.metadata["model"] == "sensor" and list(comp.outputs) == estimator.outputs_
    rec = data.runs[-1]
    raw = np.stack([rec.outputs[o] for o in estimator.outputs_], 1)
    got = comp.compensate(temperature_c=rec.temperature_c, raw=raw)["compensated"]
    want = np.stack([estimator.compensate(rec).outputs[o] for o in estimator.outputs_], 1)
    # b and E in float32 on both sides (depth ≈ 64 operations), at the output's scale
    scale = np.abs(raw).max(axis=0)
    assert np.all(np.abs(got - want) <= 64 * np.finfo(np.float32).eps * scale)
    with pytest.raises(ConfigError, match="px4-params"):
        estimator.export(tmp_path / "s.params", "px4-params")
    assert not (tmp_path / "s.params").exists()
    with pytest.raises(ThermonetError, match="report\\(\\): a sensor model"):
        estimator.report()
