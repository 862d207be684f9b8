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
* noisy samples (scatters, the min/max band of a time series) are drawn
  faintly behind binned means: 1 °C (one bin width) against temperature,
  :data:`LIMIT_BINS` time bins over the recording against time;
* the y-scale is set by binned means only (:func:`y_limits`): of the raw
  output's error, the baseline's and the chosen family's curves, with a
  :data:`Y_MARGIN` margin.  Never by single samples (white noise at 500 Hz
  would flatten a 4 mg drift) nor by a candidate that is neither chosen nor
  the baseline: such a curve may leave the frame, is clipped by the axes and
  says "(off scale)" in the legend;
* time from the start of the held-out data in the unit that suits its length
  (:func:`time_unit`: s up to 10 min, min up to 3 h, h beyond), named in the
  axis label;
* y labels say what is drawn: the raw output's error, a model's predicted
  drift, a residual.

The residual figures are :mod:`thermonet.reporting.residual_plots`'; every ``plot_*`` is
importable from here, where the figure drawers (:mod:`thermonet.reporting.plot_workers`)
look them up by name.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from ..scoring.metrics import (  # one 1-D series check for metrics and plots
    _series,
    allan,
)
from .plot_style import (  # noqa: F401  re-exported: the plots' public constants and helpers
    _RAW_BINNED_COLOR,
    _RAW_COLOR,
    _TIME_STEPS,
    DPI,
    FIGSIZE_IN,
    LIMIT_BINS,
    MAX_LINE_POINTS,
    MAX_SCATTER_POINTS,
    MIN_BIN_SAMPLES,
    OFF_SCALE,
    PALETTE,
    Y_MARGIN,
    _apply_limits,
    _bin_means,
    _bin_text,
    _binned,
    _centred,
    _check_length,
    _dense,
    _even_bins,
    _legend,
    _new_figure,
    _off_scale,
    _save,
    _scale_sources,
    _stride,
    _style,
    _title,
    family_colours,
    time_unit,
    y_limits,
)
from .residual_plots import (  # plot_workers draws every plot_* by name from this module
    plot_residual_vs_temperature,
    plot_residual_vs_time,
    sample_band,
)

__all__ = [
    "family_colours",
    "PALETTE",
    "plot_drift_vs_temperature",
    "plot_residual_vs_time",
    "plot_residual_vs_temperature",
    "plot_allan",
    "plot_accuracy_cost",
    "accuracy_cost_figure",
    "drift_vs_temperature_figure",
    "depends_on_more_than",
    "y_limits",
    "time_unit",
    "FIGSIZE_IN",
    "DPI",
    "MAX_SCATTER_POINTS",
    "MAX_LINE_POINTS",
    "LIMIT_BINS",
    "MIN_BIN_SAMPLES",
    "Y_MARGIN",
    "OFF_SCALE",
]


def drift_vs_temperature_figure(*, temperature_c: np.ndarray, observed_drift: np.ndarray,
                                curves: Mapping[str, tuple[np.ndarray, np.ndarray]],
                                axis: str, units: str, chosen: str | None = None,
                                baseline: str | None = None,
                                colours: Mapping[str, str] | None = None,
                                bin_width: float = 1.0,
                                x_label: str = "temperature (°C)") -> Figure:
    """The figure :func:`plot_drift_vs_temperature` writes, not yet saved (its axes can be
    read: limits, labels, legend); same parameters but the path."""
    t = _series("temperature_c", temperature_c)
    d = _series("observed_drift", observed_drift)
    _check_length("observed_drift", d, t.size, "temperature_c")
    checked: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, curve in curves.items():
        if len(curve) != 2:
            raise ValueError(f"curve '{name}' must be (temperature_grid, predicted), "
                             f"got {len(curve)} items")
        grid = _series(f"curves['{name}'][0]", curve[0])
        pred = _series(f"curves['{name}'][1]", curve[1])
        _check_length(f"curves['{name}'][1]", pred, grid.size, f"curves['{name}'][0]")
        checked[name] = (grid, _centred(pred))
    colours = colours or family_colours(list(curves))
    fig, ax = _new_figure()
    dc = _centred(d)
    if t.size > MAX_SCATTER_POINTS:   # a high-rate log: thinned dots would paint a block
        sample_band(ax, t, dc, label=f"raw output error ({t.size} samples): mean ± sd in "
                                     f"{LIMIT_BINS} bins")
    else:
        ax.scatter(t, dc, s=3, color=_RAW_COLOR, alpha=0.25, linewidths=0,
                   label=f"raw output error ({t.size} samples)", rasterized=True, zorder=1)
    # The y-scale: the raw error's binned means as drawn, and the chosen family's and the
    # baseline's curves averaged in fine bins of temperature (a curve of a model with noisy
    # dynamic inputs is noisy sample by sample too).
    _, raw_means, raw_counts = _bin_means(t, dc, bin_width)
    fine = {name: _dense(*_even_bins(grid, pred, smooth=True)[1:])
            for name, (grid, pred) in checked.items()}
    limits = y_limits([_dense(raw_means, raw_counts)]
                      + [fine[n] for n in _scale_sources(list(checked), chosen, baseline)])
    if t.size:
        bx, by = _binned(t, dc, bin_width)
        ax.plot(bx, by, "o-", color=_RAW_BINNED_COLOR, markersize=3, linewidth=1.0,
                label=f"raw output error, {_bin_text(bin_width, x_label)}", zorder=6)
    off = False
    for i, (name, (grid, pred)) in enumerate(checked.items()):
        style = _style(name, colours, chosen, baseline, i)
        style["label"] = f"predicted drift: {style['label']}"
        dynamic = depends_on_more_than(grid, pred)
        if dynamic:
            style["label"] += " (means at each temperature)"
        if _off_scale(fine[name], limits):
            style["label"] += f" {OFF_SCALE}"
            off = True
        if dynamic:
            # a model on dynamic inputs (rate, lag …): several drifts at one temperature —
            # drawn sample by sample, heating and cooling zigzag into a filled wedge; its
            # means in fine temperature bins are the curve a reader can follow
            cx, means, _ = _even_bins(grid, pred, smooth=True)
            ax.plot(cx, means, **style)
            continue
        order = np.argsort(grid, kind="stable")
        sel = order[_stride(order.size, MAX_LINE_POINTS)]
        ax.plot(grid[sel], pred[sel], **style)
    _title(ax, f"{axis}: raw output error and predicted drift vs temperature (about their means)")
    ax.set_xlabel(x_label)
    ax.set_ylabel(f"raw output error / drift, mean removed ({units})")
    _apply_limits(ax, limits, off)
    ax.grid(True, alpha=0.3)
    _legend(ax)
    return fig


#: A curve whose values in one fine temperature bin spread over more than this fraction of
#: its whole range depends on more than the temperature (:func:`depends_on_more_than`).
NOT_A_FUNCTION_SPREAD = 0.05


def depends_on_more_than(grid: np.ndarray, pred: np.ndarray) -> bool:
    """Whether ``pred`` is not a function of ``grid`` (a model on dynamic inputs evaluated on
    the samples): in :data:`LIMIT_BINS` equal bins of ``grid`` some bin's values spread over
    more than :data:`NOT_A_FUNCTION_SPREAD` of the curve's whole range."""
    ok = np.isfinite(grid) & np.isfinite(pred)
    g, p = grid[ok], pred[ok]
    span = float(np.ptp(p)) if p.size else 0.0
    if p.size < 3 or span <= 0.0 or float(np.ptp(g)) <= 0.0:
        return False
    edges = np.linspace(float(g.min()), float(g.max()), LIMIT_BINS + 1)
    idx = np.clip(np.searchsorted(edges, g, side="right") - 1, 0, LIMIT_BINS - 1)
    hi = np.full(LIMIT_BINS, -np.inf)
    lo = np.full(LIMIT_BINS, np.inf)
    np.maximum.at(hi, idx, p)
    np.minimum.at(lo, idx, p)
    used = np.isfinite(hi)
    return bool(np.max(hi[used] - lo[used]) > NOT_A_FUNCTION_SPREAD * span)


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
    as gravity's projection, is not what a model compensates).  The y-scale
    comes from the raw error's binned means and the chosen family's and the
    baseline's curves (:func:`y_limits`); another family's curve may leave
    the frame, marked "(off scale)".

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
        Families drawn stronger (the baseline dashed); with the raw error they set the y-scale.
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
    return _save(drift_vs_temperature_figure(
        temperature_c=temperature_c, observed_drift=observed_drift, curves=curves, axis=axis,
        units=units, chosen=chosen, baseline=baseline, colours=colours, bin_width=bin_width,
        x_label=x_label), path)


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
    _title(ax, f"{axis}: overlapping Allan deviation")
    ax.set_xlabel("averaging time τ (s)")
    ax.set_ylabel(f"Allan deviation ({units})")
    ax.grid(True, which="both", alpha=0.3)
    _legend(ax)
    return _save(fig, path)


def accuracy_cost_figure(points: Mapping[str, tuple[float | None, float | None]], *,
                         chosen: str | None = None, baseline: str | None = None,
                         colours: Mapping[str, str] | None = None) -> Figure:
    """Held-out error against cost on board, one point per family (front).

    ``points``: family → (operations per sample, test score ratio to raw — the masked mean
    over axes, < 1 better).  The x axis is logarithmic (a cubic costs a few operations, an
    RBF or a perceptron a hundred or more); the chosen family is ringed, the baseline a
    square; the families no other beats on both axes (the Pareto front) are joined.
    """
    fig, ax = _new_figure()
    pts = {k: (float(c), float(e)) for k, (c, e) in points.items()
           if c is not None and e is not None and c > 0 and np.isfinite(e)}  # known cost only
    for i, (name, (c, e)) in enumerate(pts.items()):
        st = _style(name, colours, chosen, baseline, i)
        ax.scatter([c], [e], s=140 if name == chosen else 60, color=st["color"],
                   marker="s" if name == baseline else "o", zorder=st["zorder"],
                   edgecolors="black" if name == chosen else "none",
                   linewidths=2.0 if name == chosen else 0.0, label=st["label"])
        ax.annotate(name, (c, e), textcoords="offset points", xytext=(6, 4), fontsize=8)
    front = sorted((c, e) for k, (c, e) in pts.items()
                   if not any(c2 <= c and e2 <= e and (c2, e2) != (c, e)
                              for k2, (c2, e2) in pts.items() if k2 != k))
    if len(front) > 1:
        ax.plot([c for c, _ in front], [e for _, e in front], color="0.4", linewidth=1.0,
                linestyle=":", zorder=1, label="front (nothing better and cheaper)")
    if pts:
        ax.set_xscale("log")
    ax.axhline(1.0, color=_RAW_COLOR, linewidth=1.0, label="raw (no compensation)")
    _title(ax, "held-out error against cost on board")
    ax.set_xlabel("operations per sample (multiply-adds and transcendental calls)")
    ax.set_ylabel("test score / raw (< 1 better)")
    ax.grid(True, which="both", alpha=0.3)
    _legend(ax)
    return fig


def plot_accuracy_cost(path: str | Path,
                       points: Mapping[str, tuple[float | None, float | None]], *,
                       chosen: str | None = None, baseline: str | None = None,
                       colours: Mapping[str, str] | None = None) -> Path:
    """:func:`accuracy_cost_figure` written as a PNG."""
    return _save(accuracy_cost_figure(points, chosen=chosen, baseline=baseline,
                                      colours=colours), path)
