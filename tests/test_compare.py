"""`compare` end to end on data the tests make: honest split, metrics, choice, tracking."""

from __future__ import annotations

import json

import mlflow
import numpy as np
import pytest

from conftest import toy_dataset
from thermonet.data.io import write_parquet
from thermonet.training.checkpoint import load_checkpoint
from thermonet.training.config import CompareConfig, FamilyConfig, TrainConfig
from thermonet.training.config_sections import DataConfig
from thermonet.training.train import predict
from thermonet.workflows.compare import format_table, run_compare

FAST = TrainConfig(max_epochs=20, patience=5)


def config(path, families, **kw) -> CompareConfig:
    kw.setdefault("baseline", "cubic" if any(f.label == "cubic" for f in families) else None)
    return CompareConfig(data=DataConfig(paths=[str(path)]), families=families, train=FAST, **kw)


def test_compare_recovers_quadratic_drift_and_writes_everything(tmp_path):
    path = write_parquet(toy_dataset(), tmp_path / "toy.parquet")
    fams = [FamilyConfig(family="poly", name="cubic", params={"degree": 3}),
            FamilyConfig(family="linear", name="linear")]
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    res = run_compare(config(path, fams), tmp_path / "out", tracking_uri=uri, quiet=True)

    # split by run: train run0, run1; validate run2; test run3
    assert res["split"]["folds"] == [{"train": ["run0", "run1"], "val": "run2", "test": "run3"}]
    cubic = res["families"]["cubic"]["axes"]["gyro_x"]
    linear = res["families"]["linear"]["axes"]["gyro_x"]
    # the drift is quadratic: the cubic leaves only the noise (σ = 0.002), the line does not
    assert cubic["rms_comp"] == pytest.approx(0.002, rel=0.1)
    assert cubic["drift_error_rms"] < 0.001
    assert linear["rms_comp"] > 10 * cubic["rms_comp"]
    # raw pp of 1 °C-binned means of 0.05 + 0.01 d − 2e-4 d²  over d in [0.6, 70.6]
    d = np.linspace(0.6, 70.6, 1000)
    assert cubic["pp_raw"] == pytest.approx(np.ptp(0.01 * d - 2e-4 * d ** 2), rel=0.05)
    assert cubic["pp_raw"] / cubic["pp_comp"] > 10
    assert res["chosen"] == "cubic"

    out = tmp_path / "out"
    on_disk = json.loads((out / "results.json").read_text())
    assert on_disk["chosen"] == "cubic"
    assert set(on_disk["families"]["cubic"]) >= {"fit_seconds", "n_params", "axes", "status"}
    assert on_disk["families"]["cubic"]["n_params"] == 4
    assert sorted(p.name for p in (out / "plots").glob("*.png")) == [
        "accuracy_vs_cost.png", "allan_gyro_x.png", "drift_vs_temperature_gyro_x.png",
        "residual_vs_temperature_gyro_x.png", "residual_vs_time_gyro_x.png"]
    assert (out / "report.html").stat().st_size > 10_000
    assert on_disk["schema"] == 3
    # the typed result is the single source: results.json holds nothing outside it (read back
    # and written again, the same document), and a schema-2 file reads to the same objects
    from thermonet.reporting.results import ComparisonResult as Typed
    assert Typed.from_json(on_disk).to_json() == on_disk
    old = {**on_disk, "schema": 2, "per_axis": {"checkpoint": "models/per-axis.pt"}}
    assert Typed.from_json(old).to_json() == on_disk
    with pytest.raises(ValueError, match="key 'schema': 9"):
        Typed.from_json({**on_disk, "schema": 9})
    # the cubic leaves the noise σ = 0.002 of a raw spread of about 0.06: far better than raw
    assert cubic["verdict"] == "better" and cubic["interval"][1] < 0.1
    assert cubic["compensate"] is True
    assert cubic["vs_baseline"]["ratio"] == pytest.approx(1.0)
    assert linear["vs_baseline"]["verdict"] == "worse"
    model, meta = load_checkpoint(out / "models" / "cubic.pt")
    sig = np.array([[-20.0], [15.0], [50.0]])
    truth = 0.05 + 0.01 * (sig[:, 0] + 20) - 2e-4 * (sig[:, 0] + 20) ** 2
    assert np.allclose(predict(model, sig)[:, 0], truth, atol=2e-3)
    # the checkpoint carries the family's own resolved config and its best epoch
    assert meta["config"]["family"]["params"] == {"degree": 3}
    assert meta["config"]["train"]["optimizer"] == "lbfgs" and "data" not in meta["config"]
    assert meta["epoch"] == res["families"]["cubic"]["best_epoch"]
    # refitted on training + validation after cross-validation (selection.refit): the model
    # that ships has no validation loss of its own
    assert meta["best_val"] is None
    # and loads as an estimator
    from thermonet import DriftEstimator
    est = DriftEstimator.load(out / "models" / "cubic.pt")
    assert est.best_epoch_ == meta["epoch"] and est.family.degree == 3
    np.testing.assert_allclose(est.predict(toy_dataset()[3]), predict(model, toy_dataset()[3]
                                                                      .temperature_c[:, None]))

    client = mlflow.tracking.MlflowClient(tracking_uri=uri)
    parent = client.get_run(res["mlflow_run_id"])
    assert parent.data.tags["chosen"] == "cubic"
    child = client.get_run(res["families"]["cubic"]["mlflow_run_id"])
    assert child.data.tags["mlflow.parentRunId"] == parent.info.run_id
    assert child.data.tags["family"] == "poly"
    assert child.data.metrics["test/gyro_x/rms_comp"] == pytest.approx(cubic["rms_comp"])
    # the cubic's least squares is final (no gradient refinement): epoch 0 is its whole curve
    assert len(client.get_metric_history(child.info.run_id, "val/loss")) == 1
    arts = {a.path for a in client.list_artifacts(parent.info.run_id)}
    assert {"results.json", "config.resolved.yaml", "plots"} <= arts
    assert "cubic" in format_table(res) and "chosen: cubic" in format_table(res)


def test_the_typed_result_is_what_every_consumer_reads_and_what_was_written(tmp_path,
                                                                            monkeypatch):
    """issue 51: compare hands its typed result to the table, the report and the API — none
    parses a document back (from_json is not called in the process that wrote it) — and the
    result is the file: its document is results.json, its table and page those of the file."""
    import thermonet
    from thermonet.reporting.report import render_report
    from thermonet.reporting.results import ComparisonResult as Typed
    from thermonet.workflows.compare import compare_result

    path = write_parquet(toy_dataset(), tmp_path / "toy.parquet")
    fams = [FamilyConfig(family="poly", name="cubic", params={"degree": 3}),
            FamilyConfig(family="linear", name="linear")]

    def no_parse(*a, **k):
        raise AssertionError("a document parsed in the process that built the result")

    with monkeypatch.context() as m:
        m.setattr(Typed, "from_json", classmethod(no_parse))
        res = compare_result(config(path, fams), tmp_path / "out", track=False, quiet=True,
                             plots=False)
        table, page = format_table(res), render_report(res)
        api = thermonet.compare(config(path, fams), out=tmp_path / "api", plots=False)
        assert api.record.chosen == res.chosen and api.table().startswith(table.split()[0])
    assert isinstance(res, Typed) and res.families["cubic"].checkpoint_sha256
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    assert res.to_json() == doc
    assert format_table(doc) == table and render_report(doc) == page   # a file, read once


def test_family_that_cannot_fit_is_reported_and_others_go_on(tmp_path):
    path = write_parquet(toy_dataset(soak_levels=[0.0, 20.0, 40.0]), tmp_path / "soaks.parquet")
    fams = [FamilyConfig(family="poly", name="poly6", params={"degree": 6}),
            FamilyConfig(family="linear", name="linear")]
    res = run_compare(config(path, fams), tmp_path / "out", track=False, quiet=True)
    bad = res["families"]["poly6"]
    assert bad["status"] == "failed"
    assert "3 distinct" in bad["reason"]
    assert bad["checkpoint"] is None
    assert res["families"]["linear"]["status"] == "ok"
    assert not (tmp_path / "out" / "models" / "poly6.pt").exists()
    assert "poly6" in format_table(res) and "not fitted" in format_table(res)


def test_do_no_harm_when_nothing_beats_raw(tmp_path):
    # no thermal drift at all: every model can only add error on held-out data
    path = write_parquet(toy_dataset(drift_scale=0.0, noise=0.01), tmp_path / "flat.parquet")
    fams = [FamilyConfig(family="rbf", name="rbf", inputs=["dT", "dT2"], params={"n_centres": 8})]
    res = run_compare(config(path, fams), tmp_path / "out", track=False, quiet=True)
    assert res["chosen"] is None
    assert "do no harm" in res["chosen_reason"]


def test_single_run_is_split_in_contiguous_time_blocks(tmp_path):
    ds = toy_dataset(n_runs=1)
    path = write_parquet(ds, tmp_path / "one.parquet")
    fams = [FamilyConfig(family="poly", name="cubic", params={"degree": 3})]
    res = run_compare(config(path, fams), tmp_path / "out", track=False, quiet=True)
    fold = res["split"]["folds"][0]
    assert fold == {"train": "run0[train]", "val": "run0[val]", "test": "run0[test]"}
    assert res["split"]["strategy"] == "time-blocks"


def test_leave_one_run_out_reports_folds(tmp_path):
    path = write_parquet(toy_dataset(n_runs=3), tmp_path / "three.parquet")
    cfg = config(path, [FamilyConfig(family="poly", name="quad", params={"degree": 2})])
    cfg.split.strategy = "leave-one-run-out"
    res = run_compare(cfg, tmp_path / "out", track=False, quiet=True)
    assert [f["test"] for f in res["split"]["folds"]] == ["run0", "run1", "run2"]
    fam = res["families"]["quad"]
    assert len(fam["folds"]) == 3
    mean = np.mean([f["gyro_x"]["rms_comp"] for f in fam["folds"]])
    assert fam["axes"]["gyro_x"]["rms_comp"] == pytest.approx(mean)


def test_two_runs_train_then_verify_with_interleaved_validation_blocks(tmp_path):
    from thermonet.training.config import SplitConfig
    from thermonet.training.parts import make_splits

    ds = toy_dataset(n_runs=2)
    split, = make_splits(ds, SplitConfig())
    assert split.label == "train-then-verify"
    assert split.test is ds["run1"]
    train, val = split.train[0], split.val
    # contiguous blocks: 20 blocks of 6 min; every 5th block (index 2 mod 5) validates
    assert val.n_samples == pytest.approx(0.2 * ds["run0"].n_samples, rel=0.01)
    assert train.n_samples + val.n_samples == ds["run0"].n_samples
    assert not set(train.time_s) & set(val.time_s)
    gaps = np.flatnonzero(np.diff(val.time_s) > 1.5)
    assert len(gaps) == 3  # four contiguous validation blocks
    # the validation blocks sample the whole temperature range
    assert val.temperature_c.min() < -5 and val.temperature_c.max() > 35


def test_train_on_heating_fits_only_the_heating_branch(tmp_path):
    """PX4/ArduPilot practice: a cubic fitted on heating samples learns the heating branch."""
    from thermonet.core.recording import Dataset, Recording

    rng = np.random.default_rng(3)
    runs = []
    for k in range(3):
        t = np.arange(0.0, 4 * 3600.0, 1.0)
        temp = 30.0 - np.abs(30.0 - 60.0 * t / t[-1])           # ramps 0 → 30 → 0 °C
        heating = t < t[-1] / 2
        drift = 1e-3 * temp + np.where(heating, 0.05, -0.05)      # ±0.05 hysteresis
        runs.append(Recording(time_s=t, temperature_c=temp,
                              outputs={"gyro_x": drift + rng.normal(0, 1e-3, t.size)},
                              drift={"drift_gyro_x": drift}, run_id=f"run{k}",
                              units={"gyro_x": "deg/s"}, sample_rate_hz=1.0))
    path = write_parquet(Dataset(runs), tmp_path / "cycles.parquet")
    fams = [FamilyConfig(family="poly", name="heating", params={"degree": 3}, train_on="heating"),
            FamilyConfig(family="poly", name="all", params={"degree": 3})]
    res = run_compare(config(path, fams), tmp_path / "out", track=False, quiet=True)
    assert res["families"]["heating"]["train_on"] == "heating"
    mid = np.array([[15.0]])
    heat_model, _ = load_checkpoint(tmp_path / "out" / "models" / "heating.pt")
    all_model, _ = load_checkpoint(tmp_path / "out" / "models" / "all.pt")
    # the checkpoints carry the per-axis do-no-harm mask of results.json; the fitted curves
    # themselves are judged here, so the mask is lifted
    for label, model in (("heating", heat_model), ("all", all_model)):
        assert model.compensated_axes == [res["families"][label]["axes"]["gyro_x"]["compensate"]]
        model.set_compensate([True])
    assert predict(heat_model, mid)[0, 0] == pytest.approx(0.015 + 0.05, abs=0.005)
    assert predict(all_model, mid)[0, 0] == pytest.approx(0.015, abs=0.005)
    # on a run that cools as much as it heats, the heating-only fit is off by the hysteresis
    assert res["families"]["heating"]["axes"]["gyro_x"]["drift_error_rms"] == \
        pytest.approx(0.05 * np.sqrt(2), rel=0.15)


def _numbers(res: dict) -> dict:
    """Everything a comparison decides, without what differs between runs (paths, times)."""
    return {label: {"params": f["n_params"], "best_epoch": f["best_epoch"],
                    "val_score": f["val_score"], "axes": f["axes"]}
            for label, f in res["families"].items()} | {"chosen": res["chosen"]}


def test_families_side_by_side_give_the_serial_results(tmp_path):
    """Families fitted in threads (config `workers`, CLI --workers) share the built parts and
    their window means, and every number is the one-after-another run's, bit for bit."""
    path = write_parquet(toy_dataset(), tmp_path / "toy.parquet")
    fams = [FamilyConfig(family="poly", name="cubic", params={"degree": 3}),
            FamilyConfig(family="rbf", name="rbf", inputs=["dT", "dT2"], params={"n_centres": 8}),
            FamilyConfig(family="lorentz", name="lorentz"),
            FamilyConfig(family="linear", name="linear")]
    serial = run_compare(config(path, fams, workers=1), tmp_path / "serial", track=False,
                         quiet=True, plots=False)
    side = run_compare(config(path, fams, workers=3), tmp_path / "side", track=False,
                       quiet=True, plots=False)
    assert _numbers(side) == _numbers(serial)
    assert list(side["families"]) == [f.label for f in fams]     # config order kept
    override = run_compare(config(path, fams), tmp_path / "over", track=False, quiet=True,
                           plots=False, workers=2)
    assert _numbers(override) == _numbers(serial)


def test_data_read_by_a_figure_drawer_gives_the_same_comparison(tmp_path):
    """With figures drawn by helpers, the first reads the config's data as it starts while
    the command imports torch (``--profile`` names the stage): the comparison is the one
    the command makes reading the data itself (``workers=1``: no helpers), its data
    recorded the same (digest, runs, provenance)."""
    from thermonet.core import profile

    path = write_parquet(toy_dataset(), tmp_path / "toy.parquet")
    fams = [FamilyConfig(family="poly", name="cubic", params={"degree": 3}),
            FamilyConfig(family="linear", name="linear")]
    here = run_compare(config(path, fams, workers=1), tmp_path / "here", track=False,
                       quiet=True)
    profile.reset()
    profile.enable()
    try:
        helped = run_compare(config(path, fams, workers=2), tmp_path / "helped", track=False,
                             quiet=True)
        stages = list(profile.timings())
    finally:
        profile.enable(False)
        profile.reset()
    assert "read the data (in a helper)" in stages
    assert _numbers(helped) == _numbers(here)
    assert helped["data_hash"] == here["data_hash"] and helped["data"] == here["data"]
    assert helped["config"]["data"] == here["config"]["data"]


def test_data_a_drawer_cannot_read_is_refused_by_the_command(tmp_path, capsys):
    """A bad data file with helpers to read it: the command reads it itself and refuses it
    in its own one line naming the file and the column, exit 1, nothing written."""
    from thermonet.cli import main

    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,temperature_c,gyro_x\n0,20,0.1\n1,21,abc\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data: {{paths: ['{bad}']}}\nfamilies: [{{family: linear}}]\n")
    codes, errs = [], []
    for workers in ("1", "2"):
        codes.append(main(["compare", str(cfg), "--out", str(tmp_path / f"o{workers}"),
                           "--no-track", "-q", "--workers", workers]))
        errs.append(capsys.readouterr().err.strip().splitlines())
    assert codes == [1, 1] and errs[0] == errs[1] and len(errs[0]) == 1
    assert "bad.csv" in errs[0][0] and "gyro_x" in errs[0][0]
    assert not (tmp_path / "o2").exists()


def test_family_workers_rule_and_validation():
    from thermonet.core.errors import ConfigError
    from thermonet.training.config import from_dict
    from thermonet.workflows.compare_fit import family_workers

    fams = [FamilyConfig(family="poly", name="cubic", params={"degree": 3}),
            FamilyConfig(family="linear", name="linear")]
    assert family_workers(CompareConfig(families=fams, workers=8)) == 2   # at most one per family
    assert family_workers(CompareConfig(families=fams, workers=1)) == 1
    assert family_workers(CompareConfig(families=fams, workers=8), workers=1) == 1
    # a family with its own torch thread count makes the comparison serial
    fams[1].train = {"threads": 2}
    assert family_workers(CompareConfig(families=fams, workers=2)) == 1
    for bad in (-1, 1.5, True):
        with pytest.raises(ConfigError, match="'workers'"):
            from_dict(CompareConfig, {"data": {"preset": "patent-gyro"}, "workers": bad},
                      source="c.yaml")


def test_a_fit_that_raises_stops_the_others_and_is_reported(tmp_path, monkeypatch):
    """An unexpected error in one family's fit (not a FitError, which is a result) ends the
    comparison with that error while the other threads stop at their next epoch; nothing is
    written to --out."""
    import thermonet.training.train as train_mod

    path = write_parquet(toy_dataset(), tmp_path / "toy.parquet")
    fams = [FamilyConfig(family="rbf", name="rbf", inputs=["dT", "dT2"], params={"n_centres": 8},
                         train={"max_epochs": 2000, "patience": 2000, "min_delta": 0.0}),
            FamilyConfig(family="linear", name="linear")]
    real_fit = train_mod.fit
    epochs = []

    def fit(*, family, on_epoch, **kw):
        if family == "linear":
            raise RuntimeError("disk on fire")

        def counted(*a):
            epochs.append(a[0])
            on_epoch(*a)
        return real_fit(family=family, on_epoch=counted, **kw)

    monkeypatch.setattr(train_mod, "fit", fit)
    with pytest.raises(RuntimeError, match="disk on fire"):
        run_compare(config(path, fams, workers=2), tmp_path / "out", track=False, quiet=True,
                    plots=False)
    assert not (tmp_path / "out").exists()
    assert len(epochs) < 2000          # the RBF stopped early instead of running its course


def test_drawers_that_cannot_be_started_leave_the_command_to_do_it_all(tmp_path, monkeypatch):
    """No process to be had for the figure drawers (the pool raises OSError): the command
    reads the data and draws the figures itself; the comparison is the same."""
    from thermonet.reporting import plot_workers

    def refuse(*_: object, **__: object) -> None:
        raise OSError(11, "Resource temporarily unavailable")

    path = write_parquet(toy_dataset(), tmp_path / "toy.parquet")
    fams = [FamilyConfig(family="poly", name="cubic", params={"degree": 3})]
    here = run_compare(config(path, fams, workers=1), tmp_path / "here", track=False,
                       quiet=True)
    monkeypatch.setattr(plot_workers, "Helpers", refuse)
    refused = run_compare(config(path, fams, workers=2), tmp_path / "refused", track=False,
                          quiet=True)
    assert _numbers(refused) == _numbers(here)
    assert sorted(p.name for p in (tmp_path / "refused" / "plots").glob("*.png")) == \
        sorted(p.name for p in (tmp_path / "here" / "plots").glob("*.png")) != []


def test_implausible_lorentz_warns_only_where_it_ships(tmp_path):
    """Every family's parameter table is made, so a Lorentz fitted to a straight drift (the
    flank of a peak far outside the data: width ≫ span) carries the note in its rows; the
    comparison warns about it only where that Lorentz is the model that ships."""
    ds = toy_dataset(dt_s=10.0, law=lambda temp: 0.002 * (temp + 20.0))
    path = write_parquet(ds, tmp_path / "line.parquet")
    lor = FamilyConfig(family="lorentz", name="lorentz", params={"xc_margin": 4.0})
    cub = FamilyConfig(family="poly", name="cubic", params={"degree": 3})
    cfgs = [config(path, fams) for fams in ([cub, lor], [lor])]
    for cfg in cfgs:     # long enough for the peak to leave the data (test_api_contract's)
        cfg.train = TrainConfig(max_epochs=300, patience=50)
    both, alone = (run_compare(cfg, tmp_path / name, track=False, quiet=True)
                   for cfg, name in zip(cfgs, ("both", "alone"), strict=True))
    assert both["chosen"] == "cubic" and alone["chosen"] == "lorentz"
    assert not [w for w in both["warnings"] if "implausible" in w]
    said = [w for w in alone["warnings"] if w.startswith("lorentz on gyro_x: implausible")]
    assert len(said) == 1 and "× the trained span" in said[0]


def test_a_comparison_leaves_the_warnings_filters_as_it_found_them(tmp_path):
    """Families are fitted side by side in threads, where a ``warnings.catch_warnings`` is a
    race (the filters are global: a thread restoring them can keep another's "ignore"): the
    parameter tables once silenced Lorentz's note that way and left UserWarnings ignored for
    the rest of the process. A comparison now adds no filter."""
    import warnings

    before = list(warnings.filters)
    cfg = CompareConfig(train=FAST)      # the default set, a Lorentz among ten families
    cfg.tracking.enabled = False
    run_compare(cfg, tmp_path / "out", dataset=toy_dataset(dt_s=10.0), quiet=True,
                plots=False, workers=2)
    assert [f for f in warnings.filters if f not in before] == []
