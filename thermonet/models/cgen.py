"""What a family hands the C-header generator: its constants and the body that evaluates it.

Each :class:`~thermonet.models.base.Family` owns its C code
(:meth:`~thermonet.models.base.Family.emit_c`); the generator in
:mod:`thermonet.exporting.c_header` only assembles the header around it.  A
body reads the standardised features ``z[0 .. N_FEATURES-1]`` and writes the
drift in the output's own units to ``y[0 .. N_AXES-1]``; it may use the loop
variables ``f`` and ``a`` (declared ``int`` by the generator) and declares
anything else inside its own block, under names that shadow none of the generator's
(``i``, ``f``, ``a``, ``s``, ``z``, ``y``: headers build with ``-Wshadow``).  The model is
``float``; an exponential is :func:`c_exp` / :func:`c_expm1` (the bounded fast ones on a
single-precision target, see :func:`c_target_prelude`), never ``expf`` directly, so every
family follows the target's arithmetic through these shared helpers; a dense layer is
:func:`c_affine` (straight-line, fused multiply-adds where the target fuses).  Constants
are ``static const`` arrays named ``<prefix>_<family tag>_<name>``; their values come
from the same torch
expressions the family's exported graph evaluates (:meth:`Family.drift`), so
nothing numeric is restated in C.

This module needs only numpy, so the families can import it without pulling
in the export layer.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
import torch

from ..core.errors import ExportError

__all__ = ["CBody", "c_float", "c_array", "as_float32", "c_exp", "c_expm1", "c_target_prelude",
           "c_affine", "c_constant_bytes", "C_TYPE_BYTES",
           "FAST_EXPF_MAX_REL_ERR", "FAST_EXPM1F_MAX_REL_ERR", "FAST_EXP_DOMAIN"]


@dataclass
class CBody:
    """A family's share of the header.

    Attributes
    ----------
    constants : list of str
        C declarations (``#define`` lines, ``static const`` arrays) placed
        before the function.
    body : str
        C statements (indented four spaces) computing ``y[a]`` from ``z[f]``.
    """

    constants: list[str] = field(default_factory=list)
    body: str = ""


def c_float(value: float) -> str:
    """A float32 literal that round-trips exactly (9 significant digits).

    Raises
    ------
    ExportError
        For a NaN or infinite value (a header cannot carry it).
    """
    v = float(np.float32(value))
    if not math.isfinite(v):
        raise ExportError(f"non-finite constant {v!r} cannot be written to a C header")
    return f"{v:.9e}f"


def c_array(name: str, values: object, ctype: str = "float") -> str:
    """``static const <ctype> name[..][..] = {...};`` for a 1-D or 2-D array."""
    arr = np.asarray(values, dtype=np.float64)
    shape = "".join(f"[{n}]" for n in arr.shape)

    def fmt(v: float) -> str:
        return c_float(v) if ctype == "float" else str(int(v))

    def rows(a: np.ndarray) -> str:
        if a.ndim == 1:
            return "{" + ", ".join(fmt(v) for v in a) + "}"
        return "{\n    " + ",\n    ".join(rows(r) for r in a) + "}"

    return f"static const {ctype} {name}{shape} = {rows(arr)};"


#: Bytes of the C types a family's constants use (``int`` is 32 bits on every target the
#: header supports: Cortex-M, RISC-V, x86-64).
C_TYPE_BYTES = {"float": 4, "double": 8, "int": 4, "int8_t": 1, "uint8_t": 1, "int16_t": 2,
                "uint16_t": 2, "int32_t": 4, "uint32_t": 4}
_C_ARRAY = re.compile(r"^\s*static\s+const\s+(\w+)\s+\w+((?:\[\d+\])+)\s*=", re.MULTILINE)


def c_constant_bytes(constants: list[str]) -> int:
    """Bytes of constant data the declarations hold: every ``static const`` array (as
    :func:`c_array` writes them), element size × element count; ``#define`` lines and
    comments hold none.

    Raises
    ------
    ExportError
        For an array of a type not in :data:`C_TYPE_BYTES`.
    """
    total = 0
    for decl in constants:
        for ctype, dims in _C_ARRAY.findall(decl):
            if ctype not in C_TYPE_BYTES:
                raise ExportError(f"constant of unknown C type {ctype!r}: cannot count its bytes")
            total += C_TYPE_BYTES[ctype] * math.prod(int(d) for d in re.findall(r"\d+", dims))
    return total


def as_float32(tensor: torch.Tensor) -> np.ndarray:
    """A tensor's float32 values (as the graph stores them) in a float64 array."""
    return tensor.detach().cpu().to(torch.float32).numpy().astype(np.float64)


# ------------------------------------------------------------------ target arithmetic
#: Measured maximum relative errors of the header's fast ``expf`` / ``expm1f``
#: (``thermonet_fast_expf``: x in [-87, 88]; ``thermonet_fast_expm1f``: x in [-87, 88],
#: relative to |expm1(x)|), against numpy's float64 ``exp``/``expm1`` of the same float32
#: argument on every float32 in the range sampled densely (``tests/test_mcu.py`` measures
#: them again on the compiled C, unfused on the host and fused on the emulated Cortex-M4F,
#: and fails if they are exceeded; measured there, 2026-11-25: 8.6e-8 and 2.2e-7, i.e. 0.72
#: and 1.8 ε32).  For scale: libm's expf is within 1 ulp.
FAST_EXPF_MAX_REL_ERR = 1.5e-7
FAST_EXPM1F_MAX_REL_ERR = 3.0e-7
#: the domain on which those bounds hold (below it: 0 / -1, above it: the value at 88)
FAST_EXP_DOMAIN = (-87.0, 88.0)
#: exp(r) = 1 + r + r²·Q(r) on |r| ≤ ln 2 / 2: Q's coefficients (weighted least squares
#: iterated to the minimax of the relative error; truncation 3e-9, below float32 rounding)
_EXP_Q = ("4.999999404e-01f", "1.666652113e-01f", "4.166838899e-02f", "8.368713781e-03f",
          "1.381460461e-03f")

#: The arithmetic type of raw / drift / compensated (``thermonet_real_t``), the time type of
#: ``step`` (``thermonet_time_t``) and the fast exponentials: shared by every family and by
#: every header included in one translation unit (guarded by ``THERMONET_REAL_T_DEFINED``).
C_EXPF = "THERMONET_EXPF"
C_EXPM1F = "THERMONET_EXPM1F"
C_MAC = "THERMONET_MAC"
#: The sign-bit copy of a tanh in C (``__builtin_copysignf`` under GCC/clang).
C_COPYSIGNF = "THERMONET_COPYSIGNF"


def c_affine(out: str, weights: str, bias: str, n_out: int, terms: list[tuple[int, str]],
             indent: str = "    ") -> str:
    """Straight-line C for ``out[o] = bias[o] + Σ weights[o][c]·x`` over ``terms`` (c, x).

    Summed left to right as the loops it replaces did, one :data:`C_MAC` per term (fused
    where the float path's FPU fuses): the generator knows every size, so there is no loop,
    no index arithmetic and no intermediate store — what a Cortex-M spends on those is as
    much as the arithmetic itself.  The constants stay in their arrays.
    """
    lines = []
    for o in range(n_out):
        lines.append(f"{indent}{out}[{o}] = {bias}[{o}];")
        lines += [f"{indent}{out}[{o}] = {C_MAC}({out}[{o}], {weights}[{o}][{c}], {x});"
                  for c, x in terms]
    return "\n".join(lines)


def c_exp(arg: str) -> str:
    """C expression for ``expf(arg)``: the fast bounded one on the float path."""
    return f"{C_EXPF}({arg})"


def c_expm1(arg: str) -> str:
    """C expression for ``expm1f(arg)``: the fast bounded one on the float path."""
    return f"{C_EXPM1F}({arg})"


def c_target_prelude() -> list[str]:
    """The header's target-selection block (export/README.md, "On a microcontroller").

    * ``THERMONET_REAL_IS_DOUBLE``: 1 where the FPU has double precision — x86 and other
      hosts, an Arm FPU with ``__ARM_FP`` bit 3 (Cortex-M7 ``fpv5-d16``, Cortex-A), a RISC-V
      D extension — else 0 (Cortex-M0+/M3 without FPU, M4F/M33 with a single-precision FPU,
      RISC-V F only).  ``-DTHERMONET_USE_DOUBLE`` / ``-DTHERMONET_USE_FLOAT`` force it.
    * ``thermonet_real_t``: ``double`` or ``float`` accordingly (raw, drift, compensated).
    * ``THERMONET_TIME_US``: 1 on the float path (``step`` takes ``uint64_t`` microseconds,
      as PX4's ``hrt_absolute_time()`` and ArduPilot's ``AP_HAL::micros64()`` give them;
      no double arithmetic), 0 on the double path (``double`` seconds); can be forced.
    * ``THERMONET_FAST_EXP``: 1 on the float path (the polynomial ``expf``/``expm1f``
      below, bounded errors :data:`FAST_EXPF_MAX_REL_ERR`), 0 on the double path (libm).
    """
    q = _EXP_Q
    return [
        "#ifndef THERMONET_REAL_T_DEFINED",
        "#define THERMONET_REAL_T_DEFINED",
        "#include <stdint.h>",
        "/* Arithmetic of raw, drift and compensated: double where the FPU has double",
        " * precision (hosts, Cortex-M7 fpv5-d16, __ARM_FP bit 3, RISC-V D), float where it",
        " * has not (Cortex-M0+/M3: no FPU, M4F/M33: single precision). Force with",
        " * -DTHERMONET_USE_DOUBLE or -DTHERMONET_USE_FLOAT. The model itself is float. */",
        "#if defined(THERMONET_USE_DOUBLE)",
        "#define THERMONET_REAL_IS_DOUBLE 1",
        "#elif defined(THERMONET_USE_FLOAT)",
        "#define THERMONET_REAL_IS_DOUBLE 0",
        "#elif defined(__arm__) || defined(__thumb__) || defined(__aarch64__)",
        "#if defined(__aarch64__) || (defined(__ARM_FP) && (__ARM_FP & 0x8))",
        "#define THERMONET_REAL_IS_DOUBLE 1",
        "#else",
        "#define THERMONET_REAL_IS_DOUBLE 0",
        "#endif",
        "#elif defined(__riscv)",
        "#if defined(__riscv_flen) && __riscv_flen >= 64",
        "#define THERMONET_REAL_IS_DOUBLE 1",
        "#else",
        "#define THERMONET_REAL_IS_DOUBLE 0",
        "#endif",
        "#else",
        "#define THERMONET_REAL_IS_DOUBLE 1",
        "#endif",
        "#if THERMONET_REAL_IS_DOUBLE",
        "typedef double thermonet_real_t;",
        "#else",
        "typedef float thermonet_real_t;",
        "#endif",
        "/* step()'s time: uint64_t microseconds on the float path (no double arithmetic),",
        " * double seconds on the double path; -DTHERMONET_TIME_US=0/1 forces it. */",
        "#ifndef THERMONET_TIME_US",
        "#define THERMONET_TIME_US (!THERMONET_REAL_IS_DOUBLE)",
        "#endif",
        "#if THERMONET_TIME_US",
        "typedef uint64_t thermonet_time_t;",
        "#define THERMONET_TIME_FROM_US(us) ((thermonet_time_t)(us))",
        "#else",
        "typedef double thermonet_time_t;",
        "#define THERMONET_TIME_FROM_US(us) ((thermonet_time_t)(us) * 1.0e-6)",
        "#endif",
        "/* expf / expm1f: polynomial, range-reduced, bounded (max relative error",
        f" * {FAST_EXPF_MAX_REL_ERR:.1e} / {FAST_EXPM1F_MAX_REL_ERR:.1e} on"
        f" [{FAST_EXP_DOMAIN[0]:g}, {FAST_EXP_DOMAIN[1]:g}]) on the float path;",
        " * libm's on the double path. -DTHERMONET_FAST_EXP=0/1 forces it. */",
        "#ifndef THERMONET_FAST_EXP",
        "#define THERMONET_FAST_EXP (!THERMONET_REAL_IS_DOUBLE)",
        "#endif",
        "/* acc + w * x: fused (one instruction, one rounding) on the float path where the FPU",
        " * fuses (FP_FAST_FMAF: Cortex-M4F, M7, M33), else as written (the double path keeps",
        " * the host's reference rounding). -DTHERMONET_FMA=0/1 forces it. GCC and clang:",
        " * __builtin_fmaf, one vfma at every -O level (a plain fmaf is a call to libm's at",
        " * -O0); another compiler: fmaf. Either is the same fused operation. */",
        "#ifndef THERMONET_FMA",
        "#if !THERMONET_REAL_IS_DOUBLE && (defined(FP_FAST_FMAF) || defined(__FP_FAST_FMAF))",
        "#define THERMONET_FMA 1",
        "#else",
        "#define THERMONET_FMA 0",
        "#endif",
        "#endif",
        "#if THERMONET_FMA && defined(__GNUC__)",
        f"#define {C_MAC}(acc, w, x) __builtin_fmaf((w), (x), (acc))",
        "#elif THERMONET_FMA",
        f"#define {C_MAC}(acc, w, x) fmaf((w), (x), (acc))",
        "#else",
        f"#define {C_MAC}(acc, w, x) ((acc) + (w) * (x))",
        "#endif",
        "/* copysignf: a sign-bit copy; GCC and clang inline __builtin_copysignf at every -O",
        " * level (a plain copysignf is a call to libm's at -O0). */",
        "#if defined(__GNUC__)",
        f"#define {C_COPYSIGNF}(x, s) __builtin_copysignf((x), (s))",
        "#else",
        f"#define {C_COPYSIGNF}(x, s) copysignf((x), (s))",
        "#endif",
        "/* exp(x) = 2^k exp(r): k = round(x / ln 2) (rounded by the float addition of",
        " * 1.5 * 2^23, which leaves k in the low mantissa bits), r = x - k ln 2 (ln 2 = hi + lo,",
        " * k hi exact), |r| <= ln 2 / 2, exp(r) = 1 + r + r^2 Q(r), 2^k built from k's bits.",
        " * x < -87: 0; x > 88: exp(88); NaN: NaN. */",
        "static inline float thermonet_fast_expf(float x)",
        "{",
        "    union { float f; uint32_t u; } t, s;",
        "    float r, q;",
        "    if (!(x >= -87.0f)) return x == x ? 0.0f : x;",
        "    if (x > 88.0f) x = 88.0f;",
        f"    t.f = {C_MAC}(1.258291200e+07f, x, 1.442695041e+00f);",
        "    s.u = (t.u << 23) + 0x3F800000u;",
        "    t.f -= 1.258291200e+07f;",
        f"    r = {C_MAC}({C_MAC}(x, -t.f, 6.93145752e-01f), -t.f, 1.42860677e-06f);",
        f"    q = {C_MAC}({q[3]}, r, {q[4]});",
        f"    q = {C_MAC}({q[2]}, r, q);",
        f"    q = {C_MAC}({q[1]}, r, q);",
        f"    q = {C_MAC}({q[0]}, r, q);",
        f"    q = {C_MAC}(r, r * r, q);",
        f"    return {C_MAC}(s.f, s.f, q);",
        "}",
        "/* expm1: the polynomial itself on |x| <= ln 2 / 2 (relative error kept near 0),",
        " * exp(x) - 1 beyond (|expm1| > 0.29 there). */",
        "static inline float thermonet_fast_expm1f(float x)",
        "{",
        "    if (x > -3.465735903e-01f && x < 3.465735903e-01f) {",
        "        const float r = x;",
        f"        float q = {C_MAC}({q[3]}, r, {q[4]});",
        f"        q = {C_MAC}({q[2]}, r, q);",
        f"        q = {C_MAC}({q[1]}, r, q);",
        f"        q = {C_MAC}({q[0]}, r, q);",
        f"        return {C_MAC}(r, r * r, q);",
        "    }",
        "    return thermonet_fast_expf(x) - 1.0f;",
        "}",
        "#if THERMONET_FAST_EXP",
        f"#define {C_EXPF}(x) thermonet_fast_expf(x)",
        f"#define {C_EXPM1F}(x) thermonet_fast_expm1f(x)",
        "#else",
        f"#define {C_EXPF}(x) expf(x)",
        f"#define {C_EXPM1F}(x) expm1f(x)",
        "#endif",
        "#endif /* THERMONET_REAL_T_DEFINED */",
    ]
