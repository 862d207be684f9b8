""":class:`TimeBlockSplit`: the scikit-learn cross-validator over time blocks or whole runs.

A ``sklearn.model_selection.BaseCrossValidator`` (so ``GridSearchCV``, ``cross_val_score``
and ``check_cv`` take it as one of their own) whose folds are those of ``compare``'s model
selection: both call :func:`thermonet.scoring.folds.deal`.  The purge between adjacent blocks
is :func:`thermonet.api.time_blocks`'s ``purge_s`` (a row is a whole block, so the gap is cut
when the blocks are made); compare's own plan purges samples with
:func:`thermonet.scoring.folds.purged`.

This module imports scikit-learn (about a second): :mod:`thermonet.api` and
:mod:`thermonet.api.splits` load it only when ``TimeBlockSplit`` is first used.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
from sklearn.model_selection import BaseCrossValidator

from ..core.errors import ConfigError
from ..core.recording import Recording
from ..scoring.folds import deal
from .checks import whole
from .data import BLOCK_INDEX, BLOCK_RUN, runs_of

__all__ = ["TimeBlockSplit"]


class TimeBlockSplit(BaseCrossValidator):
    """scikit-learn cross-validation splitter over recordings: time blocks or whole runs.

    Rows of ``X`` cut by :func:`~thermonet.api.time_blocks` go to fold ``(block index + run
    number) mod n_splits`` (``compare``'s deal, :func:`thermonet.scoring.folds.deal`); rows
    that are whole runs go to fold ``run number mod n_splits`` (with ``n_splits`` ≥ the number
    of runs: leave one run out).  Never random: the same ``X`` gives the same folds.
    ``groups`` is ignored (the blocks are the groups).

    Parameters
    ----------
    n_splits : int
        Folds: a whole number ≥ 2 (``True`` is no number), checked when the splitter is
        made.
    """

    def __init__(self, n_splits: int = 5) -> None:
        self.n_splits = n_splits
        self._check()          # a splitter checks at once (scikit-learn's KFold does too)

    def __repr__(self) -> str:
        return f"TimeBlockSplit(n_splits={self.n_splits!r})"

    def get_n_splits(self, X: Any = None, y: Any = None, groups: Any = None) -> int:
        """The number of folds (:meth:`split` yields this many)."""
        self._check()
        return int(self.n_splits)

    def _check(self) -> None:
        whole(self.n_splits, "TimeBlockSplit(n_splits)", 2, 100_000)

    def folds(self, X: Sequence[Recording]) -> np.ndarray:
        """The fold of each row of ``X``."""
        self._check()
        rows = runs_of(X, "TimeBlockSplit.split(X)")
        run_no: dict[str, int] = {}
        block = np.empty(len(rows), dtype=int)
        run = np.empty(len(rows), dtype=int)
        for i, r in enumerate(rows):
            run[i] = run_no.setdefault(r.meta.get(BLOCK_RUN, r.run_id), len(run_no))
            index = r.meta.get(BLOCK_INDEX)
            block[i] = int(index) if index is not None else 0      # a whole run: one block
        fold = deal(block, run, int(self.n_splits))
        missing = sorted(set(range(int(self.n_splits))) - set(fold.tolist()))
        if missing:
            raise ConfigError(f"TimeBlockSplit: {len(rows)} rows (runs or blocks) leave fold "
                              f"{missing[0]} of {self.n_splits} empty; cut the runs with "
                              "thermonet.time_blocks or use fewer splits")
        return fold

    def _iter_test_masks(self, X: Any = None, y: Any = None, groups: Any = None
                         ) -> Iterator[np.ndarray]:
        """Each fold's validation rows, as a boolean mask over ``X`` (scikit-learn's hook)."""
        fold = self.folds(X)
        for f in range(int(self.n_splits)):
            yield fold == f

    def split(self, X: Sequence[Recording], y: Any = None, groups: Any = None
              ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """``(train rows, validation rows)`` per fold, as index arrays into ``X``.

        ``X`` is read as runs first (a Dataset, a Recording or a list of them; anything else
        is refused in one line), then split by scikit-learn's own ``split``."""
        yield from super().split(runs_of(X, "TimeBlockSplit.split(X)"), y, groups)
