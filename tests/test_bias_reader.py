"""The estimator-bias reader (thermonet.data.logs.bias) on the real PX4 fixture and on simulated
flights written as real ULog / DataFlash files: what is read, what is undone, the rejection rules.

Expectations are independent of the reader: pyulog's own arrays for the real log, the
simulator's true drift for the flights."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from pyulog import ULog

from thermonet.core.errors import InputError
from thermonet.data.logs.bias import CONVERGE_S, read_bias_log
from thermonet.data.logs.flight_writers import write_flight
from thermonet.data.logs.writers import write_log
from thermonet.sim.fcboard import simulate_board
from thermonet.sim.flights import simulate_flights, true_drift

REAL = Path(__file__).parent / "data" / "real" / "px4_ulog_sample" / "sample_log_small.ulg"
IDS = {("gyro", 2424842): 0, ("gyro", 3670050): 1, ("gyro", 2621474): 2,
       ("acc", 2424842): 0, ("acc", 3670058): 1, ("acc", 2621482): 2}


def test_real_px4_fixture_older_form():
    """The real log's estimator_sensor_bias (older firmware: no variance, no validity) is read,
    rotated back by SENS_BOARD_ROT 4 (yaw 180°, ±3° trims) and its CAL offsets added back; its
    7 samples span 6 s, under the convergence time, so none is trusted."""
    log = read_bias_log(REAL)
    ulog = ULog(str(REAL), ["estimator_sensor_bias"])
    d = ulog.get_dataset("estimator_sensor_bias").data
    p = ulog.initial_parameters
    ekf = {s.kind: s for s in log.series if s.source == "ekf"}
    assert set(ekf) == {"gyro", "acc"} and ekf["gyro"].device_id == 2424842
    g = ekf["gyro"]
    assert g.variance is None and g.time_s.size == 7 and not g.valid.any()
    # yaw 180°: x and y change sign; the trims (0.76°, −2.94°) tilt by at most sin(3.1°)
    bias = np.column_stack([d[f"gyro_bias[{j}]"] for j in range(3)])
    expect = np.column_stack([-bias[:, 0], -bias[:, 1], bias[:, 2]]) + [
        p["CAL_GYRO0_XOFF"], p["CAL_GYRO0_YOFF"], p["CAL_GYRO0_ZOFF"]]
    tol = np.linalg.norm(bias, axis=1).max() * math.sin(math.radians(3.1)) + 1e-6
    assert np.abs(g.drift - expect).max() <= tol
    assert any("older firmware" in n for n in log.notes)
    # the temperature is sensor_gyro 0's (about 40 °C on this board)
    assert 39.5 < float(np.median(g.temperature_c)) < 40.6


def test_real_px4_fixture_still_gyro_is_the_raw_mean():
    """The log is on the bench: each gyro's still window is the mean of its raw samples."""
    log = read_bias_log(REAL)
    ulog = ULog(str(REAL), ["sensor_gyro"])
    still = {s.device_id: s for s in log.series if s.source == "still"}
    assert len(still) == 3
    for d in ulog.data_list:
        dev = int(np.median(d.data["device_id"]))
        raw = np.column_stack([d.data[a] for a in "xyz"]).mean(axis=0)
        np.testing.assert_allclose(still[dev].drift[0], raw, atol=1e-9)


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """Six flights of one vehicle (flights 4–6 with a thermal calibration loaded), as PX4
    (current and older firmware) and ArduPilot logs."""
    root = tmp_path_factory.mktemp("flights")
    out = {}
    for ap, ext, old in (("px4", ".ulg", False), ("px4", ".ulg", True),
                         ("ardupilot", ".bin", False)):
        sims = simulate_flights(6, seed=5, autopilot=ap)
        tag = f"{ap}{'-old' if old else ''}"
        out[tag] = (sims, [write_flight(f.log, f.biases, root / f"{tag}-{k}{ext}",
                                        old_firmware=old) for k, f in enumerate(sims)])
    return out


@pytest.mark.parametrize("tag", ["px4", "ardupilot"])
def test_applied_calibration_undone(flights, tag):
    """With the offsets (and, from flight 4, a thermal calibration) undone, the estimator's
    bias is the true drift up to the estimator's lag; left as logged it is not."""
    sims, paths = flights[tag]
    for k in (0, 5):
        log = read_bias_log(paths[k])
        for s in (s for s in log.series if s.source == "ekf"):
            truth = true_drift(5, s.kind, IDS[(s.kind, s.device_id)], s.temperature_c)[s.valid]
            err = np.median(np.abs(s.drift[s.valid] - truth))
            scale = 0.01 if s.kind == "gyro" else 0.08
            assert err < 0.25 * scale, (tag, k, s.name, err)
            assert len(s.notes) >= (2 if k == 5 else 1)


def test_still_windows_are_the_truth(flights):
    """On the ground the raw gyro's window means are the true drift within the noise."""
    _, paths = flights["px4"]
    log = read_bias_log(paths[2])
    still = [s for s in log.series if s.source == "still"]
    assert {s.device_id for s in still} == {2424842, 3670050, 2621474}
    for s in still:
        truth = true_drift(5, "gyro", IDS[("gyro", s.device_id)], s.temperature_c)
        # the windows' thermometer: IMU 2 reads whole degrees (±0.5 °C of drift slope)
        assert np.abs(s.drift - truth).max() < 2e-3


def test_variance_and_validity(flights):
    """Current firmware: the samples before convergence are rejected by the validity flag and
    the variance; the older form: by time, from CONVERGE_S on."""
    new = read_bias_log(flights["px4"][1][0])
    old = read_bias_log(flights["px4-old"][1][0])
    g_new = next(s for s in new.series if s.source == "ekf" and s.kind == "gyro")
    g_old = next(s for s in old.series if s.source == "ekf" and s.kind == "gyro")
    assert g_new.variance is not None and g_old.variance is None
    first_new = g_new.time_s[np.argmax(g_new.valid)] - g_new.time_s[0]
    first_old = g_old.time_s[np.argmax(g_old.valid)] - g_old.time_s[0]
    assert 30.0 < first_new < CONVERGE_S and first_old == pytest.approx(CONVERGE_S, abs=1.01)


def test_ardupilot_int16_bias_resolution(flights):
    """XKF1 holds the gyro bias in centi-degrees per second: read back within that step."""
    sims, paths = flights["ardupilot"]
    log = read_bias_log(paths[0])
    g = next(s for s in log.series if s.source == "ekf" and s.kind == "gyro" and s.estimator == 0)
    logged = sims[0].biases[0].gyro_bias
    step = math.radians(0.01)
    offs = [sims[0].log.params[f"INS_GYROFFS_{a}"] for a in "XYZ"]
    assert np.abs(g.drift - offs - logged).max() <= 0.5 * step + 1e-7


def test_no_bias_topics_is_one_line(tmp_path):
    """A chamber log (sensor topics only) is refused in one line naming what it lacks."""
    path = write_log(simulate_board(seed=1, rate_hz=0.1), tmp_path / "chamber.ulg")
    with pytest.raises(InputError) as err:
        read_bias_log(path)
    msg = str(err.value)
    assert "chamber.ulg" in msg and "estimator_sensor_bias" in msg and "\n" not in msg


def test_clock_jump_is_one_line(tmp_path):
    """A log whose clock jumps (here forward by 500 s: the writer orders records by time) is
    refused in one line."""
    sim = simulate_flights(1, seed=2)[0]
    b = sim.biases[0]
    b.time_s = b.time_s.copy()
    b.time_s[400:] += 500.0
    path = write_flight(sim.log, sim.biases, tmp_path / "jump.ulg")
    with pytest.raises(InputError, match=r"jump\.ulg.*clock jumps forward by 50\d"):
        read_bias_log(path)


def test_real_ardupilot_fixture_ekf2_gyro_bias():
    """The real 2017 ArduPilot log (EKF2: NKF1 core 0, NKF6 core 1) is read: GX..GZ in deg/s
    (int16 centi-degrees per second), rotated back by AHRS_ORIENTATION 8 (roll 180°: y and z
    change sign) and INS_GYROFFS / INS_GYR2OFFS added back; 1 s of log: none trusted."""
    from pymavlink import DFReader

    path = REAL.parents[1] / "ardupilot_bin_sample" / "test.BIN"
    log = read_bias_log(path)
    r = DFReader.DFReader_binary(str(path), zero_time_base=True)
    rows: dict[str, list[list[float]]] = {"NKF1": [], "NKF6": []}
    params: dict[str, float] = {}
    while (m := r.recv_match(type=["NKF1", "NKF6", "PARM"])) is not None:
        if m.get_type() == "PARM":
            params[m.Name] = m.Value
        else:
            rows[m.get_type()].append([m.GX, m.GY, m.GZ])
    ekf = {s.estimator: s for s in log.series if s.source == "ekf"}
    assert set(ekf) == {0, 1} and all(s.kind == "gyro" for s in ekf.values())
    for core, (msg, pre, dev) in enumerate((("NKF1", "INS_GYROFFS", "INS_GYR_ID"),
                                            ("NKF6", "INS_GYR2OFFS", "INS_GYR2_ID"))):
        b = np.radians(np.asarray(rows[msg]))
        expect = np.column_stack([b[:, 0], -b[:, 1], -b[:, 2]]) + [
            params[f"{pre}_{a}"] for a in "XYZ"]
        np.testing.assert_allclose(ekf[core].drift, expect, atol=1e-7)
        assert ekf[core].device_id == int(params[dev]) and not ekf[core].valid.any()


def test_real_px4_current_form_variance_and_validity():
    """A real PX4 log of the current estimator_sensor_bias (SITL, pyulog's test data): the
    variance is read, and the samples kept are those the log marks valid whose variance has
    settled (at most MAX_VARIANCE_RATIO × the median of the series' second half) —
    recomputed here from pyulog's arrays."""
    from thermonet.data.logs.bias import MAX_VARIANCE_RATIO

    path = REAL.parents[1] / "px4_sitl_bias_variance" / "sample_px4_events.ulg"
    log = read_bias_log(path)
    d = ULog(str(path), ["estimator_sensor_bias"]).get_dataset("estimator_sensor_bias").data
    for kind, pre in (("gyro", "gyro"), ("acc", "accel")):
        s = next(x for x in log.series if x.source == "ekf" and x.kind == kind)
        var = np.column_stack([d[f"{pre}_bias_variance[{j}]"] for j in range(3)]).max(axis=1)
        settled = np.median(var[var.size // 2:])
        expect = (d[f"{pre}_bias_valid"] == 1) & (var <= MAX_VARIANCE_RATIO * settled)
        assert s.variance is not None and s.device_id == int(d[f"{pre}_device_id"][0])
        np.testing.assert_array_equal(s.valid, expect)
    gyro = next(x for x in log.series if x.source == "ekf" and x.kind == "gyro")
    assert 0 < (~gyro.valid).sum() < 10          # the first samples, before it settled


def test_ardupilot_without_ekf_messages_is_one_line(tmp_path):
    """An ArduPilot chamber log (IMU, BARO and PARM only) is refused in one line."""
    path = write_log(simulate_board(seed=1, autopilot="ardupilot", rate_hz=0.05),
                     tmp_path / "chamber.bin")
    with pytest.raises(InputError) as err:
        read_bias_log(path)
    assert "chamber.bin" in str(err.value) and "no XKF1 / XKF2 messages" in str(err.value)
    assert "\n" not in str(err.value)
