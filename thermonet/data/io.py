"""Recording files: thermonet's Parquet format, native CSV, and mapped foreign files.

On-disk format (Parquet, format version :data:`FORMAT_VERSION`)
----------------------------------------------------------------
One row per sample; several runs stack in one file, told apart by ``run``:

``run`` (string), ``device`` (string; only when the file holds several units —
a fleet — whose runs are then told apart by ``device`` and ``run`` together),
``time_s`` (s), ``temperature_c`` (°C; omitted when no run
has one), outputs ``<kind>_<axis>``, references ``ref_<kind>_<axis>``,
simulated truth ``drift_<kind>_<axis>``, proxies by name (``freq_hz``,
``temp_raw``).  A channel a run lacks is null in that run's rows.  The schema
metadata key ``thermonet`` holds one JSON blob::

    {"format": "thermonet", "version": 1, "meta": {...dataset meta...},
     "runs": [{"run_id", "device_id", "sensor_kind", "sample_rate_hz", "meta",
               "units", "temperature", "outputs", "references", "drift",
               "proxies", "n_samples"}, ...]}

Values are float64 and JSON floats round-trip exactly, so a write/read round
trip is lossless.

Reading
-------
* ``.parquet`` with the blob: the format above.  Without it but with the
  conventional column names: default units (:func:`thermonet.data.mapping.default_unit`),
  one run per ``run`` value, or one run named after the file stem.
* ``.csv`` / ``.tsv`` / ``.txt`` whose header uses the conventional names
  (``time_s`` and at least one output): read as is, separator sniffed.
* Anything else: a column mapping (:mod:`thermonet.data.mapping`).

Row numbers in error messages are **1-based data rows**: row 1 is the first
line after the skipped banner lines and the header (the first row of a
Parquet table); the message also gives the physical file line for text files.
"""

from __future__ import annotations

import csv
import io
import json
import logging
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from ..core.errors import InputError
from ..core.fileio import atomic_path, not_a_file
from ..core.recording import OUTPUT_NAME, Dataset, Recording
from .mapping import ChannelSpec, ColumnMapping, TimeSpec, default_unit, load_mapping

__all__ = ["FORMAT_VERSION", "METADATA_KEY", "write_parquet", "read_dataset", "read_datasets"]

log = logging.getLogger(__name__)

#: Version of the Parquet layout written by :func:`write_parquet`.
FORMAT_VERSION = 1
#: Schema-metadata key of the JSON blob.
METADATA_KEY = "thermonet"

_PARQUET = (".parquet", ".pq")
_TEXT = (".csv", ".tsv", ".txt")
_SNIFF_DELIMITERS = ",;\t|"
_GROUPS = ("outputs", "references", "drift", "proxies")


# ----------------------------------------------------------------- writing
def write_parquet(dataset: Dataset, path: str | Path) -> Path:
    """Write ``dataset`` to ``path`` atomically; return the path.

    The table is written to a temporary file in the same directory and moved
    over ``path`` with :func:`os.replace`, so a failed write leaves nothing new
    at ``path`` (and an existing file there untouched).
    """
    path = Path(path)
    if path.suffix.lower() not in (".parquet", ".pq"):
        raise InputError.at(path, "a thermonet recording file ends in .parquet (or .pq)")
    if path.is_dir():
        raise InputError.at(path, "is a directory; give a .parquet file name")
    if not path.parent.is_dir():
        raise InputError.at(path, f"output directory '{path.parent}' does not exist")
    for run in dataset:
        run.validate()
    with atomic_path(path, make_parents=False) as tmp:
        pq.write_table(_to_table(dataset), tmp)
    return path


def _to_table(dataset: Dataset) -> pa.Table:
    runs = list(dataset)
    names: list[str] = []
    for group in _GROUPS:
        for run in runs:
            names += [k for k in getattr(run, group) if k not in names]
    has_temp = any(r.temperature_c is not None for r in runs)
    cols: dict[str, pa.Array] = {
        "run": pa.array(np.concatenate([[r.run_id] * r.n_samples for r in runs]), pa.string())}
    if dataset.is_fleet:
        cols["device"] = pa.array(np.concatenate([[r.device_id] * r.n_samples for r in runs]),
                                  pa.string())
    cols["time_s"] = pa.array(np.concatenate([r.time_s for r in runs]), pa.float64())
    for name in (["temperature_c"] if has_temp else []) + names:
        parts, masks = [], []
        for r in runs:
            try:
                parts.append(np.asarray(r.channel(name), dtype=np.float64))
                masks.append(np.zeros(r.n_samples, dtype=bool))
            except KeyError:
                parts.append(np.zeros(r.n_samples))
                masks.append(np.ones(r.n_samples, dtype=bool))
        cols[name] = pa.array(np.concatenate(parts), pa.float64(), mask=np.concatenate(masks))
    blob: dict[str, Any] = {"format": "thermonet", "version": FORMAT_VERSION,
            "meta": _str_dict(dataset.meta, "dataset meta"), "runs": []}
    for r in runs:
        blob["runs"].append({
            "run_id": r.run_id, "device_id": r.device_id, "sensor_kind": r.sensor_kind,
            "sample_rate_hz": None if r.sample_rate_hz is None else float(r.sample_rate_hz),
            "meta": _str_dict(r.meta, f"run '{r.run_id}' meta"),
            "units": _str_dict(r.units, f"run '{r.run_id}' units"),
            "temperature": r.temperature_c is not None,
            **{g: list(getattr(r, g)) for g in _GROUPS}, "n_samples": r.n_samples})
    table = pa.table(cols)
    return table.replace_schema_metadata(
        {METADATA_KEY: json.dumps(blob, allow_nan=False, ensure_ascii=False)})


def _str_dict(d: dict, what: str) -> dict[str, str]:
    for k, v in d.items():
        if not isinstance(k, str) or not isinstance(v, str):
            raise InputError(f"{what}: key {k!r} has value {v!r}; only strings can be stored")
    return dict(d)


# ----------------------------------------------------------------- reading
def read_dataset(path: str | Path, mapping: ColumnMapping | str | Path | None = None
                 ) -> Dataset:
    """Read one recording file into a validated :class:`Dataset`.

    Parameters
    ----------
    path : path
        A thermonet Parquet file, a CSV/TSV with conventional column names, or
        any file ``mapping`` describes.
    mapping : ColumnMapping, path to a YAML mapping, or None

    Raises
    ------
    InputError
        One line naming the file, the column and the 1-based data row.
    """
    return read_datasets([path], mapping)


def read_datasets(paths: Sequence[str | Path] | str | Path,
                  mapping: ColumnMapping | str | Path | None = None, *,
                  validate: bool = True) -> Dataset:
    """Read several files into one validated :class:`Dataset`.

    Each file gives one run (id: the mapping's ``run_id``, else the file stem)
    unless it has a run column; thermonet Parquet files keep their runs.
    Skipped malformed rows are summed into ``Dataset.meta['skipped_rows']``.
    ``validate=False`` leaves the runs unvalidated (``fleet`` validates unit by
    unit, so that one bad unit fails alone).
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    if not paths:
        raise InputError("no input files given")
    if mapping is not None and not isinstance(mapping, ColumnMapping):
        mapping = load_mapping(mapping)
    runs: list[Recording] = []
    meta: dict[str, str] = {}
    skipped: int | None = None
    for p in paths:
        file_runs, file_meta, n_skipped = _read_one(Path(p), mapping)
        runs += file_runs
        for k, v in file_meta.items():
            meta.setdefault(k, v)
        if n_skipped is not None:
            skipped = (skipped or 0) + n_skipped
    if skipped is not None:
        meta["skipped_rows"] = str(skipped)
    seen: dict[tuple[str, str], str] = {}
    several = len({r.device_id for r in runs}) > 1
    for r in runs:
        key = (r.device_id, r.run_id)
        if key in seen:
            unit = f" of unit '{r.device_id}'" if several else ""
            raise InputError.at(r.meta.get("source", ""), f"run id '{r.run_id}'{unit} already "
                                f"used by {seen[key]} (a unit's run ids must be unique; set "
                                "'run_id' per file, rename the files, or give each unit its "
                                "own device id)")
        seen[key] = r.meta.get("source", "")
    source = str(paths[0]) if len(paths) == 1 else ""
    if not validate:
        if not runs:
            raise InputError.at(source, "no runs")
        return Dataset(runs=runs, meta=meta)
    return Dataset(runs=runs, meta=meta).validate(source)


def _read_one(path: Path, mapping: ColumnMapping | None
              ) -> tuple[list[Recording], dict[str, str], int | None]:
    from .logs import is_log

    if is_log(str(path).partition("#")[0]):
        from .logs import read_log_instance

        if mapping is not None:
            raise InputError.at(path, "a flight-controller log is read with no mapping")
        ds = read_log_instance(path)
        return list(ds.runs), dict(ds.meta), None
    why = not_a_file(path)
    if why:
        raise InputError.at(path, why)
    fmt = mapping.format if mapping is not None else "auto"
    ext = path.suffix.lower()
    if fmt == "auto":
        fmt = "parquet" if ext in _PARQUET else "tsv" if ext == ".tsv" else \
            "csv" if ext in _TEXT or mapping is not None else ""
    if not fmt:
        raise InputError.at(path, f"unknown file type '{ext}' (thermonet reads .parquet, "
                            ".csv, .tsv, .txt; for other files give a mapping with 'format')")
    if fmt == "parquet":
        table = _read_parquet_table(path)
        blob = (table.schema.metadata or {}).get(METADATA_KEY.encode())
        if blob is not None and mapping is None:
            runs, meta = _from_thermonet_table(path, table, blob)
            return runs, meta, None
        frame = _Frame(path=path, data=table.to_pandas(),
                       rows=np.arange(1, table.num_rows + 1), lines=None)
    else:
        frame = _read_text(path, mapping, sep="\t" if fmt == "tsv" else None)
    if mapping is None:
        mapping = _native_mapping(path, list(frame.data.columns), frame.numeric_header)
    runs, n_skipped = _apply_mapping(frame, mapping)
    return runs, {}, (n_skipped if mapping.malformed_rows == "skip" else None)


def _read_parquet_table(path: Path) -> pa.Table:
    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as err:
        raise InputError.at(path, f"not a readable Parquet file ({err})") from err
    dup = [n for n, c in Counter(table.column_names).items() if c > 1]
    if dup:
        raise InputError.at(path, "duplicate column", column=dup[0])
    return table


def _from_thermonet_table(path: Path, table: pa.Table, blob: bytes
                          ) -> tuple[list[Recording], dict[str, str]]:
    try:
        info = json.loads(blob)
    except (ValueError, UnicodeDecodeError) as err:
        raise InputError.at(path, f"corrupt '{METADATA_KEY}' metadata (not JSON: {err})") from None
    entries = _check_blob(path, info)
    version = info["version"]
    if version > FORMAT_VERSION:
        raise InputError.at(path, f"format version {version} is newer than this thermonet "
                            f"reads ({FORMAT_VERSION}); upgrade thermonet")
    for col in ("run", "time_s"):
        if col not in table.column_names:
            raise InputError.at(path, "missing column", column=col)
    run_col = np.asarray(table.column("run").to_pylist(), dtype=object)
    dev_col = (np.asarray(table.column("device").to_pylist(), dtype=object)
               if "device" in table.column_names else None)
    runs = []
    for e in entries:
        sel = run_col == e["run_id"]
        if dev_col is not None:
            sel &= dev_col == e["device_id"]
        idx = np.flatnonzero(sel)
        rows = idx + 1

        def take(name: str, e: Any = e, idx: np.ndarray = idx, rows: np.ndarray = rows
                 ) -> np.ndarray:  # this run's e, idx, rows bound now (called in this loop only)
            if name not in table.column_names:
                raise InputError.at(path, f"missing column (run '{e['run_id']}' lists it)",
                                    column=name)
            if pa.types.is_boolean(table.schema.field(name).type):
                raise InputError.at(path, "a boolean column, not a measurement", column=name)
            values = table.column(name).to_numpy(zero_copy_only=False)[idx]
            return _check_finite(path, name, np.asarray(values, dtype=np.float64), rows, None)

        time_s = take("time_s")
        _check_time(path, "time_s", time_s, rows, None)
        groups = {g: {k: take(k) for k in e[g]} for g in _GROUPS}
        runs.append(Recording(
            time_s=time_s, temperature_c=take("temperature_c") if e["temperature"] else None,
            **groups, units=dict(e["units"]), device_id=e["device_id"],
            sensor_kind=e["sensor_kind"], run_id=e["run_id"],
            sample_rate_hz=e["sample_rate_hz"], meta=dict(e["meta"])))
    return runs, dict(info.get("meta", {}))


#: Highest sample rate accepted from a file's metadata (Hz); absurd values are corrupt files.
MAX_SAMPLE_RATE_HZ = 1e6


def _check_blob(path: Path, info: Any) -> list[dict[str, Any]]:
    """Every field of the ``thermonet`` metadata blob, by type and rule; return the run entries.

    A Parquet file is input: each value is checked before use and a bad one
    is named (``runs[0].units``), never a traceback.
    """
    from ..core.names import AXIS, SIGNAL, TEXT_ID, UNIT, check_finite, check_name

    def bad(key: str, why: str) -> InputError:
        return InputError.at(path, f"corrupt '{METADATA_KEY}' metadata: field '{key}': {why}")

    if not isinstance(info, dict):
        raise bad("<top>", f"expected a mapping, got {type(info).__name__}")
    for key in ("version", "runs"):
        if key not in info:
            raise bad(key, "missing")
    if isinstance(info["version"], bool) or not isinstance(info["version"], int):
        raise bad("version", f"{info['version']!r} is not an integer")
    if not isinstance(info["runs"], list) or not info["runs"]:
        raise bad("runs", "expected a non-empty list of runs")
    if not isinstance(info.get("meta", {}), dict):
        raise bad("meta", "expected a mapping")
    need = ("run_id", "device_id", "sensor_kind", "sample_rate_hz", "meta", "units",
            "temperature") + _GROUPS
    for i, e in enumerate(info["runs"]):
        at = f"runs[{i}]"
        if not isinstance(e, dict):
            raise bad(at, "expected a mapping")
        for key in need:
            if key not in e:
                raise bad(f"{at}.{key}", "missing")
        for key in ("run_id", "device_id"):
            check_name(e[key], TEXT_ID, f"{path}: '{METADATA_KEY}' metadata field '{at}.{key}'")
        if e["sensor_kind"] is not None and not isinstance(e["sensor_kind"], str):
            raise bad(f"{at}.sensor_kind", f"{e['sensor_kind']!r} is not a string")
        if e["sample_rate_hz"] is not None:
            check_finite(e["sample_rate_hz"], f"{path}: '{METADATA_KEY}' metadata field "
                         f"'{at}.sample_rate_hz' (Hz, > 0)", low=1e-9, high=MAX_SAMPLE_RATE_HZ)
        if not isinstance(e["temperature"], bool):
            raise bad(f"{at}.temperature", f"{e['temperature']!r} is not true or false")
        if not isinstance(e["meta"], dict):
            raise bad(f"{at}.meta", "expected a mapping")
        for group in _GROUPS:
            names = e[group]
            if not isinstance(names, list):
                raise bad(f"{at}.{group}", f"expected a list of channel names, got {names!r}")
            for name in names:
                check_name(name, AXIS if group == "outputs" else SIGNAL,
                           f"{path}: '{METADATA_KEY}' metadata field '{at}.{group}'")
        units = e["units"]
        if not isinstance(units, dict):
            raise bad(f"{at}.units", f"expected a mapping channel -> unit, got {units!r}")
        for name, unit in units.items():
            check_name(name, SIGNAL, f"{path}: '{METADATA_KEY}' metadata field '{at}.units'")
            check_name(unit, UNIT, f"{path}: '{METADATA_KEY}' metadata field '{at}.units.{name}'")
    return list(info["runs"])


# ----------------------------------------------------------- text parsing
class _Frame:
    """Cells of one source file, with the 1-based data row (and file line) of each."""

    def __init__(self, *, path: Path, data: pd.DataFrame, rows: np.ndarray,
                 lines: np.ndarray | None, skipped_lines: Sequence[int] = (),
                 numeric_header: Sequence[str] = ()) -> None:
        self.path, self.data, self.rows, self.lines = path, data, rows, lines
        self.skipped_lines = list(skipped_lines)
        # header names that all parse as numbers: most likely a first data row
        self.numeric_header = list(numeric_header)


def _read_text(path: Path, mapping: ColumnMapping | None, sep: str | None) -> _Frame:
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
    return _Frame(path=path, data=data, rows=rows, lines=rows - 1 + first_data,
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
def _native_mapping(path: Path, columns: list, numeric_header: Sequence[str] = ()
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


def _resolve(frame: _Frame, col: str | int, key: str) -> str | int:
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


def _apply_mapping(frame: _Frame, mapping: ColumnMapping) -> tuple[list[Recording], int]:
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
        _check_time(path, _label(t_label), t, rows[sel], None if lines is None else lines[sel])
        chans: dict[str, dict[str, np.ndarray]] = {g: {} for g in _GROUPS}
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


def _id_column(frame: _Frame, column: str | int, key: str, what: str,
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


def _line(frame: _Frame, i: int) -> str:
    return "" if frame.lines is None else f" (file line {int(frame.lines[i])})"


def _check_finite(path: Path, name: str, v: np.ndarray, rows: np.ndarray,
                  lines: np.ndarray | None) -> np.ndarray:
    bad = np.flatnonzero(~np.isfinite(v))
    if bad.size:
        i = int(bad[0])
        where = "" if lines is None else f" (file line {int(lines[i])})"
        raise InputError.at(path, f"non-finite value {float(v[i])!r}{where}", column=name,
                            row=int(rows[i]))
    return v


def _check_time(path: Path, name: str, t: np.ndarray, rows: np.ndarray,
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
