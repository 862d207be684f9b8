"""Hostile inputs, round three, part A: the torch-free runtime's number parser.

``export/thermonet_runtime.py`` reads a CSV cell as a CSV reader (pandas) reads a numeric
field — a decimal number with an optional exponent, inf/infinity, and pandas' missing-value
spellings as a missing sample — and refuses what no CSV writer means as a number (Python's
literal syntax ``1_000``, other scripts' digits, hex, complex), naming the column and row.
The Python API refuses strings where numbers are meant (``step("1_000", ...)``).
"""

from __future__ import annotations

import csv
import io
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from conftest import RUNTIME, load_runtime
from thermonet.exporting import export_onnx
from thermonet.features.inputs import FeatureSpec
from thermonet.training.train import TrainConfig, fit

AXES = ["gyro_x", "gyro_y"]




rt = load_runtime()

#: Cells a CSV writer means as numbers, and the value each one is.
NUMBERS = {"1": 1.0, "-2": -2.0, "+3": 3.0, "0.5": 0.5, ".5": 0.5, "5.": 5.0, "-.5e-3": -5e-4,
           "1e5": 1e5, "1E+05": 1e5, "2.5e-310": 2.5e-310, "  7 ": 7.0, "\t8": 8.0,
           "0012": 12.0, "1e-400": 0.0, "-0": 0.0}
#: Infinity as pandas reads it.
INFINITIES = {"inf": math.inf, "-inf": -math.inf, "+inf": math.inf, "Inf": math.inf,
              "INF": math.inf, "infinity": math.inf, "-Infinity": -math.inf,
              "+INFINITY": math.inf}
#: A missing sample (NaN): empty, and pandas' default missing-value spellings.
MISSING = ["", "   ", "nan", "NaN", "-nan", "-NaN", "NA", "N/A", "n/a", "NULL", "null", "None",
           "#N/A", "<NA>", "1.#QNAN"]
#: Not numbers: Python's literal syntax and other things no CSV writer means.
REFUSED = ["1_000", "1_0.5", "0x10", "0b1", "0o7", "1e3j", "3+4j", "١٢٣", "１２", "\u00a07",
           "7\u00a0", "\u22121", "1,5", "1e", "e5", "1d3", "1.5f", "nan(1)", "+nan", "NAN",
           "infinit", "Inf.", "--1", "1..2", "hot", "True", "1e400", "-1e400"]


@pytest.mark.parametrize("cell, value", sorted(NUMBERS.items()))
def test_decimal_numbers_are_read_as_pandas_reads_them(cell: str, value: float) -> None:
    got = rt.parse_number(cell)
    np.testing.assert_allclose(got, value, rtol=1e-15, atol=0)
    theirs = pd.read_csv(io.StringIO(f"a,b\n\"{cell}\",1\n"))["a"][0]
    np.testing.assert_allclose(float(theirs), got, rtol=1e-15, atol=0)


@pytest.mark.parametrize("cell, value", sorted(INFINITIES.items()))
def test_infinities_are_read_as_pandas_reads_them(cell: str, value: float) -> None:
    assert rt.parse_number(cell) == value              # exact: ±inf
    assert pd.read_csv(io.StringIO(f"a,b\n{cell},1\n"))["a"][0] == value


@pytest.mark.parametrize("cell", MISSING)
def test_missing_value_spellings_are_a_missing_sample(cell: str) -> None:
    assert math.isnan(rt.parse_number(cell))
    theirs = pd.read_csv(io.StringIO(f"a,b\n\"{cell}\",1\n"))["a"][0]
    assert pd.isna(theirs) or str(theirs).strip() == ""


@pytest.mark.parametrize("cell", REFUSED)
def test_what_no_csv_writer_means_as_a_number_is_refused(cell: str) -> None:
    with pytest.raises(ValueError) as info:
        rt.parse_number(cell)
    assert "\n" not in str(info.value)
    if "e400" not in cell:  # pandas keeps every one of them a string, never a number
        theirs = pd.read_csv(io.StringIO(f"a,b\n\"{cell}\",1\n"), dtype={"a": str})["a"][0]
        assert pd.to_numeric(pd.Series([theirs]), errors="coerce").isna().all()
    else:
        assert "beyond the range of a 64-bit float" in str(info.value)


# ------------------------------------------------------------------ command line
@pytest.fixture(scope="module")
def model_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    temp = np.linspace(-20.0, 60.0, 400)
    drift = np.column_stack([1e-3 * (temp - 25.0), -5e-4 * (temp - 25.0)]) + 0.01
    model = fit(family="poly", inputs=["dT"], outputs=AXES, train=[(temp[:, None], drift)],
                val=None, spec=FeatureSpec(inputs=["dT"], t_ref=25.0), hyper={"degree": 1},
                config=TrainConfig(max_epochs=5)).model
    return export_onnx(model, tmp_path_factory.mktemp("rt") / "lin.onnx",
                       metadata={"output_units": {a: "deg/s" for a in AXES}})


def _cli(model: Path, src: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(RUNTIME), str(model), str(src), "--out", str(out)],
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("cell, column, row", [
    ("1_000", "temperature_c", 3), ("0x1A", "gyro_y", 2), ("  1e3j", "gyro_x", 4),
    ("２５", "temperature_c", 2), ("1e400", "gyro_x", 3), ("infinit", "temperature_c", 4),
])
def test_cli_refuses_python_literals_naming_column_and_row(model_path: Path, tmp_path: Path,
                                                           cell: str, column: str, row: int
                                                           ) -> None:
    rows = [["temperature_c", "gyro_x", "gyro_y"], ["20", "0", "0"], ["21", "0", "0"],
            ["22", "0", "0"]]
    rows[row - 1][rows[0].index(column)] = cell
    src = tmp_path / "in.csv"
    with src.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    proc = _cli(model_path, src, tmp_path / "out.csv")
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    # named as thermonet's readers name a row: the data row, then its file line (header: 1)
    assert f"{src}: column '{column}', row {row - 1} (file line {row}): " in lines[0]
    assert repr(cell.strip(" \t")) in lines[0]
    assert not (tmp_path / "out.csv").exists()


def test_cli_reads_numbers_infinities_and_missing_values_as_a_csv_reader(model_path: Path,
                                                                         tmp_path: Path
                                                                         ) -> None:
    src = tmp_path / "in.csv"
    src.write_text("temperature_c,gyro_x,gyro_y\n"
                   " 25 ,1.0,2.0\n"          # spaces around a number
                   "3.5e1,1,2\n"             # 35 °C
                   "NA,1,2\n"                # missing temperature: NaN drift, flag
                   "Infinity,1,2\n"          # not finite: NaN drift, flag
                   ",1,2\n"                  # empty: missing
                   "25,nan,2\n")             # a missing raw value: NaN compensated only
    out = tmp_path / "out.csv"
    proc = _cli(model_path, src, out)
    assert proc.returncode == 0, proc.stderr
    got = list(csv.DictReader(out.open()))
    assert [r["out_of_range"] for r in got] == ["0", "0", "1", "1", "1", "0"]
    np.testing.assert_allclose(float(got[0]["gyro_x_drift"]), 0.01, atol=1e-6)
    np.testing.assert_allclose(float(got[1]["gyro_x_drift"]), 0.01 + 1e-3 * 10.0, atol=1e-6)
    np.testing.assert_allclose(float(got[1]["gyro_y_comp"]), 2.0 - (0.01 - 5e-4 * 10.0),
                               atol=1e-6)
    for r in got[2:5]:
        assert math.isnan(float(r["gyro_x_drift"])) and math.isnan(float(r["gyro_x_comp"]))
    assert math.isnan(float(got[5]["gyro_x_comp"]))
    np.testing.assert_allclose(float(got[5]["gyro_y_comp"]), 2.0 - 0.01, atol=1e-6)
    # what the runtime writes it reads back: its own output is valid input
    again = _cli(model_path, out, tmp_path / "again.csv")
    assert again.returncode == 1 and "already has output column" in again.stderr


# ------------------------------------------------------------------ Python API
def test_step_and_compensate_refuse_strings_where_numbers_are_meant(model_path: Path) -> None:
    comp = rt.Compensator(model_path)
    raw = [1.0, 2.0]
    for t, temp in (("1_000", 25.0), (0.0, "25"), (b"1", 25.0), (True, 25.0), ([1, 2], 25.0),
                    (None, 25.0)):
        with pytest.raises(rt.RuntimeInputError, match=r"step\(\): input '(time_s|"
                           r"temperature_c)' must be one number"):
            comp.step(t, temp, raw)
    with pytest.raises(rt.RuntimeInputError, match="input 'time_s' has dtype"):
        comp.compensate(temperature_c=[25.0, 26.0], raw=[raw, raw], time_s=["1_000", "2"])
    with pytest.raises(rt.RuntimeInputError, match="input 'temperature_c' has dtype"):
        comp.compensate(temperature_c=["25"], raw=[raw])
    # numbers of any real type are fine
    a = comp.step(np.float32(1.0), np.int64(35), raw)
    b = comp.step(2, 35.0, np.array(raw))
    np.testing.assert_allclose(a.drift, b.drift, rtol=1e-7)
    np.testing.assert_allclose(b.drift, [0.02, 0.005], atol=1e-6)


# ------------------------------------------------------- the output path, named as given
def test_an_out_that_cannot_be_created_is_named_never_its_tmp(model_path: Path,
                                                              tmp_path: Path) -> None:
    """``--out`` in a directory that does not exist, under a file, or a directory itself: one
    line naming the user's path (was the runtime's own ``OUT.tmp``), exit 1, nothing
    written, before the model runs."""
    src = tmp_path / "in.csv"
    src.write_text("temperature_c,gyro_x,gyro_y\n20,0,0\n21,0,0\n")
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    for out, why in ((tmp_path / "no" / "such" / "o.csv",
                      f"cannot be created: its directory {tmp_path / 'no' / 'such'} does not "
                      "exist"),
                     (tmp_path / "afile" / "o.csv",
                      f"cannot be created: its directory {tmp_path / 'afile'} is not a "
                      "directory"),
                     (tmp_path / "adir", "--out is a directory; give a file name")):
        proc = _cli(model_path, src, out)
        assert proc.returncode == 1
        assert proc.stderr.strip().splitlines() == [f"thermonet_runtime: {out}: {why}"]
        assert ".tmp" not in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir", "afile", "in.csv"]
    assert not list((tmp_path / "adir").iterdir())


# ------------------------------------------------------- a band no residual makes
def _with_band(model_path: Path, tmp_path: Path, half: float, growth: float = 0.0,
               holds: Any = None) -> Path:
    """The fixture's model exported again with a band (half-width ``half`` on gyro_y;
    ``holds``: its ``holds_for`` block)."""
    import json

    import onnx

    from thermonet.exporting.onnx_seal import seal_onnx

    band = {"level": 0.9, "signal": "temperature_c", "window_s": 60.0, "axes": {
        a: {"edges": [-20.0, 20.0, 60.0], "half_width": [0.002, half if a == "gyro_y" else
                                                             0.003],
            "growth_below": 0.0, "growth_above": growth if a == "gyro_y" else 0.0}
        for a in AXES}}
    if holds is not None:
        band["holds_for"] = holds
    proto = onnx.load(str(model_path))
    entry = proto.metadata_props.add()
    entry.key, entry.value = "band", json.dumps(band)
    path = tmp_path / f"band-{half:g}-{growth:g}{'-held' * (holds is not None)}.onnx"
    onnx.save_model(proto, str(path))
    seal_onnx(path)
    return path


def test_a_band_no_residual_makes_is_refused_in_one_line(model_path: Path,
                                                         tmp_path: Path) -> None:
    """A re-sealed ONNX whose band half-width is 1e308 (beyond a float32), or a million
    times the model's largest drift over its trained range (here ~0.02 deg/s), or whose
    growth across the trained span is: refused when loaded, naming the file, the axis and
    the value (was: accepted, the band column 1e308).  A plausible band loads."""
    ok = rt.Compensator(_with_band(model_path, tmp_path, 0.004))
    assert ok.band_tables is not None and ok.band(25.0).tolist() == [0.003, 0.004]
    temps = np.linspace(-20.0, 60.0, 257)                 # the trained range
    drift = ok.compensate(temperature_c=temps, raw=np.zeros((temps.size, 2))).drift[:, 1]
    scale = max(float(np.max(np.abs(drift))), float(np.ptp(drift)))   # gyro_y's, ~0.02
    assert 0.01 < scale < 0.05
    for half, growth, what in (
            (1e308, 0.0, "half-width 1e+308 is beyond a float32"),
            (1e4, 0.0, "half-width 1e+04 is"), (0.004, 1e3, "growth_above x the trained "
                                                           "span 8e+04 is")):
        path = _with_band(model_path, tmp_path, half, growth)
        with pytest.raises(rt.RuntimeInputError) as err:
            rt.Compensator(path)
        msg = str(err.value)
        assert msg.startswith(f"{path}: metadata 'band' of 'gyro_y': {what}"), msg
        assert "\n" not in msg and "no residual of this model makes such a band" in msg
        if "float32" not in what:
            ratio = float(msg.split(" is ")[1].split(" times")[0])
            value = half if growth == 0 else growth * 80.0
            assert ratio == pytest.approx(value / scale, rel=1e-2)
            assert f"trained range ({scale:.4g})" in msg


def test_where_the_band_holds_is_the_fit_times_rule_and_a_bad_statement_is_refused(
        model_path: Path, tmp_path: Path) -> None:
    """The runtime's ``band_holds`` gives thermonet's own verdict
    (``scoring.band_rates.outside_holds``) on rates either side of the judged one, both
    signs, NaN (never held) and every direction; a file whose band does not say where it
    holds: True wherever the rate is finite; a judged rate that is negative or not a number:
    refused in one line."""
    from thermonet.scoring.band_rates import outside_holds

    held = {"heating_c_per_min": 0.75, "cooling_c_per_min": None, "meaning": "..."}
    comp = rt.Compensator(_with_band(model_path, tmp_path, 0.004, holds=held))
    rates = np.tile([0.0, 0.5, 0.75, 0.7500001, 2.0, -0.5, -2.0, np.nan], 3)
    dirs = np.repeat([-1, 0, 1], 8)
    want = ~outside_holds({"heating": 0.75, "cooling": None}, rates, dirs)
    assert comp.band_holds(rates, dirs).tolist() == want.tolist()
    # the never-moving ones and heating up to 0.75, each but the NaN rate (unknown: never
    # held)
    assert want.sum() == 7 + 4
    plain = rt.Compensator(_with_band(model_path, tmp_path, 0.004))
    assert plain.band_holds(rates, dirs).tolist() == np.isfinite(rates).tolist()
    # a direction none of the three, or arrays of two shapes: one line (the C function
    # answers 0 for such a direction; tests/test_band.py)
    for rate, direction, why in ((0.5, 2, "direction 2 is not -1 (cooling), 0 (never moved) "
                                           "or +1 (heating)"),
                                 (0.5, "heating", "rate_c_per_min and direction must be "
                                                  "numbers (or arrays of one shape)"),
                                 ([0.5, 1.5], [-1, 1, 0], "rate_c_per_min and direction must "
                                                          "be numbers (or arrays of one shape)")):
        with pytest.raises(rt.RuntimeInputError) as err:
            comp.band_holds(rate, direction)
        assert str(err.value) == f"band_holds: {why}"
    assert not rt.band_holds_rule(held, 0.5, 2)      # the rule itself: outside, as C says
    for bad in ({"heating_c_per_min": -1.0}, {"cooling_c_per_min": "fast"}, [0.5]):
        path = _with_band(model_path, tmp_path, 0.004, holds=bad)
        with pytest.raises(rt.RuntimeInputError) as err:
            rt.Compensator(path)
        assert str(err.value) == (f"{path}: metadata 'band' key 'holds_for' is not a rate >= 0 "
                                  "or null per direction (heating_c_per_min, cooling_c_per_min)")
