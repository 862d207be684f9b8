"""The standardisation every family trains in: per-column mean and scale of the training
arrays (shared by the point-wise loop, :mod:`thermonet.training.train`, and the recurrent one,
:mod:`thermonet.training.recurrent`)."""

from __future__ import annotations

import numpy as np

__all__ = ["column_scale"]


def column_scale(a: np.ndarray) -> np.ndarray:
    """Per-column standard deviation of ``a`` (n, k); a constant column (rate on soaks, an
    axis with no drift) keeps unit scale."""
    mean, std = a.mean(axis=0), a.std(axis=0)
    return np.where(std > 1e-12 * np.maximum(1.0, np.abs(mean)), std, 1.0)
