"""Magnetometers: read in µT, simulated, fitted in PX4's ``TC_M*`` form, lent a thermometer with
a fitted lag, written, verified, and the bad inputs refused one line per instance.

The firmware formula is re-implemented from the source in ``tests/oracles.py``, independently
of thermonet: PX4 ``TemperatureCompensation::calc_thermal_offsets_3D`` for ``TC_M<s>_*``
(PX4-Autopilot v1.15+, ``temp_comp_params_mag_<s>.yaml``): T clamped to [TMIN, TMAX], offset_i = Σ_k
X<k>_i (T − TREF)^k in **gauss** (``sensor_mag``'s unit), subtracted; the slot is the one whose
``TC_M<s>_ID`` is the magnetometer's device id; ``TC_M_ENABLE`` = 1.  The lag is a first-order
lag re-implemented here as a plain loop (zero-order hold of the input; thermonet's is exact
for an input linear between samples — at 4-s samples and τ ≥ 120 s the two differ by far
less than the tolerances below).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from oracles import px4_offsets, px4_slot, read_params
from thermonet.cli import main
from thermonet.data.logs import read_log
from thermonet.data.logs.base import lend_thermometer
from thermonet.data.logs.writers import write_log
from thermonet.sim.fcboard import EARTH_FIELD_UT, MAG_IDS, MAG_LAG_S, simulate_board
from thermonet.workflows.calibrate import calibrate
from thermonet.workflows.firmware_fit import fit_firmware
from thermonet.workflows.magnetometer import LAG_GRID_S, with_lag

RATE_HZ = 0.25          # 675 samples per 45-minute warm-up: fast, and over calibrate's minimum


def _tc_m(p: dict[str, float], device_id: int, temp: np.ndarray) -> np.ndarray:
    """PX4's calc_thermal_offsets_3D (tests/oracles.py) on the TC_M slot of ``device_id``:
    µT (gauss × 100)."""
    assert p["TC_M_ENABLE"] == 1
    pre = px4_slot(p, "M", device_id)
    assert pre is not None, device_id
    return 100.0 * px4_offsets(p, pre, temp)


def _lag(t: np.ndarray, x: np.ndarray, tau: float) -> np.ndarray:
    out = np.empty_like(x)
    out[0] = x[0]
    for k in range(1, x.size):
        a = np.exp(-(t[k] - t[k - 1]) / tau) if tau > 0 else 0.0
        out[k] = a * out[k - 1] + (1.0 - a) * x[k]
    return out


def _cubic(fw: dict, temp: np.ndarray) -> np.ndarray:
    x = np.clip(temp, fw["t_min"], fw["t_max"]) - fw["t_ref"]
    return np.column_stack([sum(c[k] * x ** k for k in range(4)) for c in fw["coef"]])


def _binned_pp(temp: np.ndarray, y: np.ndarray) -> float:
    bins = np.floor(temp)
    return float(np.ptp([y[bins == b].mean() for b in np.unique(bins)
                         if np.sum(bins == b) >= 3]))


def _removed(temp: np.ndarray, truth: np.ndarray, corr: np.ndarray) -> np.ndarray:
    return np.array([1.0 - _binned_pp(temp, truth[:, j] - corr[:, j])
                     / _binned_pp(temp, truth[:, j]) for j in range(3)])


def test_simulated_board_other_sensors_unchanged_by_the_magnetometers() -> None:
    """The magnetometers draw from their own random streams: every other sensor's samples are
    those of the board before magnetometers — per instance the sums of squares of its values,
    truth and logged temperature, recorded from that code (``tests/data/fcboard_fingerprint.json``:
    seed 5, 0.1 Hz, both presets, runs 0 and 1).  Compared to 1e-9 relative: a libm's last
    bit differs between CPUs (a SHA-256 of the samples did), any change of a random stream
    moves these sums by far more."""
    want = json.loads((Path(__file__).parent / "data" / "fcboard_fingerprint.json").read_text())
    for key, rows in want["boards"].items():
        preset, run = key.split("#")
        got = [[i.kind, i.instance] + [float((np.asarray(a, dtype=np.float64) ** 2).sum())
                                       for a in (i.values, i.truth, i.temperature_c)]
               for i in simulate_board(preset, seed=5, rate_hz=0.1, run=int(run)).instances
               if i.kind != "mag"]
        assert [r[:2] for r in got] == [r[:2] for r in rows], key
        np.testing.assert_allclose([r[2:] for r in got], [r[2:] for r in rows], rtol=1e-9,
                                   err_msg=key)
    board = simulate_board("fc-board", seed=5, rate_hz=0.1)
    mags = [i for i in board.instances if i.kind == "mag"]
    assert [(m.name, m.device_id) for m in mags] == [("mag0", MAG_IDS[0]), ("mag1", MAG_IDS[1])]
    assert mags[0].temperature_c is not None and mags[1].temperature_c is None
    # the Earth's field (50-60 µT) stays in the signal, the drift is several µT on some axis
    assert 50.0 < float(np.linalg.norm(EARTH_FIELD_UT)) < 60.0
    assert all(np.allclose(np.linalg.norm(m.values - m.truth, axis=1),
                           np.linalg.norm(EARTH_FIELD_UT), atol=2.0) for m in mags)
    assert all(np.max(np.ptp(m.truth, axis=0)) > 5.0 for m in mags)


def test_ulog_and_dataflash_magnetometers_in_microtesla(tmp_path: Path) -> None:
    board = simulate_board("fc-board", seed=2, rate_hz=0.1)
    from pyulog import ULog

    path = write_log(board, tmp_path / "b.ulg")
    raw = {d.multi_id: d.data for d in ULog(str(path), ["sensor_mag"]).data_list}
    back = {i.name: i for i in read_log(path).instances}
    for m in (0, 1):
        sim = next(i for i in board.instances if i.name == f"mag{m}")
        assert np.all(raw[m]["device_id"] == MAG_IDS[m])
        # sensor_mag is gauss (float32); the reader gives µT
        assert np.allclose(raw[m]["x"], sim.values[:, 0] / 100.0, rtol=1e-6)
        assert np.allclose(back[f"mag{m}"].values, sim.values, rtol=1e-6, atol=1e-5)
    assert np.all(np.isnan(raw[1]["temperature"])) and back["mag1"].temperature_c is None
    ap = simulate_board("fc-board", autopilot="ardupilot", seed=2, rate_hz=0.1)
    back = {i.name: i for i in read_log(write_log(ap, tmp_path / "b.bin")).instances}
    sim = next(i for i in ap.instances if i.name == "mag0")
    # MAG is int16 milligauss: 0.1 µT steps; ArduPilot logs no magnetometer temperature
    assert np.max(np.abs(back["mag0"].values - sim.values)) <= 0.05 + 1e-9
    assert back["mag0"].temperature_c is None and back["mag0"].device_id == MAG_IDS[0]


@pytest.mark.numerics
def test_tc_m_through_px4_formula_on_the_next_warm_up_five_boards(tmp_path: Path) -> None:
    """Five boards: the written TC_M file, applied through PX4's formula to the board's next
    warm-up, removes ≥ 80 % of the 1 °C-binned drift on every axis (mag0, own thermometer);
    the lent barometer thermometer with the fitted lag ≥ 70 % (mag1), more than the same
    cubic fitted with no lag; ``thermonet verify`` PASSes the file on that log."""
    gains = []
    for seed in range(5):
        first = write_log(simulate_board("fc-board", seed=seed, rate_hz=RATE_HZ),
                          tmp_path / f"s{seed}.ulg")
        nxt_board = simulate_board("fc-board", seed=seed, rate_hz=RATE_HZ, run=1)
        nxt = write_log(nxt_board, tmp_path / f"s{seed}_next.ulg")
        doc = calibrate(first, tmp_path / f"c{seed}", compare=False)
        p = read_params(tmp_path / f"c{seed}" / "px4.params")
        assert p["TC_M0_ID"] == MAG_IDS[0] and all(p[f"TC_M{s}_ID"] == 0 for s in (1, 2, 3))
        assert all(p[f"TC_M0_X0_{i}"] == 0.0 for i in range(3))   # zero at TREF: field kept
        assert p["TC_M0_TMIN"] <= p["TC_M0_TREF"] <= p["TC_M0_TMAX"]
        by = {i.name: i for i in nxt_board.instances}
        logged = {i.name: i for i in read_log(nxt).instances}
        temp0 = np.asarray(logged["mag0"].temperature_c)          # as the firmware reads it
        assert np.all(_removed(temp0, by["mag0"].truth,
                               _tc_m(p, MAG_IDS[0], temp0)) >= 0.8), seed
        d1 = doc["instances"]["mag1"]
        assert d1["status"] == "model only" and d1["thermometer"]["name"] == "baro0"
        assert d1["thermometer"]["chosen"] == "default"
        tau = d1["thermometer"]["lag_s"]
        baro_t = np.interp(by["mag1"].time_s, by["baro0"].time_s, by["baro0"].temperature_c)
        with_lag_removed = _removed(baro_t, by["mag1"].truth,
                                    _cubic(d1["firmware"], _lag(by["mag1"].time_s, baro_t, tau)))
        assert np.all(with_lag_removed >= 0.7), seed
        src = {i.name: i for i in read_log(first).instances}
        nolag = fit_firmware(with_lag(lend_thermometer(src["mag1"], src["baro0"]), 0.0), "px4")
        no_lag_removed = _removed(baro_t, by["mag1"].truth, _cubic(
            {"t_min": nolag.t_min, "t_max": nolag.t_max, "t_ref": nolag.t_ref,
             "coef": nolag.coef.tolist()}, baro_t))
        gains.append(with_lag_removed.mean() - no_lag_removed.mean())
        # the heading error of a level board, before and after, in the results
        for name in ("mag0", "mag1"):
            head = doc["instances"][name]["heading"]
            assert head["after"] < 0.25 * head["before"] and head["after"] < 2.0
        assert main(["verify", str(tmp_path / f"c{seed}" / "px4.params"), str(nxt),
                     "--out", str(tmp_path / f"v{seed}"), "-q"]) == 0
        ver = json.loads((tmp_path / f"v{seed}" / "results.json").read_text())
        assert ver["instances"]["mag0"]["status"] == "judged"
        assert all(ver["instances"]["mag0"]["passed"])
        assert ver["instances"]["mag1"]["status"] == "not covered"
    assert all(g > 0 for g in gains), gains              # the lag helps on every board


@pytest.mark.numerics
def test_fitted_lag_finds_the_simulated_one() -> None:
    """The lag chosen on held-out time blocks is the simulated die lag (300 s for mag1) or a
    neighbour on the grid; no lag scores worse."""
    from thermonet.workflows.magnetometer import choose_lag

    for seed in (0, 1, 2):
        board = simulate_board("fc-board", seed=seed, rate_hz=RATE_HZ)
        by = {i.name: i for i in board.instances}
        tau, scores = choose_lag([lend_thermometer(by["mag1"], by["baro0"])])
        grid = list(LAG_GRID_S)
        k = grid.index(MAG_LAG_S[1])
        assert tau in grid[k - 1:k + 2], (seed, tau)
        assert scores[0.0] > scores[tau]


def test_ardupilot_has_no_magnetometer_parameters_one_line(tmp_path: Path) -> None:
    # 0.5 Hz: the held-out quarter holds the 200 samples a judgement needs
    board = simulate_board("fc-board", autopilot="ardupilot", seed=4, rate_hz=0.5)
    doc = calibrate(write_log(board, tmp_path / "b.bin"), tmp_path / "c", compare=False)
    for name in ("mag0", "mag1"):
        d = doc["instances"][name]
        assert d["status"] == "model only"
        assert d["reason"].startswith("ArduPilot has no magnetometer temperature-calibration "
                                      "parameters") and "ONNX or C" in d["reason"]
        assert d["held_out"]["status"] == "judged"
    parm = (tmp_path / "c" / "ardupilot.parm").read_text()
    assert "COMPASS" not in parm and "MAG" not in parm
    report = (tmp_path / "c" / "report.txt").read_text()
    assert report.count("ArduPilot has no magnetometer temperature-calibration parameters") == 2


def test_bad_magnetometer_input_one_line_per_instance_rest_calibrated(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A magnetometer that moved during the soak, one whose only thermometer to borrow spans
    under 10 °C, one with no thermometer at all: one line each, the rest calibrated.  A
    named thermometer the log does not have: refused in one line, nothing written."""
    board = simulate_board("fc-board", seed=6, rate_hz=RATE_HZ)
    by = {i.name: i for i in board.instances}
    m0 = by["mag0"]
    half = m0.n_samples // 2                      # turned 90° about z half-way through
    m0.values[half:] = m0.values[half:] @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0],
                                                    [0.0, 0.0, 1.0]]).T
    third = write_log(board, tmp_path / "moved.ulg")
    assert main(["calibrate", str(third), "--out", str(tmp_path / "c1"), "--no-compare",
                 "--mag-thermometer", "mag1=gyro1", "--detail"]) == 0
    out = capsys.readouterr().out
    lines = [ln for ln in out.splitlines() if ln.startswith("mag0 ")]
    assert len(lines) == 1 and "LEFT OUT" in lines[0] and "moved during the soak" in lines[0]
    doc = json.loads((tmp_path / "c1" / "results.json").read_text())
    assert doc["instances"]["mag1"]["thermometer"]["name"] == "gyro1"
    assert doc["instances"]["mag1"]["thermometer"]["chosen"] == "named"
    assert doc["instances"]["gyro0"]["status"] == "fitted"
    # a stand-in spanning under 10 °C: the barometer's thermometer held near 30 °C
    board = simulate_board("fc-board", seed=6, rate_hz=RATE_HZ)
    baro = next(i for i in board.instances if i.name == "baro0")
    baro.temperature_c = 30.0 + 0.004 * np.arange(baro.n_samples) % 3.0
    narrow = write_log(board, tmp_path / "narrow.ulg")
    assert main(["calibrate", str(narrow), "--out", str(tmp_path / "c2"), "--no-compare",
                 "-v"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("mag1 ")]
    assert len(lines) == 1 and "LEFT OUT" in lines[0]
    assert "baro0's thermometer, lent" in lines[0] and "spans only" in lines[0]
    # no thermometer to lend: baro0, gyro0 and acc0 without one, and none named
    board = simulate_board("fc-board", seed=6, rate_hz=RATE_HZ)
    board.instances = [i for i in board.instances if i.name not in ("baro0", "gyro0", "acc0")]
    none = write_log(board, tmp_path / "none.ulg")
    assert main(["calibrate", str(none), "--out", str(tmp_path / "c3"), "--no-compare",
                 "-v"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("mag1 ")]
    assert len(lines) == 1 and "LEFT OUT — no thermometer" in lines[0]
    # a named thermometer the log does not have: one line naming file, instance and key
    assert main(["calibrate", str(none), "--out", str(tmp_path / "c4"),
                 "--mag-thermometer", "mag1=baro0"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(none) in err and "mag1=baro0" in err
    assert not (tmp_path / "c4").exists()
    for spec, expect in (("mag7=gyro1", "no magnetometer mag7"), ("baro0", "expected MAG=")):
        assert main(["calibrate", str(none), "--out", str(tmp_path / "c5"),
                     "--mag-thermometer", spec]) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and expect in err, err
        assert not (tmp_path / "c5").exists()


def test_verify_a_magnetometer_without_its_own_thermometer_is_not_judged(tmp_path: Path) -> None:
    """PX4 applies TC_M* with the magnetometer's own temperature: a TC_M slot for mag1 (which
    logs NaN) is not judged, and verify says why."""
    from thermonet.workflows.verify import evaluate, read_param_file

    board = simulate_board("fc-board", seed=7, rate_hz=RATE_HZ)
    path = write_log(board, tmp_path / "b.ulg")
    calibrate(path, tmp_path / "c", compare=False)
    text = (tmp_path / "c" / "px4.params").read_text()
    text = text.replace("TC_M1_ID\t0\t", f"TC_M1_ID\t{MAG_IDS[1]}\t")
    text = text.replace("TC_M1_TMAX\t0\t", "TC_M1_TMAX\t50\t")
    (tmp_path / "m1.params").write_text(text)
    res = evaluate(read_param_file(tmp_path / "m1.params"), read_log(path))
    assert res["mag1"]["status"] == "not judged"
    assert "no temperature of its own" in res["mag1"]["reason"]
    assert res["mag0"]["status"] == "judged" and all(res["mag0"]["passed"])


@pytest.mark.numerics
def test_a_thermonet_model_of_a_magnetometer_exports_as_tc_m_in_gauss(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The comparison's cubic (``at-t-ref``: the Earth's field stays, zero at TREF) exported with
    ``thermonet export --format px4-params``: TC_M* in gauss, X0 = 0, cutting the simulated
    drift through PX4's formula; ArduPilot refused in one line.  A lent thermometer's models
    take the lag as a dynamic input and export as ONNX."""
    board = simulate_board("fc-board", seed=3, rate_hz=RATE_HZ)
    board.instances = [i for i in board.instances if i.name in ("mag0", "mag1", "baro0")]
    calibrate(write_log(board, tmp_path / "b.ulg"), tmp_path / "cal")
    src = str(tmp_path / "cal" / "instances" / "mag0")
    assert main(["export", src, "--format", "px4-params", "--family", "px4-cubic",
                 "--device-id", str(MAG_IDS[0]), "--out", str(tmp_path / "m.params")]) == 0
    p = read_params(tmp_path / "m.params")
    # X0: the model's value at TREF, zero to float64 rounding of the expansion (µT -> gauss)
    assert all(abs(p[f"TC_M0_X0_{i}"]) < 1e-6 for i in range(3))
    m0 = next(i for i in board.instances if i.name == "mag0")
    temp = np.asarray(m0.temperature_c)
    assert np.all(_removed(temp, m0.truth, _tc_m(p, MAG_IDS[0], temp)) >= 0.8)
    capsys.readouterr()
    assert main(["export", src, "--format", "ardupilot-params", "--family", "px4-cubic",
                 "--out", str(tmp_path / "m.parm")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "ArduPilot has no magnetometer temperature-calibration parameters" in err
    cmp = json.loads((tmp_path / "cal" / "instances" / "mag1" / "results.json").read_text())
    tau = json.loads((tmp_path / "cal" / "results.json").read_text())[
        "instances"]["mag1"]["thermometer"]["lag_s"]
    assert cmp["families"]["px4-cubic-lag"]["inputs"] == ["dT", f"lag_{tau:g}"]
    assert main(["export", str(tmp_path / "cal" / "instances" / "mag1"), "--format", "onnx",
                 "--family", "px4-cubic-lag", "--out", str(tmp_path / "m1.onnx")]) == 0


@pytest.mark.numerics
def test_heated_then_cooled_the_lag_is_what_makes_a_lent_thermometer_work(
        tmp_path: Path) -> None:
    """``fc-board-cycle``: the die is colder than the barometer while heating and warmer while
    cooling.  The fitted lag is the simulated one, and on the next cycle the lagged cubic
    removes ≥ 85 % per axis where the un-lagged one leaves far more (means ≥ 5 points
    apart; bench_magnetometers.py measures 10-22 points on ten seeds)."""
    for seed in range(3):
        first = write_log(simulate_board("fc-board-cycle", seed=seed, rate_hz=RATE_HZ),
                          tmp_path / f"c{seed}.ulg")
        nxt = simulate_board("fc-board-cycle", seed=seed, rate_hz=RATE_HZ, run=1)
        doc = calibrate(first, tmp_path / f"cal{seed}", compare=False)
        d1 = doc["instances"]["mag1"]
        assert d1["thermometer"]["lag_s"] == MAG_LAG_S[1]       # a grid value: exact
        by = {i.name: i for i in nxt.instances}
        baro_t = np.interp(by["mag1"].time_s, by["baro0"].time_s, by["baro0"].temperature_c)
        lagged = _removed(baro_t, by["mag1"].truth, _cubic(
            d1["firmware"], _lag(by["mag1"].time_s, baro_t, MAG_LAG_S[1])))
        src = {i.name: i for i in read_log(first).instances}
        nolag = fit_firmware(with_lag(lend_thermometer(src["mag1"], src["baro0"]), 0.0), "px4")
        unlagged = _removed(baro_t, by["mag1"].truth, _cubic(
            {"t_min": nolag.t_min, "t_max": nolag.t_max, "t_ref": nolag.t_ref,
             "coef": nolag.coef.tolist()}, baro_t))
        assert np.all(lagged >= 0.85), (seed, lagged)
        assert lagged.mean() - unlagged.mean() >= 0.05, (seed, lagged, unlagged)


def test_two_logs_of_one_board_each_checked_for_motion_on_its_own(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``calibrate a.ulg b.ulg``: the motion check looks within each log, never across the
    join, where the first log ends hot and the second starts cold (the drift, not a turn of
    the board: was "the field direction turns 10° ... moved" and both magnetometers left
    out).  A board that really turns inside the second log is still caught, naming the log."""
    assert main(["simulate", "fc-board", "--runs", "2", "--seed", "0", "--out",
                 str(tmp_path / "b.ulg")]) == 0
    logs = [str(tmp_path / "b_run1.ulg"), str(tmp_path / "b_run2.ulg")]
    assert main(["calibrate", *logs, "--out", str(tmp_path / "c"), "--no-compare",
                 "--detail"]) == 0
    out = capsys.readouterr().out
    assert "moved" not in out and "turns" not in out
    doc = json.loads((tmp_path / "c" / "results.json").read_text())
    mags = {k: v for k, v in doc["instances"].items() if k.startswith("mag")}
    assert mags["mag0"]["status"] == "fitted", mags["mag0"]
    assert mags["mag1"]["status"] == "model only", mags["mag1"]   # a lent thermometer
    params = read_params(tmp_path / "c" / "px4.params")
    assert int(params["TC_M0_ID"]) == MAG_IDS[0]
    # the held-out log through PX4's own formula: the drift cut on every axis
    held = {i.name: i for i in simulate_board("fc-board", seed=0, run=1).instances}["mag0"]
    temp = np.asarray(held.temperature_c, dtype=np.float64)   # the second log, its truth
    assert np.all(_removed(temp, held.truth, _tc_m(params, MAG_IDS[0], temp)) >= 0.8)
    # a turn of 90° about z half-way through the second log: left out, the log named
    second = simulate_board("fc-board", seed=0, rate_hz=RATE_HZ, run=1)
    m0 = next(i for i in second.instances if i.name == "mag0")
    half = m0.n_samples // 2
    m0.values[half:] = m0.values[half:] @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0],
                                                    [0.0, 0.0, 1.0]]).T
    first = write_log(simulate_board("fc-board", seed=0, rate_hz=RATE_HZ, run=0),
                      tmp_path / "r1.ulg")
    moved = write_log(second, tmp_path / "r2.ulg")
    assert main(["calibrate", str(first), str(moved), "--out", str(tmp_path / "d"),
                 "--no-compare", "--detail"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("mag0 ")]
    assert len(lines) == 1 and "LEFT OUT — log 2: the field direction turns 40° between " \
        "t = 1324 s and 1384 s (more than 5° within 60 s): the magnetometer moved" in lines[0]


def test_a_thermometer_in_kelvin_is_named_kelvin_not_damage(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A sensor whose thermometer the log holds in kelvin (a driver's unit bug) keeps its
    samples and is left out in one line saying kelvin, with the span in K and °C: the
    autopilot's compensation reads that same kelvin, so parameters fitted in °C would not
    match it (was: every sample dropped as "a temperature outside -80..200 °C", then the
    instance dropped as "0 samples ... a damaged instance field").  The rest is calibrated;
    PX4's ULog and ArduPilot's DataFlash alike."""
    board = simulate_board("fc-board", seed=6, rate_hz=RATE_HZ)
    m0 = next(i for i in board.instances if i.name == "mag0")
    assert m0.temperature_c is not None
    lo, hi = (float(x) for x in np.percentile(m0.temperature_c, [1.0, 99.0]))
    m0.temperature_c = m0.temperature_c + 273.15
    log = write_log(board, tmp_path / "k.ulg")
    inst = {i.name: i for i in read_log(log).instances}["mag0"]
    assert inst.n_samples == m0.n_samples and inst.damaged == 0
    assert main(["calibrate", str(log), "--out", str(tmp_path / "c"), "--no-compare",
                 "--detail"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("mag0 ")]
    assert len(lines) == 1, lines
    assert (f"{m0.n_samples} samples" in lines[0] and "LEFT OUT — its thermometer reads "
            f"{lo + 273.15:.1f}..{hi + 273.15:.1f}: kelvin ({lo:.1f}..{hi:.1f} °C)"
            in lines[0]), lines[0]
    doc = json.loads((tmp_path / "c" / "results.json").read_text())
    assert doc["instances"]["gyro0"]["status"] == "fitted"
    assert "damaged instance field" not in json.dumps(doc)
    # ArduPilot: an IMU's thermometer in kelvin, its gyro and accelerometer left out
    ap = simulate_board("fc-board", autopilot="ardupilot", seed=6, rate_hz=RATE_HZ)
    for i in ap.instances:
        if i.name in ("gyro1", "acc1"):
            assert i.temperature_c is not None
            i.temperature_c = i.temperature_c + 273.15
    bin_log = write_log(ap, tmp_path / "k.bin")
    assert main(["calibrate", str(bin_log), "--out", str(tmp_path / "d"), "--no-compare",
                 "--detail"]) == 0
    out = capsys.readouterr().out.splitlines()
    for name in ("gyro1", "acc1"):
        line = next(ln for ln in out if ln.startswith(f"{name} "))
        assert "LEFT OUT — its thermometer reads" in line and ": kelvin (" in line, line
    assert next(ln for ln in out if ln.startswith("gyro0 ")).count("fitted") >= 1


def test_a_magnetometer_lent_two_thermometers_is_refused() -> None:
    """``--mag-thermometer mag1=baro0 --mag-thermometer mag1=gyro0`` silently took the last;
    now one line naming both (the same one twice is no conflict)."""
    from thermonet.core.errors import InputError
    from thermonet.workflows.magnetometer import parse_thermometers

    with pytest.raises(InputError) as err:
        parse_thermometers(["mag1=baro0", "mag1=gyro0"])
    assert str(err.value) == ("--mag-thermometer 'mag1=gyro0': mag1 is already lent baro0's "
                              "thermometer (--mag-thermometer mag1=baro0): name one "
                              "thermometer per magnetometer")
    assert parse_thermometers(["mag1=baro0", "mag1=baro0"]) == {"mag1": "baro0"}


def test_a_firmware_form_left_out_names_the_axis_it_fails_and_never_says_it_is_enough() -> None:
    """The verdict of a firmware form that does not cut every held-out axis said "the
    firmware form is enough" beside "LEFT OUT — does not reduce the drift" (cut 14.0x,
    9.6x, 0.6x); it now names the axis it fails and recommends nothing."""
    from thermonet.workflows.calibrate_compare import verdict

    fams = {"px4-cubic": {"status": "ok", "val_score": 0.5,
                          "held_out_pp_raw": {"mag_x": 1.4, "mag_y": 0.96, "mag_z": 0.3},
                          "held_out_pp_comp": {"mag_x": 0.1, "mag_y": 0.1, "mag_z": 0.5}},
            "linear": {"status": "ok", "val_score": 0.45}}
    ok, line = verdict({"firmware_family": "px4-cubic", "chosen": "linear", "dir": "d",
                        "families": fams})
    assert not ok and line.endswith("cut 14.0x, 9.6x, 0.6x (val score ratio 0.5); it does "
                                    "not cut mag_z 0.6x")
    fams["px4-cubic"]["held_out_pp_comp"]["mag_z"] = 0.03
    ok, line = verdict({"firmware_family": "px4-cubic", "chosen": "linear", "dir": "d",
                        "families": fams})
    assert ok and line.endswith("the firmware form is enough")

