"""Any recording file but thermonet's own Parquet, chunk by chunk (:mod:`thermonet.data.chunks`):
Parquet record batches or ``chunk_rows`` text lines as :class:`~thermonet.data.text.Frame`\\ s,
each mapped to channels by the whole-file reader's own step
(:func:`thermonet.data.tables.map_frame`) and cut into one run's pieces, every value checked,
time across chunk edges too (:func:`mapped_frames`); the one pass that discovers such a file's
layout (:func:`discover`: its runs, their samples and skipped rows, counted as the whole-file
reader counts them).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Any

import numpy as np

from ..core.errors import InputError
from .chunk_base import Continuity, Layout, RunTally, batches, parquet_file
from .mapping import ColumnMapping
from .tables import (
    GROUPS,
    Mapped,
    MapState,
    map_frame,
    native_mapping,
    run_meta,
    run_units,
    sensor_kind_of,
)
from .text import Frame, iter_text_frames

__all__ = ["mapped_frames", "discover"]

log = logging.getLogger("thermonet.data.tables")   # the whole-file reader's logger
_ROLES = {"output": "outputs", "reference": "references", "drift": "drift", "proxy": "proxies"}


def _frames(layout: Layout, chunk_rows: int) -> Iterator[Frame]:
    path = layout.path
    if layout.fmt != "parquet":
        yield from iter_text_frames(path, layout.mapping, "\t" if layout.fmt == "tsv" else None,
                                    chunk_rows=chunk_rows,
                                    float_columns=lambda names, n: _float_columns(
                                        layout.mapping, names, n))
        return
    pf = parquet_file(path)
    names = list(pf.schema_arrow.names)
    dup = [n for n in names if names.count(n) > 1]
    if dup:
        raise InputError.at(path, "duplicate column", column=dup[0])
    row0 = 1
    for batch in batches(pf, path, chunk_rows, None):
        yield Frame(path=path, data=batch.to_pandas(),
                    rows=np.arange(row0, row0 + batch.num_rows), lines=None)
        row0 += batch.num_rows


def _float_columns(mapping: ColumnMapping | None, names: list[str] | None, n_fields: int
                   ) -> set[str | int]:
    """The columns of a text table that the mapping reads as numbers (without a mapping:
    every column of the header but ``run`` and ``device``)."""
    if mapping is None:
        return set() if names is None else {n for n in names if n not in ("run", "device")}
    cols = ([mapping.time.column] if mapping.time is not None else []) + \
        [ch.column for ch in mapping.channels]
    out: set[str | int] = set()
    for c in cols:
        if isinstance(c, int):
            out.add(names[c] if names is not None and c < len(names) else c)
        else:
            out.add(c)
    return out


def mapped_frames(layout: Layout, chunk_rows: int
                   ) -> Iterator[tuple[Frame, Mapped | None,
                                       list[tuple[tuple[str, str], np.ndarray,
                                                  dict[str, np.ndarray]]]]]:
    """Per chunk of a mapped file: the frame, its mapped rows (None: every row of it was
    skipped) and its pieces ((device, run), data rows, {"time_s" and each channel: values}),
    in file order, every value checked (time across chunk edges too)."""
    state = MapState()
    seen = Continuity(layout.path)
    for frame in _frames(layout, chunk_rows):
        if layout.mapping is None:
            layout.mapping = native_mapping(layout.path, list(frame.data.columns),
                                            frame.numeric_header)
        if len(frame.data) == 0:
            yield frame, None, []
            continue
        m = map_frame(frame, layout.mapping, state)
        pieces = []
        for dev, run, sel in m.groups:
            rows = m.rows[sel]
            lines = None if m.lines is None else m.lines[sel]
            t = m.time_s[sel]
            seen.check((dev, run), m.t_label, t, rows, lines)
            pieces.append(((dev, run), rows,
                           {"time_s": t, **{k: v[sel] for k, v in m.channels.items()}}))
        yield frame, m, pieces


def discover(layout: Layout, chunk_rows: int) -> None:
    """One pass over a mapped file: its runs, their samples and skipped rows (counted as
    the whole-file reader counts them), every value checked."""
    tallies: dict[tuple[str, str], RunTally] = {}
    numeric_header: list[str] = []
    skipped_total = 0
    skipped_lines: list[int] = []                       # the file's first 20
    run_skipped: dict[tuple[str, str], list[int]] = {}  # with a run column: count, lines
    n_rows = 0
    for frame, m, pieces in mapped_frames(layout, chunk_rows):
        mapping = layout.mapping
        assert mapping is not None
        numeric_header = frame.numeric_header
        skipped_total += len(frame.skipped_lines) if m is None else m.n_skipped
        if len(skipped_lines) < 20:
            skipped_lines += sorted(int(x) for x in frame.skipped_lines)[:20]
        if m is not None and mapping.run_column is not None and m.bad_any.any():
            # a row with a bad mapped cell belongs to the run its run cell names
            at = np.asarray(frame.lines if frame.lines is not None else frame.rows)
            devs = (frame.data[_column_label(frame, mapping.device_column)].astype(str)
                    .str.strip().to_numpy() if mapping.device_column is not None
                    else np.full(len(frame.data), mapping.device_id, dtype=object))
            for i in np.flatnonzero(m.bad_any):
                tally_skip = run_skipped.setdefault((str(devs[i]), str(m.run_all[i])), [0])
                tally_skip[0] += 1
                if len(tally_skip) <= 20:   # the count, then the first 20 lines
                    tally_skip.append(int(at[i]))
        for key, _rows, piece in pieces:
            n_rows += piece["time_s"].size
            tallies.setdefault(key, RunTally()).add(piece["time_s"], piece.get("temperature_c"))
    mapping = layout.mapping
    if mapping is None or not tallies:
        raise InputError.at(layout.path, "no data rows")
    roles: dict[str, list[str]] = {g: [] for g in GROUPS}
    temperature = False
    for ch in mapping.channels:
        if ch.role == "temperature":
            temperature = True
        else:
            roles[_ROLES[ch.role]].append(ch.name)
    kind = sensor_kind_of(mapping)
    runs, times = [], []
    for (dev, run), tally in tallies.items():
        mine = run_skipped.get((dev, run), [0])
        skips = (skipped_total, skipped_lines) if mapping.run_column is None else \
            (mine[0], mine[1:])
        runs.append({"run_id": run, "device_id": dev, "sensor_kind": kind,
                     "sample_rate_hz": mapping.sample_rate_hz,
                     "meta": run_meta(mapping, layout.path, numeric_header, skips),
                     "units": run_units(mapping), "temperature": temperature,
                     **{g: list(v) for g, v in roles.items()}, "n_samples": tally.n})
        times.append(tally.times(temperature))
    if mapping.malformed_rows == "skip":
        if skipped_total:
            log.warning("%s: skipped %d malformed row(s)", layout.path, skipped_total)
        layout.meta["skipped_rows"] = str(skipped_total)
    layout.runs, layout.times, layout.num_rows = runs, times, n_rows
    layout.columns = ["time_s", *[ch.name for ch in mapping.channels]]


def _column_label(frame: Frame, column: str | int | None) -> Any:
    labels = list(frame.data.columns)
    return labels[column] if isinstance(column, int) else column
