"""The C header's streaming form run and checked on the host: ``<prefix>_step`` (and
``<prefix>_step_block``) compiled with a driver that runs it over a sequence
(:data:`STREAM_DRIVER`, :data:`STREAM_BLOCK_DRIVER`, :func:`run_stream_c`), the export's parity
check of it against torch on a synthetic sequence with a gap and a missing temperature
(:func:`check_stream`, :func:`judge_step_parity`), on the header's double or float path
(:data:`REAL_FLAGS`; the float path's extra error: :func:`float_path_slack`).  The C text
itself and its interface: :mod:`thermonet.exporting.c_stream_render`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import ExportError
from ..features import dynamics
from .c_driver import c_compiler, run_c_driver
from .c_stream_render import _proxies

if TYPE_CHECKING:
    from ..models.composite import DriftModels

__all__ = ["STREAM_DRIVER", "STREAM_BLOCK_DRIVER",
           "run_stream_c", "check_stream", "REAL_FLAGS", "float_path_slack", "judge_step_parity"]

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


def run_stream_c(model: DriftModels, header_text: str, time_s: np.ndarray,
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


def check_stream(model: DriftModels, header_text: str, *, prefix: str = "thermonet",
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


def judge_step_parity(model: DriftModels, got: dict[str, np.ndarray], raw: np.ndarray,
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
