"""The figures of a comparison (:mod:`thermonet.workflows.compare`, its write step): per PNG
figure of the last fold's test data, the function of :mod:`thermonet.reporting.plots` that
draws it and its arguments (:func:`plot_jobs`), every fitted family in its own colour and the
shipped model's residual-drift band where it has one; the drawers
(:mod:`thermonet.reporting.plot_workers`) draw them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core.names import path_component
from ..core.recording import Dataset
from ..features.inputs import TEMPERATURE
from ..reporting.colours import family_colours
from ..reporting.plot_workers import PlotJob
from ..reporting.results import ComparisonResult, clean
from ..scoring.band import evaluate_tables
from .compare_judge import Fitted

__all__ = ["plot_jobs"]


def plot_jobs(out: Path, fitted: dict[str, Fitted], results: ComparisonResult,
              ds: Dataset) -> list[PlotJob]:
    """The PNG figures of the last fold's test data, every fitted family in its own colour:
    per figure the function of :mod:`thermonet.reporting.plots` and its arguments."""
    ok = {k: f for k, f in fitted.items() if f.model is not None and f.test_parts}
    if not ok:
        return []
    paths: list[PlotJob] = []
    part = next(iter(ok.values())).test_parts[-1]
    colours = family_colours(list(fitted))
    style: dict[str, Any] = {"chosen": results.chosen, "baseline": results.baseline,
                             "colours": colours}
    x_label = "temperature (°C)" if ds[0].temperature_c is not None else \
        f"{sorted(ds[0].proxies)[0]} ({ds[0].units.get(sorted(ds[0].proxies)[0], '') or 'proxy'})"
    pdir = out / "plots"
    for j, axis in enumerate(part.outputs):
        unit = results.units.get(axis, "")
        curves = {label: (part.bin_by, f.test_preds[-1][:, j]) for label, f in ok.items()}
        safe = path_component(axis.replace(".", "_"))  # a name from data, made a file name
        paths.append(("plot_drift_vs_temperature", dict(
            path=pdir / f"drift_vs_temperature_{safe}.png", temperature_c=part.bin_by,
            observed_drift=part.target[:, j], curves=curves, axis=axis, units=unit,
            bin_width=part.bin_width, x_label=x_label, **style)))
        if results.target == "drift":
            resid = {label: part.target[:, j] - f.test_preds[-1][:, j] for label, f in ok.items()}
            paths.append(("plot_residual_vs_time", dict(
                path=pdir / f"residual_vs_time_{safe}.png", time_s=part.time_s,
                raw_error=part.target[:, j], compensated=resid, axis=axis, units=unit,
                **style)))
            paths.append(("plot_residual_vs_temperature", dict(
                path=pdir / f"residual_vs_temperature_{safe}.png", temperature_c=part.bin_by,
                raw_error=part.target[:, j], compensated=resid, axis=axis, units=unit,
                bin_width=part.bin_width, x_label=x_label, band=_band_curve(results, axis,
                                                                           part.bin_by),
                **style)))
            paths.append(("plot_allan", dict(
                path=pdir / f"allan_{safe}.png", rate_hz=part.rate_hz,
                raw_error=part.target[:, j], compensated=resid, axis=axis, units=unit,
                **style)))
    fams = results.families
    # as results.json holds them (clean: a non-finite score is None)
    points = {k: ((fams[k].cost or {}).get("ops_per_sample"), clean(fams[k].test_score))
              for k in ok if k in fams and fams[k].ok}
    if any(c is not None for c, _ in points.values()):
        paths.append(("plot_accuracy_cost", dict(path=pdir / "accuracy_vs_cost.png",
                                                 points=points, **style)))
    return paths


def _band_curve(results: ComparisonResult, axis: str, x: Any) -> Any:
    """(grid, half-width) of the shipped model's band on ``axis`` over ``x``'s range, or None
    (no band, or a band over another signal than the plot's x)."""
    import numpy as np

    band = results.band or {}
    t = (band.get("axes") or {}).get(axis)
    xs = np.asarray(x, dtype=np.float64)
    if t is None or band.get("signal") != TEMPERATURE or not np.isfinite(xs).any():
        return None
    grid = np.linspace(float(np.nanmin(xs)), float(np.nanmax(xs)), 400)
    return grid, evaluate_tables(grid, t["edges"], t["half_width"], t["growth_below"],
                                 t["growth_above"])
