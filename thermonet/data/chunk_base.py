"""What every chunked read (:mod:`thermonet.data.chunks`) stands on: what a recording file
holds (:class:`Layout`: its runs, columns and size; :class:`RunTimes`: a run's first and last
time, samples, median step and temperature extremes, tallied by :class:`RunTally`), a Parquet
file opened with its page checksums verified and read in record batches (a damaged page one
line), and a run's time checked across chunk edges (:class:`Continuity`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ..core.errors import InputError
from ..core.fileio import not_a_file
from .mapping import ColumnMapping
from .parquet_format import READ_OPTIONS
from .values import check_time

__all__ = ["MEDIAN_SAMPLES", "RunTimes", "Layout", "ParquetLayout", "RunTally", "Continuity",
           "parquet_file", "batches"]

#: A run's median sample step (its gap rule) is taken over this many first samples.
MEDIAN_SAMPLES = 4096
_READ = {"pre_buffer": False, "buffer_size": 1 << 20, **READ_OPTIONS}


@dataclass
class RunTimes:
    """A run's first and last time, its samples, its first :data:`MEDIAN_SAMPLES` time
    steps' median and its temperature's extremes (None without a thermometer)."""

    first: float
    last: float
    n: int
    median_step: float
    temperature: tuple[float, float] | None


@dataclass
class Layout:
    """What a recording file holds: its runs (entries as in the ``thermonet`` metadata blob:
    ``run_id``, ``device_id``, ``sensor_kind``, ``sample_rate_hz``, ``meta``, ``units``,
    ``temperature``, the channel groups, ``n_samples``), its columns and its size.

    ``kind`` is ``thermonet`` (the footer gave it all), ``parquet`` or ``text`` (a pass
    over the file, through ``mapping``).  ``times`` (per run) is known after that pass, or
    after :func:`run_times`."""

    path: Path
    runs: list[dict[str, Any]]
    meta: dict[str, str]
    columns: list[str]
    num_rows: int
    row_groups: list[int] = field(default_factory=list)
    kind: str = "thermonet"
    mapping: ColumnMapping | None = None
    fmt: str = "parquet"
    times: list[RunTimes] | None = None
    digest: dict[str, str] | None = None     # a thermonet file's per-column SHA-256

    @property
    def is_fleet(self) -> bool:
        if self.kind == "thermonet":
            return "device" in self.columns
        return len({e["device_id"] for e in self.runs}) > 1


ParquetLayout = Layout   # the name of a thermonet Parquet file's layout before any file streamed


def parquet_file(path: Path) -> pq.ParquetFile:
    why = not_a_file(path)
    if why:
        raise InputError.at(path, why)
    try:
        return pq.ParquetFile(path, **_READ)
    except (pa.ArrowException, OSError) as err:
        raise InputError.at(path, f"not a readable Parquet file ({err})") from err


def batches(pf: pq.ParquetFile, path: Path, chunk_rows: int, columns: list[str] | None
             ) -> Iterator[pa.RecordBatch]:
    """Record batches; a page that fails its checksum or cannot be decoded is one line."""
    it = pf.iter_batches(batch_size=int(chunk_rows), columns=columns)
    row0 = 1
    while True:
        try:
            batch = next(it)
        except StopIteration:
            return
        except (pa.ArrowException, OSError) as err:
            raise InputError.at(path, f"damaged Parquet data after data row {row0 - 1} "
                                f"({err}); the file is corrupt or truncated") from None
        row0 += batch.num_rows
        yield batch


class Continuity:
    """Each run's last time, data row and file line: time checked across chunk edges."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.last: dict[Any, tuple[float, int, int | None]] = {}

    def check(self, key: Any, name: str, t: np.ndarray, rows: np.ndarray,
              lines: np.ndarray | None) -> None:
        prev = self.last.get(key)
        if prev is not None and t.size and t[0] <= prev[0]:
            check_time(self.path, name, np.array([prev[0], t[0]]),
                       np.array([prev[1], rows[0]]),
                       None if lines is None or prev[2] is None
                       else np.array([prev[2], lines[0]]))
        if t.size:
            self.last[key] = (float(t[-1]), int(rows[-1]),
                              None if lines is None else int(lines[-1]))


class RunTally:
    """One run's counts, times and temperature extremes while the layout is discovered."""

    def __init__(self) -> None:
        self.n = 0
        self.first = self.last = 0.0
        self.head: list[np.ndarray] = []
        self.have = 0
        self.lo, self.hi = np.inf, -np.inf

    def add(self, t: np.ndarray, temp: np.ndarray | None) -> None:
        if self.n == 0:
            self.first = float(t[0])
        self.last = float(t[-1])
        self.n += t.size
        if self.have < MEDIAN_SAMPLES:
            self.head.append(t[:MEDIAN_SAMPLES - self.have])
            self.have += self.head[-1].size
        if temp is not None:
            self.lo, self.hi = min(self.lo, float(temp.min())), max(self.hi, float(temp.max()))

    def times(self, has_temp: bool) -> RunTimes:
        t = np.concatenate(self.head) if self.head else np.zeros(0)
        med = float(np.median(np.diff(t))) if t.size > 1 else float("nan")
        return RunTimes(self.first, self.last, self.n, med,
                        (self.lo, self.hi) if has_temp else None)
