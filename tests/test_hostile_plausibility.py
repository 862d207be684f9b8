"""Absurd sizes and impossible settings (issue 25, classes 4 and 8): refused before anything
is allocated or written, in one line naming the option or key and its value."""

from __future__ import annotations

from pathlib import Path

import pytest

from thermonet.cli import main
from thermonet.config import MAX_BLOCKS, load_config
from thermonet.errors import ConfigError
from thermonet.sim import simulate_fleet
from thermonet.sim.fleet import MAX_UNITS
from thermonet.sim.presets import MAX_SAMPLES, get_preset, request_samples


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
    (["fc-board-cycle", "--runs", "2"], "--runs 2: preset 'fc-board-cycle' simulates one board"),
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
