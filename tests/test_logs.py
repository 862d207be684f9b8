"""Flight-controller logs: the real PX4 / ArduPilot samples, simulated boards read back by the
autopilots' own tools (pyulog, pymavlink), undoing an applied calibration, bad logs."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from pymavlink import DFReader
from pyulog import ULog

from thermonet.cli import main
from thermonet.core.errors import InputError
from thermonet.data.firmware import ardupilot_correction
from thermonet.data.io import read_datasets
from thermonet.data.logs import read_log, temperature_step
from thermonet.data.logs.base import FlightLog
from thermonet.data.logs.writers import write_dataflash, write_log, write_ulog
from thermonet.sim.fcboard import simulate_board

REAL = Path(__file__).parent / "data" / "real"
ULG = REAL / "px4_ulog_sample" / "sample_log_small.ulg"
BIN = REAL / "ardupilot_bin_sample" / "test.BIN"


def test_real_px4_ulog_every_instance_with_its_device_id_and_pascals() -> None:
    log = read_log(ULG)
    names = sorted(i.name for i in log.instances)
    assert names == ["acc0", "acc1", "acc2", "baro0", "baro1", "gyro0", "gyro1", "gyro2",
                     "mag0", "mag1"]
    by = {i.name: i for i in log.instances}
    # device ids as the log's own calibration parameters name them
    assert by["gyro0"].device_id == int(log.params["CAL_GYRO0_ID"]) == 2424842
    for inst in log.instances:
        assert inst.n_samples == 6
    # this log is from before PX4 moved sensor_baro to Pa: ~1003 hPa → ~1.003e5 Pa, with a note
    raw = ULog(str(ULG), ["sensor_baro"]).data_list[0].data["pressure"]
    assert 900 < float(np.median(raw)) < 1100
    assert np.allclose(by["baro0"].values[:, 0], 100.0 * np.asarray(raw, dtype=np.float64))
    assert "hPa" in by["baro0"].notes[0]
    assert by["mag0"].temperature_c is None          # sensor_mag logs NaN temperature
    assert log.params["TC_G_ENABLE"] == 0


def test_real_ardupilot_bin_rotated_back_to_the_sensor_frame() -> None:
    log = read_log(BIN)
    by = {i.name: i for i in log.instances}
    assert sorted(by) == ["acc0", "acc1", "baro0", "gyro0", "gyro1", "mag0", "mag1", "mag2"]
    assert log.params["AHRS_ORIENTATION"] == 8                       # ROLL_180
    assert by["gyro0"].device_id == int(log.params["INS_GYR_ID"])
    # independent: the first IMU message read with pymavlink, ROLL_180 inverse = (x, -y, -z)
    f = DFReader.DFReader_binary(str(BIN))
    m = f.recv_match(type="IMU")
    assert np.allclose(by["gyro0"].values[0], [m.GyrX, -m.GyrY, -m.GyrZ], atol=1e-12)
    scale = np.array([log.params[f"INS_ACCSCAL_{a}"] for a in "XYZ"])
    assert np.allclose(by["acc0"].values[0], np.array([m.AccX, -m.AccY, -m.AccZ]) / scale)
    assert by["acc0"].values[0, 2] > 9.0          # gravity on +z in the sensor frame
    assert by["gyro0"].temperature_c[0] == pytest.approx(m.T)
    assert any("AHRS_ORIENTATION 8" in n for n in by["gyro0"].notes)


def test_real_ardupilot_bin_magnetometers_in_microtesla_calibration_undone() -> None:
    """``MAG`` is milligauss after ``Compass::correct_field`` ((raw + ofs) through the
    COMPASS_DIA/ODI matrix, + motor offsets); the reader gives the driver's field in µT."""
    log = read_log(BIN)
    by = {i.name: i for i in log.instances}
    assert by["mag0"].device_id == int(log.params["COMPASS_DEV_ID"]) == 466441
    assert by["mag1"].device_id == int(log.params["COMPASS_DEV_ID2"])
    f = DFReader.DFReader_binary(str(BIN))
    m = f.recv_match(type="MAG")                      # the first compass (MAG, MAG2, MAG3)
    p = log.params
    mat = np.array([[p["COMPASS_DIA_X"], p["COMPASS_ODI_X"], p["COMPASS_ODI_Y"]],
                    [p["COMPASS_ODI_X"], p["COMPASS_DIA_Y"], p["COMPASS_ODI_Z"]],
                    [p["COMPASS_ODI_Y"], p["COMPASS_ODI_Z"], p["COMPASS_DIA_Z"]]])
    field = np.array([m.MagX, m.MagY, m.MagZ], dtype=float)
    raw = np.linalg.solve(mat, field) - np.array([m.OfsX, m.OfsY, m.OfsZ], dtype=float)
    assert np.allclose(by["mag0"].values[0], 0.1 * raw, atol=1e-9)      # mG -> µT
    assert by["mag0"].temperature_c is None                            # MAG has no temperature
    assert 20.0 < np.linalg.norm(by["mag1"].values[0]) < 70.0          # the Earth's field, µT
    assert any("soft-iron" in n for n in by["mag0"].notes)


@pytest.mark.parametrize("path", [ULG, BIN])
def test_info_lists_every_instance(path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    log = read_log(path)
    for inst in log.instances:
        line = next(x for x in out.splitlines() if x.startswith(inst.name + " "))
        assert str(inst.device_id) in line and str(inst.n_samples) in line
        if inst.temperature_c is not None:
            assert f"{np.ptp(inst.temperature_c):.2f}" in line
            assert f"{temperature_step(inst.temperature_c):.3g}" in line


def test_temperature_step() -> None:
    assert temperature_step(np.array([20.0, 21.0, 21.0, 22.0, 24.0])) == 1.0
    assert temperature_step(np.arange(0, 5, 0.01)) == pytest.approx(0.01)
    assert temperature_step(None) is None


@pytest.mark.parametrize("preset", ["fc-board", "fc-board-cycle"])
def test_simulated_ulog_read_back_by_pyulog(tmp_path: Path, preset: str) -> None:
    board = simulate_board(preset, autopilot="px4", seed=1, rate_hz=0.1)
    path = write_ulog(board, tmp_path / "board.ulg")
    ulog = ULog(str(path))
    assert ulog.initial_parameters["SYS_CAL_TMIN"] == pytest.approx(5.0)
    assert ulog.initial_parameters["TC_G_ENABLE"] == 0
    topics = {(d.name, d.multi_id): d.data for d in ulog.data_list}
    assert sorted(topics) == sorted([("sensor_gyro", k) for k in range(3)]
                                    + [("sensor_accel", k) for k in range(3)]
                                    + [("sensor_baro", 0)]
                                    + [("sensor_mag", 0), ("sensor_mag", 1)])
    g1 = next(i for i in board.instances if i.name == "gyro1")
    d = topics[("sensor_gyro", 1)]
    assert np.all(d["device_id"] == g1.device_id)
    assert np.allclose(d["x"], g1.values[:, 0], atol=1e-6)
    assert np.allclose(d["temperature"], g1.temperature_c, atol=1e-4)
    baro = topics[("sensor_baro", 0)]
    assert 1.0e5 < float(np.median(baro["pressure"])) < 1.03e5        # Pa, as current PX4
    temps = next(i for i in board.instances if i.name == "gyro0").temperature_c
    if preset == "fc-board":
        assert np.all(np.diff(temps[::10]) > -0.2)                   # warming only
    else:
        assert temps[-1] < temps.max() - 20                          # warmed, then cooled


def test_simulated_dataflash_read_back_by_pymavlink(tmp_path: Path) -> None:
    board = simulate_board("fc-board", autopilot="ardupilot", seed=2, rate_hz=0.1)
    path = write_dataflash(board, tmp_path / "board.bin")
    f = DFReader.DFReader_binary(str(path))
    imus: dict[int, list[list[float]]] = {}
    baro = []
    while True:
        m = f.recv_match(type=["IMU", "BARO"])
        if m is None:
            break
        if m.get_type() == "IMU":
            imus.setdefault(m.I, []).append([m.GyrX, m.AccZ, m.T])
        else:
            baro.append(m.Press)
    assert f.params["INS_TCAL1_ENABLE"] == 0 and f.params["INS_GYR2_ID"] == 3670050
    assert sorted(imus) == [0, 1, 2]
    g2 = next(i for i in board.instances if i.name == "gyro2")
    a = np.array(imus[2])
    assert np.allclose(a[:, 0], g2.values[:, 0], atol=1e-6)
    assert np.allclose(a[:, 1], -9.80665, atol=0.5)
    assert np.allclose(a[:, 2], np.round(a[:, 2]))                    # the whole-degree IMU
    assert len(baro) == g2.n_samples


def test_board_id_from_the_real_logs_and_every_simulated_board_its_own(tmp_path: Path) -> None:
    """The board's own id (two boards of one model share the sensors' device ids): PX4's
    ``sys_uuid`` info field, ArduPilot's system-id MSG line, read independently with pyulog /
    pymavlink; the simulator draws one per seed (the same for every run) and writes it where
    the firmware does, so it survives the round trip."""
    assert read_log(ULG).board_id == ULog(str(ULG), []).msg_info_dict["sys_uuid"] \
        == "000600000000383638393239510d0035002d"
    f = DFReader.DFReader_binary(str(BIN))
    lines = []
    while (m := f.recv_match(type="MSG")) is not None:
        lines.append(m.Message)
    assert read_log(BIN).board_id == "PX4v4 00360029 30365103 31323731" == lines[2]
    for ap, ext in (("px4", ".ulg"), ("ardupilot", ".bin")):
        logs = {(seed, run): simulate_board("fc-board", autopilot=ap, seed=seed, rate_hz=0.02,
                                            run=run) for seed, run in ((0, 0), (0, 1), (1, 0))}
        back = {k: read_log(write_log(b, tmp_path / f"s{k[0]}r{k[1]}{ext}"))
                for k, b in logs.items()}
        for k, b in logs.items():
            assert b.board_id and back[k].board_id == b.board_id
        assert back[0, 1].board_id == back[0, 0].board_id               # one board, two runs
        assert back[1, 0].board_id != back[0, 0].board_id               # two boards ...
        assert [i.device_id for i in back[1, 0].instances] == [         # ... of one model
            i.device_id for i in back[0, 0].instances]
    # where the firmware writes it, as the autopilots' own tools read it
    px4 = simulate_board("fc-board", autopilot="px4", seed=1, rate_hz=0.02)
    assert ULog(str(tmp_path / "s1r0.ulg"), []).msg_info_dict["sys_uuid"] == px4.board_id
    assert len(px4.board_id or "") == 36                     # 18 bytes in hex, as PX4's
    msg = DFReader.DFReader_binary(str(tmp_path / "s1r0.bin")).recv_match(type="MSG")
    assert msg.Message == logs[1, 0].board_id
    assert re.fullmatch(r"\S+( [0-9A-F]{8}){3}", msg.Message)   # ChibiOS's get_system_id


def test_ardupilot_applied_calibration_is_undone(tmp_path: Path) -> None:
    """A log recorded with INS_TCAL1 enabled: the reader adds the firmware's correction back."""
    board = simulate_board("fc-board", autopilot="ardupilot", seed=3, rate_hz=0.1)
    p = dict(board.params)
    p.update({"INS_TCAL1_ENABLE": 1.0, "INS_TCAL1_TMIN": 10.0, "INS_TCAL1_TMAX": 45.0,
              "INS_GYR1_CALTEMP": 20.0, "INS_ACC1_CALTEMP": 20.0})
    rng = np.random.default_rng(0)
    for kind in ("GYR", "ACC"):
        for k in (1, 2, 3):
            for ax in "XYZ":
                p[f"INS_TCAL1_{kind}{k}_{ax}"] = float(rng.normal(0, 10.0 ** (3 - k)))
    raw = {i.name: i.values.copy() for i in board.instances}
    for inst in board.instances:
        if inst.instance == 0 and inst.kind in ("gyro", "acc"):
            inst.values = inst.values - ardupilot_correction(p, inst.kind, inst.temperature_c,
                                                             20.0, imu=1)
    board.params = p
    back = read_log(write_dataflash(board, tmp_path / "tcal.bin"))
    for inst in back.instances:
        if inst.kind in ("baro", "mag"):
            continue
        assert np.allclose(inst.values, raw[inst.name], atol=2e-5), inst.name
        assert any("INS_TCAL1_ENABLE=1" in n for n in inst.notes) == (inst.instance == 0)


def test_old_px4_baro_in_hpa_is_converted(tmp_path: Path) -> None:
    board = simulate_board("fc-board", autopilot="px4", seed=4, rate_hz=0.1)
    baro = next(i for i in board.instances if i.kind == "baro")
    pa = baro.values.copy()
    baro.values = pa / 100.0
    back = next(i for i in read_log(write_ulog(board, tmp_path / "old.ulg")).instances
                if i.kind == "baro")
    assert np.allclose(back.values, pa, rtol=1e-6)
    assert "hPa" in back.notes[0]


def test_read_datasets_reads_one_instance(tmp_path: Path) -> None:
    path = write_log(simulate_board("fc-board", seed=5, rate_hz=0.1), tmp_path / "b.ulg")
    ds = read_datasets(f"{path}#acc1")
    assert ds.device_id == "3670058" and ds.axes == ["acc_x", "acc_y", "acc_z"]
    assert ds[0].units["acc_x"] == "m/s^2"
    with pytest.raises(InputError, match="several sensor instances"):
        read_datasets(path)
    with pytest.raises(InputError, match="no sensor instance 'gyro9'"):
        read_datasets(f"{path}#gyro9")


def _bad(tmp_path: Path, name: str, data: bytes) -> Path:
    p = tmp_path / name
    p.write_bytes(data)
    return p


@pytest.mark.parametrize("what", ["truncated-ulog", "garbage-ulog", "garbage-bin",
                                  "no-sensors", "sitl-zeros", "no-temperature"])
def test_bad_logs_one_line_exit_1(tmp_path: Path, what: str,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    board = simulate_board("fc-board", autopilot="px4", seed=6, rate_hz=0.05)
    if what == "truncated-ulog":
        full = write_ulog(board, tmp_path / "full.ulg").read_bytes()
        path, expect = _bad(tmp_path, "t.ulg", full[:200]), "no sensor topics"
    elif what == "garbage-ulog":
        path, expect = _bad(tmp_path, "g.ulg", b"\x00garbage" * 50), "not a readable ULog"
    elif what == "garbage-bin":
        path, expect = _bad(tmp_path, "g.bin", b"\x00garbage" * 50), "not an ArduPilot DataFlash"
    else:
        if what == "no-sensors":
            board = FlightLog(board.path, "px4", [], board.params)
            expect = "no sensor topics"
        elif what == "sitl-zeros":
            for inst in board.instances:
                inst.values = np.zeros_like(inst.values)
            expect = "SITL"
        else:
            for inst in board.instances:
                inst.temperature_c = None
            expect = "no sensor reports a temperature"
        path = write_ulog(board, tmp_path / f"{what}.ulg")
    for cmd in (["info", str(path)], ["calibrate", str(path), "--out", str(tmp_path / "o")]):
        assert main(cmd) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(path) in err and expect in err
    assert not (tmp_path / "o").exists()


def test_dataflash_tclr_used_when_no_imu_messages(tmp_path: Path) -> None:
    """ArduPilot's learning log (TCLR: TimeUS, I, SType, Temp, X, Y, Z; SType 0 accel, 1 gyro)."""
    import struct

    def msg(mtype: int, payload: bytes) -> bytes:
        return b"\xa3\x95" + bytes([mtype]) + payload

    fmt = "<BB4s16s64s"
    data = msg(128, struct.pack(fmt, 128, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns"))
    data += msg(128, struct.pack(fmt, 64, 31, b"PARM", b"QNf", b"TimeUS,Name,Value"))
    data += msg(128, struct.pack(fmt, 67, 29, b"TCLR", b"QBBffff", b"TimeUS,I,SType,Temp,X,Y,Z"))
    data += msg(64, struct.pack("<Q16sf", 0, b"INS_GYR_ID", 2424842.0))
    t = np.arange(50) * 0.5
    for i, ti in enumerate(t):
        for stype, xyz in ((0, (0.1, 0.2, -9.8)), (1, (0.01 * i, 0.0, -0.01))):
            data += msg(67, struct.pack("<QBBffff", int(ti * 1e6), 0, stype, 20.0 + 0.1 * i,
                                        *xyz))
    path = _bad(tmp_path, "tclr.bin", data)
    log = read_log(path)
    by = {i.name: i for i in log.instances}
    assert sorted(by) == ["acc0", "gyro0"] and by["gyro0"].device_id == 2424842
    assert np.allclose(by["gyro0"].values[:, 0], 0.01 * np.arange(50), atol=1e-6)
    assert np.allclose(by["acc0"].values[0], [0.1, 0.2, -9.8], atol=1e-6)
    assert np.allclose(by["gyro0"].temperature_c, 20.0 + 0.1 * np.arange(50), atol=1e-5)
    assert "TCLR" in by["gyro0"].notes[0]


@pytest.mark.parametrize("src, name, hint", [
    ("px4_ulog_sample/sample_log_small.ulg", "log.bin",
     "not an ArduPilot DataFlash log (no 0xA3 0x95 header): it starts as a PX4 ULog does "
     "(name it .ulg)"),
    ("ardupilot_bin_sample/test.BIN", "log.ulg",
     "; it starts as an ArduPilot DataFlash log does (name it .bin)")])
def test_a_log_under_the_other_autopilots_extension_is_told_so(
        tmp_path: Path, src: str, name: str, hint: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A real ULog renamed .bin (or a real DataFlash log renamed .ulg) is refused in one line
    that says which log it is and what to name it."""
    path = tmp_path / name
    path.write_bytes((Path(__file__).parent / "data" / "real" / src).read_bytes())
    assert main(["info", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"thermonet: error: {path}: ") and \
        err[0].endswith(hint), err


def test_info_says_when_no_temperature_ever_changes(capsys: pytest.CaptureFixture[str]) -> None:
    """The real PX4 SITL log (every thermometer at 0 °C): info names the instances whose
    temperature never changes, once; a real flight log's (its temperatures move) says nothing."""
    real = Path(__file__).parent / "data" / "real"
    assert main(["info", str(real / "px4_sitl_bias_variance" / "sample_px4_events.ulg")]) == 0
    out = capsys.readouterr().out
    said = [ln.strip() for ln in out.splitlines() if "never changes" in ln]
    assert said == ["acc0, baro0, baro1, gyro0, mag0: the temperature never changes (the same "
                    "value on every sample: a SITL log, or a thermometer stuck at one value): "
                    "nothing to calibrate from"], out
    assert main(["info", str(real / "px4_ulog_sample" / "sample_log_small.ulg")]) == 0
    assert "never changes" not in capsys.readouterr().out
