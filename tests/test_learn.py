"""``thermonet learn`` (thermonet.workflows.learn, .learn_data) on simulated flights of one
vehicle written as real ULog / DataFlash files: accuracy on a held-out flight against the
simulator's truth and against a chamber calibration of the same board, the estimator's lag,
divergences rejected, bad logs refused in one line while the good ones count, the cache that
resumes a job and the growth of a directory.

The truth is the simulator's (thermonet.sim.flights.true_drift, the fc-board law); the chamber
calibration is calibrate's own firmware fit of ``simulate_board`` with the same seed."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from thermonet.cli import main
from thermonet.core.errors import ThermonetError
from thermonet.data.firmware import FirmwareFit
from thermonet.data.logs.flight_writers import write_flight
from thermonet.data.logs.writers import write_log
from thermonet.sim.fcboard import simulate_board
from thermonet.sim.flights import EKF_TAU_S, simulate_flights
from thermonet.workflows.firmware_fit import fit_firmware
from thermonet.workflows.learn import format_learn_report, learn
from thermonet.workflows.learn_data import ROBUST_S, InstanceWindows, median_within_flights
from thermonet.workflows.learn_fit import binned_pp
from thermonet.workflows.magnetometer import fit_correction
from thermonet.workflows.verify import Limits

#: instances the estimator runs on (IMU 2's gyro is learned from still windows only)
EKF_INSTANCES = ("gyro0", "gyro1", "acc0", "acc1")


def _write(flights, root: Path, ext: str) -> list[Path]:
    root.mkdir(parents=True, exist_ok=True)
    return [write_flight(f.log, f.biases, root / f"flight{k + 1:03d}{ext}")
            for k, f in enumerate(flights)]


def _fit(d: dict) -> FirmwareFit:
    f = d["firmware"]
    return FirmwareFit(d["kind"], d["device_id"], f["t_ref"], f["t_min"], f["t_max"],
                       np.asarray(f["coef"]))


def _judge(doc: dict, held, seed: int, autopilot: str) -> dict[str, list[tuple]]:
    """Per EKF instance and axis: (raw, learned, chamber) binned drift p-p on the held-out
    flight's true drift at its logged temperature."""
    board = simulate_board(seed=seed, autopilot=autopilot, rate_hz=0.2)
    out = {}
    for inst in held.log.instances:
        if inst.name not in EKF_INSTANCES:
            continue
        temp, truth = inst.temperature_c, held.truth[inst.name]
        learned = truth - fit_correction(_fit(doc["instances"][inst.name]), temp)
        chamber_inst = next(i for i in board.instances if i.name == inst.name)
        chamber = truth - fit_correction(fit_firmware(chamber_inst, autopilot), temp)
        out[inst.name] = list(zip(binned_pp(temp, truth), binned_pp(temp, learned),
                                  binned_pp(temp, chamber), strict=True))
    return out


@pytest.mark.parametrize("autopilot,ext", [
    ("px4", ".ulg"), pytest.param("ardupilot", ".bin", marks=pytest.mark.slow)])
def test_held_out_flight_against_truth_and_chamber(tmp_path, autopilot, ext):
    """Learned from 19 flights, applied to the 20th: per axis the binned drift is at most 0.3×
    raw, and at most 1.5× a chamber calibration of the same board or within verify's floor
    (a drift that small no longer matters); the lag chosen is near the estimator's."""
    seed = 7
    flights = simulate_flights(20, seed=seed, autopilot=autopilot)
    paths = _write(flights[:-1], tmp_path / "logs", ext)
    doc = learn(paths, tmp_path / "out", executor="serial", compare=False)
    assert len(doc["logs"]) == 19 and not doc["refused"]
    floor = Limits().floor
    for name, axes in _judge(doc, flights[-1], seed, autopilot).items():
        kind = name[:-1]
        # the lag is told within a step of the grid around the estimator's (the score is flat
        # near its minimum where the drift is small)
        assert 0.7 * EKF_TAU_S[kind] <= doc["instances"][name]["lag_s"] <= 1.5 * EKF_TAU_S[
            kind], name
        for raw, got, chamber in axes:
            if raw <= floor[kind]:
                continue
            assert got <= 0.3 * raw, (name, raw, got)
            assert got <= max(1.5 * chamber, floor[kind]), (name, got, chamber)
    text = (tmp_path / "out" / ("px4.params" if autopilot == "px4" else "ardupilot.parm"))
    assert text.is_file()


def test_divergences_are_rejected(tmp_path):
    """Estimators that wandered off in some flights: their windows are left out."""
    flights = simulate_flights(12, seed=3)
    paths = _write(flights, tmp_path / "logs", ".ulg")
    doc = learn(paths, tmp_path / "out", executor="serial", compare=False)
    rejected = sum(doc["instances"][n]["rejected_windows"] for n in EKF_INSTANCES)
    assert rejected > 0
    assert all(doc["instances"][n]["status"] == "fitted" for n in EKF_INSTANCES)


def test_every_fit_reads_each_flights_running_median_never_across_two():
    """The windows every fit reads are each flight's running median (scipy's
    ``median_filter``, ``mode="nearest"``, as the oracle), over kept windows in time order:
    a flight's first windows (its coldest) take nothing of the flight before (its hottest);
    windows left out stay out of every median."""
    from scipy.ndimage import median_filter

    g = np.random.default_rng(0)
    n = 60
    flight = np.repeat([1, 0], n)                      # stored out of flight order
    time_s = np.concatenate([np.arange(n), np.arange(n)]) * 10.0 + 5.0
    warm = np.linspace(0.0, 1.0, n)                    # each flight warms: drift 0 -> 1
    drift = np.column_stack([np.concatenate([warm, warm])] * 3) + \
        0.01 * g.standard_normal((2 * n, 3))
    drift[n + 3] += 50.0                               # a burst the median removes
    keep = np.ones(2 * n, dtype=bool)
    keep[7] = False                                    # a divergence left out
    inst = InstanceWindows(kind="gyro", device_id=1, name="gyro0", flights=["a", "b"],
                           flight=flight, time_s=time_s, temp=20.0 + 30.0 * drift[:, 0],
                           drifts={"0": drift.copy()}, weight=np.full(2 * n, 10.0),
                           still=np.zeros(2 * n, dtype=bool), keep=keep, window_s=10.0)
    span = median_within_flights(inst)
    assert span == 31 and ROBUST_S == 310.0            # PX4's 31 samples, 10-s windows
    got = inst.drift
    for f in (0, 1):
        sel = np.flatnonzero(keep & (flight == f))
        want = median_filter(drift[sel], size=(span, 1), mode="nearest")
        np.testing.assert_array_equal(got[sel], want)   # the same order statistics
    assert got[7, 0] == drift[7, 0]                    # left out: untouched
    assert np.all(np.abs(got[n:n + 5, 0]) < 0.2)       # a flight's start: its own cold values
    assert abs(got[n + 3, 0]) < 0.2                    # the burst is gone


def _bad_logs(root: Path) -> dict[str, Path]:
    """One log of each kind learn must refuse, each named for what it lacks."""
    root.mkdir(parents=True, exist_ok=True)
    bad = {}
    other = simulate_flights(1, seed=21)[0]
    for inst in other.log.instances:
        inst.device_id += 7
    for b in other.biases:
        b.gyro_device_id += 7
        b.accel_device_id += 7
    bad["other"] = write_flight(other.log, other.biases, root / "x_other_vehicle.ulg")
    twin = simulate_flights(1, seed=25)[0]        # the same model: same ids, its own board id
    bad["board"] = write_flight(twin.log, twin.biases, root / "x_other_board.ulg")
    bad["no_bias"] = write_log(simulate_board(seed=1, rate_hz=0.05), root / "x_chamber.ulg")
    never = simulate_flights(1, seed=22)[0]
    for b in never.biases:
        b.gyro_valid = np.zeros(b.time_s.size, dtype=bool)
        b.accel_valid = np.zeros(b.time_s.size, dtype=bool)
    bad["never"] = write_flight(never.log, never.biases, root / "x_never_converged.ulg")
    jump = simulate_flights(1, seed=23)[0]
    for b in jump.biases:
        b.time_s = np.where(np.arange(b.time_s.size) >= 300, b.time_s + 900.0, b.time_s)
    bad["jump"] = write_flight(jump.log, jump.biases, root / "x_clock_jump.ulg")
    ap = simulate_flights(1, seed=24, autopilot="ardupilot")[0]
    bad["ardupilot"] = write_flight(ap.log, ap.biases, root / "x_ardupilot.bin")
    return bad


def test_bad_logs_one_line_each_good_ones_counted(tmp_path, capsys):
    """Another vehicle's ids, another board of the same model (its board id), no bias topic,
    never converged, a clock jump, an ArduPilot log among PX4 logs: one line each naming the
    log and what it lacks; the good logs are used."""
    good = _write(simulate_flights(4, seed=5), tmp_path / "logs", ".ulg")
    bad = _bad_logs(tmp_path / "logs")
    rc = main(["learn", str(tmp_path / "logs"), "--out", str(tmp_path / "out"),
               "--executor", "serial", "--no-compare"])
    assert rc == 0
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    assert len(doc["logs"]) == len(good)
    why = {Path(r["log"]).name: r["reason"] for r in doc["refused"]}
    assert set(why) == {p.name for p in bad.values()}
    assert "another vehicle" in why["x_other_vehicle.ulg"]
    assert "another board of the same model" in why["x_other_board.ulg"]
    assert "estimator_sensor_bias" in why["x_chamber.ulg"]
    assert "never converged" in why["x_never_converged.ulg"]
    assert "clock jumps" in why["x_clock_jump.ulg"]
    assert "an ArduPilot log among px4" in why["x_ardupilot.bin"]
    out = capsys.readouterr().out
    for p in bad.values():
        lines = [line for line in out.splitlines() if p.name in line]
        assert len(lines) == 1, lines
    # the parameter file as the results file is named (under --out), the instances in order
    assert f"parameter file: {tmp_path / 'out' / doc['params_file']}" in out.splitlines()
    assert list(doc["instances"]) == sorted(doc["instances"])


def test_no_usable_log_is_one_line_and_nothing_written(tmp_path, capsys):
    """Only logs learn cannot use: exit 1, one line, no output directory."""
    root = tmp_path / "logs"
    write_log(simulate_board(seed=1, rate_hz=0.05), root / "chamber.ulg")
    rc = main(["learn", str(root), "--out", str(tmp_path / "out"), "--executor", "serial"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len([e for e in err if "no log to learn from" in e]) == 1
    assert "chamber.ulg" in err[-1] and not (tmp_path / "out").exists()


def test_resume_from_the_cache_and_grow(tmp_path, capsys):
    """Every log is cached as it is read (on the process pool): run again, nothing is read
    again; add flights, only they are read, and the report says what changed."""
    flights = simulate_flights(8, seed=9)
    logs = tmp_path / "logs"
    _write(flights[:5], logs, ".ulg")
    out = tmp_path / "out"
    assert main(["learn", str(logs), "--out", str(out), "--workers", "2", "--no-compare"]) == 0
    assert len(list((out / "cache").glob("*.json"))) == 5
    first = json.loads((out / "results.json").read_text())
    capsys.readouterr()
    for k, f in enumerate(flights[5:], start=6):
        write_flight(f.log, f.biases, logs / f"flight{k:03d}.ulg")
    assert main(["learn", str(logs), "--out", str(out), "--executor", "serial",
                 "--no-compare"]) == 0
    captured = capsys.readouterr()
    assert "8 logs: 5 read before (cache), 3 to read" in captured.err
    doc = json.loads((out / "results.json").read_text())
    assert doc["changes"][0] == "flights: 5 -> 8"
    assert any(c.startswith("gyro0: flights 5 -> 8") for c in doc["changes"])
    assert "changed: flights: 5 -> 8" in captured.out
    assert first["instances"]["gyro0"]["firmware"] != doc["instances"]["gyro0"]["firmware"]
    # a copy of a flight under another name is that flight once, not a ninth: refused in one
    # line; nothing else changed, and the report says so rather than "8 -> 8"
    (logs / "flight009.ulg").write_bytes((logs / "flight001.ulg").read_bytes())
    assert main(["learn", str(logs), "--out", str(out), "--executor", "serial",
                 "--no-compare"]) == 0
    captured = capsys.readouterr()
    assert "9 logs: 8 read before (cache), 0 to read, 1 the same as another" in captured.err
    again = json.loads((out / "results.json").read_text())
    assert len(again["logs"]) == 8 and len(again["refused"]) == 1
    assert "the same log as" in again["refused"][0]["reason"]
    assert "flight001.ulg" in again["refused"][0]["reason"]
    assert again["changes"] == ["nothing (the same logs as before)"]
    assert again["instances"]["gyro0"]["firmware"] == doc["instances"]["gyro0"]["firmware"]


def test_coverage_map_says_what_is_missing(tmp_path):
    """From a few warm-season flights only: the map's bins count flights and minutes, and the
    cold end is named as missing in plain words."""
    flights = [f for f in simulate_flights(30, seed=4) if f.ambient_c > 18.0][:4]
    paths = _write(flights, tmp_path / "logs", ".ulg")
    doc = learn(paths, tmp_path / "out", executor="serial", compare=False)
    d = doc["instances"]["gyro0"]
    assert all(c["flights"] <= 4 and c["minutes"] >= 0 for c in d["coverage"])
    lo = d["supported_c"][0]
    assert lo > 15 and any(f"fly once below {lo} °C to cover the cold end" in w
                           for w in d["missing"])
    total = sum(c["minutes"] for c in d["coverage"])
    assert math.isclose(total, d["minutes"], rel_tol=0.02)
    # the console names exactly the supported bins (2 flights and 2 minutes each), holes
    # left out, where it once printed the first to the last as if none were between
    ok = {c["bin_c"] for c in d["coverage"] if c["flights"] >= 2 and c["minutes"] >= 2}
    text = format_learn_report(doc).split("gyro0 (")[1]
    line = next(x for x in text.splitlines() if x.strip().startswith("coverage: supported"))
    spans = line.split("supported ")[1].removesuffix(" °C").split(", ")
    named = {b for sp in spans for b in range(int(sp.split("..")[0]), int(sp.split("..")[1]))}
    assert named == ok


def test_an_instance_no_bin_supports_is_left_out_of_the_parameter_file(tmp_path):
    """Four flights across the seasons: the accelerometers' windows (valid only once the
    board has warmed) leave no 1 °C bin with 2 flights and 2 minutes, so their fit rests on
    too little: left out of px4.params, saying why; the gyros with supported bins are in."""
    paths = _write(simulate_flights(4, seed=1), tmp_path / "logs", ".ulg")
    doc = learn(paths, tmp_path / "out", executor="serial", compare=False)
    bare = [n for n, x in doc["instances"].items() if x["supported_c"] is None]
    kept = [n for n, x in doc["instances"].items() if x["supported_c"] is not None]
    assert {"acc0", "acc1"} <= set(bare) and {"gyro0", "gyro1"} <= set(kept)
    params = (tmp_path / "out" / "px4.params").read_text()
    ids = {n: str(x["device_id"]) for n, x in doc["instances"].items()}
    for n in bare:
        x = doc["instances"][n]
        assert x["status"] == "skipped" and "no 1 °C bin has 2 flights" in x["reason"]
        assert not any(ids[n] in ln for ln in params.splitlines() if "TC_A" in ln)
    for n in ("gyro0", "gyro1"):
        assert doc["instances"][n]["status"] == "fitted"
        assert any(ids[n] in ln for ln in params.splitlines() if "TC_G" in ln)


def test_comparison_on_whole_flights(tmp_path):
    """The comparison with one run per flight: 4 flights, the last tests (fast twin of the
    test below, without the export)."""
    paths = _write(simulate_flights(4, seed=2), tmp_path / "logs", ".ulg")
    doc = learn(paths, tmp_path / "out", executor="serial", export=False)
    c = doc["instances"]["gyro1"]["compare"]
    assert c["status"] == "ok" and c["test_flight"] == "flight4" and c["flights"] == 4
    assert (tmp_path / "out" / "instances" / "gyro1" / "results.json").is_file()
    # the firmware form's band, judged on whole flights, and how it grows where none flew
    assert "whole flights held out" in (tmp_path / "out" / "report.txt").read_text()


@pytest.mark.slow
def test_comparison_onnx_and_c_on_whole_flights(tmp_path):
    """With the comparison: one run per flight (the last tests), the per-axis choice, the
    band, and the chosen model exported as ONNX and C beside it."""
    flights = simulate_flights(8, seed=2)
    paths = _write(flights, tmp_path / "logs", ".ulg")
    doc = learn(paths, tmp_path / "out", executor="serial")
    c = doc["instances"]["gyro0"]["compare"]
    assert c["status"] == "ok" and c["test_flight"] == "flight8" and c["flights"] == 8
    assert set(c["families"]) >= {"px4-cubic", "linear", "rbf"}
    for rel in doc["instances"]["gyro0"]["export"].values():
        assert (tmp_path / "out" / rel).is_file()
    # the comparison's own record names where it is, not the staging directory it was built in
    text = (tmp_path / "out" / "instances" / "gyro0" / "results.json").read_text()
    assert ".staging" not in text and str(tmp_path / "out" / "instances" / "gyro0") in text


def test_a_stopped_job_loses_no_log_read(tmp_path):
    """Stopped (Ctrl-C) after its third log: the three stay cached and the next run reads only
    the rest."""
    paths = _write(simulate_flights(5, seed=6), tmp_path / "logs", ".ulg")
    out = tmp_path / "out"

    def stop_at_third(line: str) -> None:
        if line.startswith("[3/"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        learn(paths, out, executor="serial", compare=False, say=stop_at_third)
    assert len(list((out / "cache").glob("*.json"))) == 3 and not (out / "results.json").exists()
    lines: list[str] = []
    doc = learn(paths, out, executor="serial", compare=False, say=lines.append)
    assert lines[0] == "5 logs: 3 read before (cache), 2 to read" and len(doc["logs"]) == 5



def test_a_held_out_flight_beyond_the_others_says_the_firmware_holds_its_edge(tmp_path):
    """Four flights, the last one hotter than the three others (the fc-board seed 1 vehicle):
    on the accelerometers it lies wholly above what the others covered, where the firmware
    clamps — its correction is a constant there, so no binned drift is cut, and the report
    says why instead of printing an unexplained "x -> x"."""
    from thermonet.workflows.learn import format_learn_report

    paths = _write(simulate_flights(4, seed=1), tmp_path / "logs", ".ulg")
    doc = learn(paths, tmp_path / "out", executor="serial", compare=False)
    h = doc["instances"]["acc0"]["held_out"]
    lo, hi = h["trained_c"]
    assert h["outside_trained"] == 1.0 and lo < hi
    assert h["pp_corrected"] == pytest.approx(h["pp_raw"], rel=1e-9)
    assert f"100% of it outside the other flights' {lo:.1f}..{hi:.1f} °C" in format_learn_report(doc)
    for d in doc["instances"].values():           # a share, wherever a flight was held out
        if (d.get("held_out") or {}).get("status") == "judged":
            assert 0.0 <= d["held_out"]["outside_trained"] <= 1.0


def test_a_log_too_short_to_learn_from_says_no_parameter_file_yet(tmp_path, capsys):
    """The real PX4 fixture (half a minute per sensor): read and kept, nothing fitted; the
    console says there is no parameter file yet and that no bin is supported (was
    "coverage: supported nothing" and no word of the file), in the singular where it is
    one ("1 log", "1 flight")."""

    log = Path(__file__).parent / "data" / "real" / "px4_sitl_bias_variance" / \
        "sample_px4_events.ulg"
    assert main(["learn", str(log), "--out", str(tmp_path / "out"), "--executor",
                 "serial"]) == 0
    cap = capsys.readouterr()
    assert not list((tmp_path / "out").glob("*.params"))
    assert "  coverage: no 1 °C bin supported yet" in cap.out.splitlines()
    assert ("parameter file: none yet (no sensor could be fitted: fly more and run learn "
            "again)") in cap.out.splitlines()
    assert cap.err.splitlines()[0].startswith("1 log: 0 read before (cache), 1 to read")
    assert "gyro0: learning from 1 flight" in cap.err.splitlines()


def test_a_sensor_not_learned_is_not_written_and_the_report_says_so(tmp_path, capsys):
    """ArduPilot: the estimator runs on IMUs 1 and 2, IMU 3's gyro is learned from still
    windows, its accelerometer from nothing.  INS_TCAL3 holds both: the file once wrote
    INS_TCAL3_ACC* = 0, which wipes the board's accelerometer calibration when loaded (and
    verify then FAILed acc2 1.0x).  Now only the gyro's coefficients are written (as
    ``export`` writes a gyro model), with the device ids and board id calibrate writes; the
    console names acc2 as not learned and why; verify leaves acc2 "not covered" and refuses
    the file on another board of the same model."""
    from thermonet.sim.fcboard import board_id
    from thermonet.workflows.verify import evaluate, read_param_file

    _write(simulate_flights(10, seed=0, autopilot="ardupilot"), tmp_path / "logs", ".bin")
    assert main(["learn", str(tmp_path / "logs"), "--out", str(tmp_path / "out"), "--executor",
                 "serial", "--no-compare"]) == 0
    out = capsys.readouterr().out
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    assert doc["instances"]["gyro2"]["status"] == "fitted" and "acc2" not in doc["instances"]
    (miss,) = doc["not_learned"]
    assert miss["name"] == "acc2" and "EK3_IMU_MASK" in miss["reason"]
    assert miss["parameter_file"] == "INS_TCAL3_ACC* are not written: the board keeps its own"
    assert (f"acc2 (id {miss['device_id']}): not learned — {miss['reason']}; "
            f"{miss['parameter_file']}") in out.splitlines()
    text = (tmp_path / "out" / "ardupilot.parm").read_text()
    names = [ln.split(",")[0] for ln in text.splitlines() if not ln.startswith("#")]
    assert not [n for n in names if n.startswith("INS_TCAL3_ACC")]
    assert len([n for n in names if n.startswith("INS_TCAL3_GYR")]) == 9
    assert len([n for n in names if n.startswith("INS_TCAL1_ACC")]) == 9
    gyro2 = doc["instances"]["gyro2"]["device_id"]
    assert f"# device ids: INS_TCAL3 gyro {gyro2} acc 0" in text.splitlines()
    assert f"# board id: {board_id(0, 'ardupilot')}" in text.splitlines()
    pf = read_param_file(tmp_path / "out" / "ardupilot.parm")
    res = evaluate(pf, simulate_board(seed=0, autopilot="ardupilot", rate_hz=0.2))
    assert res["acc2"]["status"] == "not covered" and "INS_TCAL3_ACC*" in res["acc2"]["reason"]
    assert res["gyro2"]["status"] == "judged"
    with pytest.raises(ThermonetError, match="belongs to another board"):
        evaluate(pf, simulate_board(seed=1, autopilot="ardupilot", rate_hz=0.2))
    # PX4: no barometer is learned, so none is written (once: TC_B_ENABLE 0 and every TC_B
    # slot cleared, wiping a chamber calibration of the barometer)
    doc = learn(_write(simulate_flights(4, seed=2), tmp_path / "px4", ".ulg"),
                tmp_path / "out4", executor="serial", compare=False, export=False)
    params = (tmp_path / "out4" / "px4.params").read_text()
    assert "TC_G0_ID" in params and "TC_B" not in params
    assert f"# board id: {board_id(2, 'px4')}" in params.splitlines()


def test_a_run_again_says_what_it_drops_and_refuses_another_vehicle(tmp_path):
    """Run again with only the new logs: the logs given are the flights learned (the cache
    only spares reading), and a warning names the flights learned before that are left out
    and how to keep them (was a silent "flights: 4 -> 2").  Logs of another board of the
    same model: refused in one line, the directory as it was (was: silently replaced).
    results.json records each log's SHA-256, so verify knows a log the file was learned
    from."""
    from thermonet.core.errors import InputError
    from thermonet.core.outdir import sha256_file
    from thermonet.workflows.verify import trained_on

    logs = tmp_path / "logs"
    paths = _write(simulate_flights(4, seed=5), logs, ".ulg")
    out = tmp_path / "out"
    first = learn(paths, out, executor="serial", compare=False, export=False)
    assert first["logs_sha256"] == [sha256_file(p) for p in paths] and not first["warnings"]
    assert trained_on(out / "px4.params", sha256_file(paths[1])) == str(paths[1])
    said: list[str] = []
    doc = learn(paths[2:], out, executor="serial", compare=False, export=False, say=said.append)
    (warning,) = doc["warnings"]
    assert warning.startswith("2 flights learned before (of 4) are not among the logs given "
                              "and left out of this fit: flight001.ulg, flight002.ulg")
    assert f"(thermonet learn {logs} NEW_LOGS --out {out})" in warning
    assert f"warning: {warning}" in said and f"warning: {warning}" in format_learn_report(doc)
    assert doc["changes"][0] == "flights: 4 -> 2"
    before = (out / "results.json").read_bytes()
    twin = _write(simulate_flights(2, seed=25), tmp_path / "twin", ".ulg")
    with pytest.raises(InputError, match=r"out: learned before from another vehicle \(of board "):
        learn(twin, out, executor="serial", compare=False, export=False)
    assert (out / "results.json").read_bytes() == before
    doc = learn(twin, out, executor="serial", compare=False, export=False, overwrite=True)
    assert doc["logs"] == [str(p) for p in twin] and not doc["warnings"]


def test_a_fit_supported_over_a_degree_is_not_written(tmp_path):
    """Six ArduPilot flights support IMU 3's gyro only at −1..0 °C (two flights and two
    minutes a bin): a cubic there is an offset's guess the autopilot would carry across its
    whole clamp — written, verify failed it at 3.0x on a bench warm-up (a new user's pass).
    Under learn_data.MIN_SUPPORTED_SPAN_C it is left out, saying its span; the instances
    supported wider are written as before."""
    from thermonet.workflows.learn_data import MIN_SUPPORTED_SPAN_C

    _write(simulate_flights(6, seed=0, autopilot="ardupilot"), tmp_path / "logs", ".bin")
    doc = learn([tmp_path / "logs"], tmp_path / "out", executor="serial", compare=False,
                export=False)
    g2 = doc["instances"]["gyro2"]
    lo, hi = g2["supported_c"]
    assert hi - lo < MIN_SUPPORTED_SPAN_C and g2["status"] == "skipped"
    assert g2["reason"].startswith(f"left out of the parameter file: supported only at "
                                   f"{lo}..{hi} °C (under 5 °C)")
    names = [ln.split(",")[0] for ln in (tmp_path / "out" / "ardupilot.parm").read_text()
             .splitlines() if not ln.startswith("#")]
    assert not [n for n in names if n.startswith("INS_TCAL3_")]
    wide = [k for k, v in doc["instances"].items() if v["status"] == "fitted"]
    assert wide and all(doc["instances"][k]["supported_c"][1] -
                        doc["instances"][k]["supported_c"][0] >= MIN_SUPPORTED_SPAN_C
                        for k in wide)
