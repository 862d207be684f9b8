"""A recording larger than memory, reduced to window means in one streamed pass.

Thermal drift moves with temperature, over minutes; a chamber test logs the sensor at
100–1,000 Hz for days.  Every family of a comparison is fitted on window means already
(``train.average_s``, 1 s by default, :func:`thermonet.training.train.average_windows`),
and model selection scores the low-frequency residual.  So a thermonet Parquet file
too long to hold (``data.in_memory_samples``) is read chunk by chunk
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
  mean (:class:`thermonet.core.recording.WindowStats`), merged across chunk edges with
  Chan's pairwise update, so a held-out score over the samples is recovered from the
  rows.

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
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, InputError
from ..core.recording import GAP_FACTOR, Dataset, Recording, WindowStats
from ..data.chunks import DEFAULT_CHUNK_ROWS, ParquetLayout, iter_run_chunks, open_parquet
from . import dynamics

__all__ = ["MEDIAN_SAMPLES", "reduce_parquet", "source_samples"]

#: A run's median sample step (its gap rule) is taken over this many first samples.
MEDIAN_SAMPLES = 4096
_GROUPS = ("outputs", "references", "proxies", "drift")


def source_samples(paths: Sequence[str | Path]) -> int | None:
    """Samples in thermonet Parquet files, from their footers; None where one is not one."""
    total = 0
    for p in paths:
        path = Path(p)
        layout = open_parquet(path) if path.suffix.lower() in (".parquet", ".pq") \
            and path.is_file() else None
        if layout is None:
            return None
        total += layout.num_rows
    return total


class _Run:
    """One run's reduction: the dynamic-input stream, the open window, the finished rows."""

    def __init__(self, entry: dict[str, Any], means: list[str], dyn: list[str],
                 ss_cols: list[tuple[str, str, str | None]], window_s: float, med_dt: float,
                 gap_s: float | None) -> None:
        self.entry, self.means, self.ss_cols = entry, means, ss_cols
        self.window_s, self.cut = window_s, GAP_FACTOR * med_dt
        self.stream = dynamics.DynamicStream(dyn, gap_s) if dyn and gap_s else None
        self.dyn = [d.signal for d in dynamics.dynamic_signals(dyn)]
        self.t_last: float | None = None
        self.seg_t0 = 0.0
        self.seg_base = 0
        self.last_key = -1
        # the open window: key, count, the mean columns' means, the target columns' means, their ss
        self.open: tuple[int, float, np.ndarray, np.ndarray, np.ndarray] | None = None
        self.rows: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []

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
        counts = np.diff(np.append(starts, t.size)).astype(np.float64)
        mean = np.add.reduceat(m, starts, axis=0) / counts[:, None]
        dmean = np.add.reduceat(d, starts, axis=0) / counts[:, None] if d.shape[1] else \
            np.zeros((starts.size, 0))
        which = np.repeat(np.arange(starts.size), counts.astype(np.int64))
        ss = np.add.reduceat((d - dmean[which]) ** 2, starts, axis=0) if d.shape[1] else \
            np.zeros((starts.size, 0))
        keys = key[starts]
        if self.open is not None and self.open[0] == keys[0]:
            # the window the last chunk left open goes on: Chan's pairwise update
            _, na, ma, da, sa = self.open
            nb = counts[0]
            n = na + nb
            mean[0] = ma + (mean[0] - ma) * (nb / n)
            delta = dmean[0] - da
            ss[0] = sa + ss[0] + delta * delta * (na * nb / n)
            dmean[0] = da + delta * (nb / n)
            counts[0] = n
        elif self.open is not None:
            self._close()
        self.rows.append((counts[:-1], mean[:-1], ss[:-1], keys[:-1]))
        self.open = (int(keys[-1]), float(counts[-1]), mean[-1], dmean[-1], ss[-1])

    def _close(self) -> None:
        assert self.open is not None
        k, n, mean, _, ss = self.open
        self.rows.append((np.array([n]), mean[None, :], ss[None, :], np.array([k])))
        self.open = None

    def recording(self, gap_s: float, source_rate_hz: float, source: Path) -> Recording:
        if self.open is not None:
            self._close()
        if not self.rows:
            raise InputError.at(source, f"run '{self.entry['run_id']}' has no rows")
        n = np.concatenate([r[0] for r in self.rows])
        mean = np.concatenate([r[1] for r in self.rows])
        ss = np.concatenate([r[2] for r in self.rows])
        col = {c: mean[:, i] for i, c in enumerate(self.means)}
        e = self.entry
        groups = {g: {k: col[k] for k in e[g]} for g in _GROUPS}
        drift_ss = {a: ss[:, i] for i, (kind, a, _) in enumerate(self.ss_cols) if kind == "drift"}
        out_ss = {a: ss[:, i] for i, (kind, a, _) in enumerate(self.ss_cols)
                  if kind == "output"}
        stats = WindowStats(self.window_s, n, {s: col[s] for s in self.dyn}, gap_s, drift_ss,
                            out_ss, int(n.sum()), source_rate_hz)
        return Recording(time_s=col["time_s"],
                         temperature_c=col["temperature_c"] if e["temperature"] else None,
                         **groups, units=dict(e["units"]), device_id=e["device_id"],
                         sensor_kind=e["sensor_kind"], run_id=e["run_id"],
                         sample_rate_hz=None,
                         meta={**dict(e["meta"]), "source": str(source),
                               "reduced": f"{self.window_s:g} s window means of "
                                          f"{int(n.sum())} samples"},
                         windows=stats)


def _time_pass(layout: ParquetLayout, chunk_rows: int
               ) -> tuple[list[float], list[float]]:
    """Per run: the median step of its first :data:`MEDIAN_SAMPLES` samples and its span."""
    head: dict[int, list[np.ndarray]] = {}
    have: dict[int, int] = {}
    first: dict[int, float] = {}
    last: dict[int, float] = {}
    for i, _, piece in iter_run_chunks(layout, ["time_s"], chunk_rows=chunk_rows):
        t = piece["time_s"]
        first.setdefault(i, float(t[0]))
        last[i] = float(t[-1])
        if have.get(i, 0) < MEDIAN_SAMPLES:
            head.setdefault(i, []).append(t[:MEDIAN_SAMPLES - have.get(i, 0)])
            have[i] = have.get(i, 0) + head[i][-1].size
    med, span = [], []
    for i, e in enumerate(layout.runs):
        t = np.concatenate(head.get(i, [np.zeros(0)]))
        if t.size < 2:
            raise InputError.at(layout.path, f"run '{e['run_id']}' has fewer than 2 samples")
        med.append(float(np.median(np.diff(t))))
        span.append(last[i] - first[i])
    return med, span


def reduce_parquet(path: str | Path, *, window_s: float, inputs: Sequence[str] = (),
                   gap_s: str | float | None = "auto", chunk_rows: int = DEFAULT_CHUNK_ROWS,
                   max_rows: int | None = None) -> Dataset:
    """The runs of a thermonet Parquet file as window means (module docstring), streamed.

    Parameters
    ----------
    path : a thermonet Parquet file (``thermonet convert`` makes one from a CSV)
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
    path = Path(path)
    if not (math.isfinite(window_s) and window_s > 0):
        raise ConfigError(f"window_s must be a positive number of seconds, got {window_s!r}")
    layout = open_parquet(path)
    if layout is None:
        raise InputError.at(path, "not a thermonet Parquet file (no 'thermonet' metadata): "
                            "only thermonet's own format is streamed; convert it once with "
                            "'thermonet convert'")
    if layout.is_fleet:
        raise InputError.at(path, "holds several units: a fleet is calibrated with "
                            "'thermonet fleet', one unit at a time")
    med, span = _time_pass(layout, chunk_rows)
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
        refs = set(e["references"])
        ss_cols: list[tuple[str, str, str | None]] = []
        for o in e["outputs"]:
            r = f"ref_{o}" if f"ref_{o}" in refs else None
            ss_cols.append(("drift", o, r))
            if r:
                ss_cols.append(("output", o, None))
        columns.update(c for c in means if c not in signals)
        reducers.append(_Run(e, means, dyn, ss_cols, window_s, med[i], gap))
    for i, _, piece in iter_run_chunks(layout, sorted(columns), chunk_rows=chunk_rows):
        reducers[i].push(piece)
    rate = [1.0 / m if m > 0 else math.nan for m in med]
    runs = [r.recording(gap or 0.0, rate[i], path) for i, r in enumerate(reducers)]
    return Dataset(runs, meta={"source": str(path), **layout.meta}).validate(str(path))
