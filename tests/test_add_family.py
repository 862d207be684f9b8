"""Adding a family is one class and one registration (issue 51, item 3).

The class below is a whole new family — a drift whose slope changes at a knee temperature,
:math:`a + b\\,T + c\\,\\max(0, T - T_k)`, with the knee :math:`T_k` a hyper-parameter — written
as a user would: its hyper-parameter declared once in its body (default and rule, through
:func:`thermonet.models.specs.param`), its math once in :meth:`Hinge.design`.  One
:func:`~thermonet.models.register_family` call later it is a family like the built-ins: a spec
by name with its default, the config's and the API's checks in the same words, a
:class:`~thermonet.DriftEstimator` fit on simulated recordings that recovers the coefficients
the data were made with, and an ONNX file through the format registry that onnxruntime runs
to the fitted model's predictions.  It is unregistered afterwards.
"""

from __future__ import annotations

import pickle

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from sklearn.base import clone

import thermonet
from conftest import toy_dataset
from thermonet.core.errors import ConfigError
from thermonet.core.recording import Dataset
from thermonet.exporting import FORMATS
from thermonet.models import Family, hyper, register_family, registry
from thermonet.models.specs import param

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

#: The drift the recordings carry: a + b·T + c·max(0, T − knee), deg/s and °C.
A, B, C, KNEE = 0.05, 0.01, -0.03, 30.0
NOISE = 0.002


class Hinge(Family):
    """:math:`a + b\\,T + c\\,\\max(0, T - T_k)` per axis: one class is the whole family."""

    name, max_inputs, default_inputs = "hinge", 1, ["T"]
    knee: float = param(default=25.0, rule=hyper.number(-60.0, 150.0,
                                                        "a temperature in [-60, 150] °C"))
    k: torch.Tensor                                    # a buffer, for the type checker

    def __init__(self, *, n_inputs: int, n_outputs: int, **given: object) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        self.take_hyper(given)                         # its spec: the default, the rule
        self.coef = torch.nn.Parameter(torch.zeros(3, n_outputs))
        self.register_buffer("k", torch.zeros(()))    # the knee, standardised

    def design(self, z: torch.Tensor) -> torch.Tensor:
        return torch.stack([z[:, 0] ** 0, z[:, 0], torch.relu(z[:, 0] - self.k)], 1)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.design(z) @ self.coef

    def initialize(self, x, y, *, seed=0, x_mean=None, x_std=None) -> None:  # closed form
        self.k.fill_(float((self.knee - x_mean[0]) / x_std[0]))
        with torch.no_grad():
            self.coef.copy_(torch.linalg.lstsq(self.design(x), y).solution)

    def trainable(self) -> bool:
        return False                                   # the least-squares fit is final


@pytest.fixture(scope="module")
def hinge():
    register_family(Hinge)                             # the one registration
    try:
        yield Hinge
    finally:
        registry.unregister_family("hinge")


def _recordings(n_runs: int = 3, seed: int = 0) -> Dataset:
    """1-axis gyro on 2-hour ramps −20 → 50 °C (0.5 Hz), the hinge drift plus white noise."""
    return toy_dataset(n_runs=n_runs, seed=seed, noise=NOISE, dt_s=2.0, run_step_c=0.3,
                       device_id="hinge-toy",
                       law=lambda temp: A + B * temp + C * np.maximum(0.0, temp - KNEE))


def test_one_class_and_one_registration_make_a_family(hinge):
    """Registered, the class is found by name; its spec is the one its body declared (the
    default, the rule, the inputs), and the config and the API refuse a value in its words."""
    from thermonet.training.config import config_from_mapping

    assert "hinge" in registry.family_names() and registry.get_family("hinge") is Hinge
    spec = registry.make_spec("hinge")
    assert spec == Hinge.spec() and spec.get_params() == {"knee": 25.0}
    assert Hinge.spec.rules() is not None and not hasattr(Hinge, "knee")   # moved to the spec
    assert (Hinge.spec.max_inputs, Hinge.spec.default_inputs) == (1, ("T",))
    fam = Hinge(n_inputs=1, n_outputs=2, knee=40)
    assert fam.knee == 40.0 and isinstance(fam.knee, float) and fam.hyper() == {"knee": 40.0}
    said = "hinge: knee must be a temperature in [-60, 150] °C, got 999"
    with pytest.raises(ConfigError, match=r"^hinge: knee must be"):
        Hinge(n_inputs=1, n_outputs=1, knee=999)
    with pytest.raises(ConfigError) as cfg_err:
        config_from_mapping({"families": [{"family": "hinge", "params": {"knee": 999},
                                           "inputs": ["T"]}]})
    with pytest.raises(ConfigError) as api_err:
        thermonet.DriftEstimator("hinge", knee=999).fit(None)
    assert said in str(cfg_err.value) and said in str(api_err.value)
    with pytest.raises(ConfigError, match=r"model 'hinge': unknown hyper-parameter 'kne' "
                                          r"\(valid: knee\)"):
        registry.make_spec("hinge", {"kne": 3})
    # a spec like the built-ins': scikit-learn's clone and pickle (found as Hinge.spec)
    twin = pickle.loads(pickle.dumps(Hinge.spec(knee=3.0)))
    assert twin == clone(Hinge.spec(knee=3.0)) == Hinge.spec(knee=3.0) and repr(twin) == \
        "Hinge(knee=3.0)"


@pytest.fixture(scope="module")
def fitted(hinge):
    ds = _recordings()
    est = thermonet.DriftEstimator("hinge", knee=KNEE).fit(ds[0], val=ds[1])
    return est, ds[2], ds[0]


def test_a_fit_recovers_the_coefficients_the_data_were_made_with(fitted):
    """The fitted model, read back on a held-out run as a + b·T + c·max(0, T − knee) by plain
    least squares, gives the a, b, c the recordings were simulated with — within about ten
    standard errors of white noise of NOISE on 3,600 samples (~2e-6 on b, ~5e-6 on c, ~5e-5
    on a), where the run stays inside the trained range (beyond it the model holds its edge
    value)."""
    est, test, train = fitted
    inside = (test.temperature_c >= train.temperature_c.min()) \
        & (test.temperature_c <= train.temperature_c.max())   # the model clamps beyond
    temp = test.temperature_c[inside]
    pred = est.predict(test)[inside, 0]
    design = np.column_stack([np.ones_like(temp), temp, np.maximum(0.0, temp - KNEE)])
    (a, b, c), *_ = np.linalg.lstsq(design, pred, rcond=None)
    assert abs(b - B) < 2e-5 and abs(c - C) < 6e-5 and abs(a - A) < 5e-4, (a, b, c)
    # the curve itself: within the noise's reach of the drift the run was made with
    truth = test.drift["drift_gyro_x"][inside]
    assert np.max(np.abs(pred - truth)) < 1e-3
    assert est.score(test) > 0.99


def test_it_exports_through_the_format_registry_and_runs_in_onnxruntime(fitted, tmp_path):
    """ONNX through the format registry (its parity check included, torch's exporter: the
    family has no hand-built graph); onnxruntime's drift is the estimator's prediction to
    float32 rounding."""
    est, test, _ = fitted
    assert "onnx" in FORMATS
    path = est.export(tmp_path / "hinge.onnx", format="onnx")
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert meta["exporter"] != "direct" and "hinge" in meta.values()
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    names = [i.name for i in sess.get_inputs()]
    assert names == ["temperature_c", "raw"]
    raw = test.outputs["gyro_x"][:, None].astype(np.float64)
    comp, drift, flag = sess.run(None, {"temperature_c": test.temperature_c.astype(np.float32),
                                        "raw": raw})
    pred = est.predict(test)
    scale = float(np.max(np.abs(pred)))
    np.testing.assert_allclose(drift, pred, rtol=0, atol=1e-5 * scale + 1e-7)
    np.testing.assert_allclose(comp, raw - drift, rtol=0, atol=1e-12)
    assert flag.dtype == np.bool_ and flag.shape == (raw.shape[0],)


def test_unregistering_leaves_the_built_ins(hinge):
    with pytest.raises(ValueError, match="built in"):
        registry.unregister_family("poly")
    assert list(registry.BUILTIN) == list(registry.FAMILIES)[:len(registry.BUILTIN)]


def test_registering_a_class_that_is_no_family_is_refused_in_one_line():
    class NotAFamily:
        name = "not-a-family"

    with pytest.raises(ConfigError, match=r"^register_family: 'NotAFamily' is neither a "
                       r"thermonet.models.Family subclass nor a family spec$"):
        register_family(NotAFamily)
    assert "not-a-family" not in registry.FAMILIES
