"""The two real recordings load with the shipped mappings and match their SOURCE.txt."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thermonet.core.errors import InputError
from thermonet.data.io import read_dataset, read_datasets

REPO = Path(__file__).resolve().parents[1]
REAL = Path(__file__).resolve().parent / "data" / "real"  # copied in, with licences
PAN = REAL / "pan_tvac_gyro" / "TVCtest3_7_20.csv"
BMI = [REAL / "bmi270_two_soaks" / "BMI_270_cold_test_.csv",
       REAL / "bmi270_two_soaks" / "BMI_270_hot_test.csv"]
MAPS = REPO / "configs" / "data"


def test_pan_tvac_gyro_matches_source():
    ds = read_dataset(PAN, MAPS / "pan_tvac_gyro.yaml")
    r = ds["tvac_2020-03-07"]
    assert r.n_samples == 6250 and r.temperature_c is None
    assert r.units["gyro_x"] == "rad/s" and r.units["temp_raw"] == "counts"
    assert r.outputs.keys() == {"gyro_x", "gyro_y", "gyro_z"}
    # 25 bursts of 250 samples at 50 Hz, one every ~305 s, 7325 s in all.
    gaps = np.flatnonzero(np.diff(r.time_s) > 1.0)
    assert gaps.size == 24 and np.all(np.diff(np.r_[-1, gaps, 6249]) == 250)
    np.testing.assert_allclose(np.diff(r.time_s[gaps]), 305.0, atol=1.0)
    assert r.duration_s == pytest.approx(7324.61, abs=1e-6)
    assert r.effective_rate_hz == pytest.approx(50.0, rel=1e-6)
    # Raw thermometer counts 65249 -> 63123 while cooling.
    raw = r.proxies["temp_raw"]
    assert (raw.max(), raw.min()) == (65249.0, 63123.0)
    assert raw[:250].mean() > raw[-250:].mean() + 2000
    # First row: gyrox -6.53E-02 rad/s, halved by the driver correction.
    assert r.outputs["gyro_x"][0] == pytest.approx(-0.03265, abs=1e-12)
    assert r.time_s[0] == pytest.approx(15.352, abs=1e-12)


def test_pan_tvac_gyro_approximate_celsius():
    r = read_dataset(PAN, MAPS / "pan_tvac_gyro_celsius.yaml")[0]
    # The linear counts->degC fit brackets the thermocouple's 21.5 -> 8.8 degC within ~1.5.
    assert 20.0 < r.temperature_c.max() < 23.5 and 7.0 < r.temperature_c.min() < 10.0
    assert np.corrcoef(r.temperature_c, r.proxies["temp_raw"])[0, 1] == pytest.approx(1.0)


def test_bmi270_two_soaks_match_source():
    ds = read_datasets(BMI, MAPS / "bmi270.yaml")
    cold, hot = ds["BMI_270_cold_test_"], ds["BMI_270_hot_test"]
    # SOURCE: cold 3255 rows, hot 6533 rows; the malformed rows are the extra lines.
    assert (cold.n_samples, hot.n_samples) == (3255, 6533)
    assert (cold.meta["skipped_rows"], hot.meta["skipped_rows"]) == ("2", "3")
    assert ds.meta["skipped_rows"] == "5"
    assert cold.temperature_c.min() == pytest.approx(12.98, abs=0.01)
    assert cold.temperature_c.max() == pytest.approx(13.30, abs=0.01)
    assert hot.temperature_c.min() == pytest.approx(47.2, abs=0.05)
    assert hot.temperature_c.max() == pytest.approx(49.4, abs=0.05)
    # 50 Hz: ~65 s and ~131 s.
    assert cold.duration_s == pytest.approx(65.1, abs=0.2)
    assert hot.duration_s == pytest.approx(130.7, abs=0.2)
    # x4.0 makes the static accelerometer read 1 g in either orientation.
    for r in (cold, hot):
        g = np.sqrt(sum(r.outputs[f"acc_{a}"] ** 2 for a in "xyz"))
        assert np.median(g) == pytest.approx(1.0, abs=0.05)
        assert r.units["gyro_x"] == "deg/s"
        assert np.median(np.abs(r.outputs["gyro_y"])) < 1.5  # a static gyro, deg/s


def test_bmi270_cold_alone_has_no_thermal_span():
    with pytest.raises(InputError, match=r"BMI_270_cold_test_\.csv, column 'temperature_c': "
                       r"temperature spans only 0\.314 °C over all runs"):
        read_dataset(BMI[0], MAPS / "bmi270.yaml")


def test_bmi270_configs_comment_says_what_its_comparison_does(tmp_path, monkeypatch):
    """configs/bmi270.yaml's header says what ``thermonet compare`` on it prints and
    decides: both families fitted, the cubic held back (soaks: no excursion to hold out,
    interleaved blocks) and the baseline line chosen (it promised 'which families cannot be
    fitted', which the comparison never says: both fit)."""
    import thermonet

    config = REPO / "configs" / "bmi270.yaml"
    head = "".join(line[1:] for line in config.read_text().splitlines(keepends=True)
                   if line.startswith("#"))
    monkeypatch.chdir(REPO)                                     # its data paths are relative
    res = thermonet.compare(config, out=tmp_path / "b", plots=False)
    data = res.results
    assert {f: r["status"] for f, r in data["families"].items()} == {"linear": "ok",
                                                                      "cubic": "ok"}
    assert data["selection"]["held_back"]["candidates"] == ["cubic"]
    assert data["chosen"] == data["baseline"] == "linear"
    assert "cannot be fitted" not in head
    assert "'held back: cubic'" in " ".join(head.split()) and "interleaved time blocks" in \
        " ".join(head.split())
