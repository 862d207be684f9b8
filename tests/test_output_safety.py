"""The names the user gave are the names written, and an output never overwrites an input.

* ``simulate fc-board --runs 1 --out b.ulg`` writes ``b.ulg``; N > 1 ``b_run1.ulg`` … (as the
  help says);
* ``export``, ``convert``, ``calibrate``, ``verify`` and the torch-free runtime refuse, in one
  line, exit 1, nothing written, an output that resolves to one of their inputs (the same path,
  a symbolic or hard link, ``..`` in the path, or — runtime — the output's ``.tmp``);
* the runtime stopped by SIGTERM / SIGINT in the middle of writing removes its ``.tmp`` and
  exits 128 + the signal (a real subprocess, killed while its output pipe is full).
"""

from __future__ import annotations

import hashlib
import os
import select
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import thermonet
from conftest import RUNTIME, toy_dataset
from thermonet.cli import build_parser, main
from thermonet.data.io import write_parquet
from thermonet.data.logs import read_log
from thermonet.data.logs.writers import write_log
from thermonet.sim.fcboard import simulate_board


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _aliases(path: Path, tmp: Path) -> list[Path]:
    """Other names of ``path``: itself, a symbolic link, a hard link, a path through ``..``."""
    sym = tmp / f"sym-{path.name}"
    hard = tmp / f"hard-{path.name}"
    for p in (sym, hard):
        if p.exists() or p.is_symlink():
            p.unlink()
    os.symlink(path, sym)
    os.link(path, hard)
    return [path, sym, hard, path.parent / ".." / path.parent.name / path.name]


# ---------------------------------------------------------------- simulate: the name given


@pytest.mark.parametrize("ext", [".ulg", ".bin"])
def test_simulate_writes_the_file_named(tmp_path: Path, ext: str,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    one = tmp_path / f"b{ext}"
    assert main(["simulate", "fc-board", "--runs", "1", "--out", str(one)]) == 0
    assert one.is_file() and not (tmp_path / f"b_run1{ext}").exists()
    assert f"wrote {one}:" in capsys.readouterr().out
    # the same board's warm-up 0 as without --runs: byte for byte
    plain = tmp_path / f"plain{ext}"
    assert main(["simulate", "fc-board", "--out", str(plain)]) == 0
    assert _digest(plain) == _digest(one)
    many = tmp_path / "m" / f"b{ext}"
    many.parent.mkdir()
    assert main(["simulate", "fc-board", "--runs", "3", "--out", str(many)]) == 0
    assert sorted(p.name for p in many.parent.iterdir()) == [f"b_run{k}{ext}" for k in (1, 2, 3)]
    assert read_log(many.parent / f"b_run1{ext}").autopilot == (
        "px4" if ext == ".ulg" else "ardupilot")
    sim = build_parser()._subparsers._group_actions[0].choices["simulate"]
    runs = next(a for a in sim._actions if a.dest == "runs")
    assert "FILE itself when N is 1" in runs.help and "FILE_run1 .. FILE_runN" in runs.help


# ---------------------------------------------------------------- export / convert


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    ds = toy_dataset(n_runs=3)
    est = thermonet.DriftEstimator("poly", ["dT"], degree=3,
                                   train=thermonet.TrainConfig(max_epochs=5)).fit(ds[0], val=ds[1])
    return est.save(tmp_path_factory.mktemp("ckpt") / "cubic.pt")


@pytest.mark.parametrize("fmt", ["onnx", "c"])
def test_export_never_overwrites_its_checkpoint(checkpoint: Path, tmp_path: Path, fmt: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    before = _digest(checkpoint)
    for out in _aliases(checkpoint, tmp_path):
        assert main(["export", str(checkpoint), "--format", fmt, "--out", str(out)]) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        assert f"{out}: the output is the input {checkpoint}" in err
        assert "refusing to overwrite an input (nothing written)" in err
        assert _digest(checkpoint) == before
    # another name: written
    assert main(["export", str(checkpoint), "--format", fmt, "--out",
                 str(tmp_path / f"model.{fmt}")]) == 0


def test_convert_never_overwrites_an_input(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    src = write_parquet(toy_dataset(n_runs=2), tmp_path / "toy.parquet")
    other = write_parquet(toy_dataset(n_runs=1, seed=3), tmp_path / "other.parquet")
    before = _digest(src)
    for out in _aliases(src, tmp_path):
        assert main(["convert", str(other), str(src), "--out", str(out), "--overwrite"]) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"the output is the input {src}" in err, err
        assert _digest(src) == before
    assert main(["convert", str(src), "--out", str(tmp_path / "new.parquet")]) == 0


# ---------------------------------------------------------------- calibrate / verify


@pytest.fixture(scope="module")
def board(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("board")
    log = write_log(simulate_board("fc-board", autopilot="px4", seed=4, rate_hz=0.5),
                    tmp / "b.ulg")
    later = write_log(simulate_board("fc-board", autopilot="px4", seed=4, rate_hz=0.5, run=1),
                      tmp / "later.ulg")
    assert main(["calibrate", str(log), "--out", str(tmp / "cal"), "--no-compare", "-q"]) == 0
    return {"log": log, "later": later, "params": tmp / "cal" / "px4.params"}


def test_calibrate_and_verify_never_write_over_what_they_read(
        board: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    digests = {k: _digest(p) for k, p in board.items()}
    cases = [(["calibrate", str(board["log"]), "--out", str(out), "--overwrite"], board["log"])
             for out in _aliases(board["log"], tmp_path)]
    cases += [(["verify", str(board["params"]), str(board["later"]), "--out", str(out),
                "--overwrite"], inp)
              for inp in (board["params"], board["later"]) for out in (inp, tmp_path / ".." /
                                                                       tmp_path.name / "x")
              if out == inp]
    for argv, inp in cases:
        assert main(argv) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"the output is the input {inp}" in err, err
    # a previous verification whose report.txt is the parameter file read: --overwrite would
    # replace it, so it is refused
    prev = tmp_path / "v"
    assert main(["verify", str(board["params"]), str(board["later"]), "--out", str(prev),
                 "-q"]) in (0, 3)
    inside = prev / "report.txt"
    inside.write_bytes(board["params"].read_bytes())
    assert main(["verify", str(inside), str(board["later"]), "--out", str(prev),
                 "--overwrite", "-q"]) == 1
    err = capsys.readouterr().err.strip()
    assert f"would replace {inside}, which is or holds the input {inside}" in err
    assert inside.read_bytes() == board["params"].read_bytes()
    assert {k: _digest(p) for k, p in board.items()} == digests


# ---------------------------------------------------------------- the runtime


@pytest.fixture(scope="module")
def onnx_model(checkpoint: Path) -> Path:
    out = checkpoint.parent / "cubic.onnx"
    assert main(["export", str(checkpoint), "--format", "onnx", "--out", str(out)]) == 0
    return out


def _csv(path: Path, n: int) -> Path:
    temp = np.linspace(-20.0, 50.0, n)
    with path.open("w") as fh:
        fh.write("temperature_c,gyro_x\n")
        fh.writelines(f"{float(t)!r},{0.01 * float(t)!r}\n" for t in temp)
    return path


def _runtime(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(RUNTIME), *args], capture_output=True,
                          text=True, timeout=300)


def test_runtime_never_overwrites_its_inputs(onnx_model: Path, tmp_path: Path) -> None:
    data = _csv(tmp_path / "in.csv", 50)
    tmp_named = _csv(tmp_path / "x.csv.tmp", 50)          # the .tmp of --out x.csv
    before = {p: _digest(p) for p in (onnx_model, data, tmp_named)}
    for out, inp, what in [(data, data, "the output"), (onnx_model, onnx_model, "the output"),
                           (tmp_path / "sub" / ".." / "in.csv", data, "the output"),
                           (tmp_path / "x.csv", tmp_named, "the output's temporary file")]:
        src = tmp_named if inp == tmp_named else data
        run = _runtime(str(onnx_model), str(src), "--out", str(out))
        assert run.returncode == 1, run.stderr
        line = run.stderr.strip()
        assert len(line.splitlines()) == 1 and f"{what}" in line and f"is the input {inp}" in line
        assert "(nothing written)" in line
    assert {p: _digest(p) for p in before} == before
    ok = _runtime(str(onnx_model), str(data), "--out", str(tmp_path / "out.csv"))
    assert ok.returncode == 0 and (tmp_path / "out.csv").read_text().count("\n") == 51


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_runtime_stopped_mid_write_removes_its_tmp(onnx_model: Path, tmp_path: Path,
                                                   sig: signal.Signals) -> None:
    """The runtime's ``.tmp`` is a FIFO here, so the test knows it is mid-write: it reads the
    first rows, stops reading (the writer blocks on the full pipe with most of its 20,000
    rows unwritten), then signals it."""
    data = _csv(tmp_path / "in.csv", 20_000)
    out = tmp_path / "out.csv"
    out.write_text("previous\n")                           # left as it was
    tmp = tmp_path / "out.csv.tmp"
    os.mkfifo(tmp)
    fd = os.open(tmp, os.O_RDONLY | os.O_NONBLOCK)
    proc = subprocess.Popen([sys.executable, str(RUNTIME), str(onnx_model), str(data),
                             "--out", str(out)], stderr=subprocess.PIPE, text=True)
    try:
        got = b""
        while b"\n" not in got or got.count(b"\n") < 100:  # the header and the first rows
            ready, _, _ = select.select([fd], [], [], 1.0)
            if not ready:
                assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
                continue
            try:
                chunk = os.read(fd, 4096)
            except BlockingIOError:
                continue
            assert chunk or proc.poll() is None, proc.stderr.read() if proc.stderr else ""
            got += chunk
        assert got.startswith(b"temperature_c,gyro_x,gyro_x_comp,gyro_x_drift,out_of_range\r\n")
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        os.close(fd)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + sig
    assert err.strip() == (f"thermonet_runtime: stopped by {sig.name}; {out} not written")
    assert not os.path.lexists(tmp)
    assert out.read_text() == "previous\n"
