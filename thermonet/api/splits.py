"""Time blocks and a scikit-learn splitter over them: hyper-parameter searches that never
shuffle samples.

scikit-learn's model-selection tools (``cross_val_score``, ``GridSearchCV``) index the rows of
``X``; for a :class:`~thermonet.api.DriftEstimator` a row is one :class:`Recording` — a whole
run, or a contiguous block of one cut by :func:`time_blocks`.  :class:`TimeBlockSplit` deals
the rows to folds the way ``compare``'s model selection does
(:func:`thermonet.scoring.selection.plan_folds`): blocks round-robin over the folds, shifted by
the run, so every fold's validation blocks sample the whole temperature history; whole runs
one fold per run (leave one run out) when ``X`` is runs.  A sample is never separated from
its block, and adjacent blocks are separated by ``purge_s`` seconds cut away from both:

* residuals are correlated over minutes, so a validation block scored next to a training
  block that touches it looks better than the model is;
* dynamic inputs (``rate``, ``lag_<tau>``) carry state: each block's restart at its own start
  (its first ``3 τ`` are warm-up) — choose ``purge_s`` ≥ 3 τ for such inputs.

Example::

    from sklearn.model_selection import GridSearchCV
    blocks = thermonet.time_blocks(ds, n_blocks=40, purge_s=60)
    search = GridSearchCV(thermonet.DriftEstimator("poly", "dT"), {"degree": [1, 2, 3, 4]},
                          cv=thermonet.TimeBlockSplit(n_splits=5)).fit(blocks)
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.recording import Recording
from .data import BLOCK_RUN

__all__ = ["time_blocks", "TimeBlockSplit"]

#: ``meta`` key of a block's index in its run (:data:`BLOCK_RUN` names the run).
BLOCK_INDEX = "block_index"


def time_blocks(data: Any, n_blocks: int = 40, *, purge_s: float = 0.0) -> list[Recording]:
    """Every run of ``data`` cut by time into ``n_blocks`` contiguous blocks of equal
    duration, in run order then time order, ``purge_s`` seconds left out between adjacent
    blocks (half from each side; at most half a block).

    Each block is a :class:`Recording` named ``<run>[b<k>]`` whose ``meta`` names its run
    (``block_of_run``) and index (``block_index``), which :class:`TimeBlockSplit` reads.
    """
    from .checks import seconds, whole
    from .data import runs_of

    n_blocks = int(whole(n_blocks, "time_blocks(n_blocks)", 2, 100_000))  # type: ignore[arg-type]
    purge_s = float(seconds(purge_s, "time_blocks(purge_s)", lo_open=False))  # type: ignore[arg-type]
    out = []
    for rec in runs_of(data, "time_blocks(data)"):
        t = np.asarray(rec.time_s, dtype=np.float64)
        span = max(float(t[-1] - t[0]), 1e-12)
        width = span / n_blocks
        cut = min(0.5 * float(purge_s), 0.25 * width)      # from each side of a boundary
        block = np.minimum(((t - t[0]) / span * n_blocks).astype(int), n_blocks - 1)
        start = t[0] + block * width
        keep = np.ones(t.size, dtype=bool)
        if cut > 0:
            keep = ((t - start >= cut) | (block == 0)) & \
                ((start + width - t > cut) | (block == n_blocks - 1))
        for k in range(n_blocks):
            m = keep & (block == k)
            if m.sum() < 10:
                raise ConfigError(f"time_blocks: run '{rec.run_id}' has {int(m.sum())} samples "
                                  f"in block {k} of {n_blocks} (need 10; use fewer blocks)")
            b = rec.select(m, run_id=f"{rec.run_id}[b{k}]")
            b.meta = {**b.meta, BLOCK_RUN: rec.run_id, BLOCK_INDEX: str(k)}
            out.append(b)
    return out


class TimeBlockSplit:
    """scikit-learn cross-validation splitter over recordings: time blocks or whole runs.

    Rows of ``X`` cut by :func:`time_blocks` go to fold ``(block index + run number) mod
    n_splits`` (``compare``'s deal); rows that are whole runs go to fold ``run number mod
    n_splits`` (with ``n_splits`` ≥ the number of runs: leave one run out).  Never random:
    the same ``X`` gives the same folds.  ``groups`` is ignored (the blocks are the groups).

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
        from .checks import whole

        whole(self.n_splits, "TimeBlockSplit(n_splits)", 2, 100_000)

    def folds(self, X: Sequence[Recording]) -> np.ndarray:
        """The fold of each row of ``X``."""
        from .data import runs_of

        self._check()
        rows = runs_of(X, "TimeBlockSplit.split(X)")
        run_no: dict[str, int] = {}
        fold = np.empty(len(rows), dtype=int)
        for i, r in enumerate(rows):
            run = r.meta.get(BLOCK_RUN, r.run_id)
            j = run_no.setdefault(run, len(run_no))
            index = r.meta.get(BLOCK_INDEX)
            fold[i] = ((int(index) if index is not None else 0) + j) % int(self.n_splits)
        missing = sorted(set(range(int(self.n_splits))) - set(fold.tolist()))
        if missing:
            raise ConfigError(f"TimeBlockSplit: {len(rows)} rows (runs or blocks) leave fold "
                              f"{missing[0]} of {self.n_splits} empty; cut the runs with "
                              "thermonet.time_blocks or use fewer splits")
        return fold

    def split(self, X: Sequence[Recording], y: Any = None, groups: Any = None
              ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """``(train rows, validation rows)`` per fold, as index arrays into ``X``."""
        fold = self.folds(X)
        idx = np.arange(fold.size)
        for f in range(int(self.n_splits)):
            yield idx[fold != f], idx[fold == f]
