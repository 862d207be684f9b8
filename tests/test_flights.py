"""The simulator of flights (thermonet.sim.flights) and its writer
(thermonet.data.logs.flight_writers): the same board as fc-board, the seasons, the estimator's
lag and divergence, and the round trip through pyulog and pymavlink."""

from __future__ import annotations

import numpy as np
from pymavlink import DFReader
from pyulog import ULog

from thermonet.data.logs.flight_writers import write_flight
from thermonet.sim.fcboard import simulate_board
from thermonet.sim.flights import EKF_TAU_S, simulate_flights, true_drift


def test_same_board_as_fc_board():
    """The flights' true drift is fc-board's truth at the same die temperature (same seed)."""
    board = simulate_board(seed=4, rate_hz=0.05)
    for inst in board.instances:
        if inst.kind not in ("gyro", "acc"):
            continue
        # fc-board's die temperature before rounding is not logged: IMU 0 rounds to 0.01 °C
        if inst.instance != 0:
            continue
        ours = true_drift(4, inst.kind, 0, inst.temperature_c)
        scale = 0.01 if inst.kind == "gyro" else 0.08
        assert np.abs(ours - inst.truth).max() < 0.01 * scale


def test_flights_span_the_seasons_and_are_reproducible():
    """Ten flights span the ambient range; the same seed gives the same flights."""
    a = simulate_flights(10, seed=1)
    b = simulate_flights(10, seed=1)
    amb = [f.ambient_c for f in a]
    assert min(amb) < 2.0 and max(amb) > 28.0
    np.testing.assert_array_equal(a[3].biases[0].gyro_bias, b[3].biases[0].gyro_bias)
    temps = np.concatenate([f.log.instances[0].temperature_c for f in a])
    assert temps.min() < 5.0 and temps.max() > 45.0


def test_estimator_lags_the_truth():
    """The logged bias follows the bias it must find through a first-order lag of EKF_TAU_S:
    late in a flight it is closer to the lagged target than to the target itself."""
    f = simulate_flights(3, seed=2)[0]          # flight 1: no thermal calibration loaded
    b = f.biases[0]
    t = b.time_s
    target = f.truth["gyro0"] - np.array([f.log.params[f"CAL_GYRO0_{a}OFF"] for a in "XYZ"])
    lagged = np.empty_like(target)
    state = np.zeros(3)
    for k in range(t.size):
        a = np.exp(-(t[k] - t[k - 1]) / EKF_TAU_S["gyro"]) if k else 0.0
        state = target[k] + (state - target[k]) * a
        lagged[k] = state
    late = t - t[0] > 300
    err_lag = np.median(np.abs(b.gyro_bias[late] - lagged[late]))
    err_raw = np.median(np.abs(b.gyro_bias[late] - target[late]))
    assert err_lag < 0.5 * err_raw


def test_some_flights_diverge():
    """About DIVERGE_FRACTION of the flights have an estimator far off its target a while."""
    flights = simulate_flights(40, seed=3)
    off = 0
    for f in flights:
        target = f.truth["gyro0"]
        for b in f.biases[:1]:
            applied = target - b.gyro_bias
            off += int(np.ptp(applied[200:], axis=0).max() > 0.01)
    assert 1 <= off <= 15


def test_round_trip_ulog_and_dataflash(tmp_path):
    """The written logs are read by the autopilots' own tools with every topic / message."""
    f = simulate_flights(1, seed=6)[0]
    ulg = write_flight(f.log, f.biases, tmp_path / "a.ulg")
    u = ULog(str(ulg))
    names = {(d.name, d.multi_id) for d in u.data_list}
    assert {("estimator_sensor_bias", 0), ("estimator_sensor_bias", 1),
            ("sensor_gyro", 2), ("sensor_accel", 2)} <= names
    d = u.get_dataset("estimator_sensor_bias", 1).data
    np.testing.assert_allclose(d["gyro_bias[2]"], f.biases[1].gyro_bias[:, 2], rtol=1e-6,
                               atol=1e-9)
    assert set(np.unique(d["gyro_bias_valid"])) <= {0, 1} and "gyro_bias_variance[0]" in d
    fa = simulate_flights(1, seed=6, autopilot="ardupilot")[0]
    binp = write_flight(fa.log, fa.biases, tmp_path / "a.bin")
    r = DFReader.DFReader_binary(str(binp), zero_time_base=True)
    counts: dict[str, int] = {}
    while (m := r.recv_match(type=["XKF1", "XKF2", "IMU"])) is not None:
        counts[m.get_type()] = counts.get(m.get_type(), 0) + 1
    n = fa.biases[0].time_s.size
    assert counts == {"XKF1": 2 * n, "XKF2": 2 * n, "IMU": 3 * n}


def test_simulate_command_writes_the_flights(tmp_path, capsys):
    """``thermonet simulate fc-board-flights``: N logs in the directory, as .bin on request,
    each read back by the bias reader; an option it does not use is refused, nothing written."""
    from thermonet.cli import main
    from thermonet.data.logs.bias import read_bias_log

    out = tmp_path / "flights"
    assert main(["simulate", "fc-board-flights", "--flights", "2", "--seed", "3", "--out",
                 str(out), "--format", "bin"]) == 0
    logs = sorted(out.glob("*.bin"))
    assert [p.name for p in logs] == ["flight0001.bin", "flight0002.bin"]
    assert read_bias_log(logs[1]).autopilot == "ardupilot"
    assert main(["simulate", "fc-board-flights", "--flights", "2", "--runs", "3", "--out",
                 str(tmp_path / "other")]) == 1
    assert "--runs 3" in capsys.readouterr().err and not (tmp_path / "other").exists()
    # every option it does not use is refused by name, not ignored (--test, --clusters and
    # --outliers were ignored: exit 0 and flights that never saw them)
    for opt in (["--test", "soaks:1,2"], ["--clusters", "2"], ["--outliers", "1"]):
        assert main(["simulate", "fc-board-flights", "--flights", "2", *opt, "--out",
                     str(tmp_path / "other")]) == 1
        err = capsys.readouterr().err
        assert f"{opt[0]} {opt[1]}: fc-board-flights" in err and "takes only" in err
        assert not (tmp_path / "other").exists()
    # one flight's ambient is one temperature, not "-8..-8"
    assert main(["simulate", "fc-board-flights", "--flights", "1", "--out",
                 str(tmp_path / "one")]) == 0
    line = capsys.readouterr().out
    assert "1 flight of one vehicle" in line and ".." not in line.split("ambient")[1]
    # an unknown preset lists every preset simulate writes, the flight-controller ones too
    assert main(["simulate", "no-such", "--out", str(tmp_path / "x.parquet")]) == 1
    err = capsys.readouterr().err
    assert "unknown preset 'no-such'" in err
    assert all(p in err for p in ("consumer-imu", "fc-board", "fc-board-cycle",
                                  "fc-board-flights"))
