"""The researcher's Python API: :class:`DriftEstimator`, :func:`compare`, :func:`simulate`,
:func:`read`, :func:`time_blocks` and :class:`TimeBlockSplit`.

A drift model in the scikit-learn / lmfit mould::

    import thermonet

    from thermonet.api import Poly             # the family specs (thermonet.models.specs)

    ds = thermonet.simulate("patent-gyro", runs=3, seed=0)
    est = thermonet.DriftEstimator(Poly(degree=3), "dT").fit(ds[0], val=ds[1])
    drift = est.predict(ds[2])                 # (N, axes), in the outputs' units
    print(est.score(ds[2]))                    # 1 − error variance after / before, axis mean
    print(est.parameters_)                     # axis, name, value, stderr, unit, note
    est.save("cubic.pt")
    est.export("cubic.onnx", format="onnx")

The estimator (:mod:`thermonet.api.estimator`)
    The constructor only stores its arguments: the family — a spec such as
    ``Poly(degree=3)`` (:mod:`thermonet.models.specs`, one torch-free class per family with
    its hyper-parameters as keywords) or a name (``"poly"``: its spec with the defaults;
    ``DriftEstimator("poly", degree=3)`` is shorthand for the spec) —, the inputs, the target
    and feature settings and every field of :class:`~thermonet.TrainConfig` as a keyword of
    its own (``seed=3``, ``max_epochs=50``) — all listed by ``get_params()`` (the family's
    hyper-parameters nested: ``family__degree``), set by ``set_params()``, copied by
    :func:`sklearn.base.clone` (scikit-learn's ``BaseEstimator`` protocol, without importing
    scikit-learn: :mod:`thermonet.core.params`).  :meth:`~DriftEstimator.fit` checks them (an error names the
    argument and value), resolves the feature references from the training runs, builds each
    run's signals and targets and fits through the one split pipeline
    (:mod:`thermonet.training.pipeline`, what ``compare`` runs), with the targets resolved as
    ``compare`` resolves them (:mod:`thermonet.features.target`: a reference channel, else
    zero for a gyro, else the change from :math:`T_{ref}` — gravity is no drift).  Learned
    state ends in ``_``.
    ``fit``, ``predict``, ``score`` and ``compensate`` each take a Recording, a list of them
    or a Dataset.  Guards: the training runs must span at least 1 °C and share units (as
    ``compare`` checks the data it reads); a validation run that is also a training run, and
    scoring or compensating data in another unit than the training data, are refused, naming
    the run and both units.  ``fit(..., val=...)`` records ``compare``'s validation score
    (``val_score_``); ``fit(..., track=True)`` logs the fit to MLflow (``mlflow_run_id_``);
    saves and exports carry the data digest, the validation score and the run id.

Parameters with uncertainties (:mod:`thermonet.api.parameters`)
    ``est.parameters_`` is a pandas table ``axis, name, value, stderr, unit, note``: a polynomial's
    ``c0 … cN`` in output unit / °C^k about :math:`T_{ref}` with least-squares standard
    errors (``est.covariance_`` holds the matrices; the residuals of a time series are
    correlated, so read them as a lower bound — the module says how much), Lorentz and RBF
    parameters in physical units, other families' stored parameters (not physical; stderr
    NaN, ``note`` says why; where computed, ``note`` names the method, ``ols`` or
    ``block-bootstrap``, and ``within 2 SE of zero``).  Standard errors and covariance are sealed into the checkpoint:
    ``DriftEstimator.load`` and ``compare``'s estimators state the fit's.
    ``est.report()`` is the fit report as text.

Hyper-parameter searches (:mod:`thermonet.api.splits`)
    scikit-learn's ``GridSearchCV`` and ``cross_val_score`` work on a DriftEstimator whose
    ``X`` is a list of recordings — whole runs, or contiguous time blocks cut by
    :func:`time_blocks` — split by :class:`TimeBlockSplit` (:mod:`thermonet.api.cv`, a scikit-learn
    ``BaseCrossValidator``: blocks dealt round-robin to the folds by the deal ``compare``'s
    model selection uses, :func:`thermonet.scoring.folds.deal`; never random samples)::

        from sklearn.model_selection import GridSearchCV
        blocks = thermonet.time_blocks(ds, n_blocks=40, purge_s=60)
        search = GridSearchCV(thermonet.DriftEstimator("poly", "dT"),
                              {"family__degree": [1, 2, 3, 4]},
                              cv=thermonet.TimeBlockSplit(n_splits=5)).fit(blocks)
        search.best_params_

    The score is :meth:`DriftEstimator.score` (``compare``'s offset-free score: the fraction
    of the error's variance removed, each source run about its own mean, so the blocks of a
    fold count as their run); scikit-learn's ``y`` is None throughout (the drift is in the
    recordings).

Comparisons (:mod:`thermonet.api.comparison`)
    ``thermonet.compare(config, data=None, out=None, track=False)`` runs ``thermonet
    compare``'s workflow and returns a :class:`ComparisonResult` (``.chosen``,
    ``.families[name].axes[axis]``, ``.warnings``, ``.scores()``, ``.table()``,
    ``.estimator(name)``); files are written only where ``out`` is given.

Arguments checked at the door (:mod:`thermonet.api.checks`)
    Every public function and class checks its arguments before it opens a file, reads or
    reduces data or builds a model, and refuses a bad one in one line naming it — a
    ``ConfigError`` (a ``ValueError``) that is also a ``TypeError`` when the type is wrong:
    ``read(paths, mapping, window_s=, inputs=, gap_s=, chunk_rows=)``, ``simulate(preset,
    runs, seed)``, ``compare(config, data, out, track, tracking_uri=, overwrite=, plots=,
    workers=, quiet=)``, ``DriftEstimator.fit`` (every constructor argument, the family's
    hyper-parameter names *and values*, and ``track``/``tracking_uri``/``experiment``),
    ``time_blocks(n_blocks, purge_s)`` and ``TimeBlockSplit(n_splits)`` (when made).  The
    rules: ``bool`` is not a number (``window_s=True`` is refused, not 1 s); ``track``,
    ``overwrite``, ``plots`` and ``quiet`` are ``True`` or ``False`` — ``track="no"`` is
    refused, never read as true, and the MLflow store is ``tracking_uri``; ``workers`` is a
    whole number >= 1, ``0`` for one per CPU, or None for the config's; a path is a ``str``
    or ``os.PathLike``; ``inputs`` is a list of known input names or one name alone
    (``"dT"`` is ``["dT"]``, never ``["d", "T"]``).  The estimator's constructor only stores
    (scikit-learn's rule: ``set_params`` and ``clone`` never raise on a value); its
    :meth:`~DriftEstimator.fit` checks first.

A saved estimator is an ordinary thermonet checkpoint (``thermonet export`` reads it).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ..models.specs import GRU, MLP, RBF, FamilySpec, Fuzzy, Linear, Lorentz, Poly
from .comparison import AxisSummary, ComparisonResult, FamilySummary, compare
from .data import read, simulate
from .estimator import DriftEstimator
from .fitted import NotFittedError
from .splits import time_blocks

if TYPE_CHECKING:
    from .cv import TimeBlockSplit

__all__ = ["DriftEstimator", "NotFittedError", "simulate", "read", "compare",
           "ComparisonResult", "FamilySummary", "AxisSummary", "time_blocks", "TimeBlockSplit",
           "FamilySpec", "Linear", "Poly", "Lorentz", "Fuzzy", "RBF", "MLP", "GRU"]


def __getattr__(name: str) -> Any:
    """:class:`TimeBlockSplit` on first access (a scikit-learn ``BaseCrossValidator``:
    :mod:`thermonet.api.cv`), so ``import thermonet.api`` does not import scikit-learn."""
    if name == "TimeBlockSplit":
        from .cv import TimeBlockSplit  # lazy: scikit-learn costs about a second to import
        return TimeBlockSplit
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
