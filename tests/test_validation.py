"""Bad configs and inconsistent data are refused with one line naming the file and key."""

from __future__ import annotations

import re

import numpy as np
import pytest

from conftest import toy_dataset
from thermonet.core.errors import ConfigError, InputError
from thermonet.core.recording import Dataset
from thermonet.data.io import write_parquet
from thermonet.data.mapping import load_mapping
from thermonet.training.config import SplitConfig, load_config
from thermonet.training.parts import make_splits
from thermonet.workflows.compare import run_compare


def cfg_file(tmp_path, text):
    p = tmp_path / "c.yaml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("families, key, what", [
    ("[{family: polly}]", "families[0]", "unknown model family 'polly'"),
    ("[{family: poly, inputs: [dt]}]", "families[0].inputs", "dt"),
    ("[{family: poly, params: {degre: 2}}]", "families[0]", "unknown hyper-parameter 'degre'"),
    ("[{family: lorentz, inputs: [dT, dT2]}]", "families[0]", "1 input"),
])
def test_family_mistakes_stop_before_any_data(tmp_path, families, key, what):
    with pytest.raises(ConfigError) as err:
        load_config(cfg_file(tmp_path, f"families: {families}\n"))
    msg = str(err.value)
    assert msg.startswith(f"{tmp_path / 'c.yaml'}: key '{key}")
    assert what in msg


def test_duplicate_yaml_keys_are_errors(tmp_path):
    with pytest.raises(ConfigError, match=r"c\.yaml: key 'split' given twice \(line 3\)"):
        load_config(
            cfg_file(tmp_path, "split: {strategy: runs}\ntarget: drift\nsplit: {n_blocks: 10}\n")
        )
    m = tmp_path / "m.yaml"
    m.write_text("sample_rate_hz: 1\nheader: false\nchannels:\n  temperature_c: {column: 0}\n"
                 "  gyro_x: {column: 1}\n  gyro_x: {column: 0}\n")
    with pytest.raises(InputError, match=r"m\.yaml: key 'gyro_x' given twice \(line 6\)"):
        load_mapping(m)


def test_misspelt_channel_is_not_silently_a_proxy(tmp_path):
    m = tmp_path / "m.yaml"
    m.write_text("sample_rate_hz: 1\nheader: false\nchannels:\n"
                 "  temprature_c: {column: 0, unit: degC}\n  gyro_x: {column: 1}\n")
    with pytest.raises(InputError, match="temprature_c.*proxy: true.*misspelling"):
        load_mapping(m)


def test_runs_in_different_units_are_refused():
    a, b = toy_dataset(n_runs=2)
    b.units["gyro_x"] = "rad/s"
    with pytest.raises(InputError, match=r"column 'gyro_x'.*'rad/s'.*'deg/s'"):
        Dataset([a, b]).validate()


def test_runs_with_different_proxies_are_refused():
    a, b = toy_dataset(n_runs=2)
    b.proxies["freq_hz"] = np.full(b.n_samples, 4517.0)
    with pytest.raises(InputError, match=r"run 'run1' has proxies \['freq_hz'\]"):
        Dataset([a, b]).validate()


@pytest.mark.parametrize("split, key", [
    (dict(strategy="runs", train=["run0", "run1"], val="run1", test="run3"), "split.val"),
    (dict(strategy="runs", train=["run0", "run3"], val="run1", test="run3"), "split.test"),
    (dict(strategy="runs", train=["run0"], val="run3", test="run3"), "split.val"),
    (dict(strategy="train-then-verify"), "split.strategy"),
])
def test_split_roles_may_not_overlap(split, key):
    with pytest.raises(ConfigError, match=re.escape(f"c.yaml: key '{key}'")):
        make_splits(toy_dataset(n_runs=4), SplitConfig(**split), source="c.yaml")


def test_named_runs_without_val_validate_on_blocks_of_the_training_runs():
    ds = toy_dataset(n_runs=3)
    split, = make_splits(ds, SplitConfig(strategy="runs", train=["run0", "run1"], test="run2"))
    assert split.describe["val"] == "val"
    assert split.val.n_samples == pytest.approx(0.2 * 2 * ds[0].n_samples, rel=0.01)
    assert sum(r.n_samples for r in split.train) + split.val.n_samples == 2 * ds[0].n_samples


def test_n_blocks_below_five_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match=r"c\.yaml: key 'split\.n_blocks': 3 is below 5"):
        load_config(cfg_file(tmp_path, "split: {n_blocks: 3}\n"))


def test_missing_signal_stops_compare_before_writing(tmp_path):
    path = write_parquet(toy_dataset(n_runs=3), tmp_path / "toy.parquet")
    cfg = load_config(cfg_file(tmp_path, f"data: {{paths: ['{path}']}}\n"
                                         "families: [{family: poly, inputs: [d_freq_hz]}]\n"))
    with pytest.raises(
        ConfigError, match=r"key 'families\[0\]\.inputs': no proxy channel 'freq_hz'"
    ):
        run_compare(cfg, tmp_path / "out", track=False, quiet=True)
    assert not (tmp_path / "out").exists()


def test_negative_seed_and_wrong_suffix_are_one_line_errors(tmp_path):
    from thermonet.sim import simulate

    with pytest.raises(ConfigError, match="seed must be a non-negative integer, got -1"):
        simulate("mems-gyro", runs=1, seed=-1)
    with pytest.raises(InputError, match=r"x\.csv: a thermonet recording file ends in \.parquet"):
        write_parquet(toy_dataset(n_runs=1), tmp_path / "x.csv")
    assert not (tmp_path / "x.csv").exists()


def test_datetime_time_column_becomes_seconds(tmp_path):
    import pandas as pd

    from thermonet.data.io import read_dataset

    n = 100
    pd.DataFrame({"ts": pd.date_range("2026-01-01", periods=n, freq="500ms"),
                  "temp": np.linspace(20.0, 30.0, n), "gx": np.zeros(n)}).to_parquet(
        tmp_path / "dt.parquet")
    (tmp_path / "dt.yaml").write_text("time: {column: ts, unit: ms}\nchannels:\n"
                                      "  temperature_c: {column: temp}\n  gyro_x: {column: gx}\n")
    rec, = read_dataset(tmp_path / "dt.parquet", mapping=tmp_path / "dt.yaml")
    np.testing.assert_allclose(rec.time_s, 0.5 * np.arange(n))


def test_four_position_on_a_run_shorter_than_the_window():
    from thermonet.core.recording import Recording
    from thermonet.sim.fourpos import four_position_estimates

    t = np.arange(0.0, 300.0, 1.0)
    ref = np.repeat([1.0, 0.0, -1.0, 0.0], 75)
    rec = Recording(time_s=t, temperature_c=np.full(t.size, 25.0),
                    outputs={"acc_x": 0.002 + 1.0001 * ref}, references={"ref_acc_x": ref},
                    sample_rate_hz=1.0)
    est = four_position_estimates(rec, "acc_x", settle_s=0.0, window_s=600.0)
    assert len(est) == 1
    temp, k0, k1 = est[0]
    assert (
        temp == pytest.approx(25.0) and k0 == pytest.approx(0.002) and k1 == pytest.approx(1.0001)
    )


def test_empty_run_id_names_column_and_row(tmp_path):
    from thermonet.data.io import read_dataset

    lines = ["run,time_s,temperature_c,gyro_x"] + [f"a,{i},{20 + i},0.1" for i in range(15)]
    (tmp_path / "r.csv").write_text("\n".join(lines + [",15,35,0.1"]) + "\n")
    with pytest.raises(InputError, match=r"r\.csv, column 'run', row 16: empty run id"):
        read_dataset(tmp_path / "r.csv")


def test_skipped_rows_are_counted_per_run(tmp_path):
    from thermonet.data.io import read_dataset

    lines = ["run,time_s,temperature_c,gyro_x"]
    lines += [f"a,{i},{20 + i},0.1" for i in range(15)] + ["a,15,35,oops"]
    lines += [f"b,{i},{20 + i},0.1" for i in range(15)]
    (tmp_path / "r.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "m.yaml").write_text("run_column: run\nmalformed_rows: skip\n"
                                     "time: {column: time_s, unit: s}\nchannels:\n"
                                     "  temperature_c: {column: temperature_c}\n"
                                     "  gyro_x: {column: gyro_x}\n")
    ds = read_dataset(tmp_path / "r.csv", mapping=tmp_path / "m.yaml")
    assert ds.meta["skipped_rows"] == "1"
    assert [(r.run_id, r.meta["skipped_rows"]) for r in ds] == [("a", "1"), ("b", "0")]
