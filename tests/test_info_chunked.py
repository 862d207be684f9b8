"""``thermonet info`` on a thermonet Parquet file read in chunks equals the summary
of the whole file read into memory, and names a bad value by column and row as the whole-file
reader does."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from thermonet.cli import main
from thermonet.core.errors import InputError
from thermonet.core.recording import Dataset, Recording
from thermonet.data.chunks import iter_run_chunks, open_parquet
from thermonet.data.io import read_dataset, write_parquet
from thermonet.workflows.info import summarize
from thermonet.workflows.info_chunked import summarize_parquet
from tolerances import assert_f64_close

pytestmark = pytest.mark.numerics

SLOPE = 0.01  # deg/s per °C


def _run(run_id: str, sigma: float, t0: float, seed: int, rate: float | None,
         n: int = 5000) -> Recording:
    rng = np.random.default_rng(seed)
    temp = t0 + 10.0 * np.arange(n) / n
    ref = 5.0 * np.sin(np.arange(n) / 50.0)
    t = np.cumsum(rng.uniform(0.05, 0.15, n))   # jittered: the median interval is computed
    return Recording(time_s=t, temperature_c=temp,
                     outputs={"gyro_x": ref + SLOPE * temp + rng.normal(0, sigma, n),
                              "gyro_y": -SLOPE * temp + rng.normal(0, sigma, n)},
                     references={"ref_gyro_x": ref}, proxies={"freq_hz": 1e3 + temp},
                     units={"gyro_x": "deg/s", "gyro_y": "deg/s", "temperature_c": "degC",
                            "ref_gyro_x": "deg/s", "freq_hz": "Hz"},
                     run_id=run_id, sample_rate_hz=rate, meta={"skipped_rows": "2"})


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    ds = Dataset(runs=[_run("a", 0.002, 0.0, 1, 10.0), _run("b", 0.004, 10.0, 2, None),
                       _run("c", 0.003, 30.0, 3, None, n=777)])
    return write_parquet(ds, tmp_path_factory.mktemp("info") / "rec.parquet")


@pytest.mark.parametrize("chunk_rows", [1000, 4999, 65536])
def test_chunked_summary_equals_the_whole_file(recording, chunk_rows):
    want = summarize(read_dataset(recording))
    got = summarize_parquet(recording, chunk_rows=chunk_rows)
    json.dumps(got)
    floats = ("noise_floor", "drift_peak_to_peak")
    if chunk_rows < 4999:   # run 'b' (4,999 intervals, no stored rate): a strided median,
        strided = [r["sample_rate_hz"] for r in (got, want) for r in r["runs"][1:2]]
        assert strided[0] == pytest.approx(strided[1], rel=0.02)   # checked below
        got["runs"][1]["sample_rate_hz"] = want["runs"][1]["sample_rate_hz"]
        got["noise_floor_basis"] = want["noise_floor_basis"]
    for key in want:
        if key != "outputs":
            assert got[key] == want[key], key   # counts, copies, min/max: exact
    for g, w in zip(got["outputs"], want["outputs"], strict=True):
        assert {k: g[k] for k in g if k not in floats} == {k: w[k] for k in w if k not in floats}
        # sums of differences and of bin members merged in another order: float64 rounding
        assert_f64_close([g[k] for k in floats], [w[k] for k in floats], rtol=1e-12)
    assert got["outputs"][0]["noise_floor"] == pytest.approx(0.003, rel=0.05)


def test_runs_without_a_rate_longer_than_the_budget_use_a_strided_median(recording):
    """Run 'b' (5,000 samples, no stored rate) with 1,000-row chunks: every 5th interval,
    whose median is the whole run's within the jitter's sampling error."""
    want = summarize(read_dataset(recording))["runs"][1]["sample_rate_hz"]
    got = summarize_parquet(recording, chunk_rows=1000)["runs"][1]["sample_rate_hz"]
    t = read_dataset(recording)["b"].time_s
    assert got == pytest.approx(1.0 / np.median(np.diff(t)[::5]), rel=1e-12)
    assert got == pytest.approx(want, rel=0.02)   # uniform 0.05..0.15 s: σ(median) ≈ 1 %


def test_pieces_belong_to_one_run_in_file_order(recording):
    layout = open_parquet(recording)
    assert layout is not None and [e["run_id"] for e in layout.runs] == ["a", "b", "c"]
    pieces = list(iter_run_chunks(layout, ["gyro_x"], chunk_rows=1200))
    assert max(len(p[1]) for p in pieces) <= 1200
    rows = np.concatenate([p[1] for p in pieces])
    assert np.array_equal(rows, np.arange(1, 5000 + 5000 + 777 + 1))   # every row once
    whole = read_dataset(recording)
    for i, rid in enumerate(["a", "b", "c"]):
        got = np.concatenate([p[2]["gyro_x"] for p in pieces if p[0] == i])
        np.testing.assert_array_equal(got, whole[rid].outputs["gyro_x"])  # copied values


def _edit(src, dst, column: str, row: int, value: float):
    table = pq.read_table(src)
    col = table.column(column).to_numpy().copy()
    col[row - 1] = value
    table = table.set_column(table.column_names.index(column), column, pa.array(col))
    pq.write_table(table, dst)
    return dst


def test_bad_values_are_named_by_column_and_row(recording, tmp_path):
    t = pq.read_table(recording).column("time_s").to_numpy()
    # a time going back exactly at a chunk edge (row 1001 is the first of the second chunk)
    bad = _edit(recording, tmp_path / "t.parquet", "time_s", 1001, float(t[999]))
    with pytest.raises(InputError, match=r"column 'time_s', row 1001: duplicate timestamp"):
        summarize_parquet(bad, chunk_rows=1000)
    bad = _edit(recording, tmp_path / "n.parquet", "gyro_y", 7000, float("inf"))
    with pytest.raises(InputError, match=r"column 'gyro_y', row 7000: non-finite value inf"):
        summarize_parquet(bad, chunk_rows=1000)


def test_cli_info_streams_a_thermonet_parquet_file(recording, capsys):
    assert main(["info", str(recording), "--json", "--chunk-rows", "1000"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got == json.loads(json.dumps(summarize_parquet(recording, chunk_rows=1000)))
    assert main(["info", str(recording), "--chunk-rows", "0"]) == 1
    assert "--chunk-rows must be >= 1, got 0" in capsys.readouterr().err


def test_a_span_too_small_for_a_model_is_summarised_and_said(tmp_path, capsys):
    """A temperature span below what a model needs: the whole-file reader (what compare
    reads) refuses it in one line; ``info`` summarises the file — checking a file is what it
    is for — and says in a warning what compare would refuse (was: info refused it too)."""
    soak = _run("soak", 0.002, 20.0, 4, 10.0)
    soak.temperature_c = 20.0 + 0.01 * np.sin(np.arange(soak.n_samples) / 100.0)
    path = write_parquet(Dataset(runs=[soak]), tmp_path / "soak.parquet")
    with pytest.raises(InputError) as whole:
        read_dataset(path)
    assert "temperature spans only 0.02 °C over all runs" in str(whole.value)
    got = summarize_parquet(path, chunk_rows=1000)
    assert got["runs"][0]["samples"] == soak.n_samples
    assert got["warnings"][-1] == (
        "the temperature spans only 0.02 °C over all runs: a model needs at least 1 °C "
        "(compare and train refuse these data; load several soaks together)")
    assert main(["info", str(path)]) == 0
    assert "warning: the temperature spans only 0.02 °C" in capsys.readouterr().out


def test_convert_a_csv_once_then_read_it_in_chunks(tmp_path, capsys):
    """CSV → thermonet Parquet (``thermonet convert``), then the chunked summary of the Parquet
    file equals the whole summary of the CSV."""
    rec = _run("r", 0.002, 0.0, 5, None, n=3000)
    csv = tmp_path / "r.csv"
    with csv.open("w") as fh:
        fh.write("time_s,temperature_c,gyro_x,gyro_y,ref_gyro_x,freq_hz\n")
        for k in range(rec.n_samples):
            fh.write(",".join(repr(float(v)) for v in (
                rec.time_s[k], rec.temperature_c[k], rec.outputs["gyro_x"][k],
                rec.outputs["gyro_y"][k], rec.references["ref_gyro_x"][k],
                rec.proxies["freq_hz"][k])) + "\n")
    out = tmp_path / "r.parquet"
    assert main(["convert", str(csv), "--out", str(out)]) == 0
    assert "1 run(s), 3000 samples" in capsys.readouterr().out
    want = summarize(read_dataset(csv))
    got = summarize_parquet(out, chunk_rows=2999)   # two chunks; 2,999 intervals: exact median
    assert got["runs"] == want["runs"] and got["channels"] == want["channels"]
    assert_f64_close([o["noise_floor"] for o in got["outputs"]],
                     [o["noise_floor"] for o in want["outputs"]])
    assert main(["convert", str(csv), "--out", str(out)]) == 1
    assert "already exists (give --overwrite" in capsys.readouterr().err


@pytest.mark.parametrize("group, name", [("outputs", "gyro_z"), ("references", "ref_gyro_y"),
                                         ("proxies", "volts"), ("drift", "drift_gyro_x"),
                                         ("temperature", "temperature_c")])
def test_metadata_naming_a_column_the_file_lacks_is_one_line(recording, tmp_path, capsys,
                                                             group, name):
    """A thermonet file whose metadata lists a channel it does not hold (an edited blob, a
    column dropped by another tool): every reader — the chunked ``info``, ``convert``, the
    whole-file read — names the file, the run and the column in one line, never a KeyError."""
    table = pq.read_table(recording)
    blob = json.loads(table.schema.metadata[b"thermonet"])
    if group == "temperature":
        table = table.drop_columns(["temperature_c"])
    else:
        blob["runs"][1][group] = [*blob["runs"][1][group], name]
    bad = tmp_path / "bad.parquet"
    pq.write_table(table.replace_schema_metadata({b"thermonet": json.dumps(blob)}), bad)
    run = "a" if group == "temperature" else "b"
    line = f"{bad}, column '{name}': missing column (run '{run}' lists it)"
    with pytest.raises(InputError) as whole:
        read_dataset(bad)
    assert str(whole.value) == line
    with pytest.raises(InputError) as chunked:
        summarize_parquet(bad, chunk_rows=1000)
    assert str(chunked.value) == line
    assert main(["info", str(bad)]) == 1
    assert capsys.readouterr().err == f"thermonet: error: {line}\n"
    out = tmp_path / "out.parquet"
    assert main(["convert", str(bad), "--out", str(out)]) == 1
    assert capsys.readouterr().err == f"thermonet: error: {line}\n"
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["bad.parquet"]


def test_units_that_differ_across_files_name_the_file_given(tmp_path, capsys):
    """Two thermonet files whose runs differ in a unit: the message names the file passed
    (was the CSV the Parquet had been converted from, a file the user never gave), streamed
    (``info``) and whole (``read_datasets``); the recorded origin stays in the run's meta."""
    from thermonet.data.io import read_datasets

    files = []
    for name, unit in (("day1", "hPa"), ("day2", "Pa")):
        run = _run(name, 0.01, 10.0 + 20 * len(files), len(files), 10.0, n=200)
        run.units["gyro_y"] = "deg/h" if unit == "Pa" else "deg/s"
        run.meta = {"source": f"/elsewhere/{name}_origin.csv"}
        files.append(write_parquet(Dataset(runs=[run]), tmp_path / f"{name}.parquet"))
    want = (f"{files[1]}, column 'gyro_y': run 'day2' is in 'deg/h', run 'day1' in 'deg/s' "
            "(convert one with a mapping scale)")
    assert main(["info", *map(str, files)]) == 1
    assert capsys.readouterr().err.strip() == f"thermonet: error: {want}"
    with pytest.raises(InputError) as err:
        read_datasets(files)
    assert str(err.value) == want
    assert read_dataset(files[0])[0].meta["source"] == "/elsewhere/day1_origin.csv"
