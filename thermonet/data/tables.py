"""Text tables (CSV, TSV, whitespace) read into recordings: the separator sniffed, the header's
conventional names taken as they are (the native layout), or a column mapping applied
(:mod:`thermonet.data.mapping`: which column is time, temperature, each output, reference and
proxy, in which unit; several runs or devices told apart by an id column).  Every value is
checked where it is read: a non-finite number or a time that does not increase is refused with
the file, the column and the line.
"""

from __future__ import annotations

import csv
import io
import itertools
import logging
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..core.errors import InputError
from ..core.recording import OUTPUT_NAME, Recording
from .mapping import ChannelSpec, ColumnMapping, TimeSpec, default_unit

__all__ = ["Frame", "GROUPS", "read_text", "iter_text_frames", "native_mapping", "apply_mapping",
           "map_frame", "Mapped", "MapState", "run_meta", "run_units", "sensor_kind_of",
           "check_finite", "check_time", "float_values"]

log = logging.getLogger(__name__)
#: The channel groups of a recording besides time and temperature.
GROUPS = ("outputs", "references", "drift", "proxies")

_SNIFF_DELIMITERS = ",;\t|"


# ----------------------------------------------------------- text parsing
class Frame:
    """Cells of one source file, with the 1-based data row (and file line) of each."""

    def __init__(self, *, path: Path, data: pd.DataFrame, rows: np.ndarray,
                 lines: np.ndarray | None, skipped_lines: Sequence[int] = (),
                 numeric_header: Sequence[str] = ()) -> None:
        self.path, self.data, self.rows, self.lines = path, data, rows, lines
        self.skipped_lines = list(skipped_lines)
        # header names that all parse as numbers: most likely a first data row
        self.numeric_header = list(numeric_header)


def read_text(path: Path, mapping: ColumnMapping | None, sep: str | None) -> Frame:
    """The whole text file as one :class:`Frame` (:func:`iter_text_frames` with no chunking)."""
    frames = list(iter_text_frames(path, mapping, sep, chunk_rows=None))
    frame = frames[0]
    frame.skipped_lines = [ln for f in frames for ln in f.skipped_lines]
    return frame


def _text_lines(path: Path, chunk_rows: int | None) -> Iterator[tuple[list[str], int]]:
    """Blocks of at most ``chunk_rows`` physical lines (None: all) and the file offset of
    each block's first byte; a byte that is not UTF-8 is named by its file offset."""
    if chunk_rows is None:
        try:
            # utf-8-sig drops the byte-order mark spreadsheet exports put before the header.
            text = path.read_text(encoding="utf-8-sig")
        except UnicodeDecodeError as err:
            raise InputError.at(path, f"not UTF-8 text (byte {err.start})") from err
        yield text.splitlines(), 0
        return
    offset = 0
    with path.open("rb") as f:
        while True:
            block = list(itertools.islice(f, chunk_rows))
            if not block:
                return
            raw = b"".join(block)
            try:
                text = raw.decode("utf-8-sig" if offset == 0 else "utf-8")
            except UnicodeDecodeError as err:
                raise InputError.at(path, f"not UTF-8 text (byte {offset + err.start})") from err
            yield text.splitlines(), offset
            offset += len(raw)


#: Appended to a block of lines when grouping them into records: csv takes it into the last
#: record only when that record's quoted cell is still open at the block's end.
_SENTINEL = "\x01"


class _Records:
    """Physical lines grouped into the text of whole CSV records: a quoted cell may hold a line
    break (legal CSV), so one record may span several physical lines.  csv's own parser (the
    separator's dialect) decides where each record ends; a record still open at a block's end
    is carried into the next block.  Downstream every element is one record, so the records
    parsed from the lines and the lines themselves stay aligned (row ``i`` is line ``i``).

    ``joins`` maps the record index after each multi-line record to the physical lines
    absorbed so far, for :meth:`extra_at` (file line numbers in messages)."""

    def __init__(self, path: Path, sep: str, first_line: int) -> None:
        self.path, self.sep, self.first_line = path, sep, first_line
        self.tail: list[str] = []
        self.count = 0
        self.extra = 0
        self.joins: list[tuple[int, int]] = []

    def feed(self, block: list[str]) -> list[str]:
        lines = self.tail + block
        self.tail = []
        if not any('"' in ln for ln in lines):   # no quote: one line, one record
            self.count += len(lines)
            return lines
        reader = csv.reader(itertools.chain(lines, [_SENTINEL]), delimiter=self.sep)
        out: list[str] = []
        start = 0
        for _ in reader:
            end = reader.line_num
            if end > len(lines):   # the sentinel itself, or a record still open at the end
                self.tail = lines[start:]
                break
            if end - start == 1:
                out.append(lines[start])
            else:
                out.append("\n".join(lines[start:end]))
                self.extra += end - start - 1
                self.joins.append((self.count + len(out), self.extra))
            start = end
        self.count += len(out)
        return out

    def blocks(self, blocks: Iterator[tuple[list[str], int]]
               ) -> Iterator[tuple[list[str], int]]:
        """``blocks`` as blocks of whole records (none empty).

        Raises
        ------
        InputError
            A quoted cell still open at the end of the file (its closing quote missing: it
            would swallow every line after it), named by the file line it opens on."""
        for block, offset in blocks:
            out = self.feed(block)
            if out:
                yield out, offset
        self.check_closed()

    def check_closed(self) -> None:
        """Refuse a quoted cell left open at the end of the file (module docstring)."""
        if self.tail:
            line = self.first_line + self.count + self.extra
            raise InputError.at(self.path, f"file line {line}: a quoted cell opens on this "
                                "line and never closes (a '\"' is missing; it would swallow "
                                f"the {len(self.tail) - 1} lines after it)")

    def extra_at(self, index: np.ndarray) -> np.ndarray:
        """Physical lines absorbed before each record ``index`` (0-based, counted from the
        first line after the banner)."""
        if not self.joins:
            return np.zeros(np.shape(index), dtype=np.int64)
        starts = np.array([j[0] for j in self.joins])
        cum = np.array([0] + [j[1] for j in self.joins])
        return cum[np.searchsorted(starts, index, side="right")]


class _Pending:
    """The lines read so far from a text table's blocks (``more`` reads the next block)."""

    def __init__(self, blocks: Iterator[tuple[list[str], int]]) -> None:
        self.blocks = blocks
        self.lines: list[str] = []
        self.exhausted = False

    def more(self) -> bool:
        """Append the next block's lines; False once the blocks are exhausted."""
        if self.exhausted:
            return False
        for block, _ in self.blocks:
            self.lines.extend(block)
            return True
        self.exhausted = True
        return False


def _read_header(path: Path, src: _Pending, records: list[list[str]], sep: str,
                 first_data: int) -> tuple[list[str], list[list[str]], int]:
    """The header's column names (blank lines before it skipped, duplicates refused); the
    records after it; the physical line of the first data row."""
    lines = src.lines
    while True:
        while records and not records[0]:  # blank lines before the header
            records.pop(0)
            lines.pop(0)
            first_data += 1
        if records or not src.more():
            break
        records = list(csv.reader(lines, delimiter=sep))
    if not records:
        raise InputError.at(path, "no header line (file is empty after the banner)")
    names = [c.strip() for c in records.pop(0)]
    lines.pop(0)
    first_data += 1
    dup = [n for n, c in Counter(names).items() if c > 1]
    if dup:
        raise InputError.at(path, "duplicate column in the header", column=dup[0])
    return names, records, first_data


def _field_count(path: Path, names: list[str] | None, mapping: ColumnMapping | None,
                 records: list[list[str]]) -> int:
    """Fields per well-formed row: the header's, else the mapping's ``n_fields``, else the
    most common count of the first records."""
    if names is not None:
        return len(names)
    if mapping is not None and mapping.n_fields is not None:
        return mapping.n_fields
    counts = [len(r) for r in records if r]
    if not counts:
        raise InputError.at(path, "no data rows")
    return Counter(counts).most_common(1)[0][0]


def _first_records(path: Path, sep: str | None, skip: int, chunk_rows: int | None
                   ) -> tuple[_Pending, str, _Records]:
    """The banner skipped, the separator sniffed from the first 50 non-blank lines (where not
    given), and the first block's lines grouped into records (a quoted cell may span lines):
    the source (its ``lines`` the first records, its ``blocks`` the rest, record-joined), the
    separator and the record joiner."""
    src = _Pending(_text_lines(path, chunk_rows))
    while len(src.lines) < skip and src.more():
        pass
    del src.lines[:skip]
    while not src.lines and src.more():
        pass
    if sep is None:
        while len([ln for ln in src.lines if ln.strip()]) < 50 and src.more():
            pass
        sep = _sniff(path, [ln for ln in src.lines if ln.strip()][:50])
    joined = _Records(path, sep, skip + 1)
    src.lines[:] = joined.feed(src.lines)
    if src.exhausted:
        joined.check_closed()
    src.blocks = joined.blocks(src.blocks)
    return src, sep, joined


def iter_text_frames(path: Path, mapping: ColumnMapping | None, sep: str | None, *,
                     chunk_rows: int | None,
                     float_columns: Callable[[list[str] | None, int], set[str | int]] | None
                     = None) -> Iterator[Frame]:
    """The data rows of a text table, ``chunk_rows`` physical lines at a time (None: the
    whole file as one frame): the banner skipped, the separator sniffed from the first 50
    non-blank lines, the header read, each row's field count checked.  Row and file-line
    numbers run on across frames, so a message names the same row whatever the chunk.

    Without a header and without the mapping's ``n_fields``, a well-formed row has the most
    common field count of the first frame (of the whole file when not chunked).

    ``float_columns`` (chunked only): given the header (None without) and the field count,
    the columns that hold numbers; a block whose lines are plain is then parsed by
    :func:`_fast_frame` (pyarrow), any other by the whole-file reader's parsing."""
    skip = mapping.skip_lines if mapping else 0
    header = mapping.header if mapping else True
    malformed = mapping.malformed_rows if mapping else "error"
    if mapping is not None and mapping.separator is not None:
        sep = mapping.separator
    src, sep, joined = _first_records(path, sep, skip, chunk_rows)
    lines, blocks = src.lines, src.blocks
    records = list(csv.reader(lines, delimiter=sep))
    names: list[str] | None = None
    first_data = skip + 1  # physical line of data row 1, before the header shift
    if header:
        names, records, first_data = _read_header(path, src, records, sep, first_data)
    lead = first_data - skip - 1   # records before data row 1 (blank lines, the header)

    def line_of(i: np.ndarray) -> np.ndarray:
        """The physical file line of 0-based data records ``i``."""
        i = np.asarray(i, dtype=np.int64)
        return first_data + i + joined.extra_at(lead + i)
    n_fields = _field_count(path, names, mapping, records)
    numeric = names if names and all(n and _is_float(n) for n in names) else []
    fast = None if float_columns is None or chunk_rows is None else \
        float_columns(names, n_fields)
    base = 0   # index of this frame's first record among all records after the header
    any_rows = False
    first: list[list[str]] | None = records
    while True:
        step = max(len(lines) if chunk_rows is None else int(chunk_rows), 1)
        for a in range(0, max(len(lines), 1), step):   # the first block may hold more
            part = lines[a:a + step]
            recs = None if first is None else first[a:a + step]
            frame = None if fast is None else _fast_frame(
                path, part, base, line_of, names, n_fields, sep, fast, numeric)
            if frame is None:
                recs = recs if recs is not None else list(csv.reader(part, delimiter=sep))
                frame = _frame(path, part, recs, base, line_of, names, n_fields, sep,
                               malformed, numeric)
            base += len(part) if recs is None else len(recs)
            if frame is not None:
                any_rows = any_rows or frame.rows.size > 0
                yield frame
        first = None
        lines = []
        for block, _ in blocks:
            lines = block
            break
        if not lines:
            break
    if not any_rows:
        raise InputError.at(path, "no data rows")


def _fast_frame(path: Path, lines: list[str], base: int,
                line_of: Callable[[np.ndarray], np.ndarray],
                names: list[str] | None, n_fields: int, sep: str, floats: set[str | int],
                numeric: list[str]) -> Frame | None:
    """A block of plain numeric lines parsed by pyarrow's CSV reader: the ``floats``
    columns as float64, the others as text.  None where the block is not that plain (a
    blank line, a quote, a wrong field count, a cell that is not a finite number): the
    block then goes through the whole-file reader's parsing (:func:`_frame`), which names
    the fault.  Values equal that parsing's: both round each decimal string correctly."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    if not lines or "" in lines:
        return None
    text = "\n".join(lines)
    if '"' in text:
        return None
    labels: list[str | int] = list(names) if names is not None else list(range(n_fields))
    keys = [str(x) for x in labels]
    if len(set(keys)) != len(keys):
        return None
    try:
        table = pacsv.read_csv(
            io.BytesIO(text.encode("utf-8")),
            read_options=pacsv.ReadOptions(column_names=keys, use_threads=False,
                                           block_size=max(1 << 20, len(text) + 1)),
            parse_options=pacsv.ParseOptions(delimiter=sep, quote_char=False,
                                             ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(
                column_types={k: pa.float64() if x in floats else pa.string()
                              for k, x in zip(keys, labels, strict=True)},
                strings_can_be_null=False, quoted_strings_can_be_null=False))
    except (pa.ArrowException, ValueError):
        return None
    if table.num_rows != len(lines):
        return None
    data = {}
    for k, x in zip(keys, labels, strict=True):
        col = table.column(k)
        if x in floats:
            v = col.to_numpy(zero_copy_only=False) if col.null_count == 0 else None
            if v is None or not np.isfinite(v).all():
                return None
            data[x] = v
        else:
            data[x] = col.to_pandas()
    rows = np.arange(base + 1, base + 1 + len(lines))
    return Frame(path=path, data=pd.DataFrame(data), rows=rows, lines=line_of(rows - 1),
                 numeric_header=numeric)


def _frame(path: Path, lines: list[str], records: list[list[str]], base: int,
           line_of: Callable[[np.ndarray], np.ndarray], names: list[str] | None,
           n_fields: int, sep: str, malformed: str,
           numeric: list[str]) -> Frame | None:
    """One frame of text records (``base``: the index of the first among all data records),
    or None when every record of it is blank or skipped."""
    keep: list[int] = []
    skipped_lines: list[int] = []
    for i, rec in enumerate(records):
        if not rec:
            continue  # blank lines carry no sample
        if len(rec) != n_fields:
            if malformed == "error":
                raise InputError.at(path, f"expected {n_fields} fields, found {len(rec)} "
                                    f"(file line {int(line_of(np.asarray(base + i)))}; set "
                                    "malformed_rows: "
                                    "skip in a mapping to drop such rows)", row=base + i + 1)
            skipped_lines.append(int(line_of(np.asarray(base + i))))
            continue
        keep.append(i)
    if not keep:
        if skipped_lines:   # the rows dropped here still count
            return Frame(path=path, data=pd.DataFrame(
                {c: pd.Series([], dtype=str) for c in (
                    names if names is not None else list(range(n_fields)))}),
                rows=np.zeros(0, dtype=np.int64), lines=np.zeros(0, dtype=np.int64),
                skipped_lines=skipped_lines, numeric_header=numeric)
        return None
    # The csv pre-scan only sorts rows by field count; pandas does the parsing.
    data = pd.read_csv(io.StringIO("\n".join(lines[i] for i in keep)), sep=sep, header=None,
                       names=names if names is not None else list(range(n_fields)),
                       dtype=str, keep_default_na=False, skip_blank_lines=False)
    rows = np.asarray(keep) + base + 1
    return Frame(path=path, data=data, rows=rows, lines=line_of(rows - 1),
                 skipped_lines=skipped_lines, numeric_header=numeric)


def _sniff(path: Path, sample: list[str]) -> str:
    """The candidate separator that splits most sample lines into the same number
    (> 1) of fields.  csv.Sniffer gives up on a sample with one broken line,
    which is exactly the file a user most needs a clear error for."""
    if not sample:
        raise InputError.at(path, "no data rows")
    best: tuple[float, int, str] | None = None
    for sep in _SNIFF_DELIMITERS:
        counts = Counter(len(rec) for rec in csv.reader(sample, delimiter=sep))
        n_fields, hits = counts.most_common(1)[0]
        if n_fields > 1 and (best is None or (hits, n_fields) > best[:2]):
            best = (hits, n_fields, sep)
    return "," if best is None else best[2]  # no separator at all: a single column


# ------------------------------------------------------------ mapping
def native_mapping(path: Path, columns: list, numeric_header: Sequence[str] = ()
                    ) -> ColumnMapping:
    names = [str(c) for c in columns]
    if "time_s" not in names or not any(OUTPUT_NAME.match(n) for n in names):
        hint = ("; its first line is all numbers, so the file has no header line: describe "
                "it with a mapping with 'header: false' and columns by 0-based index"
                if numeric_header else "; describe the file with a mapping (YAML)")
        raise InputError.at(path, "columns are not thermonet's conventional names (need "
                            "'time_s' and an output like 'gyro_x'; found "
                            f"{', '.join(names[:8])}){hint}")
    channels = [ChannelSpec(name=n, column=n, unit=default_unit(n))
                for n in names if n not in ("time_s", "run", "device")]
    bad = [c.name for c in channels if not c.name.replace("_", "a").isalnum()]
    if bad:
        raise InputError.at(path, "not a thermonet channel name (letters, digits, '_'); "
                            "describe the file with a mapping", column=bad[0])
    return ColumnMapping(channels=tuple(channels), time=TimeSpec(column="time_s", unit="s"),
                         run_column="run" if "run" in names else None,
                         device_column="device" if "device" in names else None,
                         run_id=path.stem,
                         source="<conventional names>")


def _resolve(frame: Frame, col: str | int, key: str) -> str | int:
    """The DataFrame label of a mapping column (a header name or 0-based index)."""
    labels = list(frame.data.columns)
    if isinstance(col, int):
        if col >= len(labels):
            raise InputError.at(frame.path, f"column index {col} out of range (rows have "
                                f"{len(labels)} fields; mapping key '{key}')")
        return labels[col]
    if col not in labels:
        raise InputError.at(frame.path, "missing column (mapping key "
                            f"'{key}'; file has: {', '.join(map(str, labels))})", column=col)
    return col


@dataclass
class Mapped:
    """One frame's rows as thermonet channels: the kept rows' time (s) and scaled channel
    values, their data rows and file lines, and the (device, run) groups they fall in."""

    frame: Frame
    groups: list[tuple[str, str, np.ndarray]]     # (device id, run id, mask over kept rows)
    time_s: np.ndarray
    channels: dict[str, np.ndarray]
    rows: np.ndarray
    lines: np.ndarray | None
    t_label: str
    bad_any: np.ndarray                           # over the frame's rows: a bad mapped cell
    run_all: np.ndarray                           # over the frame's rows: each row's run id
    n_skipped: int
    sensor_kind: str

    def run_skips(self, mapping: ColumnMapping, device_id: str, run_id: str
                  ) -> tuple[int, list[int]]:
        """The skipped rows counted for one run, and their file lines (or data rows)."""
        frame = self.frame
        if mapping.run_column is None:
            return self.n_skipped, sorted(frame.skipped_lines)
        # rows with a bad mapped cell belong to the run their run cell names; a row with a
        # wrong field count has no readable run cell and counts for the file only
        mine = self.bad_any & (self.run_all == run_id)
        if mapping.device_column is not None and mine.any():
            dev_all = frame.data[_resolve(frame, mapping.device_column, "")]
            mine &= dev_all.astype(str).str.strip().to_numpy() == device_id
        at = frame.lines if frame.lines is not None else frame.rows
        return int(mine.sum()), sorted(np.asarray(at)[mine].tolist())


class MapState:
    """What mapping one frame carries to the next: the first stamp of a date/time column
    (times are seconds since the file's first sample)."""

    def __init__(self) -> None:
        self.t0_ns: float | None = None


def sensor_kind_of(mapping: ColumnMapping) -> str:
    kinds = {m.group(1) for c in mapping.channels if c.role == "output"
             for m in [OUTPUT_NAME.match(c.name)] if m is not None}
    return mapping.sensor_kind or (kinds.pop() if len(kinds) == 1 else "mixed")


def _parse_cells(frame: Frame, mapping: ColumnMapping, state: MapState
                 ) -> tuple[dict[str | int, np.ndarray], np.ndarray,
                            tuple[int, str | int] | None]:
    """The mapped columns as float64 (the time column's date/time stamps as seconds since
    the recording's first); the rows with a cell that is not a finite number; the first such
    cell (row index, column), for the message."""
    path = frame.path
    numeric_keys: list[tuple[str, str | int]] = []
    if mapping.time is not None:
        numeric_keys.append(("time.column", _resolve(frame, mapping.time.column, "time.column")))
    for ch in mapping.channels:
        numeric_keys.append((f"channels.{ch.name}.column",
                             _resolve(frame, ch.column, f"channels.{ch.name}.column")))
    values: dict[str | int, np.ndarray] = {}
    bad_any = np.zeros(len(frame.data), dtype=bool)
    first_bad: tuple[int, str | int] | None = None
    for _, label in numeric_keys:
        if label in values:
            continue
        cells = frame.data[label]
        if pd.api.types.is_bool_dtype(cells):  # True/False read as 1/0 would be a silent guess
            raise InputError.at(path, "a boolean column, not a measurement", column=str(label))
        if pd.api.types.is_datetime64_any_dtype(cells) or pd.api.types.is_timedelta64_dtype(cells):
            # a timestamp column: seconds since its first sample, whatever its own unit
            # (to_numeric would give µs or ns counts that a 'unit: s' then misreads)
            if label != numeric_keys[0][1] or mapping.time is None:
                raise InputError.at(path, "a date/time column can only be the time column",
                                    column=str(label))
            v = _stamp_units(cells, mapping, state)
        else:
            v = pd.to_numeric(cells.str.strip() if cells.dtype != np.float64 and
                              hasattr(cells, "str") else cells, errors="coerce")
            v = np.asarray(v, dtype=np.float64)
        values[label] = v
        bad = ~np.isfinite(v)
        if bad.any():
            bad_any |= bad
            i = int(np.argmax(bad))
            if first_bad is None or i < first_bad[0]:
                first_bad = (i, label)
    return values, bad_any, first_bad


def _stamp_units(cells: Any, mapping: ColumnMapping, state: MapState) -> np.ndarray:
    """A date/time (or time-delta) column as the time column's units since the recording's
    first stamp (kept in ``state`` across frames); NaN where a stamp is missing."""
    assert mapping.time is not None
    stamps = cells.astype("datetime64[ns]") if pd.api.types.is_datetime64_any_dtype(
        cells) else cells.astype("timedelta64[ns]")
    ns = stamps.to_numpy().astype("int64").astype(np.float64)
    if state.t0_ns is None and ns.size:
        state.t0_ns = float(ns[0])
    v = (ns - (state.t0_ns or 0.0)) * 1e-9 / mapping.time.seconds_per_unit
    v[np.asarray(stamps.isna())] = np.nan
    return v


def map_frame(frame: Frame, mapping: ColumnMapping, state: MapState | None = None, *,
              check: bool = True) -> Mapped:
    """Parse one frame's mapped cells (file, column and row named for a bad one), apply the
    time unit and each channel's scale and offset, group the rows by (device, run) and
    check each group's time within the frame (``check``)."""
    path = frame.path
    values, bad_any, first_bad = _parse_cells(frame, mapping,
                                              state if state is not None else MapState())
    n_skipped = len(frame.skipped_lines)
    if first_bad is not None:
        if mapping.malformed_rows == "error":
            i, label = first_bad
            cell = frame.data[label].iloc[i]
            what = ("empty cell" if str(cell).strip() == "" else
                    f"non-finite value {str(cell).strip()!r}" if _is_float(cell) else
                    f"non-numeric cell {str(cell).strip()!r}")
            raise InputError.at(path, what + _line(frame, i), column=_label(label),
                                row=int(frame.rows[i]))
        n_skipped += int(bad_any.sum())
        frame.skipped_lines += list(np.asarray(frame.lines if frame.lines is not None
                                               else frame.rows)[bad_any])
    keep = ~bad_any
    rows = frame.rows[keep]
    lines = None if frame.lines is None else frame.lines[keep]
    if mapping.time is not None:
        t_label = _resolve(frame, mapping.time.column, "time.column")
        time_s = values[t_label][keep] * mapping.time.seconds_per_unit
    else:
        t_label = "time_s"
        time_s = (rows - 1) / mapping.sample_rate_hz
    n_keep = int(keep.sum())
    if mapping.run_column is not None:
        run_all = _id_column(frame, mapping.run_column, "run_column", "run id", keep)
        run_ids = run_all[keep]
    else:
        run_all = np.full(len(keep), mapping.run_id or path.stem, dtype=object)
        run_ids = run_all[keep]
    if mapping.device_column is not None:
        dev_ids = _id_column(frame, mapping.device_column, "device_column", "device id",
                             keep)[keep]
    else:
        dev_ids = np.full(n_keep, mapping.device_id, dtype=object)
    if mapping.run_column is None and mapping.device_column is None:
        groups = [(str(mapping.device_id), str(run_all[0]) if len(run_all) else "",
                   np.ones(n_keep, dtype=bool))] if n_keep else []
    else:
        pairs = pd.unique(pd.Series(list(zip(dev_ids, run_ids, strict=True)), dtype=object))
        groups = [(str(dev), str(rid), (dev_ids == dev) & (run_ids == rid))
                  for dev, rid in pairs]
    if check:
        for _, _, sel in groups:
            check_time(path, _label(t_label), time_s[sel], rows[sel],
                       None if lines is None else lines[sel])
    channels = {ch.name: values[_resolve(frame, ch.column, "")][keep] * ch.scale + ch.offset
                for ch in mapping.channels}
    return Mapped(frame, groups, time_s, channels, rows, lines, _label(t_label), bad_any,
                  run_all, n_skipped, sensor_kind_of(mapping))


def run_meta(mapping: ColumnMapping, path: Path, numeric_header: Sequence[str],
             skips: tuple[int, list[int]] | None) -> dict[str, str]:
    """A mapped run's metadata: the mapping's, its source, the numeric header, and (with
    ``malformed_rows: skip``) its skipped rows and the first 20 of their lines."""
    meta = dict(mapping.meta)
    meta["source"] = str(path)
    if mapping.source != "<conventional names>":
        meta["mapping"] = mapping.source
    if numeric_header:  # diagnostics.input_warnings suggests 'header: false'
        meta["numeric_header"] = ",".join(list(numeric_header)[:8])
    if mapping.malformed_rows == "skip" and skips is not None:
        meta["skipped_rows"] = str(skips[0])
        # The first few only: enough to find them in an editor, short in a log.
        meta["skipped_lines"] = ",".join(str(int(x)) for x in skips[1][:20])
    return meta


def run_units(mapping: ColumnMapping) -> dict[str, str]:
    return {"time_s": "s", **{ch.name: ch.unit for ch in mapping.channels}}


def apply_mapping(frame: Frame, mapping: ColumnMapping) -> tuple[list[Recording], int]:
    """The whole file's frame as recordings, one per (device, run)."""
    m = map_frame(frame, mapping)
    path = frame.path
    if mapping.malformed_rows == "skip":
        log.warning("%s: skipped %d malformed row(s)", path, m.n_skipped)
    roles = {"output": "outputs", "reference": "references", "drift": "drift",
             "proxy": "proxies"}
    runs = []
    for device_id, run_id, sel in m.groups:
        chans: dict[str, Any] = {g: {} for g in GROUPS}
        temperature = None
        for ch in mapping.channels:
            v = m.channels[ch.name][sel]
            if ch.role == "temperature":
                temperature = v
            else:
                chans[roles[ch.role]][ch.name] = v
        meta = run_meta(mapping, path, frame.numeric_header,
                        m.run_skips(mapping, device_id, run_id))
        runs.append(Recording(time_s=m.time_s[sel], temperature_c=temperature, **chans,
                              units=run_units(mapping), device_id=device_id,
                              sensor_kind=m.sensor_kind, run_id=run_id,
                              sample_rate_hz=mapping.sample_rate_hz, meta=meta))
    return runs, m.n_skipped


def _id_column(frame: Frame, column: str | int, key: str, what: str,
               keep: np.ndarray) -> np.ndarray:
    """The stripped string cells of a run or device column; an empty kept cell is an error."""
    label = _resolve(frame, column, key)
    cells = frame.data[label]
    empty = (cells.isna() | (cells.astype(str).str.strip() == "")).to_numpy()[keep]
    if empty.any():
        i = int(np.flatnonzero(keep)[np.argmax(empty)])
        raise InputError.at(frame.path, f"empty {what}" + _line(frame, i),
                            column=_label(label), row=int(frame.rows[i]))
    return np.asarray(cells.astype(str).str.strip().to_numpy(), dtype=object)


# ---------------------------------------------------------------- checks
def _is_float(cell: object) -> bool:
    try:
        float(str(cell))
    except ValueError:
        return False
    return True


def _label(label: str | int) -> str:
    return f"#{label} (0-based)" if isinstance(label, int) else str(label)


def _line(frame: Frame, i: int) -> str:
    return "" if frame.lines is None else f" (file line {int(frame.lines[i])})"


def check_finite(path: Path, name: str, v: np.ndarray, rows: np.ndarray,
                  lines: np.ndarray | None) -> np.ndarray:
    bad = np.flatnonzero(~np.isfinite(v))
    if bad.size:
        i = int(bad[0])
        where = "" if lines is None else f" (file line {int(lines[i])})"
        raise InputError.at(path, f"non-finite value {float(v[i])!r}{where}", column=name,
                            row=int(rows[i]))
    return v


def check_time(path: Path, name: str, t: np.ndarray, rows: np.ndarray,
                lines: np.ndarray | None) -> None:
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        kind = "duplicate" if dt[i - 1] == 0 else "decreasing"
        where = "" if lines is None else f"; file line {int(lines[i])}"
        raise InputError.at(path, f"{kind} timestamp {float(t[i])!r} s after "
                            f"{float(t[i - 1])!r} s "
                            f"(time must increase strictly{where})", column=name,
                            row=int(rows[i]))


def float_values(path: Path, name: str, column: Any, rows: np.ndarray,
                 lines: np.ndarray | None = None) -> np.ndarray:
    """A column of a thermonet table (a pyarrow array or chunked array) as float64: a
    column of text, dates or anything else that is not numbers is named by file, column and
    the first row that is not a number, as the mapped reader names it."""
    import pyarrow as pa

    typ = column.type
    if pa.types.is_boolean(typ):
        raise InputError.at(path, "a boolean column, not a measurement", column=name)
    if pa.types.is_floating(typ) or pa.types.is_integer(typ) or pa.types.is_decimal(typ):
        return np.asarray(column.to_numpy(zero_copy_only=False), dtype=np.float64)
    if pa.types.is_null(typ):
        cells = pd.Series([""] * len(column), dtype=object)
    elif pa.types.is_string(typ) or pa.types.is_large_string(typ) or \
            pa.types.is_dictionary(typ):
        cells = pd.Series(column.to_pylist(), dtype=object)
    else:
        raise InputError.at(path, f"a column of {typ}, not numbers", column=name)
    strip = cells.astype(str).str.strip()
    v = np.asarray(pd.to_numeric(strip.where(cells.notna(), ""), errors="coerce"),
                   dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(v))
    if bad.size:
        i = int(bad[0])
        cell = "" if cells.iloc[i] is None else str(cells.iloc[i]).strip()
        what = ("empty cell" if cell == "" else f"non-finite value {cell!r}"
                if _is_float(cell) else f"non-numeric cell {cell!r}")
        where = "" if lines is None else f" (file line {int(lines[i])})"
        raise InputError.at(path, what + where, column=name, row=int(rows[i]))
    return v
