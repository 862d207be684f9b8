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
trip is lossless.  Every data page carries a CRC-32 (:data:`WRITE_OPTIONS`), verified on
every read (:data:`READ_OPTIONS`), and the key-value metadata ``thermonet.digest`` the
SHA-256 of each float column (:class:`Digest`), checked by both readers (whole and
streamed, :mod:`thermonet.data.chunks`) once the values passed their own checks.

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

import dataclasses
import json
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ..core.errors import InputError
from ..core.fileio import atomic_path, not_a_file
from ..core.recording import DEFAULT_DEVICE, Dataset, Recording
from .logs import is_log_source, read_log_instance
from .mapping import ColumnMapping, default_unit, load_mapping, unit_factor
from .parquet_format import (
    DIGEST_KEY,
    FORMAT_VERSION,
    METADATA_KEY,
    READ_OPTIONS,
    WRITE_OPTIONS,
    Digest,
    parse_blob,
    stored_digest,
    str_dict,
)
from .tables import GROUPS, apply_mapping, native_mapping
from .text import Frame, read_text
from .values import check_finite, check_time, float_values

__all__ = ["write_parquet", "write_csv", "in_default_units", "read_dataset", "read_datasets", "check_run_ids",
           "file_format", "check_output_file", "PARQUET_SUFFIXES"]


_PARQUET = (".parquet", ".pq")


_TEXT = (".csv", ".tsv", ".txt")


# ----------------------------------------------------------------- writing
#: What a thermonet recording file's name ends in.
PARQUET_SUFFIXES = (".parquet", ".pq")


def check_output_file(path: str | Path, suffixes: tuple[str, ...]) -> Path:
    """A recording file about to be written: its suffix one of ``suffixes``, not a directory,
    its directory existing (one line naming the path otherwise)."""
    path = Path(path)
    kind = "a thermonet recording file" if suffixes == PARQUET_SUFFIXES else \
        f"a {suffixes[0][1:].upper()} recording file"
    ends = " (or ".join(suffixes) + ")" * (len(suffixes) - 1)
    if path.suffix.lower() not in suffixes:
        raise InputError.at(path, f"{kind} ends in {ends}")
    if path.is_dir():
        raise InputError.at(path, f"is a directory; give a {suffixes[0]} file name")
    if not path.parent.is_dir():
        raise InputError.at(path, f"output directory '{path.parent}' does not exist")
    return path


def write_parquet(dataset: Dataset, path: str | Path) -> Path:
    """Write ``dataset`` to ``path`` atomically; return the path.

    The table is written to a temporary file in the same directory and moved
    over ``path`` with :func:`os.replace`, so a failed write leaves nothing new
    at ``path`` (and an existing file there untouched).
    """
    path = check_output_file(path, PARQUET_SUFFIXES)
    for run in dataset:
        run.validate()
    table = _to_table(dataset)
    digest = Digest()
    for name in table.column_names:
        if pa.types.is_floating(table.schema.field(name).type):
            digest.add(name, table.column(name))
    with atomic_path(path, make_parents=False) as tmp:
        with pq.ParquetWriter(tmp, table.schema, **WRITE_OPTIONS) as writer:
            writer.write_table(table)
            writer.add_key_value_metadata({DIGEST_KEY: digest.text()})
    return path


def write_csv(dataset: Dataset, path: str | Path) -> Path:
    """Write ``dataset`` to ``path`` as comma-separated text with thermonet's conventional
    column names (``run``, ``time_s``, ``temperature_c``, the outputs …; an absent value is an
    empty cell), atomically; return the path.  It reads back without a mapping, and it is the
    input ``export/thermonet_runtime.py`` takes (each run's rows one sequence: the runtime
    restarts a model's dynamic state at each run).  The device id is a ``device`` column
    (read back by the reader); a channel in a unit other than its default is named in a
    warning (:func:`_warn_other_units`: a CSV carries no units)."""
    import pyarrow.csv as pacsv

    path = check_output_file(path, (".csv",))
    for run in dataset:
        run.validate()
    _warn_other_units(dataset, path)
    table = _to_table(dataset).replace_schema_metadata(None)
    if "device" not in table.column_names and any(r.device_id != DEFAULT_DEVICE
                                                  for r in dataset):
        # the device id read back (the reader's 'device' column): not lost to the default
        table = table.add_column(1, "device", pa.array(
            np.concatenate([[r.device_id] * r.n_samples for r in dataset]), pa.string()))
    with atomic_path(path, make_parents=False) as tmp:
        # plain cells (channel names are letters, digits and '_'); a run id is quoted only
        # where it needs it (a comma, a quote)
        try:
            body = pacsv.WriteOptions(include_header=False, quoting_style="none")
            with open(tmp, "wb") as fh:
                fh.write((",".join(table.column_names) + "\n").encode())
                pacsv.write_csv(table, fh, body)
        except pa.ArrowInvalid:
            pacsv.write_csv(table, tmp)
    return path


def in_default_units(dataset: Dataset, path: str | Path) -> tuple[Dataset, list[str]]:
    """``dataset`` with every channel in its default unit (:func:`default_unit`, what a CSV
    is read back in: a CSV carries no units) for ``thermonet convert --out x.csv``, and
    ``<channel> <unit> -> <default>`` for each channel converted (the factors of
    :data:`~thermonet.data.mapping.UNIT_IN_DEFAULT`).

    Raises
    ------
    InputError
        A channel in a unit with no known conversion to its default (raw counts as a
        gyro, a proxy in volts), named with the advice to write Parquet, which keeps units.
    """
    said: dict[str, str] = {}
    runs = []
    for r in dataset:
        units = dict(r.units)
        groups: dict[str, Any] = {g: dict(getattr(r, g)) for g in GROUPS}
        for g, chans in groups.items():
            for name, values in chans.items():
                unit, want = r.units.get(name), default_unit(name, proxy=g == "proxies")
                if not unit or unit == want:
                    continue
                factor = unit_factor(unit, want)
                if factor is None:
                    raise InputError.at(path, f"{name} is in '{unit}', which has no "
                                        f"conversion to '{want}', the unit a CSV (it carries "
                                        "none) is read back in: write a .parquet file "
                                        "instead (it keeps the units)", column=name)
                chans[name] = np.asarray(values, dtype=np.float64) * factor
                units[name] = want
                said.setdefault(name, f"{name} {unit} -> {want}")
        runs.append(dataclasses.replace(r, **groups, units=units))
    return Dataset(runs=runs, meta=dict(dataset.meta)), list(said.values())


def _warn_other_units(dataset: Dataset, path: Path) -> None:
    """A CSV carries no units: thermonet reads every conventional column back in its default
    unit (:func:`~thermonet.data.mapping.default_unit`), so the channels in another (rad/s
    read back as deg/s: 57x off) are named in one warning with how to read them back.  The
    file is still written: the runtime's CSV is in the model's own units, whatever they are."""
    other: dict[str, tuple[str, str]] = {}
    for r in dataset:
        for name in (["temperature_c"] if r.temperature_c is not None else []) + [
                k for g in GROUPS for k in getattr(r, g)]:
            unit = r.units.get(name)
            want = default_unit(name, proxy=name in r.proxies)
            if unit and unit != want:
                other.setdefault(name, (unit, want))
    if other:
        import warnings

        said = ", ".join(f"{n} in {u} (read back as {w})" for n, (u, w) in other.items())
        warnings.warn(f"{path}: a CSV carries no units: {said}; read it with a mapping that "
                      "names the units, or write Parquet (it keeps them)", UserWarning,
                      stacklevel=3)


def _to_table(dataset: Dataset) -> pa.Table:
    runs = list(dataset)
    names: list[str] = []
    for group in GROUPS:
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
            "meta": str_dict(dataset.meta, "dataset meta"), "runs": []}
    for r in runs:
        blob["runs"].append({
            "run_id": r.run_id, "device_id": r.device_id, "sensor_kind": r.sensor_kind,
            "sample_rate_hz": None if r.sample_rate_hz is None else float(r.sample_rate_hz),
            "meta": str_dict(r.meta, f"run '{r.run_id}' meta"),
            "units": str_dict(r.units, f"run '{r.run_id}' units"),
            "temperature": r.temperature_c is not None,
            **{g: list(getattr(r, g)) for g in GROUPS}, "n_samples": r.n_samples})
    table = pa.table(cols)
    return table.replace_schema_metadata(
        {METADATA_KEY: json.dumps(blob, allow_nan=False, ensure_ascii=False)})


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
    unless it has a run column; thermonet Parquet files keep their runs; one sensor
    instance of a flight-controller log (``LOG#gyro0``) is one run whose id is the log's
    stem and the instance (``b_run1:gyro0``:
    :func:`thermonet.data.logs.log_run_id`), so warm-ups of one board in several logs are
    several runs of one unit.
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
    given: list[str | None] = []   # the table each run was read from (a message names it)
    meta: dict[str, str] = {}
    skipped: int | None = None
    for p in paths:
        file_runs, file_meta, n_skipped = _read_one(Path(p), mapping)
        runs += file_runs
        given += [None if is_log_source(p) else str(p)] * len(file_runs)
        for k, v in file_meta.items():
            meta.setdefault(k, v)
        if n_skipped is not None:
            skipped = (skipped or 0) + n_skipped
    if skipped is not None:
        meta["skipped_rows"] = str(skipped)
    check_run_ids([(r.device_id, r.run_id, g or r.meta.get("source", ""))
                   for r, g in zip(runs, given, strict=True)])
    source = str(paths[0]) if len(paths) == 1 else ""
    if not validate:
        if not runs:
            raise InputError.at(source, "no runs")
        return Dataset(runs=runs, meta=meta)
    # a thermonet file's runs keep the origin it recorded ('source'); a message names the
    # file given, so it stands in while the runs are checked
    kept: list[str | None] = [r.meta.get("source") for r in runs]
    for r, g in zip(runs, given, strict=True):
        if g is not None:
            r.meta["source"] = g
    try:
        return Dataset(runs=runs, meta=meta).validate(source)
    finally:
        for r, was in zip(runs, kept, strict=True):
            if was is None:
                r.meta.pop("source", None)
            else:
                r.meta["source"] = was


def check_run_ids(ids: Sequence[tuple[str, str, str]]) -> None:
    """(device id, run id, source file) of every run read: a unit's run ids are unique."""
    seen: dict[tuple[str, str], str] = {}
    several = len({d for d, _, _ in ids}) > 1
    for device_id, run_id, source in ids:
        key = (device_id, run_id)
        if key in seen:
            unit = f" of unit '{device_id}'" if several else ""
            fix = ("a log's run id is its file name and instance: rename one of the logs"
                   if is_log_source(source) else "a file's run id is the mapping's "
                   "run_id where it sets one, else the file name without its extension: "
                   "rename or copy one file under another name, leave run_id out of a "
                   "mapping that reads several files, or map a run_column")
            raise InputError.at(source, f"run id '{run_id}'{unit} already "
                                f"used by {seen[key]} (a unit's run ids must be unique; {fix})")
        seen[key] = source


def _read_one(path: Path, mapping: ColumnMapping | None
              ) -> tuple[list[Recording], dict[str, str], int | None]:
    if is_log_source(path):
        if mapping is not None:
            raise InputError.at(path, "a flight-controller log is read with no mapping")
        ds = read_log_instance(path)
        return list(ds.runs), dict(ds.meta), None
    why = not_a_file(path)
    if why:
        raise InputError.at(path, why)
    fmt = file_format(path, mapping)
    if fmt == "parquet":
        table = _read_parquet_table(path)
        blob = (table.schema.metadata or {}).get(METADATA_KEY.encode())
        if blob is not None and mapping is None:
            runs, meta = _from_thermonet_table(path, table, blob)
            try:
                stored = stored_digest(path, pq.read_metadata(path).metadata)
            except (pa.ArrowException, OSError) as err:
                raise InputError.at(path, f"not a readable Parquet file ({err})") from err
            if stored:
                digest = Digest()
                for name in table.column_names:
                    if name in stored:
                        digest.add(name, table.column(name))
                digest.check(path, stored)
            return runs, meta, None
        frame = Frame(path=path, data=table.to_pandas(),
                       rows=np.arange(1, table.num_rows + 1), lines=None)
    else:
        frame = read_text(path, mapping, sep="\t" if fmt == "tsv" else None)
    if mapping is None:
        mapping = native_mapping(path, list(frame.data.columns), frame.numeric_header)
    runs, n_skipped = apply_mapping(frame, mapping)
    return runs, {}, (n_skipped if mapping.malformed_rows == "skip" else None)


def file_format(path: Path, mapping: ColumnMapping | None) -> str:
    """``parquet``, ``csv`` or ``tsv``: the mapping's ``format``, else by the extension."""
    fmt = mapping.format if mapping is not None else "auto"
    ext = path.suffix.lower()
    if fmt == "auto":
        fmt = "parquet" if ext in _PARQUET else "tsv" if ext == ".tsv" else \
            "csv" if ext in _TEXT or mapping is not None else ""
    if not fmt:
        raise InputError.at(path, f"unknown file type '{ext}' (thermonet reads .parquet, "
                            ".csv, .tsv, .txt, and .ulg / .bin flight-controller logs; for other "
                            "files give a mapping with 'format')")
    return fmt


def _read_parquet_table(path: Path) -> pa.Table:
    try:
        table = pq.read_table(path, **READ_OPTIONS)
    except (pa.ArrowException, OSError) as err:
        raise InputError.at(path, f"not a readable Parquet file ({err})") from err
    dup = [n for n, c in Counter(table.column_names).items() if c > 1]
    if dup:
        raise InputError.at(path, "duplicate column", column=dup[0])
    return table


def _from_thermonet_table(path: Path, table: pa.Table, blob: bytes
                          ) -> tuple[list[Recording], dict[str, str]]:
    info, entries = parse_blob(path, blob)
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
            values = float_values(path, name, table.column(name).take(idx), rows)
            return check_finite(path, name, values, rows, None)

        time_s = take("time_s")
        check_time(path, "time_s", time_s, rows, None)
        groups: dict[str, Any] = {g: {k: take(k) for k in e[g]} for g in GROUPS}
        runs.append(Recording(
            time_s=time_s, temperature_c=take("temperature_c") if e["temperature"] else None,
            **groups, units=dict(e["units"]), device_id=e["device_id"],
            sensor_kind=e["sensor_kind"], run_id=e["run_id"],
            sample_rate_hz=e["sample_rate_hz"], meta=dict(e["meta"])))
    return runs, dict(info.get("meta", {}))
