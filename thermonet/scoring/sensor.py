"""Metrics of a full sensor model (``model: sensor``) on a held-out run.

Per soak (a settled stretch of steady temperature, found as
:func:`thermonet.sim.fourpos.four_position_estimates` finds it) the triad's output is
regressed on its reference vectors, :math:`y = M x + b` (study 000's per-soak K0, K1,
generalised to a 3 × 3 M), once on the raw output and once on the compensated one.  From
the per-soak M:

``sf_ppm_per_c_raw`` / ``sf_ppm_per_c_comp``
    study 000's scale-factor temperature coefficient of the diagonal element,
    :math:`\\Delta K = (K_{max} - K_{min}) / \\bar K \\cdot 10^6 / (T_{max} - T_{min})`
    (:func:`~thermonet.scoring.metrics.scale_factor_tempco_ppm_per_c`);
``misalignment_mrad_raw`` / ``_comp`` and ``misalignment_spread_mrad_raw`` / ``_comp``
    per off-diagonal element :math:`M_{ij}` (the sensitivity of axis i to input j,
    radians for small angles): its mean over the soaks and its peak-to-peak over them, in
    mrad (the spread is what temperature does to the misalignment).

And over every held-out sample: ``residual_rms_raw`` (raw − reference), ``residual_rms_comp``
(compensated − reference) and ``residual_rms_bias_only`` (the bias-only model's
compensated − reference), in the output's units; ``ratio_vs_raw`` and ``ratio_vs_bias``
with their paired block-bootstrap verdicts (:mod:`thermonet.scoring.verdicts`, the same
blocks and draws as every bias model's verdict).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .metrics import rms, scale_factor_tempco_ppm_per_c
from .verdicts import block_labels, block_stats, draws, ratio_interval, verdict_of

__all__ = ["soak_matrices", "triad_metrics", "residual_verdicts"]


def _soaks(time_s: np.ndarray, temp: np.ndarray, *, max_rate_c_per_h: float, window_s: float,
           settle_s: float) -> list[np.ndarray]:
    """Boolean masks of the settled soaks (smoothed rate below ``max_rate_c_per_h``)."""
    dt = float(np.median(np.diff(time_s)))
    w = min(max(3, int(round(window_s / dt))), len(time_s))
    smooth = np.convolve(temp, np.ones(w) / w, mode="same")
    rate = np.abs(np.gradient(smooth, time_s)) * 3600.0
    half = w // 2
    rate[:half] = rate[half]
    rate[-half:] = rate[-half - 1]
    d = np.diff(np.r_[0, (rate < max_rate_c_per_h).astype(np.int8), 0])
    out = []
    for i0, i1 in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=False):
        m = np.zeros(time_s.size, dtype=bool)
        m[i0:i1] = True
        m &= time_s >= time_s[i0] + settle_s
        out.append(m)
    return out


def soak_matrices(time_s: np.ndarray, temperature_c: np.ndarray, y: np.ndarray,
                  ref: np.ndarray, *, max_rate_c_per_h: float = 1.0, window_s: float = 600.0,
                  settle_s: float = 600.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per settled soak whose references span every direction: temperature (G,), bias (G, k)
    and M (G, k, k) of :math:`y = M x + b` by least squares (``y``, ``ref`` (n, k))."""
    t = np.asarray(time_s, dtype=np.float64)
    temp = np.asarray(temperature_c, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    x = np.asarray(ref, dtype=np.float64)
    k = x.shape[1]
    temps, bs, ms = [], [], []
    for m in _soaks(t, temp, max_rate_c_per_h=max_rate_c_per_h, window_s=window_s,
                    settle_s=settle_s):
        xs = x[m]
        if xs.shape[0] < 3 * (k + 1):
            continue
        sv = np.linalg.svd(xs - xs.mean(axis=0), compute_uv=False)
        if not sv[0] > 0 or np.sum(sv > 1e-3 * sv[0]) < k:
            continue
        coef, *_ = np.linalg.lstsq(np.c_[xs, np.ones(xs.shape[0])], y[m], rcond=None)
        temps.append(float(temp[m].mean()))
        bs.append(coef[k])
        ms.append(coef[:k].T)
    return np.asarray(temps), np.asarray(bs).reshape(-1, k), np.asarray(ms).reshape(-1, k, k)


def triad_metrics(axes: Sequence[str], temps: np.ndarray, m_raw: np.ndarray,
                  m_comp: np.ndarray) -> dict[str, dict[str, float]]:
    """Per axis: scale-factor tempco (ppm/°C) raw and compensated; per off-diagonal element
    ``<row>-><col>`` (e.g. ``acc_x<-acc_y``): misalignment and its spread (mrad).

    Needs two soaks or more (else the dict is empty: the tempco is not defined)."""
    out: dict[str, dict[str, float]] = {}
    if temps.size < 2:
        return out
    for i, a in enumerate(axes):
        out[a] = {"sf_ppm_per_c_raw": scale_factor_tempco_ppm_per_c(temps, m_raw[:, i, i]),
                  "sf_ppm_per_c_comp": scale_factor_tempco_ppm_per_c(temps, m_comp[:, i, i]),
                  "n_soaks": float(temps.size)}
        for j, b in enumerate(axes):
            if i == j:
                continue
            raw, comp = m_raw[:, i, j] * 1e3, m_comp[:, i, j] * 1e3
            out[f"{a}<-{b}"] = {"misalignment_mrad_raw": float(raw.mean()),
                                "misalignment_mrad_comp": float(comp.mean()),
                                "misalignment_spread_mrad_raw": float(np.ptp(raw)),
                                "misalignment_spread_mrad_comp": float(np.ptp(comp))}
    return out


def residual_verdicts(axes: Sequence[str], time_s: np.ndarray, raw_err: np.ndarray,
                      comp_err: np.ndarray, bias_err: np.ndarray) -> dict[str, dict[str, Any]]:
    """Per axis: RMS residuals (raw, sensor model, bias-only) and the paired block-bootstrap
    ratios and verdicts of the sensor model against raw and against the bias-only model.

    The ratios are of the offset-free block scores (each block's error about the held-out
    set's mean, :func:`~thermonet.scoring.verdicts.block_stats`), as for bias models."""
    labels = block_labels(np.asarray(time_s, dtype=np.float64))
    vs_raw = block_stats(raw_err, raw_err - comp_err, labels)
    vs_bias = block_stats(bias_err, bias_err - comp_err, labels)
    counts = draws(vs_raw.n.size)
    r_raw, _, i_raw = ratio_interval(vs_raw.ss_comp, vs_raw.ss_raw, counts)
    r_bias, _, i_bias = ratio_interval(vs_bias.ss_comp, vs_bias.ss_raw, counts)
    out: dict[str, dict[str, Any]] = {}
    for j, a in enumerate(axes):
        out[a] = {"residual_rms_raw": rms(raw_err[:, j]), "residual_rms_comp": rms(comp_err[:, j]),
                  "residual_rms_bias_only": rms(bias_err[:, j]),
                  "ratio_vs_raw": float(r_raw[j]), "ci_vs_raw": [float(v) for v in i_raw[:, j]],
                  "verdict_vs_raw": verdict_of(float(i_raw[0, j]), float(i_raw[1, j])),
                  "ratio_vs_bias": float(r_bias[j]),
                  "ci_vs_bias": [float(v) for v in i_bias[:, j]],
                  "verdict_vs_bias": verdict_of(float(i_bias[0, j]), float(i_bias[1, j]))}
    return out
