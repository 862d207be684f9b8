"""Multilayer perceptron: a small dense network on any inputs, sized for a
microcontroller.

.. math::

    h^{(0)} = z, \\qquad
    h^{(l)} = \\phi\\big(W_l\\, h^{(l-1)} + b_l\\big)\\ \\ (l = 1 \\dots L), \\qquad
    \\hat y = W_o\\, h^{(L)} + b_o

with ``hidden = [H_1, …, H_L]`` units per layer (default ``[8, 8]``: 97 constants, 388
bytes and 144 operations per sample for one input and one axis, 16 of them ``expm1``
calls; :meth:`Family.cost`), activation :math:`\\phi` one of

* ``tanh`` (default): smooth, bounded, the literature's temperature-compensation MLPs;
  in C :math:`\\tanh x = \\operatorname{sign}(x)\\,\\frac{-e}{e + 2}`,
  :math:`e = \\operatorname{expm1}(-2|x|)` — the header's bounded fast ``expm1f`` on a
  single-precision FPU (:func:`~.cgen.c_expm1`), no cancellation near 0, exactly ±1 in
  saturation;
* ``relu``: :math:`\\max(0, x)`, no transcendental (piecewise linear: it extrapolates
  linearly, and its corners show in the drift curve);
* ``silu``: :math:`x\\,\\sigma(x) = x / (1 + e^{-x})` (one ``expf``).

``weight_decay`` :math:`\\lambda \\ge 0` (default 1e-6) adds :math:`\\lambda \\sum W^2` over
every weight matrix (the biases are free) to the mean squared error in standardised units
that the training loop minimises (:meth:`penalty`); it keeps the weights — and so the
curve's bends and its extrapolation — small where the data do not ask for them.

Start (:meth:`initialize`), deterministic from the seed (a seeded ``torch.Generator``, never
the global random state: families are fitted side by side in threads): each hidden layer's
weights are drawn :math:`\\mathcal N(0, g^2/\\text{fan-in})` (:math:`g` the activation's gain)
and each unit's bias puts its transition on a training sample drawn at random
(:math:`b_j = -W_j h_{r_j}`), so the units' bends are spread over the data; the output
layer is then the closed-form minimum of the penalised loss given the hidden features
(ridge least squares, :math:`\\lambda N A` on the weights).  The training loop refines
everything (L-BFGS by default, early stopping).

Evaluation (:meth:`drift`) is axis-major: one ``addmm`` per layer on (H, N) rows, the
de-standardisation folded into the output layer.  A NaN in ``z[0]`` reaches every axis
through the first layer; the output adds ``z[0] − z[0]`` (0, or NaN) as well, so that no
activation kernel that clamps its argument (onnxruntime's MLAS ``tanh`` does) can turn a
broken thermometer into a plausible drift.
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
from .base import Family, as_numpy, distinct_levels, output_layer
from .cgen import C_COPYSIGNF, CBody, as_float32, c_affine, c_array, c_exp, c_expm1
from .hyper import MLP_MAX_LAYERS, MLP_MAX_WIDTH

__all__ = ["MLP", "ACTIVATIONS", "ACTIVATION_OPS"]

#: The activations, with their gain for the start's weight scale (Glorot's 5/3 for tanh,
#: He's √2 for relu, ≈ √2 for silu)
ACTIVATIONS = {"tanh": 5.0 / 3.0, "relu": math.sqrt(2.0), "silu": math.sqrt(2.0)}
#: (operations, transcendental calls) of one activation in the C body: tanh: −2|x|, expm1,
#: e + 2, the division (the sign is a bit copy); relu: one max; silu: expf, 1 + e, the division
ACTIVATION_OPS = {"tanh": (4, 1), "relu": (1, 0), "silu": (3, 1)}
#: Bounds on the architecture: a network for a microcontroller, not a research model
MAX_LAYERS, MAX_WIDTH = MLP_MAX_LAYERS, MLP_MAX_WIDTH


class MLP(Family):
    """Dense network ``n_inputs → hidden[0] → … → hidden[-1] → n_outputs``."""

    spec = specs.MLP       # name, inputs, hyper-parameters: their defaults and rules
    hidden: list[int]
    activation: str
    weight_decay: float

    def __init__(self, *, n_inputs: int, n_outputs: int, **hyper: Any) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        self.take_hyper(hyper)
        sizes = [self.n_inputs, *self.hidden]
        self.weights = nn.ParameterList(
            [nn.Parameter(torch.zeros(n, m)) for m, n in zip(sizes[:-1], sizes[1:], strict=True)])
        self.biases = nn.ParameterList([nn.Parameter(torch.zeros(n)) for n in self.hidden])
        self.weight = nn.Parameter(torch.zeros(n_outputs, self.hidden[-1]))   # output layer
        self.bias = nn.Parameter(torch.zeros(n_outputs))

    # ------------------------------------------------------------------ the function
    def act(self, x: torch.Tensor) -> torch.Tensor:
        """The activation, elementwise."""
        if self.activation == "tanh":
            return torch.tanh(x)
        if self.activation == "relu":
            return torch.relu(x)
        return F.silu(x)

    def features(self, z: torch.Tensor) -> torch.Tensor:
        """The last hidden layer's outputs (N, H_L) from standardised features (N, F)."""
        h = z
        for w, b in zip(self.weights, self.biases, strict=True):
            h = self.act(torch.addmm(b, h, w.T))
        return h

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return torch.addmm(self.bias, self.features(z), self.weight.T)

    def penalty(self) -> torch.Tensor | None:
        """:math:`\\lambda \\sum W^2` over the hidden and output weight matrices; None for
        :math:`\\lambda = 0`."""
        if self.weight_decay == 0.0:
            return None
        total = (self.weight * self.weight).sum()
        for w in self.weights:
            total = total + (w * w).sum()
        return self.weight_decay * total

    def drift(self, z: Sequence[torch.Tensor], y_std: torch.Tensor,
              y_mean: torch.Tensor) -> torch.Tensor:
        h = torch.stack(list(z))                                        # (F, N)
        for w, b in zip(self.weights, self.biases, strict=True):
            h = self.act(torch.addmm(b[:, None], w, h))                  # (H, N)
        wo, bo = output_layer(self.weight, self.bias, y_std, y_mean)
        # z0 - z0: 0 for a finite sample, NaN for a NaN one, whatever the activation kernel
        return torch.addmm(bo[:, None] + (z[0] - z[0]), wo, h)

    # ------------------------------------------------------------------ C and cost
    def _c_activation(self, var: str) -> str:
        """C statements applying the activation to the float lvalue ``var`` (finite in the
        header: its signals are clamped and a non-finite one is handled after the body)."""
        if self.activation == "tanh":
            return (f"{{ const float e = {c_expm1(f'-2.0f * fabsf({var})')}; "
                    f"{var} = {C_COPYSIGNF}(-e / (e + 2.0f), {var}); }}")
        if self.activation == "relu":
            return f"if ({var} < 0.0f) {var} = 0.0f;"
        return f"{var} = {var} / (1.0f + {c_exp(f'-{var}')});"

    def emit_c(self, prefix: str, y_std: torch.Tensor, y_mean: torch.Tensor) -> CBody:
        p = prefix
        ind = " " * 8
        with torch.no_grad():
            wo, bo = output_layer(self.weight, self.bias, y_std, y_mean)
        consts: list[str] = []
        lines = ["    {", f"{ind}int j;"]
        lines += [f"{ind}float h{k}[{n}];" for k, n in enumerate(self.hidden)]
        prev = [f"z[{f}]" for f in range(self.n_inputs)]
        for k, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            consts += [c_array(f"{p}_mlp_w{k}", as_float32(w)),
                       c_array(f"{p}_mlp_b{k}", as_float32(b))]
            lines.append(c_affine(f"h{k}", f"{p}_mlp_w{k}", f"{p}_mlp_b{k}", self.hidden[k],
                                  list(enumerate(prev)), ind))
            lines.append(f"{ind}for (j = 0; j < {self.hidden[k]}; ++j) "
                         f"{self._c_activation(f'h{k}[j]')}")
            prev = [f"h{k}[{j}]" for j in range(self.hidden[k])]
        consts += [c_array(f"{p}_mlp_wo", as_float32(wo)), c_array(f"{p}_mlp_bo", as_float32(bo))]
        lines.append(c_affine("y", f"{p}_mlp_wo", f"{p}_mlp_bo", self.n_outputs,
                              list(enumerate(prev)), ind))
        lines.append("    }")
        return CBody(consts, "\n".join(lines))

    def op_count(self) -> tuple[int, int]:
        """One multiply-add per weight, and each hidden unit's activation
        (:data:`ACTIVATION_OPS`)."""
        sizes = [self.n_inputs, *self.hidden, self.n_outputs]
        macs = sum(m * n for m, n in zip(sizes[:-1], sizes[1:], strict=True))
        ops, trans = ACTIVATION_OPS[self.activation]
        units = sum(self.hidden)
        return macs + ops * units, trans * units

    # ------------------------------------------------------------------ fitting
    def check_fittable(self, x: torch.Tensor) -> str | None:
        xn = as_numpy(x)
        n_coef = self.hidden[-1] + 1
        if xn.shape[0] < n_coef:
            return (f"{xn.shape[0]} samples for the {n_coef} output-layer coefficients per axis "
                    "(fewer units in the last hidden layer)")
        if max(distinct_levels(xn[:, j], cap=2) for j in range(xn.shape[1])) < 2:
            return "every input takes a single value: nothing to fit"
        return None

    def initialize(self, x: torch.Tensor, y: torch.Tensor, *, seed: int = 0,
                   x_mean: np.ndarray | None = None, x_std: np.ndarray | None = None) -> None:
        gen = torch.Generator().manual_seed(int(seed))
        gain = ACTIVATIONS[self.activation]
        h = torch.as_tensor(as_numpy(x))                              # float64 (N, F)
        n = h.shape[0]
        with torch.no_grad():
            for w, b in zip(self.weights, self.biases, strict=True):
                fan_out, fan_in = w.shape
                w64 = torch.randn(fan_out, fan_in, generator=gen, dtype=torch.float64)
                w64 *= gain / math.sqrt(fan_in)
                rows = torch.randint(n, (fan_out,), generator=gen)
                b64 = -(w64 * h[rows]).sum(dim=1)         # unit j's transition at sample r_j
                w.copy_(w64)
                b.copy_(b64)
                # the float32 parameters' own features, as the network will compute them
                h = self.act(torch.addmm(b.double(), h, w.double().T))
        coef = _ridge_with_bias(as_numpy(h), as_numpy(y), self.weight_decay * n * self.n_outputs)
        with torch.no_grad():
            self.weight.copy_(torch.as_tensor(coef[:-1].T))
            self.bias.copy_(torch.as_tensor(coef[-1]))


def _ridge_with_bias(h: np.ndarray, y: np.ndarray, lam: float) -> np.ndarray:
    """Coefficients (K + 1, A) minimising :math:`\\lVert [H, 1] c - y \\rVert^2 + \\lambda
    \\lVert c_{:K} \\rVert^2` (the bias unpenalised), plus a tiny relative ridge on every
    coefficient so that a unit constant on the data (saturated) stays determined."""
    d = np.hstack([h, np.ones((h.shape[0], 1))])
    g = d.T @ d
    diag = np.full(g.shape[0], float(lam))
    diag[-1] = 0.0
    diag += 1e-10 * max(float(np.trace(g)) / g.shape[0], 1e-6)
    return np.linalg.solve(g + np.diag(diag), d.T @ y)
