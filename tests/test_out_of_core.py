"""Recordings larger than memory: a thermonet Parquet file streamed in chunks and
reduced to window means (:mod:`thermonet.features.windows`) gives the rows the whole array
gives, and a comparison on those rows agrees with the comparison on the samples.

Independent expectations: the whole file read into memory and averaged by
:func:`thermonet.training.train.average_windows` (what every fit does); sums of squares
computed per window straight from the samples; :func:`thermonet.scoring.axis_metrics.axis_metrics`
on the samples; the in-memory ``thermonet compare`` of the same file.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from thermonet.cli import main
from thermonet.core.errors import ConfigError, InputError
from thermonet.core.recording import GAP_FACTOR, Dataset, Recording
from thermonet.data.io import read_dataset, write_parquet
from thermonet.features.inputs import signal_matrix
from thermonet.features.windows import reduce_parquet
from thermonet.scoring.axis_metrics import axis_metrics, window_axis_metrics
from thermonet.training.checkpoint import load_checkpoint
from thermonet.training.config import config_from_mapping
from thermonet.training.train import average_windows
from thermonet.workflows.compare_plan import load_compare_data
from tolerances import assert_f64_close

pytestmark = pytest.mark.numerics

INPUTS = ["dT", "rate", "lag_300", "play_0.5"]
SIGNALS = ["temperature_c", "rate_c_per_min", "lag_300_c", "play_0.5_c"]


def _run(run_id: str, rate_hz: float, seconds: float, seed: int, gap: tuple[float, float] | None
         ) -> Recording:
    """A warming and cooling run with a reference on gyro_x and, optionally, a gap."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate_hz) + 1000.0 * seed
    if gap is not None:
        t = t[(t < t[0] + gap[0]) | (t >= t[0] + gap[1])]
    n = t.size
    x = (t - t[0]) / seconds
    temp = 20.0 + 30.0 * np.sin(np.pi * x) + rng.normal(0, 0.02, n)
    ref = 2.0 * np.sin(t / 37.0)
    return Recording(time_s=t, temperature_c=temp,
                     outputs={"gyro_x": ref + 0.01 * (temp - 20) + rng.normal(0, 0.003, n),
                              "gyro_y": 1e-4 * (temp - 20) ** 2 + rng.normal(0, 0.002, n)},
                     references={"ref_gyro_x": ref},
                     units={"gyro_x": "deg/s", "gyro_y": "deg/s", "ref_gyro_x": "deg/s",
                            "temperature_c": "degC"},
                     run_id=run_id)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    ds = Dataset(runs=[_run("a", 20.0, 1800.0, 1, (600.0, 660.0)),
                       _run("b", 10.0, 1500.0, 2, None)])
    return write_parquet(ds, tmp_path_factory.mktemp("ooc") / "rec.parquet")


@pytest.mark.parametrize("chunk_rows", [997, 65536])
def test_streamed_windows_equal_the_whole_array_averaged(recording, chunk_rows):
    """Every row (time, temperature, dynamic inputs, drift), the counts and the sums of
    squares inside each window: as the whole file in memory gives them, whatever the chunk
    (997 rows cut windows, dynamic-input scans and the gap at every chunk edge)."""
    reduced = reduce_parquet(recording, window_s=2.0, inputs=INPUTS, chunk_rows=chunk_rows)
    whole = read_dataset(recording)
    gap = GAP_FACTOR * float(np.median(np.diff(whole[0].time_s)))  # "auto": the first run
    for rec, red in zip(whole, reduced, strict=True):
        assert red.windows is not None and red.windows.gap_s == pytest.approx(gap, rel=1e-12)
        sig = signal_matrix(rec, SIGNALS, gap)
        y = np.column_stack([rec.drift_observed(a) for a in rec.outputs])
        want_sig, want_y, want_t = average_windows(sig, y, rec.time_s, 2.0)
        got_sig = signal_matrix(red, SIGNALS, gap)
        got_y = np.column_stack([red.drift_observed(a) for a in red.outputs])
        assert got_sig.shape == want_sig.shape
        scale = np.abs(want_sig).max(axis=0)
        # rate and lag: float64 rounding of the signal (the blocked scans, test_dynamics)
        assert_f64_close(got_sig, want_sig, rtol=0, atol=float(scale.max()) * 1e-12)
        assert_f64_close(got_y, want_y, rtol=0, atol=float(np.abs(want_y).max()) * 1e-12)
        assert_f64_close(red.time_s, want_t, rtol=1e-15)
        n = red.windows.n
        assert int(n.sum()) == rec.n_samples == red.windows.source_samples
        # the samples of each window, cut by the counts: sums of squares about their mean
        for j, axis in enumerate(rec.outputs):
            pieces = np.split(y[:, j], np.cumsum(n)[:-1].astype(int))
            ss = np.array([((p - p.mean()) ** 2).sum() for p in pieces])
            assert_f64_close(red.windows.ss[axis], ss, rtol=1e-9,
                             atol=float(ss.max()) * 1e-12)
            assert_f64_close([p.mean() for p in pieces], got_y[:, j], rtol=0,
                             atol=float(np.abs(got_y).max()) * 1e-12)
        # an output with a reference keeps the output's own spread too (at-t-ref targets)
        out = np.split(rec.outputs["gyro_x"], np.cumsum(n)[:-1].astype(int))
        assert_f64_close(red.windows.ss_output["gyro_x"],
                         [((p - p.mean()) ** 2).sum() for p in out], rtol=1e-9)


def test_max_rows_widens_the_windows(recording):
    """Over ``max_rows`` the windows widen to fit (the rows of a long recording stay bounded);
    the counts still add up to every sample."""
    whole = read_dataset(recording)
    span = sum(float(r.time_s[-1] - r.time_s[0]) for r in whole)
    reduced = reduce_parquet(recording, window_s=1.0, max_rows=1000)
    rows = sum(r.n_samples for r in reduced)
    assert reduced[0].windows is not None
    assert reduced[0].windows.window_s == pytest.approx(span / 1000, rel=1e-12)
    assert rows <= 1000 + 2 * len(whole)        # + a partial window at each run end and gap
    assert [int(r.windows.n.sum()) for r in reduced if r.windows is not None] == \
        [r.n_samples for r in whole]


def test_window_metrics_are_the_samples_metrics(recording):
    """rms and msd of the raw error over the samples, from the rows alone, to rounding; the
    residual's within the bound that the drift's move inside a window sets; the noise floor
    as the first differences estimate it for white noise."""
    rec = read_dataset(recording)[1]
    window = 1.0
    red = reduce_parquet(recording, window_s=window)[1]
    assert red.windows is not None
    slope = 0.01                          # deg/s per °C: the simulated drift of gyro_x
    raw = rec.drift_observed("gyro_x")
    want = axis_metrics(bin_by=rec.temperature_c, time_s=rec.time_s, raw=raw,
                        reference=np.zeros_like(raw),
                        predicted_drift=slope * (rec.temperature_c - 20.0), rate_hz=10.0)
    got = window_axis_metrics(bin_by=red.temperature_c, raw=red.drift_observed("gyro_x"),
                              predicted_drift=slope * (red.temperature_c - 20.0),
                              weight=red.windows.n, within_ss=red.windows.ss["gyro_x"],
                              rate_hz=1.0 / window)
    assert got["rms_raw"] == pytest.approx(want["rms_raw"], rel=1e-10)
    assert got["msd_raw"] == pytest.approx(want["msd_raw"], rel=1e-10)
    # The rows take the residual's spread inside a window for the raw error's: too large by
    # the drift's own spread there, a ramp of slope × dT/dt × window (std: range / √12) plus
    # the thermometer's noise through the slope, against the white noise σ (0.003).
    ramp = slope * (30.0 * np.pi / 1500.0) * window / 12 ** 0.5   # run b: 30 sin(πt/1500 s)
    excess = (ramp ** 2 + (slope * 0.02) ** 2) / 0.003 ** 2
    assert excess < 0.02                     # the bound is a small correction here
    assert want["rms_comp"] <= got["rms_comp"] <= want["rms_comp"] * (1 + excess)
    # With the co-moments of temperature and target inside each window and the model's
    # slope (0.01, exact: the model is linear), the residual's spread inside a window is
    # exact: S_rr = S_yy − 2 J S_Ty + J² S_TT, even over 5 s windows of a fast ramp
    for window in (1.0, 5.0):
        red = reduce_parquet(recording, window_s=window)[1]
        win = red.windows
        assert win is not None and win.sxx is not None and win.signal_names[0] == "temperature_c"
        s_rr = win.ss["gyro_x"] - 2 * slope * win.sxd["gyro_x"][:, 0] \
            + slope ** 2 * win.sxx[:, 0, 0]
        exact = window_axis_metrics(bin_by=red.temperature_c, raw=red.drift_observed("gyro_x"),
                                    predicted_drift=slope * (red.temperature_c - 20.0),
                                    weight=win.n, within_ss=win.ss["gyro_x"],
                                    within_ss_comp=s_rr, rate_hz=1.0 / window)
        assert exact["rms_comp"] == pytest.approx(want["rms_comp"], rel=1e-9)
        assert exact["msd_comp"] == pytest.approx(want["msd_comp"], rel=1e-9)
    assert got["noise_floor"] == pytest.approx(want["noise_floor"], rel=0.05)
    assert got["pp_raw"] == pytest.approx(want["pp_raw"], rel=0.05)


def _config(path: Path, limit: int, tmp: Path) -> Path:
    cfg = {"data": {"paths": [str(path)], "in_memory_samples": limit, "chunk_rows": 4093},
           "features": {"t_ref": 25.0},
           "families": [{"name": "cubic", "family": "poly", "inputs": ["dT"],
                         "params": {"degree": 3}},
                        {"name": "linear", "family": "linear", "inputs": ["dT"]},
                        {"name": "poly2-rate", "family": "poly", "inputs": ["dT", "rate"],
                         "params": {"degree": 2}}],
           "baseline": "cubic", "tracking": {"enabled": False}}
    out = tmp / f"cfg_{limit}.yaml"
    out.write_text(yaml.safe_dump(cfg))
    return out


@pytest.fixture(scope="module")
def two_comparisons(tmp_path_factory):
    """One simulated chamber test (patent-gyro, 4 runs at 2 Hz) compared in memory and
    streamed in 4,093-row chunks."""
    from thermonet.sim import simulate

    tmp = tmp_path_factory.mktemp("ooc_cmp")
    data = write_parquet(simulate("patent-gyro", runs=4, seed=3, sample_rate_hz=2.0),
                         tmp / "pg.parquet")
    docs = {}
    for mode, limit in (("memory", 10**9), ("streamed", 0)):
        rc = main(["compare", str(_config(data, limit, tmp)), "--out", str(tmp / mode), "-q",
                   "--no-track"])
        assert rc == 0
        docs[mode] = json.loads((tmp / mode / "results.json").read_text())
    return tmp, docs


def test_streamed_comparison_agrees_with_the_in_memory_one(two_comparisons):
    tmp, docs = two_comparisons
    mem, st = docs["memory"], docs["streamed"]
    assert "streamed" not in mem["data"]
    assert st["data"]["streamed"]["samples"] == sum(r["samples"] for r in mem["data"]["runs"])
    assert st["data"]["streamed"]["window_s"] == 1.0
    assert st["chosen"] == mem["chosen"]
    assert "streamed: " in (tmp / "streamed" / "report.html").read_text(encoding="utf-8")
    assert st["data"]["runs"][0]["rows"] < st["data"]["runs"][0]["samples"]
    for fam, m in mem["families"].items():
        s = st["families"][fam]
        assert s["status"] == m["status"] == "ok"
        for axis, ma in m["axes"].items():
            sa = s["axes"][axis]
            # the raw error's score is the samples' own: recovered exactly from the rows
            assert sa["score_raw"] == pytest.approx(ma["score_raw"], rel=1e-9)
            assert sa["rms_raw"] == pytest.approx(ma["rms_raw"], rel=1e-9)
            # the residual's: the drift's move inside one window is neglected
            assert sa["score_ratio"] == pytest.approx(ma["score_ratio"], rel=1e-3)
            assert sa["verdict"] == ma["verdict"]
    # the shipped least-squares models are fitted on the same 1 s windows: same coefficients
    for fam in ("cubic", "linear"):
        a, _ = load_checkpoint(tmp / "memory" / "models" / f"{fam}.pt")
        b, _ = load_checkpoint(tmp / "streamed" / "models" / f"{fam}.pt")
        want = {k: v.double().numpy() for k, v in a.state_dict().items()}
        got = {k: v.double().numpy() for k, v in b.state_dict().items()}
        assert list(got) == list(want)
        # float64 least squares on the same rows summed in another order (Chan's merge at
        # chunk edges): equal to rounding, relative to the model's largest coefficient
        scale = max(float(np.abs(v).max()) for v in want.values() if v.size)
        for k in want:
            assert_f64_close(got[k], want[k], rtol=1e-9, atol=scale * 1e-12,
                             err_msg=f"{fam}.{k}")


def test_what_cannot_be_streamed_is_refused_in_one_line(tmp_path, recording):
    units = [_run("a", 5.0, 600.0, 1, None), _run("a", 5.0, 600.0, 2, None)]
    units[1].device_id = "unit2"
    fleet = Dataset(runs=units)
    fpath = write_parquet(fleet, tmp_path / "fleet.parquet")
    cfg = config_from_mapping({"data": {"paths": [str(fpath)], "in_memory_samples": 0}})
    with pytest.raises(InputError, match=r"fleet\.parquet.*several units"):
        load_compare_data(cfg)
    cfg = config_from_mapping({"data": {"paths": [str(recording)], "in_memory_samples": 0},
                               "target": "four-position"})
    with pytest.raises(ConfigError, match=r"in_memory_samples.*four-position"):
        load_compare_data(cfg)
    with pytest.raises(ConfigError, match=r"data\.chunk_rows"):
        config_from_mapping({"data": {"chunk_rows": 0}})
    # a CSV streams as a thermonet file does (tests/test_stream_any_file.py); under the
    # limit it is read whole
    csv = tmp_path / "rec.csv"
    rec = _run("a", 5.0, 600.0, 1, None)
    np.savetxt(csv, np.column_stack([rec.time_s, rec.temperature_c, rec.outputs["gyro_x"]]),
               delimiter=",", header="time_s,temperature_c,gyro_x", comments="")
    cfg = config_from_mapping({"data": {"paths": [str(csv)], "in_memory_samples": 0}})
    assert load_compare_data(cfg)[0].windows is not None
    cfg = config_from_mapping({"data": {"paths": [str(csv)], "in_memory_samples": 3000}})
    assert load_compare_data(cfg)[0].windows is None


def test_the_api_fits_and_scores_a_streamed_recording_as_its_samples(recording):
    """``thermonet.read(path, window_s=...)``: an estimator fitted on the streamed runs has
    the coefficients of one fitted on the samples (both average 1 s windows), and scores a
    run as the samples score: the raw error's variance exact, the residual's within the
    drift's move inside a window."""
    import thermonet

    whole = thermonet.read(recording)
    rows = thermonet.read(recording, window_s=1.0, inputs=["dT", "rate"], chunk_rows=1111)
    assert rows[0].windows is not None and whole[0].windows is None
    params = dict(degree=2, t_ref=25.0)
    a = thermonet.DriftEstimator("poly", ["dT", "rate"], **params).fit(whole[0])
    b = thermonet.DriftEstimator("poly", ["dT", "rate"], **params).fit(rows[0])
    want = {k: v.double().numpy() for k, v in a.model_.state_dict().items()}
    got = {k: v.double().numpy() for k, v in b.model_.state_dict().items()}
    scale = max(float(np.abs(v).max()) for v in want.values() if v.size)
    for k in want:
        assert_f64_close(got[k], want[k], rtol=1e-9, atol=scale * 1e-12, err_msg=k)
    # 1 − score: the residual's variance over the raw error's, over the samples of run b.
    # From the rows the raw variance is exact and the residual's exact to first order in
    # the signals' spread inside a window (training.pipeline.residual_spread). Without that
    # term it would be too large by the drift's own spread inside a 1 s window (slope
    # 0.01 × 0.063 °C/s / √12) and the thermometer's noise through it (0.01 × 0.02),
    # against σ = 0.003: ≈ 0.8 %; what is left is the model's curvature, far below.
    without = ((0.01 * 0.063 / 12 ** 0.5) ** 2 + (0.01 * 0.02) ** 2) / 0.003 ** 2
    want_ratio, got_ratio = 1.0 - a.score(whole[1]), 1.0 - b.score(rows[1])
    assert got_ratio == pytest.approx(want_ratio, rel=without / 10)


def test_a_streamed_run_without_the_dynamic_input_is_refused_naming_it(recording):
    """``read(path, window_s=...)`` without ``inputs``, then an estimator reading ``rate``:
    the rate is computed on the samples while a file is streamed, so the run cannot give it;
    refused in one line naming the run, the input and the read that gives it (was 'gap_s must
    be a positive number of seconds, got 0.0' — the gap of a run streamed without dynamic
    inputs — where the user gave no gap_s; and with a gap_s, 'computed with gap_s 0 s')."""
    import thermonet

    rows = thermonet.read(recording, window_s=1.0)
    assert rows[0].windows is not None and rows[0].windows.gap_s == 0.0
    for extra in ({}, {"gap_s": 30.0}):
        with pytest.raises(InputError) as err:
            thermonet.DriftEstimator("poly", ["dT", "rate"], degree=2, t_ref=25.0,
                                     **extra).fit(rows[0])
        msg = str(err.value)
        assert len(msg.splitlines()) == 1 and "gap_s" not in msg, msg
        assert msg == (f"run '{rows[0].run_id}' of {recording}: reduced to 1-s window means "
                       "without the dynamic input(s) ['rate'], which are computed on the "
                       "samples while the file is streamed: read it with them named "
                       "(read(..., window_s=1, inputs=['dT', 'rate']))")
    # read as the message says: fitted
    rows = thermonet.read(recording, window_s=1.0, inputs=["dT", "rate"])
    est = thermonet.DriftEstimator("poly", ["dT", "rate"], degree=2, t_ref=25.0).fit(rows[0])
    assert est.spec_.gap_s == pytest.approx(rows[0].windows.gap_s) and est.spec_.gap_s > 0


def test_a_bad_value_deep_in_a_streamed_file_is_one_line_and_nothing_written(tmp_path, capsys):
    """A NaN in the third chunk of a streamed file: ``compare`` names the file, the column and
    the data row in one line, exits 1 and writes no output directory."""
    import pyarrow.parquet as pq

    rec = _run("a", 10.0, 1200.0, 1, None)
    path = write_parquet(Dataset(runs=[rec]), tmp_path / "bad.parquet")
    table = pq.read_table(path)
    col = table.column("gyro_y").to_numpy().copy()
    col[9000] = np.nan
    table = table.set_column(table.schema.get_field_index("gyro_y"), "gyro_y", [col])
    pq.write_table(table, path)       # schema metadata (the run list) kept
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump({"data": {"paths": [str(path)], "in_memory_samples": 0,
                                            "chunk_rows": 4000},
                                   "tracking": {"enabled": False}}))
    rc = main(["compare", str(cfg), "--out", str(tmp_path / "out"), "-q", "--no-track"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1
    assert "bad.parquet" in err[0] and "gyro_y" in err[0] and "9001" in err[0], err[0]
    assert not (tmp_path / "out").exists()


def test_time_blocks_of_a_streamed_run_are_scored_over_its_samples(tmp_path):
    """One run split into interleaved time blocks (the held-out blocks stacked, their rows'
    counts and sums of squares carried along): the raw error's score over the test blocks'
    samples, recovered from the rows, equals the in-memory comparison's."""
    from thermonet.sim import simulate

    data = write_parquet(simulate("patent-gyro", runs=1, seed=5, sample_rate_hz=2.0),
                         tmp_path / "one.parquet")
    docs = {}
    for mode, limit in (("memory", 10**9), ("streamed", 0)):
        cfg = {"data": {"paths": [str(data)], "in_memory_samples": limit},
               "split": {"strategy": "time-blocks", "n_blocks": 10},
               "features": {"t_ref": 25.0},
               "families": [{"name": "cubic", "family": "poly", "inputs": ["dT"],
                             "params": {"degree": 3}},
                            {"name": "linear", "family": "linear", "inputs": ["dT"]}],
               "baseline": "cubic", "tracking": {"enabled": False}}
        path = tmp_path / f"{mode}.yaml"
        path.write_text(yaml.safe_dump(cfg))
        assert main(["compare", str(path), "--out", str(tmp_path / mode), "-q",
                     "--no-track"]) == 0
        docs[mode] = json.loads((tmp_path / mode / "results.json").read_text())
    mem, st = docs["memory"], docs["streamed"]
    assert st["split"]["strategy"] == mem["split"]["strategy"] == "time-blocks"
    # the blocks are cut on time: here (a 21,200 s run, 10 blocks) every edge falls on a
    # window edge, so both comparisons hold out the same samples; elsewhere a window that
    # straddles an edge goes whole to one side
    for fam in ("cubic", "linear"):
        for axis, m in mem["families"][fam]["axes"].items():
            s = st["families"][fam]["axes"][axis]
            assert s["score_raw"] == pytest.approx(m["score_raw"], rel=1e-9)
            assert s["score_ratio"] == pytest.approx(m["score_ratio"], rel=1e-3)
