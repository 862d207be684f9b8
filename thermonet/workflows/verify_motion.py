"""Whether a log ``thermonet verify`` is given is a warm-up at rest (:func:`moving_log`).

verify judges a calibration by the binned drift of the sensors' output against their
temperature, which is the drift only while the vehicle does not move: in flight the gyro
reads the vehicle's turns and the accelerometer its accelerations, every 1 °C bin's mean
holds them, and every axis looks uncorrected (about 1.0x).  The test of stillness is
``learn``'s (:func:`thermonet.data.logs.bias.still_windows`: 10-s windows where every gyro
axis's standard deviation is under 0.01 rad/s and its mean under 0.1 rad/s); a log whose
gyros are still in fewer than :data:`MIN_STILL_SHARE` of their windows is refused.
"""

from __future__ import annotations

import numpy as np

from ..data.logs import FlightLog
from ..data.logs.bias import STILL_WINDOW_S, still_windows

__all__ = ["MIN_STILL_SHARE", "MIN_WINDOWS", "moving_log"]

#: A log is a warm-up at rest when its gyros are still in at least this share of their
#: windows (a bench or chamber warm-up: all of them; a flight: about a third).
MIN_STILL_SHARE = 0.8
#: Fewer windows of at least five samples than this: too little to tell (not refused).
MIN_WINDOWS = 10


def _windows(time_s: np.ndarray) -> int:
    """The still-detection windows of at least five samples (those ``still_windows`` judges)."""
    t = np.asarray(time_s, dtype=np.float64)
    if t.size < 5:
        return 0
    _, counts = np.unique(np.floor((t - t[0]) / STILL_WINDOW_S), return_counts=True)
    return int(np.count_nonzero(counts >= 5))


def moving_log(log: FlightLog) -> str | None:
    """Why ``log`` is not a warm-up at rest (one phrase naming the gyro and its share of
    still windows), or None: still, or too short or too sparse to tell."""
    best: tuple[float, str] | None = None
    for inst in log.instances:
        if inst.kind != "gyro" or inst.temperature_c is None:
            continue
        n = _windows(inst.time_s)
        if n < MIN_WINDOWS:
            continue
        series = still_windows(inst, log.autopilot, log.params)
        share = (0 if series is None else int(series.time_s.size)) / n
        if share >= MIN_STILL_SHARE:
            return None                # one gyro still: the vehicle is
        if best is None or share > best[0]:
            best = (share, inst.name)
    if best is None:
        return None
    return (f"the vehicle moves: {best[1]} is still in only {best[0]:.0%} of its "
            f"{STILL_WINDOW_S:g}-s windows (at rest: at least {MIN_STILL_SHARE:.0%})")
