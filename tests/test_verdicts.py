"""Offset-free scores, block-bootstrap verdicts, per-axis do-no-harm, ties and warnings."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import load_runtime
from thermonet.core.errors import ConfigError
from thermonet.core.recording import Dataset, Recording
from thermonet.data.diagnostics import input_warnings
from thermonet.data.io import write_parquet
from thermonet.exporting import export_onnx
from thermonet.scoring.verdicts import (
    DECISION_RTOL,
    above,
    below,
    block_labels,
    block_stats,
    choose,
    draws,
    ratio_interval,
    same,
    verdict_of,
)
from thermonet.training.checkpoint import load_checkpoint
from thermonet.training.config import CompareConfig, FamilyConfig, TrainConfig
from thermonet.training.config_sections import DataConfig
from thermonet.training.train import predict
from thermonet.workflows.compare import format_table, run_compare

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

FAST = TrainConfig(max_epochs=15, patience=4)
RATE_HZ = 0.5  # one sample every 2 s: small recordings, fast tests


def _run(run_id: str, temp: np.ndarray, drift: dict[str, np.ndarray], *, noise: float,
         rng: np.random.Generator) -> Recording:
    t = np.arange(temp.size) / RATE_HZ
    return Recording(time_s=t, temperature_c=temp,
                     outputs={a: d + rng.normal(0.0, noise, t.size) for a, d in drift.items()},
                     drift={f"drift_{a}": d for a, d in drift.items()},
                     units={a: "deg/s" for a in drift} | {"temperature_c": "degC"},
                     device_id="synthetic", run_id=run_id, sample_rate_hz=RATE_HZ)


def _ramp(n: int = 1800, lo: float = -10.0, hi: float = 50.0) -> np.ndarray:
    return np.linspace(lo, hi, n)


def _compare(tmp_path, ds: Dataset, families: list[FamilyConfig], **kw) -> dict:
    path = write_parquet(ds, tmp_path / "data.parquet")
    kw.setdefault("baseline", None)
    cfg = CompareConfig(data=DataConfig(paths=[str(path)]), families=families, train=FAST, **kw)
    return run_compare(cfg, tmp_path / "out", track=False, quiet=True, plots=False)


# ------------------------------------------------------------------ the statistics alone
def test_block_labels_cut_at_gaps_and_into_enough_pieces():
    t = np.r_[np.arange(100.0), 1000.0 + np.arange(100.0)]  # two stretches, a gap between
    labels = block_labels(t, min_blocks=20)
    assert labels.max() + 1 == 20
    assert len(set(labels[:100]) & set(labels[100:])) == 0  # no block spans the gap
    assert np.all(np.diff(labels) >= 0)
    assert np.bincount(labels).min() == 10


def test_ratio_interval_and_verdicts_on_known_ratios():
    rng = np.random.default_rng(0)
    raw = rng.normal(size=(400, 2))
    pred = np.column_stack([0.5 * raw[:, 0], -0.5 * raw[:, 1]])  # residual 0.5× / 1.5× raw
    s = block_stats(raw, pred, block_labels(np.arange(400.0)))
    ratio, boot, iv = ratio_interval(s.ss_comp, s.ss_raw, draws(s.n.size))
    np.testing.assert_allclose(ratio, [0.5, 1.5], rtol=1e-9)
    np.testing.assert_allclose(iv[:, 0], 0.5, rtol=1e-9)  # exact in every draw
    assert verdict_of(*iv[:, 0]) == "better" and verdict_of(*iv[:, 1]) == "worse"
    assert verdict_of(0.9, 1.1) == "indistinguishable"
    # the offset is reported, not scored: a constant added to raw changes no score
    s2 = block_stats(raw + 7.0, pred, block_labels(np.arange(400.0)))
    np.testing.assert_allclose(s2.ss_raw, s.ss_raw)
    assert s2.offset_raw[0] == pytest.approx(7.0 + raw[:, 0].mean())


def test_choose_one_standard_error_rule():
    """The single validation part's choice is the one rule (one_se): within one standard
    error of the best's *paired* difference over the shared draws, the fewest parameters.
    A candidate whose own interval overlaps the best's but which is worse on every draw by
    more than the SE of the difference is not tied (the pairing is the point)."""
    rng = np.random.default_rng(0)
    common = rng.normal(0.50, 0.05, 1000)       # the draws' shared part (the same blocks)
    scores = {"rbf": (0.50, common), "cubic": (0.55, common + 0.05 + rng.normal(0, 0.08, 1000)),
              "linear": (0.80, common + 0.30 + rng.normal(0, 0.02, 1000))}
    chosen, tied, why = choose(scores, {"rbf": 99, "cubic": 12, "linear": 6})
    assert chosen == "cubic" and tied == ["cubic", "rbf"]
    assert why.startswith("tie:") and "fewest parameters" in why
    # its interval overlaps rbf's (0.40-0.60), but it is 0.05 worse on every draw (SE 0.01)
    scores["cubic"] = (0.55, common + 0.05 + rng.normal(0, 0.01, 1000))
    chosen, tied, _ = choose(scores, {"rbf": 99, "cubic": 12, "linear": 6})
    assert chosen == "rbf" and tied == []
    none, _, why = choose({"a": (1.0, np.ones(10))}, {"a": 2})
    assert none is None and "do no harm" in why


def test_decisions_do_not_turn_on_the_last_bits():
    """Scores equal up to rounding (the poly3 family and the cubic baseline are one model) are
    one score for every decision, whichever of the two a CPU rounds lower: the fewest
    parameters, then the family listed first, decide (thermonet.scoring.verdicts, DECISION_RTOL)."""
    boot = np.linspace(0.30, 0.50, 1000)
    for bump in (-3e-7, 0.0, 3e-7):       # float32 rounding of a ratio of 0.4, either way
        scores = {"cubic": (0.40, boot), "poly3": (0.40 * (1 + bump), boot),
                  "rbf": (0.20, boot - 0.2)}
        chosen, tied, _ = choose(scores, {"cubic": 4, "poly3": 4, "rbf": 99})
        assert chosen == "rbf" and tied == []
        scores["rbf"] = (0.40 * (1 - bump), boot)            # now all three tie
        chosen, tied, _ = choose(scores, {"cubic": 4, "poly3": 4, "rbf": 99})
        assert chosen == "cubic" and tied == ["cubic", "poly3", "rbf"]
        # listed the other way round, the first listed wins: config order, never the bits
        flipped = dict(reversed(list(scores.items())))
        assert choose(flipped, {"cubic": 4, "poly3": 4, "rbf": 99})[0] == "poly3"
    # a score of 1 up to rounding does not beat raw; an interval edge at 1 is no verdict
    for eps in (-1e-9, 0.0, 1e-9):
        assert choose({"a": (1.0 + eps, np.full(10, 1.0))}, {"a": 2})[0] is None
        assert verdict_of(0.5, 1.0 + eps) == "indistinguishable"
        assert verdict_of(1.0 + eps, 1.5) == "indistinguishable"
    # clear of the margin, the plain comparison holds
    assert verdict_of(0.5, 1.0 - 10 * DECISION_RTOL) == "better"
    assert verdict_of(1.0 + 10 * DECISION_RTOL, 1.5) == "worse"
    assert same(1.0, 1.0 + 0.5 * DECISION_RTOL) and not same(1.0, 1.0 + 2 * DECISION_RTOL)
    assert below(0.9, 1.0) and not below(1.0 - 0.5 * DECISION_RTOL, 1.0)
    assert above(1.1, 1.0) and not above(float("nan"), 1.0) and not below(float("nan"), 1.0)


# --------------------------------------------------------------------- whole comparisons
def test_do_no_harm_fires_on_an_axis_without_drift(tmp_path):
    rng = np.random.default_rng(1)
    runs = []
    for k in range(4):
        temp = _ramp() + 0.3 * k
        runs.append(_run(f"run{k}", temp, {"gyro_x": 0.01 * (temp - 20.0),
                                           "gyro_y": np.zeros_like(temp)}, noise=0.01, rng=rng))
    res = _compare(tmp_path, Dataset(runs),
                   [FamilyConfig(family="poly", name="cubic", params={"degree": 3})])
    assert res["chosen"] == "cubic"
    axes = res["families"]["cubic"]["axes"]
    assert axes["gyro_x"]["compensate"] is True and axes["gyro_x"]["verdict"] == "better"
    assert axes["gyro_y"]["compensate"] is False
    assert axes["gyro_y"]["val_verdict"] != "better"
    assert res["uncompensated_axes"] == ["gyro_y"]
    assert any(w.startswith("gyro_y: left uncompensated") for w in res["warnings"])
    model, meta = load_checkpoint(tmp_path / "out" / "models" / "cubic.pt")
    assert meta["extra"]["compensate"] == {"gyro_x": True, "gyro_y": False}
    # the model carries the mask (set before the checkpoint was written), and so does its export
    assert res["families"]["cubic"]["compensate_in_model"] is True
    assert model.compensated_axes == [True, False]
    temps = np.linspace(-10.0, 50.0, 61)
    assert np.all(predict(model, temps[:, None])[:, 1] == 0.0)
    raw = np.column_stack([0.01 * (temps - 20.0), np.full_like(temps, 0.123)])
    comp = load_runtime().Compensator(export_onnx(model, tmp_path / "cubic.onnx")).compensate(
        temperature_c=temps, raw=raw)
    assert np.all(comp.drift[:, 1] == 0.0) and np.all(comp.compensated[:, 1] == raw[:, 1])
    np.testing.assert_allclose(comp.drift[:, 0], 0.01 * (temps - 20.0), atol=0.02)
    assert "left uncompensated: gyro_y" in format_table(res)
    html = (tmp_path / "out" / "report.html").read_text()
    assert "Left uncompensated (drift 0): <b>gyro_y</b>" in html


def test_ties_are_called_ties_and_the_fewest_parameters_win_unless_the_baseline_ties(tmp_path):
    """The drift is a line: the three families are the same model on held-out data.  Without a
    baseline the fewest parameters win (linear); with the cubic as the baseline it stays — a
    challenger, a simpler one too, must beat it by more than one SE."""
    rng = np.random.default_rng(2)
    runs = [_run(f"run{k}", _ramp() + 0.2 * k, {"gyro_x": 0.004 * (_ramp() + 0.2 * k)},
                 noise=0.02, rng=rng) for k in range(4)]
    fams = [FamilyConfig(family="poly", name="cubic", params={"degree": 3}),
            FamilyConfig(family="poly", name="quadratic", params={"degree": 2}),
            FamilyConfig(family="linear", name="linear")]
    (tmp_path / "alone").mkdir()
    alone = _compare(tmp_path / "alone", Dataset(runs), fams)
    assert alone["chosen"] == "linear" and set(alone["tie"]) == {"cubic", "quadratic", "linear"}
    res = _compare(tmp_path, Dataset(runs), fams, baseline="cubic")
    assert res["chosen"] == "cubic"
    assert set(res["tie"]) == {"cubic", "quadratic", "linear"}
    assert res["chosen_reason"].startswith("tie:") and "the baseline cubic stays" in \
        res["chosen_reason"]
    assert any(w.startswith("tie:") for w in res["warnings"])
    vs = res["families"]["linear"]["axes"]["gyro_x"]["vs_baseline"]
    assert vs["verdict"] == "indistinguishable" and vs["ratio"] == pytest.approx(1.0, abs=0.01)
    assert "vs cubic" in format_table(res)


def test_chronological_split_of_a_ramp_warns_of_extrapolation(tmp_path):
    rng = np.random.default_rng(3)
    temp = _ramp(3600, 0.0, 60.0)
    drift = 0.002 * temp + 1e-4 * temp ** 2
    first = _run("first-half", temp[:1800], {"gyro_x": drift[:1800]}, noise=0.005, rng=rng)
    second = _run("second-half", temp[1800:], {"gyro_x": drift[1800:]}, noise=0.005, rng=rng)
    second.time_s = second.time_s + 1800 / RATE_HZ
    res = _compare(tmp_path, Dataset([first, second]),
                   [FamilyConfig(family="poly", name="quadratic", params={"degree": 2})])
    assert res["split"]["strategy"] == "train-then-verify"
    assert res["data"]["outside_trained_range"]["temperature_c"] > 0.99
    assert any(w.startswith("extrapolation: 100 % of the test samples of temperature_c")
               for w in res["warnings"])
    # how far: the test ramp ends at 60 °C, the trained range at the first half's top
    lo, hi = res["data"]["trained_range"]["temperature_c"]
    far = res["data"]["outside_trained_range_max"]["temperature_c"]
    assert far == pytest.approx(temp.max() - hi, rel=1e-9) and 29.0 < far < 31.0
    warning, = (w for w in res["warnings"] if w.startswith("extrapolation:"))
    assert f"up to {far:.3g} °C beyond it ({100 * far / (hi - lo):.0f} % of the trained span)" \
        in warning


@pytest.mark.parametrize("fraction, text", [(0.0031, "0.31 %"), (0.047, "4.7 %"),
                                            (0.47, "47 %"), (1.0, "100 %"), (0.0, "0 %")])
def test_percentages_in_warnings_never_round_a_small_fraction_to_zero(fraction, text):
    from thermonet.data.diagnostics import percent

    assert percent(fraction) == text


def test_verification_after_a_hotter_excursion_is_worse_and_warned(tmp_path):
    """The bias depends on thermal history: after 75 °C the slope of the cooling branch flips."""
    rng = np.random.default_rng(4)
    cycle = np.r_[_ramp(900, 20.0, 50.0), _ramp(900, 50.0, 20.0)]
    runs = [_run(f"cal{k}", cycle + 0.1 * k, {"gyro_x": 0.01 * (cycle + 0.1 * k - 35.0)},
                 noise=0.01, rng=rng) for k in range(2)]
    branch = _ramp(900, 50.0, 20.0)  # recorded after an excursion to 75 °C
    runs.append(_run("verify-after-75C", branch, {"gyro_x": -0.01 * (branch - 35.0)},
                     noise=0.01, rng=rng))
    fams = [FamilyConfig(family="linear", name="linear"),
            FamilyConfig(family="poly", name="cubic", params={"degree": 3})]
    res = _compare(tmp_path, Dataset(runs), fams, baseline="cubic")
    assert res["split"]["folds"][0]["test"] == "verify-after-75C"
    for name in ("linear", "cubic"):
        ax = res["families"][name]["axes"]["gyro_x"]
        assert ax["val_verdict"] == "better"        # fine on the calibration cycle …
        assert ax["verdict"] == "worse"             # … twice the raw error after 75 °C
        assert ax["score_ratio"] == pytest.approx(2.0, rel=0.1)
        assert ax["interval"][0] > 1.0
    chosen = res["chosen"]
    assert any(w.startswith(f"gyro_x: the chosen model {chosen} is worse than raw")
               for w in res["warnings"])
    on_disk = json.loads((tmp_path / "out" / "results.json").read_text())
    assert on_disk["warnings"] == res["warnings"]
    html = (tmp_path / "out" / "report.html").read_text()
    assert "Worse than raw on the held-out test data: <b>gyro_x</b>" in html


def test_baseline_that_is_not_a_family_is_an_error_before_fitting(tmp_path):
    rng = np.random.default_rng(5)
    ds = Dataset([_run(f"run{k}", _ramp(), {"gyro_x": 0.01 * _ramp()}, noise=0.01, rng=rng)
                  for k in range(3)])
    with pytest.raises(ConfigError, match=r"key 'baseline': no family named 'px4' "
                                          r"\(families: linear\)"):
        _compare(tmp_path, ds, [FamilyConfig(family="linear", name="linear")], baseline="px4")
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------ implausible inputs
def test_implausible_inputs_are_warned():
    rng = np.random.default_rng(6)
    kelvin = _run("kelvin", _ramp() + 273.15, {"gyro_x": np.zeros(1800)}, noise=0.01, rng=rng)
    ms_as_s = _run("ms-as-s", _ramp(), {"gyro_x": np.zeros(1800)}, noise=0.01, rng=rng)
    ms_as_s.time_s = ms_as_s.time_s * 1e4          # a 1-h test that lasts 41 days …
    ms_as_s.sample_rate_hz = RATE_HZ / 1e4          # … at one sample every 5.6 h
    too_fast = _run("s-as-ms", _ramp(), {"gyro_x": np.zeros(1800)}, noise=0.01, rng=rng)
    too_fast.time_s = too_fast.time_s / 1000.0      # 60 °C in 3.6 s
    too_fast.sample_rate_hz = RATE_HZ * 1000.0
    bursts = _run("bursts", _ramp(), {"gyro_x": np.zeros(1800)}, noise=0.01, rng=rng)
    bursts.time_s = bursts.time_s + 300.0 * (np.arange(1800) // 5)  # 10-s bursts, 300-s gaps
    w = input_warnings(Dataset([kelvin]), signals=["temperature_c"], rate_window_s=60.0)
    assert len(w) == 1 and w[0].startswith("run 'kelvin': temperature_c spans 263.1 … 323.1 °C")
    assert "Kelvin" in w[0]
    w = input_warnings(Dataset([ms_as_s]), signals=["temperature_c"], rate_window_s=60.0)
    assert any("ms or µs read as seconds" in x for x in w)
    assert any("sample rate 5e-05 Hz" in x for x in w)
    w = input_warnings(Dataset([too_fast]), signals=["temperature_c"], rate_window_s=60.0)
    assert any("too short by a time-unit factor" in x for x in w)
    quiet = input_warnings(Dataset([bursts]), signals=["temperature_c"], rate_window_s=60.0)
    assert quiet == []  # gaps only matter to the rate input
    w = input_warnings(Dataset([bursts]), signals=["temperature_c", "rate_c_per_min"],
                       rate_window_s=60.0)
    assert len(w) == 1 and "the rate input (dT/dt over 60 s)" in w[0] and "gaps up to 302 s" in w[0]


def test_default_baseline_applies_only_where_a_cubic_exists(tmp_path):
    from thermonet.training.config import load_config
    from thermonet.workflows.compare_plan import plan

    rng = np.random.default_rng(7)
    path = write_parquet(Dataset([_run(f"run{k}", _ramp(), {"gyro_x": 0.01 * _ramp()},
                                       noise=0.01, rng=rng) for k in range(3)]),
                         tmp_path / "d.parquet")
    body = f"data: {{paths: ['{path}']}}\nfamilies: [{{family: linear, name: line}}]\n"
    (tmp_path / "implicit.yaml").write_text(body)
    cfg = load_config(tmp_path / "implicit.yaml")
    plan(cfg)  # no 'baseline' key, no cubic: no baseline
    assert cfg.baseline is None
    (tmp_path / "explicit.yaml").write_text(body + "baseline: cubic\n")
    with pytest.raises(ConfigError, match=r"explicit\.yaml: key 'baseline': no family named "
                                          r"'cubic' \(families: line\)"):
        plan(load_config(tmp_path / "explicit.yaml"))


@pytest.mark.parametrize("x, text", [(0.5, "0.5"), (0.98512, "0.985"), (0.99995, "0.99995"),
                                     (1.00004, "1.00004"), (0.9999999, "0.9999999"),
                                     (1.0, "1"), (16.716, "16.7"), (float("nan"), "nan")])
def test_a_ratio_that_is_not_1_never_prints_as_1(x, text):
    """The console's verdict cells: "better" and "indistinguishable" must not look alike
    (an interval [0.985, 0.99995] printed as [0.985, 1])."""
    from thermonet.reporting.report import ratio_text

    assert ratio_text(x) == text


def _one_axis_results(name: str, ratio: float, interval: list[float], verdict: str) -> dict:
    """results.json's shape for one family on one axis (the keys format_table and the report
    read), with a selection block naming the same candidate."""
    axis = {"score_ratio": ratio, "interval": interval, "verdict": verdict, "compensate": True,
            "vs_baseline": None, "pp_raw": 0.02, "pp_comp": 0.001}
    return {"device": "d", "units": {"gyro_x": "deg/s"}, "baseline": None, "chosen": name,
            "chosen_reason": "the best out of fold",
            "families": {name: {"status": "ok", "val_score": 0.4, "fit_seconds": 0.5,
                                "n_params": 4, "axes": {"gyro_x": axis}},
                         "cubic": {"status": "ok", "val_score": 0.5, "fit_seconds": 0.25,
                                   "n_params": 4, "axes": {"gyro_x": dict(axis)}}},
            "selection": {"kind": "excursions", "folds": 3, "purge_s": 60.0, "window_s": 60.0,
                          "candidates": {name: {"status": "ok", "score": 0.4,
                                                "interval": [0.3, 0.5],
                                                "fold_scores": [0.4, 0.41, 0.39]},
                                         "cubic": {"status": "failed", "reason": "x"}}}}


@pytest.mark.parametrize("name", ["rbf", "poly3-rate-and-hysteresis", "m" * 64])
def test_a_long_family_name_never_shifts_the_console_table(name):
    """The name column is as wide as the longest family name: every row's cells start where
    the header's do (a name over 14 characters used to push its row right)."""
    from thermonet.workflows.compare import format_table

    lines = format_table(_one_axis_results(name, 0.5, [0.4, 0.6], "better")).splitlines()
    head, rows = lines[0], [ln for ln in lines[2:] if ln.split()[:1] in ([name], ["cubic"])][:2]
    assert len(rows) == 2
    for row in rows:
        assert row.index(" gyro_x ") == head.index(" axis ")
        # right-aligned cells end where their headers end
        assert row.index("0.6] +") + len("0.6] +") == head.index("vs raw") + len("vs raw")
        assert row.rindex("0.001") + len("0.001") == head.rindex("pp_comp") + len("pp_comp")
    scores = [ln for ln in lines if ln.startswith("  ") and ("0.4 [0.3, 0.5]" in ln
                                                             or "not a candidate" in ln)]
    assert len(scores) == 2 and len({ln.index(ln.split()[1]) for ln in scores}) == 1


def test_the_report_prints_a_ratio_as_the_console_does():
    """A ratio that differs from 1 never reads 1 on the page either (was 'worse 1 [1, 1.01]'
    where the console said 1.003 [1.001, 1.01])."""
    from thermonet.reporting.report import render_report
    from thermonet.workflows.compare import format_table

    res = _one_axis_results("cubic2", 1.0031, [1.0012, 1.0104], "worse")
    assert "1.003 [1.001, 1.01] !" in format_table(res)
    page = render_report(res)
    assert "<b>worse</b><br>1.003 [1.001, 1.01]</td>" in page
    assert "<br>1 [" not in page
