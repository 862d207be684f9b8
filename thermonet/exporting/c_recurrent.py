"""The C header of a recurrent model (the GRU): a state struct, ``_init`` and ``_step``.

A recurrent model's header has, in place of the stateless ``<prefix>_compensate``::

    int <prefix>_compensate_state(const float *signals, const float *h_in, float *h_out,
                                  const thermonet_real_t *raw,
                                  thermonet_real_t *compensated, thermonet_real_t *drift);

one step of the model from the state ``h_in`` (``<PREFIX>_GRU_HIDDEN`` floats) to
``h_out`` (the ONNX graph's ``state``/``state_out``), and the streaming form every header
has (same signature as a model with dynamic inputs, :mod:`.c_stream`)::

    typedef struct { ... } <prefix>_state;
    void <prefix>_init(<prefix>_state *st);
    int  <prefix>_step(<prefix>_state *st, thermonet_time_t time_s, float temperature_c,
                       [const float *proxies,] const thermonet_real_t *raw,
                       thermonet_real_t *compensated, thermonet_real_t *drift, int *flag);

``step`` is the stream of :mod:`thermonet.models.sequence`: the state restarts at 0 on the
first call and after a gap (``<PREFIX>_GRU_GAP_S``, flag set), the window number is
``floor((t − t_0)/<PREFIX>_GRU_STEP_S)`` (integer microseconds on the float path), the
window's running mean is kept as its first sample plus the mean deviation from it (float32
without cancellation), and the state the window's last sample produced is committed when
a later window opens.  A non-finite signal gives NaN drift and NaN compensated output,
flag set, and leaves the state untouched; a time not after the previous call's is refused
(NaN outputs, flag set, return −1, state unchanged), as for the dynamic inputs.

:func:`c_step_parity_check` compares ``_compensate_state`` with torch's step at the
parity points and random states; :func:`check_recurrent_stream` compares ``_step`` with
torch's stream (:func:`~thermonet.models.sequence.stream_relative`) over a jittered
sequence with a gap and a missing temperature.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ExportError
from ..models.sequence import stream_relative
from .c_driver import c_compiler, run_c_driver
from .c_stream import REAL_FLAGS, float_path_slack, judge_step_parity, run_stream_c
from .c_stream_render import _proxies, step_signature_c, step_time_guard_c
from .parity import check_drift_parity, check_points, trained_range
from .recurrent import _tolerance, hidden_size, step_reference

if TYPE_CHECKING:
    from ..models import DriftModel

__all__ = ["render_recurrent_stream_c", "c_step_parity_check", "check_recurrent_stream"]


def render_recurrent_stream_c(model: DriftModel, p: str) -> list[str]:
    """Lines of the state struct, ``<p>_init`` and ``<p>_step`` of a recurrent model."""
    P = p.upper()
    fam: Any = model.family
    step_s, gap_s = float(fam.step_s), float(fam.gap_s)
    signals = list(model.signals)
    proxies = _proxies(model)
    lines = [
        "",
        "/* ---- streaming form: the GRU's state in time (thermonet.models.sequence) */",
        f"#define {P}_N_DYNAMIC 0",
        f"#define {P}_N_PROXIES {len(proxies)}",
        f"#define {P}_GRU_STEP_S {step_s!r} /* s: the state advances once per window */",
        # UINT64_C: the constant has uint64_t's own type (unsigned long on LP64, unsigned
        # long long on the Cortex-M): no sign or rank conversion against the time (-Wconversion
        # -Wsign-conversion), where an 'ull' suffix is a different type on LP64
        f"#define {P}_GRU_STEP_US UINT64_C({int(round(step_s * 1e6))})",
        f"#define {P}_GRU_GAP_S {gap_s!r} /* s: a longer step restarts the state, flag set */",
        f"#define {P}_GRU_GAP_US UINT64_C({int(round(gap_s * 1e6))})",
    ]
    if proxies:
        lines.append(f"static const int {p}_proxy_signal[{P}_N_PROXIES] = "
                     "{" + ", ".join(str(signals.index(x)) for x in proxies) + "};")
    lines += [
        "",
        "typedef struct {",
        "    thermonet_time_t t_last;    /* time of the last accepted call (s, or us) */",
        "    thermonet_time_t t_prev;    /* time of the last finite sample */",
        "    thermonet_time_t t0;        /* time of the last (re)start */",
        "    int32_t k;                  /* current window number since t0 */",
        f"    float base[{P}_N_SIGNALS];  /* the window's first sample */",
        f"    float acc[{P}_N_SIGNALS];   /* sum of deviations from it */",
        "    int count;                  /* samples in the window so far */",
        f"    float h[{P}_GRU_HIDDEN];    /* state committed after the previous window */",
        f"    float h_next[{P}_GRU_HIDDEN]; /* state after this window's last sample */",
        "    int seen, started;",
        f"}} {p}_state;",
        "",
        f"static inline void {p}_init({p}_state *st)",
        "{",
        "    int j;",
        "    st->t_last = 0;",
        "    st->t_prev = 0;",
        "    st->t0 = 0;",
        "    st->k = 0;",
        f"    for (j = 0; j < {P}_N_SIGNALS; ++j) st->base[j] = st->acc[j] = 0.0f;",
        "    st->count = 0;",
        f"    for (j = 0; j < {P}_GRU_HIDDEN; ++j) st->h[j] = st->h_next[j] = 0.0f;",
        "    st->seen = 0;",
        "    st->started = 0;",
        "}",
        "",
        *step_signature_c(p, proxies),
        "{",
        f"    float s[{P}_N_SIGNALS], m[{P}_N_SIGNALS], spare[{P}_GRU_HIDDEN];",
        "    int a, j, restart, gap, finite = 1;",
        "    int32_t k = 0;",
        *step_time_guard_c(P),
    ]
    if "temperature_c" in signals:
        lines.append(f"    s[{signals.index('temperature_c')}] = temperature_c;")
    else:
        lines.append("    (void)temperature_c;")
    for k, _ in enumerate(proxies):
        lines.append(f"    s[{p}_proxy_signal[{k}]] = proxies[{k}];")
    lines += [
        f"    for (j = 0; j < {P}_N_SIGNALS; ++j) if (!(s[j] - s[j] == 0.0f)) finite = 0;",
        "    if (!finite) {   /* NaN drift and output, flag set, the state untouched */",
        f"        (void){p}_compensate_state(s, st->h, spare, raw, compensated, drift);",
        "        *flag = 1;",
        "        return 0;",
        "    }",
        "    /* k = floor((t - t0) / step), counted up from the current window: no division",
        "     * (a 64-bit one is a run-time routine on a Cortex-M), at most gap/step + 1 turns */",
        "#if THERMONET_TIME_US",
        f"    restart = !st->started || (time_s - st->t_prev) > {P}_GRU_GAP_US;",
        "    if (!restart) {",
        "        k = st->k;",
        f"        while (time_s - st->t0 >= (uint64_t)(k + 1) * {P}_GRU_STEP_US) ++k;",
        "    }",
        "#else",
        f"    restart = !st->started || (time_s - st->t_prev) > {P}_GRU_GAP_S;",
        "    if (!restart) {",
        "        k = st->k;",
        f"        while (time_s - st->t0 >= (double)(k + 1) * {P}_GRU_STEP_S) ++k;",
        "    }",
        "#endif",
        "    gap = st->started && restart;",
        "    if (restart) {",
        f"        for (j = 0; j < {P}_GRU_HIDDEN; ++j) st->h[j] = 0.0f;",
        "        st->t0 = time_s;",
        "    } else if (k != st->k) {",
        f"        for (j = 0; j < {P}_GRU_HIDDEN; ++j) st->h[j] = st->h_next[j];",
        "    }",
        "    if (restart || k != st->k) {",
        "        st->k = k;",
        f"        for (j = 0; j < {P}_N_SIGNALS; ++j) {{",
        "            st->base[j] = s[j];",
        "            st->acc[j] = 0.0f;",
        "        }",
        "        st->count = 0;",
        "    }",
        "    st->count += 1;",
        f"    for (j = 0; j < {P}_N_SIGNALS; ++j) {{",
        "        st->acc[j] += s[j] - st->base[j];",
        "        m[j] = st->base[j] + st->acc[j] / (float)st->count;",
        "    }",
        "    st->started = 1;",
        "    st->t_prev = time_s;",
        f"    *flag = {p}_compensate_state(m, st->h, st->h_next, raw, compensated, drift) | gap;",
        "    return 0;",
        "}",
    ]
    return lines


#: Driver of ``_compensate_state``: in: int n, then per point S signal floats, H state
#: floats, A raw doubles; out: A comp doubles, A drift doubles, H state floats, int flag.
STEP_DRIVER = r"""
#include <stdio.h>
#include "model.h"
int main(int argc, char **argv)
{
    FILE *in, *out;
    int n, k, flag, a;
    float s[PFX_N_SIGNALS], h[PFX_GRU_HIDDEN], h_out[PFX_GRU_HIDDEN];
    double raw_in[PFX_N_AXES], comp_out[PFX_N_AXES], drift_out[PFX_N_AXES];
    thermonet_real_t raw[PFX_N_AXES], comp[PFX_N_AXES], drift[PFX_N_AXES];
    if (argc != 3) return 2;
    in = fopen(argv[1], "rb");
    out = fopen(argv[2], "wb");
    if (!in || !out || fread(&n, sizeof n, 1, in) != 1) return 3;
    for (k = 0; k < n; ++k) {
        if (fread(s, sizeof(float), PFX_N_SIGNALS, in) != PFX_N_SIGNALS) return 4;
        if (fread(h, sizeof(float), PFX_GRU_HIDDEN, in) != PFX_GRU_HIDDEN) return 4;
        if (fread(raw_in, sizeof(double), PFX_N_AXES, in) != PFX_N_AXES) return 4;
        for (a = 0; a < PFX_N_AXES; ++a) raw[a] = (thermonet_real_t)raw_in[a];
        flag = pfx_compensate_state(s, h, h_out, raw, comp, drift);
        for (a = 0; a < PFX_N_AXES; ++a) {
            comp_out[a] = (double)comp[a];
            drift_out[a] = (double)drift[a];
        }
        fwrite(comp_out, sizeof(double), PFX_N_AXES, out);
        fwrite(drift_out, sizeof(double), PFX_N_AXES, out);
        fwrite(h_out, sizeof(float), PFX_GRU_HIDDEN, out);
        fwrite(&flag, sizeof flag, 1, out);
    }
    fclose(in);
    fclose(out);
    return 0;
}
"""


def c_step_parity_check(model: DriftModel, header_text: str, *, prefix: str = "thermonet",
                        seed: int = 0, real: str = "auto") -> dict[str, float] | None:
    """``_compensate_state`` against torch's step at the parity points and seeded random
    states (the tolerance of :func:`.recurrent.recurrent_parity_check`, plus
    :func:`~.c_stream.float_path_slack` on the float path); None without a C compiler."""
    cc = c_compiler()
    if cc is None:
        return None
    points = check_points(list(trained_range(model).values()), seed)
    n, n_axes = points.shape[0], len(model.outputs)
    hidden = hidden_size(model)
    states = np.random.default_rng(seed + 2).uniform(-1.0, 1.0, (n, hidden)).astype(np.float32)
    d_torch, f_torch, h_torch = step_reference(model, points, states)
    tol, h_tol = _tolerance(model, points, states, d_torch, h_torch, 1e-5)
    const = model.constant().detach().cpu().double().numpy()
    if real == "float":
        tol = tol + float_path_slack(const, d_torch)
    rows = np.zeros(n, dtype=[("s", np.float32, len(model.signals)),
                              ("h", np.float32, hidden), ("raw", np.float64, n_axes)])
    rows["s"], rows["h"], rows["raw"] = points, states, const
    out = run_c_driver(cc, header_text, STEP_DRIVER, rows,
                       [("comp", np.float64, n_axes), ("drift", np.float64, n_axes),
                        ("h", np.float32, hidden), ("flag", np.int32)], prefix=prefix,
                       cflags=("-Wall", "-Wextra", "-Werror", "-O2", *REAL_FLAGS[real]),
                       driver_name="the C step parity driver")
    err = check_drift_parity(model, points, out["drift"] - const, d_torch, tol,
                             what="C header (recurrent step)", who="C")
    h_err = float(np.abs(out["h"].astype(np.float64) - h_torch).max())
    h_slack = 8 * float(np.finfo(np.float32).eps) if real == "float" else 0.0
    if h_err > h_tol + h_slack:
        raise ExportError(f"C header parity check failed: the next state differs from torch by "
                          f"{h_err:.3g} (tolerance {h_tol + h_slack:.3g})")
    if not np.array_equal(out["flag"].astype(bool), f_torch.astype(bool)):
        raise ExportError("C header parity check failed: out_of_range flag differs from torch")
    return {"n_points": float(n), "max_abs_diff": float(err.max())}


def check_recurrent_stream(model: DriftModel, header_text: str, *, prefix: str = "thermonet",
                           seed: int = 0, rtol: float = 1e-4, real: str = "auto"
                           ) -> dict[str, float] | None:
    """``_step`` over a jittered sequence against torch's stream.

    3,000 samples of heat/cool triangles inside the trained range, spaced 0.05–0.15
    ``step_s`` apart (so ten or so per window), a gap of 3 × ``gap_s`` half-way and a
    missing temperature at a third: the drift less its float64 constant within ``rtol`` of
    the axis's largest (the C running means and state run in float32; plus
    :func:`~.c_stream.float_path_slack` on the float path), NaN exactly at the missing
    sample, ``compensated = raw − drift``, the flag set after the gap.  None without a C
    compiler.
    """
    if c_compiler() is None:
        return None
    fam: Any = model.family
    step_s, gap_s = float(fam.step_s), float(fam.gap_s)
    rng = np.random.default_rng(seed)
    n = 3000
    dt = np.minimum(rng.uniform(0.05, 0.15, n) * step_s, 0.5 * gap_s)
    t = 1.7e9 + np.cumsum(dt)
    t[n // 2:] += 3.0 * gap_s
    signals = list(model.signals)
    ranges = trained_range(model)
    lo, hi = ranges.get("temperature_c", (20.0, 30.0))
    span = t - t[0]
    period = span[-1] / 3.0
    temp = lo + (hi - lo) * (0.1 + 0.8 * (1.0 - np.abs(2.0 * ((span % period) / period) - 1.0)))
    temp[n // 3] = np.nan
    proxies = _proxies(model)
    prox = np.column_stack([np.full(n, 0.5 * sum(ranges[x])) for x in proxies]) \
        if proxies else None
    cols = {"temperature_c": temp}
    for k, x in enumerate(proxies):
        cols[x] = prox[:, k]  # type: ignore[index]
    s = np.column_stack([cols[x] for x in signals])
    want, _ = stream_relative(model, t, s)
    const = model.constant().detach().cpu().double().numpy()
    raw = np.zeros((n, len(model.outputs)))
    got = run_stream_c(model, header_text, t, temp, raw, prox, prefix=prefix,
                       cflags=("-O2", *REAL_FLAGS[real]))
    worst = judge_step_parity(model, got, raw, want, const, t, temp, real=real, rtol=rtol)
    if not got["flag"][n // 2] or not got["flag"][n // 3]:
        raise ExportError("C header step() parity check failed: flag not set after the gap or "
                          "at the missing temperature")
    return {"n_samples": float(n), "max_abs_diff": worst}
