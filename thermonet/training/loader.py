"""The one place that decides how recordings are read: whole, or streamed and reduced.

Recording files of more than ``data.in_memory_samples`` samples (counted cheaply:
:func:`thermonet.data.chunks.count_samples`) are streamed ``data.chunk_rows`` rows at a
time and each run reduced to window means (:func:`thermonet.features.windows.reduce_parquet`)
— any tabular file: thermonet or plain Parquet, CSV, TSV, with or without a column mapping.
Flight-controller logs and simulations are held whole.  ``compare``
(:func:`load_compare_data`), ``fleet`` (:func:`load_unit_file`, each unit's own file in its
worker) and the API (:func:`read_recordings`) ask here.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..core.errors import ConfigError
from ..core.fileio import not_a_file
from ..core.recording import Dataset
from ..data.mapping import load_mapping
from .config import CompareConfig, train_config_of
from .parts import check_loaded, load_data

__all__ = ["stream_samples", "load_compare_data", "load_fleet_data", "streamed_data",
           "load_unit_file", "read_recordings", "check_mapping_key"]


def _mapping(mapping: Any) -> Any:
    if mapping is None or not isinstance(mapping, (str, os.PathLike)):
        return mapping

    return load_mapping(Path(mapping))


def stream_samples(paths: Sequence[str | Path], mapping: Any, limit: int) -> int | None:
    """The samples of ``paths`` when they are to be streamed (more than ``limit``), else
    None (read them whole: small files, or not tabular files)."""
    from ..data.chunks import count_samples  # lazy: importing it loads pandas, pyarrow

    if not paths:
        return None
    n = count_samples(paths, _mapping(mapping))
    return n if n is not None and n > limit else None


def check_mapping_key(cfg: CompareConfig) -> None:
    """A config's ``data.mapping`` that names no readable file: one line naming the key,
    the path and the directory a relative path was resolved against (before any data is
    read)."""
    m = cfg.data.mapping
    if not isinstance(m, (str, os.PathLike)):
        return
    why = not_a_file(Path(m), "mapping file")
    if why:
        where = "" if Path(m).is_absolute() else (
            f" (a relative path is resolved against the current directory {Path.cwd()}; "
            "give it from there, or absolute)")
        raise ConfigError(f"key 'data.mapping': {m}: {why}{where}")


def load_compare_data(cfg: CompareConfig, source: str = "config") -> Dataset:
    """A comparison's data: read whole, or — more than ``data.in_memory_samples`` samples
    in tabular files — :func:`streamed_data`."""
    check_mapping_key(cfg)
    d = cfg.data
    n = stream_samples(d.paths, d.mapping, d.in_memory_samples)
    if n is None:
        return load_data(d, source=source)
    return check_loaded(streamed_data(cfg, d.paths, source, samples=n), d, source)


def load_fleet_data(cfg: CompareConfig, source: str = "config") -> Dataset:
    """A fleet's recordings when they are not one file per unit: read whole by the driver,
    which splits them into units (each unit's own file streams in its worker instead:
    :func:`load_unit_file`)."""
    check_mapping_key(cfg)
    return load_data(cfg.data, source=source, allow_fleet=True)


def load_unit_file(cfg: CompareConfig | None, path: str) -> Dataset:
    """One fleet unit's own file: streamed as ``compare`` streams it when it holds more
    than ``data.in_memory_samples`` samples, else read whole."""
    from ..data.io import read_dataset  # lazy: importing it loads pandas, pyarrow

    n = stream_samples([path], None, cfg.data.in_memory_samples) if cfg is not None else None
    if cfg is None or n is None:
        return read_dataset(path)
    return streamed_data(cfg, [path], path, samples=n, mapping=None)


def streamed_data(cfg: CompareConfig, paths: Sequence[str], source: str = "config", *,
                  samples: int | None = None, mapping: Any = "config") -> Dataset:
    """Recording files streamed in ``data.chunk_rows`` chunks and reduced to window means
    (:func:`thermonet.features.windows.reduce_parquet`): one row per ``train.average_s``
    (the shortest any family averages over), at most ``data.max_rows`` rows over the
    files, the dynamic inputs every family reads computed on the samples.  ``mapping``:
    the config's ``data.mapping`` unless given."""
    from ..data.io import check_run_ids  # lazy: importing it loads pandas, pyarrow
    from ..features.windows import reduce_parquet  # lazy: importing it loads pandas, pyarrow

    d = cfg.data
    # (model 'sensor' never comes here: compare fits it on its own path, reading the
    # samples, and fleet refuses it)
    if cfg.target == "four-position":
        raise ConfigError(f"{source}: key 'data.in_memory_samples': the data holds "
                          f"{samples if samples is not None else 'more'} samples (over "
                          f"{d.in_memory_samples}), and the four-position target is fitted on "
                          "the samples only, not on a recording streamed as window means; "
                          "raise 'data.in_memory_samples' if it fits in memory")
    avg = [train_config_of(cfg, fam).average_s for fam in cfg.families]
    window = min((a for a in avg if a > 0), default=1.0)
    inputs = sorted({i for fam in cfg.families for i in fam.inputs}
                    | ({"rate"} if any(f.train_on == "heating" for f in cfg.families) else set()))
    mapping = _mapping(d.mapping if mapping == "config" else mapping)
    runs = []
    per_file = max(d.max_rows // len(paths), 1000)
    for path in paths:
        runs += reduce_parquet(path, window_s=window, inputs=inputs, gap_s=cfg.features.gap_s,
                               chunk_rows=d.chunk_rows, max_rows=per_file,
                               mapping=mapping).runs
    check_run_ids([(r.device_id, r.run_id, r.meta.get("source", "")) for r in runs])
    return Dataset(runs, meta={"source": ", ".join(map(str, paths))}).validate(source)


def read_recordings(paths: Sequence[str | os.PathLike[str]], mapping: Any = None, *,
                    window_s: float | None = None, inputs: Sequence[str] = (),
                    gap_s: str | float = "auto", chunk_rows: int = 65_536) -> Dataset:
    """The API's read: whole (``window_s`` None), or each file streamed ``chunk_rows`` rows
    at a time and each run reduced to ``window_s`` window means."""
    from ..data.io import check_run_ids, read_datasets  # lazy: importing it loads pandas, pyarrow

    mapping = _mapping(mapping)
    if window_s is None:
        return read_datasets([Path(p) for p in paths], mapping=mapping)
    from ..features.windows import reduce_parquet  # lazy: importing it loads pandas, pyarrow

    runs = [r for p in paths for r in reduce_parquet(
        Path(p), window_s=window_s, inputs=list(inputs), gap_s=gap_s,
        chunk_rows=chunk_rows, mapping=mapping).runs]
    check_run_ids([(r.device_id, r.run_id, r.meta.get("source", "")) for r in runs])
    return Dataset(runs).validate()
