"""Absurd sizes and impossible settings (classes 4 and 8): refused before anything
is allocated or written, in one line naming the option or key and its value."""

from __future__ import annotations

from pathlib import Path

import pytest

from thermonet.cli import main
from thermonet.core.errors import ConfigError
from thermonet.sim import simulate_fleet
from thermonet.sim.fleet import MAX_UNITS
from thermonet.sim.presets import MAX_SAMPLES, get_preset, request_samples
from thermonet.training.config import load_config
from thermonet.training.splits import MAX_BLOCKS


@pytest.mark.parametrize("argv,expect", [
    (["accel", "--units", "1000000000"], "units=1000000000 is above the limit of 10,000 units"),
    (["patent-gyro", "--units", "1001"], "above the limit of 50,000,000 per simulation"),
    (["accel", "--units", "1001"], "above the limit of 50,000,000 per simulation"),
    (["consumer-imu", "--units", "2000", "--runs", "1000"], "above the limit"),
    (["accel", "--units", "0"], "units must be at least 1"),
    (["accel", "--units", "3", "--outliers", "4"], "outliers must be between 0 and units"),
    (["accel", "--runs", "1001"], "--runs 1001: not in 1..1000"),
    (["accel", "--seed", "-3"], "--seed -3: must be a non-negative integer"),
    (["fc-board", "--units", "3"], "--units 3: preset 'fc-board' simulates one board"),
    (["fc-board-cycle", "--runs", "101"], "--runs 101: preset 'fc-board-cycle' writes at most 100"),
    (["fc-board", "--outliers", "1"], "--outliers 1: preset 'fc-board' simulates one board"),
])
def test_absurd_simulation_requests_refused_in_one_line(tmp_path, capsys, argv, expect):
    out = tmp_path / ("b.ulg" if argv[0].startswith("fc-board") else "f.parquet")
    assert main(["simulate", *argv, "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expect in err, err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_fleet_size_is_counted_before_anything_is_simulated():
    cfg = get_preset("patent-gyro")
    per_unit = request_samples(cfg, cfg.default_runs)
    units = MAX_SAMPLES // per_unit + 1
    with pytest.raises(ConfigError, match=f"{units} units × 5 runs"):
        simulate_fleet("patent-gyro", units=units, seed=0)
    # a worker holds only its own unit: the same fleet is fine one unit at a time
    ds = simulate_fleet("accel", units=units, runs=1, seed=0, unit_indices=[units - 1])
    assert len(ds.unit_ids) == 1
    with pytest.raises(ConfigError, match="10,000 units"):
        simulate_fleet("accel", units=MAX_UNITS + 1, runs=1, seed=0, unit_indices=[])
    # the count matches what is simulated
    small = simulate_fleet("accel", units=2, runs=2, seed=0)
    assert sum(r.n_samples for r in small) == 2 * request_samples(get_preset("accel"), 2)


def test_fleet_units_of_a_billion_refused_at_once(tmp_path, capsys):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data: {preset: accel, runs: 3}\n")
    assert main(["fleet", str(cfg), "--units", "1000000000", "--out", str(tmp_path / "o"),
                 "--no-track", "-q"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "10,000 units" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("value,expect", [
    ("1000000", f"key 'split.n_blocks': 1000000 is above {MAX_BLOCKS}"),
    ("4", "key 'split.n_blocks': 4 is below 5"),
    ("2.5", "split.n_blocks"),
    ("true", "split.n_blocks"),
])
def test_impossible_split_settings_refused(tmp_path: Path, capsys, value, expect):
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data: {{preset: accel-ramp}}\nsplit: {{strategy: time-blocks, "
                   f"n_blocks: {value}}}\n")
    with pytest.raises(ConfigError, match="split.n_blocks"):
        load_config(cfg)
    assert main(["compare", str(cfg), "--out", str(tmp_path / "o"), "--no-track", "-q"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expect in err and str(cfg) in err, err
    assert not (tmp_path / "o").exists()
    load_config_ok = tmp_path / "ok.yaml"
    load_config_ok.write_text(f"data: {{preset: accel-ramp}}\nsplit: {{n_blocks: {MAX_BLOCKS}}}\n")
    assert load_config(load_config_ok).split.n_blocks == MAX_BLOCKS


# ---------------------------------------------------------------- info's plausibility (class 8)
def _temp_csv(path: Path, temps, *, values=None, dt: float = 1.0) -> Path:
    import numpy as np

    temps = np.asarray(temps, dtype=float)
    t = np.arange(temps.size) * dt
    g = np.zeros(temps.size) if values is None else np.asarray(values, dtype=float)
    path.write_text("time_s,temperature_c,gyro_x\n" + "".join(
        f"{a!r},{b!r},{c!r}\n" for a, b, c in zip(t.tolist(), temps.tolist(), g.tolist(),
                                                    strict=True)))
    return path


def _info_json(path: Path, capsys, *extra: str) -> dict:
    import json

    assert main(["info", str(path), "--json", *extra]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("lo,hi,hint", [
    (253.15, 343.15, "Kelvin? subtract 273.15"),            # −20 … 70 °C in K
    (-4.0, 257.0, "°F? subtract 32, then multiply by 5/9"),   # −20 … 125 °C in °F
    (-20000.0, 70000.0, "m°C? divide by 1000"),              # −20 … 70 °C in m°C
    (1e305, 1e306, "check the mapping's temperature unit and scale"),
])
def test_info_hints_at_temperature_units(tmp_path, capsys, lo, hi, hint):
    import numpy as np

    from thermonet.data.diagnostics import input_warnings
    from thermonet.data.io import read_datasets

    f = _temp_csv(tmp_path / "t.csv", np.linspace(lo, hi, 3600))
    s = _info_json(f, capsys)
    temp = [w for w in s["warnings"] if "temperature_c spans" in w]
    assert len(temp) == 1 and hint in temp[0], s["warnings"]
    # the same sentences compare gives: one function, not a copy
    assert s["warnings"] == input_warnings(read_datasets([f]))
    # and the text view shows them
    assert main(["info", str(f)]) == 0
    assert f"warning: {temp[0]}" in capsys.readouterr().out


def test_info_warns_on_absurd_values_and_rates(tmp_path, capsys):
    import warnings

    import numpy as np

    temps = np.linspace(20.0, 40.0, 600)
    f = _temp_csv(tmp_path / "big.csv", temps, values=np.tile([1e306, -1e306], 300))
    with warnings.catch_warnings():  # no numpy overflow warning on the way
        warnings.simplefilter("error", RuntimeWarning)
        s = _info_json(f, capsys)
    assert any("gyro_x reaches 1e+306 deg/s" in w for w in s["warnings"]), s["warnings"]
    # a gyro read 1e5 too large (4.8e6 °/s): under the any-unit cap (1e12), beyond any gyro
    f = _temp_csv(tmp_path / "scaled.csv", temps, values=np.tile([4.8e6, -4.8e6], 300))
    s = _info_json(f, capsys)
    assert any(
        "gyro_x reaches 4.8e+06 deg/s, beyond any plausible reading (|value| > 20000 deg/s); "
        "a wrong unit or scale in the mapping" in w for w in s["warnings"]), s["warnings"]
    f = _temp_csv(tmp_path / "fine.csv", temps, values=np.tile([1500.0, -1500.0], 300))
    assert _info_json(f, capsys)["warnings"] == []              # 1500 °/s: a fast gyro
    f = _temp_csv(tmp_path / "slow.csv", temps, dt=1e300)
    s = _info_json(f, capsys)
    assert any("sample rate 1e-300 Hz is outside" in w for w in s["warnings"]), s["warnings"]
    f = _temp_csv(tmp_path / "fast.csv", temps, dt=1e-7)
    s = _info_json(f, capsys)
    assert any("sample rate 1e+07 Hz is outside" in w for w in s["warnings"]), s["warnings"]
    # plausible data: no warning at all
    f = _temp_csv(tmp_path / "ok.csv", temps, dt=10.0)
    assert _info_json(f, capsys)["warnings"] == []


@pytest.mark.parametrize("setting,expect", [
    ("sample_rate_hz: 1.0e-300", "key 'sample_rate_hz': 1e-300 Hz is not a possible sample rate"),
    ("sample_rate_hz: 1.0e+12", "key 'sample_rate_hz': 1e+12 Hz is not a possible sample rate"),
    ("sample_rate_hz: 0", "key 'sample_rate_hz': must be > 0"),
    ("sample_rate_hz: -5", "key 'sample_rate_hz': must be > 0"),
    ("sample_rate_hz: .inf", "key 'sample_rate_hz': expected a finite number"),
    ("scale0", "key 'channels.gyro_x.scale': is 0"),
])
def test_impossible_mapping_settings_refused_in_one_line(tmp_path, capsys, setting, expect):
    f = tmp_path / "d.csv"
    f.write_text("temp,g\n" + "".join(f"{20 + k * 0.05!r},0.0\n" for k in range(400)))
    m = tmp_path / "m.yaml"
    time = "sample_rate_hz: 1.0" if setting == "scale0" else setting
    scale = ", scale: 0" if setting == "scale0" else ""
    m.write_text(f"{time}\nchannels:\n  temperature_c: {{column: temp}}\n"
                 f"  gyro_x: {{column: g{scale}}}\n")
    assert main(["info", str(f), "--mapping", str(m)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(m) in err and expect in err, err


@pytest.mark.parametrize("section,expect", [
    ("features: {gap_s: 1.0e-300}", "key 'features.gap_s': 1e-300 is not a number of seconds"),
    ("features: {gap_s: 1.0e+300}", "key 'features.gap_s': 1e+300 is not a number of seconds"),
    ("features: {t_ref: 1.0e+306}", "key 'features.t_ref': 1e+306 °C is not a reference"),
    ("features: {t_ref: .nan}", "key 'features.t_ref': nan °C"),
    ("features: {t_ref: 300.0}", "key 'features.t_ref': 300.0 °C"),   # Kelvin
    ("features: {t_ref_window_min: 0}", "key 'features.t_ref_window_min'"),
    ("train: {lr: .inf}", "key 'train.lr': must be a finite number > 0, got inf"),
    ("train: {max_epochs: 1000000000000}",
     "key 'train.max_epochs': must be an integer in 0..1,000,000,000"),
    ("train: {average_s: 1.0e+300}", "key 'train.average_s': must be a finite number >= 0 and <= 86400"),
    ("train: {threads: 100000}", "key 'train.threads': must be an integer in 0..1,024"),
    ("families: [{family: poly, name: c, inputs: [dT], train: {average_s: 1.0e+9}}]",
     "key 'families[0].train.average_s': must be a finite number >= 0"),
])
def test_impossible_config_settings_refused_before_anything_runs(tmp_path, capsys, section,
                                                                  expect):
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data: {{preset: accel-ramp}}\n{section}\n")
    with pytest.raises(ConfigError):
        load_config(cfg)
    assert main(["compare", str(cfg), "--out", str(tmp_path / "o"), "--no-track", "-q"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expect in err and str(cfg) in err, err
    assert not (tmp_path / "o").exists()
