"""Plug-in families: a researcher's own family, in their own installed package, registered
through the entry-point group ``thermonet.families``, is fitted by ``thermonet compare``,
judged next to a built-in family and exported to ONNX like one.

The package is built and installed for real (pip, into a directory of its own) and the
command line runs as a separate process with that directory on ``PYTHONPATH``: the family
is found through the installed distribution's entry point, as a user's would be.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from thermonet.models.registry import BUILTIN

ROOT = Path(__file__).resolve().parents[1]

PYPROJECT = """\
[build-system]
requires = ["setuptools>=61"]
build-backend = "setuptools.build_meta"

[project]
name = "thermonet-quadratic"
version = "0.1.0"

[project.entry-points."thermonet.families"]
my-quadratic = "thermonet_quadratic:Quadratic"

[tool.setuptools]
py-modules = ["thermonet_quadratic"]
"""

def _documented_family() -> str:
    """The example of configs/README.md ("A family of your own"), run as the user's module."""
    text = (ROOT / "configs" / "README.md").read_text(encoding="utf-8")
    section = text.split("### A family of your own (plug-in)", 1)[1]
    return section.split("```python\n", 1)[1].split("```", 1)[0]


FAMILY = _documented_family()


@pytest.fixture(scope="module")
def plugin_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("plugin")
    pkg = root / "pkg"
    pkg.mkdir()
    (pkg / "pyproject.toml").write_text(PYPROJECT)
    (pkg / "thermonet_quadratic.py").write_text(FAMILY)
    site = root / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                    "--no-build-isolation", "--no-index", "--target", str(site), str(pkg)],
                   check=True, capture_output=True, text=True)
    assert any(site.glob("thermonet_quadratic-0.1.0.dist-info/entry_points.txt"))
    return site


def _thermonet(site: Path, *args: object, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)])}
    return subprocess.run([sys.executable, "-m", "thermonet.cli", *map(str, args)], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=900)


def test_an_installed_family_is_compared_judged_and_exported(plugin_path, tmp_path):
    data = tmp_path / "pg.parquet"
    r = _thermonet(plugin_path, "simulate", "patent-gyro", "--runs", "3", "--seed", "7",
                   "--out", data, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    cfg = tmp_path / "c.yaml"
    cfg.write_text(textwrap.dedent(f"""\
        data: {{paths: ['{data}'], outputs: [gyro_x]}}
        train: {{max_epochs: 20, patience: 5, max_train_samples: 3000}}
        families:
          - {{name: cubic, family: poly, inputs: [dT], params: {{degree: 3}}}}
          - {{name: mine, family: my-quadratic, inputs: [dT]}}
        """))
    r = _thermonet(plugin_path, "compare", cfg, "--out", tmp_path / "out", "--no-track",
                   "--no-plots", "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    mine = res["families"]["mine"]
    assert mine["status"] == "ok" and mine["family"] == "my-quadratic"
    assert mine["n_params"] == 3            # c0, c1, c2 for the one axis
    axis = mine["axes"]["gyro_x"]
    # judged like a built-in: held-out score against raw with its bootstrap verdict, and
    # against the baseline (the cubic)
    assert 0.0 < axis["score_ratio"] < 0.5 and axis["verdict"] == "better"
    assert axis["vs_baseline"]["verdict"] in ("better", "worse", "indistinguishable")
    assert mine["checkpoint"] and res["chosen"] in ("cubic", "mine")
    # exported to ONNX like a built-in (the exporter checks the graph against torch)
    r = _thermonet(plugin_path, "export", tmp_path / "out", "--family", "mine", "--format", "onnx",
                   "--out", tmp_path / "mine.onnx", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    import onnxruntime as ort

    sess = ort.InferenceSession(str(tmp_path / "mine.onnx"), providers=["CPUExecutionProvider"])
    assert [o.name for o in sess.get_outputs()] == ["compensated", "drift", "out_of_range"]
    dtypes = {"tensor(float)": np.float32, "tensor(double)": np.float64}
    feeds = {i.name: np.full([d if isinstance(d, int) else 2 for d in i.shape], 30.0,
                             dtype=dtypes[i.type]) for i in sess.get_inputs()}
    compensated, drift, _ = sess.run(None, feeds)
    assert np.isfinite(drift).all() and np.abs(drift).max() > 0     # a fitted curve, not zeros


def test_an_unknown_name_lists_the_installed_family(plugin_path, tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("families: [{family: my-quadratc}]\n")
    r = _thermonet(plugin_path, "compare", cfg, "--out", tmp_path / "out", cwd=tmp_path)
    assert r.returncode == 1
    line = r.stderr.strip()
    assert "\n" not in line and "unknown model family 'my-quadratc'" in line
    assert line.endswith(f"valid: {', '.join(BUILTIN)}, my-quadratic)")   # built-ins, then it
