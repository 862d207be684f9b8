"""The C99 header of a full sensor model: b(s) and E(s) as two bias headers, M⁻¹ in C.

The header holds two ordinary model headers (:func:`thermonet.exporting.c_header.render_c_header`,
the same code every bias model's header comes from), prefixed ``<prefix>_bias`` (one output
per axis) and ``<prefix>_elem`` (one output per element of E = M − I, named
``<kind>_m<row><col>`` in C: the axis-name rule has no dot), and one function::

    int <prefix>_compensate(const float *signals, const thermonet_real_t *raw,
                            thermonet_real_t *compensated, thermonet_real_t *drift);

It evaluates ``b`` and ``E`` as drifts of a zero raw input (so ``drift = b`` and ``E``), then per
triad the adjugate solve of :func:`thermonet.models.sensor.solve_columns`:
``compensated = M⁻¹ (raw − b)``, ``drift = raw − compensated``, in ``thermonet_real_t``
(double on a host or a double-precision FPU, as the ONNX graph's float64 inverse; float on
a single-precision FPU, unchecked against torch here).  Returns 1 when a signal was outside the
trained range or not finite.  Batch form only: the caller passes the signals (a model with
dynamic inputs needs its own ``_bias_step``/``_elem_step`` state; not wrapped here).

Written only after the host's compiler built it and its output matched torch
(:func:`sensor_c_parity`, the ONNX check's points and tolerance).
"""

from __future__ import annotations

import copy
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import torch

from ..core.errors import ExportError
from ..core.fileio import atomic_write_text
from ..models.sensor import SensorModel, check_invertible
from .sensor_probe import PARITY_EPS32, probe

__all__ = ["render_sensor_c", "sensor_c_parity", "export_sensor_c"]

_DRIVER = r"""
#include <stdio.h>
#include "model.h"
int main(int argc, char **argv)
{
    FILE *in, *out;
    int n, k, a, flag;
    float s[PFX_N_SIGNALS];
    double raw_in[PFX_N_AXES], comp_out[PFX_N_AXES];
    thermonet_real_t raw[PFX_N_AXES], comp[PFX_N_AXES], drift[PFX_N_AXES];
    if (argc != 3) return 2;
    in = fopen(argv[1], "rb");
    out = fopen(argv[2], "wb");
    if (!in || !out || fread(&n, sizeof n, 1, in) != 1) return 3;
    for (k = 0; k < n; ++k) {
        if (fread(s, sizeof(float), PFX_N_SIGNALS, in) != PFX_N_SIGNALS) return 4;
        if (fread(raw_in, sizeof(double), PFX_N_AXES, in) != PFX_N_AXES) return 4;
        for (a = 0; a < PFX_N_AXES; ++a) raw[a] = (thermonet_real_t)raw_in[a];
        flag = pfx_compensate(s, raw, comp, drift);
        for (a = 0; a < PFX_N_AXES; ++a) comp_out[a] = (double)comp[a];
        fwrite(comp_out, sizeof(double), PFX_N_AXES, out);
        fwrite(&flag, sizeof flag, 1, out);
    }
    fclose(in);
    fclose(out);
    return 0;
}
"""


def _c_names(model: SensorModel) -> SensorModel:
    """A copy whose element outputs follow the C axis-name rule (``gyro_mxy``)."""
    c = copy.deepcopy(model)
    c.elements.outputs = [e.replace(".m_", "_m") for e in model.element_outputs]
    return c


def _solve_lines(p: str, model: SensorModel) -> list[str]:
    lines: list[str] = []
    i = j = 0
    for t in model.triads:
        k = len(t)
        lines.append(f"    /* triad {', '.join(t)} */")
        if k == 1:
            lines.append(f"    compensated[{i}] = (raw[{i}] - b[{i}]) / "
                         f"((thermonet_real_t)1 + e[{j}]);")
        else:
            lines.append("    {")
            for r in range(3):
                for c in range(3):
                    one = "(thermonet_real_t)1 + " if r == c else ""
                    lines.append(f"        const thermonet_real_t m{r}{c} = {one}e[{j + 3 * r + c}];")
            for r in range(3):
                lines.append(f"        const thermonet_real_t v{r} = raw[{i + r}] - b[{i + r}];")
            # cofactors C_rc, det = sum_c m0c C0c, inverse = C^T / det (solve_columns)
            cof = {}
            for r in range(3):
                r1, r2 = [x for x in range(3) if x != r]
                for c in range(3):
                    c1, c2 = [x for x in range(3) if x != c]
                    sign = "" if (r + c) % 2 == 0 else "-"
                    cof[r, c] = f"c{r}{c}"
                    lines.append(f"        const thermonet_real_t c{r}{c} = {sign}(m{r1}{c1} * "
                                 f"m{r2}{c2} - m{r1}{c2} * m{r2}{c1});")
            lines.append("        const thermonet_real_t inv_det = (thermonet_real_t)1 / "
                         "(m00 * c00 + m01 * c01 + m02 * c02);")
            for q in range(3):
                lines.append(f"        compensated[{i + q}] = (c0{q} * v0 + c1{q} * v1 + "
                             f"c2{q} * v2) * inv_det;")
            lines.append("    }")
        i += k
        j += k * k
    return lines


def render_sensor_c(model: SensorModel, *, prefix: str = "thermonet") -> str:
    """The header's text (see the module docstring)."""
    from .c_header import render_c_header

    c = _c_names(model)
    p, P = prefix, prefix.upper()
    bias_h = render_c_header(c.bias, prefix=f"{p}_bias")
    elem_h = render_c_header(c.elements, prefix=f"{p}_elem")
    n_a, n_e = len(model.outputs), len(model.element_outputs)
    body = [
        f"/* {p}.h: full sensor model (bias, scale factor, misalignment), generated by "
        "thermonet.",
        f" * triads: {'; '.join(', '.join(t) for t in model.triads)}.",
        " * compensated = M(s)^-1 (raw - b(s)), M = I + E; returns 1 when a signal is outside",
        " * the trained range or not finite. */",
        f"#ifndef {P}_SENSOR_H", f"#define {P}_SENSOR_H", bias_h, elem_h,
        f"#define {P}_N_SIGNALS {P}_BIAS_N_SIGNALS", f"#define {P}_N_AXES {n_a}",
        f"static inline int {p}_compensate(const float *signals, const thermonet_real_t *raw,",
        "                                  thermonet_real_t *compensated, "
        "thermonet_real_t *drift)", "{",
        f"    thermonet_real_t zb[{n_a}], cb[{n_a}], b[{n_a}];",
        f"    thermonet_real_t ze[{n_e}], ce[{n_e}], e[{n_e}];",
        "    int a, flag;",
        f"    for (a = 0; a < {n_a}; ++a) zb[a] = 0;",
        f"    for (a = 0; a < {n_e}; ++a) ze[a] = 0;",
        f"    flag = {p}_bias_compensate(signals, zb, cb, b);   /* drift of 0 = b(s) */",
        f"    flag |= {p}_elem_compensate(signals, ze, ce, e);  /* E(s) */",
        *_solve_lines(p, model),
        f"    for (a = 0; a < {n_a}; ++a) drift[a] = raw[a] - compensated[a];",
        "    return flag;", "}", f"#endif /* {P}_SENSOR_H */", ""]
    return "\n".join(body)


def sensor_c_parity(model: SensorModel, text: str, *, prefix: str = "thermonet"
                    ) -> dict[str, float]:
    """Compile ``text`` (double path) and compare with torch on the ONNX check's points."""

    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise ExportError("no C compiler found: the sensor C header cannot be checked, so it "
                          "is not written")
    sig, raw = probe(model)
    with torch.no_grad():
        want, flag_t = model.columns(torch.as_tensor(sig, dtype=torch.float32).unbind(1),
                                     torch.as_tensor(raw))
        b = model.bias.drift64(torch.as_tensor(sig, dtype=torch.float32)).numpy()
    driver = _DRIVER.replace("PFX", prefix.upper()).replace("pfx", prefix)
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        (tmp / "model.h").write_text(text)
        (tmp / "driver.c").write_text(driver)
        built = subprocess.run([cc, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror",
                                "-DTHERMONET_USE_DOUBLE", "-o", str(tmp / "driver"),
                                str(tmp / "driver.c"), "-lm"], capture_output=True, text=True)
        if built.returncode != 0:
            first = (built.stderr.strip().splitlines() or ["?"])[0]
            raise ExportError(f"the sensor C header does not compile: {first}")
        rows = np.zeros(sig.shape[0], dtype=[("s", np.float32, sig.shape[1]),
                                             ("raw", np.float64, raw.shape[1])])
        rows["s"], rows["raw"] = sig, raw
        (tmp / "in.bin").write_bytes(np.int32(sig.shape[0]).tobytes() + rows.tobytes())
        run = subprocess.run([str(tmp / "driver"), str(tmp / "in.bin"), str(tmp / "out.bin")],
                             capture_output=True, text=True)
        if run.returncode != 0:
            raise ExportError(f"the sensor C parity driver failed (exit {run.returncode})")
        out = np.fromfile(tmp / "out.bin", dtype=[("comp", np.float64, raw.shape[1]),
                                                  ("flag", np.int32)])
    tol = PARITY_EPS32 * float(np.finfo(np.float32).eps) * (np.abs(raw) + np.abs(b))
    err = np.abs(out["comp"] - want.numpy())
    if not np.all(err <= tol):
        i, j = np.unravel_index(int(np.argmax(err / tol)), err.shape)
        raise ExportError(f"sensor C header parity failed: '{model.outputs[j]}' differs from "
                          f"torch by {err[i, j]:.3g} (tolerance {tol[i, j]:.3g})")
    if not np.array_equal(out["flag"].astype(bool), flag_t.numpy()):
        raise ExportError("sensor C header parity failed: out_of_range flag differs from torch")
    return {"max_abs_error": float(err.max()),
            "max_error_over_tolerance": float((err / tol).max())}


def export_sensor_c(model: SensorModel, path: str | Path, *, prefix: str = "thermonet"
                    ) -> Path:
    """Write the header to ``path`` after the invertibility check and parity with torch."""

    check_invertible(model, probe(model)[0], what="sensor model")
    text = render_sensor_c(model, prefix=prefix)
    sensor_c_parity(model, text, prefix=prefix)
    return atomic_write_text(path, text)
