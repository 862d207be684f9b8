"""Short two-way ramps: the ``cycle:`` test spec, and the fleet prior's paired fast points.

A fast sample is off by the thermometer's lag times the rate; heating and cooling carry that
error with opposite signs, so a bin visited both ways at matching rates gives one paired
point whose lag error cancels (:func:`thermonet.scoring.prior_points.bin_points`).  Checked
on a synthetic series with a known delay: the known cubic comes back within what the noise
and the lag's second-order term allow, where the same samples taken one way are biased.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from thermonet.cli import main
from thermonet.core.errors import ConfigError
from thermonet.scoring.prior import fit_unit
from thermonet.scoring.prior_points import MAX_RATE_C_PER_MIN, Points, bin_points, shape_design
from thermonet.sim.chamber import Ramp, Soak
from thermonet.sim.fleet import short_test

T_REF, SCALE, DEGREE = 25.0, 35.0, 3
FS = 10.0                 # Hz
DELAY_S = 30.0            # the thermometer reads the die's temperature this late
NOISE = 0.01              # white noise of the output
C1, C2, C3 = 0.01, 5e-5, 1e-6     # the known cubic in (T − 25): f = c1·x + c2·x² + c3·x³


def _f(temp: np.ndarray) -> np.ndarray:
    x = temp - T_REF
    return C1 * x + C2 * x ** 2 + C3 * x ** 3


def _series(legs: list[tuple[float, float]], seed: int = 0
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time, thermometer, output) of a die temperature through ``legs`` ((to °C, minutes),
    a leg to the same temperature is a soak), starting soaked at 0 °C, read DELAY_S late."""
    die = [np.zeros(int(2 * 60 * FS))]
    for to, minutes in legs:
        n = int(minutes * 60 * FS)
        die.append(np.linspace(die[-1][-1], to, n + 1)[1:])
    d = np.concatenate(die)
    t = np.arange(d.size) / FS
    lag = int(DELAY_S * FS)
    thermo = np.r_[np.full(lag, d[0]), d[:-lag]]
    y = _f(d) + np.random.default_rng(seed).standard_normal(d.size) * NOISE
    return t, thermo, y


def _curve_error(pts: Points) -> float:
    """Largest |fitted − known| over 0…60 °C, each curve's mean over the grid removed."""
    shape = fit_unit(pts, t_ref=T_REF, scale=SCALE, degree=DEGREE).shape
    grid = np.linspace(0.0, 60.0, 61)
    fit = shape_design(grid, T_REF, SCALE, DEGREE) @ shape
    true = _f(grid)
    return float(np.max(np.abs((fit - fit.mean()) - (true - true.mean()))))


def _tolerance(pts: Points, rate_c_per_min: float) -> float:
    """What the noise and the lag's second-order term allow: 5 standard errors of the fitted
    curve (at its worst temperature, from the points' sampling variances alone) plus
    max |f''|·(lag·rate)²/2, the part of the lag's error a pair does not cancel."""
    X = shape_design(pts.temperature_c, T_REF, SCALE, DEGREE)
    X = X - X.mean(axis=0)
    cov = float(np.mean(pts.sampling_var)) * np.linalg.pinv(X.T @ X)
    G = shape_design(np.linspace(0.0, 60.0, 61), T_REF, SCALE, DEGREE)
    G = G - G.mean(axis=0)
    sd = float(np.sqrt(np.max(np.einsum("ij,jk,ik->i", G, cov, G))))
    shift = DELAY_S * rate_c_per_min / 60.0
    f2 = 2 * C2 + 6 * C3 * 35.0
    return 5.0 * sd + f2 * shift ** 2 / 2.0


# ------------------------------------------------------------------ the spec
def test_cycle_spec_goes_up_and_back_at_one_rate() -> None:
    p = short_test("cycle:-20,75,10")
    assert p.start_c == -20.0
    soak, up, down = p.segments
    assert isinstance(soak, Soak) and soak.temperature_c == -20.0
    assert isinstance(up, Ramp) and isinstance(down, Ramp)
    assert (up.to_c, down.to_c) == (75.0, -20.0)
    # 95 °C each way in 5 min: 19 °C/min
    assert up.rate_c_per_h == pytest.approx(1140.0) and down.rate_c_per_h == pytest.approx(1140.0)
    ramp = short_test("ramp:20,30,10")            # unchanged: one way, 1 °C/min
    assert len(ramp.segments) == 2 and ramp.segments[1].rate_c_per_h == pytest.approx(60.0)


@pytest.mark.parametrize("spec", ["cycle:10,10,10", "cycle:0,60", "cycle:0,60,0",
                                  "cycle:0,60,-5", "cycle:0,200,10", "cycle:a,60,10",
                                  "cycle:0,60,nan", "cycle:0,60,2000", "cycles:0,60,10"])
def test_bad_cycle_specs_are_one_line_naming_the_value(spec: str) -> None:
    with pytest.raises(ConfigError) as e:
        short_test(spec)
    msg = str(e.value)
    assert repr(spec) in msg and "cycle:FROM,TO,MINUTES" in msg and "\n" not in msg


@pytest.mark.parametrize("spec,minutes", [("cycle:-20,75,0.001", "3.17"),
                                          ("ramp:-20,75,1e-300", "1.58")])
def test_a_ramp_no_chamber_can_run_is_refused_naming_the_minutes_needed(spec, minutes) -> None:
    """95 °C in 0.001 min is 190,000 °C/min: a thermal shock, which the chamber model does
    not simulate; the line says how many minutes the test needs at 60 °C/min."""
    with pytest.raises(ConfigError) as e:
        short_test(spec)
    msg = str(e.value)
    assert repr(spec) in msg and "above 60 °C/min" in msg and f"at least {minutes} minutes" \
        in msg and "\n" not in msg
    assert short_test("cycle:-20,75,3.2").segments[1].rate_c_per_h <= 60.0 * 60.0


# ------------------------------------------------------------------ the pairing rule
def test_two_way_fast_ramp_recovers_the_cubic_where_one_way_is_biased() -> None:
    rate = 6.0                                    # °C/min: 5× the one-way limit
    # up 0 → 60 in 10 min, 3 min at 60 (the turn a soak), down in 10 min
    t, thermo, y = _series([(60.0, 10.0), (60.0, 3.0), (0.0, 10.0)])
    pts = bin_points(thermo, y, time_s=t)
    fast = (pts.temperature_c > 5) & (pts.temperature_c < 55)
    assert fast.sum() >= 40                       # the paired points: one per degree
    err = _curve_error(pts)
    assert err < _tolerance(pts, rate)
    # the same samples taken one way (every fast sample kept): biased by lag × rate
    t1, th1, y1 = _series([(60.0, 10.0), (60.0, 3.0)])
    kept = bin_points(th1, y1, time_s=t1, max_rate_c_per_min=np.inf)
    assert _curve_error(kept) > 2 * _tolerance(kept, rate)
    # the rule keeps none of them: one way, nothing to pair with
    one_way = bin_points(th1, y1, time_s=t1)
    assert not np.any((one_way.temperature_c > 5) & (one_way.temperature_c < 55))
    # without pairing the two-way test has its soaks alone
    alone = bin_points(thermo, y, time_s=t, pair_fast=False)
    assert not np.any((alone.temperature_c > 5) & (alone.temperature_c < 55))


def test_pairs_need_matching_rates_and_weigh_both_directions_equally() -> None:
    # up at 6 °C/min, down at 2 °C/min: the net rate 2 °C/min is above the limit
    t, thermo, y = _series([(60.0, 10.0), (60.0, 3.0), (0.0, 30.0)])
    pts = bin_points(thermo, y, time_s=t)
    assert (6.0 - 2.0) / 2.0 > MAX_RATE_C_PER_MIN
    assert not np.any((pts.temperature_c > 5) & (pts.temperature_c < 55))
    # a pair's value is the mean of the two directions' means, whatever their counts
    tt = np.arange(0.0, 1200.0, 0.1)
    temp = np.where(tt < 600, tt / 60.0 * 3.0, 30.0 - (tt - 600) / 60.0 * 3.0)   # ±3 °C/min
    val = np.where(tt < 600, 1.0, 3.0)
    p = bin_points(temp, val, time_s=tt)
    mid = np.abs(p.temperature_c - 15.0) < 0.5
    assert mid.sum() == 1 and p.value[mid][0] == pytest.approx(2.0)
    assert p.n_samples[mid][0] == pytest.approx(400, abs=4)


# ------------------------------------------------------------------ the station
FLEET = """data: {preset: consumer-imu, seed: 0, runs: 1}
target: {gyro: zero, acc: at-t-ref}
features: {t_ref: 25.0}
"""


def test_station_takes_a_cycle_test(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    Path("fleet.yaml").write_text(FLEET)
    assert main(["prior", "fleet.yaml", "--units", "12", "--clusters", "2", "--out",
                 "prior.json", "-q"]) == 0
    Path("new.yaml").write_text(FLEET.replace("seed: 0", "seed: 7"))
    rc = main(["station", "new.yaml", "--prior", "prior.json", "--units", "2", "--clusters",
               "2", "--test", "cycle:-20,75,10", "--out", "st", "--executor", "serial", "-q"])
    assert rc in (0, 3)
    res = json.loads(Path("st/results.json").read_text())
    assert len(res["units"]) == 2
    for unit in res["units"].values():
        assert unit["temperature_span_c"] > 60.0     # the lagging thermometer: −20 … 55 °C
    capsys.readouterr()
    assert main(["station", "new.yaml", "--prior", "prior.json", "--units", "2", "--test",
                 "cycle:0,60", "--out", "st2", "--executor", "serial"]) == 1
    err = capsys.readouterr().err.strip()
    assert "'cycle:0,60'" in err and len(err.splitlines()) == 1
    assert not Path("st2").exists()
