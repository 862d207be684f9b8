"""Each axis its own model: several fitted drift models, one per distinct candidate, shipped as
one model.

The per-axis choice (:func:`thermonet.scoring.selection.select`) may give gyro_x to a cubic in
ΔT, gyro_y to an RBF and leave acc_z raw.  :class:`AxisModels` carries that as one model:

.. math::

    d_a(s) = \\sum_k m_{k,a}\\, d_{k,a}(s_k), \\qquad m_{k,a} = [\\text{part } k \\text{ owns
    axis } a]

Each *part* is a complete :class:`~thermonet.models.drift_model.DriftModel` fitted on every axis, whose
``compensate`` mask is set to the axes it owns (an axis no part owns is left raw).  A masked
axis of a :class:`DriftModel` is exactly 0 for every finite input (its output coefficients are
0, :mod:`thermonet.models.base`) and NaN for a NaN signal, so the sum is *exactly* the owning
part's drift on each axis (adding exact zeros rounds nothing) and a broken thermometer still
gives NaN on every axis.  Every part keeps its own clamp, features and standardisation; the
composite's signals are the union of the parts' (first-appearance order, temperature first),
and each part reads its own columns.  The out-of-range flag is the OR of the parts' flags.

What can be composed (:func:`composable`): parts with the same outputs, the same target modes
and the same references; point-wise families (a recurrent family's state cannot be shared),
and signals of the same name meaning the same thing (dynamic inputs share a name only when
their constants agree; the gap rule ``gap_s`` must agree), and trained ranges that overlap.

The composite goes wherever a :class:`DriftModel` goes (``export/README.md``, "A model per
axis"): one checkpoint (:mod:`thermonet.training.checkpoint`: the parts, the owner table
and the labels under one seal), one ONNX graph summing the parts (metadata ``axis_models``),
one C header (each part a body of its own, one ``compensate``/``step`` writing each axis from
its owner), the autopilot files only where every owned axis is a cubic on temperature.  For
the exporters it answers what a DriftModel does: :attr:`AxisModels.spec` (the union's
features and references), :attr:`~AxisModels.sig_lo`/:attr:`~AxisModels.sig_hi` (the range
where no part flags), :attr:`~AxisModels.sig_ref`, and ``family`` (name ``per-axis``, not
recurrent, no polynomial form).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from ..core.errors import ConfigError, ExportError
from ..features.inputs import FeatureSpec
from .drift_model import DriftModel
from .registry import PER_AXIS

__all__ = ["AxisModels", "composable", "axis_owner_table", "PER_AXIS", "DriftModels"]


class _PerAxisFamily:
    """What ``model.family`` answers for an :class:`AxisModels`: the attributes the exporters
    ask of any model (its name, not recurrent, no single polynomial form); a composite has no
    single family to emit C for or to refit."""

    name = PER_AXIS
    recurrent = False

    def hyper(self) -> dict[str, Any]:
        return {}

    def polynomial_form(self) -> None:
        return None

    def emit_c(self, *args: Any, **kwargs: Any) -> Any:
        raise ExportError("a per-axis model has no single family body: each part is emitted "
                          "on its own (thermonet.exporting.c_header)")


def composable(parts: Sequence[DriftModel]) -> str | None:
    """Why ``parts`` cannot be one :class:`AxisModels` (None when they can)."""
    if not parts:
        return "no part"
    first = parts[0]
    for p in parts:
        if getattr(p.family, "recurrent", False):
            return f"{p.family_name} is recurrent (its state cannot be shared with other parts)"
        if list(p.outputs) != list(first.outputs):
            return f"outputs differ: {p.outputs} vs {first.outputs}"
        if p.target_modes != first.target_modes:
            return f"target modes differ: {p.target_modes} vs {first.target_modes}"
    refs: dict[str, float] = {}
    gaps = {float(p.spec.gap_s) for p in parts if p.spec.gap_s is not None and p.spec.dynamic}
    if len(gaps) > 1:
        return f"the dynamic inputs' gap rule differs between parts: {sorted(gaps)} s"
    dyn: dict[str, Any] = {}
    ranges: dict[str, tuple[float, float]] = {}
    for p in parts:
        ref = dict(zip(p.signals, p.sig_ref.detach().double().tolist(), strict=True))
        for s, v in ref.items():
            if s in refs and not np.isclose(refs[s], v, rtol=1e-6, atol=1e-9):
                return f"signal {s} has rest value {v} in {p.family_name}, {refs[s]} elsewhere"
            refs.setdefault(s, v)
        for s, lo, hi in zip(p.signals, p.sig_lo.tolist(), p.sig_hi.tolist(), strict=True):
            a, b = ranges.get(s, (-np.inf, np.inf))
            ranges[s] = (max(a, lo), min(b, hi))
            if not ranges[s][0] <= ranges[s][1]:
                return f"the parts' trained ranges of signal {s} do not overlap"
        for d in (p.spec.dynamic or {}).get("inputs", []):
            if d["signal"] in dyn and dyn[d["signal"]] != d:
                return f"dynamic signal {d['signal']} defined twice differently"
            dyn[d["signal"]] = d
    return None


class AxisModels(nn.Module):
    """One model made of per-axis parts (module docstring).

    Parameters
    ----------
    parts : sequence of DriftModel
        The distinct candidates, each fitted on every output axis.
    owner : sequence of int or None
        Per output axis, the index of the part that compensates it, or None (left raw).
    labels : sequence of str, optional
        The candidates' labels (``poly3``, ``rbf``…), in part order: what results.json calls
        them.

    The parts' ``compensate`` masks are set from ``owner`` (each part keeps the axes it owns;
    an axis its own out-of-fold rule left raw was never given to it).
    """

    #: The parts (an ``nn.ModuleList`` at run time, typed as what it holds).
    parts: list[DriftModel]
    #: Its key in :data:`thermonet.models.shipped.MODEL_KINDS`: a drift to subtract per axis.
    kind = "bias"

    def __init__(self, parts: Sequence[DriftModel], owner: Sequence[int | None],
                 labels: Sequence[str] | None = None) -> None:
        super().__init__()
        why = composable(parts)
        if why:
            raise ConfigError(f"the per-axis models cannot be shipped as one: {why}")
        outputs = list(parts[0].outputs)
        owner = [None if o is None else int(o) for o in owner]
        if len(owner) != len(outputs):
            raise ConfigError(f"per-axis owner table has {len(owner)} entries for "
                              f"{len(outputs)} outputs {outputs}")
        bad = [o for o in owner if o is not None and not 0 <= o < len(parts)]
        if bad:
            raise ConfigError(f"per-axis owner {bad[0]} names no part (parts 0..{len(parts) - 1})")
        unused = [k for k in range(len(parts)) if k not in owner]
        if unused:
            raise ConfigError(f"part {unused[0]} ({parts[unused[0]].family_name}) owns no axis")
        self.parts = nn.ModuleList(parts)  # type: ignore[assignment]
        self.owner = owner
        self.labels = list(labels) if labels is not None else [p.family_name for p in parts]
        if len(self.labels) != len(parts):
            raise ConfigError(f"{len(self.labels)} labels for {len(parts)} parts")
        for k, p in enumerate(parts):
            p.set_compensate([o == k for o in owner])
        self.outputs = outputs
        signals: list[str] = []
        for p in parts:
            signals += [s for s in p.signals if s not in signals]
        self.signals = signals
        self.columns = [[signals.index(s) for s in p.signals] for p in parts]

    # -- what a DriftModel offers, for the whole --------------------------------------------
    @property
    def family_name(self) -> str:
        return PER_AXIS

    @property
    def compensated_axes(self) -> list[bool]:
        return [o is not None for o in self.owner]

    @property
    def target_modes(self) -> list[str]:
        return self.parts[0].target_modes

    @property
    def n_params(self) -> int:
        return int(sum(p.n_params for p in self.parts))

    @property
    def inputs(self) -> list[str]:
        out: list[str] = []
        for p in self.parts:
            out += [i for i in p.inputs if i not in out]
        return out

    @property
    def family(self) -> _PerAxisFamily:
        """Not a :class:`~thermonet.models.base.Family`: the name and the flags exporters ask
        of every model (``recurrent`` False, no polynomial form)."""
        return _PerAxisFamily()

    @property
    def spec(self) -> FeatureSpec:
        """The union of the parts' features as one :class:`FeatureSpec`: every part's inputs
        (first-appearance order), the first temperature reference, the proxies' references and
        the common gap rule.  For the metadata (``t_ref``, ``proxy_ref``, the dynamic-input
        block) and the streaming header; each part evaluates its own spec."""
        t_ref = next((p.spec.t_ref for p in self.parts if p.spec.t_ref is not None), None)
        proxy_ref: dict[str, float] = {}
        for p in self.parts:
            for k, v in p.spec.proxy_ref.items():
                proxy_ref.setdefault(k, float(v))
        gap = next((p.spec.gap_s for p in self.parts if p.spec.dynamic), None)
        return FeatureSpec(inputs=self.inputs, t_ref=t_ref, proxy_ref=proxy_ref, gap_s=gap)

    def _per_signal(self, name: str, pick: Any) -> torch.Tensor:
        """One value per composite signal from the parts' buffer ``name`` (``pick`` reduces
        the parts' values of a shared signal)."""
        out = []
        for s in self.signals:
            vals = [getattr(p, name)[p.signals.index(s)] for p in self.parts if s in p.signals]
            out.append(pick(torch.stack(vals)))
        return torch.stack(out)

    @property
    def sig_lo(self) -> torch.Tensor:
        """Per signal, the highest of the parts' trained lows: with :attr:`sig_hi` the range
        where no part flags (the composite's flag is the OR of the parts')."""
        return self._per_signal("sig_lo", lambda v: v.max())

    @property
    def sig_hi(self) -> torch.Tensor:
        """Per signal, the lowest of the parts' trained highs (see :attr:`sig_lo`)."""
        return self._per_signal("sig_hi", lambda v: v.min())

    @property
    def sig_ref(self) -> torch.Tensor:
        """Per signal, its rest value (the parts agree: :func:`composable`)."""
        return self._per_signal("sig_ref", lambda v: v[0])

    def axis_table(self) -> dict[str, str | None]:
        """Per output axis, the label of its part (None: left raw)."""
        return axis_owner_table(self.outputs, self.owner, self.labels)

    def part_signals(self, signals: torch.Tensor, k: int) -> torch.Tensor:
        """Part ``k``'s columns of the composite's signals (N, S)."""
        return signals[:, self.columns[k]]

    def evaluate(self, signals: Sequence[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Relative drift (A, N) and out-of-range flag (N,): the sum of the parts' (each
        reading its own signal columns), the OR of their flags."""
        cols = list(signals)
        total: torch.Tensor | None = None
        flag: torch.Tensor | None = None
        for k, p in enumerate(self.parts):
            d, f = p.evaluate([cols[i] for i in self.columns[k]])
            total = d if total is None else total + d
            flag = f if flag is None else flag | f
        assert total is not None and flag is not None
        return total, flag

    def relative(self, signals: torch.Tensor) -> torch.Tensor:
        return self.evaluate(signals.unbind(1))[0].T

    def constant(self) -> torch.Tensor:
        c = torch.zeros(len(self.outputs), dtype=torch.float64)
        for p in self.parts:
            c = c + p.constant()
        return c

    def drift64(self, signals: torch.Tensor) -> torch.Tensor:
        return self.relative(signals).double() + self.constant()

    def out_of_range(self, signals: torch.Tensor | np.ndarray) -> torch.Tensor:
        s = torch.as_tensor(signals, dtype=torch.float32)
        flags = [p.out_of_range(s[:, self.columns[k]]) for k, p in enumerate(self.parts)]
        out = flags[0]
        for f in flags[1:]:
            out = out | f
        return out

    def forward(self, signals: torch.Tensor) -> torch.Tensor:
        r = self.relative(signals)
        return r + self.constant().to(r.dtype)

    def compensated(self, signals: np.ndarray, raw: np.ndarray) -> np.ndarray:
        """``raw − drift`` (N, A), float64: the :class:`~thermonet.models.shipped.ShippedModel`
        operation (the parts are point-wise)."""
        was_training = self.training
        self.eval()
        try:
            with torch.no_grad():
                drift = self.drift64(torch.as_tensor(np.asarray(signals, dtype=np.float64),
                                                     dtype=torch.float32))
        finally:
            self.train(was_training)
        return np.asarray(raw, dtype=np.float64) - drift.cpu().numpy()


#: Any model thermonet fits and ships: one family, or a per-axis composite of several.
DriftModels = DriftModel | AxisModels


def axis_owner_table(outputs: Sequence[str], owner: Sequence[int | None],
                     labels: Sequence[str]) -> dict[str, str | None]:
    """``{axis: label of its part, or None}``."""
    return {a: (None if o is None else labels[o]) for a, o in zip(outputs, owner, strict=True)}
