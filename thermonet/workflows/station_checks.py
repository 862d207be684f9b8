"""What a station checks of its units' data before it trusts them (:mod:`thermonet.workflows.
station`): an axis that does not move, one unit's data under two serial numbers, one test
filed twice under one unit, the runs a unit of several runs was calibrated from, and what the
config fixes of every unit's data against the prior (:func:`check_config_channels`).

**A dead or stuck axis** (:func:`dead_axes`).  A live sensor's output has noise: over a
whole thermal test no two of its float samples need be equal, and its extremes are its
rarest values.  An axis is dead or saturated where every sample is the same value (a
sample standard deviation of 0: a disconnected axis reads 0.0, a clipped one its full
scale, e.g. 32.767), or where its output piles up at one extreme: at least
:data:`STUCK_SHARE` (5 %) of its samples equal to the axis's maximum (or minimum), that value
held over consecutive samples, and no value of the axis more frequent (a clipped signal
collects its whole tail at the clip; a noisy signal, even a coarsely quantised one, holds
its extreme less often than the values inside).  Such an axis FAILs its unit whatever its
residual says: a constant fits any curve's points.

**One unit under two serial numbers** (:func:`identical_units`): each unit's outputs (every
axis, its runs in order) hashed as float64 bytes; two units with the same hash and the same
number of samples are refused before any unit is calibrated.  A unit whose every axis is
constant is left to :func:`dead_axes` (two dead units read the same zeros).  **One test
filed twice** (:func:`identical_runs`): two runs of one unit whose outputs are identical.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ConfigError, InputError, counted
from ..core.recording import Dataset, Recording
from ..data.mapping import load_mapping
from ..scoring.prior import FleetPrior
from ..sim.presets import get_preset
from ..training.config import CompareConfig
from .station_prior import axes_mismatch

if TYPE_CHECKING:
    from .fleet_units import UnitSource

__all__ = ["STUCK_SHARE", "dead_axes", "axis_dead", "identical_units", "identical_runs",
           "run_sources", "runs_line", "check_station_config", "check_config_channels"]

#: The share of an axis's samples at its maximum or minimum from which, held over
#: consecutive samples and its most frequent value, the axis is stuck at that extreme.
STUCK_SHARE = 0.05


def _samples(runs: Iterable[Recording], axis: str) -> list[np.ndarray]:
    out = []
    for r in runs:
        if axis in r.outputs:
            x = np.asarray(r.outputs[axis], dtype=np.float64)
            out.append(x[np.isfinite(x)])
    return out


def _longest_run(x: np.ndarray, value: float) -> int:
    """The most consecutive samples of ``x`` equal to ``value``."""
    hit = np.concatenate([[False], x == value, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(hit))
    return int((edges[1::2] - edges[::2]).max()) if edges.size else 0


def axis_dead(parts: Sequence[np.ndarray]) -> str | None:
    """Why an axis's samples (one array per run) are a dead or stuck axis, or None."""
    x = np.concatenate(list(parts)) if parts else np.zeros(0)
    if x.size < 2:
        return None
    lo, hi = float(x.min()), float(x.max())
    if lo == hi:
        return f"constant at {hi:.6g} over the whole test (a dead or saturated axis)"
    values, counts = np.unique(x, return_counts=True)
    top = int(counts.max())
    for value, count, name in ((hi, int(counts[-1]), "maximum"),
                               (lo, int(counts[0]), "minimum")):
        longest = max(_longest_run(p, value) for p in parts)
        if count >= STUCK_SHARE * x.size and count == top and longest >= 2:
            return (f"stuck at {value:.6g}, its {name}, on {count / x.size:.0%} of the "
                    f"samples ({longest} in a row: a saturated or stuck axis)")
    return None


def dead_axes(ds: Dataset, axes: Sequence[str]) -> dict[str, str]:
    """Per axis of ``axes`` that is dead or stuck over the unit's runs, why (:func:`axis_dead`;
    a run reduced to window means is judged on its means)."""
    out = {}
    for a in axes:
        why = axis_dead(_samples(ds.runs, a))
        if why is not None:
            out[a] = f"{a}: {why}"
    return out


def _digest(runs: Sequence[Recording], axes: Sequence[str]) -> tuple[str, int]:
    h = hashlib.sha256()
    n = 0
    for a in axes:
        h.update(a.encode())
        for r in runs:
            x = np.ascontiguousarray(np.asarray(r.outputs[a], dtype=np.float64))
            h.update(x.tobytes())
            n += x.size if a == axes[0] else 0
    return h.hexdigest(), n


def identical_units(units: Sequence[tuple[str, Dataset]]) -> None:
    """Refuse two units whose outputs are identical sample for sample (module docstring)."""
    seen: dict[tuple[str, int], str] = {}
    for dev, ds in units:
        axes = sorted(set.intersection(*(set(r.outputs) for r in ds.runs))) if ds.runs else []
        if not axes or len(dead_axes(ds, axes)) == len(axes):
            continue
        key = _digest(ds.runs, axes)
        if key in seen:
            raise InputError(f"units '{seen[key]}' and '{dev}' hold identical outputs "
                             f"({', '.join(axes)}: {key[1]} samples each, byte for byte): one "
                             "unit's data filed under two serial numbers? Nothing calibrated")
        seen[key] = dev


def _file_name(source: Any) -> str | None:
    """The name of the file a run was read from, where its ``source`` is one (a thermonet
    Parquet file's runs carry the origin they recorded instead: a simulation, a log)."""
    return Path(source).name if isinstance(source, str) and source and Path(
        source).is_file() else None


def _where(r: Recording) -> str:
    name = _file_name(r.meta.get("source"))
    return f"'{r.run_id}' ({name})" if name else f"'{r.run_id}'"


def identical_runs(dev: str, ds: Dataset) -> None:
    """Refuse two runs of one unit whose outputs are identical (one test filed twice)."""
    seen: dict[tuple[str, int], Recording] = {}
    for r in ds.runs:
        axes = sorted(r.outputs)
        key = _digest([r], axes)
        if key in seen and len(dead_axes(Dataset(runs=[r]), axes)) < len(axes):
            raise InputError(f"unit '{dev}': runs {_where(seen[key])} and {_where(r)} hold "
                             f"identical outputs ({key[1]} samples, byte for byte): one test "
                             "filed twice? Nothing calibrated")
        seen.setdefault(key, r)


def run_sources(ds: Dataset) -> list[dict[str, Any]]:
    """A unit's runs as results.json records them: id and where each came from (the file it
    was read from, or the origin a thermonet file recorded)."""
    return [{"run_id": r.run_id, "source": r.meta.get("source")} for r in ds.runs]


def runs_line(dev: str, runs: Sequence[dict[str, Any]]) -> str | None:
    """The console line of a unit built from several runs, e.g. "unit 1001: 2 runs (line
    from line.csv, retest from retest.csv): calibrated from both"; None for one run."""
    if len(runs) < 2:
        return None
    named = [str(r["run_id"]) + (f" from {name}" if (name := _file_name(r.get("source")))
                                 else "") for r in runs]
    every = "both" if len(runs) == 2 else f"all {len(runs)}"
    return f"unit {dev}: {counted(len(runs), 'run')} ({', '.join(named)}): calibrated from {every}"


def check_station_config(cfg: CompareConfig) -> None:
    """A station config's keys the station would not read: top-level ``limits`` (the fleet
    command's; a station's are ``station.limits``)."""
    where = getattr(cfg, "_source", "config")
    if cfg.limits:
        raise ConfigError(f"{where}: key 'limits': the station's limits go under "
                          "'station.limits' (top-level 'limits' are `thermonet fleet`'s, "
                          "which the station does not read)")


def _config_channels(cfg: CompareConfig, sources: Sequence[UnitSource]
                     ) -> tuple[str, dict[str, str]] | None:
    """The output channels, with their units of measure, that the config fixes for every
    unit, and the key that does (``key 'data.preset' ('consumer-imu')``): the preset its
    units are simulated from, or the mapping its files are read with; None where the
    units' own files say (a thermonet file records its channels and units)."""
    sims = [s.sim for s in sources if s.sim is not None]
    preset = (str(sims[0]["preset"]) if sims and len(sims) == len(sources) else
              cfg.data.preset if not cfg.data.paths else None)
    if preset:
        return (f"key 'data.preset' ('{preset}')",
                {ax.name: ax.unit for ax in get_preset(preset).axes})
    m = cfg.data.mapping
    if cfg.data.paths and isinstance(m, str) and Path(m).is_file():
        return (f"key 'data.mapping' ({m})",
                {ch.name: ch.unit for ch in load_mapping(m).channels if ch.role == "output"})
    return None


def check_config_channels(cfg: CompareConfig, fp: FleetPrior, sources: Sequence[UnitSource],
                          prior_name: str) -> None:
    """Refuse, before any unit runs, a config that gives every unit other axes than the
    prior's (``data.outputs``, else the preset's or the mapping's output channels) or
    another unit of measure on one (the preset's, the mapping's): one line naming the key,
    both values and the prior.  What a unit's own file says is checked in its task, and
    fails that unit alone (:func:`~thermonet.workflows.station_prior.check_compatible`)."""
    where = getattr(cfg, "_source", "config")
    fixed = _config_channels(cfg, sources)
    if cfg.data.outputs:
        key, axes = f"key 'data.outputs' ({', '.join(cfg.data.outputs)})", list(cfg.data.outputs)
    elif fixed is not None:
        key, axes = fixed[0], list(fixed[1])
    else:
        return
    why = axes_mismatch(fp, axes, prior_name)
    if why is not None:
        raise ConfigError(f"{where}: {key}: {why}")
    if fixed is None:
        return
    key, uom = fixed
    for a in fp.axis_names:
        if a in uom and uom[a] != fp.units.get(a):
            raise ConfigError(f"{where}: {key}: {a} in '{uom[a]}', and the prior ({prior_name}) "
                              f"has {a} in '{fp.units.get(a)}' (convert one of them first: the "
                              "channel's scale, or the prior's data)")
