"""Lorentz curve (study 000, Origin's ``Lorentz`` form), one input, per-axis parameters.

.. math::

    \\hat y = y_0 + \\frac{2A}{\\pi}\\,\\frac{w}{4 (z - x_c)^2 + w^2}

Bounded parameters: :math:`w = \\operatorname{softplus}(w_r) + \\text{tiny} > 0`;
:math:`x_c = l + (h - l)\\,\\sigma(c_r)` stays within ``xc_margin`` × the data
span of the trained input range :math:`[l, h]` (buffers set by
:meth:`Lorentz.initialize`).  The initial guess follows lmfit's
``LorentzianModel.guess`` in spirit but is exhaustive: every ``(x_c, w)`` of a
grid over the data (centres across and beyond the range, widths from 2 % to
20× the span) gets its closed-form least-squares :math:`(y_0, A)`, and the best
pair starts the gradient refinement.  A monotonic drift (peak outside the
range) is then represented by a far centre and a wide curve.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from . import specs
from .base import TINY, Family, as_numpy, distinct_levels
from .cgen import CBody, as_float32, c_array

__all__ = ["Lorentz", "lorentzian"]


def lorentzian(x: torch.Tensor, y0: torch.Tensor, amplitude: torch.Tensor, center: torch.Tensor,
               width: torch.Tensor) -> torch.Tensor:
    """Origin's Lorentz curve; ``width`` (FWHM) guarded by ``max(tiny, w)``."""
    w = torch.clamp(width, min=TINY)
    return y0 + (2.0 / math.pi) * amplitude * w / (4.0 * (x - center) ** 2 + w * w)


def _grid_guess(x: np.ndarray, y: np.ndarray, lo: float, hi: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Best (y0, A, xc, w) per output over an (xc, w) grid, each with least-squares y0, A."""
    step = max(1, x.size // 2000)  # even decimation: the guess needs the shape, not every sample
    x, y = x[::step], y[::step]
    span = max(float(np.ptp(x)), TINY)
    xcs = np.linspace(lo, hi, 49)
    ws = span * np.logspace(np.log10(0.02), np.log10(20.0), 36)
    xc_g, w_g = (a.ravel() for a in np.meshgrid(xcs, ws, indexing="ij"))
    g = (2.0 / np.pi) * w_g[:, None] / (4.0 * (x[None, :] - xc_g[:, None]) ** 2 + w_g[:, None] ** 2)
    n = x.size
    sg, sgg = g.sum(1), (g * g).sum(1)                 # (K,)
    sy, syy, sgy = y.sum(0), (y * y).sum(0), g @ y     # (A,), (A,), (K, A)
    det = np.maximum(n * sgg - sg * sg, TINY)[:, None]
    amp = (n * sgy - sg[:, None] * sy[None, :]) / det
    y0 = (sy[None, :] - amp * sg[:, None]) / n
    sse = syy[None, :] - 2 * y0 * sy[None, :] - 2 * amp * sgy + n * y0 ** 2 \
        + 2 * y0 * amp * sg[:, None] + amp ** 2 * sgg[:, None]
    best = np.argmin(sse, axis=0)                      # (A,)
    cols = np.arange(y.shape[1])
    return y0[best, cols], amp[best, cols], xc_g[best], w_g[best]


class Lorentz(Family):
    """Origin's Lorentz curve on one input, per-axis ``y0, A, xc, w``."""

    xc_lo: torch.Tensor      # buffers, declared for the type checker
    xc_hi: torch.Tensor

    spec = specs.Lorentz   # name, inputs, hyper-parameters: their defaults and rules
    xc_margin: float

    def __init__(self, *, n_inputs: int, n_outputs: int, **hyper: Any) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        self.take_hyper(hyper)
        self.y0 = nn.Parameter(torch.zeros(n_outputs))
        self.amplitude = nn.Parameter(torch.zeros(n_outputs))
        self.center_raw = nn.Parameter(torch.zeros(n_outputs))
        self.width_raw = nn.Parameter(torch.ones(n_outputs))
        self.register_buffer("xc_lo", torch.tensor([-1.0]))
        self.register_buffer("xc_hi", torch.tensor([1.0]))

    @property
    def center(self) -> torch.Tensor:
        return self.xc_lo + (self.xc_hi - self.xc_lo) * torch.sigmoid(self.center_raw)

    @property
    def width(self) -> torch.Tensor:
        return F.softplus(self.width_raw) + TINY

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return lorentzian(z[:, 0:1], self.y0, self.amplitude, self.center, self.width)

    def output_form(self, y_std: torch.Tensor, y_mean: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(y0, k, xc, h)`` (each (A,)) of the curve in output units,
        :math:`y = y_0 + k / ((z - x_c)^2 + h)` with :math:`k = A w s_y / (2\\pi)`,
        :math:`h = w^2/4`, :math:`w = \\max(\\text{tiny}, w)`."""
        w = torch.clamp(self.width, min=TINY)
        return (self.y0 * y_std + y_mean, self.amplitude * w * y_std * (0.5 / math.pi),
                self.center, 0.25 * w * w)

    def drift(self, z: Sequence[torch.Tensor], y_std: torch.Tensor,
              y_mean: torch.Tensor) -> torch.Tensor:
        y0, k, xc, h = self.output_form(y_std, y_mean)
        dx = z[0] - xc[:, None]
        return y0[:, None] + k[:, None] / (dx * dx + h[:, None])

    def emit_c(self, prefix: str, y_std: torch.Tensor, y_mean: torch.Tensor) -> CBody:
        p, P = prefix, prefix.upper()
        with torch.no_grad():
            y0, k, xc, h = (as_float32(v) for v in self.output_form(y_std, y_mean))
        consts = [c_array(f"{p}_lor_y0", y0), c_array(f"{p}_lor_k", k),
                  c_array(f"{p}_lor_xc", xc), c_array(f"{p}_lor_h", h)]
        body = f"""\
    for (a = 0; a < {P}_N_AXES; ++a) {{
        float dx = z[0] - {p}_lor_xc[a];
        y[a] = {p}_lor_y0[a] + {p}_lor_k[a] / (dx * dx + {p}_lor_h[a]);
    }}"""
        return CBody(consts, body)

    def op_count(self) -> tuple[int, int]:
        """Per axis ``z − xc``, ``dx·dx + h`` (one multiply-add), the division and
        ``y0 +``: :math:`4A`."""
        return 4 * self.n_outputs, 0

    def check_fittable(self, x: torch.Tensor) -> str | None:
        xn = as_numpy(x)
        levels = distinct_levels(xn[:, 0], cap=4)
        if levels < 4:
            return (f"the input takes {levels} distinct value(s); the Lorentz curve has 4 "
                    "parameters and needs at least 4")
        return None

    def initialize(self, x: torch.Tensor, y: torch.Tensor, *, seed: int = 0,
                   x_mean: np.ndarray | None = None, x_std: np.ndarray | None = None) -> None:
        xn, yn = as_numpy(x)[:, 0], as_numpy(y)
        lo, hi = float(xn.min()), float(xn.max())
        margin = self.xc_margin * max(hi - lo, TINY)
        lo_b, hi_b = lo - margin, hi + margin
        y0, amp, xc, w = _grid_guess(xn, yn, lo_b, hi_b)
        frac = np.clip((xc - lo_b) / max(hi_b - lo_b, TINY), 1e-4, 1 - 1e-4)
        w = np.maximum(w - TINY, TINY)
        with torch.no_grad():
            self.xc_lo.fill_(lo_b)
            self.xc_hi.fill_(hi_b)
            self.y0.copy_(torch.as_tensor(y0))
            self.amplitude.copy_(torch.as_tensor(amp))
            self.center_raw.copy_(torch.as_tensor(np.log(frac / (1 - frac))))
            # inverse softplus, stable for small and large w
            self.width_raw.copy_(torch.as_tensor(w + np.log(-np.expm1(-w))))
