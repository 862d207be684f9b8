"""The one cross-validation deal (thermonet.scoring.folds): compare's plan_folds and the API's
TimeBlockSplit, a scikit-learn BaseCrossValidator, give the same rows the same folds."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from sklearn.model_selection import BaseCrossValidator, check_cv

import thermonet
from conftest import toy_dataset
from thermonet.scoring.fold_plan import plan_folds
from thermonet.scoring.folds import deal, purged

pytestmark = pytest.mark.numerics


def test_the_deal_is_round_robin_shifted_by_the_run():
    # written out by hand: run 0's blocks 0..6 over 3 folds, run 2's shifted by two
    np.testing.assert_array_equal(deal(np.arange(7), 0, 3), [0, 1, 2, 0, 1, 2, 0])
    np.testing.assert_array_equal(deal(np.arange(7), 2, 3), [2, 0, 1, 2, 0, 1, 2])
    np.testing.assert_array_equal(deal(0, np.arange(4), 4), [0, 1, 2, 3])   # whole runs


def test_purge_leaves_out_what_lies_within_purge_s_of_validation():
    t = np.arange(20, dtype=float)
    val = (t >= 8) & (t <= 10)
    # brute force: distance to the nearest validation sample
    d = np.abs(t[:, None] - t[val][None, :]).min(axis=1)
    np.testing.assert_array_equal(purged(t, val, 2.0), d <= 2.0)
    assert purged(t, np.zeros(20, bool), 5.0).sum() == 0


def test_time_block_split_is_a_scikit_learn_cross_validator():
    cv = thermonet.TimeBlockSplit(n_splits=3)
    assert isinstance(cv, BaseCrossValidator)
    assert check_cv(cv) is cv                    # scikit-learn takes it as its own
    assert repr(cv) == "TimeBlockSplit(n_splits=3)"
    assert thermonet.api.splits.TimeBlockSplit is thermonet.TimeBlockSplit


def test_the_api_and_compare_deal_the_same_block_to_the_same_fold():
    """One run cut into 40 blocks: TimeBlockSplit's fold of each block is plan_folds' fold of
    the samples in the middle of that block (no purge, no test rows: the same blocks)."""
    ds = toy_dataset(n_runs=2, noise=0.002)
    blocks = thermonet.time_blocks(ds, n_blocks=40)
    api_fold = thermonet.TimeBlockSplit(n_splits=5).folds(blocks)
    pool = [(r, np.ones(r.n_samples, dtype=bool)) for r in ds.runs]
    plan = plan_folds(pool, folds=5, blocks_per_fold=8, tau_s=0.0, by_run=False)
    assert plan is not None and plan.kind == "blocks"
    for i, b in enumerate(blocks):
        j = i // 40                                         # the run the block was cut from
        mid = np.searchsorted(ds.runs[j].time_s, b.time_s[b.n_samples // 2])
        assert plan.fold_of[j][mid] == api_fold[i] == (i % 40 + j) % 5


def test_importing_the_api_does_not_import_scikit_learn():
    code = ("import sys, thermonet.api, thermonet.api.splits, thermonet.scoring.selection; "
            "print(sorted(m for m in ('sklearn', 'torch') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"
