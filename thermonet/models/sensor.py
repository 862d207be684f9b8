"""The full thermal sensor model: bias, scale factor and misalignment versus temperature.

Per output triad (the ``x``, ``y``, ``z`` axes of one kind: gyro, acc; a kind with one axis
is a 1 × 1 "triad") the sensor reads

.. math:: r = M(s)\\, x + b(s), \\qquad M(s) = I + E(s)

with :math:`x` the true input (turntable rate, gravity), :math:`b(s)` the bias vector and
:math:`E(s)` the scale-factor errors (diagonal) and misalignments / cross-axis
sensitivities (off the diagonal, radians for small angles), every element a function of the
same signals :math:`s` (temperature, proxies, dynamic inputs) as a bias model.  The
compensation inverts it:

.. math:: \\hat x = M(s)^{-1} (r - b(s))

**One mechanism.**  :math:`b` and :math:`E` are two ordinary
:class:`~thermonet.models.drift_model.DriftModel` s built from any registered family: ``bias``
with one output per sensor axis (output units), ``elements`` with one output per element of
:math:`E` (dimensionless, named ``<kind>.m_<row><col>``).  So the Lorentz curve or the RBF
serves for a scale factor as for a bias, with the same clamp to the trained range, the same
standardisation, and the same per-output mask (``compensate``): an element the model does
not use (do no harm) is masked to exactly 0, i.e. left at identity (diagonal) or zero
(off-diagonal and bias).

**The inverse** is the adjugate over the determinant (:func:`solve_columns`), written with
element-wise operations only, so the same function runs in torch, exports to ONNX as
Mul/Sub/Div, and is one line of C per element.  It is evaluated in float64 (the raw outputs
may be large, the elements are ~1e-3).  A model whose :math:`M` is singular or nearly so
(condition number over :data:`MAX_CONDITION`) anywhere on its training signals is refused
(:func:`check_invertible`): its inverse would amplify noise without bound.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from ..core.errors import FitError, InputError
from ..core.recording import output_kind
from .drift_model import DriftModel

__all__ = ["MAX_CONDITION", "SensorModel", "triads_of", "element_names", "solve_columns",
           "check_invertible"]

#: Largest condition number of M(s) a sensor model may have.  An IMU's M is within a few
#: percent of a rotation-free identity (cond ≈ 1.0x, also for raw counts with one scale per
#: axis); 1e3 leaves room for uneven axis scales and refuses a fit that lost an axis.
MAX_CONDITION = 1e3

_AXES = ("x", "y", "z")


def triads_of(outputs: Sequence[str], *, source: str = "data") -> list[list[str]]:
    """The outputs grouped per kind, each group in ``x, y, z`` order.

    A kind with one axis is a group of one (a single-axis accelerometer's scale factor);
    a kind with two axes, or axes not named ``x``/``y``/``z``, is refused: its misalignment
    is not defined.
    """
    groups: dict[str, list[str]] = {}
    for name in outputs:
        groups.setdefault(output_kind(name), []).append(name)
    out = []
    for kind, names in groups.items():
        axes = [n.split("_", 1)[1] for n in names]
        if len(names) == 1:
            out.append(names)
            continue
        if sorted(axes) != list(_AXES):
            raise InputError(f"{source}: model 'sensor' needs the outputs of kind '{kind}' as "
                             f"one axis or a triad x, y, z; got {sorted(names)}")
        out.append([f"{kind}_{a}" for a in _AXES])
    return out


def element_names(triad: Sequence[str]) -> list[str]:
    """Names of the elements of E for one triad, row-major: ``gyro.m_xx``, ``gyro.m_xy`` …"""
    kind = output_kind(triad[0])
    axes = [n.split("_", 1)[1] for n in triad]
    return [f"{kind}.m_{r}{c}" for r in axes for c in axes]


def solve_columns(m: Sequence[Sequence[torch.Tensor]], v: Sequence[torch.Tensor]
                  ) -> list[torch.Tensor]:
    """:math:`M^{-1} v` per sample, for k = 1 or 3, by the adjugate (Cramer's rule).

    ``m[r][c]`` and ``v[r]`` are (N,) columns; element-wise operations only (ONNX Mul, Sub,
    Div; C arithmetic).  A singular M gives ±inf/NaN: callers check invertibility first.
    """
    k = len(v)
    if k == 1:
        return [v[0] / m[0][0]]
    if k != 3:
        raise ValueError(f"solve_columns: k = {k} (1 or 3)")
    # cofactors C[r][c]; inverse = C^T / det
    def cof(r: int, c: int) -> torch.Tensor:
        r1, r2 = [i for i in range(3) if i != r]
        c1, c2 = [j for j in range(3) if j != c]
        sign = 1.0 if (r + c) % 2 == 0 else -1.0
        return sign * (m[r1][c1] * m[r2][c2] - m[r1][c2] * m[r2][c1])

    cofs = [[cof(r, c) for c in range(3)] for r in range(3)]
    det = m[0][0] * cofs[0][0] + m[0][1] * cofs[0][1] + m[0][2] * cofs[0][2]
    inv_det = 1.0 / det
    return [(cofs[0][i] * v[0] + cofs[1][i] * v[1] + cofs[2][i] * v[2]) * inv_det
            for i in range(3)]


class SensorModel(nn.Module):
    """Signals and raw outputs → compensated outputs :math:`M(s)^{-1}(r - b(s))`.

    Parameters
    ----------
    bias : DriftModel
        :math:`b(s)`, one output per sensor axis (outputs in ``triads`` order).
    elements : DriftModel
        :math:`E(s) = M(s) - I`, one output per element (:func:`element_names` of each
        triad, concatenated), same feature spec as ``bias``.
    triads : list of list of str
        The sensor axes grouped per kind (:func:`triads_of`).
    """

    def __init__(self, *, bias: DriftModel, elements: DriftModel,
                 triads: Sequence[Sequence[str]]) -> None:
        super().__init__()
        self.triads = [list(t) for t in triads]
        self.outputs = [o for t in self.triads for o in t]
        self.element_outputs = [e for t in self.triads for e in element_names(t)]
        if list(bias.outputs) != self.outputs:
            raise InputError(f"sensor model: bias outputs {bias.outputs} differ from the "
                             f"triads' axes {self.outputs}")
        if list(elements.outputs) != self.element_outputs:
            raise InputError(f"sensor model: element outputs {elements.outputs} differ from "
                             f"{self.element_outputs}")
        if bias.signals != elements.signals:
            raise InputError("sensor model: bias and elements read different signals "
                             f"({bias.signals} vs {elements.signals})")
        self.bias = bias
        self.elements = elements
        self.signals = list(bias.signals)

    #: Its key in :data:`thermonet.models.shipped.MODEL_KINDS`.
    kind = "sensor"

    @property
    def family_name(self) -> str:
        return self.bias.family_name

    @property
    def inputs(self) -> list[str]:
        """The family's inputs (``dT``, ...), its bias's and elements' alike."""
        return list(self.bias.inputs)

    @property
    def n_params(self) -> int:
        return self.bias.n_params + self.elements.n_params

    def matrices(self, signals: torch.Tensor) -> list[np.ndarray]:
        """Per triad, M(s) as a float64 array (N, k, k) (masked elements at identity)."""
        with torch.no_grad():
            e = self.elements.drift64(torch.as_tensor(signals, dtype=torch.float32)).numpy()
        out, j = [], 0
        for t in self.triads:
            k = len(t)
            m = e[:, j:j + k * k].reshape(-1, k, k) + np.eye(k)
            out.append(m)
            j += k * k
        return out

    def columns(self, signal_cols: Sequence[torch.Tensor], raw: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """Compensated (N, O) float64 and out-of-range flag (N,) from one (N,) column per
        signal and the raw outputs (N, O): what the ONNX graph evaluates."""
        rel_b, flag = self.bias.evaluate(signal_cols)
        rel_e, _ = self.elements.evaluate(signal_cols)
        b = rel_b.to(torch.float64) + self.bias.constant()[:, None]      # (O, N)
        e = rel_e.to(torch.float64) + self.elements.constant()[:, None]  # (E, N)
        raw = raw.to(torch.float64)
        comp: list[torch.Tensor] = []
        i = j = 0
        for t in self.triads:
            k = len(t)
            m = [[e[j + r * k + c] + (1.0 if r == c else 0.0) for c in range(k)]
                 for r in range(k)]
            v = [raw[:, i + r] - b[i + r] for r in range(k)]
            comp.extend(solve_columns(m, v))
            i += k
            j += k * k
        return torch.stack(comp, dim=1), flag

    def forward(self, signals: torch.Tensor, raw: torch.Tensor) -> torch.Tensor:
        """Compensated outputs (N, O), float64, from signals (N, S) and raw (N, O)."""
        return self.columns(signals.to(torch.float32).unbind(1), raw)[0]

    def compensate(self, signals: np.ndarray, raw: np.ndarray) -> np.ndarray:
        """NumPy in, NumPy out (float64), under ``no_grad``."""
        self.eval()
        with torch.no_grad():
            return self(torch.as_tensor(np.asarray(signals, dtype=np.float64)),
                        torch.as_tensor(np.asarray(raw, dtype=np.float64))).numpy()


    def compensated(self, signals: np.ndarray, raw: np.ndarray) -> np.ndarray:
        """:meth:`compensate`: the :class:`~thermonet.models.shipped.ShippedModel` operation."""
        return self.compensate(signals, raw)

    def out_of_range(self, signals: torch.Tensor | np.ndarray) -> torch.Tensor:
        """Bool (N,): the bias model's flag, the one the ONNX graph and C header return (bias
        and elements share the spec and the trained range)."""
        return self.bias.out_of_range(signals)


def check_invertible(model: SensorModel, signals: np.ndarray, *, what: str = "sensor model"
                     ) -> float:
    """Refuse a model whose M(s) is singular or near-singular on ``signals`` (N, S).

    Returns the largest condition number found (2-norm).

    Raises
    ------
    FitError
        One line: the triad, the worst condition number (or a non-finite element) and the
        signals where it occurs.
    """
    s = np.asarray(signals, dtype=np.float64)
    for t, m in zip(model.triads, model.matrices(torch.as_tensor(s)), strict=True):
        kind = output_kind(t[0])
        bad = ~np.isfinite(m).all(axis=(1, 2))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise FitError(f"{what}: M(s) of '{kind}' has a non-finite element at signals "
                           f"{dict(zip(model.signals, s[i].round(3).tolist(), strict=True))}")
        cond = np.linalg.cond(m)
        worst = int(np.nanargmax(np.where(np.isfinite(cond), cond, np.inf)))
        c = float(cond[worst])
        if not np.isfinite(c) or c > MAX_CONDITION:
            where = dict(zip(model.signals, s[worst].round(3).tolist(), strict=True))
            raise FitError(f"{what}: M(s) of '{kind}' is singular or near-singular (condition "
                           f"number {c:.3g} > {MAX_CONDITION:g}, det "
                           f"{float(np.linalg.det(m[worst])):.3g}) at signals {where}; refusing "
                           "it (is an axis unexcited, or a reference column wrong?)")
    return float(max(np.linalg.cond(m).max() for m in model.matrices(torch.as_tensor(s))))
