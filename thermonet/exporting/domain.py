"""The output-range check every export passes through (:meth:`ExportFormat.write`).

A model is evaluated as it is exported (float32, through the clamp) on a grid
over its trained range — the signals' ``sig_lo`` … ``sig_hi``, the same points
the ONNX parity check uses — and refused unless, on every output axis, the
drift there is finite and lies within the training target's mean ± :data:`MAX_STD`
standard deviations (the model's ``y_mean``/``y_std`` buffers, with the target
normalisation and the per-axis mask of :meth:`DriftModel.output_scaling`):

.. math:: |r_a(s) - \\mathrm{shift}_a| \\le K\\, |\\mathrm{scale}_a|
          \\quad \\text{for every grid point } s

i.e. the family's standardised output stays within ±K.  Measured on the shipped
configs, fitted models reach at most ≈ 30 on their grids: 1.5–2.5 where the data
covers the range, 23 for the BMI270 cubic across the gap between its two soaks,
30 for ``poly3-hyst`` in the corners of its three-signal box that no run visits.
K = 1000 leaves a wide margin for such honest extrapolation inside the box and
still refuses what no fit produces: a weight set to 3e38 (the runtime would answer
−1.8e38 °/s), an inf, a weight scaled by 1e6.  (An edited checkpoint is refused
before this, by its digest: :mod:`thermonet.training.checkpoint`.)  An uncompensated axis
(scale 0) must be exactly 0.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import ExportError

if TYPE_CHECKING:
    from ..models.composite import DriftModels

__all__ = ["MAX_STD", "check_output_range"]

#: How many training standard deviations from the training mean the exported drift may
#: reach anywhere on the trained range.
MAX_STD = 1000.0


def check_output_range(model: DriftModels, *, source: str,
                       units: Mapping[str, str] | None = None) -> None:
    """Refuse ``model`` unless its drift is finite and plausibly bounded on its trained range.

    Parameters
    ----------
    model : DriftModel or AxisModels
    source : str
        What the model came from (the checkpoint file), named in the error.
    units : mapping axis -> unit, optional
        Output units, for the message.

    Raises
    ------
    ExportError
        One line naming ``source``, the axis, the value and where on the range.
    """
    import torch

    from ..models.composite import AxisModels  # torch boundary (pyproject.toml): loads torch
    from .parity import check_points, trained_range  # torch boundary (pyproject.toml): loads torch

    if isinstance(model, AxisModels):
        for k, part in enumerate(model.parts):
            check_output_range(part, units=units,
                               source=f"{source} (part {k}, '{model.labels[k]}')")
        return
    ranges = trained_range(model)
    for sig, (lo, hi) in ranges.items():
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise ExportError(f"{source}: trained range of signal '{sig}' is [{lo:g}, {hi:g}], "
                              "not a fitted model's; refusing to export")
    points = check_points(list(ranges.values()), seed=0)
    with torch.no_grad():
        drift = model.relative(torch.from_numpy(points)).double().numpy()
        scale, shift = (t.detach().cpu().double().numpy() for t in model.output_scaling())
        const = model.constant().detach().cpu().double().numpy()
    units = dict(units or {})

    def at(k: int) -> str:
        return ", ".join(f"{s}={float(points[k, i]):.6g}" for i, s in enumerate(model.signals))

    for a, axis in enumerate(model.outputs):
        unit = f" {units[axis]}" if units.get(axis) else ""
        col = drift[:, a]
        bad = ~np.isfinite(col)
        if bool(bad.any()):
            k = int(np.argmax(bad))
            raise ExportError(f"{source}: axis '{axis}': the model's drift is {col[k]:g} at "
                              f"{at(k)}, inside its trained range; refusing to export")
        bound = MAX_STD * abs(float(scale[a]))
        excess = np.abs(col - shift[a]) - bound
        k = int(np.argmax(excess))
        if excess[k] > 0:
            lo, hi = shift[a] - bound + const[a], shift[a] + bound + const[a]
            raise ExportError(f"{source}: axis '{axis}': the model's drift reaches "
                              f"{col[k] + const[a]:.4g}{unit} at {at(k)}, inside its trained "
                              f"range but outside the plausible {lo:.4g} … {hi:.4g}{unit} "
                              f"(training mean ± {MAX_STD:g} std); the model is broken or was "
                              "edited; refusing to export")
