"""The full sensor model (``model: sensor``): preset, fit, metrics, refusals, export.

Expectations are independent of the code under test: the preset's own laws
(:mod:`thermonet.sim.multiposition`, evaluated directly), numpy's ``linalg.solve`` as the
oracle of the 3 × 3 inverse, onnxruntime and the torch-free runtime against torch, and the
scatter of per-soak least-squares estimates as the noise-limited uncertainty of a recovered
element.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import load_runtime
from thermonet.core.errors import ConfigError, ExportError, FitError, InputError
from thermonet.core.recording import Dataset
from thermonet.core.trainconfig import TrainConfig
from thermonet.models.sensor import check_invertible, solve_columns, triads_of
from thermonet.scoring.metrics import scale_factor_tempco_ppm_per_c
from thermonet.scoring.sensor import soak_matrices
from thermonet.sim import PRESETS, simulate
from thermonet.training.pipeline import split_spec
from thermonet.training.sensor import do_no_harm, fit_sensor, sensor_run, steady_estimates
from thermonet.training.sensor_checkpoint import load_sensor, save_sensor
from tolerances import EPS32

PRESET = PRESETS["imu-multiposition"]
AXES = {a.name: a for a in PRESET.axes}


def _truth_m(triad: list[str], temps: np.ndarray) -> np.ndarray:
    """M(T) of the preset's laws: 1 + scale factor on the diagonal, cross-axis off it."""
    m = np.zeros((temps.size, len(triad), len(triad)))
    for i, a in enumerate(triad):
        m[:, i, i] = 1.0 + AXES[a].scale_factor_ppm(temps) * 1e-6
        for other, law in AXES[a].cross_axis_urad:
            m[:, i, triad.index(other)] = law(temps) * 1e-6
    return m


@pytest.fixture(scope="module")
def data() -> Dataset:
    return simulate("imu-multiposition", runs=4, seed=0)


@pytest.fixture(scope="module")
def fitted(data):
    outs = sorted(data.runs[0].outputs)
    triads = triads_of(outs)
    outputs = [o for t in triads for o in t]
    spec = split_spec(["dT"], data.runs[:2])
    runs = [sensor_run(r, spec, outputs) for r in data.runs]
    kw = dict(family="poly", spec=spec, outputs=outputs, triads=triads, train=runs[:2],
              val=runs[2], hyper={"degree": 3}, config=TrainConfig())
    return {"full": fit_sensor(**kw), "bias": fit_sensor(**kw, elements=False), "runs": runs,
            "triads": triads, "outputs": outputs, "spec": spec}


# ------------------------------------------------------------------------------ the preset
def test_preset_poses_references_and_scale_factor_magnitude(data):
    rec = data.runs[0]
    assert sorted(rec.references) == sorted(f"ref_{a}" for a in AXES)
    # six faces and ±100 °/s about each axis: the gyro refs take exactly these values
    for a in ("gyro_x", "gyro_y", "gyro_z"):
        assert set(np.unique(rec.references[f"ref_{a}"])) == {-100.0, 0.0, 100.0}
    for a in ("acc_x", "acc_y", "acc_z"):
        assert set(np.unique(rec.references[f"ref_{a}"])) == {-1.0, 0.0, 1.0}
    temp = rec.temperature_c
    assert temp.min() == pytest.approx(-40.0, abs=0.5) and temp.max() == pytest.approx(85, abs=0.5)
    # per-soak M from the raw outputs equals the laws' M within the noise; the scale-factor
    # tempco (study 000's definition) is the laws' own, ≈ 140 ppm/°C
    for triad in (["acc_x", "acc_y", "acc_z"], ["gyro_x", "gyro_y", "gyro_z"]):
        y = np.stack([rec.outputs[a] for a in triad], 1)
        x = np.stack([rec.references[f"ref_{a}"] for a in triad], 1)
        temps, _, m = soak_matrices(rec.time_s, temp, y, x)
        assert temps.size == 11
        truth = _truth_m(triad, temps)
        # white noise 45 µg / 0.0022 °/s per sample over ≥ 60 samples per pose, plus flicker:
        # a per-soak element is good to a few 1e-6; 5e-5 is 3 mrad's 1.7 %
        assert np.abs(m - truth).max() < 5e-5
        for i in range(3):
            want = scale_factor_tempco_ppm_per_c(temps, truth[:, i, i])
            got = scale_factor_tempco_ppm_per_c(temps, m[:, i, i])
            assert got == pytest.approx(want, rel=0.02)
            assert 120.0 < want < 160.0  # study 000's magnitude (151.6 ppm/°C)
        off = truth[:, ~np.eye(3, dtype=bool)]
        assert 1.0e-3 < np.abs(off).mean() < 4e-3            # a few mrad
        slope = np.abs(np.polyfit(temps, off, 1)[0])           # rad/°C per element
        assert np.all((15e-6 <= slope) & (slope <= 45e-6))    # tens of µrad/°C


# --------------------------------------------------------------------------- the fit
@pytest.mark.numerics
def test_known_laws_recovered_within_the_per_soak_scatter(fitted):
    """Each element of M(T) and b(T) agrees with the preset's law within three standard
    deviations of the per-soak least-squares estimates about that law (the noise-limited
    uncertainty of one soak; the fitted curve pools 22 soaks, so it is better than that)."""
    model, runs = fitted["full"].model, fitted["runs"][:2]
    outputs = fitted["outputs"]
    idx = [[outputs.index(o) for o in t] for t in fitted["triads"]]
    _, g_t, g_b, g_e = steady_estimates(runs, idx)
    grid = np.linspace(-40.0, 85.0, 26)
    m_fit = model.matrices(torch.as_tensor(grid[:, None]))
    with torch.no_grad():
        b_fit = model.bias.drift64(torch.as_tensor(grid[:, None], dtype=torch.float32)).numpy()
    j = 0
    for t, triad in enumerate(fitted["triads"]):
        k2 = len(triad) ** 2
        soak = g_e[:, j:j + k2].reshape(-1, 3, 3) + np.eye(3)
        sigma = (soak - _truth_m(triad, g_t)).std(axis=0)      # (3, 3) per element
        err = np.abs(m_fit[t] - _truth_m(triad, grid))
        assert np.all(err <= 3.0 * sigma), (triad, err.max(axis=0), sigma)
        j += k2
        for a in triad:
            c = outputs.index(a)
            s_b = (g_b[:, c] - AXES[a].bias(g_t)).std()
            assert np.abs(b_fit[:, c] - AXES[a].bias(grid)).max() <= 3.0 * s_b + 3 * 2e-5


@pytest.mark.numerics
def test_bias_only_is_measurably_worse_and_the_done_when_targets_hold(fitted):
    """Held-out run: the sensor model's residual ≥ 5× below the bias-only model's on every
    axis; the compensated scale-factor tempco ≤ 15 ppm/°C (targets)."""
    test = fitted["runs"][3]
    full, bias = fitted["full"].model, fitted["bias"].model
    comp = full.compensate(test.signals, test.raw) - test.ref
    comp_b = bias.compensate(test.signals, test.raw) - test.ref
    rms = np.sqrt(np.mean(comp ** 2, axis=0))
    rms_b = np.sqrt(np.mean(comp_b ** 2, axis=0))
    assert np.all(rms_b >= 5.0 * rms), rms_b / rms
    outputs = fitted["outputs"]
    for triad in fitted["triads"]:
        idx = [outputs.index(o) for o in triad]
        temps, _, m = soak_matrices(test.time_s, test.temperature, comp[:, idx] + test.ref[:, idx],
                                    test.ref[:, idx])
        for i in range(3):
            assert scale_factor_tempco_ppm_per_c(temps, m[:, i, i]) <= 15.0


@pytest.mark.numerics
def test_inverse_is_the_linear_solve(fitted):
    """M(s)⁻¹(raw − b): the adjugate formula against numpy.linalg.solve (float64)."""
    model = fitted["full"].model
    rng = np.random.default_rng(1)
    temps = rng.uniform(-40, 85, 50)
    x = rng.uniform(-2, 2, (50, 6))
    ms = model.matrices(torch.as_tensor(temps[:, None]))
    with torch.no_grad():
        b = model.bias.drift64(torch.as_tensor(temps[:, None], dtype=torch.float32)).numpy()
    raw = np.empty_like(x)
    raw[:, :3] = np.einsum("nrc,nc->nr", ms[0], x[:, :3]) + b[:, :3]
    raw[:, 3:] = np.einsum("nrc,nc->nr", ms[1], x[:, 3:]) + b[:, 3:]
    got = model.compensate(temps[:, None], raw)
    # M is float64 from the float32 elements, so the round trip is float64-exact up to the
    # condition number (≈ 1.01)
    np.testing.assert_allclose(got, x, rtol=0, atol=1e-12 * np.abs(raw).max())
    a = np.array([[2.0, 1, 0], [0, 3, 1], [1, 0, 1]])
    m = [[torch.tensor([a[r, c]], dtype=torch.float64) for c in range(3)] for r in range(3)]
    v = [torch.tensor([x], dtype=torch.float64) for x in (1.0, 2.0, 3.0)]
    want = np.linalg.solve(np.array([[2.0, 1, 0], [0, 3, 1], [1, 0, 1]]), [1.0, 2, 3])
    np.testing.assert_allclose([float(c) for c in solve_columns(m, v)], want, rtol=1e-12)


def test_do_no_harm_masks_an_element_that_hurts(fitted):
    """An element pushed 10 mrad off is left at zero by do-no-harm; the others stay."""
    import copy

    model = copy.deepcopy(fitted["full"].model)
    j = model.elements.outputs.index("gyro.m_xy")
    with torch.no_grad():
        model.elements.y_offset[j] += 0.01
    kept = do_no_harm(model, fitted["runs"][2])
    assert kept["gyro.m_xy"] is False
    assert model.elements.compensated_axes[j] is False
    assert all(kept[a] for a in fitted["outputs"])         # every bias element helps
    assert kept["gyro.m_xx"] and kept["acc.m_yy"]          # scale factors help


# ------------------------------------------------------------------------------ refusals
def test_singular_m_is_refused_at_fit_check_and_export(fitted, tmp_path):
    import copy

    from thermonet.exporting.sensor_export import export_sensor_onnx

    model = copy.deepcopy(fitted["full"].model)
    j = model.elements.outputs.index("acc.m_yy")
    with torch.no_grad():
        model.elements.y_offset[j] -= 1.0      # M_yy ≈ 0: the y axis lost
    with pytest.raises(FitError, match=r"'acc' is singular or near-singular \(condition number"):
        check_invertible(model, np.array([[25.0]]))
    out = tmp_path / "m.onnx"
    with pytest.raises(FitError, match="singular"):
        export_sensor_onnx(model, out)
    assert not out.exists()


def _static(data: Dataset) -> Dataset:
    """The preset's runs with the table parked on one face (+z up, gyro at rest): a static
    single-position soak, references present."""
    ds = simulate("imu-multiposition", runs=3, seed=0, table__program="static")
    for rec in ds.runs:
        for a, ax in AXES.items():
            rec.references[f"ref_{a}"] = np.full(rec.n_samples, ax.reference_level)
    return ds


def test_static_single_position_data_say_scale_factor_not_observable(data):
    ds = _static(data)
    outputs = [o for t in triads_of(sorted(ds.runs[0].outputs)) for o in t]
    spec = split_spec(["dT"], ds.runs[:1])
    runs = [sensor_run(r, spec, outputs) for r in ds.runs]
    with pytest.raises(InputError, match=r"scale factor and misalignment of '(acc|gyro)' are not "
                                         r"observable: .* span 0 of 3 direction"):
        fit_sensor(family="poly", spec=spec, outputs=outputs, triads=triads_of(outputs),
                   train=runs[:2], val=runs[2], hyper={"degree": 3}, config=TrainConfig())
    # without reference channels at all: the missing column is named
    bare = simulate("imu-multiposition", runs=1, seed=0, table__program="static").runs[0]
    with pytest.raises(InputError, match=r"column .ref_acc_x.: model .sensor. needs the known excitation.*no reference channel"):
        sensor_run(bare, spec, outputs)


def test_config_model_key():
    from thermonet.training.config import config_from_mapping

    assert config_from_mapping({"families": [{"family": "poly"}]}).model == "bias"
    assert config_from_mapping({"model": "sensor", "families": [{"family": "poly"}]}
                               ).model == "sensor"
    with pytest.raises(ConfigError, match="model"):
        config_from_mapping({"model": "full"})
    with pytest.raises(ConfigError, match="model 'sensor'.*'target'"):
        config_from_mapping({"model": "sensor", "target": "four-position"})


# ------------------------------------------------------------------------------ export
@pytest.mark.numerics
def test_onnx_runtime_batch_and_stream_match_torch(fitted, data, tmp_path):
    from thermonet.exporting.sensor_export import export_sensor_onnx

    model = fitted["full"].model
    info = export_sensor_onnx(model, tmp_path / "s.onnx")
    assert info["status"] == "ok"
    rt = load_runtime()
    comp = rt.Compensator(str(tmp_path / "s.onnx"))
    assert comp.metadata["model"] == "sensor"
    rec = data.runs[3]
    raw = np.stack([rec.outputs[o] for o in model.outputs], 1)
    want = model.compensate(rec.temperature_c[:, None], raw)
    got = comp.compensate(temperature_c=rec.temperature_c, raw=raw)["compensated"]
    # b and E in float32 on both sides (depth ≈ 64 operations), at the output's scale
    scale = np.abs(raw).max(axis=0)
    assert np.all(np.abs(got - want) <= 64 * EPS32 * scale)
    for i in range(0, rec.n_samples, 997):
        s = comp.step(float(rec.time_s[i]), float(rec.temperature_c[i]), raw[i])
        assert np.all(np.abs(np.ravel(s["compensated"]) - want[i]) <= 64 * EPS32 * scale)


@pytest.mark.numerics
def test_c_header_compiles_and_matches_torch_and_a_broken_one_is_caught(fitted):
    """gcc -std=c99 -Wall -Wextra -Werror builds the header; its compensated outputs match
    torch within the ONNX check's tolerance (so C = torch = onnxruntime); a header with one
    cofactor's sign flipped fails the same check."""
    from thermonet.exporting.sensor_c import render_sensor_c, sensor_c_parity

    model = fitted["full"].model
    text = render_sensor_c(model, prefix="imu")
    stats = sensor_c_parity(model, text, prefix="imu")
    assert stats["max_error_over_tolerance"] <= 1.0
    broken = text.replace("const thermonet_real_t c01 = -(", "const thermonet_real_t c01 = (", 1)
    assert broken != text
    with pytest.raises(ExportError, match="sensor C header parity failed"):
        sensor_c_parity(model, broken, prefix="imu")


def test_checkpoint_round_trip_and_autopilot_refusal(fitted, tmp_path):
    from thermonet.exporting import export_source
    from thermonet.exporting.sensor_export import bias_only_path

    ckpt = save_sensor(tmp_path / "models" / "cubic.pt", fitted["full"], family="poly",
                       hyper={"degree": 3})
    model, payload = load_sensor(ckpt)
    t = np.linspace(-40, 85, 7)[:, None]
    raw = np.tile([1.0, -2.0, 3.0, 0.5, -0.5, 1.0], (7, 1))
    # the same weights on the same batch: bit-identical
    assert np.array_equal(model.compensate(t, raw), fitted["full"].model.compensate(t, raw))
    assert payload["kept"] == fitted["full"].kept
    with pytest.raises(ExportError, match=r"cannot be written as px4-params: those parameters "
                                          r"hold a bias polynomial per axis only; export the "
                                          r"bias-only model .*cubic\.bias-only\.pt"):
        export_source(str(ckpt), fmt="px4-params", out=tmp_path / "x.params", device_id=1)
    with pytest.raises(ExportError, match="ardupilot-params"):
        export_source(str(ckpt), fmt="ardupilot-params", out=tmp_path / "x.parm")
    assert not (tmp_path / "x.params").exists()
    assert bias_only_path(ckpt) == tmp_path / "models" / "cubic.bias-only.pt"


@pytest.mark.slow
def test_compare_with_model_sensor_end_to_end(tmp_path):
    """``thermonet compare`` on the preset: results.json carries the metrics and verdicts,
    the chosen family meets the sensor model's targets, its ONNX and bias-only exports work."""
    import subprocess
    import sys

    cfg = tmp_path / "sensor.yaml"
    cfg.write_text("model: sensor\ndata: {preset: imu-multiposition}\ntracking: {enabled: false}\n"
                   "families:\n  - {family: poly, name: cubic, inputs: [dT], params: {degree: 3}}\n"
                   "  - {family: linear, name: linear, inputs: [dT]}\n")
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, "-m", "thermonet.cli", "compare", str(cfg), "--out",
                          str(out), "--quiet"], capture_output=True, text=True,
                         cwd=Path(__file__).resolve().parents[1])
    assert run.returncode == 0, run.stderr[-2000:]
    res = json.loads((out / "results.json").read_text())
    assert res["model"] == "sensor" and res["chosen"] == "cubic"
    assert "done_when" not in res       # a development target, not the product's (issue 51)
    cubic, linear = res["families"]["cubic"], res["families"]["linear"]
    for a, m in cubic["axes"].items():
        assert m["verdict_vs_raw"] == "better" and m["verdict_vs_bias"] == "better", a
        assert m["sf_ppm_per_c_raw"] > 100.0 and m["sf_ppm_per_c_comp"] <= 15.0
        # the sensor model's targets, from results.json's own numbers
        assert m["residual_rms_bias_only"] >= 5.0 * m["residual_rms_comp"], a
        # bias-only leaves the scale factor as it is
        assert m["sf_ppm_per_c_bias_only"] == pytest.approx(m["sf_ppm_per_c_raw"], rel=0.05)
    assert cubic["triads"]["acc"]["sf_ppm_per_c_comp_max"] <= 15.0
    assert cubic["triads"]["gyro"]["residual_ratio_vs_bias_max"] <= 0.2
    for pair, m in cubic["misalignment"].items():
        assert 1.0 < abs(m["misalignment_mrad_raw"]) < 4.0, pair
        assert m["misalignment_spread_mrad_comp"] < 0.1 * m["misalignment_spread_mrad_raw"]
    # a linear law cannot follow the curvature: its residual is larger (the laws are cubic)
    assert all(linear["axes"][a]["residual_rms_comp"] > cubic["axes"][a]["residual_rms_comp"]
               for a in cubic["axes"])
    assert res["onnx"]["status"] == "ok" and (out / "model.onnx").is_file()
    run = subprocess.run([sys.executable, "-m", "thermonet.cli", "export", str(out),
                          "--format", "c", "--out", str(tmp_path / "imu.h")],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "thermonet_compensate(const float *signals" in (tmp_path / "imu.h").read_text()
    page = (out / "report.html").read_text()
    assert "SF ppm/°C raw" in page and "met:" not in page     # no development target shown
    assert (out / "sensor_soaks.png").is_file() and "data:image/png;base64," in page
    bias_ckpt = out / cubic["bias_only_checkpoint"]
    run = subprocess.run([sys.executable, "-m", "thermonet.cli", "export", str(bias_ckpt),
                          "--format", "px4-params", "--device-id", "1", "--out",
                          str(tmp_path / "tc.params")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "TC_G0_X0_0" in (tmp_path / "tc.params").read_text()


def test_python_api_compare_returns_the_sensor_models(data):
    import thermonet

    cfg = {"model": "sensor", "tracking": {"enabled": False},
           "families": [{"family": "poly", "name": "cubic", "params": {"degree": 3}}]}
    res = thermonet.compare(cfg, data=data)
    assert res.chosen == "cubic"
    table = res.residuals()
    assert list(table.index.get_level_values("axis")) == res.model("cubic").outputs
    assert (table["residual_rms_bias_only"] >= 5 * table["residual_rms_comp"]).all()


@pytest.mark.slow
@pytest.mark.parametrize("family, inputs, hyper", [
    ("lorentz", ["dT"], {}), ("ts-fuzzy", ["dT"], {"n_sets": 6}),
    ("rbf", ["dT", "dT2"], {"n_centres": 16, "tail": 3}),
    ("poly", ["dT", "rate"], {"degree": 3, "cross": True})], ids=lambda v: str(v))
def test_every_element_from_other_families(fitted, data, family, inputs, hyper):
    """The same mechanism with the default set's other families: each beats its own
    bias-only model ≥ 5× on every axis of the held-out run."""
    spec = split_spec(inputs, data.runs[:2])
    runs = [sensor_run(r, spec, fitted["outputs"]) for r in data.runs]
    kw = dict(family=family, spec=spec, outputs=fitted["outputs"], triads=fitted["triads"],
              train=runs[:2], val=runs[2], hyper=hyper, config=TrainConfig())
    full, bias = fit_sensor(**kw), fit_sensor(**kw, elements=False)
    t = runs[3]
    e = full.model.compensate(t.signals, t.raw) - t.ref
    e_b = bias.model.compensate(t.signals, t.raw) - t.ref
    assert np.all(np.sqrt(np.mean(e_b ** 2, 0)) >= 5 * np.sqrt(np.mean(e ** 2, 0)))


def test_an_input_that_does_not_vary_over_the_soaks_is_refused_with_the_family_reason(data):
    outputs = [o for t in triads_of(sorted(data.runs[0].outputs)) for o in t]
    spec = split_spec(["dT", "rate", "play_1"], data.runs[:2])
    runs = [sensor_run(r, spec, outputs) for r in data.runs[:3]]
    with pytest.raises(FitError, match=r"cannot be fitted as a sensor model on 264 "
                                       r"steady-temperature estimates: input 3 takes 3 distinct"):
        fit_sensor(family="poly", spec=spec, outputs=outputs, triads=triads_of(outputs),
                   train=runs[:2], val=runs[2], hyper={"degree": 3, "cross": True},
                   config=TrainConfig())


def test_an_edited_sensor_checkpoint_is_refused(fitted, tmp_path):
    ckpt = save_sensor(tmp_path / "m.pt", fitted["full"], family="poly", hyper={"degree": 3})
    payload = torch.load(ckpt, weights_only=True)
    payload["state_dict"]["elements.y_offset"][0] += 1e-3     # a scale factor edited
    torch.save(payload, ckpt)
    with pytest.raises(InputError, match="does not match the checkpoint's SHA-256 digest"):
        load_sensor(ckpt)


def test_sensor_comparison_is_tracked_in_mlflow(data, tmp_path):
    import mlflow

    from thermonet.training.config import config_from_mapping
    from thermonet.workflows.compare import run_compare

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    cfg = config_from_mapping({"model": "sensor", "tracking": {"experiment": "sensor-test"},
                               "families": [{"family": "poly", "name": "cubic",
                                             "params": {"degree": 3}}]})
    res = run_compare(cfg, tmp_path / "out", track=True, tracking_uri=uri, quiet=True,
                      dataset=data, plots=False)
    client = mlflow.MlflowClient(tracking_uri=uri)
    child = client.get_run(res["families"]["cubic"]["mlflow_run_id"])
    assert child.data.tags["mlflow.parentRunId"] == res["mlflow_run_id"]
    assert child.data.metrics["test/acc_x/residual_rms_comp"] == pytest.approx(
        res["families"]["cubic"]["axes"]["acc_x"]["residual_rms_comp"], rel=1e-12)
    assert [a.path for a in client.list_artifacts(child.info.run_id, "model")] == \
        ["model/cubic.pt"]


def test_compare_refuses_data_without_references_and_writes_nothing(tmp_path):
    from thermonet.training.config import config_from_mapping
    from thermonet.workflows.compare import run_compare

    cfg = config_from_mapping({"model": "sensor", "tracking": {"enabled": False},
                               "families": [{"family": "poly", "params": {"degree": 3}}]})
    ds = simulate("consumer-imu", runs=2, seed=0)   # a level unit: no ref_ columns
    with pytest.raises(InputError, match=r"column 'ref_gyro_x': model 'sensor' needs the "
                                         r"known excitation"):
        run_compare(cfg, tmp_path / "out", quiet=True, dataset=ds, plots=False)
    assert not (tmp_path / "out").exists()


@pytest.mark.numerics
def test_study_000_single_axis_as_a_one_by_one_sensor_model():
    """The accel preset (study 000: four positions per soak, one axis): a 1 × 1 triad; the
    Lorentz sensor model brings the held-out scale-factor tempco from ≈150 ppm/°C to study
    000's order (11.8 ppm/°C with Lorentz), within the issue's 15 ppm/°C."""
    ds = simulate("accel", seed=0)
    spec = split_spec(["dT"], ds.runs[:1])
    runs = [sensor_run(r, spec, ["acc_x"]) for r in ds.runs]
    fit = fit_sensor(family="lorentz", spec=spec, outputs=["acc_x"], triads=[["acc_x"]],
                     train=runs[:1], val=runs[1], hyper={}, config=TrainConfig())
    t = runs[2]
    comp = fit.model.compensate(t.signals, t.raw)
    temps, _, m_raw = soak_matrices(t.time_s, t.temperature, t.raw, t.ref)
    _, _, m_comp = soak_matrices(t.time_s, t.temperature, comp, t.ref)
    raw = scale_factor_tempco_ppm_per_c(temps, m_raw[:, 0, 0])
    after = scale_factor_tempco_ppm_per_c(temps, m_comp[:, 0, 0])
    assert raw == pytest.approx(151.6, rel=0.1)
    assert after <= 15.0
