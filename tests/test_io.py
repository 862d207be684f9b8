"""Parquet round trip, native CSV/Parquet, bad-input messages, atomic writes."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from thermonet.core.errors import InputError
from thermonet.core.recording import Dataset, Recording
from thermonet.data.io import read_dataset, read_datasets, write_parquet


def _dataset() -> Dataset:
    rng = np.random.default_rng(0)
    n = 200
    t = np.arange(n) * 0.1 + 1e-7 * rng.random(n)  # awkward floats: exactness matters
    temp = np.linspace(-10.0, 40.0, n)
    a = Recording(time_s=t, temperature_c=temp,
                  outputs={"gyro_x": 0.003 * temp + rng.normal(0, 0.01, n),
                           "gyro_y": rng.normal(0, 0.01, n)},
                  references={"ref_gyro_x": np.full(n, 10.0)},
                  drift={"drift_gyro_x": 0.003 * temp},
                  proxies={"freq_hz": 4517.0 + 0.4 * temp},
                  units={"time_s": "s", "temperature_c": "degC", "gyro_x": "deg/s",
                         "gyro_y": "deg/s", "ref_gyro_x": "deg/s", "drift_gyro_x": "deg/s",
                         "freq_hz": "Hz"},
                  device_id="hrg-7", sensor_kind="gyro", run_id="soak_a", sample_rate_hz=10.0,
                  meta={"preset": "hrg", "seed": "0"})
    # run b lacks the reference and drift channels: they are null in its Parquet rows
    b = Recording(time_s=t[:50] + 1000.0, temperature_c=np.linspace(40.0, 60.0, 50),
                  outputs={"gyro_x": rng.normal(0, 1, 50), "gyro_y": rng.normal(0, 1, 50)},
                  proxies={"freq_hz": np.linspace(4517.0, 4525.0, 50)},
                  units={"gyro_x": "deg/s", "freq_hz": "Hz"},
                  device_id="hrg-7", sensor_kind="gyro", run_id="soak b/ü", meta={})
    return Dataset(runs=[a, b], meta={"study": "001"})


def _bits(x: np.ndarray) -> bytes:
    return np.ascontiguousarray(x, dtype=np.float64).tobytes()


def test_parquet_round_trip_is_lossless(tmp_path):
    ds = _dataset()
    path = write_parquet(ds, tmp_path / "rec.parquet")
    back = read_dataset(path)
    assert back.meta == {"study": "001"}
    assert back.run_ids == ["soak_a", "soak b/ü"]
    for r0, r1 in zip(ds, back, strict=True):
        assert _bits(r0.time_s) == _bits(r1.time_s)
        for group in ("outputs", "references", "drift", "proxies"):
            g0, g1 = getattr(r0, group), getattr(r1, group)
            assert list(g0) == list(g1)
            assert all(_bits(g0[k]) == _bits(g1[k]) for k in g0)
        assert (r0.temperature_c is None) == (r1.temperature_c is None)
        if r0.temperature_c is not None:
            assert _bits(r0.temperature_c) == _bits(r1.temperature_c)
        assert (r1.units, r1.meta, r1.device_id, r1.sensor_kind, r1.sample_rate_hz) == \
            (r0.units, r0.meta, r0.device_id, r0.sensor_kind, r0.sample_rate_hz)
    # One stacked table: run b, without reference and drift, has nulls there, not fake values.
    table = pd.read_parquet(path)
    assert len(table) == 250 and table["ref_gyro_x"].isna().sum() == 50
    assert table["drift_gyro_x"].isna().sum() == 50 and table["temperature_c"].notna().all()
    assert set(table["run"]) == {"soak_a", "soak b/ü"}


def test_native_csv_without_mapping(tmp_path):
    n = 40
    t = np.arange(n) * 0.5
    temp = 20.0 + 0.25 * t
    df = pd.DataFrame({"time_s": t, "temperature_c": temp, "gyro_x": 0.01 * temp - 0.2,
                       "ref_gyro_x": np.ones(n), "freq_hz": 4517 + 0.4 * temp})
    path = tmp_path / "chamber_run3.csv"
    df.to_csv(path, sep=";", index=False)  # separator is sniffed, not assumed
    ds = read_dataset(path)
    r = ds[0]
    assert ds.run_ids == ["chamber_run3"]
    np.testing.assert_allclose(r.temperature_c, temp, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.drift_observed("gyro_x"), 0.01 * temp - 1.2, atol=1e-12)
    assert r.proxies.keys() == {"freq_hz"}
    assert r.units == {"time_s": "s", "temperature_c": "degC", "gyro_x": "deg/s",
                       "ref_gyro_x": "deg/s", "freq_hz": "Hz"}
    assert r.effective_rate_hz == pytest.approx(2.0)


def test_a_csv_keeps_the_device_id_and_names_the_units_it_cannot_carry(tmp_path):
    """``write_csv`` (``convert``/``simulate --out x.csv``): the device id is a ``device``
    column the reader takes back (was lost to 'device'); a channel in a unit other than its
    default is named in one warning — read back it would be in the default unit (rad/s as
    deg/s: 57x off) — and the file is written (the runtime's CSV is in the model's units)."""
    from thermonet.data.io import write_csv

    ds = Dataset(runs=[_dataset()[0]])         # one run: run b's empty cells read as errors
    back = read_dataset(write_csv(ds, tmp_path / "same.csv"))
    assert back.unit_ids == ["hrg-7"] and back.run_ids == ["soak_a"]
    np.testing.assert_array_equal(back["soak_a"].outputs["gyro_x"], ds["soak_a"].outputs["gyro_x"])
    assert back["soak_a"].units["gyro_x"] == "deg/s"
    rad = Dataset(runs=[_dataset()[0]])
    rad[0].units["gyro_y"] = "rad/s"
    with pytest.warns(UserWarning) as got:
        write_csv(rad, tmp_path / "rad.csv")
    assert [str(w.message) for w in got] == [
        f"{tmp_path / 'rad.csv'}: a CSV carries no units: gyro_y in rad/s (read back as "
        "deg/s); read it with a mapping that names the units, or write Parquet (it keeps them)"]
    assert read_dataset(tmp_path / "rad.csv")[0].units["gyro_y"] == "deg/s"


def test_native_tsv_with_run_column_and_foreign_parquet(tmp_path):
    n = 30
    df = pd.DataFrame({"run": ["cold"] * n + ["hot"] * n,
                       "time_s": np.r_[np.arange(n), np.arange(n)] * 1.0,
                       "temperature_c": np.r_[np.full(n, -10.0), np.full(n, 50.0)],
                       "acc_z": np.r_[np.full(n, 1.001), np.full(n, 0.998)]})
    df.to_csv(tmp_path / "two.tsv", sep="\t", index=False)
    ds = read_dataset(tmp_path / "two.tsv")
    assert ds.run_ids == ["cold", "hot"]
    assert ds["hot"].outputs["acc_z"][0] == 0.998 and ds["hot"].units["acc_z"] == "g"
    assert ds[0].sensor_kind == "acc"
    # A Parquet file without thermonet metadata but with the conventional names.
    df.drop(columns="run").iloc[:n].assign(temperature_c=np.linspace(0, 5, n)).to_parquet(
        tmp_path / "plain.parquet")
    plain = read_dataset(tmp_path / "plain.parquet")
    assert plain.run_ids == ["plain"] and plain[0].n_samples == n
    assert plain[0].temperature_c[-1] == 5.0


def test_read_datasets_one_run_per_file(tmp_path):
    for name, t0 in (("a", 10.0), ("b", 30.0)):
        pd.DataFrame({"time_s": np.arange(20.0), "temperature_c": np.full(20, t0),
                      "gyro_z": np.full(20, t0 / 100)}).to_csv(tmp_path / f"{name}.csv",
                                                               index=False)
    ds = read_datasets([tmp_path / "a.csv", tmp_path / "b.csv"])
    assert ds.run_ids == ["a", "b"] and ds["b"].outputs["gyro_z"][0] == 0.3
    with pytest.raises(InputError, match=r"a\.csv.*temperature spans only 0 °C"):
        read_dataset(tmp_path / "a.csv")


def _write(tmp_path, text: str, name: str = "bad.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _good_rows(n: int = 12, start: int = 0) -> list[str]:
    return [f"{i},{20 + i},{0.1 * i}" for i in range(start, start + n)]


HEADER = "time_s,temperature_c,gyro_x"


@pytest.mark.parametrize("rows, pattern", [
    # Data row k is file line k + 1 (the header is line 1).
    (lambda r: r[:4] + ["4,24,abc"] + r[5:],
     r"bad\.csv, column 'gyro_x', row 5: non-numeric cell 'abc' \(file line 6\)"),
    (lambda r: r[:6] + ["6,26,nan"] + r[7:],
     r"column 'gyro_x', row 7: non-finite value 'nan' \(file line 8\)"),
    (lambda r: r[:2] + ["2,inf,0.2"] + r[3:],
     r"column 'temperature_c', row 3: non-finite value 'inf'"),
    (lambda r: r[:3] + ["3,23,"] + r[4:], r"column 'gyro_x', row 4: empty cell"),
    (lambda r: r[:8] + ["7,28,0.8"] + r[9:],
     r"column 'time_s', row 9: duplicate timestamp 7\.0 s after 7\.0 s"),
    (lambda r: r[:8] + ["2,28,0.8"] + r[9:],
     r"column 'time_s', row 9: decreasing timestamp 2\.0 s"),
    (lambda r: r[:3] + ["3,23"] + r[4:], r"row 4: expected 3 fields, found 2 \(file line 5;"),
    (lambda r: r[:5], r"bad\.csv, run 'bad': too few samples: 5"),
])
def test_bad_rows_name_file_column_row(tmp_path, rows, pattern):
    path = _write(tmp_path, "\n".join([HEADER] + rows(_good_rows())) + "\n")
    with pytest.raises(InputError, match=pattern):
        read_dataset(path)


def test_bad_files(tmp_path):
    with pytest.raises(InputError, match=r"nope\.csv: file not found"):
        read_dataset(tmp_path / "nope.csv")
    dup = _write(tmp_path, "\n".join(["time_s,gyro_x,gyro_x"] + _good_rows()), "dup.csv")
    with pytest.raises(InputError, match=r"dup\.csv, column 'gyro_x': duplicate column"):
        read_dataset(dup)
    foreign = _write(tmp_path, "\n".join(["t,T,g"] + _good_rows()), "foreign.csv")
    with pytest.raises(InputError, match=r"foreign\.csv: columns are not thermonet's "
                       r"conventional names .*found t, T, g\); describe the file with a mapping"):
        read_dataset(foreign)
    odd = _write(tmp_path, "\n".join([HEADER] + _good_rows()), "log.dat")
    with pytest.raises(InputError, match=r"log\.dat: unknown file type '\.dat'"):
        read_dataset(odd)
    flat = _write(tmp_path, "\n".join([HEADER] + [f"{i},20.5,0.1" for i in range(20)]),
                  "flat.csv")
    with pytest.raises(InputError, match=r"flat\.csv, column 'temperature_c': temperature "
                       r"spans only 0 °C"):
        read_dataset(flat)
    with pytest.raises(InputError, match=r"not a readable Parquet file"):
        read_dataset(_write(tmp_path, "not parquet", "x.parquet"))


def test_parquet_bad_units_and_nan_rows(tmp_path):
    ds = _dataset()
    ds[0].units["gyro_x"] = "deg/sec"
    with pytest.raises(InputError, match=r"column 'gyro_x': unknown unit 'deg/sec'"):
        write_parquet(ds, tmp_path / "u.parquet")
    ds = _dataset()
    path = write_parquet(ds, tmp_path / "ok.parquet")
    raw = pq.read_table(path)
    col = raw.column("gyro_y").to_numpy().copy()
    col[17] = np.nan
    bad = raw.set_column(raw.column_names.index("gyro_y"), "gyro_y", pa.array(col))
    pq.write_table(bad.replace_schema_metadata(raw.schema.metadata), tmp_path / "nan.parquet")
    with pytest.raises(InputError, match=r"nan\.parquet, column 'gyro_y', row 18: non-finite"):
        read_dataset(tmp_path / "nan.parquet")


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    ds = _dataset()
    ds[1].meta["calibration"] = np.arange(3)  # not storable: fails mid-write
    target = tmp_path / "out.parquet"
    with pytest.raises(InputError, match=r"run 'soak b/ü' meta: key 'calibration'"):
        write_parquet(ds, target)
    assert list(tmp_path.iterdir()) == []
    # A good earlier file survives a failed overwrite unchanged.
    good = write_parquet(_dataset(), target)
    before = good.read_bytes()
    with pytest.raises(InputError):
        write_parquet(ds, target)
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.parquet"]
    # A directory where the file should go is refused before anything is written.
    (tmp_path / "dir.parquet").mkdir()
    with pytest.raises(InputError, match="is a directory"):
        write_parquet(_dataset(), tmp_path / "dir.parquet")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.parquet", "out.parquet"]


def test_a_dataset_prints_one_line_per_run_not_its_arrays():
    """``print(thermonet.read(...))`` said every array of every run (a new user's pass)."""
    ds = _dataset()
    text = repr(ds)
    assert text.splitlines()[0] == f"Dataset({len(ds)} runs"
    assert len(text.splitlines()) == len(ds) + 1 and "array(" not in text
    first = ds[0]
    assert repr(first).startswith(f"Recording(run '{first.run_id}' of unit "
                                  f"'{first.device_id}', {first.n_samples} samples")


def test_convert_to_csv_writes_the_units_it_is_read_back_in(tmp_path, capsys):
    """``thermonet convert --out x.csv`` of a channel in a non-default unit (hPa: read back
    as Pa, 100x off before) writes it in the default unit and says so in one line; a unit
    with no known conversion (a proxy in Pa) is refused in one line, nothing written."""
    from thermonet.cli import main

    n = 40
    src = tmp_path / "lab.csv"
    src.write_text("t;temp;gx;p\n" + "".join(
        f"{10.0 * i};{10 + 0.5 * i};{0.01 * i};{1012.5 + 0.1 * i}\n" for i in range(n)))
    mapping = tmp_path / "m.yaml"
    mapping.write_text("time: {column: t, unit: s}\nchannels:\n  temperature_c: {column: temp}\n"
                       "  gyro_x: {column: gx, unit: rad/s}\n  baro_p: {column: p, unit: hPa}\n")
    out = tmp_path / "x.csv"
    assert main(["convert", str(src), "--mapping", str(mapping), "--out", str(out)]) == 0
    said = capsys.readouterr().out.splitlines()
    assert said[0] == (f"{out}: written in the default units a CSV is read back in: "
                       "gyro_x rad/s -> deg/s, baro_p hPa -> Pa")
    back = read_dataset(out)[0]
    assert back.units["baro_p"] == "Pa" and back.units["gyro_x"] == "deg/s"
    np.testing.assert_allclose(back.outputs["baro_p"], 100 * (1012.5 + 0.1 * np.arange(n)),
                               rtol=1e-15)
    np.testing.assert_allclose(back.outputs["gyro_x"], np.degrees(0.01 * np.arange(n)),
                               rtol=1e-15)
    mapping.write_text(mapping.read_text() + "  p_raw: {column: p, unit: Pa, proxy: true}\n")
    bad = tmp_path / "y.csv"
    assert main(["convert", str(src), "--mapping", str(mapping), "--out", str(bad)]) == 1
    assert capsys.readouterr().err.strip() == (
        f"thermonet: error: {bad}, column 'p_raw': p_raw is in 'Pa', which has no conversion "
        "to 'counts', the unit a CSV (it carries none) is read back in: write a .parquet file "
        "instead (it keeps the units)")
    assert not bad.exists()
