"""A small gated recurrent unit: thermal history learnt from the signals alone.

One GRU layer of ``hidden`` units (default 8; 4–16 is the range meant for a
microcontroller: 8 units, one input and one axis are 273 constants, 1,092 bytes and 344
operations per sample, 24 of them ``expf``/``expm1f`` calls; :meth:`Family.cost`) and a
linear read-out, in standardised units (PyTorch's gate layout, ``r``, ``u``, ``n``):

.. math::

    r &= \\sigma(W_{ir} z + b_{ir} + W_{hr} h + b_{hr}), \\qquad
    u = \\sigma(W_{iu} z + b_{iu} + W_{hu} h + b_{hu}), \\\\
    n &= \\tanh(W_{in} z + b_{in} + r \\odot (W_{hn} h + b_{hn})), \\qquad
    h' = n + u \\odot (h - n), \\qquad \\hat y = W_o h' + b_o .

**Time.**  The state advances once per ``step_s`` seconds (default 10 s: thermal time
constants are minutes), whatever the sample rate, so the model means the same on a
10 Hz board as on the 1 s windows it was trained on.  Samples are grouped into windows
``k = floor((t - t_0) / step_s)`` counted from the stream's (re)start ``t_0``; within a
window every sample's drift is the read-out of ``cell(h, z(m))``, ``h`` the state
committed at the end of the previous window and ``m`` the running mean of the window's
signals so far; when a sample opens a later window, the previous window's last ``h'``
(the cell on its full mean) is committed.  Training sees exactly the windows' end
points: the training runs are averaged into ``step_s`` windows (the signals are averaged,
as :func:`~thermonet.training.train.average_windows` does for every family) and the
loss is that of the read-out after each window.  :mod:`thermonet.models.sequence` is
the reference implementation of this stream; the runtime (``export/thermonet_runtime.py``)
and the C header's ``<prefix>_step`` repeat it.

**Start-up, gaps, missing samples** (as a board carries its state): the stream starts
with :math:`h = 0`; a sample more than ``gap_s`` (default 60 s) after the last finite
one restarts it (:math:`h = 0`, new window, out-of-range flag set on that sample); a
sample with a non-finite signal gives NaN drift and leaves the state untouched.
**Warm-up**: from :math:`h = 0` the state needs a few time constants of its own to
reflect the device's history; the first ``warmup`` windows (default 30, 5 min) of every
training segment are left out of the training and validation losses, while the
held-out scores keep every sample (the warm-up error counts against the GRU).

**Training** (:func:`thermonet.training.train.fit` runs :func:`fit_recurrent`): each
contiguous segment (no step over ``gap_s``) of every training run is one sequence of
``step_s`` windows; truncated back-propagation through time over chunks of ``chunk``
windows (default 64), the state carried from chunk to chunk (detached), one Adam step
(learning rate ``lr``, default 3e-3; the gradient clipped to norm 1, the usual
guard against gradients exploding through time; halved when the monitored loss stalls)
per chunk, epochs and early stopping from the
``train`` section (its ``optimizer`` and ``lr`` are for the full-batch families and not
used here).  ``weight_decay`` :math:`\\lambda` adds :math:`\\lambda \\sum W^2` over the
weight matrices (:meth:`penalty`).  Start: weights uniform in
:math:`\\pm 1/\\sqrt{H}` (PyTorch's default) from a generator seeded with the training
seed, the read-out the least-squares fit to the start's states (ridge
:data:`READOUT_RIDGE`: random states are nearly collinear, and an unregularised read-out's
large weights make the first gradient steps diverge); the fit is
reproducible for a seed on one machine.

Stateless evaluation (:meth:`drift`, what :meth:`DriftModel.forward
<thermonet.models.drift_model.DriftModel.forward>` computes on signals without time) is the
**steady state** after a long soak at those signals: the cell iterated
:data:`SETTLE_STEPS` times from :math:`h = 0`; it places ``at-t-ref`` targets' zero and
draws the family's drift curve.  The exports evaluate :meth:`drift_step` (state in,
state out).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from . import specs
from .base import Family, as_numpy, distinct_levels, least_squares, output_layer
from .cgen import C_COPYSIGNF, CBody, as_float32, c_affine, c_array, c_exp, c_expm1

__all__ = ["GRU", "SETTLE_STEPS", "CELL_OPS"]

#: Relative ridge of the start's least-squares read-out: random states are nearly collinear,
#: and an unregularised read-out's large weights make the first gradient steps diverge.
READOUT_RIDGE = 1e-2
#: Cell iterations of the stateless (steady-state) evaluation.
SETTLE_STEPS = 200
#: (operations, transcendentals) per hidden unit besides the two matrix products: r and u
#: (an add, then the sigmoid: expf, 1 + e, the division), n (r·gh + gi, then tanh as the
#: MLP's: −2|x|, expm1, e + 2, the division), h' = n + u (h − n) (two)
CELL_OPS = (4 + 4 + 1 + 4 + 2, 3)


class GRU(Family):
    """One GRU layer of ``hidden`` units and a linear read-out, state carried in time."""

    spec = specs.GRU       # name, inputs, hyper-parameters: their defaults and rules
    hidden: int
    step_s: float
    gap_s: float
    chunk: int
    warmup: int
    lr: float
    weight_decay: float
    #: The family carries a state between samples (the exports stream it).
    recurrent: ClassVar[bool] = True

    def __init__(self, *, n_inputs: int, n_outputs: int, **hyper: Any) -> None:
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        self.take_hyper(hyper)
        self.rnn = nn.GRU(self.n_inputs, self.hidden, batch_first=True)
        self.weight = nn.Parameter(torch.zeros(n_outputs, self.hidden))
        self.bias = nn.Parameter(torch.zeros(n_outputs))

    # ------------------------------------------------------------------ the function
    def _params(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        r = self.rnn
        return (r.weight_ih_l0, r.weight_hh_l0,  # type: ignore[return-value]
                r.bias_ih_l0, r.bias_hh_l0)

    def cell_t(self, z: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        """The cell, axis-major: features (F, N) and state (H, N) → next state (H, N)."""
        w_ih, w_hh, b_ih, b_hh = self._params()
        H = self.hidden
        gi = torch.addmm(b_ih[:, None], w_ih, z)
        gh = torch.addmm(b_hh[:, None], w_hh, h)
        r = torch.sigmoid(gi[:H] + gh[:H])
        u = torch.sigmoid(gi[H:2 * H] + gh[H:2 * H])
        n = torch.tanh(gi[2 * H:] + r * gh[2 * H:])
        return n + u * (h - n)

    def scan(self, z: torch.Tensor, h0: torch.Tensor | None = None
             ) -> tuple[torch.Tensor, torch.Tensor]:
        """States after every step of sequences ``z`` (B, T, F) from ``h0`` (1, B, H)
        (zeros when None): (B, T, H) and the last (1, B, H) (PyTorch's fused GRU)."""
        return self.rnn(z, h0)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        """The rows of ``z`` (N, F) as one sequence of steps from :math:`h = 0` (N, A)."""
        states, _ = self.scan(z[None])
        return torch.addmm(self.bias, states[0], self.weight.T)

    def drift_step(self, z: Sequence[torch.Tensor], h: torch.Tensor, y_std: torch.Tensor,
                   y_mean: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Drift (A, N) and next state (H, N) from feature columns (N,) and states (H, N):
        the read-out of ``cell(h, z)``, de-standardisation folded in.  A NaN in ``z[0]``
        gives NaN drift on every axis (and a NaN state, which the stream never commits)."""
        hn = self.cell_t(torch.stack(list(z)), h)
        wo, bo = output_layer(self.weight, self.bias, y_std, y_mean)
        return torch.addmm(bo[:, None] + (z[0] - z[0]), wo, hn), hn

    def settle(self, z: Sequence[torch.Tensor]) -> torch.Tensor:
        """Steady state (H, N) at constant features: the cell iterated from 0."""
        zt = torch.stack(list(z))
        h = torch.zeros(self.hidden, zt.shape[1], dtype=zt.dtype, device=zt.device)
        for _ in range(SETTLE_STEPS):
            h = self.cell_t(zt, h)
        return h

    def drift(self, z: Sequence[torch.Tensor], y_std: torch.Tensor,
              y_mean: torch.Tensor) -> torch.Tensor:
        """Steady-state drift (A, N): after a long soak at each sample's signals."""
        wo, bo = output_layer(self.weight, self.bias, y_std, y_mean)
        return torch.addmm(bo[:, None] + (z[0] - z[0]), wo, self.settle(z))

    def penalty(self) -> torch.Tensor | None:
        if self.weight_decay == 0.0:
            return None
        w_ih, w_hh, _, _ = self._params()
        total = (w_ih * w_ih).sum() + (w_hh * w_hh).sum() + (self.weight * self.weight).sum()
        return self.weight_decay * total

    # ------------------------------------------------------------------ C and cost
    def emit_c(self, prefix: str, y_std: torch.Tensor, y_mean: torch.Tensor) -> CBody:
        """Body from ``z`` and the state ``h_in`` (H floats) to ``y`` and ``h_out``: the
        header declares both for a recurrent family (``<prefix>_compensate_state``)."""
        p, H = prefix, self.hidden
        ind = " " * 8
        w_ih, w_hh, b_ih, b_hh = self._params()
        with torch.no_grad():
            wo, bo = output_layer(self.weight, self.bias, y_std, y_mean)
        consts = [f"#define {p.upper()}_GRU_HIDDEN {H}",
                  c_array(f"{p}_gru_w_ih", as_float32(w_ih)),
                  c_array(f"{p}_gru_b_ih", as_float32(b_ih)),
                  c_array(f"{p}_gru_w_hh", as_float32(w_hh)),
                  c_array(f"{p}_gru_b_hh", as_float32(b_hh)),
                  c_array(f"{p}_gru_wo", as_float32(wo)), c_array(f"{p}_gru_bo", as_float32(bo))]
        tanh = (f"{{ const float e = {c_expm1('-2.0f * fabsf(x)')}; "
                f"nn = {C_COPYSIGNF}(-e / (e + 2.0f), x); }}")
        lines = ["    {", f"{ind}int j;", f"{ind}float gi[{3 * H}], gh[{3 * H}];",
                 c_affine("gi", f"{p}_gru_w_ih", f"{p}_gru_b_ih", 3 * H,
                          [(f, f"z[{f}]") for f in range(self.n_inputs)], ind),
                 c_affine("gh", f"{p}_gru_w_hh", f"{p}_gru_b_hh", 3 * H,
                          [(k, f"h_in[{k}]") for k in range(H)], ind),
                 f"{ind}for (j = 0; j < {H}; ++j) {{",
                 f"{ind}    const float r = 1.0f / (1.0f + {c_exp('-(gi[j] + gh[j])')});",
                 f"{ind}    const float u = 1.0f / (1.0f + "
                 f"{c_exp(f'-(gi[{H} + j] + gh[{H} + j])')});",
                 f"{ind}    const float x = gi[{2 * H} + j] + r * gh[{2 * H} + j];",
                 f"{ind}    float nn;",
                 f"{ind}    {tanh}",
                 f"{ind}    h_out[j] = nn + u * (h_in[j] - nn);",
                 f"{ind}}}",
                 c_affine("y", f"{p}_gru_wo", f"{p}_gru_bo", self.n_outputs,
                          [(k, f"h_out[{k}]") for k in range(H)], ind),
                 "    }"]
        return CBody(consts, "\n".join(lines))

    def op_count(self) -> tuple[int, int]:
        """One multiply-add per weight of the two gate products and the read-out, and each
        unit's gates (:data:`CELL_OPS`)."""
        H, F, A = self.hidden, self.n_inputs, self.n_outputs
        ops, trans = CELL_OPS
        return 3 * H * (F + H) + A * H + ops * H, trans * H

    # ------------------------------------------------------------------ fitting
    def check_fittable(self, x: torch.Tensor) -> str | None:
        xn = as_numpy(x)
        if xn.shape[0] < self.hidden + 1:
            return f"{xn.shape[0]} windows for the {self.hidden + 1} read-out coefficients per axis"
        if max(distinct_levels(xn[:, j], cap=2) for j in range(xn.shape[1])) < 2:
            return "every input takes a single value: nothing to fit"
        return None

    def start(self, seed: int) -> None:
        """PyTorch's default start (uniform in ±1/√H), drawn from a seeded generator, with
        the update gate's bias set by the chrono start (Tallec & Ollivier 2018, "Can
        recurrent neural networks warp time?"): :math:`b_u = \\log U(1, T - 1)`,
        ``T = chunk``, so that the units start with memories of 2 to ``chunk`` windows —
        thermal lags are tens of windows, which a start at :math:`u \\approx 0.5` (a
        memory of one or two windows) has to climb to through flat gradients."""
        gen = torch.Generator().manual_seed(int(seed))
        k = 1.0 / math.sqrt(self.hidden)
        H = self.hidden
        with torch.no_grad():
            for prm in self.rnn.parameters():
                prm.copy_(torch.rand(prm.shape, generator=gen, dtype=torch.float64) * 2 * k - k)
            span = torch.rand(H, generator=gen, dtype=torch.float64) * (self.chunk - 2) + 1.0
            _, _, b_ih, b_hh = self._params()
            b_ih[H:2 * H] = torch.log(span)
            b_hh[H:2 * H] = 0.0

    def fit_readout(self, states: np.ndarray, y: np.ndarray) -> None:
        """Read-out as the least-squares fit of standardised targets (M, A) to states (M, H)."""
        design = np.hstack([states, np.ones((states.shape[0], 1))])
        coef = least_squares(design, y, ridge=READOUT_RIDGE)
        with torch.no_grad():
            self.weight.copy_(torch.as_tensor(coef[:-1].T))
            self.bias.copy_(torch.as_tensor(coef[-1]))

    def initialize(self, x: torch.Tensor, y: torch.Tensor, *, seed: int = 0,
                   x_mean: np.ndarray | None = None, x_std: np.ndarray | None = None) -> None:
        """The rows as one sequence (the training loop starts the GRU on its segments)."""
        self.start(seed)
        with torch.no_grad():
            states, _ = self.scan(torch.as_tensor(as_numpy(x), dtype=torch.float32)[None])
        self.fit_readout(as_numpy(states[0]), as_numpy(y))

