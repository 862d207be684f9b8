"""Provenance that is true (class 10).

What a comparison writes about how its models were made — ``config.resolved.yaml``,
``results.json`` (``config`` and ``provenance``), each checkpoint, ``report.html``, a fleet's
``results.json`` — says what was actually used: the data files with their SHA-256 (never the
default simulator preset when the data came from files), the tracking actually done (off
under ``--no-track``), the options as given.  ``info`` on a CSV whose header line is a data
row suggests ``header: false``, and says its noise floor is per sample at the file's rate.
Real files, real comparisons; nothing mocked.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from conftest import toy_dataset
from thermonet.cli import main
from thermonet.core.recording import Dataset, Recording
from thermonet.data.io import read_datasets, write_parquet
from thermonet.training.config import load_config
from thermonet.workflows.info import summarize

FAMILY = "families:\n  - {family: poly, name: cubic, inputs: [dT], params: {degree: 3}}\n" \
         "train: {max_epochs: 3}\nbaseline: null\n"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _csv(path: Path, run: Recording, *, header: bool = True) -> Path:
    rows = zip(run.time_s.tolist(), run.temperature_c.tolist(), run.outputs["gyro_x"].tolist(),
               strict=True)
    lines = (["time_s,temperature_c,gyro_x"] if header else []) + \
        [f"{t!r},{c!r},{g!r}" for t, c, g in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def on_files(tmp_path_factory) -> Path:
    """A comparison on a Parquet file, under --no-track (the config says tracking is on)."""
    tmp = tmp_path_factory.mktemp("prov")
    data = write_parquet(toy_dataset(n_runs=3), tmp / "toy.parquet")
    cfg = tmp / "c.yaml"
    cfg.write_text(f"data: {{paths: ['{data}']}}\n{FAMILY}tracking: {{enabled: true}}\n")
    assert main(["compare", str(cfg), "--out", str(tmp / "out"), "--no-track", "-q",
                 "--no-plots"]) == 0
    return tmp


def test_resolved_config_of_a_comparison_on_files_says_files_and_no_tracking(on_files):
    out, data = on_files / "out", on_files / "toy.parquet"
    text = (out / "config.resolved.yaml").read_text()
    resolved = yaml.safe_load(text)
    assert resolved["data"]["preset"] is None and resolved["data"]["paths"] == [str(data)]
    assert "seed" not in resolved["data"] and "runs" not in resolved["data"]
    assert resolved["tracking"]["enabled"] is False and resolved["tracking"]["uri"] is None
    assert "patent-gyro" not in text
    # the digest of the data file heads the file, and the file is still a config
    assert f"#   {_sha(data)}  {data}" in text and "# tracking: off" in text
    assert "track=False" in text
    back = load_config(out / "config.resolved.yaml")
    assert back.data.paths == [str(data)] and back.data.preset is None
    assert back.tracking.enabled is False


def test_results_checkpoint_and_report_record_what_was_used(on_files):
    out, data = on_files / "out", on_files / "toy.parquet"
    res = json.loads((out / "results.json").read_text())
    assert res["config"]["data"]["preset"] is None
    assert res["config"]["tracking"]["enabled"] is False
    prov = res["provenance"]
    assert prov["data"] == {"kind": "files", "files": [{"path": str(data),
                                                        "sha256": _sha(data)}],
                            "mapping": None, "skipped_rows": None}
    assert prov["options"] == {"track": False, "tracking_uri": None, "workers": None,
                               "plots": False}
    assert res["mlflow_run_id"] is None
    payload = torch.load(out / "models" / "cubic.pt", weights_only=True)
    assert payload["config"]["tracking"]["enabled"] is False
    assert payload["extra"]["provenance"]["data"]["files"][0]["sha256"] == _sha(data)
    assert payload["extra"]["mlflow_run_id"] == ""
    html = (out / "report.html").read_text()
    assert _sha(data) in html and "tracking: off" in html
    # the resolved config's header: the options given, not those left unset (was
    # "tracking_uri=None, workers=None")
    head = (out / "config.resolved.yaml").read_text()
    assert "# options as given: track=False, plots=False\n" in head


def test_an_exported_onnx_file_names_its_checkpoint_and_data(on_files, tmp_path):
    import onnx

    out, data = on_files / "out", on_files / "toy.parquet"
    assert main(["export", str(out), "--format", "onnx", "--family", "cubic",
                 "--out", str(tmp_path / "m.onnx")]) == 0
    props = {p.key: p.value for p in onnx.load(str(tmp_path / "m.onnx")).metadata_props}
    payload = torch.load(out / "models" / "cubic.pt", weights_only=True)
    assert props["checkpoint_sha256"] == payload["sha256"]
    assert json.loads(props["data_source"])["files"] == [{"path": str(data),
                                                          "sha256": _sha(data)}]


def test_a_mapping_and_several_files_are_each_recorded(tmp_path, capsys):
    ds = toy_dataset(n_runs=3)
    files = [_csv(tmp_path / f"r{k}.csv", ds[k], header=False) for k in range(3)]
    with files[1].open("a") as f:                   # two rows the mapping skips
        f.write("1e9,abc,0.1\n1e9,2\n")
    mapping = tmp_path / "m.yaml"
    mapping.write_text("header: false\ntime: {column: 0, unit: s}\nmalformed_rows: skip\n"
                       "channels:\n  temperature_c: {column: 1}\n  gyro_x: {column: 2}\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data: {{paths: {[str(f) for f in files]}, mapping: '{mapping}'}}\n{FAMILY}")
    assert main(["compare", str(cfg), "--out", str(tmp_path / "out"), "--no-track", "-q",
                 "--no-plots"]) == 0
    prov = json.loads((tmp_path / "out" / "results.json").read_text())["provenance"]["data"]
    assert [f["sha256"] for f in prov["files"]] == [_sha(f) for f in files]
    assert prov["mapping"] == {"path": str(mapping), "sha256": _sha(mapping)}
    assert prov["skipped_rows"] == 2            # said where the data's provenance is
    assert "2 malformed rows skipped" in (tmp_path / "out" / "report.html").read_text()
    text = (tmp_path / "out" / "config.resolved.yaml").read_text()
    assert f"# mapping: {_sha(mapping)}  {mapping}" in text


def test_a_simulated_comparison_names_its_preset_runs_and_tracking_store(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data: {{preset: accel-ramp, seed: 3}}\n{FAMILY}")
    uri = f"sqlite:///{tmp_path / 'store.db'}"
    assert main(["compare", str(cfg), "--out", str(tmp_path / "out"), "-q", "--no-plots",
                 "--tracking-uri", uri]) == 0
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    assert res["config"]["data"]["preset"] == "accel-ramp" and res["config"]["data"]["seed"] == 3
    n_runs = len(res["data"]["runs"])
    assert res["config"]["data"]["runs"] == n_runs   # what was simulated, not null
    assert res["config"]["tracking"] == {"enabled": True, "uri": uri, "experiment": "thermonet"}
    assert res["provenance"]["data"] == {"kind": "simulated", "preset": "accel-ramp",
                                         "runs": n_runs, "seed": 3}
    assert res["mlflow_run_id"]
    text = (tmp_path / "out" / "config.resolved.yaml").read_text()
    assert f"# tracking: MLflow at {uri}" in text


def test_a_fleet_on_files_records_files_and_no_tracking(tmp_path):
    runs = []
    for unit in ("u1", "u2"):
        for r in toy_dataset(n_runs=3, seed=1 if unit == "u1" else 2):
            r.device_id = unit
            runs.append(r)
    data = write_parquet(Dataset(runs), tmp_path / "fleet.parquet")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data: {{paths: ['{data}']}}\n{FAMILY}tracking: {{enabled: true}}\n")
    rc = main(["fleet", str(cfg), "--out", str(tmp_path / "out"), "--no-track", "-q",
               "--no-plots", "--executor", "serial"])
    assert rc in (0, 3)
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    assert res["config"]["data"]["preset"] is None
    assert res["config"]["tracking"]["enabled"] is False
    assert res["provenance"]["data"]["files"] == [{"path": str(data), "sha256": _sha(data)}]


# ------------------------------------------------------------------------------ info
def _one_run(n: int = 400, rate: float = 10.0, seed: int = 0) -> Recording:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    temp = 20.0 + 10.0 * np.arange(n) / n
    return Recording(time_s=t, temperature_c=temp,
                     outputs={"gyro_x": 0.01 * temp + rng.normal(0, 0.002, n)},
                     units={"gyro_x": "deg/s", "temperature_c": "degC"}, run_id=f"r{seed}")


def test_info_without_mapping_on_a_headerless_csv_suggests_header_false(tmp_path, capsys):
    f = _csv(tmp_path / "raw.csv", _one_run(), header=False)
    assert main(["info", str(f)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(f) in err and "'header: false'" in err, err


@pytest.mark.parametrize("first,warned", [
    ("0.0,20.0,0.2", True),          # a data row read as the header
    ("-1,2e3,.5", True),             # every name a number, whatever the notation
    ("t,20.0,0.2", False),           # a header with one numeric name is still a header
    ("time,temp,rate", False),
])
def test_info_with_a_mapping_warns_when_the_header_is_all_numbers(tmp_path, capsys, first,
                                                                   warned):
    body = "\n".join(f"{k * 0.1!r},{20 + k * 0.05!r},{0.01 * k!r}" for k in range(1, 400))
    f = tmp_path / "d.csv"
    f.write_text(first + "\n" + body + "\n")
    mapping = tmp_path / "m.yaml"
    mapping.write_text("time: {column: 0, unit: s}\n"
                       "channels:\n  temperature_c: {column: 1}\n  gyro_x: {column: 2}\n")
    assert main(["info", str(f), "--mapping", str(mapping), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    hint = [w for w in s["warnings"] if "set 'header: false'" in w]
    assert bool(hint) == warned, s["warnings"]
    if warned:
        assert str(f) in hint[0]
    # with header: false the first line is a sample and the warning is gone
    mapping.write_text("header: false\ntime: {column: 0, unit: s}\n"
                       "channels:\n  temperature_c: {column: 1}\n  gyro_x: {column: 2}\n")
    if warned:
        ds = read_datasets([f], mapping=mapping)
        assert ds[0].n_samples == 400
        assert not [w for w in summarize(ds)["warnings"] if "header" in w]


def test_info_noise_floor_says_per_sample_at_the_files_rate(tmp_path, capsys):
    f = write_parquet(Dataset([_one_run()]), tmp_path / "a.parquet")
    assert main(["info", str(f)]) == 0
    text = capsys.readouterr().out
    assert "noise floor: 1 sigma per sample at 10 Hz" in text
    two = Dataset([_one_run(rate=10.0, seed=1), _one_run(rate=1.0, seed=2)])
    s = summarize(two)
    assert s["noise_floor_basis"] == "1 sigma per sample at each run's rate (1 … 10 Hz)"
    # the floor is per sample: the same white noise at both rates gives the same floor
    # (a density would differ by √10); statistical tolerance of a 400-sample estimate
    assert s["outputs"][0]["noise_floor"] == pytest.approx(0.002, rel=0.15)


def test_calibrate_records_the_log_digest_and_no_default_preset(tmp_path):
    log = tmp_path / "board.ulg"
    assert main(["simulate", "fc-board", "--seed", "1", "--out", str(log)]) == 0
    out = tmp_path / "cal"
    assert main(["calibrate", str(log), "--out", str(out)]) == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["log_sha256"] == _sha(log)
    assert f"log sha256: {_sha(log)}" in (out / "report.txt").read_text()
    # each instance's comparison ran on the log's data: its resolved config names no
    # simulator preset and no tracking (the defaults of an empty config did not apply)
    resolved = sorted(out.glob("instances/*/config.resolved.yaml"))
    assert resolved
    for path in resolved:
        text = path.read_text()
        cfg = yaml.safe_load(text)
        assert cfg["data"]["preset"] is None and cfg["tracking"]["enabled"] is False, path
        assert "patent-gyro" not in text and "# data: a dataset passed by the caller" in text


def test_an_api_checkpoint_records_what_it_was_fitted_on(tmp_path):
    import thermonet
    from thermonet.training.parts import data_hash

    ds = toy_dataset(n_runs=3)
    path = write_parquet(ds, tmp_path / "toy.parquet")
    runs = read_datasets([path])
    est = thermonet.DriftEstimator("linear", ["dT"], train=thermonet.TrainConfig(max_epochs=3))
    est.fit([runs[0], runs[1]], val=runs[2])
    payload = torch.load(est.save(tmp_path / "m.pt"), weights_only=True)
    src = payload["extra"]["provenance"]["data"]
    assert src["runs"] == ["run0", "run1"] and src["val"] == ["run2"]
    assert src["data_hash"] == payload["extra"]["data_hash"] == data_hash(Dataset(list(runs)))
    # loaded back and saved again, the record is kept as it was
    back = thermonet.DriftEstimator.load(tmp_path / "m.pt")
    again = torch.load(back.save(tmp_path / "again.pt"), weights_only=True)
    assert again["extra"]["provenance"] == payload["extra"]["provenance"]
    assert again["extra"]["data_hash"] == payload["extra"]["data_hash"]
