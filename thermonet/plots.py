"""Comparison plots of the compensation families, written as PNG files.

Figures are built with :class:`matplotlib.figure.Figure` and rendered by the
Agg canvas directly, never through ``pyplot``: nothing registers in pyplot's
figure manager, so thousands of calls leak no figures and no display backend
is ever needed (or switched for the rest of the process).

Every function takes the output path first, writes one PNG of
:data:`FIGSIZE_IN` × :data:`DPI` pixels, creates missing parent directories
and returns the :class:`~pathlib.Path` written.  Long series are decimated
before drawing so a plot takes well under a second on 50k samples.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .metrics import _series, allan  # one 1-D series check for metrics and plots
from .recording import GAP_FACTOR

__all__ = [
    "plot_drift_vs_temperature",
    "plot_residual_vs_time",
    "plot_allan",
    "FIGSIZE_IN",
    "DPI",
    "MAX_SCATTER_POINTS",
    "MAX_LINE_POINTS",
]

#: Figure size, inches (width, height); with :data:`DPI` gives 1000 × 600 px.
FIGSIZE_IN = (10.0, 6.0)
#: Resolution of the PNG files, dots per inch.
DPI = 100
#: Scatter plots show at most this many samples (evenly strided in time).
MAX_SCATTER_POINTS = 5000
#: Time series keep at most about this many vertices (min/max per bucket).
MAX_LINE_POINTS = 8000

# A step longer than GAP_FACTOR median sample intervals is a gap in the log (burst mode, a
# pause between soaks); the line is broken there instead of drawing a straight segment across
# hours without data.

_RAW_COLOR = "0.55"


def _check_length(name: str, arr: np.ndarray, n: int, against: str) -> None:
    if arr.shape[0] != n:
        raise ValueError(f"'{name}' has {arr.shape[0]} samples, '{against}' has {n}")


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


def plot_drift_vs_temperature(path: str | Path, *, temperature_c: np.ndarray,
                              observed_drift: np.ndarray,
                              curves: Mapping[str, tuple[np.ndarray, np.ndarray]],
                              axis: str, units: str) -> Path:
    """Scatter of observed drift against temperature, one line per model family.

    Parameters
    ----------
    path : str or Path
        PNG file to write.
    temperature_c : ndarray, shape (n,)
        Device temperature, °C.
    observed_drift : ndarray, shape (n,)
        Output minus reference, ``units``; at most :data:`MAX_SCATTER_POINTS`
        are drawn.
    curves : mapping of str to (ndarray, ndarray)
        Family name → (temperature grid in °C, predicted drift in ``units``).
    axis : str
        Channel name for the title (``gyro_x``).
    units : str
        Units of the drift (``deg/s``).

    Returns
    -------
    Path
        The file written.
    """
    t = _series("temperature_c", temperature_c)
    d = _series("observed_drift", observed_drift)
    _check_length("observed_drift", d, t.size, "temperature_c")
    fig, ax = _new_figure()
    keep = _stride(t.size, MAX_SCATTER_POINTS)
    ax.scatter(t[keep], d[keep], s=4, color=_RAW_COLOR, alpha=0.5, linewidths=0,
               label=f"observed ({t.size} samples)", rasterized=True)
    for name, curve in curves.items():
        if len(curve) != 2:
            raise ValueError(f"curve '{name}' must be (temperature_grid, predicted), "
                             f"got {len(curve)} items")
        grid = _series(f"curves['{name}'][0]", curve[0])
        pred = _series(f"curves['{name}'][1]", curve[1])
        _check_length(f"curves['{name}'][1]", pred, grid.size, f"curves['{name}'][0]")
        order = np.argsort(grid, kind="stable")
        ax.plot(grid[order], pred[order], linewidth=2, label=name)
    ax.set_title(f"{axis}: drift vs temperature")
    ax.set_xlabel("temperature (°C)")
    ax.set_ylabel(f"drift ({units})")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")
    return _save(fig, path)


def plot_residual_vs_time(path: str | Path, *, time_s: np.ndarray, raw_error: np.ndarray,
                          compensated: Mapping[str, np.ndarray], axis: str,
                          units: str) -> Path:
    """Error against time before compensation and after each family's compensation.

    Parameters
    ----------
    path : str or Path
        PNG file to write.
    time_s : ndarray, shape (n,)
        Sample times, s (plotted in hours when the run is longer than 2 h).
    raw_error : ndarray, shape (n,)
        Output minus reference before compensation, ``units``.
    compensated : mapping of str to ndarray
        Family name → residual after compensation, shape (n,), ``units``.
    axis, units : str
        Channel name and units for the title and labels.

    Returns
    -------
    Path
        The file written.
    """
    t = _series("time_s", time_s)
    raw = _series("raw_error", raw_error)
    _check_length("raw_error", raw, t.size, "time_s")
    residuals = {}
    for name, r in compensated.items():
        residuals[name] = _series(f"compensated['{name}']", r)
        _check_length(f"compensated['{name}']", residuals[name], t.size, "time_s")
    span = float(np.ptp(t)) if t.size else 0.0
    scale, t_unit = (3600.0, "h") if span > 7200.0 else (1.0, "s")

    fig, ax = _new_figure()
    series: list[tuple[str, np.ndarray, dict[str, Any]]] = [("raw", raw, {"color": _RAW_COLOR})]
    for name, y, kw in series + [(name, r, {}) for name, r in residuals.items()]:
        keep = _minmax_indices(y, MAX_LINE_POINTS)
        breaks = _gap_breaks(t, keep)
        x_d = np.insert(t[keep], breaks, np.nan)
        y_d = np.insert(y[keep], breaks, np.nan)
        ax.plot(x_d / scale, y_d, linewidth=0.8, label=name, **kw)
    ax.set_title(f"{axis}: error vs time, before and after compensation")
    ax.set_xlabel(f"time ({t_unit})")
    ax.set_ylabel(f"error ({units})")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")
    return _save(fig, path)


def plot_allan(path: str | Path, *, rate_hz: float, raw_error: np.ndarray,
               compensated: Mapping[str, np.ndarray], axis: str, units: str) -> Path:
    """Log-log overlapping Allan deviation before and after compensation.

    Uses :func:`thermonet.metrics.allan` (octave averaging times); samples are
    taken as contiguous at ``rate_hz``.  A series too short for any averaging
    time is left out of the plot.

    Parameters
    ----------
    path : str or Path
        PNG file to write.
    rate_hz : float
        Sample rate, Hz.
    raw_error : ndarray, shape (n,)
        Output minus reference before compensation, ``units``.
    compensated : mapping of str to ndarray
        Family name → residual after compensation, ``units``.
    axis, units : str
        Channel name and units for the title and labels.

    Returns
    -------
    Path
        The file written.
    """
    raw = _series("raw_error", raw_error)
    fig, ax = _new_figure()
    for name, y, kw in [("raw", raw, {"color": _RAW_COLOR})] + [
            (name, _series(f"compensated['{name}']", r), {}) for name, r in compensated.items()]:
        taus, adev = allan(y, rate_hz)
        positive = adev > 0  # a log axis cannot show a zero deviation
        if positive.any():
            ax.loglog(taus[positive], adev[positive], marker="o", markersize=3, label=name, **kw)
    ax.set_title(f"{axis}: overlapping Allan deviation")
    ax.set_xlabel("averaging time τ (s)")
    ax.set_ylabel(f"Allan deviation ({units})")
    ax.grid(True, which="both", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best")
    return _save(fig, path)
