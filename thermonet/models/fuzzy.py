"""One-input Takagi–Sugeno fuzzy model (study 002).

``n_sets`` triangular membership functions with peaks :math:`p_i` evenly
spaced over the universe :math:`[l, h]` and half-width the spacing
:math:`\\delta = (h - l)/(n - 1)`, so inside the universe they sum to one:

.. math::

    \\lambda_i(z) = \\max\\!\\left(0,\\ 1 - \\frac{|\\tilde z - p_i|}{\\delta}\\right),
    \\quad \\tilde z = \\min(\\max(z, l), h)

    y_i = b_i + a_i \\tilde z, \\qquad
    \\hat y = \\frac{\\sum_i \\lambda_i y_i}{\\max(\\text{tiny}, \\sum_i \\lambda_i)}

The universe defaults to the trained input range; ``universe=[lo, hi]`` gives
it in the input feature's own units (``T``: °C, e.g. study 002's [−40, 75];
``dT``: °C relative to T_ref) and is converted to standardised units at
:meth:`TSFuzzy.initialize`.  The sets are fixed (as in the study); the rule
coefficients :math:`a_i, b_i` (per axis) are found by least squares — the
output is linear in them — and then refined by the training loop.  Rules whose
set no sample reaches keep the minimum-norm (ridge) value, zero.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from ..core.errors import ConfigError
from . import specs
from .base import TINY, Family, as_numpy, distinct_levels, least_squares
from .cgen import CBody, as_float32, c_array, c_float

__all__ = ["TSFuzzy"]


class TSFuzzy(Family):
    """Takagi–Sugeno fuzzy model: triangular sets, first-order rules, per-axis coefficients."""

    peaks: torch.Tensor      # buffers, declared for the type checker
    spacing: torch.Tensor
    bounds: torch.Tensor

    spec = specs.Fuzzy     # name, inputs, hyper-parameters: their defaults and rules
    n_sets: int
    universe: list[float] | None

    def __init__(self, *, n_inputs: int, n_outputs: int, **hyper: Any) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        n_sets = self.take_hyper(hyper)["n_sets"]
        self.slope = nn.Parameter(torch.zeros(n_outputs, n_sets))      # a_i
        self.intercept = nn.Parameter(torch.zeros(n_outputs, n_sets))  # b_i
        self.register_buffer("peaks", torch.linspace(-1.0, 1.0, n_sets))
        self.register_buffer("spacing", torch.tensor([2.0 / (n_sets - 1)]))
        self.register_buffer("bounds", torch.tensor([-1.0, 1.0]))

    def memberships(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Clamped input (N, 1) and normalised memberships (N, n_sets)."""
        x = torch.minimum(torch.maximum(z[:, 0:1], self.bounds[0:1]), self.bounds[1:2])
        lam = torch.relu(1.0 - torch.abs(x - self.peaks) / torch.clamp(self.spacing, min=TINY))
        return x, lam / torch.clamp(lam.sum(dim=1, keepdim=True), min=TINY)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        x, lam = self.memberships(z)
        return lam @ self.intercept.T + (lam * x) @ self.slope.T

    def rules(self, y_std: torch.Tensor, y_mean: torch.Tensor) -> torch.Tensor:
        """Rule coefficients in output units, (A, 2 n_sets): intercepts then slopes.

        Since the normalised memberships sum to one, :math:`\\bar y` folds into
        every intercept: :math:`b'_i = b_i s_y + \\bar y`, :math:`a'_i = a_i s_y`.
        """
        return torch.cat([self.intercept * y_std[:, None] + y_mean[:, None],
                          self.slope * y_std[:, None]], dim=1)

    def drift(self, z: Sequence[torch.Tensor], y_std: torch.Tensor,
              y_mean: torch.Tensor) -> torch.Tensor:
        x = torch.minimum(torch.maximum(z[0], self.bounds[0]), self.bounds[1])
        inv = 1.0 / torch.clamp(self.spacing, min=TINY)
        xs = x * inv
        lam = torch.relu(1.0 - torch.abs(xs - (self.peaks * inv)[:, None]))   # (n_sets, N)
        u = torch.cat([lam, lam * x])
        # the clamp of x would hide a NaN input: z0 - z0 (0 or NaN) brings it back
        total = torch.clamp(lam.sum(dim=0), min=TINY) + (z[0] - z[0])
        return torch.mm(self.rules(y_std, y_mean), u) / total

    def emit_c(self, prefix: str, y_std: torch.Tensor, y_mean: torch.Tensor) -> CBody:
        # At most two neighbouring sets are non-zero at any x: find them by index
        # instead of evaluating all n_sets (the same memberships, fewer instructions).
        p, P = prefix, prefix.upper()
        with torch.no_grad():
            rules = as_float32(self.rules(y_std, y_mean))  # (A, 2n)
            lo, hi = (float(v) for v in as_float32(self.bounds))
            inv = float(as_float32(1.0 / torch.clamp(self.spacing, min=TINY))[0])
        n = self.n_sets
        consts = [f"#define {P}_FUZZY_SETS {n}",
                  c_array(f"{p}_fz_intercept", rules[:, :n]),
                  c_array(f"{p}_fz_slope", rules[:, n:])]
        body = f"""\
    {{
        float x = z[0], t, lam0, lam1, inv_total;
        int k;  /* the left set (not i: the generator's loop variable) */
        if (!(x >= {c_float(lo)})) x = {c_float(lo)};  /* NaN too: it is flagged later */
        if (x > {c_float(hi)}) x = {c_float(hi)};
        t = (x - {c_float(lo)}) * {c_float(inv)};
        k = (int)t;
        if (k > {P}_FUZZY_SETS - 2) k = {P}_FUZZY_SETS - 2;
        if (k < 0) k = 0;
        lam1 = t - (float)k;
        lam0 = 1.0f - lam1;
        if (lam0 < 0.0f) lam0 = 0.0f;
        if (lam1 > 1.0f) lam1 = 1.0f;
        inv_total = 1.0f / (lam0 + lam1);
        for (a = 0; a < {P}_N_AXES; ++a) {{
            y[a] = (lam0 * ({p}_fz_intercept[a][k] + {p}_fz_slope[a][k] * x)
                    + lam1 * ({p}_fz_intercept[a][k + 1] + {p}_fz_slope[a][k + 1] * x))
                   * inv_total;
        }}
    }}"""
        return CBody(consts, body)

    def op_count(self) -> tuple[int, int]:
        """The two neighbouring sets only (:meth:`emit_c`): the input's clamp (2), its
        position (2), the two memberships (2) and their clamps (2), the normalisation (2);
        per axis the two rules (2 multiply-adds), their weighted sum (2) and the
        normalisation (1): :math:`10 + 5A`, whatever ``n_sets``."""
        return 10 + 5 * self.n_outputs, 0

    def check_fittable(self, x: torch.Tensor) -> str | None:
        levels = distinct_levels(as_numpy(x)[:, 0], cap=2)
        if levels < 2:
            return "the input takes a single value; the fuzzy rules need at least 2"
        return None

    def initialize(self, x: torch.Tensor, y: torch.Tensor, *, seed: int = 0,
                   x_mean: np.ndarray | None = None, x_std: np.ndarray | None = None) -> None:
        xn = as_numpy(x)
        if self.universe is None:
            lo, hi = float(xn[:, 0].min()), float(xn[:, 0].max())
        else:
            m = 0.0 if x_mean is None else float(np.asarray(x_mean).ravel()[0])
            s = 1.0 if x_std is None else float(np.asarray(x_std).ravel()[0])
            lo, hi = ((u - m) / s for u in self.universe)
        if hi - lo <= TINY:
            raise ConfigError(f"ts-fuzzy: empty universe [{lo}, {hi}] (standardised)")
        with torch.no_grad():
            self.bounds.copy_(torch.tensor([lo, hi]))
            self.peaks.copy_(torch.linspace(lo, hi, self.n_sets))
            self.spacing.fill_((hi - lo) / (self.n_sets - 1))
            xc, lam = self.memberships(torch.as_tensor(xn, dtype=torch.float32))
        lam_n, xc_n = as_numpy(lam), as_numpy(xc)
        coef = least_squares(np.hstack([lam_n, lam_n * xc_n]), as_numpy(y))  # (2n, A)
        with torch.no_grad():
            self.intercept.copy_(torch.as_tensor(coef[:self.n_sets].T))
            self.slope.copy_(torch.as_tensor(coef[self.n_sets:].T))
