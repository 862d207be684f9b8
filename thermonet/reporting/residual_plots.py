"""The residual figures of a comparison (:mod:`thermonet.reporting.plots`, whose conventions
they follow): the raw output's error and each family's residual against time
(:func:`plot_residual_vs_time`) and against temperature (:func:`plot_residual_vs_temperature`),
about their means, the samples drawn faintly behind binned means — as a band of mean ± sd in
equal bins (:func:`sample_band`, :func:`band_of`; the drift-vs-temperature figure's too) or a
min/max line broken at the log's gaps.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ..scoring.metrics import _series  # one 1-D series check for metrics and plots
from .plot_style import (
    _RAW_BINNED_COLOR,
    _RAW_COLOR,
    _TIME_STEPS,
    LIMIT_BINS,
    MAX_LINE_POINTS,
    MAX_SCATTER_POINTS,
    OFF_SCALE,
    _apply_limits,
    _bin_means,
    _bin_text,
    _binned,
    _centred,
    _check_length,
    _dense,
    _even_bins,
    _gap_breaks,
    _legend,
    _minmax_indices,
    _new_figure,
    _off_scale,
    _residuals,
    _save,
    _scale_sources,
    _stride,
    _style,
    _title,
    duration_text,
    family_colours,
    time_unit,
    y_limits,
)

__all__ = ["band_of", "sample_band", "residual_vs_time_figure", "plot_residual_vs_time",
           "residual_vs_temperature_figure", "plot_residual_vs_temperature"]


def band_of(x: np.ndarray, y: np.ndarray, n_bins: int = LIMIT_BINS
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(centres, mean − sd, mean + sd)`` of ``y`` in ``n_bins`` equal bins spanning ``x``'s
    finite range (NaN where a bin is empty: a gap stays a gap)."""
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any():
        empty = np.empty(0)
        return empty, empty, empty
    lo, hi = float(x[ok].min()), float(x[ok].max())
    edges = np.linspace(lo, hi, n_bins + 1) if hi > lo else np.array([lo, lo + 1.0])
    nb = edges.size - 1
    k = np.clip(np.searchsorted(edges, x[ok], side="right") - 1, 0, nb - 1)
    n = np.bincount(k, minlength=nb).astype(np.float64)
    s = np.bincount(k, weights=y[ok], minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s / n
        var = np.bincount(k, weights=(y[ok] - mean[k]) ** 2, minlength=nb) / n
    sd = np.sqrt(var)
    return 0.5 * (edges[:-1] + edges[1:]), mean - sd, mean + sd


def sample_band(ax: Axes, x: np.ndarray, y: np.ndarray, *, label: str) -> None:
    """Many samples as a light band — mean ± sd in :data:`LIMIT_BINS` equal bins of ``x``
    (:func:`band_of`) — under the binned means: at hundreds of hertz the samples themselves
    would paint a solid block."""
    cx, lo, hi = band_of(x, y)
    ax.fill_between(cx, lo, hi, color=_RAW_COLOR, alpha=0.25, linewidth=0, zorder=1,
                    label=label)


def _faint_line(ax: Axes, t: np.ndarray, x: np.ndarray, y: np.ndarray, **kw: Any) -> None:
    """Every sample of ``y`` as a faint min/max band (broken at gaps in the log) under the
    binned means."""
    keep = _minmax_indices(y, MAX_LINE_POINTS)
    breaks = _gap_breaks(t, keep)
    ax.plot(np.insert(x[keep], breaks, np.nan), np.insert(y[keep], breaks, np.nan),
            linewidth=0.6, **kw)


def residual_vs_time_figure(*, time_s: np.ndarray, raw_error: np.ndarray,
                            compensated: Mapping[str, np.ndarray], axis: str, units: str,
                            chosen: str | None = None, baseline: str | None = None,
                            colours: Mapping[str, str] | None = None) -> Figure:
    """The figure :func:`plot_residual_vs_time` writes, not yet saved (its axes can be read:
    limits, labels, legend); same parameters but the path."""
    t = _series("time_s", time_s)
    raw = _series("raw_error", raw_error)
    _check_length("raw_error", raw, t.size, "time_s")
    residuals = {name: _centred(r) for name, r in _residuals(compensated, t.size, "time_s").items()}
    colours = colours or family_colours(list(residuals))
    start = t[0] if t.size else 0.0
    unit, seconds = time_unit(float(np.nanmax(t) - start) if t.size else 0.0)
    x = (t - start) / seconds
    fig, ax = _new_figure()
    rawc = _centred(raw)
    if t.size > MAX_LINE_POINTS:   # the samples, binned: mean ± sd in each time bin
        sample_band(ax, x, rawc, label=f"raw output error ({t.size} samples): mean ± sd in "
                                       f"{LIMIT_BINS} bins")
    elif t.size:  # the samples: a faint band (a residual's band would only cover it again)
        _faint_line(ax, t, x, rawc, color=_RAW_COLOR, alpha=0.3, zorder=1,
                    label="raw output error, samples")
    styles = {name: _style(name, colours, chosen, baseline, i)
              for i, name in enumerate(residuals)}
    bx, raw_means, raw_counts = _even_bins(x, rawc)
    binned = {name: _even_bins(x, y) for name, y in residuals.items()}
    dense = {name: _dense(b[1], b[2]) for name, b in binned.items()}
    limits = y_limits([_dense(raw_means, raw_counts)]
                      + [dense[n] for n in _scale_sources(list(residuals), chosen, baseline)])
    width = (float(bx[1] - bx[0]) if bx.size > 1 else 0.0)
    # the window in natural units (5.57 s, not 0.0929 min), whatever unit the axis is in
    what = f"{duration_text(width * seconds)} means" if width > 0 else "mean"
    if bx.size:
        ax.plot(bx, raw_means, color=_RAW_BINNED_COLOR, linewidth=1.4, zorder=6,
                label=f"raw output error, {what}")
    off = False
    for name, (cx, means, _) in binned.items():
        kw = dict(styles[name])
        if _off_scale(dense[name], limits):
            kw["label"] += f" {OFF_SCALE}"
            off = True
        ax.plot(cx, means, **kw)
    _title(ax, f"{axis}: error vs time before and after compensation, {what} "
                 "(about its mean)")
    ax.set_xlabel(f"time from start ({unit})")
    ax.xaxis.set_major_locator(MaxNLocator(nbins="auto", steps=_TIME_STEPS[unit]))
    ax.set_ylabel(f"error, mean removed ({units})")
    _apply_limits(ax, limits, off)
    ax.grid(True, alpha=0.3)
    _legend(ax)
    return fig


def plot_residual_vs_time(path: str | Path, *, time_s: np.ndarray, raw_error: np.ndarray,
                          compensated: Mapping[str, np.ndarray], axis: str,
                          units: str, chosen: str | None = None, baseline: str | None = None,
                          colours: Mapping[str, str] | None = None) -> Path:
    """Error against time before compensation and after each family's, offsets removed.

    Every family and the raw error are drawn as means over :data:`LIMIT_BINS`
    equal time bins (fewer on short series, see :data:`MIN_BIN_SAMPLES`); the
    raw error's samples lie faintly behind them (a min/max band).  The
    y-scale comes from the binned means of raw, the chosen family and the
    baseline (:func:`y_limits`); another family may leave the frame, marked
    "(off scale)".  Time runs from the first sample in the unit
    :func:`time_unit` gives for the span.

    Parameters
    ----------
    path : str or Path
        PNG file to write.
    time_s : ndarray, shape (n,)
        Sample times, s; plotted from the first sample in s, min or h.
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
    return _save(residual_vs_time_figure(
        time_s=time_s, raw_error=raw_error, compensated=compensated, axis=axis, units=units,
        chosen=chosen, baseline=baseline, colours=colours), path)


def residual_vs_temperature_figure(*, temperature_c: np.ndarray, raw_error: np.ndarray,
                                   compensated: Mapping[str, np.ndarray], axis: str, units: str,
                                   chosen: str | None = None, baseline: str | None = None,
                                   colours: Mapping[str, str] | None = None,
                                   bin_width: float = 1.0,
                                   x_label: str = "temperature (°C)") -> Figure:
    """The figure :func:`plot_residual_vs_temperature` writes, not yet saved (its axes can be
    read: limits, labels, legend); same parameters but the path."""
    t = _series("temperature_c", temperature_c)
    raw = _centred(_series("raw_error", raw_error))
    _check_length("raw_error", raw, t.size, "temperature_c")
    residuals = {name: _centred(r)
                 for name, r in _residuals(compensated, t.size, "temperature_c").items()}
    colours = colours or family_colours(list(compensated))
    fig, ax = _new_figure()
    keep = _stride(t.size, MAX_SCATTER_POINTS)
    ax.scatter(t[keep], raw[keep], s=3, color=_RAW_COLOR, alpha=0.2, linewidths=0,
               rasterized=True, zorder=1)
    _, raw_means, raw_counts = _bin_means(t, raw, bin_width)
    dense = {name: _dense(*_bin_means(t, y, bin_width)[1:]) for name, y in residuals.items()}
    limits = y_limits([_dense(raw_means, raw_counts)]
                      + [dense[n] for n in _scale_sources(list(residuals), chosen, baseline)])
    if t.size:
        bx, by = _binned(t, raw, bin_width)
        ax.plot(bx, by, "o-", color=_RAW_BINNED_COLOR, markersize=3, linewidth=1.2, zorder=6,
                label="raw output error (binned means)")
    off = False
    for i, (name, y) in enumerate(residuals.items()):
        style = _style(name, colours, chosen, baseline, i)
        if name == chosen:
            ax.scatter(t[keep], y[keep], s=3, color=style["color"], alpha=0.15, linewidths=0,
                       rasterized=True, zorder=2)
        if _off_scale(dense[name], limits):
            style["label"] += f" {OFF_SCALE}"
            off = True
        if t.size:
            bx, by = _binned(t, y, bin_width)
            ax.plot(bx, by, **style)
    _title(ax, f"{axis}: error vs temperature after compensation, "
                 f"{_bin_text(bin_width, x_label)} (about their means)")
    ax.set_xlabel(x_label)
    ax.set_ylabel(f"error after compensation, mean removed ({units})")
    _apply_limits(ax, limits, off)
    ax.grid(True, alpha=0.3)
    _legend(ax)
    return fig


def plot_residual_vs_temperature(path: str | Path, *, temperature_c: np.ndarray,
                                 raw_error: np.ndarray, compensated: Mapping[str, np.ndarray],
                                 axis: str, units: str, chosen: str | None = None,
                                 baseline: str | None = None,
                                 colours: Mapping[str, str] | None = None,
                                 bin_width: float = 1.0,
                                 x_label: str = "temperature (°C)",
                                 band: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    """Binned means of the error against temperature, raw and after each family.

    A light scatter of the raw error and of the chosen family's residual sits
    under the ``bin_width`` binned means (offsets removed): thousands of noisy
    points would otherwise hide a drift smaller than the noise.  The y-scale
    comes from the binned means of raw, the chosen family and the baseline
    (:func:`y_limits`); another family may leave the frame, marked "(off scale)".

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
    band : (ndarray, ndarray), optional
        (grid, half-width) of the shipped model's residual-drift band
        (:mod:`thermonet.scoring.band`), shaded ± about zero (the residuals are drawn
        offset-free, as the band is).

    Returns
    -------
    Path
        The file written.
    """
    fig = residual_vs_temperature_figure(
        temperature_c=temperature_c, raw_error=raw_error, compensated=compensated, axis=axis,
        units=units, chosen=chosen, baseline=baseline, colours=colours, bin_width=bin_width,
        x_label=x_label)
    if band is not None and fig.axes:
        ax = fig.axes[0]
        grid, half = (np.asarray(v, dtype=np.float64) for v in band)
        ax.fill_between(grid, -half, half, color="0.5", alpha=0.15, linewidth=0,
                        label="residual-drift band (shipped model)", zorder=0)
        ax.legend(loc="best", fontsize="small")
    return _save(fig, path)
