"""A dependency-free C99 header that evaluates a drift model on a microcontroller.

The header holds the model's constants as ``static const float`` arrays and one
``static inline`` function::

    int <prefix>_compensate(const float *signals, const double *raw,
                            double *compensated, double *drift);

``signals`` holds ``<PREFIX>_N_SIGNALS`` values in the order of
``<PREFIX>_SIGNAL_NAMES`` (e.g. ``temperature_c`` in °C); ``raw``,
``compensated`` and ``drift`` hold ``<PREFIX>_N_AXES`` values in the order of
``<PREFIX>_AXIS_NAMES``.  It evaluates, in float32, exactly what the ONNX graph
evaluates:

.. math::

    s' = \\operatorname{clip}(s, s_{lo}, s_{hi}),\\;
    x_f = (s'_{i_f} - r_f)^{q_f},\\;
    z = (x - \\bar x)/s_x,\\;
    r = m\\,\\big(f(z)\\, s_y + \\bar y - \\alpha\\, y_{ref}\\big),\\;
    d = c + r,\\;
    \\text{compensated} = \\text{raw} - d

with the target of each axis as in :mod:`thermonet.models.base`: ``α`` = 1 on
``at-t-ref`` axes (normalised to zero at the rest signals, ``y_ref``), ``m`` =
0 on an axis left uncompensated, and ``c`` the per-axis drift constant, a
``double`` (``<PREFIX>_DRIFT_CONSTANT``): ``r`` is float32, ``d`` and
``raw − d`` are computed in double, so an output with a large constant (1e6
counts) keeps its drift's precision.  The axes' target modes and
compensation flags are written in the header's comment.

and returns 1 when a signal was outside the trained range or not finite (the
out-of-range flag), else 0.  A non-finite signal gives NaN drift and NaN
compensated output.  No heap, no libm beyond ``expf`` (RBF only); the only
headers are ``<math.h>`` (``expf``, ``NAN``).  Parameters the model stores in a
transformed form (Lorentz centre through a sigmoid, width through softplus; RBF
widths as log σ) are converted once here with torch's own float32 operations,
so the header's constants are the values the graph computes.

Each family registers an emitter in :data:`EMITTERS`; a family without one is
refused with :class:`~thermonet.errors.ExportError`.  Parity with onnxruntime
is tested to the tolerance of :mod:`.onnx_export` (1e-5 relative to the axis's
largest drift): only summation order and ``expf`` rounding differ.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .. import __version__
from ..errors import ExportError
from ..fileio import atomic_write_text
from ..names import c_comment, c_string, check_model_names
from .onnx_export import (
    _check_points,
    check_drift_parity,
    check_model_finite,
    family_name,
    float32_tolerance,
    trained_range,
)

__all__ = ["export_c_header", "render_c_header", "EMITTERS"]

_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _f(value: float) -> str:
    """A float32 literal that round-trips exactly (9 significant digits)."""
    v = float(np.float32(value))
    if not math.isfinite(v):
        raise ExportError(f"non-finite constant {v!r} cannot be written to a C header")
    return f"{v:.9e}f"


def _array(name: str, values: object, ctype: str = "float") -> str:
    arr = np.asarray(values, dtype=np.float64)
    shape = "".join(f"[{n}]" for n in arr.shape)
    fmt = _f if ctype == "float" else (lambda v: str(int(v)))

    def rows(a: np.ndarray) -> str:
        if a.ndim == 1:
            return "{" + ", ".join(fmt(v) for v in a) + "}"
        return "{\n    " + ",\n    ".join(rows(r) for r in a) + "}"

    return f"static const {ctype} {name}{shape} = {rows(arr)};"


def _double_array(name: str, values: object) -> str:
    """A ``static const double`` array whose literals round-trip exactly (17 digits)."""
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(arr)):
        raise ExportError(f"non-finite constant in {name} cannot be written to a C header")
    return f"static const double {name}[{arr.size}] = {{" + ", ".join(
        f"{float(v):.17g}" for v in arr) + "};"


def _t(tensor: torch.Tensor) -> np.ndarray:
    return tensor.detach().cpu().to(torch.float32).numpy().astype(np.float64)


# -- family emitters: (constants, body) computing yz[A] from z[F] --------------------------------
Emitter = Callable[[nn.Module, str], tuple[list[str], str]]


def _emit_linear(fam: nn.Module, p: str) -> tuple[list[str], str]:
    consts = [_array(f"{p}_lin_w", _t(fam.weight)), _array(f"{p}_lin_b", _t(fam.bias))]
    body = f"""\
    for (a = 0; a < {p.upper()}_N_AXES; ++a) {{
        float acc = {p}_lin_b[a];
        for (f = 0; f < {p.upper()}_N_FEATURES; ++f) acc += {p}_lin_w[a][f] * z[f];
        yz[a] = acc;
    }}"""
    return consts, body


def _emit_poly(fam: nn.Module, p: str) -> tuple[list[str], str]:
    terms = np.asarray(fam.terms, dtype=np.int64).reshape(len(fam.terms), fam.n_inputs)
    consts = [f"#define {p.upper()}_POLY_DEGREE {int(fam.degree)}",
              f"#define {p.upper()}_POLY_TERMS {terms.shape[0]}",
              _array(f"{p}_poly_exp", terms, "int"),
              _array(f"{p}_poly_w", _t(fam.weight)), _array(f"{p}_poly_b", _t(fam.bias))]
    P = p.upper()
    # powers[f][k] = z^(k+1) by repeated multiplication, as the torch module does.
    body = f"""\
    {{
        float powers[{P}_N_FEATURES][{P}_POLY_DEGREE];
        float term[{P}_POLY_TERMS];
        int k, t;
        for (f = 0; f < {P}_N_FEATURES; ++f) {{
            powers[f][0] = z[f];
            for (k = 1; k < {P}_POLY_DEGREE; ++k) powers[f][k] = powers[f][k - 1] * z[f];
        }}
        for (t = 0; t < {P}_POLY_TERMS; ++t) {{
            int first = 1;
            float v = 0.0f;
            for (f = 0; f < {P}_N_FEATURES; ++f) {{
                int e = {p}_poly_exp[t][f];
                if (e == 0) continue;
                v = first ? powers[f][e - 1] : v * powers[f][e - 1];
                first = 0;
            }}
            term[t] = v;
        }}
        for (a = 0; a < {P}_N_AXES; ++a) {{
            float acc = {p}_poly_b[a];
            for (t = 0; t < {P}_POLY_TERMS; ++t) acc += {p}_poly_w[a][t] * term[t];
            yz[a] = acc;
        }}
    }}"""
    return consts, body


def _emit_lorentz(fam: nn.Module, p: str) -> tuple[list[str], str]:
    with torch.no_grad():
        center = _t(fam.center.reshape(-1))
        width = _t(torch.clamp(fam.width, min=1e-6).reshape(-1))
    consts = [_array(f"{p}_lor_y0", _t(fam.y0)), _array(f"{p}_lor_amp", _t(fam.amplitude)),
              _array(f"{p}_lor_xc", center), _array(f"{p}_lor_w", width)]
    body = f"""\
    for (a = 0; a < {p.upper()}_N_AXES; ++a) {{
        float dx = z[0] - {p}_lor_xc[a];
        float w = {p}_lor_w[a];
        yz[a] = {p}_lor_y0[a] + 0.636619772f * {p}_lor_amp[a] * w / (4.0f * dx * dx + w * w);
    }}"""
    return consts, body


def _emit_fuzzy(fam: nn.Module, p: str) -> tuple[list[str], str]:
    P = p.upper()
    consts = [f"#define {P}_FUZZY_SETS {int(fam.n_sets)}",
              _array(f"{p}_fz_peaks", _t(fam.peaks)),
              _array(f"{p}_fz_bounds", _t(fam.bounds)),
              f"static const float {p}_fz_spacing = {_f(max(float(_t(fam.spacing)[0]), 1e-6))};",
              _array(f"{p}_fz_slope", _t(fam.slope)),
              _array(f"{p}_fz_intercept", _t(fam.intercept))]
    body = f"""\
    {{
        float lam[{P}_FUZZY_SETS];
        float x = z[0], total = 0.0f;
        int i;
        if (x < {p}_fz_bounds[0]) x = {p}_fz_bounds[0];
        if (x > {p}_fz_bounds[1]) x = {p}_fz_bounds[1];
        for (i = 0; i < {P}_FUZZY_SETS; ++i) {{
            float dx = x - {p}_fz_peaks[i];
            float m = 1.0f - (dx < 0.0f ? -dx : dx) / {p}_fz_spacing;
            lam[i] = m > 0.0f ? m : 0.0f;
            total += lam[i];
        }}
        if (total < 1e-6f) total = 1e-6f;
        for (i = 0; i < {P}_FUZZY_SETS; ++i) lam[i] /= total;
        for (a = 0; a < {P}_N_AXES; ++a) {{
            float acc = 0.0f, acc_x = 0.0f;
            for (i = 0; i < {P}_FUZZY_SETS; ++i) {{
                acc += lam[i] * {p}_fz_intercept[a][i];
                acc_x += lam[i] * x * {p}_fz_slope[a][i];
            }}
            yz[a] = acc + acc_x;
        }}
    }}"""
    return consts, body


def _emit_rbf(fam: nn.Module, p: str) -> tuple[list[str], str]:
    P = p.upper()
    with torch.no_grad():
        two_sigma2 = 2.0 * torch.exp(torch.clamp(2.0 * fam.log_sigma, min=-60.0, max=60.0))
    consts = [f"#define {P}_RBF_CENTRES {int(fam.n_centres)}",
              _array(f"{p}_rbf_c", _t(fam.centres)),
              _array(f"{p}_rbf_two_sigma2", _t(two_sigma2)),
              _array(f"{p}_rbf_w", _t(fam.weight)), _array(f"{p}_rbf_b", _t(fam.bias))]
    body = f"""\
    {{
        float phi[{P}_RBF_CENTRES];
        int j;
        for (j = 0; j < {P}_RBF_CENTRES; ++j) {{
            float d2 = 0.0f;
            for (f = 0; f < {P}_N_FEATURES; ++f) {{
                float dz = z[f] - {p}_rbf_c[j][f];
                d2 += dz * dz;
            }}
            phi[j] = expf(-d2 / {p}_rbf_two_sigma2[j]);
        }}
        for (a = 0; a < {P}_N_AXES; ++a) {{
            float acc = {p}_rbf_b[a];
            for (j = 0; j < {P}_RBF_CENTRES; ++j) acc += {p}_rbf_w[a][j] * phi[j];
            yz[a] = acc;
        }}
    }}"""
    return consts, body


#: Family name → emitter of its C constants and body.
EMITTERS: dict[str, Emitter] = {
    "linear": _emit_linear,
    "poly": _emit_poly,
    "lorentz": _emit_lorentz,
    "ts-fuzzy": _emit_fuzzy,
    "rbf": _emit_rbf,
}


def render_c_header(model: nn.Module, *, prefix: str = "thermonet") -> str:
    """The header text for ``model`` (see :func:`export_c_header`)."""
    if not _IDENT.fullmatch(prefix):
        raise ExportError(f"C prefix {prefix!r} is not a C identifier")
    check_model_names(model, error=ExportError)  # names reach C source: checked, then escaped
    check_model_finite(model)
    family = family_name(model)
    if family not in EMITTERS:
        raise ExportError(f"no C emitter for model family '{family}' "
                          f"(supported: {', '.join(EMITTERS)})")
    p, P = prefix, prefix.upper()
    feats = model.features
    signals, outputs = list(model.signals), list(model.outputs)
    fam_consts, fam_body = EMITTERS[family](model.family, p)
    guard = f"{P}_MODEL_H"
    t_ref = getattr(model.spec, "t_ref", None)
    names = lambda xs: "{" + ", ".join(c_string(x) for x in xs) + "}"  # noqa: E731
    modes = list(model.target_modes)
    comp_axes = list(model.compensated_axes)
    targets = ", ".join(f"{o} {m}{'' if c else ' (uncompensated: drift 0)'}"
                        for o, m, c in zip(outputs, modes, comp_axes, strict=True))
    lines = [
        f"/* {p}.h: temperature-drift compensation, generated by thermonet {__version__}.",
        f" * family: {c_comment(family)}; inputs (features): {c_comment(model.inputs)};",
        f" * T_ref: {t_ref if t_ref is not None else 'n/a'} degC.",
        f" * signals: {c_comment(signals)}; axes: {c_comment(outputs)}.",
        f" * drift relative to (per axis): {c_comment(targets)}.",
        " * compensated = raw - drift (double); returns 1 when a signal is outside the trained",
        " * range (drift evaluated at the clamped value) or not finite (drift = NaN). */",
        f"#ifndef {guard}",
        f"#define {guard}",
        "",
        "#include <math.h>",
        "",
        "/* The NaN/inf test (v - v == 0) is folded away under fast-math, which would turn a",
        " * broken thermometer into a plausible correction: refuse to compile that way. */",
        "#if defined(__FAST_MATH__)",
        f"#error \"{p}.h must not be compiled with -ffast-math / -Ofast (non-finite inputs)\"",
        "#endif",
        "",
        f"#define {P}_N_SIGNALS {len(signals)}",
        f"#define {P}_N_FEATURES {len(model.inputs)}",
        f"#define {P}_N_AXES {len(outputs)}",
        f"#define {P}_SIGNAL_NAMES {names(signals)}",
        f"#define {P}_AXIS_NAMES {names(outputs)}",
        "",
        _array(f"{p}_sig_lo", _t(model.sig_lo)),
        _array(f"{p}_sig_hi", _t(model.sig_hi)),
        _array(f"{p}_feat_index", feats.index.cpu().numpy(), "int"),
        _array(f"{p}_feat_ref", _t(feats.ref)),
        _array(f"{p}_feat_square", feats.square.cpu().numpy(), "int"),
        _array(f"{p}_x_mean", _t(model.x_mean)),
        _array(f"{p}_x_std", _t(model.x_std)),
        _array(f"{p}_y_mean", _t(model.y_mean)),
        _array(f"{p}_y_std", _t(model.y_std)),
        _array(f"{p}_y_ref", _t(model.y_ref)),
        _array(f"{p}_at_t_ref", _t(model._at_t_ref(torch.float32))),
        _array(f"{p}_compensate_axis", _t(model.compensate)),
        _double_array(f"{P}_DRIFT_CONSTANT", model.constant().detach().cpu().double().numpy()),
        *fam_consts,
        "",
        f"static inline int {p}_compensate(const float *signals, const double *raw,",
        "                                 double *compensated, double *drift)",
        "{",
        f"    float s[{P}_N_SIGNALS];",
        f"    float z[{P}_N_FEATURES];",
        f"    float yz[{P}_N_AXES];",
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
        f"    for (f = 0; f < {P}_N_FEATURES; ++f) {{",
        f"        float d = s[{p}_feat_index[f]] - {p}_feat_ref[f];",
        f"        float x = {p}_feat_square[f] ? d * d : d;",
        f"        z[f] = (x - {p}_x_mean[f]) / {p}_x_std[f];",
        "    }",
        fam_body,
        f"    for (a = 0; a < {P}_N_AXES; ++a) {{",
        f"        float y = yz[a] * {p}_y_std[a] + {p}_y_mean[a];",
        f"        float r = nonfinite ? NAN : (y - {p}_at_t_ref[a] * {p}_y_ref[a]) "
        f"* {p}_compensate_axis[a];",
        f"        double d = (double)r + {P}_DRIFT_CONSTANT[a];",
        "        drift[a] = d;",
        "        compensated[a] = raw[a] - d;",
        "    }",
        "    (void)i; (void)f;",
        "    return flag | nonfinite;",
        "}",
        "",
        f"#endif /* {guard} */",
        "",
    ]
    return "\n".join(lines)


#: A driver that evaluates the header on points read from a file (parity check, tests).
PARITY_DRIVER = r"""
#include <stdio.h>
#include "model.h"
/* in: int n, then per point S signal floats and A raw doubles;
   out: A comp doubles, A drift doubles, int flag */
int main(int argc, char **argv)
{
    FILE *in, *out;
    int n, k, flag;
    float s[PFX_N_SIGNALS];
    double raw[PFX_N_AXES], comp[PFX_N_AXES], drift[PFX_N_AXES];
    if (argc != 3) return 2;
    in = fopen(argv[1], "rb");
    out = fopen(argv[2], "wb");
    if (!in || !out || fread(&n, sizeof n, 1, in) != 1) return 3;
    for (k = 0; k < n; ++k) {
        if (fread(s, sizeof(float), PFX_N_SIGNALS, in) != PFX_N_SIGNALS) return 4;
        if (fread(raw, sizeof(double), PFX_N_AXES, in) != PFX_N_AXES) return 4;
        flag = pfx_compensate(s, raw, comp, drift);
        fwrite(comp, sizeof(double), PFX_N_AXES, out);
        fwrite(drift, sizeof(double), PFX_N_AXES, out);
        fwrite(&flag, sizeof flag, 1, out);
    }
    fclose(in);
    fclose(out);
    return 0;
}
"""


def c_parity_check(model: nn.Module, header_text: str, *, prefix: str = "thermonet",
                   seed: int = 0) -> dict[str, float] | None:
    """Compile the header with the system C compiler and compare it with torch.

    The points are the ONNX check's (grid and random points in range, float32);
    the tolerance is :func:`~.onnx_export.float32_tolerance`.  Returns ``None``
    (and logs it) when no C compiler is found — the header is then unchecked.

    Raises
    ------
    ExportError
        The header does not compile, or a drift or flag differs from torch.
    """
    import logging
    import shutil
    import subprocess
    import tempfile

    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        logging.getLogger(__name__).warning("no C compiler found: the C header is not checked")
        return None
    points = _check_points(list(trained_range(model).values()), seed)
    n, n_axes = points.shape[0], len(model.outputs)
    const = model.constant().detach().cpu().double().numpy()
    with torch.no_grad():  # float32 drift relative to the float64 constant
        d_torch = model.relative(torch.from_numpy(points)).double().numpy()
        flag_torch = model.out_of_range(torch.from_numpy(points)).numpy()
    tol = float32_tolerance(model, points, d_torch)
    driver = PARITY_DRIVER.replace("PFX", prefix.upper()).replace("pfx", prefix)
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        (tmp / "model.h").write_text(header_text)
        (tmp / "driver.c").write_text(driver)
        built = subprocess.run([cc, "-std=c99", "-O2", "-o", str(tmp / "driver"),
                                str(tmp / "driver.c"), "-lm"], capture_output=True, text=True)
        if built.returncode != 0:
            first = (built.stderr.strip().splitlines() or ["?"])[0]
            raise ExportError(f"the C header does not compile: {first}")
        rows = np.zeros(n, dtype=[("s", np.float32, len(model.signals)),
                                  ("raw", np.float64, n_axes)])
        rows["s"], rows["raw"] = points, const
        blob = np.int32(n).tobytes() + rows.tobytes()
        (tmp / "in.bin").write_bytes(blob)
        run = subprocess.run([str(tmp / "driver"), str(tmp / "in.bin"), str(tmp / "out.bin")],
                             capture_output=True, text=True)
        if run.returncode != 0:
            raise ExportError(f"the C parity driver failed (exit {run.returncode})")
        rec = np.dtype([("comp", np.float64, n_axes), ("drift", np.float64, n_axes),
                        ("flag", np.int32)])
        c_out = np.fromfile(tmp / "out.bin", dtype=rec)
    err = check_drift_parity(model, points, c_out["drift"] - const, d_torch, tol,
                             what="C header", who="C")
    # raw = the constant: compensated is minus the relative drift, computed in double
    if not bool(np.all(np.abs(c_out["comp"] + d_torch) <= tol)):
        raise ExportError("C header parity check failed: 'compensated' is not raw - drift")
    if not np.array_equal(c_out["flag"].astype(bool), flag_torch):
        raise ExportError("C header parity check failed: out_of_range flag differs from torch")
    return {"n_points": float(n), "max_abs_diff": float(err.max())}


def export_c_header(model: nn.Module, path: str | Path, *, prefix: str = "thermonet",
                    check: bool = True) -> Path:
    """Write the model as a C99 header (atomic: temp file + ``os.replace``).

    Parameters
    ----------
    model : DriftModel
        Any family with an entry in :data:`EMITTERS`.
    path : str or Path
        Destination ``.h``.
    prefix : str
        Prefix of every symbol (``<prefix>_compensate``, ``<PREFIX>_N_AXES``);
        a C identifier.
    check : bool
        Compile the header and compare it with torch before writing
        (:func:`c_parity_check`; skipped with a warning when no C compiler exists).

    Returns
    -------
    Path

    Raises
    ------
    ExportError
        Unknown family, NaN/inf parameters, a prefix that is not a C identifier, or a
        failed parity check (nothing is written then).
    """
    text = render_c_header(model, prefix=prefix)
    if check:
        c_parity_check(model, text, prefix=prefix)
    return atomic_write_text(path, text)
