"""Recordings larger than memory: any tabular recording read chunk by chunk.

A recording of tens of millions of samples is read a bounded number of rows at a time
(:data:`DEFAULT_CHUNK_ROWS`, or the ``chunk_rows`` a caller gives), never as a whole
table.  :func:`open_source` describes a file (:class:`Layout`: its runs, their channels,
units and sample counts) and :func:`iter_run_chunks` streams it, cutting every chunk where
the run changes, so each piece belongs to one run and arrives in file order:

* **thermonet Parquet** (the ``thermonet`` metadata blob): the layout is the file's footer
  (:func:`open_parquet`, no data read); the row groups are streamed with
  ``pyarrow.parquet.ParquetFile.iter_batches``.
* **any other Parquet file, CSV, TSV or text table**, with or without a column mapping
  (:mod:`thermonet.data.mapping`): the layout takes one pass (the runs are the run column's
  values, the sample counts and the skipped rows are counted); Parquet is read in record
  batches, text ``chunk_rows`` lines at a time (:func:`thermonet.data.text.iter_text_frames`),
  and each chunk goes through the whole-file reader's own mapping step
  (:func:`thermonet.data.tables.map_frame`: the same parsing, units, scale and offset, and
  the same one-line error naming file, column, row and file line).

Every value is checked as the whole-file reader (:mod:`thermonet.data.io`) checks it —
numeric, finite, and time strictly increasing within a run, across chunk edges too — and a
bad one is named by column and 1-based data row, as there.  Parquet is read with its page
checksums verified (thermonet writes them: :data:`thermonet.data.parquet_format.WRITE_OPTIONS`): a
damaged page is refused in one line, not read as other numbers.

Decisions:

* **Budget.**  A chunk is at most ``chunk_rows`` rows of the columns asked for (float64):
  the default 65,536 rows is 512 KiB per column — independent of the file's length.
  pyarrow reads the file through a 1 MiB buffer without pre-buffering (its default
  pre-buffering reads every column chunk ahead: 640 MB on a 20 M-sample file).  A text
  chunk also holds its lines and cells as strings while it is parsed (≈ 100 B a cell).
* **Text without a header or ``n_fields``.**  A well-formed row has the most common field
  count of the first chunk (the whole-file reader: of the whole file).
* **Runs.**  Rows of one run need not be contiguous (a run's rows are taken in file
  order wherever they are), but a run's time must increase across all its rows.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from ..core.errors import InputError, counted
from ..core.fileio import atomic_path, not_a_file
from ..core.recording import MIN_SAMPLES, Dataset, Recording
from ..core.recording import MIN_SAMPLES as MIN_SAMPLES_
from .chunk_base import Continuity, Layout, RunTally, RunTimes, batches, parquet_file
from .io import PARQUET_SUFFIXES, check_output_file, check_run_ids, file_format
from .logs import is_log_source
from .mapped_chunks import discover, mapped_frames
from .mapping import ColumnMapping
from .parquet_format import (
    DIGEST_KEY,
    FORMAT_VERSION,
    METADATA_KEY,
    WRITE_OPTIONS,
    Digest,
    parse_blob,
    stored_digest,
    str_dict,
)
from .tables import (
    GROUPS,
)
from .values import check_finite, check_time, float_values

__all__ = ["DEFAULT_CHUNK_ROWS", "open_parquet", "open_source", "iter_run_chunks", "run_times", "count_samples",
           "validate_layouts", "write_streamed"]

#: Rows per chunk when a caller gives none (512 KiB per float64 column).
DEFAULT_CHUNK_ROWS = 1 << 16


def open_parquet(path: str | Path) -> Layout | None:
    """The layout of a thermonet Parquet file (footer only), or None without the blob."""
    path = Path(path)
    pf = parquet_file(path)
    blob = (pf.schema_arrow.metadata or {}).get(METADATA_KEY.encode())
    if blob is None:
        return None
    info, runs = parse_blob(path, blob)
    names = list(pf.schema_arrow.names)
    for col in ("run", "time_s"):
        if col not in names:
            raise InputError.at(path, "missing column", column=col)
    for e in runs:   # every channel a run's metadata lists is a column (as the whole read asks)
        for col in (["temperature_c"] if e["temperature"] else []) + [
                c for g in ("outputs", "references", "drift", "proxies") for c in e[g]]:
            if col not in names:
                raise InputError.at(path, f"missing column (run '{e['run_id']}' lists it)",
                                    column=col)
    md = pf.metadata
    return Layout(path=path, runs=runs, meta=dict(info.get("meta", {})), columns=names,
                  num_rows=md.num_rows,
                  row_groups=[md.row_group(i).num_rows for i in range(md.num_row_groups)],
                  digest=stored_digest(path, md.metadata))


def open_source(path: str | Path, mapping: ColumnMapping | None = None, *,
                chunk_rows: int = DEFAULT_CHUNK_ROWS) -> Layout:
    """The layout of any tabular recording: a thermonet Parquet file's from its footer
    (without a mapping), any other's from one streamed pass (``chunk_rows`` rows at a time),
    which checks every value on the way (module docstring)."""
    path = Path(path)
    why = not_a_file(path)
    if why:
        raise InputError.at(path, why)
    fmt = file_format(path, mapping)
    if fmt == "parquet" and mapping is None:
        layout = open_parquet(path)
        if layout is not None:
            return layout
    layout = Layout(path=path, runs=[], meta={}, columns=[], num_rows=0,
                    kind="parquet" if fmt == "parquet" else "text", mapping=mapping, fmt=fmt)
    discover(layout, int(chunk_rows))
    return layout


# ------------------------------------------------------------------ thermonet files
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


def _thermonet_pieces(layout: Layout, cols: list[str], chunk_rows: int
                      ) -> Iterator[tuple[int, np.ndarray, dict[str, np.ndarray]]]:
    path = layout.path
    index = {(e["run_id"], e["device_id"] if layout.is_fleet else None): i
             for i, e in enumerate(layout.runs)}
    seen = Continuity(path)
    pf = parquet_file(path)
    for name in cols:
        if pa.types.is_boolean(pf.schema_arrow.field(name).type):
            raise InputError.at(path, "a boolean column, not a measurement", column=name)
    keys = ["run"] + (["device"] if layout.is_fleet else [])
    row0 = 1
    digest = Digest() if layout.digest else None
    for batch in batches(pf, path, chunk_rows, keys + cols):
        rows_all = np.arange(row0, row0 + batch.num_rows)
        values = {c: float_values(path, c, batch.column(c), rows_all) for c in cols}
        if digest is not None:
            for c, v in values.items():
                digest.add(c, v)
        for a, b, key in _segments(batch, layout.is_fleet):
            rows = rows_all[a:b]
            if key not in index:
                raise InputError.at(path, f"run {key[0]!r} is not listed in the "
                                    f"'{METADATA_KEY}' metadata", column="run", row=int(rows[0]))
            i = index[key]
            piece = {c: check_finite(path, c, v[a:b], rows, None) for c, v in values.items()}
            t = piece["time_s"]
            check_time(path, "time_s", t, rows, None)
            seen.check(i, "time_s", t, rows, None)
            yield i, rows, piece
        row0 += batch.num_rows
    if digest is not None:   # every row read: the values are those thermonet wrote
        digest.check(path, layout.digest)


# ------------------------------------------------------------------ any file
def iter_run_chunks(layout: Layout, columns: Sequence[str], *,
                    chunk_rows: int = DEFAULT_CHUNK_ROWS
                    ) -> Iterator[tuple[int, np.ndarray, dict[str, np.ndarray]]]:
    """Yield ``(run index, data rows, {column: float64 values})`` pieces in file order.

    ``run index`` is the position of the piece's run in ``layout.runs``; ``data rows``
    the 1-based rows of the piece (for messages); ``columns`` (thermonet channel names)
    always include ``time_s`` (checked strictly increasing within each run, across pieces
    too).

    Raises
    ------
    InputError
        A row of no listed run, a missing, boolean or non-numeric column, a non-finite
        value or a time that does not increase (named by file, column and row), a damaged
        Parquet page.
    """
    if int(chunk_rows) < 1:
        raise InputError(f"chunk_rows must be >= 1, got {chunk_rows}")
    path = layout.path
    cols = ["time_s", *[c for c in columns if c != "time_s"]]
    for name in cols:
        if name not in layout.columns:
            raise InputError.at(path, "missing column", column=name)
    if layout.kind == "thermonet":
        yield from _thermonet_pieces(layout, cols, int(chunk_rows))
        return
    index = {(e["device_id"], e["run_id"]): i for i, e in enumerate(layout.runs)}
    for _, _, pieces in mapped_frames(layout, int(chunk_rows)):
        for key, rows, piece in pieces:
            if key not in index:
                raise InputError.at(path, f"run '{key[1]}' of unit '{key[0]}' appeared since "
                                    "the file was first read (the file changed while it was "
                                    "read?)", row=int(rows[0]))
            yield index[key], rows, {c: piece[c] for c in cols}


def count_samples(paths: Sequence[str | Path], mapping: ColumnMapping | None = None
                  ) -> int | None:
    """How many samples the files hold, read cheaply: a Parquet file's row count from its
    footer, a text file's lines less its banner and header (blank or malformed lines
    counted: an upper bound).  None where one is not a tabular file (a flight log, a file
    that does not exist: the whole-file reader names what is wrong with it)."""
    total = 0
    for p in paths:
        path = Path(p)

        if is_log_source(path) or not_a_file(path):
            return None
        try:
            fmt = file_format(path, mapping)
        except InputError:
            return None
        if fmt == "parquet":
            try:
                total += pq.ParquetFile(path).metadata.num_rows
            except (pa.ArrowException, OSError):
                return None
            continue
        lines, last = 0, b"\n"
        with path.open("rb") as f:
            while block := f.read(1 << 20):
                lines += block.count(b"\n")
                last = block[-1:]
        lines += last != b"\n"
        skip = mapping.skip_lines if mapping is not None else 0
        header = 1 if mapping is None or mapping.header else 0
        total += max(lines - skip - header, 0)
    return total


def run_times(layout: Layout, chunk_rows: int = DEFAULT_CHUNK_ROWS) -> list[RunTimes]:
    """Per run of ``layout``: its :class:`RunTimes` (one pass over time and temperature of a
    thermonet file; known already from the layout pass of any other)."""
    if layout.times is not None:
        return layout.times
    tallies = [RunTally() for _ in layout.runs]
    temp = ["temperature_c"] if "temperature_c" in layout.columns else []
    for i, _, piece in iter_run_chunks(layout, temp, chunk_rows=chunk_rows):
        has = layout.runs[i]["temperature"]
        tallies[i].add(piece["time_s"], piece["temperature_c"] if has else None)
    layout.times = [t.times(bool(e["temperature"])) for t, e in zip(tallies, layout.runs,
                                                                      strict=True)]
    return layout.times


def validate_layouts(layouts: Sequence[Layout],
                     temperature: Sequence[tuple[float, float] | None], *,
                     min_span_c: float | None = None) -> None:
    """``Dataset.validate`` on a skeleton of every run of ``layouts`` — its channels, units
    and metadata with ``MIN_SAMPLES`` placeholder samples whose temperature spans the run's
    own extremes (``temperature``, per run) — so files the whole-file reader refuses (runs
    that differ in channels or units, too little temperature span) are refused with the
    same line without holding their samples.  ``min_span_c``: the span asked of the runs
    together (None: a model's, :data:`~thermonet.core.recording.MIN_TEMPERATURE_SPAN_C`;
    ``info`` asks none: it summarises what a model could not fit, and says so)."""
    k = MIN_SAMPLES
    skeleton = []
    entries = [(lay, e) for lay in layouts for e in lay.runs]
    for (lay, e), temp in zip(entries, temperature, strict=True):
        zeros = np.zeros(k)
        skeleton.append(Recording(
            time_s=np.arange(k, dtype=np.float64),
            temperature_c=None if temp is None or not e["temperature"]
            else np.linspace(temp[0], temp[1], k),
            outputs={n: zeros for n in e["outputs"]},
            references={n: zeros for n in e["references"]},
            drift={n: zeros for n in e["drift"]}, proxies={n: zeros for n in e["proxies"]},
            units=dict(e["units"]), device_id=e["device_id"], sensor_kind=e["sensor_kind"],
            run_id=e["run_id"], sample_rate_hz=e["sample_rate_hz"],
            # the file given, not the origin a thermonet file recorded: what a message names
            meta={**dict(e["meta"]), "source": str(lay.path)}))
    meta: dict[str, str] = {}
    for lay in layouts:
        for key, v in lay.meta.items():
            meta.setdefault(key, v)
    source = str(layouts[0].path) if len(layouts) == 1 else ""
    if min_span_c is None:
        Dataset(runs=skeleton, meta=meta).validate(source)
    else:
        Dataset(runs=skeleton, meta=meta).validate(source, min_span_c=min_span_c)


def _streamed_schema(layouts: Sequence[Layout], entries: list[dict[str, Any]],
                     times: list[Any], channels: list[str], fleet: bool) -> Any:
    """The Parquet schema of a streamed file: run (and device) ids, time and channels, with
    the thermonet metadata (dataset meta, one entry per run with its sample count)."""
    import json

    fields = [pa.field("run", pa.string())] + ([pa.field("device", pa.string())] if fleet
                                               else [])
    fields += [pa.field(c, pa.float64()) for c in ["time_s", *channels]]
    meta: dict[str, str] = {}
    skipped = [int(lay.meta["skipped_rows"]) for lay in layouts if "skipped_rows" in lay.meta]
    for lay in layouts:
        for key, v in lay.meta.items():
            meta.setdefault(key, v)
    if skipped:
        meta["skipped_rows"] = str(sum(skipped))
    blob: dict[str, Any] = {"format": "thermonet", "version": FORMAT_VERSION,
                            "meta": str_dict(meta, "dataset meta"), "runs": []}
    for e, rt in zip(entries, times, strict=True):
        blob["runs"].append({
            "run_id": e["run_id"], "device_id": e["device_id"], "sensor_kind": e["sensor_kind"],
            "sample_rate_hz": e["sample_rate_hz"],
            "meta": str_dict(e["meta"], f"run '{e['run_id']}' meta"),
            "units": str_dict(e["units"], f"run '{e['run_id']}' units"),
            "temperature": e["temperature"], **{g: list(e[g]) for g in GROUPS},
            "n_samples": rt.n})
    schema = pa.schema(fields, metadata={METADATA_KEY: json.dumps(
        blob, allow_nan=False, ensure_ascii=False)})
    return schema


def _piece_table(e: dict[str, Any], piece: dict[str, np.ndarray], channels: list[str],
                 schema: Any, *, fleet: bool) -> Any:
    """One chunk of one run as a table of ``schema``: its ids, its time, and null in the
    channels the run does not have."""
    n = piece["time_s"].size
    mine = set(["temperature_c"] if e["temperature"] else []) | {
        k for g in GROUPS for k in e[g]}
    arrays = [pa.array(np.full(n, e["run_id"], dtype=object), pa.string())]
    if fleet:
        arrays.append(pa.array(np.full(n, e["device_id"], dtype=object), pa.string()))
    arrays.append(pa.array(piece["time_s"], pa.float64()))
    arrays += [pa.array(piece[c], pa.float64()) if c in mine and c in piece
               else pa.nulls(n, pa.float64()) for c in channels]
    return pa.Table.from_arrays(arrays, schema=schema)


def write_streamed(layouts: Sequence[Layout], out: str | Path, *,
                   chunk_rows: int = DEFAULT_CHUNK_ROWS) -> tuple[int, int]:
    """Recording files to one thermonet Parquet file (``thermonet convert``), read
    ``chunk_rows`` rows at a time and written in row groups of about as many rows: memory
    is one chunk, whatever the files' size.  The runs are checked first as the whole-file
    reader checks them (:func:`validate_layouts`); a bad value anywhere leaves nothing at
    ``out`` (written to a temporary file and moved over it at the end).  Rows keep their
    file order (a run's rows need not be contiguous).  Returns (runs, samples)."""
    out = check_output_file(out, PARQUET_SUFFIXES)
    check_run_ids([(e["device_id"], e["run_id"], str(lay.path)) for lay in layouts
                   for e in lay.runs])
    times = [rt for lay in layouts for rt in run_times(lay, chunk_rows)]
    pairs = [(str(lay.path), e) for lay in layouts for e in lay.runs]
    for (src, e), rt in zip(pairs, times, strict=True):
        if rt.n < MIN_SAMPLES_:
            raise InputError.at(f"{src}, run '{e['run_id']}'", f"too few samples: {rt.n} "
                                f"(need at least {MIN_SAMPLES_})")
    validate_layouts(layouts, [rt.temperature for rt in times])
    entries = [e for lay in layouts for e in lay.runs]
    fleet = len({e["device_id"] for e in entries}) > 1
    has_temp = any(e["temperature"] for e in entries)
    names: list[str] = []
    for group in GROUPS:
        for e in entries:
            names += [k for k in e[group] if k not in names]
    channels = (["temperature_c"] if has_temp else []) + names
    schema = _streamed_schema(layouts, entries, times, channels, fleet)
    n_total = 0
    with atomic_path(out, make_parents=False) as tmp:
        writer = pq.ParquetWriter(tmp, schema, **WRITE_OPTIONS)
        digest = Digest()

        def write(tables: list[pa.Table], rows: int) -> None:
            table = pa.concat_tables(tables)
            for c in ["time_s", *channels]:
                digest.add(c, table.column(c))
            writer.write_table(table, row_group_size=rows)

        try:
            buffer: list[pa.Table] = []
            held = 0
            base = 0
            for lay in layouts:
                cols = [c for c in channels if c in lay.columns]
                for i, _rows, piece in iter_run_chunks(lay, cols, chunk_rows=chunk_rows):
                    n = piece["time_s"].size
                    buffer.append(_piece_table(entries[base + i], piece, channels, schema,
                                               fleet=fleet))
                    held += n
                    n_total += n
                    if held >= chunk_rows:
                        write(buffer, held)
                        buffer, held = [], 0
                base += len(lay.runs)
            if buffer:
                write(buffer, held)
            writer.add_key_value_metadata({DIGEST_KEY: digest.text()})
        finally:
            writer.close()
        for (src, e), rt in zip(pairs, times, strict=True):
            if e.get("n_samples") is not None and int(e["n_samples"]) != rt.n:
                raise InputError.at(src, f"run '{e['run_id']}': {counted(rt.n, 'row')}, its "
                                    f"metadata says {e['n_samples']}")
    return len(entries), n_total
