"""Hyper-parameters chosen by cross-validation on the training pool (``families[].tune``,
"every family tuned by inner cross-validation").

Known answers: a drift that is a quadratic in ΔT is tuned to degree 2 out of 1..5 (degree 1
cannot follow it; 3..5 add parameters the one-standard-error rule does not pay for), and the
choice never looks at the test run: changing the test run's outputs changes neither the tuned
value nor any grid point's out-of-fold score.
"""

from __future__ import annotations

import numpy as np
import pytest

from thermonet.core.errors import ConfigError
from thermonet.core.recording import Dataset, Recording
from thermonet.training.config import config_from_mapping
from thermonet.workflows.compare import run_compare

pytestmark = pytest.mark.numerics

QUAD = (0.02, 0.004)   # drift = a·ΔT + b·ΔT² [deg/s], ΔT about 25 °C


def _run(i: int, *, test_bump: float = 0.0) -> Recording:
    """One heat/cool cycle of a 1-axis gyro at 0.2 Hz with a quadratic drift; runs differ in
    their temperature path and noise.  ``test_bump`` adds a cubic the training never sees."""
    rng = np.random.default_rng(10 + i)
    n = 1800
    t = np.arange(n) * 5.0
    lo, hi = -10.0 + 3 * i, 60.0 - 2 * i
    temp = np.interp(t, [0, 0.45 * t[-1], t[-1]], [lo, hi, lo + 5]) + rng.normal(0, 0.02, n)
    d = temp - 25.0
    drift = QUAD[0] * d + QUAD[1] * d ** 2 + test_bump * (d / 30.0) ** 3
    return Recording(time_s=t, temperature_c=temp,
                     outputs={"gyro_x": drift + rng.normal(0, 0.01, n)},
                     units={"gyro_x": "deg/s"}, run_id=f"run{i}", sample_rate_hz=0.2)


def _config() -> dict:
    return {"split": {"strategy": "runs", "train": ["run0", "run1", "run2"], "val": "run3",
                      "test": "run4"},
            "features": {"t_ref": 25.0},
            "families": [
                {"family": "poly", "name": "cubic", "inputs": ["dT"], "params": {"degree": 3}},
                {"family": "poly", "name": "poly", "inputs": ["dT"],
                 "tune": {"degree": [1, 2, 3, 4, 5]}}],
            "tracking": {"enabled": False}}


def _compare(tmp_path, name: str, test_bump: float = 0.0) -> dict:
    runs = [_run(i) for i in range(4)] + [_run(4, test_bump=test_bump)]
    cfg = config_from_mapping(_config())
    return run_compare(cfg, tmp_path / name, dataset=Dataset(runs), track=False, quiet=True,
                       plots=False)


def test_a_quadratic_drift_is_tuned_to_degree_two_on_the_training_pool_only(tmp_path):
    res = _compare(tmp_path, "a")
    tuned = res["families"]["poly"]["tuned"]
    assert tuned["degree"] == 2, tuned
    grid = tuned["tuning"]["grid"]
    assert list(grid) == [f"degree={d}" for d in range(1, 6)]
    # degree 1 cannot follow a quadratic: far worse out of fold than degree 2
    assert grid["degree=1"] > 5 * grid["degree=2"]
    assert "chose degree=2" in tuned["tuning"]["rule"]
    # the model compare keeps is the tuned one (the checkpointed hyper-parameters)
    assert res["families"]["poly"]["n_params"] == 3        # 2 coefficients + offset, 1 axis
    # ... and its checkpoint says so: the tuned value is the family config's parameter
    from thermonet.training.checkpoint import load_checkpoint

    model, meta = load_checkpoint(tmp_path / "a" / "models" / "poly.pt")
    assert meta["hyper"]["degree"] == 2 == meta["config"]["family"]["params"]["degree"]
    # the baseline is never tuned
    assert "tuning" not in res["families"]["cubic"]["tuned"]
    # the test run is not seen: a cubic added to it alone changes the verdicts, not the tuning
    other = _compare(tmp_path, "b", test_bump=0.5)
    assert other["families"]["poly"]["tuned"] == tuned
    assert other["families"]["poly"]["test_score"] != pytest.approx(
        res["families"]["poly"]["test_score"], rel=1e-3)


@pytest.mark.parametrize("tune, key", [
    ({"degree": []}, "families[0].tune.degree"),
    ({"degree": 3}, "families[0].tune.degree"),
    ({"degree": list(range(1, 18))}, "families[0].tune"),
    ({"order": [1, 2]}, "families[0].tune"),
    ({"degree": [2, "three"]}, "families[0].tune"),
])
def test_a_bad_grid_is_one_clear_error_naming_its_key(tune, key):
    from thermonet.training.config import check_families

    mapping = {"families": [{"family": "poly", "inputs": ["dT"], "tune": tune}]}
    with pytest.raises(ConfigError) as err:   # torch-free checks, then the built families
        check_families(config_from_mapping(mapping, source="c.yaml"), source="c.yaml")
    msg = str(err.value)
    assert f"key '{key}" in msg and "\n" not in msg, msg


def test_the_tuned_values_read_in_one_line():
    from thermonet.reporting.report import tuned_text

    tuned = {"n_centres": 16, "width_scale": 0.5, "ridge": ["inf", 1e-4, "inf"],
             "tuning": {"grid": {"n_centres=8": 0.0037429, "n_centres=16": 0.0035929},
                        "rule": "chose n_centres=16"}}
    assert tuned_text(tuned) == ("n_centres=16, width_scale=0.5, ridge=[inf 0.0001 inf] "
                                 "(out-of-fold score: n_centres=8 0.00374, n_centres=16 0.00359)")
    assert tuned_text({}) == ""


def test_tuning_choice_records_the_grid_and_the_rule_whatever_the_outcome():
    """One rule turns select()'s outcome over a grid into the chosen point and its record
    (compare's families and the sensor model alike): a chosen label maps back to its point;
    with none chosen the configured values stay and the record says so under the same keys."""
    from thermonet.scoring.selection import Selection, point_label, tuning_choice

    points = [{"degree": 2}, {"degree": 3, "cross": False}]
    assert [point_label(q) for q in points] == ["degree=2", "degree=3,cross=False"]
    cands = {"degree=2": {"status": "ok", "score": 0.5},
             "degree=3,cross=False": {"status": "failed", "reason": "too few windows"}}
    chosen = Selection("degree=2", [], "lowest out-of-fold score", {}, {"candidates": cands})
    point, record = tuning_choice(chosen, points)
    assert point is points[0]
    assert record == {"grid": {"degree=2": 0.5, "degree=3,cross=False": "too few windows"},
                      "rule": "lowest out-of-fold score"}
    none = Selection(None, [], "no candidate beats raw", {}, {"candidates": cands})
    point, record = tuning_choice(none, points)
    assert point is None
    assert record["rule"] == "kept the configured values: no candidate beats raw"
    assert record["grid"]["degree=2"] == 0.5
