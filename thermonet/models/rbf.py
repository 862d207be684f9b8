"""Gaussian radial-basis-function network (study 003), multi-input, multi-output.

.. math::

    \\varphi_j(z) = \\exp\\!\\left(-\\frac{\\lVert z - c_j \\rVert^2}{2\\sigma_j^2}\\right),
    \\qquad \\hat y_a = \\sum_j w_{a j}\\, \\varphi_j(z) + b_a

Centres :math:`c_j`, widths :math:`\\sigma_j = e^{s_j}` (log-parametrised,
with :math:`2 s_j` clipped to ±:data:`~.base.LOG_CLIP` so :math:`\\sigma_j^2` stays a
positive float32) and output weights are all trained; centres and widths are shared by
the axes, the weights form an (A, J) matrix.  Study 003 uses inputs
``[dT, dT2]`` (``[dT]`` is its "traditional" model).

``init="kmeans"`` (default): k-means centres (scikit-learn, seeded), each width
the distance to the nearest other centre × ``width_scale``, weights and bias
by least squares.  ``init="random"``: centres drawn uniformly in the data's
bounding box (seeded), unit widths, zero weights — plain gradient descent from
scratch, for comparison.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from ..core.errors import ConfigError
from .base import LOG_CLIP, TINY, Family, as_numpy, least_squares, output_layer
from .cgen import CBody, as_float32, c_affine, c_array, c_exp

__all__ = ["RBF"]

_INITS = ("kmeans", "random")


class RBF(Family):
    """Gaussian RBF network with ``n_centres`` shared units."""

    name = "rbf"
    max_inputs = None
    default_inputs = ["dT", "dT2"]

    def __init__(self, *, n_inputs: int, n_outputs: int, n_centres: int = 16,
                 init: str = "kmeans", width_scale: float = 1.0) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        if (
            isinstance(n_centres, bool)
            or not isinstance(n_centres, int)
            or not 1 <= n_centres <= 4096
        ):
            raise ConfigError(f"rbf: n_centres must be an integer in 1..4096, got {n_centres!r}")
        if init not in _INITS:
            raise ConfigError(f"rbf: init must be one of {', '.join(_INITS)}, got {init!r}")
        if isinstance(width_scale, bool) or not isinstance(width_scale, (int, float)) \
                or not width_scale > 0:
            raise ConfigError(f"rbf: width_scale must be a number > 0, got {width_scale!r}")
        self.n_centres = int(n_centres)
        self.init = init
        self.width_scale = float(width_scale)
        self.centres = nn.Parameter(torch.zeros(n_centres, n_inputs))
        self.log_sigma = nn.Parameter(torch.zeros(n_centres))
        self.weight = nn.Parameter(torch.zeros(n_outputs, n_centres))
        self.bias = nn.Parameter(torch.zeros(n_outputs))

    def basis(self, z: torch.Tensor) -> torch.Tensor:
        """Unit activations φ (N, J)."""
        # one (N, J) difference per input, summed: the same value as broadcasting
        # (N, 1, F) − (1, J, F), but exported as trailing-axis broadcasts, which
        # onnxruntime runs several times faster than a middle-axis one
        diff = z[:, 0:1] - self.centres[:, 0]
        d2 = diff * diff
        for f in range(1, self.n_inputs):
            diff = z[:, f:f + 1] - self.centres[:, f]
            d2 = d2 + diff * diff
        return torch.exp(-d2 * self.inv_two_sigma2())

    def inv_two_sigma2(self) -> torch.Tensor:
        """:math:`1 / (2\\sigma_j^2)` (J,), with :math:`2 s_j` clipped to ±LOG_CLIP."""
        return 0.5 * torch.exp(-torch.clamp(2.0 * self.log_sigma, min=-LOG_CLIP, max=LOG_CLIP))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.basis(z) @ self.weight.T + self.bias

    def exponent(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(M, b)``: the exponent of every unit as one matrix product.

        With :math:`g_j = 1/(2\\sigma_j^2)`,

        .. math::

            -g_j \\lVert z - c_j \\rVert^2
            = \\underbrace{[z_1 \\dots z_F,\\ \\lVert z \\rVert^2]}_{u}\\,
              \\underbrace{\\begin{bmatrix} 2 g_j c_j \\\\ -g_j \\end{bmatrix}}_{M_{:,j}}
              \\; \\underbrace{-\\, g_j \\lVert c_j \\rVert^2}_{b_j}

        M is (F + 1, J), b is (J,).
        """
        g = self.inv_two_sigma2()
        m = torch.cat([2.0 * self.centres * g[:, None], -g[:, None]], dim=1).T
        return m, -g * (self.centres * self.centres).sum(dim=1)

    def drift(self, z: Sequence[torch.Tensor], y_std: torch.Tensor,
              y_mean: torch.Tensor) -> torch.Tensor:
        # ‖z − c‖² expanded: one (J, F+2) × (F+2, N) product — the rows of u are z,
        # ‖z‖² and ones, so the bias b rides in the product instead of a pass over
        # (J, N) — then exp, then one (A, J) × (J, N) product: two Gemm nodes
        # instead of F broadcast passes over (N, J) per input
        zz = z[0] * z[0]
        for zf in z[1:]:
            zz = zz + zf * zf
        m, b = self.exponent()
        u = torch.stack([*z, zz, torch.ones_like(zz)])
        phi = torch.exp(torch.mm(torch.cat([m.T, b[:, None]], dim=1), u))
        w, c = output_layer(self.weight, self.bias, y_std, y_mean)
        return torch.addmm(c[:, None], w, phi)

    def emit_c(self, prefix: str, y_std: torch.Tensor, y_mean: torch.Tensor) -> CBody:
        p, P = prefix, prefix.upper()
        with torch.no_grad():
            m, b = self.exponent()
            w, c = output_layer(self.weight, self.bias, y_std, y_mean)
        consts = [f"#define {P}_RBF_CENTRES {int(self.n_centres)}",
                  # one row per centre: F coefficients of z, then that of ||z||^2
                  c_array(f"{p}_rbf_m", as_float32(m.T)), c_array(f"{p}_rbf_b", as_float32(b)),
                  c_array(f"{p}_rbf_w", as_float32(w)), c_array(f"{p}_rbf_c", as_float32(c))]
        n_c, n_f = int(self.n_centres), int(m.shape[0]) - 1
        # exponent of centre j: b_j + m_j,F·||z||² + Σ_f m_j,f·z_f (this order), then exp
        exponent = c_affine("phi", f"{p}_rbf_m", f"{p}_rbf_b", n_c,
                            [(n_f, "zz")] + [(f, f"z[{f}]") for f in range(n_f)], " " * 8)
        body = f"""\
    {{
        float phi[{P}_RBF_CENTRES];
        float zz = 0.0f;
        int j;
        for (f = 0; f < {P}_N_FEATURES; ++f) zz += z[f] * z[f];
{exponent}
        for (j = 0; j < {P}_RBF_CENTRES; ++j) phi[j] = {c_exp('phi[j]')};
{c_affine("y", f"{p}_rbf_w", f"{p}_rbf_c", int(w.shape[0]),
          [(j, f"phi[{j}]") for j in range(n_c)], " " * 8)}
    }}"""
        return CBody(consts, body)

    def check_fittable(self, x: torch.Tensor) -> str | None:
        xn = as_numpy(x)
        if xn.shape[0] < self.n_centres:
            return f"{xn.shape[0]} samples for {self.n_centres} centres"
        span = np.maximum(np.ptp(xn, axis=0), TINY)
        rows = np.unique(np.floor((xn - xn.min(axis=0)) / (0.005 * span)), axis=0).shape[0]
        if rows < self.n_centres:
            return (f"the inputs take {rows} distinct value(s), fewer than the "
                    f"{self.n_centres} centres (lower n_centres)")
        return None

    def initialize(self, x: torch.Tensor, y: torch.Tensor, *, seed: int = 0,
                   x_mean: np.ndarray | None = None, x_std: np.ndarray | None = None) -> None:
        xn, yn = as_numpy(x), as_numpy(y)
        if self.init == "random":
            rng = np.random.default_rng(seed)
            centres = rng.uniform(
                xn.min(axis=0), xn.max(axis=0), size=(self.n_centres, xn.shape[1])
            )
            with torch.no_grad():
                self.centres.copy_(torch.as_tensor(centres))
                self.log_sigma.zero_()
                self.weight.zero_()
                self.bias.zero_()
            return
        step = max(1, xn.shape[0] // 5000)  # even decimation bounds k-means cost
        from sklearn.cluster import KMeans  # heavy: loaded when an RBF is initialised

        km = KMeans(n_clusters=self.n_centres, random_state=seed, n_init=4).fit(xn[::step])
        centres = km.cluster_centers_
        dist = np.sqrt(((centres[:, None, :] - centres[None, :, :]) ** 2).sum(-1))
        np.fill_diagonal(dist, np.inf)
        nearest = dist.min(axis=1) if self.n_centres > 1 else np.full(1, float(np.ptp(xn)))
        # Coincident centres (few distinct inputs) would get zero width; give them
        # the typical spacing instead.
        ok = np.isfinite(nearest) & (nearest > TINY)
        fallback = float(np.median(nearest[ok])) if ok.any() else 1.0
        sigma = np.where(ok, nearest, fallback) * self.width_scale
        with torch.no_grad():
            self.centres.copy_(torch.as_tensor(centres))
            self.log_sigma.copy_(torch.as_tensor(np.log(sigma)))
            phi = as_numpy(self.basis(torch.as_tensor(xn, dtype=torch.float32)))
        coef = least_squares(np.hstack([phi, np.ones((phi.shape[0], 1))]), yn, ridge=1e-6)
        with torch.no_grad():
            self.weight.copy_(torch.as_tensor(coef[:-1].T))
            self.bias.copy_(torch.as_tensor(coef[-1]))

    def hyper(self) -> dict[str, Any]:
        return {"n_centres": self.n_centres, "init": self.init, "width_scale": self.width_scale}
