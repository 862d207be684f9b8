"""``thermonet verify`` judges or refuses: every kind of damaged parameter file, paired with the
firmware's formula re-implemented here.

The oracle (``tests/oracles.py``, the firmware files and commits cited there) applies each file
as the autopilot would, independently of thermonet's reader and of
:mod:`thermonet.data.firmware`: the file parsed line by line with the *last* value of a name
winning (as a parameter load does), PX4 ``calc_thermal_offsets_3D/_1D`` (T clamped to
[TMIN, TMAX], offset = sum_k X_k (T - TREF)^k) and ArduPilot ``TCal::correct_sensor``
(P(T - 35) - P(T_cal - 35), c_k * 1e-6), in float32 as the firmware computes, on the log read
back with pyulog / pymavlink.  For every damaged file the oracle shows what the vehicle would
do (NaN or inf rates, a value other than the one verify would have used), and verify refuses
it in one line naming the file, line and parameter (exit 1, nothing written) or FAILs it
(exit 3).  Where verify says PASS, the oracle's corrected rates are finite and their binned
drift smaller on every axis.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from oracles import ardupilot_offsets, px4_offsets, px4_slot, read_params
from thermonet.cli import main
from thermonet.data.logs.writers import write_log
from thermonet.sim.fcboard import simulate_board
from thermonet.workflows.calibrate import calibrate

pytestmark = pytest.mark.numerics

REAL_ULG = Path(__file__).parent / "data" / "real" / "px4_ulog_sample" / "sample_log_small.ulg"
F32 = np.float32


# ------------------------------------------------------------------ the oracle


def _load(path: Path) -> dict[str, float]:
    """The parameters as a vehicle loads the file: every line in order, the last value wins."""
    return read_params(path, strict=False)


def _binned_pp(temp: np.ndarray, y: np.ndarray) -> float:
    bins = np.floor(temp)
    return float(np.ptp([y[bins == b].astype(np.float64).mean() for b in np.unique(bins)]))


def _px4_streams(ulg: Path) -> list[tuple[str, int, np.ndarray, np.ndarray]]:
    """(kind letter, device id, temperature, outputs (n, axes)) per sensor, read by pyulog."""
    from pyulog import ULog

    out = []
    for d in ULog(str(ulg), ["sensor_gyro", "sensor_accel", "sensor_baro",
                             "sensor_mag"]).data_list:
        t = {"sensor_gyro": "G", "sensor_accel": "A", "sensor_baro": "B",
             "sensor_mag": "M"}[d.name]      # sensor_mag and TC_M* both in gauss
        cols = ["pressure"] if t == "B" else ["x", "y", "z"]
        y = np.column_stack([d.data[c].astype(np.float64) for c in cols])
        if t != "G":
            y = y - np.median(y, axis=0)
        out.append((t, int(np.median(d.data["device_id"])),
                    d.data["temperature"].astype(np.float64), y))
    return out


def px4_firmware(params: dict[str, float], ulg: Path) -> dict[tuple[str, int], np.ndarray]:
    """Per (kind, device id) with an enabled slot: the corrected outputs, float32."""
    out = {}
    for t, dev, temp, y in _px4_streams(ulg):
        if params.get(f"TC_{t}_ENABLE", 1) != 1:
            continue
        pre = px4_slot(params, t, dev)
        if pre is None:
            continue
        offs = px4_offsets(params, pre, temp, dtype=F32)
        with np.errstate(all="ignore"):
            out[(t, dev)] = y.astype(F32) - (offs[:, None] if t == "B" else offs)
    return out


def ardupilot_firmware(params: dict[str, float], binlog: Path, t_cal: float = 25.0
                       ) -> dict[tuple[str, int], np.ndarray]:
    """Per (kind, IMU) with INS_TCAL<n>_ENABLE = 1: the corrected outputs, float32."""
    from pymavlink import mavutil

    rows: dict[int, list[list[float]]] = {}
    mlog = mavutil.mavlink_connection(str(binlog))
    while (m := mlog.recv_match(type="IMU")) is not None:
        rows.setdefault(int(m.I), []).append([m.T, m.GyrX, m.GyrY, m.GyrZ,
                                              m.AccX, m.AccY, m.AccZ])
    out = {}
    for imu, r in rows.items():
        a = np.asarray(r)
        pre = f"INS_TCAL{imu + 1}_"
        if params.get(pre + "ENABLE") != 1:
            continue
        for kind, name, first in (("G", "gyro", 1), ("A", "acc", 4)):
            y = a[:, first:first + 3]
            if kind == "A":
                y = y - y.mean(axis=0)
            offs = ardupilot_offsets(params, imu, name, a[:, 0], t_cal, dtype=F32)
            with np.errstate(all="ignore"):
                out[(kind, imu)] = y.astype(F32) - offs
    return out


# ------------------------------------------------------------------ the board and its files


@pytest.fixture(scope="module")
def board(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, Path]]:
    """Per autopilot: a calibration of warm-up 0 (``params``) and warm-up 1 (``log``)."""
    tmp = tmp_path_factory.mktemp("damaged")
    out: dict[str, dict[str, Path]] = {}
    for ap, ext, fname in (("px4", ".ulg", "px4.params"), ("ardupilot", ".bin", "ardupilot.parm")):
        first = write_log(simulate_board("fc-board", autopilot=ap, seed=21, rate_hz=0.5),
                          tmp / f"first{ext}")
        later = write_log(simulate_board("fc-board", autopilot=ap, seed=21, rate_hz=0.5, run=1),
                          tmp / f"later{ext}")
        calibrate(first, tmp / f"cal-{ap}", compare=False)
        out[ap] = {"params": tmp / f"cal-{ap}" / fname, "log": later, "first": first}
    return out


def _line_of(text: str, name: str) -> int:
    """1-based line number of parameter ``name`` in ``text``."""
    for no, line in enumerate(text.splitlines(), start=1):
        if re.search(rf"(^|\s){re.escape(name)}[\s,]", line):
            return no
    raise AssertionError(name)


def _set(text: str, name: str, value: str) -> str:
    """``text`` with parameter ``name`` given ``value`` (PX4 tab-separated or NAME,VALUE)."""
    lines = text.splitlines()
    no = _line_of(text, name) - 1
    f = lines[no].split("\t")
    lines[no] = "\t".join(f[:3] + [value] + f[4:]) if len(f) == 5 else f"{name},{value}"
    return "\n".join(lines) + "\n"


def _drop(text: str, name: str) -> str:
    lines = text.splitlines()
    del lines[_line_of(text, name) - 1]
    return "\n".join(lines) + "\n"


def _append(text: str, name: str, value: str) -> str:
    px4 = "\t" in text
    return text + (f"1\t1\t{name}\t{value}\t9\n" if px4 else f"{name},{value}\n")


# Each damage: (id, autopilot, transform of the file's text, expected exit status, the
# parameter the one-line refusal names (None: FAIL, no refusal), a fragment of the message).
Damage = tuple[str, str, Callable[[str], str], int, str | None, str]
DAMAGES: list[Damage] = [
    ("px4-nan-coefficient", "px4", lambda s: _set(s, "TC_G0_X1_0", "nan"), 1, "TC_G0_X1_0",
     "is nan: not a finite number"),
    ("px4-nan-tref", "px4", lambda s: _set(s, "TC_G0_TREF", "nan"), 1, "TC_G0_TREF",
     "is nan: not a finite number"),
    ("px4-nan-tmin", "px4", lambda s: _set(s, "TC_A1_TMIN", "NaN"), 1, "TC_A1_TMIN",
     "is nan: not a finite number"),
    ("px4-inf-baro", "px4", lambda s: _set(s, "TC_B0_X2", "-inf"), 1, "TC_B0_X2",
     "is -inf: not a finite number"),
    ("px4-inf-tmax", "px4", lambda s: _set(s, "TC_G2_TMAX", "inf"), 1, "TC_G2_TMAX",
     "is inf: not a finite number"),
    ("px4-float32-overflow", "px4", lambda s: _set(s, "TC_G1_X3_1", "1e39"), 1, "TC_G1_X3_1",
     "does not fit the firmware's float32"),
    ("px4-duplicate", "px4", lambda s: _append(s, "TC_G0_X0_0", "99"), 1, "TC_G0_X0_0",
     "is set again (first on line"),
    ("px4-tmin-above-tmax", "px4",
     lambda s: _set(_set(s, "TC_G1_TMIN", "60"), "TC_G1_TMAX", "10"), 1, "TC_G1_TMIN",
     "TC_G1_TMIN = 60 is not below TC_G1_TMAX = 10"),
    ("px4-tref-outside", "px4", lambda s: _set(s, "TC_A0_TREF", "95"), 1, "TC_A0_TREF",
     "is outside TC_A0_TMIN..TMAX"),
    ("px4-implausible-range", "px4", lambda s: _set(s, "TC_A2_TMAX", "1e6"), 1, "TC_A2_TMAX",
     "is not a temperature a sensor works at"),
    ("px4-unparsable", "px4", lambda s: _set(s, "TC_G0_X0_0", "abc"), 1, "TC_G0_X0_0",
     "value 'abc' is not a number"),
    ("px4-missing", "px4", lambda s: _drop(s, "TC_G0_X3_2"), 1, "TC_G0_X3_2", "is missing"),
    ("px4-garbage-id", "px4", lambda s: _set(s, "TC_G0_ID", "2424842.5"), 1, "TC_G0_ID",
     "is not a device id"),
    ("px4-same-id-twice", "px4", lambda s: _set(s, "TC_G1_ID", _ids(s)["TC_G0_ID"]), 1,
     "TC_G1_ID", "which slot applies is ambiguous"),
    ("px4-zero-ids", "px4", lambda s: re.sub(r"(TC_[GABM]\d_ID\t)\d+", r"\g<1>0", s), 1, None,
     "nothing of later.ulg can be judged"),
    ("px4-huge-coefficient", "px4", lambda s: _set(s, "TC_G0_X3_0", "3e38"), 3, None, ""),
    ("ap-nan-coefficient", "ardupilot", lambda s: _set(s, "INS_TCAL1_GYR1_X", "nan"), 1,
     "INS_TCAL1_GYR1_X", "is nan: not a finite number"),
    ("ap-nan-tmin", "ardupilot", lambda s: _set(s, "INS_TCAL2_TMIN", "nan"), 1,
     "INS_TCAL2_TMIN", "is nan: not a finite number"),
    ("ap-inf", "ardupilot", lambda s: _set(s, "INS_TCAL3_ACC2_Y", "inf"), 1,
     "INS_TCAL3_ACC2_Y", "is inf: not a finite number"),
    ("ap-duplicate", "ardupilot", lambda s: _append(s, "INS_TCAL1_ACC1_X", "99"), 1,
     "INS_TCAL1_ACC1_X", "is set again (first on line"),
    ("ap-tmin-above-tmax", "ardupilot",
     lambda s: _set(_set(s, "INS_TCAL1_TMIN", "70"), "INS_TCAL1_TMAX", "5"), 1,
     "INS_TCAL1_TMIN", "INS_TCAL1_TMIN = 70 is not below INS_TCAL1_TMAX = 5"),
    ("ap-unparsable", "ardupilot", lambda s: _set(s, "INS_TCAL1_GYR2_Z", "1,5"), 1,
     None, "expected NAME,VALUE"),
    ("ap-unparsable-word", "ardupilot", lambda s: _set(s, "INS_TCAL2_GYR2_Z", "0x1p3"), 1,
     "INS_TCAL2_GYR2_Z", "value '0x1p3' is not a number"),
    ("ap-missing", "ardupilot", lambda s: _drop(s, "INS_TCAL1_ACC3_Z"), 1, "INS_TCAL1_ACC3_Z",
     "is missing"),
    ("ap-garbage-id", "ardupilot", lambda s: _append(s, "INS_GYR_ID", "12.5"), 1,
     "INS_GYR_ID", "is not a device id"),
]


def _ids(text: str) -> dict[str, str]:
    return {f.split("\t")[2]: f.split("\t")[3] for f in text.splitlines()
            if "\t" in f and f.split("\t")[2].endswith("_ID")}


@pytest.mark.parametrize("damage", DAMAGES, ids=[d[0] for d in DAMAGES])
def test_a_damaged_file_is_refused_or_failed_never_passed(
        board: dict[str, dict[str, Path]], tmp_path: Path, damage: Damage,
        capsys: pytest.CaptureFixture[str]) -> None:
    _, ap, transform, status, param, fragment = damage
    good = board[ap]["params"]
    bad = tmp_path / good.name
    bad.write_text(transform(good.read_text()))
    out = tmp_path / "v"
    rc = main(["verify", str(bad), str(board[ap]["log"]), "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip()
    assert rc == status, err
    if status == 1:
        assert not out.exists()                                   # nothing written
        assert len(err.splitlines()) == 1 and str(bad) in err and fragment in err, err
        if param is not None:
            assert f"parameter {param}" in err
            assert "is missing" in fragment \
                or f"line {_line_of(bad.read_text(), param)}" in err
        return
    # FAIL: the firmware would output non-finite rates; verify names how many per axis
    doc = json.loads((out / "results.json").read_text())
    assert doc["passed"] is False
    g0 = doc["instances"]["gyro0"]
    assert g0["passed"][0] is False and g0["pp_corrected"][0] is None and g0["cut"][0] is None
    # as many samples as the firmware's float32 arithmetic turns into inf (|T - TREF| > 1)
    fw = px4_firmware(_load(bad), board[ap]["log"])
    assert g0["nonfinite"][0] == np.count_nonzero(~np.isfinite(fw[("G", g0["device_id"])][:, 0]))
    assert 0 < g0["nonfinite"][0] < g0["n_samples"]
    assert g0["passed"][1:] == [True, True] and g0["nonfinite"][1:] == [0, 0]


NON_FINITE = ("px4-nan-coefficient", "px4-nan-tref", "px4-nan-tmin", "px4-inf-baro",
              "px4-float32-overflow", "px4-duplicate", "ap-nan-coefficient", "ap-nan-tmin",
              "ap-inf", "ap-duplicate")


@pytest.mark.parametrize("damage", [d for d in DAMAGES if d[0] in NON_FINITE],
                         ids=lambda d: d[0])
def test_what_the_firmware_would_do_with_the_damaged_file(board: dict[str, dict[str, Path]],
                                                          tmp_path: Path, damage: Damage
                                                          ) -> None:
    """The damage is real: loaded by the autopilot, each file gives non-finite rates or
    (a name twice) other rates than its first value gives."""
    _, ap, transform, _, param, _ = damage
    bad = tmp_path / board[ap]["params"].name
    bad.write_text(transform(board[ap]["params"].read_text()))
    params = _load(bad)
    fw = (px4_firmware if ap == "px4" else ardupilot_firmware)(params, board[ap]["log"])
    if "duplicate" in damage[0]:
        assert param is not None and params[param] == 99.0     # the vehicle loads the last
        first = _load(board[ap]["params"])[param]
        assert first != 99.0
        return
    assert any(not np.all(np.isfinite(v)) for v in fw.values())


@pytest.mark.parametrize("ap", ["px4", "ardupilot"])
def test_pass_means_finite_and_improved_through_the_firmware(board: dict[str, dict[str, Path]],
                                                             tmp_path: Path, ap: str) -> None:
    out = tmp_path / "v"
    assert main(["verify", str(board[ap]["params"]), str(board[ap]["log"]), "--out", str(out),
                 "-q"]) == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["passed"] is True
    fw = (px4_firmware if ap == "px4" else ardupilot_firmware)(_load(board[ap]["params"]),
                                                                board[ap]["log"])
    judged = [d for d in doc["instances"].values() if d["status"] == "judged"]
    assert len(judged) == (8 if ap == "px4" else 6) == len(fw)   # PX4: mag0's TC_M too
    if ap == "px4":
        streams = {(t, dev): (temp, y) for t, dev, temp, y in _px4_streams(board[ap]["log"])}
        for key, corrected in fw.items():
            temp, raw = streams[key]
            assert np.all(np.isfinite(corrected))
            for j in range(raw.shape[1]):
                assert _binned_pp(temp, corrected[:, j]) < _binned_pp(temp, raw[:, j]) / 3
    else:
        assert all(np.all(np.isfinite(v)) for v in fw.values())


def test_judge_axes_a_nan_anywhere_in_the_corrected_axis_fails() -> None:
    """verify's test, per axis: NaN or inf in one sample of the corrected axis is a FAIL (its
    binned drift is not computed, its cut is NaN), whatever the other samples do."""
    from thermonet.workflows.verify import Limits, judge_axes

    temp = np.linspace(10.0, 40.0, 600)
    drift = np.column_stack([0.01 * (temp - 25) / 15, 0.02 * ((temp - 25) / 15) ** 2,
                             0.001 * np.sin(temp)])
    corr = drift.copy()
    corr[300, 0] = np.nan                   # one sample of x
    corr[:, 1] = np.inf                     # all of y
    res = judge_axes(temp, drift, corr, "gyro", Limits())
    assert res["passed"] == [False, False, True]
    assert res["nonfinite"] == [1, 600, 0]
    assert math.isnan(res["pp_corrected"][0]) and math.isnan(res["cut"][0])
    assert res["pp_raw"][0] == pytest.approx(_binned_pp(temp, drift[:, 0]), rel=1e-12)
    # z: corrected exactly: nothing left, cut inf, under the floor
    assert res["pp_corrected"][2] == 0.0 and math.isinf(res["cut"][2])
    # beyond a float32 is the firmware's inf too
    huge = np.zeros_like(drift)
    huge[5, 2] = -4e38
    assert judge_axes(temp, drift, huge, "gyro", Limits())["nonfinite"] == [0, 0, 1]


def test_a_log_too_short_or_too_narrow_is_not_judged_per_instance(
        board: dict[str, dict[str, Path]], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    from thermonet.data.logs import read_log
    from thermonet.workflows.firmware_fit import MIN_SAMPLES, MIN_SPAN_C

    log = read_log(board["px4"]["log"])
    g1 = next(i for i in log.instances if i.name == "gyro1")
    keep = MIN_SAMPLES - 1
    for attr in ("time_s", "temperature_c", "values"):
        setattr(g1, attr, getattr(g1, attr)[:keep])
    a0 = next(i for i in log.instances if i.name == "acc0")
    a0.temperature_c = 30.0 + (MIN_SPAN_C - 0.5) * np.linspace(0, 1, a0.n_samples)
    path = write_log(log, tmp_path / "short.ulg")
    out = tmp_path / "v"
    rc = main(["verify", str(board["px4"]["params"]), str(path), "--out", str(out)])
    text = capsys.readouterr().out
    doc = json.loads((out / "results.json").read_text())
    assert rc == (0 if doc["passed"] else 3)
    g1d, a0d = doc["instances"]["gyro1"], doc["instances"]["acc0"]
    assert g1d["status"] == "not judged" and "passed" not in g1d
    assert g1d["reason"] == f"too few samples: {keep} (need at least {MIN_SAMPLES})"
    assert a0d["status"] == "not judged" and f"spans only {MIN_SPAN_C - 0.5:.2f} °C" in a0d["reason"]
    assert re.search(r"^gyro1 .* not judged: too few samples", text, re.M)
    assert "PASS" not in next(ln for ln in text.splitlines() if ln.startswith("acc0"))
    judged = [n for n, d in doc["instances"].items() if d["status"] == "judged"]
    assert sorted(judged) == ["acc1", "acc2", "baro0", "gyro0", "gyro2", "mag0"]


def test_the_real_six_sample_log_is_refused_not_passed(board: dict[str, dict[str, Path]],
                                                       tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    """The real PX4 log calibrate refuses (6 samples, < 0.4 °C): its sensors have the
    simulated board's device ids, so the file applies to them — and verify refuses to judge
    any, in one line, exit 1, instead of '0->0 (infx PASS)'.  (thermonet's file names the
    board it was fitted on, which is not this log's: refused as another board; the same file
    without that line, as the autopilot's own tools write it, reaches the instances.)"""
    out = tmp_path / "v"
    assert main(["verify", str(board["px4"]["params"]), str(REAL_ULG), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "belongs to another board: fitted on board" in err
    assert "is board '000600000000383638393239510d0035002d'" in err
    plain = tmp_path / "px4.params"
    plain.write_text("".join(ln for ln in board["px4"]["params"].read_text().splitlines(True)
                             if not ln.startswith("# board id:")))
    assert main(["verify", str(plain), str(REAL_ULG), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "nothing of sample_log_small.ulg can be judged" in err
    assert "gyro0: not judged, too few samples: 6 (need at least 200)" in err
    assert "acc1: not covered" in err                    # 3670050 is not the board's acc1
    assert not out.exists()


def test_exit_codes_and_their_documentation(board: dict[str, dict[str, Path]],
                                            tmp_path: Path) -> None:
    """0 PASS, 3 FAIL, 1 refused: as the module, the CLI help and the README say."""
    import thermonet.workflows.verify as verify_module
    from thermonet.cli import build_parser

    p = board["px4"]
    assert main(["verify", str(p["params"]), str(p["log"]), "--out", str(tmp_path / "a"),
                 "-q"]) == 0
    assert main(["verify", str(p["params"]), str(p["log"]), "--out", str(tmp_path / "b"),
                 "-q", "--min-cut", "1e9", "--gyro-floor", "0", "--acc-floor", "0",
                 "--baro-floor", "0"]) == verify_module.EXIT_FAILED == 3
    assert main(["verify", str(p["params"]), str(REAL_ULG), "--out", str(tmp_path / "c"),
                 "-q"]) == 1
    doc = verify_module.__doc__ or ""
    assert "Exit status: 0 PASS" in doc and "3 FAIL" in doc and "1 refused" in doc
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    section = readme[readme.index("**Verify** a file"):]
    assert "Exit 0: PASS" in section and "3: FAIL" in section and "1: refused" in section
    sub = build_parser()._subparsers._group_actions[0].choices["verify"]
    help_text = " ".join(sub.description.split())
    assert "Exit 0 PASS, 3 FAIL" in help_text and "1 refused (a damaged parameter file" in help_text


@pytest.mark.parametrize("line,reader", [("1\t1\tTC_G0_X0_0\tabc\t9", "read_px4_params"),
                                         ("INS_TCAL1_GYR1_X,abc", "read_ardupilot_params")])
def test_the_exporters_readers_name_file_line_and_parameter(tmp_path: Path, line: str,
                                                            reader: str) -> None:
    """``thermonet.exporting.read_px4_params`` / ``read_ardupilot_params`` (the export tests'
    readers): a value that is not a number names the file, the line and the parameter, not
    ``could not convert string to float``."""
    import thermonet.exporting as exporting
    from thermonet.core.errors import ExportError

    path = tmp_path / "f.params"
    path.write_text("# header\n\n" + line + "\n")
    name = line.replace(",", "\t").split("\t")[-3 if "\t1\t" in line else 0]
    with pytest.raises(ExportError) as err:
        getattr(exporting, reader)(path)
    assert str(err.value) == f"{path}: line 3: parameter {name}: value 'abc' is not a number"


@pytest.mark.parametrize("ap", ["px4", "ardupilot"])
def test_a_byte_order_mark_is_read_and_a_line_of_neither_format_says_both(
        board: dict[str, dict[str, Path]], tmp_path: Path, ap: str) -> None:
    """Windows Notepad saves a UTF-8 byte-order mark: the file was refused ("line 1: expected
    NAME,VALUE, got '\\ufeff# thermonet …'", ArduPilot's syntax for a PX4 file).  It is read
    as the same file without it, by verify and by the exporters' readers; a first line of
    neither format names both."""
    import thermonet.exporting as exporting
    from thermonet.core.errors import InputError
    from thermonet.workflows.verify import read_param_file

    src = board[ap]["params"]
    bom = tmp_path / src.name
    bom.write_bytes(b"\xef\xbb\xbf" + src.read_bytes())
    assert read_param_file(bom).params == read_param_file(src).params
    reader = exporting.read_px4_params if ap == "px4" else exporting.read_ardupilot_params
    assert reader(bom) == reader(src)
    assert main(["verify", str(bom), str(board[ap]["log"]), "--out", str(tmp_path / "v"),
                 "-q"]) == 0
    junk = tmp_path / "junk.params"
    junk.write_text("\ufeff# notes\nTC_G0_ID = 5\n")
    with pytest.raises(InputError) as err:
        read_param_file(junk)
    assert str(err.value) == (f"{junk}: line 2: 'TC_G0_ID = 5' is neither a PX4 parameter line "
                              "(Vehicle-Id Component-Id Name Value Type, tab-separated) nor an "
                              "ArduPilot one (NAME,VALUE or NAME VALUE)")


# An offset at TREF (PX4's X0) beyond what a thermal calibration can hold, per kind: the
# parameter, its value, the instance, the axis and the bound in the report's line.
OFFSETS = [("TC_M0_X0_0", "5", "mag0", 0, "5 gauss (500 µT)", "beyond the 65 µT"),
           ("TC_G0_X0_1", "0.5", "gyro0", 1, "0.5 rad/s", "beyond the 0.35 rad/s"),
           ("TC_A1_X0_2", "-3", "acc1", 2, "-3 m/s²", "beyond the 2 m/s²"),
           ("TC_B0_X0", "2500", "baro0", 0, "2500 Pa", "beyond the 1000 Pa")]


@pytest.mark.parametrize("param, value, inst, axis, given, bound", OFFSETS,
                         ids=[o[0] for o in OFFSETS])
def test_an_offset_at_tref_no_calibration_can_hold_fails(
        board: dict[str, dict[str, Path]], tmp_path: Path, capsys: pytest.CaptureFixture[str],
        param: str, value: str, inst: str, axis: int, given: str, bound: str) -> None:
    """A constant the binned drift cannot see (5 gauss on a magnetometer: 500 µT off every
    sample) FAILs the axis, exit 3, with one line naming the parameter and why; the oracle
    shows the firmware shifting every corrected sample by exactly that constant."""
    good = board["px4"]["params"]
    bad = tmp_path / good.name
    bad.write_text(_set(good.read_text(), param, value))
    out = tmp_path / "v"
    assert main(["verify", str(bad), str(board["px4"]["log"]), "--out", str(out)]) == 3
    report = capsys.readouterr().out
    fails = [ln.strip() for ln in report.splitlines() if ln.strip().startswith("FAIL: TC_")]
    assert fails == [f"FAIL: {param} = {given}: the firmware would subtract it from every "
                     f"sample at TREF; {bound} an offset at TREF can be"
                     + fails[0].split("can be", 1)[1]], report
    doc = json.loads((out / "results.json").read_text())
    d = doc["instances"][inst]
    assert doc["passed"] is False and d["status"] == "judged"
    assert d["passed"][axis] is False and d["offset_failures"] == [fails[0][len("FAIL: "):]]
    assert all(ok for j, ok in enumerate(d["passed"]) if j != axis)   # the drift itself: cut
    assert all(all(o["passed"]) for n, o in doc["instances"].items()
               if n != inst and o["status"] == "judged")
    # the firmware: the same binned drift, every sample moved by the constant
    dev = d["device_id"]
    kind = param[3]
    fw_good = px4_firmware(_load(good), board["px4"]["log"])[(kind, dev)][:, axis]
    fw_bad = px4_firmware(_load(bad), board["px4"]["log"])[(kind, dev)][:, axis]
    shift = float(value) - _load(good)[param]      # in the file's unit (gauss for TC_M)
    np.testing.assert_allclose(fw_good.astype(np.float64) - fw_bad, shift, rtol=0,
                               atol=1e-5 * abs(shift))


def test_an_offset_within_the_bound_passes_and_the_bound_is_reported(
        board: dict[str, dict[str, Path]], tmp_path: Path) -> None:
    """0.64 gauss at TREF is within the 65 µT bound (PASS); 0.66 beyond it (FAIL); the
    bounds are in results.json's limits."""
    good = board["px4"]["params"]
    rcs = []
    for value in ("0.64", "-0.66"):
        bad = tmp_path / value / good.name
        bad.parent.mkdir()
        bad.write_text(_set(good.read_text(), "TC_M0_X0_2", value))
        rcs.append(main(["verify", str(bad), str(board["px4"]["log"]), "--out",
                         str(tmp_path / value / "v"), "-q"]))
    assert rcs == [0, 3]
    doc = json.loads((tmp_path / "0.64" / "v" / "results.json").read_text())
    assert doc["limits"]["max_offset"] == {"gyro": 0.35, "acc": 2.0, "baro": 1000.0,
                                           "mag": 65.0}
