"""The drift a flight log reveals: the estimator's sensor biases and the still-on-the-ground gyro.

``read_bias_log(path)`` (PX4 ``.ulg`` or ArduPilot ``.bin``) returns a :class:`BiasLog`: per
sensor (by device id) one or more :class:`BiasSeries` whose ``drift`` is the sensor's own
temperature drift as the chamber path defines it — the raw sensor-frame output with nothing
applied — together with the sensor's thermometer at the same instants.

What is read
------------
**PX4** (``msg/EstimatorSensorBias.msg``), every ``estimator_sensor_bias`` instance (one per
EKF2 instance): ``gyro_device_id``, ``gyro_bias[3]`` (rad/s), ``accel_device_id``,
``accel_bias[3]`` (m/s²), body frame, "subtract from uncorrected data".  Newer firmware adds
``*_bias_variance[3]`` and ``*_bias_valid``; older firmware (the real fixture
``tests/data/real/px4_ulog_sample``) has neither: both forms are read.  The sensor's
temperature is the ``sensor_gyro`` / ``sensor_accel`` instance with the same device id,
interpolated to the bias times.

**ArduPilot** (``libraries/AP_NavEKF3/LogStructure.h``): ``XKF1`` per core ``C``, ``GX, GY,
GZ`` (logged as int16 centi-degrees per second, format ``c``; pymavlink returns deg/s,
converted to rad/s here) and ``XKF2`` ``AX, AY, AZ`` (int16 centi-m/s², pymavlink m/s²).
Core ``k`` runs on the ``k``-th IMU set in ``EK3_IMU_MASK`` (default 3: IMUs 0 and 1).
Older logs of EKF2 (the real fixture ``tests/data/real/ardupilot_bin_sample``, 2017): the gyro
bias of ``NKF1`` (core 0) and ``NKF6`` (core 1), same fields and units, cores on
``EK2_IMU_MASK``; EKF2 logs only the accelerometer's z bias, which is not learned.  The
temperature is that IMU's ``IMU.T``.  EKF3 logs no per-bias variance or validity flag in
XKF1/XKF2: every sample counts equally, and convergence is by time (below).

**Still on the ground** (both autopilots): every gyro's raw samples in
:data:`STILL_WINDOW_S` windows where every axis's standard deviation is under
:data:`STILL_STD_RAD_S` and the mean rate under :data:`STILL_MAX_RATE_RAD_S`: the vehicle is
not turning, so the mean *is* the bias (the Earth's rotation, ≤ 7.3e-5 rad/s, is left in).
This covers every gyro, also those no estimator runs on, and the warm-up before the
estimator has converged.

What is undone
--------------
The estimator's bias is relative to the data it is fed, which the autopilot has already
corrected (``src/lib/sensor_calibration``; ``AP_InertialSensor_Backend::_rotate_and_correct_*``):
``fed = R · scale · (raw − TC(T) − offset)``.  So ``raw drift = scale⁻¹ · Rᵀ · bias +
offset + TC(T)``, with

* PX4: ``R`` = ``SENS_BOARD_ROT`` (the rotations of PX4's ``rotation.h`` table below) after
  the ``SENS_BOARD_{X,Y,Z}_OFF`` trims; ``offset`` = ``CAL_GYRO<n>_{X,Y,Z}OFF`` /
  ``CAL_ACC<n>_{X,Y,Z}OFF`` of the slot whose ``CAL_*<n>_ID`` is the device id, ``scale`` =
  ``CAL_ACC<n>_{X,Y,Z}SCALE``; ``TC(T)`` = the ``TC_G`` / ``TC_A`` slot with that id when
  ``TC_*_ENABLE`` = 1 (PX4's ``calc_thermal_offsets_3D``).  ``sensor_gyro`` is raw already
  (the still windows undo nothing).
* ArduPilot: ``R`` = ``AHRS_ORIENTATION``; ``offset`` = ``INS_GYROFFS`` / ``INS_GYR2OFFS`` …
  — the boot-time gyro calibration saves its offsets there, so a log's value is the one in
  effect — and ``INS_ACCOFFS`` …, ``scale`` = ``INS_ACCSCAL`` …; ``TC(T)`` = ``INS_TCAL<n>``
  when enabled (``TCal::correct_sensor``).  The ``IMU`` gyro is logged after all of them:
  the still windows add the offset back (the rotation and ``INS_TCAL`` are undone by
  :func:`~thermonet.data.logs.dataflash.read_dataflash`).

Each series says what was undone in its notes.  The last value a log records for a
parameter is the one used (ArduPilot logs a parameter again when it changes).

Validity and convergence
------------------------
A sample is kept (``valid``) where the log says the estimate is valid (``*_bias_valid``, newer
PX4), its variance is finite and at most :data:`MAX_VARIANCE_RATIO` times the median variance
of the series' second half (converged), its magnitude is under the log's ``*_bias_limit``
where logged, and — for logs without a validity flag — from :data:`CONVERGE_S` seconds after
the series' first sample on.  ``variance`` is kept for weighting (``None`` when not logged).
A log whose clock jumps (back in time, or a gap over :data:`MAX_GAP_S`) is refused in one line.
"""

from __future__ import annotations

import contextlib
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import InputError
from ..firmware import px4_offsets_3d
from .base import FlightLog, SensorInstance
from .dataflash import ardupilot_tcal_correction, orientation_matrix, read_dataflash
from .ulog import read_ulog

__all__ = ["BiasSeries", "BiasLog", "read_bias_log", "px4_board_rotation", "still_windows",
           "STILL_WINDOW_S", "STILL_STD_RAD_S", "STILL_MAX_RATE_RAD_S", "CONVERGE_S",
           "MAX_VARIANCE_RATIO", "MAX_GAP_S", "BIAS_KINDS"]

#: Sensor kinds whose bias the estimators log and thermonet learns.
BIAS_KINDS = ("gyro", "acc")
#: Length of a still-detection window, s.
STILL_WINDOW_S = 10.0
#: Largest per-axis standard deviation (rad/s) of the raw gyro in a still window.
STILL_STD_RAD_S = 0.01
#: Largest mean rate (rad/s) of a still window (a steady turn is not still).
STILL_MAX_RATE_RAD_S = 0.1
#: Logs without a validity flag: the estimate is trusted from this many seconds after the
#: estimator's first sample (three times a slow EKF bias time constant).
CONVERGE_S = 300.0
#: A sample whose variance exceeds this multiple of its series' settled (median, second
#: half) variance has not converged.
MAX_VARIANCE_RATIO = 25.0
#: A step of the log's clock longer than this (s), or backwards, is a clock jump.
MAX_GAP_S = 60.0
_RAD_PER_DEG = math.pi / 180.0
#: EKF2's gyro-bias messages (older ArduPilot): ``NKF1`` core 0, ``NKF6`` core 1, the same
#: ``GX, GY, GZ`` (int16 centi-degrees per second) as ``XKF1``, without a core field.
_EKF2_GYRO = {"NKF1": 0, "NKF6": 1}
#: PX4 ``rotation.h``: (roll, pitch, yaw) in degrees of ``SENS_BOARD_ROT`` 0..20.
_PX4_ROTATIONS = [(0, 0, 0), (0, 0, 45), (0, 0, 90), (0, 0, 135), (0, 0, 180), (0, 0, 225),
                  (0, 0, 270), (0, 0, 315), (180, 0, 0), (180, 0, 45), (180, 0, 90),
                  (180, 0, 135), (0, 180, 0), (180, 0, 225), (180, 0, 270), (180, 0, 315),
                  (90, 0, 0), (90, 0, 45), (90, 0, 90), (90, 0, 135), (270, 0, 0)]


@dataclass
class BiasSeries:
    """One sensor's drift as one source of one log reveals it (see the module).

    ``source`` is ``ekf`` (the estimator's bias, instance ``estimator``) or ``still`` (the
    raw gyro's mean in still windows; ``estimator`` is -1).  ``drift`` (n, 3) SI in the
    sensor frame, with what the log applied undone; ``temperature_c`` the sensor's own
    thermometer at ``time_s`` (not lagged); ``variance`` (n, 3) as logged, or for still
    windows the variance of the window mean (None: not logged); ``valid`` the samples to use.
    """

    kind: str
    device_id: int
    source: str
    estimator: int
    time_s: np.ndarray
    drift: np.ndarray
    temperature_c: np.ndarray
    valid: np.ndarray
    variance: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    #: (n, 3) the part of ``drift`` that is what the autopilot applied (offsets, TC(T)),
    #: added back at once — the estimator's lag is in ``drift − applied`` only (None: none).
    applied: np.ndarray | None = None

    @property
    def name(self) -> str:
        where = f"ekf{self.estimator}" if self.source == "ekf" else "still"
        return f"{self.kind} {self.device_id} ({where})"


@dataclass
class BiasLog:
    """What one log reveals of its sensors' drift: the series, the sensors it holds (device
    ids by instance name) and the board's own id where logged (together: the vehicle's
    identity), and the parameters."""

    path: Path
    autopilot: str
    series: list[BiasSeries]
    sensors: dict[str, int]
    params: dict[str, float]
    duration_s: float
    notes: list[str] = field(default_factory=list)
    board_id: str | None = None


def read_bias_log(path: str | Path) -> BiasLog:
    """Read the estimator's biases and the still-gyro windows of a PX4 / ArduPilot log.

    Raises
    ------
    InputError
        Not a readable log (the readers' own lines), no estimator bias in it ("firmware
        without bias topics"), or a clock that jumps — one line naming the file.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".ulg":
        log = read_ulog(path)
        raw, notes = _px4_bias_rows(path)
    elif suffix == ".bin":
        log = read_dataflash(path)
        raw, notes = _ardupilot_bias_rows(path, log.params)
    else:
        raise InputError.at(path, "not a flight-controller log (expected .ulg or .bin)")
    if not raw:
        what = ("no estimator_sensor_bias topic" if suffix == ".ulg"
                else "no XKF1 / XKF2 messages")
        raise InputError.at(path, f"{what}: this firmware logs no estimator bias to learn from")
    _check_clock(path, raw)
    series = [s for r in raw for s in _ekf_series(log, r)]
    series += [s for inst in log.instances if inst.kind == "gyro"
               for s in [still_windows(inst, log.autopilot, log.params)] if s is not None]
    sensors = {i.name: i.device_id for i in log.instances if i.kind in BIAS_KINDS}
    t_all = np.concatenate([i.time_s for i in log.instances if i.n_samples] or [np.zeros(1)])
    return BiasLog(path=path, autopilot=log.autopilot, series=series, sensors=sensors,
                   params=dict(log.params), duration_s=float(np.ptp(t_all)),
                   notes=notes + list(log.notes), board_id=getattr(log, "board_id", None))


def _check_clock(path: Path, raw: list[dict[str, Any]]) -> None:
    """Refuse a log whose clock steps back or jumps forward by over :data:`MAX_GAP_S`, judged
    on the estimator's rows in the log's own order (the sensor readers sort and screen their
    samples)."""
    for name, t in ((f"estimator {r['estimator']} {r['kind']} bias", np.asarray(r["time_s"]))
                    for r in raw):
        if t.size < 2:
            continue
        dt = np.diff(t)
        k = int(np.argmin(dt))
        if dt[k] < 0:
            raise InputError.at(path, f"the clock jumps back by {-dt[k]:.1f} s at t = "
                                f"{t[k]:.1f} s ({name}): timestamps cannot be trusted")
        k = int(np.argmax(dt))
        if dt[k] > MAX_GAP_S:
            raise InputError.at(path, f"the clock jumps forward by {dt[k]:.1f} s at t = "
                                f"{t[k]:.1f} s ({name}): timestamps cannot be trusted")


def _ulog_columns(d: Any, stem: str) -> np.ndarray | None:
    """``stem[0..2]`` of a pyulog dataset as (n, 3), or None when the log lacks them."""
    cols = [d.data.get(f"{stem}[{j}]") for j in range(3)]
    if any(c is None for c in cols):
        return None
    return np.column_stack([np.asarray(c, dtype=np.float64) for c in cols])


def _px4_bias_rows(path: Path) -> tuple[list[dict[str, Any]], list[str]]:
    """Per ``estimator_sensor_bias`` instance and kind: the raw rows (times, device ids,
    bias, variance and valid where logged, the limit where logged)."""
    from pyulog import ULog

    try:
        with contextlib.redirect_stdout(io.StringIO()):
            ulog = ULog(str(path), ["estimator_sensor_bias"])
    except Exception as err:  # noqa: BLE001 — pyulog raises anything on a corrupt file
        raise InputError.at(path, f"not a readable ULog ({type(err).__name__})") from None
    rows: list[dict[str, Any]] = []
    notes: list[str] = []
    for d in sorted(ulog.data_list, key=lambda d: d.multi_id):
        t = np.asarray(d.data["timestamp"], dtype=np.float64) * 1e-6
        for kind, pre in (("gyro", "gyro"), ("acc", "accel")):
            bias = _ulog_columns(d, f"{pre}_bias")
            ids = d.data.get(f"{pre}_device_id")
            if bias is None or ids is None:
                continue
            var = _ulog_columns(d, f"{pre}_bias_variance")
            valid = d.data.get(f"{pre}_bias_valid")
            limit = d.data.get(f"{pre}_bias_limit")
            if var is None and valid is None:
                notes.append(f"estimator_sensor_bias {d.multi_id} {kind}: older firmware (no "
                             f"variance or validity): trusted from {CONVERGE_S:g} s on")
            rows.append({"kind": kind, "estimator": int(d.multi_id), "time_s": t,
                         "device_id": np.asarray(ids, dtype=np.int64), "bias": bias,
                         "variance": var,
                         "valid": None if valid is None else np.asarray(valid, dtype=bool),
                         "limit": None if limit is None else np.asarray(limit, dtype=float)})
    return rows, notes


def _ardupilot_bias_rows(path: Path, params: dict[str, float]
                         ) -> tuple[list[dict[str, Any]], list[str]]:
    """Per EKF3 core and kind: XKF1 gyro bias (deg/s → rad/s), XKF2 accel bias (m/s²), with
    the device id of the IMU the core runs on (``EK3_IMU_MASK``)."""
    from pymavlink import DFReader

    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            reader = DFReader.DFReader_binary(str(path), zero_time_base=True)
            got: dict[tuple[str, int], list[list[float]]] = {}
            while True:
                m = reader.recv_match(type=["XKF1", "XKF2", *_EKF2_GYRO])
                if m is None:
                    break
                if m.get_type() in _EKF2_GYRO:          # EKF2 (older firmware): gyro only
                    got.setdefault(("gyro2", _EKF2_GYRO[m.get_type()]), []).append(
                        [m.TimeUS * 1e-6, m.GX * _RAD_PER_DEG, m.GY * _RAD_PER_DEG,
                         m.GZ * _RAD_PER_DEG])
                elif m.get_type() == "XKF1":
                    got.setdefault(("gyro", int(m.C)), []).append(
                        [m.TimeUS * 1e-6, m.GX * _RAD_PER_DEG, m.GY * _RAD_PER_DEG,
                         m.GZ * _RAD_PER_DEG])
                else:
                    got.setdefault(("acc", int(m.C)), []).append(
                        [m.TimeUS * 1e-6, m.AX, m.AY, m.AZ])
    except Exception as err:  # noqa: BLE001 — pymavlink raises anything on a corrupt file
        raise InputError.at(path, f"XKF1 / XKF2 cannot be read ({type(err).__name__})") from None
    if any(k in ("gyro", "acc") for k, _ in got):   # EKF3 logged: EKF2's rows not used
        got = {key: v for key, v in got.items() if key[0] != "gyro2"}
    rows: list[dict[str, Any]] = []
    for (kind0, core), data in sorted(got.items()):
        ekf = "EK2" if kind0 == "gyro2" else "EK3"
        kind = "gyro" if kind0 == "gyro2" else kind0
        mask = int(params.get(f"{ekf}_IMU_MASK", 3))
        imus = [k for k in range(3) if mask >> k & 1]
        if core >= len(imus):
            continue
        a = np.asarray(data, dtype=np.float64)
        n = "" if imus[core] == 0 else str(imus[core] + 1)
        dev = int(params.get(f"INS_{'GYR' if kind == 'gyro' else 'ACC'}{n}_ID", 0))
        rows.append({"kind": kind, "estimator": core, "time_s": a[:, 0],
                     "device_id": np.full(a.shape[0], dev, dtype=np.int64), "bias": a[:, 1:4],
                     "variance": None, "valid": None, "limit": None, "imu": imus[core]})
    notes = ["EKF3 / EKF2 log no bias variance or validity: every sample weighs the same, "
             f"trusted from {CONVERGE_S:g} s after each core's first sample"] if rows else []
    if any(key[0] == "gyro2" for key in got):
        notes.append("EKF2 log (NKF1 / NKF6): its gyro biases read; EKF2 logs only the "
                     "accelerometer's z bias (NKF2.AZbias), not learned")
    return rows, notes


def px4_board_rotation(params: dict[str, float]) -> np.ndarray:
    """PX4's board rotation ``R`` (sensor → body): ``SENS_BOARD_ROT`` then the
    ``SENS_BOARD_{X,Y,Z}_OFF`` trims (degrees), as ``sensor_calibration`` builds it."""
    rot = int(params.get("SENS_BOARD_ROT", 0))
    if not 0 <= rot < len(_PX4_ROTATIONS):
        raise InputError(f"SENS_BOARD_ROT {rot}: thermonet knows PX4 rotations "
                         f"0..{len(_PX4_ROTATIONS) - 1}")
    trim = _euler(*(params.get(f"SENS_BOARD_{a}_OFF", 0.0) for a in "XYZ"))
    return trim @ _euler(*_PX4_ROTATIONS[rot])


def _euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """The direction-cosine matrix of (roll, pitch, yaw) in degrees (3-2-1)."""
    r, p, y = (math.radians(float(v)) for v in (roll, pitch, yaw))
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    return np.round(rz @ ry @ rx, 12)


def _slot(params: dict[str, float], prefix: str, device_id: int) -> int | None:
    """The slot ``n`` whose ``<prefix><n>_ID`` is ``device_id`` (PX4's CAL_* / TC_*)."""
    for n in range(4):
        if int(params.get(f"{prefix}{n}_ID", -1)) == device_id:
            return n
    return None


def _px4_applied(params: dict[str, float], kind: str, device_id: int, temp: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """PX4: (R, scale (3,), offset (n, 3) incl. TC(T)) applied to ``device_id``, and notes."""
    notes: list[str] = []
    rot = px4_board_rotation(params)
    if not np.allclose(rot, np.eye(3)):
        notes.append(f"rotated back from the body frame (SENS_BOARD_ROT "
                     f"{int(params.get('SENS_BOARD_ROT', 0))} and its trims)")
    cal = "CAL_GYRO" if kind == "gyro" else "CAL_ACC"
    slot = _slot(params, cal, device_id)
    offset = np.zeros((temp.size, 3))
    scale = np.ones(3)
    if slot is not None:
        offset += [params.get(f"{cal}{slot}_{a}OFF", 0.0) for a in "XYZ"]
        if kind == "acc":
            s = np.array([params.get(f"{cal}{slot}_{a}SCALE", 1.0) for a in "XYZ"])
            scale = np.where(s > 0, s, 1.0)
        notes.append(f"{cal}{slot} offsets{' and scales' if kind == 'acc' else ''} added back")
    letter = "G" if kind == "gyro" else "A"
    tc = _slot(params, f"TC_{letter}", device_id)
    if params.get(f"TC_{letter}_ENABLE", 0.0) == 1.0 and tc is not None:
        try:
            offset += px4_offsets_3d(params, kind, temp, tc)
            notes.append(f"TC_{letter}_ENABLE=1: slot TC_{letter}{tc}'s thermal correction "
                         "added back")
        except KeyError as err:
            notes.append(f"TC_{letter}{tc} incomplete in the log ({err}): not undone")
    return rot, scale, offset, notes


def _ardupilot_applied(params: dict[str, float], kind: str, imu: int, temp: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """ArduPilot: (R, scale, offset (n, 3) incl. INS_TCAL(T)) applied to IMU ``imu``."""
    orient = int(params.get("AHRS_ORIENTATION", 0))
    rot = orientation_matrix(orient).T if orient else np.eye(3)
    notes = [f"rotated back from the body frame (AHRS_ORIENTATION {orient})"] if orient else []
    n = "" if imu == 0 else str(imu + 1)
    name = f"INS_GYR{n}OFFS" if kind == "gyro" else f"INS_ACC{n}OFFS"
    offset = np.tile([params.get(f"{name}_{a}", 0.0) for a in "XYZ"], (temp.size, 1))
    scale = np.ones(3)
    if kind == "acc":
        s = np.array([params.get(f"INS_ACC{n}SCAL_{a}", 1.0) for a in "XYZ"])
        scale = np.where(s > 0, s, 1.0)
    notes.append(f"{name} added back" + (" (the boot-time gyro calibration's offsets)"
                                         if kind == "gyro" else " and INS_ACC*SCAL undone"))
    corr = ardupilot_tcal_correction(params, imu + 1, kind, temp)
    if corr is not None:
        offset = offset + corr
        notes.append(f"INS_TCAL{imu + 1}_ENABLE=1: its temperature correction added back")
    return rot, scale, offset, notes


def _ekf_series(log: FlightLog, r: dict[str, Any]) -> list[BiasSeries]:
    """One estimator's rows as series, one per device id it ran on, with the applied
    calibration undone and the convergence rules applied."""
    out = []
    for dev in np.unique(r["device_id"]):
        sel = r["device_id"] == dev
        inst = next((i for i in log.instances if i.kind == r["kind"] and i.device_id == dev
                     and i.temperature_c is not None and i.n_samples), None)
        if inst is None or int(dev) == 0:
            continue
        t = r["time_s"][sel]
        temp = np.interp(t, inst.time_s, np.asarray(inst.temperature_c, dtype=np.float64))
        if log.autopilot == "px4":
            rot, scale, offset, notes = _px4_applied(log.params, r["kind"], int(dev), temp)
        else:
            rot, scale, offset, notes = _ardupilot_applied(log.params, r["kind"], r["imu"],
                                                           temp)
        drift = (r["bias"][sel] @ rot) / scale + offset      # Rᵀ·b row-wise, then scale⁻¹
        var = None if r["variance"] is None else (r["variance"][sel] @ (rot ** 2)) / scale ** 2
        valid = _valid(t, r["bias"][sel], None if r["valid"] is None else r["valid"][sel],
                       var, None if r["limit"] is None else r["limit"][sel])
        out.append(BiasSeries(r["kind"], int(dev), "ekf", int(r["estimator"]), t, drift, temp,
                              valid, var, notes, applied=offset))
    return out


def _valid(t: np.ndarray, bias: np.ndarray, flag: np.ndarray | None,
           variance: np.ndarray | None, limit: np.ndarray | None) -> np.ndarray:
    """The samples to use (see the module's *Validity and convergence*)."""
    ok = np.all(np.isfinite(bias), axis=1)
    if flag is not None:
        ok &= flag
    if variance is not None:
        v = np.max(variance, axis=1)
        settled = v[v.size // 2:]
        settled = settled[np.isfinite(settled)]
        ref = float(np.median(settled)) if settled.size else math.inf
        ok &= np.isfinite(v) & (v <= MAX_VARIANCE_RATIO * max(ref, 1e-30))
    if limit is not None:
        ok &= ~(np.linalg.norm(bias, axis=1) >= limit) | ~(limit > 0)
    if flag is None and variance is None and t.size:
        ok &= t - t[0] >= CONVERGE_S
    return np.asarray(ok, dtype=bool)


def still_windows(inst: SensorInstance, autopilot: str, params: dict[str, float]
                  ) -> BiasSeries | None:
    """A gyro's still windows (see the module) as a series, or None when it has none."""
    if inst.temperature_c is None or inst.n_samples < 3:
        return None
    t = np.asarray(inst.time_s, dtype=np.float64)
    edges = np.floor((t - t[0]) / STILL_WINDOW_S).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, np.diff(edges) != 0])
    ends = np.r_[starts[1:], t.size]
    rows = []
    for a, b in zip(starts, ends, strict=True):
        if b - a < 5:
            continue
        v = inst.values[a:b]
        sd = v.std(axis=0, ddof=1)
        mean = v.mean(axis=0)
        if np.all(sd < STILL_STD_RAD_S) and np.all(np.abs(mean) < STILL_MAX_RATE_RAD_S):
            rows.append([t[a:b].mean(), float(np.mean(inst.temperature_c[a:b])), *mean,
                         *(sd ** 2 / (b - a))])
    if not rows:
        return None
    arr = np.asarray(rows)
    notes = ["still windows: the raw gyro's mean"]
    drift = arr[:, 2:5]
    if autopilot == "ardupilot":      # IMU is logged after INS_GYROFFS: added back
        n = "" if inst.instance == 0 else str(inst.instance + 1)
        drift = drift + [params.get(f"INS_GYR{n}OFFS_{a}", 0.0) for a in "XYZ"]
        notes.append(f"INS_GYR{n}OFFS added back")
    return BiasSeries("gyro", inst.device_id, "still", -1, arr[:, 0], drift, arr[:, 1],
                      np.ones(arr.shape[0], dtype=bool), arr[:, 5:8], notes)
