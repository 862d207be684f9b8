"""A dependency-free C99 header that evaluates a drift model on a microcontroller.

The header holds the model's constants as ``static const float`` arrays and one
``static inline`` function::

    int <prefix>_compensate(const float *signals, const thermonet_real_t *raw,
                            thermonet_real_t *compensated, thermonet_real_t *drift);

``thermonet_real_t`` is chosen by the header from the target
(:func:`thermonet.models.cgen.c_target_prelude`): ``double`` where the FPU has double
precision (every host, Cortex-M7 ``fpv5-d16``), ``float`` where it has not (Cortex-M0+,
M4F, M33): no double arithmetic in software on a microcontroller.

``signals`` holds ``<PREFIX>_N_SIGNALS`` values in the order of
``<PREFIX>_SIGNAL_NAMES`` (e.g. ``temperature_c`` in °C); ``raw``,
``compensated`` and ``drift`` hold ``<PREFIX>_N_AXES`` values in the order of
``<PREFIX>_AXIS_NAMES``.  It evaluates, in float32, exactly what the ONNX graph
evaluates:

.. math::

    s' = \\operatorname{clip}(s, s_{lo}, s_{hi}),\\;
    x_f = (s'_{i_f} - r_f)^{q_f},\\;
    z = (x - \\bar x)\\, s_x^{-1},\\;
    r = \\mathrm{drift}\\big(z;\\ m\\, s_y,\\ m(\\bar y - \\alpha\\, y_{ref})\\big),\\;
    d = c + r,\\;
    \\text{compensated} = \\text{raw} - d

with the target of each axis as in :mod:`thermonet.models.base`: ``α`` = 1 on
``at-t-ref`` axes (normalised to zero at the rest signals, ``y_ref``), ``m`` =
0 on an axis left uncompensated, and ``c`` the per-axis drift constant, a
``double`` (``<PREFIX>_DRIFT_CONSTANT``): ``r`` is float32, ``d`` and
``raw − d`` are computed in double, so an output with a large constant (1e6
counts) keeps its drift's precision.  On the float path ``c`` = hi + lo, two floats
(``<PREFIX>_DRIFT_HI``/``_LO``), and ``compensated = (raw − hi) − (lo + r)``: the first
subtraction is exact for raw near c, so the small result keeps float's relative
precision (a 1e-3 drift on 1e6 counts; ``tests/test_mcu.py``).  The axes' target modes and
compensation flags are written in the header's comment.

The function returns 1 when a signal was outside the trained range or not finite (the
out-of-range flag), else 0.  A non-finite signal gives NaN drift and NaN
compensated output.  No heap, no libm beyond ``expf``/``expm1f`` on the double path
(RBF; dynamic inputs) and none on the float path (its own bounded polynomial ones,
:data:`~thermonet.models.cgen.FAST_EXPF_MAX_REL_ERR`); the only headers are ``<math.h>``
and ``<stdint.h>``.  Parameters the model stores in a
transformed form (Lorentz centre through a sigmoid, width through softplus; RBF
widths as log σ) and the de-standardisation (folded into each family's last
product, as in the graph: :meth:`~thermonet.models.base.Family.drift`) are
computed by the family's own torch expressions in float32, so the header's
constants are the values the graph computes and nothing numeric is restated in C.

Each family owns its C code (:meth:`~thermonet.models.base.Family.emit_c`,
see :mod:`thermonet.models.cgen`): constants computed by the same torch
expressions as its exported graph, and a body from ``z[f]`` to the drift
``y[a]``; this module assembles the header around it.  A family without one
is refused with :class:`~thermonet.core.errors.ExportError`.  Parity with onnxruntime
is tested to the tolerance of :mod:`.onnx_export` (1e-5 relative to the axis's
largest drift): only summation order and ``expf`` rounding differ.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Mapping, Sequence

import numpy as np

from ..core.errors import ExportError
from ..core.names import LABEL, c_comment, c_string, check_model_names, check_names
from ..core.version import __version__
from ..models import DriftModel
from ..models.cgen import as_float32, c_array, c_float, c_target_prelude
from ..models.composite import AxisModels, DriftModels
from .c_recurrent import render_recurrent_stream_c
from .c_stream_render import render_stream_block_c, render_stream_c
from .onnx_export import check_model_finite, family_name

__all__ = ["render_c_header", "render_axis_models_c", "guard_open", "seal_header",
           "units_lines", "units_comment", "FAST_MATH_REFUSAL"]

_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: Stands for the header's model id in the text the id is the digest of (:func:`seal_header`).
_MODEL_ID = "@THERMONET_MODEL_ID@"

#: The fast-math refusal every model body carries, said once however many bodies a header
#: holds (a per-axis model's parts, a sensor model's two), naming no file: -ffast-math /
#: -Ofast (``__FAST_MATH__``), and -ffinite-math-only alone (``__FINITE_MATH_ONLY__`` is 1
#: there, 0 otherwise on GCC and clang), which folds the same test away without
#: ``__FAST_MATH__``.  -Ofast defines both: one ``#error``, the first.
FAST_MATH_REFUSAL = [
    "/* The NaN/inf test (v - v == 0) is folded away under fast-math or finite-math-only,",
    " * which would turn a broken thermometer into a plausible correction: refuse to compile",
    " * that way. */",
    "#if defined(__FAST_MATH__) && !defined(THERMONET_FAST_MATH_REFUSED)",
    "#define THERMONET_FAST_MATH_REFUSED",
    "#error \"a thermonet header must not be compiled with -ffast-math / -Ofast (it would fold "
    "away the test for NaN and infinite inputs): build the file that includes it without "
    "them\"",
    "#elif defined(__FINITE_MATH_ONLY__) && !defined(THERMONET_FAST_MATH_REFUSED)",
    "#if __FINITE_MATH_ONLY__",
    "#define THERMONET_FAST_MATH_REFUSED",
    "#error \"a thermonet header must not be compiled with -ffinite-math-only (it would fold "
    "away the test for NaN and infinite inputs): build the file that includes it without "
    "it\"",
    "#endif",
    "#endif",
]


def guard_open(p: str, guard: str) -> list[str]:
    """The include guard ``guard`` and the model's id ``<P>_MODEL_ID``: the same header
    included twice is read once, and a header of **another** model under the same prefix
    (two exports left at the default prefix) is a compile error — the guard alone would
    skip it without a word.  :func:`seal_header` writes the id."""
    P = p.upper()
    return [
        f"/* {P}_MODEL_ID: this model's id (a digest of the header below its first line). A",
        " * header of another model with the same prefix cannot be included beside it. */",
        f"#if defined({P}_MODEL_ID) && {P}_MODEL_ID != {_MODEL_ID}",
        f"#error \"two thermonet headers of different models use the prefix '{p}': export one "
        "of them again under another prefix (thermonet export ... --format c --prefix NAME, "
        "or export_c_header(prefix=...))\"",
        "#endif",
        f"#ifndef {guard}",
        f"#define {guard}",
        f"#define {P}_MODEL_ID {_MODEL_ID}",
    ]


def seal_header(text: str) -> str:
    """``text`` with its model id written (:func:`guard_open`): the first 32 bits of the
    SHA-256 of the text after its first line (the title, which names the file), so the same
    model under the same prefix has the same id whatever its file is called, and another
    model (or the same one with other units) another.  A band's tables, inserted after
    (:func:`.c_band.insert_band`), are not in it: they do not change the compensation."""
    body = text.split("\n", 1)[-1]
    digest = hashlib.sha256(body.replace(_MODEL_ID, "").encode("utf-8")).hexdigest()[:8]
    return text.replace(_MODEL_ID, f"0x{digest}UL")


def units_lines(P: str, outputs: Sequence[str], units: Mapping[str, str] | None
                ) -> list[str]:
    """``<P>_AXIS_UNITS``: per axis, in the order of ``<P>_AXIS_NAMES``, the unit of
    ``raw``, ``drift`` and ``compensated`` (the unit the model was trained in: convert a
    sensor's counts to it before the call); "" where the model does not record one."""
    got = [str((units or {}).get(a) or "") for a in outputs]
    return [f"#define {P}_AXIS_UNITS {{" + ", ".join(c_string(u) for u in got) + "}"]


def units_comment(P: str, outputs: Sequence[str], units: Mapping[str, str] | None
                  ) -> list[str]:
    """The header comment's lines saying each axis's unit (:func:`units_lines`)."""
    got = [f"{a} {(units or {}).get(a) or '(not recorded)'}" for a in outputs]
    return [f" * units of raw, drift and compensated ({P}_AXIS_UNITS): {c_comment(got)};",
            " * convert the sensor's output (counts) to them before the call."]


_f = c_float
_array = c_array
_t = as_float32


def _double_array(name: str, values: object) -> str:
    """A ``static const double`` array whose literals round-trip exactly (17 digits)."""
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(arr)):
        raise ExportError(f"non-finite constant in {name} cannot be written to a C header")
    return f"static const double {name}[{arr.size}] = {{" + ", ".join(
        f"{float(v):.17g}" for v in arr) + "};"


def _drift_constant_lines(P: str, constant: np.ndarray) -> list[str]:
    """The per-axis drift constant c, in the arithmetic of the target.

    Double path: c as a ``double``.  Float path: c = hi + lo with hi = float(c) and lo =
    float(c − hi) (|c − hi − lo| ≤ 2⁻²⁴·|lo|): ``compensated = (raw − hi) − (lo + r)``
    subtracts the large part first, exactly for raw near c (Sterbenz), so a 1e-3 drift on a
    1e6 constant keeps float's relative precision on the small result.
    """
    c = np.asarray(constant, dtype=np.float64).reshape(-1)
    hi = c.astype(np.float32)
    lo = (c - hi.astype(np.float64)).astype(np.float32)
    return [
        "#if THERMONET_REAL_IS_DOUBLE",
        _double_array(f"{P}_DRIFT_CONSTANT", c),
        "#else",
        "/* the drift constant c = hi + lo in two floats (c - hi is exact in float64) */",
        _array(f"{P}_DRIFT_HI", hi.astype(np.float64)),
        _array(f"{P}_DRIFT_LO", lo.astype(np.float64)),
        "#endif",
    ]


def _output_lines(P: str, n_axes: int) -> list[str]:
    """drift = c + y and compensated = raw − drift per axis, straight-line (the sizes are
    known: no loop on the part), NaN for a non-finite signal decided once."""
    lines = ["    if (nonfinite) {", *(f"        y[{k}] = NAN;" for k in range(n_axes)), "    }",
             "#if THERMONET_REAL_IS_DOUBLE"]
    for k in range(n_axes):
        lines += [f"    drift[{k}] = (double)y[{k}] + {P}_DRIFT_CONSTANT[{k}];",
                  f"    compensated[{k}] = raw[{k}] - drift[{k}];"]
    lines += ["#else", "    /* raw - hi first: exact for raw near the constant (Sterbenz) */"]
    for k in range(n_axes):
        lines += [f"    y[{k}] += {P}_DRIFT_LO[{k}];",
                  f"    drift[{k}] = {P}_DRIFT_HI[{k}] + y[{k}];",
                  f"    compensated[{k}] = (raw[{k}] - {P}_DRIFT_HI[{k}]) - y[{k}];"]
    return [*lines, "#endif"]


def _signature(p: str, recurrent: bool) -> list[str]:
    """The model function's declaration: stateless ``<p>_compensate``, or a recurrent
    model's step ``<p>_compensate_state`` with the state in and out (.c_recurrent)."""
    if recurrent:
        return [f"static inline int {p}_compensate_state(const float *signals, const float *h_in,",
                "                                       float *h_out,",
                "                                       const thermonet_real_t *raw,",
                "                                       thermonet_real_t *compensated,",
                "                                       thermonet_real_t *drift)"]
    return [f"static inline int {p}_compensate(const float *signals, const thermonet_real_t *raw,",
            "                                 thermonet_real_t *compensated,",
            "                                 thermonet_real_t *drift)"]


def _guard_c(model: DriftModel, p: str) -> tuple[list[str], list[str]]:
    """The joint guard's tables and code (:meth:`DriftModel._guard`, in float, after the
    signals' clamp): each dynamic input held inside the bounds trained near the clamped
    temperature, the flag raised where that moved it.  Nothing without a guard."""
    if not model.guarded:
        return [], []
    assert model.t_col is not None
    n_bins, n_joint = (int(v) for v in model.guard_lo.shape)
    consts = [
        f"/* joint guard: {n_bins} temperature bins; u = (T - t0) * k - 0.5 bins past the",
        " * first bin's centre; bounds per bin (row-major, one column per dynamic input) */",
        _array(f"{p}_guard_knots", _t(model.guard_knots)),
        _array(f"{p}_guard_col", np.asarray(model.joint), "int"),
        _array(f"{p}_guard_lo", _t(model.guard_lo).reshape(-1)),
        _array(f"{p}_guard_hi", _t(model.guard_hi).reshape(-1)),
    ]
    body = [
        "    {",
        f"        float u = (s[{model.t_col}] - {p}_guard_knots[0]) * {p}_guard_knots[1] - 0.5f;",
        "        float w;",
        "        int g, k;",
        "        if (!(u >= 0.0f)) u = 0.0f;   /* below the first centre, or NaN (drift NaN) */",
        f"        g = u < {float(n_bins - 2)}f ? (int)u : {n_bins - 2};",
        "        w = u - (float)g;",
        "        if (w > 1.0f) w = 1.0f;",
        f"        for (k = 0; k < {n_joint}; ++k) {{",
        f"            const float *lo = {p}_guard_lo + g * {n_joint} + k;",
        f"            const float *hi = {p}_guard_hi + g * {n_joint} + k;",
        f"            float b_lo = lo[0] + w * (lo[{n_joint}] - lo[0]);",
        f"            float b_hi = hi[0] + w * (hi[{n_joint}] - hi[0]);",
        f"            float v = s[{p}_guard_col[k]];",
        "            if (!(v >= b_lo && v <= b_hi)) flag = 1;",
        "            if (v < b_lo) v = b_lo;",
        "            if (v > b_hi) v = b_hi;",
        f"            s[{p}_guard_col[k]] = v;",
        "        }",
        "    }",
    ]
    return consts, body


def render_c_header(model: DriftModels, *, prefix: str = "thermonet",
                    units: Mapping[str, str] | None = None, file_name: str | None = None
                    ) -> str:
    """The header text for ``model`` (see :func:`export_c_header`); a per-axis model's is
    :func:`render_axis_models_c`.  ``units``: per axis the unit of raw and drift (the
    checkpoint's; written as ``<PREFIX>_AXIS_UNITS`` and in the comment); ``file_name``: the
    file it is written to, named in its first line (nothing else depends on it)."""
    if not _IDENT.fullmatch(prefix):
        raise ExportError(f"C prefix {prefix!r} is not a C identifier")
    if isinstance(model, AxisModels):
        text = render_axis_models_c(model, prefix=prefix, units=units, file_name=file_name)
    else:
        text = _render_single(model, prefix, stream=True, units=units, title=file_name)
    return seal_header(text)


def _render_single(model: DriftModel, prefix: str, *, stream: bool,
                   units: Mapping[str, str] | None = None, title: str | None = None) -> str:
    """One family's header; ``stream=False`` leaves out the state struct, ``init``, ``step``
    and ``step_block`` (a per-axis model's part: the composite streams once for all).
    ``title`` names the file (or the part) in the first line.  Its model id is written by
    :func:`seal_header` on the whole header."""
    check_model_names(model, error=ExportError)  # names reach C source: checked, then escaped
    check_model_finite(model)
    family = family_name(model)
    p, P = prefix, prefix.upper()
    feats = model.features
    signals, outputs = list(model.signals), list(model.outputs)
    # the target normalisation and the mask, folded into the family's output layer
    y_scale, y_shift = model.output_scaling()
    fam_c = model.family.emit_c(p, y_scale, y_shift)
    fam_consts, fam_body = fam_c.constants, fam_c.body
    recurrent = model.family.recurrent
    guard_consts, guard_body = _guard_c(model, p)
    guard = f"{P}_MODEL_H"
    t_ref = getattr(model.spec, "t_ref", None)
    names = lambda xs: "{" + ", ".join(c_string(x) for x in xs) + "}"  # noqa: E731
    modes = list(model.target_modes)
    comp_axes = list(model.compensated_axes)
    targets = ", ".join(f"{o} {m}{'' if c else ' (uncompensated: drift 0)'}"
                        for o, m, c in zip(outputs, modes, comp_axes, strict=True))
    name = c_comment(title) if title else "thermonet header"
    lines = [
        f"/* {name}: temperature-drift compensation, generated by thermonet {__version__}.",
        f" * family: {c_comment(family)}; inputs (features): {c_comment(model.inputs)};",
        f" * T_ref: {t_ref if t_ref is not None else 'n/a'} degC.",
        f" * signals: {c_comment(signals)}; axes: {c_comment(outputs)}.",
        f" * drift relative to (per axis): {c_comment(targets)}.",
        *units_comment(P, outputs, units),
        " * compensated = raw - drift (thermonet_real_t: double, or float on a single-precision",
        " * FPU); returns 1 when a signal is outside the trained range (drift evaluated at the",
        " * clamped value) or not finite (drift = NaN). */",
        *guard_open(p, guard),
        "",
        "#include <math.h>",
        *c_target_prelude(),
        "",
        *FAST_MATH_REFUSAL,
        "",
        f"#define {P}_N_SIGNALS {len(signals)}",
        f"#define {P}_N_FEATURES {len(model.inputs)}",
        f"#define {P}_N_AXES {len(outputs)}",
        f"#define {P}_SIGNAL_NAMES {names(signals)}",
        f"#define {P}_AXIS_NAMES {names(outputs)}",
        *units_lines(P, outputs, units),
        "",
        _array(f"{p}_sig_lo", _t(model.sig_lo)),
        _array(f"{p}_sig_hi", _t(model.sig_hi)),
        _array(f"{p}_feat_index", feats.index.cpu().numpy(), "int"),
        _array(f"{p}_feat_ref", _t(feats.ref)),
        _array(f"{p}_feat_square", feats.square.cpu().numpy(), "int"),
        _array(f"{p}_x_mean", _t(model.x_mean)),
        _array(f"{p}_x_inv_std", _t(1.0 / model.x_std)),
        *_drift_constant_lines(P, model.constant().detach().cpu().double().numpy()),
        *guard_consts,
        *fam_consts,
        "",
        *_signature(p, recurrent),
        "{",
        f"    float s[{P}_N_SIGNALS];",
        f"    float z[{P}_N_FEATURES];",
        f"    float y[{P}_N_AXES];",
        "    int i, f, a, flag = 0, nonfinite = 0;",
        f"    for (i = 0; i < {P}_N_SIGNALS; ++i) {{",
        "        float v = signals[i];",
        "        /* v - v is 0 for every finite v and NaN for NaN and +-inf */",
        "        if (!(v - v == 0.0f)) nonfinite = 1;",
        f"        if (!(v >= {p}_sig_lo[i] && v <= {p}_sig_hi[i])) flag = 1;",
        f"        if (v < {p}_sig_lo[i]) v = {p}_sig_lo[i];",
        f"        if (v > {p}_sig_hi[i]) v = {p}_sig_hi[i];",
        "        s[i] = v;",
        "    }",
        *guard_body,
        f"    for (f = 0; f < {P}_N_FEATURES; ++f) {{",
        f"        float d = s[{p}_feat_index[f]] - {p}_feat_ref[f];",
        f"        float x = {p}_feat_square[f] ? d * d : d;",
        f"        z[f] = (x - {p}_x_mean[f]) * {p}_x_inv_std[f];",
        "    }",
        fam_body,
        *_output_lines(P, len(outputs)),
        "    (void)i; (void)f; (void)a;",
        "    return flag | nonfinite;",
        "}",
        *((render_recurrent_stream_c(model, p) if recurrent else render_stream_c(model, p))
          if stream else []),
        *(render_stream_block_c(model, p) if stream else []),  # calls <p>_step: either state
        "",
        f"#endif /* {guard} */",
        "",
    ]
    return "\n".join(lines)




def render_axis_models_c(model: AxisModels, *, prefix: str = "thermonet",
                         units: Mapping[str, str] | None = None, file_name: str | None = None
                         ) -> str:
    """A per-axis model's header: one ``<prefix>_compensate`` over the union of the signals
    and one streaming ``<prefix>_step``/``step_block`` (one state struct: the union's dynamic
    inputs), the interface of every header.

    Each part is its own header body under the prefix ``<prefix>_part<k>`` (its constants,
    features, clamp and family, ``<prefix>_part<k>_compensate`` on its own signals), without
    a stream of its own.  ``<prefix>_compensate`` gathers each part's signals from the
    union, calls every part and writes each axis from the part that owns it (the other
    parts' drift there is exactly 0: the sum of :class:`AxisModels` is the owner's value,
    so nothing is added); an axis no part owns has drift 0 and ``compensated = raw``.  A
    non-finite signal gives NaN on every axis (as the sum does: a masked axis is NaN × 0);
    the flag is the OR of the parts'.  Every part evaluates all the axes (those it does not
    own with zero coefficients): the cost is the sum of the parts'.
    """
    check_model_names(model, error=ExportError)
    check_names(model.labels, LABEL, "per-axis labels", error=ExportError)
    check_model_finite(model)
    p, P = prefix, prefix.upper()
    signals, outputs = list(model.signals), list(model.outputs)
    n_s, n_a = len(signals), len(outputs)
    guard = f"{P}_MODEL_H"
    names = lambda xs: "{" + ", ".join(c_string(x) for x in xs) + "}"  # noqa: E731
    table = ", ".join(f"{a} {'raw (drift 0)' if k is None else f'part {k} ' + model.labels[k]}"
                      for a, k in zip(outputs, model.owner, strict=True))
    # the parts' titles name no file: the model id (:func:`seal_header`) is the digest of
    # everything below the first line, the same whatever the file is called
    parts = [_render_single(part, f"{p}_part{k}", stream=False, units=units,
                            title=f"part {k} ({model.labels[k]}) of this per-axis model")
             for k, part in enumerate(model.parts)]
    modes = ", ".join(f"{o} {m}" for o, m in zip(outputs, model.target_modes, strict=True))
    listed = ", ".join(f"{k} {lab} ({part.family_name})"
                       for k, (lab, part) in enumerate(zip(model.labels, model.parts,
                                                           strict=True)))
    body = [
        f"/* {c_comment(file_name) if file_name else 'thermonet header'}: temperature-drift "
        f"compensation, generated by thermonet {__version__}.",
        f" * family: per-axis: each axis computed by its own candidate: {c_comment(table)}.",
        f" * parts: {c_comment(listed)}.",
        f" * signals: {c_comment(signals)}; axes: {c_comment(outputs)}.",
        f" * drift relative to (per axis): {c_comment(modes)}.",
        *units_comment(P, outputs, units),
        " * compensated = raw - drift; returns 1 when a signal is outside a part's trained",
        " * range (drift evaluated at the clamped value) or not finite (drift = NaN). */",
        *guard_open(p, guard),
        "",
        *parts,
        f"#define {P}_N_SIGNALS {n_s}",
        f"#define {P}_N_AXES {n_a}",
        f"#define {P}_N_PARTS {len(model.parts)}",
        f"#define {P}_SIGNAL_NAMES {names(signals)}",
        f"#define {P}_AXIS_NAMES {names(outputs)}",
        *units_lines(P, outputs, units),
        "",
        *_signature(p, False),
        "{",
        "    int i, flag = 0, nonfinite = 0;",
    ]
    for k in range(len(model.parts)):
        pk = f"{P}_PART{k}"
        body += [f"    float s{k}[{pk}_N_SIGNALS];",
                 f"    thermonet_real_t c{k}[{n_a}], d{k}[{n_a}];"]
    body += [f"    for (i = 0; i < {P}_N_SIGNALS; ++i)",
             "        if (!(signals[i] - signals[i] == 0.0f)) nonfinite = 1;"]
    for k, cols in enumerate(model.columns):
        body += [f"    s{k}[{j}] = signals[{c}];" for j, c in enumerate(cols)]
        body.append(f"    flag |= {p}_part{k}_compensate(s{k}, raw, c{k}, d{k});")
    for a, owner in enumerate(model.owner):
        name = c_comment(outputs[a])
        if owner is None:
            body += [f"    drift[{a}] = 0;   /* {name}: left raw */",
                     f"    compensated[{a}] = raw[{a}];"]
        else:
            body += [f"    drift[{a}] = d{owner}[{a}];   /* {name}: part {owner} */",
                     f"    compensated[{a}] = c{owner}[{a}];"]
    body += [
        "    if (nonfinite) {   /* any part's signal: NaN on every axis, as the sum */",
        f"        for (i = 0; i < {P}_N_AXES; ++i) {{",
        "            drift[i] = NAN;",
        "            compensated[i] = NAN;",
        "        }",
        "    }",
        "    return flag | nonfinite;",
        "}",
        *render_stream_c(model, p),
        *render_stream_block_c(model, p),
        "",
        f"#endif /* {guard} */",
        "",
    ]
    return seal_header("\n".join(body))
