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
                                               "poly3-rate", "poly3-hyst"]
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


def test_missing_and_invalid_yaml(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(write(tmp_path, "a: [1, 2\n"))
