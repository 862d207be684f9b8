"""The RBF family's fits in closed form (:mod:`thermonet.models.rbf`), in numpy: the placed
centres of ``init="quantiles"`` (:func:`quantile_centres`), the Gaussian design and the kernel
between the centres (:func:`design`), the penalised least squares of the polynomial tail
(:func:`penalised`), every ridge of every width at once (:func:`ridge_path`,
:func:`ridge_paths`) and the inner cross-validation's purged blocked folds
(:func:`inner_folds`) that ``ridge: cv`` chooses the width and each axis's ridge by.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from .base import TINY

__all__ = ["RIDGE_GRID", "WIDTH_GRID", "INNER_FOLDS", "INNER_BLOCKS", "quantile_centres",
           "distinct_rows", "design", "penalised", "ridge_path", "ridge_paths", "inner_folds"]

#: relative ridge strengths tried by ``ridge: cv`` (× tr(ΦᵀΦ)/J); ∞ is the tail alone
RIDGE_GRID = (1e-6, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0, math.inf)
#: width multipliers tried by ``ridge: cv`` (× width_scale × median nearest-centre distance)
WIDTH_GRID = (0.5, 1.0, 2.0)
INNER_FOLDS, INNER_BLOCKS = 5, 40
#: jitter on the kernel's diagonal before its Cholesky factor (relative; K's diagonal is 1)
_JITTER = 1e-9


def quantile_centres(x: np.ndarray, n: int) -> np.ndarray:
    """``init="quantiles"``'s ``n`` centres of the (N, F) inputs ``x``.

    The first input's values at the ``n`` quantiles (k + ½)/n — where the data are, as
    k-means puts them on one variable — kept at least half an even grid step (its span /
    (2 (n − 1))) apart, so that a temperature the recording dwelt at (a soak, a coarse
    thermometer's one reading) holds one centre, not several on top of each other: a
    forward sweep pushes each centre up to that spacing from the one below, a backward
    sweep pulls it back under the maximum.  Each other input is linearly interpolated along
    the samples sorted by the first (a stable sort: the result depends on the data alone).
    Distinct centres whenever the first input varies."""
    x = np.asarray(x, dtype=np.float64)
    order = np.argsort(x[:, 0], kind="stable")
    first = x[order, 0]
    lo, hi = float(first[0]), float(first[-1])
    at = np.quantile(first, (np.arange(n) + 0.5) / n)
    if n > 1:
        gap = (hi - lo) / (2 * (n - 1))
        for k in range(1, n):
            at[k] = max(at[k], at[k - 1] + gap)
        at[-1] = min(at[-1], hi)
        for k in range(n - 2, -1, -1):
            at[k] = min(at[k], at[k + 1] - gap)
    out = np.empty((n, x.shape[1]))
    out[:, 0] = at
    for j in range(1, x.shape[1]):
        out[:, j] = np.interp(at, first, x[order, j])
    return out


def distinct_rows(a: np.ndarray) -> int:
    """How many distinct rows the (N, F) array of whole numbers ``a`` holds: what
    ``np.unique(a, axis=0).shape[0]`` counts, by one lexicographic sort of the rows (a
    tenth of its time: no structured view)."""
    if a.shape[0] == 0:
        return 0
    k = a[np.lexsort(a.T[::-1])]
    return 1 + int(np.count_nonzero(np.any(k[1:] != k[:-1], axis=1)))


def gaussian(x: np.ndarray, centres: np.ndarray, sigma: float) -> np.ndarray:
    d2 = ((x[:, None, :] - centres[None, :, :]) ** 2).sum(axis=-1)
    return np.exp(-d2 / (2.0 * sigma * sigma))


def design(x: np.ndarray, centres: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Φ (N, J) of every row, and the Cholesky factor L of the kernel between centres
    (K = L Lᵀ, jittered: wᵀKw = ‖Lᵀw‖²) — what every fold and ridge of one width shares."""
    k = gaussian(centres, centres, sigma) + _JITTER * np.eye(centres.shape[0])
    return gaussian(x, centres, sigma), np.linalg.cholesky(k)


def penalised(phi_all: np.ndarray, chol: np.ndarray, poly: np.ndarray, y: np.ndarray,
               lam: float, rows: np.ndarray | None
               ) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
    """Coefficients [w; t; b] of min ‖Φw + Pt − y‖² + λ' wᵀKw on ``rows`` (all if None), λ'
    = λ·tr(ΦᵀΦ)/J, and a scorer: validation rows → per-axis mean squared error."""
    r = slice(None) if rows is None else rows
    phi, p, yy = phi_all[r], poly[r], y[r]
    n_c = chol.shape[0]
    if math.isinf(lam):  # the tail alone
        c_p = np.linalg.lstsq(p, yy, rcond=None)[0]
        coef = np.vstack([np.zeros((n_c, y.shape[1])), c_p])
    else:
        lam_abs = lam * max(float((phi * phi).sum()) / n_c, TINY)
        design = np.vstack([np.hstack([phi, p]),
                            np.hstack([math.sqrt(lam_abs) * chol.T,
                                       np.zeros((n_c, p.shape[1]))])])
        target = np.vstack([yy, np.zeros((n_c, y.shape[1]))])
        coef = np.linalg.lstsq(design, target, rcond=None)[0]

    def score(val: np.ndarray) -> np.ndarray:
        pred = np.hstack([phi_all[val], poly[val]]) @ coef
        return ((pred - y[val]) ** 2).mean(axis=0)

    return coef, score


def ridge_path(phi_all: np.ndarray, chol: np.ndarray, poly: np.ndarray, y: np.ndarray,
                lams: Sequence[float], rows: np.ndarray | None
                ) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
    """:func:`penalised` for every ridge of ``lams`` at once: coefficients (R, J + d + 1, A)
    and a scorer (validation rows → (R, A) mean squared errors).

    With :math:`v = L^\\top w` (:math:`K = L L^\\top`) the penalty is :math:`\\lambda'
    \\lVert v \\rVert^2` on the design :math:`\\Psi = \\Phi L^{-\\top}`; the unpenalised
    tail is projected out (:math:`\\tilde\\Psi = (I - QQ^\\top)\\Psi`, :math:`P = QR`), and
    one SVD :math:`\\tilde\\Psi = U S V^\\top` gives every ridge:
    :math:`v_\\lambda = V\\,\\mathrm{diag}(s/(s^2 + \\lambda'))\\,U^\\top \\tilde y`,
    :math:`w = L^{-\\top} v`, :math:`t = R^{-1} Q^\\top (y - \\Phi w)` (λ = ∞: w = 0, the
    tail's least squares).  The same minimum as the augmented least squares of
    :func:`penalised` (its oracle in ``tests/test_batched.py``), without a factorisation
    per ridge.  One width of :func:`ridge_paths`."""
    coef, score = ridge_paths(phi_all[None], chol[None], poly, y, lams, rows)
    return coef[0], lambda val: score(val)[0]


def ridge_paths(phi_all: np.ndarray, chol: np.ndarray, poly: np.ndarray, y: np.ndarray,
                 lams: Sequence[float], rows: np.ndarray | None, *,
                 l_inv: np.ndarray | None = None
                 ) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
    """:func:`ridge_path` of every width at once: Φ (W, N, J) and L (W, J, J) of each width
    (``l_inv``: their inverses, when the caller has them for every fold), the same tail and
    training rows; coefficients (W, R, J + d + 1, A) and a scorer (validation rows →
    (W, R, A)).  The tail's QR once for the rows, the widths' SVDs in one stacked call:
    each width's numbers are those of its own path (the same factorisations, stacked)."""
    r = slice(None) if rows is None else rows
    phi, p, yy = phi_all[:, r], poly[r], y[r]                  # (W, n, J), (n, d + 1), (n, A)
    n_c, n_a = chol.shape[-1], y.shape[1]
    # Φ L⁻ᵀ as one matrix product (L⁻¹ is J × J, cond(L) = √cond(K) ≤ ~3e4): numpy only —
    # scipy's triangular solve cost several ms a call here, more than the whole path
    if l_inv is None:
        l_inv = np.linalg.inv(chol)
    l_inv_t = np.swapaxes(l_inv, -1, -2)
    psi = phi @ l_inv_t                                        # (W, n, J)
    q, rp = np.linalg.qr(p)
    psi_t = psi - q @ (q.T @ psi)
    y_t = yy - q @ (q.T @ yy)
    u, sv, vt = np.linalg.svd(psi_t, full_matrices=False)      # (W, n, J), (W, J), (W, J, J)
    uy = np.swapaxes(u, -1, -2) @ y_t                          # (W, J, A)
    scale = np.maximum((phi * phi).sum(axis=(1, 2)) / n_c, TINY)          # (W,)
    lam = np.asarray(lams, dtype=np.float64)
    shrink = np.where(np.isinf(lam)[None, :, None], 0.0,
                      sv[:, None, :] / (sv[:, None, :] ** 2
                                        + lam[None, :, None] * scale[:, None, None]))
    v = np.swapaxes(vt, -1, -2)[:, None] @ (shrink[..., None] * uy[:, None])   # (W, R, J, A)
    w = l_inv_t[:, None] @ v                                   # (W, R, J, A): L⁻ᵀ v
    rhs = (q.T @ yy) - np.einsum("wpj,wrja->wrpa", q.T @ phi, w)           # (W, R, d + 1, A)
    t = np.linalg.solve(rp, rhs)                               # (W, R, d + 1, A): R⁻¹ ·
    coef = np.concatenate([w, t], axis=2)                      # (W, R, J + d + 1, A)
    n_w, n_p = coef.shape[0], coef.shape[2]
    flat = coef.transpose(0, 2, 1, 3).reshape(n_w, n_p, -1)    # (W, J + d + 1, R·A)

    def score(val: np.ndarray) -> np.ndarray:
        tail = np.broadcast_to(poly[val], (n_w, len(val), poly.shape[1]))
        pred = np.concatenate([phi_all[:, val], tail], axis=2) @ flat      # (W, n, R·A)
        res = pred.reshape(n_w, len(val), len(lams), n_a) - y[val][None, :, None, :]
        return (res * res).mean(axis=1)

    return coef, score


def inner_folds(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """:data:`INNER_BLOCKS` contiguous blocks of the (time-ordered) training rows dealt
    round-robin into :data:`INNER_FOLDS` folds; the rows of a validation block's neighbours
    (one block each side) are purged from that fold's training rows."""
    block = np.minimum(np.arange(n) * INNER_BLOCKS // n, INNER_BLOCKS - 1)
    folds = []
    for f in range(INNER_FOLDS):
        val = block % INNER_FOLDS == f                  # blocks f, f + F, f + 2F, …
        # a validation block's neighbours: the block below one (b + 1 is a validation
        # block) and the block above one (b − 1 is)
        near = (((block + 1) % INNER_FOLDS == f) & (block + 1 < INNER_BLOCKS)) \
            | (((block - 1) % INNER_FOLDS == f) & (block >= 1))
        folds.append((np.flatnonzero(~(val | near)), np.flatnonzero(val)))
    return folds
