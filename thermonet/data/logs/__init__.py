"""Flight-controller logs: PX4 ULog (``.ulg``, pyulog), ArduPilot DataFlash (``.bin``, pymavlink).

``read_log(path)`` dispatches on the file suffix and returns a
:class:`FlightLog`: one :class:`SensorInstance` per sensor, with no mapping.
``LOG#instance`` (``b.ulg#gyro0``) names one sensor instance of a log wherever a
recording file is expected (:func:`read_log_instance`, :func:`split_instance`).
"""

from __future__ import annotations

from pathlib import Path

from ...core.errors import InputError
from ...core.fileio import not_a_file
from ...core.recording import Dataset
from .base import AXES, UNITS, FlightLog, SensorInstance, temperature_step
from .dataflash import read_dataflash
from .ulog import read_ulog

__all__ = ["read_log", "read_logs", "read_log_instance", "is_log", "is_log_source",
           "split_instance", "readable_instances", "log_run_id", "LOG_SUFFIXES", "FlightLog",
           "SensorInstance", "AXES", "UNITS", "temperature_step"]

#: File suffixes read as flight-controller logs (case-insensitive).
LOG_SUFFIXES = {".ulg": "ulog", ".bin": "dataflash"}


def is_log(path: str | Path) -> bool:
    """True for a ``.ulg`` / ``.bin`` (any case) path."""
    return Path(path).suffix.lower() in LOG_SUFFIXES


def split_instance(path: str | Path) -> tuple[str, str]:
    """``(file, instance)`` of ``LOG#instance`` (``"b.ulg#gyro0"`` → ``("b.ulg", "gyro0")``);
    ``(path, "")`` for anything else.  The split is at the last ``#``, and only where what
    comes before it is a log's name (``.ulg`` / ``.bin``): a file named ``run#2.ulg`` stays
    whole."""
    text = str(path)
    file, sep, name = text.rpartition("#")
    if sep and is_log(file) and name and "/" not in name and "\\" not in name:
        return file, name
    return text, ""


def is_log_source(path: str | Path) -> bool:
    """True for a flight-controller log as a recording source: a ``.ulg`` / ``.bin`` path,
    or one sensor instance of it, ``LOG#instance``."""
    return is_log(split_instance(path)[0])


def read_log(path: str | Path) -> FlightLog:
    """Read a PX4 ULog or an ArduPilot DataFlash log (by suffix); ``LOG#instance`` (one
    instance, what ``fit`` and ``info`` read) is refused, naming the log to give instead."""
    file, name = split_instance(path)
    if name:
        raise InputError.at(path, f"'#{name}' (one sensor instance) is not accepted here: this "
                            f"command reads every instance of a log — give the log itself, "
                            f"{file}")
    kind = LOG_SUFFIXES.get(Path(path).suffix.lower())
    why = not_a_file(path, "flight-controller log")  # a directory, FIFO or device by name
    if why:
        raise InputError.at(path, why)
    if kind == "ulog":
        return read_ulog(path)
    if kind == "dataflash":
        return read_dataflash(path)
    hint = ("; for a chamber recording (CSV, Parquet) use thermonet compare with a config "
            "(README)" if Path(path).suffix.lower() in (".csv", ".tsv", ".txt", ".parquet", ".pq")
            else "")
    raise InputError.at(path, "not a flight-controller log (expected .ulg or .bin)" + hint)


def read_logs(paths: list[str | Path]) -> list[FlightLog]:
    """:func:`read_log` of each path, in order."""
    return [read_log(p) for p in paths]


def readable_instances(log: FlightLog) -> list[SensorInstance]:
    """The instances ``LOG#name`` reads as a recording: those with samples and a
    thermometer of their own (a magnetometer without one is calibrated by ``thermonet
    calibrate``, which lends it another sensor's)."""
    return [i for i in log.instances if i.n_samples and i.temperature_c is not None]


def log_run_id(file: str | Path, instance: str) -> str:
    """The run id of one sensor instance of a log read as a recording: the file's stem, a
    colon and the instance (``b_run1.ulg#gyro0`` → ``b_run1:gyro0``).  Logs of the same
    board hold the same instances, so the file tells their runs apart: three warm-ups of
    ``gyro0`` in ``b_run1.ulg`` … ``b_run3.ulg`` are three runs of one unit."""
    return f"{Path(file).stem}:{instance}"


def read_log_instance(path: str | Path) -> Dataset:
    """One sensor instance of a log as a :class:`Dataset`: ``LOG#gyro0`` (``#`` + instance name).

    Without ``#name`` the log must hold exactly one calibratable instance
    (gyro, accel or baro).  This is how :func:`thermonet.data.io.read_datasets`
    reads a ``.ulg`` / ``.bin`` path.  The run's id is :func:`log_run_id` (file stem and
    instance), so logs of one board read together are distinct runs of one unit.
    """
    file, name = split_instance(path)
    log = read_log(file)
    readable = readable_instances(log)
    names = ", ".join(i.name for i in readable)
    insts = [i for i in log.instances if i.kind != "mag"]
    if name:
        insts = [i for i in log.instances if i.name == name]
        if not insts:
            raise InputError.at(file, f"no sensor instance '{name}' (readable instances: "
                                f"{names})")
        if not any(i is insts[0] for i in readable):
            why = ("holds no samples" if not insts[0].n_samples else
                   "has no thermometer of its own, so it cannot be read as a recording "
                   "(thermonet calibrate lends it another sensor's)")
            raise InputError.at(file, f"sensor instance '{name}' {why}; readable instances: "
                                f"{names}")
    if len(insts) != 1:
        what = "several sensor instances" if insts else "no gyro, accelerometer or barometer"
        raise InputError.at(file, f"the log holds {what}; name one as "
                            f"'{file}#<instance>' ({names})")
    ds = insts[0].to_dataset(file)
    for run in ds.runs:
        run.run_id = log_run_id(file, insts[0].name)
    return ds
