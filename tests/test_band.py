"""The residual-drift band (:mod:`thermonet.scoring.band`): its finite-sample rule, its
coverage on simulated data with a known drift law, the refusals, and the same band through
results.json, the checkpoint, DriftEstimator, ONNX + the runtime (batch and step), the C
header and the autopilot files' EKF recommendation."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from conftest import load_runtime
from thermonet.core.errors import ConfigError, ThermonetError
from thermonet.scoring.band import (
    Band,
    band_from_oof,
    band_problem,
    conformal_quantile,
    evaluate_tables,
    holds_for,
    min_windows,
    outside_holds,
    sample_directions,
    window_directions,
    window_rates,
)
from thermonet.scoring.fold_plan import plan_folds
from thermonet.scoring.oof_pool import CandidateOOF
from tolerances import assert_f32_close, assert_f64_close

pytestmark = pytest.mark.numerics

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------- the finite-sample rule
def test_min_windows_is_the_smallest_n_with_a_finite_quantile():
    # ⌈(n + 1)·level⌉ ≤ n: n ≥ level / (1 − level)
    assert min_windows(0.9) == 9
    assert min_windows(0.95) == 19
    assert min_windows(0.5) == 1
    assert min_windows(0.8) == 4


def test_conformal_quantile_is_the_rank_ceil_n_plus_1_level():
    s = np.arange(1.0, 10.0)[::-1]          # 9 scores 9..1
    assert conformal_quantile(s, 0.9) == 9.0          # ⌈10·0.9⌉ = 9th smallest
    assert conformal_quantile(np.arange(1.0, 20.0), 0.9) == 18.0  # ⌈20·0.9⌉ = 18
    assert math.isinf(conformal_quantile(np.arange(1.0, 9.0), 0.9))  # 8 < 9 windows


def test_evaluate_tables_piecewise_and_linear_past_the_edges():
    e, h = [0.0, 10.0, 20.0], [1.0, 2.0]
    x = np.array([-5.0, 0.0, 9.99, 10.0, 20.0, 25.0, np.nan])
    got = evaluate_tables(x, e, h, 0.1, 0.3)
    want = np.array([1.0 + 0.5, 1.0, 1.0, 2.0, 2.0, 2.0 + 1.5, np.nan])
    assert_f64_close(got[:-1], want[:-1])
    assert np.isnan(got[-1])


# ------------------------------------------------- coverage on a known law (no compare run)
LAW = 2e-5          # drift y = LAW·(T − 30)³, output units
T_LO, T_HI = 0.0, 60.0


def _sigma(t: np.ndarray) -> np.ndarray:
    """Per-sample noise of the residual: grows from 0.01 to 0.03 over the range."""
    return 0.01 * (1.0 + 2.0 * (t - T_LO) / (T_HI - T_LO))


def _run(seed: int, span_s: float = 24000.0) -> SimpleNamespace:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, span_s, 1.0)
    temp = T_LO + (T_HI - T_LO) * t / t[-1]
    y = LAW * (temp - 30.0) ** 3 + rng.normal(0.0, _sigma(temp))
    return SimpleNamespace(time_s=t, effective_rate_hz=1.0, temp=temp, y=y[:, None])


def _pool_band(run: SimpleNamespace, level: float = 0.9) -> Band:
    """The band of the exact law (a perfect model) from a one-run pool's 5 × 8 blocks."""
    plan = plan_folds([(run, np.ones(run.time_s.size, bool))], folds=5, blocks_per_fold=8,
                      tau_s=0.0, window_s=60.0)
    assert plan is not None
    oof = CandidateOOF("law", 1)
    truth = LAW * (run.temp - 30.0) ** 3
    for f in range(plan.k):
        rows = np.flatnonzero(plan.fold_of[0] == f)
        oof.pred.append([truth[rows][:, None]])
        oof.inside.append([np.ones(rows.size, bool)])
    return band_from_oof(plan=plan, targets=[run.y], times=[run.time_s], temps=[run.temp],
                         oofs=[oof], compensate=[True], ranges=[(T_LO, T_HI)],
                         outputs=["gyro_x"], level=level, bins=4, units={"gyro_x": "deg/s"})


@pytest.fixture(scope="module")
def known() -> tuple[SimpleNamespace, Band]:
    run = _run(0)
    return run, _pool_band(run)


def test_band_matches_the_known_noise_quantile(known):
    """Per bin the half-width is the 90 % quantile of |window mean| of N(0, σ(T)²)/60:
    1.645 σ(T_mid)/√60 (the bin's σ varies by ±17 % across it, the quantile of ~80 windows
    scatters by ~15 %: 30 % is the statistical tolerance)."""
    _, band = known
    b = band.axes["gyro_x"]
    assert len(b.half) == 4 and b.n == [100, 100, 100, 100]
    mids = (np.asarray(b.edges[:-1]) + np.asarray(b.edges[1:])) / 2
    want = 1.6449 * _sigma(mids) / math.sqrt(60.0)
    np.testing.assert_allclose(b.half, want, rtol=0.30)


def test_band_covers_ninety_percent_of_a_fresh_run(known):
    """A fresh run of the same law: the fraction of its window means (about the run's mean)
    inside the band is 0.9 within the binomial scatter of 400 windows (±3 SE = ±0.045)."""
    _, band = known
    fresh = _run(1)
    n = fresh.time_s.size // 60 * 60
    resid = (fresh.y[:n, 0] - LAW * (fresh.temp[:n] - 30.0) ** 3).reshape(-1, 60).mean(1)
    tw = fresh.temp[:n].reshape(-1, 60).mean(1)
    covered = np.abs(resid - resid.mean()) <= band.evaluate(tw)[:, 0]
    assert 0.855 <= covered.mean() <= 0.945


def test_growth_past_the_edge_is_the_raw_slope_at_the_edge(known):
    """A model holds its edge value past the trained range: the error grows at the drift's
    own slope there — the derivative at the edge of a quadratic least-squares fit of
    LAW·(T − 30)³ over the edge bin, plus its standard error (the noise: within 10 %) — or
    faster where the folds that extrapolate say so (then the rule says which)."""
    _, band = known
    b = band.axes["gyro_x"]
    for lo, hi, edge, got in ((b.edges[0], b.edges[1], b.edges[0], b.grow_lo),
                              (b.edges[-2], b.edges[-1], b.edges[-1], b.grow_hi)):
        t = np.linspace(lo, hi, 1001)
        slope = np.polyfit(t - edge, LAW * (t - 30.0) ** 3, 2)[1]
        assert abs(slope) <= got
        if "extrapolate" not in b.grow_rule:
            assert got <= 1.10 * abs(slope)


def test_band_document_round_trip_and_figures(known):
    _, band = known
    doc = json.loads(json.dumps(band.to_json()))
    assert band_problem(doc) is None
    back = Band.from_json(doc)
    x = np.linspace(-10.0, 70.0, 33)
    np.testing.assert_array_equal(back.evaluate(x), band.evaluate(x))  # values copied
    # the display figures: deg/s → deg/h is × 3600
    assert_f64_close(doc["display"]["gyro_x"]["half_width"],
                     np.asarray(band.axes["gyro_x"].half) * 3600.0)
    # the temperature rate: 60 °C over 24000 s, window means 60 s apart
    assert_f64_close(band.signal_rate, 60.0 / 23999.0, rtol=1e-6)


def test_the_band_states_the_directions_and_rates_it_was_judged_on(known):
    """The known run heats 60 °C in 23,999 s (0.15 °C/min), never cools: the band says it
    was judged on heating up to that rate and never on cooling; a cooling window, or one
    heating faster, lies outside what it states, a slower or a soak inside; the statement
    survives the document's round trip; a proxy's band states nothing."""
    run, band = known
    assert_f64_close(band.holds_for["heating"], 3600.0 / 23999.0, rtol=1e-9)
    assert band.holds_for["cooling"] is None
    doc = json.loads(json.dumps(band.to_json()))
    assert "never on cooling" in doc["holds_for"]["meaning"]
    assert Band.from_json(doc).holds_for == band.holds_for
    # per window: its rate and its excursion's direction — heating slower and faster than
    # judged, a cooling, the soak after the cooling (still the cooling's excursion), and a
    # run that never moves
    rates = np.array([0.10, 0.20, -0.10, 0.0, 0.0])
    dirs = np.array([1, 1, -1, -1, 0])
    assert outside_holds(band.holds_for, rates, dirs).tolist() == [False, True, True, True,
                                                                    False]
    assert not outside_holds({}, rates, dirs).any()          # nothing stated: nothing flagged
    plan = plan_folds([(run, np.ones(run.time_s.size, bool))], folds=5, blocks_per_fold=8,
                      tau_s=0.0, window_s=60.0)
    proxy = band_from_oof(plan=plan, targets=[run.y], times=[run.time_s], temps=[run.temp],
                          oofs=[None], compensate=[False], ranges=[(T_LO, T_HI)],
                          outputs=["gyro_x"], signal="freq_hz")
    assert proxy.holds_for == {} and "holds_for" not in proxy.to_json()
    _c_holds_as_python(band, rates, dirs)


def test_the_band_is_nan_at_an_infinite_signal_in_the_runtime_as_in_c(known):
    """The docs: NaN for a NaN or infinite signal (a missing or broken reading).  The C
    header's ``thermonet_band`` gave NaN at ±inf, the runtime inf (was: NaN at NaN only, so
    the CSV command wrote ``inf`` beside a row of NaN drift).  Both on the same tables, with
    finite points past each edge as the check that nothing else moved."""
    from thermonet.exporting.c_band import BAND_DRIVER, insert_band
    from thermonet.exporting.c_driver import c_compiler, run_c_driver

    rt = load_runtime()
    e, h = [0.0, 10.0, 20.0], [1.0, 2.0]
    x = np.array([np.inf, -np.inf, np.nan, -5.0, 5.0, 25.0])
    got = rt.band_tables(x, e, h, 0.1, 0.3)
    assert np.isnan(got[:3]).all()
    assert_f64_close(got[3:], np.array([1.0 + 0.5, 1.0, 2.0 + 1.5]))
    _, band = known
    doc = band.to_json()
    t = doc["axes"]["gyro_x"]
    cc = c_compiler()
    assert cc is not None, "the C band needs a C compiler (gcc: the README's set-up)"
    head = ("#ifndef THERMONET_MODEL_H\n#define THERMONET_MODEL_H\n#define THERMONET_N_AXES 1\n"
            '#define THERMONET_AXIS_NAMES {"gyro_x"}\n#endif /* THERMONET_MODEL_H */\n')
    text = insert_band(head, doc, "thermonet", ["gyro_x"], [band.signal])
    pts = np.array([np.inf, -np.inf, np.nan, T_LO - 5.0, (T_LO + T_HI) / 2, T_HI + 5.0],
                   dtype=np.float32)
    rows = np.zeros(pts.size, dtype=[("x", np.float32)])
    rows["x"] = pts
    c_out = run_c_driver(cc, text, BAND_DRIVER, rows, [("b", np.float32, 1)])["b"][:, 0]
    py = rt.band_tables(pts.astype(np.float64), t["edges"], t["half_width"],
                        t["growth_below"], t["growth_above"])
    assert np.isnan(c_out[:3]).all() and np.isnan(py[:3]).all()
    assert_f32_close(c_out[3:].astype(np.float64), py[3:], "affine")
    # and the package's own band (DriftEstimator.predict(return_band=True), the report) the same
    own = band.evaluate(pts.astype(np.float64), ["gyro_x"])[:, 0]
    assert np.isnan(own[:3]).all()
    assert_f64_close(own[3:], py[3:])


def _c_holds_as_python(band: Band, rates: np.ndarray, dirs: np.ndarray) -> None:
    """The C header's ``<prefix>_band_holds`` gives the windows' verdicts; the export's own
    check (``check_band_c``) passes it and refuses a header whose judged rate was changed."""
    from thermonet.core.errors import ExportError
    from thermonet.exporting.c_band import HOLDS_DRIVER, check_band_c, insert_band
    from thermonet.exporting.c_driver import c_compiler, run_c_driver

    cc = c_compiler()
    assert cc is not None, "the C band needs a C compiler (gcc: the README's set-up)"
    doc = band.to_json()
    head = ("#ifndef THERMONET_MODEL_H\n#define THERMONET_MODEL_H\n#define THERMONET_N_AXES 1\n"
            '#define THERMONET_AXIS_NAMES {"gyro_x"}\n#endif /* THERMONET_MODEL_H */\n')
    text = insert_band(head, doc, "thermonet", ["gyro_x"], [band.signal])
    assert "#define THERMONET_BAND_HOLDS_COOLING_C_PER_MIN -1.000000000e+00f" in text
    rows = np.zeros(rates.size, dtype=[("r", np.float32), ("d", np.int32)])
    rows["r"], rows["d"] = rates, dirs
    got = run_c_driver(cc, text, HOLDS_DRIVER, rows, np.int32)
    assert got.tolist() == [1, 0, 0, 0, 1]
    # a direction none of the three: not held, in C as in Python
    odd = np.zeros(2, dtype=rows.dtype)
    odd["r"], odd["d"] = 0.1, [2, -2]
    assert run_c_driver(cc, text, HOLDS_DRIVER, odd, np.int32).tolist() == [0, 0]
    assert outside_holds(band.holds_for, odd["r"].astype(float), odd["d"]).all()
    # a rate that is not finite (NaN: unknown — a window of one time, a NaN temperature —
    # or ±inf) is never held, in every direction (was: NaN held everywhere C compared it),
    # and the three forms agree on it: C, thermonet's rule and the runtime's
    rt = load_runtime()
    held_rt = {f"{k}_c_per_min": v for k, v in band.holds_for.items()}
    bad_r = np.array([np.nan, np.inf, -np.inf, -np.nan], dtype=np.float32)
    rows = np.zeros(4 * bad_r.size, dtype=[("r", np.float32), ("d", np.int32)])
    rows["r"] = np.tile(bad_r, 4)
    rows["d"] = np.repeat([0, 1, -1, 2], bad_r.size)
    assert run_c_driver(cc, text, HOLDS_DRIVER, rows, np.int32).tolist() == [0] * rows.size
    r64 = rows["r"].astype(np.float64)
    assert outside_holds(band.holds_for, r64, rows["d"]).all()
    assert not rt.band_holds_rule(held_rt, r64, rows["d"]).any()
    assert outside_holds({}, r64, rows["d"]).all()                 # nothing stated too
    assert not rt.band_holds_rule({}, r64, rows["d"]).any()
    # beside them the finite rates keep their verdicts in all three
    mixed = np.concatenate([rates, [np.nan, 0.05]])
    mdirs = np.concatenate([dirs, [0, 1]])
    want = [True, False, False, False, True, False, True]
    assert (~outside_holds(band.holds_for, mixed, mdirs)).tolist() == want
    assert rt.band_holds_rule(held_rt, mixed, mdirs).tolist() == want
    mrows = np.zeros(mixed.size, dtype=rows.dtype)
    mrows["r"], mrows["d"] = mixed, mdirs
    assert run_c_driver(cc, text, HOLDS_DRIVER, mrows, np.int32).tolist() == \
        [int(w) for w in want]
    check_band_c(doc, text, "thermonet")
    bad = text.replace("HOLDS_HEATING_C_PER_MIN ", "HOLDS_HEATING_C_PER_MIN 2.0f * ", 1)
    assert bad != text
    with pytest.raises(ExportError, match="band_holds differs from Python"):
        check_band_c(doc, bad, "thermonet")


def test_window_rates_and_how_many_windows_judge_a_direction():
    """Per window the least-squares slope (°C/min): a window heating at 1 °C/min and one
    cooling at 2 °C/min, exactly; a direction needs min_windows(level) windows to be judged
    (9 at 0.9): 8 cooling windows are not enough, 9 are, and the fastest of them is stated."""
    t = np.arange(0.0, 120.0, 1.0)
    temp = np.where(t < 60, 20.0 + t / 60.0, 21.0 - 2.0 * (t - 60.0) / 60.0)
    got = window_rates(t, temp, (t // 60).astype(int))
    assert_f64_close(got, [1.0, -2.0], rtol=1e-9)
    assert min_windows(0.9) == 9
    up, down = np.ones(20, np.int8), -np.ones(8, np.int8)
    assert holds_for(np.r_[np.full(20, 0.5), np.full(8, -1.0)], np.r_[up, down], 0.9) == {
        "heating": 0.5, "cooling": None}
    nine = -np.ones(9, np.int8)
    assert holds_for(np.r_[np.full(20, 0.5), -np.linspace(0.2, 1.0, 9)], np.r_[up, nine],
                     0.9)["cooling"] == 1.0


def test_a_windows_direction_is_its_excursions():
    """A cycle cooling 25 → −10, a soak at −10, heating to 60: the soak belongs to the
    cooling that ends there (its error is still the cooling's), whatever its own slope."""
    t = np.arange(0.0, 9000.0, 10.0)
    temp = np.interp(t, [0, 2100, 3000, 7200, 9000], [25, -10, -10, 60, 60])
    d = sample_directions(temp)
    assert d[t < 2100].tolist() == [-1] * int((t < 2100).sum())
    assert set(d[(t > 2200) & (t < 2900)]) == {-1}              # the soak after the cooling
    assert set(d[(t > 3200) & (t < 7000)]) == {1}
    w = window_directions(d, (t // 600).astype(int))
    assert w[:5].tolist() == [-1] * 5 and w[6:11].tolist() == [1] * 5


# ---------------------------------------------------------------------------- refusals
@pytest.mark.parametrize("level", [0, 1, 1.5, -0.1, True, "0.9", float("nan")])
def test_a_level_outside_0_1_is_refused_naming_the_key(level):
    from thermonet.training.config import config_from_mapping

    with pytest.raises(ConfigError, match=r"band\.level"):
        config_from_mapping({"band": {"level": level}})


@pytest.mark.parametrize("bins", [0, 51, True, 2.5])
def test_bins_outside_1_50_are_refused_naming_the_key(bins):
    from thermonet.training.config import config_from_mapping

    with pytest.raises(ConfigError, match=r"band\.bins"):
        config_from_mapping({"band": {"bins": bins}})


def test_a_band_without_folds_is_refused_naming_both_keys():
    from thermonet.training.config import config_from_mapping

    with pytest.raises(ConfigError, match=r"band\.level.*selection\.folds is 0"):
        config_from_mapping({"band": {"level": 0.9}, "selection": {"folds": 0}})
    # without band.level the default is quiet: no folds, no band
    config_from_mapping({"selection": {"folds": 0}})


def test_too_few_windows_says_how_many_are_needed():
    run = _run(0, span_s=2400.0)        # 40 windows of 60 s, ~8 per fold
    with pytest.raises(ConfigError, match=r"band\.level.*0\.95 needs at least 19"):
        _tiny_band(run, 0.95)


def _tiny_band(run: SimpleNamespace, level: float) -> Band:
    plan = plan_folds([(run, np.ones(run.time_s.size, bool))], folds=5, blocks_per_fold=8,
                      tau_s=0.0, window_s=60.0)
    assert plan is not None
    oof = CandidateOOF("law", 1)
    for f in range(plan.k):
        rows = np.flatnonzero(plan.fold_of[0] == f)
        oof.pred.append([np.zeros((rows.size, 1))])
        # only fold 0's rows count as inside the trained domain: 8 blocks, fewer than 19
        oof.inside.append([np.full(rows.size, f == 0)])
    return band_from_oof(plan=plan, targets=[run.y], times=[run.time_s], temps=[run.temp],
                         oofs=[oof], compensate=[True], ranges=[(T_LO, T_HI)],
                         outputs=["gyro_x"], level=level)


def test_a_damaged_band_document_is_named():
    good = {"level": 0.9, "signal": "temperature_c", "window_s": 60.0,
            "axes": {"gyro_x": {"edges": [0.0, 1.0], "half_width": [0.1],
                                "growth_below": 0.0, "growth_above": 0.0}}}
    assert band_problem(good) is None
    assert "edges must increase" in band_problem(
        {**good, "axes": {"gyro_x": {**good["axes"]["gyro_x"], "edges": [1.0, 0.0]}}})
    assert "growth_above" in band_problem(
        {**good, "axes": {"gyro_x": {**good["axes"]["gyro_x"], "growth_above": -1.0}}})
    assert "band.level" in band_problem({**good, "level": 2.0})


# ------------------------------------------------- through compare, checkpoint and exports
@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    """consumer-imu (two runs at 0.2 Hz): a per-axis model with dynamic inputs."""
    from thermonet.sim import simulate
    from thermonet.training.config import load_config
    from thermonet.workflows.compare import run_compare

    ds = simulate("consumer-imu", runs=2, seed=0, sample_rate_hz=0.2)
    out = tmp_path_factory.mktemp("band") / "out"
    res = run_compare(load_config(ROOT / "configs" / "consumer-imu.yaml"), out, dataset=ds,
                      track=False, quiet=True, plots=False)
    return res, ds, out


@pytest.mark.slow   # a whole comparison
def test_the_band_says_what_the_folds_held_out(compared):
    """One consumer-imu cycle trains (the other tests): its legs are held out, so the band was
    measured on held-out excursions, and results.json says so beside every band."""
    res, _, out = compared
    assert res["selection"]["kind"] == "excursions"
    assert res["families"]["cubic"]["band"]["judged_on"] == "whole thermal excursions held out"
    # the report's band table: the navigation filter's figures in the axis's unit
    page = (out / "report.html").read_text()
    f = res["band"]["filter"]["gyro_x"]
    unit = res["units"]["gyro_x"]
    assert f"<td>{f['bound']:.3g} {unit}</td><td>{f['rate']:.3g} {unit}/°C</td>" in page


@pytest.mark.slow   # a whole comparison
def test_results_and_checkpoint_carry_the_shipped_models_band(compared):
    from thermonet.api.estimator import DriftEstimator

    res, ds, out = compared
    chosen = res["chosen"]
    assert res["band"]["model"] == chosen and res["band"]["status"] == "ok"
    assert list(res["band"]["axes"]) == list(res["units"])
    est = DriftEstimator.load(res["families"][chosen]["checkpoint"])
    assert est.band_ is not None
    on_disk = json.loads((out / "results.json").read_text())
    assert on_disk["band"]["axes"] == est.band_.to_json()["axes"]   # copied, not computed
    drift, band = est.predict(ds[0], return_band=True)
    np.testing.assert_array_equal(drift, est.predict(ds[0]))       # the same computation
    assert band.shape == drift.shape and np.isfinite(band).all() and (band > 0).all()
    # re-saved and loaded: the band stays
    again = DriftEstimator.load(est.save(out.parent / "again.pt"))
    x = np.linspace(-30.0, 90.0, 25)
    np.testing.assert_array_equal(again.band_.evaluate(x), est.band_.evaluate(x))


@pytest.fixture(scope="module")
def per_axis_compared(tmp_path_factory):
    """patent-gyro (five runs at 0.05 Hz, seed 1): a per-axis model of three owners (the
    cubic, the RBF, the fuzzy model)."""
    from thermonet.sim import simulate
    from thermonet.training.config import load_config
    from thermonet.workflows.compare import run_compare

    ds = simulate("patent-gyro", runs=5, seed=1, sample_rate_hz=0.05)
    out = tmp_path_factory.mktemp("band-per-axis") / "out"
    return run_compare(load_config(ROOT / "configs" / "default.yaml"), out, dataset=ds,
                       track=False, quiet=True, plots=False)


@pytest.mark.slow   # a whole comparison
def test_per_axis_band_is_each_owners_own(per_axis_compared):
    """Each axis of the per-axis model carries the band its owner's family has on that axis
    (same out-of-fold residuals, same mask) — or the raw drift's band on an axis left raw.
    Every owner compensates the axes it owns in its own family too (the same mask, decided on
    its own domain: `export --family <owner>` ships what the per-axis model gives it)."""
    res = per_axis_compared
    # the fixture's device is built to ship a model per axis: a test that skipped when it
    # did not would pass without checking anything
    assert res["chosen"] == "per-axis", f"the fixture shipped {res['chosen']}, not per-axis"
    owners = res["families"]["per-axis"]["params"]["axes"]
    assert len({o for o in owners.values() if o is not None}) >= 2, owners
    for axis, owner in owners.items():
        if owner is None:
            continue
        assert res["families"][owner]["axes"][axis]["compensate"], (axis, owner)
        own = res["families"][owner]["band"]["axes"][axis]
        shipped = res["band"]["axes"][axis]
        assert shipped["half_width"] == own["half_width"] or \
            shipped["edges"] != own["edges"]   # the composite's narrower trained range


@pytest.mark.slow   # a whole comparison
def test_band_parity_onnx_runtime_step_and_c(compared, tmp_path):
    from thermonet.api.estimator import DriftEstimator
    from thermonet.exporting.c_band import BAND_DRIVER
    from thermonet.exporting.c_driver import c_compiler, run_c_driver

    res, ds, _ = compared
    est = DriftEstimator.load(res["families"][res["chosen"]]["checkpoint"])
    rt = load_runtime()
    comp = rt.Compensator(est.export(tmp_path / "m.onnx", "onnx"))
    rec = ds[0]
    temp = np.asarray(rec.temperature_c, dtype=np.float64)
    raw = np.column_stack([np.asarray(rec.outputs[a], dtype=np.float64) for a in comp.outputs])
    got = comp.compensate(temperature_c=temp, raw=raw, time_s=np.asarray(rec.time_s)).band
    # the runtime reads temperature as float32, as the graph does: the same tables there
    want = est.band_.evaluate(temp.astype(np.float32).astype(np.float64))
    assert_f64_close(got, want)
    comp.reset()
    one = comp.step(float(rec.time_s[0]), float(temp[0]), raw[0]).band
    assert_f64_close(one, want[0])
    x = np.array([-40.0, 0.0, 25.0, 150.0])
    assert_f64_close(comp.band(x), est.band_.evaluate(x))
    # the C header: its own tables (float32) and <prefix>_band
    header = est.export(tmp_path / "m.h", "c").read_text()
    assert "thermonet_band_bias_bound" in header and "THERMONET_BAND_LEVEL" in header
    cc = c_compiler()
    assert cc is not None, "the C band needs a C compiler (gcc: the README's set-up)"
    pts = np.concatenate([np.linspace(-40.0, 120.0, 97), [np.nan]]).astype(np.float32)
    rows = np.zeros(pts.size, dtype=[("x", np.float32)])
    rows["x"] = pts
    c_out = run_c_driver(cc, header, BAND_DRIVER, rows,
                         [("b", np.float32, len(comp.outputs))])["b"].astype(np.float64)
    py = est.band_.evaluate(pts.astype(np.float64))
    assert np.isnan(c_out[-1]).all()
    # float32 tables and arithmetic, one multiply-add: the affine depth; away from the bin
    # edges (an edge rounded to float32 may move a point one bin)
    edges = np.concatenate([b.edges for b in est.band_.axes.values()])
    away = np.min(np.abs(pts[:-1, None] - edges[None, :]), axis=1) > 1e-3
    assert_f32_close(c_out[:-1][away], py[:-1][away], "affine")


@pytest.mark.slow   # a whole comparison
def test_ekf_recommendation_from_the_band(compared):
    from thermonet.exporting.autopilot import ekf_recommendation
    from thermonet.scoring.band import shipped_band

    res, _, _ = compared
    doc = shipped_band({"band": res["band"]})
    lines = ekf_recommendation(doc, res["units"], "px4")
    text = "\n".join(lines)
    assert all(line.startswith("#") for line in lines)
    assert "EKF2_GYR_B_NOISE" in text and "EKF2_ACC_B_NOISE" in text and "v1.14" in text
    # the gyro value: max over gyro axes of rate (unit/°C) × SI factor × °C/s
    band = Band.from_json(doc)
    nums = band.filter_numbers()
    si = {"deg/s": math.pi / 180.0, "rad/s": 1.0}
    want = max(nums[a]["rate"] * si[res["units"][a]] * band.signal_rate
               for a in nums if a.startswith("gyro"))
    line = next(x for x in lines if "EKF2_GYR_B_NOISE" in x)
    assert_f64_close(float(line.split(">=")[1].split()[0]), want, rtol=1e-8)  # 9 digits
    ap = "\n".join(ekf_recommendation(doc, res["units"], "ardupilot"))
    assert "EK3_GBIAS_P_NSE" in ap and "EK3_ABIAS_P_NSE" in ap


def test_predict_band_refused_without_one():
    from conftest import toy_dataset
    from thermonet.api.estimator import DriftEstimator

    ds = toy_dataset(n_runs=2)
    est = DriftEstimator("poly", ["dT"], degree=1).fit(ds)
    with pytest.raises(ThermonetError, match="carries no band"):
        est.predict(ds, return_band=True)


@pytest.mark.slow   # a whole comparison
def test_calibrate_writes_the_ekf_recommendation_beside_the_parameter_file(tmp_path):
    """A simulated PX4 board (gyro and accelerometer): ``ekf-recommendation.txt`` beside
    ``px4.params`` holds per instance the bias noise = the firmware form's band rate × the
    training's temperature rate (rad/s and m/s² already: SI factor 1), never a parameter
    line the loader would read."""
    from thermonet.data.logs.writers import write_log
    from thermonet.exporting import read_px4_params
    from thermonet.sim.fcboard import simulate_board
    from thermonet.workflows.calibrate import calibrate
    from thermonet.workflows.calibrate_files import EKF_FILE

    board = simulate_board("fc-board", autopilot="px4", seed=3, rate_hz=0.5)
    board.instances = [i for i in board.instances if i.name in ("gyro0", "acc0")]
    doc = calibrate(write_log(board, tmp_path / "b.ulg"), tmp_path / "cal")
    text = (tmp_path / "cal" / EKF_FILE).read_text()
    assert all(line.startswith("#") for line in text.splitlines())
    assert not any(k.startswith("EKF2") for k in read_px4_params(tmp_path / "cal" / "px4.params"))
    for name, param in (("gyro0", "EKF2_GYR_B_NOISE"), ("acc0", "EKF2_ACC_B_NOISE")):
        band = Band.from_json(doc["instances"][name]["compare"]["band"])
        want = max(v["rate"] for v in band.filter_numbers().values()) * band.signal_rate
        block = text[text.index(f"# {name} "):]
        line = next(x for x in block.splitlines() if param in x)
        assert_f64_close(float(line.split(">=")[1].split()[0]), want, rtol=1e-8)  # 9 digits


@pytest.mark.slow   # a whole comparison
def test_a_damaged_band_is_refused_by_the_checkpoint_and_the_runtime(compared, tmp_path):
    """A band edited after the fact (level 2) is named in one line: by ``load_checkpoint``
    (the checkpoint re-sealed, so only the band is wrong) and by the runtime (the ONNX file
    re-sealed likewise)."""
    import onnx

    from thermonet.core.errors import InputError
    from thermonet.exporting.onnx_seal import seal_onnx
    from thermonet.training.checkpoint import load_checkpoint, save_checkpoint

    res, _, _ = compared
    model, meta = load_checkpoint(res["families"][res["chosen"]]["checkpoint"])
    extra = dict(meta["extra"])
    extra["band"] = {**extra["band"], "level": 2.0}
    path = save_checkpoint(tmp_path / "bad.pt", model, config=meta["config"], extra=extra)
    with pytest.raises(InputError, match=r"extra\.band.*band\.level"):
        load_checkpoint(path)
    from thermonet.api.estimator import DriftEstimator

    est = DriftEstimator.load(res["families"][res["chosen"]]["checkpoint"])
    onnx_path = est.export(tmp_path / "m.onnx", "onnx")
    proto = onnx.load(str(onnx_path))
    for p in proto.metadata_props:
        if p.key == "band":
            doc = json.loads(p.value)
            doc["level"] = 2.0
            p.value = json.dumps(doc)
    onnx.save_model(proto, str(onnx_path))
    seal_onnx(onnx_path)
    rt = load_runtime()
    with pytest.raises(rt.RuntimeInputError, match="metadata 'band' is not a band"):
        rt.Compensator(onnx_path)


def test_the_runtime_command_writes_the_band_beside_each_row(compared, tmp_path):
    """``thermonet_runtime.py model.onnx in.csv --out out.csv`` on a file with a band: one
    ``<axis>_band`` column per axis, each row's value the band at its float32 temperature
    (``Compensator.band``, itself checked against ``DriftEstimator``'s band above), written
    exactly (``repr``); a file without a band writes no such column."""
    import csv

    from thermonet.api.estimator import DriftEstimator

    res, ds, _ = compared
    est = DriftEstimator.load(res["families"][res["chosen"]]["checkpoint"])
    rt = load_runtime()
    model = est.export(tmp_path / "m.onnx", "onnx")
    comp = rt.Compensator(model)
    rec = ds[0]
    n = 200
    cols = {"time_s": np.asarray(rec.time_s)[:n],
            "temperature_c": np.asarray(rec.temperature_c, dtype=np.float64)[:n],
            **{a: np.asarray(rec.outputs[a], dtype=np.float64)[:n] for a in comp.outputs}}
    names = [c for c in cols if c in comp.needs or c in comp.outputs]
    with (tmp_path / "in.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for i in range(n):
            w.writerow([repr(float(cols[c][i])) for c in names])
    assert rt.main([str(model), str(tmp_path / "in.csv"), "--out", str(tmp_path / "o.csv")]) == 0
    with (tmp_path / "o.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    got = np.array([[float(r[f"{a}_band"]) for a in comp.outputs] for r in rows])
    want = comp.band(cols["temperature_c"].astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(got, want)          # the same evaluation, written exactly
    assert np.all(got > 0)
    # without a band: the same command, no band columns
    plain = DriftEstimator.load(res["families"]["cubic"]["checkpoint"])
    plain.band_ = None
    model2 = plain.export(tmp_path / "plain.onnx", "onnx")
    assert rt.main([str(model2), str(tmp_path / "in.csv"), "--out", str(tmp_path / "p.csv")]) == 0
    header = (tmp_path / "p.csv").read_text().splitlines()[0].split(",")
    assert not [h for h in header if h.endswith("_band")]
    assert f"{comp.outputs[0]}_drift" in header
