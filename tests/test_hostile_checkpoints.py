"""Edited standalone checkpoints and absurd models (class 5).

A checkpoint carries a SHA-256 digest over its tensors, config and metadata, verified by
``load_checkpoint`` (so by ``thermonet export`` and ``DriftEstimator.load``): any edit — a
weight ×1000, a changed config, a removed digest — is refused in one line naming the file.
Every export format then checks the model's drift on its trained range (finite, within the
training targets' mean ± 1000 std), so a model that is absurd although its file is intact
(re-sealed after an edit, or edited in memory) is never written.  Real checkpoints written by
``DriftEstimator.save``, real exports through onnxruntime; nothing mocked.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import thermonet
from conftest import toy_dataset
from thermonet.cli import main
from thermonet.core.errors import ExportError, InputError
from thermonet.exporting.domain import MAX_STD, check_output_range
from thermonet.training.checkpoint import (
    DIGEST_KEY,
    checkpoint_digest,
    load_checkpoint,
    save_checkpoint,
    seal_checkpoint,
)

ROOT = Path(__file__).resolve().parent.parent
FORMATS = ["onnx", "c", "px4-params", "ardupilot-params"]
SUFFIX = {"onnx": ".onnx", "c": ".h", "px4-params": ".params", "ardupilot-params": ".parm"}


@pytest.fixture(scope="module")
def fitted(tmp_path_factory) -> tuple[thermonet.DriftEstimator, Path]:
    ds = toy_dataset(n_runs=3)
    est = thermonet.DriftEstimator("poly", ["dT"], degree=3,
                                   train=thermonet.TrainConfig(max_epochs=5)).fit(ds[0], val=ds[1])
    path = est.save(tmp_path_factory.mktemp("ckpt") / "cubic.pt")
    return est, path


def _edit(src: Path, dst: Path, how: str, *, seal: bool = False) -> Path:
    """A copy of ``src`` with one thing changed, as a user with torch.load/torch.save would."""
    p = torch.load(src, weights_only=True)
    state = p["state_dict"]
    if how == "weight x1000":
        state["family.weight"] = state["family.weight"] * 1000.0
    elif how == "weight x1e6":
        state["family.weight"] = state["family.weight"] * 1e6
    elif how == "weight 3e38":
        w = state["family.weight"].clone()
        w.view(-1)[0] = 3e38
        state["family.weight"] = w
    elif how == "weight nan":
        w = state["family.weight"].clone()
        w.view(-1)[-1] = float("nan")
        state["family.weight"] = w
    elif how == "bias +1 ulp":
        state["family.bias"] = torch.nextafter(state["family.bias"],
                                               torch.full_like(state["family.bias"], 1.0))
    elif how == "trained range wider":
        state["sig_hi"] = state["sig_hi"] + 100.0
    elif how == "y_std x10":
        state["y_std"] = state["y_std"] * 10.0
    elif how == "config lr":
        p["config"]["train"]["lr"] = 0.5
    elif how == "extra device_id":
        p["extra"]["device_id"] = "someone-else"
    elif how == "epoch":
        p["epoch"] = 999
    elif how == "extra key added":
        p["extra"]["note"] = "harmless?"
    elif how == "digest removed":
        del p[DIGEST_KEY]
    elif how == "digest not text":
        p[DIGEST_KEY] = 12345
    elif how == "digest of another file":
        p[DIGEST_KEY] = "0" * 64
    else:
        raise AssertionError(how)
    torch.save(p, dst)
    if seal:
        seal_checkpoint(dst)
    return dst


def test_a_saved_checkpoint_carries_its_digest_and_loads(fitted):
    est, path = fitted
    payload = torch.load(path, weights_only=True)
    assert payload[DIGEST_KEY] == checkpoint_digest(payload)
    model, meta = load_checkpoint(path)
    assert meta[DIGEST_KEY] == payload[DIGEST_KEY]
    back = thermonet.DriftEstimator.load(path)
    ds = toy_dataset(n_runs=3)
    # saved and loaded: the same weights through the same computation, bit for bit
    np.testing.assert_array_equal(back.predict(ds[2]), est.predict(ds[2]))
    # the digest is of the content, not of pickle's bytes: the same content saved again
    # (another pickle) gives the same digest
    torch.save(payload, path.parent / "again.pt")
    assert checkpoint_digest(torch.load(path.parent / "again.pt", weights_only=True)) == \
        payload[DIGEST_KEY]


EDITS = ["weight x1000", "weight 3e38", "bias +1 ulp", "trained range wider", "y_std x10",
         "config lr", "extra device_id", "epoch", "extra key added", "digest of another file",
         "digest not text"]


@pytest.mark.parametrize("how", EDITS)
def test_an_edited_checkpoint_is_refused_on_load(fitted, tmp_path, how):
    _, path = fitted
    bad = _edit(path, tmp_path / "edited.pt", how)
    for load in (load_checkpoint, thermonet.DriftEstimator.load):
        with pytest.raises(InputError, match=r"edited\.pt: content does not match the "
                                             r"checkpoint's SHA-256 digest"):
            load(bad)


@pytest.mark.parametrize("how", ["weight x1000", "config lr", "weight 3e38"])
@pytest.mark.parametrize("fmt", ["onnx", "c"])
def test_export_of_an_edited_checkpoint_is_refused_in_one_line(fitted, tmp_path, capsys,
                                                               how, fmt):
    _, path = fitted
    bad = _edit(path, tmp_path / "edited.pt", how)
    out = tmp_path / f"m{SUFFIX[fmt]}"
    assert main(["export", str(bad), "--format", fmt, "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(bad) in err and "SHA-256 digest" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["edited.pt"]  # nothing written


def test_a_checkpoint_without_digest_is_refused_until_sealed(fitted, tmp_path, capsys):
    _, path = fitted
    old = _edit(path, tmp_path / "old.pt", "digest removed")
    with pytest.raises(InputError, match=r"old\.pt: checkpoint carries no integrity digest.*"
                                         r"seal_checkpoint"):
        load_checkpoint(old)
    assert main(["export", str(old), "--format", "c", "--out", str(tmp_path / "m.h")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no integrity digest" in err
    # the owner vouches for it: sealed again, it loads and exports
    seal_checkpoint(old)
    load_checkpoint(old)
    assert main(["export", str(old), "--format", "c", "--out", str(tmp_path / "m.h")]) == 0
    assert (tmp_path / "m.h").is_file()


def test_seal_refuses_what_is_not_a_checkpoint(tmp_path):
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"\x80\x04not a pickle")
    with pytest.raises(InputError, match=r"junk\.pt: not a readable checkpoint"):
        seal_checkpoint(junk)
    torch.save({"state_dict": {}}, tmp_path / "partial.pt")
    with pytest.raises(InputError, match=r"partial\.pt: not a thermonet checkpoint"):
        seal_checkpoint(tmp_path / "partial.pt")


@pytest.mark.parametrize("how", ["weight x1e6", "weight 3e38", "weight nan"])
@pytest.mark.parametrize("fmt", FORMATS)
def test_a_sealed_but_absurd_model_is_refused_by_every_format(fitted, tmp_path, capsys,
                                                              how, fmt):
    """The file is intact (sealed after the edit), the model is not: every format's output
    range check refuses it, naming the file and the axis, and writes nothing."""
    _, path = fitted
    bad = _edit(path, tmp_path / "sealed.pt", how, seal=True)
    load_checkpoint(bad)  # the digest is right: the range check is what refuses it
    out = tmp_path / f"m{SUFFIX[fmt]}"
    extra = ["--device-id", "1"] if fmt == "px4-params" else []
    assert main(["export", str(bad), "--format", fmt, "--out", str(out), *extra]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert f"{bad}: axis 'gyro_x': the model's drift" in err and "refusing to export" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sealed.pt"]


def test_the_issues_3e38_model_never_reaches_the_runtime(fitted, tmp_path, capsys):
    _, path = fitted
    bad = _edit(path, tmp_path / "big.pt", "weight 3e38", seal=True)
    assert main(["export", str(bad), "--format", "onnx", "--out", str(tmp_path / "m.onnx")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "axis 'gyro_x'" in err and str(bad) in err, err
    assert not (tmp_path / "m.onnx").exists()
    # the intact model exports, and the runtime's output on the trained range stays within
    # the bound the check applies
    assert main(["export", str(path), "--format", "onnx", "--out", str(tmp_path / "ok.onnx")]) == 0
    model, _ = load_checkpoint(path)
    lo, hi = float(model.sig_lo[0]), float(model.sig_hi[0])
    temps = np.linspace(lo, hi, 50).tolist()
    csv = tmp_path / "in.csv"
    csv.write_text("temperature_c,gyro_x\n" + "".join(f"{t!r},0.0\n" for t in temps))
    run = subprocess.run([sys.executable, str(ROOT / "export" / "thermonet_runtime.py"),
                          str(tmp_path / "ok.onnx"), str(csv), "--out", str(tmp_path / "o.csv")],
                         capture_output=True, text=True, check=False)
    assert run.returncode == 0, run.stderr
    import csv as csvmod

    rows = list(csvmod.DictReader((tmp_path / "o.csv").open()))
    drift = np.array([float(r["gyro_x_drift"]) for r in rows])
    y_mean, y_std = float(model.y_mean[0]), float(model.y_std[0])
    const = float(model.constant()[0])
    assert np.all(np.isfinite(drift))
    assert np.all(np.abs(drift - const - y_mean) <= MAX_STD * y_std)


def test_an_absurd_model_in_memory_is_refused_by_the_api(tmp_path):
    ds = toy_dataset(n_runs=3)
    est = thermonet.DriftEstimator("linear", ["dT"],
                                   train=thermonet.TrainConfig(max_epochs=3)).fit(ds[0], val=ds[1])
    est.export(tmp_path / "ok.h", format="c")
    for value in (3e38, float("inf")):
        with torch.no_grad():
            est.model_.family.weight.fill_(value)
        for fmt in ("onnx", "c"):
            out = tmp_path / f"bad{SUFFIX[fmt]}"
            with pytest.raises(ExportError, match=r"model 'linear' \(in memory\)|NaN or inf"):
                est.export(out, format=fmt)
            assert not out.exists()


def test_range_check_passes_a_fitted_model_and_names_a_non_fitted_one(fitted):
    est, _ = fitted
    check_output_range(est.model_, source="m.pt")   # a fitted model: within bounds
    model, _ = load_checkpoint(fitted[1])
    with torch.no_grad():
        model.sig_lo.fill_(-float("inf"))
    with pytest.raises(ExportError, match=r"m\.pt: trained range of signal 'temperature_c' is "
                                          r"\[-inf"):
        check_output_range(model, source="m.pt")


def test_a_compare_checkpoint_is_sealed_too(tmp_path):
    """The checkpoints compare writes carry the same digest (and results.json's SHA-256)."""
    from thermonet.training.config import load_config
    from thermonet.workflows.compare import run_compare

    cfg_file = tmp_path / "c.yaml"
    from thermonet.data.io import write_parquet

    data = write_parquet(toy_dataset(n_runs=3), tmp_path / "toy.parquet")
    cfg_file.write_text(f"data: {{paths: ['{data}']}}\nfamilies:\n"
                        "  - {family: poly, name: cubic, inputs: [dT], params: {degree: 3}}\n"
                        "train: {max_epochs: 3}\nbaseline: null\n")
    run_compare(load_config(cfg_file), tmp_path / "out", track=False, quiet=True, plots=False)
    ckpt = tmp_path / "out" / "models" / "cubic.pt"
    payload = torch.load(ckpt, weights_only=True)
    assert payload[DIGEST_KEY] == checkpoint_digest(payload)
    # a copy taken out of the comparison and edited is refused on its own
    bad = _edit(ckpt, tmp_path / "alone.pt", "weight x1000")
    with pytest.raises(InputError, match="SHA-256 digest"):
        load_checkpoint(bad)


def test_save_then_edit_in_python_then_save_again_is_fine(fitted, tmp_path):
    """Editing a model in Python and saving it through thermonet writes a fresh digest."""
    est, _ = fitted
    model, _ = load_checkpoint(fitted[1])
    with torch.no_grad():
        model.family.bias.add_(1e-3)
    p = save_checkpoint(tmp_path / "re.pt", model, config={})
    load_checkpoint(p)


# ------------------------------------------------- the exported ONNX file is sealed too
def _edit_onnx(src: Path, dst: Path, how: str) -> Path:
    import onnx
    from onnx import numpy_helper

    proto = onnx.load(str(src))
    if how in ("weight x1000", "weight 3e38"):
        init = max(proto.graph.initializer, key=lambda t: numpy_helper.to_array(t).size)
        arr = numpy_helper.to_array(init).copy()
        if how == "weight x1000":
            arr = arr * 1000
        else:
            arr.reshape(-1)[0] = 3e38
        init.CopyFrom(numpy_helper.from_array(arr.astype(arr.dtype), init.name))
    else:
        for p in proto.metadata_props:
            if how == "device_id" and p.key == "device_id":
                p.value = '"someone-else"'
        if how == "digest removed":
            keep = [p for p in proto.metadata_props if p.key != "thermonet_sha256"]
            del proto.metadata_props[:]
            proto.metadata_props.extend(keep)
    onnx.save(proto, str(dst))
    return dst


@pytest.fixture(scope="module")
def runtime():
    sys.path.insert(0, str(ROOT / "export"))
    try:
        import thermonet_runtime as rt
    finally:
        sys.path.pop(0)
    return rt


@pytest.mark.parametrize("how", ["weight x1000", "weight 3e38", "device_id", "digest removed"])
def test_the_runtime_refuses_an_edited_onnx_file(fitted, tmp_path, capsys, runtime, how):
    from thermonet.exporting.onnx_seal import DIGEST_KEY as ONNX_DIGEST
    from thermonet.exporting.onnx_seal import seal_onnx

    _, path = fitted
    good = tmp_path / "m.onnx"
    assert main(["export", str(path), "--format", "onnx", "--out", str(good)]) == 0
    comp = runtime.Compensator(good)  # the file as exported runs
    assert len(comp.metadata[ONNX_DIGEST]) == 64
    bad = _edit_onnx(good, tmp_path / "edited.onnx", how)
    want = "carries no integrity digest" if how == "digest removed" else \
        "content does not match its SHA-256 digest"
    with pytest.raises(runtime.RuntimeInputError, match=want) as err:
        runtime.Compensator(bad)
    assert str(bad) in str(err.value) and "\n" not in str(err.value)
    csv = tmp_path / "in.csv"
    csv.write_text("temperature_c,gyro_x\n20.0,0.0\n")
    assert runtime.main([str(bad), str(csv), "--out", str(tmp_path / "o.csv")]) == 1
    assert want in capsys.readouterr().err and not (tmp_path / "o.csv").exists()
    # re-sealed by its owner it runs again (and a re-sealed 3e38 is the owner's business)
    seal_onnx(bad)
    runtime.Compensator(bad)


class _Payload:
    """A pickle that would run code on load (``os.mkdir`` a marker) if loaded unsafely."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.mkdir, (str(self.marker),))


@pytest.mark.parametrize("how", ["torch.save", "pickle"])
def test_a_hostile_pickle_is_named_never_loaded_unsafely(tmp_path, capsys, how):
    """A pickle that names code to run, given as a checkpoint (export, DriftEstimator.load,
    seal) or a sensor model: one line saying it is no thermonet checkpoint and why (an
    unsafe pickle naming os.mkdir), never torch's advice to re-run torch.load with
    weights_only=False, and the code never runs."""
    import pickle

    from thermonet.training.sensor_checkpoint import load_sensor

    marker = tmp_path / "ran"
    bad = tmp_path / "model.pt"
    if how == "torch.save":
        torch.save({"state_dict": {}, "x": _Payload(marker)}, bad)
    else:
        bad.write_bytes(pickle.dumps({"x": _Payload(marker)}, protocol=4))
    want = (f"{bad}: not a thermonet checkpoint: it is a pickle that names Python code to run "
            f"or a class to rebuild ({os.mkdir.__module__}.mkdir), which a checkpoint never holds (an "
            "unsafe pickle); refused unread, nothing in it was run")
    for load in (load_checkpoint, seal_checkpoint, thermonet.DriftEstimator.load):
        with pytest.raises(InputError) as err:
            load(bad)
        assert str(err.value) == want
    with pytest.raises(InputError) as err:
        load_sensor(bad)
    assert str(err.value) == want.replace("checkpoint", "sensor model")
    assert main(["export", str(bad), "--format", "onnx", "--out", str(tmp_path / "m.onnx")]) == 1
    err_text = capsys.readouterr().err
    assert err_text.endswith(f"thermonet: error: {want}\n")
    assert "weights_only=False" not in err_text and "set to `False`" not in err_text
    assert not marker.exists() and not (tmp_path / "m.onnx").exists()


def test_a_damaged_pickle_is_not_readable_without_torchs_advice(tmp_path):
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"\x80\x04not a pickle")
    with pytest.raises(InputError) as err:
        load_checkpoint(junk)
    assert str(err.value).startswith(f"{junk}: not a readable checkpoint (")
    assert "weights_only" not in str(err.value) and "\n" not in str(err.value)


def test_an_onnx_file_given_as_a_checkpoint_is_said_to_be_one(fitted, tmp_path):
    """DriftEstimator.load("m.onnx") said "not a readable checkpoint (… Unsupported operand
    8)": it now says the file is an ONNX file and what to load instead — by its content too
    (an ONNX file named .pt), while a damaged pickle named .onnx stays unreadable."""
    est, _ = fitted
    onnx = est.export(tmp_path / "m.onnx")
    renamed = tmp_path / "m.pt"
    renamed.write_bytes(onnx.read_bytes())
    for path in (onnx, renamed):
        with pytest.raises(InputError) as err:
            thermonet.DriftEstimator.load(path)
        assert str(err.value) == (
            f"{path}: an ONNX file (an exported model), not a thermonet checkpoint: load the "
            ".pt checkpoint it was exported from (compare's models/<label>.pt, "
            "DriftEstimator.save), or run the ONNX file with export/thermonet_runtime.py")
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"\x80\x04not a pickle")
    with pytest.raises(InputError, match=r"junk\.onnx: not a readable checkpoint \("):
        load_checkpoint(junk)


def test_a_library_warning_reaches_the_console_as_one_line_of_thermonets(tmp_path, capsys):
    """torch warns (a UserWarning with its file and source line, as Python prints it) while
    reading a plain pickle given to export: the console shows it as one line in
    thermonet's voice, then the refusal — two lines, no file:line, no 'UserWarning:'."""
    import pickle

    bad = tmp_path / "model.pt"
    bad.write_bytes(pickle.dumps({"x": _Payload(tmp_path / "ran")}, protocol=4))
    assert main(["export", str(bad), "--format", "c", "--out", str(tmp_path / "m.h")]) == 1
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 2, lines
    assert lines[0].startswith("thermonet: warning: Detected pickle protocol 4 in the "
                               "checkpoint, which was not the default pickle protocol")
    assert lines[1].startswith(f"thermonet: error: {bad}: not a thermonet checkpoint")
    assert "UserWarning" not in lines[0] and ".py:" not in lines[0]
