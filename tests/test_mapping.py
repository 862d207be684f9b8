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
    ("time: {column: 0, unit: days}\nchannels:\n  gyro_x: {column: 1}\n",
     r"key 'time\.unit': unknown time unit 'days' \(known: s, ms, us, µs, μs, min, h\)"),
    ("time: {column: 0}\nsample_rate_hz: 50\nchannels:\n  gyro_x: {column: 1}\n",
     r"key 'time': give exactly one of 'time'"),
    ("channels:\n  gyro_x: {column: 1}\n", r"key 'time': give exactly one of"),
    ("sample_rate_hz: 50\nheader: false\nchannels:\n  gyro_x: {column: GyroX}\n",
     r"key 'channels\.gyro_x\.column': column 'GyroX' given by name but 'header' is false"),
    ("sample_rate_hz: 50\nchannels:\n  temp_raw: {column: 1}\n",
     r"key 'channels': no output channel"),
    ("sample_rate_hz: 50\nchannels:\n  temperature_c: {column: 1, unit: counts}\n"
     "  gyro_x: {column: 2}\n", r"temperature_c must be in degC, got 'counts'"),
    ("sample_rate_hz: 50\nchannels:\n  gyro_x: {column: 1, unit: m/s^2}\n",
     r"key 'channels\.gyro_x\.unit': 'm/s\^2' is a unit of acceleration, and gyro_x is a gyro "
     r"channel \(its units: deg/s, deg/h, rad/s; or counts / 1 for raw values\)"),
    ("sample_rate_hz: 50\nchannels:\n  acc_x: {column: 1}\n  ref_acc_x: {column: 2, unit: Pa}\n",
     r"key 'channels\.ref_acc_x\.unit': 'Pa' is a unit of pressure, and ref_acc_x is an "
     r"accelerometer channel \(its units: g, mg, m/s\^2;"),
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


def test_a_parquet_file_read_as_text_names_the_mapping_format_that_did_it(tmp_path):
    """A Parquet file read with a mapping whose ``format: csv`` said only "not UTF-8 text":
    the message now says what the file is and which key made it read as text; a Parquet file
    named .csv names its extension."""
    from thermonet.data.io import write_parquet
    from thermonet.sim import simulate

    pq = write_parquet(simulate("accel", runs=1, seed=0), tmp_path / "a.parquet")
    mapping = _yaml(tmp_path, """\
        format: csv
        time: {column: time_s, unit: s}
        channels:
          temperature_c: {column: temperature_c, unit: degC}
          acc_x: {column: acc_x, unit: g}
    """)
    with pytest.raises(InputError) as err:
        read_dataset(pq, mapping=mapping)
    msg = str(err.value)
    assert msg.startswith(f"{pq}: not UTF-8 text (byte ")
    assert msg.endswith(f": a Parquet file (it starts with 'PAR1'), read as text because the "
                        f"mapping {mapping} says 'format: csv'; set its format to parquet (or "
                        "auto)")
    renamed = tmp_path / "a.csv"
    renamed.write_bytes(pq.read_bytes())
    with pytest.raises(InputError, match=r"a Parquet file \(it starts with 'PAR1'\), read as "
                                         r"text because of its extension '\.csv'; rename it "
                                         r"to \.parquet$"):
        read_dataset(renamed)


NOTE_MAPPING = """\
    time: {column: t, unit: s}
    channels:
      temperature_c: {column: temp, unit: degC}
      gyro_x: {column: gx, unit: deg/s}
    device_id: bench
    run_id: soak
"""


def _noted_csv(tmp_path, n=2000, bad_row=None):
    """A CSV whose 'note' column (not mapped) holds quoted cells with line breaks — legal
    CSV — on rows 1, 37, 38, 999 and 1000 (the last two at the 1000-line chunk edge), one
    with a doubled quote; row ``bad_row``'s gyro cell is 'oops'.  Returns the path and the
    physical file line of each data row."""
    notes = {1: '"first\nsecond"', 37: '"a ""quoted""\n\nword"', 38: '"x\ny\nz"',
             999: '"edge\nof the chunk"', 1000: '"and\nover it"'}
    lines, line_of, at = ["t,temp,gx,note"], {}, 2
    for i in range(1, n + 1):
        gx = "oops" if i == bad_row else f"{0.01 * i:.6f}"
        cell = notes.get(i, "plain")
        lines.append(f"{0.1 * i:.1f},{20 + 0.01 * i:.4f},{gx},{cell}")
        line_of[i] = at
        at += 1 + cell.count("\n")
    path = tmp_path / "noted.csv"
    path.write_text("\n".join(lines) + "\n")
    return path, line_of


def test_a_quoted_line_break_in_an_unmapped_column_is_read_as_csv(tmp_path, capsys):
    """Quoted cells that span lines (in a column the mapping leaves out) are one row each:
    the whole read, the chunked info (a cell across the chunk edge) and convert give every
    one of the 2,000 rows with its own values (was an IndexError in map_frame)."""
    from thermonet.cli import main
    from thermonet.workflows.info_chunked import summarize_parquet

    path, _ = _noted_csv(tmp_path)
    mp = load_mapping(_yaml(tmp_path, NOTE_MAPPING))
    r = read_dataset(path, mp)["soak"]
    i = np.arange(1, 2001)
    assert r.n_samples == 2000
    np.testing.assert_array_equal(r.time_s, np.array([float(f"{0.1 * k:.1f}") for k in i]))
    np.testing.assert_array_equal(r.outputs["gyro_x"],
                                  np.array([float(f"{0.01 * k:.6f}") for k in i]))
    for chunk in (7, 999, 1000, 65536):
        got = summarize_parquet(path, chunk_rows=chunk, mapping=mp)
        assert got["runs"][0]["samples"] == 2000
        assert got["temperature_range_c"] == [20.01, 40.0]
    out = tmp_path / "noted.parquet"
    assert main(["convert", str(path), "--mapping", str(tmp_path / "map.yaml"),
                 "--out", str(out), "--chunk-rows", "999"]) == 0
    back = read_dataset(out)["soak"]
    np.testing.assert_array_equal(back.outputs["gyro_x"], r.outputs["gyro_x"])
    np.testing.assert_array_equal(back.temperature_c, r.temperature_c)
    capsys.readouterr()


@pytest.mark.parametrize("chunk", [None, 999, 1000])
def test_a_bad_cell_after_multi_line_cells_names_its_own_file_line(tmp_path, chunk):
    """After quoted cells that span lines, a message still names the row and its physical
    file line (here 7 lines further down than the row number suggests)."""
    path, line_of = _noted_csv(tmp_path, bad_row=1500)
    mp = load_mapping(_yaml(tmp_path, NOTE_MAPPING))
    want = f"{path}, column 'gx', row 1500: non-numeric cell 'oops' (file line {line_of[1500]})"
    assert line_of[1500] == 1508
    assert _refusal(path, mp, chunk) == want


def _refusal(path, mp, chunk):
    """The one line a mapped text file is refused with, read whole (``chunk`` None) or in
    chunks of ``chunk`` rows (as ``info`` reads it)."""
    from thermonet.workflows.info_chunked import summarize_parquet

    with pytest.raises(InputError) as err:
        if chunk is None:
            read_dataset(path, mp)
        else:
            summarize_parquet(path, chunk_rows=chunk, mapping=mp)
    return str(err.value)


def test_a_quoted_cell_left_open_to_the_end_is_one_line(tmp_path):
    """A quote that never closes would swallow the rest of the file into one cell: refused
    in one line naming the file line it opens on (not a traceback, not rows lost)."""
    path, _ = _noted_csv(tmp_path, n=30)
    text = path.read_text().splitlines()
    text[10] = text[10].replace("plain", '"never closed')  # row 9, on file line 11
    path.write_text("\n".join(text) + "\n")
    mp = load_mapping(_yaml(tmp_path, NOTE_MAPPING))
    want = (f"{path}: file line 11: a quoted cell opens on this line and never closes (a '\"' "
            "is missing; it would swallow the 21 lines after it)")
    for chunk in (None, 5, 11, 100):
        assert _refusal(path, mp, chunk) == want


# ------------------------------------------------------------- a European chamber logger
# Its habits: a banner, ';' separators, bracketed units in the headers, a trailing ';'.

LAB_HEADER = ["Zeit [s]", "Temp [°F]", "Gyro X [°/s]", "Druck [hPa]"]
LAB_MAPPING = """\
    separator: ";"
    skip_lines: 2
    time: {{column: "{time}", unit: {unit}}}
    channels:
      temperature_c: {{column: "Temp [°F]", unit: degC, scale: 0.5555555556,
                      offset: -17.7777777778}}
      gyro_x: {{column: "Gyro X [°/s]", unit: deg/s}}
      baro_p: {{column: "Druck [hPa]", unit: hPa}}
    {extra}
"""


def _lab(tmp_path, *, header=None, trail="", row_trail=";", n=40, name="lab.csv",
         time_scale=1.0, cell=None):
    """A chamber logger's file: 2 banner lines, a header, ``n`` rows every 30 s from 14 °F
    (-10 °C) up 2 °F a row; ``cell`` (row index, text) replaces a row's temperature."""
    rows = [f"{30.0 * i / time_scale:.17g};{14 + 2 * i:.2f};{0.01 + 0.001 * i:.5f};"
            f"{1012.5 + 0.1 * i:.2f}" for i in range(n)]
    if cell is not None:
        parts = rows[cell[0]].split(";")
        parts[1] = cell[1]
        rows[cell[0]] = ";".join(parts)
    head = ";".join(header or LAB_HEADER) + trail
    path = tmp_path / name
    path.write_text("# ThermoLog TL-500\n# Kammer: VT 4002\n" + head + "\n"
                    + "\n".join(r + row_trail for r in rows) + "\n", encoding="utf-8")
    return path


def _lab_map(tmp_path, time="Zeit [s]", unit="s", extra="", name="lab.yaml"):
    return _yaml(tmp_path, LAB_MAPPING.format(time=time, unit=unit, extra=extra), name)


def _both(path, mapping, chunk_rows=7):
    """The whole-file read and the streamed layout pass (``chunk_rows`` lines a chunk)."""
    from thermonet.data.chunks import open_source

    ds = read_dataset(path, mapping)
    layout = open_source(path, load_mapping(mapping), chunk_rows=chunk_rows)
    return ds, layout


@pytest.mark.parametrize("trail", ["", ";"])
def test_one_trailing_separator_on_the_rows_is_no_column(tmp_path, trail):
    """A trailing ';' on every data row (the header with or without one) was "expected 4
    fields, found 5", and malformed_rows: skip then dropped every row: read as no column,
    whole and streamed (the streamed fast parser and its fallback alike)."""
    path = _lab(tmp_path, trail=trail)
    ds, layout = _both(path, _lab_map(tmp_path))
    r = ds[0]
    assert r.n_samples == 40 == layout.times[0].n
    np.testing.assert_allclose(r.outputs["baro_p"], 1012.5 + 0.1 * np.arange(40), atol=1e-9)
    np.testing.assert_allclose(r.time_s, 30.0 * np.arange(40))


def test_every_row_skipped_says_how_many_and_why(tmp_path):
    """skip_lines one short reads a banner line as a one-field header: the error no longer
    advises malformed_rows: skip, and where skip was set, "no data rows" says what happened."""
    path = _lab(tmp_path)
    short = "separator: ';'\nskip_lines: 1\nsample_rate_hz: 0.5\nchannels:\n  gyro_x: {column: 2}\n"
    with pytest.raises(InputError) as err:
        read_dataset(path, _yaml(tmp_path, short))
    assert str(err.value) == (f"{path}, row 1: expected 1 field (the header line has one), "
                              "found 4 (file line 3); is skip_lines right (a banner line "
                              "read as the header?), or the separator?")
    with pytest.raises(InputError) as err:
        read_dataset(path, _yaml(tmp_path, short + "malformed_rows: skip\n"))
    assert str(err.value) == (f"{path}: no data rows: all 41 rows skipped as malformed "
                              "(expected 1 field, found 5, 4); are skip_lines and the "
                              "separator right?")


def test_empty_and_repeated_header_names_the_mapping_does_not_read(tmp_path):
    """Two trailing separators (two empty names) and a name twice ('Reserve [V]') in columns
    the mapping never reads are read past; a repeated name it reads is refused, and without a
    mapping empty names are named as such (was "column '': duplicate column")."""
    header = LAB_HEADER + ["Reserve [V]", "Reserve [V]"]
    path = _lab(tmp_path, header=header, trail=";;", row_trail=";0;0;;")
    assert _both(path, _lab_map(tmp_path))[0][0].n_samples == 40
    dup = _lab(tmp_path, header=[*LAB_HEADER[:3], "Gyro X [°/s]"], name="dup.csv")
    with pytest.raises(InputError) as err:
        read_dataset(dup, _lab_map(tmp_path))
    assert str(err.value) == (f"{dup}, column 'Gyro X [°/s]': duplicate column in the header "
                              "(the mapping reads it; rename one in the file)")
    native = tmp_path / "native.csv"
    native.write_text("time_s,gyro_x,temperature_c,,\n0,1,20,,\n")
    with pytest.raises(InputError) as err:
        read_dataset(native)
    assert str(err.value) == (f"{native}: header fields 4, 5 are empty (file line 1: a "
                              "separator too many at the end of the header line?)")


def test_n_fields_that_contradicts_the_header_is_refused(tmp_path):
    path = _lab(tmp_path, trail=";")
    mp = _lab_map(tmp_path, extra="n_fields: 7")
    with pytest.raises(InputError) as err:
        read_dataset(path, mp)
    assert str(err.value) == (f"{path}: mapping key 'n_fields' is 7, but the header line has "
                              "4 fields (with a header, leave n_fields out: the header sets "
                              f"it; mapping {mp})")
    assert read_dataset(path, _lab_map(tmp_path, extra="n_fields: 5", name="m5.yaml"))[0] \
        .n_samples == 40                      # the header's count with its trailing field


@pytest.mark.parametrize("unit,scale", [("min", 60.0), ("h", 3600.0)])
def test_time_in_minutes_and_hours(tmp_path, unit, scale):
    path = _lab(tmp_path, header=["Zeit [x]", *LAB_HEADER[1:]], time_scale=scale)
    ds, layout = _both(path, _lab_map(tmp_path, time="Zeit [x]", unit=unit))
    np.testing.assert_allclose(ds[0].time_s, 30.0 * np.arange(40), rtol=1e-12)
    assert layout.times[0].last == pytest.approx(30.0 * 39, rel=1e-12)


@pytest.mark.parametrize("cell,time,hint", [
    ((3, "20,03"), "Zeit [s]", "; thermonet reads '.' as the decimal mark: convert the file "
     "(e.g. export it with '.' decimals in the logger's or spreadsheet's locale setting)"),
    (None, "Uhrzeit", "; time in a CSV must be numeric (time.unit s, ms, us, min or h since "
     "the start), not clock or date text: export elapsed time, or give sample_rate_hz instead "
     "of time"),
])
def test_decimal_comma_and_clock_text_say_what_to_do(tmp_path, cell, time, hint):
    path = _lab(tmp_path, cell=cell, header=[time, *LAB_HEADER[1:]])
    if cell is None:   # clock text in the time column
        text = path.read_text().replace("\n0;", "\n10:00:00;", 1)
        path.write_text(text)
    with pytest.raises(InputError) as err:
        read_dataset(path, _lab_map(tmp_path, time=time))
    column, value = ("Temp [°F]", "20,03") if cell else (time, "10:00:00")
    row = 4 if cell else 1
    assert str(err.value) == (f"{path}, column '{column}', row {row}: non-numeric cell "
                              f"'{value}' (file line {row + 3}){hint}")


@pytest.mark.parametrize("chunk_rows", [None, 5])
def test_not_utf8_names_the_file_line_and_the_fix(tmp_path, chunk_rows):
    from thermonet.data.text import iter_text_frames

    path = tmp_path / "cp1252.csv"
    path.write_bytes("# Prüfling\n".encode() + "# Kammer: Vötsch\n".encode("cp1252")
                     + b"time_s;gyro_x\n" + b"0;1\n" * 20)
    with pytest.raises(InputError) as err:
        list(iter_text_frames(path, None, None, chunk_rows=chunk_rows))
    assert str(err.value) == (f"{path}: not UTF-8 text (byte 23, file line 2, 0xf6): the file "
                              "must be UTF-8 (or plain ASCII); save or export it as UTF-8")


def test_a_header_unit_other_than_the_mappings_is_one_warning(tmp_path):
    """A header's bracketed unit that contradicts the mapping's, with no scale or offset
    (°F read as degC, Pa as hPa, rad/s as deg/s), is one warning naming the file, the columns
    and both units; the converted °F column and agreeing units are not named."""
    from thermonet.data.diagnostics import input_warnings

    header = ["Zeit [s]", "Temp [°F]", "Gyro X [°/s]", "Druck [Pa]", "Rate (rad/s)",
              "Heat [°F]"]
    path = _lab(tmp_path, header=header, row_trail=";0.5;68")
    mp = _yaml(tmp_path, """\
        separator: ";"
        skip_lines: 2
        time: {column: "Zeit [s]", unit: s}
        channels:
          temperature_c: {column: "Temp [°F]", unit: degC, scale: 0.5555555556,
                          offset: -17.7777777778}
          gyro_x: {column: "Gyro X [°/s]", unit: deg/s}
          gyro_y: {column: "Rate (rad/s)", unit: deg/s}
          baro_p: {column: "Druck [Pa]", unit: hPa}
          t_chip: {column: "Heat [°F]", unit: degC, proxy: true}
    """)
    ds = read_dataset(path, mp)
    want = (f"run 'lab': in {path} the headers name other units than the mapping ('Rate "
            "(rad/s)' says rad/s, mapped as deg/s; 'Druck [Pa]' says Pa, mapped as hPa; "
            "'Heat [°F]' says °F, mapped as degC); is the mapping's unit right? (convert with "
            "scale/offset where the header is)")
    assert [w for w in input_warnings(ds) if "headers name" in w] == [want]
    assert "header_units" not in read_dataset(_lab(tmp_path, name="ok.csv"),
                                              _lab_map(tmp_path))[0].meta


@pytest.mark.parametrize("tz", ["Europe/Berlin", None])
def test_parquet_date_time_stamps_zoned_or_not(tmp_path, tz):
    """A Parquet time column of zoned stamps (was a TypeError from pandas) is read through
    UTC: across the night clocks went forward in Berlin the samples stay 60 s apart."""
    import pandas as pd

    stamps = pd.date_range("2024-03-31 00:30", periods=120, freq="60s", tz="UTC")
    stamps = stamps.tz_convert(tz) if tz else stamps.tz_localize(None)
    path = tmp_path / "zoned.parquet"
    pd.DataFrame({"Zeitstempel": stamps, "Temp [°C]": np.linspace(10, 40, 120),
                  "gx": np.linspace(0, 1, 120)}).to_parquet(path)
    mp = _yaml(tmp_path, """\
        time: {column: Zeitstempel, unit: s}
        channels:
          temperature_c: {column: "Temp [°C]", unit: degC}
          gyro_x: {column: gx, unit: deg/s}
    """)
    ds, layout = _both(path, mp, chunk_rows=50)
    np.testing.assert_allclose(ds[0].time_s, 60.0 * np.arange(120), rtol=1e-12)
    assert (layout.times[0].first, layout.times[0].last) == (0.0, pytest.approx(60.0 * 119))


def test_no_skipped_rows_no_warning(tmp_path, caplog):
    with caplog.at_level(logging.WARNING, logger="thermonet.data.tables"):
        _both(_lab(tmp_path), _lab_map(tmp_path, extra="malformed_rows: skip"))
    assert "malformed" not in caplog.text
