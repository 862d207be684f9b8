"""Linear drift model (study 000's baseline).

.. math:: \\hat y = W z + b

on standardised features :math:`z`; per axis, study 000's
:math:`B(T) = k\\,T + b`.  Fitted in closed form (least squares), and that fit is final:
the training loop records epoch 0 only (:meth:`Linear.trainable`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from . import specs
from .base import Family, as_numpy, distinct_levels, least_squares, output_layer
from .cgen import CBody, as_float32, c_affine, c_array

__all__ = ["Linear"]


class Linear(Family):
    """:math:`\\hat y = W z + b`, ``W`` of shape (A, F)."""

    spec = specs.Linear    # name, inputs (no hyper-parameters)

    def __init__(self, *, n_inputs: int, n_outputs: int, **hyper: Any) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        self.take_hyper(hyper)
        self.weight = nn.Parameter(torch.zeros(n_outputs, n_inputs))
        self.bias = nn.Parameter(torch.zeros(n_outputs))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return z @ self.weight.T + self.bias

    def coefficient_degree(self, inputs: Sequence[str]) -> int:
        """A straight line on ``T`` or ``dT`` alone (exact); a cubic summary otherwise."""
        return 1 if list(inputs) in (["dT"], ["T"]) else 3

    def drift(self, z: Sequence[torch.Tensor], y_std: torch.Tensor,
              y_mean: torch.Tensor) -> torch.Tensor:
        w, b = output_layer(self.weight, self.bias, y_std, y_mean)
        return torch.addmm(b[:, None], w, torch.stack(list(z)))

    def emit_c(self, prefix: str, y_std: torch.Tensor, y_mean: torch.Tensor) -> CBody:
        p = prefix
        with torch.no_grad():
            w, b = output_layer(self.weight, self.bias, y_std, y_mean)
        consts = [c_array(f"{p}_lin_w", as_float32(w)), c_array(f"{p}_lin_b", as_float32(b))]
        body = c_affine("y", f"{p}_lin_w", f"{p}_lin_b", int(w.shape[0]),
                        [(f, f"z[{f}]") for f in range(int(w.shape[1]))])
        return CBody(consts, body)

    def op_count(self) -> tuple[int, int]:
        """One multiply-add per weight: :math:`A F`."""
        return self.n_outputs * self.n_inputs, 0

    def check_fittable(self, x: torch.Tensor) -> str | None:
        xn = as_numpy(x)
        if xn.shape[0] < self.n_inputs + 1:
            return f"{xn.shape[0]} samples for {self.n_inputs + 1} coefficients per axis"
        for j in range(xn.shape[1]):
            if distinct_levels(xn[:, j], cap=2) < 2:
                return f"input {j + 1} takes a single value: no slope to fit"
        return None

    def initialize(self, x: torch.Tensor, y: torch.Tensor, *, seed: int = 0,
                   x_mean: np.ndarray | None = None, x_std: np.ndarray | None = None) -> None:
        xn, yn = as_numpy(x), as_numpy(y)
        design = np.hstack([xn, np.ones((xn.shape[0], 1))])
        coef = least_squares(design, yn)  # (F + 1, A)
        with torch.no_grad():
            self.weight.copy_(torch.as_tensor(coef[:-1].T))
            self.bias.copy_(torch.as_tensor(coef[-1]))

    def trainable(self) -> bool:
        """False: the least-squares start is the exact minimum of the training loss, so the
        gradient refinement has nothing to add (it never kept an epoch past 0 on the default,
        BMI270 and ``calibrate`` comparisons: the loop restored epoch 0's parameters, bit for
        bit) — it only cost up to ``patience`` L-BFGS epochs per fit, and the first one
        imported ``torch._dynamo`` (about a second)."""
        return False

    def polynomial_form(self) -> np.ndarray | None:
        """A line is a degree-1 polynomial: :math:`[b_a, w_a]` when there is one input."""
        if self.n_inputs != 1:
            return None
        return np.column_stack([as_numpy(self.bias),
                                as_numpy(self.weight)])
