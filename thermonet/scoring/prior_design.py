"""Which temperatures a new unit should be tested at next, under the fleet prior
(:mod:`thermonet.scoring.prior`): Bayesian I-optimal design (Chaloner & Verdinelli 1995) — the
point that most lowers the posterior variance of the offset-free curve averaged over the
fleet's range (:func:`next_temperatures`, one plan for every axis: :func:`soak_plan`); without
data the first two are chosen as a pair (one point of one run only fixes its constant).  A
mixture prior's designs are judged on units drawn from it (:data:`DESIGN_DRAWS`, fixed seed).
:func:`points_needed` says how many such points reach a target error.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .prior import AxisPrior, FleetPrior
from .prior_points import shape_design

__all__ = ["DESIGN_DRAWS", "SWEEP_STEP_C", "expected_error", "next_temperatures", "typical_drift", "soak_plan",
           "point_error", "has_curve",
           "plan_errors", "design_errors", "points_needed", "first_below"]


def _run_information(X: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Information of one run's points on the shape, its constant profiled out."""
    sx = w @ X
    return np.asarray((X.T * w) @ X - np.outer(sx, sx) / w.sum())


def expected_error(prior: AxisPrior, information: np.ndarray, grid: np.ndarray) -> float:
    """RMS over ``grid`` rows of the offset-free curve's posterior std (moment-matched prior)."""
    _, S = prior.moment_matched()
    post = np.linalg.inv(np.linalg.inv(S) + information)
    G = grid - grid.mean(axis=0)
    return float(np.sqrt(max(np.einsum("ij,jk,ik->", G, post, G) / len(G), 0.0)))


def _design_setup(fp: FleetPrior, axis: str, step_c: float
                  ) -> tuple[AxisPrior, np.ndarray, float]:
    """The axis's prior, its design rows over the candidate temperatures (where the error is
    averaged) and the weight of one point."""
    ap = fp.axis(axis)
    grid = shape_design(_candidates(fp, step_c), fp.t_ref, fp.scale, fp.degree)
    return ap, grid, 1.0 / (ap.misfit_var + ap.sampling_var + 1e-300)


#: A soak plan is judged against a sweep of the fleet's range soaked every this many °C (and
#: at its top): the full calibration a short test stands in for (:func:`soak_plan`).
SWEEP_STEP_C = 10.0
#: Units drawn from a mixture prior to judge a design by simulation (fixed seed: the same
#: plan every time).
DESIGN_DRAWS = 400
#: Point-error columns a mixture design's draws get at once (more are drawn as a design
#: needs them: :class:`_DrawNoise`).
_NOISE_BLOCK = 64


class _DrawNoise:
    """Each draw's point errors, one column per temperature of a design, as many as a design
    has (a unit's whole test can hold hundreds of points, a plan a few): the first
    :data:`_NOISE_BLOCK` columns drawn at once, further columns one temperature at a time
    from the same stream, so column j is the same whatever the design's length and designs
    of every length are judged on the same draws."""

    def __init__(self, rng: np.random.Generator, sd: float) -> None:
        self._rng, self._sd = rng, sd
        self._cols = rng.standard_normal((DESIGN_DRAWS, _NOISE_BLOCK)) / sd

    def columns(self, n: int) -> np.ndarray:
        if n > self._cols.shape[1]:
            more = self._rng.standard_normal((n - self._cols.shape[1], DESIGN_DRAWS))
            self._cols = np.hstack([self._cols, more.T / self._sd])
        return self._cols[:, :n]


def _mixture_error(fp: FleetPrior, ap: AxisPrior, grid: np.ndarray, w0: float
                   ) -> Callable[[list[float]], float]:
    """Expected error of a design under a mixture prior, by simulation: units drawn from the
    mixture, their points at the design's temperatures (the point error added), each one's
    posterior shape (clusters reweighted by evidence, as :func:`posterior`) against its own
    curve.  Unlike one Gaussian's, it depends on how well the points tell the clusters apart."""
    rng = np.random.default_rng(0)
    comp = rng.choice(ap.n_clusters, size=DESIGN_DRAWS, p=ap.weights)
    z = rng.standard_normal((DESIGN_DRAWS, fp.degree))
    beta = ap.means[comp] + np.einsum("nij,nj->ni", np.linalg.cholesky(ap.covs)[comp], z)
    noise = _DrawNoise(rng, math.sqrt(w0))
    Gc = grid - grid.mean(axis=0)
    sinv = np.linalg.inv(ap.covs)
    consts = [float(mu @ si @ mu) + float(np.linalg.slogdet(S)[1])
              for mu, si, S in zip(ap.means, sinv, ap.covs, strict=True)]

    def err(temps: list[float]) -> float:
        X = shape_design(np.asarray(temps), fp.t_ref, fp.scale, fp.degree)
        Xc = X - X.mean(axis=0)
        y = beta @ X.T + noise.columns(len(temps))
        yc = y - y.mean(axis=1, keepdims=True)
        J, b = w0 * Xc.T @ Xc, w0 * yc @ Xc                       # (d, d), (draws, d)
        logev, means = [], []
        for mu, si, c in zip(ap.means, sinv, consts, strict=True):
            A = si + J
            m = np.linalg.solve(A, (si @ mu)[:, None] + b.T).T     # (draws, d)
            q = w0 * np.sum(yc ** 2, axis=1) + c - np.einsum("ni,ij,nj->n", m, A, m)
            logev.append(-0.5 * (q + np.linalg.slogdet(A)[1]))
            means.append(m)
        lw = np.log(ap.weights)[:, None] + np.asarray(logev)
        wp = np.exp(lw - lw.max(axis=0))
        wp /= wp.sum(axis=0)
        shape = np.einsum("kn,kni->ni", wp, np.asarray(means))
        e = (shape - beta) @ Gc.T
        return float(np.sqrt(np.mean(e ** 2)))
    return err


def _axis_error(fp: FleetPrior, axis: str, step_c: float) -> Callable[[list[float]], float]:
    """Expected error of ``axis``'s offset-free curve after one run's points at ``temps``
    (exact for one cluster, where it does not depend on the values measured; by simulation
    for a mixture, :func:`_mixture_error`)."""
    ap, grid, w0 = _design_setup(fp, axis, step_c)
    mixture = _mixture_error(fp, ap, grid, w0) if ap.n_clusters > 1 else None

    def err(temps: list[float]) -> float:
        if len(temps) < 2:
            return expected_error(ap, np.zeros((fp.degree, fp.degree)), grid)
        if mixture is not None:
            return mixture(temps)
        X = shape_design(np.asarray(temps), fp.t_ref, fp.scale, fp.degree)
        return expected_error(ap, _run_information(X, np.full(len(temps), w0)), grid)
    return err


def _greedy(cost: Callable[[list[float]], float], cand: np.ndarray, measured_c: list[float],
            n: int, *, apart_c: float = 0.0) -> list[float]:
    """``n`` more temperatures, each lowering ``cost`` most (the first two as a pair when
    nothing was measured: one point of one run only fixes its constant).  With ``apart_c``,
    a candidate closer than that to a temperature measured or chosen is not taken (a soak
    plan's temperatures are distinct); fewer than ``n`` come back when none is left."""
    chosen = [float(t) for t in measured_c]
    out: list[float] = []
    while len(out) < n:
        free = [float(t) for t in cand if all(abs(t - c) >= apart_c for c in chosen)] \
            if apart_c > 0 else [float(t) for t in cand]
        if not chosen:
            pairs = [(a, b) for i, a in enumerate(free) for b in free[i + 1:]
                     if b - a >= apart_c]
            if not pairs:
                break
            best = min(pairs, key=lambda ab: cost([ab[0], ab[1]]))
            pick = [best[0], best[1]][:n - len(out)]
        elif free:
            pick = [min(free, key=lambda t: cost(chosen + [t]))]
        else:
            break
        chosen += pick
        out += pick
    return out


def _candidates(fp: FleetPrior, step_c: float) -> np.ndarray:
    return np.arange(fp.range_c[0], fp.range_c[1] + 1e-9, step_c)


def next_temperatures(fp: FleetPrior, axis: str, measured_c: list[float], n: int, *,
                      step_c: float = 2.5, apart_c: float | None = None) -> list[float]:
    """The ``n`` temperatures to measure next on one run of ``axis`` (greedy I-optimal).

    Each at least ``apart_c`` (default ``step_c``, the separation :func:`soak_plan` keeps)
    from a temperature measured or chosen: a soak repeated is one longer soak, not a new
    point (the prior's arithmetic, which takes points as independent, would rate it so).
    Fewer than ``n`` come back where the measured points leave no such candidate (a test
    that covered the range every ``apart_c``); ``apart_c=0``: the design alone, repeats
    allowed (:func:`design_errors`' points of one run)."""
    sep = step_c if apart_c is None else apart_c
    return _greedy(_axis_error(fp, axis, step_c), _candidates(fp, step_c), measured_c, n,
                   apart_c=sep)


def typical_drift(fp: FleetPrior, axis: str) -> float:
    """The fleet's mean curve's offset-free RMS over the range (the drift a test must learn)."""
    mu, _ = fp.axis(axis).moment_matched()
    curve = shape_design(np.linspace(*fp.range_c, 41), fp.t_ref, fp.scale, fp.degree) @ mu
    return float(np.sqrt(np.mean((curve - curve.mean()) ** 2)))


def point_error(ap: AxisPrior) -> float:
    """A point's own error on the axis: √(misfit variance + sampling variance)."""
    return math.sqrt(ap.misfit_var + ap.sampling_var)


def has_curve(fp: FleetPrior, axis: str) -> bool:
    """Whether the axis has a curve to learn: its fleet's drift above a point's own error
    (else a test only fixes its offset)."""
    return typical_drift(fp, axis) > point_error(fp.axis(axis))


def soak_plan(fp: FleetPrior, n: int, *, measured_c: list[float] | None = None,
              step_c: float = 2.5, ends: bool = True) -> list[float]:
    """One test for every axis: ``n`` soak temperatures, in rising order — soak them in that
    order, so that a hysteresis stays on one branch (the prior's points are each a constant
    apart per run, not per branch; measured, a test that turned back did worse).

    With ``ends`` (the default) the first two are the ends of the fleet's range (those not
    already in ``measured_c``), and the rest lower most the worst axis's expected error over
    what a sweep of the range every :data:`SWEEP_STEP_C` would leave — axes whose drift is
    below a point's own error left out (nothing to learn there).  Worst axis first: on
    ``bench_prior.py`` (leave units out) the mean over axes of (error / drift)², the rule
    before, left acc_x at 1.33× the full sweep's error with 200 units (1.48× with 50).  Every temperature of a plan is at least ``step_c`` from the
    others and from ``measured_c`` (a soak repeated is one longer soak, not a point: the
    error a point has beyond its sampling — hysteresis, lag — is not averaged away by
    soaking there again, though the prior's arithmetic, which takes points as independent,
    would rate it so), so the middle is an interior temperature; a range too narrow for
    that, or no axis with a curve to learn, gives a shorter plan (its ends).

    The expected error is the prior's: a point's error, the clusters and their spread, but
    no lag or hysteresis, and it rated a test that left an end to the prior too well — on ``bench_prior.py`` (200 units, leave units out) the free plan
    (1.5 / 46.5 / 74 °C and the like) was 1.36–1.75× the full sweep's error on four axes
    where the ends and its chosen middle (−21 / 49–51.5 / 75 °C) were 1.04–1.36×.
    ``ends=False``: every temperature by the expected error alone (the plan before)."""
    measured = list(measured_c or [])
    cost = _plan_cost(fp, step_c)
    if cost is None:
        return [fp.range_c[0], fp.range_c[1]][:n]
    fixed: list[float] = []
    if ends:
        fixed = [t for t in fp.range_c if all(abs(t - m) >= step_c for m in measured)][:n]
    more = _greedy(cost, _candidates(fp, step_c), measured + fixed, n - len(fixed),
                   apart_c=step_c) if n > len(fixed) else []
    return sorted(fixed + more)


def _axis_costs(fp: FleetPrior, step_c: float
                ) -> list[tuple[Callable[[list[float]], float], float, float]]:
    """Per axis with a curve to learn (drift above a point's own error): its expected error
    after one run at given temperatures, its typical drift, and the expected error of a sweep
    of the range every :data:`SWEEP_STEP_C` (and at its top)."""
    sweep = [float(t) for t in np.arange(fp.range_c[0], fp.range_c[1], SWEEP_STEP_C)]
    out = []
    for ap in fp.axes:
        if has_curve(fp, ap.axis):
            err = _axis_error(fp, ap.axis, step_c)
            out.append((err, typical_drift(fp, ap.axis),
                        max(err([*sweep, fp.range_c[1]]), 1e-300)))
    return out


def _plan_cost(fp: FleetPrior, step_c: float) -> Callable[[list[float]], float] | None:
    """The worst, over the axes with a curve to learn, of the expected error after one run at
    ``temps`` over a sweep's (what the plan stands in for); None without such an axis."""
    costs = _axis_costs(fp, step_c)
    if not costs:
        return None

    def cost(temps: list[float]) -> float:
        return max(err(temps) / full for err, _, full in costs)
    return cost


def plan_errors(fp: FleetPrior, plan: list[float], *, step_c: float = 2.5
                ) -> tuple[float, float] | None:
    """What a :func:`soak_plan`'s temperatures inside the range add: the expected error (RMS
    over the axes with a curve to learn, each as a fraction of its typical drift) after the
    plan's ends alone and after the whole plan; None without such an axis or ends."""
    costs = _axis_costs(fp, step_c)
    ends = [t for t in plan if t in fp.range_c]
    if not costs or len(ends) < 2:
        return None

    def rms(temps: list[float]) -> float:
        return math.sqrt(sum((err(temps) / typ) ** 2 for err, typ, _ in costs) / len(costs))
    return rms(ends), rms(list(plan))


def design_errors(fp: FleetPrior, axis: str, *, max_points: int = 12, step_c: float = 2.5
                  ) -> tuple[list[float], list[float]]:
    """The first ``max_points`` temperatures of one run in :func:`next_temperatures` order,
    and the expected error after 2 … ``max_points`` of them."""
    ap, grid, w0 = _design_setup(fp, axis, step_c)
    temps = next_temperatures(fp, axis, [], max_points, step_c=step_c, apart_c=0.0)
    errs = []
    for k in range(2, max_points + 1):
        X = shape_design(np.asarray(temps[:k]), fp.t_ref, fp.scale, fp.degree)
        errs.append(expected_error(ap, _run_information(X, np.full(k, w0)), grid))
    return temps, errs


def points_needed(fp: FleetPrior, axis: str, target: float, *, max_points: int = 12,
                  step_c: float = 2.5) -> tuple[int | None, list[float], list[float]]:
    """Points of one run (in :func:`next_temperatures` order) for an expected error ≤ target.

    Returns ``(n or None, temperatures, expected error after 2 … max_points points)``."""
    temps, errs = design_errors(fp, axis, max_points=max_points, step_c=step_c)
    return first_below(errs, target), temps, errs


def first_below(errs: list[float], target: float) -> int | None:
    """The number of points (errs[0] is after 2) whose expected error is ≤ target."""
    return next((k + 2 for k, e in enumerate(errs) if e <= target), None)
