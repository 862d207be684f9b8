"""The style and scales every comparison plot shares (:mod:`thermonet.reporting.plots`).

Figure size and resolution, the family colours (:func:`family_colours`), how noisy samples
are binned and thinned, the y-scale from binned means (:func:`y_limits`), the time unit
(:func:`time_unit`), and the figure/save helpers.  Split from the figure functions so that
each module stays one reader's size; the conventions themselves are documented in
:mod:`thermonet.reporting.plots`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ..core.recording import GAP_FACTOR
from ..scoring.metrics import _series  # one 1-D series check for metrics and plots
from .colours import PALETTE, family_colours  # noqa: F401  re-exported: the plots' colours

#: Figure size, inches (width, height); with :data:`DPI` gives 1000 × 600 px.
FIGSIZE_IN = (10.0, 6.0)
#: Resolution of the PNG files, dots per inch.
DPI = 100
#: Scatter plots show at most this many samples (evenly strided in time).
MAX_SCATTER_POINTS = 5000
#: Time series keep at most about this many vertices: a min and a max per pixel column.
MAX_LINE_POINTS = 2 * int(FIGSIZE_IN[0] * DPI)

#: Time series are averaged in at most this many equal time bins (about 1/200 of the span,
#: 5 px each), for the lines drawn over the noise and for the y-scale.
LIMIT_BINS = 200
#: … and in fewer bins where there are not this many samples per bin.
MIN_BIN_SAMPLES = 10
#: Margin added below and above the binned means' range, as a fraction of that range.
Y_MARGIN = 0.08
#: Added to the legend label of a curve whose binned means leave the frame.
OFF_SCALE = "(off scale)"
# A bin counts for the y-scale when it holds at least this fraction of the median bin's
# samples: a sparsely filled bin (the end of a ramp, a stray thermometer reading) has a
# noise-level mean.
_DENSE_FRACTION = 0.25
# Time units by the recording's length: (longest span shown in the unit, name, seconds).
_TIME_UNITS = ((600.0, "s", 1.0), (3 * 3600.0, "min", 60.0), (math.inf, "h", 3600.0))
# Tick steps (MaxNLocator's nice mantissas) that suit each unit: 15 / 30 min, 6 / 12 h.
_TIME_STEPS = {"s": [1, 2, 2.5, 5, 10], "min": [1, 1.5, 2, 3, 5, 6, 10],
               "h": [1, 2, 2.5, 3, 5, 6, 10]}

# A step longer than GAP_FACTOR median sample intervals is a gap in the log (burst mode, a
# pause between soaks); the line is broken there instead of drawing a straight segment across
# hours without data.

_RAW_COLOR = "0.55"
_RAW_BINNED_COLOR = "0.2"

def _style(name: str, colours: Mapping[str, str] | None, chosen: str | None,
           baseline: str | None, index: int) -> dict[str, Any]:
    """Line style of one family: its colour, stronger when chosen or the baseline."""
    colour = (colours or {}).get(name) or family_colours([f"_{k}" for k in range(index + 1)]
                                                          )[f"_{index}"]
    if name == chosen:
        return {"color": colour, "linewidth": 2.8, "alpha": 1.0, "zorder": 5,
                "label": f"{name} (chosen)"}
    if name == baseline:
        return {"color": colour, "linewidth": 2.2, "alpha": 1.0, "zorder": 4,
                "linestyle": "--", "label": f"{name} (baseline)"}
    return {"color": colour, "linewidth": 1.1, "alpha": 0.8, "zorder": 3, "label": name}


def _centred(y: np.ndarray) -> np.ndarray:
    """``y`` minus its mean over the finite samples (a NaN, e.g. a warm-up sample, stays NaN)."""
    finite = np.isfinite(y)
    return y - np.mean(y[finite]) if finite.any() else y


def _bin_means(x: np.ndarray, y: np.ndarray, width: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means of ``y`` in ``width``-wide bins :math:`[k\\,w, (k+1)\\,w)` of ``x`` (the
    convention of :func:`thermonet.scoring.metrics.binned_means`), over the pairs where both
    are finite: occupied bins' centres (ascending), means and sample counts."""
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any() or not (math.isfinite(width) and width > 0):
        empty = np.empty(0)
        return empty, empty, np.empty(0, dtype=np.int64)
    idx = np.floor(x[ok] / width).astype(np.int64)
    keys, inv = np.unique(idx, return_inverse=True)
    counts = np.bincount(inv)
    return (keys + 0.5) * width, np.bincount(inv, weights=y[ok]) / counts, counts


def _binned(x: np.ndarray, y: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Binned means, with a NaN between bins that are not neighbours (no line across a
    temperature range without data, e.g. between two isothermal soaks)."""
    centres, means, _ = _bin_means(x, y, width)
    cuts = np.flatnonzero(np.diff(centres) > 1.5 * width) + 1
    return np.insert(centres, cuts, np.nan), np.insert(means, cuts, np.nan)


def _n_bins(n: int) -> int:
    """How many bins a series of ``n`` samples is averaged in: :data:`LIMIT_BINS`, fewer where
    a bin would hold less than :data:`MIN_BIN_SAMPLES` samples."""
    return max(1, min(LIMIT_BINS, n // MIN_BIN_SAMPLES))


def _dense(means: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """``means`` with NaN where a bin holds under a quarter of the median occupied bin's
    samples: those do not set the y-scale."""
    occupied = counts > 0
    if not occupied.any():
        return np.full(means.shape, np.nan)
    floor = max(1.0, _DENSE_FRACTION * float(np.median(counts[occupied])))
    return np.where(counts >= floor, means, np.nan)


def _even_bins(x: np.ndarray, y: np.ndarray, smooth: bool = False
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means of ``y`` in :func:`_n_bins` equal bins spanning ``x``'s finite range: every bin's
    centre, mean (NaN where empty: a gap in the log breaks the line) and count.

    A ``smooth`` series (a model's curve, not noise to average away) takes up to
    :data:`LIMIT_BINS` bins however few its samples: ten soaks' curve keeps its ten values.
    """
    ok = np.isfinite(x) & np.isfinite(y)
    nb = min(LIMIT_BINS, max(1, int(ok.sum()))) if smooth else _n_bins(int(ok.sum()))
    if not ok.any():
        empty = np.empty(0)
        return empty, empty, np.empty(0, dtype=np.int64)
    lo, hi = float(x[ok].min()), float(x[ok].max())
    if hi <= lo:
        return np.array([lo]), np.array([float(np.mean(y[ok]))]), np.array([int(ok.sum())])
    edges = np.linspace(lo, hi, nb + 1)
    idx = np.clip(np.searchsorted(edges, x[ok], side="right") - 1, 0, nb - 1)
    counts = np.bincount(idx, minlength=nb)
    sums = np.bincount(idx, weights=y[ok], minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    return 0.5 * (edges[:-1] + edges[1:]), means, counts


def y_limits(series: Sequence[np.ndarray], margin: float = Y_MARGIN
             ) -> tuple[float, float] | None:
    """The y-limits that show every finite value of ``series`` (binned means), with ``margin``
    of their range added below and above; None where there is no finite value or no range
    (matplotlib's own autoscaling then applies)."""
    finite = [v[np.isfinite(v)] for v in (np.asarray(s, dtype=np.float64).ravel()
                                          for s in series)]
    values = np.concatenate(finite) if finite else np.empty(0)
    if values.size == 0:
        return None
    lo, hi = float(values.min()), float(values.max())
    span = hi - lo
    if not (span > 0 and math.isfinite(span)):
        return None
    return lo - margin * span, hi + margin * span


def _off_scale(values: np.ndarray, limits: tuple[float, float] | None) -> bool:
    """True where a finite value of ``values`` lies outside ``limits``."""
    if limits is None:
        return False
    v = values[np.isfinite(values)]
    return bool(v.size) and bool((v.min() < limits[0]) or (v.max() > limits[1]))


def _scale_sources(names: Sequence[str], chosen: str | None, baseline: str | None) -> list[str]:
    """The families whose binned means set the y-scale besides raw: the chosen and the baseline."""
    return [n for n in names if n in (chosen, baseline)]


#: ``gid`` of the figure text that explains the y-scale when a curve leaves the frame.
Y_SCALE_NOTE = "y-scale-note"


def _apply_limits(ax: Axes, limits: tuple[float, float] | None, any_off_scale: bool) -> None:
    """Set the y-limits from the binned means (the noise and any off-scale curve are clipped)."""
    if limits is None:
        return
    ax.set_ylim(*limits)
    ax.yaxis.set_major_locator(MaxNLocator(nbins="auto", steps=[1, 2, 2.5, 5, 10]))
    if any_off_scale:
        # below the axes, in the figure's bottom-left corner (under the tick labels, left of
        # the centred x label): never over the legend or the curves, wherever "best" puts it
        ax.figure.text(0.01, 0.008, f"y-scale: binned means of raw, the baseline and the "
                       f"chosen family; curves marked {OFF_SCALE} leave the frame",
                       fontsize=7, color="0.3", ha="left", va="bottom", gid=Y_SCALE_NOTE)


def time_unit(span_s: float) -> tuple[str, float]:
    """The unit a time axis spanning ``span_s`` seconds is drawn in, and its length in s.

    ``("s", 1.0)`` up to 10 min, ``("min", 60.0)`` up to 3 h, ``("h", 3600.0)`` beyond: a
    200 s recording runs 0–200 s, not 0–0.056 h.
    """
    span = float(span_s) if math.isfinite(float(span_s)) else 0.0
    for longest, name, seconds in _TIME_UNITS:
        if span <= longest:
            return name, seconds
    return _TIME_UNITS[-1][1], _TIME_UNITS[-1][2]  # pragma: no cover - inf covers every span


def duration_text(seconds: float) -> str:
    """A duration in the unit a reader thinks in: ``5.57 s`` (under 2 min), ``12.5 min``
    (under 2 h), ``3.5 h`` — a window of 5.6 s is never "0.0929 min"."""
    s = float(seconds)
    if not math.isfinite(s) or s < 120.0:
        return f"{s:.3g} s"
    if s < 7200.0:
        return f"{s / 60.0:.3g} min"
    return f"{s / 3600.0:.3g} h"


def _bin_text(width: float, x_label: str) -> str:
    unit = x_label[x_label.rfind("(") + 1: -1] if x_label.endswith(")") else ""
    return f"{width:.3g} {unit}".strip() + " binned means"


def _check_length(name: str, arr: np.ndarray, n: int, against: str) -> None:
    if arr.shape[0] != n:
        raise ValueError(f"'{name}' has {arr.shape[0]} samples, '{against}' has {n}")


def _residuals(compensated: Mapping[str, np.ndarray], n: int, against: str
               ) -> dict[str, np.ndarray]:
    """Each family's residual as a checked 1-D series of ``n`` samples (as long as ``against``)."""
    out = {}
    for name, r in compensated.items():
        out[name] = _series(f"compensated['{name}']", r)
        _check_length(f"compensated['{name}']", out[name], n, against)
    return out


def _title(ax: Axes, text: str) -> None:
    """The axes' title at its default place, stated: ``y=1.0`` is where matplotlib puts it
    over axes with nothing above them, and naming it skips the search for decorations above
    (a tight bounding box of the x axis per draw, a fifth of a figure's drawing time); the
    pixels are the same."""
    ax.set_title(text, y=1.0)


def _new_figure() -> tuple[Figure, Axes]:
    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI)
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot(1, 1, 1)


def _save(fig: Figure, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # No bbox_inches="tight": the file must keep the documented pixel size.
    fig.savefig(path, format="png", dpi=DPI)
    fig.clear()
    return path


def _stride(n: int, max_points: int) -> np.ndarray:
    """Indices of at most ``max_points`` samples, evenly spread, in time order."""
    if n <= max_points:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, max_points).round().astype(np.int64))


def _minmax_indices(y: np.ndarray, max_points: int) -> np.ndarray:
    """Indices of the min and max of ``y`` in each of ``max_points // 2`` buckets.

    Plain striding would hide spikes and the true noise envelope; the min/max
    pair per bucket draws the same band a full-resolution plot would.
    """
    n = y.size
    if n <= max_points:
        return np.arange(n)
    size = -(-n // (max_points // 2))  # ceil: samples per bucket
    rows = -(-n // size)
    # Pad with the last value (not NaN) so every bucket has a plain min and max.
    padded = np.full(rows * size, y[-1])
    padded[:n] = y
    blocks = padded.reshape(rows, size)
    base = np.arange(rows) * size
    keep = np.concatenate([base + np.argmin(blocks, axis=1),
                           base + np.argmax(blocks, axis=1)])
    return np.unique(np.minimum(keep, n - 1))


def _gap_breaks(t: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Positions in ``keep`` before which a NaN breaks the line at a time gap."""
    steps = np.diff(t)
    if steps.size == 0:
        return np.empty(0, dtype=np.int64)
    gaps = np.flatnonzero(steps > GAP_FACTOR * np.median(steps)) + 1
    pos = np.unique(np.searchsorted(keep, gaps))
    return pos[(pos > 0) & (pos < keep.size)]


def _legend(ax: Axes) -> None:
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        ax.legend(loc="best", fontsize=8, ncol=2 if len(handles) > 8 else 1)
