"""Config loading: defaults, overrides, unknown keys and wrong types named."""

import re
from pathlib import Path

import pytest

from thermonet.core.errors import ConfigError
from thermonet.training.config import CompareConfig, load_config, to_dict

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "c.yaml"
    p.write_text(text)
    return p


def test_default_is_the_simulator():
    cfg = load_config(None)
    assert cfg.data.preset == "patent-gyro"
    assert [f.label for f in cfg.families] == ["cubic", "linear", "lorentz", "ts-fuzzy", "rbf",
                                               "cubic-delayed-1min", "cubic-delayed-2min",
                                               "cubic-delayed-5min", "poly3-rate", "poly3-hyst"]
    assert [f.inputs for f in cfg.families[5:8]] == [["delayed_60"], ["delayed_120"],
                                                     ["delayed_300"]]
    hyst = cfg.families[-1]
    assert hyst.inputs == ["dT", "rate", "play_1"] and hyst.params == {"degree": 3, "cross": True}
    # configs/default.yaml (make demo) names no families: it gets the same set
    assert [f.label for f in load_config(CONFIGS / "default.yaml").families] == \
        [f.label for f in cfg.families]


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.yaml")), ids=lambda p: p.stem)
def test_shipped_configs_load(path):
    cfg = load_config(path)
    assert isinstance(cfg, CompareConfig)
    assert cfg.families
    assert to_dict(cfg)["data"]["preset"] == cfg.data.preset


def test_override_keeps_other_defaults(tmp_path):
    cfg = load_config(write(tmp_path, "train:\n  lr: 0.05\n"))
    assert cfg.train.lr == 0.05
    assert cfg.train.max_epochs == CompareConfig().train.max_epochs


def test_int_accepted_for_float(tmp_path):
    assert load_config(write(tmp_path, "features:\n  t_ref: 25\n")).features.t_ref == 25.0


@pytest.mark.parametrize("text, key", [
    ("dataa: {}\n", "'dataa'"),
    ("train:\n  lrate: 0.1\n", "'train.lrate'"),
    ("families:\n  - {family: poly, degree: 3}\n", "'families[0].degree'"),
])
def test_unknown_key_named(tmp_path, text, key):
    with pytest.raises(ConfigError, match=re.escape(f"key {key}: unknown key")):
        load_config(write(tmp_path, text))


@pytest.mark.parametrize("text, key", [
    ("train:\n  max_epochs: many\n", "'train.max_epochs'"),
    ("train:\n  max_epochs: 1.5\n", "'train.max_epochs'"),
    ("tracking:\n  enabled: 'yes'\n", "'tracking.enabled'"),
    ("split:\n  strategy: random\n", "'split.strategy'"),
    ("families: 3\n", "'families'"),
    ("families:\n  - {family: rbf, inputs: dT}\n", "'families[0].inputs'"),
])
def test_wrong_type_named(tmp_path, text, key):
    with pytest.raises(ConfigError, match=re.escape(f"c.yaml: key {key}")):
        load_config(write(tmp_path, text))


def test_duplicate_family_names(tmp_path):
    text = "families:\n  - {family: poly}\n  - {family: poly}\n"
    with pytest.raises(ConfigError, match="duplicate family name 'poly'"):
        load_config(write(tmp_path, text))


def test_a_family_with_no_inputs_is_refused_when_the_config_loads(tmp_path):
    """Not after the data are read, under families[0].params with an output count."""
    text = "families: [{name: a, family: poly, inputs: []}]\n"
    with pytest.raises(ConfigError) as err:
        load_config(write(tmp_path, text))
    msg = str(err.value)
    assert msg == (f"{tmp_path / 'c.yaml'}: key 'families[0].inputs': an empty list; name at "
                   "least one input (such as [dT]), or leave the key out for [dT]")


def test_missing_and_invalid_yaml(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(write(tmp_path, "a: [1, 2\n"))


# ---------------------------------------------- family hyper-parameters, before any data
#: (family, params, the key named): values every built-in family refuses
BAD_HYPER = [
    ("poly", "{degree: 0}", "params.degree"), ("poly", "{degree: 13}", "params.degree"),
    ("poly", "{degree: 2.5}", "params.degree"), ("poly", "{degree: true}", "params.degree"),
    ("poly", "{degree: '3'}", "params.degree"), ("poly", "{cross: 'no'}", "params.cross"),
    ("poly", "{cross: 1}", "params.cross"),
    ("lorentz", "{xc_margin: -0.5}", "params.xc_margin"),
    ("lorentz", "{xc_margin: .nan}", "params.xc_margin"),
    ("lorentz", "{xc_margin: 101}", "params.xc_margin"),
    ("ts-fuzzy", "{n_sets: 1}", "params.n_sets"), ("ts-fuzzy", "{n_sets: 65}", "params.n_sets"),
    ("ts-fuzzy", "{universe: [3, 1]}", "params.universe"),
    ("ts-fuzzy", "{universe: [0, .inf]}", "params.universe"),
    ("ts-fuzzy", "{universe: [0]}", "params.universe"),
    ("ts-fuzzy", "{universe: 'wide'}", "params.universe"),
    ("rbf", "{n_centres: 0}", "params.n_centres"), ("rbf", "{n_centres: 5000}",
                                                    "params.n_centres"),
    ("rbf", "{init: grid}", "params.init"), ("rbf", "{width_scale: .inf}", "params.width_scale"),
    ("rbf", "{width_scale: 0}", "params.width_scale"), ("rbf", "{tail: 4}", "params.tail"),
    ("rbf", "{ridge: -1}", "params.ridge"), ("rbf", "{ridge: auto}", "params.ridge"),
    ("rbf", "{tail: 3, init: random}", "params"),
    ("mlp", "{hidden: 8}", "params.hidden"), ("mlp", "{hidden: [8, 0]}", "params.hidden"),
    ("mlp", "{hidden: [1, 1, 1, 1, 1]}", "params.hidden"),
    ("mlp", "{activation: sigmoid}", "params.activation"),
    ("mlp", "{weight_decay: -1e-6}", "params.weight_decay"),
    ("gru", "{hidden: 65}", "params.hidden"), ("gru", "{step_s: 0}", "params.step_s"),
    ("gru", "{gap_s: .inf}", "params.gap_s"), ("gru", "{chunk: 1}", "params.chunk"),
    ("gru", "{warmup: -1}", "params.warmup"), ("gru", "{lr: 2}", "params.lr"),
    ("gru", "{weight_decay: 1e4}", "params.weight_decay"),
    ("poly", "{degre: 3}", ""), ("linear", "{degree: 1}", ""),
]


@pytest.mark.parametrize("family, params, key", BAD_HYPER)
def test_a_bad_hyper_parameter_is_refused_when_the_config_loads(tmp_path, family, params, key):
    """Refused by load_config itself — before the data, torch or any directory — in one
    line naming the file and the dotted key of the value."""
    text = f"data: {{paths: [no/such/file.parquet]}}\nfamilies:\n" \
           f"  - {{family: {family}, inputs: [dT], params: {params}}}\n"
    with pytest.raises(ConfigError) as err:
        load_config(write(tmp_path, text))
    msg = str(err.value)
    assert "\n" not in msg and f"c.yaml: key 'families[0]{'.' + key if key else ''}" in msg, msg
    assert "no/such/file" not in msg


@pytest.mark.parametrize("tune, key", [
    ("{degree: [2, 13]}", "families[0].tune.degree"),
    ("{degree: [2, true]}", "families[0].tune.degree"),
    ("{cross: [true, 'no']}", "families[0].tune.cross"),
])
def test_every_grid_value_is_checked_when_the_config_loads(tmp_path, tune, key):
    text = f"families:\n  - {{family: poly, inputs: [dT], tune: {tune}}}\n"
    with pytest.raises(ConfigError, match=re.escape(f"key '{key}'")):
        load_config(write(tmp_path, text))


def test_hyper_parameter_values_are_checked_without_torch(tmp_path):
    import subprocess
    import sys

    cfg = write(tmp_path, "families:\n  - {family: rbf, inputs: [dT], params: "
                          "{width_scale: .inf}}\n")
    code = ("import sys\nfrom thermonet.training.config import load_config\n"
            f"try:\n    load_config({str(cfg)!r})\nexcept ValueError as e:\n    print(e)\n"
            "print('torch' in sys.modules)\n")
    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=root, timeout=120)
    assert r.returncode == 0, r.stderr
    said, torch_loaded = r.stdout.strip().splitlines()
    assert "key 'families[0].params.width_scale'" in said and torch_loaded == "False"


def test_the_rules_are_the_constructors(tmp_path):
    """One declaration (each family's spec, thermonet.models.specs) for the config and the
    families' constructors: each built-in's constructor refuses what the config refuses, with
    the same words."""
    from thermonet.models import build_family
    from thermonet.models.hyper import HyperError
    from thermonet.models.mlp import ACTIVATIONS
    from thermonet.models.registry import BUILTIN, family_signature
    from thermonet.models.specs import RBF

    for name, spec in BUILTIN.items():         # every hyper-parameter has a rule
        rules = spec.rules()
        assert rules is not None and set(family_signature(name).hyper) == set(rules), name
    said = BUILTIN["mlp"].rules()["activation"].said   # type: ignore[index]
    assert set(ACTIVATIONS) == set(said.split("one of ")[1].split(", "))
    with pytest.raises(HyperError) as table:
        RBF(width_scale=float("inf")).checked()
    with pytest.raises(HyperError) as built:
        build_family("rbf", n_inputs=1, n_outputs=1, hyper={"width_scale": float("inf")})
    assert str(table.value) == str(built.value) and built.value.key == "width_scale"
