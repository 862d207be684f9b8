"""Hostile input: every crafted input gets its one documented behaviour.

The corpus (:data:`CASES`) is a table ``input → exit code → message pattern →
paths that must not exist afterwards``, run through the in-process CLI entry
point; a new input path joins it with one row.  Subprocesses are used only
where a real process is the point: signals and concurrent stores.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import torch

from conftest import toy_dataset
from thermonet.cli import main
from thermonet.data.io import write_parquet
from thermonet.data.parquet_format import METADATA_KEY
from thermonet.training.checkpoint import seal_checkpoint

ROOT = Path(__file__).resolve().parent.parent

# The bomb ("billion laughs"), 421 bytes here: 10 chained anchors of 9 aliases each,
# 9**9 ≈ 387 million leaves if expanded.
BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{n}: &{n} [{', '.join(['*' + p] * 9)}]\n"
    for p, n in zip("abcdefghi", "bcdefghij", strict=True))


def _cfg(tmp: Path, body: str, name: str = "c.yaml") -> Path:
    p = tmp / name
    p.write_text(body)
    return p


def _tiny(tmp: Path, extra: str = "") -> str:
    data = write_parquet(toy_dataset(n_runs=3), tmp / "toy.parquet")
    return (f"data: {{paths: ['{data}']}}\ntrain: {{max_epochs: 5, patience: 2}}\n"
            f"families:\n  - {{name: lin, family: linear, inputs: [dT]}}\n{extra}")


def _corrupt_parquet(tmp: Path, edit: Callable[[dict], None]) -> Path:
    path = write_parquet(toy_dataset(n_runs=1), tmp / "bad.parquet")
    table = pq.read_table(path)
    blob = json.loads(table.schema.metadata[METADATA_KEY.encode()])
    edit(blob)
    pq.write_table(table.replace_schema_metadata({METADATA_KEY: json.dumps(blob)}), path)
    return path


def _bool_column(tmp: Path) -> Path:
    import pyarrow as pa

    path = write_parquet(toy_dataset(n_runs=1), tmp / "bool.parquet")
    table = pq.read_table(path)
    i = table.column_names.index("temperature_c")
    flags = pa.array([v > 0 for v in table.column(i).to_pylist()])
    table = table.set_column(i, "temperature_c", flags).replace_schema_metadata(
        table.schema.metadata)
    pq.write_table(table, path)
    return path


def _compare(cfg: Path, tmp: Path, *more: str) -> list[str]:
    return ["compare", str(cfg), "--out", str(tmp / "out"), "--tracking-uri",
            f"sqlite:///{tmp / 'mlflow.db'}", "-q", *more]


def _set(path: str, value: object) -> Callable[[dict], None]:
    def edit(blob: dict) -> None:
        keys = path.split(".")
        target = blob
        for k in keys[:-1]:
            target = target[int(k)] if isinstance(target, list) else target[k]
        if value is KeyError:
            del target[keys[-1]]
        else:
            target[keys[-1]] = value
    return edit


# (id, argv builder, exit code, stderr pattern, paths (relative to tmp) that must not exist)
CASES: list[tuple[str, Callable[[Path], list[str]], int, str, tuple[str, ...]]] = [
    ("config-alias-bomb", lambda t: _compare(_cfg(t, "meta:\n" + "".join(
        "  " + ln + "\n" for ln in BOMB.splitlines())), t),
     1, r"c\.yaml: YAML anchor '&a' refused .*\(line 2\)", ("out", "mlflow.db")),
    ("config-alias-in-train", lambda t: _compare(_cfg(t, _tiny(t).replace(
        "inputs: [dT]}", "inputs: [dT], train: {max_epochs: &e 5}}")), t),
     1, r"c\.yaml: YAML anchor '&e' refused", ("out", "mlflow.db")),
    ("mapping-alias-bomb", lambda t: ["info", str(_cfg(t, "a,b\n1,2\n", "x.csv")),
                                      "--mapping", str(_cfg(t, "meta:\n" + "".join(
                                          "  " + ln + "\n" for ln in BOMB.splitlines()),
                                          "m.yaml"))],
     1, r"m\.yaml.*YAML anchor '&a' refused", ()),
    ("family-name-escapes", lambda t: _compare(_cfg(t, _tiny(t).replace(
        "name: lin", "name: ../../x")), t),
     1, r"c\.yaml: key 'families\[0\]\.name': '\.\./\.\./x' is not a safe family name",
     ("out", "mlflow.db", "../x.pt")),
    ("family-name-300", lambda t: _compare(_cfg(t, _tiny(t).replace(
        "name: lin", "name: " + "n" * 300)), t),
     1, r"key 'families\[0\]\.name'.*at most 64", ("out", "mlflow.db")),
    ("train-unknown-key", lambda t: _compare(_cfg(t, _tiny(t).replace(
        "inputs: [dT]}", "inputs: [dT], train: {bogus: 1}}")), t),
     1, r"c\.yaml: key 'families\[0\]\.train\.bogus': unknown key", ("out", "mlflow.db")),
    ("train-wrong-type", lambda t: _compare(_cfg(t, _tiny(t).replace(
        "inputs: [dT]}", "inputs: [dT], train: {max_epochs: hot}}")), t),
     1, r"c\.yaml: key 'families\[0\]\.train\.max_epochs'", ("out", "mlflow.db")),
    ("inputs-twice", lambda t: _compare(_cfg(t, _tiny(t).replace(
        "inputs: [dT]}", "inputs: [dT, dT]}")), t),
     1, r"c\.yaml: key 'families\[0\]\.inputs'.*twice", ("out", "mlflow.db")),
    ("target-mode-unknown", lambda t: _compare(_cfg(t, _tiny(t, "target: {gyro: bogus}\n")), t),
     1, r"c\.yaml: key 'target\.gyro': 'bogus' is not one of channel, zero, at-t-ref",
     ("out", "mlflow.db")),
    ("baseline-unknown", lambda t: _compare(_cfg(t, _tiny(t, "baseline: nope\n")), t),
     1, r"c\.yaml: key 'baseline': no family named 'nope'", ("out", "mlflow.db")),
    ("empty-config", lambda t: _compare(_cfg(t, "# nothing\n"), t),
     1, r"c\.yaml: empty config file", ("out", "mlflow.db")),
    ("config-is-directory", lambda t: _compare(t, t),
     1, r"is a directory, not a config file", ("out", "mlflow.db")),
    ("config-is-dev-null", lambda t: _compare(Path(os.devnull), t),
     1, r"/dev/null: is a device, not a config file", ("out", "mlflow.db")),
    ("config-is-fifo", lambda t: (os.mkfifo(t / "fifo.yaml"), _compare(t / "fifo.yaml", t))[1],
     1, r"fifo\.yaml: is a FIFO, not a config file", ("out", "mlflow.db")),
    ("config-runs-bound", lambda t: _compare(_cfg(t, "data: {runs: 100000}\n"), t),
     1, r"c\.yaml: key 'data\.runs': 100000 is not in 1\.\.1000", ("out", "mlflow.db")),
    ("config-runs-zero", lambda t: _compare(_cfg(t, "data: {runs: 0}\n"), t),
     1, r"c\.yaml: key 'data\.runs': 0 is not in", ("out", "mlflow.db")),
    ("simulate-runs-bound", lambda t: ["simulate", "patent-gyro", "--runs", "100000", "--out",
                                       str(t / "s.parquet")],
     1, r"--runs 100000: not in 1\.\.1000", ("s.parquet",)),
    ("out-uncreatable-file", lambda t: ["simulate", "accel", "--runs", "1", "--out",
                                        "/proc/thermonet-h9.parquet"],
     1, r"^thermonet: error: /proc/thermonet-h9\.parquet: No such file", ()),
    ("out-uncreatable-dir", lambda t: ["compare", "--out", "/proc/thermonet-h9", "--no-track"],
     1, r"^thermonet: error: /proc/thermonet-h9: cannot create the output directory", ()),
    ("out-is-a-file", lambda t: ["compare", "--out", str(_cfg(t, "x", "f.txt")), "--no-track"],
     1, r"f\.txt: --out must be a directory", ()),
    ("info-directory", lambda t: ["info", str(t)], 1, r"is a directory, not a file", ()),
    ("info-fifo", lambda t: (os.mkfifo(t / "f.csv"), ["info", str(t / "f.csv")])[1],
     1, r"f\.csv: is a FIFO", ()),
    ("info-dev-null", lambda t: ["info", os.devnull], 1, r"/dev/null: is a device", ()),
    ("parquet-units-list", lambda t: ["info", str(_corrupt_parquet(
        t, _set("runs.0.units", ["deg/s"])))],
     1, r"bad\.parquet: corrupt 'thermonet' metadata: field 'runs\[0\]\.units'", ()),
    ("parquet-runs-string", lambda t: ["info", str(_corrupt_parquet(t, _set("runs", "run0")))],
     1, r"bad\.parquet: corrupt 'thermonet' metadata: field 'runs'", ()),
    ("parquet-missing-key", lambda t: ["info", str(_corrupt_parquet(
        t, _set("runs.0.device_id", KeyError)))],
     1, r"field 'runs\[0\]\.device_id': missing", ()),
    ("parquet-rate-text", lambda t: ["info", str(_corrupt_parquet(
        t, _set("runs.0.sample_rate_hz", "fast")))],
     1, r"bad\.parquet: 'thermonet' metadata field 'runs\[0\]\.sample_rate_hz'.*not a finite", ()),
    ("parquet-rate-tiny", lambda t: ["info", str(_corrupt_parquet(
        t, _set("runs.0.sample_rate_hz", 1e-300)))],
     1, r"sample_rate_hz.*1e-300 is not a finite number in", ()),
    ("parquet-rate-negative", lambda t: ["info", str(_corrupt_parquet(
        t, _set("runs.0.sample_rate_hz", -1.0)))],
     1, r"sample_rate_hz.*-1\.0 is not a finite number in", ()),
    ("parquet-axis-newline", lambda t: ["info", str(_corrupt_parquet(
        t, _set("runs.0.outputs", ["gyro_x\n"])))],
     1, r"runs\[0\]\.outputs.*is not an axis name", ()),
    ("parquet-bool-column", lambda t: ["info", str(_bool_column(t))],
     1, r"bool\.parquet, column 'temperature_c': a boolean column", ()),
]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_corpus(case, tmp_path, capsys, monkeypatch):
    _, build, code, pattern, absent = case
    monkeypatch.chdir(tmp_path)
    argv = build(tmp_path)
    assert main(argv) == code
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    assert re.search(pattern, err), err
    for rel in absent:
        assert not (tmp_path / rel).exists(), rel
    assert not list(tmp_path.glob(".out.*")), "a staging directory was left"


# ------------------------------------------------------------- a real comparison to attack
@pytest.fixture(scope="module")
def compared(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("cmp")
    cfg = _cfg(tmp, _tiny(tmp))
    assert main(["compare", str(cfg), "--out", str(tmp / "out"), "--no-track", "-q"]) == 0
    return tmp


def _checkpoint(compared: Path) -> dict:
    return torch.load(compared / "out" / "models" / "lin.pt", weights_only=True)


C_PAYLOAD = ('gyro_x"}\n#include <stdlib.h>\n__attribute__((constructor)) static void p(void)'
             '{system("touch MARKER");}\n#define X {"')


@pytest.mark.parametrize("fmt", ["c", "onnx"])
def test_crafted_axis_name_never_reaches_generated_code(compared, tmp_path, capsys, fmt):
    marker = tmp_path / "pwned"
    payload = _checkpoint(compared)
    payload["outputs"] = [C_PAYLOAD.replace("MARKER", str(marker))]
    torch.save(payload, tmp_path / "evil.pt")
    seal_checkpoint(tmp_path / "evil.pt")  # sealed again: the checks below, not the digest
    out = tmp_path / ("m.h" if fmt == "c" else "m.onnx")
    assert main(["export", str(tmp_path / "evil.pt"), "--format", fmt, "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and re.search(r"evil\.pt: key 'outputs'\[0\]: .* is not an axis name",
                                         err), err
    assert not out.exists() and not marker.exists()
    assert not list(tmp_path.glob("*.tmp")) and not list(tmp_path.glob(".m.*"))


@pytest.mark.parametrize("key,value,pattern", [
    ("outputs", ["gyro_x\n"], r"key 'outputs'\[0\]: 'gyro_x\\n' is not an axis name"),
    ("outputs", ["gyro_x", "gyro_x"], r"key 'outputs': 'gyro_x' given twice"),
    ("family", "os.system", r"key 'family': 'os\.system' is not a model family"),
    ("signals", ["temperature_c */"], r"key 'signals'\[0\]"),
    ("extra.units", {"gyro_x": "deg/s */ x"}, r"key 'extra\.units'\['gyro_x'\]: .* not a unit"),
    ("extra.device_id", "a\nb", r"key 'extra\.device_id'"),
    ("spec.t_ref", float("nan"), r"key 'spec\.t_ref': nan is not a finite number"),
    ("range", None, r"trained range of signal 'temperature_c' is \[10, -10\]"),
    ("state.target_code", 7, r"buffer 'target_code' holds 7, not a target mode code"),
    ("state.compensate", 0.5, r"buffer 'compensate' is \[0\.5\], expected 0 or 1"),
    ("state.y_offset", float("inf"), r"buffer 'y_offset' holds a non-finite value"),
])
def test_crafted_checkpoint_values_refused(compared, tmp_path, capsys, key, value, pattern):
    payload = _checkpoint(compared)
    if key == "range":
        payload["state_dict"]["sig_lo"] = torch.tensor([10.0])
        payload["state_dict"]["sig_hi"] = torch.tensor([-10.0])
    elif key.startswith("state."):  # a target buffer (thermonet.features.target) of the model
        state = payload["state_dict"]
        state[key[6:]] = torch.full_like(state[key[6:]], value)
    elif "." in key:
        outer, inner = key.split(".")
        payload[outer][inner] = value
    else:
        payload[key] = value
    torch.save(payload, tmp_path / "bad.pt")
    seal_checkpoint(tmp_path / "bad.pt")  # sealed again: the checks below, not the digest
    assert main(["export", str(tmp_path / "bad.pt"), "--format", "c",
                 "--out", str(tmp_path / "m.h")]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and re.search(r"bad\.pt: " + pattern, err), err
    assert not (tmp_path / "m.h").exists()


def test_output_directory_is_whole_refused_or_replaced(compared, tmp_path, capsys):
    out = compared / "out"
    results = json.loads((out / "results.json").read_text())
    sha = results["families"]["lin"]["checkpoint_sha256"]
    assert re.fullmatch(r"[0-9a-f]{64}", sha)
    assert results["families"]["lin"]["checkpoint"] == str(out / "models" / "lin.pt")
    cfg = compared / "c.yaml"
    # a previous comparison is refused without --overwrite, and left as it was
    assert main(["compare", str(cfg), "--out", str(out), "--no-track", "-q"]) == 1
    assert "pass --overwrite" in capsys.readouterr().err
    assert json.loads((out / "results.json").read_text())["families"]["lin"][
        "checkpoint_sha256"] == sha
    # a non-empty directory that is not a comparison is refused, untouched
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    assert main(["compare", str(cfg), "--out", str(other), "--no-track", "-q"]) == 1
    assert "holds no thermonet comparison" in capsys.readouterr().err
    assert sorted(p.name for p in other.iterdir()) == ["notes.txt"]
    # a stale checkpoint dropped into the directory is not listed, so never exported
    (out / "models" / "stale.pt").write_bytes((out / "models" / "lin.pt").read_bytes())
    assert main(["export", str(out), "--family", "stale", "--format", "c",
                 "--out", str(tmp_path / "s.h")]) == 1
    assert "no family 'stale'" in capsys.readouterr().err
    # --overwrite replaces it whole: the stale file is gone with the old comparison
    assert main(["compare", str(cfg), "--out", str(out), "--no-track", "-q", "--overwrite"]) == 0
    assert not (out / "models" / "stale.pt").exists()
    assert not list(compared.glob(".out.*"))


def test_export_verifies_checkpoint_hash(compared, tmp_path, capsys):
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(compared / "out", out)
    ckpt = out / "models" / "lin.pt"
    payload = torch.load(ckpt, weights_only=True)
    payload["extra"]["label"] = "lin"
    payload["epoch"] = 999  # same model, different bytes: another comparison's file
    torch.save(payload, ckpt)
    assert main(["export", str(out), "--family", "lin", "--format", "c",
                 "--out", str(tmp_path / "m.h")]) == 1
    assert re.search(r"lin\.pt: content does not match the SHA-256",
                     capsys.readouterr().err)
    res = json.loads((out / "results.json").read_text())
    del res["families"]["lin"]["checkpoint_sha256"]
    (out / "results.json").write_text(json.dumps(res))
    assert main(["export", str(out), "--family", "lin", "--format", "c",
                 "--out", str(tmp_path / "m.h")]) == 1
    assert "records no checkpoint_sha256" in capsys.readouterr().err
    assert not (tmp_path / "m.h").exists()


def test_export_never_logs_where_the_checkpoint_says(compared, tmp_path, caplog, monkeypatch):
    import mlflow

    from thermonet.tracking import Tracker

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    local = f"sqlite:///{tmp_path.resolve() / 'mlflow.db'}"
    with Tracker(uri=local).run("family") as run_id:  # the working directory's store
        pass
    payload = _checkpoint(compared)
    payload["config"]["tracking"]["uri"] = "http://192.0.2.1:5000"  # TEST-NET-1: unreachable
    payload["extra"]["mlflow_run_id"] = run_id
    torch.save(payload, tmp_path / "k.pt")
    seal_checkpoint(tmp_path / "k.pt")  # sealed again: the checks below, not the digest
    assert main(["export", str(tmp_path / "k.pt"), "--format", "onnx",
                 "--out", str(tmp_path / "m.onnx")]) == 0
    assert "192.0.2.1" not in " ".join(r.getMessage() for r in caplog.records)
    client = mlflow.MlflowClient(tracking_uri=local)
    assert [a.path for a in client.list_artifacts(run_id, "onnx")] == ["onnx/m.onnx"]


def test_export_to_a_store_that_does_not_exist_warns_and_creates_none(compared, tmp_path,
                                                                        caplog, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    payload = _checkpoint(compared)
    payload["extra"]["mlflow_run_id"] = "0123456789abcdef0123456789abcdef"
    torch.save(payload, tmp_path / "k.pt")
    seal_checkpoint(tmp_path / "k.pt")
    assert main(["export", str(tmp_path / "k.pt"), "--format", "onnx",
                 "--out", str(tmp_path / "m.onnx")]) == 0
    store = f"sqlite:///{tmp_path.resolve() / 'mlflow.db'}"
    assert [r.getMessage() for r in caplog.records if r.levelname == "WARNING"] == [
        f"wrote {tmp_path / 'm.onnx'}; not logged to MLflow run "
        f"0123456789abcdef0123456789abcdef: no tracking store at {store} (give --tracking-uri)"]
    assert not (tmp_path / "mlflow.db").exists()     # MLflow would have created an empty one


def test_runtime_refuses_hostile_metadata_and_csv(compared, tmp_path, capsys):
    import onnx

    sys.path.insert(0, str(ROOT / "export"))
    try:
        import thermonet_runtime as rt
    finally:
        sys.path.pop(0)
    model = tmp_path / "m.onnx"
    assert main(["export", str(compared / "out"), "--family", "lin", "--format", "onnx",
                 "--out", str(model), "--tracking-uri", f"sqlite:///{tmp_path / 'x.db'}"]) == 0
    for key, value, pattern in [("signal_units", "{not json", "'signal_units' is not valid JSON"),
                                ("output_units", '["deg/s"]', "'output_units' is not a mapping"),
                                ("signals", "3", "'signals' is not a non-empty list"),
                                ("outputs", '["gyro_x\\"}"]', "'outputs'.* is not a valid name")]:
        proto = onnx.load(str(model))
        for prop in proto.metadata_props:
            if prop.key == key:
                prop.value = value
        bad = tmp_path / f"bad_{key}.onnx"
        onnx.save(proto, str(bad))
        with pytest.raises(rt.RuntimeInputError, match=pattern):
            rt.Compensator(bad)
    header = "temperature_c,gyro_x\n"
    for name, data, pattern in [("bom.csv", b"\xef\xbb\xbf" + header.encode() + b"20,0.1\n",
                                 "byte-order mark"),
                                ("semi.csv", b"temperature_c;gyro_x\n20;0.1\n", "separated by ';'"),
                                ("latin.csv", header.encode() + b"20,0.1\xe9\n", "not UTF-8")]:
        (tmp_path / name).write_bytes(data)
        capsys.readouterr()
        assert rt.main([str(model), str(tmp_path / name), "--out", str(tmp_path / "o.csv")]) == 1
        assert re.search(f"{name}: .*{pattern}", capsys.readouterr().err)
    os.mkfifo(tmp_path / "fifo.csv")
    assert rt.main([str(model), str(tmp_path / "fifo.csv"), "--out", str(tmp_path / "o.csv")]) == 1
    assert "fifo.csv: is a FIFO, not a CSV file" in capsys.readouterr().err
    assert not (tmp_path / "o.csv").exists()


def test_bad_csv_messages(compared, tmp_path, capsys):
    """The runtime's CSV messages name the real problem (checked on stderr)."""
    sys.path.insert(0, str(ROOT / "export"))
    try:
        import thermonet_runtime as rt
    finally:
        sys.path.pop(0)
    model = tmp_path / "m.onnx"
    assert main(["export", str(compared / "out"), "--family", "lin", "--format", "onnx",
                 "--out", str(model), "--tracking-uri", f"sqlite:///{tmp_path / 'x.db'}"]) == 0
    capsys.readouterr()
    (tmp_path / "semi.csv").write_text("temperature_c;gyro_x\n20;0.1\n")
    assert rt.main([str(model), str(tmp_path / "semi.csv"), "--out", str(tmp_path / "o.csv")]) == 1
    assert "separated by ';'" in capsys.readouterr().err
    assert rt.main([str(model), str(tmp_path), "--out", str(tmp_path / "o.csv")]) == 1
    assert "is a directory, not a CSV file" in capsys.readouterr().err


# ------------------------------------------------------------- real processes
def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def _start(cfg: Path, out: Path, db: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "thermonet.cli", "compare", str(cfg),
                             "--out", str(out), "--tracking-uri", f"sqlite:///{db}", "-q"],
                            env=_env(), cwd=cfg.parent, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _running_runs(db: Path) -> int:
    """RUNNING runs in the store, read-only (never creating or migrating it meanwhile)."""
    import sqlite3

    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1.0)
        try:
            return int(con.execute("select count(*) from runs where status = 'RUNNING'")
                       .fetchone()[0])
        finally:
            con.close()
    except sqlite3.Error:  # not created yet, or being migrated
        return 0


def _wait_running(db: Path, proc: subprocess.Popen, timeout_s: float = 300.0) -> None:
    """Until the comparison has an open nested run (a family is being fitted)."""
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            if _running_runs(db) >= 2:
                return
            time.sleep(0.5)
        pytest.fail("the comparison never started a family run")
    except BaseException:
        proc.kill()
        proc.communicate()
        raise


def _statuses(db: Path) -> list[str]:
    import mlflow

    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{db}")
    exp = client.get_experiment_by_name("thermonet")
    return sorted(r.info.status for r in client.search_runs([exp.experiment_id]))


@pytest.fixture
def endless(tmp_path) -> Path:
    # a family trained by gradient steps (a linear model's least squares is final: no epochs)
    return _cfg(tmp_path, _tiny(tmp_path).replace(
        "max_epochs: 5, patience: 2", "max_epochs: 1000000, patience: 1000000, "
        "min_delta: 0.0, optimizer: adam, lr: 1.0e-9").replace(
        "{name: lin, family: linear, inputs: [dT]}", "{name: fz, family: ts-fuzzy, inputs: [dT]}"))


def test_a_signal_whose_exception_was_lost_still_stops_the_run(endless, tmp_path):
    """Python swallows an exception raised by a signal handler inside a garbage-collection
    callback ("Exception ignored in ..."): the handler also records the signal, and the
    training loop polls the record each epoch.  Here the record is made from another thread
    (no exception raised at all), as if the handler's raise had been lost."""
    import threading

    from thermonet.core.errors import Interrupted, clear_interrupt, request_interrupt
    from thermonet.training.config import load_config
    from thermonet.workflows.compare import run_compare

    cfg = load_config(endless)
    timer = threading.Timer(3.0, request_interrupt, args=(int(signal.SIGTERM),))
    timer.start()
    try:
        with pytest.raises(Interrupted) as err:
            run_compare(cfg, tmp_path / "out", track=False, quiet=True, plots=False)
    finally:
        timer.cancel()
        clear_interrupt()
    assert err.value.signum == signal.SIGTERM
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("signum,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupt_one_line_runs_killed_out_untouched(endless, tmp_path, signum, code):
    db = tmp_path / "mlflow.db"
    proc = _start(endless, tmp_path / "out", db)
    _wait_running(db, proc)
    proc.send_signal(signum)
    try:
        stdout, stderr = proc.communicate(timeout=120)
    finally:  # a child that ignored the signal must not outlive the test
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == code, stderr
    assert stderr.strip() == (f"thermonet: interrupted by {signal.Signals(signum).name}; "
                              "stopped (outputs are written whole or not at all)")
    assert _statuses(db) == ["KILLED", "KILLED"]
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out.*"))


def test_sigkill_leaves_running_runs_that_a_later_tracker_tidies(endless, tmp_path):
    from thermonet.tracking import tidy_orphaned_runs

    db = tmp_path / "mlflow.db"
    proc = _start(endless, tmp_path / "out", db)
    _wait_running(db, proc)
    proc.kill()
    proc.communicate(timeout=60)
    assert _statuses(db) == ["RUNNING", "RUNNING"]
    assert not (tmp_path / "out").exists()  # only a hidden .out.*.partial may be left
    ended = tidy_orphaned_runs(f"sqlite:///{db}")
    assert len(ended) == 2 and _statuses(db) == ["KILLED", "KILLED"]
    assert tidy_orphaned_runs(f"sqlite:///{db}") == []


def _comparisons_at_once(tmp_path: Path, rounds: tuple[str, ...]) -> None:
    """Two command-line comparisons started together on one MLflow store, once per round
    (the first on a store neither has created yet): each exits 0 and every run FINISHED."""
    cfg = _cfg(tmp_path, _tiny(tmp_path))
    db = tmp_path / "mlflow.db"
    for round_ in rounds:
        procs = [_start(cfg, tmp_path / f"out-{round_[0]}{i}", db) for i in range(2)]
        for p in procs:
            _, stderr = p.communicate(timeout=300)
            assert p.returncode == 0, f"{round_}: {stderr}"
    # 2 comparisons a round × (parent + one family)
    assert _statuses(db) == ["FINISHED"] * (4 * len(rounds))


def test_two_comparisons_at_once_on_a_new_store(tmp_path):
    """The fast twin of the test below: the new store's round alone (the race on creating
    and migrating the store)."""
    _comparisons_at_once(tmp_path, ("new store",))


@pytest.mark.slow
def test_two_comparisons_at_once_on_a_new_then_an_existing_store(tmp_path):
    """Both rounds, four processes (`make test-slow`)."""
    _comparisons_at_once(tmp_path, ("new store", "existing store"))


def test_c_escaping_round_trips_through_a_compiler(tmp_path):
    """Defence in depth: an escaped name is inert in a comment and exact in a string literal."""
    import shutil

    from thermonet.core.names import c_comment, c_string

    nasty = 'gyro_x"}\n*/ system("x"); /* ??= \\ é\t' + C_PAYLOAD
    assert "*/" not in c_comment(nasty) and "/*" not in c_comment(nasty)
    assert "\n" not in c_comment(nasty)
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.fail("no C compiler: the C header export checks need one")
    src = tmp_path / "t.c"
    src.write_text(f"#include <stdio.h>\n/* {c_comment(nasty)} */\n"
                   f"int main(void) {{ fputs({c_string(nasty)}, stdout); return 0; }}\n")
    subprocess.run([cc, "-std=c99", "-Wall", "-Werror", "-o", str(tmp_path / "t"), str(src)],
                   check=True, capture_output=True)
    out = subprocess.run([str(tmp_path / "t")], check=True, capture_output=True).stdout
    assert out == nasty.encode("utf-8")
