"""The one deal of rows to cross-validation folds, and the purge around a validation fold.

Two callers split data for cross-validation and both use this module, so a fold means the same
thing everywhere:

* ``compare``'s model selection (:func:`thermonet.scoring.selection.plan_folds`): the samples
  of every pool run, labelled by their contiguous time block (or one label per run when whole
  runs are the folds), purged by :func:`purged` around each validation fold;
* the API's scikit-learn cross-validator (:class:`thermonet.api.cv.TimeBlockSplit`, a
  ``BaseCrossValidator``): rows that are whole runs or blocks cut by
  :func:`thermonet.api.time_blocks`, which leaves the purge out between adjacent blocks.

The deal (:func:`deal`): block ``b`` of the ``r``-th run goes to fold ``(b + r) mod k`` —
round-robin over the folds, shifted by the run so that every fold sees every run's start and
end; a whole run (block 0) is fold ``r mod k`` (leave one run out when ``k`` is the number of
runs).  It is the ``test_fold`` of scikit-learn's ``PredefinedSplit`` (fold ``f`` validates
where the label is ``f``; ``-1`` is never validated), computed with numpy alone: this module
and its callers in ``compare`` do not import scikit-learn (seconds of start-up).  Never
random: the same rows give the same folds.
"""

from __future__ import annotations

import numpy as np

__all__ = ["deal", "purged"]


def deal(block: np.ndarray | int, run: np.ndarray | int, k: int) -> np.ndarray:
    """The fold of each row: ``(block + run) mod k`` (block and run numbers count from 0)."""
    return np.asarray((np.asarray(block) + np.asarray(run)) % int(k))


def purged(t: np.ndarray, val: np.ndarray, purge_s: float) -> np.ndarray:
    """Samples of one run (times ``t``, ascending) within ``purge_s`` seconds of a validation
    sample (mask ``val``), the validation samples included: what a fold's training leaves
    out so that validation does not leak into training through the dynamic inputs' memory."""
    if not val.any():
        return np.zeros(t.size, dtype=bool)
    tv = t[val]
    i = np.clip(np.searchsorted(tv, t), 1, tv.size - 1) if tv.size > 1 else np.zeros(t.size, int)
    d = np.abs(t - tv[i])
    if tv.size > 1:
        d = np.minimum(d, np.abs(t - tv[i - 1]))
    return (d <= purge_s) | val
