"""``simulate fc-board --runs N`` → ``calibrate LOG [LOG ...]`` → ``verify PARAMS LOG``, PX4 and
ArduPilot, through the command line and real log files.

The later log's drift is judged here with the firmware's formula re-implemented from the
source in ``tests/oracles.py`` (PX4 ``TemperatureCompensation::calc_thermal_offsets_3D/_1D``:
T clamped to [TMIN, TMAX], offset = sum_k X_k (T - TREF)^k, the slot whose ``TC_*_ID`` is the
sensor's device id; ArduPilot ``TCal::correct_sensor``: P(T - 35) - P(T_cal - 35), c_k * 1e-6),
independently of thermonet.data.firmware, on the log read back with pyulog / pymavlink.
"""

from __future__ import annotations

import json
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from oracles import px4_offsets, px4_slot, read_params
from thermonet.cli import main
from thermonet.core.errors import InputError
from thermonet.data.logs import read_log
from thermonet.data.logs.writers import write_log
from thermonet.sim.fcboard import simulate_board
from thermonet.workflows.verify import Limits, evaluate, read_param_file


def _binned_pp(temp: np.ndarray, y: np.ndarray) -> float:
    bins = np.floor(temp)
    return float(np.ptp([y[bins == b].mean() for b in np.unique(bins)]))


def _px4_later_log_cuts(params: dict[str, float], ulg: Path) -> dict[str, list[float]]:
    """Per instance and axis: binned drift before / after PX4's formula, on the log as
    pyulog reads it."""
    from pyulog import ULog

    cuts: dict[str, list[float]] = {}
    for d in ULog(str(ulg), ["sensor_gyro", "sensor_accel", "sensor_baro"]).data_list:
        t = {"sensor_gyro": "G", "sensor_accel": "A", "sensor_baro": "B"}[d.name]
        dev = int(np.median(d.data["device_id"]))
        pre = px4_slot(params, t, dev)
        assert pre is not None, (t, dev)
        temp = d.data["temperature"].astype(np.float64)
        off = px4_offsets(params, pre, temp)
        if t == "B":
            ys, offs = [d.data["pressure"].astype(np.float64)], [off]
        else:
            ys, offs = [d.data[a].astype(np.float64) for a in "xyz"], list(off.T)
        name = {"G": "gyro", "A": "acc", "B": "baro"}[t] + str(d.multi_id)
        cuts[name] = [_binned_pp(temp, y) / _binned_pp(temp, y - o)
                      for y, o in zip(ys, offs, strict=True)]
    return cuts


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[Path]]:
    """Three warm-ups of one board, as .ulg and as .bin, written by the command line.

    Seed 3: the third warm-up stays inside the range of the first two.  (Where a later
    warm-up runs hotter than the calibration the firmware clamps and the cut there is
    smaller; an axis whose drift is near the noise cannot be cut 3x at all — verify's
    floors, :class:`thermonet.workflows.verify.Limits`, are for those.)"""
    tmp = tmp_path_factory.mktemp("runs")
    out = {}
    for ext in (".ulg", ".bin"):
        assert main(["simulate", "fc-board", "--runs", "3", "--seed", "3",
                     "--out", str(tmp / f"board{ext}")]) == 0
        out[ext] = [tmp / f"board_run{k}{ext}" for k in (1, 2, 3)]
    return out


def test_simulate_runs_are_one_board_warmed_again(runs: dict[str, list[Path]]) -> None:
    logs = [read_log(p) for p in runs[".ulg"]]
    ids = [sorted((i.name, i.device_id) for i in lg.instances) for lg in logs]
    assert ids[0] == ids[1] == ids[2] and len(ids[0]) == 9   # 7 + 2 magnetometers
    g = [next(i for i in lg.instances if i.name == "gyro1") for lg in logs]
    # new warm-ups (other start temperatures) and new noise ...
    assert len({round(float(x.temperature_c[0]), 1) for x in g}) == 3
    assert not np.array_equal(g[0].values, g[1].values)
    # ... the same drift law: at the same temperature the binned outputs agree within noise
    common = [b for b in range(15, 45) if all(np.any(np.floor(x.temperature_c) == b) for x in g)]
    assert len(common) > 20
    for b in common:
        means = [x.values[np.floor(x.temperature_c) == b, 0].mean() for x in g]
        assert np.ptp(means) < 1e-3      # 5e-4 rad/s noise per sample; drift ~1e-2 rad/s
    assert read_log(runs[".bin"][0]).autopilot == "ardupilot"


@pytest.mark.parametrize("ext", [".ulg", ".bin"])
def test_calibrate_two_logs_then_verify_the_third(runs: dict[str, list[Path]], tmp_path: Path,
                                                  ext: str, capsys: pytest.CaptureFixture[str]
                                                  ) -> None:
    first, second, third = (str(p) for p in runs[ext])
    cal = tmp_path / "cal"
    assert main(["calibrate", first, second, "--out", str(cal), "--no-compare"]) == 0
    report = capsys.readouterr().out
    assert "held-out check fitted on the first 1 and applied to" in report
    assert "the parameter file is the refit on all 2 logs" in report
    doc = json.loads((cal / "results.json").read_text())
    assert doc["logs"] == [first, second] and doc["held_out_log"] == second
    # mag0 too on PX4 (TC_M*): its motion is checked within each log, never across the join
    # where one log ends hot and the next starts cold (issue 52); ArduPilot has no compass TCAL
    expect = {"gyro0", "gyro1", "gyro2", "acc0", "acc1", "acc2"} | (
        {"baro0", "mag0"} if ext == ".ulg" else set())
    # every instance gets parameters, the whole-degree IMU included (with its resolution)
    assert {n for n, d in doc["instances"].items() if d["status"] == "fitted"} == expect
    assert doc["instances"]["gyro2"]["resolution"]["step_c"] == 1.0
    for name in expect:
        held = doc["instances"][name]["held_out"]
        assert held["status"] == "judged" and min(held["cut"]) >= 3.0, (name, held)
    params = cal / ("px4.params" if ext == ".ulg" else "ardupilot.parm")
    out = tmp_path / "verify"
    assert main(["verify", str(params), third, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert text.rstrip().endswith("report: " + str(out / "report.html"))
    ver = json.loads((out / "results.json").read_text())
    assert ver["kind"] == "verification" and ver["passed"] is True
    judged = {n for n, d in ver["instances"].items() if d["status"] == "judged"}
    assert judged == expect
    HTMLParser().feed((out / "report.html").read_text())
    assert (out / "report.txt").read_text() == text[:text.index("report: ")]
    # each instance's line says its unit (the autopilots' SI units)
    for name, unit in (("gyro0", "[rad/s]"), ("acc0", "[m/s²]")):
        line, = (x for x in text.splitlines() if x.startswith(name))
        assert "binned drift p-p " + unit in line, line
    if ext == ".ulg":
        # the done-when: through PX4's own formula the later log's binned drift falls >= 3x
        cuts = _px4_later_log_cuts(read_params(params), Path(third))
        # (the magnetometer's TC_M* through PX4's formula: tests/test_magnetometers.py)
        assert set(cuts) == expect - {"mag0"}
        for name, c in cuts.items():
            assert min(c) >= 3.0, (name, c)
            # thermonet's verify reports the same numbers
            assert ver["instances"][name]["cut"] == pytest.approx(c, rel=1e-6)


def test_calibrate_one_log_and_verify_it_on_another_with_limits(runs: dict[str, list[Path]],
                                                                tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]
                                                                ) -> None:
    first, _, third = (str(p) for p in runs[".ulg"])
    assert main(["calibrate", first, "--out", str(tmp_path / "cal"), "--no-compare",
                 "-q"]) == 0
    doc = json.loads((tmp_path / "cal" / "results.json").read_text())
    # one log: no held-out log, the held-out check runs on a quarter of it in time blocks
    assert doc["held_out_log"] is None
    held = doc["instances"]["gyro0"]["held_out"]
    assert held["status"] == "judged" and held["data"].startswith("time blocks 3, 7, 11, 15, 19")
    params = str(tmp_path / "cal" / "px4.params")
    assert main(["verify", params, third, "--out", str(tmp_path / "v"), "-q"]) == 0
    assert json.loads((tmp_path / "v" / "results.json").read_text())["trained_on"] is None
    # the calibration's own directory as --out: it says what the directory holds (was "holds
    # no thermonet verification (no complete results.json)"), and leaves it as it was
    before = sorted(p.name for p in (tmp_path / "cal").iterdir())
    assert main(["verify", params, third, "--out", str(tmp_path / "cal"), "-q"]) == 1
    assert capsys.readouterr().err.strip() == (
        f"thermonet: error: {tmp_path / 'cal'}: --out holds a thermonet calibration, not a "
        "verification; choose another --out")
    assert sorted(p.name for p in (tmp_path / "cal").iterdir()) == before
    # on the very log it was fitted on (found by its bytes in the calibration's results.json,
    # copied under another name): a PASS on training data, and the report says so
    twin = tmp_path / "renamed.ulg"
    twin.write_bytes(Path(first).read_bytes())
    capsys.readouterr()
    assert main(["verify", params, str(twin), "--out", str(tmp_path / "vt")]) == 0
    out = capsys.readouterr().out
    assert f"warning: this log is {first}, which the parameters were fitted on" in out
    assert "PASS (on its own training log)" in out
    assert json.loads((tmp_path / "vt" / "results.json").read_text())["trained_on"] == first
    assert "which the parameters were fitted on" in (tmp_path / "vt" / "report.html").read_text()
    # an impossible limit: every axis FAILs, exit 3, the report says which
    assert main(["verify", params, third, "--out", str(tmp_path / "v2"), "--min-cut", "1e6",
                 "--gyro-floor", "0", "--acc-floor", "0", "--baro-floor", "0",
                 "--mag-floor", "0"]) == 3
    out = capsys.readouterr().out
    assert "FAIL" in out and "PASS" not in out.replace("PASS/FAIL", "")
    assert json.loads((tmp_path / "v2" / "results.json").read_text())["passed"] is False


def test_logs_of_two_boards_and_foreign_files_refused_in_one_line(
        runs: dict[str, list[Path]], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    other = simulate_board("fc-board", autopilot="px4", seed=3, run=1)
    for inst in other.instances:
        inst.device_id += 1                      # the same model of board, other sensors
    other_path = write_log(other, tmp_path / "other.ulg")
    first = str(runs[".ulg"][0])
    assert main(["calibrate", first, str(other_path), "--out", str(tmp_path / "c")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not the same board" in err
    assert "gyro0 2424843" in err and "gyro0 2424842" in err and first in err
    assert not (tmp_path / "c").exists()
    assert main(["calibrate", first, "--out", str(tmp_path / "c"), "--no-compare", "-q"]) == 0
    params = str(tmp_path / "c" / "px4.params")
    for log, expect in ((other_path, "belongs to another board: its device ids 396825, 2424842"),
                        (runs[".bin"][1], "is a PX4 parameter file; ")):
        assert main(["verify", params, str(log), "--out", str(tmp_path / "v")]) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and expect in err, err
        if "another board" in expect:
            assert "2424843" in err               # the log's ids named too
        else:
            assert err.endswith("is an ArduPilot log (verify needs the same autopilot)")
        assert not (tmp_path / "v").exists()


@pytest.mark.parametrize("ext", [".ulg", ".bin"])
def test_logs_of_two_boards_of_one_model_refused_by_their_board_ids(
        runs: dict[str, list[Path]], tmp_path: Path, ext: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Two boards of one model log the same sensors' device ids: the board's own id (PX4's
    sys_uuid, ArduPilot's system-id line) tells them apart; calibrate refuses them in one
    line naming both logs and both ids, before anything is written."""
    ap = "px4" if ext == ".ulg" else "ardupilot"
    other = simulate_board("fc-board", autopilot=ap, seed=4, run=1)   # another board, one model
    other_path = write_log(other, tmp_path / f"other{ext}")
    first = runs[ext][0]
    mine, theirs = read_log(first), read_log(other_path)
    assert [(i.name, i.device_id) for i in mine.instances] == [
        (i.name, i.device_id) for i in theirs.instances]
    assert mine.board_id and theirs.board_id and mine.board_id != theirs.board_id
    assert main(["calibrate", str(first), str(other_path), "--out", str(tmp_path / "c"),
                 "--no-compare"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not the same board" in err, err
    assert str(first) in err and str(other_path) in err
    assert mine.board_id in err and theirs.board_id in err
    assert not (tmp_path / "c").exists()
    # the file says the board it was fitted on; verify refuses it on the other board's log,
    # whose device ids are the same
    assert main(["calibrate", str(first), "--out", str(tmp_path / "c"), "--no-compare",
                 "-q"]) == 0
    params = tmp_path / "c" / ("px4.params" if ap == "px4" else "ardupilot.parm")
    assert f"# board id: {mine.board_id}\n" in params.read_text()
    assert json.loads((tmp_path / "c" / "results.json").read_text())["board_id"] == mine.board_id
    assert main(["verify", str(params), str(other_path), "--out", str(tmp_path / "v")]) == 1
    err = capsys.readouterr().err.strip()
    assert err == (f"thermonet: error: {params} belongs to another board: fitted on board "
                   f"{mine.board_id!r}, {other_path.name} is board {theirs.board_id!r} (two "
                   "boards of one model share their sensors' device ids; a thermal "
                   "calibration is one board's)"), err
    assert not (tmp_path / "v").exists()
    assert main(["verify", str(params), str(runs[ext][2]), "--out", str(tmp_path / "v"),
                 "-q"]) == 0                                     # its own board's next log


def test_log_outside_the_calibrated_range_warns_per_instance(runs: dict[str, list[Path]],
                                                             tmp_path: Path) -> None:
    from thermonet.workflows.calibrate import calibrate

    calibrate(runs[".ulg"][0], tmp_path / "c", compare=False)
    hot = read_log(runs[".ulg"][0])                       # the calibration log itself ...
    g0 = next(i for i in hot.instances if i.name == "gyro0")
    g0.temperature_c = g0.temperature_c + 15.0            # this one sensor runs far hotter
    hot_path = write_log(hot, tmp_path / "hot.ulg")
    res = evaluate(read_param_file(tmp_path / "c" / "px4.params"), read_log(hot_path), Limits())
    assert len(res["gyro0"]["warnings"]) == 1
    assert "outside the calibrated" in res["gyro0"]["warnings"][0]
    assert "holds the correction constant" in res["gyro0"]["warnings"][0]
    # 15 °C hotter: past the top only, and the warning names that side alone (not "0.0 °C
    # below")
    assert "°C above)" in res["gyro0"]["warnings"][0]
    assert "below" not in res["gyro0"]["warnings"][0]
    assert all(not d["warnings"] for n, d in res.items() if n != "gyro0")


def test_verify_reads_the_autopilots_own_files(runs: dict[str, list[Path]],
                                               tmp_path: Path) -> None:
    """A ``tempcal_IMU.py`` file (``NAME VALUE`` lines, no device ids) is applied IMU by IMU
    with a warning saying so; a ``process_sensor_caldata.py`` file (tab-separated, Python
    ``str`` floats, the ``TC_B0`` baro 100x off — PX4 issue #20051) is read and its baro
    FAILs where its gyros PASS."""
    from test_autopilot_parity import _px4_script, _tempcal_imu

    first, _, third = runs[".bin"]
    lines = [f"{k} {v}" for k, v in _tempcal_imu(first).items()]
    lines += [f"INS_TCAL{n}_ENABLE 1" for n in (1, 2, 3)]
    ap = tmp_path / "tcal.parm"
    ap.write_text("\n".join(lines) + "\n")
    res = evaluate(read_param_file(ap), read_log(third))
    for name in ("gyro0", "acc0", "gyro1", "acc1"):
        assert res[name]["status"] == "judged" and min(res[name]["cut"]) >= 3.0, name
        assert "names no device ids" in res[name]["warnings"][0]
    # the report names ArduPilot's IMU groups as the file does: INS_TCAL1 for IMU 0
    from thermonet.workflows.verify_report import format_verify_report

    text = format_verify_report({"params_file": str(ap), "log": str(third),
                                 "autopilot": "ardupilot", "instances": res, "passed": True,
                                 "limits": {"min_cut": 3.0, "floor": {}}})
    assert any(ln.startswith("gyro1 ") and " INS_TCAL2: binned drift p-p" in ln
               for ln in text.splitlines()), text
    first, _, third = runs[".ulg"]
    script = _px4_script(first)
    rows = ["# generated by a re-implementation of process_sensor_caldata.py (no TC_*_ENABLE)"]
    rows += [f"1\t1\t{k}\t{v}\t{6 if k.endswith('_ID') else 9}" for k, v in script.items()]
    px4 = tmp_path / "script.params"
    px4.write_text("\n".join(rows) + "\n")
    res = evaluate(read_param_file(px4), read_log(third))
    assert all(all(res[f"gyro{k}"]["passed"]) for k in range(3))
    assert all("has no TC_" in d["warnings"][0] for d in res.values() if d["status"] == "judged")
    assert res["baro0"]["passed"] == [False] and res["baro0"]["cut"][0] < 0.1


def test_a_calibration_not_applied_fails_and_a_pass_names_what_it_leaves_uncorrected(
        runs: dict[str, list[Path]], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The file's gyro slots with TC_G_ENABLE 0 (the firmware applies none of them): FAIL,
    exit 3, each gyro "not applied" (was: "not covered" and PASS); a file that calibrates
    the accelerometers and barometer only: PASS, and the verdict names the sensors it leaves
    uncorrected."""
    first, _, third = (str(p) for p in runs[".ulg"])
    assert main(["calibrate", first, "--out", str(tmp_path / "cal"), "--no-compare",
                 "-q"]) == 0
    text = (tmp_path / "cal" / "px4.params").read_text()
    assert "TC_G_ENABLE\t1\t" in text
    off = tmp_path / "off.params"
    off.write_text(text.replace("TC_G_ENABLE\t1\t", "TC_G_ENABLE\t0\t"))
    capsys.readouterr()
    assert main(["verify", str(off), third, "--out", str(tmp_path / "v1")]) == 3
    out = capsys.readouterr().out
    doc = json.loads((tmp_path / "v1" / "results.json").read_text())
    gyros = [n for n in doc["instances"] if n.startswith("gyro")]
    assert gyros and all(doc["instances"][n]["status"] == "not applied" for n in gyros)
    assert out.splitlines()[-2] == (f"FAIL: {', '.join(gyros)}: calibrated by the file but not "
                                    "applied (ENABLE is not 1)")
    # no gyro slot at all: the gyros are not covered, the rest judged and passing
    no_gyro = tmp_path / "nogyro.params"
    no_gyro.write_text("\n".join(ln for ln in text.splitlines()
                                 if not ln.split("\t")[2:3] or
                                 not ln.split("\t")[2].startswith("TC_G")) + "\n")
    assert main(["verify", str(no_gyro), third, "--out", str(tmp_path / "v2")]) == 0
    out = capsys.readouterr().out
    doc = json.loads((tmp_path / "v2" / "results.json").read_text())
    judged = [n for n, d in doc["instances"].items() if d["status"] == "judged"]
    left = [n for n, d in doc["instances"].items() if d["status"] == "not covered"]
    assert set(gyros) <= set(left) and judged
    assert out.splitlines()[-2] == (f"PASS for {', '.join(judged)}; not covered by this file: "
                                    f"{', '.join(left)} (their drift is not corrected)")
    # each judged instance names the parameters applied to it as the file does
    assert any(ln.startswith("acc0 ") and " TC_A0: binned drift p-p" in ln
               for ln in out.splitlines()), out


def test_a_file_with_one_sensor_of_an_imu_is_judged_on_it_and_leaves_the_other(
        runs: dict[str, list[Path]], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """ArduPilot's INS_TCAL<n> holds one IMU's gyro and accelerometer; a file with only the
    gyro's (what ``export`` writes for a gyro model, so loading it leaves the accelerometer's
    calibration alone) is judged on the gyro — the same cut as the whole tempcal_IMU.py file
    gives it — and the accelerometer is "not covered", named in the PASS line (was refused:
    "parameter INS_TCAL1_ACC1_X is missing").  Half an accelerometer group, or a group that
    enables nothing, is still refused in one line."""
    from test_autopilot_parity import _tempcal_imu

    first, _, third = runs[".bin"]
    full = _tempcal_imu(first)
    whole = tmp_path / "whole.parm"
    whole.write_text("".join(f"{k} {v}\n" for k, v in full.items()) + "INS_TCAL1_ENABLE 1\n")
    gyro = tmp_path / "gyro.parm"
    rows = {k: v for k, v in full.items() if k.startswith("INS_TCAL1_") and "_ACC" not in k}
    gyro.write_text("".join(f"{k},{v}\n" for k, v in rows.items()) + "INS_TCAL1_ENABLE,1\n")
    pf = read_param_file(gyro)
    assert pf.kinds == {"imu1": {"gyro"}}
    res = evaluate(pf, read_log(third))
    ref = evaluate(read_param_file(whole), read_log(third))
    assert res["gyro0"]["status"] == "judged"
    assert res["gyro0"]["cut"] == pytest.approx(ref["gyro0"]["cut"], rel=1e-12)
    assert res["acc0"]["status"] == "not covered"
    assert "INS_TCAL1_ACC*" in res["acc0"]["reason"]
    assert main(["verify", str(gyro), str(third), "--out", str(tmp_path / "v")]) == 0
    last = capsys.readouterr().out.splitlines()[-2]
    assert last.startswith("PASS for gyro0; not covered by this file: ") and "acc0" in last
    half = tmp_path / "half.parm"
    half.write_text(gyro.read_text() + f"INS_TCAL1_ACC1_X,{full['INS_TCAL1_ACC1_X']}\n")
    with pytest.raises(InputError, match="parameter INS_TCAL1_ACC1_Y is missing"):
        read_param_file(half)
    empty = tmp_path / "empty.parm"
    empty.write_text("INS_TCAL1_ENABLE,1\nINS_TCAL1_TMIN,0\nINS_TCAL1_TMAX,50\n")
    with pytest.raises(InputError, match="line 1: parameter INS_TCAL1_ENABLE = 1 but the file "
                                         "has none of INS_TCAL1_GYR"):
        read_param_file(empty)


def test_a_flight_log_is_refused_as_moving(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """verify judges a still warm-up: on a flight (the gyro still in about a third of its
    10-s windows, learn's test of stillness) every axis read ~1.0x FAIL with no hint; now
    one line, exit 1, nothing written.  The chamber warm-up of the same board passes the
    test (every window still)."""
    from thermonet.data.logs.flight_writers import write_flight
    from thermonet.sim.flights import simulate_flights
    from thermonet.workflows.verify_motion import moving_log

    flight = simulate_flights(1, seed=4)[0]
    log = write_flight(flight.log, flight.biases, tmp_path / "flight.ulg")
    board = write_log(simulate_board(seed=4), tmp_path / "board.ulg")
    assert moving_log(read_log(board)) is None
    assert moving_log(read_log(log)).startswith("the vehicle moves: gyro")
    assert main(["calibrate", str(board), "--out", str(tmp_path / "cal"), "--no-compare",
                 "-q"]) == 0
    capsys.readouterr()
    assert main(["verify", str(tmp_path / "cal" / "px4.params"), str(log), "--out",
                 str(tmp_path / "v")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"thermonet: error: {log}: the vehicle moves: ")
    assert "verify judges a warm-up at rest" in err[0] and not (tmp_path / "v").exists()


def test_a_pass_names_what_the_file_calibrates_but_the_log_could_not_judge() -> None:
    """The PASS line named the judged and the uncovered instances only: the ones the file
    calibrates that the log could not judge (a damaged gyro) are named too, with why."""
    from thermonet.workflows.verify_report import verdict_line

    why = "too damaged: 40% of its samples dropped"
    insts = {"acc0": {"status": "judged"}, "gyro0": {"status": "not judged", "reason": why},
             "gyro1": {"status": "not judged", "reason": why},
             "mag1": {"status": "not covered", "reason": "no TC_M*_ID equals its device id"}}
    assert verdict_line({"passed": True, "instances": insts}) == (
        f"PASS for acc0; not judged: gyro0, gyro1 ({why}); not covered by this file: mag1 "
        "(its drift is not corrected)")
    insts["acc0"] = {"status": "judged", "passed": [False]}
    assert verdict_line({"passed": False, "instances": insts}) == (
        f"FAIL: see the axes marked FAIL; not judged: gyro0, gyro1 ({why})")
