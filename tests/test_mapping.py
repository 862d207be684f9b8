"""Column mappings: strict YAML schema and its effect on loaded values."""

from __future__ import annotations

import logging
import textwrap

import numpy as np
import pytest

from thermonet.core.errors import ConfigError, InputError
from thermonet.data.io import read_dataset
from thermonet.data.mapping import ColumnMapping, MappingError, load_mapping


def _yaml(tmp_path, text: str, name: str = "map.yaml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


BANNER_MAPPING = """\
    skip_lines: 2
    header: false
    separator: auto
    malformed_rows: {malformed}
    time: {{column: 0, unit: µs}}
    channels:
      gyro_x: {{column: 2, unit: deg/s, scale: 0.5}}
      temperature_c: {{column: 1, unit: degC, scale: 0.01, offset: -40}}
      temp_raw: {{column: 1, unit: counts}}
      drive: {{column: 3, unit: Hz, proxy: true}}
    device_id: unit-7
    run_id: soak1
    meta: {{operator: ada}}
"""


def _banner_file(tmp_path, rows):
    lines = ["== serial log 2026-05-08 ==", "# firmware 1.2"] + rows
    path = tmp_path / "log.txt"
    path.write_text("\n".join(lines) + "\n")
    return path


def _rows(n=20):
    # counts 6000 + 100 i -> 0.01 * counts - 40 = 20 + i °C; gyro raw 2 * (0.1 + 0.01 i)
    return [f"{1000 * i}\t{6000 + 100 * i}\t{2 * (0.1 + 0.01 * i):.6f}\t{4517 + i}"
            for i in range(n)]


def test_mapping_scales_offsets_units_and_roles(tmp_path):
    mp = load_mapping(_yaml(tmp_path, BANNER_MAPPING.format(malformed="error")))
    assert mp.time.unit == "µs" and mp.time.seconds_per_unit == 1e-6
    ds = read_dataset(_banner_file(tmp_path, _rows()), mp)
    r = ds["soak1"]
    i = np.arange(20)
    np.testing.assert_allclose(r.time_s, i * 1e-3, rtol=0, atol=1e-15)
    np.testing.assert_allclose(r.temperature_c, 20.0 + i, atol=1e-9)
    np.testing.assert_allclose(r.outputs["gyro_x"], 0.1 + 0.01 * i, atol=1e-12)
    assert r.proxies.keys() == {"temp_raw", "drive"}
    assert r.proxies["temp_raw"][-1] == 7900.0 and r.proxies["drive"][0] == 4517.0
    assert r.units == {"time_s": "s", "gyro_x": "deg/s", "temperature_c": "degC",
                       "temp_raw": "counts", "drive": "Hz"}
    assert (r.device_id, r.sensor_kind, r.meta["operator"]) == ("unit-7", "gyro", "ada")


def test_skip_counts_malformed_rows_and_logs_them(tmp_path, caplog):
    rows = _rows(30)
    rows[5] = rows[5] + "\t99"           # a field too many
    rows[11] = "110000\t7100"            # truncated line
    rows[20] = rows[20].replace("\t", "\tx", 1)  # non-numeric cell
    path = _banner_file(tmp_path, rows)
    with pytest.raises(InputError, match=r"log\.txt, row 6: expected 4 fields, found 5 "
                       r"\(file line 8;"):
        read_dataset(path, _yaml(tmp_path, BANNER_MAPPING.format(malformed="error")))
    mp = _yaml(tmp_path, BANNER_MAPPING.format(malformed="skip"))
    with caplog.at_level(logging.WARNING, logger="thermonet.data.tables"):
        ds = read_dataset(path, mp)
    assert ds.meta["skipped_rows"] == "3"
    r = ds[0]
    assert r.n_samples == 27 and r.meta["skipped_rows"] == "3"
    assert r.meta["skipped_lines"] == "8,14,23"  # data row k is file line k + 2
    assert "skipped 3 malformed row(s)" in caplog.text
    # Skipped rows leave gaps in a time column; they never shift later samples.
    assert 5e-3 not in r.time_s and r.time_s[5] == pytest.approx(6e-3)


def test_fixed_sample_rate_and_header_by_name(tmp_path):
    path = tmp_path / "imu.csv"
    path.write_text("Temp;GyroX\n" + "\n".join(f"{25 + 0.1 * i};{0.01 * i}"
                                              for i in range(50)) + "\n")
    mp = ColumnMapping.from_dict({
        "sample_rate_hz": 20, "channels": {
            "temperature_c": {"column": "Temp"}, "gyro_x": {"column": "GyroX"}}})
    r = read_dataset(path, mp)[0]
    assert r.sample_rate_hz == 20.0 and r.time_s[-1] == pytest.approx(49 / 20)
    assert r.temperature_c[-1] == pytest.approx(29.9) and r.units["gyro_x"] == "deg/s"
    bad = ColumnMapping.from_dict({
        "sample_rate_hz": 20, "channels": {"gyro_x": {"column": "GyroZ"}}})
    with pytest.raises(InputError, match=r"imu\.csv, column 'GyroZ': missing column \(mapping "
                       r"key 'channels\.gyro_x\.column'; file has: Temp, GyroX\)"):
        read_dataset(path, bad)


@pytest.mark.parametrize("text, pattern", [
    ("sample_rate_hz: 50\nchanels: {}\n", r"key 'chanels': unknown key \(allowed:"),
    ("sample_rate_hz: 50\nchannels:\n  gyro_x: {column: 1, scal: 0.5}\n",
     r"key 'channels\.gyro_x\.scal': unknown key"),
    ("sample_rate_hz: 50\nchannels:\n  gyro_x: {column: 1, scale: half}\n",
     r"key 'channels\.gyro_x\.scale': expected a number, got 'half'"),
    ("sample_rate_hz: 50\nchannels:\n  gyro_x: {column: 1, scale: true}\n",
     r"key 'channels\.gyro_x\.scale': expected a number, got True"),
    ("sample_rate_hz: 50\nheader: yes please\nchannels:\n  gyro_x: {column: 1}\n",
     r"key 'header': expected true or false"),
    ("sample_rate_hz: 50\nchannels:\n  gyro_x: {column: 1, unit: deg/sec}\n",
     r"key 'channels\.gyro_x\.unit': unknown unit 'deg/sec' \(known:"),
    ("time: {column: 0, unit: min}\nchannels:\n  gyro_x: {column: 1}\n",
     r"key 'time\.unit': unknown time unit 'min' \(known: s, ms, us"),
    ("time: {column: 0}\nsample_rate_hz: 50\nchannels:\n  gyro_x: {column: 1}\n",
     r"key 'time': give exactly one of 'time'"),
    ("channels:\n  gyro_x: {column: 1}\n", r"key 'time': give exactly one of"),
    ("sample_rate_hz: 50\nheader: false\nchannels:\n  gyro_x: {column: GyroX}\n",
     r"key 'channels\.gyro_x\.column': column 'GyroX' given by name but 'header' is false"),
    ("sample_rate_hz: 50\nchannels:\n  temp_raw: {column: 1}\n",
     r"key 'channels': no output channel"),
    ("sample_rate_hz: 50\nchannels:\n  temperature_c: {column: 1, unit: counts}\n"
     "  gyro_x: {column: 2}\n", r"temperature_c must be in degC, got 'counts'"),
    ("sample_rate_hz: 50\nmalformed_rows: ignore\nchannels:\n  gyro_x: {column: 1}\n",
     r"key 'malformed_rows': expected 'error' or 'skip', got 'ignore'"),
    ("- just\n- a list\n", r"must be a YAML mapping of keys, got list"),
    ("channels: [unclosed\n", r"not valid YAML"),
])
def test_mapping_errors_name_file_and_key(tmp_path, text, pattern):
    path = _yaml(tmp_path, text, "my_map.yaml")
    with pytest.raises(MappingError, match=r"my_map\.yaml.*" + pattern) as info:
        load_mapping(path)
    # Callers may treat it as either kind of user error (the CLI exits 1 on both).
    assert isinstance(info.value, InputError) and isinstance(info.value, ConfigError)
    assert "\n" not in str(info.value)


def test_missing_mapping_file(tmp_path):
    with pytest.raises(MappingError, match=r"absent\.yaml: mapping file not found"):
        load_mapping(tmp_path / "absent.yaml")
