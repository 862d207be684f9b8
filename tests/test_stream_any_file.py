"""Every tabular recording streams: thermonet Parquet, plain Parquet, CSV and TSV, with or
without a column mapping, read chunk by chunk (:mod:`thermonet.data.chunks`) give the values
the whole-file reader (:mod:`thermonet.data.io`) gives, the same skipped rows, the same
``info`` figures and the same window means; ``convert`` streams; and bad input — a cell
that does not parse deep in a long file, a column whose cells turn to text in a later row
group, a truncated or damaged file, time going backwards across a chunk edge, a newer format
version — is one line naming file, column and row, exit 1, nothing written.

Independent expectations: the whole-file reader (:func:`thermonet.data.io.read_dataset`,
which parses each file in one piece) and :func:`thermonet.workflows.info.summarize` on it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml

from thermonet.cli import main
from thermonet.core.errors import InputError
from thermonet.core.recording import Dataset, Recording
from thermonet.data.chunks import iter_run_chunks, open_source
from thermonet.data.io import read_dataset, write_parquet
from thermonet.data.mapping import ColumnMapping, load_mapping
from thermonet.features.windows import reduce_parquet
from thermonet.workflows.info import summarize
from thermonet.workflows.info_chunked import summarize_parquet
from tolerances import assert_f64_close

pytestmark = pytest.mark.numerics

N = 3000          # samples per run
CHUNKS = [7, 997, 65536]


def _runs() -> list[Recording]:
    out = []
    for k, run_id in enumerate(("warm", "cool")):
        rng = np.random.default_rng(k)
        t = 100.0 * k + np.arange(N) * 0.5
        temp = 10.0 + 40.0 * np.sin(np.pi * np.arange(N) / N) + rng.normal(0, 0.01, N)
        ref = np.sin(t / 20.0)
        out.append(Recording(
            time_s=t, temperature_c=temp,
            outputs={"gyro_x": ref + 0.01 * temp + rng.normal(0, 1e-3, N),
                     "gyro_y": -2e-4 * temp ** 2 + rng.normal(0, 1e-3, N)},
            references={"ref_gyro_x": ref}, proxies={"freq_hz": 1000.0 + temp},
            units={"gyro_x": "deg/s", "gyro_y": "deg/s", "ref_gyro_x": "deg/s",
                   "temperature_c": "degC", "freq_hz": "Hz"}, run_id=run_id))
    return out


COLUMNS = ["time_s", "temperature_c", "gyro_x", "gyro_y", "ref_gyro_x", "freq_hz"]


def _write_csv(path: Path, runs: list[Recording], sep: str = ",") -> Path:
    """Conventional names, a run column, the runs' rows interleaved in blocks of 100."""
    rows = []
    for r in runs:
        cols = [r.time_s, r.temperature_c, r.outputs["gyro_x"], r.outputs["gyro_y"],
                r.references["ref_gyro_x"], r.proxies["freq_hz"]]
        rows.append([[repr(float(c[i])) for c in cols] + [r.run_id] for i in range(N)])
    order = [rows[k][i] for b in range(0, N, 100) for k in range(len(rows))
             for i in range(b, min(b + 100, N))]
    path.write_text(sep.join(COLUMNS + ["run"]) + "\n"
                    + "\n".join(sep.join(x) for x in order) + "\n")
    return path


#: a foreign layout: time in ms, the gyro in rad/s scaled to deg/s with an offset, a banner
MAPPING = {"skip_lines": 2, "time": {"column": "t_ms", "unit": "ms"}, "run_column": "test",
           "channels": {"temperature_c": {"column": "temp"},
                        "gyro_x": {"column": "gx", "unit": "deg/s",
                                   "scale": 57.29577951308232, "offset": 0.25},
                        "gyro_y": {"column": "gy", "unit": "deg/s"},
                        "freq_hz": {"column": "f", "unit": "Hz"}},
           "device_id": "imu7"}


def _write_mapped_csv(path: Path, runs: list[Recording], bad: dict[int, str] | None = None,
                      ) -> Path:
    lines = ["# logger v2", "# export", "t_ms;temp;gx;gy;f;test"]
    k = 0
    for r in runs:
        for i in range(N):
            k += 1
            gx = (r.outputs["gyro_x"][i] - 0.25) / 57.29577951308232
            cells = [repr(float(r.time_s[i] * 1000.0)), repr(float(r.temperature_c[i])),
                     repr(float(gx)), repr(float(r.outputs["gyro_y"][i])),
                     repr(float(r.proxies["freq_hz"][i])), r.run_id]
            lines.append(bad[k] if bad and k in bad else ";".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, tuple[Path, ColumnMapping | None]]:
    tmp = tmp_path_factory.mktemp("any")
    runs = _runs()
    out: dict[str, tuple[Path, ColumnMapping | None]] = {}
    out["thermonet"] = (write_parquet(Dataset(runs=runs), tmp / "rec.parquet"), None)
    out["csv"] = (_write_csv(tmp / "rec.csv", runs), None)
    out["tsv"] = (_write_csv(tmp / "rec.tsv", runs, "\t"), None)
    table = pq.read_table(out["thermonet"][0]).replace_schema_metadata(None)
    pq.write_table(table, tmp / "plain.parquet", row_group_size=1000)
    out["plain-parquet"] = (tmp / "plain.parquet", None)
    mpath = tmp / "m.yaml"
    mpath.write_text(yaml.safe_dump(MAPPING))
    out["mapped-csv"] = (_write_mapped_csv(tmp / "foreign.csv", runs), load_mapping(mpath))
    foreign = pa.table({"t_ms": np.concatenate([r.time_s * 1000 for r in runs]),
                        "temp": np.concatenate([r.temperature_c for r in runs]),
                        "gx": np.concatenate([(r.outputs["gyro_x"] - 0.25) / 57.29577951308232
                                              for r in runs]),
                        "gy": np.concatenate([r.outputs["gyro_y"] for r in runs]),
                        "f": np.concatenate([r.proxies["freq_hz"] for r in runs]),
                        "test": np.repeat([r.run_id for r in runs], N)})
    pq.write_table(foreign, tmp / "foreign.parquet", row_group_size=777)
    pm = dict(MAPPING, format="parquet")
    del pm["skip_lines"]
    out["mapped-parquet"] = (tmp / "foreign.parquet", ColumnMapping.from_dict(pm))
    return out


KINDS = ["thermonet", "csv", "tsv", "plain-parquet", "mapped-csv", "mapped-parquet"]


@pytest.mark.parametrize("chunk_rows", CHUNKS)
@pytest.mark.parametrize("kind", KINDS)
def test_chunked_reader_gives_the_whole_file_readers_values(files, kind, chunk_rows):
    """Every channel of every run, in order: the values the whole-file reader gives (the
    same parsing, time unit, scale and offset — equal to float64 rounding), with the same
    runs, units, metadata and sample counts."""
    path, mapping = files[kind]
    whole = read_dataset(path, mapping)
    layout = open_source(path, mapping, chunk_rows=chunk_rows)
    assert [(e["device_id"], e["run_id"], e["n_samples"]) for e in layout.runs] == \
        [(r.device_id, r.run_id, r.n_samples) for r in whole]
    for e, r in zip(layout.runs, whole, strict=True):
        assert e["units"] == r.units and e["meta"] == r.meta
        assert (e["outputs"], e["proxies"]) == (list(r.outputs), list(r.proxies))
    names = [c for c in layout.columns if c not in ("time_s", "run", "device")]
    got: dict[int, dict[str, list[np.ndarray]]] = {}
    for i, rows, piece in iter_run_chunks(layout, names, chunk_rows=chunk_rows):
        assert rows.size == piece["time_s"].size <= chunk_rows
        for k, v in piece.items():
            got.setdefault(i, {}).setdefault(k, []).append(v)
    for i, r in enumerate(whole):
        for k, parts in got[i].items():
            want = r.time_s if k == "time_s" else r.channel(k)
            # the same text through the same parser: equal to float64 rounding
            assert_f64_close(np.concatenate(parts), want, err_msg=f"{kind} {k}")


@pytest.mark.parametrize("kind", KINDS[1:])
def test_info_of_any_file_streamed_equals_the_whole_file_summary(files, kind):
    path, mapping = files[kind]
    want = summarize(read_dataset(path, mapping))
    got = summarize_parquet(path, mapping=mapping, chunk_rows=500)
    json.dumps(got)
    for key in ("device_id", "sensor_kind", "n_runs", "channels", "temperature_range_c",
                "skipped_rows", "warnings", "noise_floor_basis"):
        assert got[key] == want[key], key
    for g, w in zip(got["runs"], want["runs"], strict=True):
        assert g["samples"] == w["samples"] and g["run_id"] == w["run_id"]
        assert_f64_close(g["duration_s"], w["duration_s"])
        assert_f64_close(g["sample_rate_hz"], w["sample_rate_hz"])
    for g, w in zip(got["outputs"], want["outputs"], strict=True):
        # Chan's merge of the first differences' moments and binned sums: float64 rounding
        assert_f64_close(g["noise_floor"], w["noise_floor"], rtol=1e-9)
        assert_f64_close(g["drift_peak_to_peak"], w["drift_peak_to_peak"], rtol=1e-9)


@pytest.mark.parametrize("kind", ["csv", "mapped-csv", "mapped-parquet"])
def test_a_streamed_plain_file_reduces_as_its_converted_copy(files, kind, tmp_path):
    """The window means of a CSV (or mapped) file streamed directly equal those of the same
    file converted first (``thermonet convert``, itself streamed in 611-row chunks)."""
    path, mapping = files[kind]
    out = tmp_path / "conv.parquet"
    args = ["convert", str(path), "--out", str(out), "--chunk-rows", "611"]
    if mapping is not None:
        mfile = tmp_path / "m.yaml"
        mfile.write_text(yaml.safe_dump(
            {k: v for k, v in (MAPPING if kind == "mapped-csv" else
                               dict({k: v for k, v in MAPPING.items() if k != "skip_lines"},
                                    format="parquet")).items()}))
        args += ["--mapping", str(mfile)]
    assert main(args) == 0
    assert b"thermonet.digest" in pq.read_metadata(out).metadata   # checked by the reads
    whole, conv = read_dataset(path, mapping), read_dataset(out)
    for a, b in zip(whole, conv, strict=True):
        assert (a.run_id, a.units) == (b.run_id, b.units)
        # the mapping's file is named where it was read from (here: another copy)
        assert {k: v for k, v in a.meta.items() if k != "mapping"} == \
            {k: v for k, v in b.meta.items() if k != "mapping"}
        assert np.array_equal(a.time_s, b.time_s)          # values copied, not computed
        for k in [*a.outputs, *a.proxies, "temperature_c"]:
            assert np.array_equal(a.channel(k), b.channel(k))
    inputs = ["dT", "rate", "lag_300"]
    direct = reduce_parquet(path, window_s=5.0, inputs=inputs, chunk_rows=433,
                            mapping=mapping)
    first = reduce_parquet(out, window_s=5.0, inputs=inputs, chunk_rows=4096)
    for a, b in zip(direct, first, strict=True):
        assert a.windows is not None and b.windows is not None
        assert np.array_equal(a.windows.n, b.windows.n)
        assert_f64_close(a.time_s, b.time_s)
        for k in [*a.outputs, *a.proxies, "temperature_c", "rate_c_per_min", "lag_300_c"]:
            # other chunk edges: Chan's merges and the dynamic inputs' blocked scans
            want = b.channel(k) if k in (*b.outputs, *b.proxies, "temperature_c") \
                else b.windows.signals[k]
            got = a.channel(k) if k in (*a.outputs, *a.proxies, "temperature_c") \
                else a.windows.signals[k]
            assert_f64_close(got, want, atol=float(np.abs(want).max()) * 1e-12, err_msg=k)


def test_skipped_rows_are_counted_as_the_whole_file_reader_counts_them(tmp_path):
    """``malformed_rows: skip``: rows with a wrong field count and rows with a bad cell,
    spread over several chunks, counted per run and per file as read whole."""
    runs = _runs()
    bad = {5: "1;2;3", 1200: "oops", 2500: "250000;12;x;1;2;warm", 4000: ";;;;;cool",
           4001: "400500;11;0.1;0.2;nan;cool"}
    path = _write_mapped_csv(tmp_path / "skips.csv", runs, bad)
    mapping = ColumnMapping.from_dict(dict(MAPPING, malformed_rows="skip"))
    whole = read_dataset(path, mapping)
    for chunk in (3, 1000):
        layout = open_source(path, mapping, chunk_rows=chunk)
        assert layout.meta["skipped_rows"] == whole.meta["skipped_rows"] == "5"
        assert [e["meta"] for e in layout.runs] == [r.meta for r in whole]
        assert [e["n_samples"] for e in layout.runs] == [r.n_samples for r in whole]


# ----------------------------------------------------------------------- refusals
def _compare(tmp_path: Path, data: Path, chunk_rows: int, capsys, mapping: Path | None = None
             ) -> list[str]:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump({
        "data": {"paths": [str(data)], "in_memory_samples": 0, "chunk_rows": chunk_rows,
                 **({"mapping": str(mapping)} if mapping else {})},
        "families": [{"name": "linear", "family": "linear", "inputs": ["dT"]}],
        "baseline": None, "tracking": {"enabled": False}}))
    capsys.readouterr()
    rc = main(["compare", str(cfg), "--out", str(tmp_path / "out"), "-q", "--no-track"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1, err
    assert not (tmp_path / "out").exists()
    return err


def _convert(tmp_path: Path, data: Path, chunk_rows: int, capsys,
             mapping: Path | None = None) -> str:
    out = tmp_path / "conv.parquet"
    capsys.readouterr()
    rc = main(["convert", str(data), "--out", str(out), "--chunk-rows", str(chunk_rows)]
              + (["--mapping", str(mapping)] if mapping else []))
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1, err
    assert not out.exists() and not list(tmp_path.glob(".conv.parquet*"))
    return err[0]


def test_a_row_that_fails_to_parse_deep_in_a_long_csv(tmp_path, capsys):
    """Row 4,321 of 6,000 (chunks of 1,000 lines: the fifth chunk) has a cell that is not a
    number: the whole-file reader's line, from compare, convert and info alike."""
    runs = _runs()
    path = _write_mapped_csv(tmp_path / "deep.csv", runs,
                             {4321: f"{float(runs[1].time_s[1320]) * 1000!r};20.5;0.1;12..5;1000;cool"})
    mfile = tmp_path / "m.yaml"
    mfile.write_text(yaml.safe_dump(MAPPING))
    with pytest.raises(InputError) as whole:
        read_dataset(path, load_mapping(mfile))
    want = str(whole.value)
    assert "deep.csv" in want and "column 'gy'" in want and "row 4321" in want
    assert "non-numeric cell '12..5'" in want and "file line 4324" in want
    assert _compare(tmp_path, path, 1000, capsys, mfile)[0] == f"thermonet: error: {want}"
    assert _convert(tmp_path, path, 1000, capsys, mfile) == f"thermonet: error: {want}"
    capsys.readouterr()
    assert main(["info", str(path), "--mapping", str(mfile), "--chunk-rows", "1000"]) == 1
    assert capsys.readouterr().err.strip() == f"thermonet: error: {want}"


def test_a_column_whose_cells_turn_to_text_in_a_later_row_group(tmp_path, capsys):
    """A plain Parquet file whose gyro column is text (numbers written as strings; one
    row group of 500 rows further on holds 'n/a'): file, column and row, not a traceback;
    and a thermonet file with such a column (once a bare ``could not convert string to
    float``) is named the same way by both readers."""
    runs = _runs()
    n = 2 * N
    gy = np.concatenate([r.outputs["gyro_y"] for r in runs]).astype(str).astype(object)
    gy[4567] = "n/a"
    table = pa.table({"time_s": np.concatenate([r.time_s + 1e4 * k for k, r in
                                                enumerate(runs)]),
                      "temperature_c": np.concatenate([r.temperature_c for r in runs]),
                      "gyro_x": np.concatenate([r.outputs["gyro_x"] for r in runs]),
                      "gyro_y": pa.array(gy, pa.string())})
    assert table.num_rows == n
    path = tmp_path / "text.parquet"
    pq.write_table(table, path, row_group_size=500)
    err = _compare(tmp_path, path, 1024, capsys)[0]
    assert "text.parquet" in err and "column 'gyro_y'" in err and "row 4568" in err, err
    assert "non-numeric cell 'n/a'" in err
    # a CSV whose gy column turns to text at a chunk edge (a reader that infers the
    # column's type from its first block would fail there with no row)
    bad = {k: f"{float(runs[1].time_s[k - N - 1]) * 1000!r};20;0.1;n/a;1000;cool"
           for k in range(4001, 2 * N + 1)}
    text = _write_mapped_csv(tmp_path / "turns.csv", runs, bad)
    mfile = tmp_path / "m.yaml"
    mfile.write_text(yaml.safe_dump(MAPPING))
    err = _compare(tmp_path, text, 1000, capsys, mfile)[0]
    assert "turns.csv, column 'gy', row 4001: non-numeric cell 'n/a' (file line 4004)" in err
    # a thermonet file with a text column
    good = write_parquet(Dataset(runs=runs), tmp_path / "tn.parquet")
    t = pq.read_table(good)
    col = t.column("gyro_y").to_numpy().astype(str).astype(object)
    col[3456] = "1.2.3"
    t = t.set_column(t.schema.get_field_index("gyro_y"), "gyro_y", pa.array(col, pa.string()))
    pq.write_table(t, good, row_group_size=1000)
    with pytest.raises(InputError) as whole:
        read_dataset(good)
    assert "column 'gyro_y'" in str(whole.value) and "row 3457" in str(whole.value)
    assert "non-numeric cell '1.2.3'" in str(whole.value)
    with pytest.raises(InputError) as streamed:
        reduce_parquet(good, window_s=1.0, chunk_rows=999)
    assert str(streamed.value) == str(whole.value)


def test_a_truncated_file_is_refused_in_one_line(tmp_path, capsys, files):
    """A Parquet file cut in the middle (no footer left) and a CSV cut in the middle of a
    row: one line, exit 1, nothing written."""
    data = files["thermonet"][0].read_bytes()
    cut = tmp_path / "cut.parquet"
    cut.write_bytes(data[: len(data) // 2])
    err = _compare(tmp_path, cut, 1000, capsys)[0]
    assert "cut.parquet" in err and "not a readable Parquet file" in err
    text = files["csv"][0].read_text()
    half = text[: len(text) // 2]
    half = half[: half.rindex(",") - 3]
    short = tmp_path / "cut.csv"
    short.write_text(half)
    lines = half.count("\n")
    err = _convert(tmp_path, short, 500, capsys)
    assert "cut.csv" in err and f"row {lines}:" in err and "expected 7 fields" in err, err


def test_time_going_backwards_across_a_chunk_edge(tmp_path, capsys):
    """Row 1,001 (the first of the second 1,000-row chunk) is earlier than row 1,000 of
    the same run: named by file, column, row and file line, as the whole-file reader
    names it, from compare and from convert."""
    runs = _runs()
    t = runs[0].time_s
    runs[0].time_s = np.concatenate([t[:1000], t[1000:] - 0.75])
    csv = _write_csv(tmp_path / "back.csv", runs[:1])
    with pytest.raises(InputError) as whole:
        read_dataset(csv)
    want = str(whole.value)
    assert "column 'time_s', row 1001" in want and "decreasing timestamp" in want
    assert "file line 1002" in want
    assert _compare(tmp_path, csv, 1000, capsys)[0] == f"thermonet: error: {want}"
    assert _convert(tmp_path, csv, 1000, capsys) == f"thermonet: error: {want}"


def test_a_newer_format_version_is_refused_by_both_readers(tmp_path, files):
    path = tmp_path / "v99.parquet"
    table = pq.read_table(files["thermonet"][0])
    blob = json.loads(table.schema.metadata[b"thermonet"])
    blob["version"] = 99
    pq.write_table(table.replace_schema_metadata({"thermonet": json.dumps(blob)}), path)
    with pytest.raises(InputError) as whole:
        read_dataset(path)
    with pytest.raises(InputError) as streamed:
        reduce_parquet(path, window_s=1.0)
    assert str(whole.value) == str(streamed.value)
    assert "format version 99 is newer" in str(whole.value)
    with pytest.raises(InputError, match="format version 99"):
        summarize_parquet(path)


def test_damaged_bytes_are_refused_not_read_as_other_numbers(tmp_path, capsys, files):
    """thermonet writes page checksums and reads them back verified: 256 flipped bytes in the
    middle of a file are one line from the whole-file reader, the streamed one and compare
    (without the checksums pyarrow decodes the damaged page into other numbers)."""
    src = files["thermonet"][0]
    meta = pq.ParquetFile(src).metadata
    assert meta.num_rows == 2 * N
    data = bytearray(src.read_bytes())
    mid = len(data) // 2
    for i in range(mid, mid + 256):
        data[i] ^= 0xFF
    bad = tmp_path / "flipped.parquet"
    bad.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"flipped\.parquet"):
        read_dataset(bad)
    with pytest.raises(InputError, match=r"flipped\.parquet"):
        reduce_parquet(bad, window_s=1.0, chunk_rows=500)
    err = _compare(tmp_path, bad, 500, capsys)[0]
    assert "flipped.parquet" in err
    # a convert's output carries the checksums too
    out = tmp_path / "c.parquet"
    assert main(["convert", str(files["csv"][0]), "--out", str(out)]) == 0
    data = bytearray(out.read_bytes())
    mid = len(data) // 2
    for i in range(mid, mid + 256):
        data[i] ^= 0xFF
    out.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"c\.parquet"):
        read_dataset(out)


def test_plausibility_warnings_of_a_streamed_file_are_the_samples(tmp_path):
    """One absurd sample (a wrong scale, a corrupt cell) and temperatures in Kelvin: the
    warnings of the file streamed into 5 s window means are those of the samples read
    whole, not of the means (which average the spike below the limit)."""
    from thermonet.data.diagnostics import input_warnings

    runs = _runs()
    for r in runs:
        r.temperature_c = r.temperature_c + 273.15
    runs[1].outputs["gyro_y"][1234] = 4e12
    path = _write_csv(tmp_path / "odd.csv", runs)
    want = input_warnings(read_dataset(path))
    assert any("reaches 4e+12" in w for w in want) and any("Kelvin" in w for w in want)
    reduced = reduce_parquet(path, window_s=5.0, chunk_rows=1000)
    assert float(np.abs(reduced[1].outputs["gyro_y"]).max()) < 1e12   # the means hide it
    assert input_warnings(reduced) == want


def test_a_data_digest_refuses_values_that_are_not_those_written(tmp_path, files):
    """thermonet stores the SHA-256 of each float column in the file's key-value metadata:
    a file whose values changed under the same metadata (one valid-looking value; what a
    damaged page header or a tool that kept thermonet's footer could give) is refused by
    both readers, naming the column; the same values rewritten without the digest (another
    tool's rewrite drops it) read as they are."""
    src = files["thermonet"][0]
    meta = pq.read_metadata(src).metadata
    assert b"thermonet.digest" in meta
    table = pq.read_table(src)
    col = table.column("gyro_x").to_numpy().copy()
    col[4444] += 1e-3
    edited = table.set_column(table.schema.get_field_index("gyro_x"), "gyro_x", pa.array(col))
    bad = tmp_path / "edited.parquet"
    with pq.ParquetWriter(bad, edited.schema) as w:
        w.write_table(edited)
        w.add_key_value_metadata({"thermonet.digest": meta[b"thermonet.digest"].decode()})
    with pytest.raises(InputError) as whole:
        read_dataset(bad)
    assert "edited.parquet, column 'gyro_x': data digest mismatch" in str(whole.value)
    with pytest.raises(InputError) as streamed:
        reduce_parquet(bad, window_s=1.0, chunk_rows=1000)
    assert str(streamed.value) == str(whole.value)
    plain = tmp_path / "rewritten.parquet"
    pq.write_table(edited, plain)
    assert read_dataset(plain)[1].outputs["gyro_x"][4444 - N] == col[4444]
