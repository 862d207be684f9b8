"""The drift model: a family (:class:`~thermonet.models.base.Family`) wrapped into the model
that ships — physical signals in, drift out.

A :class:`~thermonet.models.base.Family` is the core of one model family.  It works in
**standardised** units: features :math:`z = (x - \\bar x)/s_x` in, standardised
drift :math:`(y - \\bar y)/s_y` out.  :class:`DriftModel` wraps it:

.. math::

    s \\xrightarrow{\\text{clamp}} [s_{lo}, s_{hi}]
      \\xrightarrow{\\text{Features}} x
      \\xrightarrow{} z = (x - \\bar x)/s_x
      \\xrightarrow{\\text{Family}} \\hat y_z
      \\xrightarrow{} \\hat y = \\hat y_z\\, s_y + \\bar y

Training runs the family on the standardised feature matrix
(:meth:`~thermonet.models.base.Family.forward`).  Evaluation — ``DriftModel.forward``, the exported
ONNX graph and the C header — runs :meth:`DriftModel.evaluate`, laid out for
speed on a batch: every signal and feature stays a 1-D column (one pass per
operation over N values, no (N, 1) broadcasts), the de-standardisation is folded
into the family's last matrix product (:meth:`~thermonet.models.base.Family.drift`), a non-finite
signal reaches the drift arithmetically (``s - s`` is 0 for a finite value and
NaN for NaN/±inf, added to the drift) instead of through a ``Where``, and the
out-of-range flag is ``clip(s) != s`` (true outside the range and for NaN).
The two paths are the same function; they differ by float32 rounding only.

What the drift is relative to (:mod:`thermonet.features.target`) lives in the model's
buffers, so checkpoints, ONNX, the C header and the autopilot files all carry
it.  Per axis :math:`a`:

.. math::

    r_a(s) &= m_a\\,\\big(\\hat y_a(s) - \\alpha_a\\, \\hat y_a(s_{ref})\\big)
        \\qquad \\text{(float32: ``relative``)} \\\\
    c_a &= m_a\\,(1 - \\alpha_a)\\, o_a \\qquad \\text{(float64: ``constant``)} \\\\
    d_a(s) &= c_a + r_a(s)

``o`` (buffer ``y_offset``, float64) is the mean training target, removed in
float64 *before* anything is rounded to float32: an output with a large
constant (1e6 counts, 4,517 Hz, 101,325 Pa) keeps its drift's precision, and
the constant is added back in float64 (:meth:`DriftModel.drift64`; the
exports carry it in float64 and compute ``raw − drift`` in float64).
``α`` is 1 for ``at-t-ref`` axes (buffer ``target_code`` = 2): the model is
normalised to zero at the rest signals :math:`s_{ref}` (buffer ``sig_ref``:
temperature at :math:`T_{ref}`, rate 0, proxies at their reference), whose
drift :math:`\\hat y(s_{ref})` is buffer ``y_ref``; the offset then cancels.
``m`` (buffer ``compensate``, 1 or 0) leaves an axis uncompensated: its
drift is exactly 0 for every finite input (a NaN signal still gives NaN).

Both the mask and the normalisation at rest cost nothing at evaluation:
:meth:`DriftModel.output_scaling` folds them into the de-standardisation,
scale :math:`m_a s_{y,a}` and shift :math:`m_a(\\bar y_a - \\alpha_a\\, \\hat y_a(s_{ref}))`,
which each family folds into its last matrix product (:meth:`~thermonet.models.base.Family.drift`).
With :math:`m_a = 0` every coefficient of that axis is 0, so a finite input
gives exactly 0 and a NaN (NaN × 0) still gives NaN.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from ..core.errors import ConfigError, InputError
from ..features.inputs import FeatureSpec, joint_columns
from ..features.module import Features
from ..features.target import MODE_CODES
from .base import Family

__all__ = ["DriftModel"]


class DriftModel(nn.Module):
    """Physical signals (N, S) → drift (N, A): Features, standardise, Family, de-standardise.

    Signals are first clamped to the range seen in training (buffers
    ``sig_lo``, ``sig_hi``): on board, a temperature outside the trained range
    is evaluated at the edge (as PX4 does), and :meth:`out_of_range` says where
    that happened so the host can flag it.

    Parameters
    ----------
    family : Family
        The core (available as ``model.family``; its name as ``model.family_name``).
    spec : FeatureSpec
        Inputs and references.
    outputs : list of str
        Output axis names (``gyro_x`` …), in column order of the drift.

    Attributes
    ----------
    inputs, signals, outputs : list of str
    spec : FeatureSpec
    """

    # buffers (registered in __init__), declared for the type checker
    x_mean: torch.Tensor
    x_std: torch.Tensor
    y_mean: torch.Tensor
    y_std: torch.Tensor
    sig_lo: torch.Tensor
    sig_hi: torch.Tensor
    y_offset: torch.Tensor
    y_ref: torch.Tensor
    sig_ref: torch.Tensor
    target_code: torch.Tensor
    compensate: torch.Tensor
    guard_knots: torch.Tensor
    guard_lo: torch.Tensor
    guard_hi: torch.Tensor
    family: Family
    #: Its key in :data:`thermonet.models.shipped.MODEL_KINDS` (a shipped model's kind).
    kind = "bias"

    def __init__(self, *, family: Family, spec: FeatureSpec, outputs: list[str]) -> None:
        super().__init__()
        if family.n_inputs != len(spec.inputs):
            raise ConfigError(f"family '{family.name}' built for {family.n_inputs} inputs, "
                              f"spec has {len(spec.inputs)}: {spec.inputs}")
        if family.n_outputs != len(outputs):
            raise ConfigError(f"family '{family.name}' built for {family.n_outputs} outputs, "
                              f"got {len(outputs)}: {list(outputs)}")
        self.spec = spec
        self.inputs = list(spec.inputs)
        self.signals = spec.signals
        self.outputs = list(outputs)
        self.features = Features(spec)
        self.family = family
        f, a, s = len(self.inputs), len(self.outputs), len(self.signals)
        self.register_buffer("x_mean", torch.zeros(f))
        self.register_buffer("x_std", torch.ones(f))
        self.register_buffer("y_mean", torch.zeros(a))
        self.register_buffer("y_std", torch.ones(a))
        self.register_buffer("sig_lo", torch.full((s,), -torch.inf))
        self.register_buffer("sig_hi", torch.full((s,), torch.inf))
        # target (see the module docstring): defaults reproduce a plain drift model
        self.register_buffer("y_offset", torch.zeros(a, dtype=torch.float64))
        self.register_buffer("y_ref", torch.zeros(a))
        self.register_buffer("sig_ref", torch.zeros(s))
        self.register_buffer("target_code", torch.zeros(a, dtype=torch.int64))
        self.register_buffer("compensate", torch.ones(a))
        # the joint guard (set_guard): none until a fit with dynamic inputs sets it
        self.t_col, self.joint = joint_columns(self.signals)
        self.register_buffer("guard_knots", torch.zeros(2))
        self.register_buffer("guard_lo", torch.zeros(0, len(self.joint)))
        self.register_buffer("guard_hi", torch.zeros(0, len(self.joint)))

    #: Buffers added with targets and the guard; a checkpoint written before them loads with
    #: their defaults (no guard).
    _TARGET_BUFFERS = ("y_offset", "y_ref", "sig_ref", "target_code", "compensate",
                       "guard_knots", "guard_lo", "guard_hi")

    def _load_from_state_dict(self, state_dict: dict, prefix: str, *args: Any,
                              **kwargs: Any) -> None:
        for name in self._TARGET_BUFFERS:
            state_dict.setdefault(prefix + name, getattr(self, name).detach().clone())
        for name in ("guard_lo", "guard_hi"):   # the tables' bin count is the checkpoint's
            saved = state_dict[prefix + name]
            if isinstance(saved, torch.Tensor) and saved.dim() == 2 and \
                    saved.shape[1] == len(self.joint):
                self._buffers[name] = torch.zeros_like(saved, dtype=self.guard_knots.dtype)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    @property
    def guarded(self) -> bool:
        """True when the model holds its dynamic inputs inside the joint envelope it was
        trained on (:meth:`set_guard`)."""
        return self.guard_lo.shape[0] >= 2 and len(self.joint) > 0

    def set_guard(self, tables: Mapping[str, np.ndarray] | None) -> None:
        """Store the joint envelope of the dynamic inputs (``knots``, per-bin ``lo``/``hi``
        (B, J) of :meth:`thermonet.scoring.selection.Envelope.tables`; None: no guard).

        On evaluation each dynamic input is held inside the bounds trained near the
        (clamped) temperature, interpolated linearly between the bins' centres, and the
        out-of-range flag is raised where that moved it: a cooling rate never trained at
        that temperature is evaluated at the nearest trained one, never extrapolated.  The
        ONNX graph and the C header compute the same (parity-checked on export)."""
        dtype = self.guard_knots.dtype
        if tables is None:
            lo = hi = torch.zeros(0, len(self.joint), dtype=dtype)
            knots = torch.zeros(2, dtype=dtype)
        else:
            lo = torch.as_tensor(np.asarray(tables["lo"], dtype=np.float64), dtype=dtype)
            hi = torch.as_tensor(np.asarray(tables["hi"], dtype=np.float64), dtype=dtype)
            knots = torch.as_tensor(np.asarray(tables["knots"], dtype=np.float64), dtype=dtype)
            if lo.dim() != 2 or lo.shape != hi.shape or lo.shape[1] != len(self.joint) or \
                    lo.shape[0] < 2 or knots.shape != (2,) or \
                    not (torch.isfinite(lo).all() and torch.isfinite(hi).all()
                         and torch.isfinite(knots).all()) or bool((lo > hi).any()):
                raise ConfigError(f"guard tables {tuple(lo.shape)} do not fit the dynamic "
                                  f"inputs {[self.signals[j] for j in self.joint]}")
        self._buffers["guard_knots"], self._buffers["guard_lo"] = knots, lo
        self._buffers["guard_hi"] = hi

    @property
    def target_modes(self) -> list[str]:
        """Target mode per output axis (``channel``, ``zero``, ``at-t-ref``, ``four-position``)."""
        names = {v: k for k, v in MODE_CODES.items()}
        return [names.get(int(c), "channel") for c in self.target_code.tolist()]

    @property
    def compensated_axes(self) -> list[bool]:
        """Per output axis: False where the model leaves the axis uncompensated (drift 0)."""
        return [bool(v) for v in (self.compensate.detach().cpu() != 0).tolist()]

    def set_compensate(self, mask: Any) -> None:
        """Per-axis mask: False leaves that axis uncompensated (drift 0 in every export)."""
        m = np.asarray(mask, dtype=bool).reshape(-1)
        if m.size != len(self.outputs):
            raise ConfigError(f"compensate mask has {m.size} entries for {len(self.outputs)} "
                              f"outputs {self.outputs}")
        self.compensate.copy_(torch.as_tensor(m.astype(np.float64), dtype=self.compensate.dtype))

    def set_target(self, *, modes: Any, offset: np.ndarray, rest: np.ndarray) -> None:
        """Store the target modes, the float64 offset and the normalisation at rest.

        Parameters
        ----------
        modes : sequence of str
            Per axis, a key of :data:`thermonet.features.target.MODE_CODES`.
        offset : (A,) float64
            The constant removed from the training target before standardisation.
        rest : (S,) float64
            Signals at rest (T_ref, rate 0, proxy references): ``at-t-ref`` axes
            are normalised to zero there (evaluated in float64, through the clamp).
        """
        modes = list(modes)
        if len(modes) != len(self.outputs):
            raise ConfigError(f"{len(modes)} target modes for {len(self.outputs)} outputs")
        bad = [m for m in modes if m not in MODE_CODES]
        if bad:
            raise ConfigError(f"unknown target mode {bad[0]!r} (valid: {', '.join(MODE_CODES)})")
        rest = np.asarray(rest, dtype=np.float64).reshape(-1)
        if rest.size != len(self.signals) or not np.all(np.isfinite(rest)):
            raise ConfigError(f"rest signals {rest.tolist()} do not fit signals {self.signals}")
        with torch.no_grad():
            self.y_offset.copy_(torch.as_tensor(np.asarray(offset, dtype=np.float64)))
            self.sig_ref.copy_(torch.as_tensor(rest, dtype=self.sig_ref.dtype))
            with _float64_copy(self):      # the model as float64, plain: no mode, no mask
                self.target_code.zero_()
                self.compensate.fill_(1.0)
                at_rest = self.relative(torch.as_tensor(rest[None, :]))[0]
            self.y_ref.copy_(at_rest.to(self.y_ref.dtype))
            self.target_code.copy_(torch.as_tensor([MODE_CODES[m] for m in modes]))

    def _at_t_ref(self, dtype: torch.dtype) -> torch.Tensor:
        return (self.target_code == MODE_CODES["at-t-ref"]).to(dtype)

    def constant(self) -> torch.Tensor:
        """Per-axis float64 constant of the drift: the offset on ``channel``/``zero`` axes
        (0 on ``at-t-ref`` axes, where it cancels, and on uncompensated axes)."""
        a = self._at_t_ref(torch.float64)
        return self.y_offset.double() * (1.0 - a) * self.compensate.double()

    def output_scaling(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Scale and shift (A,) that map the family's standardised output to :meth:`relative`.

        .. math:: r_a = \\hat y_{z,a}\\, m_a s_{y,a} + m_a(\\bar y_a - \\alpha_a\\, y_{ref,a})

        The target normalisation and the mask folded into the de-standardisation:
        :meth:`Family.drift` and :meth:`Family.emit_c` take these in place of
        ``y_std``/``y_mean``, so neither costs an operation at evaluation.
        """
        m = self.compensate.to(self.y_std.dtype)
        shift = self.y_mean - self._at_t_ref(self.y_mean.dtype) * self.y_ref.to(self.y_mean.dtype)
        return self.y_std * m, shift * m

    def relative(self, signals: torch.Tensor) -> torch.Tensor:
        """Drift minus :meth:`constant`, in the model's dtype (float32 as trained and
        exported): what the ONNX graph and the C header compute in float32
        (:meth:`evaluate` on the columns of ``signals`` (N, S))."""
        return self.evaluate(signals.unbind(1))[0].T

    def drift64(self, signals: torch.Tensor) -> torch.Tensor:
        """Drift in float64: :meth:`relative` (model dtype) plus the float64 constant."""
        return self.relative(signals).double() + self.constant()

    @property
    def family_name(self) -> str:
        return self.family.name

    @property
    def n_params(self) -> int:
        """Number of parameters the model computes with (:meth:`Family.n_effective`): what
        every report states."""
        return int(self.family.n_effective())

    @property
    def n_structural(self) -> int:
        """Number of trainable parameters the family was built with, whatever the fit
        switched off: what ``compare``'s choice among tied families prefers fewer of (its
        rule unchanged by a fit that zeroes a part)."""
        return int(sum(p.numel() for p in self.parameters() if p.requires_grad))

    def set_scaling(self, *, x_mean: np.ndarray, x_std: np.ndarray, y_mean: np.ndarray,
                    y_std: np.ndarray, sig_lo: np.ndarray, sig_hi: np.ndarray) -> None:
        """Store the standardisation and the trained signal range (float32 buffers)."""
        for name, value in (("x_mean", x_mean), ("x_std", x_std), ("y_mean", y_mean),
                            ("y_std", y_std), ("sig_lo", sig_lo), ("sig_hi", sig_hi)):
            buf = getattr(self, name)
            buf.copy_(torch.as_tensor(np.asarray(value, dtype=np.float64), dtype=buf.dtype))

    def compensated(self, signals: np.ndarray, raw: np.ndarray) -> np.ndarray:
        """``raw − drift`` (N, A), float64, from signals (N, S) and raw outputs (N, A): the
        :class:`~thermonet.models.shipped.ShippedModel` operation (point-wise; a recurrent
        family's stream needs its times: :func:`thermonet.training.train.predict`)."""
        if self.family.recurrent:
            raise InputError(f"model '{self.family_name}' carries a state in time: compensate "
                             "its stream with thermonet.training.train.predict(..., time_s)")
        was_training = self.training
        self.eval()
        try:
            with torch.no_grad():
                drift = self.drift64(torch.as_tensor(np.asarray(signals, dtype=np.float64),
                                                     dtype=torch.float32,
                                                     device=self.sig_lo.device))
        finally:
            self.train(was_training)
        return np.asarray(raw, dtype=np.float64) - drift.cpu().numpy()

    def out_of_range(self, signals: torch.Tensor | np.ndarray) -> torch.Tensor:
        """Bool (N,): the flag :meth:`evaluate` returns — true where a signal lies outside the
        trained range or is not finite, or the guard held a dynamic input (:meth:`set_guard`)."""
        s = torch.as_tensor(signals, dtype=self.sig_lo.dtype, device=self.sig_lo.device)
        with torch.no_grad():
            return self.standardise(s.unbind(1))[1]

    def evaluate(self, signals: Sequence[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Relative drift, axis-major (A, N), and out-of-range flag (N,) from one (N,)
        column per signal (:meth:`relative` is the (N, A) view).

        The drift is :meth:`relative`'s (drift minus the float64 :meth:`constant`),
        de-standardised by :meth:`output_scaling` (target normalisation and mask
        folded in).

        .. math::

            s' = \\min(\\max(s, s_{lo}), s_{hi}),\\quad
            z_f = (x_f(s') - \\bar x_f)\\, s_{x,f}^{-1},\\quad
            z_1 \\leftarrow z_1 + \\textstyle\\sum_i (s_i - s_i),\\quad
            r = \\mathrm{drift}(z;\\ m\\, s_y,\\ m(\\bar y - \\alpha\\, y_{ref}))

        The added term is 0 for finite signals and NaN for NaN/±inf, and every
        family's :meth:`Family.drift` carries a NaN in ``z[0]`` to every axis, so a
        broken thermometer gives NaN drift (never the clamped edge value); the flag is
        :math:`\\bigvee_i s'_i \\ne s_i`.  This is what the ONNX graph and the
        C header evaluate.
        """
        z, flag = self.standardise(signals)
        scale, shift = self.output_scaling()
        return self.family.drift(z, scale, shift), flag

    def standardise(self, signals: Sequence[torch.Tensor]
                    ) -> tuple[list[torch.Tensor], torch.Tensor]:
        """Standardised feature columns (N,) and the out-of-range flag (N,) from one (N,)
        column per signal: the clamp, the features and the NaN term of :meth:`evaluate`."""
        # float32 as trained and exported; a float64 copy (model.double()) computes in
        # float64 — the export's parity check uses one as its reference
        cols = [s.to(self.sig_lo.dtype) for s in signals]
        lo, hi = self.sig_lo, self.sig_hi
        clamped = [torch.minimum(torch.maximum(s, lo[i]), hi[i]) for i, s in enumerate(cols)]
        flag = clamped[0] != cols[0]
        nonfinite = cols[0] - cols[0]
        for s, c in zip(cols[1:], clamped[1:], strict=True):
            flag = flag | (c != s)
            nonfinite = nonfinite + (s - s)
        if self.guarded:
            flag = self._guard(clamped, flag)
        inv_std = 1.0 / self.x_std
        z = [(x - self.x_mean[f]) * inv_std[f]
             for f, x in enumerate(self.features.columns(clamped))]
        # one (N,) addition; every family carries a NaN in z[0] to every output axis
        # (cheaper than adding an (N, 1) column to the (N, A) drift, a broadcast)
        z[0] = z[0] + nonfinite
        return z, flag

    def _guard(self, cols: list[torch.Tensor], flag: torch.Tensor) -> torch.Tensor:
        """Hold each dynamic input of ``cols`` (clamped signals, changed in place) inside the
        joint envelope at its temperature; returns ``flag`` raised where that moved one.

        .. math:: u = (T' - t_0)\\,k - \\tfrac12,\\quad
                  i = \\min(\\max(\\lfloor u \\rfloor, 0), B-2),\\quad
                  w = \\min(\\max(u - i, 0), 1),\\quad
                  b = b_i + w\\,(b_{i+1} - b_i)

        (a NaN temperature takes ``u = 0``: its drift is NaN whatever the bin)."""
        assert self.t_col is not None
        t = cols[self.t_col]
        u = (t - self.guard_knots[0]) * self.guard_knots[1] - 0.5
        u = torch.where(u == u, u, torch.zeros_like(u))
        i = torch.clamp(torch.floor(u), 0.0, float(self.guard_lo.shape[0] - 2))
        w = torch.clamp(u - i, 0.0, 1.0)
        i0 = i.long()
        i1 = i0 + 1
        for k, c in enumerate(self.joint):
            lo_t, hi_t = self.guard_lo[:, k], self.guard_hi[:, k]
            lo = lo_t[i0] + w * (lo_t[i1] - lo_t[i0])
            hi = hi_t[i0] + w * (hi_t[i1] - hi_t[i0])
            held = torch.minimum(torch.maximum(cols[c], lo), hi)
            flag = flag | (held != cols[c])
            cols[c] = held
        return flag

    def evaluate_state(self, signals: Sequence[torch.Tensor], state: torch.Tensor
                       ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """A recurrent family's step: relative drift (A, N), flag (N,) and next state
        (H, N) from signal columns (N,) and states (H, N) (:meth:`evaluate` with the
        family's :meth:`drift_step` in place of its stateless drift)."""
        z, flag = self.standardise(signals)
        scale, shift = self.output_scaling()
        drift, nxt = self.family.drift_step(z, state, scale, shift)  # type: ignore[operator]
        return drift, flag, nxt

    def forward(self, signals: torch.Tensor) -> torch.Tensor:
        """Drift (N, A) from signals (N, S); NaN where a signal is not finite.

        In the model's dtype: float32 as trained (a large constant then loses
        precision: use :meth:`drift64` / :func:`thermonet.training.train.predict`); a float64
        copy (``model.double()``) computes in float64 — the export's parity check
        uses one as its reference.
        """
        r = self.relative(signals)
        return r + self.constant().to(r.dtype)


@contextlib.contextmanager
def _float64_copy(module: nn.Module) -> Iterator[None]:
    """Inside, every parameter and buffer of ``module`` is a copy — float64 where it is
    floating point, as ``copy.deepcopy(module).double()`` gives — and on leaving the
    originals are put back untouched, whatever was done to the copies.  A deep copy of
    the module cost a tenth of a closed-form fit (its dict machinery, not its tensors)."""
    saved: list[tuple[dict[str, Any], str, Any]] = []
    try:
        for mod in module.modules():
            stores: tuple[dict[str, Any], ...] = (mod._parameters, mod._buffers)
            for store in stores:
                for name, t in list(store.items()):
                    if t is None:
                        continue
                    dtype = torch.float64 if t.is_floating_point() else t.dtype
                    new = t.detach().to(dtype, copy=True)
                    saved.append((store, name, t))
                    store[name] = (nn.Parameter(new, requires_grad=False)
                                   if isinstance(t, nn.Parameter) else new)
        yield
    finally:
        for store, name, t in reversed(saved):
            store[name] = t
