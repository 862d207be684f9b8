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


# ------------------------------------------------------------------ hostile plug-ins
# Each is a real installed distribution: a module and a ``<name>.dist-info`` folder (METADATA
# and entry_points.txt) in a directory put on sys.path, found through importlib.metadata as
# pip's would be.  The process's registry is reset around each test.

_GOOD_FAMILY = '''
import torch
from thermonet.models import Family


class Fam(Family):
    name, max_inputs = "{name}", 1

    def __init__(self, *, n_inputs, n_outputs, scale=1.0):
        super().__init__(n_inputs=n_inputs, n_outputs=n_outputs)
        self.scale = scale   # stored under its name: a checkpoint rebuilds the family
        {init}
        self.w = torch.nn.Parameter(torch.zeros(n_outputs))

    def forward(self, z):
        {forward}

    def initialize(self, x, y, *, seed=0, x_mean=None, x_std=None):
        pass
{extra}
'''


def _family_source(name: str, *, init: str = "pass",
                   forward: str = "return z[:, :1] * self.w", extra: str = "") -> str:
    return _GOOD_FAMILY.format(name=name, init=init, forward=forward, extra=extra)


@pytest.fixture
def install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``install(name, source, attr="Fam")``: a distribution whose entry point
    ``name = <module>:<attr>`` in the group thermonet.families loads ``source``."""
    from thermonet.models import registry

    site = tmp_path / "site"
    site.mkdir()
    modules: list[str] = []

    def reset() -> None:
        registry._plugins.cache_clear()
        registry._MODELS = None

    monkeypatch.setattr(registry, "_MODELS", None)
    registry._plugins.cache_clear()

    def _install(name: str, source: str, attr: str = "Fam") -> str:
        module = f"tn_plugin_{len(modules)}_{tmp_path.name.replace('-', '_')}"
        modules.append(module)
        (site / f"{module}.py").write_text(textwrap.dedent(source))
        info = site / f"{module}-0.1.dist-info"
        info.mkdir()
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {module}\nVersion: 0.1\n")
        (info / "entry_points.txt").write_text(
            f"[thermonet.families]\n{name} = {module}:{attr}\n")
        monkeypatch.syspath_prepend(str(site))
        registry._plugins.cache_clear()
        return f"{name} = {module}:{attr}"

    yield _install
    for m in modules:
        sys.modules.pop(m, None)
    reset()


#: What a plug-in's module may do when it is imported, and what the error then says.
IMPORT_FAILURES = {
    "runtime-error": ('raise RuntimeError("the licence server is down")\n',
                      "RuntimeError: the licence server is down"),
    "syntax-error": ("def broken(:\n    pass\n", "SyntaxError"),
    "sys-exit-7": ("import sys\nsys.exit(7)\n", "sys.exit(7)"),
    "bare-system-exit": ("raise SystemExit\n", "sys.exit(None)"),
    "missing-dependency": ("import thermonet_no_such_module_x\n", "ModuleNotFoundError"),
    "key-error": ("{}['x']\n", "KeyError"),
    "zero-division": ("1 / 0\n", "ZeroDivisionError"),
}


@pytest.mark.parametrize("case", sorted(IMPORT_FAILURES))
def test_a_plugin_failing_at_import_is_one_line_naming_it(install, case, tmp_path):
    from thermonet.core.errors import ConfigError
    from thermonet.models.registry import get_family
    from thermonet.training.config import load_config

    body, said = IMPORT_FAILURES[case]
    entry = install("broken-fam", body)
    for call in (lambda: get_family("broken-fam"),
                 lambda: load_config(_config(tmp_path, "broken-fam"))):
        with pytest.raises(ConfigError) as err:
            call()
        msg = str(err.value)
        assert "\n" not in msg, msg
        assert "model family 'broken-fam'" in msg and f"'{entry}'" in msg and said in msg, msg


def _config(tmp_path: Path, family: str, params: str = "{}") -> Path:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"families: [{{family: {family}, inputs: [dT], params: {params}}}]\n")
    return cfg


@pytest.mark.parametrize("case", ["runtime-error", "syntax-error", "sys-exit-7"])
def test_the_command_line_says_a_broken_plugin_in_one_line_and_exits_1(install, case, tmp_path,
                                                                       capsys):
    from thermonet.cli import main

    entry = install("broken-fam", IMPORT_FAILURES[case][0])
    code = main(["compare", str(_config(tmp_path, "broken-fam")), "--out",
                 str(tmp_path / "out"), "--no-track"])
    err = capsys.readouterr().err.strip()
    assert code == 1
    assert "\n" not in err and err.startswith("thermonet: error: ") and entry in err, err
    assert not (tmp_path / "out").exists()


def test_a_plugin_calling_sys_exit_does_not_end_the_process(install, tmp_path):
    """As a separate process too: exit status 1 and one line, not a silent 7."""
    install("exit-fam", "import sys\nsys.exit(7)\n")
    site = tmp_path / "site"                     # where the fixture installed it
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)])}
    r = subprocess.run([sys.executable, "-m", "thermonet.cli", "compare",
                        str(_config(tmp_path, "exit-fam")), "--out", str(tmp_path / "out"),
                        "--no-track"], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 1, (r.returncode, r.stderr)
    line = r.stderr.strip()
    assert "\n" not in line and "sys.exit(7)" in line and "'exit-fam = " in line, line


def test_ctrl_c_while_a_plugin_imports_goes_through(install):
    from thermonet.models.registry import get_family

    install("slow-fam", "raise KeyboardInterrupt\n")
    with pytest.raises(KeyboardInterrupt):
        get_family("slow-fam")


#: Entry points that load but are no family, or families whose constructor fails.
BUILD_FAILURES = {
    "not-a-class": ("Fam = 3\n", "Fam", "is not a subclass of thermonet.models.Family"),
    "not-a-family": ("class Fam:\n    pass\n", "Fam", "is not a subclass"),
    "no-such-attribute": (_family_source("x"), "Missing", "AttributeError"),
    "constructor-raises": (_family_source("x", init='raise RuntimeError("no GPU here")'), "Fam",
                           "RuntimeError: no GPU here"),
    "constructor-exits": (_family_source("x", init="import sys; sys.exit(3)"), "Fam",
                          "sys.exit(3)"),
    "constructor-type-error": (_family_source("x", init="len(5)"), "Fam", "TypeError"),
}


@pytest.mark.parametrize("case", sorted(BUILD_FAILURES))
def test_a_plugin_that_is_no_family_or_cannot_be_built_is_refused_before_data(install, case,
                                                                              tmp_path):
    """The config is refused when it is loaded (its families are built to check their
    values), and the API refuses before it looks at the data (None here)."""
    import thermonet
    from thermonet.core.errors import ConfigError
    from thermonet.training.config import load_config

    source, attr, said = BUILD_FAILURES[case]
    entry = install("odd-fam", source, attr)
    with pytest.raises(ConfigError) as err:
        load_config(_config(tmp_path, "odd-fam"))
    msg = str(err.value)
    assert "\n" not in msg and "key 'families[0]" in msg and f"'{entry}'" in msg and said in msg
    with pytest.raises(ConfigError) as err:
        thermonet.DriftEstimator("odd-fam", "dT").fit(None)       # data never looked at
    assert "odd-fam" in str(err.value) and said in str(err.value)


def test_a_broken_plugin_is_said_and_the_others_still_work(install):
    from thermonet.models.registry import models

    install("broken-fam", 'raise RuntimeError("boom")\n')
    install("fine-fam", _family_source("fine-fam", forward="return z * self.w"))
    with pytest.warns(UserWarning, match="broken-fam.*RuntimeError: boom"):
        registry = models()
    assert "broken-fam" not in registry and "fine-fam" in registry and "poly" in registry


@pytest.mark.parametrize("value, said", [
    (-1.0, "scale must be > 0"), (0.0, "scale must be > 0"), ("big", "scale must be > 0"),
])
def test_a_plugins_own_value_checks_run_before_data(install, tmp_path, value, said):
    """A plug-in checks its values in its constructor: the config is built to ask it."""
    from thermonet.core.errors import ConfigError
    from thermonet.training.config import load_config

    init = ('if isinstance(scale, bool) or not isinstance(scale, (int, float)) or scale <= 0:\n'
            '            raise ValueError(f"scale must be > 0, got {scale!r}")')
    install("scaled", _family_source("scaled", init=init, forward="return z * self.w"))
    with pytest.raises(ConfigError) as err:
        load_config(_config(tmp_path, "scaled", f"{{scale: {value!r}}}"))
    msg = str(err.value)
    assert "key 'families[0].params'" in msg and "'scaled = " in msg and said in msg, msg
    load_config(_config(tmp_path, "scaled", "{scale: 2.0}"))     # a good value passes


# -------------------------------------------------------------- output shapes
def _three_axes():
    from dataclasses import replace

    from conftest import toy_dataset
    from thermonet.core.recording import Dataset

    ds = toy_dataset(n_runs=2, noise=0.0005)
    return Dataset([replace(r, outputs={**r.outputs, "gyro_y": 0.5 * r.outputs["gyro_x"],
                                        "gyro_z": -r.outputs["gyro_x"]},
                            units={**r.units, "gyro_y": "deg/s", "gyro_z": "deg/s"})
                    for r in ds])


#: forward bodies (z: (N, 1) standardised input, self.w: (A,)) and the shape they give
BAD_FORWARDS = {
    "one-column-for-three-axes": "return z[:, :1] * self.w[0]",
    "one-row": "return (z * self.w).mean(0, keepdim=True)",
    "an-extra-row": "return torch.cat([z * self.w, z[:1] * self.w])",
    "transposed": "return (z * self.w).T",
    "flat": "return (z * self.w).sum(1)",
    "not-a-tensor": "return (z * self.w).detach().numpy()",
    "raises": 'raise RuntimeError("forward broke")',
}


@pytest.mark.parametrize("case", sorted(BAD_FORWARDS))
def test_a_family_with_the_wrong_output_shape_is_refused_naming_it(install, case):
    import thermonet
    from thermonet.core.errors import FitError

    install("shape-fam", _family_source("shape-fam", forward=BAD_FORWARDS[case]))
    ds = _three_axes()
    with pytest.raises(FitError) as err:
        thermonet.DriftEstimator("shape-fam", "dT", max_epochs=3).fit(ds[0])
    msg = str(err.value)
    assert "\n" not in msg and "model 'shape-fam'" in msg and "forward()" in msg, msg
    if case not in ("raises", "not-a-tensor"):
        assert "for 7 rows and 3 output axes, expected a tensor of shape (7, 3)" in msg, msg


def test_a_wrong_drift_layout_is_refused_too(install):
    """drift() is the evaluation path (ONNX, C): (A, N), axis-major."""
    import thermonet
    from thermonet.core.errors import FitError

    extra = ("\n    def drift(self, z, y_std, y_mean):\n"
             "        return self(torch.stack(list(z), dim=1)) * y_std + y_mean\n")
    install("layout-fam", _family_source("layout-fam", forward="return z * self.w",
                                         extra=extra))
    with pytest.raises(FitError, match=r"model 'layout-fam': its drift\(\) gave \(7, 3\) for 7 "
                                       r"rows and 3 output axes, expected .* \(3, 7\)"):
        thermonet.DriftEstimator("layout-fam", "dT", max_epochs=3).fit(_three_axes()[0])


def test_a_well_shaped_plugin_fits_and_a_misshaped_one_fails_alone_in_compare(install):
    """In a comparison the misshaped family is reported failed, naming the shape; the
    others are fitted and judged."""
    import thermonet

    install("good-fam", _family_source("good-fam", forward="return z * self.w"))
    install("bad-fam", _family_source("bad-fam", forward=BAD_FORWARDS[
        "one-column-for-three-axes"]))
    res = thermonet.compare({
        "families": [{"name": "cubic", "family": "poly", "inputs": ["dT"],
                      "params": {"degree": 3}},
                     {"name": "good", "family": "good-fam", "inputs": ["dT"]},
                     {"name": "bad", "family": "bad-fam", "inputs": ["dT"]}],
        "train": {"max_epochs": 3}, "selection": {"folds": 0}}, data=_three_axes(),
        plots=False)
    assert res.families["cubic"].ok and res.families["good"].ok
    bad = res.families["bad"]
    assert bad.status == "failed" and "model 'bad-fam'" in bad.reason
    assert "expected a tensor of shape" in bad.reason and "3 output axes" in bad.reason


@pytest.mark.parametrize("family, hyper", [
    ("linear", {}), ("poly", {"degree": 2}), ("poly", {"degree": 2, "cross": True}),
    ("lorentz", {}), ("ts-fuzzy", {"n_sets": 3}), ("rbf", {"n_centres": 4}),
    ("rbf", {"n_centres": 4, "tail": 3}), ("mlp", {"hidden": [4]}), ("gru", {"hidden": 2}),
])
def test_every_built_in_family_passes_the_shape_probe(family, hyper):
    """The probe runs on every family; the built-ins give (N, A) and (A, N)."""
    import torch

    from thermonet.models import build_family
    from thermonet.models.base import check_output_shape

    fam = build_family(family, n_inputs=1, n_outputs=3, hyper=hyper)
    z = torch.linspace(-1.5, 1.5, 50, dtype=torch.float32)[:, None]
    y = torch.cat([z, z ** 2, -z], dim=1)
    if fam.recurrent:
        fam.start(0)
    else:
        fam.initialize(z.double(), y.double(), seed=0, x_mean=np.zeros(1), x_std=np.ones(1))
    check_output_shape(fam, z, family)
