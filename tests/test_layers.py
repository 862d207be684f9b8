"""The package's layers: a config loads without torch, and a built-in family's torch-free spec
(thermonet.models.specs) is the one source of the hyper-parameters, defaults and input limits of
the family class it builds."""

from __future__ import annotations

import inspect
import subprocess
import sys
from pathlib import Path

import pytest

from thermonet.models.registry import BUILTIN

ROOT = Path(__file__).resolve().parents[1]


def test_load_config_is_public_and_torch_free():
    code = ("import sys, thermonet\n"
            "cfg = thermonet.load_config('configs/default.yaml')\n"
            "print(len(cfg.families), cfg.families[0].label, 'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    n, first, torch_loaded = out.stdout.split()
    assert int(n) >= 5 and first == "cubic"
    assert torch_loaded == "False"


def test_a_wrong_hyper_parameter_is_refused_without_torch(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("families: [{family: ts-fuzzy, params: {n_set: 4}}]\n")
    code = ("import sys, thermonet\n"
            "from thermonet.core.errors import ConfigError\n"
            f"try:\n    thermonet.load_config({str(cfg)!r})\n"
            "except ConfigError as err:\n    print(err)\n"
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    msg, torch_loaded = out.stdout.strip().splitlines()
    assert msg.startswith(f"{cfg}: key 'families[0]': model 'ts-fuzzy': unknown hyper-parameter "
                          "'n_set' (valid: n_sets")
    assert torch_loaded == "False"


@pytest.mark.parametrize("name", list(BUILTIN))
def test_the_spec_matches_the_class(name):
    """The spec is the one source: the family class names it and takes from it its name, its
    inputs, its hyper-parameters and their defaults (built with none given, it states the
    spec's defaults as its rules store them), and refuses what the spec refuses."""
    from thermonet.core.errors import ConfigError
    from thermonet.models.registry import family_signature, get_family

    spec = BUILTIN[name]
    cls = get_family(name)
    assert cls.spec is spec and cls.name == spec.key == name
    assert spec.target == f"{cls.__module__}:{cls.__qualname__}"
    assert spec.param_names() == family_signature(name).hyper
    assert spec.max_inputs == cls.max_inputs == family_signature(name).max_inputs
    assert list(spec.default_inputs) == list(cls.default_inputs)
    # no default written in the class: its constructor's only keywords are the shape's
    params = inspect.signature(cls.__init__).parameters
    assert [k for k, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY] == \
        ["n_inputs", "n_outputs"]
    stated = cls(n_inputs=1, n_outputs=1).hyper()
    assert set(stated) <= set(spec.param_names())
    assert stated == {k: v for k, v in spec().checked().items() if k in stated}
    with pytest.raises(ConfigError, match=f"model '{name}': unknown hyper-parameter 'nope'"):
        cls(n_inputs=1, n_outputs=1, nope=1)
