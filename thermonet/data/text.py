"""Text files (CSV, TSV, whitespace) parsed into :class:`Frame`\\ s of cells: the separator
sniffed, quoted cells across lines grouped into whole records, rows with a wrong field count
skipped and counted, the whole file at once (:func:`read_text`) or ``chunk_rows`` lines at a
time (:func:`iter_text_frames`).  Which column is what is the mapping's business
(:mod:`thermonet.data.tables`).
"""

from __future__ import annotations

import csv
import io
import itertools
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.errors import InputError, counted
from .mapping import ColumnMapping
from .values import all_skipped_message, field_count_message, is_float, not_utf8

__all__ = ["Frame", "read_text", "iter_text_frames"]

_SNIFF_DELIMITERS = ",;\t|"


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
        raw = path.read_bytes()
        try:
            # utf-8-sig drops the byte-order mark spreadsheet exports put before the header.
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError as err:
            raise not_utf8(path, err, 0, raw, 1) from err
        yield text.splitlines(), 0
        return
    offset, line = 0, 1
    with path.open("rb") as f:
        while True:
            block = list(itertools.islice(f, chunk_rows))
            if not block:
                return
            raw = b"".join(block)
            try:
                text = raw.decode("utf-8-sig" if offset == 0 else "utf-8")
            except UnicodeDecodeError as err:
                raise not_utf8(path, err, offset, raw, line) from err
            yield text.splitlines(), offset
            offset += len(raw)
            line += len(block)


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
                                f"the {counted(len(self.tail) - 1, 'line')} after it)")

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
                 first_data: int, used: set[str] | None
                 ) -> tuple[list[str], list[list[str]], int, bool]:
    """The header's column names (blank lines before it skipped); the records after it; the
    physical line of the first data row; whether the header ended in one empty name (a
    trailing separator, dropped: rows may then end in one empty field too).

    A name twice is refused where ``used`` (the names a mapping reads; None: every name) holds
    it; else the second is renamed ``<name> #<field>`` (a column no one reads)."""
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
    trailing = len(names) > 1 and names[-1] == "" and names[-2] != ""
    if trailing:
        names.pop()
    empty = [i + 1 for i, n in enumerate(names) if n == ""]
    if len(empty) > 1 and (used is None or "" in used):
        raise InputError.at(path, f"header fields {', '.join(map(str, empty))} are empty "
                            f"(file line {first_data - 1}: a separator too many at the end of "
                            "the header line?)")
    dup = [n for n, c in Counter(names).items() if c > 1]
    if any(n in used for n in dup) if used is not None else dup:
        bad = [n for n in dup if used is None or n in used][0]
        raise InputError.at(path, "duplicate column in the header (the mapping reads it; "
                            "rename one in the file)", column=bad)
    seen: set[str] = set()
    for i, n in enumerate(names):
        if n in seen:
            names[i] = f"{n} #{i}"
        seen.add(names[i])
    return names, records, first_data, trailing


def _field_count(path: Path, names: list[str] | None, mapping: ColumnMapping | None,
                 records: list[list[str]]) -> int:
    """Fields per well-formed row: the header's, else the mapping's ``n_fields``, else the
    most common count of the first records.  A mapping's ``n_fields`` other than the header's
    field count (with or without a trailing empty one) is refused."""
    if names is not None:
        if mapping is not None and mapping.n_fields is not None and \
                mapping.n_fields not in (len(names), len(names) + 1):
            raise InputError.at(path, f"mapping key 'n_fields' is {mapping.n_fields}, but the "
                                f"header line has {len(names)} fields (with a header, leave "
                                f"n_fields out: the header sets it; mapping {mapping.source})")
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


#: The first bytes of binary files a text reader may be pointed at by a mapping's format or
#: a file's extension, and what each is.
_BINARY_MAGIC = {b"PAR1": ("Parquet", "parquet"), b"\x89HDF": ("HDF5", None),
                 b"ULog": ("PX4 ULog", None)}


def _not_text(err: InputError, path: Path, mapping: ColumnMapping | None) -> InputError:
    """``err`` where a binary file was read as text ("not UTF-8 text"): what the file is and
    what made it read as text — the mapping's ``format`` or the file's extension."""
    if "not UTF-8 text" not in str(err):
        return err
    try:
        with path.open("rb") as f:
            head = f.read(4)
    except OSError:
        return err
    kind = next((v for k, v in _BINARY_MAGIC.items() if head.startswith(k)), None)
    if kind is None:
        return err
    name, fmt = kind
    fix = f"set its format to {fmt} (or auto)" if fmt else "a mapping reads CSV, TSV or Parquet"
    if mapping is not None and mapping.format in ("csv", "tsv"):
        why = f"the mapping {mapping.source} says 'format: {mapping.format}'; {fix}"
    else:
        why = (f"of its extension '{path.suffix}'; rename it to .parquet" if fmt else
               f"of its extension '{path.suffix}'") + (" or set the mapping's format to "
                                                       f"{fmt}" if fmt and mapping else "")
    start = head.decode("ascii", "backslashreplace")
    return InputError(f"{err}: a {name} file (it starts with '{start}'), read as text because "
                      f"{why}")


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
    try:
        src, sep, joined = _first_records(path, sep, skip, chunk_rows)
    except InputError as err:
        raise _not_text(err, path, mapping) from None
    lines, blocks = src.lines, src.blocks
    records = list(csv.reader(lines, delimiter=sep))
    names: list[str] | None = None
    first_data = skip + 1  # physical line of data row 1, before the header shift
    if header:
        names, records, first_data, _ = _read_header(path, src, records, sep, first_data,
                                                     _used_names(mapping))
    lead = first_data - skip - 1   # records before data row 1 (blank lines, the header)

    def line_of(i: np.ndarray) -> np.ndarray:
        """The physical file line of 0-based data records ``i``."""
        i = np.asarray(i, dtype=np.int64)
        return first_data + i + joined.extra_at(lead + i)
    n_fields = _field_count(path, names, mapping, records)
    numeric = names if names and all(n and is_float(n) for n in names) else []
    fast = None if float_columns is None or chunk_rows is None else \
        float_columns(names, n_fields)
    base = 0   # index of this frame's first record among all records after the header
    any_rows = False
    found: Counter[int] = Counter()   # field counts of the rows skipped for it
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
                               malformed, numeric, found)
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
        raise InputError.at(path, "no data rows" + all_skipped_message(found, n_fields))


def _used_names(mapping: ColumnMapping | None) -> set[str] | None:
    """The header names a mapping reads (None without a mapping: every name is read)."""
    if mapping is None:
        return None
    cols = [mapping.run_column, mapping.device_column] + [ch.column for ch in mapping.channels]
    if mapping.time is not None:
        cols.append(mapping.time.column)
    return {c for c in cols if isinstance(c, str)}


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
    if all(ln.endswith(sep) for ln in lines):   # a logger's trailing separator on every row
        lines = [ln[:-1] for ln in lines]
        text = "\n".join(lines)
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
           numeric: list[str], found: Counter[int] | None = None) -> Frame | None:
    """One frame of text records (``base``: the index of the first among all data records),
    or None when every record of it is blank or skipped.  A row of ``n_fields`` + 1 fields
    whose last is empty (a logger's trailing separator) is a row of ``n_fields``; the field
    counts of rows skipped for theirs are tallied in ``found``."""
    keep: list[int] = []
    skipped_lines: list[int] = []
    lines = list(lines)
    for i, rec in enumerate(records):
        if not rec:
            continue  # blank lines carry no sample
        if len(rec) == n_fields + 1 and rec[-1] == "" and lines[i].endswith(sep):
            lines[i] = lines[i][:-1]
        elif len(rec) != n_fields:
            if malformed == "error":
                raise InputError.at(path, field_count_message(
                    n_fields, len(rec), int(line_of(np.asarray(base + i))), names),
                    row=base + i + 1)
            if found is not None:
                found[len(rec)] += 1
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

