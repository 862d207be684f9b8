"""Split strategies: every registered one keeps its roles apart and never samples at random."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import toy_dataset
from thermonet.core.errors import ConfigError
from thermonet.training.config import SplitConfig, from_dict
from thermonet.training.splits import SPLITS, Split, make_splits, register_split


def _keys(recs) -> set[float]:
    """Sample identities: the toy runs' temperatures are distinct across runs and samples."""
    return {float(v) for r in recs for v in np.round(r.temperature_c, 9)}


@pytest.mark.parametrize("name", list(SPLITS))
def test_every_strategy_keeps_train_val_test_apart(name):
    worked = 0
    for n_runs in (1, 2, 3, 4):
        ds = toy_dataset(n_runs=n_runs)
        try:
            splits = make_splits(ds, SplitConfig(strategy=name, n_blocks=10))
        except ConfigError as err:  # a strategy may need more (or exactly) so many runs
            assert "split.strategy" in str(err)
            continue
        worked += 1
        for s in splits:
            train, test = _keys(s.train), _keys([s.test])
            val = _keys([s.val]) if s.val is not None else set()
            assert train and test
            assert not train & test and not train & val and not val & test
            # every sample goes to one role at most; nothing is invented
            assert train | val | test <= _keys(ds)
    assert worked, f"strategy {name!r} split none of 1..4 runs"


def test_time_blocks_hold_out_contiguous_stretches_over_the_whole_range():
    ds = toy_dataset(n_runs=1)
    split, = make_splits(ds, SplitConfig(strategy="time-blocks", n_blocks=10))
    t = split.test.time_s
    # two held-out blocks of 720 s each (one in every group of five), each contiguous
    gaps = np.flatnonzero(np.diff(t) > 1.5)
    assert gaps.size == 1
    assert np.ptp(split.test.temperature_c) > 0.5 * np.ptp(ds[0].temperature_c)


def test_unknown_strategy_names_the_registered_ones(tmp_path):
    with pytest.raises(ConfigError, match=r"c\.yaml: key 'split\.strategy': 'random' is not one "
                                          r"of 'auto', .*'time-blocks'"):
        from_dict(SplitConfig, {"strategy": "random"}, source="c.yaml", prefix="split")


def test_a_registered_strategy_is_usable_from_a_config():
    @register_split("last-run-only-test")
    def _toy(runs, cfg, source):
        return [Split(runs[:-1], None, runs[-1], "toy", {"test": runs[-1].run_id})]

    try:
        cfg = from_dict(SplitConfig, {"strategy": "last-run-only-test"}, prefix="split")
        split, = make_splits(toy_dataset(n_runs=3), cfg)
        assert split.test.run_id == "run2" and [r.run_id for r in split.train] == ["run0", "run1"]
        with pytest.raises(ValueError, match="already registered"):
            register_split("last-run-only-test")(_toy)
    finally:
        SPLITS.pop("last-run-only-test")
