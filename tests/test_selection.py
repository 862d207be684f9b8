"""Model selection by purged, blocked cross-validation (thermonet.scoring.selection)."""

from __future__ import annotations

import numpy as np
import pytest

from thermonet.core.recording import Recording
from thermonet.scoring.domain import in_domain, noise_widths
from thermonet.scoring.fold_plan import plan_folds, purge_rule, window_labels, window_rule
from thermonet.scoring.oof_pool import CandidateOOF
from thermonet.scoring.selection import select

pytestmark = pytest.mark.numerics


def _cycle(n: int = 7200, rate_hz: float = 1.0, seed: int = 0) -> Recording:
    """One climate cycle 20 → 60 → −10 → 30 °C (a triangle wave), 1 Hz, a 1-axis gyro."""
    t = np.arange(n) / rate_hz
    knots_t = np.array([0.0, 0.3, 0.75, 1.0]) * t[-1]
    temp = np.interp(t, knots_t, [20.0, 60.0, -10.0, 30.0])
    rng = np.random.default_rng(seed)
    temp = temp + rng.normal(0.0, 0.05, n)
    return Recording(time_s=t, temperature_c=temp, outputs={"gyro_x": np.zeros(n)},
                     units={"gyro_x": "deg/s"}, run_id="cycle", sample_rate_hz=rate_hz)


def test_the_deal_is_scikit_learns_predefined_split():
    """plan_folds deals without importing scikit-learn; its folds are PredefinedSplit's over
    the same test_fold (the oracle: scikit-learn's own splitter), masked runs included."""
    from sklearn.model_selection import PredefinedSplit

    rec = _cycle(3000)
    mask = np.ones(rec.n_samples, dtype=bool)
    mask[2500:] = False                       # the test part: never validated (-1)
    plan = plan_folds([(rec, mask)], folds=5, blocks_per_fold=8, tau_s=0.0)
    assert plan is not None
    ps = PredefinedSplit(plan.fold_of[0])
    assert ps.get_n_splits() == plan.k == 5
    for f, (_, val_idx) in enumerate(ps.split()):
        np.testing.assert_array_equal(np.flatnonzero(plan.fold_of[0] == f), val_idx)


def _brute_force_distance(t: np.ndarray, val: np.ndarray) -> np.ndarray:
    tv = t[val]
    return np.abs(t[:, None] - tv[None, :]).min(axis=1)


def test_one_run_is_dealt_round_robin_in_short_blocks_with_a_purge():
    rec = _cycle(4000)
    mask = np.ones(rec.n_samples, dtype=bool)
    plan = plan_folds([(rec, mask)], folds=5, blocks_per_fold=8, tau_s=60.0)
    assert plan is not None and plan.kind == "blocks" and plan.k == 5
    # 40 blocks of equal time dealt round-robin: block b validates in fold b % 5
    block_s = (rec.time_s[-1] - rec.time_s[0]) / 40
    assert plan.block_s == pytest.approx(block_s, rel=1e-12)
    block = np.minimum((rec.time_s / block_s).astype(int), 39)
    np.testing.assert_array_equal(plan.fold_of[0], block % 5)       # integers: exact
    # the documented rules: window 60 s (≤ half a block), purge min(max(3τ, window), block/2)
    assert plan.window_s == pytest.approx(window_rule(1.0, block_s)) == pytest.approx(
        min(60.0, block_s / 2))
    assert plan.purge_s == pytest.approx(purge_rule(60.0, plan.window_s, block_s))
    assert plan.purge_s == pytest.approx(min(180.0, block_s / 2))
    for f in range(5):
        val = plan.fold_of[0] == f
        train = plan.train_masks[f][0]
        assert not (train & val).any()
        # no training sample within the purge of a validation sample (brute force)
        d = _brute_force_distance(rec.time_s, val)
        assert d[train].min() > plan.purge_s
        # and everything farther than the purge trains
        assert train[(d > plan.purge_s)].all()
        assert train.mean() >= 0.75 * (1 - 1 / 5) - 1e-9      # at most half a block each side


def test_round_robin_folds_validate_inside_the_trained_temperatures_where_slabs_do_not():
    """The finding behind blocked folds: K contiguous slabs of one cycle validate far outside the trained
    range; tens of short blocks dealt round-robin do not."""
    rec = _cycle(7200)
    mask = np.ones(rec.n_samples, dtype=bool)
    temp = rec.temperature_c[:, None]
    widen = noise_widths(temp)

    def outside(plan) -> float:
        fr = []
        for f in range(plan.k):
            tr = plan.train_masks[f][0]
            val = plan.fold_of[0] == f
            lo, hi = temp[tr].min(0), temp[tr].max(0)
            fr.append(1.0 - in_domain(temp[val], lo, hi, widen).mean())
        return max(fr)

    rr = plan_folds([(rec, mask)], folds=5, blocks_per_fold=8, tau_s=0.0)
    slabs = plan_folds([(rec, mask)], folds=5, blocks_per_fold=1, tau_s=0.0)
    assert rr is not None and slabs is not None
    # a slab validates on temperatures it never trained on; dealt blocks only at the two
    # extremes of the cycle (the block holding the peak or the trough)
    assert outside(slabs) > 0.3
    assert outside(rr) < 0.05


def test_several_runs_leave_one_run_out_and_test_rows_never_validate():
    runs = [_cycle(1200, seed=s) for s in range(3)]
    masks = [np.ones(r.n_samples, dtype=bool) for r in runs]
    masks[1][600:] = False                        # e.g. test blocks of that run
    plan = plan_folds(list(zip(runs, masks, strict=True)), folds=5, blocks_per_fold=8,
                      tau_s=300.0)
    assert plan is not None and plan.kind == "leave-one-run-out" and plan.k == 3
    for f in range(3):
        for j in range(3):
            val = plan.fold_of[j] == f
            assert val.any() == (j == f)
            assert not (val & ~masks[j]).any()                    # never a test row
            assert not (plan.train_masks[f][j] & ~masks[j]).any()
            assert plan.train_masks[f][j].any() == (j != f)


def test_too_little_data_gives_no_folds():
    rec = _cycle(50)
    assert plan_folds([(rec, np.ones(50, dtype=bool))], folds=5, blocks_per_fold=8,
                      tau_s=0.0) is None
    assert plan_folds([(rec, np.ones(50, dtype=bool))], folds=0, blocks_per_fold=8,
                      tau_s=0.0) is None


def test_noise_width_is_three_sigma_of_the_thermometer_noise_not_the_ramp():
    rng = np.random.default_rng(4)
    t = np.arange(20000.0)
    ramp = 0.01 * t + rng.normal(0.0, 0.2, t.size)
    w = noise_widths(ramp[:, None])[0]
    # 3 σ with σ the noise (0.2 °C): the steady ramp step (0.01 °C) is not noise
    assert w == pytest.approx(3 * 0.2, rel=0.05)
    # a sample at the edge plus noise is inside, one a degree past it outside
    assert in_domain(np.array([[10.3], [11.0]]), np.array([0.0]), np.array([10.0]),
                     np.array([w])).tolist() == [True, False]


def test_window_labels_restart_in_every_contiguous_stretch():
    t = np.concatenate([np.arange(0.0, 150.0), np.arange(1000.0, 1130.0)])
    wl = window_labels(t, 60.0)
    # 150 s → windows 0,1,2 (60+60+30); the next stretch starts a new window
    assert wl[0] == 0 and wl[59] == 0 and wl[60] == 1 and wl[149] == 2
    assert wl[150] == 3 and wl[-1] == 5


def _slow_error(n: int, seed: int, amp: float) -> np.ndarray:
    """A low-frequency model error: white noise smoothed over 10 min, scaled to rms ``amp``."""
    e = np.convolve(np.random.default_rng(seed).normal(size=n + 600), np.ones(600), "valid")
    return amp * e[:n] / np.std(e[:n])


def _toy_selection(noise: float, seed: int = 0):
    """One run, 2 h at 1 Hz, drift 0.01·T + 2e-4·T² plus white noise of σ ``noise``;
    candidates: two with slow errors of the same size (99 and 4 parameters), one leaving
    30 % of the drift (2 parameters)."""
    rec = _cycle(7200, seed=seed)
    rng = np.random.default_rng(seed + 10)
    temp = rec.temperature_c
    drift = 0.01 * temp + 2e-4 * temp ** 2
    y = (drift + rng.normal(0.0, noise, temp.size))[:, None]
    mask = np.ones(rec.n_samples, dtype=bool)
    plan = plan_folds([(rec, mask)], folds=5, blocks_per_fold=8, tau_s=0.0)
    assert plan is not None

    def cand(label: str, pred: np.ndarray, n_params: int) -> CandidateOOF:
        c = CandidateOOF(label, n_params)
        for f in range(plan.k):
            rows = np.flatnonzero(plan.fold_of[0] == f)
            c.pred.append([pred[rows, None]])
            c.inside.append([np.ones(rows.size, dtype=bool)])
        return c

    n = temp.size
    cands = {"exact-big": cand("exact-big", drift + _slow_error(n, 1, 0.01), 99),
             "exact-small": cand("exact-small", drift + _slow_error(n, 2, 0.01), 4),
             "poor": cand("poor", 0.7 * drift, 2)}
    return plan, y, rec.time_s, cands, drift


def test_one_standard_error_rule_on_paired_out_of_fold_errors():
    plan, y, t, cands, _ = _toy_selection(noise=0.05)
    sel = select(plan, [y], [t], cands, ["gyro_x"])
    rec = sel.record["candidates"]
    # two models with slow errors of the same size: a difference within one SE of the paired
    # difference, so the fewer parameters win
    big, small = rec["exact-big"], rec["exact-small"]
    assert max(big["score"], small["score"]) < rec["poor"]["score"]
    d = small["diff_to_best"] if small["diff_to_best"] > 0 else big["diff_to_best"]
    se = small["se_of_diff"] if small["diff_to_best"] > 0 else big["se_of_diff"]
    assert 0 <= d <= se
    assert sel.chosen == "exact-small" and sel.reason.startswith("tie:")
    assert sel.tied == ["exact-small", "exact-big"]
    # the poor model is far outside one SE; every candidate compensates the axis
    assert rec["poor"]["diff_to_best"] > 5 * rec["poor"]["se_of_diff"]
    assert sel.compensate == {"exact-big": [True], "exact-small": [True], "poor": [True]}
    # per fold scores and the fraction left out are recorded
    assert len(rec["poor"]["fold_scores"]) == 5 and rec["poor"]["left_out_fraction"] == [0.0] * 5
    # the poor model's score: 30 % of the drift's low-frequency spread left (white noise
    # averaged out by 60 s windows, σ/√60 ≈ 0.006 against a drift spread of ~0.3)
    assert rec["poor"]["score"] == pytest.approx(0.3, abs=0.02)


def test_score_is_the_drift_not_the_white_noise():
    """White noise as large as the drift: sample by sample the exact model and one leaving
    30 % of the drift are within a few % of each other; the window means tell them apart."""
    plan, y, t, cands, drift = _toy_selection(noise=0.5)
    del cands["exact-small"]
    sel = select(plan, [y], [t], cands, ["gyro_x"])
    rec = sel.record["candidates"]
    assert (plan.fold_of[0] >= 0).all()                  # every sample validates once
    sample_exact = np.std(y[:, 0] - drift) / np.std(y[:, 0])
    sample_poor = np.std(y[:, 0] - 0.7 * drift) / np.std(y[:, 0])
    assert abs(sample_poor / sample_exact - 1) < 0.1     # a near tie per sample
    assert rec["poor"]["score"] > 1.5 * rec["exact-big"]["score"]        # not in window means
    assert sel.chosen == "exact-big"


def test_do_no_harm_and_a_failed_candidate():
    plan, y, t, cands, _ = _toy_selection(noise=0.05)
    zero = CandidateOOF("zero", 1)
    for f in range(plan.k):
        rows = np.flatnonzero(plan.fold_of[0] == f)
        zero.pred.append([np.zeros((rows.size, 1))])
        zero.inside.append([np.ones(rows.size, dtype=bool)])
    sel = select(plan, [y], [t], {"zero": zero}, ["gyro_x"])
    assert sel.chosen is None and "do no harm" in sel.reason and sel.compensate["zero"] == [False]
    broken = CandidateOOF("broken", 3, failed="cross-validation fold 2: span too short")
    sel = select(plan, [y], [t], {**cands, "broken": broken}, ["gyro_x"])
    assert sel.chosen == "exact-small"
    assert sel.record["candidates"]["broken"]["status"] == "failed"


def test_compare_chooses_out_of_fold_and_records_it(tmp_path):
    """compare end to end: the choice, the masks and every figure of the record come from the
    cross-validation over the pool (train + validation runs), never the test run."""
    from conftest import toy_dataset
    from thermonet.data.io import write_parquet
    from thermonet.training.config import CompareConfig, FamilyConfig, TrainConfig
    from thermonet.training.config_sections import DataConfig
    from thermonet.workflows.compare import format_table, run_compare

    path = write_parquet(toy_dataset(n_runs=4), tmp_path / "toy.parquet")
    fams = [FamilyConfig(family="poly", name="cubic", params={"degree": 3}),
            FamilyConfig(family="linear", name="linear")]
    cfg = CompareConfig(data=DataConfig(paths=[str(path)]), families=fams, baseline="cubic",
                        train=TrainConfig(max_epochs=20, patience=5))
    res = run_compare(cfg, tmp_path / "out", track=False, quiet=True, plots=False)
    sel = res["selection"]
    assert sel["kind"] == "leave-one-run-out" and sel["folds"] == 3     # run0-2; run3 tests
    # the drift is quadratic: the line leaves most of it, the cubic only noise
    cubic, line = sel["candidates"]["cubic"], sel["candidates"]["linear"]
    assert cubic["score"] < 0.1 < line["score"] and len(cubic["fold_scores"]) == 3
    assert line["diff_to_best"] > line["se_of_diff"]
    assert res["chosen"] == "cubic" and res["chosen_reason"].startswith("chose cubic")
    assert res["chosen_reason"] == sel["rule"]
    assert cubic["axes"]["gyro_x"]["compensate"] is True
    assert res["families"]["cubic"]["axes"]["gyro_x"]["compensate"] is True
    assert cubic["left_out_fraction"] == pytest.approx([0.0, 0.0, 0.0], abs=0.02)
    text = format_table(res)
    assert "selection: leave-one-run-out, 3 folds" in text and "folds " in text
    html = (tmp_path / "out" / "report.html").read_text()
    assert "How the model was chosen" in html and "leave-one-run-out" in html


def test_time_blocks_pool_never_holds_a_test_block():
    from thermonet.training.config import SplitConfig
    from thermonet.training.splits import block_roles, make_splits

    rec = _cycle(6000)
    (split,) = make_splits([rec], SplitConfig(strategy="time-blocks", n_blocks=20))
    (run, mask), = split.pool
    assert run is rec                                   # the whole run: dynamics uncut
    np.testing.assert_array_equal(mask, block_roles(rec, 20) != 4)
    test_t = split.test.time_s
    assert not np.isin(rec.time_s[mask], test_t).any()
    plan = plan_folds(split.pool, folds=5, blocks_per_fold=8, tau_s=0.0)
    assert plan is not None
    for f in range(plan.k):
        assert not ((plan.fold_of[0] == f) & ~mask).any()
        assert not (plan.train_masks[f][0] & ~mask).any()


def test_a_time_block_split_of_several_runs_deals_blocks_inside_every_run():
    """Two isothermal soaks split by time blocks are tested inside each soak: leaving one soak
    out would ask for a temperature never trained on, so the folds are blocks in both runs."""
    from thermonet.training.config import SplitConfig
    from thermonet.training.splits import make_splits

    cold, hot = _cycle(3000, seed=1), _cycle(3000, seed=2)
    cold.temperature_c = 13.0 + 0.05 * np.sin(np.arange(3000) / 50)
    hot.temperature_c = 48.0 + 0.05 * np.sin(np.arange(3000) / 50)
    hot.run_id = "hot"
    (split,) = make_splits([cold, hot], SplitConfig(strategy="time-blocks", n_blocks=20))
    by_run = plan_folds(split.pool, folds=5, blocks_per_fold=8, tau_s=0.0)
    blocks = plan_folds(split.pool, folds=5, blocks_per_fold=8, tau_s=0.0, by_run=False)
    assert by_run is not None and by_run.kind == "leave-one-run-out"
    assert blocks is not None and blocks.kind == "blocks" and blocks.k == 5
    for f in range(5):                       # every fold validates in both runs
        assert all((fo == f).any() for fo in blocks.fold_of)
        assert all(m.any() for m in blocks.train_masks[f])


def test_fewer_folds_than_asked_are_said_in_the_note():
    """selection.folds: 3 over a pool of two runs split by run gives two folds (one run left
    out each): the plan's note (results.json's selection.note, the console's "folds:" line)
    says so and why; as many runs as folds, no note."""
    runs = [_cycle(1200, seed=s) for s in range(2)]
    pool = [(r, np.ones(r.n_samples, dtype=bool)) for r in runs]
    plan = plan_folds(pool, folds=3, blocks_per_fold=8, tau_s=0.0)
    assert plan is not None and plan.k == 2
    assert plan.note == ("2 folds, not 3 (selection.folds): the split is by run, so each fold "
                         "leaves one whole run out, and the training data hold 2 runs")
    assert plan.describe()["note"] == plan.note
    same = plan_folds(pool, folds=2, blocks_per_fold=8, tau_s=0.0)
    assert same is not None and same.k == 2 and same.note == ""


@pytest.mark.parametrize("selection, key, why", [
    # one run held out per fold, each one 2 h stretch: one 100000 s window a fold, no spread
    ({"window_s": 100000.0}, "selection.window_s",
     "100000 s windows are longer than the validation data hold: a fold's score is the "
     "spread of two or more window means (the longest validation stretch of each of the 3 "
     "folds: 7199, 7199, 7199 s); use at most 3599.5 s, or remove the key (the rule gives "
     "60 s here)"),
])
def test_a_window_the_folds_cannot_hold_is_refused_before_fitting(tmp_path, selection, key,
                                                                   why):
    """An over-long selection.window_s was leaked numpy warnings and "chosen: none", exit 0:
    now one line naming the key and what the data hold, nothing written."""
    from conftest import toy_dataset
    from thermonet.core.errors import ConfigError
    from thermonet.training.config import config_from_mapping
    from thermonet.workflows.compare import run_compare

    cfg = config_from_mapping({"families": [{"name": "cubic", "family": "poly",
                                             "params": {"degree": 3}}],
                               "selection": selection, "tracking": {"enabled": False}})
    with pytest.raises(ConfigError) as err:
        run_compare(cfg, tmp_path / "out", dataset=toy_dataset(n_runs=4), track=False,
                    quiet=True, plots=False)
    assert str(err.value) == f"config: key '{key}': {why}"
    assert not (tmp_path / "out").exists()


def test_a_purge_that_leaves_no_training_data_is_refused_naming_purge_s(tmp_path):
    """One run's excursions held out, purged by selection.purge_s = 1e6 s on each side: no
    training data is left in any fold — was "too little training data for 5 folds" without
    the cause; now one line naming selection.purge_s, nothing written."""
    from thermonet.core.errors import ConfigError
    from thermonet.sim import simulate
    from thermonet.training.config import config_from_mapping
    from thermonet.workflows.compare import run_compare

    ds = simulate("consumer-imu", runs=1, seed=0, sample_rate_hz=0.2)
    for purge, window in ((1e6, None), (None, 1e5)):
        cfg = config_from_mapping({
            "data": {"outputs": ["gyro_x"]},
            "families": [{"name": "cubic", "family": "poly", "params": {"degree": 3}}],
            "selection": {"purge_s": purge, "window_s": window},
            "tracking": {"enabled": False}})
        with pytest.raises(ConfigError) as err:
            run_compare(cfg, tmp_path / "out", dataset=ds, track=False, quiet=True,
                        plots=False)
        msg = str(err.value)
        key = "purge_s" if purge else "window_s"
        assert msg.startswith(f"config: key 'selection.{key}': ") and "\n" not in msg
        assert "leave" in msg and "too little training data for 2 cross-validation folds" \
            in msg, msg
        assert not (tmp_path / "out").exists()
