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

from ..features import dynamics
from ..models.cgen import c_expm1

if TYPE_CHECKING:
    from ..models.composite import DriftModels

__all__ = ["render_stream_c", "render_stream_block_c", "stream_signature_has_proxies",
           "step_time_guard_c", "step_signature_c"]

_KIND_CODE = {"rate": 0, "lag": 1, "play": 2, "delayed": 3}


def _float(v: float) -> str:
    return f"{float(np.float32(v)):.9e}f"


def _proxies(model: DriftModels) -> list[str]:
    dyn = {d.signal for d in dynamics.dynamic_signals(model.inputs)}
    return [s for s in model.signals if s != "temperature_c" and s not in dyn]


def stream_signature_has_proxies(model: DriftModels) -> bool:
    """Whether ``<prefix>_step`` takes a ``proxies`` argument (the model reads proxies)."""
    return bool(_proxies(model))


def render_stream_c(model: DriftModels, p: str) -> list[str]:
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
            "/* kind: 0 rate (degC/min, tau s), 1 lag (degC, tau s), 2 play (degC, half-width),"
            " 3 delayed (degC, tau s) */",
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
            f"                s[{p}_dyn_signal[j]] = ({p}_dyn_kind[j] == 2 || {p}_dyn_kind[j] == 3)"
            " ? T - v",
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


def render_stream_block_c(model: DriftModels, p: str) -> list[str]:
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
