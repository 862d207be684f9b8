"""The C99 header of a full sensor model: b(s) and E(s) as two bias bodies, M⁻¹ in C.

The header holds two ordinary model bodies (:func:`thermonet.exporting.c_header._render_single`,
the code every bias model's header comes from, without their own streaming form), prefixed
``<prefix>_bias`` (one output per axis) and ``<prefix>_elem`` (one output per element of
E = M − I, named ``<kind>_m<row><col>`` in C: the axis-name rule has no dot), then the
interface of every header::

    int <prefix>_compensate(const float *signals, const thermonet_real_t *raw,
                            thermonet_real_t *compensated, thermonet_real_t *drift);
    typedef struct { ... } <prefix>_state;
    void <prefix>_init(<prefix>_state *st);
    int  <prefix>_step(<prefix>_state *st, thermonet_time_t time_s, float temperature_c,
                       [const float *proxies,] const thermonet_real_t *raw,
                       thermonet_real_t *compensated, thermonet_real_t *drift, int *flag);
    int  <prefix>_step_block(<prefix>_state *st, int n, const thermonet_time_t *time_s,
                             const float *temperature_c, [const float *proxies,]
                             const thermonet_real_t *raw, thermonet_real_t *compensated,
                             thermonet_real_t *drift, int *flag);

``_compensate`` evaluates ``b`` and ``E`` as drifts of a zero raw input (so ``drift = b`` and
``E``), then per triad the adjugate solve of :func:`thermonet.models.sensor.solve_columns`:
``compensated = M⁻¹ (raw − b)``, ``drift = raw − compensated``, in ``thermonet_real_t``
(double on a host or a double-precision FPU, as the ONNX graph's float64 inverse; float on
a single-precision FPU).  Returns 1 when a signal was outside the trained range or not
finite.

``_step`` and ``_step_block`` are :mod:`thermonet.exporting.c_stream`'s, generated from the
bias model (b and E share one feature spec, so one state computes the dynamic inputs of
both): the same signature, time guard (a time not finite or not after the previous call's:
NaN out, flag set, −1, state unchanged), gap restart and NaN temperature as every bias
model's header, then ``_compensate`` on the signals it built.  A firmware calls a sensor
model exactly as it calls a bias model.  Recurrent families (the GRU) are refused.

Written only after the host's compiler built it and its outputs matched torch on both
arithmetic paths (``-DTHERMONET_USE_DOUBLE`` and ``-DTHERMONET_USE_FLOAT``):
:func:`sensor_c_parity` (the batch form, the ONNX check's points and tolerance) and
:func:`sensor_stream_parity` (``_step`` over a heat/cool sequence with a gap and a missing
temperature, against torch on :func:`thermonet.features.dynamics.compute` of it).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

from ..core.errors import ExportError
from ..core.fileio import atomic_write_text
from ..core.names import c_comment
from ..features import dynamics
from ..models.sensor import SensorModel, check_invertible
from .c_driver import PARITY_DRIVER, c_compiler, run_c_driver
from .c_header import (
    _IDENT,
    _render_single,
    guard_open,
    seal_header,
    units_comment,
    units_lines,
)
from .c_stream import REAL_FLAGS, run_stream_c
from .c_stream_render import render_stream_block_c, render_stream_c
from .sensor_probe import PARITY_EPS32, STREAM_RTOL, probe

__all__ = ["render_sensor_c", "sensor_c_parity", "sensor_stream_parity", "sensor_sequence",
           "export_sensor_c"]


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


def render_sensor_c(model: SensorModel, *, prefix: str = "thermonet",
                    units: Mapping[str, str] | None = None, file_name: str | None = None
                    ) -> str:
    """The header's text (see the module docstring); ``units`` and ``file_name`` as
    :func:`thermonet.exporting.c_header.render_c_header` takes them."""
    if not _IDENT.fullmatch(prefix):
        raise ExportError(f"C prefix {prefix!r} is not a C identifier")
    if model.bias.family.recurrent:
        raise ExportError(f"a sensor model of the recurrent family '{model.family_name}' has "
                          "no C header (its state would be two GRUs'); export it as onnx")
    c = _c_names(model)
    p, P = prefix, prefix.upper()
    # the bodies without their own streaming form: the sensor's step below computes the
    # dynamic inputs once for both (b and E read the same signals, one feature spec)
    # the bodies' titles name no file: the model id is the digest below the first line
    bias_h = _render_single(c.bias, f"{p}_bias", stream=False, units=units,
                            title="the bias b(s) of this sensor model")
    elem_h = _render_single(c.elements, f"{p}_elem", stream=False,
                            title="the elements E(s) of this sensor model")
    n_a, n_e = len(model.outputs), len(model.element_outputs)
    body = [
        f"/* {c_comment(file_name) if file_name else 'thermonet header'}: full sensor model "
        "(bias, scale factor, misalignment), generated by thermonet.",
        f" * triads: {'; '.join(', '.join(t) for t in model.triads)}.",
        *units_comment(P, list(model.outputs), units),
        " * compensated = M(s)^-1 (raw - b(s)), M = I + E; returns 1 when a signal is outside",
        f" * the trained range or not finite. Streaming: {p}_init, {p}_step, {p}_step_block",
        " * (dynamic inputs from time and temperature), as every thermonet header. */",
        *guard_open(p, f"{P}_SENSOR_H"), bias_h, elem_h,
        f"#define {P}_N_SIGNALS {P}_BIAS_N_SIGNALS", f"#define {P}_N_AXES {n_a}",
        *units_lines(P, list(model.outputs), units),
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
        "    return flag;", "}",
        # init/step/step_block of the bias model's inputs, calling {p}_compensate above
        *render_stream_c(c.bias, p),
        *render_stream_block_c(c.bias, p),
        "", f"#endif /* {P}_SENSOR_H */", ""]
    return seal_header("\n".join(body))


def _tolerance(raw: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The ONNX check's: :data:`PARITY_EPS32` × ε32 × (|raw| + |b|), per sample and axis."""
    return PARITY_EPS32 * float(np.finfo(np.float32).eps) * (np.abs(raw) + np.abs(b))


def sensor_c_parity(model: SensorModel, text: str, *, prefix: str = "thermonet",
                    real: str = "double") -> dict[str, float]:
    """Compile ``text`` and compare ``_compensate`` with torch on the ONNX check's points.

    ``real``: ``"double"`` (the host's path, as the ONNX graph's float64 inverse) or
    ``"float"`` (``-DTHERMONET_USE_FLOAT``: raw, b, E's sum and the solve in float, as on a
    single-precision FPU; a few ε32 of |raw| more, well inside :data:`PARITY_EPS32`)."""

    cc = c_compiler()
    if cc is None:
        raise ExportError("no C compiler found: the sensor C header cannot be checked, so it "
                          "is not written")
    sig, raw = probe(model)
    with torch.no_grad():
        want, flag_t = model.columns(torch.as_tensor(sig, dtype=torch.float32).unbind(1),
                                     torch.as_tensor(raw))
        b = model.bias.drift64(torch.as_tensor(sig, dtype=torch.float32)).numpy()
    rows = np.zeros(sig.shape[0], dtype=[("s", np.float32, sig.shape[1]),
                                         ("raw", np.float64, raw.shape[1])])
    rows["s"], rows["raw"] = sig, raw
    # the batch driver of every header: the sensor's _compensate has the same signature
    out = run_c_driver(cc, text, PARITY_DRIVER, rows,
                       [("comp", np.float64, raw.shape[1]), ("drift", np.float64, raw.shape[1]),
                        ("flag", np.int32)], prefix=prefix,
                       cflags=("-O2", "-Wall", "-Wextra", "-Werror", *REAL_FLAGS[real]),
                       header="the sensor C header", driver_name="the sensor C parity driver")
    tol = _tolerance(raw, b)
    err = np.abs(out["comp"] - want.numpy())
    if not np.all(err <= tol):
        i, j = np.unravel_index(int(np.argmax(err / tol)), err.shape)
        raise ExportError(f"sensor C header parity failed ({real} path): '{model.outputs[j]}' "
                          f"differs from torch by {err[i, j]:.3g} (tolerance {tol[i, j]:.3g})")
    if not np.array_equal(out["flag"].astype(bool), flag_t.numpy()):
        raise ExportError("sensor C header parity failed: out_of_range flag differs from torch")
    return {"max_abs_error": float(err.max()),
            "max_error_over_tolerance": float((err / tol).max())}


def sensor_sequence(model: SensorModel, seed: int = 0, n_max: int = 20000
                    ) -> dict[str, np.ndarray]:
    """A stream to check ``_step`` on: heat/cool triangles inside the trained temperature
    range (slow enough that a trained ``rate`` stays inside its range), jittered steps of
    0.1–0.3 ``gap_s``, a gap (2 ``gap_s``) half-way, a missing temperature at a third;
    proxies at mid-range; raw = b + up to ±10 × max(|b|, 1) per axis.

    Returns ``time_s``, ``temperature_c``, ``proxies`` (N, P), ``raw`` (N, O), the float64
    ``signals`` (N, S) of :func:`thermonet.features.dynamics.compute` and ``gap`` (N,)."""
    bias = model.bias
    signals = list(model.signals)
    gap_s = float(bias.spec.gap_s or dynamics.DEFAULT_GAP_S)
    lo_s, hi_s = bias.sig_lo.double().numpy(), bias.sig_hi.double().numpy()
    rng = np.random.default_rng(seed)
    if "temperature_c" in signals:
        j = signals.index("temperature_c")
        lo, hi = float(lo_s[j]), float(hi_s[j])
    else:
        lo, hi = 20.0, 30.0
    n = 3000
    if "rate_c_per_min" in signals:   # the triangle's slope at 70 % of the trained rate
        j = signals.index("rate_c_per_min")
        r_max = max(abs(float(lo_s[j])), abs(float(hi_s[j])))
        if r_max > 0:
            period = 2.0 * 0.8 * (hi - lo) * 60.0 / (0.7 * r_max)
            n = int(min(n_max, max(n, np.ceil(3.0 * period / (0.2 * gap_s)))))
    t = 1.7e9 + np.cumsum(rng.uniform(0.1, 0.3, n) * gap_s)
    t[n // 2:] += 2.0 * gap_s
    span = t - t[0]
    period = span[-1] / 3.0
    temp = lo + (hi - lo) * (0.1 + 0.8 * (1.0 - np.abs(2.0 * ((span % period) / period) - 1.0)))
    temp[n // 3] = np.nan
    dyn_names = {d.signal for d in dynamics.dynamic_signals(bias.inputs)}
    prox_names = [x for x in signals if x != "temperature_c" and x not in dyn_names]
    prox = np.column_stack([np.full(n, 0.5 * (lo_s[signals.index(x)] + hi_s[signals.index(x)]))
                            for x in prox_names]) if prox_names else np.zeros((n, 0))
    dyn, gap = dynamics.compute(t, temp, bias.inputs, gap_s)
    cols = {"temperature_c": temp, **dyn, **{x: prox[:, k] for k, x in enumerate(prox_names)}}
    s = np.column_stack([cols[x] for x in signals])
    with torch.no_grad():
        b = bias.drift64(torch.as_tensor(s, dtype=torch.float32)).numpy()
    scale = np.maximum(np.abs(np.nan_to_num(b)).max(axis=0), 1.0)
    raw = np.nan_to_num(b) + rng.uniform(-10.0, 10.0, b.shape) * scale
    return {"time_s": t, "temperature_c": temp, "proxies": prox, "raw": raw, "signals": s,
            "gap": gap}


def term_scale(model: SensorModel, signals: np.ndarray, raw: np.ndarray) -> np.ndarray:
    """Per axis a, the largest |b_a| + Σ_c |E_ac x_c| over the samples (x = M⁻¹(raw − b)):
    the magnitude of what the drift (raw − compensated = b + E x) sums, at which the float32
    error of b and E (and of the dynamic inputs they read) is bounded; NaN samples skipped."""
    with torch.no_grad():
        s32 = torch.as_tensor(signals, dtype=torch.float32)
        b = model.bias.drift64(s32).numpy()
        e = model.elements.drift64(s32).numpy()
        x = model.columns(s32.unbind(1), torch.as_tensor(raw))[0].numpy()
    terms = sample_terms(model, b, e, x)
    return np.nanmax(np.where(np.isfinite(terms), terms, np.nan), axis=0)


def sample_terms(model: SensorModel, b: np.ndarray, e: np.ndarray, x: np.ndarray
                 ) -> np.ndarray:
    """Per sample and axis a, |b_a| + Σ_c |E_ac| |x_c| (b (N, O), E (N, elements) row-major per
    triad, x (N, O) the compensated output): what the drift sums, sample by sample."""
    terms = np.abs(b)
    i = j = 0
    for t in model.triads:
        k = len(t)
        m = np.abs(e[:, j:j + k * k].reshape(-1, k, k))
        terms[:, i:i + k] += np.einsum("nrc,nc->nr", m, np.abs(x[:, i:i + k]))
        i += k
        j += k * k
    return terms


def sensor_stream_parity(model: SensorModel, text: str, *, prefix: str = "thermonet",
                         real: str = "double", seed: int = 0) -> dict[str, float]:
    """Compile ``text`` and run ``<prefix>_step`` over :func:`sensor_sequence` against torch
    (:meth:`SensorModel.columns` on the float64 dynamic inputs, cast to float32 as the graph
    reads them).

    ``compensated`` must be NaN exactly where torch's is (the missing temperature), ``drift``
    exactly ``raw − compensated`` in the header's arithmetic, the flag set after the gap and
    at the missing temperature, every call accepted; ``compensated`` within
    :data:`STREAM_RTOL` of each axis's :func:`term_scale` (the C recurrences run in float32,
    as a bias header's ``check_stream``) plus the batch check's :data:`PARITY_EPS32` bound.

    Raises
    ------
    ExportError
        No compiler, a build failure, or any of the above violated (the first sample named).
    """
    if c_compiler() is None:
        raise ExportError("no C compiler found: the sensor C header cannot be checked, so it "
                          "is not written")
    seq = sensor_sequence(model, seed)
    t, temp, raw, s = seq["time_s"], seq["temperature_c"], seq["raw"], seq["signals"]
    got = run_stream_c(model.bias, text, t, temp, raw,
                       seq["proxies"] if seq["proxies"].shape[1] else None, prefix=prefix,
                       cflags=("-O2", *REAL_FLAGS[real]))
    with torch.no_grad():
        s32 = torch.as_tensor(s, dtype=torch.float32)
        want = model.columns(s32.unbind(1), torch.as_tensor(raw))[0].numpy()
        b = model.bias.drift64(s32).numpy()
    what = f"sensor C header step() parity failed ({real} path)"
    if not (got["ret"] == 0).all():
        raise ExportError(f"{what}: a call on the increasing sequence was refused")
    # drift = raw - compensated, one subtraction in the header's arithmetic (float: of floats)
    dt = np.float32 if real == "float" else np.float64
    diff = (raw.astype(dt) - got["compensated"].astype(dt)).astype(np.float64)
    if not np.array_equal(got["drift"], diff, equal_nan=True):
        raise ExportError(f"{what}: 'drift' is not raw - compensated")
    if not np.array_equal(np.isnan(got["compensated"]), np.isnan(want)):
        raise ExportError(f"{what}: NaN output where torch has none (or the reverse)")
    # a gap restarts the dynamic inputs' state and raises the flag (a model without them
    # keeps no state: no gap to flag); a missing temperature is a non-finite signal
    gap = seq["gap"] if dynamics.dynamic_signals(model.bias.inputs) else np.zeros_like(temp, bool)
    if not got["flag"][gap].all() or not got["flag"][np.isnan(temp)].all():
        raise ExportError(f"{what}: flag not set after the gap or at the missing temperature")
    ok = ~np.isnan(want)
    tol = STREAM_RTOL * term_scale(model, s, raw) + _tolerance(raw, np.nan_to_num(b))
    err = np.where(ok, np.abs(got["compensated"] - want), 0.0)
    k, a = (int(v) for v in np.unravel_index(int(np.argmax(err / tol)), err.shape))
    if err[k, a] > tol[k, a]:
        raise ExportError(f"{what} at sample {k} (t = {t[k]:.3f} s, T = {temp[k]:.4g} degC), "
                          f"axis '{model.outputs[a]}': C {got['compensated'][k, a]:.9g} vs "
                          f"torch {want[k, a]:.9g} (tolerance {tol[k, a]:.3g})")
    return {"n_samples": float(t.size), "max_abs_error": float(err.max()),
            "max_error_over_tolerance": float((err / tol).max())}


def export_sensor_c(model: SensorModel, path: str | Path, *, prefix: str = "thermonet",
                    units: Mapping[str, str] | None = None) -> Path:
    """Write the header to ``path`` after the invertibility check and parity with torch
    (batch and ``step()``, the double and the float path); ``units``: per axis the unit of
    raw and drift (``<PREFIX>_AXIS_UNITS``)."""

    check_invertible(model, probe(model)[0], what="sensor model")
    text = render_sensor_c(model, prefix=prefix, units=units, file_name=Path(path).name)
    for real in ("double", "float"):
        sensor_c_parity(model, text, prefix=prefix, real=real)
        sensor_stream_parity(model, text, prefix=prefix, real=real)
    return atomic_write_text(path, text)
