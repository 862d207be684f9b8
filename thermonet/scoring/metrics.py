"""The field's own metrics, computed per axis on held-out data.

Every function takes plain numpy arrays and returns Python floats (or numpy
arrays for curves), so results go straight into ``results.json``.  The
metrics follow the four seed studies (``shared/SEEDS.md``):

* study 000: peak-to-peak of 1 °C-binned means (:func:`binned_peak_to_peak`)
  and the scale-factor temperature coefficient in ppm/°C
  (:func:`scale_factor_tempco_ppm_per_c`);
* study 002: Allan-deviation bias stability before/after compensation
  (:func:`allan`, :func:`bias_instability`);
* study 003: mean square deviation against the reference, offset included
  (:func:`msd`).

Conventions used throughout
---------------------------
* ``rms`` is the standard deviation about the mean (offset removed); ``msd``
  and :func:`drift_error_rms` keep the offset.
* The bias instability is the **minimum of the overlapping Allan deviation**
  (the flat floor, in the units of ``y``), *not* IEEE-952's B, which is that
  minimum divided by :data:`IEEE952_FLICKER_FACTOR` (0.664).
* Allan statistics treat the samples as one contiguous series at ``rate_hz``:
  a gap in time (a burst-mode log) simply joins the samples either side.

Every metric of one held-out axis at once, as ``results.json`` reports it:
:mod:`thermonet.scoring.axis_metrics`.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "rms",
    "msd",
    "drift_error_rms",
    "noise_floor",
    "binned_means",
    "binned_peak_to_peak",
    "scale_factor_tempco_ppm_per_c",
    "allan",
    "bias_instability",
    "bias_instability_detail",
    "IEEE952_FLICKER_FACTOR",
    "MIN_ALLAN_SAMPLES",
    "MIN_ALLAN_CLUSTERS",
]

#: Flicker-floor factor: the Allan deviation of flicker (bias-instability)
#: noise of IEEE-952 coefficient B is flat at ``sqrt(2 ln 2 / pi) * B`` ≈ 0.664 B.
IEEE952_FLICKER_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)

#: The longest averaging time used for the bias instability spans at least this
#: many clusters; beyond it the ADEV estimate scatters by tens of percent and a
#: spurious dip would be read as the floor.
MIN_ALLAN_CLUSTERS = 8

#: Fewer samples than this give fewer than three usable averaging times.
MIN_ALLAN_SAMPLES = 4 * MIN_ALLAN_CLUSTERS

# Averaging times per decade for the bias-instability search: denser than
# octaves so the flat floor is not missed between two grid points.
_TAUS_PER_DECADE = 10


def _series(name: str, values: object) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 1:
        raise ValueError(f"'{name}' must be a 1-D series, got shape {arr.shape}")
    return arr


def _same_length(**series: np.ndarray) -> None:
    names = list(series)
    n0 = series[names[0]].shape[0]
    for name in names[1:]:
        if series[name].shape[0] != n0:
            raise ValueError(f"'{name}' has {series[name].shape[0]} samples, "
                             f"'{names[0]}' has {n0}")


def _finite(name: str, arr: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise ValueError(f"'{name}' has a non-finite value {arr[bad[0]]!r} at index {int(bad[0])}")


def _positive_rate(rate_hz: float) -> float:
    rate = float(rate_hz)
    if not math.isfinite(rate) or rate <= 0.0:
        raise ValueError(f"rate_hz must be a positive sample rate in Hz, got {rate_hz!r}")
    return rate


def rms(y: np.ndarray) -> float:
    """Standard deviation of ``y`` about its mean (offset removed).

    .. math:: \\mathrm{rms}(y) = \\sqrt{\\tfrac{1}{n}\\sum_i (y_i - \\bar y)^2}

    Parameters
    ----------
    y : ndarray, shape (n,)
        An error series (e.g. output minus reference), any units.

    Returns
    -------
    float
        In the units of ``y``; ``nan`` for an empty series.
    """
    y = _series("y", y)
    return float(np.std(y)) if y.size else float("nan")


def msd(x: np.ndarray, x_ref: np.ndarray) -> float:
    """Mean square deviation of an output from its reference, offset included.

    Study 003's figure of merit, computed before and after compensation:

    .. math:: \\mathrm{msd} = \\tfrac{1}{n}\\sum_i (x_i - x_{\\mathrm{ref},i})^2
              = \\mathrm{rms}(x - x_{\\mathrm{ref}})^2 + \\overline{(x - x_{\\mathrm{ref}})}^2

    Parameters
    ----------
    x, x_ref : ndarray, shape (n,)
        Sensor output and the reference it should read (same units).

    Returns
    -------
    float
        In the squared units of ``x`` (e.g. (°/s)²); ``nan`` when empty.
    """
    x = _series("x", x)
    x_ref = _series("x_ref", x_ref)
    _same_length(x=x, x_ref=x_ref)
    return float(np.mean((x - x_ref) ** 2)) if x.size else float("nan")


def drift_error_rms(pred: np.ndarray, true: np.ndarray) -> float:
    """Root mean square of the drift-prediction error, offset included.

    .. math:: \\sqrt{\\tfrac{1}{n}\\sum_i (\\hat d_i - d_i)^2}

    Unlike :func:`rms`, a constant offset between predicted and true drift
    counts as error: a model that gets the shape right but the level wrong
    does not compensate the bias.

    Parameters
    ----------
    pred, true : ndarray, shape (n,)
        Predicted and true (simulated) drift, same units.

    Returns
    -------
    float
        In the units of the drift; ``nan`` when empty.
    """
    pred = _series("pred", pred)
    true = _series("true", true)
    _same_length(pred=pred, true=true)
    return float(np.sqrt(np.mean((pred - true) ** 2))) if pred.size else float("nan")


def noise_floor(y: np.ndarray) -> float:
    """White-noise standard deviation per sample, from first differences.

    .. math:: \\sigma_w = \\operatorname{std}(\\Delta y) / \\sqrt{2}

    Differencing removes the slow thermal drift, so this is the floor no
    model can go below on a single sample.  Units: those of ``y``; ``nan``
    for fewer than 3 samples.
    """
    y = np.asarray(y, dtype=np.float64)
    if y.size < 3:
        return float("nan")
    return float(np.std(np.diff(y)) / np.sqrt(2.0))


def binned_means(temperature_c: np.ndarray, y: np.ndarray, bin_c: float = 1.0
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Means of ``y`` in ``bin_c``-wide bins of ``temperature_c``.

    Bin ``k`` covers :math:`[k\\,w, (k+1)\\,w)` with :math:`w` = ``bin_c``;
    only occupied bins are returned.  The binning variable may be any
    temperature proxy (a frequency in Hz, raw counts) with a suitable width.

    Parameters
    ----------
    temperature_c : ndarray, shape (n,)
        Binning variable, °C (or the proxy's units).
    y : ndarray, shape (n,)
        Values to average, any units.
    bin_c : float
        Bin width in the units of ``temperature_c``; must be positive.

    Returns
    -------
    centres : ndarray
        Bin centres, ascending.
    means : ndarray
        Mean of ``y`` in each bin, units of ``y``.
    """
    t = _series("temperature_c", temperature_c)
    y = _series("y", y)
    _same_length(temperature_c=t, y=y)
    _finite("temperature_c", t)
    if not (math.isfinite(bin_c) and bin_c > 0):
        raise ValueError(f"bin width must be positive, got {bin_c!r}")
    idx = np.floor(t / bin_c).astype(np.int64)
    keys, inv = np.unique(idx, return_inverse=True)
    sums = np.bincount(inv, weights=y)
    counts = np.bincount(inv)
    return (keys + 0.5) * bin_c, sums / counts


def binned_peak_to_peak(temperature_c: np.ndarray, y: np.ndarray, bin_c: float = 1.0) -> float:
    """Peak-to-peak of the per-bin means of ``y`` over 1 °C temperature bins.

    Study 000's bias temperature error, the spread of the per-temperature means:

    .. math:: B_{pp} = \\max_k \\bar y_k - \\min_k \\bar y_k

    Units: those of ``y``; ``nan`` for an empty series.
    """
    _, means = binned_means(temperature_c, y, bin_c)
    return float(np.ptp(means)) if means.size else float("nan")


def scale_factor_tempco_ppm_per_c(temperature_c: np.ndarray, k: np.ndarray) -> float:
    """Scale-factor temperature coefficient over per-temperature-point scale factors.

    Study 000's figure of merit:

    .. math:: \\Delta K = \\frac{K_{max} - K_{min}}{|\\bar K|}
              \\cdot \\frac{10^6}{T_{max} - T_{min}}

    The absolute mean keeps the coefficient positive for an axis mounted with
    a negative scale factor.

    Parameters
    ----------
    temperature_c : ndarray, shape (m,)
        Temperature of each test point, °C.
    k : ndarray, shape (m,)
        Scale factor measured at each point (any units, e.g. mA/g or LSB/(°/s)).

    Returns
    -------
    float
        ppm/°C.

    Raises
    ------
    ValueError
        Fewer than two points, mismatched lengths, non-finite values, a zero
        temperature span or a zero mean scale factor.
    """
    t = _series("temperature_c", temperature_c)
    k = _series("k", k)
    _same_length(temperature_c=t, k=k)
    _finite("temperature_c", t)
    _finite("k", k)
    if t.size < 2:
        raise ValueError(f"need at least 2 temperature points for a scale-factor "
                         f"temperature coefficient, got {t.size}")
    span_c = float(np.ptp(t))
    if span_c == 0.0:
        raise ValueError(f"all temperature points are at {t[0]!r} °C: the span is zero")
    k_mean = float(np.mean(k))
    if k_mean == 0.0:
        raise ValueError("the mean scale factor 'k' is zero; a relative change is undefined")
    return float(np.ptp(k) / abs(k_mean) * 1e6 / span_c)


#: Series up to this length get allantools' fully overlapping OADEV at every τ.
ALLAN_EXACT_MAX = 1 << 17
#: Beyond it, the estimate at τ = m/f_s uses every ``max(1, m // ALLAN_OVERLAP)``-th start.
ALLAN_OVERLAP = 8


def _averaging_factors(n_phase: int, rate: float, taus: str | np.ndarray) -> np.ndarray:
    """Averaging factors m (τ = m/f_s) of a tau grid, as :func:`allantools.tau_generator`
    makes them for ``n_phase`` phase points: rounded, ``0 < m < n_phase``, unique, sorted.
    ``"octave"`` (1, 2, 4, … up to the phase length) and arrays are made here; allantools'
    other named grids (``"decade"``, ``"all"``, ``"log10"``) are asked of it."""
    if isinstance(taus, str):
        if taus != "octave":
            import allantools  # 0.3-0.8 s of imports (scipy.stats): only for its other grids

            _, m, _ = allantools.tau_generator(np.zeros(n_phase), rate, taus)
            return np.asarray(m, dtype=np.float64)
        top = int(np.floor(np.log2(n_phase)))
        grid = (1.0 / rate) * np.logspace(0, top, top + 1, base=2.0)
    else:
        grid = np.asarray(taus, dtype=np.float64).reshape(-1)
    m = np.round(grid * rate)
    return np.unique(m[(m < n_phase) & (m > 0)])


def allan(y: np.ndarray, rate_hz: float, taus: str | np.ndarray = "octave"
          ) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of a rate-type (frequency-type) series.

    .. math:: \\sigma^2(\\tau) = \\frac{1}{2 m^2 \\tau_0^2\\, |J|}\\sum_{j \\in J}
              \\left(x_{j+2m} - 2x_{j+m} + x_j\\right)^2,
              \\quad \\tau = m \\tau_0,\\ x = \\tau_0 \\textstyle\\sum y

    Up to :data:`ALLAN_EXACT_MAX` samples this is :func:`allantools.oadev` with
    ``data_type="freq"`` (J: every start, fully overlapping), computed here with
    allantools' own operations in its order — phase = τ0 · cumsum(y − mean) with a leading
    0, ``Σ v²`` by ``np.sum`` — so the two agree exactly (its oracle in
    ``tests/test_eval_layout.py``): importing allantools costs 0.3-0.8 s (it loads
    ``scipy.stats``), more than every Allan deviation of a comparison.  On longer
    series the starts at τ = m τ0 are every ``max(1, m // ALLAN_OVERLAP)``-th
    (stride 1 for m < 8): each τ then costs O(N·8/m), so a log-spaced grid
    costs O(N) in total instead of O(N log N) passes over a series too long
    for the cache; the estimator is unbiased and, with 8 overlapping starts
    per cluster length, keeps nearly all the confidence of full overlap (on
    white noise, 400,000 samples, τ > 1,000 τ0: 10.55 % rms scatter against
    10.45 % fully overlapped).  The samples are taken as one contiguous series at
    ``rate_hz``: a time gap joins the samples either side.

    Parameters
    ----------
    y : ndarray, shape (n,)
        Sensor output or error, e.g. °/s; must be finite.
    rate_hz : float
        Sample rate, Hz.
    taus : {"octave", "decade", "all", "log10"} or ndarray
        Averaging times (s) or allantools' name for a grid.

    Returns
    -------
    taus_s : ndarray
        Averaging times actually used, s.
    adev : ndarray
        Allan deviation, units of ``y``.  Both arrays are empty when the
        series has fewer than 3 samples.
    """
    y = _series("y", y)
    rate = _positive_rate(rate_hz)
    _finite("y", y)
    if y.size < 3:
        # allantools raises an IndexError / UserWarning here; an empty curve is the honest answer.
        return np.empty(0), np.empty(0)
    phase = np.insert(np.cumsum(y - np.mean(y)) * (1.0 / rate), 0, 0.0)
    exact = y.size <= ALLAN_EXACT_MAX
    keep_t, keep_d = [], []
    for m_f in _averaging_factors(phase.size, rate, taus):
        m = int(m_f)
        stride = 1 if exact else max(1, m // ALLAN_OVERLAP)
        n = (phase.size - 2 * m + stride - 1) // stride
        if n < 2:          # allantools drops an estimate from a single difference too
            continue
        v = phase[2 * m::stride][:n] - 2 * phase[m::stride][:n] + phase[:n * stride:stride]
        keep_t.append(m_f / rate)
        keep_d.append(np.sqrt(np.sum(v * v) / (2.0 * n)) / m * rate)
    return np.asarray(keep_t, dtype=np.float64), np.asarray(keep_d, dtype=np.float64)


def bias_instability_detail(y: np.ndarray, rate_hz: float) -> dict[str, float | int | str]:
    """Bias instability as the minimum of the overlapping Allan deviation, with its context.

    Convention: the flat floor of the OADEV curve,

    .. math:: \\sigma_{BI} = \\min_{\\tau} \\sigma(\\tau),
              \\qquad B_{\\mathrm{IEEE\\,952}} = \\sigma_{BI} / 0.664

    searched over ~10 averaging times per decade from one sample up to
    ``n / MIN_ALLAN_CLUSTERS`` samples.  The samples are used as given,
    contiguous at ``rate_hz`` (gaps join); non-finite samples are dropped and
    counted.

    Parameters
    ----------
    y : ndarray, shape (n,)
        Rate-type series (e.g. °/s).
    rate_hz : float
        Sample rate, Hz.

    Returns
    -------
    dict
        ``bias_instability_adev_min`` (units of ``y``; ``nan`` when undefined),
        ``tau_at_min_s`` (s), ``n_samples``, ``n_dropped_nonfinite`` and
        ``reason`` (empty when the floor was found inside the curve; otherwise
        why the value is ``nan`` or only an upper bound).
    """
    y = _series("y", y)
    rate = _positive_rate(rate_hz)
    finite = np.isfinite(y)
    y = y[finite]
    out: dict[str, float | int | str] = {
        "bias_instability_adev_min": float("nan"),
        "tau_at_min_s": float("nan"),
        "n_samples": int(y.size),
        "n_dropped_nonfinite": int((~finite).sum()),
        "reason": "",
    }
    if y.size < MIN_ALLAN_SAMPLES:
        out["reason"] = (f"only {y.size} finite samples; at least {MIN_ALLAN_SAMPLES} "
                         f"are needed for an Allan-deviation floor")
        return out
    m_max = y.size // MIN_ALLAN_CLUSTERS
    n_grid = max(3, int(math.ceil(_TAUS_PER_DECADE * math.log10(m_max))) + 1)
    m = np.unique(np.round(np.logspace(0.0, math.log10(m_max), n_grid)).astype(np.int64))
    taus_s, adev = allan(y, rate, taus=m / rate)
    ok = np.isfinite(adev)
    if not ok.any():
        out["reason"] = "the Allan deviation is undefined at every averaging time"
        return out
    taus_s, adev = taus_s[ok], adev[ok]
    i = int(np.argmin(adev))
    out["bias_instability_adev_min"] = float(adev[i])
    out["tau_at_min_s"] = float(taus_s[i])
    if i == adev.size - 1:
        out["reason"] = (f"the Allan deviation still falls at the longest usable tau "
                         f"({taus_s[i]:.6g} s); the value is an upper bound of the floor")
    return out


def bias_instability(y: np.ndarray, rate_hz: float) -> float:
    """Bias instability: the minimum of the overlapping Allan deviation, units of ``y``.

    .. math:: \\sigma_{BI} = \\min_{\\tau} \\sigma_{\\mathrm{OADEV}}(\\tau)

    This is the flat floor of the curve, not IEEE-952's B (which is
    :math:`\\sigma_{BI} / 0.664`, see :data:`IEEE952_FLICKER_FACTOR`).  Returns
    ``nan`` for a series too short to have a floor; call
    :func:`bias_instability_detail` for the reason and the averaging time.
    """
    return float(bias_instability_detail(y, rate_hz)["bias_instability_adev_min"])
