"""`thermonet prior` and `thermonet station` end to end on simulated structured fleets.

The prior leaves the planted outliers out of the population (and, refusing a fleet left too
small, names them); the station flags new units 10 σ off their fleet and passes the others,
gives a unit with a whole climate cycle its verdict, says "not judged (why)" of a residual it
cannot judge and puts the unit of measure on a residual; the firmware header compiled with
gcc gives the posterior polynomial (float32 tolerance); bad input (a prior of other axes than
the preset's, a config of another t_ref, a mapping's unit of measure or data.outputs not the
prior's, a soak repeated, an --out below a file) is one line, exit 1, nothing written, and
comes before the work.  A line's own files (CSV with serial numbers): a dead or stuck axis
fails, without a firmware file; one unit's data under two serials, or one test filed twice,
is refused; a unit of two runs says so; a top-level ``limits``, a config with no data and a
prior edited by hand (its sha256) are refused.  A unit whose own data fail a check (outside
the prior's range, a dead thermometer, a file in other units) FAILs alone with its reason and
the others finish, on the process pool as in this process; a bug in a unit's task still
stops the batch.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from thermonet.cli import main
from thermonet.data.io import write_parquet
from thermonet.scoring.prior_io import prior_digest
from thermonet.sim import simulate_fleet

FLEET = """data: {preset: consumer-imu, seed: 0, runs: 1}
target: {gyro: zero, acc: at-t-ref}
features: {t_ref: 25.0}
station:
  limits:
    gyro_x: {max_tempco: 0.01}
"""


@pytest.fixture(scope="module")
def prior(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("prior")
    (d / "fleet.yaml").write_text(FLEET)
    assert main(["prior", str(d / "fleet.yaml"), "--units", "24", "--clusters", "2",
                 "--outliers", "2", "--out", str(d / "prior.json"), "-q"]) == 0
    return d / "prior.json"


def test_prior_leaves_the_planted_outliers_out(prior: Path) -> None:
    data = json.loads(prior.read_text())
    assert {"consumer-imu-u022", "consumer-imu-u023"} <= set(data["excluded"])
    assert data["n_units"] == 24 - len(data["excluded"]) and data["n_units"] >= 20
    assert set(data["axes"]) == {"gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"}
    assert data["range_c"] == [-20.0, 75.0]
    # the 3-soak test for every axis: the range's ends and one middle temperature between them
    plan = data["three_soak_plan_c"]
    assert len(plan) == 3 and plan[0] == -20.0 and plan[2] == 75.0 and -20.0 < plan[1] < 75.0
    # the simulated gyro_y tempco is −0.003 °/s/K (c₁ of the preset): the prior's mean curve
    ax = data["axes"]["gyro_y"]
    slope = float(np.dot(ax["weights"], np.asarray(ax["means"])[:, 0])) / data["scale_c"]
    assert slope == pytest.approx(-0.003, rel=0.35)


def test_station_flags_strangers_passes_the_rest_and_writes_a_header(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    Path("new.yaml").write_text(FLEET.replace("seed: 0", "seed: 7"))
    rc = main(["station", "new.yaml", "--prior", str(prior), "--units", "6", "--outliers", "2",
               "--clusters", "2", "--test", "soaks:-10,25,60", "--out", "st",
               "--executor", "serial", "-q"])
    res = json.loads(Path("st/results.json").read_text())
    assert rc == 3                                   # the outliers fail
    flagged = set(res["summary"]["flagged_unlike_fleet"])
    # no normal unit flagged; the outliers (recall measured by bench_prior.py) among the flags
    assert flagged and flagged <= {"consumer-imu-u004", "consumer-imu-u005"}
    # the console says what failed: unlike its fleet, with the p-value (was "like_its_fleet")
    from thermonet.workflows.station import format_station

    dev = sorted(flagged)[0]
    axis = next(a for a, r in res["units"][dev]["axes"].items() if r["flagged_unlike_fleet"])
    line = next(ln for ln in format_station(res).splitlines() if ln.startswith(dev))
    assert f"{axis}: unlike its fleet (p={res['units'][dev]['axes'][axis]['p_value']:.2g})" \
        in line and "like_its_fleet" not in line, line
    # the prior the station used: its file and digest (the config it was built from apart)
    assert res["prior_file"] == str(prior) and res["prior"].endswith("fleet.yaml")
    import hashlib
    assert res["prior_sha256"] == hashlib.sha256(prior.read_bytes()).hexdigest()
    for dev in ("consumer-imu-u000", "consumer-imu-u001", "consumer-imu-u002"):
        assert res["units"][dev]["verdict"] == "PASS"
    assert res["units"]["consumer-imu-u000"]["files"] == "units/consumer-imu-u000"
    cal = json.loads(Path("st/units/consumer-imu-u000/calibration.json").read_text())
    unit = cal["axes"]["gyro_y"]
    assert unit["held_out_rms"] is not None and unit["held_out_rms"] < 0.03   # °/s
    assert unit["coefficients"][1] == pytest.approx(-0.003, rel=0.35)
    _header_matches(Path("st/units/consumer-imu-u000"), tmp_path)
    head = Path("st/units/consumer-imu-u000/thermonet_cal.h").read_text().split("*/")[0]
    assert "drift in the axis's unit (gyro_x deg/s, " in head and "acc_z m/s^2)" in head


def _header_matches(udir: Path, tmp: Path) -> None:
    cal = json.loads((udir / "calibration.json").read_text())
    c = cal["axes"]["acc_z"]["coefficients"]
    src = tmp / "main.c"
    src.write_text(f'#include <stdio.h>\n#include "{udir.resolve()}/thermonet_cal.h"\n'
                   "int main(void){for(int i=-20;i<=75;i+=5)"
                   'printf("%.9g\\n",(double)thermonet_cal_acc_z((float)i));return 0;}\n')
    exe = tmp / "cal"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-o", str(exe),
                    str(src)], check=True)
    got = np.array([float(v) for v in subprocess.run([str(exe)], capture_output=True,
                                                     text=True, check=True).stdout.split()])
    t = np.arange(-20, 76, 5, dtype=np.float64) - 25.0
    want = np.polynomial.polynomial.polyval(t, c)
    scale = np.max(np.abs(np.asarray(c)[:, None] * np.abs(t)[None] ** np.arange(len(c))[:, None]))
    # float32 Horner: a few ulps of the largest term per step
    assert np.allclose(got, want, rtol=0, atol=8 * len(c) * np.finfo(np.float32).eps * scale)


def _one_line_refusal(capsys: pytest.CaptureFixture[str], argv: list[str], words: str) -> None:
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1, err


def test_refusals_are_one_line_and_write_nothing(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    Path("new.yaml").write_text(FLEET)
    Path("acc.yaml").write_text("data: {preset: accel-ramp}\ntarget: drift\n")
    _one_line_refusal(capsys, ["prior", "new.yaml", "--units", "5", "--out", "p.json"],
                      "a fleet prior needs at least 10 calibrated units")
    assert not Path("p.json").exists()
    # the preset's axes are the config's: refused before any unit runs, naming the key
    _one_line_refusal(capsys, ["station", "acc.yaml", "--prior", str(prior), "--units", "2",
                               "--out", "st", "--executor", "serial"],
                      f"acc.yaml: key 'data.preset' ('accel-ramp'): the prior ({prior}) is of "
                      "axes gyro_x, gyro_y, gyro_z, acc_x, acc_y, acc_z; the data lack gyro_x")
    # units measured outside the prior's range: each FAILs with the reason (was: exit 1 for
    # the batch, nothing written)
    assert main(["station", "new.yaml", "--prior", str(prior), "--units", "3", "--test",
                 "soaks:-40,25", "--out", "cold", "--executor", "serial"]) == 3
    out = capsys.readouterr().out
    for k in range(3):
        assert (f"consumer-imu-u{k:03d}: FAIL  not calibrated: measured -40.0 to 24.9 °C, "
                "outside the fleet prior's range -20 to 75 °C (the prior says nothing there)"
                ) in out.splitlines(), out
    assert json.loads(Path("cold/results.json").read_text())["summary"]["not_calibrated"] == [
        f"consumer-imu-u{k:03d}" for k in range(3)]
    # a bad test spec is refused before any unit runs: said once, with no unit's progress
    assert main(["station", "new.yaml", "--prior", str(prior), "--units", "3", "--test",
                 "cycle:-20,75", "--out", "st", "--executor", "serial"]) == 1
    out, err = capsys.readouterr()
    assert "station:" not in out and err.count("cycle:-20,75") == 1 and "unit" not in err, err
    _one_line_refusal(capsys, ["station", "new.yaml", "--prior", "new.yaml", "--units", "2",
                               "--out", "st"], "--prior: not JSON")
    _one_line_refusal(capsys, ["station", "new.yaml", "--prior", str(prior), "--test",
                               "soaks:0", "--out", "st"], "--test needs --units")
    Path("deg2.yaml").write_text(FLEET.replace("station:", "station:\n  degree: 2"))
    _one_line_refusal(capsys, ["station", "deg2.yaml", "--prior", str(prior), "--units", "2",
                               "--out", "st"], "is of degree 3")
    ds = simulate_fleet("consumer-imu", units=1, seed=3, test="soaks:0,25,50")
    for r in ds:     # the same unit's gyro in rad/s: another unit of measure than the prior's
        for a in ("gyro_x", "gyro_y", "gyro_z"):
            r.outputs[a] = np.deg2rad(r.outputs[a])
            r.units[a] = "rad/s"
    write_parquet(ds, "rad.parquet")
    Path("rad.yaml").write_text(FLEET.replace("preset: consumer-imu, seed: 0, runs: 1",
                                              "paths: [rad.parquet]"))
    # a unit's own file in other units than the prior's: that unit FAILs, saying so
    assert main(["station", "rad.yaml", "--prior", str(prior), "--out", "rad", "--executor",
                 "serial", "-q"]) == 3
    cal = json.loads(Path("rad/units/consumer-imu-u000/calibration.json").read_text())
    assert cal["verdict"] == "FAIL" and cal["axes"] == {} and cal["error"] == (
        "unit 'consumer-imu-u000': axis gyro_x is in 'rad/s', the prior's in 'deg/s' (convert "
        "one of them first)")
    assert not Path("rad/units/consumer-imu-u000/thermonet_cal.h").exists()
    Path("bad.yaml").write_text(FLEET.replace("gyro_x: {max_tempco", "gyro_q: {max_tempco"))
    _one_line_refusal(capsys, ["station", "bad.yaml", "--prior", str(prior), "--units", "2",
                               "--out", "st"], "station.limits.gyro_q")
    assert not Path("st").exists()


def test_points_needed_for_a_residual_limit(prior: Path) -> None:
    from thermonet.scoring.prior import StationLimit
    from thermonet.scoring.prior_io import prior_from_dict
    from thermonet.workflows.station import prior_summary

    fp = prior_from_dict(json.loads(prior.read_text()), str(prior))
    misfit = fp.axis("gyro_y").misfit_var
    for lim, expect_none in ((0.5 * np.sqrt(misfit), True), (100 * np.sqrt(misfit), False)):
        row = prior_summary(fp, {"gyro_y": StationLimit(max_residual=float(lim))}
                            )["gyro_y"]["points_needed"][-1]
        assert row["limit"] == "max_residual"
        # a limit under a point's own error is out of reach; a loose one needs the first pair
        assert (row["points"] is None) == expect_none
        if not expect_none:
            assert row["points"] == 2 and len(row["temperatures_c"]) == 2


def _station_on(executors: tuple[str, ...], prior: Path, tmp: Path) -> None:
    """The same units on each executor: the same verdicts and the same unit files."""
    (tmp / "new.yaml").write_text(FLEET.replace("seed: 0", "seed: 11"))
    seen = []
    for ex in executors:
        out = tmp / f"st-{ex}"
        main(["station", str(tmp / "new.yaml"), "--prior", str(prior), "--units", "3",
              "--clusters", "2", "--test", "soaks:-10,25,60", "--out", str(out),
              "--executor", ex, "--workers", "2", "-q"])
        res = json.loads((out / "results.json").read_text())
        files = {p.relative_to(out).as_posix(): p.read_bytes()
                 for p in sorted((out / "units").rglob("*")) if p.is_file()}
        seen.append(({d: u["axes"] for d, u in res["units"].items()}, files))
    for other in seen[1:]:
        assert other == seen[0]          # the same arithmetic in every process: bit-identical


def test_serial_and_process_pool_give_identical_units(prior: Path, tmp_path: Path) -> None:
    _station_on(("serial", "process"), prior, tmp_path)


@pytest.mark.slow
def test_serial_and_ray_give_identical_units(prior: Path, tmp_path: Path) -> None:
    """A real local Ray (its start-up is most of this test's time; `make test-slow`)."""
    _station_on(("serial", "ray"), prior, tmp_path)


def test_failures_with_one_reason_are_said_once() -> None:
    from thermonet.core.errors import failures_line

    bad = [(f"u{i}", f"unit 'u{i}': measured -40 °C") for i in range(4)] + [("u9", "no data")]
    assert failures_line(bad, "unit") == ("4 units ('u0', 'u1', …): measured -40 °C; "
                                          "unit 'u9': no data")
    assert failures_line(bad[:2], "unit") == "2 units ('u0', 'u1'): measured -40 °C"
    many = [(f"u{i}", f"reason {i}") for i in range(7)]
    line = failures_line(many, "unit", shown=5)
    assert line.endswith("unit 'u4': reason 4 (and 2 more reasons)") and "u5" not in line


def test_a_unit_with_a_whole_climate_cycle_gets_a_verdict(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The preset's own climate cycle (no --test): ~200 points per axis, once past the 64
    point errors the mixture design drew when choosing a failed unit's next temperatures."""
    monkeypatch.chdir(tmp_path)
    Path("new.yaml").write_text(FLEET)
    rc = main(["station", "new.yaml", "--prior", str(prior), "--units", "1", "--out", "cyc",
               "--executor", "serial", "-q"])
    res = json.loads(Path("cyc/results.json").read_text())
    cal = json.loads(Path("cyc/units/consumer-imu-u000/calibration.json").read_text())
    assert rc == (0 if res["summary"]["failed"] == 0 else 3)
    fp = json.loads(prior.read_text())
    for axis in fp["axes"]:
        r = cal["axes"][axis]
        assert r["points"] > 64 and r["held_out_rms"] is not None
        assert r["verdict"] == ("PASS" if all(c["ok"] for c in r["checks"]) else "FAIL")
        if r["verdict"] == "FAIL":    # new temperatures inside the prior's range, none a
            nxt = r["next_temperatures_c"]    # repeat: a cycle over the range leaves none
            assert len(nxt) <= 2 and all(fp["range_c"][0] <= t <= fp["range_c"][1] for t in nxt)
            assert all(abs(a - b) >= 2.5 for i, a in enumerate(nxt) for b in nxt[i + 1:])


def test_a_residual_not_judged_says_so_and_residuals_carry_their_unit(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    Path("res.yaml").write_text(FLEET.replace("{max_tempco: 0.01}",
                                              "{max_tempco: 0.01, max_residual: 0.05}"))
    capsys.readouterr()
    # one soak: one point per axis, nothing to hold out; the residual limit fails, saying why
    assert main(["station", "res.yaml", "--prior", str(prior), "--units", "1", "--test",
                 "soaks:25", "--out", "one", "--executor", "serial"]) == 3
    out = capsys.readouterr().out
    assert ("consumer-imu-u000: FAIL  held-out residual not judged (1 point)  "
            "[gyro_x: max_residual: not judged (1 point)]") in out, out
    cal = json.loads(Path("one/units/consumer-imu-u000/calibration.json").read_text())
    gx = cal["axes"]["gyro_x"]
    assert gx["held_out_rms"] is None and gx["held_out_not_judged"] == "1 point"
    assert {"limit": "max_residual", "value": None, "max": 0.05, "ok": False,
            "not_judged": "1 point"} in gx["checks"]
    # three soaks: the worst held-out residual of results.json per unit of measure (the
    # gyro's in °/s and the accelerometer's in m/s² are not compared with one another)
    main(["station", "res.yaml", "--prior", str(prior), "--units", "1", "--test",
          "soaks:-10,25,60", "--out", "three", "--executor", "serial"])
    out = capsys.readouterr().out
    res = json.loads(Path("three/results.json").read_text())
    axes = res["units"]["consumer-imu-u000"]["axes"]
    uom = json.loads(prior.read_text())["units_of_measure"]
    worst = {u: max((a for a in axes if uom[a] == u), key=lambda a: axes[a]["held_out_rms"])
             for u in ("deg/s", "m/s^2")}
    assert "worst held-out residual " + ", ".join(
        f"{a} {axes[a]['held_out_rms']:.3g} {u}" for u, a in worst.items()) in out, out


def test_the_prior_and_the_config_must_agree_before_any_unit_runs(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    Path("new.yaml").write_text(FLEET)
    # the config's t_ref is not the prior's: refused before any unit runs (no progress line)
    Path("t40.yaml").write_text(FLEET.replace("t_ref: 25.0", "t_ref: 40.0"))
    _one_line_refusal(capsys, ["station", "t40.yaml", "--prior", str(prior), "--units", "3",
                               "--test", "soaks:-15,25,65", "--out", "st", "--executor",
                               "serial"],
                      f"t40.yaml: key 'features.t_ref': 40 °C, and the prior ({prior}) is of "
                      "t_ref 25 °C")
    # another target mode than the prior's: named by the config's key, before any unit runs
    # (was: per unit, after each had run, naming neither the file nor the key)
    Path("tgt.yaml").write_text(FLEET.replace("gyro: zero", "gyro: at-t-ref"))
    _one_line_refusal(capsys, ["station", "tgt.yaml", "--prior", str(prior), "--units", "2",
                               "--out", "st", "--executor", "serial"],
                      f"tgt.yaml: key 'target.gyro': 'at-t-ref', and the prior ({prior}) is of "
                      "target 'zero' on gyro_x")
    # a prior of the gyros only: the unit's accelerometers are not dropped silently
    data = json.loads(prior.read_text())
    for key in ("axes", "units_of_measure", "targets"):
        data[key] = {a: v for a, v in data[key].items() if a.startswith("gyro")}
    data["sha256"] = prior_digest(data)     # sealed again, as `thermonet prior` writes it
    Path("gyro.json").write_text(json.dumps(data))
    _one_line_refusal(capsys, ["station", "new.yaml", "--prior", "gyro.json", "--units", "2",
                               "--test", "soaks:-10,25,60", "--out", "st", "--executor",
                               "serial"],
                      "new.yaml: key 'data.preset' ('consumer-imu'): the prior (gyro.json) is of "
                      "axes gyro_x, gyro_y, gyro_z; the data also hold acc_x, acc_y, acc_z")
    # a soak test repeating a temperature in a row
    _one_line_refusal(capsys, ["station", "new.yaml", "--prior", str(prior), "--units", "2",
                               "--test", "soaks:30,30,30", "--out", "st"],
                      "30 °C twice in a row is one longer soak")
    assert not Path("st").exists()


def test_prior_refusals_name_what_and_come_before_the_work(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    import thermonet.cli.fleet as cli_fleet

    monkeypatch.chdir(tmp_path)
    Path("new.yaml").write_text(FLEET)
    # too few units left: which ones and why (the last 3 of 12 are the planted outliers)
    assert main(["prior", "new.yaml", "--units", "12", "--outliers", "3", "--out",
                 "p.json"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "9 remain after leaving out 3: " in err, err
    assert all(f"'consumer-imu-u{i:03d}': robust outlier: " in err for i in (9, 10, 11)), err
    assert not Path("p.json").exists()
    Path("afile").write_text("not a directory\n")

    def no_data(*_: object) -> None:
        raise AssertionError("the units were read before --out was checked")
    monkeypatch.setattr(cli_fleet, "_station_sources", no_data)
    _one_line_refusal(capsys, ["prior", "new.yaml", "--units", "15", "--out", "afile/p.json"],
                      f"afile/p.json: --out cannot be created: {tmp_path / 'afile'} is not a "
                      "directory")


def test_a_station_out_that_cannot_be_made_is_named(prior: Path, tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """The station's --out under a file, or where no one (root included) can write: one
    line naming it, never its staging directory (core.outdir.make_stage), nothing left."""
    monkeypatch.chdir(tmp_path)
    Path("new.yaml").write_text(FLEET)
    Path("afile").write_text("not a directory\n")
    _one_line_refusal(capsys, ["station", "new.yaml", "--prior", str(prior), "--units", "1",
                               "--out", "afile/st", "--executor", "serial"],
                      f"afile/st: --out cannot be created: {tmp_path / 'afile'} is not a "
                      "directory")
    assert Path("/proc/self").is_dir(), "Linux: /proc takes no new directory"
    assert main(["station", "new.yaml", "--prior", str(prior), "--units", "1", "--out",
                 "/proc/thermonet-st", "--executor", "serial"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(
        "thermonet: error: /proc/thermonet-st: --out cannot be created (") and \
        ".partial" not in err[0], err


def test_a_fast_test_is_not_compared_with_a_prior_of_soaks(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A prior built from soak sweeps records its tests ("soaks"); a unit's 40-min
    up-and-down (fast ramps: points paired heating with cooling, a lag error no soak shows)
    would be flagged on its own shape although it is of the same fleet (bench_prior: 100 % of
    normal units), so its fleet comparison is not judged and fails nothing, and the console
    says why; a soak test against the same prior is compared as before."""
    from thermonet.scoring.prior import posterior
    from thermonet.scoring.prior_io import prior_from_dict
    from thermonet.training.config import config_from_mapping
    from thermonet.workflows.station import unit_points

    monkeypatch.chdir(tmp_path)
    sweep = "soaks:-20,-5,10,25,40,55,75"
    write_parquet(simulate_fleet("consumer-imu", units=12, seed=4, test=sweep), "sweeps.parquet")
    Path("fleet.yaml").write_text(FLEET.replace("preset: consumer-imu, seed: 0, runs: 1",
                                                "paths: [sweeps.parquet]"))
    assert main(["prior", "fleet.yaml", "--out", "prior.json", "-q"]) == 0
    doc = json.loads(Path("prior.json").read_text())
    assert doc["test_kinds"] == {"soaks": doc["n_units"]}
    Path("new.yaml").write_text(FLEET.replace("gyro_x: {max_tempco: 0.01}",
                                              '"*": {max_noise: 1.0}'))
    cycle = "cycle:-20,75,40"
    assert main(["station", "new.yaml", "--prior", "prior.json", "--units", "2", "--test", cycle,
                 "--out", "moving", "--executor", "serial"]) == 0
    out = capsys.readouterr().out
    res = json.loads(Path("moving/results.json").read_text())
    assert res["summary"]["not_compared_with_fleet"] == ["consumer-imu-u000", "consumer-imu-u001"]
    assert res["summary"]["flagged_unlike_fleet"] == []
    assert res["units"]["consumer-imu-u000"]["test_kind"] == "fast ramps"
    assert "2 units not compared with the fleet: a test of fast ramps, where the prior's units " \
           f"ran soaks ({doc['n_units']} units)" in out
    # without the rule the same units' shapes are flagged on some axis
    fp = prior_from_dict(doc, "prior.json")
    cfg = config_from_mapping({"data": {"preset": "consumer-imu"},
                               "target": {"gyro": "zero", "acc": "at-t-ref"},
                               "features": {"t_ref": 25.0}}, source="test")
    unit = simulate_fleet("consumer-imu", units=1, seed=0, test=cycle)
    pts, _, _, _ = unit_points(cfg, unit, "u")
    assert any(posterior(fp.axis(a), pts[a], t_ref=fp.t_ref, scale=fp.scale).flagged
               for a in fp.axis_names)
    # a soak test is compared with the same prior
    assert main(["station", "new.yaml", "--prior", "prior.json", "--units", "2", "--test",
                 "soaks:-10,25,60", "--out", "soaked", "--executor", "serial", "-q"]) in (0, 3)
    res = json.loads(Path("soaked/results.json").read_text())
    assert res["summary"]["not_compared_with_fleet"] == []
    assert {u["test_kind"] for u in res["units"].values()} == {"soaks"}


# ------------------------------------------------------------------ a line's files
#: A production line's CSV (serial numbers, milliseconds) and its column mapping.
LINE_MAP = """time: {column: t_ms, unit: ms}
device_column: serial
channels:
  temperature_c: {column: temp, unit: degC}
  gyro_x: {column: gx, unit: deg/s}
  gyro_y: {column: gy, unit: deg/s}
  gyro_z: {column: gz, unit: deg/s}
  acc_x: {column: ax, unit: m/s^2}
  acc_y: {column: ay, unit: m/s^2}
  acc_z: {column: az, unit: m/s^2}
"""
LINE_AXES = ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")


def _line_units(n: int = 3, seed: int = 11) -> list[Any]:
    """``n`` new units' 3-soak tests, as the line records them (one run each)."""
    return list(simulate_fleet("consumer-imu", units=n, seed=seed, test="soaks:-15,25,65"))


def _write_line(runs: list[Any], path: str) -> None:
    """The runs as the line's CSV (serial, t_ms, temp, one column per axis)."""
    rows = ["serial,t_ms,temp,gx,gy,gz,ax,ay,az"]
    for r in runs:
        cols = np.column_stack([np.asarray(r.time_s) * 1000.0, r.temperature_c,
                                *(r.outputs[a] for a in LINE_AXES)])
        rows += [r.device_id + "," + ",".join(repr(float(v)) for v in row) for row in cols]
    Path(path).write_text("\n".join(rows) + "\n")


def _line_config(*files: str) -> str:
    Path("map.yaml").write_text(LINE_MAP)
    return FLEET.replace("preset: consumer-imu, seed: 0, runs: 1",
                         f"paths: [{', '.join(files)}], mapping: map.yaml")


def _station_of_line(runs, prior, capsys) -> str:
    """``runs`` written as line.csv and calibrated by the station (serial): its stdout; a unit
    failed (exit 3)."""
    _write_line(runs, "line.csv")
    Path("line.yaml").write_text(_line_config("line.csv"))
    capsys.readouterr()
    assert main(["station", "line.yaml", "--prior", str(prior), "--out", "st",
                 "--executor", "serial"]) == 3
    return capsys.readouterr().out




def test_a_dead_or_stuck_axis_fails_and_gets_no_firmware_file(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """gyro_z at 0.0 on every sample (a dead axis), at 32.767 (saturated), clipped at its
    90th percentile (10 % of the samples at the maximum): each FAILs on that axis, saying
    so, and no thermonet_cal.h claims it calibrated; the good unit passes with its file."""
    monkeypatch.chdir(tmp_path)
    runs = _line_units(4)
    runs[0].outputs["gyro_z"] = np.zeros_like(runs[0].outputs["gyro_z"])
    runs[1].outputs["gyro_z"] = np.full_like(runs[1].outputs["gyro_z"], 32.767)
    z = runs[2].outputs["gyro_z"]
    runs[2].outputs["gyro_z"] = np.minimum(z, np.quantile(z, 0.9))
    out = _station_of_line(runs, prior, capsys)
    ids = [r.device_id for r in runs]
    lines = {d: next(ln for ln in out.splitlines() if ln.startswith(f"{d}: ")) for d in ids}
    words = {ids[0]: "gyro_z: constant at 0 over the whole test (a dead or saturated axis)",
             ids[1]: "gyro_z: constant at 32.767 over the whole test (a dead or saturated axis)",
             ids[2]: "gyro_z: stuck at "}
    res = json.loads(Path("st/results.json").read_text())
    assert res["summary"]["dead_axes"] == sorted(ids[:3])
    for dev, w in words.items():
        assert lines[dev].startswith(f"{dev}: FAIL") and w in lines[dev], lines[dev]
        assert res["units"][dev]["axes"]["gyro_z"]["dead_axis"].startswith(w)
        assert res["units"][dev]["axes"]["gyro_z"]["failed"][0] == "dead_axis"
        cal = json.loads(Path(f"st/units/{dev}/calibration.json").read_text())
        assert cal["verdict"] == "FAIL" and cal["axes"]["gyro_z"]["verdict"] == "FAIL"
        assert cal["firmware_header"].startswith("not written: " + w)
        assert not Path(f"st/units/{dev}/thermonet_cal.h").exists()
    assert "its maximum, on 10% of the samples" in lines[ids[2]], lines[ids[2]]
    assert "a saturated or stuck axis" in lines[ids[2]]
    good = res["units"][ids[3]]
    assert good["axes"]["gyro_z"]["dead_axis"] is None and "dead_axis" not in str(
        lines[ids[3]]) and Path(f"st/units/{ids[3]}/thermonet_cal.h").is_file()


def test_one_units_data_under_two_serials_is_refused_before_any_unit_runs(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    runs = _line_units(3)
    runs[1].outputs = {a: v.copy() for a, v in runs[0].outputs.items()}   # a copy-paste
    _write_line(runs, "line.csv")
    Path("line.yaml").write_text(_line_config("line.csv"))
    capsys.readouterr()
    assert main(["station", "line.yaml", "--prior", str(prior), "--out", "st",
                 "--executor", "serial"]) == 1
    out, err = capsys.readouterr()
    assert len(err.strip().splitlines()) == 1 and "station:" not in out, err
    n = runs[0].n_samples
    assert (f"units '{runs[0].device_id}' and '{runs[1].device_id}' hold identical outputs "
            f"(acc_x, acc_y, acc_z, gyro_x, gyro_y, gyro_z: {n} samples each, byte for byte)"
            in err), err
    assert not Path("st").exists()


def test_a_unit_of_two_runs_says_so_and_one_test_filed_twice_is_refused(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    runs = _line_units(3)
    _write_line(runs, "line.csv")
    retest = _line_units(1, seed=23)[0]            # another test, filed under unit 0
    retest.device_id = runs[0].device_id
    _write_line([retest], "retest.csv")
    Path("twice.yaml").write_text(_line_config("line.csv", "retest.csv"))
    capsys.readouterr()
    assert main(["station", "twice.yaml", "--prior", str(prior), "--out", "st",
                 "--executor", "serial"]) in (0, 3)
    out = capsys.readouterr().out
    dev = runs[0].device_id
    assert (f"unit {dev}: 2 runs (line from line.csv, retest from retest.csv): calibrated "
            "from both") in out.splitlines(), out
    res = json.loads(Path("st/results.json").read_text())
    assert res["summary"]["several_runs"] == [dev] and res["units"][dev]["runs"] == 2
    assert [(r["run_id"], Path(r["source"]).name) for r in res["units"][dev]["run_sources"]] \
        == [("line", "line.csv"), ("retest", "retest.csv")]
    # the same test filed again under another name: refused, naming both files
    _write_line([runs[0]], "same.csv")
    Path("same.yaml").write_text(_line_config("line.csv", "same.csv"))
    _one_line_refusal(capsys, ["station", "same.yaml", "--prior", str(prior), "--out", "st2",
                               "--executor", "serial"],
                      f"unit '{dev}': runs 'line' (line.csv) and 'same' (same.csv) hold "
                      f"identical outputs ({runs[0].n_samples} samples, byte for byte)")
    assert not Path("st2").exists()


def test_a_station_config_with_top_level_limits_or_no_data_is_refused(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    Path("top.yaml").write_text(FLEET + "limits:\n  gyro_x: {max_std: 0.0000001}\n")
    _one_line_refusal(capsys, ["station", "top.yaml", "--prior", str(prior), "--units", "2",
                               "--out", "st", "--executor", "serial"],
                      "top.yaml: key 'limits': the station's limits go under 'station.limits'")
    Path("nodata.yaml").write_text(FLEET.split("\n", 1)[1])
    _one_line_refusal(capsys, ["station", "nodata.yaml", "--prior", str(prior), "--out", "st",
                               "--executor", "serial"],
                      "nodata.yaml: config names no data (data.paths or data.preset)")
    assert not Path("st").exists()


def test_a_prior_edited_by_hand_is_refused_and_an_unsealed_one_warned(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """`thermonet prior` seals its file with the sha256 of its content; a range widened by
    hand no longer matches it; a prior without one (older) is read with one warning."""
    from thermonet.scoring.prior_io import prior_digest

    monkeypatch.chdir(tmp_path)
    data = json.loads(prior.read_text())
    assert data["sha256"] == prior_digest(data)
    Path("new.yaml").write_text(FLEET)
    wide = {**data, "range_c": [-40.0, 85.0]}
    Path("wide.json").write_text(json.dumps(wide, indent=1))
    _one_line_refusal(capsys, ["station", "new.yaml", "--prior", "wide.json", "--units", "1",
                               "--test", "soaks:-10,25,60", "--out", "st", "--executor",
                               "serial"],
                      "wide.json: its content does not match its sha256 (edited by hand?)")
    assert not Path("st").exists()
    old = {k: v for k, v in data.items() if k != "sha256"}
    Path("old.json").write_text(json.dumps(old))
    assert main(["station", "new.yaml", "--prior", "old.json", "--units", "1", "--test",
                 "soaks:-10,25,60", "--out", "st", "--executor", "serial", "-q"]) in (0, 3)
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["thermonet: warning: old.json: no sha256 of its content (a prior written "
                   "before it was recorded): read unchecked; write it again with `thermonet "
                   "prior` to seal it"], err


# ------------------------------------------------------------------ a unit's own failure
def _unit_files(out: Path) -> dict[str, bytes]:
    return {p.relative_to(out).as_posix(): p.read_bytes()
            for p in sorted((out / "units").rglob("*")) if p.is_file()}


def test_a_unit_whose_data_fail_a_check_fails_alone_and_the_others_finish(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A unit measured 30 °C colder than the prior's range and one whose thermometer reads
    25.0 on every sample: each FAILs with its reason (calibration.json, its console line),
    gets no firmware file, and the good units are calibrated and written; exit 3 — the same
    files on the process pool as in this process."""
    monkeypatch.chdir(tmp_path)
    runs = _line_units(4)
    runs[0].temperature_c = np.asarray(runs[0].temperature_c) - 30.0     # -45 … 35 °C
    runs[1].temperature_c = np.full_like(runs[1].temperature_c, 25.0)    # a dead thermometer
    out = _station_of_line(runs, prior, capsys)
    ids = [r.device_id for r in runs]
    cold = (f"unit '{ids[0]}': measured -45.0 to 34.9 °C, outside the fleet prior's range -20 "
            "to 75 °C (the prior says nothing there)")
    dead = (f"unit '{ids[1]}': line.csv, column 'temperature_c': temperature spans only 0 °C "
            "over all runs")
    lines = out.splitlines()
    assert f"{ids[0]}: FAIL  not calibrated: {cold.split(': ', 1)[1]}" in lines, out
    assert any(ln.startswith(f"{ids[1]}: FAIL  not calibrated: {dead.split(': ', 1)[1]}")
               for ln in lines), out
    assert "2 of 4 units passed (2 not calibrated: their data failed a check); " in out, out
    res = json.loads(Path("st/results.json").read_text())
    s = res["summary"]
    assert (s["n_units"], s["passed"], s["failed"]) == (4, 2, 2)
    assert s["not_calibrated"] == sorted(ids[:2]) and s["dead_axes"] == []
    for dev, why in ((ids[0], cold), (ids[1], dead)):
        cal = json.loads(Path(f"st/units/{dev}/calibration.json").read_text())
        assert cal["verdict"] == "FAIL" and cal["axes"] == {} and cal["error"].startswith(why)
        assert cal["firmware_header"] == "not written: " + cal["error"]
        assert res["units"][dev]["error"] == cal["error"] and res["units"][dev]["axes"] == {}
        assert res["units"][dev]["files"] == f"units/{dev}"
        assert sorted(p.name for p in Path(f"st/units/{dev}").iterdir()) == ["calibration.json"]
    assert json.loads(Path(f"st/units/{ids[0]}/calibration.json").read_text())["runs"] == 1
    for dev in ids[2:]:      # the good units: calibrated, judged, and their firmware files
        u = res["units"][dev]
        assert u["verdict"] == "PASS" and u["error"] is None, u
        cal = json.loads(Path(f"st/units/{dev}/calibration.json").read_text())
        assert -0.006 < cal["axes"]["gyro_y"]["coefficients"][1] < 0.0     # °/s/K
        assert cal["axes"]["gyro_y"]["held_out_rms"] < 0.03
        assert cal["firmware_header"] == "thermonet_cal.h"
        assert f"unit {dev}: PASS" in Path(f"st/units/{dev}/thermonet_cal.h").read_text()
    # the good units' files are what they would be without the failed units beside them
    _write_line(runs[2:], "good.csv")
    Path("good.yaml").write_text(_line_config("good.csv"))
    assert main(["station", "good.yaml", "--prior", str(prior), "--out", "alone",
                 "--executor", "serial", "-q"]) == 0
    for dev in ids[2:]:
        assert (Path(f"alone/units/{dev}/thermonet_cal.h").read_bytes()
                == Path(f"st/units/{dev}/thermonet_cal.h").read_bytes())
        assert (json.loads(Path(f"alone/units/{dev}/calibration.json").read_text())["axes"]
                == json.loads(Path(f"st/units/{dev}/calibration.json").read_text())["axes"])
    # the process pool: the same verdicts, reasons and files, byte for byte
    assert main(["station", "line.yaml", "--prior", str(prior), "--out", "pool",
                 "--executor", "process", "--workers", "2", "-q"]) == 3
    assert _unit_files(Path("pool")) == _unit_files(Path("st"))


def test_a_bug_in_one_units_task_still_stops_the_batch(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Only a unit's own data make its FAIL: any other error in its task (a bug) stops the
    batch as before — one line naming the unit and the error, exit 1, nothing written."""
    import thermonet.workflows.station as station

    monkeypatch.chdir(tmp_path)
    Path("new.yaml").write_text(FLEET)
    kind = station.unit_test_kind

    def broken(ds: Any) -> str:
        if ds.runs[0].device_id == "consumer-imu-u001":
            raise ZeroDivisionError("a bug")
        return kind(ds)
    monkeypatch.setattr(station, "unit_test_kind", broken)
    _one_line_refusal(capsys, ["station", "new.yaml", "--prior", str(prior), "--units", "3",
                               "--test", "soaks:-10,25,60", "--out", "st", "--executor",
                               "serial"], "unit 'consumer-imu-u001': ZeroDivisionError: a bug")
    assert not Path("st").exists()


def test_a_config_whose_channels_contradict_the_prior_is_refused_before_any_unit_runs(
        prior: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The mapping's unit of measure on an axis, or data.outputs, is every unit's: refused
    in one line naming the key, both values and the prior, before any unit runs (no progress
    line, no unit directory) — not once per unit after all had run."""
    monkeypatch.chdir(tmp_path)
    _write_line(_line_units(2), "line.csv")
    Path("line.yaml").write_text(_line_config("line.csv"))
    Path("map.yaml").write_text(LINE_MAP.replace("gx, unit: deg/s", "gx, unit: rad/s"))
    capsys.readouterr()
    assert main(["station", "line.yaml", "--prior", str(prior), "--out", "st",
                 "--executor", "serial"]) == 1
    out, err = capsys.readouterr()
    assert err.strip().splitlines() == [
        f"thermonet: error: line.yaml: key 'data.mapping' (map.yaml): gyro_x in 'rad/s', and "
        f"the prior ({prior}) has gyro_x in 'deg/s' (convert one of them first: the channel's "
        "scale, or the prior's data)"], err
    assert "station:" not in out and not Path("st").exists()
    Path("map.yaml").write_text(LINE_MAP)
    Path("gyros.yaml").write_text(_line_config("line.csv").replace(
        "mapping: map.yaml", "mapping: map.yaml, outputs: [gyro_x, gyro_y, gyro_z]"))
    _one_line_refusal(capsys, ["station", "gyros.yaml", "--prior", str(prior), "--out", "st",
                               "--executor", "serial"],
                      f"gyros.yaml: key 'data.outputs' (gyro_x, gyro_y, gyro_z): the prior "
                      f"({prior}) is of axes gyro_x, gyro_y, gyro_z, acc_x, acc_y, acc_z; the "
                      "data lack acc_x, acc_y, acc_z")
    assert not Path("st").exists()
