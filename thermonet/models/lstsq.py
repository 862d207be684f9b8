"""Least squares for every closed-form fit: the normal equations accumulated in float64 chunk by
chunk (:class:`NormalEquations`, recordings larger than memory), :func:`least_squares`, one
chunk of them with a tiny ridge, and :class:`BlockNormalEquations`, the normal equations of
every block of rows kept apart, so that every cross-validation fold (its training rows: the
blocks it keeps) and every ridge is solved in one batched call instead of one fit per fold and
grid point.  The first two are re-exported by :mod:`thermonet.models.base`."""

from __future__ import annotations

import numpy as np

#: Floor of the ridge's scale (the mean diagonal of the Gram matrix), for an all-zero design.
RIDGE_FLOOR = 1e-6

__all__ = ["NormalEquations", "BlockNormalEquations", "least_squares"]


class NormalEquations:
    """The normal equations of ``design @ c ≈ y`` accumulated in float64, chunk by chunk.

    :math:`G = \\sum_k D_k^T D_k` and :math:`B = \\sum_k D_k^T Y_k` over row chunks
    :math:`D_k, Y_k` of the design and the targets: a least-squares fit over more rows
    than memory holds keeps only the (P, P) and (P, A) sums (recordings larger than
    memory; :meth:`merge` adds the sums of another worker's rows).  Forming
    G squares the design's condition number; the families' designs are standardised
    features and their products (condition ≲ 1e6 on the default families, so G keeps
    ≥ 4 significant digits of every coefficient — float64, never float32).  The result
    does not depend on how the rows were chunked beyond float64 rounding of the sums.
    """

    def __init__(self, n_coef: int, n_out: int) -> None:
        self.gram = np.zeros((n_coef, n_coef))
        self.rhs = np.zeros((n_coef, n_out))
        self.n_rows = 0

    def add(self, design: np.ndarray, y: np.ndarray) -> NormalEquations:
        """Add the rows of one chunk; returns ``self``."""
        d = np.asarray(design, dtype=np.float64)
        yy = np.asarray(y, dtype=np.float64).reshape(d.shape[0], -1)
        if d.ndim != 2 or d.shape[1] != self.gram.shape[0] or yy.shape[1] != self.rhs.shape[1]:
            raise ValueError(f"chunk of shape {d.shape} / {yy.shape}; expected (n, "
                             f"{self.gram.shape[0]}) / (n, {self.rhs.shape[1]})")
        self.gram += d.T @ d
        self.rhs += d.T @ yy
        self.n_rows += d.shape[0]
        return self

    def merge(self, other: NormalEquations) -> NormalEquations:
        """Add another accumulator's rows (a worker's share); returns ``self``."""
        self.gram += other.gram
        self.rhs += other.rhs
        self.n_rows += other.n_rows
        return self

    def solve(self, ridge: float = 1e-10) -> np.ndarray:
        """(P, A) coefficients, with the tiny relative ridge of :func:`least_squares`."""
        g = self.gram
        lam = ridge * max(float(np.trace(g)) / max(g.shape[0], 1), RIDGE_FLOOR)
        return np.linalg.solve(g + lam * np.eye(g.shape[0]), self.rhs)


def _relative_ridge(gram: np.ndarray, ridge: float) -> np.ndarray:
    """:meth:`NormalEquations.solve`'s ridge for each of a stack of Gram matrices (..., P, P):
    ``ridge`` × the mean diagonal, floored at :data:`RIDGE_FLOOR`."""
    p = max(gram.shape[-1], 1)
    return ridge * np.maximum(np.trace(gram, axis1=-2, axis2=-1) / p, RIDGE_FLOOR)


class BlockNormalEquations:
    """The normal equations of ``design @ c ≈ y`` per block of rows: :math:`G_b = D_b^T D_b`,
    :math:`B_b = D_b^T Y_b` for blocks :math:`b = 0 \\dots n_b - 1` (the time blocks of a
    cross-validation), formed once.

    A fold trains on the blocks it keeps: its system is :math:`\\sum_{b \\in \\text{kept}}
    G_b` — one (F, n_b) × (n_b, P·P) product for every fold at once, summed over the kept
    blocks rather than subtracted from the total (no cancellation when a fold drops most of
    the rows, its validation blocks and their purged neighbours).  :meth:`solve` then solves
    every fold in one batched ``numpy.linalg.solve`` with :meth:`NormalEquations.solve`'s
    tiny relative ridge, and :meth:`ridge_path` every fold × ridge from one symmetric
    eigendecomposition per fold.  The fold's coefficients equal a fit on the fold's rows
    alone (:func:`least_squares`) to float64 rounding times the Gram matrix's condition
    number (``tests/test_batched.py``); the same caveat on conditioning as
    :class:`NormalEquations`.
    """

    def __init__(self, design: np.ndarray, y: np.ndarray, block: np.ndarray,
                 n_blocks: int | None = None) -> None:
        d = np.asarray(design, dtype=np.float64)
        yy = np.asarray(y, dtype=np.float64).reshape(d.shape[0], -1)
        b = np.asarray(block, dtype=np.int64).reshape(-1)
        if d.ndim != 2 or b.shape[0] != d.shape[0]:
            raise ValueError(f"design {d.shape}, targets {yy.shape} and block ids {b.shape} "
                             "must have one row per sample")
        n_b = int(b.max()) + 1 if n_blocks is None else int(n_blocks)
        if b.size and (b.min() < 0 or b.max() >= n_b):
            raise ValueError(f"block ids must lie in [0, {n_b})")
        order = np.argsort(b, kind="stable")
        edges = np.searchsorted(b[order], np.arange(n_b + 1))
        self.gram = np.zeros((n_b, d.shape[1], d.shape[1]))
        self.rhs = np.zeros((n_b, d.shape[1], yy.shape[1]))
        self.n_rows = np.diff(edges)
        for k in range(n_b):
            rows = order[edges[k]:edges[k + 1]]
            self.gram[k] = d[rows].T @ d[rows]
            self.rhs[k] = d[rows].T @ yy[rows]

    def systems(self, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gram matrices (F, P, P) and right-hand sides (F, P, A) of the folds whose kept
        blocks are the true entries of ``keep`` (F, n_blocks)."""
        k = np.asarray(keep, dtype=np.float64)
        if k.ndim != 2 or k.shape[1] != self.gram.shape[0]:
            raise ValueError(f"keep has shape {k.shape}; expected (folds, {self.gram.shape[0]})")
        return (np.einsum("fb,bpq->fpq", k, self.gram),
                np.einsum("fb,bpa->fpa", k, self.rhs))

    def solve(self, keep: np.ndarray, ridge: float = 1e-10) -> np.ndarray:
        """Coefficients (F, P, A) of every fold, each with :meth:`NormalEquations.solve`'s
        relative ridge, in one batched solve."""
        g, r = self.systems(keep)
        lam = _relative_ridge(g, ridge)
        return np.linalg.solve(g + lam[:, None, None] * np.eye(g.shape[1]), r)

    def ridge_path(self, keep: np.ndarray, ridges: np.ndarray) -> np.ndarray:
        """Ridge coefficients (F, R, P, A) of every fold and every relative ridge of
        ``ridges`` (× the fold's mean Gram diagonal, as :meth:`solve`), from one
        eigendecomposition :math:`G = V \\operatorname{diag}(e) V^T` per fold:
        :math:`c_\\lambda = V \\operatorname{diag}(1/(e + \\lambda)) V^T B`."""
        g, r = self.systems(keep)
        e, v = np.linalg.eigh(g)                                     # (F, P), (F, P, P)
        lam = _relative_ridge(g, 1.0)[:, None] * np.asarray(ridges, dtype=np.float64)[None]
        vb = np.einsum("fpq,fpa->fqa", v, r)                         # Vᵀ B
        scaled = vb[:, None] / (e[:, None, :, None] + lam[:, :, None, None])
        return np.einsum("fpq,frqa->frpa", v, scaled)


def least_squares(design: np.ndarray, y: np.ndarray, ridge: float = 1e-10) -> np.ndarray:
    """Least-squares coefficients of ``design @ c ≈ y`` with a tiny ridge.

    The ridge (relative to the mean diagonal of :math:`D^T D`) only decides
    directions the data cannot see (a fuzzy rule no sample reaches); it does
    not move a well-posed solution measurably.  One chunk of :class:`NormalEquations`.
    """
    d = np.asarray(design, dtype=np.float64)
    yy = np.asarray(y, dtype=np.float64)
    coef = NormalEquations(d.shape[1], yy.reshape(d.shape[0], -1).shape[1]).add(d, yy).solve(
        ridge)
    return coef if yy.ndim == 2 else coef.reshape(d.shape[1:] + yy.shape[1:])
