"""Fleets: units in the data, simulated fleets, per-unit and fleet verdicts, limits, executors."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from thermonet.cli import main
from thermonet.core.errors import ConfigError, InputError
from thermonet.core.executors import ExecutorError, TaskFailure, run_tasks
from thermonet.core.recording import Dataset, Recording, split_units
from thermonet.data.io import read_datasets, write_parquet
from thermonet.scoring.fleetstats import MAD_TO_SIGMA, flag_outliers, parse_limits, robust_z
from thermonet.sim import simulate, simulate_fleet, unit_seed
from thermonet.sim.fleet import OUTLIER_SIGMAS, outlier_config
from thermonet.training.config import CompareConfig, FamilyConfig, load_config
from thermonet.workflows.fleet import EXIT_LIMITS_FAILED, FleetOptions, run_fleet
from thermonet.workflows.fleet_units import UnitSource, sources_from_dataset

#: Unit gains of the toy fleet; the last unit is off the fleet's law (an outlier).
GAINS = (1.0, 1.01, 0.99, 1.005, 0.995, 1.5)


def toy_unit(device: str, gain: float, *, n_runs: int = 3, seed: int = 0,
             unit: str = "deg/s") -> list[Recording]:
    """Runs of one toy gyro: drift = gain·(0.05 + 0.01·d − 2e-4·d²), d = T + 20 °C.

    In (T − 25 °C) the same law is gain·(0.095 − 0.008·x − 2e-4·x²) (x = T − 25).
    """
    rng = np.random.default_rng(seed)
    runs = []
    for k in range(n_runs):
        t = np.arange(0.0, 7200.0, 6.0)
        temp = -20.0 + 70.0 * t / t[-1] + 0.3 * k
        d = temp + 20.0
        drift = gain * (0.05 + 0.01 * d - 2e-4 * d ** 2)
        runs.append(Recording(
            time_s=t, temperature_c=temp, outputs={"gyro_x": drift + rng.normal(0, 0.002, t.size)},
            drift={"drift_gyro_x": drift}, units={"gyro_x": unit, "temperature_c": "degC"},
            device_id=device, run_id=f"run{k}", sample_rate_hz=1 / 6.0))
    return runs


def toy_fleet(gains: tuple[float, ...] = GAINS) -> Dataset:
    runs: list[Recording] = []
    for i, g in enumerate(gains):
        runs += toy_unit(f"toy-u{i:03d}", g, seed=i)
    return Dataset(runs).validate()


def toy_config(**limits: dict) -> CompareConfig:
    cfg = CompareConfig(families=[
        FamilyConfig(family="poly", name="cubic", inputs=["dT"], params={"degree": 3}),
        FamilyConfig(family="linear", name="linear", inputs=["dT"])])
    cfg.tracking.enabled = False
    cfg.limits = dict(limits)
    return cfg


# ------------------------------------------------------------------ data
def test_fleet_parquet_round_trip_keeps_units_apart(tmp_path):
    ds = simulate_fleet("patent-gyro", units=3, runs=2, seed=4, sample_rate_hz=0.05)
    assert ds.unit_ids == ["patent-gyro-u000", "patent-gyro-u001", "patent-gyro-u002"]
    assert [r.run_id for r in ds][:2] == ["run0", "run1"]  # run ids repeat across units
    path = write_parquet(ds, tmp_path / "fleet.parquet")
    import pyarrow.parquet as pq

    assert "device" in pq.read_table(path).column_names
    back = read_datasets([path])
    assert back.unit_ids == ds.unit_ids
    for a, b in zip(ds, back, strict=True):
        assert (a.device_id, a.run_id) == (b.device_id, b.run_id)
        # written and read back: values copied, exact
        np.testing.assert_array_equal(a.outputs["gyro_x"], b.outputs["gyro_x"])
    units = split_units(back)
    assert list(units) == ds.unit_ids and all(len(u) == 2 for u in units.values())


def test_unit_k_is_the_same_whatever_the_fleet_size():
    small = simulate_fleet("patent-gyro", units=2, runs=1, seed=7, sample_rate_hz=0.05)
    big = simulate_fleet("patent-gyro", units=5, runs=1, seed=7, sample_rate_hz=0.05,
                         unit_indices=[1])
    # unit k is drawn from its own seed: the same computation, bit-identical
    np.testing.assert_array_equal(small[1].outputs["gyro_y"], big[0].outputs["gyro_y"])
    assert big[0].device_id == "patent-gyro-u001"
    # and unit k is the single-device simulator at the derived seed
    one = simulate("patent-gyro", runs=1, seed=unit_seed(7, 1), sample_rate_hz=0.05)
    np.testing.assert_array_equal(one[0].outputs["gyro_y"], small[1].outputs["gyro_y"])
    assert unit_seed(7, 0) != unit_seed(7, 1) != unit_seed(8, 1)


def test_outlier_unit_law_is_scaled_by_the_stated_sigmas():
    quiet = dict(sample_rate_hz=0.05, scale_factor=False, rate_term=False, white_noise=False,
                 flicker_noise=False, random_walk_noise=False)
    normal = simulate_fleet("patent-gyro", units=2, runs=1, seed=3, **quiet)
    odd = simulate_fleet("patent-gyro", units=2, runs=1, seed=3, outliers=1, **quiet)
    # unit 0 is not the outlier: its law is the same computation, bit-identical
    np.testing.assert_array_equal(normal[0].drift["drift_gyro_x"], odd[0].drift["drift_gyro_x"])
    factor = 1.0 + OUTLIER_SIGMAS * 0.01  # patent-gyro's bias_gain_rel is 1 %
    rec_n, rec_o = normal[1], odd[1]
    off = float(rec_n.meta["unit_bias_offset"])
    for ax in ("gyro_x", "gyro_y", "gyro_z"):
        d_n = rec_n.drift[f"drift_{ax}"] - off
        d_o = rec_o.drift[f"drift_{ax}"] - off
        np.testing.assert_allclose(d_o, factor * d_n, rtol=1e-9, atol=1e-12)
    assert rec_o.meta["outlier"] == "1" and rec_n.meta["outlier"] == "0"
    assert outlier_config(simulate.__globals__["get_preset"]("accel")).axes[0].bias != \
        simulate.__globals__["get_preset"]("accel").axes[0].bias


def test_csv_device_column_and_duplicate_units(tmp_path):
    rows = ["device,run,time_s,temperature_c,gyro_x"]
    for dev in ("a", "b"):
        for run in ("r0", "r1"):
            rows += [f"{dev},{run},{t},{10 + t},{0.01 * t}" for t in range(12)]
    f1 = tmp_path / "fleet.csv"
    f1.write_text("\n".join(rows) + "\n")
    ds = read_datasets([f1])
    assert ds.unit_ids == ["a", "b"] and len(ds) == 4
    assert [len(u) for u in split_units(ds).values()] == [2, 2]
    # the same unit and run in a second file: refused, naming the run, the unit and the file
    f2 = tmp_path / "again.csv"
    f2.write_text("\n".join(rows[:13]) + "\n")
    with pytest.raises(InputError, match=r"run id 'r0' of unit 'a' already used by .*fleet\.csv"):
        read_datasets([f1, f2])


def test_units_in_different_units_of_measure_are_refused_naming_both():
    runs = toy_unit("u1", 1.0) + toy_unit("u2", 1.0, unit="rad/s")
    with pytest.raises(InputError, match=r"unit 'u2' run 'run0' is in 'rad/s', unit 'u1' run "
                                         r"'run0' in 'deg/s'"):
        Dataset(runs).validate()
    other = toy_unit("u3", 1.0)
    for r in other:
        r.outputs["gyro_y"] = r.outputs["gyro_x"].copy()
    with pytest.raises(InputError, match=r"unit 'u3' run 'run0' has outputs"):
        Dataset(toy_unit("u1", 1.0) + other).validate()


def test_compare_refuses_a_fleet_and_points_to_fleet(tmp_path):
    path = write_parquet(toy_fleet(GAINS[:2]), tmp_path / "f.parquet")
    cfg_path = tmp_path / "c.yaml"
    cfg_path.write_text(f"data: {{paths: ['{path}']}}\n")
    from thermonet.workflows.compare import run_compare

    with pytest.raises(ConfigError, match=r"holds 2 units .*thermonet fleet"):
        run_compare(load_config(cfg_path), tmp_path / "out", track=False, quiet=True)


# ------------------------------------------------------------- statistics
def test_robust_z_and_outlier_rule_by_hand():
    values = {"a": 1.0, "b": 2.0, "c": 3.0, "d": 4.0, "e": 100.0}
    z = robust_z(values)  # median 3, MAD 1
    assert z["e"] == pytest.approx(97 / MAD_TO_SIGMA)
    assert z["a"] == pytest.approx(-2 / MAD_TO_SIGMA)
    flags = flag_outliers({"c1": values})
    assert list(flags) == ["e"] and flags["e"][0]["quantity"] == "c1"
    low = {"a": -100.0, "b": 2.0, "c": 3.0, "d": 4.0, "e": 5.0}
    assert list(flag_outliers({"err": low})) == ["a"]
    assert flag_outliers({"err": low}, high_only={"err"}) == {}  # lower error is no fault
    assert robust_z({"a": 1.0, "b": 1.0, "c": 1.0, "d": 1.0, "e": 5.0}) == {}  # MAD 0
    assert robust_z({"a": 1.0, "b": 2.0, "c": 3.0, "d": 100.0}) == {}  # too few units


def test_limits_are_checked_key_by_key(tmp_path):
    lim = parse_limits({"*": {"max_std": 0.1}, "gyro_x": {"max_pp": 0.2}})
    assert lim["gyro_x"].max_pp == 0.2 and lim["*"].max_std == 0.1
    with pytest.raises(ConfigError, match=r"limits\.gyro_x\.max_pq"):
        parse_limits({"gyro_x": {"max_pq": 1.0}})
    with pytest.raises(ConfigError, match=r"max_std"):
        parse_limits({"*": {"max_std": -1.0}})
    bad = tmp_path / "bad.yaml"
    bad.write_text("limits:\n  '*': {max_ratio: 0.5}\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml: key 'limits\.\*\.max_ratio'"):
        load_config(bad)


# ------------------------------------------------------------------ fleet
def test_fleet_recovers_coefficients_flags_the_outlier_and_judges_limits(tmp_path):
    cfg = toy_config(**{"*": {"max_std": 0.0025, "max_ratio_to_raw": 0.2,
                              "min_temperature_span_c": 60.0}})
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    res = run_fleet(cfg, tmp_path / "fleet", sources_from_dataset(toy_fleet()),
                    options=FleetOptions(executor="serial", folds=3), track=True,
                    tracking_uri=uri, quiet=True)
    units = res["units"]
    assert list(units) == [f"toy-u{i:03d}" for i in range(len(GAINS))]
    for (dev, u), g in zip(units.items(), GAINS, strict=True):
        c = u["coefficients"]
        # the cubic's physical coefficients in (T − 25 °C): gain × (0.095, −0.008, −2e-4, 0)
        assert c["gyro_x.c0"] == pytest.approx(0.095 * g, abs=3e-4), dev
        assert c["gyro_x.c1"] == pytest.approx(-0.008 * g, abs=2e-5), dev
        assert c["gyro_x.c2"] == pytest.approx(-2e-4 * g, abs=2e-6), dev
        assert abs(c["gyro_x.c3"]) < 2e-7
        assert u["chosen"] in ("cubic",)
        # held-out std of the compensated output is the white noise (0.002)
        assert u["families"]["cubic"]["axes"]["gyro_x"]["rms_comp"] == pytest.approx(0.002,
                                                                                      rel=0.15)
        assert u["limits"]["verdict"] == "PASS"
        assert (tmp_path / "fleet" / "units" / dev / "models" / "cubic.pt").is_file()
    fleet = res["fleet"]
    assert list(fleet["outliers"]) == ["toy-u005"]
    # flagged on its drift curve: 50 % off the fleet's, far beyond 3.5 robust σ
    assert any(f["quantity"].startswith("cubic.gyro_x.drift@") and abs(f["z"]) > 10
               for f in fleet["outliers"]["toy-u005"])
    assert fleet["all_passed"] and fleet["verdicts"] == {"PASS": len(GAINS)}
    # leave units out: the fleet model is as good as the unit's own on the normal units
    # (gains within 1 %: 0.5 % of a 0.1 deg/s drift is below the noise) and far worse on the
    # outlier (its law is 50 % off: the residual is ~0.5 × its drift's spread)
    luo = {d: u["leave_units_out"]["axes"]["gyro_x"] for d, u in units.items()}
    for dev in list(units)[:-1]:
        assert luo[dev]["ratio"] < 1.3, dev
    out = luo["toy-u005"]
    assert out["ratio"] > 5
    assert out["std_fleet"] == pytest.approx(out["std_raw"] / 3, rel=0.35)
    on_disk = json.loads((tmp_path / "fleet" / "results.json").read_text())
    assert on_disk["fleet"]["outliers"].keys() == {"toy-u005"}
    assert (tmp_path / "fleet" / "plots" / "coefficient_spread.png").stat().st_size > 1000
    html = (tmp_path / "fleet" / "fleet.html").read_text()
    assert "toy-u005" in html and html.count('class="pass"') >= len(GAINS)
    # MLflow: one parent run, one nested run per unit, written by the driver
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    exp = client.get_experiment_by_name("thermonet")
    runs = client.search_runs([exp.experiment_id])
    parents = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    children = [r for r in runs
                if r.data.tags.get("mlflow.parentRunId") == on_disk["mlflow_run_id"]]
    assert len(parents) == 1 and len(children) == len(GAINS)
    assert {r.data.tags["verdict"] for r in children} == {"PASS"}


def test_fleet_cli_exit_code_and_all_units_export(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    write_parquet(toy_fleet(GAINS[:3]), tmp_path / "f.parquet")
    (tmp_path / "c.yaml").write_text(
        "data: {paths: [f.parquet]}\n"
        "families:\n  - {name: cubic, family: poly, inputs: [dT], params: {degree: 3}}\n"
        "limits:\n  '*': {max_std: 0.0025}\n  gyro_x: {max_pp: 0.0001}\n")
    # a negative --folds is named as typed (it also named fleet_units_max, never given)
    assert main(["fleet", "c.yaml", "--out", "fl", "--executor", "serial", "--no-track", "-q",
                 "--folds", "-1"]) == 1
    err = capsys.readouterr().err
    assert "--folds -1: must be ≥ 0" in err and "fleet_units_max" not in err
    assert not (tmp_path / "fl").exists()
    rc = main(["fleet", "c.yaml", "--out", "fl", "--executor", "serial", "--no-track", "-q",
               "--folds", "0"])
    assert rc == EXIT_LIMITS_FAILED
    res = json.loads((tmp_path / "fl" / "results.json").read_text())
    for u in res["units"].values():
        assert u["limits"]["verdict"] == "FAIL"
        assert any("max_pp" in r for r in u["limits"]["reasons"])
    assert main(["export", "fl", "--all-units", "--format", "onnx", "--out", "onnx"]) == 0
    files = sorted(p.name for p in (tmp_path / "onnx").iterdir())
    assert files == ["toy-u000.onnx", "toy-u001.onnx", "toy-u002.onnx"]
    import onnx

    meta = {p.key: p.value for p in onnx.load(tmp_path / "onnx" / "toy-u001.onnx").metadata_props}
    assert "toy-u001" in json.dumps(meta)
    assert main(["export", "fl", "--all-units", "--format", "c", "--out", "c"]) == 0
    assert len(list((tmp_path / "c").glob("toy-u00?.h"))) == 3
    # per-unit autopilot files name their unit (a '#' comment both formats and both readers
    # take), and the console says which unit each file is for
    from thermonet.exporting.autopilot_read import read_ardupilot_params, read_px4_params
    from thermonet.workflows.verify_params import read_param_file

    capsys.readouterr()
    assert main(["export", "fl", "--all-units", "--format", "px4-params", "--device-id",
                 "2490378", "--out", "px4"]) == 0
    out = capsys.readouterr().out
    assert f"unit toy-u001: wrote {Path('px4') / 'toy-u001.params'}" in out.splitlines(), out
    assert main(["export", "fl", "--all-units", "--format", "ardupilot-params", "--out",
                 "ap"]) == 0
    for f, read in ((Path("px4/toy-u001.params"), read_px4_params),
                    (Path("ap/toy-u001.parm"), read_ardupilot_params)):
        assert f.read_text().splitlines()[0] == "# unit toy-u001"
        params = read(f)
        assert params and "# unit" not in str(params)
        assert read_param_file(f).params == params     # what verify reads


def test_a_unit_a_files_metadata_lists_without_rows_is_named_with_the_file(tmp_path):
    """A fleet file whose rows of one unit were dropped (its metadata still lists it) says
    so, naming the file, instead of "too few samples: 0"."""
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    ds = simulate_fleet("patent-gyro", units=3, runs=1, seed=4, sample_rate_hz=0.05)
    table = pq.read_table(write_parquet(ds, tmp_path / "f.parquet"))
    drop = tmp_path / "drop.parquet"
    pq.write_table(table.filter(pc.not_equal(table["device"], "patent-gyro-u001")), drop)
    sources = sources_from_dataset(read_datasets([drop], validate=False), files=[str(drop)])
    errors = {s.device_id: s.error for s in sources}
    assert errors["patent-gyro-u000"] is None and errors["patent-gyro-u002"] is None
    assert errors["patent-gyro-u001"] == (f"unit 'patent-gyro-u001': no rows in {drop} (the "
                                          "file's metadata lists the unit)")


# -------------------------------------------------------------- executors
def _square_or_die(x: int) -> int:
    if x == 3:
        os._exit(7)  # a worker killed mid-task (segfault, OOM killer)
    if x == 5:
        raise RuntimeError("unit 5 is broken")
    return x * x


def test_process_pool_survives_a_dead_worker():
    out = run_tasks(_square_or_die, list(range(7)), executor="process", workers=2)
    assert [o for i, o in enumerate(out) if i not in (3, 5)] == [0, 1, 4, 16, 36]
    assert run_tasks(_threads, [0, 1], executor="process", workers=2) == [1, 1]
    assert isinstance(out[3], TaskFailure) and "worker process died" in out[3].reason
    assert isinstance(out[5], TaskFailure) and "unit 5 is broken" in out[5].reason


def _threads(_: int) -> int:
    import torch  # imported after the initializer: one thread from the environment

    return torch.get_num_threads()


class DyingSource(UnitSource):
    """A unit whose worker process dies while loading it."""

    def load(self, cfg: object = None) -> Dataset:
        os._exit(9)


def test_fleet_reports_a_killed_unit_and_finishes(tmp_path):
    sources = sources_from_dataset(toy_fleet(GAINS[:2]))
    sources.append(DyingSource("toy-dead"))
    res = run_fleet(toy_config(**{"*": {"max_std": 0.0025}}), tmp_path / "f", sources,
                    options=FleetOptions(executor="process", workers=2, folds=0), quiet=True)
    dead = res["units"]["toy-dead"]
    assert dead["status"] == "failed" and "worker process died" in dead["reason"]
    assert dead["limits"]["verdict"] == "FAIL"
    assert [res["units"][d]["limits"]["verdict"] for d in ("toy-u000", "toy-u001")] == \
        ["PASS", "PASS"]
    assert res["fleet"]["n_failed"] == 1 and not res["fleet"]["all_passed"]
    assert not (tmp_path / "f" / "units" / "toy-dead").exists()


def _numbers(res: dict) -> dict:
    return {d: (u["coefficients"], u["families"]["cubic"]["axes"], u["leave_units_out"])
            for d, u in res["units"].items()}


def test_a_unit_file_over_the_limit_is_streamed_by_its_worker(tmp_path):
    """Per-unit Parquet files over ``data.in_memory_samples``: each worker streams its own
    file into window means (thermonet.features.windows) — here one sample per 1 s window
    (the toy logs every 6 s), so the fleet's numbers are the in-memory ones to rounding."""
    from thermonet.workflows.fleet_units import sources_from_files

    paths = [str(write_parquet(unit, tmp_path / f"{dev}.parquet"))
             for dev, unit in split_units(toy_fleet(GAINS[:2])).items()]
    cfg = toy_config()
    cfg.families = cfg.families[:1]
    opts = FleetOptions(executor="serial", folds=2)
    want = _numbers(run_fleet(cfg, tmp_path / "m", sources_from_files(paths), quiet=True,
                              options=opts))
    cfg.data.in_memory_samples = 0
    got = _numbers(run_fleet(cfg, tmp_path / "s", sources_from_files(paths), quiet=True,
                             options=opts))
    assert list(got) == list(want)
    for dev in want:
        assert got[dev][0] == pytest.approx(want[dev][0], rel=1e-9, abs=1e-12)
        for axis, m in want[dev][1].items():
            for key in ("score_ratio", "score_raw", "rms_comp", "noise_floor"):
                assert got[dev][1][axis][key] == pytest.approx(m[key], rel=1e-9), key
    units = [json.loads(p.read_text()) for p in (tmp_path / "s").rglob("results.json")]
    streamed = [u["data"].get("streamed") for u in units if "data" in u]   # each unit's
    assert len(streamed) == 2 and all(s["window_s"] == 1.0 for s in streamed)


def _same_on_every_executor(tmp_path: Path, executors: tuple[str, ...], n_units: int) -> None:
    """The fleet's numbers (coefficients, held-out scores, leave-units-out) are identical
    whichever executor ran the units: the same data, the same computation."""
    sources = sources_from_dataset(toy_fleet(GAINS[:n_units]))
    cfg = toy_config()
    cfg.families = cfg.families[:1]
    got = {}
    for ex in executors:
        got[ex] = _numbers(run_fleet(cfg, tmp_path / ex, sources, quiet=True,
                                     options=FleetOptions(executor=ex, workers=2, folds=2)))
    assert list(got["serial"]) == [f"toy-u{i:03d}" for i in range(n_units)]
    for ex in executors[1:]:
        assert got[ex] == got["serial"], ex
    assert got["serial"]["toy-u000"][2]["axes"]["gyro_x"]["ratio"] > 0


def test_serial_and_process_give_identical_results(tmp_path):
    """The fast twin of the Ray test below: two units (leave-units-out needs two), serial
    against the process pool."""
    _same_on_every_executor(tmp_path, ("serial", "process"), n_units=2)


@pytest.mark.slow
def test_serial_process_and_ray_give_identical_results(tmp_path):
    """A real local Ray (its start-up is most of this test's time; `make test-slow`)."""
    _same_on_every_executor(tmp_path, ("serial", "process", "ray"), n_units=3)


def test_unreachable_ray_is_one_clear_line():
    with pytest.raises(ExecutorError, match=r"Ray cluster at '127\.0\.0\.1:1' not reachable") \
            as err:
        run_tasks(abs, [1], executor="ray", ray_address="127.0.0.1:1")
    assert "\n" not in str(err.value)


def test_executor_arguments_are_checked():
    with pytest.raises(ExecutorError, match="unknown executor 'dask'"):
        run_tasks(abs, [1], executor="dask")  # type: ignore[arg-type]
    with pytest.raises(ExecutorError, match=r"--workers must be at least 0 \(0: one per CPU\), "
                                            "got -1"):
        run_tasks(abs, [1], workers=-1)
    # 0: one per CPU this process may use, as compare --workers 0 (station, learn, fleet)
    assert run_tasks(abs, [-1, 2], workers=0) == [1, 2]
    with pytest.raises(InputError, match="device id 'x' given twice"):
        run_fleet(toy_config(), Path("unused"), [UnitSource("x"), UnitSource("x")], quiet=True)


def test_a_unit_with_too_few_runs_for_the_split_fails_alone(tmp_path):
    runs = toy_unit("toy-ok", 1.0, n_runs=2) + toy_unit("toy-short", 1.0, n_runs=1)
    cfg = toy_config()
    cfg.families = cfg.families[:1]
    cfg.split.strategy = "train-then-verify"
    res = run_fleet(cfg, tmp_path / "f", sources_from_dataset(Dataset(runs).validate()),
                    options=FleetOptions(executor="serial", folds=0), quiet=True)
    short = res["units"]["toy-short"]
    assert short["status"] == "failed"
    assert "train-then-verify needs exactly 2 runs, the data has 1" in short["reason"]
    assert res["units"]["toy-ok"]["status"] == "ok"
    assert res["fleet"]["n_failed"] == 1 and not res["fleet"]["all_passed"]


def _workers_read_their_own_file(tmp_path: Path, executors: tuple[str, ...],
                                 n_units: int) -> None:
    """A fleet given as one thermonet Parquet file per unit: the sources carry only the path
    (what goes to a worker: a few hundred bytes, not the unit's samples), each worker reads
    its own file, and the results are those of the same units read by the driver — on each of
    ``executors``."""
    import pickle

    from thermonet.workflows.fleet_units import UnitItem, sources_from_files

    fleet = toy_fleet(GAINS[:n_units])
    paths = []
    for dev, unit in split_units(fleet).items():
        paths.append(str(write_parquet(unit, tmp_path / f"{dev}.parquet")))
    sources = sources_from_files(paths)
    assert sources is not None and [s.device_id for s in sources] == list(split_units(fleet))
    assert all(s.dataset is None and s.path for s in sources)
    cfg = toy_config()
    cfg.families = cfg.families[:1]
    by_path = len(pickle.dumps(UnitItem(cfg=cfg, source=sources[0], family="cubic")))
    by_data = len(pickle.dumps(UnitItem(cfg=cfg, source=sources_from_dataset(fleet)[0],
                                        family="cubic")))
    assert by_path < 10_000 < 3 * 1200 * 8 * 3 < by_data   # 3 runs × 1,200 samples × 3 columns
    want = _numbers(run_fleet(cfg, tmp_path / "d", sources_from_dataset(fleet), quiet=True,
                              options=FleetOptions(executor="serial", folds=2)))
    assert list(want) == [f"toy-u{i:03d}" for i in range(n_units)]
    for ex in executors:
        got = _numbers(run_fleet(cfg, tmp_path / ex, sources, quiet=True,
                                 options=FleetOptions(executor=ex, workers=2, folds=2)))
        assert got == want, ex   # the same data, the same computation: identical
    # a file that is not a single unit's thermonet Parquet: the driver reads the data
    write_parquet(fleet, tmp_path / "all.parquet")
    assert sources_from_files([str(tmp_path / "all.parquet")]) is None
    odd = toy_unit("toy-odd", 1.0, unit="rad/s")
    write_parquet(Dataset(odd).validate(), tmp_path / "odd.parquet")
    with pytest.raises(InputError, match=r"odd\.parquet: unit 'toy-odd' has .*rad/s.*"
                                         r"toy-u000\.parquet has"):
        sources_from_files([paths[0], str(tmp_path / "odd.parquet")])


def test_one_file_per_unit_workers_read_their_own_file(tmp_path):
    """The fast twin of the Ray test below: two units, each read by its own worker process
    (the process pool), against the driver's read."""
    _workers_read_their_own_file(tmp_path, ("process",), n_units=2)


@pytest.mark.slow
def test_one_file_per_unit_ray_workers_read_their_own_file(tmp_path):
    """The same on a real local Ray (its start-up is most of this test's time;
    `make test-slow`)."""
    _workers_read_their_own_file(tmp_path, ("serial", "ray"), n_units=3)
