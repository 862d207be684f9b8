"""``thermonet calibrate``: simulate a board → calibrate → apply the autopilot's own formula to the
written parameter file → compare with the simulated truth, for PX4 and ArduPilot, every instance.

The formulas are re-implemented from the firmware sources in ``tests/oracles.py`` (file and
commit cited there), independently of thermonet.exporting.autopilot:

* PX4 ``TemperatureCompensation::calc_thermal_offsets_3D`` / ``_1D``: T clamped to
  [TMIN, TMAX], offset = sum_k X_k (T - TREF)^k, corrected = raw - offset (rad/s, m/s^2, Pa);
  a slot applies to the sensor whose device id equals ``TC_*_ID`` (``set_sensor_id``).
* ArduPilot ``TCal::correct_sensor``: T and T_cal clamped to [TMIN, TMAX],
  P(x) = (c1 x + c2 x^2 + c3 x^3) * 1e-6, corrected = raw - P(T - 35) + P(T_cal - 35).
"""

from __future__ import annotations

import json
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from oracles import PX4_LETTER, ardupilot_offsets, px4_offsets, px4_slot, read_params
from thermonet.cli import main
from thermonet.data.logs import read_log
from thermonet.data.logs.writers import write_log
from thermonet.sim.fcboard import simulate_board
from thermonet.workflows.calibrate import calibrate


def _px4_correction(p: dict[str, float], kind: str, device_id: int, temp: np.ndarray
                    ) -> np.ndarray:
    """PX4's offsets (tests/oracles.py) on the slot of ``device_id``, in the truth's unit."""
    t = PX4_LETTER[kind]
    assert p[f"TC_{t}_ENABLE"] == 1
    pre = px4_slot(p, t, device_id)
    assert pre is not None, (kind, device_id)
    offs = px4_offsets(p, pre, temp)
    if kind == "baro":
        return offs[:, None]
    return 100.0 * offs if kind == "mag" else offs   # TC_M* act on sensor_mag in gauss; truth µT


def _ap_correction(p: dict[str, float], kind: str, imu: int, temp: np.ndarray, t_cal: float
                   ) -> np.ndarray:
    assert p[f"INS_TCAL{imu + 1}_ENABLE"] == 1
    return ardupilot_offsets(p, imu, kind, temp, t_cal)


def _binned_pp(temp: np.ndarray, y: np.ndarray) -> float:
    bins = np.floor(temp)
    means = [y[bins == b].mean() for b in np.unique(bins) if np.sum(bins == b) >= 5]
    return float(np.ptp(means))


@pytest.mark.parametrize("autopilot,preset", [("px4", "fc-board"), ("ardupilot", "fc-board"),
                                              ("px4", "fc-board-cycle"),
                                              ("ardupilot", "fc-board-cycle")])
def test_autopilot_formula_on_the_written_file_cuts_true_drift(tmp_path: Path, autopilot: str,
                                                               preset: str) -> None:
    board = simulate_board(preset, autopilot=autopilot, seed=11, rate_hz=0.5)
    log_path = write_log(board, tmp_path / ("b.ulg" if autopilot == "px4" else "b.bin"))
    doc = calibrate(log_path, tmp_path / "cal", compare=False)
    insts = doc["instances"]
    # the whole-degree IMU is fitted, its resolution and what it costs stated; PX4 fits the
    # baro, ArduPilot cannot
    for name in ("gyro2", "acc2"):
        res = insts[name]["resolution"]
        assert insts[name]["status"] == "fitted" and res["step_c"] == 1.0
        assert "1 °C steps" in res["line"] and res["levels"] >= 40
        unit = {"gyro2": "rad/s", "acc2": "m/s²"}[name]         # the firmware's units
        worst = int(np.nanargmax(res["relative_error"]))
        assert f"off by up to {res['max_error'][worst]:.3g} {unit} (" in res["line"]
        # max |P'| * step / 2: a whole-degree thermometer costs a few % of the drift
        assert all(0.0 < r < 0.2 for r in res["relative_error"])
    assert all("resolution" not in insts[n] for n in ("gyro0", "acc1", "baro0"))
    assert insts["baro0"]["status"] == ("fitted" if autopilot == "px4" else "skipped")
    truth = {i.name: i for i in board.instances}
    if autopilot == "px4":
        p = read_params(tmp_path / "cal" / "px4.params")
        for t in "GAB":                      # every slot of every kind is in the file
            for s in range(4):
                assert f"TC_{t}{s}_ID" in p and f"TC_{t}{s}_TREF" in p
        assert p["TC_G2_ID"] == 2621474 and p["TC_G3_ID"] == 0  # nothing left in unused slots
        assert "# gyro2 (id 2621474): thermometer reports 1 °C steps" in (
            tmp_path / "cal" / "px4.params").read_text()
    else:
        p = read_params(tmp_path / "cal" / "ardupilot.parm")
        assert "INS_TCAL_OPTIONS" not in p and p["INS_TCAL3_ENABLE"] == 1   # IMU 3: whole °C
        assert "# device ids: INS_TCAL3 gyro 2621474 acc 2621482" in (
            tmp_path / "cal" / "ardupilot.parm").read_text()
    fitted = [n for n, d in insts.items() if d["status"] == "fitted"]
    assert sorted(fitted) == sorted(["gyro0", "gyro1", "gyro2", "acc0", "acc1", "acc2"]
                                    + (["baro0", "mag0"] if autopilot == "px4" else []))
    # a magnetometer on a lent thermometer (and any on ArduPilot) is fitted, not a slot
    model_only = sorted(n for n, d in insts.items() if d["status"] == "model only")
    assert model_only == (["mag1"] if autopilot == "px4" else ["mag0", "mag1"])
    for name in fitted:
        inst = truth[name]
        temp = inst.temperature_c
        if autopilot == "px4":
            corr = _px4_correction(p, inst.kind, inst.device_id, temp)
        else:
            corr = _ap_correction(p, inst.kind, inst.instance, temp, t_cal=25.0)
        for j in range(inst.truth.shape[1]):
            before = _binned_pp(temp, inst.truth[:, j])
            after = _binned_pp(temp, inst.truth[:, j] - corr[:, j])
            assert before / after >= 5.0, (name, j, before, after)
        if autopilot == "px4" and inst.kind == "gyro":
            # PX4 keeps the constant: what is left of the gyro's true drift is near zero
            resid = inst.truth - corr
            assert np.max(np.abs(resid.mean(axis=0))) < 0.05 * np.ptp(inst.truth)


def test_calibrate_cli_side_by_side_and_left_out_lines(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    board = simulate_board("fc-board-cycle", autopilot="px4", seed=12, rate_hz=0.1)
    board.instances = [i for i in board.instances if i.name != "acc0"]   # two comparisons: fast
    gyro1 = next(i for i in board.instances if i.name == "gyro1")
    gyro1.temperature_c = 30.0 + 0.1 * np.sin(np.arange(gyro1.n_samples))   # too little span
    acc1 = next(i for i in board.instances if i.name == "acc1")
    acc1.temperature_c = None                                               # no thermometer
    path = write_log(board, tmp_path / "board.ulg")
    out = tmp_path / "cal"
    assert main(["calibrate", str(path), "--out", str(out), "--detail"]) == 0
    report = capsys.readouterr().out
    lines = {ln.split()[0]: ln for ln in report.splitlines() if ln[:1].isalpha() and
             ln.split()[0] in ("gyro0", "gyro1", "gyro2", "acc1", "acc2", "baro0")}
    assert "LEFT OUT" in lines["gyro1"] and "spans only" in lines["gyro1"]
    assert "LEFT OUT" in lines["acc1"] and "no temperature" in lines["acc1"]
    for name in ("gyro0", "gyro2", "baro0"):
        assert "fitted" in lines[name]
    # the whole-degree gyro's verdict says its resolution and what it costs
    gyro2 = report[report.index(lines["gyro2"]):].splitlines()[1]
    assert "1 °C steps" in gyro2 and "% of the fitted drift" in gyro2
    doc = json.loads((out / "results.json").read_text())
    assert (out / "report.txt").read_text().startswith("thermonet calibrate")
    page = (out / "report.html").read_text()
    HTMLParser().feed(page)   # well-formed enough to parse
    for name in ("gyro0", "gyro1", "gyro2", "acc1", "acc2", "baro0"):
        assert f"<td>{name}</td>" in page
    assert "spans only" in page and 'href="instances/gyro0/report.html"' in page
    for name in ("gyro0", "gyro2", "baro0"):
        cmp = doc["instances"][name]["compare"]
        sub = json.loads((Path(cmp["dir"]) / "results.json").read_text())
        # thermonet's families were fitted side by side with the firmware form, on held-out
        # contiguous blocks, the firmware form as the baseline
        assert sub["split"]["strategy"] == "time-blocks"
        assert sub["baseline"] == cmp["firmware_family"]
        assert {"linear", "rbf", cmp["firmware_family"]} <= set(sub["families"])
        fw = cmp["families"][cmp["firmware_family"]]
        assert fw["val_score"] < 0.2
    p = read_params(out / "px4.params")
    assert p["TC_G0_ID"] == 2424842 and p["TC_G1_ID"] == 2621474 and p["TC_A0_ID"] == 2621482
    assert p["TC_G_ENABLE"] == 1 and p["TC_A_ENABLE"] == 1
    assert p["TC_B0_ID"] == 3997706


def test_calibrate_console_one_line_per_instance_detail_behind_a_flag(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A drone owner's first read: one line per sensor instance (id, result, the comparison's
    chosen model, the held-out cut of the parameter file's form, the chosen model against the
    firmware form, PASS / MARGINAL / FAIL / LEFT OUT), each instance's detail only with
    --detail (-v), which prints report.txt itself; -q and -v together are a usage error."""
    board = simulate_board("fc-board", autopilot="px4", seed=6, rate_hz=0.5)
    board.instances = [i for i in board.instances if i.name in ("gyro0", "gyro2", "baro0",
                                                                "acc1")]
    next(i for i in board.instances if i.name == "acc1").temperature_c = None   # left out
    path = write_log(board, tmp_path / "board.ulg")
    out = tmp_path / "cal"
    assert main(["calibrate", str(path), "--out", str(out), "--workers", "1"]) == 0
    text = capsys.readouterr().out
    doc = json.loads((out / "results.json").read_text())
    names = list(doc["instances"])
    assert sorted(names) == ["acc1", "baro0", "gyro0", "gyro2"]
    rows = [ln.split("  ") for ln in text.splitlines() if ln.startswith("  ")
            and ln.split()[0] in names]
    rows = [[c.strip() for c in r if c.strip()] for r in rows]
    assert [r[0] for r in rows] == names                       # one line each, in order
    assert not any(ln[:1].isalpha() and ln.split()[0] in names      # no detail block
                   for ln in text.splitlines())
    assert "held out (" not in text and "note:" not in text     # the detail is not printed
    for name, (inst, dev, result, *rest) in zip(names, rows, strict=True):
        d = doc["instances"][name]
        assert (inst, int(dev)) == (name, d["device_id"])
        if d["status"] != "fitted":
            assert result == "left out" and rest[-1].startswith("LEFT OUT: no temperature")
            continue
        chosen, cut, versus, verdict = rest
        cmp = d["compare"]
        assert result == f"fitted, slot {d['slot']}" and chosen == cmp["chosen"]
        fams = cmp["families"]
        ratio = fams[cmp["chosen"]]["val_score"] / fams[cmp["firmware_family"]]["val_score"]
        assert versus == "same" if cmp["chosen"] == cmp["firmware_family"] else \
            float(versus.rstrip("x")) == pytest.approx(ratio, abs=0.006)
        cuts = [float(c) for c in cut.replace("x", "").split("..")]
        held = d["held_out"]["cut"]
        assert cuts[0] == pytest.approx(min(held), abs=0.051)
        assert cuts[-1] == pytest.approx(max(held), abs=0.051)
        grades = d["held_out"]["grades"]
        axes = ["p"] if name == "baro0" else ["x", "y", "z"]
        weak = [a for a, g in zip(axes, grades, strict=True) if g != "fine"]
        assert verdict == ("PASS" if not weak else
                           f"{'FAIL' if 'fails' in grades else 'MARGINAL'} ({', '.join(weak)})")
    assert f"detail per instance: {out / 'report.txt'} (or calibrate --detail)" in text
    assert doc["board_id"] == board.board_id and f"board id: {board.board_id}\n" in text
    assert f"Load the parameter file only on board {board.board_id}, whose sensors" in text
    # --detail: report.txt as written (the same table, then each instance's detail)
    again = tmp_path / "again"
    assert main(["calibrate", str(path), "--out", str(again), "--workers", "1", "-v"]) == 0
    text = capsys.readouterr().out
    report = (again / "report.txt").read_text()
    assert text == report + f"results: {again / 'results.json'}\n"
    assert [ln for ln in report.splitlines() if ln.startswith("  gyro0 ")] == [
        ln for ln in (out / "report.txt").read_text().splitlines() if ln.startswith("  gyro0 ")]
    assert any(ln.startswith("gyro0 ") and "fitted, slot" in ln for ln in report.splitlines())
    assert "held out (" in report
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", str(path), "--out", str(tmp_path / "x"), "-q", "-v"])
    assert exc.value.code == 2 and not (tmp_path / "x").exists()


def test_calibrate_real_sample_log_refuses_every_instance(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    ulg = Path(__file__).parent / "data" / "real" / "px4_ulog_sample" / "sample_log_small.ulg"
    assert main(["calibrate", str(ulg), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert "no sensor instance can be calibrated" in err and "too few samples: 6" in err
    assert "mag0" in err and not (tmp_path / "o" / "px4.params").exists()
    assert read_log(ulg).instances                                          # the log itself reads


def test_simulate_board_cli_writes_both_log_formats(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    for name, autopilot in (("b.ulg", "px4"), ("b.BIN", "ardupilot")):
        path = tmp_path / name
        assert main(["simulate", "fc-board", "--seed", "3", "--out", str(path)]) == 0
        log = read_log(path)
        assert log.autopilot == autopilot and len(log.instances) == 9   # 7 + 2 magnetometers
        same = read_log(path)               # the same file read twice: values copied, exact
        assert np.array_equal(log.instances[0].values, same.instances[0].values)
    capsys.readouterr()
    assert main(["simulate", "fc-board", "--out", str(tmp_path / "b.parquet")]) == 1
    assert "FILE.ulg" in capsys.readouterr().err
    assert main(["simulate", "patent-gyro", "--out", str(tmp_path / "p.ulg")]) == 1
    assert "only the flight-controller presets" in capsys.readouterr().err
    # one board, one autopilot: a PX4 and an ArduPilot log together, refused in one line
    assert main(["calibrate", str(tmp_path / "b.ulg"), str(tmp_path / "b.BIN"), "--out",
                 str(tmp_path / "mixed"), "--no-compare"]) == 1
    assert capsys.readouterr().err.strip() == (
        f"thermonet: error: {tmp_path / 'b.BIN'}: an ArduPilot log; {tmp_path / 'b.ulg'} is a "
        "PX4 log (one board, one autopilot)")
    assert not (tmp_path / "mixed").exists()


def test_only_what_cannot_be_fitted_is_refused_with_the_reason() -> None:
    """A whole-degree thermometer is fitted (its cost stated); one reporting 5 °C steps over
    a 20 °C warm-up gives 5 distinct temperatures, fewer than a cubic needs (order + 3 = 6,
    so that the fit has residual degrees of freedom), and is refused saying so."""
    from thermonet.workflows.firmware_fit import check_instance, fit_firmware, resolution_effect

    board = simulate_board("fc-board", autopilot="px4", seed=13, rate_hz=0.5)
    gyro2 = next(i for i in board.instances if i.name == "gyro2")
    assert check_instance(gyro2, "px4") is None
    res = resolution_effect(gyro2, fit_firmware(gyro2, "px4"))
    assert res is not None and res["step_c"] == 1.0
    # the stated cost is max |P'(T)| * step / 2 of the fitted polynomial, recomputed here
    fit = fit_firmware(gyro2, "px4")
    grid = np.linspace(fit.t_min, fit.t_max, 401) - fit.t_ref
    slope = [np.max(np.abs(np.polyval(np.polyder(c[::-1]), grid))) for c in fit.coef]
    assert res["max_error"] == pytest.approx([s * 0.5 for s in slope], rel=1e-9)
    coarse = next(i for i in board.instances if i.name == "gyro0")
    coarse.temperature_c = 20.0 + 5.0 * np.floor(np.linspace(0.0, 4.999, coarse.n_samples))
    why = check_instance(coarse, "px4")
    assert why is not None and "only 5 distinct temperatures (5 °C steps" in why
    assert "needs at least 6" in why
    assert resolution_effect(next(i for i in board.instances if i.name == "gyro1"),
                             fit_firmware(next(i for i in board.instances
                                               if i.name == "gyro1"), "px4")) is None



@pytest.mark.parametrize("n", [1, 7, 31, 200, 2_701])
def test_the_running_median_is_scipys_median_filter_value_for_value(n, monkeypatch):
    """PX4's 31-sample median filter (``firmware_fit.running_median``, numpy's sliding
    windows) against its independent oracle ``scipy.ndimage.median_filter(mode="nearest")``
    (SciPy 1.x, ``scipy/ndimage/_filters.py``): an odd window's median is one of its samples,
    so equal value for value — ties, short logs and the chunk boundaries included."""
    from scipy.ndimage import median_filter

    from thermonet.workflows import firmware_fit

    monkeypatch.setattr(firmware_fit, "_MEDIAN_CHUNK", 64)     # several chunks, uneven last
    rng = np.random.default_rng(n)
    y = np.column_stack([rng.standard_normal(n), np.round(rng.standard_normal(n), 1),
                         np.linspace(0.0, 1.0, n) ** 3])
    got = firmware_fit.running_median(y)
    want = np.column_stack([median_filter(y[:, j], size=31, mode="nearest") for j in range(3)])
    assert np.array_equal(got, want)


def test_a_calibration_with_its_comparison_loads_no_scikit_learn_scipy_or_pandas(
        tmp_path: Path) -> None:
    """``thermonet calibrate`` (comparison on) in a fresh interpreter, on a simulated PX4
    board with a magnetometer: its RBF's centres (``init: quantiles``), PX4's running median
    and the magnetometer's lag need none of scikit-learn, SciPy or pandas, whose imports
    were 0.9 s of a 3.6 s calibration (issue 35); the calibration is written."""
    import subprocess
    import sys

    board = simulate_board("fc-board", autopilot="px4", seed=3, rate_hz=0.2)
    board.instances = [i for i in board.instances if i.name in ("gyro0", "acc0", "mag0")]
    log = write_log(board, tmp_path / "b.ulg")
    code = ("import sys\n"
            "from thermonet.cli import main\n"
            f"rc = main(['calibrate', {str(log)!r}, '--out', {str(tmp_path / 'cal')!r}, '-q'])\n"
            "print(rc, sorted(m for m in ('sklearn', 'scipy', 'pandas') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip().splitlines()[-1] == "0 []"
    doc = json.loads((tmp_path / "cal" / "results.json").read_text())
    assert doc["instances"]["gyro0"]["compare"]["families"]["rbf"]["status"] == "ok"


def _board_tasks(tmp_path: Path, names: tuple[str, ...], where: str) -> list[dict]:
    """calibrate's comparison tasks for some instances of a simulated PX4 board."""
    board = simulate_board("fc-board", autopilot="px4", seed=5, rate_hz=0.2)
    log = tmp_path / "b.ulg"
    if not log.exists():
        write_log(board, log)
    insts = [i for i in read_log(log).instances if i.name in names]
    return [{"inst": i, "autopilot": "px4", "where": tmp_path / where / i.name,
             "source": "b.ulg", "final": tmp_path / "final" / i.name} for i in insts]


def test_instances_compared_in_a_helper_process_are_the_commands_comparisons(
        tmp_path: Path) -> None:
    """calibrate's helper (``workers``; core.helpers' process pool,
    workflows.calibrate_compare) takes instances from the back of the
    list while the command takes them from the front: each comparison is the one the
    command alone makes, number for number, and ``--profile`` names what the helper did.
    The helper is waited for here, so that it surely takes part (in a command it imports
    while the logs are read, and helps from when it is ready)."""
    import time

    from thermonet.core import profile
    from thermonet.core.helpers import Helpers
    from thermonet.workflows.calibrate_compare import HELPER_IMPORTS, compare_all

    names = ("gyro0", "acc0", "gyro1", "acc1", "baro0", "mag0")
    alone = compare_all(_board_tasks(tmp_path, names, "alone"))
    with Helpers(1, HELPER_IMPORTS) as helper:
        while not helper.ready():
            assert not helper.failed(), "the helper did not start"
            time.sleep(0.05)
        procs = list(helper._pool._processes.values())
        profile.reset()
        profile.enable()
        try:
            side = compare_all(_board_tasks(tmp_path, names, "side"), helper)
            helped = [n for n in profile.timings() if n.endswith("(helper)")]
        finally:
            profile.enable(False)
            profile.reset()
        assert all(not p.is_alive() for p in procs)   # ended once the comparisons are done
    assert helped                                  # it compared at least one instance
    assert list(side) == list(alone)
    for name in alone:
        a, s = alone[name], side[name]
        assert isinstance(a, dict) and isinstance(s, dict)
        assert s["dir"] == a["dir"] and s["families"] == a["families"]
        assert (s["chosen"], s.get("band")) == (a["chosen"], a.get("band"))


def test_a_helper_that_fails_leaves_its_work_to_the_command(tmp_path: Path, capfd) -> None:
    """A helper whose imports fail (here: a module that does not exist) never becomes
    ready and says nothing: the command compares every instance itself, and the result is
    the same."""
    from thermonet.core.helpers import Helpers
    from thermonet.workflows.calibrate_compare import compare_all

    with Helpers(1, ["thermonet.no_such_module"]) as broken:
        got = compare_all(_board_tasks(tmp_path, ("gyro0", "acc0"), "a"), broken)
    want = compare_all(_board_tasks(tmp_path, ("gyro0", "acc0"), "b"))
    assert sorted(got) == ["acc0", "gyro0"]
    assert got == want
    assert "Traceback" not in capfd.readouterr().err


def test_workers_must_be_a_whole_number(tmp_path: Path, capsys) -> None:
    board = simulate_board("fc-board", autopilot="px4", seed=6, rate_hz=0.2)
    log = write_log(board, tmp_path / "b.ulg")
    assert main(["calibrate", str(log), "--out", str(tmp_path / "c"), "--workers", "-1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "workers -1" in err[0]
    assert not (tmp_path / "c").exists()
    # above the most this machine can use (each helper loads torch): refused, not started
    assert main(["calibrate", str(log), "--out", str(tmp_path / "c"), "--workers", "100"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("thermonet: error: --workers 100: more processes")
    assert not (tmp_path / "c").exists()


def test_how_many_helpers_calibrate_starts() -> None:
    """``workers``: N processes = N − 1 helpers; none without the comparison; by default
    none where torch is loaded already (as in this test process: the comparisons start at
    once, a helper would be ready only after a second of imports), else one per further
    CPU, at most MAX_WORKERS in all."""
    import os
    import sys

    import torch  # noqa: F401 - loaded, as in a program that has fitted before

    from thermonet.workflows.calibrate_compare import MAX_WORKERS, helper_count

    assert "torch" in sys.modules
    assert helper_count(True, None) == helper_count(True, 0) == 0
    assert helper_count(True, 1) == 0
    assert helper_count(False, 3) == 0
    assert helper_count(True, 3) == (2 if os.name == "posix" else 0)
    assert MAX_WORKERS == 3


def test_a_helper_that_cannot_be_started_leaves_the_command_to_do_it_all(
        tmp_path: Path, monkeypatch) -> None:
    """No process to be had (a limit, a sandbox: the pool raises OSError): the
    calibration runs in the command alone, the same as with ``workers=1``."""
    from thermonet.workflows import calibrate as cal

    def refuse(*_: object, **__: object) -> None:
        raise OSError(11, "Resource temporarily unavailable")

    board = simulate_board("fc-board", autopilot="px4", seed=6, rate_hz=0.2)
    board.instances = [i for i in board.instances if i.name in ("gyro0", "acc0")]
    log = write_log(board, tmp_path / "b.ulg")
    alone = calibrate(log, tmp_path / "alone", workers=1)
    monkeypatch.setattr(cal, "Helpers", refuse)
    refused = calibrate(log, tmp_path / "refused", workers=2)
    for name in ("gyro0", "acc0"):
        a, r = alone["instances"][name], refused["instances"][name]
        assert r["status"] == a["status"] and r["firmware"] == a["firmware"]
        assert r["compare"]["families"] == a["compare"]["families"]


def test_a_helper_reads_the_logs_while_the_command_imports(tmp_path: Path) -> None:
    """With a helper (``workers=2``) the first helper reads the log before its own imports
    (``--profile`` names the stage) while the command imports the comparison; the
    calibration is the one the command makes alone, number for number."""
    from thermonet.core import profile

    board = simulate_board("fc-board", autopilot="px4", seed=6, rate_hz=0.2)
    board.instances = [i for i in board.instances if i.name in ("gyro0", "acc0")]
    log = write_log(board, tmp_path / "b.ulg")
    alone = calibrate(log, tmp_path / "alone", workers=1)
    profile.reset()
    profile.enable()
    try:
        helped = calibrate(log, tmp_path / "helped", workers=2)
        stages = list(profile.timings())
    finally:
        profile.enable(False)
        profile.reset()
    assert "read the log(s) (in the helper)" in stages and "read the log(s)" not in stages
    for name in ("gyro0", "acc0"):
        a, h = alone["instances"][name], helped["instances"][name]
        assert h["status"] == a["status"] and h["firmware"] == a["firmware"]
        assert h["compare"]["families"] == a["compare"]["families"]


def test_a_log_the_helper_cannot_read_is_refused_by_the_command(tmp_path: Path,
                                                                  capsys) -> None:
    """A damaged log with a helper to read it: the helper's failure is not the message —
    the command reads the log itself and refuses it in its own one line naming the file;
    nothing is written."""
    board = simulate_board("fc-board", autopilot="px4", seed=6, rate_hz=0.2)
    log = write_log(board, tmp_path / "b.ulg")
    data = log.read_bytes()
    log.write_bytes(data[: len(data) // 3])
    alone = main(["calibrate", str(log), "--out", str(tmp_path / "a"), "--workers", "1"])
    want = capsys.readouterr().err.strip().splitlines()
    assert alone == 1 and len(want) == 1 and str(log) in want[0]
    assert main(["calibrate", str(log), "--out", str(tmp_path / "c"), "--workers", "2"]) == 1
    assert capsys.readouterr().err.strip().splitlines() == want
    assert not (tmp_path / "c").exists()
