"""MLflow tracking against a real embedded SQLite store in a temporary directory."""

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
