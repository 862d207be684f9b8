"""The standard errors' two methods (:data:`STDERR_METHODS`) and the second of them: a
moving-block residual bootstrap (Künsch 1989) of least-squares coefficients that does not
assume white residuals — the residuals resampled in contiguous blocks inside each run, each
block :func:`block_length` samples long (twice the residuals' integrated autocorrelation
time, at least :math:`n^{1/3}`), added to the fitted curve and refitted :data:`N_BOOTSTRAP`
times (:func:`block_bootstrap_cov`).  What it is for: :mod:`thermonet.training.parameters`.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["STDERR_METHODS", "N_BOOTSTRAP", "block_length", "block_bootstrap_cov"]

STDERR_METHODS = ("ols", "block-bootstrap")
#: Resamples of the block bootstrap (its stderr carries a relative error of about 1/sqrt(2 B)).
N_BOOTSTRAP = 400


def block_length(resid: np.ndarray) -> int:
    """Samples per bootstrap block: twice the residuals' integrated autocorrelation time
    (``1 + 2 Σ ρ_k``, summed while ρ_k > 0, the largest over axes), at least ``n^(1/3)``,
    at most a quarter of the samples."""
    r = np.asarray(resid, dtype=np.float64)
    r = r.reshape(r.shape[0], -1)
    n = r.shape[0]
    tau = 1.0
    for j in range(r.shape[1]):
        x = r[:, j] - r[:, j].mean()
        f = np.fft.rfft(x, 2 * n)
        acf = np.fft.irfft(f * np.conj(f))[:n]
        if acf[0] <= 0:
            continue
        rho = acf[1:] / acf[0]
        stop = int(np.argmax(rho <= 0)) if np.any(rho <= 0) else rho.size
        tau = max(tau, 1.0 + 2.0 * float(np.sum(rho[:stop])))
    return int(min(max(math.ceil(2.0 * tau), math.ceil(n ** (1.0 / 3.0)), 1), max(n // 4, 1)))


def block_bootstrap_cov(design: np.ndarray, fitted: np.ndarray, resid: np.ndarray,
                        runs: list[int], *, n_boot: int = N_BOOTSTRAP, seed: int = 0,
                        block: int | None = None) -> list[np.ndarray]:
    """Per axis, the covariance of least-squares coefficients under a moving-block residual
    bootstrap (Künsch 1989): residuals resampled in contiguous blocks of ``block`` samples
    (:func:`block_length`) taken inside one run each, added to the fitted values, refitted.

    ``design`` (n, p), ``fitted`` and ``resid`` (n, A); ``runs``: samples per run, in order.
    """
    rng = np.random.default_rng(seed)
    n, a = resid.shape
    length = block or block_length(resid)
    ends = np.cumsum(runs)
    starts_of_run = ends - np.asarray(runs)
    valid = np.concatenate([np.arange(s, e - length + 1) for s, e in
                            zip(starts_of_run, ends, strict=True) if e - s >= length]
                           or [np.arange(0, max(n - length + 1, 1))])
    n_blocks = math.ceil(n / length)
    pinv = np.linalg.pinv(design)                                   # (p, n)
    draws = np.empty((n_boot, design.shape[1], a))
    offsets = np.arange(length)
    for b in range(n_boot):
        idx = (rng.choice(valid, n_blocks)[:, None] + offsets).ravel()[:n]
        draws[b] = pinv @ (fitted + resid[idx])
    return [np.cov(draws[:, :, j], rowvar=False) for j in range(a)]
