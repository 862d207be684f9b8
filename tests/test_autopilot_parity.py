"""``thermonet calibrate`` against the autopilots' own calibration scripts, re-implemented here.

The oracles are re-implementations of the peers' scripts, written from their source and
reading the log with the same libraries the scripts use (pyulog, pymavlink), independently
of thermonet's readers and fit:

* PX4 ``Tools/process_sensor_caldata.py`` at PX4/PX4-Autopilot commit
  00f5c319563d03d2ce482dbd1b53dff25b5a7f34: per instance TMIN/TMAX the logged extremes,
  TREF their mean; ``median_filter`` (``scipy.signal.medfilt(data, 31)``) on the outputs;
  accel as ``x - np.median(x)``; ``resampleWithDeltaX`` (2,000 temperature bins, the mean
  temperature and output of each occupied bin, a Python loop here as there); ``np.polyfit``
  order 3 (baro: 5, on ``100 * (pressure - median)``: the script takes hPa).  It lives in
  ``experiments/px4_caldata_anchor.py``, the anchor ``bench_pipeline.py`` times too.
* ArduPilot ``Tools/scripts/tempcal_IMU.py`` at ArduPilot/ardupilot commit
  d420971136c6db2430273e91d117ad8c9044bcee: ``IMU`` messages (``I``, ``T``, ``GyrX`` …,
  ``TimeUS``), ``IMUData.FilterArray`` (a moving average of ``int(n / seconds) * 2``
  samples on every column, time and temperature included), ``TEMP_REF`` 35,
  ``np.polyfit(T - 35, accel - ofs, 3)`` (``ofs`` from ``accel_at_temp`` at the logged
  ``INS_ACC<n>_CALTEMP``), ``np.polyfit(T - 35, gyro, 3)``, written ``%.9f`` × 1e6,
  TMIN/TMAX ``%.1f``.

PX4: thermonet fits the same bins without the 31-sample median filter (it screens damaged
samples when reading instead), so the two agree within a few percent of the drift, not
exactly.  ArduPilot: thermonet follows the script step by step, so the coefficients agree
to the precision both files print.  Where the peer is wrong (PX4's baro ×100, issue
#20051) the last test shows thermonet right and the script's file harmful.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from oracles import px4_offsets, read_params
from thermonet.data.logs.writers import write_log
from thermonet.sim.fcboard import simulate_board
from thermonet.workflows.calibrate import calibrate

pytestmark = pytest.mark.numerics

# ------------------------------------------------------------------ PX4's script


# the PX4 script's fit, one re-implementation shared with the benchmark's anchor (its module
# docstring cites the commit): loaded from experiments/ by path, without thermonet
_ANCHOR = Path(__file__).resolve().parents[1] / "experiments" / "px4_caldata_anchor.py"
_spec = importlib.util.spec_from_file_location("px4_caldata_anchor", _ANCHOR)
assert _spec is not None and _spec.loader is not None
px4_caldata_anchor = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(px4_caldata_anchor)
_px4_script = px4_caldata_anchor.fit


@pytest.fixture(scope="module")
def px4_board(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict, dict]:
    tmp = tmp_path_factory.mktemp("px4parity")
    board = simulate_board("fc-board", autopilot="px4", seed=21, rate_hz=1.0)
    ulg = write_log(board, tmp / "board.ulg")
    calibrate(ulg, tmp / "cal", compare=False)
    return ulg, read_params(tmp / "cal" / "px4.params"), _px4_script(ulg)


def _curves(p: dict[str, float], pre: str, i: int, grid: np.ndarray) -> np.ndarray:
    """Axis ``i`` of PX4's ``calc_thermal_offsets_3D`` (tests/oracles.py) over ``grid``."""
    return px4_offsets(p, pre, grid)[:, i]


def test_px4_fit_is_process_sensor_caldata_up_to_its_filter_padding(px4_board) -> None:
    """With the median filter's ends padded by the nearest value (thermonet's one change),
    the script's fit and thermonet's are the same numbers: every gyro and accel instance,
    the whole-degree one included, to the file's 9 significant digits."""
    ulg, ours, _ = px4_board
    script = _px4_script(ulg, pad="edge")
    for t in "GA":
        for s in range(3):
            pre = f"TC_{t}{s}_"
            assert ours[pre + "ID"] == script[pre + "ID"]
            for k in ("TMIN", "TMAX", "TREF"):
                assert ours[pre + k] == pytest.approx(script[pre + k], rel=1e-8), (pre, k)
            grid = np.linspace(script[pre + "TMIN"], script[pre + "TMAX"], 200)
            for i in range(3):
                theirs, mine = _curves(script, pre, i, grid), _curves(ours, pre, i, grid)
                # 9 printed digits on coefficients of a curve whose terms reach ~10x its p-p
                assert np.max(np.abs(mine - theirs)) <= 1e-6 * np.ptp(theirs), (pre, i)


def test_px4_cubic_agrees_with_process_sensor_caldata(px4_board) -> None:
    """Against the script itself (zero-padded median filter): the same range and TREF, and
    per axis the two cubics within 4 % of the fitted drift's peak-to-peak in RMS over
    [TMIN, TMAX], 8 % at worst.  What is left is the script's zero padding, which pulls
    the first 15 samples (the cold end, where the board warms fastest and each sample has
    a bin of its own) toward zero — see the test above."""
    _, ours, script = px4_board
    for t in "GA":
        for s in range(3):
            pre = f"TC_{t}{s}_"
            assert ours[pre + "ID"] == script[pre + "ID"]
            for k in ("TMIN", "TMAX", "TREF"):     # float32 in the log, 9 digits in the file
                assert ours[pre + k] == pytest.approx(script[pre + k], rel=1e-7), (pre, k)
            grid = np.linspace(script[pre + "TMIN"], script[pre + "TMAX"], 200)
            for i in range(3):
                theirs, mine = _curves(script, pre, i, grid), _curves(ours, pre, i, grid)
                pp = np.ptp(theirs)
                assert np.sqrt(np.mean((mine - theirs) ** 2)) <= 0.04 * pp, (pre, i)
                assert np.max(np.abs(mine - theirs)) <= 0.08 * pp, (pre, i)


def test_px4_script_baro_is_100x_off_where_thermonet_is_right(px4_board) -> None:
    """PX4 issue #20051: ``process_sensor_caldata.py`` multiplies the pressure by 100
    ("convert from hPa to Pa"), but ``sensor_baro.pressure`` is logged in Pa — its baro
    coefficients come out 100× too large, and loaded on the board they make the drift
    about 100× worse.  thermonet reads the unit from the value and writes Pa: through the
    same firmware formula its file cuts the drift."""
    from pyulog import ULog

    ulg, ours, script = px4_board
    grid = np.linspace(script["TC_B0_TMIN"], script["TC_B0_TMAX"], 200)
    theirs = px4_offsets(script, "TC_B0_", grid)
    mine = px4_offsets(ours, "TC_B0_", grid)
    # the same curve, 100x: the script's file holds the drift in units of 1/100 Pa
    assert np.max(np.abs(theirs / 100.0 - mine)) <= 0.05 * np.ptp(mine)
    d = ULog(str(ulg), ["sensor_baro"]).data_list[0].data
    temp, press = d["temperature"].astype(np.float64), d["pressure"].astype(np.float64)
    y = press - np.median(press)

    def binned_pp(v: np.ndarray) -> float:
        bins = np.floor(temp)
        return float(np.ptp([v[bins == b].mean() for b in np.unique(bins)]))

    before = binned_pp(y)
    assert before > 20.0                                           # tens of Pa of drift
    assert binned_pp(y - px4_offsets(ours, "TC_B0_", temp)) <= before / 3
    assert binned_pp(y - px4_offsets(script, "TC_B0_", temp)) >= 50 * before

# ------------------------------------------------------------------ ArduPilot's script


def _moving_average(data: np.ndarray, w: int) -> np.ndarray:
    ret = np.cumsum(data)
    ret[w:] = ret[w:] - ret[:-w]
    return ret[w - 1:] / w


def _accel_at_temp(temps: np.ndarray, values: np.ndarray, temperature: float) -> float:
    if temperature < temps[0]:
        return float(values[0])
    for i in range(len(temps) - 1):
        if temps[i] <= temperature <= temps[i + 1]:
            p = (temperature - temps[i]) / (temps[i + 1] - temps[i])
            return float(values[i] + (values[i + 1] - values[i]) * p)
    return float(values[-1])


def _tempcal_imu(bin_path: Path) -> dict[str, str]:
    """``tempcal_IMU.py`` (no ``--online``, no ``--tclr``): its printed ``NAME VALUE`` lines."""
    from pymavlink import mavutil

    mlog = mavutil.mavlink_connection(str(bin_path))
    cols = ["X", "Y", "Z", "T", "time"]
    acc: dict[int, dict[str, list[float]]] = {}
    gyr: dict[int, dict[str, list[float]]] = {}
    atcal: dict[int, float] = {}
    while True:
        msg = mlog.recv_match(type=["PARM", "IMU"])
        if msg is None:
            break
        if msg.get_type() == "PARM":
            name = msg.Name
            if name.startswith("INS_ACC") and name.endswith("_CALTEMP") and name[7].isdigit():
                atcal[int(name[7]) - 1] = msg.Value
            continue
        a = acc.setdefault(msg.I, {c: [] for c in cols})
        g = gyr.setdefault(msg.I, {c: [] for c in cols})
        for dct, vals in ((a, (msg.AccX, msg.AccY, msg.AccZ)), (g, (msg.GyrX, msg.GyrY, msg.GyrZ))):
            for c, v in zip("XYZ", vals, strict=True):
                dct[c].append(v)
            dct["T"].append(msg.T)
            dct["time"].append(msg.TimeUS * 1.0e-6)
    out: dict[str, str] = {}
    for imu in sorted(acc):
        data = {}
        for key, dct in (("acc", acc[imu]), ("gyr", gyr[imu])):
            arr = {c: np.array(dct[c], dtype=float) for c in cols}
            window = int(len(arr["time"]) / (arr["time"][-1] - arr["time"][0])) * 2
            if window > 1:
                arr = {c: _moving_average(v, window) for c, v in arr.items()}
            data[key] = arr
        pre = f"INS_TCAL{imu + 1}_"
        out[pre + "TMIN"] = f"{np.amin(data['acc']['T']):.1f}"  # '%.1f'
        out[pre + "TMAX"] = f"{np.amax(data['acc']['T']):.1f}"  # '%.1f'
        for key, stype in (("acc", "ACC"), ("gyr", "GYR")):
            arr = data[key]
            trel = arr["T"] - 35.0
            for axis in "XYZ":
                y = arr[axis]
                if key == "acc":
                    ofs = (_accel_at_temp(arr["T"], y, atcal[imu]) if imu in atcal
                           else np.mean(y))
                    y = y - ofs
                coef = np.polyfit(trel, y, 3)
                for p in range(3):
                    out[f"{pre}{stype}{p + 1}_{axis}"] = "%.9f" % (coef[3 - (p + 1)] * 1.0e6)
    return out


def test_ardupilot_agrees_with_tempcal_imu_to_its_printed_precision(tmp_path: Path) -> None:
    board = simulate_board("fc-board", autopilot="ardupilot", seed=22, rate_hz=1.0)
    bin_path = write_log(board, tmp_path / "board.bin")
    calibrate(bin_path, tmp_path / "cal", compare=False)
    ours = read_params(tmp_path / "cal" / "ardupilot.parm")
    script = _tempcal_imu(bin_path)
    # the fine thermometers (IMU 1, 2); IMU 3's whole degrees are binned by thermonet instead
    checked = 0
    for name, text in script.items():
        if not name.startswith(("INS_TCAL1_", "INS_TCAL2_")):
            continue
        theirs = float(text)
        if name.endswith(("TMIN", "TMAX")):
            assert abs(ours[name] - theirs) <= 0.05 + 1e-6, name          # "%.1f"
            continue
        # the script prints 9 decimals, thermonet 9 significant digits: both roundings
        ulp9 = 0.5 * 10.0 ** (math.floor(math.log10(abs(theirs))) - 8) if theirs else 0.0
        assert abs(ours[name] - theirs) <= 0.5e-9 + ulp9 + 1e-12 * abs(theirs), (
            name, ours[name], text)
        checked += 1
    assert checked == 2 * 2 * 3 * 3          # 2 IMUs x (acc, gyro) x 3 orders x 3 axes
