"""One held-out axis before and after compensation, every metric at once: what
``results.json`` reports per axis (:data:`AXIS_METRIC_KEYS`), from the run's samples
(:func:`axis_metrics`) or from its window means over the samples they stand for
(:func:`window_axis_metrics`).  The metrics themselves are :mod:`thermonet.scoring.metrics`'.
"""

from __future__ import annotations

import math

import numpy as np

from .metrics import (  # with the one 1-D series check the metrics use
    _finite,
    _positive_rate,
    _same_length,
    _series,
    bias_instability,
    binned_peak_to_peak,
    drift_error_rms,
    msd,
    noise_floor,
    rms,
)

__all__ = ["AXIS_METRIC_KEYS", "axis_metrics", "window_axis_metrics"]

#: Keys of :func:`axis_metrics` (``drift_error_rms`` only when the true drift is known).
AXIS_METRIC_KEYS = (
    "rms_raw", "rms_comp", "msd_raw", "msd_comp", "pp_raw", "pp_comp",
    "noise_floor", "bias_instability_raw", "bias_instability_comp",
)


def axis_metrics(*, bin_by: np.ndarray, time_s: np.ndarray, raw: np.ndarray,
                 reference: np.ndarray, predicted_drift: np.ndarray,
                 true_drift: np.ndarray | None = None, rate_hz: float | None = None,
                 bin_width: float = 1.0) -> dict[str, float]:
    """Before/after metrics of one axis on a held-out run.

    With :math:`e_{raw} = x - x_{ref}` and
    :math:`e_{comp} = x - \\hat d - x_{ref}`:

    * ``rms_*`` = :func:`rms` (offset removed), ``msd_*`` = :func:`msd`
      (offset included), ``pp_*`` = :func:`binned_peak_to_peak` over
      ``bin_width`` bins of ``bin_by``;
    * ``noise_floor`` = :func:`noise_floor` of :math:`e_{raw}`;
    * ``bias_instability_*`` = :func:`bias_instability` (OADEV minimum);
    * ``drift_error_rms`` = :func:`drift_error_rms` (only if ``true_drift``).

    Parameters
    ----------
    bin_by : ndarray, shape (n,)
        Binning variable for the peak-to-peak: temperature in °C (with
        ``bin_width=1.0``, study 000's convention) or a proxy with its own width.
    time_s : ndarray, shape (n,)
        Sample times, s, non-decreasing.  Used for ``rate_hz`` when it is None.
    raw, reference, predicted_drift : ndarray, shape (n,)
        Sensor output, what it should read, and the model's drift, same units.
    true_drift : ndarray, shape (n,), optional
        Ground-truth drift (simulated data).
    rate_hz : float, optional
        Sample rate for the Allan statistics, Hz; default ``1 / median(Δt)``.
    bin_width : float
        Bin width in the units of ``bin_by``.

    Returns
    -------
    dict[str, float]
        Keys :data:`AXIS_METRIC_KEYS` (+ ``drift_error_rms``); Python floats,
        ``nan`` where undefined (too few samples).

    Raises
    ------
    ValueError
        Mismatched lengths, non-finite inputs, decreasing time or a bad rate.
    """
    arrays = {"bin_by": _series("bin_by", bin_by), "time_s": _series("time_s", time_s),
              "raw": _series("raw", raw), "reference": _series("reference", reference),
              "predicted_drift": _series("predicted_drift", predicted_drift)}
    if true_drift is not None:
        arrays["true_drift"] = _series("true_drift", true_drift)
    _same_length(**arrays)
    for name, arr in arrays.items():
        _finite(name, arr)
    rate = _rate_of(arrays["time_s"], rate_hz)
    e_raw = arrays["raw"] - arrays["reference"]
    e_comp = e_raw - arrays["predicted_drift"]
    zero = np.zeros_like(e_raw)
    b = arrays["bin_by"]
    out = {
        "rms_raw": rms(e_raw),
        "rms_comp": rms(e_comp),
        "msd_raw": msd(e_raw, zero),
        "msd_comp": msd(e_comp, zero),
        "pp_raw": binned_peak_to_peak(b, e_raw, bin_width),
        "pp_comp": binned_peak_to_peak(b, e_comp, bin_width),
        "noise_floor": noise_floor(e_raw),
        "bias_instability_raw": bias_instability(e_raw, rate),
        "bias_instability_comp": bias_instability(e_comp, rate),
    }
    if true_drift is not None:
        out["drift_error_rms"] = drift_error_rms(arrays["predicted_drift"], arrays["true_drift"])
    return {key: float(value) for key, value in out.items()}


def _rate_of(t: np.ndarray, rate_hz: float | None) -> float:
    """``rate_hz`` checked, or ``1 / median(Δt)`` of the non-decreasing times ``t``."""
    dt = np.diff(t)
    if dt.size and (dt < 0).any():
        i = int(np.flatnonzero(dt < 0)[0]) + 1
        raise ValueError(f"'time_s' decreases at index {i} ({t[i - 1]!r} -> {t[i]!r} s)")
    if rate_hz is None:
        positive = dt[dt > 0]
        if positive.size == 0:
            raise ValueError("cannot infer rate_hz: 'time_s' has no positive step; pass rate_hz")
        # The median ignores burst gaps, which would drag a mean interval up.
        rate_hz = 1.0 / float(np.median(positive))
    return _positive_rate(rate_hz)


def window_axis_metrics(*, bin_by: np.ndarray, raw: np.ndarray, predicted_drift: np.ndarray,
                        weight: np.ndarray, within_ss: np.ndarray,
                        within_ss_comp: np.ndarray | None = None,
                        true_drift: np.ndarray | None = None, rate_hz: float,
                        bin_width: float = 1.0) -> dict[str, float]:
    """:func:`axis_metrics` of a held-out run reduced to window means
    (:mod:`thermonet.features.windows`), over the samples the rows stand for.

    Row :math:`k` is the mean :math:`\\bar e_k` of :math:`w_k` samples whose squared
    deviations about it sum to :math:`S_k` (``within_ss``); the residual's, inside a
    row, are ``within_ss_comp`` (:func:`thermonet.training.pipeline.residual_spread`; default
    the raw error's).  With :math:`W = \\sum_k w_k`:

    * ``rms_*`` = :math:`\\sqrt{(\\sum_k w_k (\\bar e_k - \\mu)^2 + S_k) / W}`,
      :math:`\\mu = \\sum_k w_k \\bar e_k / W` — exactly :func:`rms` of the samples
      for the raw error;
    * ``msd_*`` = :math:`(\\sum_k w_k \\bar e_k^2 + S_k) / W`;
    * ``pp_*``: the peak-to-peak of the per-bin means, each row weighing its samples
      (the rows binned by their mean temperature);
    * ``noise_floor``: the pooled spread inside the windows,
      :math:`\\sqrt{\\sum_k S_k / \\sum_k (w_k - 1)}` — for white noise the same
      :math:`\\sigma_w` that :func:`noise_floor` estimates from first differences (which
      it is where every window holds one sample);
    * ``bias_instability_*``: :func:`bias_instability` of the row means at the rows'
      rate (averaging times from one window up);
    * ``drift_error_rms``: weighted over the rows.
    """
    e_raw = _series("raw", raw)
    pred = _series("predicted_drift", predicted_drift)
    w = _series("weight", weight)
    s = _series("within_ss", within_ss)
    b = _series("bin_by", bin_by)
    _same_length(raw=e_raw, predicted_drift=pred, weight=w, within_ss=s, bin_by=b)
    for name, arr in (("raw", e_raw), ("predicted_drift", pred), ("weight", w),
                      ("within_ss", s), ("bin_by", b)):
        _finite(name, arr)
    e_comp = e_raw - pred
    total = float(w.sum())
    within = float(s.sum())
    s_comp = s if within_ss_comp is None else _series("within_ss_comp", within_ss_comp)
    _same_length(raw=e_raw, within_ss_comp=s_comp)
    _finite("within_ss_comp", s_comp)
    within_comp = float(s_comp.sum())

    def spread(e: np.ndarray, inside: float) -> float:
        if total <= 0:
            return float("nan")
        mu = float((w * e).sum()) / total
        return math.sqrt(max(float((w * (e - mu) ** 2).sum()) + inside, 0.0) / total)

    def mean_square(e: np.ndarray, inside: float) -> float:
        return (float((w * e * e).sum()) + inside) / total if total > 0 else float("nan")

    def pp(e: np.ndarray) -> float:
        if not e.size:
            return float("nan")
        idx = np.floor(b / bin_width).astype(np.int64)
        _, inv = np.unique(idx, return_inverse=True)
        means = np.bincount(inv, weights=w * e) / np.bincount(inv, weights=w)
        return float(np.ptp(means))

    dof = float(np.clip(w - 1.0, 0.0, None).sum())
    rate = _positive_rate(rate_hz)
    out = {"rms_raw": spread(e_raw, within), "rms_comp": spread(e_comp, within_comp),
           "msd_raw": mean_square(e_raw, within), "msd_comp": mean_square(e_comp, within_comp),
           "pp_raw": pp(e_raw), "pp_comp": pp(e_comp),
           # rows of one sample each (a log slower than the windows): the samples' own
           "noise_floor": math.sqrt(within / dof) if dof > 0 else noise_floor(e_raw),
           "bias_instability_raw": bias_instability(e_raw, rate),
           "bias_instability_comp": bias_instability(e_comp, rate)}
    if true_drift is not None:
        true = _series("true_drift", true_drift)
        _same_length(raw=e_raw, true_drift=true)
        out["drift_error_rms"] = math.sqrt(float((w * (pred - true) ** 2).sum()) / total) \
            if total > 0 else float("nan")
    return out
