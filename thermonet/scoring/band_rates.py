"""What a residual-drift band (:mod:`thermonet.scoring.band`) rests on, per window: the
window means of a run's rows, the temperature's rate in each window and the direction of the
thermal excursion it belongs to, and the conditions the band was judged on — per direction
the fastest rate its calibration windows held (:func:`holds_for`), and which test windows lie
outside them (:func:`outside_holds`).

A window's direction is its excursion's (:func:`thermonet.scoring.folds.excursions`: the
soak at a turn belongs to the leg that ends there), not its own slope: a sensor lagging its
thermometer by minutes still carries a cooling's error through the soak after it and through
the first minutes of the heating that follows, where the window's own slope would call it a
soak or a heating.  Torch-free, numpy only."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .folds import excursions

__all__ = ["min_windows", "window_means", "window_rates", "holds_for",
           "holds_meaning", "outside_holds", "sample_directions", "window_directions"]


def min_windows(level: float) -> int:
    """The fewest scores whose finite-sample conformal quantile at ``level`` is finite:
    the smallest n with ⌈(n + 1)·level⌉ ≤ n (9 for 0.9, 19 for 0.95)."""
    n = 1
    while math.ceil((n + 1) * level - 1e-9) > n:
        n += 1
    return n


def window_means(values: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Means of ``values`` (n, C) per label, and the samples per window."""
    u, inv = np.unique(labels, return_inverse=True)
    n = np.bincount(inv, minlength=u.size).astype(np.float64)
    sums = np.zeros((u.size, values.shape[1]))
    np.add.at(sums, inv, values)
    return sums / n[:, None], n


def holds_for(rates: np.ndarray, directions: np.ndarray, level: float
              ) -> dict[str, float | None]:
    """Per direction the fastest rate (°C/min, ``rates`` signed slopes) among the windows of
    its excursions (``directions``: +1, −1, 0 per window), None where fewer than
    :func:`min_windows` windows held it."""
    r = np.asarray(rates, dtype=np.float64)
    d = np.asarray(directions)
    out: dict[str, float | None] = {}
    for name, sign in (("heating", 1), ("cooling", -1)):
        sel = (d == sign) & np.isfinite(r)
        out[name] = float(np.abs(r[sel]).max()) if sel.sum() >= min_windows(level) else None
    return out


def holds_meaning(held: Mapping[str, float | None]) -> str:
    """What :attr:`Band.holds_for` states, in words."""
    said = [f"{k} up to {v:.3g} °C/min" for k, v in held.items() if v is not None]
    never = [k for k, v in held.items() if v is None]
    text = ("judged by its folds on " + " and ".join(said) if said else
            "judged by its folds on soaks only")
    if never:
        text += f"; never on {' or '.join(never)}: there it states nothing"
    return text + " (a faster ramp or another direction is outside what it states)"


def outside_holds(held: Mapping[str, float | None], rates: np.ndarray,
                  directions: np.ndarray) -> np.ndarray:
    """Per window (signed rate °C/min, its excursion's direction): outside what the band
    states — an excursion in a direction never judged, or a window faster than the fastest
    judged in its direction; a run that never moves (direction 0) is inside; a direction that
    is not −1, 0 or +1 is outside.  A rate that is not finite (NaN: unknown — a window of
    one time, a NaN temperature) is outside whatever the direction: the band cannot say it
    holds there.  Nothing stated: nothing else outside.  The runtime's ``band_holds_rule``
    and the C header's ``<prefix>_band_holds`` are this rule (:mod:`.c_band` checks C)."""
    r = np.asarray(rates, dtype=np.float64).reshape(-1)
    d = np.asarray(directions)
    out = ~np.isfinite(r)
    if not held:
        return out
    out |= ~np.isin(d, (-1, 0, 1))
    for name, sign in (("heating", 1), ("cooling", -1)):
        top = held.get(name)
        sel = d == sign
        out |= sel & (True if top is None else np.abs(r) > top)
    return out


def sample_directions(temperature: np.ndarray) -> np.ndarray:
    """Per sample of one run, the direction of its excursion (+1 heating, −1 cooling, 0 a run
    that never moves): :func:`thermonet.scoring.folds.excursions`."""
    x = np.asarray(temperature, dtype=np.float64)
    out = np.zeros(x.size, dtype=np.int8)
    for leg in excursions(x):
        out[leg.start:leg.stop] = leg.direction
    return out


def window_directions(directions: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Per window (``labels``, ordered as :func:`window_means`) the direction most of its
    samples' excursions have (0 on a tie)."""
    means, _ = window_means(np.asarray(directions, dtype=np.float64)[:, None], labels)
    return np.sign(np.round(means[:, 0], 12)).astype(np.int8)


def window_rates(time_s: np.ndarray, temperature: np.ndarray, labels: np.ndarray
                 ) -> np.ndarray:
    """Per window (``labels``, as :func:`window_labels`) the least-squares slope of the
    temperature against time, °C/min (NaN with fewer than two distinct times)."""
    t = np.asarray(time_s, dtype=np.float64)
    x = np.asarray(temperature, dtype=np.float64)
    tc = t - (t[0] if t.size else 0.0)
    means, _ = window_means(np.column_stack([tc, x, tc * tc, tc * x]), labels)
    var = means[:, 2] - means[:, 0] ** 2
    cov = means[:, 3] - means[:, 0] * means[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(var > 1e-9 * np.maximum(means[:, 2], 1.0), 60.0 * cov / var, np.nan)
