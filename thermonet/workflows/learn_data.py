"""``thermonet learn``'s data: the logs' window means (each log reduced and cached by
:mod:`thermonet.workflows.learn_reduce`), checked as one vehicle, aligned for the estimator's
lag, cleaned of what did not converge, and mapped by temperature.

A log is read by :func:`~thermonet.workflows.learn_reduce.reduce_log` (on the process pool or
Ray, one log a task: the same executors as ``fleet``) into plain data: per bias series (:mod:`thermonet.data.logs.bias`)
the means over :data:`WINDOW_S` windows of its valid samples — the drift weighted by the
inverse of the reported variance (equal weights where none is logged), the temperature, and
the temperature through first-order lags of every :data:`LAG_GRID_S` time constant.  The
driver folds each reduced log into :class:`WindowFold` as it arrives and keeps of it only its
summary (path, autopilot, device ids, board id, notes): the windows an instance holds are
capped at :data:`MAX_WINDOWS` (a 30-minute flight gives ~180 per series; past the cap every
flight's windows are merged in pairs), so the memory a job needs is bounded by the cap, not
by the logs (experiments/README.md: flat from 200 to 1,000 logs).

Each reduced log is cached in ``DIR/cache/`` under its SHA-256 (:func:`cache_path`) as it
arrives, refusals included: a stopped job loses no log already read, and adding logs to a
directory reads only the new ones.

The estimator's lag (:func:`choose_lag`).  The estimator's bias ``b`` follows the bias it
must find ``d`` through its own filter; for a first-order one of time constant τ,
``τ·db/dt + b = d``, so ``d = b + τ·db/dt`` — the drift at the temperature as read, what the
firmware applies.  :func:`reduce_log` computes that for every τ of :data:`LAG_GRID_S`
(``db/dt`` by a centred difference over ± :data:`SLOPE_S`, before the windows), and each
instance keeps the τ whose weighted cubic over every flight leaves the smallest median
residual.  Still-gyro windows need none (the raw gyro has no lag).  Undoing the lag on the
bias rather than lagging the temperature is exact for any drift law, not only a line (the
first version lagged the temperature: up to 0.5× raw was left on hot held-out flights,
experiments/README.md).  Samples before convergence are already dropped by the reader.

Divergence (:func:`reject_outliers`): a window more than :data:`OUTLIER_MADS` robust standard
deviations (1.4826 × MAD) from the median of its 1 °C bin over every flight, on any axis, is
left out — an estimator that wandered
off (a maneuver, a bad magnetometer) without its variance saying so.

What every fit reads (:func:`median_within_flights`): each flight's kept windows replaced by
their running median over :data:`ROBUST_S` (PX4's ``process_sensor_caldata.py`` filters its
log by a running median first), *within* the flight, never across two — the firmware form
and the comparison both fit these.  The median once ran over the flights put end to end: at
each flight's start (its coldest windows) it took in the previous flight's hottest, and on
PX4 the firmware form of 20 flights was ≤ 1.5× a chamber calibration on 89.9 % of held-out
axes, 99.6 % within flights (experiments/README.md, "Learning from flights").
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..data.logs.bias import BIAS_KINDS
from ..data.logs.info import autopilot_article
from .firmware_fit import PX4_MEDIAN_SAMPLES, running_median
from .learn_reduce import LAG_GRID_S, WINDOW_S

__all__ = ["OUTLIER_MADS", "InstanceWindows", "gather",
           "WindowFold", "MAX_WINDOWS", "vehicle_key", "choose_lag", "reject_outliers",
           "ROBUST_S", "median_within_flights",
           "coverage", "supported_spans", "missing_words", "TARGET_RANGE_C", "MIN_BIN_FLIGHTS",
           "MIN_BIN_MINUTES"]

#: The lag's score averages the residuals over this long within each flight (s).
LAG_SCORE_S = 120.0
#: The running median every fit reads spans this long within a flight (s): PX4's 31
#: samples, one reader window each.
ROBUST_S = PX4_MEDIAN_SAMPLES * WINDOW_S
#: A window this many robust standard deviations off the fit is left out.
OUTLIER_MADS = 5.0
#: Windows one instance holds at most (about 180 half-hour flights of 10-s windows): past it
#: they are merged in pairs (:class:`WindowFold`), so memory does not grow with the logs.
MAX_WINDOWS = 2 ** 15
#: The temperatures a vehicle may meet (°C): the coverage map says what of it is missing.
TARGET_RANGE_C = (-10.0, 60.0)
#: A 1 °C bin is supported with at least this many flights and minutes.
MIN_BIN_FLIGHTS = 2
MIN_BIN_MINUTES = 2.0
#: A fit whose supported bins span less than this (°C, first to last) is not written: a cubic
#: over a degree or two is an offset's guess, and the autopilot would carry it across its
#: whole clamp (a 6-flight ArduPilot vehicle's IMU 3, supported at −1..0 °C only, wrote a
#: gyro fit that verify failed at 3.0x on a bench warm-up).
MIN_SUPPORTED_SPAN_C = 5.0


@dataclass
class InstanceWindows:
    """One sensor instance's windows over every flight: per window its flight (index into
    ``flights``), time, temperature as read, drift (n, 3) de-lagged by each lag tried, weight
    (s of data), and whether it came from still-gyro windows; ``window_s``: their length (the
    reader's :data:`WINDOW_S`, or a multiple once merged under :data:`MAX_WINDOWS`)."""

    kind: str
    device_id: int
    name: str
    flights: list[str]
    flight: np.ndarray
    time_s: np.ndarray
    temp: np.ndarray
    drifts: dict[str, np.ndarray]
    weight: np.ndarray
    still: np.ndarray
    notes: list[str] = field(default_factory=list)
    lag_s: float = 0.0
    keep: np.ndarray | None = None
    window_s: float = WINDOW_S

    @property
    def drift(self) -> np.ndarray:
        """Each window's drift (n, 3), de-lagged by the chosen lag :attr:`lag_s`."""
        return self.drifts[f"{self.lag_s:g}"]


def _name_of(sensors: dict[str, int], kind: str, dev: int) -> str:
    return next((n for n, d in sensors.items() if d == dev and n.startswith(kind)),
                f"{kind}-{dev}")


def vehicle_key(lg: dict[str, Any]) -> tuple[str, str, str | None]:
    """What :func:`not_this_vehicle` judges a log by: autopilot, device ids, board id."""
    return (lg["autopilot"], json.dumps(sorted(lg["sensors"].items())), lg.get("board_id"))


def _log_rows(doc: dict[str, Any]) -> dict[tuple[str, int], list[dict[str, np.ndarray]]]:
    """A reduced log's windows per instance (kind, device id), one block of columns per
    series; an estimator window within :data:`WINDOW_S` of a still window of the log is
    dropped (the still window measures the same bias directly).  ``drift``: every lag's of
    :data:`LAG_GRID_S` side by side (n, 3·lags), float32 as :func:`compact` holds them."""
    parts: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for s in doc["series"]:
        if s["kind"] in BIAS_KINDS and len(s["t"]):
            parts.setdefault((s["kind"], int(s["device_id"])), []).append(s)
    out = {}
    for key, series in parts.items():
        stills = [np.asarray(p["t"]) for p in series if p["source"] == "still"]
        blocks = []
        for s in series:
            t = np.asarray(s["t"], dtype=np.float64)
            keep = np.ones(t.size, dtype=bool)
            if s["source"] == "ekf":
                for st in stills:
                    if st.size:
                        keep &= ~(np.abs(t[:, None] - st[None, :]).min(axis=1) < WINDOW_S)
            drift = np.concatenate([np.asarray(s["drifts"][f"{tau:g}"], dtype=np.float32
                                               ).reshape(-1, 3) for tau in LAG_GRID_S], axis=1)
            blocks.append({"t": t[keep], "temp": np.asarray(s["temp"], dtype=np.float64)[keep],
                           "weight": np.asarray(s["weight"], dtype=np.float64)[keep],
                           "still": np.full(int(keep.sum()), s["source"] == "still"),
                           "drift": drift[keep]})
        out[key] = blocks
    return out


def _merge_pairs(c: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Each segment's windows merged in pairs (first with second, third with fourth, ...; an
    odd last one alone): time, temperature and drift averaged weighted by the seconds each
    holds, the seconds added; a segment (one series of one log) is never merged with another."""
    seg = c["seg"]
    if not seg.size:
        return c
    first = np.r_[True, seg[1:] != seg[:-1]]
    idx = np.arange(seg.size)
    pos = idx - np.maximum.accumulate(np.where(first, idx, 0))
    starts = np.flatnonzero(first | (pos % 2 == 0))
    w = c["weight"]
    wsum = np.add.reduceat(w, starts)

    def mean(x: np.ndarray) -> np.ndarray:
        if x.ndim == 1:
            return np.add.reduceat(x * w, starts) / wsum
        return np.add.reduceat(x * w[:, None], starts, axis=0) / wsum[:, None]

    return {"flight": c["flight"][starts], "seg": seg[starts], "t": mean(c["t"]),
            "temp": mean(c["temp"]), "weight": wsum, "still": c["still"][starts],
            "drift": mean(c["drift"].astype(np.float64)).astype(np.float32)}


def _concat(chunks: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    return {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}


@dataclass
class _Store:
    """One instance's windows of one vehicle: column chunks (flight: the log's index among
    those given; seg: one series of one log), each window ``2**level`` of the reader's."""

    level: int = 0
    n: int = 0
    chunks: list[dict[str, np.ndarray]] = field(default_factory=list)

    def rows(self) -> dict[str, np.ndarray]:
        """The chunks as one (kept as one)."""
        if len(self.chunks) > 1:
            self.chunks = [_concat(self.chunks)]
        return self.chunks[0]

    def coarsen(self, cap: int, level: int = 0) -> None:
        """Merge in pairs until at ``level`` at least and at most ``cap`` windows."""
        while self.chunks and (self.level < level or self.n > cap):
            self.chunks = [_merge_pairs(self.rows())]
            self.n, self.level = self.chunks[0]["seg"].size, self.level + 1
        self.level = max(self.level, level)


class WindowFold:
    """Every log's windows folded in as it arrives, in any order, per vehicle (which logs
    are the vehicle's is known only once all are read: :func:`vehicle_key`) and instance,
    at most :data:`MAX_WINDOWS` per instance: past it, every flight's windows are merged in
    pairs (10-s windows become 20-s, then 40-s, ...; a log read later is merged as far on
    arrival).  So what the job holds is bounded by the cap, not by the logs: per log only
    its summary (:meth:`add`'s caller keeps it).  Below the cap the windows are the reader's,
    unchanged; the pairs merged are the same whatever the order the logs arrive in (each
    series's windows pair up by their place in it), so the result depends on the logs only."""

    def __init__(self, cap: int | None = None) -> None:
        self.cap = MAX_WINDOWS if cap is None else int(cap)
        self._stores: dict[tuple[tuple[str, str, str | None], str, int], _Store] = {}
        self._segments = 0

    @property
    def nbytes(self) -> int:
        """Bytes of the windows held (every instance, every vehicle)."""
        return sum(a.nbytes for st in self._stores.values() for c in st.chunks
                   for a in c.values())

    def add(self, flight: int, doc: dict[str, Any]) -> None:
        """Fold in the reduced log ``doc`` (:func:`reduce_log`) as log number ``flight``."""
        key = vehicle_key(doc)
        for (kind, dev), blocks in sorted(_log_rows(doc).items()):
            store = self._stores.setdefault((key, kind, dev), _Store())
            blocks = [b for b in blocks if b["t"].size]
            if not blocks:
                continue
            for b in blocks:
                b["flight"] = np.full(b["t"].size, flight, dtype=np.int64)
                b["seg"] = np.full(b["t"].size, self._segments, dtype=np.int64)
                self._segments += 1
            rows = _concat(blocks)
            for _ in range(store.level):
                rows = _merge_pairs(rows)
            store.chunks.append(rows)
            store.n += rows["seg"].size
            if len(store.chunks) > 64:              # few arrays, not one set per log
                store.rows()
            store.coarsen(self.cap)

    def instances(self, vehicles: set[tuple[str, str, str | None]], flights: list[int],
                  names: list[str], sensors: dict[str, int]) -> Iterator[InstanceWindows]:
        """Each instance's windows over the logs of ``vehicles`` (``flights``: their numbers,
        in order; ``names``: their paths), one instance at a time, each dropped once given:
        the windows of each log in the order given, at the level all fit the cap."""
        for kind, dev in sorted({(k, d) for v, k, d in self._stores if v in vehicles}):
            parts = [self._stores.pop((v, kind, dev)) for v in sorted(vehicles, key=str)
                     if (v, kind, dev) in self._stores]
            level = max(p.level for p in parts)
            for p in parts:
                p.coarsen(self.cap, level)
            merged = _Store(level, sum(p.n for p in parts), [c for p in parts for c in p.chunks])
            merged.coarsen(self.cap)
            rows = merged.rows() if merged.chunks else {
                "flight": np.zeros(0, np.int64), "t": np.zeros(0), "temp": np.zeros(0),
                "weight": np.zeros(0), "still": np.zeros(0, bool),
                "drift": np.zeros((0, 3 * len(LAG_GRID_S)), np.float32)}
            order = np.argsort(rows["flight"], kind="stable")
            yield InstanceWindows(
                kind, dev, _name_of(sensors, kind, dev), names,
                np.searchsorted(np.asarray(flights), rows["flight"][order]),
                rows["t"][order], rows["temp"][order],
                {f"{tau:g}": np.ascontiguousarray(rows["drift"][order, 3 * j:3 * j + 3],
                                                  dtype=np.float64)
                 for j, tau in enumerate(LAG_GRID_S)},
                rows["weight"][order], rows["still"][order],
                window_s=WINDOW_S * 2 ** merged.level)


def gather(logs: list[dict[str, Any]]) -> list[InstanceWindows]:
    """Every instance's windows over the logs (reduced, of one vehicle), in the order given:
    one flight a log (:class:`WindowFold` over them)."""
    fold = WindowFold()
    for k, lg in enumerate(logs):
        fold.add(k, lg)
    return list(fold.instances({vehicle_key(lg) for lg in logs}, list(range(len(logs))),
                               [lg["path"] for lg in logs], logs[0]["sensors"] if logs else {}))


def _cubic_residuals(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Residuals (n, 3) of a weighted cubic in ``x`` per axis (a line with few points)."""
    deg = 3 if np.unique(np.round(x, 1)).size > 6 else 1
    xc = x - x.mean()
    res = np.empty_like(y)
    for j in range(y.shape[1]):
        c = np.polyfit(xc, y[:, j], deg, w=np.sqrt(w))
        res[:, j] = y[:, j] - np.polyval(c, xc)
    return res


def _smooth(flight: np.ndarray, x: np.ndarray, n: int) -> np.ndarray:
    """``x`` (rows in time order within each flight) as a moving mean of ``n`` rows, within
    each flight (never across two)."""
    out = np.empty_like(x)
    for f in np.unique(flight):
        sel = np.flatnonzero(flight == f)
        k = min(n, sel.size)
        kernel = np.ones(k) / k
        for j in range(x.shape[1]):
            pad = np.pad(x[sel, j], (k // 2, k - 1 - k // 2), mode="edge")
            out[sel, j] = np.convolve(pad, kernel, mode="valid")
    return out


def choose_lag(inst: InstanceWindows) -> dict[str, float]:
    """Set ``inst.lag_s`` to the :data:`LAG_GRID_S` lag whose cubic over every flight leaves
    the smallest median residual (relative per axis), the residuals first averaged over
    :data:`LAG_SCORE_S` within each flight: a wrong lag leaves an error that follows the
    heating rate (minutes), the slope's noise (which a longer lag amplifies) averages out;
    each lag's score, by its name."""
    scores: dict[str, float] = {}
    order = np.lexsort((inst.time_s, inst.flight))
    for tau in LAG_GRID_S:
        inst.lag_s = tau
        if inst.time_s.size < 8:
            scores[f"{tau:g}"] = math.inf
            continue
        scale = np.maximum(np.ptp(inst.drift, axis=0), 1e-12)
        res = _cubic_residuals(inst.temp, inst.drift, inst.weight)[order]
        res = _smooth(inst.flight[order], res, max(1, int(LAG_SCORE_S / inst.window_s)))
        scores[f"{tau:g}"] = float(np.mean(np.median(np.abs(res), axis=0) / scale))
    if not inst.still.all():
        inst.lag_s = float(min(LAG_GRID_S, key=lambda tau: scores[f"{tau:g}"]))
    else:
        inst.lag_s = 0.0
    return scores


def reject_outliers(inst: InstanceWindows) -> int:
    """Mark (``inst.keep``) the windows within :data:`OUTLIER_MADS` robust standard
    deviations (per axis, over every window) of the median of their 1 °C bin over every
    flight — no drift law assumed, so a curved end of the range is never mistaken for a
    divergence; the number left out.  A bin of one flight cannot judge itself: kept."""
    bins = np.floor(inst.temp).astype(np.int64)
    res = np.zeros_like(inst.drift)
    judged = np.zeros(bins.size, dtype=bool)
    for b in np.unique(bins):
        sel = bins == b
        if np.unique(inst.flight[sel]).size < 2:
            continue
        res[sel] = inst.drift[sel] - np.median(inst.drift[sel], axis=0)
        judged |= sel
    keep = np.ones(bins.size, dtype=bool)
    if judged.sum() >= 8:
        sigma = 1.4826 * np.median(np.abs(res[judged]), axis=0)
        keep = ~judged | np.all(np.abs(res) <= OUTLIER_MADS * np.maximum(sigma, 1e-12), axis=1)
    inst.keep = keep
    return int((~keep).sum())


def median_within_flights(inst: InstanceWindows) -> int:
    """Replace the kept windows' drift (at the chosen lag) by each flight's running median
    over :data:`ROBUST_S` in time order — never across two flights; the median's length in
    windows (odd, at least 1; shorter once windows are merged)."""
    span = max(1, int(ROBUST_S / inst.window_s))
    span -= 1 - span % 2                          # the largest odd number within the span
    keep = inst.keep if inst.keep is not None else np.ones(inst.time_s.size, dtype=bool)
    drift = inst.drift.copy()
    for f in np.unique(inst.flight[keep]):
        sel = np.flatnonzero(keep & (inst.flight == f))
        sel = sel[np.argsort(inst.time_s[sel], kind="stable")]
        drift[sel] = running_median(drift[sel], span)
    inst.drifts[f"{inst.lag_s:g}"] = drift
    return span


def coverage(inst: InstanceWindows) -> list[dict[str, Any]]:
    """Per 1 °C bin of the temperature (kept windows): flights and minutes."""
    keep = inst.keep if inst.keep is not None else np.ones(inst.time_s.size, dtype=bool)
    x = inst.temp[keep]
    if not x.size:
        return []
    bins = np.floor(x).astype(np.int64)
    out = []
    for b in range(int(bins.min()), int(bins.max()) + 1):
        sel = bins == b
        out.append({"bin_c": b, "flights": int(np.unique(inst.flight[keep][sel]).size),
                    "minutes": round(float(inst.weight[keep][sel].sum()) / 60.0, 2)})
    return out


def supported_spans(cov: list[dict[str, Any]]) -> list[tuple[int, int]]:
    """The 1 °C bins of :func:`coverage` with :data:`MIN_BIN_FLIGHTS` flights and
    :data:`MIN_BIN_MINUTES` minutes, consecutive ones as (first, last) bin."""
    return _runs(_supported_bins(cov))


def _supported_bins(cov: list[dict[str, Any]]) -> list[int]:
    return [c["bin_c"] for c in cov if c["flights"] >= MIN_BIN_FLIGHTS
            and c["minutes"] >= MIN_BIN_MINUTES]


def _runs(bins: list[int]) -> list[tuple[int, int]]:
    """Consecutive integers grouped as (first, last)."""
    out: list[tuple[int, int]] = []
    for b in bins:
        if out and b == out[-1][1] + 1:
            out[-1] = (out[-1][0], b)
        else:
            out.append((b, b))
    return out


def missing_words(cov: list[dict[str, Any]]) -> tuple[tuple[int, int] | None, list[str]]:
    """The supported span (first and last supported bin, °C) and, in plain words, the
    temperatures of :data:`TARGET_RANGE_C` still missing and how to fill them."""
    ok = _supported_bins(cov)
    lo_t, hi_t = TARGET_RANGE_C
    if not ok:
        return None, [f"no 1 °C bin has {MIN_BIN_FLIGHTS} flights and {MIN_BIN_MINUTES:g} "
                      "minutes yet: fly more (the model rests on too little)"]
    lo, hi = min(ok), max(ok) + 1
    words = []
    if lo > lo_t:
        words.append(f"nothing supports it below {lo} °C: fly once below {lo} °C to cover "
                     "the cold end")
    if hi < hi_t:
        words.append(f"nothing supports it above {hi} °C: fly once warmer (above "
                     f"{hi} °C at the sensor) to cover the hot end")
    holes = [b for b in range(lo, hi) if b not in ok]
    for a, b in _runs(holes):
        words.append(f"{a}..{b + 1} °C rests on fewer than {MIN_BIN_FLIGHTS} flights or "
                     f"{MIN_BIN_MINUTES:g} minutes: fly once more around "
                     f"{round((a + b + 1) / 2)} °C")
    return (lo, hi), words




def vehicle_of(logs: list[dict[str, Any]]) -> tuple[str, dict[str, int], str | None]:
    """The vehicle most logs are of: (autopilot, device ids by instance, board id)."""
    ap = Counter(lg["autopilot"] for lg in logs).most_common(1)[0][0]
    same = [lg for lg in logs if lg["autopilot"] == ap]
    key = Counter(json.dumps(sorted(lg["sensors"].items())) for lg in same).most_common(1)[0][0]
    sensors = dict(json.loads(key))
    boards = Counter(lg.get("board_id") for lg in same if lg.get("board_id"))
    return ap, sensors, (boards.most_common(1)[0][0] if boards else None)


def not_this_vehicle(lg: dict[str, Any], ap: str, sensors: dict[str, int],
                     board: str | None) -> str | None:
    """Why a reduced log is not of the vehicle (one phrase), or None when it is."""
    if lg["autopilot"] != ap:
        other = autopilot_article(lg["autopilot"])
        return (f"{other} log among {ap} logs: one vehicle, one autopilot "
                "(learn them in separate directories)")
    if lg["sensors"] != sensors:
        mine = ", ".join(f"{k} {v}" for k, v in sorted(lg["sensors"].items()))
        theirs = ", ".join(f"{k} {v}" for k, v in sorted(sensors.items()))
        return f"another vehicle's sensors (device ids {mine}; the vehicle's: {theirs})"
    if lg.get("board_id") and board and lg["board_id"] != board:
        return (f"another board of the same model (the same sensors' device ids, board id "
                f"{lg['board_id']}; the vehicle's is {board})")
    return None
