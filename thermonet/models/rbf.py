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
by least squares.  ``init="quantiles"``: the same, but the centres are placed, not
clustered: at the quantiles of the first input, kept at least half an even grid step apart,
each other input interpolated along the samples sorted by the first
(:func:`quantile_centres`).  On inputs that all follow one variable — ``[dT, dT2]`` — the
centres lie on the data's own curve, where the data are, as k-means puts them; deterministic
(no seed) and without scikit-learn, whose import (about 0.7 s with the SciPy and pandas
modules it loads) was most of a small fit's cost.  The default family set's RBF and
``thermonet calibrate``'s comparison use it (``experiments/bench_rbf_centres.py``: the same
held-out scores as k-means on calibrate's boards, a lagged lent thermometer beside ΔT
included, and as good or better on the presets).  Where the inputs vary independently of the
first, k-means is the choice: it spreads the centres in all of them.
``init="random"``: centres drawn uniformly in the
data's bounding box (seeded), unit widths, zero weights — plain gradient descent from
scratch, for comparison.

The polynomial tail (``tail: 3``; the default family set's ``rbf``)
---------------------------------------------------------------------
With ``tail = d > 0`` the network gains an unpenalised polynomial of degree ``d`` in the
first input (ΔT by default; on ``[dT, dT2]`` standardised ΔT is affine in ΔT, so the tail is
the cubic in ΔT that PX4 and ArduPilot fit) and the Gaussian part is penalised:

.. math::

    \\hat y_a = \\sum_j w_{aj}\\,\\varphi_j(z) + \\sum_{k=1}^{d} t_{ak} z_1^k + b_a,
    \\qquad \\min_{w,t,b}\\ \\lVert \\Phi w + P t - y \\rVert^2 + \\lambda_a\\, w^\\top K w

with one shared width (:math:`K_{ij} = \\varphi_j(c_i)`, the kernel between centres: the
penalty is the norm of the Gaussian part in the kernel's own space, the regularisation
network of Poggio & Girosi).  Its two limits are the reason for it: :math:`\\lambda\\to\\infty`
gives exactly the polynomial tail (the cubic — so the patent's model is at worst the
baseline it should contain), and with the samples at the centres the solution *is*
``scipy.interpolate.RBFInterpolator(kernel="gaussian", degree=d, smoothing=λ)`` (its
linear system :math:`(K + \\lambda I)w + Pt = y,\\ P^\\top w = 0` is this problem's
stationarity condition) — the independent oracle of ``tests/test_rbf_tail.py``.  (Note that
``RBFInterpolator``'s own ``degree=3`` tail on ``[dT, dT2]`` would be degree 6 in ΔT.)

``ridge: cv`` (default in tail mode) chooses, on the training rows only, the shared width
(``width_scale`` × 0.5, 1, 2 of the median nearest-centre distance) and each axis's
:math:`\\lambda_a` (relative to :math:`\\operatorname{tr}(\\Phi^\\top\\Phi)/J`, from
:data:`RIDGE_GRID`, :math:`\\infty` included) by an inner cross-validation over
:data:`INNER_BLOCKS` contiguous blocks dealt round-robin into :data:`INNER_FOLDS` folds, a
block's neighbours purged from its fold's training rows; the largest :math:`\\lambda` within
one standard error of the best is taken (the smoother model).  A number fixes
:math:`\\lambda` for every axis.  The fit is then closed-form and final: gradient refinement
of an unpenalised loss would undo the penalty, so the training loop skips its epochs
(:meth:`trainable` is False).  ``tuned()`` reports the
chosen width and :math:`\\lambda_a`.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from . import specs
from .base import LOG_CLIP, TINY, Family, as_numpy, distinct_levels, least_squares, output_layer
from .cgen import CBody, as_float32, c_affine, c_array, c_exp
from .hyper import RBF_INITS
from .rbf_fit import (
    INNER_BLOCKS,
    RIDGE_GRID,
    WIDTH_GRID,
    design,
    distinct_rows,
    inner_folds,
    penalised,
    quantile_centres,
    ridge_paths,
)

__all__ = ["RBF"]

_INITS = RBF_INITS


class RBF(Family):
    """Gaussian RBF network with ``n_centres`` shared units."""

    spec = specs.RBF       # name, inputs, hyper-parameters: their defaults and rules
    n_centres: int
    init: str
    width_scale: float
    tail: int
    ridge: float | str

    def __init__(self, *, n_inputs: int, n_outputs: int, **hyper: Any) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        n_centres = self.take_hyper(hyper)["n_centres"]
        self.centres = nn.Parameter(torch.zeros(n_centres, n_inputs))
        self.log_sigma = nn.Parameter(torch.zeros(n_centres))
        self.weight = nn.Parameter(torch.zeros(n_outputs, n_centres))
        self.bias = nn.Parameter(torch.zeros(n_outputs))
        if self.tail:
            # tail coefficients (A, d) on z_1 … z_1^d
            self.tail_weight = nn.Parameter(torch.zeros(n_outputs, self.tail))
        # what ridge 'cv' chose (reported by tuned(); not model state: inference needs only
        # the weights, and a checkpoint refuses the infinite ridge of "the tail alone")
        self._tuned: dict[str, Any] = {}

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

    def tail_columns(self, z1: Any, mul: Callable[[Any, Any], Any] = operator.mul) -> list[Any]:
        """z_1, z_1², … z_1^d by repeated multiplication (exports as Mul).  ``mul`` multiplies
        two columns: ``*`` on tensors here; the hand-built ONNX graph
        (:mod:`thermonet.exporting.onnx_graph`) passes one that writes a ``Mul`` node, so
        its tail is built by this very code."""
        cols = [z1]
        for _ in range(1, self.tail):
            cols.append(mul(cols[-1], z1))
        return cols

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        out = self.basis(z) @ self.weight.T + self.bias
        if self.tail:
            out = out + torch.stack(self.tail_columns(z[:, 0]), dim=1) @ self.tail_weight.T
        return out

    def trainable(self) -> bool:
        """False in tail mode: the closed-form penalised fit is final (module docstring)."""
        return not self.tail

    def gaussian_off(self) -> bool:
        """True where ``ridge`` chose ∞ on every axis: every Gaussian weight is exactly 0 and
        the model *is* its polynomial tail (a cubic in ``z_1`` with ``tail: 3``) — what the C
        header then computes, what :meth:`op_count` counts and what :meth:`n_effective` and
        :meth:`polynomial_form` report (read from the weights: a loaded model knows it too)."""
        # a fresh (unfitted) network has every weight 0: it is the structure, not a tail
        fitted = bool(torch.any(self.tail_weight.detach() != 0)) or bool(
            torch.any(self.bias.detach() != 0)) if self.tail else False
        return fitted and not bool(torch.any(self.weight.detach() != 0))

    def n_effective(self) -> int:
        """Parameters the model computes with: an axis whose Gaussian weights are all 0 (its
        ridge ∞) uses none of them, and with no such weight left the centres and widths go
        too — the tail and the bias remain (``tail: 3`` with ridge ∞ on every axis: the
        cubic's 4 per axis)."""
        if not self.gaussian_off() and not bool(torch.any(self.weight.detach() != 0)):
            return sum(int(p.numel()) for p in self.parameters() if p.requires_grad)
        live = int(torch.any(self.weight.detach() != 0, dim=1).sum())
        n = int(self.bias.numel()) + (int(self.tail_weight.numel()) if self.tail else 0)
        if live:
            n += live * self.n_centres + int(self.centres.numel() + self.log_sigma.numel())
        return n

    def polynomial_form(self) -> np.ndarray | None:
        """With every Gaussian weight 0 (:meth:`gaussian_off`): ``[b_a, t_{a,1} … t_{a,d}]``
        ascending in ``z_1`` — the model is that polynomial."""
        if not self.gaussian_off():
            return None
        return np.column_stack([as_numpy(self.bias), as_numpy(self.tail_weight)])

    def tuned(self) -> dict[str, Any]:
        """What ``ridge: cv`` chose: the width multiplier and each axis's relative ridge
        (``inf``: the tail alone); empty without a tail."""
        return dict(self._tuned)

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
        if self.tail:  # the tail's powers ride in the same product: one Gemm
            w = torch.cat([w, self.tail_weight * y_std[:, None]], dim=1)
            phi = torch.cat([phi, torch.stack(self.tail_columns(z[0]))])
        return torch.addmm(c[:, None], w, phi)

    def emit_c(self, prefix: str, y_std: torch.Tensor, y_mean: torch.Tensor) -> CBody:
        p, P = prefix, prefix.upper()
        if self.gaussian_off():   # ridge ∞ on every axis: the tail alone, no exp
            with torch.no_grad():
                w, c = output_layer(self.tail_weight, self.bias, y_std, y_mean)
            tail = "".join(f"        float zt{k} = {'z[0]' if k == 1 else f'zt{k - 1} * z[0]'};\n"
                           for k in range(1, self.tail + 1))
            affine = c_affine("y", f"{p}_rbf_w", f"{p}_rbf_c", int(w.shape[0]),
                              [(k, f"zt{k + 1}") for k in range(self.tail)], " " * 8)
            return CBody([c_array(f"{p}_rbf_w", as_float32(w)),
                          c_array(f"{p}_rbf_c", as_float32(c))],
                         f"    {{\n{tail}{affine}\n    }}")
        with torch.no_grad():
            m, b = self.exponent()
            w, c = output_layer(self.weight, self.bias, y_std, y_mean)
            if self.tail:  # columns J … J+d-1 of the weights: the tail's z_1 … z_1^d
                w = torch.cat([w, self.tail_weight * y_std[:, None]], dim=1)
        consts = [f"#define {P}_RBF_CENTRES {int(self.n_centres)}",
                  # one row per centre: F coefficients of z, then that of ||z||^2
                  c_array(f"{p}_rbf_m", as_float32(m.T)), c_array(f"{p}_rbf_b", as_float32(b)),
                  c_array(f"{p}_rbf_w", as_float32(w)), c_array(f"{p}_rbf_c", as_float32(c))]
        n_c, n_f = int(self.n_centres), int(m.shape[0]) - 1
        tail = "".join(f"        float zt{k} = {'z[0]' if k == 1 else f'zt{k - 1} * z[0]'};\n"
                       for k in range(1, self.tail + 1))
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
{tail}{c_affine("y", f"{p}_rbf_w", f"{p}_rbf_c", int(w.shape[0]),
          [(j, f"phi[{j}]") for j in range(n_c)]
          + [(n_c + k, f"zt{k + 1}") for k in range(self.tail)], " " * 8)}
    }}"""
        return CBody(consts, body)

    def op_count(self) -> tuple[int, int]:
        """:math:`\\lVert z \\rVert^2` (F multiply-adds), the exponents (J(F + 1)), the J
        ``exp`` calls, the tail's powers (d − 1 multiplies) and the output (A(J + d)):
        16 centres on 2 inputs, 3 axes, no tail: 2 + 48 + 16 + 48 = 114, 16 of them
        ``exp``."""
        f, j, d = self.n_inputs, self.n_centres, self.tail
        if self.gaussian_off():     # the tail alone (emit_c): its powers and the output
            return max(d - 1, 0) + self.n_outputs * d, 0
        return f + j * (f + 1) + j + max(d - 1, 0) + self.n_outputs * (j + d), j

    def check_fittable(self, x: torch.Tensor) -> str | None:
        xn = as_numpy(x)
        if xn.shape[0] < self.n_centres:
            return f"{xn.shape[0]} samples for {self.n_centres} centres"
        span = np.maximum(np.ptp(xn, axis=0), TINY)
        rows = distinct_rows(np.floor((xn - xn.min(axis=0)) / (0.005 * span)))
        if rows < self.n_centres:
            return (f"the inputs take {rows} distinct value(s), fewer than the "
                    f"{self.n_centres} centres (lower n_centres)")
        levels = distinct_levels(xn[:, 0], cap=max(2, self.tail + 1))
        if self.init == "quantiles" and self.n_centres > 1 and levels < 2:
            return ("input 1 takes 1 distinct value; init 'quantiles' spreads the centres over "
                    "its range (use init 'kmeans')")
        if self.tail and levels < self.tail + 1:
            return (f"input 1 takes {levels} distinct value(s); a degree-"
                    f"{self.tail} tail needs at least {self.tail + 1}")
        if self.tail and self.ridge == "cv" and xn.shape[0] < 2 * INNER_BLOCKS:
            return (f"{xn.shape[0]} samples: ridge 'cv' needs at least {2 * INNER_BLOCKS} "
                    "(or give ridge a number)")
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
        if self.init == "quantiles":
            centres = quantile_centres(xn, self.n_centres)
        else:
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
        if self.tail:
            self._fit_tail(xn, yn, centres, float(np.median(sigma)))
            return
        with torch.no_grad():
            self.centres.copy_(torch.as_tensor(centres))
            self.log_sigma.copy_(torch.as_tensor(np.log(sigma)))
            phi = as_numpy(self.basis(torch.as_tensor(xn, dtype=torch.float32)))
        coef = least_squares(np.hstack([phi, np.ones((phi.shape[0], 1))]), yn, ridge=1e-6)
        with torch.no_grad():
            self.weight.copy_(torch.as_tensor(coef[:-1].T))
            self.bias.copy_(torch.as_tensor(coef[-1]))

    def _fit_tail(self, xn: np.ndarray, yn: np.ndarray, centres: np.ndarray,
                  sigma0: float) -> None:
        """The penalised closed-form fit of the tail mode (module docstring)."""
        tail = np.column_stack([xn[:, 0] ** k for k in range(1, self.tail + 1)])
        poly = np.column_stack([tail, np.ones(xn.shape[0])])
        widths = [sigma0 * g for g in WIDTH_GRID] if self.ridge == "cv" else [sigma0]
        ridges = RIDGE_GRID if self.ridge == "cv" else (float(self.ridge),)
        designs = [design(xn, centres, s) for s in widths]   # Φ and chol(K), once a width
        if self.ridge == "cv":
            folds = inner_folds(xn.shape[0])
            phis = np.stack([d[0] for d in designs])
            chols = np.stack([d[1] for d in designs])
            l_inv = np.linalg.inv(chols)
            # (width, ridge, fold, axis) validation mean squared errors: every ridge of a
            # width and fold from one SVD, the widths of a fold stacked (ridge_paths)
            err = np.stack([ridge_paths(phis, chols, poly, yn, ridges, tr, l_inv=l_inv)[1](va)
                            for tr, va in folds], axis=2)
            mean = err.mean(axis=2)                       # (width, ridge, axis)
            se = err.std(axis=2, ddof=1) / math.sqrt(len(folds))
            best = mean.min(axis=1)                       # (width, axis)
            iw = int(np.argmin(best.sum(axis=1)))         # one width for every axis
            lam_idx = []
            for a in range(yn.shape[1]):
                ib = int(np.argmin(mean[iw, :, a]))
                ok = np.flatnonzero(mean[iw, :, a] <= mean[iw, ib, a] + se[iw, ib, a])
                lam_idx.append(int(ok.max()))            # the largest ridge within one SE
            lams = [ridges[i] for i in lam_idx]
            scale = WIDTH_GRID[iw]
        else:
            iw, lams, scale = 0, [ridges[0]] * yn.shape[1], 1.0
        sigma = widths[iw]
        coef = np.stack([penalised(*designs[iw], poly, yn[:, [a]], lam, None)[0][:, 0]
                         for a, lam in enumerate(lams)])          # (A, J + d + 1)
        n_c = centres.shape[0]
        with torch.no_grad():
            self.centres.copy_(torch.as_tensor(centres))
            self.log_sigma.fill_(math.log(sigma))
            self.weight.copy_(torch.as_tensor(coef[:, :n_c]))
            self.tail_weight.copy_(torch.as_tensor(coef[:, n_c:n_c + self.tail]))
            self.bias.copy_(torch.as_tensor(coef[:, -1]))
        self._tuned = {"width_scale": scale * self.width_scale,
                       "ridge": [lam if math.isfinite(lam) else "inf" for lam in lams]}

    def hyper(self) -> dict[str, Any]:
        out: dict[str, Any] = {"n_centres": self.n_centres, "init": self.init,
                               "width_scale": self.width_scale}
        if self.tail:  # only then: a checkpoint from before the tail rebuilds unchanged
            out.update(tail=self.tail, ridge=self.ridge)
        return out
