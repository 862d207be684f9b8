"""Time blocks and a scikit-learn splitter over them: hyper-parameter searches that never
shuffle samples.

scikit-learn's model-selection tools (``cross_val_score``, ``GridSearchCV``) index the rows of
``X``; for a :class:`~thermonet.api.DriftEstimator` a row is one :class:`Recording` — a whole
run, or a contiguous block of one cut by :func:`time_blocks`.  :class:`TimeBlockSplit` deals
the rows to folds the way ``compare``'s model selection does
(:func:`thermonet.scoring.fold_plan.plan_folds`): blocks round-robin over the folds, shifted by
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

from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ConfigError
from ..core.recording import Recording
from .checks import seconds, whole
from .data import BLOCK_INDEX, BLOCK_RUN, runs_of

if TYPE_CHECKING:
    from .cv import TimeBlockSplit

__all__ = ["time_blocks", "TimeBlockSplit"]

def time_blocks(data: Any, n_blocks: int = 40, *, purge_s: float = 0.0) -> list[Recording]:
    """Every run of ``data`` cut by time into ``n_blocks`` contiguous blocks of equal
    duration, in run order then time order, ``purge_s`` seconds left out between adjacent
    blocks (half from each side; at most half a block).

    Each block is a :class:`Recording` named ``<run>[b<k>]`` whose ``meta`` names its run
    (``block_of_run``) and index (``block_index``), which :class:`TimeBlockSplit` reads.
    """
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


def __getattr__(name: str) -> Any:
    """:class:`TimeBlockSplit` on first access: it is a scikit-learn ``BaseCrossValidator``
    (:mod:`thermonet.api.cv`), and importing scikit-learn costs about a second, which
    ``import thermonet.api`` and :func:`time_blocks` do not pay."""
    if name == "TimeBlockSplit":
        from .cv import TimeBlockSplit  # lazy: scikit-learn only when the splitter is used
        return TimeBlockSplit
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
