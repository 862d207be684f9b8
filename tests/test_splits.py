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


def test_time_block_parts_carry_the_dynamic_state_into_every_block():
    """A time-block split's parts are rows of the whole run (``Split.whole``): the rate and
    the hysteresis state at the first row of a held-out block are the whole run's there, as
    the board computes them, not restarted as on the carved block; the rows, times and
    targets are the carved blocks' exactly."""
    from thermonet.core.recording import Dataset, Recording
    from thermonet.features.inputs import FeatureSpec
    from thermonet.training.parts import build_part
    from thermonet.training.pipeline import split_parts

    t = np.arange(0.0, 7200.0, 1.0)
    temp = 20.0 + 30.0 * np.sin(2 * np.pi * t / 3600.0)
    rng = np.random.default_rng(0)
    recs = [Recording(time_s=t, temperature_c=temp + rng.normal(0, 0.01, t.size),
                      outputs={"gyro_x": 0.01 * temp + rng.normal(0, 1e-3, t.size)},
                      units={"gyro_x": "deg/s"}, run_id=f"r{i}", sample_rate_hz=1.0)
            for i in range(2)]
    (split,) = make_splits(Dataset(recs), SplitConfig(strategy="time-blocks", n_blocks=20),
                           source="test")
    assert [r.run_id for r, _ in split.whole] == ["r0", "r1"]
    spec = FeatureSpec(inputs=["dT", "rate", "play_1"], t_ref=20.0)
    whole = split_parts(spec, split.train, outputs=["gyro_x"], target="drift", val=split.val,
                        test=split.test, whole=split.whole)
    carved = split_parts(spec, split.train, outputs=["gyro_x"], target="drift",
                         val=split.val, test=split.test)
    for a, b in [(whole.test, carved.test), (whole.val, carved.val),
                 *zip(whole.train, carved.train, strict=True)]:
        assert a is not None and b is not None
        np.testing.assert_array_equal(a.time_s, b.time_s)
        np.testing.assert_array_equal(a.target, b.target)
        np.testing.assert_array_equal(a.signals[:, 0], b.signals[:, 0])   # temperature
    # the state: the whole run's at every test row (run r1's rows follow r0's)
    full = [build_part(r, signals=spec.signals, outputs=["gyro_x"], target="drift",
                       gap_s=spec.gap_s) for r in recs]
    role = [roles for _, roles in split.whole]
    want = np.concatenate([q.signals[r == 4] for q, r in zip(full, role, strict=True)])
    np.testing.assert_array_equal(whole.test.signals, want)
    # the carved blocks restart it: at a block's first row the rate differs from the run's
    assert not np.allclose(carved.test.signals[:, 1], want[:, 1], atol=1e-3)
