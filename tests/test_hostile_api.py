"""Hostile inputs, round three (issue 25), part A: the Python API (``DriftEstimator``).

A recording without a channel the model needs, a run with no samples, an empty list,
``None`` or a file name where recordings are meant: each is one ``ValueError`` (thermonet's
``ThermonetError``) naming the channel, the run or the problem — never a bare ``KeyError``,
``IndexError``, ``AttributeError`` or ``TypeError``.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import thermonet
from conftest import toy_dataset
from thermonet.core.errors import ThermonetError
from thermonet.core.recording import Dataset, Recording


def _two_axes(ds: Dataset) -> Dataset:
    """The toy runs with a second output ``gyro_y`` (half the drift of ``gyro_x``)."""
    return Dataset([replace(r, outputs={**r.outputs, "gyro_y": 0.5 * r.outputs["gyro_x"]},
                            units={**r.units, "gyro_y": "deg/s"}) for r in ds])


def _without(rec: Recording, channel: str) -> Recording:
    return replace(rec, outputs={k: v for k, v in rec.outputs.items() if k != channel},
                   references={k: v for k, v in rec.references.items()
                               if k != f"ref_{channel}"},
                   drift={k: v for k, v in rec.drift.items() if k != f"drift_{channel}"})


def _empty(rec: Recording) -> Recording:
    return rec.select(np.zeros(rec.n_samples, dtype=bool))


@pytest.fixture(scope="module")
def data() -> Dataset:
    return _two_axes(toy_dataset(n_runs=3, noise=0.0005))


@pytest.fixture(scope="module")
def fitted(data: Dataset) -> thermonet.DriftEstimator:
    return thermonet.DriftEstimator("poly", ["dT"], degree=2).fit(data.runs[:2])


def _one_value_error(call, *patterns: str) -> str:
    with pytest.raises(ValueError) as info:
        call()
    assert isinstance(info.value, ThermonetError), type(info.value)
    msg = str(info.value)
    assert "\n" not in msg
    for p in patterns:
        assert p in msg, msg
    return msg


# ------------------------------------------------------------------ fit
@pytest.mark.parametrize("train, patterns", [
    ([], ("fit(train)", "no recordings", "empty list")),
    ((), ("fit(train)", "no recordings", "empty tuple")),
    (Dataset([]), ("fit(train)", "no recordings", "empty Dataset")),
    (None, ("fit(train)", "expected a Dataset, a Recording or a list", "NoneType")),
    (42, ("fit(train)", "got int",)),
    ("runs/pg.parquet", ("fit(train)", "got str", "thermonet.read")),
    (Path("runs/pg.parquet"), ("fit(train)", "thermonet.read")),
    ([None], ("fit(train)", "item 0 is a NoneType")),
])
def test_fit_on_nothing_or_not_recordings_is_one_clear_error(train, patterns) -> None:
    _one_value_error(lambda: thermonet.DriftEstimator("poly", ["dT"], degree=2).fit(train),
                     *patterns)


def test_fit_on_zero_samples_names_the_run(data: Dataset) -> None:
    est = thermonet.DriftEstimator("poly", ["dT"], degree=2)
    empty = _empty(data[0])
    _one_value_error(lambda: est.fit(empty), "fit(train)", f"run '{empty.run_id}'",
                     "no samples")
    _one_value_error(lambda: est.fit([data[0], empty]), "no samples")
    _one_value_error(lambda: est.fit(data[0], val=empty), "fit(val)", "no samples")
    _one_value_error(lambda: est.fit(data[0], val=[]), "fit(val)", "no recordings")
    assert not hasattr(est, "model_")


def test_fit_without_a_channel_the_model_needs_names_it(data: Dataset) -> None:
    no_y = _without(data[1], "gyro_y")
    est = thermonet.DriftEstimator("poly", ["dT"], degree=2)
    # a second training run without gyro_y (the first run's outputs are the model's)
    _one_value_error(lambda: est.fit([data[0], no_y]), "fit(train)", "run 'run1'",
                     "no output channel 'gyro_y'", "the run has gyro_x")
    _one_value_error(lambda: est.fit(data[0], val=no_y), "fit(val)", "'gyro_y'")
    # outputs= names a channel no run has
    _one_value_error(lambda: thermonet.DriftEstimator("poly", ["dT"], degree=2,
                                                      outputs=["gyro_q"]).fit(data[0]),
                     "no output channel 'gyro_q'", "gyro_x, gyro_y")
    # a four-position model needs the axis behind '<axis>.bias'
    _one_value_error(lambda: thermonet.DriftEstimator("poly", ["dT"], degree=2,
                                                      target="four-position",
                                                      outputs=["acc_x"]).fit(data[0]),
                     "no output channel 'acc_x'")


def test_fit_without_the_signal_an_input_needs_names_the_column(data: Dataset) -> None:
    no_temp = replace(data[0], temperature_c=None)
    with pytest.raises(ValueError, match="temperature_c"):
        thermonet.DriftEstimator("poly", ["dT"], degree=2).fit(no_temp)
    with pytest.raises(ValueError, match="freq_hz"):
        thermonet.DriftEstimator("poly", ["d_freq_hz"], degree=2).fit(data[0])


# ----------------------------------------------- predict, score, compensate
def test_score_and_compensate_without_a_channel_name_it(fitted: thermonet.DriftEstimator,
                                                        data: Dataset) -> None:
    no_x = _without(data[2], "gyro_x")
    for name, call in (("score", fitted.score), ("compensate", fitted.compensate)):
        _one_value_error(lambda call=call: call(no_x), f"{name}:", "run 'run2'",
                         "no output channel 'gyro_x'", "the model needs gyro_x, gyro_y",
                         "the run has gyro_y")
    # predict needs only the model's signals (the drift it predicts is for every axis)
    pred = fitted.predict(no_x)
    # exact: the same signals through the same model in the same process (bit-identical)
    np.testing.assert_allclose(pred, fitted.predict(data[2]), rtol=0, atol=0)


def test_predict_score_compensate_without_the_thermometer_name_it(
        fitted: thermonet.DriftEstimator, data: Dataset) -> None:
    no_temp = replace(data[2], temperature_c=None)
    for call in (fitted.predict, fitted.score, fitted.compensate):
        with pytest.raises(ValueError, match="temperature_c") as info:
            call(no_temp)
        assert "\n" not in str(info.value)


def test_a_dataset_or_a_list_is_taken_run_by_run(fitted: thermonet.DriftEstimator,
                                                 data: Dataset) -> None:
    """predict, score and compensate take a Recording, a list or a Dataset, as fit does."""
    runs = [data[1], data[2]]
    one_by_one = [fitted.predict(r) for r in runs]
    for given in (runs, Dataset(runs)):
        # the same runs through the same model: bit-identical, rows run after run
        np.testing.assert_array_equal(fitted.predict(given), np.concatenate(one_by_one))
    # score pools every run's squares about that run's mean (offset-free, as compare): by
    # hand from the predictions and the outputs (the toy runs have no reference channel:
    # the observed drift is the output itself)
    ys = [np.column_stack([r.outputs["gyro_x"], r.outputs["gyro_y"]]) for r in runs]
    raw = sum(np.sum((y - y.mean(0)) ** 2, axis=0) for y in ys)
    comp = sum(np.sum((y - p - (y - p).mean(0)) ** 2, axis=0)
               for y, p in zip(ys, one_by_one, strict=True))
    expected = 1.0 - np.mean(comp / raw)
    assert fitted.score(Dataset(runs)) == pytest.approx(expected, rel=1e-12)
    assert fitted.score(runs) == pytest.approx(expected, rel=1e-12)
    clean = fitted.compensate(Dataset(runs))
    assert isinstance(clean, Dataset) and isinstance(fitted.compensate(runs), list)
    for r, c, p in zip(runs, clean, one_by_one, strict=True):
        np.testing.assert_array_equal(c.outputs["gyro_x"], r.outputs["gyro_x"] - p[:, 0])


@pytest.mark.parametrize("method", ["predict", "score", "compensate"])
def test_not_recordings_are_one_clear_error(fitted: thermonet.DriftEstimator, data: Dataset,
                                            method: str) -> None:
    call = getattr(fitted, method)
    _one_value_error(lambda: call(None), f"{method}: expected a Dataset, a Recording or a list",
                     "got NoneType")
    _one_value_error(lambda: call("run.csv"), "got str", "thermonet.read")
    _one_value_error(lambda: call([data[2], 7]), "item 1 is a int")
    _one_value_error(lambda: call([]), "no recordings")


def test_empty_recordings_predict_empty_but_cannot_be_scored(fitted: thermonet.DriftEstimator,
                                                             data: Dataset) -> None:
    empty = _empty(data[2])
    assert fitted.predict(empty).shape == (0, 2)          # an empty batch: empty output
    assert fitted.compensate(empty).n_samples == 0
    _one_value_error(lambda: fitted.score(empty), "score: run 'run2' has no samples")


def test_the_good_path_is_unchanged(fitted: thermonet.DriftEstimator, data: Dataset) -> None:
    drift = data[2].drift["drift_gyro_x"]
    inside = data[2].temperature_c <= data[1].temperature_c.max()
    pred = fitted.predict(data[2])
    np.testing.assert_allclose(pred[inside, 0], drift[inside], atol=5e-4)
    np.testing.assert_allclose(pred[:, 1], 0.5 * pred[:, 0], rtol=1e-3, atol=1e-6)
    assert fitted.score(data[2]) > 0.99
