"""The Python API: DriftEstimator's contract, save/load, export through the registries,
thermonet.read/simulate, the README example, and adding a family or format by registration."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

import thermonet
from conftest import REAL_DATA, toy_dataset
from thermonet.api import NotFittedError
from thermonet.core.errors import ConfigError
from thermonet.exporting import FORMATS, ExportFormat, register_format
from thermonet.models import MODELS
from thermonet.models.base import Family, as_numpy, least_squares
from thermonet.models.specs import Poly

ROOT = Path(__file__).resolve().parent.parent


def _true_drift(rec):
    return rec.drift["drift_gyro_x"]


def test_fit_recovers_the_known_quadratic_and_compensates():
    ds = toy_dataset(n_runs=3, noise=0.0005)
    est = thermonet.DriftEstimator("poly", ["dT"], degree=2)
    assert not hasattr(est, "model_")          # the constructor only stores
    assert est.fit(ds.runs[:2], val=ds[2]) is est
    # drift 0.05 + 0.01 d − 2e-4 d², d = T + 20: the fit recovers it on the held-out run
    pred = est.predict(ds[2])[:, 0]
    assert pred.shape == (ds[2].n_samples,)
    inside = ds[2].temperature_c <= ds[1].temperature_c.max()   # beyond it, clamped as on board
    assert np.max(np.abs(pred - _true_drift(ds[2]))[inside]) < 5e-4
    assert est.spec_.t_ref == pytest.approx(  # t - t0 <= 10 min
        np.mean(ds[0].temperature_c[:601]), abs=1e-9)
    assert est.best_val_ is not None and est.history_[0]["epoch"] == 0
    clean = est.compensate(ds[2])
    resid = clean.outputs["gyro_x"][inside]         # output − predicted drift
    assert np.std(resid) < 1.2 * 0.0005 and abs(np.mean(resid)) < 1e-4
    assert est.score(ds[2]) > 0.99


def test_unfitted_estimator_refuses_with_a_clear_error(tmp_path):
    est = thermonet.DriftEstimator("rbf")
    for call in (lambda: est.predict(toy_dataset(n_runs=1)[0]), lambda: est.save(tmp_path / "x"),
                 lambda: est.export(tmp_path / "x.onnx")):
        with pytest.raises(NotFittedError, match=r"DriftEstimator\('rbf'\) is not fitted yet"):
            call()
    assert not (tmp_path / "x").exists()


def test_bad_arguments_are_refused_at_fit():
    ds = toy_dataset(n_runs=1)
    with pytest.raises(ConfigError, match="unknown model family 'spline'"):
        thermonet.DriftEstimator("spline").fit(ds)
    # the default set's labels, which every result names, are said to be `poly`'s
    for label in ("cubic", "cubic-delayed-2min", "poly3-rate"):
        with pytest.raises(ConfigError, match=rf"unknown model family '{label}' .*labels of "
                           r"the family 'poly': DriftEstimator\('poly', 'dT', degree=3\)"):
            thermonet.DriftEstimator(label).fit(ds)
    with pytest.raises(ConfigError, match="'degre'"):
        thermonet.DriftEstimator("poly", degre=3).fit(ds)
    with pytest.raises(ConfigError, match="target: 'bias'"):
        thermonet.DriftEstimator("poly", target="bias").fit(ds)


def test_save_load_round_trip_carries_the_family_config_and_best_epoch(tmp_path):
    ds = toy_dataset(n_runs=3)
    est = thermonet.DriftEstimator("poly", ["dT"], degree=3,
                                   train=thermonet.TrainConfig(max_epochs=7)).fit(ds[0], val=ds[1])
    path = est.save(tmp_path / "m.pt")
    back = thermonet.DriftEstimator.load(path)
    # saved and loaded: the same weights through the same computation, bit for bit
    np.testing.assert_array_equal(back.predict(ds[2]), est.predict(ds[2]))
    assert (back.family, back.inputs) == (Poly(degree=3, cross=False), ["dT"])
    assert back.best_epoch_ == est.best_epoch_ and back.best_val_ == pytest.approx(est.best_val_)
    assert back.train_config_.max_epochs == 7 and back.units_ == {"gyro_x": "deg/s"}
    payload = torch.load(path, weights_only=True)
    assert payload["epoch"] == est.best_epoch_ and payload["best_val"] is not None
    assert set(payload["config"]) == {"family", "train", "features", "target"}


def test_read_real_recordings_through_a_mapping():
    d = REAL_DATA / "bmi270_two_soaks"
    ds = thermonet.read([d / "BMI_270_cold_test_.csv", d / "BMI_270_hot_test.csv"],
                        mapping=ROOT / "configs" / "data" / "bmi270.yaml")
    assert len(ds) == 2
    t = np.concatenate([r.temperature_c for r in ds])
    assert 12.0 < t.min() < 15.0 and 47.0 < t.max() < 51.0      # the README's 13–49 °C


def test_simulate_is_seeded():
    a = thermonet.simulate("patent-gyro", runs=1, seed=3)
    b = thermonet.simulate("patent-gyro", runs=1, seed=3)
    # the same seed, the same computation: bit-identical (the simulator's promise)
    np.testing.assert_array_equal(a[0].outputs["gyro_x"], b[0].outputs["gyro_x"])


def test_import_thermonet_cli_and_config_stays_light():
    code = ("import sys, thermonet, thermonet.cli, thermonet.training.config; thermonet.cli.build_parser()\n"
            "heavy = [m for m in ('torch', 'allantools', 'scipy.signal', 'sklearn', 'pandas',\n"
            "         'matplotlib', 'mlflow', 'onnx') if m in sys.modules]\n"
            "print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]"


def test_a_config_error_is_refused_before_anything_heavy_loads(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("split: {strategy: random}\n")
    code = ("import sys\nfrom thermonet.cli import main\n"
            f"rc = main(['compare', {str(bad)!r}, '--out', {str(tmp_path / 'out')!r}])\n"
            "heavy = [m for m in ('torch', 'sklearn', 'pandas', 'matplotlib', 'mlflow')\n"
            "         if m in sys.modules]\n"
            "print(rc, heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT)
    assert out.stdout.strip() == "1 []", (out.stdout, out.stderr[-300:])
    assert "split.strategy" in out.stderr and not (tmp_path / "out").exists()


def test_readme_python_example_runs(tmp_path, monkeypatch, capsys):
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Python API"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README.md", "exec"), {})
    score = float(re.search(r"held-out score ([0-9.]+)", capsys.readouterr().out).group(1))
    assert score > 0.99
    assert (tmp_path / "cubic.pt").is_file() and (tmp_path / "cubic.onnx").is_file()


# ------------------------------------------- extension points: registration only
class Quadratic(Family):
    """A toy family: b + c1 z + c2 z² on one input (what a new family module would hold)."""

    name = "toy-quadratic"
    max_inputs = 1

    def __init__(self, *, n_inputs: int, n_outputs: int) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        self.coef = nn.Parameter(torch.zeros(n_outputs, 3))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.coef[:, 0] + z * self.coef[:, 1] + z * z * self.coef[:, 2]

    def initialize(self, x, y, *, seed=0, x_mean=None, x_std=None) -> None:
        xn = as_numpy(x)[:, 0]
        coef = least_squares(np.column_stack([np.ones_like(xn), xn, xn * xn]), as_numpy(y))
        with torch.no_grad():
            self.coef.copy_(torch.as_tensor(coef.T))

    def polynomial_form(self) -> np.ndarray:
        return as_numpy(self.coef)


def _write_npz(model, out: Path, request) -> Path:
    """A toy export format: the standardised polynomial and the scaling, as .npz."""
    np.savez(out, form=model.family.polynomial_form(), y_mean=as_numpy(model.y_mean),
             y_std=as_numpy(model.y_std), units=str(request.output_units))
    return out


@pytest.fixture
def toy_extensions(monkeypatch):
    monkeypatch.setitem(MODELS, "toy-quadratic", Quadratic)           # the one family line
    monkeypatch.setitem(FORMATS, "toy-npz", ExportFormat(              # the one format line
        "toy-npz", "polynomial coefficients as .npz", _write_npz))
    yield


def test_a_family_and_a_format_are_added_by_registration_only(toy_extensions, tmp_path, capsys):
    from thermonet.cli import main
    from thermonet.exporting import read_px4_params

    ds = toy_dataset(n_runs=3, noise=0.0005)
    est = thermonet.DriftEstimator("toy-quadratic", ["dT"]).fit(ds.runs[:2], val=ds[2])
    inside = ds[2].temperature_c <= ds[1].temperature_c.max()
    assert np.max(np.abs(est.predict(ds[2])[:, 0] - _true_drift(ds[2]))[inside]) < 5e-4
    # save/load, the ONNX export and its parity check, the autopilot formats through the hook
    back = thermonet.DriftEstimator.load(est.save(tmp_path / "toy.pt"))
    # saved and loaded: the same weights through the same computation, bit for bit
    np.testing.assert_array_equal(back.predict(ds[2]), est.predict(ds[2]))
    assert est.export(tmp_path / "toy.onnx", format="onnx").stat().st_size > 0
    params = read_px4_params(est.export(tmp_path / "toy.params", format="px4-params",
                                        device_id=7))
    assert params["TC_G0_X3_0"] == 0.0 and params["TC_G0_X2_0"] != 0.0   # a quadratic
    # the new format, from the API and from the command line (choices come from the registry)
    npz = np.load(est.export(tmp_path / "toy.npz", format="toy-npz"))
    assert npz["form"].shape == (1, 3)
    assert main(["export", str(tmp_path / "toy.pt"), "--format", "toy-npz",
                 "--out", str(tmp_path / "cli.npz")]) == 0
    assert "wrote" in capsys.readouterr().out
    # the same checkpoint through the same exporter: bit-identical
    np.testing.assert_array_equal(np.load(tmp_path / "cli.npz")["form"], npz["form"])


def test_registering_a_format_twice_is_refused():
    with pytest.raises(ValueError, match="'onnx' is already registered"):
        register_format(ExportFormat("onnx", "again", _write_npz))


class _Knee(Family):
    """A plug-in whose hyper-parameter is a keyword-only constructor argument (no spec, no
    hyper()): a line, and a hinge from ``knee`` (°C) on."""

    name, max_inputs, default_inputs = "toy-knee", 1, ["T"]

    def __init__(self, *, n_inputs: int, n_outputs: int, knee: float = 25.0) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        self.knee = float(knee)
        self.coef = nn.Parameter(torch.zeros(3, n_outputs))
        self.register_buffer("_m", torch.zeros(()))
        self.register_buffer("_s", torch.ones(()))

    def _design(self, z: torch.Tensor) -> torch.Tensor:
        k = (self.knee - self._m) / self._s
        return torch.stack([z[:, 0] ** 0, z[:, 0], torch.relu(z[:, 0] - k)], 1)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self._design(z) @ self.coef

    def trainable(self) -> bool:
        return False

    def initialize(self, x, y, *, seed=0, x_mean=None, x_std=None) -> None:
        self._m.fill_(float(x_mean[0]))
        self._s.fill_(float(x_std[0]))
        with torch.no_grad():
            self.coef.copy_(torch.linalg.lstsq(self._design(x), y).solution)


class _KneeForgot(_Knee):
    name = "toy-knee-forgot"

    def __init__(self, *, n_inputs: int, n_outputs: int, bend: float = 25.0) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs, knee=bend)   # not self.bend


def test_a_plugins_keyword_only_hyper_parameter_survives_save_and_load(monkeypatch, tmp_path):
    monkeypatch.setitem(MODELS, "toy-knee", _Knee)
    monkeypatch.setitem(MODELS, "toy-knee-forgot", _KneeForgot)
    ds = toy_dataset(n_runs=3, noise=0.0005)
    est = thermonet.DriftEstimator("toy-knee", knee=0.0).fit(ds.runs[:2])
    assert est.model_.family.hyper() == {"knee": 0.0}
    back = thermonet.DriftEstimator.load(est.save(tmp_path / "knee.pt"))
    assert back.model_.family.knee == 0.0            # not the default 25.0
    np.testing.assert_allclose(back.predict(ds[2]), est.predict(ds[2]), rtol=0, atol=1e-6)
    # a keyword-only argument it does not store under its name: refused at save, one line
    forgot = thermonet.DriftEstimator("toy-knee-forgot", bend=0.0).fit(ds.runs[:2])
    with pytest.raises(ConfigError, match=r"keyword-only argument 'bend' of _KneeForgot.__init__ "
                       r"is not stored as an attribute .*store it \(self.bend = bend\) or "
                       r"define hyper\(\)") as info:
        forgot.save(tmp_path / "forgot.pt")
    assert "\n" not in str(info.value) and not (tmp_path / "forgot.pt").exists()
