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
import logging
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..core.errors import InputError
from ..core.recording import OUTPUT_NAME, Recording
from .mapping import ChannelSpec, ColumnMapping, TimeSpec, default_unit

__all__ = ["Frame", "GROUPS", "read_text", "native_mapping", "apply_mapping", "check_finite",
           "check_time"]

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
    try:
        # utf-8-sig drops the byte-order mark spreadsheet exports put before the header.
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as err:
        raise InputError.at(path, f"not UTF-8 text (byte {err.start})") from err
    skip = mapping.skip_lines if mapping else 0
    header = mapping.header if mapping else True
    malformed = mapping.malformed_rows if mapping else "error"
    lines = text.splitlines()[skip:]
    if mapping is not None and mapping.separator is not None:
        sep = mapping.separator
    if sep is None:
        sep = _sniff(path, [ln for ln in lines if ln.strip()][:50])
    records = list(csv.reader(lines, delimiter=sep))
    names: list[str] | None = None
    first_data = skip + 1  # physical line of data row 1, before the header shift
    if header:
        while records and not records[0]:  # blank lines before the header
            records.pop(0)
            lines.pop(0)
            first_data += 1
        if not records:
            raise InputError.at(path, "no header line (file is empty after the banner)")
        names = [c.strip() for c in records.pop(0)]
        lines.pop(0)
        first_data += 1
        dup = [n for n, c in Counter(names).items() if c > 1]
        if dup:
            raise InputError.at(path, "duplicate column in the header", column=dup[0])
    counts = [len(r) for r in records if r]
    if names is not None:
        n_fields = len(names)
    elif mapping is not None and mapping.n_fields is not None:
        n_fields = mapping.n_fields
    elif counts:
        n_fields = Counter(counts).most_common(1)[0][0]
    else:
        raise InputError.at(path, "no data rows")
    keep: list[int] = []
    skipped_lines: list[int] = []
    for i, rec in enumerate(records):
        if not rec:
            continue  # blank lines carry no sample
        if len(rec) != n_fields:
            if malformed == "error":
                raise InputError.at(path, f"expected {n_fields} fields, found {len(rec)} "
                                    f"(file line {first_data + i}; set malformed_rows: skip "
                                    "in a mapping to drop such rows)", row=i + 1)
            skipped_lines.append(first_data + i)
            continue
        keep.append(i)
    if not keep:
        raise InputError.at(path, "no data rows")
    # The csv pre-scan only sorts rows by field count; pandas does the parsing.
    data = pd.read_csv(io.StringIO("\n".join(lines[i] for i in keep)), sep=sep, header=None,
                       names=names if names is not None else list(range(n_fields)),
                       dtype=str, keep_default_na=False, skip_blank_lines=False)
    rows = np.asarray(keep) + 1
    numeric = names if names and all(n and _is_float(n) for n in names) else []
    return Frame(path=path, data=data, rows=rows, lines=rows - 1 + first_data,
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


def apply_mapping(frame: Frame, mapping: ColumnMapping) -> tuple[list[Recording], int]:
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
            stamps = cells.astype("datetime64[ns]") if pd.api.types.is_datetime64_any_dtype(
                cells) else cells.astype("timedelta64[ns]")
            ns = stamps.to_numpy().astype("int64").astype(np.float64)
            v = (ns - ns[0]) * 1e-9 / mapping.time.seconds_per_unit
            v[np.asarray(stamps.isna())] = np.nan
            values[label] = v
            bad = ~np.isfinite(v)
            if bad.any():
                bad_any |= bad
                i = int(np.argmax(bad))
                if first_bad is None or i < first_bad[0]:
                    first_bad = (i, label)
            continue
        v = pd.to_numeric(cells.str.strip() if cells.dtype != np.float64 and
                          hasattr(cells, "str") else cells, errors="coerce")
        v = np.asarray(v, dtype=np.float64)
        bad = ~np.isfinite(v)
        values[label] = v
        if bad.any():
            bad_any |= bad
            i = int(np.argmax(bad))
            if first_bad is None or i < first_bad[0]:
                first_bad = (i, label)
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
    if mapping.malformed_rows == "skip":
        log.warning("%s: skipped %d malformed row(s)", path, n_skipped)
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
    pairs = pd.unique(pd.Series(list(zip(dev_ids, run_ids, strict=True)), dtype=object))
    groups = [(str(dev), str(rid), (dev_ids == dev) & (run_ids == rid)) for dev, rid in pairs]
    kinds = {m.group(1) for c in mapping.channels if c.role == "output"
             for m in [OUTPUT_NAME.match(c.name)] if m is not None}
    sensor_kind = mapping.sensor_kind or (kinds.pop() if len(kinds) == 1 else "mixed")
    runs = []
    for device_id, run_id, sel in groups:
        t = time_s[sel]
        check_time(path, _label(t_label), t, rows[sel], None if lines is None else lines[sel])
        chans: dict[str, Any] = {g: {} for g in GROUPS}
        temperature = None
        units = {"time_s": "s"}
        for ch in mapping.channels:
            raw = values[_resolve(frame, ch.column, "")][keep][sel]
            v = raw * ch.scale + ch.offset
            units[ch.name] = ch.unit
            role = ch.role
            if role == "temperature":
                temperature = v
            else:
                group = {"output": "outputs", "reference": "references", "drift": "drift",
                         "proxy": "proxies"}[role]
                chans[group][ch.name] = v
        meta = dict(mapping.meta)
        meta["source"] = str(path)
        if mapping.source != "<conventional names>":
            meta["mapping"] = mapping.source
        if frame.numeric_header:  # diagnostics.input_warnings suggests 'header: false'
            meta["numeric_header"] = ",".join(frame.numeric_header[:8])
        if mapping.malformed_rows == "skip":
            if mapping.run_column is None:
                run_skipped, run_lines = n_skipped, sorted(frame.skipped_lines)
            else:
                # rows with a bad mapped cell belong to the run their run cell names; a row
                # with a wrong field count has no readable run cell and counts for the file only
                mine = bad_any & (run_all == run_id)
                if mapping.device_column is not None:
                    dev_all = frame.data[_resolve(frame, mapping.device_column, "")]
                    mine &= dev_all.astype(str).str.strip().to_numpy() == device_id
                at = frame.lines if frame.lines is not None else frame.rows
                run_skipped, run_lines = int(mine.sum()), sorted(np.asarray(at)[mine])
            meta["skipped_rows"] = str(run_skipped)
            # The first few only: enough to find them in an editor, short in a log.
            meta["skipped_lines"] = ",".join(str(int(x)) for x in run_lines[:20])
        runs.append(Recording(time_s=t, temperature_c=temperature, **chans, units=units,
                              device_id=device_id, sensor_kind=sensor_kind,
                              run_id=run_id, sample_rate_hz=mapping.sample_rate_hz, meta=meta))
    return runs, n_skipped


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
