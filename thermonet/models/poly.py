"""Polynomial drift model (PX4/ArduPilot's cubic on dT; study 001's quadratic in Δf).

With one input :math:`z` and degree :math:`n`:

.. math:: \\hat y_a = b_a + \\sum_{k=1}^{n} c_{a,k}\\, z^k

With several inputs, by default each input contributes its own powers
:math:`z_i^1 \\dots z_i^n` and there are **no cross terms** (``cross=False``):
thermal models are built from one temperature-like input plus, at most, a
rate, and cross terms multiply the parameter count for no documented gain.
``cross=True`` uses every monomial of total degree 1…n instead.

**A mix** (``mix=[w_1, …, w_m]``, one weight per input, summing to 1, no cross
terms): each input's polynomial is fitted *alone* (least squares, its own
constant) and the model is their weighted sum,

.. math:: \\hat y_a = \\sum_i w_i \\Big(b_{a,i} + \\sum_{k=1}^{n} c_{a,i,k}\\, z_i^k\\Big)

— the same terms as the additive polynomial, so it evaluates, exports and
guards as one.  ``mix=[2/3, 1/3]`` on [ΔT, ``delayed_<τ>``] is a third of the
way from the cubic in ΔT to the cubic at the delayed temperature: the step a
model with memory may take where the training data ramp at one rate
(configs/README.md, "A step toward memory at one rate"; not in the default
set: there it did not beat the cubic out of fold).
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Sequence
from itertools import combinations_with_replacement
from typing import Any

import numpy as np
import torch
from torch import nn

from . import specs
from .base import Family, as_numpy, distinct_levels, least_squares, output_layer
from .cgen import CBody, as_float32, c_affine, c_array
from .hyper import HyperError

__all__ = ["Poly", "monomials"]


def monomials(n_inputs: int, degree: int, cross: bool) -> list[tuple[int, ...]]:
    """Exponent tuples (one entry per input) of the polynomial's terms, constant excluded."""
    if not cross:
        return [tuple(k if i == j else 0 for i in range(n_inputs))
                for j in range(n_inputs) for k in range(1, degree + 1)]
    terms = []
    for d in range(1, degree + 1):
        for combo in combinations_with_replacement(range(n_inputs), d):
            terms.append(tuple(combo.count(i) for i in range(n_inputs)))
    return terms


class Poly(Family):
    """Polynomial of degree ``degree`` in each input (cross terms with ``cross=True``)."""

    spec = specs.Poly      # name, inputs, hyper-parameters: their defaults and rules
    degree: int
    cross: bool
    mix: list[float] | None

    def __init__(self, *, n_inputs: int, n_outputs: int, **hyper: Any) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        self.take_hyper(hyper)
        if self.mix is not None and (self.cross or len(self.mix) != n_inputs):
            raise HyperError("poly", "mix", f"one weight per input ({n_inputs}) with cross "
                             "false", self.mix)
        self.terms = monomials(n_inputs, self.degree, self.cross)
        self.weight = nn.Parameter(torch.zeros(n_outputs, len(self.terms)))
        self.bias = nn.Parameter(torch.zeros(n_outputs))

    def design(self, z: torch.Tensor) -> torch.Tensor:
        """Term matrix (N, n_terms), built by repeated multiplication (exports as Mul)."""
        return torch.stack(self.term_columns(list(z.unbind(1))), dim=1)

    def term_columns(self, cols: Sequence[Any], mul: Callable[[Any, Any], Any] = operator.mul
                     ) -> list[Any]:
        """The terms as 1-D columns: powers by repeated multiplication, each power once.
        ``mul`` multiplies two columns: ``*`` on tensors here; the hand-built ONNX graph
        (:mod:`thermonet.exporting.onnx_graph`) passes one that writes a ``Mul`` node, so its
        terms are built by this very code."""
        powers = []
        for c in cols:
            p = [c]
            for _ in range(1, self.degree):
                p.append(mul(p[-1], c))
            powers.append(p)
        out = []
        for exps in self.terms:
            term: Any = None
            for i, e in enumerate(exps):
                if e:
                    term = powers[i][e - 1] if term is None else mul(term, powers[i][e - 1])
            if term is not None:  # every term has a positive exponent
                out.append(term)
        return out

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.design(z) @ self.weight.T + self.bias

    def drift(self, z: Sequence[torch.Tensor], y_std: torch.Tensor,
              y_mean: torch.Tensor) -> torch.Tensor:
        w, b = output_layer(self.weight, self.bias, y_std, y_mean)
        return torch.addmm(b[:, None], w, torch.stack(self.term_columns(z)))

    def emit_c(self, prefix: str, y_std: torch.Tensor, y_mean: torch.Tensor) -> CBody:
        p, P = prefix, prefix.upper()
        with torch.no_grad():
            w, b = output_layer(self.weight, self.bias, y_std, y_mean)
        consts = [f"#define {P}_POLY_TERMS {len(self.terms)}",
                  c_array(f"{p}_poly_w", as_float32(w)), c_array(f"{p}_poly_b", as_float32(b))]
        # straight-line powers and terms (the exponents are known now): no table, no branch
        lines = [f"        float term[{P}_POLY_TERMS];"]
        for i in range(self.n_inputs):
            need = max(e[i] for e in self.terms)
            if need:
                lines.append(f"        float p{i}_1 = z[{i}];")
            for k in range(2, need + 1):
                lines.append(f"        float p{i}_{k} = p{i}_{k - 1} * z[{i}];")
        for t, exps in enumerate(self.terms):
            factors = [f"p{i}_{e}" for i, e in enumerate(exps) if e]
            lines.append(f"        term[{t}] = {' * '.join(factors)};")
        lines.append(c_affine("y", f"{p}_poly_w", f"{p}_poly_b", int(w.shape[0]),
                              [(t, f"term[{t}]") for t in range(len(self.terms))], " " * 8))
        body = "    {\n" + "\n".join(lines) + "\n    }"
        return CBody(consts, body)

    def op_count(self) -> tuple[int, int]:
        """The powers (``need − 1`` multiplies per input), the cross terms (one multiply per
        extra factor) and one multiply-add per coefficient: a cubic in one input on A axes
        is :math:`2 + 3A`."""
        powers = sum(max(max(e[i] for e in self.terms) - 1, 0) for i in range(self.n_inputs))
        products = sum(sum(1 for e in exps if e) - 1 for exps in self.terms)
        return powers + products + self.n_outputs * len(self.terms), 0

    def check_fittable(self, x: torch.Tensor) -> str | None:
        xn = as_numpy(x)
        n_coef = len(self.terms) + 1
        if xn.shape[0] < n_coef:
            return f"{xn.shape[0]} samples for {n_coef} coefficients per axis"
        for j in range(xn.shape[1]):
            levels = distinct_levels(xn[:, j], cap=self.degree + 1)
            if levels < self.degree + 1:
                return (f"input {j + 1} takes {levels} distinct value(s); a degree-"
                        f"{self.degree} polynomial needs at least {self.degree + 1}")
        return None

    def initialize(self, x: torch.Tensor, y: torch.Tensor, *, seed: int = 0,
                   x_mean: np.ndarray | None = None, x_std: np.ndarray | None = None) -> None:
        with torch.no_grad():
            d = as_numpy(self.design(torch.as_tensor(as_numpy(x))))
        one = np.ones((d.shape[0], 1))
        if self.mix is None:
            coef = least_squares(np.hstack([d, one]), as_numpy(y))
        else:       # each input's polynomial alone (its own constant), then weighted
            n = self.degree
            coef = np.zeros((d.shape[1] + 1, as_numpy(y).shape[1]))
            for i, w in enumerate(self.mix):
                alone = least_squares(np.hstack([d[:, i * n:(i + 1) * n], one]), as_numpy(y))
                coef[i * n:(i + 1) * n] = w * alone[:-1]
                coef[-1] += w * alone[-1]
        with torch.no_grad():
            self.weight.copy_(torch.as_tensor(coef[:-1].T))
            self.bias.copy_(torch.as_tensor(coef[-1]))

    def trainable(self) -> bool:
        """False: the least-squares fit is final, as :meth:`.Linear.trainable` says."""
        return False

    def coefficient_degree(self, inputs: Sequence[str]) -> int:
        """Its own degree on ``T`` or ``dT`` alone (exact); a cubic summary otherwise."""
        return self.degree if list(inputs) in (["dT"], ["T"]) else 3

    def polynomial_form(self) -> np.ndarray | None:
        """:math:`[b_a, c_{a,1} \\dots c_{a,n}]` per axis when there is one input."""
        if self.n_inputs != 1:
            return None
        return np.column_stack([as_numpy(self.bias),
                                as_numpy(self.weight)])
