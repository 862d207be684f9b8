"""The training loop: determinism, NaN handling, early stopping, decimation, clamping."""

import numpy as np
import pytest
import torch

from thermonet.core.errors import ConfigError, FitError, InputError
from thermonet.features.inputs import FeatureSpec
from thermonet.models.base import Family
from thermonet.training.train import TrainConfig, decimate, fit, predict

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

T = np.linspace(-20.0, 60.0, 400)
Y = (0.01 * np.sin(T / 15.0))[:, None]


def _fit(family="rbf", y=Y, t=T, val=None, hyper=None, inputs=("dT",), **cfg):
    spec = FeatureSpec(inputs=list(inputs), t_ref=25.0)
    return fit(family=family, inputs=list(inputs), outputs=["gyro_x"], train=[(t[:, None], y)],
               val=val, spec=spec, hyper=hyper if hyper is not None else {"n_centres": 6},
               config=TrainConfig(**cfg))


@pytest.mark.parametrize("init", ["kmeans", "random"])
def test_same_seed_gives_identical_predictions(init):
    a = _fit(hyper={"n_centres": 6, "init": init}, max_epochs=40, seed=7)
    b = _fit(hyper={"n_centres": 6, "init": init}, max_epochs=40, seed=7)
    pa, pb = predict(a.model, T[:, None]), predict(b.model, T[:, None])
    np.testing.assert_array_equal(pa, pb)   # same seed, same computation: bit-identical
    assert [h["train_loss"] for h in a.history] == [h["train_loss"] for h in b.history]


def test_nan_target_is_a_fit_error_naming_the_row():
    y = Y.copy()
    y[17, 0] = np.nan
    with pytest.raises(FitError, match="target 'gyro_x' is nan at row 17"):
        _fit(y=y, max_epochs=5)


def test_diverging_optimizer_reports_nan_loss_epoch():
    with pytest.raises(FitError, match="NaN loss at epoch 1"):
        _fit(family="ts-fuzzy", hyper={"n_sets": 3}, max_epochs=5, lr=1e20, optimizer="adam")


def test_early_stopping_on_validation_stops_and_keeps_best_state():
    # The validation run drifts the opposite way: every training step away from
    # the start makes validation worse, so the best epoch is an early one.
    val = (T[:, None], -Y + 0.002)
    res = _fit(hyper={"n_centres": 6, "init": "random"}, val=val, max_epochs=500, patience=20,
               lr=0.05)
    assert len(res.history) < 500 + 1
    assert len(res.history) == res.best_epoch + 20 + 1
    best_val = min(h["val_loss"] for h in res.history)
    assert res.best_val_loss == pytest.approx(best_val)
    assert res.history[res.best_epoch]["val_loss"] == pytest.approx(best_val)


def test_plateau_without_validation_stops_early():
    # linear data: the fuzzy model's least-squares consequents are exact at epoch 0; no step
    # improves by min_delta
    res = _fit(family="ts-fuzzy", hyper={"n_sets": 3}, y=(1e-3 * T)[:, None], max_epochs=1000,
               patience=15)
    assert res.best_epoch == 0
    assert len(res.history) == 16
    assert res.best_val_loss is None


@pytest.mark.parametrize("family,hyper", [("linear", {}), ("poly", {"degree": 3})])
def test_closed_form_families_are_final_least_squares(family, hyper):
    """Linear and poly are fitted in closed form and not refined (``trainable`` False): one
    epoch in the history whatever ``max_epochs`` says, and the coefficients are the least
    squares of the standardised design (numpy.linalg.lstsq, the independent oracle)."""
    from thermonet.models.base import as_numpy

    sig, y = T[:, None], Y
    spec = FeatureSpec(inputs=["dT"], t_ref=25.0)
    res = fit(family=family, inputs=["dT"], outputs=["gyro_x"], train=[(sig, y)],
              val=(sig, y), spec=spec, hyper=hyper, config=TrainConfig(max_epochs=50))
    assert len(res.history) == 1 and res.best_epoch == 0
    m = res.model
    with torch.no_grad():
        x = m.features(torch.as_tensor(sig)).numpy()
    z = (x - as_numpy(m.x_mean).astype(np.float64)) / as_numpy(m.x_std).astype(np.float64)
    fam = m.family
    with torch.no_grad():
        d = fam.design(torch.as_tensor(z)).numpy() if family == "poly" else z
    yz = (y - y.mean(axis=0) - as_numpy(m.y_mean)) / as_numpy(m.y_std)
    want = np.linalg.lstsq(np.hstack([d, np.ones((d.shape[0], 1))]), yz, rcond=None)[0]
    got = np.concatenate([as_numpy(fam.weight)[0], as_numpy(fam.bias)])
    # float32 parameters and scaling buffers: relative to the largest coefficient
    np.testing.assert_allclose(got, want[:, 0], rtol=0, atol=1e-4 * np.abs(want).max())


def test_on_epoch_callback_sees_every_epoch():
    seen = []
    res = fit(family="rbf", inputs=["dT"], outputs=["gyro_x"], train=[(T[:, None], Y)],
              val=(T[:, None], Y), spec=FeatureSpec(inputs=["dT"], t_ref=25.0),
              hyper={"n_centres": 6}, config=TrainConfig(max_epochs=12, patience=100),
              on_epoch=lambda e, tl, vl: seen.append((e, tl, vl)))
    assert [e for e, _, _ in seen] == list(range(13))
    assert seen[-1][1] == pytest.approx(res.history[-1]["train_loss"])
    assert res.fit_seconds > 0 and res.n_params == 6 + 6 + 6 + 1  # centres, widths, weights, bias


def test_decimation_is_even_and_fit_still_recovers_a_line():
    runs = [(np.arange(1000.0)[:, None], np.arange(1000.0)[:, None]),
            (np.arange(500.0)[:, None], np.arange(500.0)[:, None])]
    out = decimate(runs, 150)                 # total 1500 -> every 10th sample
    np.testing.assert_array_equal(out[0][0][:, 0], np.arange(0, 1000, 10))
    np.testing.assert_array_equal(out[1][1][:, 0], np.arange(0, 500, 10))
    res = _fit(family="linear", hyper={}, y=(2e-3 * T - 0.01)[:, None], max_epochs=5,
               max_train_samples=40)
    slope = np.polyfit(T, predict(res.model, T[:, None])[:, 0], 1)[0]
    assert slope == pytest.approx(2e-3, rel=1e-3)


def test_clamp_outside_trained_range_and_out_of_range_flag():
    res = _fit(family="poly", hyper={"degree": 2}, y=(1e-4 * (T - 25) ** 2)[:, None], max_epochs=5)
    m = res.model
    s = np.array([[-50.0], [-20.0], [60.0], [95.0], [np.nan], [20.0]])
    pred = predict(m, s[[0, 1, 2, 3, 5]])[:, 0]
    assert pred[0] == pytest.approx(pred[1], rel=1e-6)   # clamped to −20 °C
    assert pred[3] == pytest.approx(pred[2], rel=1e-6)   # clamped to 60 °C
    assert pred[2] == pytest.approx(1e-4 * 35 ** 2, rel=1e-4)
    flags = m.out_of_range(torch.as_tensor(s)).numpy()
    np.testing.assert_array_equal(flags, [True, False, False, True, True, False])


def test_config_and_shape_errors_name_the_key():
    with pytest.raises(ConfigError, match="train.optimizer"):
        TrainConfig(optimizer="sgd")
    with pytest.raises(ConfigError, match="train.patience"):
        TrainConfig(patience=0)
    with pytest.raises(ConfigError, match="differ from the feature spec"):
        fit(family="linear", inputs=["T"], outputs=["gyro_x"], train=[(T[:, None], Y)], val=None,
            spec=FeatureSpec(inputs=["dT"], t_ref=0.0), hyper={}, config=TrainConfig())
    res = _fit(family="linear", hyper={}, max_epochs=2)
    with pytest.raises(InputError, match=r"expected \(n, 1\)"):
        predict(res.model, np.zeros((4, 2)))


def test_a_fit_leaves_the_callers_torch_random_state_as_it_was():
    torch.manual_seed(11)
    expected = torch.rand(4)
    torch.manual_seed(11)
    a = _fit(hyper={"n_centres": 6, "init": "random"}, max_epochs=5, seed=3)
    np.testing.assert_array_equal(torch.rand(4).numpy(), expected.numpy())
    # the fit's own seeded sequence is unchanged: whatever the caller's state, the same fit
    torch.manual_seed(99)
    b = _fit(hyper={"n_centres": 6, "init": "random"}, max_epochs=5, seed=3)
    np.testing.assert_array_equal(predict(a.model, T[:, None]), predict(b.model, T[:, None]))


class _Frozen(Family):
    """A plug-in whose one parameter is frozen, trainable() left True."""

    name, max_inputs = "toy-frozen", 1

    def __init__(self, *, n_inputs: int, n_outputs: int, nan: bool = False) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        self.nan = bool(nan)
        self.w = torch.nn.Parameter(torch.zeros(n_inputs, n_outputs), requires_grad=nan)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        out = z @ self.w
        return out * float("nan") if self.nan else out

    def initialize(self, x, y, *, seed=0, x_mean=None, x_std=None) -> None:
        pass


def test_a_plugin_without_trainable_parameters_or_with_nan_output_is_told_why(monkeypatch):
    from thermonet.models import MODELS

    monkeypatch.setitem(MODELS, "toy-frozen", _Frozen)
    with pytest.raises(FitError, match=r"^model 'toy-frozen': no trainable parameter, yet "
                       r"trainable\(\) is True; a closed-form family returns False from "
                       r"trainable\(\)$"):
        _fit(family="toy-frozen", hyper={}, max_epochs=5)
    with pytest.raises(FitError, match=r"^model 'toy-frozen': the family's own output is "
                       r"NaN/inf on the first training rows after initialize\(\), before any "
                       r"training step") as info:
        _fit(family="toy-frozen", hyper={"nan": True}, max_epochs=5)
    assert "lr" not in str(info.value)
