"""The ONNX graph of the closed-form families built node by node (``onnx.helper``), no trace.

torch's exporter traces the model (``torch.export``, decompositions, onnxscript's optimiser):
most of a ``thermonet export --format onnx`` (figures below), for graphs of a dozen nodes.
The families that ship most — ``linear``, ``poly`` (on ΔT or with dynamic inputs:
``poly3-rate``, ``poly3-hyst``), ``rbf`` (with or without its polynomial tail), ``lorentz``, ``ts-fuzzy`` —
and the per-axis composite of them (:class:`~thermonet.models.composite.AxisModels`) are
written here directly from the model's parameters, with the operations of the graph torch's
exporter writes for the same model, in the same order:

* per signal: ``Clip`` to the trained range, the flag ``Not(Equal(clipped, s))`` OR-ed over the
  signals, the NaN term ``s − s`` summed over the signals (:meth:`DriftModel.standardise`);
* the features (``Sub`` the reference, ``Mul`` for a square), standardised (``Sub`` the mean,
  ``Mul`` the float32 ``1/std``), the NaN term added to the first;
* the family's :meth:`~thermonet.models.base.Family.drift`, axis-major (A, N): one ``Gemm``
  (linear, poly — the terms by repeated ``Mul``; rbf — after ``MatMul`` and ``Exp`` of the
  expanded exponent), the Lorentz curve's ``Sub``, ``Mul``, ``Add``, ``Div``, or the fuzzy
  model's triangular memberships (``Clip``, ``Abs``, ``Relu``) and normalised ``MatMul``;
* :class:`~thermonet.exporting.onnx_export.CompensatorGraph`: ``Cast`` to float64, ``Add`` the
  float64 constant, ``Transpose`` to (N, A), ``raw − drift``.

Every constant is computed by torch from the parameters exactly as the model computes it
(:func:`~thermonet.models.base.output_layer`, :meth:`DriftModel.output_scaling`,
:meth:`RBF.exponent`, :meth:`Lorentz.output_form`, :meth:`TSFuzzy.rules`), so the file holds the numbers torch's
exporter would have folded; the polynomial terms and the RBF's tail are built by the family's
own code (:meth:`Poly.term_columns`, :meth:`RBF.tail_columns`, given a ``Mul`` writer).  The
family's math lives in its torch module; this graph is checked against it, never the reverse.

Why keep a second writer at all: the time it saves is one a user waits through.  When it
came in (commit ``fe27c27``, its note in ``experiments/README.md`` then): ``thermonet export
--format onnx`` of the BMI270 soaks' per-axis choice (Lorentz + poly3-hyst + linear), median
of 3, **5.92 s traced → 1.75 s direct** (the whole-job table since: 4.73 s for release
``4846997``, 1.12 s now).  Re-measured by ``experiments/bench_onnx_direct.py`` on
2026-11-29 (the same composition fitted on ``patent-gyro``; a 2-core Xeon VM, load 3–4,
fresh processes, 3 interleaved runs; ``experiments/README.md``, "Export"): the
``export_onnx`` call **0.85 s direct against 11.0 s traced** (paired ratio 0.083), the whole
process 3.9 against 15.3 s.  torch's trace imports ``torch.onnx``, ``torch._dynamo`` and
onnxscript and runs their optimiser for a graph of a few dozen nodes.  The other families (the MLP, the GRU, a plug-in) ship rarely enough that
torch's trace is theirs: no hand-built graph for them.

A family not listed here, a subclass (it may override ``drift``), or a model not in float32
has no direct graph (:func:`direct_supported` says why); ``export_onnx`` then uses torch's
exporter.  Every file, direct or traced, passes the same parity check against the torch
model before it is written, and ``tests/test_export_onnx_direct.py`` compares each direct
graph — every family of :data:`_FAMILIES`, a test holds them equal — with torch's export of
the same model and with the torch model itself.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from ..models import DriftModel
from ..models.base import TINY, output_layer
from ..models.composite import AxisModels, DriftModels
from ..models.fuzzy import TSFuzzy
from ..models.linear import Linear
from ..models.lorentz import Lorentz
from ..models.poly import Poly
from ..models.rbf import RBF

__all__ = ["DIRECT", "direct_supported", "direct_proto"]

#: ``metadata_props['exporter']`` of a graph built here.
DIRECT = "direct"


class _Graph:
    """Nodes and initializers under construction; every value gets a fresh name."""

    def __init__(self) -> None:
        self.nodes: list[Any] = []
        self.inits: list[Any] = []
        self._n = 0

    def _name(self, hint: str) -> str:
        self._n += 1
        return f"{hint}_{self._n}"

    def const(self, value: Any, hint: str, dtype: Any = np.float32) -> str:
        """An initializer holding ``value`` (a tensor or array) in ``dtype``."""
        from onnx import numpy_helper

        if isinstance(value, torch.Tensor):
            value = value.detach().cpu().numpy()
        name = self._name(hint)
        self.inits.append(numpy_helper.from_array(np.asarray(value, dtype=dtype), name))
        return name

    def op(self, op_type: str, *inputs: str, out: str | None = None, **attrs: Any) -> str:
        """Append one node; return its output's name (``out`` when given)."""
        from onnx import helper

        name = out or self._name(op_type.lower())
        self.nodes.append(helper.make_node(op_type, list(inputs), [name], **attrs))
        return name

    def rename(self, old: str, new: str) -> None:
        """Give the value ``old`` (a node's output) the name ``new`` everywhere."""
        for node in self.nodes:
            for seq in (node.input, node.output):
                for i, v in enumerate(seq):
                    if v == old:
                        seq[i] = new

    def stack(self, cols: Sequence[str]) -> str:
        """(K, N) from K columns (N,): ``Unsqueeze`` each on axis 0, ``Concat`` (torch.stack)."""
        axis0 = self.const(np.array([0]), "axis0", np.int64)
        rows = [self.op("Unsqueeze", c, axis0) for c in cols]
        return rows[0] if len(rows) == 1 else self.op("Concat", *rows, axis=0)


def _column(t: torch.Tensor) -> torch.Tensor:
    """(A,) → (A, 1): a per-axis constant broadcast over the N samples (``v[:, None]``)."""
    return t.detach()[:, None]


# -------------------------------------------------------------------- families: drift (A, N)
def _linear(g: _Graph, fam: Linear, z: list[str], scale: torch.Tensor, shift: torch.Tensor
            ) -> str:
    w, b = output_layer(fam.weight, fam.bias, scale, shift)
    return g.op("Gemm", g.const(w, "lin_w"), g.stack(z), g.const(_column(b), "lin_b"))


def _mul(g: _Graph) -> Callable[[str, str], str]:
    """Two columns multiplied as a ``Mul`` node: what a family's own term code
    (:meth:`Poly.term_columns`, :meth:`RBF.tail_columns`) is given to write the graph."""
    return lambda a, b: g.op("Mul", a, b)


def _poly(g: _Graph, fam: Poly, z: list[str], scale: torch.Tensor, shift: torch.Tensor) -> str:
    # the family's own Poly.term_columns: each power once by repeated multiplication, then
    # each term — as Mul nodes
    terms = fam.term_columns(z, mul=_mul(g))
    w, b = output_layer(fam.weight, fam.bias, scale, shift)
    return g.op("Gemm", g.const(w, "poly_w"), g.stack(terms), g.const(_column(b), "poly_b"))


def _rbf(g: _Graph, fam: RBF, z: list[str], scale: torch.Tensor, shift: torch.Tensor) -> str:
    # RBF.drift: u = [z, ‖z‖², 1], φ = exp([Mᵀ b] u), then one Gemm over [φ, z_1 … z_1^d]
    zz = g.op("Mul", z[0], z[0])
    for zf in z[1:]:
        zz = g.op("Add", zz, g.op("Mul", zf, zf))
    ones = g.op("Expand", g.const(np.array(1.0), "one"), g.op("Shape", zz))
    m, b = fam.exponent()
    phi = g.op("Exp", g.op("MatMul", g.const(torch.cat([m.T, b[:, None]], dim=1), "rbf_mb"),
                           g.stack([*z, zz, ones])))
    w, c = output_layer(fam.weight, fam.bias, scale, shift)
    if fam.tail:
        w = torch.cat([w, fam.tail_weight * scale[:, None]], dim=1)
        phi = g.op("Concat", phi, g.stack(fam.tail_columns(z[0], mul=_mul(g))), axis=0)
    return g.op("Gemm", g.const(w, "rbf_w"), phi, g.const(_column(c), "rbf_c"))


def _lorentz(g: _Graph, fam: Lorentz, z: list[str], scale: torch.Tensor, shift: torch.Tensor
             ) -> str:
    # Lorentz.drift: y0 + k / ((z − xc)² + h), every constant (A, 1)
    y0, k, xc, h = fam.output_form(scale, shift)
    dx = g.op("Sub", z[0], g.const(_column(xc), "lor_xc"))
    den = g.op("Add", g.op("Mul", dx, dx), g.const(_column(h), "lor_h"))
    return g.op("Add", g.const(_column(y0), "lor_y0"),
                g.op("Div", g.const(_column(k), "lor_k"), den))


def _fuzzy(g: _Graph, fam: TSFuzzy, z: list[str], scale: torch.Tensor, shift: torch.Tensor
           ) -> str:
    # TSFuzzy.drift: x = clip(z_1), λ = relu(1 − |x/s − p/s|) (n_sets, N), u = [λ, λx],
    # rules · u / (max(Σλ, tiny) + (z_1 − z_1))
    x = g.op("Clip", z[0], g.const(fam.bounds[0], "fz_lo"), g.const(fam.bounds[1], "fz_hi"))
    inv = 1.0 / torch.clamp(fam.spacing, min=TINY)
    dist = g.op("Abs", g.op("Sub", g.op("Mul", x, g.const(inv[0], "fz_inv")),
                            g.const((fam.peaks * inv)[:, None], "fz_peaks")))
    lam = g.op("Relu", g.op("Sub", g.const(np.array(1.0), "one"), dist))
    u = g.op("Concat", lam, g.op("Mul", lam, x), axis=0)
    total = g.op("Add", g.op("Clip", g.op("ReduceSum", lam, g.const(np.array([0]), "axis0",
                                                                   np.int64), keepdims=0),
                             g.const(np.array(TINY), "tiny")),
                 g.op("Sub", z[0], z[0]))
    return g.op("Div", g.op("MatMul", g.const(fam.rules(scale, shift), "fz_rules"), u), total)


#: The families with a direct graph, by exact type (a subclass may override ``drift``).
_FAMILIES: dict[type, Callable[..., str]] = {Linear: _linear, Poly: _poly, RBF: _rbf,
                                             Lorentz: _lorentz, TSFuzzy: _fuzzy}


def _part_unsupported(model: DriftModel) -> str | None:
    if type(model) is not DriftModel:
        return f"{type(model).__name__} is not a plain DriftModel"
    if type(model.family) not in _FAMILIES:
        return f"family '{model.family_name}' has no direct ONNX graph"
    tensors = list(model.parameters()) + [model.sig_lo, model.sig_hi, model.x_mean, model.x_std,
                                          model.y_mean, model.y_std, model.features.ref,
                                          model.guard_knots, model.guard_lo, model.guard_hi]
    if any(t.dtype != torch.float32 for t in tensors):
        return "the model is not in float32"
    return None


def direct_supported(model: DriftModels) -> str | None:
    """Why ``model`` has no direct graph (None when it has one: every part's family is
    ``linear``, ``poly``, ``rbf``, ``lorentz`` or ``ts-fuzzy``, in float32)."""
    parts = list(model.parts) if isinstance(model, AxisModels) else [model]
    for p in parts:
        if not isinstance(p, DriftModel):
            return f"{type(p).__name__} is not a DriftModel"
        why = _part_unsupported(p)
        if why:
            return why
    return None


def _guard(g: _Graph, model: DriftModel, clamped: list[str], flag: str, tag: str) -> str:
    """The joint guard of :meth:`DriftModel._guard` on the clamped signal values (replaced in
    ``clamped``); returns the flag raised where it moved a dynamic input."""
    assert model.t_col is not None
    knots = model.guard_knots
    u = g.op("Sub", g.op("Mul", g.op("Sub", clamped[model.t_col], g.const(knots[0], f"{tag}g_t0")),
                         g.const(knots[1], f"{tag}g_k")), g.const(np.array(0.5), "half"))
    u = g.op("Where", g.op("Equal", u, u), u, g.const(np.array(0.0), "zero"))
    i = g.op("Clip", g.op("Floor", u), g.const(np.array(0.0), "zero"),
             g.const(np.array(float(model.guard_lo.shape[0] - 2)), f"{tag}g_last"))
    w = g.op("Clip", g.op("Sub", u, i), g.const(np.array(0.0), "zero"),
             g.const(np.array(1.0), "one"))
    i0 = g.op("Cast", i, to=7)                    # TensorProto.INT64
    i1 = g.op("Add", i0, g.const(np.array(1), "one_i", np.int64))
    for k, c in enumerate(model.joint):
        bounds = []
        for side, table in (("lo", model.guard_lo), ("hi", model.guard_hi)):
            t = g.const(table[:, k], f"{tag}g_{side}{k}")
            b0 = g.op("Gather", t, i0, axis=0)
            bounds.append(g.op("Add", b0, g.op("Mul", w, g.op("Sub", g.op("Gather", t, i1, axis=0),
                                                             b0))))
        held = g.op("Min", g.op("Max", clamped[c], bounds[0]), bounds[1])
        flag = g.op("Or", flag, g.op("Not", g.op("Equal", held, clamped[c])))
        clamped[c] = held
    return flag


def _part(g: _Graph, model: DriftModel, signals: list[str], tag: str) -> tuple[str, str]:
    """Relative drift (A, N) float32 and flag (N,) of one DriftModel (:meth:`evaluate`)."""
    with torch.no_grad():
        lo, hi = model.sig_lo, model.sig_hi
        clamped = [g.op("Clip", s, g.const(lo[i], f"{tag}{s}_min"), g.const(hi[i], f"{tag}{s}_max"))
                   for i, s in enumerate(signals)]
        flag = g.op("Not", g.op("Equal", clamped[0], signals[0]))
        nonfinite = g.op("Sub", signals[0], signals[0])
        for s, c in zip(signals[1:], clamped[1:], strict=True):
            flag = g.op("Or", flag, g.op("Not", g.op("Equal", c, s)))
            nonfinite = g.op("Add", nonfinite, g.op("Sub", s, s))
        if model.guarded:
            flag = _guard(g, model, clamped, flag, tag)
        inv_std = 1.0 / model.x_std
        z = []
        # Features.columns, then (x − mean) · (1/std) per feature (DriftModel.standardise)
        for f, (i, squared, relative) in enumerate(model.features._layout):
            d = (g.op("Sub", clamped[i], g.const(model.features.ref[f], "ref"))
                 if relative else clamped[i])
            x = g.op("Mul", d, d) if squared else d
            z.append(g.op("Mul", g.op("Sub", x, g.const(model.x_mean[f], "x_mean")),
                          g.const(inv_std[f], "x_inv_std")))
        z[0] = g.op("Add", z[0], nonfinite)
        scale, shift = model.output_scaling()
        drift = _FAMILIES[type(model.family)](g, model.family, z, scale, shift)
    return drift, flag


def direct_proto(model: DriftModels, opset: int) -> Any:
    """The ``ModelProto`` of :class:`~thermonet.exporting.onnx_export.CompensatorGraph` for
    ``model`` (inputs: one float32 [N] per signal, then ``raw`` float64 [N, A]; outputs
    ``compensated``, ``drift`` float64 [N, A], ``out_of_range`` bool [N]), built from its
    parameters; the caller checked :func:`direct_supported`."""
    from onnx import TensorProto, helper

    g = _Graph()
    signals = list(model.signals)
    n_axes = len(model.outputs)
    if isinstance(model, AxisModels):
        total, flag = "", ""
        for k, p in enumerate(model.parts):
            d, f = _part(g, p, [signals[i] for i in model.columns[k]], f"p{k}_")
            total = d if k == 0 else g.op("Add", total, d)
            flag = f if k == 0 else g.op("Or", flag, f)
    else:
        total, flag = _part(g, model, signals, "")
    g.rename(flag, "out_of_range")
    with torch.no_grad():
        const = model.constant().detach().double()[:, None]
    drift64 = g.op("Add", g.op("Cast", total, to=TensorProto.DOUBLE),
                   g.const(const, "drift_constant", np.float64))
    g.op("Transpose", drift64, out="drift", perm=[1, 0])
    g.op("Sub", "raw", "drift", out="compensated")
    inputs = [helper.make_tensor_value_info(s, TensorProto.FLOAT, ["N"]) for s in signals]
    inputs.append(helper.make_tensor_value_info("raw", TensorProto.DOUBLE, ["N", n_axes]))
    outputs = [helper.make_tensor_value_info("compensated", TensorProto.DOUBLE, ["N", n_axes]),
               helper.make_tensor_value_info("drift", TensorProto.DOUBLE, ["N", n_axes]),
               helper.make_tensor_value_info("out_of_range", TensorProto.BOOL, ["N"])]
    graph = helper.make_graph(g.nodes, "thermonet", inputs, outputs, initializer=g.inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)],
                             ir_version=10)
