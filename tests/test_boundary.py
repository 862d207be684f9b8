"""The torch boundary and the version's home (pyproject.toml's import-linter contracts hold
the imports; these check what a user sees)."""

from __future__ import annotations

import ast
import io
import os
import subprocess
import sys
import tokenize
import tomllib
from pathlib import Path

import pytest

import thermonet
from thermonet.core.version import __version__

ROOT = Path(__file__).resolve().parents[1]


def test_the_version_lives_in_core_and_matches_the_package_metadata():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert __version__ == project["version"]
    assert thermonet.__version__ is __version__


def test_the_command_line_starts_without_torch_or_scikit_learn():
    code = ("import sys, runpy\n"
            "sys.argv = ['thermonet', '--help']\n"
            "try:\n    runpy.run_module('thermonet.cli', run_name='__main__')\n"
            "except SystemExit:\n    pass\n"
            "print(sorted(m for m in ('torch', 'sklearn', 'pandas') if m in sys.modules),"
            " file=sys.stderr)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    assert "usage: thermonet" in out.stdout
    assert out.stderr.strip().splitlines()[-1] == "[]"


_REFUSED_EXPORT = ("import sys\n"
                   "from thermonet.cli import main\n"
                   "rc = main(sys.argv[1:])\n"
                   "print('RC', rc, sorted(m for m in ('torch', 'mlflow') if m in sys.modules),"
                   " file=sys.stderr)\n")


@pytest.mark.parametrize("args, message", [
    (["none", "--format", "onnx", "--out", "m.onnx"],
     "none: no such compare directory, checkpoint file or MLflow run id"),
    (["m.pt", "--format", "c", "--out", "."], ".: --out is a directory; give a file name"),
    (["m.pt", "--format", "c", "--out", "m.pt/x.h"],
     "m.pt/x.h: --out cannot be created: {tmp}/m.pt is not a directory"),
    (["0123456789abcdef0123456789abcdef", "--format", "onnx", "--out", "."],
     ".: --out is a directory; give a file name"),
    (["cmp", "--family", "nope", "--format", "onnx", "--out", "m.onnx"],
     "cmp/results.json: no family 'nope' (families: lin)"),
    (["cmp", "--family", "a/b", "--format", "c", "--out", "m.h"], "--family: 'a/b' is not"),
    (["cmp/results.json", "--format", "c", "--out", "m.h"],
     "cmp/results.json: a config or results file, not a compare directory, checkpoint (.pt) or "
     "MLflow run id"),
    (["m.pt", "--format", "px4-params", "--instance", "7", "--out", "x.params"],
     "--instance: PX4 calibration instance must be 0..3, got 7"),
    (["m.pt", "--format", "ardupilot-params", "--instance", "0", "--out", "x.parm"],
     "--instance: ArduPilot IMU number must be 1..3, got 0"),
    (["m.pt", "--format", "px4-params", "--device-id", "-4", "--out", "x.params"],
     "--device-id must be the sensor's positive device id, got -4"),
    (["0123456789abcdef0123456789abcdef", "--format", "c", "--tracking-uri", "m.pt",
      "--out", "m.h"], "MLflow tracking (m.pt): m.pt is a file, not a tracking store"),
    (["0123456789abcdef0123456789abcdef", "--format", "c", "--tracking-uri", "sqlite:///new.db",
      "--out", "m.h"], "MLflow run '0123456789abcdef0123456789abcdef' at sqlite:///new.db: no "
     "tracking store there (new.db does not exist)"),
])
def test_a_refused_export_imports_neither_torch_nor_mlflow(tmp_path, args, message):
    """Every argument and the source's kind are checked before torch (the model) or MLflow (a
    run id's checkpoint) is imported: the refusal is one line, in well under a second."""
    (tmp_path / "m.pt").write_bytes(b"not looked at")
    (tmp_path / "cmp").mkdir()
    (tmp_path / "cmp" / "results.json").write_text(
        '{"chosen": "lin", "families": {"lin": {"checkpoint": "models/lin.pt"}}}')
    out = subprocess.run([sys.executable, "-c", _REFUSED_EXPORT, "export", *args],
                         capture_output=True, text=True, cwd=tmp_path, check=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    lines = out.stderr.strip().splitlines()
    assert lines[-1] == "RC 1 []", out.stderr
    assert len(lines) == 2, out.stderr                                  # one line said
    assert lines[0].startswith(f"thermonet: error: {message.format(tmp=tmp_path)}"), lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cmp", "m.pt"]   # nothing written


def test_no_circle_inside_a_package_type_only_imports_counted(tmp_path):
    """pyproject.toml's contract *No circle between the modules of one package*, run with the
    imports under ``if TYPE_CHECKING:`` counted too (the other contracts leave them out): a
    module may not name, even for its annotations only, a sibling that imports it (issue 51:
    api estimator / persistence / sensor_mode were one such circle)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    contract, = (c for c in config["contracts"] if c["type"] == "acyclic_siblings")
    (tmp_path / "acyclic.toml").write_text(
        '[tool.importlinter]\nroot_package = "thermonet"\n'
        "exclude_type_checking_imports = false\n\n[[tool.importlinter.contracts]]\n"
        f'name = "{contract["name"]}"\ntype = "acyclic_siblings"\n'
        f"ancestors = {contract['ancestors']!r}\n".replace("'", '"'))
    run = subprocess.run([str(Path(sys.executable).with_name("lint-imports")), "--config",
                          str(tmp_path / "acyclic.toml"), "--no-cache"],
                         capture_output=True, text=True, cwd=ROOT)
    assert run.returncode == 0 and "1 kept, 0 broken" in run.stdout, run.stdout[-3000:]


def _unexplained_imports(source: str, module: str) -> list[str]:
    """The own-module imports (``from ..x import y``, ``from thermonet.x import y``) inside a
    function of ``source`` with no comment on any of their lines, as ``"module:line: from"``."""
    tree = ast.parse(source)
    commented = {tok.start[0] for tok in tokenize.generate_tokens(io.StringIO(source).readline)
                 if tok.type == tokenize.COMMENT}
    found = set()
    for fn in ast.walk(tree):
        if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.ImportFrom) and (
                    node.level > 0 or (node.module or "").startswith("thermonet")):
                lines = range(node.lineno, (node.end_lineno or node.lineno) + 1)
                if not commented.intersection(lines):
                    found.add(f"{module}:{node.lineno}: {'.' * node.level}{node.module}")
    return sorted(found)


def test_the_scan_flags_an_uncommented_import_inside_a_function_and_nothing_else():
    source = ("from .a import b\n"
              "def f():\n"
              "    from .c import d  # lazy: loads pandas\n"
              "    from ..e import (  # torch boundary\n"
              "        g,\n"
              "    )\n"
              "    import json\n"
              "    from thermonet.h import i\n"
              "    def inner():\n"
              "        from .j import k\n"
              "    return d, g, i, json, inner\n")
    assert _unexplained_imports(source, "m") == ["m:10: .j", "m:8: thermonet.h"]


def test_every_own_module_import_inside_a_function_says_why():
    """ARCHITECTURE.md, "The torch boundary": own-module imports sit at the top of a file;
    one left inside a function (the torch boundary, a lazy load of pyarrow/pandas/yaml/
    matplotlib/MLflow, a cycle) carries its reason as a comment on its line."""
    found = []
    for path in sorted((ROOT / "thermonet").rglob("*.py")):
        found += _unexplained_imports(path.read_text(), str(path.relative_to(ROOT)))
    assert found == []


_LBFGS_FIT = """
import sys
import numpy as np
{first}
from thermonet.features.inputs import FeatureSpec
from thermonet.training.train import TrainConfig, fit, predict
t = np.linspace(-20.0, 60.0, 300)
y = (0.02 / (1.0 + ((t - 30.0) / 12.0) ** 2))[:, None]
res = fit(family="lorentz", inputs=["dT"], outputs=["gyro_x"], train=[(t[:, None], y)],
          val=None, spec=FeatureSpec(inputs=["dT"], t_ref=25.0), hyper={{}},
          config=TrainConfig(max_epochs=8, patience=50))
assert len(res.history) == 9                 # eight L-BFGS steps were taken
import torch
left = [n for n, a in vars(torch.optim.Optimizer).items()
        if getattr(getattr(a, "__wrapped__", None), "__dynamo_disable", None) is not None]
print("torch._dynamo" in sys.modules)
print(predict(res.model, t[:, None])[:, 0].tolist())
print(left)
"""


_ADAM_FITS = """
import sys
import numpy as np
{first}
from thermonet.features.inputs import FeatureSpec
from thermonet.training.train import TrainConfig, fit, predict
t = np.linspace(-20.0, 60.0, 400)
y = (0.02 / (1.0 + ((t - 30.0) / 12.0) ** 2))[:, None]
time_s = np.arange(400.0) * 10.0
spec = FeatureSpec(inputs=["dT"], t_ref=25.0)
adam = fit(family="lorentz", inputs=["dT"], outputs=["gyro_x"], train=[(t[:, None], y)],
           val=None, spec=spec, hyper={{}},
           config=TrainConfig(max_epochs=6, patience=50, optimizer="adam", lr=1e-2))
gru = fit(family="gru", inputs=["dT"], outputs=["gyro_x"], train=[(t[:, None], y, time_s)],
          val=None, spec=spec, hyper={{}}, config=TrainConfig(max_epochs=3, patience=50))
assert len(adam.history) == 7 and len(gru.history) == 4      # steps were taken
print("torch._dynamo" in sys.modules)
print(predict(adam.model, t[:, None])[:, 0].tolist())
print(predict(gru.model, t[:, None], time_s)[:, 0].tolist())
"""


def test_adam_and_gru_fits_run_without_importing_torch_dynamo_and_give_the_same_models():
    """Adam's ``step`` imports torch._dynamo on every call for a graph break
    (training.optim.optimizer_step steps over it, under torch.no_grad as torch's wrapper
    would): a point-wise family trained with Adam and the GRU fit without the import, and
    their models are bit for bit those of torch's own calls (torch._dynamo imported first,
    its wrappers then run as shipped)."""
    out = {}
    for first in ("", "import torch._dynamo"):
        proc = subprocess.run([sys.executable, "-c", _ADAM_FITS.format(first=first)],
                              capture_output=True, text=True, check=True)
        out[first] = proc.stdout.splitlines()
    assert out[""][0] == "False" and out["import torch._dynamo"][0] == "True"
    assert out[""][1:] == out["import torch._dynamo"][1:]


def test_an_lbfgs_fit_runs_without_importing_torch_dynamo_and_gives_the_same_model():
    """torch.optim's wrappers import torch._dynamo (~0.9 s) only to call the function they
    wrap (training.optim.optimizer_without_dynamo): an L-BFGS fit no longer imports it, gives
    bit for bit the model it gives when torch._dynamo was imported first (torch's own
    wrappers then run), and leaves torch's wrappers as shipped once it is done."""
    out = {}
    for first in ("", "import torch._dynamo"):
        proc = subprocess.run([sys.executable, "-c", _LBFGS_FIT.format(first=first)],
                              capture_output=True, text=True, check=True)
        loaded, preds, left = proc.stdout.splitlines()
        out[first] = (loaded, preds)
        if not first:                      # torch's wrappers as shipped once the fit is done
            assert left == "[]", left
    assert out[""][0] == "False" and out["import torch._dynamo"][0] == "True"
    assert out[""][1] == out["import torch._dynamo"][1]
