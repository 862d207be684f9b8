"""Text tables (CSV, TSV, whitespace) read into recordings: the frames of cells
(:mod:`thermonet.data.text`: the separator sniffed) mapped to channels, the header's
conventional names taken as they are (the native layout), or a column mapping applied
(:mod:`thermonet.data.mapping`: which column is time, temperature, each output, reference and
proxy, in which unit; several runs or devices told apart by an id column).  Every value is
checked where it is read (:mod:`thermonet.data.values`): a non-finite number or a time that
does not increase is refused with the file, the column and the line.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..core.errors import InputError
from ..core.recording import OUTPUT_NAME, Recording
from .mapping import (
    ChannelSpec,
    ColumnMapping,
    TimeSpec,
    case_slip,
    default_unit,
    header_unit_clashes,
)
from .text import Frame
from .values import check_time, is_float

__all__ = ["GROUPS", "native_mapping", "apply_mapping", "map_frame", "Mapped", "MapState",
           "run_meta", "run_units", "sensor_kind_of"]

log = logging.getLogger(__name__)
#: The channel groups of a recording besides time and temperature.
GROUPS = ("outputs", "references", "drift", "proxies")


def native_mapping(path: Path, columns: list, numeric_header: Sequence[str] = ()
                    ) -> ColumnMapping:
    names = [str(c) for c in columns]
    for n in names:     # 'Gyro_X' would be read as a proxy and its axis left out of the fit
        slip = case_slip(n)
        if slip and slip not in names:
            raise InputError.at(path, f"not a thermonet column name: did you mean '{slip}'? "
                                "(thermonet's names are lower case; rename the column, or "
                                "describe the file with a mapping)", column=n)
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
    if isinstance(cells.dtype, pd.DatetimeTZDtype):   # zoned stamps: UTC (times are relative)
        cells = cells.dt.tz_convert("UTC").dt.tz_localize(None)
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
                    f"non-finite value {str(cell).strip()!r}" if is_float(cell) else
                    f"non-numeric cell {str(cell).strip()!r}")
            is_time = mapping.time is not None and label == _resolve(
                frame, mapping.time.column, "time.column")
            raise InputError.at(path, what + _line(frame, i) + _cell_hint(str(cell), is_time),
                                column=_label(label), row=int(frame.rows[i]))
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
    clashes = header_unit_clashes(mapping)
    if clashes:         # diagnostics.run_warnings names them
        meta["header_units"] = "; ".join(clashes)
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
    if mapping.malformed_rows == "skip" and m.n_skipped:
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


_DECIMAL_COMMA = re.compile(r"[+-]?[0-9.]*[0-9],[0-9]+")
_CLOCK = re.compile(r"([0-9]{4}-[0-9]{2}-[0-9]{2}|[0-9]{1,2}\.[0-9]{1,2}\.[0-9]{2,4}|"
                    r"[0-9]{1,2}:[0-9]{2})")


def _cell_hint(cell: str, is_time: bool) -> str:
    """What a non-numeric cell most likely is, and what to do (a decimal comma, clock or
    date text in the time column); "" when it looks like neither."""
    text = cell.strip()
    if _DECIMAL_COMMA.fullmatch(text):
        return ("; thermonet reads '.' as the decimal mark: convert the file (e.g. export it "
                "with '.' decimals in the logger's or spreadsheet's locale setting)")
    if is_time and _CLOCK.search(text):
        return ("; time in a CSV must be numeric (time.unit s, ms, us, min or h since the "
                "start), not clock or date text: export elapsed time, or give sample_rate_hz "
                "instead of time")
    return ""


def _label(label: str | int) -> str:
    return f"#{label} (0-based)" if isinstance(label, int) else str(label)


def _line(frame: Frame, i: int) -> str:
    return "" if frame.lines is None else f" (file line {int(frame.lines[i])})"
