"""A fleet prior: the population of a sensor type's drift curves, and a new unit's posterior.

**What is modelled.**  On each output axis a unit's drift is a polynomial of degree ``d`` in
the normalised temperature :math:`u = (T - t_{ref}) / h` (``h``: the larger distance from
:math:`t_{ref}` to an end of the fleet's range), plus one free constant per run (the turn-on
offset, or the unknown level of an ``at-t-ref`` target).  The prior is on the *shape*
:math:`\\beta = (a_1, \\dots, a_d)`; the constants get a flat prior — a turn-on offset is a
power-up's, not the fleet's, and every test measures it.

**The population** (empirical Bayes, Gaussian mixture).  Each calibrated unit's shape
:math:`\\hat\\beta_u` is fitted by weighted least squares on its 1 °C-binned means (the same
points a new unit gives, :func:`~thermonet.scoring.prior_points.bin_points`).  Their distribution is a mixture of Gaussians
:math:`\\sum_k \\pi_k\\,N(\\mu_k, \\Sigma_k)`, the number of clusters chosen by BIC among
1 … :data:`MAX_CLUSTERS` (a cluster is tried only with :data:`UNITS_PER_CLUSTER` units for it;
scikit-learn's ``GaussianMixture``, full covariances).  One cluster: the mean and the
Ledoit–Wolf shrunk covariance (``sklearn.covariance.LedoitWolf``), which stays well
conditioned on small fleets.  :math:`\\Sigma_k` includes each unit's estimation error (a full
sweep's is small beside the unit-to-unit spread), so the prior errs wide, not narrow.
Reginya et al. (CEUR Vol-2278, 2018) found 250 MPU-9250s in six clusters, not one profile.

**A bin's error** :math:`\\sigma_i^2 = v + s_i^2 / n_i`: its sampling variance plus the
misfit variance :math:`v` of the fleet's own fits (the median over units of what their bins
scatter about their own curve beyond sampling: hysteresis, lag, a curve the polynomial
does not follow).

**The posterior** (conjugate; Bishop, *PRML* §3.3, per component).  With the constants
profiled out (each run's points centred by their weighted mean, which is exact for a flat
prior), :math:`A_k = \\Sigma_k^{-1} + X_c^T W X_c`, :math:`m_k = A_k^{-1}(\\Sigma_k^{-1}\\mu_k
+ X_c^T W y_c)`; the components are reweighted by their evidence.  The same quantity
:math:`d_k^2 = y_c^T W y_c + \\mu_k^T\\Sigma_k^{-1}\\mu_k - m_k^T A_k m_k` is the unit's
Mahalanobis distance from cluster *k* under its prior predictive, :math:`\\chi^2` with
(points − runs) degrees of freedom: a unit unlike every cluster
(:math:`\\max_k p_k <` :data:`FLAG_P`) is flagged even if its own fit is good.  A long test
(:data:`SHAPE_TEST_DOF` residual degrees of freedom or more beyond the shape) is judged on its
own shape instead (:func:`_shape_p_values`): over hundreds of points the whole predictive
judges the scatter more than the shape, and flagged units of the prior's own fleet; the
shape's distance has Hotelling's predictive law, the clusters being estimated from a few
dozen units (:func:`shape_p_values`).  A unit is compared only on a test of a kind its
prior can judge (:meth:`FleetPrior.not_comparable`: fast ramps and slow tests apart).

**Which temperatures next** (Bayesian I-optimal design, Chaloner & Verdinelli 1995;
:mod:`thermonet.scoring.prior_design`): the point that most lowers the posterior variance of
the offset-free curve averaged over the fleet's range; without data the first two are chosen
as a pair (one point of one run only fixes its constant).
:func:`~thermonet.scoring.prior_design.points_needed` says how many such points reach a target
error.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import ConfigError, InputError, counted
from .prior_map import TestMap
from .prior_points import BIN_C, FAST_KIND, Points, centred, shape_design

__all__ = ["PRIOR_SCHEMA", "MIN_UNITS", "MAX_CLUSTERS", "UNITS_PER_CLUSTER", "FLAG_P",
           "SHAPE_TEST_DOF", "shape_p_values",
           "AxisPrior", "FleetPrior", "UnitFit", "fit_unit", "METHOD", "StationLimit",
           "fit_population", "Posterior", "posterior", "posterior_from_stats"]

PRIOR_SCHEMA = 1
#: Fewer calibrated units than this: no prior (a covariance of a cubic's three shape
#: coefficients from fewer units is mostly noise).
MIN_UNITS = 10
MAX_CLUSTERS = 6
#: A k-cluster mixture is tried only with at least this many units per cluster.
UNITS_PER_CLUSTER = 15
#: With at least this many residual degrees of freedom beyond the shape (a long test: a
#: climate cycle, a slow ramp), the flag tests the unit's own shape against the clusters
#: (:func:`posterior`); with fewer (a few soaks) the whole prior predictive.  Over hundreds of
#: points the whole predictive flags every unit whose points scatter a little more than the
#: fleet's median misfit (a climate-cycle unit of the prior's own fleet: p = 6e-6).
SHAPE_TEST_DOF = 10
#: A unit is flagged when its data are this unlikely under every cluster of the prior
#: (3.3 σ: a station judges thousands of units, and at 0.01 one good unit in a hundred would
#: fail by chance alone, more where the population is estimated from a few dozen units).
FLAG_P = 0.001
MAX_DEGREE = 5
#: What a prior file says it is (written into it).
METHOD = ("empirical Bayes: a Gaussian mixture over each axis's drift-curve shape in "
          "u = (T - t_ref) / scale, clusters chosen by BIC (one cluster: Ledoit-Wolf), "
          "runs' constants flat; conjugate posterior per cluster, reweighted by evidence")


# ------------------------------------------------------------------ limits
@dataclass
class StationLimit:
    """A station's pass/fail limits on one axis (None: not checked).

    ``max_residual``: held-out RMS of a unit's points (output unit); ``max_tempco``: the
    drift's slope at t_ref, |c₁| (output unit / °C); ``max_noise``: the standard deviation
    of the samples about their bin's mean (output unit)."""

    max_residual: float | None = None
    max_tempco: float | None = None
    max_noise: float | None = None

    def __post_init__(self) -> None:
        for name in ("max_residual", "max_tempco", "max_noise"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                                  or not math.isfinite(v) or v < 0):
                raise ConfigError(f"key '{name}': must be a finite number ≥ 0, got {v!r}")

    def checks(self, residual: float | None, tempco: float, noise: float, *,
               not_judged: str | None = None) -> list[dict[str, Any]]:
        """One check per limit set: ``{limit, value, max, ok}``.  No held-out residual (too
        few points to hold any out: ``not_judged`` says why) fails ``max_residual``: a limit
        set is a promise the unit was checked, and that check could not be made; the check
        then carries ``not_judged``."""
        out = []
        for name, value in (("max_residual", residual), ("max_tempco", abs(tempco)),
                            ("max_noise", noise)):
            lim = getattr(self, name)
            if lim is not None:
                out.append({"limit": name, "value": value, "max": lim,
                            "ok": value is not None and value <= lim})
                if value is None:
                    out[-1]["not_judged"] = not_judged or "no value"
        return out


# ------------------------------------------------------------------ one unit
@dataclass
class UnitFit:
    """A calibrated unit's shape on one axis (weighted least squares, runs' constants free)."""

    shape: np.ndarray          # (d,)
    cov: np.ndarray            # (d, d) estimation covariance
    misfit_var: float          # scatter of its bins about its curve beyond sampling
    n_points: int
    span_c: tuple[float, float]


def fit_unit(points: Points, *, t_ref: float, scale: float, degree: int) -> UnitFit:
    """The unit's own curve on its points (no prior): the fleet's raw material."""
    X = shape_design(points.temperature_c, t_ref, scale, degree)
    w = np.ones(points.value.size)
    Xc, yc = centred(X, points.value, w, points.run)
    dof = points.value.size - points.n_runs - degree
    if dof < 1:
        raise InputError(f"{points.value.size} points in {points.n_runs} runs cannot fit "
                         f"a degree-{degree} curve")
    beta, *_ = np.linalg.lstsq(Xc, yc, rcond=None)
    resid = yc - Xc @ beta
    s2 = float(resid @ resid / dof)
    cov = s2 * np.linalg.pinv(Xc.T @ Xc)
    misfit = max(s2 - float(np.mean(points.sampling_var)), 0.0)
    return UnitFit(beta, cov, misfit, int(points.value.size),
                   (float(points.temperature_c.min()), float(points.temperature_c.max())))


# ------------------------------------------------------------------ population
@dataclass
class AxisPrior:
    """One axis's population: a Gaussian mixture over the shape, and the misfit variance."""

    axis: str
    weights: np.ndarray        # (k,)
    means: np.ndarray          # (k, d)
    covs: np.ndarray           # (k, d, d)
    misfit_var: float
    sampling_var: float        # a typical bin's sampling variance in the fleet (for designs)
    n_units: int = 0           # the units it was estimated from (0: unknown)

    @property
    def n_clusters(self) -> int:
        return int(self.weights.size)

    def moment_matched(self) -> tuple[np.ndarray, np.ndarray]:
        """The mixture's mean and covariance (one Gaussian with its first two moments)."""
        mu = self.weights @ self.means
        d = self.means - mu
        cov = np.einsum("k,kij->ij", self.weights, self.covs) + \
            np.einsum("k,ki,kj->ij", self.weights, d, d)
        return mu, cov


def _bic_choice(z: np.ndarray, k_max: int) -> Any:
    from sklearn.mixture import GaussianMixture

    best, best_bic = None, math.inf
    for k in range(1, k_max + 1):
        gm = GaussianMixture(n_components=k, covariance_type="full", random_state=0,
                             n_init=3, reg_covar=1e-6)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")   # convergence chatter on tiny clusters
            gm.fit(z)
        bic = float(gm.bic(z))
        if bic < best_bic:
            best, best_bic = gm, bic
    return best


def fit_population(shapes: np.ndarray, *, max_clusters: int | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mixture weights, means and covariances of the units' shapes (``(units, d)``)."""
    from sklearn.covariance import LedoitWolf

    z = np.asarray(shapes, dtype=np.float64)
    n, d = z.shape
    if n < MIN_UNITS:
        raise InputError(f"a fleet prior needs at least {MIN_UNITS} calibrated units, got {n}")
    loc = np.median(z, axis=0)
    sc = np.std(z, axis=0)
    sc = np.where(sc > 0, sc, 1.0)
    zs = (z - loc) / sc                      # standardised: comparable columns for the GMM
    k_max = max(1, min(MAX_CLUSTERS if max_clusters is None else max_clusters,
                       n // UNITS_PER_CLUSTER))
    gm = _bic_choice(zs, k_max) if k_max > 1 else None
    if gm is None or gm.n_components == 1:
        lw = LedoitWolf().fit(zs)
        w, mu, cov = np.ones(1), lw.location_[None], lw.covariance_[None]
    else:
        w, mu, cov = gm.weights_, gm.means_, gm.covariances_
    means = mu * sc + loc
    covs = cov * np.outer(sc, sc)[None]
    return np.asarray(w, dtype=np.float64), means, covs


# ------------------------------------------------------------------ the prior
@dataclass
class FleetPrior:
    """The prior of a sensor type: per axis a mixture over the drift curve's shape."""

    axes: list[AxisPrior]
    degree: int
    t_ref: float
    scale: float
    range_c: tuple[float, float]
    units: dict[str, str]                     # axis -> unit of measure
    targets: dict[str, str]                   # axis -> target mode
    n_units: int
    unit_ids: list[str]
    excluded: dict[str, str] = field(default_factory=dict)   # unit id -> why
    source: str = ""
    bin_c: float = BIN_C
    #: how many of its units ran each kind of test (:func:`~thermonet.scoring.prior_points.
    #: kind_of_test`); empty in a prior written before it was recorded
    test_kinds: dict[str, int] = field(default_factory=dict)
    #: the fleet's short test (:mod:`thermonet.scoring.prior_map`), where its pilot units
    #: ran one beside their calibration; None otherwise
    test_map: TestMap | None = None

    def axis(self, name: str) -> AxisPrior:
        return next(a for a in self.axes if a.axis == name)

    @property
    def axis_names(self) -> list[str]:
        return [a.axis for a in self.axes]

    def not_comparable(self, kind: str) -> str | None:
        """Why a unit whose test is of ``kind`` cannot be compared with this fleet, or None.

        A fast ramp's points pair heating with cooling above 1.2 °C/min
        (:func:`~thermonet.scoring.prior_points.bin_points`): the pair cancels the
        thermometer's lag to first order, not the change of its rate, so its shape carries
        an error no slow test's points do, and the reverse.  bench_prior (50 units, 40 new
        of the fleet): a prior of full soak sweeps flags 100 % of their 40-min up-and-downs
        (fast ramps); a prior of those flags 100 % of their 3-soak tests and 17.5 % of their
        climate cycles; within a side, 0–2.5 % (soaks, slow cycles at 1 °C/min and ramps are
        compared with one another).  So a fast test is compared only with a prior that holds
        fast tests, a slow one only with a prior that holds slow ones.  A prior that does not
        record its tests compares every unit, as before."""
        if not self.test_kinds or kind in self.test_kinds:
            return None
        fast = {k == FAST_KIND for k in self.test_kinds}
        if (kind == FAST_KIND) in fast:
            return None
        return (f"a test of {kind}, where the prior's units ran {self.kinds_text()}: a fast "
                "ramp's paired points carry a lag error a slow test's do not (build the prior "
                "from the station's test)")

    def kinds_text(self) -> str:
        """The prior's tests, e.g. "soaks (200 units)"; "" where it does not record them."""
        return ", ".join(f"{k} ({counted(n, 'unit')})" for k, n in self.test_kinds.items())

    def physical(self, shape: np.ndarray) -> list[float]:
        """Coefficients c1 … cd of (T − t_ref)^k from a shape in normalised u."""
        return [float(shape[k - 1]) / self.scale ** k for k in range(1, self.degree + 1)]

    def to_dict(self) -> dict[str, Any]:
        return {"schema": PRIOR_SCHEMA, "kind": "fleet-prior", "degree": self.degree,
                "t_ref_c": self.t_ref, "scale_c": self.scale, "range_c": list(self.range_c),
                "bin_c": self.bin_c, "units_of_measure": self.units, "targets": self.targets,
                "n_units": self.n_units, "unit_ids": self.unit_ids, "excluded": self.excluded,
                "source": self.source, "method": METHOD, "test_kinds": self.test_kinds,
                "axes": {a.axis: {"weights": a.weights.tolist(), "means": a.means.tolist(),
                                  "covs": a.covs.tolist(), "misfit_var": a.misfit_var,
                                  "sampling_var": a.sampling_var} for a in self.axes},
                "short_test": None if self.test_map is None else self.test_map.to_dict()}


# ------------------------------------------------------------------ the posterior
@dataclass
class Posterior:
    """A unit's posterior on one axis: a mixture over its shape, and how well it fits."""

    weights: np.ndarray
    means: np.ndarray
    covs: np.ndarray
    p_values: np.ndarray       # per cluster: P(χ² ≥ d²) under the prior predictive
    dof: int

    @property
    def shape(self) -> np.ndarray:
        return np.asarray(self.weights @ self.means)

    @property
    def cov(self) -> np.ndarray:
        d = self.means - self.shape
        return np.asarray(np.einsum("k,kij->ij", self.weights, self.covs) +
                          np.einsum("k,ki,kj->ij", self.weights, d, d))

    @property
    def p_value(self) -> float | None:
        """The best cluster's p-value (None: too few points to judge)."""
        return float(self.p_values.max()) if self.dof >= 1 else None

    @property
    def flagged(self) -> bool:
        p = self.p_value
        return p is not None and p < FLAG_P


def _weights_var(prior: AxisPrior, points: Points) -> np.ndarray:
    return 1.0 / (prior.misfit_var + points.sampling_var + 1e-300)


def posterior(prior: AxisPrior, points: Points, *, t_ref: float, scale: float) -> Posterior:
    """The unit's posterior given its points (see the module docstring)."""
    X = shape_design(points.temperature_c, t_ref, scale, prior.means.shape[1])
    w = _weights_var(prior, points)
    Xc, yc = centred(X, points.value, w, points.run)
    return posterior_from_stats(prior, Xc.T @ (w[:, None] * Xc), Xc.T @ (w * yc),
                                float(yc @ (w * yc)), int(points.value.size - points.n_runs))


def posterior_from_stats(prior: AxisPrior, J: np.ndarray, b: np.ndarray, q0: float,
                         dof: int) -> Posterior:
    """The posterior from a weighted design's sufficient statistics ``J = XᵀWX``,
    ``b = XᵀWy``, ``q0 = yᵀWy`` (constants profiled out) and its residual degrees of
    freedom: the points' (:func:`posterior`) or a short test's through the fleet's map
    (:meth:`thermonet.scoring.prior_map.TestMap.stats`)."""
    from scipy.stats import chi2

    d = prior.means.shape[1]
    logev, means, covs, d2 = [], [], [], []
    for mu, S in zip(prior.means, prior.covs, strict=True):
        Si = np.linalg.inv(S)
        A = Si + J
        Ai = np.linalg.inv(A)
        m = Ai @ (Si @ mu + b)
        q = q0 + float(mu @ Si @ mu) - float(m @ A @ m)
        _, ld_s = np.linalg.slogdet(S)
        _, ld_a = np.linalg.slogdet(A)
        logev.append(-0.5 * (q + ld_s + ld_a))
        means.append(m)
        covs.append((Ai + Ai.T) / 2)
        d2.append(max(q, 0.0))
    lw = np.log(prior.weights) + np.asarray(logev)
    wpost = np.exp(lw - lw.max())
    p = chi2.sf(np.asarray(d2), max(dof, 1)) if dof >= 1 else np.ones(len(d2))
    if dof - d >= SHAPE_TEST_DOF:
        p = _shape_p_values(prior, J, b, q0, dof - d)
    return Posterior(wpost / wpost.sum(), np.asarray(means), np.asarray(covs),
                     np.asarray(p, dtype=np.float64), dof)


def _shape_p_values(prior: AxisPrior, J: np.ndarray, b: np.ndarray, q0: float, dof_r: int
                    ) -> np.ndarray:
    """Per cluster, the p-value of the unit's own shape's distance from it: the shape
    β̂ = J⁻¹b with its covariance max(s², 1)·J⁻¹ (s²: the unit's residual over its assumed
    point errors, per degree of freedom — a unit that scatters more than the fleet's median
    misfit has a less certain shape, not a different one): :func:`shape_p_values`."""
    Ji = np.linalg.inv(J)
    beta = Ji @ b
    s2 = max((q0 - float(beta @ b)) / dof_r, 1.0)
    return shape_p_values(prior, beta, s2 * Ji)


def shape_p_values(prior: AxisPrior, shape: np.ndarray, cov: np.ndarray, *,
                   predictive: bool = True) -> np.ndarray:
    """Per cluster k, how unlike cluster k a unit's shape β (estimation covariance C) is:
    D² = (β − μ_k)ᵀ(Σ_k + C)⁻¹(β − μ_k) (the station's flag on a long test, and which units a
    prior takes back).

    μ_k and Σ_k are estimated from the cluster's n_k units (its weight × the prior's units),
    so a new unit's D² is Hotelling's, not χ²: n/(n+1)·D² ~ T²(d, n − 1), i.e.
    n(n − d)/(d(n − 1)(n + 1))·D² ~ F(d, n − d) (the prediction region of a new draw from a
    normal of estimated mean and covariance; Chew, JASA 61, 1966, §3).  With n_k = 16 and
    d = 3, the 0.1 % point of D² is 37.5, where χ²₃'s is 16.3: the χ² test flagged 10 % of a
    fleet's own units on their climate cycle (bench_prior, 50 units in 3 clusters).  A
    prior that does not say how many units it holds (``n_units`` 0) is judged on χ²; so is
    a unit the prior would take back (``predictive=False``: a small cluster's wide region
    would let an outlier into the population every later unit is judged by)."""
    from scipy.stats import chi2, f

    out = []
    for w, mu, S in zip(prior.weights, prior.means, prior.covs, strict=True):
        diff = np.asarray(shape) - mu
        d2, d = float(diff @ np.linalg.solve(S + cov, diff)), mu.size
        n = float(w) * prior.n_units
        if predictive and n > d + 1:
            out.append(float(f.sf(n * (n - d) / (d * (n - 1) * (n + 1)) * d2, d, n - d)))
        else:
            out.append(float(chi2.sf(d2, d)))
    return np.asarray(out)
