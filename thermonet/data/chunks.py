"""Recordings larger than memory: a thermonet Parquet file read chunk by chunk.

A recording of tens of millions of samples is read a bounded number of rows at a time
(:data:`DEFAULT_CHUNK_ROWS`, or the ``chunk_rows`` a caller gives), never as a whole
table: :func:`open_parquet` reads only the footer (schema, the ``thermonet`` metadata
blob, row-group sizes) and :func:`iter_run_chunks` streams the row groups with
``pyarrow.parquet.ParquetFile.iter_batches``, cutting every batch where the run changes,
so each piece belongs to one run and arrives in file order.  Every value is checked as
the whole-file reader (:mod:`thermonet.data.io`) checks it — finite, and time
strictly increasing within a run, across chunk edges too — and a bad one is named by
column and 1-based data row, as there.

Decisions:

* **Budget.**  A chunk is at most ``chunk_rows`` rows of the columns asked for (float64):
  the default 65,536 rows is 512 KiB per column — independent of the file's length.
  pyarrow reads the file through a 1 MiB buffer without pre-buffering (its default
  pre-buffering reads every column chunk ahead: 640 MB on a 20 M-sample file).  Measured
  on ``thermonet info`` of a 20 M-sample file (experiments/README.md): 65,536 rows, 2.1 s
  and 236 MB peak RSS (150 MB of it the interpreter and libraries); 1,048,576 rows, 2.8 s
  and 526 MB — a larger chunk buys nothing once the per-chunk Python overhead is small.
* **Which files.**  Thermonet's own Parquet format (the metadata blob names every run
  and channel without reading data).  A CSV (or any mapped file) is converted once with
  ``thermonet convert`` (:func:`thermonet.data.io.read_datasets` then
  :func:`~thermonet.data.io.write_parquet`: that one read holds the file in memory) and
  streamed from then on; a foreign Parquet file without the blob is read whole
  (:func:`open_parquet` returns None).
* **Runs.**  Rows of one run need not be contiguous (a run's rows are taken in file
  order wherever they are), but a run's time must increase across all its rows.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from ..core.errors import InputError
from .io import METADATA_KEY, _check_blob
from .tables import check_finite

__all__ = ["DEFAULT_CHUNK_ROWS", "ParquetLayout", "open_parquet", "iter_run_chunks"]

#: Rows per chunk when a caller gives none (512 KiB per float64 column).
DEFAULT_CHUNK_ROWS = 1 << 16


@dataclass
class ParquetLayout:
    """What a thermonet Parquet file holds, from its footer alone."""

    path: Path
    runs: list[dict[str, Any]]
    meta: dict[str, str]
    columns: list[str]
    num_rows: int
    row_groups: list[int] = field(default_factory=list)

    @property
    def is_fleet(self) -> bool:
        return "device" in self.columns


def open_parquet(path: str | Path) -> ParquetLayout | None:
    """The layout of a thermonet Parquet file (footer only), or None without the blob."""
    import json

    path = Path(path)
    try:
        pf = pq.ParquetFile(path)
    except (pa.ArrowException, OSError) as err:
        raise InputError.at(path, f"not a readable Parquet file ({err})") from err
    blob = (pf.schema_arrow.metadata or {}).get(METADATA_KEY.encode())
    if blob is None:
        return None
    try:
        info = json.loads(blob)
    except (ValueError, UnicodeDecodeError) as err:
        raise InputError.at(path, f"corrupt '{METADATA_KEY}' metadata (not JSON: {err})") from None
    runs = _check_blob(path, info)
    names = list(pf.schema_arrow.names)
    for col in ("run", "time_s"):
        if col not in names:
            raise InputError.at(path, "missing column", column=col)
    md = pf.metadata
    return ParquetLayout(path=path, runs=runs, meta=dict(info.get("meta", {})), columns=names,
                         num_rows=md.num_rows,
                         row_groups=[md.row_group(i).num_rows for i in range(md.num_row_groups)])


def _segments(batch: pa.RecordBatch, fleet: bool) -> list[tuple[int, int, tuple[str, str | None]]]:
    """(start, stop, (run, device)) of the batch's stretches of one run (vectorised)."""
    keys = [batch.column("run")] + ([batch.column("device")] if fleet else [])
    n = batch.num_rows
    change = np.zeros(max(n - 1, 0), dtype=bool)
    for col in keys:
        if n > 1:
            ne = pc.not_equal(col.slice(1), col.slice(0, n - 1))
            change |= np.asarray(ne.fill_null(True).to_numpy(zero_copy_only=False), dtype=bool)
    starts = [0, *(np.flatnonzero(change) + 1).tolist()]
    stops = [*starts[1:], n]
    out = []
    for a, b in zip(starts, stops, strict=True):
        run = keys[0][a].as_py()
        dev = keys[1][a].as_py() if fleet else None
        out.append((a, b, (run, dev)))
    return out


def iter_run_chunks(layout: ParquetLayout, columns: Sequence[str], *,
                    chunk_rows: int = DEFAULT_CHUNK_ROWS
                    ) -> Iterator[tuple[int, np.ndarray, dict[str, np.ndarray]]]:
    """Yield ``(run index, data rows, {column: float64 values})`` pieces in file order.

    ``run index`` is the position of the piece's run in ``layout.runs``; ``data rows``
    the 1-based rows of the piece (for messages); ``columns`` always include ``time_s``
    (checked strictly increasing within each run, across pieces too).

    Raises
    ------
    InputError
        A row of no listed run, a missing or boolean column, a non-finite value or a
        time that does not increase (named by column and row).
    """
    if int(chunk_rows) < 1:
        raise InputError(f"chunk_rows must be >= 1, got {chunk_rows}")
    path = layout.path
    cols = ["time_s", *[c for c in columns if c != "time_s"]]
    for name in cols:
        if name not in layout.columns:
            raise InputError.at(path, "missing column", column=name)
    index = {(e["run_id"], e["device_id"] if layout.is_fleet else None): i
             for i, e in enumerate(layout.runs)}
    last_t: dict[int, float] = {}
    # pre_buffer=False and a 1 MiB read buffer: pyarrow's default pre-buffering reads every
    # column chunk of the file ahead (640 MB on a 20 M-sample file), which is what the
    # budget is for
    pf = pq.ParquetFile(path, pre_buffer=False, buffer_size=1 << 20)
    for name in cols:
        if pa.types.is_boolean(pf.schema_arrow.field(name).type):
            raise InputError.at(path, "a boolean column, not a measurement", column=name)
    keys = ["run"] + (["device"] if layout.is_fleet else [])
    row0 = 1
    for batch in pf.iter_batches(batch_size=int(chunk_rows), columns=keys + cols):
        values = {c: np.asarray(batch.column(c).to_numpy(zero_copy_only=False),
                                dtype=np.float64) for c in cols}
        for a, b, key in _segments(batch, layout.is_fleet):
            rows = np.arange(row0 + a, row0 + b)
            if key not in index:
                raise InputError.at(path, f"run {key[0]!r} is not listed in the "
                                    f"'{METADATA_KEY}' metadata", column="run", row=int(rows[0]))
            i = index[key]
            piece = {c: check_finite(path, c, v[a:b], rows, None) for c, v in values.items()}
            t = piece["time_s"]
            prev = last_t.get(i)
            tt = t if prev is None else np.concatenate([[prev], t])
            dt = np.diff(tt)
            bad = np.flatnonzero(dt <= 0)
            if bad.size:
                k = int(bad[0]) + 1
                kind = "duplicate" if dt[k - 1] == 0 else "decreasing"
                row = int(rows[k - (0 if prev is None else 1)])
                raise InputError.at(path, f"{kind} timestamp {float(tt[k])!r} s after "
                                    f"{float(tt[k - 1])!r} s (time must increase strictly)",
                                    column="time_s", row=row)
            last_t[i] = float(t[-1])
            yield i, rows, piece
        row0 += batch.num_rows
