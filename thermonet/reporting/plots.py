"""Comparison plots of the compensation families, written as PNG files.

Figures are built with :class:`matplotlib.figure.Figure` and rendered by the
Agg canvas directly, never through ``pyplot``: nothing registers in pyplot's
figure manager, so thousands of calls leak no figures and no display backend
is ever needed (or switched for the rest of the process).

Every function takes the output path first, writes one PNG of
:data:`FIGSIZE_IN` × :data:`DPI` pixels, creates missing parent directories
and returns the :class:`~pathlib.Path` written.  A figure draws at most what
it can show: scatters are strided to :data:`MAX_SCATTER_POINTS`, lines keep
the min and max of each of about one bucket per pixel column
(:data:`MAX_LINE_POINTS`), so a plot takes well under a second on 50k samples.

Conventions, so a figure does not mislead:

* every family has its own colour (:func:`family_colours`: a large
  qualitative palette that does not wrap at 10 and never uses the raw
  output's grey); the chosen family and the baseline are drawn stronger (the
  baseline dashed);
* errors are drawn about their mean (the offset removed): a model can only
  remove the temperature-dependent part, and a raw offset (gyro bias,
  gravity) would squash everything else;
* noisy scatters are light, with 1 °C (one bin width) binned means on top;
* time in hours from the start of the held-out data;
* y labels say what is drawn: the raw output's error, a model's predicted
  drift, a residual.
"""

from __future__ import annotations

import colorsys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..core.recording import GAP_FACTOR
from ..scoring.metrics import (  # one 1-D series check for metrics and plots
    _series,
    allan,
    binned_means,
)

__all__ = [
    "family_colours",
    "PALETTE",
    "plot_drift_vs_temperature",
    "plot_residual_vs_time",
    "plot_residual_vs_temperature",
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
#: Time series keep at most about this many vertices: a min and a max per pixel column.
MAX_LINE_POINTS = 2 * int(FIGSIZE_IN[0] * DPI)

# A step longer than GAP_FACTOR median sample intervals is a gap in the log (burst mode, a
# pause between soaks); the line is broken there instead of drawing a straight segment across
# hours without data.

_RAW_COLOR = "0.55"
_RAW_BINNED_COLOR = "0.2"

#: Distinct, saturated qualitative colours: tab10 without its grey, Dark2 without its grey,
#: then a dozen strong web colours; no greys, so no family looks like the raw output.
PALETTE = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22",
    "#17becf", "#1b9e77", "#d95f02", "#7570b3", "#e7298a", "#66a61e", "#e6ab02", "#a6761d",
    "#6a3d9a", "#000080", "#808000", "#800000", "#008080", "#ff1493", "#00ff7f", "#ffd700",
    "#4b0082", "#7fff00", "#ff6347", "#00bfff",
)

# Two colours closer than this (largest RGB channel difference) count as the same.
_MIN_COLOUR_DISTANCE = 0.06


def _hex_rgb(colour: str) -> np.ndarray:
    return np.array([int(colour[i:i + 2], 16) / 255.0 for i in (1, 3, 5)])


def family_colours(labels: Sequence[str]) -> dict[str, str]:
    """A distinct colour per family label, in order; never a grey.

    The first ``len(PALETTE)`` families take :data:`PALETTE`; beyond it, hues
    step by the golden angle at high saturation, skipping any candidate within
    0.06 (largest RGB channel difference) of a colour already given.
    """
    out: dict[str, str] = {}
    taken = [_hex_rgb(c) for c in PALETTE]
    k = 0
    for i, label in enumerate(labels):
        if i < len(PALETTE):
            out[label] = PALETTE[i]
            continue
        while True:
            h = (k * 0.618033988749895) % 1.0
            value = (0.55, 0.75, 0.95)[(k // 5) % 3]
            rgb = np.array(colorsys.hsv_to_rgb(h, 0.85, value))
            k += 1
            far = min(float(np.abs(rgb - t).max()) for t in taken) > _MIN_COLOUR_DISTANCE
            if far or k > 100 * len(labels):  # hundreds of families: accept near colours
                break
        taken.append(rgb)
        out[label] = "#" + "".join(f"{int(round(c * 255)):02x}" for c in rgb)
    return out


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
    return y - np.mean(y) if y.size else y


def _binned(x: np.ndarray, y: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Binned means, with a NaN between bins that are not neighbours (no line across a
    temperature range without data, e.g. between two isothermal soaks)."""
    centres, means = binned_means(x, y, bin_c=width)
    cuts = np.flatnonzero(np.diff(centres) > 1.5 * width) + 1
    return np.insert(centres, cuts, np.nan), np.insert(means, cuts, np.nan)


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


def plot_drift_vs_temperature(path: str | Path, *, temperature_c: np.ndarray,
                              observed_drift: np.ndarray,
                              curves: Mapping[str, tuple[np.ndarray, np.ndarray]],
                              axis: str, units: str, chosen: str | None = None,
                              baseline: str | None = None,
                              colours: Mapping[str, str] | None = None, bin_width: float = 1.0,
                              x_label: str = "temperature (°C)") -> Path:
    """The raw output's error against temperature, and each family's predicted drift.

    Everything is drawn about its mean over the samples given: the raw error
    as a light scatter with its ``bin_width`` binned means on top, each
    family's curve minus its own mean over the grid (an unknown constant, such
    as gravity's projection, is not what a model compensates).

    Parameters
    ----------
    path : str or Path
        PNG file to write.
    temperature_c : ndarray, shape (n,)
        Device temperature, °C (or a proxy, see ``x_label``).
    observed_drift : ndarray, shape (n,)
        The raw output's error (output minus reference), ``units``; at most
        :data:`MAX_SCATTER_POINTS` are drawn.
    curves : mapping of str to (ndarray, ndarray)
        Family name → (temperature grid in °C, predicted drift in ``units``).
    axis : str
        Channel name for the title (``gyro_x``).
    units : str
        Units of the drift (``deg/s``).
    chosen, baseline : str, optional
        Families drawn stronger (the baseline dashed).
    colours : mapping of str to str, optional
        Family → colour (default :func:`family_colours` in the order given).
    bin_width : float
        Width of the binned means, in the units of ``temperature_c`` (1 °C).
    x_label : str
        Label of the x axis.

    Returns
    -------
    Path
        The file written.
    """
    t = _series("temperature_c", temperature_c)
    d = _series("observed_drift", observed_drift)
    _check_length("observed_drift", d, t.size, "temperature_c")
    colours = colours or family_colours(list(curves))
    fig, ax = _new_figure()
    dc = _centred(d)
    keep = _stride(t.size, MAX_SCATTER_POINTS)
    ax.scatter(t[keep], dc[keep], s=3, color=_RAW_COLOR, alpha=0.25, linewidths=0,
               label=f"raw output error ({t.size} samples)", rasterized=True)
    if t.size:
        bx, by = _binned(t, dc, bin_width)
        ax.plot(bx, by, "o-", color=_RAW_BINNED_COLOR, markersize=3, linewidth=1.0,
                label=f"raw output error, {_bin_text(bin_width, x_label)}", zorder=6)
    for i, (name, curve) in enumerate(curves.items()):
        if len(curve) != 2:
            raise ValueError(f"curve '{name}' must be (temperature_grid, predicted), "
                             f"got {len(curve)} items")
        grid = _series(f"curves['{name}'][0]", curve[0])
        pred = _series(f"curves['{name}'][1]", curve[1])
        _check_length(f"curves['{name}'][1]", pred, grid.size, f"curves['{name}'][0]")
        order = np.argsort(grid, kind="stable")
        sel = order[_stride(order.size, MAX_LINE_POINTS)]
        style = _style(name, colours, chosen, baseline, i)
        style["label"] = f"predicted drift: {style['label']}"
        ax.plot(grid[sel], _centred(pred)[sel], **style)
    ax.set_title(f"{axis}: raw output error and predicted drift vs temperature (about their means)")
    ax.set_xlabel(x_label)
    ax.set_ylabel(f"raw output error / drift, mean removed ({units})")
    ax.grid(True, alpha=0.3)
    _legend(ax)
    return _save(fig, path)


def _hours(t: np.ndarray) -> np.ndarray:
    return (t - t[0]) / 3600.0 if t.size else t


def plot_residual_vs_time(path: str | Path, *, time_s: np.ndarray, raw_error: np.ndarray,
                          compensated: Mapping[str, np.ndarray], axis: str,
                          units: str, chosen: str | None = None, baseline: str | None = None,
                          colours: Mapping[str, str] | None = None) -> Path:
    """Error against time before compensation and after each family's, offsets removed.

    Parameters
    ----------
    path : str or Path
        PNG file to write.
    time_s : ndarray, shape (n,)
        Sample times, s; plotted in hours from the first sample.
    raw_error : ndarray, shape (n,)
        Output minus reference before compensation, ``units``.
    compensated : mapping of str to ndarray
        Family name → residual after compensation, shape (n,), ``units``.
    axis, units : str
        Channel name and units for the title and labels.
    chosen, baseline, colours
        As in :func:`plot_drift_vs_temperature`.

    Returns
    -------
    Path
        The file written.
    """
    t = _series("time_s", time_s)
    raw = _series("raw_error", raw_error)
    _check_length("raw_error", raw, t.size, "time_s")
    residuals = _residuals(compensated, t.size, "time_s")
    colours = colours or family_colours(list(residuals))
    hours = _hours(t)
    fig, ax = _new_figure()
    series: list[tuple[np.ndarray, dict[str, Any]]] = [
        (raw, {"color": _RAW_COLOR, "linewidth": 0.8, "label": "raw output error", "zorder": 2})]
    series += [(r, _style(name, colours, chosen, baseline, i))
               for i, (name, r) in enumerate(residuals.items())]
    for y, kw in series:
        y = _centred(y)
        keep = _minmax_indices(y, MAX_LINE_POINTS)
        breaks = _gap_breaks(t, keep)
        x_d = np.insert(hours[keep], breaks, np.nan)
        y_d = np.insert(y[keep], breaks, np.nan)
        kw = {**kw, "linewidth": min(float(kw.get("linewidth", 1.0)), 1.4)}
        ax.plot(x_d, y_d, **kw)
    ax.set_title(f"{axis}: error vs time before and after compensation (about its mean)")
    ax.set_xlabel("time from start (h)")
    ax.set_ylabel(f"error, mean removed ({units})")
    ax.grid(True, alpha=0.3)
    _legend(ax)
    return _save(fig, path)


def plot_residual_vs_temperature(path: str | Path, *, temperature_c: np.ndarray,
                                 raw_error: np.ndarray, compensated: Mapping[str, np.ndarray],
                                 axis: str, units: str, chosen: str | None = None,
                                 baseline: str | None = None,
                                 colours: Mapping[str, str] | None = None,
                                 bin_width: float = 1.0,
                                 x_label: str = "temperature (°C)") -> Path:
    """Binned means of the error against temperature, raw and after each family.

    A light scatter of the raw error and of the chosen family's residual sits
    under the ``bin_width`` binned means (offsets removed): thousands of noisy
    points would otherwise hide a drift smaller than the noise.

    Parameters
    ----------
    path : str or Path
        PNG file to write.
    temperature_c : ndarray, shape (n,)
        Device temperature, °C (or a proxy, see ``x_label``).
    raw_error : ndarray, shape (n,)
        Output minus reference before compensation, ``units``.
    compensated : mapping of str to ndarray
        Family name → residual after compensation, ``units``.
    axis, units, chosen, baseline, colours, bin_width, x_label
        As in :func:`plot_drift_vs_temperature`.

    Returns
    -------
    Path
        The file written.
    """
    t = _series("temperature_c", temperature_c)
    raw = _centred(_series("raw_error", raw_error))
    _check_length("raw_error", raw, t.size, "temperature_c")
    colours = colours or family_colours(list(compensated))
    fig, ax = _new_figure()
    keep = _stride(t.size, MAX_SCATTER_POINTS)
    ax.scatter(t[keep], raw[keep], s=3, color=_RAW_COLOR, alpha=0.2, linewidths=0,
               rasterized=True)
    if t.size:
        bx, by = _binned(t, raw, bin_width)
        ax.plot(bx, by, "o-", color=_RAW_BINNED_COLOR, markersize=3, linewidth=1.2, zorder=6,
                label="raw output error (binned means)")
    for i, (name, r) in enumerate(_residuals(compensated, t.size, "temperature_c").items()):
        y = _centred(r)
        style = _style(name, colours, chosen, baseline, i)
        if name == chosen:
            ax.scatter(t[keep], y[keep], s=3, color=style["color"], alpha=0.15, linewidths=0,
                       rasterized=True)
        if t.size:
            bx, by = _binned(t, y, bin_width)
            ax.plot(bx, by, **style)
    ax.set_title(f"{axis}: error vs temperature after compensation, "
                 f"{_bin_text(bin_width, x_label)} (about their means)")
    ax.set_xlabel(x_label)
    ax.set_ylabel(f"error after compensation, mean removed ({units})")
    ax.grid(True, alpha=0.3)
    _legend(ax)
    return _save(fig, path)


def plot_allan(path: str | Path, *, rate_hz: float, raw_error: np.ndarray,
               compensated: Mapping[str, np.ndarray], axis: str, units: str,
               chosen: str | None = None, baseline: str | None = None,
               colours: Mapping[str, str] | None = None) -> Path:
    """Log-log overlapping Allan deviation before and after compensation.

    Uses :func:`thermonet.scoring.metrics.allan` (octave averaging times); samples are
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
    chosen, baseline, colours
        As in :func:`plot_drift_vs_temperature`.

    Returns
    -------
    Path
        The file written.
    """
    raw = _series("raw_error", raw_error)
    colours = colours or family_colours(list(compensated))
    fig, ax = _new_figure()
    series: list[tuple[np.ndarray, dict[str, Any]]] = [
        (raw, {"color": _RAW_COLOR, "linewidth": 1.2, "label": "raw output error"})]
    series += [(_series(f"compensated['{name}']", r), _style(name, colours, chosen, baseline, i))
               for i, (name, r) in enumerate(compensated.items())]
    for y, kw in series:
        taus, adev = allan(y, rate_hz)
        positive = adev > 0  # a log axis cannot show a zero deviation
        if positive.any():
            ax.loglog(taus[positive], adev[positive], marker="o", markersize=3,
                      **kw)
    ax.set_title(f"{axis}: overlapping Allan deviation")
    ax.set_xlabel("averaging time τ (s)")
    ax.set_ylabel(f"Allan deviation ({units})")
    ax.grid(True, which="both", alpha=0.3)
    _legend(ax)
    return _save(fig, path)
