"""The command line's parser, option by option: every documented option of every command
parses to the value the commands read (and its default when not given), and each command
has exactly the options listed here — a sub-parser split into functions or tables must
keep them all, with their names, types, choices and defaults."""

import argparse

import pytest

from thermonet.cli import build_parser

#: per command: (arguments that set every option, the namespace they must give)
FULL = {
    "simulate": (["patent-gyro", "--runs", "3", "--seed", "7", "--out", "x.csv",
                  "--units", "4", "--outliers", "1", "--flights", "5", "--format", "bin",
                  "--clusters", "2", "--test", "soaks:0,25,50", "--overwrite"],
                 {"preset": "patent-gyro", "runs": 3, "seed": 7, "out": "x.csv", "units": 4,
                  "outliers": 1, "flights": 5, "format": "bin", "clusters": 2,
                  "test": "soaks:0,25,50", "overwrite": True}),
    "info": (["a.csv", "b.csv", "--mapping", "m.yaml", "--json", "--chunk-rows", "10"],
             {"files": ["a.csv", "b.csv"], "mapping": "m.yaml", "json": True,
              "chunk_rows": 10}),
    "convert": (["a.csv", "--mapping", "m.yaml", "--out", "o.parquet", "--overwrite",
                 "--chunk-rows", "5"],
                {"files": ["a.csv"], "mapping": "m.yaml", "out": "o.parquet",
                 "overwrite": True, "chunk_rows": 5}),
    "compare": (["c.yaml", "--out", "o", "--overwrite", "--no-track", "--tracking-uri", "u",
                 "-q", "--no-plots", "--workers", "2"],
                {"config": "c.yaml", "out": "o", "overwrite": True, "no_track": True,
                 "tracking_uri": "u", "quiet": True, "no_plots": True, "workers": 2}),
    "train": (["c.yaml", "--family", "lin", "--out", "o", "--overwrite", "--no-track",
               "--tracking-uri", "u", "--quiet", "--no-plots", "--workers", "0"],
              {"config": "c.yaml", "family": "lin", "out": "o", "overwrite": True,
               "no_track": True, "tracking_uri": "u", "quiet": True, "no_plots": True,
               "workers": 0}),
    "export": (["dir", "--format", "c", "--out", "m.h", "--all-units", "--family", "lin",
                "--tracking-uri", "u", "--device-id", "12", "--instance", "2", "--overwrite",
                "--prefix", "imu1"],
               {"source": "dir", "format": "c", "out": "m.h", "all_units": True,
                "family": "lin", "tracking_uri": "u", "device_id": 12, "instance": 2,
                "overwrite": True, "prefix": "imu1"}),
    "calibrate": (["a.ulg", "b.ulg", "--out", "o", "--overwrite", "--no-compare",
                   "--mag-thermometer", "mag1=baro0", "--mag-thermometer", "mag0=gyro0",
                   "--workers", "3", "-q"],
                  {"log": ["a.ulg", "b.ulg"], "out": "o", "overwrite": True,
                   "no_compare": True, "mag_thermometer": ["mag1=baro0", "mag0=gyro0"],
                   "workers": 3,
                   "quiet": True, "detail": False}),
    "verify": (["p.params", "l.ulg", "--out", "o", "--min-cut", "2.5", "--gyro-floor", "1e-3",
                "--acc-floor", "0.01", "--baro-floor", "2", "--mag-floor", "0.25",
                "--overwrite", "-q"],
               {"params": "p.params", "log": "l.ulg", "out": "o", "min_cut": 2.5,
                "gyro_floor": 1e-3, "acc_floor": 0.01, "baro_floor": 2.0, "mag_floor": 0.25,
                "overwrite": True, "quiet": True}),
    "fleet": (["c.yaml", "--out", "o", "--overwrite", "--no-track", "--tracking-uri", "u",
               "-q", "--no-plots", "--units", "8", "--outliers", "2", "--executor", "serial",
               "--workers", "3", "--ray-address", "r:1", "--family", "lin", "--folds", "0"],
              {"config": "c.yaml", "out": "o", "overwrite": True, "no_track": True,
               "tracking_uri": "u", "quiet": True, "no_plots": True, "units": 8,
               "outliers": 2, "executor": "serial", "workers": 3, "ray_address": "r:1",
               "family": "lin", "folds": 0}),
    "prior": (["c.yaml", "--out", "p.json", "--units", "30", "--outliers", "2", "--clusters",
               "3", "-q", "--overwrite", "--short-test", "cycle:-20,75,10"],
              {"config": "c.yaml", "out": "p.json", "units": 30, "outliers": 2, "clusters": 3,
               "quiet": True, "overwrite": True, "short_test": "cycle:-20,75,10"}),
    "station": (["c.yaml", "--prior", "p.json", "--out", "o", "--units", "9", "--outliers",
                 "1", "--clusters", "3", "--test", "ramp:20,30,10", "--executor", "ray",
                 "--workers", "2", "--ray-address", "r:1", "--overwrite", "-q"],
                {"config": "c.yaml", "prior": "p.json", "out": "o", "units": 9, "outliers": 1,
                 "clusters": 3, "test": "ramp:20,30,10", "executor": "ray", "workers": 2,
                 "ray_address": "r:1", "overwrite": True, "quiet": True}),
    "learn": (["a.ulg", "d", "--out", "o", "--executor", "serial", "--workers", "2",
               "--ray-address", "r:1", "--no-compare", "--no-export", "-q", "--overwrite"],
              {"logs": ["a.ulg", "d"], "out": "o", "executor": "serial", "workers": 2,
               "ray_address": "r:1", "no_compare": True, "no_export": True, "quiet": True,
               "overwrite": True}),
}

#: per command: (the fewest arguments it takes, the defaults of every other option)
MINIMAL = {
    "simulate": (["accel", "--out", "x.parquet"],
                 {"runs": None, "seed": 0, "units": None, "outliers": 0, "flights": None,
                  "format": None, "clusters": 0, "test": None, "overwrite": False}),
    "info": (["a.csv"], {"mapping": None, "json": False, "chunk_rows": None}),
    "convert": (["a.csv", "--out", "o.parquet"],
                {"mapping": None, "overwrite": False, "chunk_rows": None}),
    "compare": (["--out", "o"],
                {"config": None, "overwrite": False, "no_track": False, "tracking_uri": None,
                 "quiet": False, "no_plots": False, "workers": None}),
    "train": (["c.yaml", "--family", "lin", "--out", "o"],
              {"overwrite": False, "no_track": False, "tracking_uri": None, "quiet": False,
               "no_plots": False, "workers": None}),
    "export": (["dir", "--format", "onnx", "--out", "m.onnx"],
               {"all_units": False, "family": None, "tracking_uri": None, "device_id": None,
                "instance": None, "overwrite": False, "prefix": None}),
    "calibrate": (["a.bin", "--out", "o"],
                  {"overwrite": False, "no_compare": False, "mag_thermometer": None,
                   "workers": None, "quiet": False, "detail": False}),
    "verify": (["p.parm", "l.bin", "--out", "o"],
               {"min_cut": None, "gyro_floor": None, "acc_floor": None, "baro_floor": None,
                "mag_floor": None, "overwrite": False, "quiet": False}),
    "fleet": (["c.yaml", "--out", "o"],
              {"overwrite": False, "no_track": False, "tracking_uri": None, "quiet": False,
               "no_plots": False, "units": None, "outliers": 0, "executor": "process",
               "workers": None, "ray_address": None, "family": None, "folds": 5}),
    "prior": (["c.yaml", "--out", "p.json"],
              {"units": None, "outliers": 0, "clusters": 0, "quiet": False,
               "overwrite": False, "short_test": None}),
    "station": (["c.yaml", "--prior", "p.json", "--out", "o"],
                {"units": None, "outliers": 0, "clusters": 0, "test": None,
                 "executor": "process", "workers": None, "ray_address": None,
                 "overwrite": False, "quiet": False}),
    "learn": (["d", "--out", "o"],
              {"executor": "process", "workers": None, "ray_address": None,
               "no_compare": False, "no_export": False, "quiet": False, "overwrite": False}),
}


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_the_commands_in_the_order_help_lists_them():
    assert list(_subparsers()) == ["simulate", "info", "convert", "compare", "train",
                                   "export", "calibrate", "verify", "fleet", "learn",
                                   "prior", "station"]


@pytest.mark.parametrize("command", list(FULL))
def test_every_option_parses_to_what_the_command_reads(command):
    argv, want = FULL[command]
    args = build_parser().parse_args(["--profile", command, *argv])
    got = {k: v for k, v in vars(args).items() if k not in ("command", "func", "profile")}
    assert got == want
    assert args.command == command and args.profile is True
    assert args.func.__name__ == f"_cmd_{command}"
    # every option of the command appears in the full command line above
    dests = {a.dest for a in _subparsers()[command]._actions if a.dest != "help"}
    assert dests == set(want)


@pytest.mark.parametrize("command", list(MINIMAL))
def test_defaults_of_the_options_not_given(command):
    argv, defaults = MINIMAL[command]
    args = vars(build_parser().parse_args([command, *argv]))
    assert {k: args[k] for k in defaults} == defaults
    assert args["profile"] is False


@pytest.mark.parametrize("argv", [
    ["export", "d", "--format", "pdf", "--out", "x"],       # not a format
    ["fleet", "c.yaml", "--out", "o", "--executor", "dask"],  # not an executor
    ["simulate", "accel", "--out", "x", "--runs", "two"],     # not an integer
    ["verify", "p", "l", "--out", "o", "--min-cut", "x"],     # not a number
    ["train", "c.yaml", "--out", "o"],                         # --family is required
    ["compare"],                                               # --out is required
])
def test_bad_options_are_usage_errors(argv, capsys):
    with pytest.raises(SystemExit) as err:
        build_parser().parse_args(argv)
    assert err.value.code == 2
    assert "thermonet" in capsys.readouterr().err


def test_simulate_help_lists_every_preset_of_the_registry(capsys, monkeypatch):
    """``simulate --help`` names every preset registered (thermonet.sim.presets.PRESETS,
    filled as thermonet.sim loads), the flight-controller boards and the flights of one vehicle,
    not a list typed once."""
    from thermonet.sim import PRESETS
    from thermonet.sim.fcboard import BOARD_PRESETS

    monkeypatch.setenv("COLUMNS", "1000")   # one line: argparse may wrap at a name's hyphen
    with pytest.raises(SystemExit) as done:
        build_parser().parse_args(["simulate", "--help"])
    assert done.value.code == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.strip()
                .startswith("preset "))
    names = line.split(None, 1)[1].split(" (")[0].split(" | ")
    assert names == [*PRESETS, *BOARD_PRESETS, "fc-board-flights"]
    assert {"consumer-imu", "accel-ramp", "stress-imu", "imu-multiposition"} <= set(names)


def test_python_dash_m_thermonet_runs_the_command_line(tmp_path):
    """``python -m thermonet`` is the ``thermonet`` command: its version, and a refusal with
    the command's own exit status and line."""
    import subprocess
    import sys

    from thermonet.core.version import __version__

    run = subprocess.run([sys.executable, "-m", "thermonet", "--version"],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert (run.returncode, run.stdout) == (0, f"thermonet {__version__}\n")
    run = subprocess.run([sys.executable, "-m", "thermonet", "info", "nowhere.csv"],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert run.returncode == 1 and run.stderr.startswith("thermonet: error: nowhere.csv")


def test_a_reader_that_leaves_stops_the_command_quietly(tmp_path):
    """``thermonet info … | head``: the reader gone, the command stops as a Unix tool does —
    status 128 + SIGPIPE, nothing on stderr (it printed "thermonet: error: : Broken pipe")."""
    import os
    import signal
    import subprocess
    import sys

    rec = tmp_path / "r.csv"
    rec.write_text("time_s,temperature_c,gyro_x\n" + "".join(
        f"{k},{20 + 0.01 * k},{0.001 * k}\n" for k in range(200)))
    read, write = os.pipe()
    os.close(read)                                   # the reader has left before any output
    try:
        run = subprocess.run([sys.executable, "-m", "thermonet", "info", str(rec)],
                             stdout=write, stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write)
    assert run.returncode == 128 + signal.SIGPIPE and run.stderr == ""
