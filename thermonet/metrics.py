"""The field's own metrics (minimal core; extended by the metrics work)."""

from __future__ import annotations

import numpy as np

__all__ = ["noise_floor", "binned_means", "binned_peak_to_peak"]


def noise_floor(y: np.ndarray) -> float:
    """White-noise standard deviation per sample, from first differences.

    .. math:: \\sigma_w = \\operatorname{std}(\\Delta y) / \\sqrt{2}

    Differencing removes the slow thermal drift, so this is the floor no
    model can go below on a single sample.  Units: those of ``y``.
    """
    y = np.asarray(y, dtype=np.float64)
    if y.size < 3:
        return float("nan")
    return float(np.std(np.diff(y)) / np.sqrt(2.0))


def binned_means(temperature_c: np.ndarray, y: np.ndarray, bin_c: float = 1.0
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Means of ``y`` in ``bin_c``-wide temperature bins (bin centres, means)."""
    t = np.asarray(temperature_c, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    idx = np.floor(t / bin_c).astype(np.int64)
    keys, inv = np.unique(idx, return_inverse=True)
    sums = np.bincount(inv, weights=y)
    counts = np.bincount(inv)
    return (keys + 0.5) * bin_c, sums / counts


def binned_peak_to_peak(temperature_c: np.ndarray, y: np.ndarray, bin_c: float = 1.0) -> float:
    """Peak-to-peak of the per-bin means of ``y`` over 1 °C temperature bins.

    Study 000's bias temperature error, :math:`B_{max} - B_{min}` of the
    per-temperature means.  Units: those of ``y``.
    """
    _, means = binned_means(temperature_c, y, bin_c)
    return float(np.ptp(means)) if means.size else float("nan")
