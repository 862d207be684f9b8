"""Flight-controller logs: PX4 ULog (``.ulg``, pyulog), ArduPilot DataFlash (``.bin``, pymavlink).

``read_log(path)`` dispatches on the file suffix and returns a
:class:`FlightLog`: one :class:`SensorInstance` per sensor, with no mapping.
"""

from __future__ import annotations

from pathlib import Path

from ...core.errors import InputError
from ...core.fileio import not_a_file
from ...core.recording import Dataset
from .base import AXES, UNITS, FlightLog, SensorInstance, temperature_step
from .dataflash import read_dataflash
from .ulog import read_ulog

__all__ = ["read_log", "read_logs", "read_log_instance", "is_log", "LOG_SUFFIXES", "FlightLog",
           "SensorInstance", "AXES", "UNITS", "temperature_step"]

#: File suffixes read as flight-controller logs (case-insensitive).
LOG_SUFFIXES = {".ulg": "ulog", ".bin": "dataflash"}


def is_log(path: str | Path) -> bool:
    """True for a ``.ulg`` / ``.bin`` (any case) path."""
    return Path(path).suffix.lower() in LOG_SUFFIXES


def read_log(path: str | Path) -> FlightLog:
    """Read a PX4 ULog or an ArduPilot DataFlash log (by suffix)."""
    kind = LOG_SUFFIXES.get(Path(path).suffix.lower())
    why = not_a_file(path, "flight-controller log")  # a directory, FIFO or device by name
    if why:
        raise InputError.at(path, why)
    if kind == "ulog":
        return read_ulog(path)
    if kind == "dataflash":
        return read_dataflash(path)
    raise InputError.at(path, "not a flight-controller log (expected .ulg or .bin)")


def read_logs(paths: list[str | Path]) -> list[FlightLog]:
    """:func:`read_log` of each path, in order."""
    return [read_log(p) for p in paths]


def read_log_instance(path: str | Path) -> Dataset:
    """One sensor instance of a log as a :class:`Dataset`: ``LOG#gyro0`` (``#`` + instance name).

    Without ``#name`` the log must hold exactly one calibratable instance
    (gyro, accel or baro).  This is how :func:`thermonet.data.io.read_datasets`
    reads a ``.ulg`` / ``.bin`` path.
    """
    text = str(path)
    file, _, name = text.partition("#")
    log = read_log(file)
    insts = [i for i in log.instances if i.kind != "mag"]
    if name:
        insts = [i for i in log.instances if i.name == name]
        if not insts:
            raise InputError.at(file, f"no sensor instance '{name}' (instances: "
                                f"{', '.join(i.name for i in log.instances)})")
    if len(insts) != 1:
        raise InputError.at(file, "the log holds several sensor instances; name one as "
                            f"'{file}#<instance>' ({', '.join(i.name for i in insts)})")
    return insts[0].to_dataset(file)
