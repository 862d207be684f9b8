"""MLflow tracking against a real embedded SQLite store in a temporary directory."""

from pathlib import Path

import mlflow

from thermonet.tracking import Tracker, flatten_params


def test_flatten_params_nested_and_lists():
    flat = flatten_params({"a": {"b": 1, "c": [1, 2]}, "f": [{"x": "y"}], "s": "t"})
    assert flat == {"a.b": "1", "a.c": "[1, 2]", "f.0.x": "y", "s": "t"}


def test_parent_and_nested_runs_with_batched_history(tmp_path):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    tr = Tracker(uri=uri, experiment="t")
    history = [{"epoch": e, "train_loss": 1.0 / (e + 1), "val_loss": 2.0 / (e + 1)}
               for e in range(1500)]
    art = tmp_path / "note.txt"
    art.write_text("hello")
    with tr.run("parent", params={"data": {"preset": "x"}}, tags={"device": "d"}) as pid:
        with tr.run("child", params={"family": "rbf"}, nested=True) as cid:
            tr.log_history(history)
            tr.log_metrics({"test/gyro_x/rms_comp": 0.5, "bad": float("nan")})
            tr.log_artifact(art, "files")
    client = mlflow.tracking.MlflowClient(tracking_uri=uri)
    child = client.get_run(cid)
    assert child.data.tags["mlflow.parentRunId"] == pid
    assert child.data.params["family"] == "rbf"
    assert child.data.metrics["test/gyro_x/rms_comp"] == 0.5
    assert "bad" not in child.data.metrics
    losses = client.get_metric_history(cid, "val/loss")
    assert len(losses) == 1500
    assert sorted(m.step for m in losses)[-1] == 1499
    parent = client.get_run(pid)
    assert parent.data.params["data.preset"] == "x"
    assert parent.data.tags["device"] == "d"
    names = [f.path for f in client.list_artifacts(cid, "files")]
    assert names == ["files/note.txt"]
    assert (tmp_path / "mlruns").is_dir()


def test_disabled_tracker_records_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    tr = Tracker(enabled=False)
    with tr.run("x", params={"a": 1}) as rid:
        tr.log_metrics({"m": 1.0})
        tr.log_history([{"epoch": 0, "train_loss": 1.0, "val_loss": 1.0}])
    assert rid is None
    assert not (tmp_path / "mlflow.db").exists()


def test_compare_logs_the_chosen_model_as_mlflow_expects(tmp_path):
    """A tracked comparison logs the chosen model as its run's MLflow model ``model`` (ONNX,
    with a signature and an input example) and registers it under ``tracking.register`` with
    the alias ``chosen``: ``mlflow.pyfunc.load_model("runs:/<id>/model")`` and
    ``models:/NAME@chosen`` load it from a real local store, and on a held-out run both give
    the drift the torch-free runtime computes from the same graph."""
    import numpy as np

    import thermonet
    from conftest import load_runtime
    from tolerances import assert_f32_close

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    ds = thermonet.simulate("patent-gyro", runs=4, seed=0)
    res = thermonet.compare({
        "families": [{"name": "line", "family": "linear", "inputs": ["dT"]},
                     {"name": "cubic", "family": "poly", "inputs": ["dT"],
                      "params": {"degree": 3}}],
        "tracking": {"uri": uri, "experiment": "t", "register": "imu-drift"}},
        data=ds, track=True)
    run_id = res.results["mlflow_run_id"]
    assert run_id and res.chosen in ("line", "cubic", "per-axis")
    mlflow.set_tracking_uri(uri)
    try:
        by_run = mlflow.pyfunc.load_model(f"runs:/{run_id}/model")
        by_alias = mlflow.pyfunc.load_model("models:/imu-drift@chosen")
        local = mlflow.artifacts.download_artifacts(f"runs:/{run_id}/model",
                                                    dst_path=str(tmp_path / "dl"))
        version = mlflow.MlflowClient().get_model_version_by_alias("imu-drift", "chosen")
    finally:
        mlflow.set_tracking_uri(None)
    assert str(version.version) == "1" and "chosen" in version.aliases
    signature = by_run.metadata.signature
    assert signature is not None
    assert {"temperature_c", "raw"} <= set(signature.inputs.input_names())
    assert {"compensated", "drift", "out_of_range"} <= set(signature.outputs.input_names())
    onnx_file = next(Path(local).glob("*.onnx"))
    comp = load_runtime().Compensator(str(onnx_file))
    test = ds[3]                                   # never trained on
    raw = np.column_stack([test.outputs[a] for a in comp.outputs])
    want = comp.compensate(temperature_c=test.temperature_c, raw=raw)
    feeds = {"temperature_c": test.temperature_c.astype(np.float32), "raw": raw}
    for model in (by_run, by_alias):
        got = model.predict(feeds)
        assert_f32_close(got["drift"], want.drift, "family")
        assert_f32_close(got["compensated"], want.compensated, "family", scale=want.drift)
        np.testing.assert_array_equal(got["out_of_range"], want.out_of_range)   # flags
    # the graph logged is the chosen checkpoint's: its metadata names the chosen family
    import onnx

    meta = {p.key: p.value for p in onnx.load(str(onnx_file)).metadata_props}
    family = res.results["families"][res.chosen]["family"]
    assert meta["family"] == family


def test_an_mlflow_failure_fails_the_comparison_in_one_line_nothing_written(tmp_path):
    """The tracking step runs in a child process at the comparison's edge: a store MLflow
    refuses (the retired file store under a path that cannot exist) fails the comparison
    with one line naming the URI, and the output directory is never created."""
    import pytest

    import thermonet
    from thermonet.core.errors import ThermonetError

    ds = thermonet.simulate("patent-gyro", runs=3, seed=0)
    uri = "file:///proc/no-such-dir/mlruns"
    with pytest.raises(ThermonetError) as err:
        thermonet.compare({"families": [{"name": "line", "family": "linear",
                                         "inputs": ["dT"]}]},
                          data=ds, out=tmp_path / "out", track=True, tracking_uri=uri)
    assert str(err.value).startswith(f"MLflow tracking ({uri}): ")
    assert "\n" not in str(err.value)
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out*"))


# ------------------------------------------------ tracking.register: MLflow's name rules at load
#: names MLflow refuses (mlflow.utils.validation._validate_model_name and the file store's:
#: blank, '/', ':', a path separator, '%', a name resolving to another as a path, over 256
#: characters), and names it would register as they are but that break every line that shows
#: them (control characters): each with what the one line says
BAD_REGISTER_NAMES = [
    ("imu\ndrift", "control character '\\n'"), ("imu\tdrift", "control character '\\t'"),
    ("imu\x7f", "control character '\\x7f'"), ("imu\u2028x", "control character"),
    ("../../evil", "holds '/'"), ("", "is empty"), ("   ", "is empty"),
    ("a:b", "holds ':'"), ("a\\b", "holds '\\\\'"), ("100%", "holds '%'"),
    ("..", "would resolve to another name"), ("..evil", "would resolve to another name"),
    (".", "would resolve to another name"), ("m" * 257, "has 257 characters"),
]


def test_a_register_name_mlflow_would_refuse_or_mangle_is_refused_at_load(tmp_path):
    """``tracking.register`` is checked with the config, by MLflow's own rules plus no control
    character: one line naming the key and the reason, before any data is read (was: a name
    with a newline registered as such, '../../evil' and '' warned about after the fit)."""
    import pytest

    from thermonet.core.errors import ConfigError
    from thermonet.training.config import config_from_mapping, load_config

    for name, why in BAD_REGISTER_NAMES:
        with pytest.raises(ConfigError) as err:
            config_from_mapping({"tracking": {"register": name}}, source="c.yaml")
        msg = str(err.value)
        assert msg.startswith("c.yaml: key 'tracking.register': "), msg
        assert why in msg and "\n" not in msg, (name, msg)
    # names MLflow takes stay accepted
    for name in ("imu-drift", "IMU drift v2", "bmi270.gyro_x", "m" * 256, "Ωmega"):
        assert config_from_mapping({"tracking": {"register": name}}).tracking.register == name
    # the YAML file as written by a user: the newline inside a quoted string
    cfg = tmp_path / "c.yaml"
    cfg.write_text('tracking:\n  register: "imu\\ndrift"\n')
    with pytest.raises(ConfigError, match=r"c\.yaml: key 'tracking\.register': 'imu\\ndrift' "
                                          r"holds the control character"):
        load_config(cfg)


def test_register_with_tracking_off_is_refused_in_the_config_or_said_ignored(tmp_path, capsys,
                                                                             monkeypatch):
    """``register`` needs tracking: beside ``enabled: false`` in the same config it is a
    contradiction, refused at load; ``model: sensor`` registers nothing, refused too; with
    tracking off for one run (``--no-track``) the comparison runs and says in one warning
    line, also in results.json, that nothing is registered (was: ignored without a word)."""
    import json

    import pytest

    from thermonet.cli import main
    from thermonet.core.errors import ConfigError
    from thermonet.training.config import config_from_mapping

    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=r"^c\.yaml: key 'tracking\.register': 'imu' needs "
                                          r"tracking, and tracking\.enabled is false"):
        config_from_mapping({"tracking": {"register": "imu", "enabled": False}}, source="c.yaml")
    with pytest.raises(ConfigError, match=r"key 'tracking\.register': model 'sensor' logs its "
                                          r"runs but registers no model"):
        config_from_mapping({"model": "sensor", "tracking": {"register": "imu"}})
    # the CLI refuses a bad name in one line, exit 1, before any directory is made
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("tracking: {register: '../../evil'}\n")
    capsys.readouterr()
    assert main(["compare", str(cfg), "--out", str(tmp_path / "o1"), "-q"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "key 'tracking.register': '../../evil' holds '/'" in err[0]
    assert not (tmp_path / "o1").exists() and not (tmp_path / "mlflow.db").exists()
    # --no-track: the comparison runs and says register is ignored
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data: {preset: patent-gyro, runs: 3}\n"
                   "tracking: {register: imu-drift}\n"
                   "families:\n  - {name: line, family: linear, inputs: [dT]}\n")
    assert main(["compare", str(cfg), "--out", str(tmp_path / "o2"), "--no-track",
                 "--no-plots"]) == 0
    out = capsys.readouterr()
    said = [ln for ln in (out.out + out.err).splitlines() if "tracking.register" in ln]
    assert said == ["warning: tracking.register 'imu-drift' is ignored: tracking is off for "
                    "this comparison (--no-track), so no model is registered"]
    doc = json.loads((tmp_path / "o2" / "results.json").read_text())
    assert any("'imu-drift' is ignored" in w for w in doc["warnings"])
    assert not (tmp_path / "mlflow.db").exists()


# ------------------------------------------------ a tracking URI naming what no store can be
def test_a_tracking_uri_that_is_a_file_says_so_in_one_line(tmp_path, capsys, monkeypatch):
    """A bare path or file: URI naming a file, a sqlite:/// path that is a directory or a
    file that is no SQLite database: one line naming the URI and what the path is, before
    any data is read or any directory made (was MLflow's "the filesystem tracking backend
    ... is in maintenance mode", a paragraph, after the data was read)."""
    import sqlite3

    import pytest

    from thermonet.cli import main
    from thermonet.core.errors import ThermonetError
    from thermonet.tracking import Tracker, store_problem

    monkeypatch.chdir(tmp_path)
    text = tmp_path / "store.txt"
    text.write_text("not a store\n")
    db = tmp_path / "real.db"
    sqlite3.connect(db).execute("create table t (x)").connection.close()
    assert store_problem(str(text)) == (f"{text} is a file, not a tracking store (a SQLite "
                                        "store is sqlite:///PATH, a server http://HOST:PORT)")
    assert store_problem(text.as_uri()) == store_problem(str(text))
    assert store_problem(str(db)) == (f"{db} is a file, not a tracking store (a SQLite "
                                      f"database: give sqlite:///{db})")
    assert store_problem(f"sqlite:///{tmp_path}") == (
        f"{tmp_path} is a directory, not a SQLite database (give sqlite:///DIR/mlflow.db)")
    assert store_problem(f"sqlite:///{text}") == (
        f"{text} is a file but not a SQLite database (its first bytes say otherwise)")
    # what can be a store is left to MLflow: a real or new SQLite file, an empty one, a
    # server, a database, Databricks
    (tmp_path / "empty.db").touch()
    for ok in (f"sqlite:///{db}", f"sqlite:///{tmp_path / 'new.db'}", "sqlite:///empty.db",
               "http://127.0.0.1:5000", "databricks", "postgresql+psycopg2://u@h/db"):
        assert store_problem(ok) is None, ok
    # MLflow's file store (a directory, or a path not there yet), which MLflow 3 refuses as
    # "in maintenance mode" after the whole fit, and a scheme no store takes: refused first
    assert store_problem(str(tmp_path)) == (
        f"{tmp_path} names MLflow's file store (a bare path or file: URI), which this MLflow "
        "no longer writes (a SQLite store is sqlite:///PATH, a server http://HOST:PORT)")
    assert store_problem(str(tmp_path / "x" / "ml.db")) == (
        f"{tmp_path / 'x' / 'ml.db'} names MLflow's file store (a bare path or file: URI), "
        f"which this MLflow no longer writes (give sqlite:///{tmp_path / 'x' / 'ml.db'})")
    assert store_problem("bogus://x") == ("no MLflow store takes the scheme 'bogus' (a SQLite "
                                          "store is sqlite:///PATH, a server http://HOST:PORT)")
    with pytest.raises(ThermonetError, match=r"^MLflow tracking \(store\.txt\): "
                                             r"store\.txt is a file, not a tracking store"):
        Tracker(uri="store.txt")
    assert Tracker(enabled=False, uri="store.txt").uri == "store.txt"   # off: never looked at
    # the command line: one line, exit 1, nothing made
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data: {preset: patent-gyro, runs: 3}\n"
                   "families:\n  - {name: line, family: linear, inputs: [dT]}\n")
    for uri in ("store.txt", text.as_uri(), f"sqlite:///{text}", "bogus://x"):
        capsys.readouterr()
        assert main(["compare", str(cfg), "--out", "o", "--tracking-uri", uri]) == 1
        out = capsys.readouterr()
        assert out.out == "" and len(out.err.strip().splitlines()) == 1, out
        assert out.err.startswith(f"thermonet: error: MLflow tracking ({uri}): " + (
            text.name if uri == "store.txt" else "no MLflow store" if uri == "bogus://x"
            else str(text))), out.err
        assert "maintenance" not in out.err
        assert not (tmp_path / "o").exists() and not list(tmp_path.glob(".o*"))
    # fleet (before any unit is fitted) and export from a run id say the same
    capsys.readouterr()
    for args, out in ((["fleet", str(cfg), "--units", "2", "--out", "f"], "f"),
                      (["export", "0" * 32, "--format", "c", "--out", "m.h"], "m.h")):
        assert main([*args, "--tracking-uri", "store.txt"]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert err == ["thermonet: error: MLflow tracking (store.txt): store.txt is a file, "
                       "not a tracking store (a SQLite store is sqlite:///PATH, a server "
                       "http://HOST:PORT)"]
        assert not (tmp_path / out).exists()


def test_where_no_helper_process_can_be_had_the_command_tracks_itself(tmp_path, monkeypatch):
    """The MLflow worker is a helper process (core.helpers.Helpers); where none can be had (a
    script without a ``__main__`` guard, a process limit: OSError) the same calls run in the
    command, in turn — the same runs, every one FINISHED, the chosen model logged, and the
    run ids in results.json."""
    import thermonet
    from thermonet.workflows import compare_track

    def no_process(*args, **kwargs):
        raise OSError("no helper process: refused for the test")

    monkeypatch.setattr(compare_track, "Helpers", no_process)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    res = thermonet.compare({
        "families": [{"name": "line", "family": "linear", "inputs": ["dT"]},
                     {"name": "cubic", "family": "poly", "inputs": ["dT"],
                      "params": {"degree": 3}}],
        "tracking": {"uri": uri, "experiment": "inline"}},
        data=thermonet.simulate("patent-gyro", runs=3, seed=0), out=tmp_path / "out",
        track=True)
    client = mlflow.MlflowClient(tracking_uri=uri)
    exp = client.get_experiment_by_name("inline")
    runs = client.search_runs([exp.experiment_id])
    names = {r.info.run_name: r for r in runs}
    assert set(names) == {"line", "cubic", f"compare-{res.results['device']}"}
    assert all(r.info.status == "FINISHED" for r in runs)
    parent = names[f"compare-{res.results['device']}"]
    assert res.results["mlflow_run_id"] == parent.info.run_id
    logged = {a.path for a in client.list_artifacts(parent.info.run_id)}
    assert {"results.json", "config.resolved.yaml", "report.html"} <= logged
    mlflow.set_tracking_uri(uri)
    try:     # the chosen model, as its run's MLflow model
        local = mlflow.artifacts.download_artifacts(f"runs:/{parent.info.run_id}/model",
                                                    dst_path=str(tmp_path / "dl"))
    finally:
        mlflow.set_tracking_uri(None)
    assert list(Path(local).glob("*.onnx"))


def test_the_shipped_per_axis_models_figures_go_on_the_parent_run(tmp_path):
    """A per-axis model has no run of its own: its held-out figures (every number of its axes'
    records in results.json) go on the comparison's run as ``shipped/test/<axis>/<metric>``,
    readable from a real store like a family's ``test/<axis>/<metric>`` (a new user's pass:
    the parent had only cv/*/score)."""
    from thermonet.workflows.compare_track import shipped_metrics

    doc = {"chosen": "per-axis", "families": {"per-axis": {"axes": {
        "gyro_x": {"score_ratio": 0.5, "rms_comp": 0.02, "verdict": "better", "compensate": True,
                   "interval": [0.4, 0.6]},
        "gyro_y": {"score_ratio": 1.0, "rms_comp": 0.03, "compensate": False}}}}}
    got = shipped_metrics(doc)
    assert got == {"shipped/test/gyro_x/score_ratio": 0.5, "shipped/test/gyro_x/rms_comp": 0.02,
                   "shipped/test/gyro_y/score_ratio": 1.0, "shipped/test/gyro_y/rms_comp": 0.03}
    assert shipped_metrics({"families": {"cubic": {}}}) == {}
    uri = f"sqlite:///{tmp_path / 'm.db'}"
    tr = Tracker(uri=uri, experiment="t")
    with tr.run("compare", params={}) as rid:
        tr.log_metrics(got)
    logged = mlflow.tracking.MlflowClient(tracking_uri=uri).get_run(rid).data.metrics
    assert logged == got
