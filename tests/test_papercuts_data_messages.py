"""Papercuts in what the data layer, the config and the report say: each message is one
exact line naming the file, key or column, with the advice it gives followable.

``LOG#instance`` in ``convert`` and ``info``; several logs of one sensor read as several
runs; a column that differs from a thermonet name in case only; a DataFlash log cut
inside a message; config type errors in words; an unknown preset with the closest one; the
report's options; ``convert --out`` of a directory; a float32-rounded trained range; and
singular counts."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from thermonet.cli import main
from thermonet.core.errors import ConfigError, InputError
from thermonet.data.diagnostics import (
    extrapolation_warnings,
    outside_distance,
    outside_fraction,
)
from thermonet.data.io import read_dataset, read_datasets
from thermonet.data.logs import read_log
from thermonet.data.logs.base import SensorInstance, byte_ranges_note, drop_phantoms
from thermonet.data.logs.writers import write_log
from thermonet.data.mapping import MappingError, load_mapping
from thermonet.reporting.report import render_report
from thermonet.sim.fcboard import simulate_board
from thermonet.training.config import config_from_mapping

REAL_BIN = Path(__file__).parent / "data" / "real" / "ardupilot_bin_sample" / "test.BIN"
#: The instances of a simulated fc-board that read as a recording: every one with a
#: thermometer of its own (its second magnetometer has none).
READABLE = "acc0, acc1, acc2, baro0, gyro0, gyro1, gyro2, mag0"


def _board(path: Path, run: int = 0) -> Path:
    """A small simulated PX4 board log (270 samples per instance)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_log(simulate_board("fc-board", seed=5, rate_hz=0.1, run=run), path)


def _err(capsys: pytest.CaptureFixture[str]) -> str:
    return capsys.readouterr().err.strip()


# ------------------------------------------------------------------ 1. LOG#instance
def test_log_instance_syntax_works_in_convert_and_info(tmp_path, capsys):
    log = _board(tmp_path / "b.ulg")
    assert [i.name for i in read_log(log).instances][-1] == "mag1"   # in the log, no thermometer
    out = tmp_path / "x.parquet"
    assert main(["convert", str(log), "--out", str(out)]) == 1
    assert _err(capsys) == (f"thermonet: error: {log}: the log holds several sensor instances; "
                            f"name one as '{log}#<instance>' ({READABLE})")
    assert not out.exists()
    assert main(["convert", f"{log}#gyro0", "--out", str(out)]) == 0    # the advice, followed
    capsys.readouterr()
    back = read_dataset(out)
    assert back.run_ids == ["b:gyro0"] and back.axes == ["gyro_x", "gyro_y", "gyro_z"]
    assert back[0].n_samples == 270
    assert main(["info", f"{log}#mag0"]) == 0
    text = capsys.readouterr().out.splitlines()
    assert text[0].startswith(f"{log}: PX4 log, board ") and text[0].endswith(", 1 sensor instance")
    assert [ln.split()[0] for ln in text[4:5]] == ["mag0"] and text[5] == ""
    assert main(["convert", f"{log}#mag1", "--out", str(out), "--overwrite"]) == 1
    assert _err(capsys) == (f"thermonet: error: {log}: sensor instance 'mag1' has no thermometer "
                            "of its own, so it cannot be read as a recording (thermonet "
                            f"calibrate lends it another sensor's); readable instances: {READABLE}")
    assert main(["info", f"{log}#gyro7"]) == 1
    assert _err(capsys) == (f"thermonet: error: {log}: no sensor instance 'gyro7' (instances: "
                            f"{READABLE}, mag1)")


# ------------------------------------------------------------------ 2. run ids of logs
def test_three_logs_of_one_instance_load_as_three_runs(tmp_path):
    logs = [_board(tmp_path / f"b_run{k + 1}.ulg", run=k) for k in range(3)]
    ds = read_datasets([f"{p}#gyro0" for p in logs])
    assert ds.run_ids == ["b_run1:gyro0", "b_run2:gyro0", "b_run3:gyro0"]
    assert len(ds.unit_ids) == 1 and ds.device_id == str(read_log(logs[0]).instances[4].device_id)
    # the same stem in two folders: the advice is one a log can follow
    twin = _board(tmp_path / "other" / "b_run1.ulg")
    with pytest.raises(InputError) as err:
        read_datasets([f"{logs[0]}#gyro0", f"{twin}#gyro0"])
    assert str(err.value) == (f"{twin}: run id 'b_run1:gyro0' already used by {logs[0]} (a "
                              "unit's run ids must be unique; a log's run id is its file name "
                              "and instance: rename one of the logs)")


# ------------------------------------------------------------------ 3. a name's case
def _csv(path: Path, header: str) -> Path:
    t = np.arange(40.0)
    rows = "\n".join(f"{x},{20 + x / 2},{0.1 * x},{0.2},{0.3}" for x in t)
    path.write_text(f"{header}\n{rows}\n")
    return path


@pytest.mark.parametrize("header, column, meant", [
    ("time_s,temperature_c,Gyro_X,gyro_y,gyro_z", "Gyro_X", "gyro_x"),
    ("time_s,temperature_C,gyro_x,gyro_y,gyro_z", "temperature_C", "temperature_c"),
    ("Time_s,temperature_c,gyro_x,gyro_y,gyro_z", "Time_s", "time_s"),
])
def test_a_column_named_in_the_wrong_case_is_refused(tmp_path, capsys, header, column, meant):
    path = _csv(tmp_path / "in.csv", header)
    line = (f"{path}, column '{column}': not a thermonet column name: did you mean '{meant}'? "
            "(thermonet's names are lower case; rename the column, or describe the file with "
            "a mapping)")
    with pytest.raises(InputError) as err:
        read_dataset(path)
    assert str(err.value) == line
    out = tmp_path / "x.parquet"
    assert main(["convert", str(path), "--out", str(out)]) == 1          # the streamed reader
    assert _err(capsys) == f"thermonet: error: {line}" and not out.exists()
    assert main(["info", str(path)]) == 1
    assert _err(capsys) == f"thermonet: error: {line}"


def test_lower_case_names_and_true_proxies_still_read(tmp_path):
    path = _csv(tmp_path / "in.csv", "time_s,temperature_c,gyro_x,gyro_y,Freq_Hz")
    ds = read_dataset(path)
    assert ds.axes == ["gyro_x", "gyro_y"] and list(ds[0].proxies) == ["Freq_Hz"]


def test_a_mapping_channel_named_in_the_wrong_case_is_refused(tmp_path):
    m = tmp_path / "m.yaml"
    m.write_text("time: {column: t, unit: s}\nchannels:\n  Gyro_X: {column: gx}\n"
                 "  gyro_y: {column: gy}\n")
    with pytest.raises(MappingError) as err:
        load_mapping(m)
    assert str(err.value) == (f"{m}: key 'channels.Gyro_X': 'Gyro_X' is not a thermonet channel "
                              "name: did you mean 'gyro_x'? (names are lower case; to keep it "
                              "as a proxy, say 'proxy: true')")


# ------------------------------------------------------------------ 4. a cut DataFlash log
def test_truncated_real_bin_reads_what_is_there_and_says_where(tmp_path, capsys, caplog):
    data = REAL_BIN.read_bytes()
    cut = tmp_path / "half.bin"
    cut.write_bytes(data[: len(data) // 2])
    log = read_log(cut)
    assert len(log.damage) == 1
    m = re.fullmatch(r"1 damaged stretch not readable as messages, (\d+) bytes? \(under 0\.1% "
                     r"of the file\) skipped at bytes ([\d,]+)\.\.([\d,]+); the file ends "
                     r"inside a message: cut short\?", log.damage[0])
    assert m, log.damage[0]
    start, end = (int(g.replace(",", "")) for g in m.groups()[1:])
    assert end == len(data) // 2 and int(m.group(1)) == end - start
    # the stretch starts at a message header, within one message's length (at most 255 bytes)
    assert data[start:start + 2] == b"\xa3\x95" and 0 < end - start < 256
    full = {i.name: i for i in read_log(REAL_BIN).instances}
    for inst in log.instances:                       # what is there: the full log's first part
        assert np.array_equal(inst.time_s, full[inst.name].time_s[: inst.n_samples])
    assert main(["info", str(cut)]) == 0
    cap = capsys.readouterr()
    assert cap.out.startswith(f"{cut}: ArduPilot log, 8 sensor instances")
    assert f"  {log.damage[0]}" in cap.out.splitlines()
    assert f"{cut}: damaged log: {log.damage[0]}" in [r.getMessage() for r in caplog.records]


def test_the_real_bin_fixture_is_itself_cut_and_a_whole_log_is_not(tmp_path):
    # the fixture is the first 64 KiB of a longer log: it ends inside a message
    assert REAL_BIN.stat().st_size == 65536
    assert read_log(REAL_BIN).damage[0].endswith("..65,536; the file ends inside a message: "
                                                 "cut short?")
    board = simulate_board("fc-board", autopilot="ardupilot", seed=5, rate_hz=0.1)
    whole = write_log(board, tmp_path / "b.bin")
    assert read_log(whole).damage == []
    cut = tmp_path / "c.bin"
    cut.write_bytes(whole.read_bytes()[:-1])         # one byte short of its last message
    assert read_log(cut).damage[0].endswith("the file ends inside a message: cut short?")


def test_byte_counts_are_singular_for_one():
    assert byte_ranges_note([(5, 6)], 100) == ("1 damaged stretch not readable as messages, "
                                               "1 byte (1.0% of the file) skipped at bytes 5..6")


# ------------------------------------------------------------------ 5. config words, report
@pytest.mark.parametrize("section, line", [
    ({"features": {"t_ref": "hot"}},
     "c.yaml: key 'features.t_ref': expected a number or 'start', got 'hot'"),
    ({"data": {"runs": 2.5}}, "c.yaml: key 'data.runs': expected a whole number or null, got 2.5"),
    ({"selection": {"per_axis": "yes"}},
     "c.yaml: key 'selection.per_axis': expected true, false or null, got 'yes'"),
    ({"data": {"seed": "x"}}, "c.yaml: key 'data.seed': expected a whole number, got 'x'"),
    ({"data": {"paths": "a.csv"}}, "c.yaml: key 'data.paths': expected a list, got 'a.csv'"),
    ({"tracking": {"enabled": 3}}, "c.yaml: key 'tracking.enabled': expected true or false, got 3"),
    ({"data": {"preset": 3}}, "c.yaml: key 'data.preset': expected text or null, got 3"),
])
def test_config_type_errors_are_said_in_words(section, line):
    with pytest.raises(ConfigError) as err:
        config_from_mapping(section, source="c.yaml")
    assert str(err.value) == line


def _prov(options: dict) -> dict:
    return {"device": "d", "units": {}, "baseline": "cubic", "chosen": "cubic", "families": {},
            "provenance": {"data": {"kind": "simulated", "preset": "patent-gyro", "runs": 1,
                                    "seed": 0},
                           "tracking": {"enabled": False}, "options": options}}


def test_the_report_lists_only_the_options_given():
    page = render_report(_prov({"track": None, "tracking_uri": None, "workers": None}))
    assert ("data simulated: preset patent-gyro, 1 run, seed 0<br>tracking: off; options: the "
            "defaults (none given)</p>") in page
    assert "=None" not in page
    page = render_report(_prov({"track": False, "tracking_uri": None, "workers": 2}))
    assert "tracking: off; options as given: track=False, workers=2</p>" in page


# ------------------------------------------------------------------ 6. an unknown preset
def test_an_unknown_preset_names_the_file_the_key_and_the_closest(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data:\n  preset: patent-gyr\n")
    assert main(["compare", str(cfg), "--out", str(tmp_path / "out")]) == 1
    err = _err(capsys).splitlines()[-1]
    assert err.startswith(f"thermonet: error: {cfg}: key 'data.preset': unknown preset "
                          "'patent-gyr' (did you mean 'patent-gyro'? valid: accel, ")
    assert not (tmp_path / "out").exists()
    with pytest.raises(ConfigError, match=r"^c\.yaml: key 'data\.preset': unknown preset "
                                          r"'zzz' \(valid: accel, "):
        config_from_mapping({"data": {"preset": "zzz"}}, source="c.yaml")
    # a preset beside data files is not read: not checked
    config_from_mapping({"data": {"preset": "zzz", "paths": ["a.csv"]}}, source="c.yaml")


# ------------------------------------------------------------------ 7. convert --out a dir
@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_convert_to_a_directory_says_what_out_must_be_first(tmp_path, capsys, overwrite):
    src = _csv(tmp_path / "in.csv", "time_s,temperature_c,gyro_x,gyro_y,gyro_z")
    target = tmp_path / "od"
    target.mkdir()
    assert main(["convert", str(src), "--out", str(target), *overwrite]) == 1
    assert _err(capsys) == (f"thermonet: error: {target}: --out must end in .parquet (or .pq), "
                            "a thermonet recording, or .csv, the runtime's input")
    named = tmp_path / "od.parquet"
    named.mkdir()
    assert main(["convert", str(src), "--out", str(named), *overwrite]) == 1
    assert _err(capsys) == (f"thermonet: error: {named}: is a directory; --out names a .parquet "
                            "or .csv file")
    assert list(target.iterdir()) == [] and list(named.iterdir()) == []


def test_a_phantom_of_one_sample_is_counted_in_the_singular():
    def inst(k: int, n: int) -> SensorInstance:
        return SensorInstance("gyro", k, 7, np.arange(float(n)), np.full(n, 20.0),
                              np.zeros((n, 3)))

    keep, notes = drop_phantoms([inst(0, 2000), inst(1, 1)], "px4")
    assert [i.name for i in keep] == ["gyro0"]
    assert notes == ["gyro1 dropped: 1 sample where another gyro has 2000, a damaged instance "
                     "field"]


# ------------------------------------------------------------------ 8. the trained range
def test_float32_rounding_of_the_trained_range_is_not_outside_it():
    kelvin = np.array([253.15, 290.0, 323.15, 323.15])[:, None]       # a soak at the top
    lo = np.array([np.float32(253.15)], dtype=np.float64)              # as a model stores it
    hi = np.array([np.float32(323.15)], dtype=np.float64)
    assert hi[0] < 323.15                                             # float32 rounded down
    assert outside_fraction(kelvin, lo, hi)[0] == 0.0
    assert outside_distance(kelvin, lo, hi)[0] == 0.0
    beyond = np.array([[253.15], [323.2]])                            # truly outside: counted
    assert outside_fraction(beyond, lo, hi)[0] == 0.5
    assert outside_distance(beyond, lo, hi)[0] == pytest.approx(323.2 - hi[0], rel=1e-12)
    (warning,) = extrapolation_warnings({"temperature_c": 0.5},
                                        {"temperature_c": (float(lo[0]), float(hi[0]))})
    assert "outside the trained range 253.1 … 323.1 °C; the models clamp there" in warning


def test_one_instance_of_a_log_where_a_command_reads_them_all(tmp_path, capsys):
    """``calibrate 'x.ulg#gyro0'`` / ``verify … 'log.ulg#gyro0'`` said "flight-controller log
    not found" of a log that exists; ``info a.ulg b.ulg`` said "with no mapping" when none
    was given.  Each now names its real cause."""
    log = write_log(simulate_board(seed=3, rate_hz=0.2), tmp_path / "b.ulg")
    with pytest.raises(InputError) as err:
        read_log(f"{log}#gyro0")
    assert str(err.value) == (f"{log}#gyro0: '#gyro0' (one sensor instance) is not accepted "
                              "here: this command reads every instance of a log — give the log "
                              f"itself, {log}")
    for argv in (["calibrate", f"{log}#gyro0", "--out", str(tmp_path / "c")],
                 ["verify", str(tmp_path / "x.params"), f"{log}#gyro0", "--out",
                  str(tmp_path / "v")]):
        (tmp_path / "x.params").write_text("1\t1\tTC_G0_ID\t0\t6\n")
        assert main(argv) == 1
        err_line = capsys.readouterr().err.strip()
        assert "'#gyro0' (one sensor instance) is not accepted here" in err_line, err_line
    assert main(["info", str(log), str(log)]) == 1
    assert capsys.readouterr().err.strip() == ("thermonet: error: info reads one "
                                               "flight-controller log at a time (2 files "
                                               "given): run it once per log")



# ------------------------------------------------------------------ a lab engineer's first day

def test_two_files_of_one_name_say_what_a_config_can_do(tmp_path):
    """Two days' 'log.csv' in dated folders are one run id twice; the advice was "set
    'run_id' per file", which one data.mapping cannot do."""
    files = []
    for day in ("2024-03-05", "2024-03-06"):
        (tmp_path / day).mkdir()
        files.append(tmp_path / day / "log.csv")
        files[-1].write_text("time_s,temperature_c,gyro_x\n" + "".join(
            f"{i},{20 + i},{0.1 * i}\n" for i in range(20)))
    with pytest.raises(InputError) as err:
        read_datasets(files)
    assert str(err.value) == (
        f"{files[1]}: run id 'log' already used by {files[0]} (a unit's run ids must be "
        "unique; a file's run id is the mapping's run_id where it sets one, else the file "
        "name without its extension: rename or copy one file under another name, leave "
        "run_id out of a mapping that reads several files, or map a run_column)")


def test_a_relative_mapping_not_found_names_where_it_was_looked_for(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(MappingError) as err:
        load_mapping("maps/lab.yaml")
    assert str(err.value) == (
        f"maps/lab.yaml: mapping file not found (a relative path is resolved against the "
        f"current directory {tmp_path}, a config's data.mapping as --mapping; give it from "
        "there, or absolute)")


def test_a_configs_mapping_not_found_names_the_key(tmp_path, monkeypatch, capsys):
    """``data.mapping`` naming no file: one line naming the key, the path and where a relative
    path was looked for; exit 1, no output directory."""
    monkeypatch.chdir(tmp_path)
    csv = tmp_path / "day1.csv"
    csv.write_text("time_s,temperature_c,gyro_x\n0,20,1\n1,21,1\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data: {{paths: ['{csv}'], mapping: maps/lab.yaml}}\n")
    assert main(["compare", str(cfg), "--out", str(tmp_path / "o"), "--no-track"]) == 1
    assert _err(capsys) == (
        "thermonet: error: key 'data.mapping': maps/lab.yaml: mapping file not found (a relative "
        f"path is resolved against the current directory {tmp_path}; give it from there, or "
        "absolute)")
    assert not (tmp_path / "o").exists()


def test_a_mapping_given_as_a_config_and_a_csv_to_calibrate(tmp_path, capsys):
    mapping = tmp_path / "map2.yaml"
    mapping.write_text("format: csv\nseparator: ';'\nsample_rate_hz: 0.5\n"
                       "channels:\n  gyro_x: {column: 1}\n")
    with pytest.raises(ConfigError) as err:
        config_from_mapping({"format": "csv", "separator": ";", "channels": {}},
                            source=str(mapping))
    assert str(err.value).endswith(
        "; this looks like a column mapping, not a config: name it under data.mapping in a "
        "config (with data.paths), or pass it with --mapping to thermonet info/convert")
    assert str(err.value).startswith(f"{mapping}: key 'format': unknown key (known: ")
    assert main(["compare", str(mapping), "--out", str(tmp_path / "o")]) == 1
    assert "this looks like a column mapping" in _err(capsys)
    csv = tmp_path / "day1.csv"
    csv.write_text("time_s,gyro_x\n0,1\n")
    assert main(["calibrate", str(csv), "--out", str(tmp_path / "c")]) == 1
    assert _err(capsys) == (f"thermonet: error: {csv}: not a flight-controller log (expected "
                            ".ulg or .bin); for a chamber recording (CSV, Parquet) use "
                            "thermonet compare with a config (README)")
