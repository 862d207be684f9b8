"""Hostile inputs, round three, part A: paths and output directories.

* Names read from data (device ids, instance names, channel names) never become paths as
  they are: ``thermonet.core.names.path_component`` makes each one a single safe file name, and
  nothing is ever written outside ``--out``.
* ``fleet`` and ``calibrate`` refuse a non-empty ``--out`` that is not their own previous
  output, replace a previous one only with ``--overwrite`` — thermonet's own files only, the
  user's files beside them are kept — and build it whole in a staging directory (an
  interrupted ``calibrate`` leaves nothing half-written).  ``fleet --no-plots`` writes no PNG.
* A fleet unit with 0 or 1 samples (or any data its own validation refuses) fails alone,
  named; the others are calibrated.
* ``calibrate`` / ``info`` on a directory or a FIFO say what the path is.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from thermonet.cli import main
from thermonet.core.errors import InputError, ThermonetError
from thermonet.core.names import inside, path_component, path_components
from thermonet.core.outdir import KINDS
from thermonet.core.recording import OUTPUT_NAME, Dataset, Recording
from thermonet.data.logs.writers import write_log
from thermonet.sim.fcboard import simulate_board
from thermonet.training.config import CompareConfig, FamilyConfig
from thermonet.workflows.calibrate import calibrate
from thermonet.workflows.calibrate_files import EKF_FILE
from thermonet.workflows.fleet import FleetOptions, run_fleet
from thermonet.workflows.fleet_units import sources_from_dataset

#: Device ids a fleet file may hold that must not become paths as they are.
HOSTILE_IDS = ("../../../ESCAPE", "/tmp/abs-evil", "..", "a/../../b", "C:\\win\\x", "con")


def _unit_runs(device: str, *, n_runs: int = 2, gain: float = 1.0, seed: int = 0
               ) -> list[Recording]:
    """A toy gyro unit: 2-hour ramps −20 → 50 °C at 1/6 Hz, a quadratic drift."""
    rng = np.random.default_rng(seed)
    runs = []
    for k in range(n_runs):
        t = np.arange(0.0, 7200.0, 6.0)
        temp = -20.0 + 70.0 * t / t[-1] + 0.3 * k
        d = temp + 20.0
        drift = gain * (0.05 + 0.01 * d - 2e-4 * d ** 2)
        runs.append(Recording(
            time_s=t, temperature_c=temp,
            outputs={"gyro_x": drift + rng.normal(0, 0.002, t.size)},
            units={"gyro_x": "deg/s", "temperature_c": "degC"},
            device_id=device, run_id=f"run{k}", sample_rate_hz=1 / 6.0))
    return runs


def _fleet_csv(path: Path, devices: list[str]) -> Path:
    frames = []
    for i, dev in enumerate(devices):
        for r in _unit_runs(dev, seed=i):
            frames.append(pd.DataFrame({"device": dev, "run": r.run_id, "time_s": r.time_s,
                                        "temperature_c": r.temperature_c,
                                        "gyro_x": r.outputs["gyro_x"]}))
    pd.concat(frames).to_csv(path, index=False)
    return path


def _config(path: Path, data: Path) -> Path:
    path.write_text(f"data: {{paths: ['{data.as_posix()}']}}\n"
                    "families:\n  - {name: cubic, family: poly, inputs: [dT], "
                    "params: {degree: 3}}\n"
                    "split: {strategy: train-then-verify}\n"
                    "tracking: {enabled: false}\n")
    return path


def _tree(root: Path) -> set[str]:
    return {p.relative_to(root).as_posix() for p in root.rglob("*")}


def _one_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


# ------------------------------------------------------------------ the helper
@pytest.mark.parametrize("name", [*HOSTILE_IDS, ".", "", ".hidden", "-rf", "x\x00y", "unit\n",
                                  "nul.txt", "COM1", "a" * 300, "dots.", "ü-ünit", "a b"])
def test_path_component_is_one_safe_file_name(tmp_path: Path, name: str) -> None:
    comp = path_component(name)
    assert comp not in ("", ".", "..")
    assert "/" not in comp and "\\" not in comp and "\x00" not in comp
    assert not comp.startswith((".", "-")) and not comp.endswith(".")
    assert comp.isascii() and comp.isprintable() and len(comp) <= 64
    assert comp.split(".")[0].lower() not in ("con", "nul", "com1")
    assert comp == path_component(name)                       # deterministic
    target = inside(tmp_path, comp)
    assert target.parent == tmp_path
    target.mkdir()                                            # really creatable, inside
    assert target.resolve().is_relative_to(tmp_path.resolve())


@pytest.mark.parametrize("name", ["toy-u000", "patent-gyro-u012", "BMI_270", "gyro0", "a.b"])
def test_safe_names_are_kept_as_they_are(name: str) -> None:
    assert path_component(name) == name


def test_path_components_keep_different_names_apart() -> None:
    names = ["Unit", "unit", "a/b", "a_b", "a?b", "../x", "x"]
    comps = path_components(names)
    assert list(comps) == names
    assert len({c.lower() for c in comps.values()}) == len(names)   # case-insensitive too
    assert comps["x"] == "x" and comps["a_b"] != comps["a/b"]


@pytest.mark.parametrize("parts", [("..",), ("a", ".."), ("../x",), ("/etc",), ("",), ("a\\b",)])
def test_inside_refuses_anything_but_single_names(tmp_path: Path, parts: tuple[str, ...]
                                                  ) -> None:
    with pytest.raises(InputError):
        inside(tmp_path, *parts)


def test_inside_refuses_a_link_that_leaves_the_root(tmp_path: Path) -> None:
    root = tmp_path / "root"
    root.mkdir()
    (root / "link").symlink_to(tmp_path)
    with pytest.raises(InputError, match="leaves"):
        inside(root, "link", "x")


def test_an_output_channel_name_with_a_trailing_newline_is_no_channel() -> None:
    assert OUTPUT_NAME.match("gyro_x")
    for bad in ("gyro_x\n", "gyro_x/../y", "gyro_../x", "acc_z\r"):
        assert OUTPUT_NAME.match(bad) is None


# ------------------------------------------------------------- fleet, end to end
@pytest.fixture(scope="module")
def hostile_fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fleet whose unit ids are paths, run from a nested working directory."""
    root = tmp_path_factory.mktemp("hostile-fleet")
    data = _fleet_csv(root / "f.csv", [*HOSTILE_IDS, "good-unit"])
    cfg = _config(root / "c.yaml", data)
    work = root / "a" / "b" / "c"
    work.mkdir(parents=True)
    before = _tree(root)
    cwd = os.getcwd()
    os.chdir(work)
    try:
        rc = main(["fleet", str(cfg), "--out", "out", "--executor", "serial", "--no-track",
                   "-q", "--folds", "0", "--no-plots"])
    finally:
        os.chdir(cwd)
    assert rc == 0
    after = _tree(root)
    new = {p for p in after - before}
    assert new and all(p.startswith("a/b/c/out") for p in new), sorted(new)[:10]
    assert not Path("/tmp/abs-evil").exists()
    return work / "out"


def test_fleet_unit_ids_never_escape_out(hostile_fleet: Path) -> None:
    res = json.loads((hostile_fleet / "results.json").read_text())
    assert set(res["units"]) == {*HOSTILE_IDS, "good-unit"}            # the ids themselves
    dirs = sorted(p.name for p in (hostile_fleet / "units").iterdir())
    assert len(dirs) == len(HOSTILE_IDS) + 1
    for dev, u in res["units"].items():
        assert u["status"] == "ok", (dev, u.get("reason"))
        udir = hostile_fleet / u["dir"]
        assert udir.parent == hostile_fleet / "units" and udir.name == path_component(dev)
        assert (udir / "results.json").is_file() and (udir / "models" / "cubic.pt").is_file()
        unit = json.loads((udir / "results.json").read_text())
        ckpt = Path(unit["families"]["cubic"]["checkpoint"])
        assert ckpt.name == "cubic.pt" and ckpt.parent.parent.name == udir.name
    assert "good-unit" in dirs and any(d.startswith("ESCAPE-") for d in dirs)


def test_fleet_no_plots_writes_no_png_anywhere(hostile_fleet: Path) -> None:
    assert not list(hostile_fleet.rglob("*.png"))
    assert not list(hostile_fleet.glob("units/*/plots"))


def test_export_all_units_writes_inside_outdir_only(hostile_fleet: Path, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    before = _tree(tmp_path)
    assert main(["export", str(hostile_fleet), "--all-units", "--format", "c",
                 "--out", str(tmp_path / "hdr")]) == 0
    capsys.readouterr()
    new = _tree(tmp_path) - before
    assert all(p.startswith("hdr") for p in new)
    names = sorted(p.name for p in (tmp_path / "hdr").iterdir())
    expected = sorted(f"{path_component(d)}.h" for d in [*HOSTILE_IDS, "good-unit"])
    assert names == expected


def test_export_all_units_with_edited_unit_ids_skips_them(hostile_fleet: Path, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(hostile_fleet, copy)
    res = json.loads((copy / "results.json").read_text())
    res["units"] = {"../../../../../tmp/evil": res["units"]["good-unit"],
                    "/etc": res["units"]["good-unit"], "good-unit": res["units"]["good-unit"]}
    (copy / "results.json").write_text(json.dumps(res))
    before = _tree(tmp_path)
    assert main(["export", str(copy), "--all-units", "--format", "c",
                 "--out", str(tmp_path / "hdr")]) == 1
    err = capsys.readouterr().err
    assert "../../../../../tmp/evil: skipped" in err and "/etc: skipped" in err
    new = _tree(tmp_path) - before
    assert new == {"hdr", "hdr/good-unit.h"}


# ------------------------------------------------------- fleet --out and --overwrite
@pytest.fixture(scope="module")
def small_fleet(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("small-fleet")
    data = _fleet_csv(root / "f.csv", ["u1", "u2"])
    return root, _config(root / "c.yaml", data)


def _fleet(cfg: Path, out: Path, *extra: str) -> int:
    return main(["fleet", str(cfg), "--out", str(out), "--executor", "serial", "--no-track",
                 "-q", "--folds", "0", *extra])


def test_fleet_refuses_a_non_empty_folder_and_keeps_the_users_file(
        small_fleet: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, cfg = small_fleet
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("three years of work")
    for extra in ((), ("--overwrite",)):
        assert _fleet(cfg, out, *extra) == 1
        line = _one_line(capsys.readouterr().err)
        assert str(out) in line and "holds no thermonet fleet" in line
        assert _tree(out) == {"thesis.tex"}
        assert (out / "thesis.tex").read_text() == "three years of work"
    assert not list(tmp_path.glob(".mine.*"))
    # a file as --out
    assert _fleet(cfg, out / "thesis.tex") == 1
    assert "must be a directory" in _one_line(capsys.readouterr().err)


def test_fleet_overwrite_replaces_only_its_own_outputs(small_fleet: tuple[Path, Path],
                                                       tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    _, cfg = small_fleet
    out = tmp_path / "fl"
    assert _fleet(cfg, out, "--no-plots") == 0
    first = json.loads((out / "results.json").read_text())
    (out / "notes.txt").write_text("mine")
    (out / "units" / "stale-unit").mkdir()          # inside thermonet's own 'units/'
    # without --overwrite: refused, nothing changed
    assert _fleet(cfg, out) == 1
    line = _one_line(capsys.readouterr().err)
    assert "holds a previous fleet" in line and "--overwrite" in line
    assert (out / "units" / "stale-unit").is_dir() and (out / "notes.txt").exists()
    # with it: the previous fleet is replaced whole, the user's file beside it is kept
    assert _fleet(cfg, out, "--overwrite") == 0
    assert (out / "notes.txt").read_text() == "mine"
    assert not (out / "units" / "stale-unit").exists()
    assert sorted(p.name for p in (out / "units").iterdir()) == ["u1", "u2"]
    second = json.loads((out / "results.json").read_text())
    for dev in ("u1", "u2"):   # same data, same seeds: the same fit
        a = first["units"][dev]["families"]["cubic"]["axes"]["gyro_x"]["rms_comp"]
        b = second["units"][dev]["families"]["cubic"]["axes"]["gyro_x"]["rms_comp"]
        np.testing.assert_allclose(b, a, rtol=1e-6)
    # plots this time (no --no-plots): every unit has its own
    assert list((out / "units" / "u1" / "plots").glob("*.png"))
    assert not list(tmp_path.glob(".fl.*"))


# --------------------------------------------------- fleet units with too little data
def _tiny(device: str, n: int) -> Recording:
    t = np.arange(float(n)) * 6.0
    return Recording(time_s=t, temperature_c=20.0 + t / 60.0,
                     outputs={"gyro_x": np.zeros(n)},
                     units={"gyro_x": "deg/s", "temperature_c": "degC"},
                     device_id=device, run_id="run0", sample_rate_hz=1 / 6.0)


def test_fleet_units_with_zero_or_one_sample_fail_alone_named(tmp_path: Path) -> None:
    flat = _unit_runs("flat-unit")
    for r in flat:
        r.temperature_c = np.full(r.n_samples, 25.0)   # no temperature span at all
    runs = _unit_runs("u-ok") + [_tiny("u-empty", 0), _tiny("u-one", 1)] + flat
    sources = sources_from_dataset(Dataset(runs))
    assert [s.device_id for s in sources] == ["u-ok", "u-empty", "u-one", "flat-unit"]
    cfg = CompareConfig(families=[FamilyConfig(family="poly", name="cubic", inputs=["dT"],
                                               params={"degree": 3})])
    cfg.tracking.enabled = False
    cfg.split.strategy = "train-then-verify"
    res = run_fleet(cfg, tmp_path / "f", sources, quiet=True,
                    options=FleetOptions(executor="serial", folds=0))
    units = res["units"]
    assert units["u-ok"]["status"] == "ok"
    for dev, why in (("u-empty", "too few samples: 0"), ("u-one", "too few samples: 1"),
                     ("flat-unit", "temperature spans only")):
        assert units[dev]["status"] == "failed"
        assert units[dev]["reason"].startswith(f"unit '{dev}'") and why in units[dev]["reason"]
        assert units[dev]["limits"]["verdict"] == "FAIL"
    assert res["fleet"]["n_failed"] == 3 and not res["fleet"]["all_passed"]
    assert sorted(p.name for p in (tmp_path / "f" / "units").iterdir()) == ["u-ok"]


def test_fleet_cli_names_a_one_sample_unit_and_goes_on(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    data = _fleet_csv(tmp_path / "f.csv", ["u1", "u2"])
    frame = pd.read_csv(data)
    lonely = frame.iloc[:1].assign(device="lonely")
    pd.concat([frame, lonely]).to_csv(data, index=False)
    cfg = _config(tmp_path / "c.yaml", data)
    assert _fleet(cfg, tmp_path / "out", "--no-plots") == 3     # some unit failed
    err = capsys.readouterr().err
    assert "warning: unit 'lonely'" in err and "too few samples: 1" in err
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    assert [res["units"][d]["status"] for d in ("u1", "u2", "lonely")] == ["ok", "ok", "failed"]


def test_units_that_disagree_with_each_other_still_stop_the_fleet_naming_both() -> None:
    odd = _unit_runs("u-odd")
    for r in odd:
        r.units["gyro_x"] = "rad/s"
    with pytest.raises(InputError, match=r"unit 'u-odd'.*unit 'u-ok'|unit 'u-ok'.*unit 'u-odd'"):
        sources_from_dataset(Dataset(_unit_runs("u-ok") + odd))


# ------------------------------------------------------------------ calibrate
@pytest.fixture(scope="module")
def board_logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One IMU (gyro0 + acc0) of a simulated board, as a ULog and as a DataFlash log."""
    root = tmp_path_factory.mktemp("boards")
    out = {}
    for autopilot, name in (("px4", "b.ulg"), ("ardupilot", "b.bin")):
        board = simulate_board("fc-board-cycle", autopilot=autopilot, seed=12, rate_hz=0.1)
        board.instances = [i for i in board.instances if i.name in ("gyro0", "acc0")]
        out[autopilot] = write_log(board, root / name)
    return out


def test_calibrate_overwrite_leaves_no_stale_parameter_file(board_logs: dict[str, Path],
                                                            tmp_path: Path) -> None:
    out = tmp_path / "cal"
    calibrate(board_logs["ardupilot"], out, compare=False)
    assert (out / "ardupilot.parm").is_file()
    (out / "flight-notes.md").write_text("mine")
    with pytest.raises(ThermonetError, match="holds a previous calibration.*--overwrite"):
        calibrate(board_logs["px4"], out, compare=False)
    assert (out / "ardupilot.parm").is_file() and not (out / "px4.params").exists()
    doc = calibrate(board_logs["px4"], out, compare=False, overwrite=True)
    assert (out / "px4.params").is_file()
    assert not (out / "ardupilot.parm").exists()                # the stale file is gone
    assert (out / "flight-notes.md").read_text() == "mine"      # the user's is kept
    assert doc["params_file"] == str(out / "px4.params")
    assert json.loads((out / "results.json").read_text())["autopilot"] == "px4"
    assert not list(tmp_path.glob(".cal.*"))


def test_calibrate_overwrite_replaces_every_file_it_wrote(board_logs: dict[str, Path],
                                                         tmp_path: Path) -> None:
    """Everything a calibration writes at its top level is its own (``KINDS``): replaced
    whole with ``--overwrite``, the previous one removed, not kept in a hidden ``.old``
    directory; the EKF recommendation of a compared calibration never stays beside a later
    one that has none (it would name settings for another parameter file)."""
    out = tmp_path / "cal"
    calibrate(board_logs["px4"], out)                  # compared: with its EKF file
    assert (out / EKF_FILE).is_file()
    assert {p.name for p in out.iterdir()} <= KINDS["calibration"]
    calibrate(board_logs["px4"], out, compare=False, overwrite=True)
    assert not (out / EKF_FILE).exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal"]   # no .cal.*.old left


def test_calibrate_refuses_a_foreign_folder_and_a_file(board_logs: dict[str, Path],
                                                       tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    out = tmp_path / "photos"
    out.mkdir()
    (out / "cat.jpg").write_bytes(b"\xff\xd8")
    for extra in ((), ("--overwrite",)):
        assert main(["calibrate", str(board_logs["px4"]), "--out", str(out), "-q",
                     *extra]) == 1
        line = _one_line(capsys.readouterr().err)
        assert str(out) in line and "holds no thermonet calibration" in line
        assert _tree(out) == {"cat.jpg"}
    assert main(["calibrate", str(board_logs["px4"]), "--out", str(out / "cat.jpg"), "-q"]) == 1
    assert "must be a directory" in _one_line(capsys.readouterr().err)


def test_calibrate_records_final_paths_not_the_staging_directory(board_logs: dict[str, Path],
                                                                 tmp_path: Path) -> None:
    out = tmp_path / "cal"
    doc = calibrate(board_logs["px4"], out)
    text = (out / "results.json").read_text()
    assert ".partial" not in text
    for name in ("gyro0", "acc0"):
        cmp = doc["instances"][name]["compare"]
        assert cmp["dir"] == str(out / "instances" / name)
        sub = json.loads((out / "instances" / name / "results.json").read_text())
        for fam in sub["families"].values():
            if fam.get("checkpoint"):
                assert Path(fam["checkpoint"]).is_file()
                assert Path(fam["checkpoint"]).parent == out / "instances" / name / "models"
    page = (out / "report.html").read_text()
    assert 'href="instances/gyro0/report.html"' in page
    assert 'href="instances/acc0/report.html"' in page


def test_calibrate_interrupted_leaves_nothing_half_written(board_logs: dict[str, Path],
                                                           tmp_path: Path) -> None:
    """SIGINT while the instances are being compared: exit 130, no --out, no staging left."""
    out = tmp_path / "cal"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "thermonet.cli", "calibrate",
                             str(board_logs["px4"]), "--out", str(out), "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        # wait (event-driven, not timed) until the staging directory holds instances/ — the
        # first instance's comparison has started and takes seconds — then interrupt it
        # (waiting for a finished results.json raced the end of the run on a loaded machine:
        # the last comparison could finish before the signal arrived)
        while proc.poll() is None and not list(tmp_path.glob(".cal.*/instances/*")):
            time.sleep(0.05)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert "interrupted by SIGINT" in err
    assert not out.exists()
    assert not list(tmp_path.glob(".cal.*"))


# --------------------------------------------------- a directory or a FIFO as the log
@pytest.mark.parametrize("command", ["calibrate", "info"])
def test_a_directory_fifo_or_missing_log_is_named_for_what_it_is(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str) -> None:
    (tmp_path / "dir.ulg").mkdir()
    (tmp_path / "plain-dir").mkdir()
    os.mkfifo(tmp_path / "pipe.bin")
    cases = {"dir.ulg": "is a directory, not a flight-controller log",
             "plain-dir": "is a directory, not a flight-controller log",
             "pipe.bin": "is a FIFO, not a flight-controller log",
             "gone.ulg": "flight-controller log not found"}
    for name, what in cases.items():
        args = [command, str(tmp_path / name)] + (["--out", str(tmp_path / "o")]
                                                  if command == "calibrate" else [])
        if command == "info" and name == "plain-dir":
            continue   # info on a path without a log suffix reads it as a recording
        assert main(args) == 1
        line = _one_line(capsys.readouterr().err)
        assert f"{tmp_path / name}: {what}" in line, line
        assert "file not found" not in line
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------ compare, the same rules
def test_compare_overwrite_keeps_the_users_files_beside_its_outputs(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]
                                                                    ) -> None:
    data = _fleet_csv(tmp_path / "one.csv", ["only-unit"])
    cfg = _config(tmp_path / "c.yaml", data)
    out = tmp_path / "cmp"
    args = ["compare", str(cfg), "--out", str(out), "--no-track", "-q", "--no-plots"]
    assert main(args) == 0
    (out / "notes.txt").write_text("mine")
    (out / "models" / "stale.pt").write_bytes(b"not a checkpoint")   # inside its own models/
    assert main(args) == 1
    assert "pass --overwrite" in _one_line(capsys.readouterr().err)
    assert main([*args, "--overwrite"]) == 0
    assert (out / "notes.txt").read_text() == "mine"
    assert not (out / "models" / "stale.pt").exists()
    assert (out / "models" / "cubic.pt").is_file()
    assert not list(tmp_path.glob(".cmp.*"))


def test_export_all_units_never_replaces_a_file_already_there(hostile_fleet: Path,
                                                              tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]
                                                              ) -> None:
    out = tmp_path / "hdr"
    out.mkdir()
    (out / "good-unit.h").write_text("/* the user's own header */")
    (out / "README").write_text("mine")
    assert main(["export", str(hostile_fleet), "--all-units", "--format", "c",
                 "--out", str(out)]) == 1
    line = _one_line(capsys.readouterr().err)
    assert f"{out}: already holds good-unit.h" in line
    assert _tree(out) == {"good-unit.h", "README"}                      # nothing written
    assert (out / "good-unit.h").read_text() == "/* the user's own header */"
    # other files in the folder are no obstacle
    (out / "good-unit.h").unlink()
    assert main(["export", str(hostile_fleet), "--all-units", "--format", "c",
                 "--out", str(out)]) == 0
    capsys.readouterr()
    assert (out / "README").read_text() == "mine" and (out / "good-unit.h").is_file()
    # --overwrite replaces the units' own files (only theirs), never a link in their place
    (out / "good-unit.h").write_text("/* stale */")
    assert main(["export", str(hostile_fleet), "--all-units", "--format", "c",
                 "--out", str(out), "--overwrite"]) == 0
    capsys.readouterr()
    assert "thermonet" in (out / "good-unit.h").read_text()
    assert (out / "README").read_text() == "mine"
    (out / "good-unit.h").unlink()
    (out / "good-unit.h").symlink_to(out / "README")
    assert main(["export", str(hostile_fleet), "--all-units", "--format", "c",
                 "--out", str(out), "--overwrite"]) == 1
    assert "already holds good-unit.h (not a plain file: never replaced)" in _one_line(
        capsys.readouterr().err)
    assert (out / "README").read_text() == "mine"
