"""The C header's streaming form: a state struct, ``init`` and ``step`` (dynamic inputs in C).

Every header gets, after ``<prefix>_compensate``::

    typedef struct { ... } <prefix>_state;
    void <prefix>_init(<prefix>_state *st);
    int  <prefix>_step(<prefix>_state *st, thermonet_time_t time_s, float temperature_c,
                       [const float *proxies,]            -- only when the model reads proxies
                       const thermonet_real_t *raw, thermonet_real_t *compensated,
                       thermonet_real_t *drift, int *flag);

``step`` computes the model's dynamic inputs (``rate``, ``lag_<tau>``,
``play_<w>``) from time and temperature with the recurrences of
:mod:`thermonet.features.dynamics`, in float32 — time is a ``double`` (seconds) so that the
difference of two large timestamps keeps its precision, or on the float path (no
double-precision FPU) a ``uint64_t`` count of microseconds (``THERMONET_TIME_US``, as
PX4's ``hrt_absolute_time()``); only that difference is rounded to float — with
:math:`g(h) = -\\mathrm{expm1f}(-h)/h` so a step
much shorter than τ loses nothing.  Its constants (time constants, widths,
``<PREFIX>_GAP_S``) are the ones stored in the model.  Start-up, gaps and a
non-finite temperature follow the definition (state restart; flag set after a
gap; NaN drift and an untouched state for a NaN temperature).  A time that is
not finite or not after the previous call's is refused: NaN outputs, flag set,
return −1, state unchanged; otherwise ``step`` returns 0.  No heap; libm
``expf``/``expm1f`` only on the double path, the header's bounded fast ones on the float
path.  ``raw``, ``compensated`` and ``drift`` are ``thermonet_real_t`` as in
``<prefix>_compensate``.

Blocks (:func:`render_stream_block_c`)::

    int <prefix>_step_block(<prefix>_state *st, int n, const thermonet_time_t *time_s,
                            const float *temperature_c, [const float *proxies,]
                            const thermonet_real_t *raw, thermonet_real_t *compensated,
                            thermonet_real_t *drift, int *flag);

runs ``n`` consecutive samples (``proxies``, ``raw``, ``compensated`` and ``drift``
row-major, ``n`` × their width) through ``step`` with whatever state the model keeps,
so a block is exactly the samples one at a time: a buffer filled by a DMA or read from
a file is compensated in one call.  A refused sample (bad time) is refused as ``step``
refuses it, and the block goes on; the return value is the number of refused samples
(0: all accepted).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import ExportError
from ..features import dynamics
from ..models.cgen import c_expm1
from .c_driver import c_compiler, run_c_driver

if TYPE_CHECKING:
    from ..models.composite import ShippedModel

__all__ = ["render_stream_c", "render_stream_block_c", "STREAM_DRIVER", "run_stream_c", "check_stream",
           "stream_signature_has_proxies", "REAL_FLAGS", "float_path_slack",
           "judge_step_parity", "step_time_guard_c", "step_signature_c"]

_KIND_CODE = {"rate": 0, "lag": 1, "play": 2}

#: compiler flags that select the header's arithmetic on the host (``real=``)
REAL_FLAGS = {"auto": (), "double": ("-DTHERMONET_USE_DOUBLE",),
              "float": ("-DTHERMONET_USE_FLOAT",)}


def float_path_slack(const: np.ndarray, drift: np.ndarray) -> np.ndarray:
    """What the float path adds to the drift's error, per axis: its ``drift`` output
    (the constant plus the model) is a float, rounded twice at its own magnitude (lo + y,
    hi + that: one ulp in all), and the fast
    ``expf``/``expm1f`` are inside :func:`~.parity.float32_tolerance`'s margin
    (their errors, :data:`~thermonet.models.cgen.FAST_EXPF_MAX_REL_ERR`, are ≤ 2.5 ε32)."""
    big = np.abs(np.asarray(const, dtype=np.float64)) + np.nanmax(np.abs(drift), axis=0)
    return np.spacing(big.astype(np.float32)).astype(np.float64)  # two roundings of ½ ulp


def _float(v: float) -> str:
    return f"{float(np.float32(v)):.9e}f"


def _proxies(model: ShippedModel) -> list[str]:
    dyn = {d.signal for d in dynamics.dynamic_signals(model.inputs)}
    return [s for s in model.signals if s != "temperature_c" and s not in dyn]


def stream_signature_has_proxies(model: ShippedModel) -> bool:
    """Whether ``<prefix>_step`` takes a ``proxies`` argument (the model reads proxies)."""
    return bool(_proxies(model))


def render_stream_c(model: ShippedModel, p: str) -> list[str]:
    """Lines of the state struct, ``<p>_init`` and ``<p>_step`` for ``model``."""
    P = p.upper()
    signals = list(model.signals)
    dyn = dynamics.dynamic_signals(model.inputs)
    proxies = _proxies(model)
    gap_s = float(model.spec.gap_s or dynamics.DEFAULT_GAP_S) if dyn else 0.0
    nd = len(dyn)
    lines = [
        "",
        "/* ---- streaming form: dynamic inputs from time and temperature (thermonet.features.dynamics) */",
        f"#define {P}_N_DYNAMIC {nd}",
        f"#define {P}_N_PROXIES {len(proxies)}",
    ]
    gap_us = int(round(gap_s * 1e6))
    if nd:
        lines += [
            f"#define {P}_GAP_S {gap_s!r} /* s: a longer step restarts the state, flag set */",
            f"#define {P}_GAP_US {gap_us}u /* the same in microseconds (integer time) */",
            "/* kind: 0 rate (degC/min, tau s), 1 lag (degC, tau s), 2 play (degC, half-width) */",
            f"static const int {p}_dyn_kind[{P}_N_DYNAMIC] = "
            "{" + ", ".join(str(_KIND_CODE[d.kind]) for d in dyn) + "};",
            f"static const float {p}_dyn_param[{P}_N_DYNAMIC] = "
            "{" + ", ".join(_float(d.param) for d in dyn) + "};",
            f"static const int {p}_dyn_signal[{P}_N_DYNAMIC] = "
            "{" + ", ".join(str(signals.index(d.signal)) for d in dyn) + "};",
        ]
    if proxies:
        lines.append(f"static const int {p}_proxy_signal[{P}_N_PROXIES] = "
                     "{" + ", ".join(str(signals.index(x)) for x in proxies) + "};")
    state_x = f"    float x[{P}_N_DYNAMIC];      /* e (rate, lag) or P (play), per input */" \
        if nd else "    float x[1];                 /* unused: no dynamic input */"
    lines += [
        "",
        "typedef struct {",
        "    thermonet_time_t t_last;    /* time of the last accepted call (s, or us) */",
        "    thermonet_time_t t_prev;    /* time of the last finite temperature */",
        "    float temp_prev;            /* that temperature, degC */",
        state_x,
        "    int seen, started;",
        f"}} {p}_state;",
        "",
        f"static inline void {p}_init({p}_state *st)",
        "{",
        "    int j;",
        "    st->t_last = 0;",
        "    st->t_prev = 0;",
        "    st->temp_prev = 0.0f;",
        "    for (j = 0; j < (int)(sizeof st->x / sizeof st->x[0]); ++j) st->x[j] = 0.0f;",
        "    st->seen = 0;",
        "    st->started = 0;",
        "}",
        "",
        *step_signature_c(p, proxies),
        "{",
        f"    float s[{P}_N_SIGNALS];",
        "    int a, gap = 0;",
        *step_time_guard_c(P),
    ]
    if "temperature_c" in signals:
        lines.append(f"    s[{signals.index('temperature_c')}] = temperature_c;")
    for k, _ in enumerate(proxies):
        lines.append(f"    s[{p}_proxy_signal[{k}]] = proxies[{k}];")
    if nd:
        lines += [
            "    {",
            "        int j;",
            "        const float T = temperature_c;",
            "        if (!(T - T == 0.0f)) {",
            f"            for (j = 0; j < {P}_N_DYNAMIC; ++j) s[{p}_dyn_signal[j]] = NAN;",
            "        } else {",
            "#if THERMONET_TIME_US",
            f"            int restart = !st->started || (time_s - st->t_prev) > {P}_GAP_US;",
            "#else",
            f"            int restart = !st->started || (time_s - st->t_prev) > {P}_GAP_S;",
            "#endif",
            "            gap = st->started && restart;",
            "            if (restart) {",
            f"                for (j = 0; j < {P}_N_DYNAMIC; ++j)",
            f"                    st->x[j] = {p}_dyn_kind[j] == 2 ? T : 0.0f;",
            "            } else {",
            "#if THERMONET_TIME_US",
            # the step is at most the gap: a 32-bit conversion (one instruction) when it fits
            "                const float dt = (float)(" + (
                "(uint32_t)" if gap_us <= 0xFFFFFFFF else "") + "(time_s - st->t_prev)) * 1.0e-6f;",
            "#else",
            "                const float dt = (float)(time_s - st->t_prev);",
            "#endif",
            "                const float dT = T - st->temp_prev;",
            f"                for (j = 0; j < {P}_N_DYNAMIC; ++j) {{",
            f"                    const float c = {p}_dyn_param[j];",
            f"                    if ({p}_dyn_kind[j] == 2) {{",
            "                        float v = st->x[j];",
            "                        if (v < T - c) v = T - c;",
            "                        if (v > T + c) v = T + c;",
            "                        st->x[j] = v;",
            "                    } else {",
            "                        const float h = dt / c;",
            f"                        const float g = -{c_expm1('-h')} / h;",
            "                        st->x[j] = st->x[j] + g * (dT - h * st->x[j]);",
            "                    }",
            "                }",
            "            }",
            f"            for (j = 0; j < {P}_N_DYNAMIC; ++j) {{",
            f"                const float c = {p}_dyn_param[j], v = st->x[j];",
            f"                s[{p}_dyn_signal[j]] = {p}_dyn_kind[j] == 2 ? T - v",
            f"                    : ({p}_dyn_kind[j] == 0 ? 60.0f * v / c : v);",
            "            }",
            "            st->started = 1;",
            "            st->t_prev = time_s;",
            "            st->temp_prev = T;",
            "        }",
            "    }",
        ]
    else:
        lines.append("    (void)temperature_c;")
    lines += [
        f"    *flag = {p}_compensate(s, raw, compensated, drift) | gap;",
        "    return 0;",
        "}",
    ]
    return lines


def step_signature_c(p: str, proxies: Sequence[str] | bool) -> list[str]:
    """The comment and signature of ``<p>_step``, the same for every streaming header (dynamic
    inputs, the recurrent state): the firmware calls one function whatever the model."""
    return [
        "/* time_s: double seconds, or uint64_t microseconds where THERMONET_TIME_US",
        " * (the float path); THERMONET_TIME_FROM_US(us) converts a microsecond clock. */",
        f"static inline int {p}_step({p}_state *st, thermonet_time_t time_s,",
        "                              float temperature_c,",
        *(["                              const float *proxies,"] if proxies else []),
        "                              const thermonet_real_t *raw,",
        "                              thermonet_real_t *compensated, thermonet_real_t *drift,",
        "                              int *flag)",
    ]


def step_time_guard_c(P: str) -> list[str]:
    """The lines every ``<p>_step`` opens with: a time that is not finite or not after the
    previous sample is refused (NaN out, flag set, state unchanged, -1), else recorded."""
    return [
        "#if THERMONET_TIME_US",
        "    if (st->seen && !(time_s > st->t_last)) {",
        "#else",
        "    if (!(time_s - time_s == 0.0) || (st->seen && !(time_s > st->t_last))) {",
        "#endif",
        f"        for (a = 0; a < {P}_N_AXES; ++a) {{",
        "            drift[a] = NAN;",
        "            compensated[a] = NAN;",
        "        }",
        "        *flag = 1;",
        "        return -1;",
        "    }",
        "    st->t_last = time_s;",
        "    st->seen = 1;",
    ]


def render_stream_block_c(model: ShippedModel, p: str) -> list[str]:
    """Lines of ``<p>_step_block``: ``n`` samples through ``<p>_step`` (module docstring).

    Generic over the state: it only calls ``step``, so whatever ``<p>_state`` holds is
    carried from sample to sample and from block to block.
    """
    P = p.upper()
    prox = stream_signature_has_proxies(model)
    return [
        "",
        f"/* n consecutive samples through {p}_step (row-major: proxies n x {P}_N_PROXIES, raw,",
        f" * compensated and drift n x {P}_N_AXES); returns how many samples were refused */",
        f"static inline int {p}_step_block({p}_state *st, int n, const thermonet_time_t *time_s,",
        "                                    const float *temperature_c,",
        *(["                                    const float *proxies,"] if prox else []),
        "                                    const thermonet_real_t *raw,",
        "                                    thermonet_real_t *compensated,",
        "                                    thermonet_real_t *drift, int *flag)",
        "{",
        "    int k, refused = 0;",
        "    for (k = 0; k < n; ++k) {",
        f"        const long o = (long)k * {P}_N_AXES;",
        f"        refused += {p}_step(st, time_s[k], temperature_c[k],",
        *([f"                            proxies + (long)k * {P}_N_PROXIES,"] if prox else []),
        "                            raw + o, compensated + o, drift + o, flag + k) != 0;",
        "    }",
        "    return refused;",
        "}",
    ]


#: A driver that runs ``step`` over a sequence read from a file (tests, export check, bench).
STREAM_DRIVER = r"""
#include <stdio.h>
#include "model.h"
/* in: int n, then per sample: double t, float T, NP proxy floats, A raw doubles;
 * out: per sample A comp doubles, A drift doubles, int flag, int ret (converted to and from
 * the header's types: float raw/outputs and microsecond time on its float path) */
int main(int argc, char **argv)
{
    FILE *in, *out;
    int n, k, flag, ret;
    double t, raw_in[PFX_N_AXES], comp_out[PFX_N_AXES], drift_out[PFX_N_AXES];
    float temp, prox[PFX_N_PROXIES > 0 ? PFX_N_PROXIES : 1];
    thermonet_real_t raw[PFX_N_AXES], comp[PFX_N_AXES], drift[PFX_N_AXES];
    thermonet_time_t time;
    int a;
    pfx_state st;
    if (argc != 3) return 2;
    in = fopen(argv[1], "rb");
    out = fopen(argv[2], "wb");
    if (!in || !out || fread(&n, sizeof n, 1, in) != 1) return 3;
    pfx_init(&st);
    for (k = 0; k < n; ++k) {
        if (fread(&t, sizeof t, 1, in) != 1 || fread(&temp, sizeof temp, 1, in) != 1) return 4;
        if (PFX_N_PROXIES > 0 &&
            fread(prox, sizeof(float), PFX_N_PROXIES, in) != PFX_N_PROXIES) return 4;
        if (fread(raw_in, sizeof(double), PFX_N_AXES, in) != PFX_N_AXES) return 4;
        for (a = 0; a < PFX_N_AXES; ++a) raw[a] = (thermonet_real_t)raw_in[a];
#if THERMONET_TIME_US
        time = (thermonet_time_t)(t * 1e6 + 0.5);   /* microseconds, as a sensor clock */
#else
        time = t;
#endif
        ret = pfx_step(&st, time, temp, PROXY_ARG raw, comp, drift, &flag);
        for (a = 0; a < PFX_N_AXES; ++a) {
            comp_out[a] = (double)comp[a];
            drift_out[a] = (double)drift[a];
        }
        fwrite(comp_out, sizeof(double), PFX_N_AXES, out);
        fwrite(drift_out, sizeof(double), PFX_N_AXES, out);
        fwrite(&flag, sizeof flag, 1, out);
        fwrite(&ret, sizeof ret, 1, out);
    }
    (void)prox;
    fclose(in);
    fclose(out);
    return 0;
}
"""


#: The same records through ``step_block`` in blocks of ``argv[3]`` samples (the last one
#: shorter); ``ret`` of every sample is its block's number of refused samples.
STREAM_BLOCK_DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "model.h"
int main(int argc, char **argv)
{
    FILE *in, *out;
    int n, k, a, b, blk;
    double t, raw_in[PFX_N_AXES], comp_out[PFX_N_AXES], drift_out[PFX_N_AXES];
    float *temp, *prox;
    thermonet_real_t *raw, *comp, *drift;
    thermonet_time_t *time;
    int *flag, *ret;
    pfx_state st;
    if (argc != 4) return 2;
    blk = atoi(argv[3]);
    in = fopen(argv[1], "rb");
    out = fopen(argv[2], "wb");
    if (blk < 1 || !in || !out || fread(&n, sizeof n, 1, in) != 1 || n < 0) return 3;
    temp = malloc(sizeof(float) * (n + 1));
    prox = malloc(sizeof(float) * (n + 1) * (PFX_N_PROXIES > 0 ? PFX_N_PROXIES : 1));
    raw = malloc(sizeof(thermonet_real_t) * (n + 1) * PFX_N_AXES);
    comp = malloc(sizeof(thermonet_real_t) * (n + 1) * PFX_N_AXES);
    drift = malloc(sizeof(thermonet_real_t) * (n + 1) * PFX_N_AXES);
    time = malloc(sizeof(thermonet_time_t) * (n + 1));
    flag = malloc(sizeof(int) * (n + 1));
    ret = malloc(sizeof(int) * (n + 1));
    if (!temp || !prox || !raw || !comp || !drift || !time || !flag || !ret) return 5;
    for (k = 0; k < n; ++k) {
        if (fread(&t, sizeof t, 1, in) != 1 || fread(temp + k, sizeof(float), 1, in) != 1) return 4;
        if (PFX_N_PROXIES > 0 && fread(prox + (long)k * PFX_N_PROXIES, sizeof(float),
                                       PFX_N_PROXIES, in) != PFX_N_PROXIES) return 4;
        if (fread(raw_in, sizeof(double), PFX_N_AXES, in) != PFX_N_AXES) return 4;
        for (a = 0; a < PFX_N_AXES; ++a) raw[(long)k * PFX_N_AXES + a] = (thermonet_real_t)raw_in[a];
#if THERMONET_TIME_US
        time[k] = (thermonet_time_t)(t * 1e6 + 0.5);
#else
        time[k] = t;
#endif
    }
    pfx_init(&st);
    for (k = 0; k < n; k += blk) {
        const int m = n - k < blk ? n - k : blk;
        const long o = (long)k * PFX_N_AXES;
        const int r = pfx_step_block(&st, m, time + k, temp + k, PROXY_ARG raw + o, comp + o,
                                     drift + o, flag + k);
        for (b = 0; b < m; ++b) ret[k + b] = r;
    }
    for (k = 0; k < n; ++k) {
        for (a = 0; a < PFX_N_AXES; ++a) {
            comp_out[a] = (double)comp[(long)k * PFX_N_AXES + a];
            drift_out[a] = (double)drift[(long)k * PFX_N_AXES + a];
        }
        fwrite(comp_out, sizeof(double), PFX_N_AXES, out);
        fwrite(drift_out, sizeof(double), PFX_N_AXES, out);
        fwrite(flag + k, sizeof(int), 1, out);
        fwrite(ret + k, sizeof(int), 1, out);
    }
    fclose(in);
    fclose(out);
    return 0;
}
"""


def run_stream_c(model: ShippedModel, header_text: str, time_s: np.ndarray,
                 temperature_c: np.ndarray, raw: np.ndarray, proxies: np.ndarray | None = None,
                 *, prefix: str = "thermonet", cflags: tuple[str, ...] = ("-O2",),
                 block: int | None = None) -> dict[str, np.ndarray]:
    """Compile the header with a driver and run ``step`` over one sequence.

    ``block``: run it through ``step_block`` in blocks of that many samples instead
    (:data:`STREAM_BLOCK_DRIVER`; ``ret`` is then each sample's block's refused count).

    Returns ``{"compensated", "drift", "flag", "ret"}`` per sample.

    Raises
    ------
    ExportError
        No C compiler, or the header or driver does not compile or run.
    """
    cc = c_compiler()
    if cc is None:
        raise ExportError("no C compiler found")
    n, n_axes = len(time_s), len(model.outputs)
    n_prox = len(_proxies(model))
    if block is not None and int(block) < 1:
        raise ExportError(f"block must be >= 1 sample, got {block}")
    source = STREAM_DRIVER if block is None else STREAM_BLOCK_DRIVER
    proxy_arg = ("prox + (long)k * PFX_N_PROXIES," if block is not None else "prox,") \
        if n_prox else ""
    rec_in = np.dtype([("t", np.float64), ("T", np.float32), ("p", np.float32, (n_prox,)),
                       ("raw", np.float64, (n_axes,))])
    rows = np.zeros(n, dtype=rec_in)
    rows["t"], rows["T"], rows["raw"] = time_s, temperature_c, raw
    if n_prox:
        rows["p"] = np.asarray(proxies, dtype=np.float32).reshape(n, n_prox)
    # packed records (no padding), read field by field by the driver
    out = run_c_driver(cc, header_text, source.replace("PROXY_ARG", proxy_arg), rows,
                       [("comp", np.float64, (n_axes,)), ("drift", np.float64, (n_axes,)),
                        ("flag", np.int32), ("ret", np.int32)], prefix=prefix,
                       cflags=("-Wall", "-Wextra", "-Werror", *cflags),
                       args=[str(int(block))] if block is not None else [],
                       header="the C header's step()", driver_name="the C stream driver")
    return {"compensated": out["comp"], "drift": out["drift"], "flag": out["flag"].astype(bool),
            "ret": out["ret"]}


def check_stream(model: ShippedModel, header_text: str, *, prefix: str = "thermonet",
                 seed: int = 0, rtol: float = 1e-4, real: str = "auto"
                 ) -> dict[str, float] | None:
    """Run ``<prefix>_step`` over a synthetic sequence and compare it with torch.

    For a model with dynamic inputs: 3,000 jittered samples of heat/cool triangles inside
    the trained temperature range, a gap (> ``gap_s``) and a missing temperature; torch
    evaluates the same model on :func:`thermonet.features.dynamics.compute` of the sequence
    (float64 recurrences).  The drift less its float64 per-axis constant
    (``model.constant()``, added in double on both sides) must agree within ``rtol`` of the
    axis's largest such value (the C recurrences run in float32), ``compensated`` must be
    ``raw - drift``, the drift NaN exactly where the temperature is missing, and the flag
    set after the gap.  ``real="float"`` runs the header's float path on the host
    (float raw/outputs, microsecond time, fast ``expm1f``; :func:`float_path_slack` added
    to the tolerance).  Returns None (nothing to check) for a model
    without dynamic inputs or without a C compiler.

    Raises
    ------
    ExportError
        A drift outside the tolerance, or a missing NaN or gap flag.
    """
    import torch

    if not dynamics.dynamic_signals(model.inputs) or c_compiler() is None:
        return None
    rng = np.random.default_rng(seed)
    gap_s = float(model.spec.gap_s or dynamics.DEFAULT_GAP_S)
    n = 3000
    t = 1.7e9 + np.cumsum(rng.uniform(0.1, 0.3, n) * gap_s)
    t[n // 2:] += 2.0 * gap_s
    signals = list(model.signals)
    if "temperature_c" in signals:
        j = signals.index("temperature_c")
        lo, hi = float(model.sig_lo[j]), float(model.sig_hi[j])
    else:
        lo, hi = 20.0, 30.0
    span = t - t[0]
    period = span[-1] / 3.0
    temp = lo + (hi - lo) * (0.1 + 0.8 * (1.0 - np.abs(2.0 * ((span % period) / period) - 1.0)))
    temp[n // 3] = np.nan
    proxies = _proxies(model)
    prox = np.column_stack([np.full(n, 0.5 * (float(model.sig_lo[signals.index(x)])
                                             + float(model.sig_hi[signals.index(x)])))
                            for x in proxies]) if proxies else None
    raw = np.zeros((n, len(model.outputs)))
    dyn, gap = dynamics.compute(t, temp, model.inputs, gap_s)
    cols = {"temperature_c": temp, **dyn}
    for k, x in enumerate(proxies):
        cols[x] = prox[:, k]  # type: ignore[index]
    s = np.column_stack([cols[x] for x in signals])
    with torch.no_grad():
        want = model.relative(torch.from_numpy(s)).double().numpy()
        const = model.constant().detach().cpu().double().numpy()
    got = run_stream_c(model, header_text, t, temp, raw, prox, prefix=prefix,
                       cflags=("-O2", *REAL_FLAGS[real]))
    worst = judge_step_parity(model, got, raw, want, const, t, temp, real=real, rtol=rtol)
    if not got["flag"][gap].all() or not got["flag"][np.isnan(temp)].all():
        raise ExportError("C header step() parity check failed: flag not set after the gap or "
                          "at the missing temperature")
    return {"n_samples": float(n), "max_abs_diff": worst}


def judge_step_parity(model: ShippedModel, got: dict[str, np.ndarray], raw: np.ndarray,
                      want: np.ndarray, const: np.ndarray, t: np.ndarray, temp: np.ndarray, *,
                      real: str, rtol: float) -> float:
    """The C ``step()``'s output (``got``, from :func:`run_stream_c`) against torch's relative
    drift ``want`` plus the model's constant ``const``: ``compensated`` must be exactly
    ``raw − drift``, NaN where torch has NaN, and the drift within ``rtol`` of each axis's
    largest drift (plus the float path's slack).  Raises :class:`ExportError` naming the first
    sample outside; returns the largest absolute difference.  Shared by every streaming
    header (dynamic inputs, the recurrent state)."""
    if not np.array_equal(got["compensated"], raw - got["drift"], equal_nan=True):
        raise ExportError("C header step() parity check failed: 'compensated' is not raw - drift")
    drift = got["drift"] - const
    nan_want = np.isnan(want)
    if not np.array_equal(np.isnan(drift), nan_want):
        raise ExportError("C header step() parity check failed: NaN drift where torch has none "
                          "(or the reverse) on the test sequence")
    tol = rtol * np.nanmax(np.abs(want), axis=0)
    if real == "float":
        tol = tol + float_path_slack(const, want)
    err = np.where(nan_want, 0.0, np.abs(drift - want))
    k, a = (int(i) for i in np.unravel_index(int(np.argmax(err - tol)), err.shape))
    if err[k, a] > tol[a]:
        raise ExportError(f"C header step() parity check failed at sample {k} (t = {t[k]:.3f} s, "
                          f"T = {temp[k]:.4g} degC), axis '{model.outputs[a]}': C "
                          f"{drift[k, a]:.9g} vs torch {want[k, a]:.9g} (tolerance {tol[a]:.3g})")
    return float(err.max())
