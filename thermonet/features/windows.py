"""A recording larger than memory, reduced to window means in one streamed pass.

Thermal drift moves with temperature, over minutes; a chamber test logs the sensor at
100–1,000 Hz for days.  Every family of a comparison is fitted on window means already
(``train.average_s``, 1 s by default, :func:`thermonet.training.train.average_windows`),
and model selection scores the low-frequency residual.  So a recording file too long to
hold (``data.in_memory_samples``; any tabular format, through its column mapping) is read
chunk by chunk
(:func:`thermonet.data.chunks.iter_run_chunks`, a fixed number of rows at a time) and
reduced, per run, to one row per window, keeping what the comparison needs of the
samples:

* the window mean of every channel (time, temperature, outputs, references, proxies,
  simulated drift) — the rows the fit would have averaged itself, with the same
  alignment (windows start at each contiguous segment's first sample; a time step over
  :data:`~thermonet.core.recording.GAP_FACTOR` × the run's median step starts a segment);
* the window mean of every dynamic input the families read (``rate_c_per_min``,
  ``lag_*``, ``play_*``), computed on the samples at their own rate with the state
  carried across chunk edges (:class:`thermonet.features.dynamics.DynamicStream`) —
  never from the means;
* the count of samples and, per axis, the sum of squared deviations from the window
  mean, with the co-moments of the model-input columns (temperature, proxies, dynamic
  inputs) with each other and with each axis' target
  (:class:`thermonet.core.recording.WindowStats`), merged across chunk edges with Chan's
  pairwise update, so a held-out score over the samples is recovered from the rows: the
  raw error's exactly, the residual's to first order in the signals' spread inside a
  window (:func:`thermonet.training.pipeline.residual_spread`).

Memory is then the chunk (``chunk_rows`` × the columns, float64) plus the rows: one per
``window_s`` of recording, whatever the sample rate.  ``max_rows`` caps the rows: a
recording longer than ``max_rows`` × ``window_s`` is reduced to wider windows (the fit's
own sample budget, ``train.max_train_samples``, would have averaged it so anyway).

Decisions, each a difference from holding the samples:

* The median step that defines a run's gaps is that of its first
  :data:`MEDIAN_SAMPLES` samples (the whole run's median needs every step in memory).
* ``gap_s: auto`` is :data:`~thermonet.core.recording.GAP_FACTOR` × the median step of
  the file's first run, as the in-memory comparison takes it from its first training run.
* The dynamic inputs run over each whole run, as the board computes them; in memory, a
  time-block split's stacked held-out blocks restart them at each block's start.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, InputError
from ..core.recording import GAP_FACTOR, Dataset, Recording, WindowStats
from ..data.chunk_base import MEDIAN_SAMPLES, Layout
from ..data.chunks import (
    DEFAULT_CHUNK_ROWS,
    count_samples,
    iter_run_chunks,
    open_source,
    run_times,
)
from ..data.mapping import ColumnMapping
from . import dynamics

__all__ = ["MEDIAN_SAMPLES", "reduce_parquet", "source_samples"]

_GROUPS = ("outputs", "references", "proxies", "drift")


def source_samples(paths: Sequence[str | Path], mapping: ColumnMapping | None = None
                   ) -> int | None:
    """Samples in the recording files (:func:`thermonet.data.chunks.count_samples`)."""
    return count_samples(paths, mapping)


@dataclass
class _Windows:
    """Sums of a run of consecutive windows: counts (G,), the mean columns' means (G, M),
    the target columns' means (G, A) and sums of squares (G, A), and the co-moments of the
    signal columns with each other (G, S, S) and with the targets (G, S, A), all about each
    window's own means."""

    n: np.ndarray
    mean: np.ndarray
    dmean: np.ndarray
    ss: np.ndarray
    sxx: np.ndarray
    sxd: np.ndarray

    def take(self, rows: slice) -> _Windows:
        return _Windows(self.n[rows], self.mean[rows], self.dmean[rows], self.ss[rows],
                        self.sxx[rows], self.sxd[rows])

    def merge_first(self, a: _Windows, sig: list[int]) -> None:
        """Window 0 of ``self`` continues ``a``'s one window: Chan's pairwise update of the
        count, the means and every (co-)moment."""
        na, nb = float(a.n[0]), float(self.n[0])
        n = na + nb
        dx = self.mean[0, sig] - a.mean[0, sig]
        dd = self.dmean[0] - a.dmean[0]
        w = na * nb / n
        self.ss[0] = a.ss[0] + self.ss[0] + dd * dd * w
        self.sxx[0] = a.sxx[0] + self.sxx[0] + np.outer(dx, dx) * w
        self.sxd[0] = a.sxd[0] + self.sxd[0] + np.outer(dx, dd) * w
        self.mean[0] = a.mean[0] + (self.mean[0] - a.mean[0]) * (nb / n)
        self.dmean[0] = a.dmean[0] + dd * (nb / n)
        self.n[0] = n


class _Run:
    """One run's reduction: the dynamic-input stream, the open window, the finished rows."""

    def __init__(self, entry: dict[str, Any], means: list[str], signals: list[str],
                 dyn: list[str], ss_cols: list[tuple[str, str, str | None]], window_s: float,
                 med_dt: float, gap_s: float | None) -> None:
        self.entry, self.means, self.ss_cols = entry, means, ss_cols
        self.signals = signals                  # the model-input columns (co-moments)
        self.sig = [means.index(c) for c in signals]
        self.window_s, self.cut = window_s, GAP_FACTOR * med_dt
        self.stream = dynamics.DynamicStream(dyn, gap_s) if dyn and gap_s else None
        self.dyn = [d.signal for d in dynamics.dynamic_signals(dyn)]
        self.t_last: float | None = None
        self.seg_t0 = 0.0
        self.seg_base = 0
        self.last_key = -1
        self.open: tuple[int, _Windows] | None = None   # the window a chunk left open
        self.rows: list[_Windows] = []
        self.extremes: dict[str, tuple[float, float]] = {}

    def _keys(self, t: np.ndarray) -> np.ndarray:
        """Window index of every sample (as :func:`~thermonet.training.train.average_windows`)."""
        step = np.diff(t, prepend=t[0] if self.t_last is None else self.t_last)
        new = step > self.cut
        new[0] = self.t_last is None or bool(new[0])
        key = np.empty(t.size, dtype=np.int64)
        starts = [*np.flatnonzero(new).tolist(), t.size]
        a = 0
        for b in starts:
            if b > a:   # the samples [a, b) continue the current segment
                key[a:b] = self.seg_base + np.floor((t[a:b] - self.seg_t0) / self.window_s)
                self.last_key = int(key[b - 1])
            if b < t.size:
                self.seg_t0, self.seg_base = float(t[b]), self.last_key + 1
            a = b
        return key

    def push(self, piece: dict[str, np.ndarray]) -> None:
        t = piece["time_s"]
        for c, v in piece.items():   # the samples' extremes (plausibility warnings)
            lo, hi = float(v.min()), float(v.max())
            old = self.extremes.get(c)
            self.extremes[c] = (lo, hi) if old is None else (min(old[0], lo), max(old[1], hi))
        cols = dict(piece)
        if self.stream is not None:
            signals, _ = self.stream.push(t, piece["temperature_c"])
            cols.update(signals)
        key = self._keys(t)
        self.t_last = float(t[-1])
        m = np.column_stack([cols[c] for c in self.means])
        d = np.column_stack([cols[o] - (cols[r] if r else 0.0) for _, o, r in self.ss_cols]) \
            if self.ss_cols else np.zeros((t.size, 0))
        starts = np.concatenate([[0], np.flatnonzero(np.diff(key)) + 1])
        counts = np.diff(np.append(starts, t.size))
        which = np.repeat(np.arange(starts.size), counts)
        n = counts.astype(np.float64)

        def sums(x: np.ndarray) -> np.ndarray:
            return np.add.reduceat(x, starts, axis=0) if x.shape[1] else \
                np.zeros((starts.size, 0))

        mean = sums(m) / n[:, None]
        dmean = sums(d) / n[:, None]
        dc = d - dmean[which]
        xc = m[:, self.sig] - mean[which][:, self.sig]
        ns, na = len(self.sig), d.shape[1]
        sxx = np.zeros((starts.size, ns, ns))
        sxd = np.zeros((starts.size, ns, na))
        for i in range(ns):     # one signal at a time: chunk-sized temporaries only
            sxx[:, i, :] = sums(xc[:, i:i + 1] * xc)
            sxd[:, i, :] = sums(xc[:, i:i + 1] * dc)
        got = _Windows(n, mean, dmean, sums(dc * dc), sxx, sxd)
        keys = key[starts]
        if self.open is not None and self.open[0] == keys[0]:
            got.merge_first(self.open[1], self.sig)
        elif self.open is not None:
            self.rows.append(self.open[1])
        self.rows.append(got.take(slice(0, -1)))
        self.open = (int(keys[-1]), got.take(slice(-1, None)))

    def recording(self, gap_s: float, source_rate_hz: float, source: Path) -> Recording:
        if self.open is not None:
            self.rows.append(self.open[1])
            self.open = None
        if not self.rows:
            raise InputError.at(source, f"run '{self.entry['run_id']}' has no rows")

        def cat(field: str) -> np.ndarray:
            return np.concatenate([getattr(r, field) for r in self.rows])

        n, mean, ss, sxd = cat("n"), cat("mean"), cat("ss"), cat("sxd")
        col = {c: mean[:, i] for i, c in enumerate(self.means)}
        e = self.entry
        groups = {g: {k: col[k] for k in e[g]} for g in _GROUPS}

        def per_axis(kind: str, x: np.ndarray) -> dict[str, np.ndarray]:
            return {a: x[..., i] for i, (k, a, _) in enumerate(self.ss_cols) if k == kind}

        stats = WindowStats(self.window_s, n, {s: col[s] for s in self.dyn}, gap_s,
                            per_axis("drift", ss), per_axis("output", ss), int(n.sum()),
                            source_rate_hz, list(self.signals), cat("sxx"),
                            per_axis("drift", sxd), per_axis("output", sxd),
                            extremes=dict(self.extremes))
        return Recording(time_s=col["time_s"],
                         temperature_c=col["temperature_c"] if e["temperature"] else None,
                         **groups, units=dict(e["units"]), device_id=e["device_id"],
                         sensor_kind=e["sensor_kind"], run_id=e["run_id"],
                         sample_rate_hz=None,
                         meta={**dict(e["meta"]), "source": str(source),
                               "reduced": f"{self.window_s:g} s window means of "
                                          f"{int(n.sum())} samples"},
                         windows=stats)


def reduce_parquet(path: str | Path | Layout, *, window_s: float, inputs: Sequence[str] = (),
                   gap_s: str | float | None = "auto", chunk_rows: int = DEFAULT_CHUNK_ROWS,
                   max_rows: int | None = None, mapping: ColumnMapping | None = None
                   ) -> Dataset:
    """The runs of a recording file as window means (module docstring), streamed.

    Parameters
    ----------
    path : any tabular recording (thermonet or plain Parquet, CSV, TSV), or its layout
        (:func:`thermonet.data.chunks.open_source`)
    mapping : its column mapping (None: thermonet's conventional column names)
    window_s : window length, s (the fit's ``train.average_s``); > 0
    inputs : the feature names the families read: their dynamic inputs are computed
    gap_s : the dynamic inputs' gap limit, s, or ``"auto"``
    chunk_rows : rows read at a time
    max_rows : most rows over all runs (None: no cap): wider windows where needed

    Returns
    -------
    Dataset
        One reduced :class:`~thermonet.core.recording.Recording` per run, validated;
        each carries its :class:`~thermonet.core.recording.WindowStats`.
    """
    if not (math.isfinite(window_s) and window_s > 0):
        raise ConfigError(f"window_s must be a positive number of seconds, got {window_s!r}")
    layout = path if isinstance(path, Layout) else \
        open_source(path, mapping, chunk_rows=chunk_rows)
    path = layout.path
    if layout.is_fleet:
        raise InputError.at(path, "holds several units: a fleet is calibrated with "
                            "'thermonet fleet', one unit at a time")
    times = run_times(layout, chunk_rows)
    for e, rt in zip(layout.runs, times, strict=True):
        if rt.n < 2:
            raise InputError.at(path, f"run '{e['run_id']}' has fewer than 2 samples")
    med = [rt.median_step for rt in times]
    span = [rt.last - rt.first for rt in times]
    if max_rows is not None and max_rows > 0:
        window_s = max(window_s, sum(span) / max_rows)
    dyn = [d.name for d in dynamics.dynamic_signals(inputs)]
    gap: float | None = None
    if dyn:
        if not all(e["temperature"] for e in layout.runs):
            raise ConfigError(f"{path}: inputs {dyn} need a thermometer in °C")
        if gap_s is None or gap_s == "auto":
            gap = GAP_FACTOR * med[0]
        elif isinstance(gap_s, str) or not (math.isfinite(float(gap_s)) and float(gap_s) > 0):
            raise ConfigError(f"gap_s must be a positive number of seconds or 'auto', got "
                              f"{gap_s!r}")
        else:
            gap = float(gap_s)
    signals = [d.signal for d in dynamics.dynamic_signals(inputs)]
    reducers: list[_Run] = []
    columns: set[str] = {"time_s"}
    for i, e in enumerate(layout.runs):
        means = ["time_s"] + (["temperature_c"] if e["temperature"] else [])
        means += [k for g in _GROUPS for k in e[g]] + signals
        # the columns a model may read: their co-moments with the targets inside a window
        inputs_of_run = (["temperature_c"] if e["temperature"] else []) + list(e["proxies"]) \
            + signals
        refs = set(e["references"])
        ss_cols: list[tuple[str, str, str | None]] = []
        for o in e["outputs"]:
            r = f"ref_{o}" if f"ref_{o}" in refs else None
            ss_cols.append(("drift", o, r))
            if r:
                ss_cols.append(("output", o, None))
        columns.update(c for c in means if c not in signals)
        reducers.append(_Run(e, means, inputs_of_run, dyn, ss_cols, window_s, med[i], gap))
    for i, _, piece in iter_run_chunks(layout, sorted(columns), chunk_rows=chunk_rows):
        reducers[i].push(piece)
    rate = [1.0 / m if m > 0 else math.nan for m in med]
    runs = [r.recording(gap or 0.0, rate[i], path) for i, r in enumerate(reducers)]
    meta = {"source": str(path), **layout.meta}
    return Dataset(runs, meta=meta).validate(str(path))
