"""The info summary on synthetic recordings with known noise and known drift."""

from __future__ import annotations

import json

import numpy as np
import pytest

from thermonet.core.recording import Dataset, Recording
from thermonet.workflows.info import format_summary, summarize

SLOPE = 0.01  # deg/s per °C


def _run(run_id: str, sigma: float, t0: float, seed: int) -> Recording:
    rng = np.random.default_rng(seed)
    n = 20000
    temp = t0 + 10.0 * np.arange(n) / n  # a 10 °C ramp, uniform in time
    ref = 5.0 * np.sin(np.arange(n) / 50.0)  # turntable rate, removed by drift_observed
    return Recording(time_s=np.arange(n) * 0.1, temperature_c=temp,
                     outputs={"gyro_x": ref + SLOPE * temp + rng.normal(0, sigma, n)},
                     references={"ref_gyro_x": ref}, units={"gyro_x": "deg/s",
                     "temperature_c": "degC", "ref_gyro_x": "deg/s"},
                     run_id=run_id, sample_rate_hz=10.0, meta={"skipped_rows": "4"})


def test_summary_recovers_noise_and_drift():
    ds = Dataset(runs=[_run("a", 0.002, 0.0, 1), _run("b", 0.004, 10.0, 2)],
                 meta={"skipped_rows": "4"})
    s = summarize(ds)
    json.dumps(s)  # JSON-able
    (out,) = s["outputs"]
    # Noise floor per run (0.002, 0.004), averaged; the 1e-5 °C/sample ramp is negligible.
    assert out["noise_floor"] == pytest.approx(0.003, rel=0.03)
    # 1 °C bins over 0..20 °C: bin means 0.01 * (0.5 .. 19.5) -> peak-to-peak 0.19 deg/s.
    assert out["drift_peak_to_peak"] == pytest.approx(SLOPE * 19.0, abs=2e-4)
    assert s["temperature_range_c"] == pytest.approx([0.0, 20.0], abs=1e-3)
    assert [(r["run_id"], r["samples"], r["sample_rate_hz"]) for r in s["runs"]] == \
        [("a", 20000, 10.0), ("b", 20000, 10.0)]
    assert s["runs"][0]["duration_s"] == pytest.approx(1999.9)
    assert s["skipped_rows"] == 4
    roles = {c["name"]: (c["role"], c["unit"]) for c in s["channels"]}
    assert roles == {"time_s": ("time", "s"), "temperature_c": ("temperature", "degC"),
                     "gyro_x": ("output", "deg/s"), "ref_gyro_x": ("reference", "deg/s")}
    text = format_summary(s)
    assert "0.002998" in text and "  0.19" in text and "skipped malformed rows: 4" in text
    assert "0.00..10.00" in text and "10.00..20.00" in text


def test_a_fleets_file_names_each_runs_unit(tmp_path):
    """Runs of several units (a fleet's file, every run called ``run0``): the header counts
    the units, the run table names each run's unit, the drift says it is pooled — streamed or
    not; one unit's file stays as it was."""
    from thermonet.data.io import write_parquet
    from thermonet.workflows.info_chunked import summarize_parquet

    runs = [_run("run0", 0.002, 10.0 * k, k) for k in range(3)]
    for k, r in enumerate(runs):
        r.device_id = f"imu-u{k:03d}"
    write_parquet(Dataset(runs=runs), tmp_path / "fleet.parquet")
    for s in (summarize(Dataset(runs=runs)), summarize_parquet(tmp_path / "fleet.parquet",
                                                               chunk_rows=4096)):
        assert [r["unit"] for r in s["runs"]] == ["imu-u000", "imu-u001", "imu-u002"]
        lines = format_summary(s).splitlines()
        assert lines[0].startswith("3 ") and "units (imu-u000 … imu-u002), 3 run(s)" in lines[0]
        table = [ln.split() for ln in lines if ln.startswith("imu-u")]
        assert [row[:2] for row in table] == [[f"imu-u00{k}", "run0"] for k in range(3)]
        assert any("every unit pooled" in ln for ln in lines)
    one = format_summary(summarize(Dataset(runs=[runs[0]])))
    assert one.startswith("device imu-u000 (") and "pooled" not in one


def test_summary_without_thermometer_reports_proxy():
    rng = np.random.default_rng(3)
    n = 500
    raw = np.linspace(65249.0, 63123.0, n)
    r = Recording(time_s=np.arange(n) / 50.0, temperature_c=None,
                  outputs={"gyro_z": rng.normal(0.0, 0.5, n)}, proxies={"temp_raw": raw},
                  units={"gyro_z": "rad/s", "temp_raw": "counts"}, run_id="tvac")
    s = summarize(Dataset(runs=[r]))
    assert s["temperature_range_c"] is None and s["skipped_rows"] is None
    assert s["runs"][0]["proxies"] == {"temp_raw": [63123.0, 65249.0]}
    assert s["outputs"][0]["drift_peak_to_peak"] is None
    assert s["outputs"][0]["noise_floor"] == pytest.approx(0.5, rel=0.1)
    text = format_summary(s)
    assert "n/a (no °C thermometer; proxy: temp_raw 63123..65249)" in text
    assert "skipped" not in text.splitlines()[-1]
