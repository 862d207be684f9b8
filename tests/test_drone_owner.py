"""A drone owner's report: what calibrate, learn and export wrote that a board would have
taken wrongly — each case reproduced on the real thing (simulated boards and flights written
as logs, the command line, the files read back by thermonet's own readers).

1. A calibration whose held-out check could judge nothing said "load it": now it says not to,
   and what a log needs to be checked (:data:`MIN_GRADED_LOG_SAMPLES`).
2. calibrate took a flight log (the vehicle moving): now verify's motion test refuses it.
3. calibrate's ``px4.params`` disabled and cleared every kind with nothing fitted (``TC_B*``
   on a board without a barometer in the log): now such a kind is not written.
4. learn's ``px4.params`` cleared the slot of a sensor it left out: now that slot is kept
   (calibrate's too, where its log shows the board's slots).
5. export wrote another IMU's slot or device id for an instance directory's model: now its
   own by default, another refused.
6. Every ``px4.params`` said Vehicle-Id 1: now the log's ``MAV_SYS_ID``.
7. The EKF suggestions gave bounds without the autopilot's defaults beside them.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from thermonet.cli import main
from thermonet.data.firmware import FirmwareFit, px4_slot_plan, px4_vehicle_id
from thermonet.data.logs import FlightLog, SensorInstance, read_log
from thermonet.data.logs.flight_writers import write_flight
from thermonet.data.logs.writers import write_log
from thermonet.exporting.autopilot_read import read_ardupilot_params, read_px4_params
from thermonet.sim.fcboard import simulate_board
from thermonet.sim.flights import simulate_flights
from thermonet.workflows.verify import evaluate, read_param_file

REAL = Path(__file__).parent / "data" / "real"


def _rows(path: Path) -> list[list[str]]:
    return [ln.split("\t") for ln in path.read_text().splitlines() if not ln.startswith("#")]


# --------------------------------------------------------------- 1. nothing could be checked
def test_a_calibration_that_could_check_nothing_says_do_not_load(tmp_path, capsys):
    """A log cut to its first 100 kB (about 260 samples a sensor): every instance of the file
    is fitted but "not judged: too few samples" on its held-out quarter.  The console ended
    with "Load the parameter file only on board …", exit 0; verify then FAILed every axis.
    Now the console, report.txt, report.html and results.json say nothing could be checked,
    not to load the file and what a log needs (800 samples a sensor); the file is still
    written, for inspection, its header starting DO NOT LOAD."""
    whole = write_log(simulate_board("fc-board", seed=0), tmp_path / "board.ulg")
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(whole.read_bytes()[:100_000])
    out = tmp_path / "cal"
    assert main(["calibrate", str(cut), "--out", str(out), "--no-compare"]) == 0
    text = capsys.readouterr().out
    doc = json.loads((out / "results.json").read_text())
    fitted = [n for n, d in doc["instances"].items() if d["status"] == "fitted"]
    assert fitted and all(doc["instances"][n]["held_out"]["status"] == "not judged"
                          for n in fitted)
    assert "Load the parameter file only" not in text
    assert doc["advice"]["load"] == "no" and not doc["advice"]["checked"]
    said = [ln for ln in text.splitlines() if ln.startswith("Do not load the parameter file")]
    assert len(said) == 1 and "about 800 samples per sensor or more" in said[0]
    assert "held-out check (verify's test): nothing could be checked" in text
    assert said[0] in (out / "report.txt").read_text().splitlines()
    assert "do not load it: nothing in it could be checked" in (out / "report.html").read_text()
    header = (out / "px4.params").read_text().splitlines()
    assert any(ln.startswith("# DO NOT LOAD: nothing in this file could be checked")
               for ln in header)
    assert read_px4_params(out / "px4.params")["TC_A0_ID"] == 2424842     # still readable
    # the whole log is checked, and says to load it
    assert main(["calibrate", str(whole), "--out", str(tmp_path / "ok"), "--no-compare"]) == 0
    text = capsys.readouterr().out
    assert "Load the parameter file only on board" in text and "Do not load" not in text


def test_the_least_log_calibrate_can_check_is_800_evenly_logged_samples():
    """The threshold the advice names is the code's: the held-out blocks of one log (5 time
    blocks of 20) hold a quarter of its samples, and verify's test judges an instance of at
    least MIN_SAMPLES (200) — 800 samples logged evenly reach it (791 do, the blocks' edges
    rounding), 790 do not."""
    from thermonet.workflows.calibrate_logs import MIN_GRADED_LOG_SAMPLES, held_out_blocks
    from thermonet.workflows.firmware_fit import MIN_SAMPLES

    assert MIN_GRADED_LOG_SAMPLES == 800 and MIN_SAMPLES == 200
    for n, enough in ((800, True), (791, True), (790, False)):
        t = np.arange(n, dtype=np.float64)
        inst = SensorInstance("gyro", 0, 1, t, 20.0 + t / 20.0, np.zeros((n, 3)))
        _, held = held_out_blocks(FlightLog(Path("x.ulg"), "px4", [inst], {}))
        assert (held.instances[0].n_samples >= MIN_SAMPLES) is enough


# ------------------------------------------------------------------- 2. a flight log refused
def test_calibrate_refuses_a_flight_log_and_points_to_learn(tmp_path, capsys):
    """A flight (the vehicle turning and accelerating): calibrate wrote TC_A0 from it and
    advised a wider range; verify refused the same log.  Now calibrate applies verify's own
    motion test (one definition) and refuses it in one line naming the file, the share of
    time still and `thermonet learn`; nothing is written.  The real logs of tests/data/real
    are too short to tell (not refused), and a simulated warm-up at rest is still."""
    from thermonet.workflows.verify_motion import moving_log

    flight = simulate_flights(1, seed=0)[0]
    log = write_flight(flight.log, flight.biases, tmp_path / "flight0001.ulg")
    assert main(["calibrate", str(log), "--out", str(tmp_path / "cal"), "--no-compare"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    why = moving_log(read_log(log))
    assert why is not None and "still in only" in why
    assert len(err) == 1 and err[0].startswith(f"thermonet: error: {log}: {why} — ")
    assert f"thermonet learn {tmp_path}" in err[0] and not (tmp_path / "cal").exists()
    for real in (REAL / "px4_ulog_sample" / "sample_log_small.ulg",
                 REAL / "ardupilot_bin_sample" / "test.BIN",
                 REAL / "px4_sitl_bias_variance" / "sample_px4_events.ulg"):
        assert moving_log(read_log(real)) is None, real
    for preset, ap in (("fc-board", "px4"), ("fc-board-cycle", "ardupilot")):
        assert moving_log(simulate_board(preset, autopilot=ap, seed=3)) is None


# ------------------------------------------------ 3. a kind with nothing fitted is not written
def _board_without_baro_and_gyros(tmp_path: Path, sys_id: float | None) -> Path:
    """The fc-board with no barometer or magnetometer in its log and every gyro sample zero
    (each gyro left out: "every sample is exactly zero")."""
    board = simulate_board("fc-board", seed=1, rate_hz=0.5)
    insts = [SensorInstance(i.kind, i.instance, i.device_id, i.time_s, i.temperature_c,
                            np.zeros_like(i.values)) if i.kind == "gyro" else i
             for i in board.instances if i.kind in ("gyro", "acc")]
    params = dict(board.params, **({} if sys_id is None else {"MAV_SYS_ID": sys_id}))
    return write_log(FlightLog(board.path, "px4", insts, params, board_id=board.board_id),
                     tmp_path / "board.ulg")


def test_a_kind_with_nothing_fitted_is_not_written_and_the_console_says_so(tmp_path, capsys):
    """calibrate wrote TC_B_ENABLE 0 and TC_B0..3_ID 0 for a log with no barometer, and
    TC_G_ENABLE 0 with every gyro slot cleared where every gyro was left out: loaded, the
    file wiped the board's own gyro and barometer calibration.  Now such a kind is not
    written at all (as learn's file and the ArduPilot writer leave what they did not fit),
    one line per kind says so on the console, in report.txt, results.json and the file's
    header; verify and thermonet's PX4 reader read the file."""
    log = _board_without_baro_and_gyros(tmp_path, sys_id=42)
    out = tmp_path / "cal"
    assert main(["calibrate", str(log), "--out", str(out), "--no-compare"]) == 0
    text = capsys.readouterr().out.splitlines()
    names = {r[2] for r in _rows(out / "px4.params")}
    assert not {n for n in names if n.startswith(("TC_B", "TC_G", "TC_M"))}
    assert {"TC_A_ENABLE", "TC_A0_ID", "TC_A2_X3_2", "TC_A3_ID"} <= names
    lines = ["TC_G*: not written (gyro0, gyro1, gyro2 not in the file): the board keeps its own",
             "TC_B*: not written (no barometer in the log): the board keeps its own"]
    doc = json.loads((out / "results.json").read_text())
    assert doc["not_written"] == lines
    for line in lines:
        assert line in text and line in (out / "report.txt").read_text().splitlines()
        assert f"# {line}" in (out / "px4.params").read_text().splitlines()
    p = read_px4_params(out / "px4.params")
    assert p["TC_A_ENABLE"] == 1 and "TC_G_ENABLE" not in p and "TC_B_ENABLE" not in p
    res = evaluate(read_param_file(out / "px4.params"), simulate_board("fc-board", seed=1,
                                                                      rate_hz=0.5))
    assert {n for n, d in res.items() if d["status"] == "judged"} == {"acc0", "acc1", "acc2"}
    assert all(res[n]["status"] == "not covered" for n in ("gyro0", "gyro1", "gyro2", "baro0"))
    # 6. the Vehicle-Id is the log's MAV_SYS_ID, said in the file
    assert {r[0] for r in _rows(out / "px4.params")} == {"42"}
    assert ("# Vehicle-Id 42: the vehicle's MAV_SYS_ID as the log records it (QGroundControl "
            "loads the file only onto that system id)") in (out / "px4.params").read_text()


def test_the_vehicle_id_is_the_logs_system_id_else_1_said_in_the_file(tmp_path):
    """The real PX4 log records MAV_SYS_ID (1); a simulated one records none: 1, and the file
    says so; a recorded value that is no MAVLink system id is not written."""
    real = read_log(REAL / "px4_ulog_sample" / "sample_log_small.ulg")
    assert real.params["MAV_SYS_ID"] == 1
    vid, why = px4_vehicle_id(real.params)
    assert vid == 1 and "the vehicle's MAV_SYS_ID as the log records it" in why
    assert px4_vehicle_id({"MAV_SYS_ID": 17.0})[0] == 17
    for params in ({}, {"MAV_SYS_ID": 0.0}, {"MAV_SYS_ID": 300.0}):
        vid, why = px4_vehicle_id(params)
        assert vid == 1 and why.startswith("Vehicle-Id 1: the log records ")
    log = _board_without_baro_and_gyros(tmp_path, sys_id=None)
    assert main(["calibrate", str(log), "--out", str(tmp_path / "cal"), "--no-compare",
                 "-q"]) == 0
    text = (tmp_path / "cal" / "px4.params").read_text()
    assert {r[0] for r in _rows(tmp_path / "cal" / "px4.params")} == {"1"}
    assert "# Vehicle-Id 1: the log records no MAV_SYS_ID (PX4's default is 1)" in text


# ------------------------------------------------------- 4. learn keeps a left-out sensor's slot
def test_px4_slots_keep_the_sensor_left_out_and_never_name_one_device_twice():
    """PX4 applies the first slot whose ID is the sensor's.  A sensor left out keeps its slot
    where the board's active slots are known; each fit takes the slot the board has for it
    (else a free one), the rest are cleared — so no two slots name one device.  With the
    board's slots unknown the kind is rewritten whole, as before."""
    def fit(dev: int) -> FirmwareFit:
        return FirmwareFit("gyro", dev, 25.0, 0.0, 50.0, np.zeros((3, 4)))

    a, b, c = fit(11), fit(22), fit(33)
    plan = px4_slot_plan([a, c], [22, 11, 33, 0], {22})
    assert plan == [22, a, c, None]
    plan = px4_slot_plan([a, c], [22, 0, 0, 99], {22})   # a, c new; 99 another board's: cleared
    assert plan == [22, a, c, None]
    plan = px4_slot_plan([a, c], [33, 22, 0, 0], {22})   # c keeps its slot 0, a a free one
    assert plan == [c, 22, a, None]
    assert px4_slot_plan([a, c], None, {22}) == [a, c, None, None]
    assert px4_slot_plan([a, b, c], [22, 11, 33, 0]) == [a, b, c, None]


def test_learn_keeps_the_slot_of_a_sensor_it_left_out(tmp_path, capsys):
    """Eight flights of the fc-board vehicle; from flight 5 on the board runs a thermal
    calibration (TC_G2_ID 2621474 active).  learn leaves gyro2 and acc1 out and does not learn
    acc2; its px4.params wrote TC_G2_ID 0 and TC_A1/A2_ID 0, wiping the board's calibration of
    them.  Now their slots are not written (the board keeps its own), the fitted sensors take
    the slots the board has for them, the console says so per sensor, verify reads the file,
    and the Vehicle-Id is the logs' MAV_SYS_ID."""
    flights = simulate_flights(8, seed=0)
    for f in flights:
        f.log.params["MAV_SYS_ID"] = 7.0
    logs = tmp_path / "logs"
    logs.mkdir()
    for k, f in enumerate(flights):
        write_flight(f.log, f.biases, logs / f"flight{k + 1:04d}.ulg")
    assert read_log(logs / "flight0008.ulg").params["TC_G2_ID"] == 2621474
    out = tmp_path / "learned"
    assert main(["learn", str(logs), "--out", str(out), "--no-compare", "--executor",
                 "serial"]) == 0
    text = capsys.readouterr().out.splitlines()
    doc = json.loads((out / "results.json").read_text())
    assert doc["instances"]["gyro2"]["status"] == "skipped"
    p = read_px4_params(out / "px4.params")
    assert p["TC_G0_ID"] == 2424842 and p["TC_G1_ID"] == 3670050 and p["TC_G3_ID"] == 0
    assert not [n for n in p if n.startswith(("TC_G2_", "TC_A1_", "TC_A2_", "TC_B"))]
    assert p["TC_A0_ID"] == 2424842 and p["TC_G_ENABLE"] == 1
    said = "TC_G2_* are not written: the board keeps its own (its slot, TC_G2_ID 2621474 in " \
        "the last log)"
    assert doc["instances"]["gyro2"]["parameter_file"] == said and f"  {said}" in text
    (acc2,) = doc["not_learned"]
    assert acc2["parameter_file"].startswith("TC_A2_* are not written: the board keeps its own")
    assert "# TC_G2_*: not written (device 2621474, not in this file): the board keeps its own" \
        in (out / "px4.params").read_text().splitlines()
    res = evaluate(read_param_file(out / "px4.params"), simulate_board("fc-board", seed=0,
                                                                      rate_hz=0.5))
    assert res["gyro2"]["status"] == "not covered" and res["gyro0"]["status"] == "judged"
    assert {r[0] for r in _rows(out / "px4.params")} == {"7"} and doc["mav_sys_id"] == 7


def test_calibrate_keeps_the_board_slot_of_an_instance_it_leaves_out(tmp_path, capsys):
    """The same rule in calibrate: a board logged with its thermal calibration on (TC_G_ENABLE
    1, gyro2 in slot 0, gyro0 in slot 1, gyro1 in slot 2), gyro1 left out (every sample zero).
    Its slot TC_G2_* is not written (it was cleared); gyro0 and gyro2 take the board's slots
    for them, so no two slots name one device; verify reads the file."""
    board = simulate_board("fc-board", seed=1, rate_hz=0.5)
    insts = [SensorInstance(i.kind, i.instance, i.device_id, i.time_s, i.temperature_c,
                            np.zeros_like(i.values)) if i.name == "gyro1" else i
             for i in board.instances if i.kind == "gyro"]
    ids = {i.name: i.device_id for i in insts}
    params = dict(board.params, TC_G_ENABLE=1.0, TC_G0_ID=float(ids["gyro2"]),
                  TC_G1_ID=float(ids["gyro0"]), TC_G2_ID=float(ids["gyro1"]), TC_G3_ID=0.0)
    log = write_log(FlightLog(board.path, "px4", insts, params, board_id=board.board_id),
                    tmp_path / "board.ulg")
    out = tmp_path / "cal"
    assert main(["calibrate", str(log), "--out", str(out), "--no-compare"]) == 0
    text = capsys.readouterr().out.splitlines()
    p = read_px4_params(out / "px4.params")
    assert (p["TC_G0_ID"], p["TC_G1_ID"], p["TC_G3_ID"]) == (ids["gyro2"], ids["gyro0"], 0)
    assert not [n for n in p if n.startswith("TC_G2_")]
    line = ("TC_G2_*: not written (gyro1 not in the file; the board's slot for it): the board "
            "keeps its own")
    assert line in text and f"# {line}" in (out / "px4.params").read_text().splitlines()
    doc = json.loads((out / "results.json").read_text())
    assert (doc["instances"]["gyro0"]["slot"], doc["instances"]["gyro2"]["slot"]) == (1, 0)
    res = evaluate(read_param_file(out / "px4.params"), simulate_board("fc-board", seed=1,
                                                                      rate_hz=0.5))
    assert res["gyro1"]["status"] == "not covered" and res["gyro2"]["slot"] == 0


# ----------------------------------------- 5. export: an instance directory's own sensor
@pytest.fixture(scope="module")
def calibrated(tmp_path_factory) -> Path:
    """A calibration (with its comparison) of the fc-board's IMU 2 gyro alone, logged with
    MAV_SYS_ID 42: gyro1 (device 3670050) in PX4 slot 0."""
    tmp = tmp_path_factory.mktemp("cal")
    board = simulate_board("fc-board", seed=2, rate_hz=0.5)
    board.instances = [i for i in board.instances if i.name == "gyro1"]
    board.params["MAV_SYS_ID"] = 42.0
    assert main(["calibrate", str(write_log(board, tmp / "board.ulg")), "--out",
                 str(tmp / "cal"), "--workers", "1", "-q"]) == 0
    return tmp / "cal"


def test_export_from_an_instance_directory_writes_its_own_sensor(calibrated, tmp_path, capsys):
    """``export cal/instances/gyro1 --format ardupilot-params`` wrote IMU 2's gyro as
    INS_TCAL1 (the default IMU 1), and ``--device-id 12345`` for a model of device 3670050
    was written silently.  Now the recorded sensor is the default (IMU 2; PX4: its device id
    and the slot calibrate gave it, with the log's Vehicle-Id), an explicit one that
    contradicts it is refused in one line naming both; a plain compare directory (no
    recorded instance) works as before."""
    inst = calibrated / "instances" / "gyro1"
    slot = json.loads((calibrated / "results.json").read_text())["instances"]["gyro1"]["slot"]
    assert slot == 0
    ap = tmp_path / "g1.parm"
    assert main(["export", str(inst), "--family", "px4-cubic", "--format", "ardupilot-params",
                 "--out", str(ap)]) == 0
    names = set(read_ardupilot_params(ap))
    assert "INS_TCAL2_ENABLE" in names and not [n for n in names if "TCAL1" in n]
    assert "(gyro1, device 3670050: IMU 2, INS_TCAL2, as its calibration records)" in \
        capsys.readouterr().out
    px4 = tmp_path / "g1.params"
    assert main(["export", str(inst), "--family", "px4-cubic", "--format", "px4-params",
                 "--out", str(px4)]) == 0
    capsys.readouterr()
    assert read_px4_params(px4)["TC_G0_ID"] == 3670050
    assert {r[0] for r in _rows(px4)} == {"42"}
    for args, words in (
            (["--format", "ardupilot-params", "--instance", "1"],
             ("--instance 1: ", "gyro1's model, IMU 2 (INS_TCAL2)", "defaults to 2")),
            (["--format", "px4-params", "--device-id", "12345"],
             ("--device-id 12345: ", "fitted on device 3670050", "defaults to 3670050")),
            (["--format", "px4-params", "--instance", "2"],
             ("--instance 2: ", "gyro1's model, slot 0", "defaults to 0"))):
        out = tmp_path / "x.out"
        assert main(["export", str(inst), "--family", "px4-cubic", "--out", str(out),
                     *args]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and all(w in err[0] for w in words), err
        assert not out.exists()
    # the same comparison as a plain compare directory: no recorded instance, as before
    plain = tmp_path / "plain"
    shutil.copytree(inst, plain)
    assert main(["export", str(plain), "--family", "px4-cubic", "--format",
                 "ardupilot-params", "--out", str(tmp_path / "p.parm")]) == 0
    assert "INS_TCAL1_ENABLE" in read_ardupilot_params(tmp_path / "p.parm")
    assert main(["export", str(plain), "--family", "px4-cubic", "--format", "px4-params",
                 "--out", str(tmp_path / "p.params")]) == 1
    assert "--device-id is required" in capsys.readouterr().err
    assert main(["export", str(plain), "--family", "px4-cubic", "--format", "px4-params",
                 "--device-id", "12345", "--out", str(tmp_path / "p.params")]) == 0
    assert read_px4_params(tmp_path / "p.params")["TC_G0_ID"] == 12345
    assert "Vehicle-Id 1: the model's calibration records no MAV_SYS_ID" in \
        (tmp_path / "p.params").read_text()


# --------------------------------------------------------------------- 7. the EKF's defaults
def test_the_ekf_suggestions_state_the_defaults_and_when_no_change_is_needed(calibrated):
    """ekf-recommendation.txt said "EKF2_GBIAS_INIT >= 0.000255 rad/s" where PX4's default
    is 0.1: a user copying the number would make the EKF far too confident.  Each line now
    states the default (from PX4's parameter definitions) and "no change needed" where the
    default already meets the bound; a bound above the default says to raise it."""
    text = (calibrated / "ekf-recommendation.txt").read_text().splitlines()
    noise = next(ln for ln in text if "EKF2_GYR_B_NOISE >=" in ln)
    init = next(ln for ln in text if "EKF2_GBIAS_INIT >=" in ln)
    assert float(init.split(">=")[1].split()[0]) < 0.1
    assert init.endswith("; PX4's default 0.1: no change needed")
    assert noise.endswith("; PX4's default 0.001: no change needed")
    assert any("a lower bound, not a value to set" in ln for ln in text)
    from thermonet.data.firmware import EKF_DEFAULTS, ekf_bound_line

    assert EKF_DEFAULTS["EKF2_GBIAS_INIT"] == 0.1 and EKF_DEFAULTS["EKF2_GYR_B_NOISE"] == 1e-3
    assert ekf_bound_line("EKF2_GBIAS_INIT", 0.15, "rad/s", "px4").endswith(
        "PX4's default 0.1: raise it to at least 0.15")
    assert ekf_bound_line("EK3_ABIAS_P_NSE", 0.01, "m/s^2/s", "ardupilot").endswith(
        "ArduPilot's default 0.02: no change needed")
