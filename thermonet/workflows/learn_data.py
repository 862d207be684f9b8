"""``thermonet learn``'s data: each log reduced to window means, cached, checked as one vehicle,
aligned for the estimator's lag, cleaned of what did not converge, and mapped by temperature.

A log is read by :func:`reduce_log` (on the process pool or Ray, one log a task: the same
executors as ``fleet``) into plain data: per bias series (:mod:`thermonet.data.logs.bias`)
the means over :data:`WINDOW_S` windows of its valid samples — the drift weighted by the
inverse of the reported variance (equal weights where none is logged), the temperature, and
the temperature through first-order lags of every :data:`LAG_GRID_S` time constant.  So the
memory a job needs is the windows (a 30-minute flight is ~180 per series), not the logs.

Each reduced log is cached in ``DIR/cache/`` under its SHA-256 (:func:`cache_path`) as it
arrives, refusals included: a stopped job loses no log already read, and adding logs to a
directory reads only the new ones.

The estimator's lag (:func:`choose_lag`).  The estimator's bias follows the true bias through
its own filter; for a drift smooth in temperature, a first-order lag of the drift is close to
the drift of the lagged temperature.  So each instance's estimator windows are fitted against
the temperature through the lag (from :data:`LAG_GRID_S`) whose weighted cubic fit over every
flight leaves the smallest median residual; still-gyro windows keep the temperature as read
(the raw gyro has no lag).  The model learned is then the drift at the temperature as read,
what the firmware applies.  Samples before convergence are already dropped by the reader.

Divergence (:func:`reject_outliers`): a window more than :data:`OUTLIER_MADS` robust standard
deviations (1.4826 × MAD) from that fit, on any axis, is left out — an estimator that wandered
off (a maneuver, a bad magnetometer) without its variance saying so.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError
from ..core.fileio import atomic_write_text
from ..data.logs.bias import BIAS_KINDS, BiasSeries, read_bias_log

__all__ = ["WINDOW_S", "LAG_GRID_S", "OUTLIER_MADS", "READER_VERSION", "reduce_log", "reduce_or_refuse",
           "cache_path", "InstanceWindows", "gather", "choose_lag", "reject_outliers",
           "coverage", "missing_words", "TARGET_RANGE_C", "MIN_BIN_FLIGHTS", "MIN_BIN_MINUTES"]

#: Window of the means a log is reduced to, s.
WINDOW_S = 10.0
#: Time constants (s) tried for the estimator's lag (0: none).
LAG_GRID_S = (0.0, 15.0, 30.0, 60.0, 90.0, 120.0, 180.0, 240.0)
#: A window this many robust standard deviations off the fit is left out.
OUTLIER_MADS = 5.0
#: Bumped when the reduction changes: older cache entries are read again.
READER_VERSION = 1
#: The temperatures a vehicle may meet (°C): the coverage map says what of it is missing.
TARGET_RANGE_C = (-10.0, 60.0)
#: A 1 °C bin is supported with at least this many flights and minutes.
MIN_BIN_FLIGHTS = 2
MIN_BIN_MINUTES = 2.0


def _lagged(t: np.ndarray, x: np.ndarray, tau: float) -> np.ndarray:
    """``x`` through a first-order lag of ``tau`` s, settled at ``x[0]`` (step-exact)."""
    if tau <= 0:
        return x.copy()
    out = np.empty_like(x)
    out[0] = x[0]
    for k in range(1, x.size):
        a = math.exp(-(t[k] - t[k - 1]) / tau)
        out[k] = x[k] + (out[k - 1] - x[k]) * a
    return out


def _windows(s: BiasSeries) -> dict[str, Any] | None:
    """One series as window means (see the module), or None with no valid sample."""
    t = np.asarray(s.time_s, dtype=np.float64)
    if s.source == "still":
        lags = {f"{tau:g}": s.temperature_c.tolist() for tau in LAG_GRID_S}
        keep = s.valid
        return {"kind": s.kind, "device_id": s.device_id, "source": s.source,
                "estimator": s.estimator, "t": t[keep].tolist(),
                "drift": s.drift[keep].tolist(), "temp": s.temperature_c[keep].tolist(),
                "lagged": {k: list(np.asarray(v)[keep]) for k, v in lags.items()},
                "weight": np.full(int(keep.sum()), WINDOW_S).tolist(), "notes": s.notes}
    if not s.valid.any():
        return None
    lagged = {f"{tau:g}": _lagged(t, s.temperature_c, tau) for tau in LAG_GRID_S}
    idx = np.floor((t - t[0]) / WINDOW_S).astype(np.int64)
    rows: list[list[float]] = []
    for w in np.unique(idx[s.valid]):
        sel = (idx == w) & s.valid
        wts = np.ones((int(sel.sum()), 3)) if s.variance is None else \
            1.0 / np.maximum(s.variance[sel], 1e-30)
        drift = (wts * s.drift[sel]).sum(axis=0) / wts.sum(axis=0)
        rows.append([float(t[sel].mean()), float(s.temperature_c[sel].mean()), *drift,
                     *(float(v[sel].mean()) for v in lagged.values()),
                     float(np.ptp(t[sel]) + WINDOW_S / max(int(sel.sum()), 1))])
    a = np.asarray(rows)
    n = len(LAG_GRID_S)
    return {"kind": s.kind, "device_id": s.device_id, "source": s.source,
            "estimator": s.estimator, "t": a[:, 0].tolist(), "temp": a[:, 1].tolist(),
            "drift": a[:, 2:5].tolist(),
            "lagged": {f"{tau:g}": a[:, 5 + j].tolist() for j, tau in enumerate(LAG_GRID_S)},
            "weight": a[:, 5 + n].tolist(), "notes": s.notes}


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
                ("TC_", "CAL_", "INS_", "SENS_BOARD", "AHRS_ORIENT", "EK3_IMU"))},
            "notes": log.notes, "series": series}


def reduce_or_refuse(path: str) -> dict[str, Any]:
    """:func:`reduce_log`, or the log's refusal as ``{"error": line}``: a refusal is an answer
    (cached: the log is not read again), unlike a worker that died (read again next time)."""
    try:
        return reduce_log(path)
    except InputError as err:
        return {"version": READER_VERSION, "path": str(path), "error": str(err)}


def cache_path(out: Path, digest: str) -> Path:
    """Where the reduction of the log with SHA-256 ``digest`` is cached in ``out``."""
    return out / "cache" / f"{digest[:32]}.json"


def read_cache(path: Path) -> dict[str, Any] | None:
    """A cached reduction (or refusal) of this reader version, else None."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("version") == READER_VERSION else None


def write_cache(path: Path, doc: dict[str, Any]) -> None:
    atomic_write_text(path, json.dumps(doc))


@dataclass
class InstanceWindows:
    """One sensor instance's windows over every flight: per window its flight (index into
    ``flights``), time, temperature as read and lagged, drift (n, 3), weight (s of data), and
    whether it came from still-gyro windows."""

    kind: str
    device_id: int
    name: str
    flights: list[str]
    flight: np.ndarray
    time_s: np.ndarray
    temp: np.ndarray
    lagged: dict[str, np.ndarray]
    drift: np.ndarray
    weight: np.ndarray
    still: np.ndarray
    notes: list[str] = field(default_factory=list)
    lag_s: float = 0.0
    keep: np.ndarray | None = None

    @property
    def aligned(self) -> np.ndarray:
        """The temperature each window's drift belongs to: lagged for the estimator's."""
        return np.where(self.still, self.temp, self.lagged[f"{self.lag_s:g}"])


def _name_of(sensors: dict[str, int], kind: str, dev: int) -> str:
    return next((n for n, d in sensors.items() if d == dev and n.startswith(kind)),
                f"{kind}-{dev}")


def gather(logs: list[dict[str, Any]]) -> list[InstanceWindows]:
    """Every instance's windows over the logs (in the order given: one flight a log); an
    estimator window within :data:`WINDOW_S` of a still window of its flight is dropped (the
    still window measures the same bias directly)."""
    acc: dict[tuple[str, int], list[tuple[int, dict[str, Any]]]] = {}
    for k, lg in enumerate(logs):
        for s in lg["series"]:
            if s["kind"] in BIAS_KINDS and s["t"]:
                acc.setdefault((s["kind"], int(s["device_id"])), []).append((k, s))
    out = []
    for (kind, dev), parts in sorted(acc.items()):
        cols: dict[str, list[Any]] = {c: [] for c in ("flight", "t", "temp", "drift", "weight",
                                                      "still")}
        lag: dict[str, list[float]] = {f"{tau:g}": [] for tau in LAG_GRID_S}
        for k, s in parts:
            t = np.asarray(s["t"])
            keep = np.ones(t.size, dtype=bool)
            if s["source"] == "ekf":
                stills = [np.asarray(p["t"]) for kk, p in parts if kk == k and
                          p["source"] == "still"]
                for st in stills:
                    near = np.abs(t[:, None] - st[None, :]).min(axis=1) < WINDOW_S if \
                        st.size else np.zeros(t.size, dtype=bool)
                    keep &= ~near
            cols["flight"].append(np.full(int(keep.sum()), k))
            cols["t"].append(t[keep])
            cols["temp"].append(np.asarray(s["temp"])[keep])
            cols["drift"].append(np.asarray(s["drift"]).reshape(-1, 3)[keep])
            cols["weight"].append(np.asarray(s["weight"])[keep])
            cols["still"].append(np.full(int(keep.sum()), s["source"] == "still"))
            for key in lag:
                lag[key].extend(np.asarray(s["lagged"][key])[keep].tolist())
        names = [lg["path"] for lg in logs]
        out.append(InstanceWindows(
            kind, dev, _name_of(logs[parts[0][0]]["sensors"], kind, dev), names,
            np.concatenate(cols["flight"]), np.concatenate(cols["t"]),
            np.concatenate(cols["temp"]), {k: np.asarray(v) for k, v in lag.items()},
            np.concatenate(cols["drift"]), np.concatenate(cols["weight"]),
            np.concatenate(cols["still"])))
    return out


def _cubic_residuals(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Residuals (n, 3) of a weighted cubic in ``x`` per axis (a line with few points)."""
    deg = 3 if np.unique(np.round(x, 1)).size > 6 else 1
    xc = x - x.mean()
    res = np.empty_like(y)
    for j in range(y.shape[1]):
        c = np.polyfit(xc, y[:, j], deg, w=np.sqrt(w))
        res[:, j] = y[:, j] - np.polyval(c, xc)
    return res


def choose_lag(inst: InstanceWindows) -> dict[str, float]:
    """Set ``inst.lag_s`` to the :data:`LAG_GRID_S` lag whose cubic leaves the smallest median
    residual (relative per axis) over every flight; each lag's score, by its name."""
    scores: dict[str, float] = {}
    scale = np.maximum(np.ptp(inst.drift, axis=0), 1e-12)
    for tau in LAG_GRID_S:
        inst.lag_s = tau
        if inst.time_s.size < 8:
            scores[f"{tau:g}"] = math.inf
            continue
        res = _cubic_residuals(inst.aligned, inst.drift, inst.weight)
        scores[f"{tau:g}"] = float(np.mean(np.median(np.abs(res), axis=0) / scale))
    if not inst.still.all():
        inst.lag_s = float(min(LAG_GRID_S, key=lambda tau: scores[f"{tau:g}"]))
    else:
        inst.lag_s = 0.0
    return scores


def reject_outliers(inst: InstanceWindows) -> int:
    """Mark (``inst.keep``) the windows within :data:`OUTLIER_MADS` robust standard
    deviations of the cubic (two passes); the number left out."""
    keep = np.ones(inst.time_s.size, dtype=bool)
    for _ in range(2):
        if keep.sum() < 8:
            break
        full = np.zeros_like(inst.drift)
        x = inst.aligned
        # every window's residual from the cubic fitted on the kept ones
        for j in range(3):
            xc = x[keep].mean()
            deg = 3 if np.unique(np.round(x[keep], 1)).size > 6 else 1
            c = np.polyfit(x[keep] - xc, inst.drift[keep, j], deg, w=np.sqrt(inst.weight[keep]))
            full[:, j] = inst.drift[:, j] - np.polyval(c, x - xc)
        sigma = 1.4826 * np.median(np.abs(full[keep]), axis=0)
        keep = np.all(np.abs(full) <= OUTLIER_MADS * np.maximum(sigma, 1e-12), axis=1)
    inst.keep = keep
    return int((~keep).sum())


def coverage(inst: InstanceWindows) -> list[dict[str, Any]]:
    """Per 1 °C bin of the aligned temperature (kept windows): flights and minutes."""
    keep = inst.keep if inst.keep is not None else np.ones(inst.time_s.size, dtype=bool)
    x = inst.aligned[keep]
    if not x.size:
        return []
    bins = np.floor(x).astype(np.int64)
    out = []
    for b in range(int(bins.min()), int(bins.max()) + 1):
        sel = bins == b
        out.append({"bin_c": b, "flights": int(np.unique(inst.flight[keep][sel]).size),
                    "minutes": round(float(inst.weight[keep][sel].sum()) / 60.0, 2)})
    return out


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
    ok = [c["bin_c"] for c in cov if c["flights"] >= MIN_BIN_FLIGHTS
          and c["minutes"] >= MIN_BIN_MINUTES]
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
        words.append(f"nothing supports it above {hi} °C: fly once on a hot day (above "
                     f"{hi} °C at the sensor) to cover the hot end")
    holes = [b for b in range(lo, hi) if b not in ok]
    for a, b in _runs(holes):
        words.append(f"{a}..{b + 1} °C rests on fewer than {MIN_BIN_FLIGHTS} flights or "
                     f"{MIN_BIN_MINUTES:g} minutes: fly once more around {(a + b + 1) / 2:.0f} °C")
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
        return (f"a {lg['autopilot']} log among {ap} logs: one vehicle, one autopilot "
                "(learn them in separate directories)")
    if lg.get("board_id") and board and lg["board_id"] != board:
        return f"another board (board id {lg['board_id']}, the vehicle's is {board})"
    if lg["sensors"] != sensors:
        mine = ", ".join(f"{k} {v}" for k, v in sorted(lg["sensors"].items()))
        theirs = ", ".join(f"{k} {v}" for k, v in sorted(sensors.items()))
        return f"another vehicle's sensors (device ids {mine}; the vehicle's: {theirs})"
    return None
