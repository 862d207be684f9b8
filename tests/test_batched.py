"""Batched closed-form fits against the same fits one at a time, and against independent
oracles (numpy.linalg.lstsq, scipy.linalg.solve).

* :class:`thermonet.models.lstsq.BlockNormalEquations`: every cross-validation fold of a
  linear, polynomial and dynamic-input polynomial design solved in one batched call (the fold's
  system summed from its kept blocks) equals :func:`~thermonet.models.lstsq.least_squares` on
  the fold's rows alone, and numpy's SVD least squares; its ridge path (one eigendecomposition
  per fold) equals scipy's dense solve at every ridge.
* The RBF tail's inner cross-validation (:func:`thermonet.models.rbf_fit.ridge_path`: every ridge
  of a width and fold from one SVD) equals the one-ridge-at-a-time augmented least squares it
  replaced (:func:`thermonet.models.rbf_fit.penalised`) and the penalised problem's stationarity
  system solved by scipy.

Tolerances (tests/tolerances.py, float64): a solve's coefficients carry float64 rounding times
the system's condition number; predictions of a fitted design (``D @ c``) are compared, at the
targets' scale, where the bound is ~1e-12 whatever the condition.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
import torch

from thermonet.features.inputs import FeatureSpec
from thermonet.models.lstsq import BlockNormalEquations, least_squares
from thermonet.models.poly import Poly
from thermonet.models.rbf_fit import (
    RIDGE_GRID,
    design,
    inner_folds,
    penalised,
    ridge_path,
    ridge_paths,
)
from thermonet.training.train import TrainConfig, fit
from tolerances import EPS64, assert_f64_close

pytestmark = pytest.mark.numerics

N, N_BLOCKS, N_FOLDS = 1200, 20, 5


def _signals() -> np.ndarray:
    """Heat/cool cycles: temperature, its rate and a hysteresis input (poly3-hyst's kind)."""
    t = np.linspace(0.0, 1.0, N)
    # two incommensurate cycles and a trend (one sinusoid would tie T² and rate² by
    # sin² + cos² = 1: a rank-deficient cubic)
    temp = 20.0 + 25.0 * np.sin(2 * np.pi * t) + 10.0 * np.sin(5.4 * np.pi * t + 1.0) + 8 * t ** 3
    rate = np.gradient(temp, t)
    play = np.empty_like(temp)          # play_3 = T − P(T), a hysteresis input (half-width 3)
    play[0] = temp[0]
    for i in range(1, temp.size):
        play[i] = min(max(play[i - 1], temp[i] - 3.0), temp[i] + 3.0)
    return np.column_stack([temp, rate, temp - play])


def _standardised(x: np.ndarray) -> np.ndarray:
    return (x - x.mean(axis=0)) / x.std(axis=0)


def _design_of(kind: str) -> np.ndarray:
    z = _standardised(_signals())
    if kind == "linear":
        d = z[:, :1]
    elif kind == "poly":
        d = Poly(n_inputs=1, n_outputs=1, degree=3).design(torch.as_tensor(z[:, :1])).numpy()
    else:   # the default set's poly3-hyst shape: every monomial of degree <= 3 in 3 inputs
        d = Poly(n_inputs=3, n_outputs=1, degree=3,
                 cross=True).design(torch.as_tensor(z)).numpy()
    return np.hstack([d, np.ones((N, 1))])


def _targets(seed: int = 0) -> np.ndarray:
    z = _standardised(_signals())
    rng = np.random.default_rng(seed)
    return np.column_stack([np.sin(z[:, 0]) + 0.3 * z[:, 1] * z[:, 0],
                            0.2 * z[:, 2] ** 2 - z[:, 1]]) + 0.01 * rng.standard_normal((N, 2))


def _folds() -> tuple[np.ndarray, np.ndarray]:
    """Block id per row (contiguous blocks) and per fold the kept blocks: the validation
    blocks (dealt round-robin) and their neighbours left out, as the selection's purge."""
    block = np.minimum(np.arange(N) * N_BLOCKS // N, N_BLOCKS - 1)
    keep = np.ones((N_FOLDS, N_BLOCKS), dtype=bool)
    for f in range(N_FOLDS):
        val = np.arange(f, N_BLOCKS, N_FOLDS)
        out = np.union1d(val, np.union1d(val - 1, val + 1))
        keep[f, out[(out >= 0) & (out < N_BLOCKS)]] = False
    return block, keep


@pytest.mark.parametrize("kind", ["linear", "poly", "dynamic-poly"])
def test_every_fold_in_one_solve_equals_each_fold_alone(kind: str) -> None:
    d, y = _design_of(kind), _targets()
    block, keep = _folds()
    batched = BlockNormalEquations(d, y, block, N_BLOCKS).solve(keep)     # (F, P, A)
    assert batched.shape == (N_FOLDS, d.shape[1], 2)
    scale = np.abs(y).max()
    for f in range(N_FOLDS):
        rows = np.flatnonzero(keep[f][block])
        alone = least_squares(d[rows], y[rows])            # the one-at-a-time fit
        oracle = np.linalg.lstsq(d[rows], y[rows], rcond=None)[0]  # SVD, no normal equations
        # the same normal equations summed in another order: float64 rounding times the Gram
        # matrix's condition number (cond(D)², ≤ 1e8 here), 64 ε of margin; compared as the
        # fold's predictions on every row (validation rows included), at the targets' scale
        cond_g = np.linalg.cond(d[rows]) ** 2
        assert_f64_close(d @ batched[f], d @ alone, rtol=0, atol=64 * EPS64 * cond_g * scale)
        # numpy's SVD solve has no normal equations (nor the 1e-10 relative ridge, which moves
        # a fit by ~1e-10 × cond(G) of the scale)
        assert_f64_close(d @ batched[f], d @ oracle, rtol=0,
                         atol=(64 * EPS64 + 1e-10) * cond_g * scale)


def test_the_fold_system_is_the_sum_of_its_kept_blocks() -> None:
    d, y = _design_of("poly"), _targets()
    block, keep = _folds()
    g, r = BlockNormalEquations(d, y, block, N_BLOCKS).systems(keep)
    for f in range(N_FOLDS):
        rows = np.flatnonzero(keep[f][block])
        want_g, want_r = d[rows].T @ d[rows], d[rows].T @ y[rows]
        # sums in another order: relative to the largest entry (odd moments are near 0)
        assert_f64_close(g[f], want_g, rtol=0, atol=1e-12 * np.abs(want_g).max())
        assert_f64_close(r[f], want_r, rtol=0, atol=1e-12 * np.abs(want_r).max())
    # a fold keeping every block is the whole fit
    whole = BlockNormalEquations(d, y, block, N_BLOCKS).solve(np.ones((1, N_BLOCKS), bool))
    assert_f64_close(d @ whole[0], d @ least_squares(d, y), atol=1e-12 * np.abs(y).max())


@pytest.mark.parametrize("kind", ["linear", "poly", "dynamic-poly"])
def test_ridge_path_from_one_eigendecomposition_equals_scipy_at_every_ridge(kind: str) -> None:
    d, y = _design_of(kind), _targets(1)
    block, keep = _folds()
    ridges = np.array([1e-8, 1e-4, 1e-2, 1.0, 100.0])
    path = BlockNormalEquations(d, y, block, N_BLOCKS).ridge_path(keep, ridges)  # (F, R, P, A)
    for f in range(N_FOLDS):
        rows = np.flatnonzero(keep[f][block])
        g = d[rows].T @ d[rows]
        scale = np.trace(g) / g.shape[0]
        for i, lam in enumerate(ridges):
            want = scipy.linalg.solve(g + lam * scale * np.eye(g.shape[0]), d[rows].T @ y[rows],
                                      assume_a="pos")
            cond = np.linalg.cond(g + lam * scale * np.eye(g.shape[0]))
            # two factorisations (eigh, Cholesky) of one system: ε × its condition number
            assert_f64_close(path[f, i], want, rtol=0,
                             atol=64 * EPS64 * cond * np.abs(want).max())
    # the tiny ridge of solve() on the path: the same fit, as predictions at the targets' scale
    # to ε × the Gram matrix's condition number (two factorisations: eigh and LU)
    eqs = BlockNormalEquations(d, y, block, N_BLOCKS)
    at_tiny, solved = eqs.ridge_path(keep, np.array([1e-10]))[:, 0], eqs.solve(keep)
    for f in range(N_FOLDS):
        cond_g = np.linalg.cond(d[np.flatnonzero(keep[f][block])]) ** 2
        assert_f64_close(d @ at_tiny[f], d @ solved[f], rtol=0,
                         atol=64 * EPS64 * cond_g * np.abs(y).max())


def test_bad_block_ids_and_keep_shape_are_refused() -> None:
    d, y = _design_of("linear"), _targets()
    with pytest.raises(ValueError, match="block ids"):
        BlockNormalEquations(d, y, np.full(N, 7), 5)
    with pytest.raises(ValueError, match="one row per sample"):
        BlockNormalEquations(d, y, np.zeros(N - 1, dtype=int))
    with pytest.raises(ValueError, match="keep has shape"):
        BlockNormalEquations(d, y, np.zeros(N, dtype=int), 2).solve(np.ones((3, 4), bool))


# --------------------------------------------------------------- the RBF tail's ridge path
def _rbf_case(width: float) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray, np.ndarray]:
    z = _standardised(_signals()[:, :1])
    x = _standardised(np.column_stack([z[:, 0], z[:, 0] ** 2]))
    centres = x[np.linspace(0, N - 1, 12).astype(int)] + 0.01
    poly = np.column_stack([x[:, 0] ** k for k in range(1, 4)] + [np.ones(N)])
    return design(x, centres, width), poly, _targets(2)


@pytest.mark.parametrize("width", [0.1, 0.4, 1.2])
def test_rbf_ridge_path_equals_one_ridge_at_a_time(width: float) -> None:
    dz, poly, y = _rbf_case(width)
    for tr, va in inner_folds(N):
        coef, score = ridge_path(*dz, poly, y, RIDGE_GRID, tr)
        err = score(va)                                         # (R, A)
        for i, lam in enumerate(RIDGE_GRID):
            c1, s1 = penalised(*dz, poly, y, lam, tr)          # the replaced per-ridge fit
            pred = np.hstack([dz[0], poly]) @ coef[i]
            pred1 = np.hstack([dz[0], poly]) @ c1
            # both are float64 minimisers of the same strictly convex problem; the Gaussian
            # columns make it ill-conditioned at the smallest ridge and widest width, where
            # the two factorisations agree to ~1e-10 of the targets' scale
            assert_f64_close(pred, pred1, rtol=0, atol=1e-9 * np.abs(y).max())
            assert_f64_close(err[i], s1(va), rtol=1e-8)
        assert np.all(coef[-1, :dz[1].shape[0]] == 0)           # λ = ∞: no Gaussian part


def test_rbf_ridge_path_solves_the_stationarity_system() -> None:
    """Independent oracle: the minimiser of ‖Φw + Pt − y‖² + λ' wᵀKw solves
    [[ΦᵀΦ + λ'K, ΦᵀP], [PᵀΦ, PᵀP]] [w; t] = [Φᵀy; Pᵀy] (scipy.linalg.solve), K the jittered
    kernel between centres (L Lᵀ), λ' = λ · tr(ΦᵀΦ)/J on the training rows."""
    (phi, chol), poly, y = _rbf_case(0.3)
    tr, _ = inner_folds(N)[2]
    lams = (1e-3, 1e-1, 10.0)
    coef, _ = ridge_path(phi, chol, poly, y, lams, tr)
    ph, p, yy = phi[tr], poly[tr], y[tr]
    k = chol @ chol.T
    j = phi.shape[1]
    for i, lam in enumerate(lams):
        lam_abs = lam * float((ph * ph).sum()) / j
        a = np.block([[ph.T @ ph + lam_abs * k, ph.T @ p], [p.T @ ph, p.T @ p]])
        want = scipy.linalg.solve(a, np.vstack([ph.T @ yy, p.T @ yy]))
        full = np.hstack([phi, poly])
        assert_f64_close(full @ coef[i], full @ want, rtol=0,
                         atol=1e-15 * np.linalg.cond(a) * np.abs(y).max())
        assert not math.isnan(float(coef[i].sum()))


def test_rbf_tail_fit_through_the_loop_keeps_its_choices() -> None:
    """End to end: the RBF with the cubic tail fitted by ``fit`` (its inner cross-validation
    now on the ridge path) reports one ridge per axis from the grid, and predicts what its
    final per-axis penalised least squares (penalised, unchanged) gives at those ridges."""
    s = _signals()[:, :1]
    y = _targets(3)
    res = fit(family="rbf", inputs=["dT", "dT2"], outputs=["a", "b"], train=[(s, y)], val=None,
              spec=FeatureSpec(inputs=["dT", "dT2"], t_ref=25.0),
              hyper={"n_centres": 8, "tail": 3}, config=TrainConfig())
    tuned = res.model.family.tuned()
    assert set(tuned) == {"width_scale", "ridge"} and len(tuned["ridge"]) == 2
    grid = {lam if math.isfinite(lam) else "inf" for lam in RIDGE_GRID}
    assert all(r in grid for r in tuned["ridge"])
    assert len(res.history) == 1     # closed form and final


def test_rbf_widths_stacked_are_each_widths_own_path() -> None:
    """The inner cross-validation solves every width of a fold in one stacked call
    (ridge_paths, with the widths' L⁻¹ given once): each width's coefficients and scores
    are those of its own path (ridge_path, itself checked against the per-ridge fit and
    scipy above) — the same factorisations, stacked, so equal to a few float64 ulps."""
    cases = [_rbf_case(w) for w in (0.2, 0.5, 1.1)]
    poly, y = cases[0][1], cases[0][2]
    phis = np.stack([c[0][0] for c in cases])
    chols = np.stack([c[0][1] for c in cases])
    for tr, va in inner_folds(N):
        coef, score = ridge_paths(phis, chols, poly, y, RIDGE_GRID, tr,
                                   l_inv=np.linalg.inv(chols))
        err = score(va)
        assert coef.shape[:2] == (3, len(RIDGE_GRID)) and err.shape == (3, len(RIDGE_GRID), 2)
        for k, (dz, _, _) in enumerate(cases):
            c1, s1 = ridge_path(*dz, poly, y, RIDGE_GRID, tr)
            full = np.hstack([dz[0], poly])
            for i in range(len(RIDGE_GRID)):
                assert_f64_close(full @ coef[k, i], full @ c1[i], rtol=0,
                                 atol=1e3 * EPS64 * np.linalg.cond(full) * np.abs(y).max())
            assert_f64_close(err[k], s1(va), rtol=1e-9)


@pytest.mark.parametrize("n", [80, 81, 119, 200, 2001, 4567])
def test_inner_folds_are_the_dealt_blocks_less_their_neighbours(n: int) -> None:
    """inner_folds by block arithmetic equals its definition with set operations: 40
    contiguous blocks dealt round-robin into 5 folds; a fold trains on every block that is
    neither one of its validation blocks nor next to one."""
    from thermonet.models.rbf_fit import INNER_BLOCKS, INNER_FOLDS

    block = np.minimum(np.arange(n) * INNER_BLOCKS // n, INNER_BLOCKS - 1)
    folds = inner_folds(n)
    assert len(folds) == INNER_FOLDS
    for f, (tr, va) in enumerate(folds):
        val_blocks = np.arange(f, INNER_BLOCKS, INNER_FOLDS)
        near = np.union1d(val_blocks - 1, val_blocks + 1)
        assert np.array_equal(va, np.flatnonzero(np.isin(block, val_blocks)))
        assert np.array_equal(tr, np.flatnonzero(~np.isin(block, np.union1d(val_blocks, near))))
