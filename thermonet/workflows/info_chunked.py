"""``thermonet info`` on recordings larger than memory: the summary in one chunked pass.

:func:`summarize_parquet` returns what :func:`thermonet.workflows.info.summarize` returns
for the same files, without holding them: the runs, channels and units come from a
thermonet file's footer, or from a first pass over any other file
(:func:`thermonet.data.chunks.open_source`), and one pass over the rows
(:func:`~thermonet.data.chunks.iter_run_chunks`, at most ``chunk_rows`` rows at a
time) accumulates per run and channel:

* count, first and last time (duration), temperature and proxy minimum and maximum, the
  largest |value| of every channel (the plausibility warnings,
  :func:`thermonet.data.diagnostics.run_warnings`);
* the noise floor's first differences, the last sample carried across chunk edges, merged
  chunk by chunk with Chan et al.'s pairwise update of (count, mean, M2) — the variance
  of all differences, as ``np.std`` computes it in one piece, to float64 rounding;
* the drift's per-bin sums and counts (bins of ``bin_c`` °C over all runs), whose ratio is
  :func:`thermonet.scoring.metrics.binned_means`;
* the sample intervals for the median rate — only for a run without a stored
  ``sample_rate_hz``: every interval when the run has at most ``chunk_rows`` of them,
  else every k-th one (k = ⌈intervals / chunk_rows⌉, a fixed stride known from the
  run's stored sample count), whose median stands for the whole run's (documented
  approximation; memory stays within the chunk budget).

Checked while reading: every value finite, time strictly increasing within each run
(across chunk edges too), each run's sample count equal to the one its metadata
states and at least :data:`thermonet.core.recording.MIN_SAMPLES`.  Then the checks of a
whole :class:`~thermonet.core.recording.Dataset` (``Dataset.validate``: channels and
units of every run, references and drift matching outputs, the same channels in every
run, the temperature span) run on a skeleton of each run — its channels, units and
metadata with ``MIN_SAMPLES`` placeholder samples whose temperature spans the run's own
minimum to maximum — so a file the whole-file reader refuses is refused here with the
same line.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError
from ..core.recording import MIN_SAMPLES, MIN_TEMPERATURE_SPAN_C
from ..data.chunk_base import Layout
from ..data.chunks import (
    DEFAULT_CHUNK_ROWS,
    iter_run_chunks,
    open_parquet,
    open_source,
    validate_layouts,
)
from ..data.diagnostics import run_warnings
from ..data.io import check_run_ids
from ..data.mapping import ColumnMapping, channel_role

__all__ = ["summarize_parquet", "open_parquet", "open_source", "DEFAULT_CHUNK_ROWS"]


class _Moments:
    """Count, mean and M2 of a stream of numbers, merged piece by piece (Chan et al. 1979)."""

    __slots__ = ("n", "mean", "m2")

    def __init__(self) -> None:
        self.n, self.mean, self.m2 = 0, 0.0, 0.0

    def add(self, x: np.ndarray) -> None:
        if x.size == 0:
            return
        nb, mb = x.size, float(np.mean(x))
        m2b = float(np.sum((x - mb) ** 2))
        n = self.n + nb
        delta = mb - self.mean
        self.mean += delta * nb / n
        self.m2 += m2b + delta * delta * self.n * nb / n
        self.n = n

    def std(self) -> float:
        return math.sqrt(self.m2 / self.n) if self.n else math.nan


class _Run:
    """What one run's pass accumulates."""

    def __init__(self, entry: dict[str, Any], cap: int) -> None:
        self.entry = entry
        self.n = 0
        self.t0 = self.t1 = math.nan
        self.lo: dict[str, float] = {}
        self.hi: dict[str, float] = {}
        self.peak: dict[str, float] = {}
        self.last: dict[str, float] = {}
        self.noise: dict[str, _Moments] = {o: _Moments() for o in entry["outputs"]}
        n_int = max(int(entry.get("n_samples") or 0) - 1, 1)
        self.stride = -(-n_int // cap) if entry["sample_rate_hz"] is None else 0
        self.intervals: list[np.ndarray] = []

    def add(self, piece: dict[str, np.ndarray]) -> None:
        t = piece["time_s"]
        first = self.n
        if self.stride:
            prev = [] if first == 0 else [self.t1]
            dt = np.diff(np.concatenate([prev, t]))
            k0 = first - 1 if first else 0        # index of dt[0] among the run's intervals
            self.intervals.append(dt[(-k0) % self.stride::self.stride])
        if first == 0:
            self.t0 = float(t[0])
        self.t1 = float(t[-1])
        self.n += t.size
        for name, v in piece.items():
            if name == "time_s":
                continue
            self.lo[name] = min(self.lo.get(name, math.inf), float(v.min()))
            self.hi[name] = max(self.hi.get(name, -math.inf), float(v.max()))
            self.peak[name] = max(self.peak.get(name, 0.0), float(np.max(np.abs(v))))
        for o, mom in self.noise.items():
            ref = f"ref_{o}"
            y = piece[o] - piece[ref] if ref in self.entry["references"] else piece[o]
            mom.add(np.diff(y if first == 0 else np.concatenate([[self.last[o]], y])))
            self.last[o] = float(y[-1])

    def rate_hz(self) -> float:
        if self.entry["sample_rate_hz"]:
            return float(self.entry["sample_rate_hz"])
        return float(1.0 / np.median(np.concatenate(self.intervals)))


@np.errstate(over="ignore", invalid="ignore")  # absurd values: warned about, not a traceback
def summarize_parquet(path: str | Path | Layout | Sequence[Layout], *, bin_c: float = 1.0,
                      chunk_rows: int = DEFAULT_CHUNK_ROWS,
                      mapping: ColumnMapping | None = None) -> dict[str, Any]:
    """:func:`thermonet.workflows.info.summarize` of recording files, read in chunks: a
    path (through ``mapping``), a layout (:func:`thermonet.data.chunks.open_source`) or
    the layouts of several files.

    Raises
    ------
    InputError
        A bad value (named by file, column and row), as the whole-file reader names it.
    """
    if isinstance(path, Layout):
        layouts = [path]
    elif isinstance(path, (str, Path)):
        layouts = [open_source(path, mapping, chunk_rows=chunk_rows)]
    else:
        layouts = list(path)
    return _summarize(layouts, bin_c=bin_c, chunk_rows=chunk_rows)


def _summarize(layouts: list[Layout], *, bin_c: float, chunk_rows: int) -> dict[str, Any]:
    entries = [e for lay in layouts for e in lay.runs]
    check_run_ids([(e["device_id"], e["run_id"], str(lay.path)) for lay in layouts
                   for e in lay.runs])
    has_temp = any(e["temperature"] for e in entries)
    names: list[str] = []
    units: dict[str, str] = {}
    for e in entries:
        for n in ["time_s"] + (["temperature_c"] if e["temperature"] else []) + [
                x for g in ("outputs", "references", "drift", "proxies") for x in e[g]]:
            if n not in names:
                names.append(n)
                units[n] = e["units"].get(n, "s" if n == "time_s" else "?")
    read = [n for n in names if n == "temperature_c" or any(
        n in e[g] for e in entries for g in ("outputs", "references", "proxies"))]
    runs = [_Run(e, int(chunk_rows)) for e in entries]
    first_out = list(entries[0]["outputs"])
    bins: dict[str, dict[int, list[float]]] = {o: {} for o in first_out}
    pieces = ((base + i, piece) for lay, base in zip(
        layouts, np.cumsum([0] + [len(x.runs) for x in layouts]).tolist(), strict=False)
        for i, _rows, piece in iter_run_chunks(
            lay, [n for n in read if n in lay.columns], chunk_rows=chunk_rows))
    for i, piece in pieces:
        e = entries[i]
        mine = {k: v for k, v in piece.items()
                if k == "time_s" or (k == "temperature_c" and e["temperature"])
                or any(k in e[g] for g in ("outputs", "references", "proxies"))}
        runs[i].add(mine)
        if e["temperature"]:
            _bin_drift(bins, piece, e, bin_c)
    _check_counts(runs, layouts)
    spans = [(r.lo["temperature_c"], r.hi["temperature_c"]) if r.entry["temperature"]
             else None for r in runs]
    validate_layouts(layouts, spans, min_span_c=0.0)   # a span too small is said, not refused
    channels = [{"name": n, "role": "time" if n == "time_s" else
                 ("proxy" if any(n in e["proxies"] for e in entries) else channel_role(n)),
                 "unit": units[n]} for n in names]
    run_rows, warnings = [], []
    for r in runs:
        e = r.entry
        temp = e["temperature"]
        run_rows.append({
            "run_id": e["run_id"], "unit": e["device_id"], "samples": r.n,
            "duration_s": r.t1 - r.t0, "sample_rate_hz": r.rate_hz(),
            "temperature_min_c": r.lo["temperature_c"] if temp else None,
            "temperature_max_c": r.hi["temperature_c"] if temp else None,
            "proxies": {k: [r.lo[k], r.hi[k]] for k in e["proxies"]},
            "skipped_rows": int(e["meta"]["skipped_rows"]) if "skipped_rows" in e["meta"]
            else None,
        })
        span = (r.lo["temperature_c"], r.hi["temperature_c"],
                r.hi["temperature_c"] - r.lo["temperature_c"]) if temp else None
        peaks = {k: r.peak[k] for g in ("outputs", "references", "proxies") for k in e[g]}
        warnings += run_warnings(f"run '{e['run_id']}'", e["meta"], e["units"], span, peaks,
                                 r.t1 - r.t0, r.rate_hz())
    warnings += _span_warning(spans)
    outputs = _output_rows(runs, bins, units, has_temp)
    t_rows = [r for r in run_rows if r["temperature_min_c"] is not None]
    t_range = [min(r["temperature_min_c"] for r in t_rows),
               max(r["temperature_max_c"] for r in t_rows)] if t_rows else None
    skip_counts = [lay.meta["skipped_rows"] for lay in layouts if "skipped_rows" in lay.meta]
    skipped = str(sum(int(c) for c in skip_counts)) if skip_counts else None
    rates = sorted({float(f"{r['sample_rate_hz']:.4g}") for r in run_rows})
    at = f"{rates[0]:g} Hz" if len(rates) == 1 else f"each run's rate ({rates[0]:g} … " \
        f"{rates[-1]:g} Hz)"
    return {"device_id": entries[0]["device_id"], "sensor_kind": entries[0]["sensor_kind"],
            "n_runs": len(entries), "channels": channels, "runs": run_rows,
            "outputs": outputs, "temperature_range_c": t_range, "bin_c": bin_c,
            "skipped_rows": None if skipped is None else int(skipped),
            "noise_floor_basis": f"1 sigma per sample at {at}",
            "warnings": warnings}


def _bin_drift(bins: dict[str, dict[int, list[float]]], piece: dict[str, np.ndarray],
               e: dict[str, Any], bin_c: float) -> None:
    """A chunk's observed drift (output − reference) added to the per-°C-bin sums and counts
    of every output in ``bins``."""
    idx = np.floor(piece["temperature_c"] / bin_c).astype(np.int64)
    keys, inv = np.unique(idx, return_inverse=True)
    counts = np.bincount(inv)
    for o, acc in bins.items():
        y = piece[o] - piece[f"ref_{o}"] if f"ref_{o}" in e["references"] else piece[o]
        sums = np.bincount(inv, weights=y)
        for k, s, c in zip(keys.tolist(), sums.tolist(), counts.tolist(), strict=True):
            cell = acc.setdefault(k, [0.0, 0])
            cell[0] += s
            cell[1] += c


def _check_counts(runs: list[_Run], layouts: list[Layout]) -> None:
    """Every run has enough samples, and as many as its metadata says (named by file)."""
    sources = [str(lay.path) for lay in layouts for _ in lay.runs]
    for r, src in zip(runs, sources, strict=True):
        e = r.entry
        where = f"run '{e['run_id']}'"
        if r.n < MIN_SAMPLES:
            raise InputError.at(src, f"{where}: too few samples: {r.n} (need at least "
                                f"{MIN_SAMPLES})")
        if e.get("n_samples") is not None and int(e["n_samples"]) != r.n:
            raise InputError.at(src, f"{where}: {r.n} rows, its metadata says "
                                f"{e['n_samples']}")


def _output_rows(runs: list[_Run], bins: dict[str, dict[int, list[float]]],
                 units: dict[str, str], has_temp: bool) -> list[dict[str, Any]]:
    """Per output: its noise floor (mean over runs) and binned drift peak-to-peak."""
    outputs = []
    for o, acc in bins.items():
        floors = [r.noise[o].std() / math.sqrt(2.0) for r in runs
                  if o in r.noise and r.noise[o].n >= 2]
        floors = [f for f in floors if math.isfinite(f)]
        pp = None
        if has_temp and acc:
            means = [s / c for s, c in acc.values()]
            pp = _num(max(means) - min(means))
        outputs.append({"name": o, "unit": units.get(o, "?"),
                        "noise_floor": _num(float(np.mean(floors))) if floors else None,
                        "drift_peak_to_peak": pp})
    return outputs


def _num(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _span_warning(spans: list[tuple[float, float] | None]) -> list[str]:
    """The line a temperature span too small for a model gets (``compare`` refuses such
    data: :meth:`~thermonet.core.recording.Dataset.validate`); ``info`` summarises it."""
    got = [s for s in spans if s is not None]
    if not got or len(got) != len(spans):
        return []
    span = max(s[1] for s in got) - min(s[0] for s in got)
    if span >= MIN_TEMPERATURE_SPAN_C:
        return []
    return [f"the temperature spans only {span:.3g} °C over all runs: a model needs at least "
            f"{MIN_TEMPERATURE_SPAN_C:g} °C (compare and train refuse these data; load several "
            "soaks together)"]
