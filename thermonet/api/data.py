"""What the API takes: runs (one, a list or a Dataset), the checks on them that name the
argument in one line, and :func:`simulate` / :func:`read` to make them (see :mod:`thermonet.api`)."""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, InputError, ThermonetError
from ..core.recording import KNOWN_UNITS, TEMPERATURE, Dataset, Recording
from ..sim import simulate as _simulate
from ..sim.presets import MAX_RUNS
from .checks import gap, input_names, path, seconds, text, whole
from .checks import paths as path_list

__all__ = ["Data", "BLOCK_RUN", "BLOCK_INDEX", "runs_of", "data_source", "has_samples", "names_of",
           "needs_outputs", "same_units", "known_units", "same_run", "simulate", "read"]

#: ``meta`` key naming the run a time block was cut from (:func:`thermonet.api.time_blocks`).
BLOCK_RUN = "block_of_run"
#: ``meta`` key of a time block's index in its run (:data:`BLOCK_RUN` names the run).
BLOCK_INDEX = "block_index"

#: What ``fit``, ``predict``, ``score`` and ``compensate`` take: one run, a list of runs or a
#: Dataset (each run's dynamic inputs computed on that run alone).
Data = Dataset | Recording | Sequence[Recording]


def runs_of(data: Any, what: str, *, allow_empty: bool = False) -> list[Recording]:
    """The runs of ``data``: each a :class:`Recording` (with samples unless ``allow_empty``),
    else one ValueError line naming the argument."""
    expected = "expected a Dataset, a Recording or a list of Recordings"
    if isinstance(data, Recording):
        runs = [data]
    elif isinstance(data, (str, bytes, os.PathLike)) or not isinstance(data, Iterable) \
            or isinstance(data, dict):
        hint = " (read files with thermonet.read(paths, mapping))" \
            if isinstance(data, (str, bytes, os.PathLike)) else ""
        raise ThermonetError(f"{what}: {expected}, got {type(data).__name__}{hint}")
    else:
        runs = list(data)
    if not runs:
        raise ThermonetError(f"{what}: no recordings (an empty {type(data).__name__}); "
                             "give at least one run")
    for i, r in enumerate(runs):
        if not isinstance(r, Recording):
            raise ThermonetError(f"{what}: {expected}; item {i} is a {type(r).__name__}")
        if not allow_empty:
            has_samples(r, what)
        known_units(r, what)
    return runs


def known_units(rec: Recording, what: str) -> None:
    """Every unit ``rec`` states is one thermonet knows (fit's rule,
    :meth:`~thermonet.core.recording.Recording.validate`, the same line), and its temperature
    is in degC: a temperature in K or degF would be clamped to the trained range unseen.
    :func:`runs_of` applies it to what fit, predict, score and compensate take."""
    source = f"{what}, run '{rec.run_id}'"
    for name, unit in rec.units.items():
        if unit not in KNOWN_UNITS:
            raise InputError.at(source, f"unknown unit '{unit}' (known: "
                                f"{', '.join(sorted(KNOWN_UNITS))})", column=name)
    unit = rec.units.get(TEMPERATURE, "")
    if unit and KNOWN_UNITS[unit] != "temperature":
        raise InputError.at(source, f"temperature in '{unit}', expected degC (convert it with "
                            "a mapping scale and offset)", column=TEMPERATURE)


def data_source(runs: list[Recording], val: list[Recording] | None) -> dict[str, Any]:
    """What a fit was given (a checkpoint's ``extra.provenance.data``): the runs, where they
    came from (the files read, or the simulator) and the digest of their samples."""
    from ..training.parts import data_hash  # lazy: importing it loads yaml

    every = runs + list(val or [])
    return {"kind": "dataset", "device": runs[0].device_id,
            "runs": [r.run_id for r in runs], "val": [r.run_id for r in val or []],
            "sources": sorted({r.meta.get("source", "") for r in every} - {""})[:20],
            "preset": runs[0].meta.get("preset") or None,
            "data_hash": data_hash(Dataset(every))}


def has_samples(rec: Recording, what: str) -> Recording:
    if rec.n_samples == 0:
        raise ThermonetError(f"{what}: run '{rec.run_id}' has no samples")
    return rec


def names_of(value: Any, what: str) -> list[str] | None:
    """``inputs``/``outputs`` as a list of names: None stays None, one name is a list of one."""
    if value is None:
        return None
    if isinstance(value, str):
        return [value]
    if isinstance(value, Iterable) and not isinstance(value, (bytes, dict)):
        names = list(value)
        bad = [v for v in names if not isinstance(v, str)]
        if not bad and names:
            return names
        if not names:
            raise ConfigError(f"{what}: an empty list; name at least one, or leave it None")
        raise ConfigError(f"{what}: expected names (strings), got {bad[0]!r} "
                          f"({type(bad[0]).__name__}) in {names!r}")
    raise ConfigError(f"{what}: expected a name or a list of names, got {value!r}")


def needs_outputs(rec: Recording, outputs: Sequence[str], what: str) -> None:
    """Every output channel the model needs (``gyro_x`` for ``gyro_x.bias`` too) is in ``rec``."""
    needed = list(dict.fromkeys(o.split(".")[0] for o in outputs))
    missing = [a for a in needed if a not in rec.outputs]
    if missing:
        raise ThermonetError(f"{what}: run '{rec.run_id}' has no output channel '{missing[0]}' "
                             f"(the model needs {', '.join(needed)}; the run has "
                             f"{', '.join(rec.outputs) or 'none'})")


def same_units(rec: Recording, units: dict[str, str], what: str, trained: str) -> None:
    """Each channel of ``units`` that ``rec`` carries is in the same unit (where both say)."""
    for name, unit in units.items():
        channel = name.split(".")[0]
        if name.endswith(".scale"):
            continue
        theirs = rec.units.get(channel, "")
        if unit and theirs and theirs != unit and channel in {**rec.outputs, **rec.proxies}:
            raise ThermonetError(f"{what}: run '{rec.run_id}' has {channel} in '{theirs}', "
                                 f"{trained} in '{unit}' (convert one with a mapping scale)")


def same_run(a: Recording, b: Recording) -> bool:
    """Whether two recordings are one run (the same object, or the same id and samples)."""
    if a is b:
        return True
    if a.run_id != b.run_id or a.n_samples != b.n_samples:
        return False
    return bool(np.array_equal(a.time_s, b.time_s))


def simulate(preset: str, runs: int | None = None, seed: int = 0) -> Dataset:
    """A simulated chamber test from a study preset (``patent-gyro``, ``consumer-imu``...).

    Same preset, runs and seed give identical data.  ``preset`` is a preset's name,
    ``runs`` a whole number from 1 (None: the preset's own number), ``seed`` a whole number
    >= 0; anything else is refused before anything is simulated
    (:mod:`thermonet.api.checks`).
    """
    text(preset, "simulate(preset)", rule="a preset name such as 'patent-gyro'")
    whole(runs, "simulate(runs)", 1, MAX_RUNS, none=True)
    whole(seed, "simulate(seed)", 0)
    return _simulate(preset, runs=None if runs is None else int(runs), seed=int(seed))


def read(paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
         mapping: str | os.PathLike[str] | None = None, *, window_s: float | None = None,
         inputs: Sequence[str] | str = (), gap_s: str | float = "auto",
         chunk_rows: int = 65_536) -> Dataset:
    """Recordings from CSV/TSV/Parquet files (one run per file unless a ``run`` column),
    through a YAML column mapping when the columns are not thermonet's own.

    With ``window_s``, each file (any of them, through the mapping) is
    streamed ``chunk_rows`` rows at a time and each run reduced to ``window_s`` window means
    (:mod:`thermonet.features.windows`, what ``compare`` does with a recording larger than
    memory); ``inputs`` names the dynamic inputs to compute on the samples (those the
    estimator will read, e.g. ``["dT", "rate"]``) and ``gap_s`` their gap limit.  An
    estimator fits, predicts and scores such runs as runs of samples (the scores over the
    samples the rows stand for).

    Every argument is checked before a file is opened (:mod:`thermonet.api.checks`):
    ``paths`` a path or a non-empty list of paths; ``mapping`` a path or None;
    ``window_s`` None or a number of seconds > 0 (``True`` is no number); ``inputs`` known
    input names, one alone as a string, and only with ``window_s``; ``gap_s`` ``"auto"`` or
    seconds; ``chunk_rows`` a whole number >= 1.
    """
    from ..training.loader import read_recordings  # lazy: importing it loads yaml

    files = path_list(paths, "read(paths)")
    path(mapping, "read(mapping)", none=True)
    seconds(window_s, "read(window_s)", none=True)
    names = input_names(inputs, "read(inputs)", empty=True)
    gap(gap_s, "read(gap_s)")
    whole(chunk_rows, "read(chunk_rows)", 1)
    if window_s is None and names:
        raise ConfigError("read(inputs): the dynamic inputs are computed while streaming; "
                          "give window_s too, or leave inputs out (an estimator computes "
                          "its inputs from the samples)")
    return read_recordings(list(files), None if mapping is None else Path(mapping),
                           window_s=None if window_s is None else float(window_s),
                           inputs=names, gap_s=gap_s, chunk_rows=int(chunk_rows))
