"""Hostile inputs, round three, part A: the Python API (``DriftEstimator``).

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


def test_predict_refuses_outputs_in_another_unit_as_score_does(
        fitted: thermonet.DriftEstimator, data: Dataset) -> None:
    """The drift is in the training outputs' unit: a run carrying them in another is refused
    by predict too, naming both units; a run without them is still predicted."""
    rad = replace(data[2], units={**data[2].units, "gyro_x": "rad/s"})
    for name in ("predict", "score", "compensate"):
        msg = _one_value_error(lambda name=name: getattr(fitted, name)(rad), f"{name}:",
                               "run 'run2' has gyro_x in 'rad/s', the model was trained in "
                               "'deg/s'")
        assert "in in" not in msg


@pytest.mark.parametrize("unit", ["K", "degF", "counts"])
def test_a_temperature_not_in_degc_is_refused_everywhere(fitted: thermonet.DriftEstimator,
                                                         data: Dataset, unit: str) -> None:
    """fit's rule (an unknown unit; the temperature in degC), one function for all four."""
    rec = replace(data[2], units={**data[2].units, "temperature_c": unit})
    said = f"unknown unit '{unit}'" if unit != "counts" else "temperature in 'counts', expected degC"
    for name in ("predict", "score", "compensate"):
        _one_value_error(lambda name=name: getattr(fitted, name)(rec),
                         f"{name}, run 'run2', column 'temperature_c': {said}")
    _one_value_error(lambda: thermonet.DriftEstimator("poly", ["dT"]).fit([rec]),
                     f"fit(train), run 'run2', column 'temperature_c': {said}")


def test_the_good_path_is_unchanged(fitted: thermonet.DriftEstimator, data: Dataset) -> None:
    drift = data[2].drift["drift_gyro_x"]
    inside = data[2].temperature_c <= data[1].temperature_c.max()
    pred = fitted.predict(data[2])
    np.testing.assert_allclose(pred[inside, 0], drift[inside], atol=5e-4)
    np.testing.assert_allclose(pred[:, 1], 0.5 * pred[:, 0], rtol=1e-3, atol=1e-6)
    assert fitted.score(data[2]) > 0.99


# ------------------------------------------------- every argument checked at the door
# Each bad value is refused in one line naming the argument, before any data is read: the
# files named here do not exist, and the data given is None, so an error about either would
# mean the argument was not checked first.

NOT_A_NUMBER = [True, False, "10", b"10", [10], None, object()]
NOT_A_FLAG = ["no", "yes", "False", 0, 1, 1.0, None, [True]]
NOT_A_PATH = [123, 1.5, True, b"x.csv", {"path": "x"}, object()]


def _refused(call, argument: str, *more: str, kind: type[Exception] = ValueError) -> str:
    with pytest.raises(kind) as info:
        call()
    assert isinstance(info.value, ThermonetError), type(info.value)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(argument), msg
    for m in more:
        assert m in msg, msg
    return msg


MISSING = "no/such/dir/run.parquet"


@pytest.mark.parametrize("paths", NOT_A_PATH + [[], [MISSING, 5], ()])
def test_read_paths_must_be_paths(paths) -> None:
    _refused(lambda: thermonet.read(paths), "read(paths")


@pytest.mark.parametrize("mapping", NOT_A_PATH + ["", "   "])
def test_read_mapping_must_be_a_path(mapping) -> None:
    _refused(lambda: thermonet.read(MISSING, mapping), "read(mapping)")


@pytest.mark.parametrize("window_s", [v for v in NOT_A_NUMBER if v is not None]
                         + [0, 0.0, -1.0, float("nan"), float("inf"), -float("inf")])
def test_read_window_s_is_seconds_and_bool_is_no_number(window_s) -> None:
    _refused(lambda: thermonet.read(MISSING, window_s=window_s), "read(window_s)",
             "a number of seconds > 0")


@pytest.mark.parametrize("inputs, said", [
    (["dX"], "unknown model input 'dX'"), ("bogus", "unknown model input 'bogus'"),
    (["dT", "dT"], "names an input twice"), ([3], "expected names (strings)"),
    (["dT", None], "expected names (strings)"), (5, "expected an input name"),
    ({"dT": 1}, "expected an input name"), (["d", "T"], "unknown model input 'd'"),
])
def test_read_inputs_are_known_input_names(inputs, said) -> None:
    _refused(lambda: thermonet.read(MISSING, window_s=10.0, inputs=inputs), "read(inputs)",
             said)


def test_read_inputs_alone_are_one_name_not_letters(tmp_path: Path) -> None:
    """``inputs="dT"`` is the input dT (it used to be read as ['d', 'T'])."""
    from thermonet.data.io import write_parquet

    f = tmp_path / "run.parquet"
    write_parquet(toy_dataset(n_runs=1), f)
    one = thermonet.read(f, window_s=60.0, inputs="dT")
    listed = thermonet.read(f, window_s=60.0, inputs=["dT"])
    assert one[0].n_samples == listed[0].n_samples > 0
    np.testing.assert_array_equal(one[0].time_s, listed[0].time_s)


def test_read_inputs_that_would_be_ignored_are_refused() -> None:
    # (a mapping with window_s is no longer refused: any file streams through its mapping,
    # tests/test_stream_any_file.py)
    _refused(lambda: thermonet.read(MISSING, inputs=["dT"]), "read(inputs)", "window_s")


@pytest.mark.parametrize("gap_s", [True, "manual", "", -1.0, 0.0, float("nan"), 1e9, [1.0]])
def test_read_gap_s_is_auto_or_seconds(gap_s) -> None:
    _refused(lambda: thermonet.read(MISSING, window_s=10.0, gap_s=gap_s), "read(gap_s)")


@pytest.mark.parametrize("chunk_rows", [0, -5, 1.5, True, "100", None])
def test_read_chunk_rows_is_a_whole_number(chunk_rows) -> None:
    _refused(lambda: thermonet.read(MISSING, window_s=10.0, chunk_rows=chunk_rows),
             "read(chunk_rows)", "a whole number >= 1")


@pytest.mark.parametrize("kind", [TypeError, ValueError])
def test_a_wrong_type_is_a_type_error_and_a_value_error(kind) -> None:
    _refused(lambda: thermonet.read(123), "read(paths)", kind=kind)
    _refused(lambda: thermonet.compare(workers="4"), "compare(workers)", kind=kind)


@pytest.mark.parametrize("preset, runs, seed, argument", [
    (None, 1, 0, "simulate(preset)"), (3, 1, 0, "simulate(preset)"),
    ("", 1, 0, "simulate(preset)"), ("patent-gyro", 0, 0, "simulate(runs)"),
    ("patent-gyro", True, 0, "simulate(runs)"), ("patent-gyro", 2.5, 0, "simulate(runs)"),
    ("patent-gyro", 10**6, 0, "simulate(runs)"), ("patent-gyro", "3", 0, "simulate(runs)"),
    ("patent-gyro", 1, -1, "simulate(seed)"), ("patent-gyro", 1, False, "simulate(seed)"),
    ("patent-gyro", 1, 0.5, "simulate(seed)"), ("patent-gyro", 1, None, "simulate(seed)"),
])
def test_simulate_arguments(preset, runs, seed, argument) -> None:
    _refused(lambda: thermonet.simulate(preset, runs=runs, seed=seed), argument)


# compare: a config whose data are files that do not exist, so that reading them would fail
_UNREAD = {"data": {"paths": [MISSING]},
           "families": [{"family": "poly", "inputs": ["dT"], "params": {"degree": 2}}]}


@pytest.mark.parametrize("value", NOT_A_FLAG)
@pytest.mark.parametrize("argument", ["track", "overwrite", "plots", "quiet"])
def test_compare_switches_are_true_or_false(argument, value, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    _refused(lambda: thermonet.compare(_UNREAD, **{argument: value}), f"compare({argument})",
             "expected True or False")
    assert not (tmp_path / "mlflow.db").exists() and not list(tmp_path.iterdir())


@pytest.mark.parametrize("workers", [-1, -3, True, False, 1.5, "4", [2], float("nan")])
def test_compare_workers_is_a_whole_number_or_none(workers) -> None:
    _refused(lambda: thermonet.compare(_UNREAD, workers=workers), "compare(workers)",
             "a whole number >= 0 (0: one per CPU) or None")


@pytest.mark.parametrize("out", NOT_A_PATH + [""])
def test_compare_out_is_a_path_or_none(out) -> None:
    _refused(lambda: thermonet.compare(_UNREAD, out=out), "compare(out)")


@pytest.mark.parametrize("uri", [5, True, b"sqlite:///x.db", "", ["sqlite:///x.db"]])
def test_compare_tracking_uri_is_a_string_or_none(uri) -> None:
    _refused(lambda: thermonet.compare(_UNREAD, tracking_uri=uri), "compare(tracking_uri)")


@pytest.mark.parametrize("config", [5, True, ["families"], b"c.yaml", ""])
def test_compare_config_is_a_path_a_dict_or_a_config(config) -> None:
    _refused(lambda: thermonet.compare(config), "compare(config)")


@pytest.mark.parametrize("params, key", [
    ({"degree": 40}, "families[0].params.degree"),
    ({"degree": True}, "families[0].params.degree"),
    ({"degree": "3"}, "families[0].params.degree"), ({"cross": "no"}, "families[0].params.cross"),
    ({"degre": 3}, "families[0]"),
])
def test_compare_hyper_parameters_checked_before_the_data(params, key) -> None:
    cfg = {**_UNREAD, "families": [{"family": "poly", "inputs": ["dT"], "params": params}]}
    _refused(lambda: thermonet.compare(cfg), "compare(config)", f"key '{key}")


# DriftEstimator: the constructor stores (scikit-learn's rule); fit checks every argument
# first — given None as data here, so any complaint about the data means it checked late
@pytest.mark.parametrize("kwargs, argument", [
    ({"family": 3}, "family"), ({"family": None}, "family"),
    ({"family": "polly"}, "unknown model family 'polly'"),
    ({"inputs": ["dX"]}, "inputs"), ({"inputs": "dX"}, "inputs"), ({"inputs": []}, "inputs"),
    ({"inputs": [1]}, "inputs"), ({"inputs": 7}, "inputs"), ({"inputs": ["dT", "dT"]}, "inputs"),
    ({"t_ref": True}, "t_ref"), ({"t_ref": "end"}, "t_ref"), ({"t_ref": float("nan")}, "t_ref"),
    ({"t_ref": 1e6}, "t_ref"), ({"t_ref": None}, "t_ref"),
    ({"t_ref_window_min": 0}, "t_ref_window_min"), ({"t_ref_window_min": True},
                                                    "t_ref_window_min"),
    ({"t_ref_window_min": 1e5}, "t_ref_window_min"),
    ({"gap_s": "never"}, "gap_s"), ({"gap_s": False}, "gap_s"), ({"gap_s": -2.0}, "gap_s"),
    ({"target": "bias"}, "target"), ({"target": {"gyro": "sideways"}}, "target"),
    ({"target": 3}, "target"),
    ({"outputs": []}, "outputs"), ({"outputs": [3]}, "outputs"), ({"outputs": 3}, "outputs"),
    ({"train_on": "cooling"}, "train_on"), ({"train_on": True}, "train_on"),
    ({"stderr": "jackknife"}, "stderr"), ({"stderr": None}, "stderr"),
    ({"train": 5}, "train"), ({"train": {"lrate": 1}}, "DriftEstimator: key 'train.lrate'"),
    ({"max_epochs": "5"}, "train.max_epochs"), ({"max_epochs": True}, "train.max_epochs"),
    ({"seed": 1.5}, "train.seed"), ({"lr": 0.0}, "train.lr"), ({"lr": float("inf")}, "train.lr"),
    ({"threads": -1}, "train.threads"), ({"optimizer": "sgd"}, "train.optimizer"),
    ({"degree": 40}, "poly: degree"), ({"degree": True}, "poly: degree"),
    ({"degree": 2.0}, "poly: degree"), ({"cross": "no"}, "poly: cross"),
    ({"degre": 3}, "model 'poly': unknown hyper-parameter 'degre'"),
])
def test_fit_checks_every_constructor_argument_before_the_data(kwargs, argument) -> None:
    args = {"family": "poly", "inputs": ["dT"], **kwargs}
    est = thermonet.DriftEstimator(**args)           # stores, never raises (scikit-learn)
    _refused(lambda: est.fit(None), argument)
    assert not hasattr(est, "model_")


@pytest.mark.parametrize("family, hyper, key", [
    ("rbf", {"width_scale": float("inf")}, "width_scale"),
    ("rbf", {"n_centres": 0}, "n_centres"), ("rbf", {"ridge": -1}, "ridge"),
    ("rbf", {"tail": 3, "init": "random"}, "tail needs init 'kmeans' or 'quantiles'"),
    ("mlp", {"hidden": "8"}, "hidden"), ("mlp", {"hidden": [0]}, "hidden"),
    ("mlp", {"activation": "sigmoid"}, "activation"),
    ("mlp", {"weight_decay": float("nan")}, "weight_decay"),
    ("lorentz", {"xc_margin": -1}, "xc_margin"), ("ts-fuzzy", {"n_sets": 1}, "n_sets"),
    ("ts-fuzzy", {"universe": [5, 1]}, "universe"),
    ("ts-fuzzy", {"universe": ["0", "1"]}, "universe"),
    ("gru", {"hidden": 0}, "hidden"), ("gru", {"step_s": True}, "step_s"),
])
def test_every_built_in_familys_values_checked_before_the_data(family, hyper, key) -> None:
    est = thermonet.DriftEstimator(family, ["dT"], **hyper)
    _refused(lambda: est.fit(None), f"{family}:", key)


@pytest.mark.parametrize("kwargs, argument", [
    ({"track": "no"}, "fit(track)"), ({"track": 1}, "fit(track)"),
    ({"track": None}, "fit(track)"), ({"tracking_uri": 5}, "fit(tracking_uri)"),
    ({"tracking_uri": ""}, "fit(tracking_uri)"), ({"experiment": ""}, "fit(experiment)"),
    ({"experiment": None}, "fit(experiment)"),
])
def test_fit_tracking_arguments(kwargs, argument, tmp_path, monkeypatch) -> None:
    """``track="no"`` used to turn tracking on and write mlflow.db in the working folder."""
    monkeypatch.chdir(tmp_path)
    est = thermonet.DriftEstimator("poly", ["dT"], degree=2)
    _refused(lambda: est.fit(toy_dataset(n_runs=1)[0], **kwargs), argument)
    assert not list(tmp_path.iterdir())


def test_inputs_as_one_name_fit_as_a_list_of_one(data: Dataset) -> None:
    one = thermonet.DriftEstimator("poly", "dT", degree=2).fit(data.runs[:2])
    assert one.spec_.inputs == ["dT"]
    listed = thermonet.DriftEstimator("poly", ["dT"], degree=2).fit(data.runs[:2])
    np.testing.assert_array_equal(one.predict(data[2]), listed.predict(data[2]))


def test_set_params_and_clone_never_raise_on_a_value_fit_does() -> None:
    from sklearn.base import clone

    est = thermonet.DriftEstimator("poly", ["dT"], degree=2)
    bad = clone(est.set_params(degree=40, cross="no"))
    _refused(lambda: bad.fit(None), "poly: degree")
    bad = clone(est.set_params(degree=3, max_epochs="x"))
    _refused(lambda: bad.fit(None), "train.max_epochs")


@pytest.mark.parametrize("n_blocks", [1, 0, -2, True, 2.0, "4", None, 10**7])
def test_time_blocks_n_blocks(n_blocks) -> None:
    _refused(lambda: thermonet.time_blocks(None, n_blocks=n_blocks), "time_blocks(n_blocks)")


@pytest.mark.parametrize("purge_s", [-1.0, True, "60", None, float("nan"), float("inf")])
def test_time_blocks_purge_s(purge_s) -> None:
    _refused(lambda: thermonet.time_blocks(None, n_blocks=4, purge_s=purge_s),
             "time_blocks(purge_s)")


@pytest.mark.parametrize("n_splits", [1, 0, -5, True, False, 2.5, "5", None])
def test_time_block_split_is_checked_when_made(n_splits) -> None:
    _refused(lambda: thermonet.TimeBlockSplit(n_splits), "TimeBlockSplit(n_splits)",
             "a whole number in 2..")


def test_numpy_numbers_are_numbers() -> None:
    """What a grid built with numpy gives (np.int64, np.float64) is a number, np.bool_ not."""
    assert thermonet.TimeBlockSplit(np.int64(3)).get_n_splits() == 3
    _refused(lambda: thermonet.TimeBlockSplit(np.bool_(True)), "TimeBlockSplit(n_splits)")
    _refused(lambda: thermonet.read(MISSING, window_s=np.bool_(True)), "read(window_s)")


@pytest.mark.parametrize("where", NOT_A_PATH + [""])
def test_save_load_and_export_paths(fitted: thermonet.DriftEstimator, where, tmp_path,
                                    monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    _refused(lambda: fitted.save(where), "save(path)")
    _refused(lambda: thermonet.DriftEstimator.load(where), "load(path)")
    _refused(lambda: fitted.export(where), "export(path)")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("kwargs, argument", [
    ({"format": None}, "export(format)"), ({"format": 3}, "export(format)"),
    ({"device_id": -1}, "export(device_id)"), ({"device_id": True}, "export(device_id)"),
    ({"device_id": "7"}, "export(device_id)"), ({"instance": 1.5}, "export(instance)"),
])
def test_export_arguments(fitted: thermonet.DriftEstimator, kwargs, argument, tmp_path) -> None:
    _refused(lambda: fitted.export(tmp_path / "m.onnx", **kwargs), argument)
    assert not (tmp_path / "m.onnx").exists()


def test_compare_into_a_previous_comparison_names_the_python_option(tmp_path) -> None:
    """A second ``thermonet.compare(cfg, data=ds, out=D)`` said "pass --overwrite", the
    command line's spelling: the API names its own (``overwrite=True``, ``compare(out)``),
    and ``overwrite=True`` then replaces it."""
    cfg = {"families": [{"name": "cubic", "family": "poly", "params": {"degree": 3}}],
           "tracking": {"enabled": False}}
    ds = toy_dataset(n_runs=3)
    out = tmp_path / "cmp"
    thermonet.compare(cfg, data=ds, out=out, plots=False)
    msg = _refused(lambda: thermonet.compare(cfg, data=ds, out=out, plots=False), str(out))
    assert msg == (f"{out}: compare(out) holds a previous comparison; pass overwrite=True to "
                   "replace it, or choose another compare(out)")
    assert "--" not in msg
    assert thermonet.compare(cfg, data=ds, out=out, plots=False, overwrite=True).chosen == \
        "cubic"


def test_an_unknown_keyword_lists_both_sets_and_the_closest_name() -> None:
    est = thermonet.DriftEstimator("mlp", max_epoch=3)
    msg = _one_value_error(lambda: est.fit(None), "model 'mlp': unknown hyper-parameter "
                           "'max_epoch' (valid: hidden, activation, weight_decay), nor an "
                           "estimator keyword (inputs, t_ref, ", "max_epochs",
                           "; did you mean 'max_epochs'?")
    assert "self" not in msg
