"""``thermonet learn``'s reading of one log (:func:`reduce_log`, in a worker): per bias series
(:mod:`thermonet.data.logs.bias`) the means over :data:`WINDOW_S` windows of its valid
samples — the drift weighted by the inverse of the reported variance, the temperature, and
the drift with the estimator's lag undone for every :data:`LAG_GRID_S` time constant
(:mod:`thermonet.workflows.learn_data` says why and chooses among them) — and its cache entry
in ``DIR/cache/`` under the log's SHA-256 (:func:`cache_path`, refusals included), so a
stopped job loses no log already read."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError
from ..core.fileio import atomic_write_text
from ..data.logs.bias import BiasSeries, read_bias_log

__all__ = ["WINDOW_S", "LAG_GRID_S", "SLOPE_S", "READER_VERSION", "reduce_log",
           "reduce_or_refuse", "reduce_for_cache", "compact", "cache_path", "read_cache",
           "write_cache"]

#: Window of the means a log is reduced to, s.
WINDOW_S = 10.0
#: Time constants (s) tried for the estimator's lag (0: none).
LAG_GRID_S = (0.0, 15.0, 30.0, 45.0, 60.0, 90.0, 120.0, 150.0, 180.0, 240.0)
#: Half-width (s) of the centred difference that estimates the bias's slope.
SLOPE_S = 30.0
#: Bumped when the reduction changes: older cache entries are read again.
READER_VERSION = 2


def _delag(t: np.ndarray, b: np.ndarray, tau: float) -> np.ndarray:
    """``b + τ·db/dt`` (n, 3): what a first-order lag of ``tau`` s was fed; the slope by a
    centred difference over ± :data:`SLOPE_S` (one-sided at the ends)."""
    if tau <= 0:
        return b.copy()
    lo = np.clip(t - SLOPE_S, t[0], t[-1])
    hi = np.clip(t + SLOPE_S, t[0], t[-1])
    span = np.maximum(hi - lo, 1e-9)
    slope = np.column_stack([(np.interp(hi, t, b[:, j]) - np.interp(lo, t, b[:, j])) / span
                             for j in range(b.shape[1])])
    return b + tau * slope


def _windows(s: BiasSeries) -> dict[str, Any] | None:
    """One series as window means (see the module), or None with no valid sample: per lag
    of :data:`LAG_GRID_S` the de-lagged drift (the same for still windows)."""
    t = np.asarray(s.time_s, dtype=np.float64)
    base = {"kind": s.kind, "device_id": s.device_id, "source": s.source,
            "estimator": s.estimator, "notes": s.notes}
    if s.source == "still":
        keep = s.valid
        d = s.drift[keep].tolist()
        return {**base, "t": t[keep].tolist(), "temp": s.temperature_c[keep].tolist(),
                "drifts": {f"{tau:g}": d for tau in LAG_GRID_S},
                "weight": np.full(int(keep.sum()), WINDOW_S).tolist()}
    if not s.valid.any():
        return None
    applied = s.applied if s.applied is not None else np.zeros_like(s.drift)
    # the lag is the estimator's: undone on its bias, before what was applied is added back
    delagged = [_delag(t, s.drift - applied, tau) + applied for tau in LAG_GRID_S]
    idx = np.floor((t - t[0]) / WINDOW_S).astype(np.int64)
    rows: list[list[float]] = []
    for w in np.unique(idx[s.valid]):
        sel = (idx == w) & s.valid
        wts = np.ones((int(sel.sum()), 3)) if s.variance is None else \
            1.0 / np.maximum(s.variance[sel], 1e-30)
        means = [((wts * d[sel]).sum(axis=0) / wts.sum(axis=0)).tolist() for d in delagged]
        rows.append([float(t[sel].mean()), float(s.temperature_c[sel].mean()),
                     float(np.ptp(t[sel]) + WINDOW_S / max(int(sel.sum()), 1)),
                     *(v for m in means for v in m)])
    a = np.asarray(rows)
    return {**base, "t": a[:, 0].tolist(), "temp": a[:, 1].tolist(), "weight": a[:, 2].tolist(),
            "drifts": {f"{tau:g}": a[:, 3 + 3 * j:6 + 3 * j].tolist()
                       for j, tau in enumerate(LAG_GRID_S)}}


def reduce_log(path: str) -> dict[str, Any]:
    """Read one log (:func:`~thermonet.data.logs.bias.read_bias_log`) into window means:
    plain data a worker returns and the cache holds.  A log that cannot be learned from
    raises :class:`~thermonet.core.errors.InputError` (one line naming it)."""
    log = read_bias_log(path)
    series = [w for s in log.series for w in [_windows(s)] if w is not None]
    if not any(w["source"] == "ekf" for w in series):
        raise InputError.at(path, "the estimator never converged: no valid bias sample "
                            "(every sample invalid, unsettled or before convergence)")
    return {"version": READER_VERSION, "path": str(path), "autopilot": log.autopilot,
            "sensors": log.sensors, "board_id": log.board_id, "duration_s": log.duration_s,
            "params": {k: v for k, v in log.params.items() if k.startswith(
                ("TC_", "CAL_", "INS_", "SENS_BOARD", "AHRS_ORIENT", "EK3_IMU", "MAV_SYS_ID"))},
            "notes": log.notes, "series": series}


def reduce_or_refuse(path: str) -> dict[str, Any]:
    """:func:`reduce_log`, or the log's refusal as ``{"error": line}``: a refusal is an answer
    (cached: the log is not read again), unlike a worker that died (read again next time)."""
    try:
        return reduce_log(path)
    except InputError as err:
        return {"version": READER_VERSION, "path": str(path), "error": str(err)}


def reduce_for_cache(path: str) -> tuple[dict[str, Any], str]:
    """:func:`reduce_or_refuse` as a worker returns it: the reduced log with its columns as
    arrays (:func:`compact`, quick to send) and its cache entry's text, formatted in the worker
    — the driver writes the text as it is and folds the arrays, so it formats no floats (a
    log's ~35,000: 18 ms, a tenth of reading it)."""
    doc = reduce_or_refuse(path)
    text = json.dumps(doc)
    return compact(doc), text


def compact(doc: dict[str, Any]) -> dict[str, Any]:
    """A reduced log as the job holds it while the rest are read: each series's columns as
    numpy arrays (time, temperature and weights float64, the drifts float32 — a ULP of
    float32 is ~1e-7 of the value, far below any drift), not lists of Python floats (about
    eight times the memory).  :func:`gather` reads both."""
    for s in doc.get("series", []):
        for key in ("t", "temp", "weight"):
            s[key] = np.asarray(s[key], dtype=np.float64)
        s["drifts"] = {k: np.asarray(v, dtype=np.float32).reshape(-1, 3)
                       for k, v in s["drifts"].items()}
    return doc


def cache_path(out: Path, digest: str) -> Path:
    """Where the reduction of the log with SHA-256 ``digest`` is cached in ``out``."""
    return out / "cache" / f"{digest[:32]}.json"


def read_cache(path: Path) -> dict[str, Any] | None:
    """A cached reduction (or refusal) of this reader version, else None."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return compact(doc) if isinstance(doc, dict) and doc.get("version") == READER_VERSION \
        else None


def write_cache(path: Path, doc: dict[str, Any] | str) -> None:
    """The cache entry: a reduced log, or its JSON text already made."""
    atomic_write_text(path, doc if isinstance(doc, str) else json.dumps(doc))
