"""The command line end to end, in-process through ``thermonet.cli.main`` (what the console
script calls); one test runs it as a separate process, where exit codes come from ``sys.exit``."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from conftest import REAL_DATA
from thermonet.cli import main

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@dataclass
class Result:
    returncode: int
    stdout: str
    stderr: str


@pytest.fixture
def thermonet(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
              ) -> Callable[..., Result]:
    """Run the CLI in this process; argparse's exits (help, usage) become return codes."""
    def run(*args: object, cwd: Path | None = None) -> Result:
        if cwd is not None:
            monkeypatch.chdir(cwd)
        capsys.readouterr()
        try:
            rc = main([str(a) for a in args])
        except SystemExit as exc:
            rc = exc.code if isinstance(exc.code, int) else 1
        out = capsys.readouterr()
        return Result(rc, out.out, out.err)
    return run


def test_the_console_entry_point_runs_as_a_process(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,temperature_c,gyro_x\n0,20,0.1\n1,21,abc\n")
    r = subprocess.run([sys.executable, "-m", "thermonet.cli", "info", str(bad)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1
    assert "bad.csv" in r.stderr and "gyro_x" in r.stderr


_RUN_WITH = """
import atexit, sys, tempfile, threading, time
from pathlib import Path

kept = tempfile.TemporaryDirectory()                    # removed by its weakref.finalize
Path(sys.argv[1]).write_text(kept.name)
atexit.register(lambda: print("exit handler ran", flush=False))
print("before the command", end=" ")                    # left in stdout's buffer
if sys.argv[2] == "thread":                             # still running when main returns
    threading.Thread(target=lambda: (time.sleep(0.5), print("thread done"))).start()
sys.argv = ["thermonet", *sys.argv[3:]]
from thermonet.cli import run
run()
"""


@pytest.mark.parametrize("other_thread", [False, True])
def test_the_process_ends_with_its_exit_handlers_run_and_its_output_flushed(
        tmp_path, other_thread):
    """``cli.run`` ends the process without freeing its modules, but as the interpreter
    would in all else: the command's exit code, exit handlers run (a temporary directory's
    finalizer among them), buffered output written; with another thread still running,
    the interpreter's own exit, which waits for it."""
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,temperature_c,gyro_x\n0,20,0.1\n1,21,abc\n")
    where = tmp_path / "tmpdir.txt"
    r = subprocess.run([sys.executable, "-c", _RUN_WITH, str(where),
                        "thread" if other_thread else "-", "info", str(bad)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 1 and "bad.csv" in r.stderr
    assert r.stdout.startswith("before the command")
    assert "exit handler ran" in r.stdout
    assert ("thread done" in r.stdout) == other_thread
    assert where.read_text() and not Path(where.read_text()).exists()


@pytest.mark.parametrize("args", [["--help"], ["simulate", "--help"], ["info", "--help"],
                                  ["compare", "--help"], ["train", "--help"],
                                  ["export", "--help"]])
def test_help_everywhere(thermonet, args):
    r = thermonet(*args)
    assert r.returncode == 0
    assert "usage: thermonet" in r.stdout


@pytest.mark.parametrize("args", [[], ["frobnicate"], ["simulate"],
                                  ["export", "x", "--format", "pdf", "--out", "y"]])
def test_usage_errors_exit_2(thermonet, args):
    assert thermonet(*args).returncode == 2


def test_bad_input_exits_1_with_one_line(thermonet, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,temperature_c,gyro_x\n0,20,0.1\n1,21,abc\n")
    r = thermonet("info", bad)
    assert r.returncode == 1
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1
    assert "bad.csv" in lines[0] and "gyro_x" in lines[0]
    r = thermonet("compare", tmp_path / "missing.yaml", "--out", tmp_path / "o")
    assert r.returncode == 1 and "missing.yaml" in r.stderr
    # a negative --workers is refused as the config's 'workers' is (fleet, learn and
    # station refuse theirs too), before any work: it was accepted
    r = thermonet("compare", "--workers", "-5", "--out", tmp_path / "o")
    assert r.returncode == 1 and "--workers -5: must be an integer >= 0" in r.stderr
    assert not (tmp_path / "o").exists()


def test_info_on_both_real_recordings(thermonet):
    pan = thermonet("info", REAL_DATA / "pan_tvac_gyro" / "TVCtest3_7_20.csv",
                    "--mapping", CONFIGS / "data" / "pan_tvac_gyro.yaml", "--json")
    assert pan.returncode == 0, pan.stderr
    summary = json.loads(pan.stdout)
    text = json.dumps(summary)
    assert "gyro_x" in text and "temp_raw" in text and "6250" in text
    bmi = thermonet("info", REAL_DATA / "bmi270_two_soaks" / "BMI_270_cold_test_.csv",
                    REAL_DATA / "bmi270_two_soaks" / "BMI_270_hot_test.csv",
                    "--mapping", CONFIGS / "data" / "bmi270.yaml")
    assert bmi.returncode == 0, bmi.stderr
    assert "12.98..13.30" in bmi.stdout and "47.22..49.36" in bmi.stdout
    assert "skipped malformed rows: 5" in bmi.stdout


@pytest.mark.slow
def test_simulate_then_info_then_compare_then_export(thermonet, tmp_path):
    sim = tmp_path / "pg.parquet"
    r = thermonet("simulate", "patent-gyro", "--runs", "3", "--seed", "7", "--out", sim)
    assert r.returncode == 0, r.stderr
    assert sim.is_file()
    r = thermonet("info", sim)
    assert r.returncode == 0, r.stderr
    for axis in ("gyro_x", "gyro_y", "gyro_z"):
        assert axis in r.stdout
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data: {{paths: ['{sim}']}}\n"
                   "train: {max_epochs: 30, patience: 5, max_train_samples: 3000}\n"
                   # one family ships whole: its training run is where the export is logged
                   "selection: {per_axis: false}\n"
                   "families:\n"
                   "  - {name: cubic, family: poly, inputs: [dT], params: {degree: 3}}\n"
                   "  - {name: rbf, family: rbf, inputs: [dT, dT2], params: {n_centres: 8}}\n")
    r = thermonet("compare", cfg, "--out", tmp_path / "out", "--tracking-uri",
                  f"sqlite:///{tmp_path / 'mlflow.db'}", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "chosen:" in r.stdout
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    assert res["chosen"] in ("cubic", "rbf")
    r = thermonet("export", tmp_path / "out", "--format", "onnx", "--out", tmp_path / "m.onnx",
                  "--tracking-uri", f"sqlite:///{tmp_path / 'mlflow.db'}", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "m.onnx").stat().st_size > 500
    # the exported file is logged to the family's training run, as a file and as an ONNX model
    import mlflow

    client = mlflow.tracking.MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'mlflow.db'}")
    run_id = res["families"][res["chosen"]]["mlflow_run_id"]
    logged = {a.path for a in client.list_artifacts(run_id, "onnx")}
    assert logged == {"onnx/m.onnx"}
    models = client.search_logged_models(
        experiment_ids=[client.get_run(run_id).info.experiment_id])
    # the MLflow model 'model' of the family's run (runs:/<id>/model), and compare's own run's
    # (the chosen model, logged by the tracked comparison)
    assert sorted((m.name, m.source_run_id) for m in models) == sorted(
        [("model", run_id), ("model", res["mlflow_run_id"])])
    # an MLflow run id is a source too: the checkpoint artifact is fetched from the store
    r = thermonet("export", run_id, "--format", "c", "--out", tmp_path / "m.h",
                  "--tracking-uri", f"sqlite:///{tmp_path / 'mlflow.db'}", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "thermonet_compensate" in (tmp_path / "m.h").read_text()
    r = thermonet("export", "0" * 32, "--format", "c", "--out", tmp_path / "n.h",
                  "--tracking-uri", f"sqlite:///{tmp_path / 'mlflow.db'}", cwd=tmp_path)
    assert r.returncode == 1 and "0" * 32 in r.stderr
    assert not (tmp_path / "n.h").exists()
    r = thermonet("export", tmp_path / "out", "--family", "cubic", "--format", "px4-params",
                  "--out", tmp_path / "noid.params")
    assert r.returncode == 1 and "--device-id" in r.stderr
    assert not (tmp_path / "noid.params").exists()
    r = thermonet("export", tmp_path / "out", "--family", "cubic", "--format", "px4-params",
                  "--device-id", "2490378", "--out", tmp_path / "tc.params")
    assert r.returncode == 0, r.stderr
    assert "1\t1\tTC_G0_ID\t2490378\t6" in (tmp_path / "tc.params").read_text()
    r = thermonet("export", tmp_path / "out", "--family", "cubic", "--format", "ardupilot-params",
                  "--out", tmp_path / "tcal.parm")
    assert r.returncode == 0, r.stderr
    text = (tmp_path / "tcal.parm").read_text()
    # a gyro model leaves the accelerometer's calibration alone
    assert "INS_TCAL1_GYR1_X," in text and "INS_TCAL1_ACC" not in text
    r = thermonet("export", tmp_path / "out", "--family", "rbf", "--format", "px4-params",
                  "--device-id", "2490378", "--out", tmp_path / "p.params")
    assert r.returncode == 1 and "one input, dT or T" in r.stderr
    assert not (tmp_path / "p.params").exists()


def test_train_names_itself_in_its_banner(thermonet, tmp_path):
    """``thermonet train`` printed ``thermonet compare: …`` as its first line."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data: {preset: accel-ramp}\nfamilies: [{name: cubic, family: poly, "
                   "params: {degree: 3}}, {name: lin, family: linear}]\n")
    r = thermonet("train", cfg, "--family", "lin", "--out", tmp_path / "o", "--no-track",
                  "--no-plots")
    assert r.returncode == 0, r.stderr
    first = r.stderr.splitlines()[0]                # the progress lines go to stderr
    assert first.startswith("thermonet train: accel-ramp (1 run, outputs acc_x)"), first
