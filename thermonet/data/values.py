"""A column's values checked where they are read: a non-finite number or a time that does not
increase is refused with the file, the column, the data row and (for a text file) the file
line; a Parquet column that is not numbers is named the same way.  Shared by the text tables
(:mod:`thermonet.data.tables`), the whole-file reader (:mod:`thermonet.data.io`) and the
chunked one (:mod:`thermonet.data.chunks`).  Also the messages of a text file that is not
values at all (not UTF-8; rows of the wrong field count, every row of them).
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..core.errors import InputError, counted

__all__ = ["is_float", "check_finite", "check_time", "float_values", "not_utf8",
           "field_count_message", "all_skipped_message"]


def is_float(cell: object) -> bool:
    try:
        float(str(cell))
    except ValueError:
        return False
    return True


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
                if is_float(cell) else f"non-numeric cell {cell!r}")
        where = "" if lines is None else f" (file line {int(lines[i])})"
        raise InputError.at(path, what + where, column=name, row=int(rows[i]))
    return v


def not_utf8(path: Path, err: UnicodeDecodeError, offset: int, raw: bytes, line: int
              ) -> InputError:
    """A byte that is not UTF-8, named by its file offset and file line (``raw`` starts at
    ``offset``, on file line ``line``)."""
    at = line + raw.count(b"\n", 0, err.start)
    return InputError.at(path, f"not UTF-8 text (byte {offset + err.start}, file line {at}, "
                         f"0x{raw[err.start]:02x}): the file must be UTF-8 (or plain ASCII); "
                         "save or export it as UTF-8")


def field_count_message(n_fields: int, n: int, line: int, names: list[str] | None) -> str:
    """A row of ``n`` fields where ``n_fields`` are expected: a header of one field over
    rows of many is a banner line read as the header (``skip_lines``), not a bad row."""
    if names is not None and len(names) == 1 and n > 1:
        return (f"expected 1 field (the header line has one), found {n} (file line {line}); "
                "is skip_lines right (a banner line read as the header?), or the separator?")
    return (f"expected {n_fields} fields, found {n} (file line {line}; set malformed_rows: "
            "skip in a mapping to drop such rows)")


def all_skipped_message(found: Counter[int], n_fields: int) -> str:
    """Why a file whose every row was skipped for its field count has no data rows."""
    if not found:
        return ""
    counts = ", ".join(str(k) for k, _ in found.most_common(3))
    return (f": all {sum(found.values())} rows skipped as malformed (expected "
            f"{counted(n_fields, 'field')}, found {counts}); are skip_lines and the separator "
            "right?")
