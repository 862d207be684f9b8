"""The residual-drift band in the C header (:mod:`thermonet.scoring.band`): its tables as
constants, ``<prefix>_band(x, out)`` evaluating them as :meth:`~thermonet.scoring.band.Band.
evaluate` does (float: a bound needs no double), ``<prefix>_band_signal(st, temperature_c)``
giving its ``x`` after a step (the step's delayed temperature for a model on one, which the
thermometer does not give), and the numbers a navigation filter can use —
per axis the residual bias bound and its rate of change with the band's signal
(``<prefix>_band_bias_bound``, ``<prefix>_band_bias_rate``; configs/README.md, "The
residual-drift band").  :func:`check_band_c` compiles it and compares it with Python."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..core.errors import ExportError
from ..core.names import c_comment
from ..models.cgen import c_float
from ..scoring.band import Band, evaluate_tables
from ..scoring.band_rates import outside_holds
from .c_driver import c_compiler, run_c_driver

__all__ = ["render_band_c", "insert_band", "check_band_c", "BAND_DRIVER", "HOLDS_DRIVER"]

BAND_DRIVER = r"""
#include <stdio.h>
#include "model.h"
/* in: int n, then n floats x; out: per x PFX_N_AXES floats, the band */
int main(int argc, char **argv) {
    FILE *in, *out;
    int n, i;
    if (argc < 3) return 2;
    in = fopen(argv[1], "rb");
    out = fopen(argv[2], "wb");
    if (!in || !out || fread(&n, sizeof n, 1, in) != 1) return 3;
    for (i = 0; i < n; ++i) {
        float x, b[PFX_N_AXES];
        if (fread(&x, sizeof x, 1, in) != 1) return 4;
        pfx_band(x, b);
        fwrite(b, sizeof(float), PFX_N_AXES, out);
    }
    fclose(in);
    fclose(out);
    return 0;
}
"""


HOLDS_DRIVER = r"""
#include <stdio.h>
#include "model.h"
/* in: int n, then n (float rate, int direction); out: n ints, pfx_band_holds */
int main(int argc, char **argv) {
    FILE *in, *out;
    int n, i, d, h;
    float r;
    if (argc < 3) return 2;
    in = fopen(argv[1], "rb");
    out = fopen(argv[2], "wb");
    if (!in || !out || fread(&n, sizeof n, 1, in) != 1) return 3;
    for (i = 0; i < n; ++i) {
        if (fread(&r, sizeof r, 1, in) != 1 || fread(&d, sizeof d, 1, in) != 1) return 4;
        h = pfx_band_holds(r, d);
        fwrite(&h, sizeof h, 1, out);
    }
    fclose(in);
    fclose(out);
    return 0;
}
"""


def _floats(xs: Sequence[float]) -> str:
    return "{" + ", ".join(c_float(float(x)) for x in xs) + "}"


def render_band_c(band: Mapping[str, Any], prefix: str, outputs: Sequence[str],
                  signals: Sequence[str], dynamic: Sequence[Any] | None = None) -> list[str]:
    """The header lines of ``band`` (:func:`thermonet.scoring.band.shipped_band`).

    ``dynamic``: the header's streaming form's dynamic inputs
    (:func:`thermonet.features.dynamics.dynamic_signals`, in the order of its
    ``<prefix>_dyn_*`` arrays), given when the header has ``<prefix>_state``: then
    ``<prefix>_band_signal`` (:func:`_signal_lines`); None: a bare header without one."""
    b = Band.from_json(band)
    if sorted(b.axes) != sorted(outputs) or b.signal not in signals:
        raise ExportError(f"the band's axes {list(b.axes)} / signal {b.signal!r} do not match "
                          f"the model's outputs {list(outputs)} / signals {list(signals)}")
    b.axes = {a: b.axes[a] for a in outputs}      # the header's axis order
    p, P = prefix, prefix.upper()
    kmax = max(len(t.half) for t in b.axes.values())
    edges = [t.edges + [t.edges[-1]] * (kmax + 1 - len(t.edges)) for t in b.axes.values()]
    half = [t.half + [t.half[-1]] * (kmax - len(t.half)) for t in b.axes.values()]
    nums = b.filter_numbers()
    rows = lambda m: "{" + ", ".join(_floats(r) for r in m) + "}"  # noqa: E731
    accessor = _signal_lines(b.signal, p, dynamic)
    arg = ([] if dynamic is None else
           [" * x: that proxy's value, as given to the step."] if not accessor else
           [f" * x: the temperature ({p}_band_signal(st, temperature_c) after {p}_step(): the",
            " * same)."] if b.signal == "temperature_c" else
           [f" * x: {p}_band_signal(st, temperature_c) after {p}_step(): the step's value of",
            " * this signal, which the thermometer does not give (not temperature_c)."])
    return [
        f"/* Residual-drift band (thermonet.scoring.band): a {b.window_s:g} s window mean of the",
        f" * corrected output's residual lies within +-{p}_band() of the run's mean residual for",
        f" * {b.level:.0%} of windows on runs like the training runs (drift only: not noise, shocks,",
        " * aging or a run's constant offset); piecewise constant over bins of the signal",
        f" * {c_comment(b.signal)}, growing linearly past the trained range. Output units.",
        *arg,
        " */",
        f"#define {P}_BAND_LEVEL {c_float(b.level)}",
        f"#define {P}_BAND_SIGNAL_INDEX {list(signals).index(b.signal)}",
        f"#define {P}_BAND_MAX_BINS {kmax}",
        f"static const int {p}_band_bins[{P}_N_AXES] = "
        + "{" + ", ".join(str(len(t.half)) for t in b.axes.values()) + "};",
        f"static const float {p}_band_edges[{P}_N_AXES][{P}_BAND_MAX_BINS + 1] = {rows(edges)};",
        f"static const float {p}_band_half[{P}_N_AXES][{P}_BAND_MAX_BINS] = {rows(half)};",
        f"static const float {p}_band_grow_below[{P}_N_AXES] = "
        f"{_floats([t.grow_lo for t in b.axes.values()])};",
        f"static const float {p}_band_grow_above[{P}_N_AXES] = "
        f"{_floats([t.grow_hi for t in b.axes.values()])};",
        "/* For a navigation filter: per axis the residual bias bound (largest in-range half-width,",
        " * output unit) and its rate of change with the signal (output unit per signal unit):",
        " * see configs/README.md for the EKF noise settings they suggest. */",
        f"static const float {p}_band_bias_bound[{P}_N_AXES] = "
        f"{_floats([v['bound'] for v in nums.values()])};",
        f"static const float {p}_band_bias_rate[{P}_N_AXES] = "
        f"{_floats([v['rate'] for v in nums.values()])};",
        "",
        f"static inline void {p}_band(float x, float out[{P}_N_AXES])",
        "{",
        "    int a, k;",
        "    float d;",
        "    (void)a; (void)k; (void)d;",
        "    if (!(x - x == 0.0f)) {   /* NaN or inf in, NaN out */",
        f"        for (a = 0; a < {P}_N_AXES; ++a) out[a] = x - x;",
        "        return;",
        "    }",
        *_group_lines(b, p),
        "}",
        *accessor,
        *_holds_lines(b, p),
    ]


#: The step's value of each kind of dynamic input from the state (``v``: its ``x[j]``, ``c``:
#: its constant; ``st->temp_prev``: the temperature just stepped) — the same expression as
#: :func:`.c_stream_render.render_stream_c`'s, so the same float.
_FROM_STATE = {"rate": "60.0f * v / c", "lag": "v", "play": "st->temp_prev - v",
               "delayed": "st->temp_prev - v"}


def _signal_lines(signal: str, p: str, dynamic: Sequence[Any] | None) -> list[str]:
    """``<prefix>_band_signal(st, temperature_c)``: the ``x`` to give ``<prefix>_band`` for
    the sample just stepped — the temperature itself where the band is on it, the dynamic
    input ``step`` computed (the delayed temperature of ``cubic-delayed-2min``: the band's
    signal is the model's first, :func:`thermonet.scoring.band.band_from_oof`) read back from
    the state where it is on one, as ``step`` computed it (bit for bit).  Nothing for a band
    on a proxy (the firmware has it: ``proxies[k]``) or a header without a state."""
    if dynamic is None:
        return []
    dyn = {d.signal: (j, d) for j, d in enumerate(dynamic)}
    head = [
        "",
        f"/* The x to give {p}_band() for the sample just given to {p}_step(st, time,",
        " * temperature_c, ...) (a step that returned 0): the band's signal "
        f"{c_comment(signal)}, as",
    ]
    sig = f"static inline float {p}_band_signal(const {p}_state *st, float temperature_c)"
    if signal == "temperature_c":
        return [*head, " * the step read it: temperature_c itself. */", sig, "{",
                "    (void)st;", "    return temperature_c;", "}"]
    if signal not in dyn:
        return []
    j, d = dyn[signal]
    return [*head,
            f" * the step computed it from time and temperature ({d.kind}, "
            f"{c_comment(d.param_key)} {d.param:g}),",
            " * read back from st; NaN for a non-finite temperature_c (the step's drift is",
            " * NaN there too) or before the first step. */",
            sig, "{",
            f"    const float v = st->x[{j}]" + (f", c = {p}_dyn_param[{j}];" if d.kind == "rate"
                                              else ";"),
            "    if (!(temperature_c - temperature_c == 0.0f) || !st->started) return NAN;",
            f"    return {_FROM_STATE[d.kind]};", "}"]


def _holds_lines(b: Band, p: str) -> list[str]:
    """``<prefix>_band_holds(rate, direction)``: where the band states its level
    (:attr:`Band.holds_for`, :func:`~thermonet.scoring.band_rates.outside_holds`'s rule);
    nothing for a band that does not record it."""
    if not b.holds_for:
        return []
    P = p.upper()
    top = {k: -1.0 if v is None else v for k, v in b.holds_for.items()}
    return [
        "",
        "/* Where the band holds (configs/README.md, \"The residual-drift band\"): its level was",
        " * judged on windows whose temperature moved at most this fast (deg C/min: a window's",
        " * least-squares slope over the band's window) in the direction of their excursion",
        " * (heating: the temperature rising since its last turn, the soak after a turn counted",
        " * with the leg that ends there); negative: never judged in that direction, the band",
        " * states nothing there.  A faster ramp or the other direction is outside it. */",
        f"#define {P}_BAND_HOLDS_HEATING_C_PER_MIN {c_float(top.get('heating', -1.0))}",
        f"#define {P}_BAND_HOLDS_COOLING_C_PER_MIN {c_float(top.get('cooling', -1.0))}",
        "",
        "/* 1 where the band holds for a window of this rate (deg C/min) and direction (+1",
        " * heating, -1 cooling, 0 a temperature that never moved), else 0 (also for any other",
        " * direction, and for a rate that is not finite: NaN, an unknown rate, or inf). */",
        f"static inline int {p}_band_holds(float rate_c_per_min, int direction)",
        "{",
        "    float top, r;",
        "    if (!(rate_c_per_min - rate_c_per_min == 0.0f)) return 0;   /* NaN or inf */",
        "    if (direction == 0) return 1;",
        "    if (direction != 1 && direction != -1) return 0;",
        f"    top = direction == 1 ? {P}_BAND_HOLDS_HEATING_C_PER_MIN"
        f" : {P}_BAND_HOLDS_COOLING_C_PER_MIN;",
        "    if (top < 0.0f) return 0;",
        "    r = rate_c_per_min < 0.0f ? -rate_c_per_min : rate_c_per_min;",
        "    return !(r > top);",
        "}",
    ]


def _group_lines(b: Any, p: str) -> list[str]:
    """The evaluation, one bin search per group of axes that share their edges (a family's
    axes do: the same windows), the edges as literals; then per axis one table load."""
    groups: dict[tuple[float, ...], list[int]] = {}
    for a, t in enumerate(b.axes.values()):
        groups.setdefault(tuple(float(np.float32(e)) for e in t.edges), []).append(a)
    lines: list[str] = []
    for edges, axes in groups.items():
        e0, en, inner = c_float(edges[0]), c_float(edges[-1]), edges[1:-1]
        nb = len(edges) - 1
        lines += [f"    /* axes {', '.join(str(a) for a in axes)}: {nb} bin(s) */",
                  f"    if (x < {e0}) {{", f"        d = {e0} - x;"]
        lines += [f"        out[{a}] = {p}_band_half[{a}][0] + {p}_band_grow_below[{a}] * d;"
                  for a in axes]
        lines += [f"    }} else if (x > {en}) {{", f"        d = x - {en};"]
        lines += [f"        out[{a}] = {p}_band_half[{a}][{nb - 1}] + "
                  f"{p}_band_grow_above[{a}] * d;" for a in axes]
        lines += ["    } else {",
                  "        k = " + (" + ".join(f"(x >= {c_float(e)})" for e in inner)
                                   if inner else "0") + ";"]
        lines += [f"        out[{a}] = {p}_band_half[{a}][k];" for a in axes]
        lines += ["    }"]
    return lines


def insert_band(text: str, band: Mapping[str, Any], prefix: str, outputs: Sequence[str],
                signals: Sequence[str], dynamic: Sequence[Any] | None = None) -> str:
    """``text`` (a header) with the band's lines before its closing include guard
    (``dynamic``: :func:`render_band_c`'s)."""
    end = f"#endif /* {prefix.upper()}_MODEL_H */"
    if end not in text:
        raise ExportError("the header has no include guard to close the band before")
    lines = "\n".join(render_band_c(band, prefix, outputs, signals, dynamic))
    head, _, tail = text.rpartition(end)
    return head + lines + "\n\n" + end + tail


def _header_axes(text: str, prefix: str) -> list[str] | None:
    """The axis names the header lists (``<PREFIX>_AXIS_NAMES``)."""
    import re

    m = re.search(rf"#define {prefix.upper()}_AXIS_NAMES \{{(.*)\}}", text)
    return None if m is None else re.findall(r'"((?:[^"\\]|\\.)*)"', m.group(1))


def check_band_c(band: Mapping[str, Any], text: str, prefix: str, *, seed: int = 0
                 ) -> float | None:
    """Compile ``text`` and compare ``<prefix>_band`` with Python's evaluation on points
    inside, at the edges of and past every axis's bins (and NaN); returns the largest relative
    difference (None without a C compiler).  Tolerance: float32 rounding of the tables and
    the arithmetic (1e-5 relative)."""
    cc = c_compiler()
    if cc is None:
        return None
    b = Band.from_json(band)
    order = _header_axes(text, prefix) or list(b.axes)
    b.axes = {a: b.axes[a] for a in order}
    pts = []
    for t in b.axes.values():
        span = t.edges[-1] - t.edges[0]
        pts += list(t.edges) + list(np.linspace(t.edges[0] - 0.5 * span,
                                                t.edges[-1] + 0.5 * span, 41))
    rng = np.random.default_rng(seed)
    lo = min(t.edges[0] for t in b.axes.values())
    hi = max(t.edges[-1] for t in b.axes.values())
    pts += list(rng.uniform(lo - 10, hi + 10, 64)) + [float("nan")]
    x = np.asarray(pts, dtype=np.float32)
    rows = np.zeros(x.size, dtype=[("x", np.float32)])
    rows["x"] = x
    out = run_c_driver(cc, text, BAND_DRIVER, rows, [("b", np.float32, len(b.axes))],
                       prefix=prefix, cflags=("-O2",), header="the C header's band",
                       driver_name="the C band driver")["b"].astype(np.float64)
    # Python's rule on the header's float32 tables (an edge rounded to float decides a bin)

    f32 = lambda v: np.asarray(v, dtype=np.float32).astype(np.float64)  # noqa: E731
    want = np.stack([evaluate_tables(x.astype(np.float64), f32(t.edges), f32(t.half),
                                     float(f32(t.grow_lo)), float(f32(t.grow_hi)))
                     for t in b.axes.values()], axis=1)
    nan = np.isnan(want)
    if not np.array_equal(nan, np.isnan(out)):
        raise ExportError("C band: NaN where Python has a value (or the reverse)")
    rel = np.abs(out[~nan] - want[~nan]) / np.maximum(np.abs(want[~nan]), 1e-30)
    worst = float(rel.max()) if rel.size else 0.0
    if worst > 1e-5:
        raise ExportError(f"C band differs from Python by {worst:.3g} (relative)")
    if b.holds_for:
        _check_holds_c(cc, b, text, prefix)
    return worst


def _check_holds_c(cc: str, b: Band, text: str, prefix: str) -> None:
    """``<prefix>_band_holds`` against :func:`~thermonet.scoring.band_rates.outside_holds` on
    rates either side of each judged rate (at its float32 value, and a float32 step past it),
    both signs, NaN and ±inf (never held), and every direction: exactly equal (a comparison,
    no arithmetic)."""
    tops = [float(np.float32(v)) for v in b.holds_for.values() if v is not None] + [1.0]
    rates = [0.0, float("nan"), float("inf")]
    for t in tops:
        rates += [t, float(np.nextafter(np.float32(t), np.float32(np.inf))), t / 2, 2 * t]
    rates += [-r for r in rates]
    rows = np.zeros(3 * len(rates), dtype=[("r", np.float32), ("d", np.int32)])
    rows["r"] = np.tile(np.asarray(rates, dtype=np.float32), 3)
    rows["d"] = np.repeat(np.array([-1, 0, 1], dtype=np.int32), len(rates))
    extra = np.zeros(4, dtype=rows.dtype)            # directions that are none of the three
    extra["r"], extra["d"] = 0.0, [2, -2, 7, -1000]
    rows = np.concatenate([rows, extra])
    got = run_c_driver(cc, text, HOLDS_DRIVER, rows, np.int32, prefix=prefix,
                       header="the C header's band", driver_name="the C band-holds driver")
    held = {k: None if v is None else float(np.float32(v)) for k, v in b.holds_for.items()}
    want = ~outside_holds(held, rows["r"].astype(np.float64), rows["d"])
    if not np.array_equal(got.astype(bool), want):
        i = int(np.flatnonzero(got.astype(bool) != want)[0])
        raise ExportError(f"C band_holds differs from Python at rate {rows['r'][i]:g} °C/min, "
                          f"direction {rows['d'][i]}")
