"""Least squares for every closed-form fit: the normal equations accumulated in float64 chunk by
chunk (:class:`NormalEquations`, recordings larger than memory) and :func:`least_squares`, one
chunk of them with a tiny ridge.  Re-exported by :mod:`thermonet.models.base`."""

from __future__ import annotations

import numpy as np

#: Floor of the ridge's scale (the mean diagonal of the Gram matrix), for an all-zero design.
RIDGE_FLOOR = 1e-6

__all__ = ["NormalEquations", "least_squares"]


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
