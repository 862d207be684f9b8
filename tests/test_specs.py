"""Family specs (thermonet.models.specs): one torch-free object per family, shared by the API and
the config, and scikit-learn's own estimator checks on DriftEstimator with every built-in family.

scikit-learn's checks feed ``fit`` 2-D arrays; a DriftEstimator fits recordings (the drift is in
them, and so is the temperature every family needs), so its own tags say ``two_d_array=False``
and scikit-learn would skip every check.  ``_Checked`` lifts that one tag so that the whole list
runs: the checks on parameters, cloning, construction, tags and the unfitted state must pass;
the ones that fit arrays are expected failures, each with its reason (``xfail_strict``: one that
starts passing, or one that stops, fails this file).  What those checks ask of ``fit`` —
returns self, leaves its parameters alone, pickles, is idempotent — is checked on recordings in
``test_fit_keeps_scikit_learns_rules_on_recordings``.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.utils.estimator_checks import parametrize_with_checks

import thermonet
from conftest import toy_dataset
from thermonet.core.errors import ConfigError
from thermonet.models import registry
from thermonet.models.specs import GRU, MLP, RBF, Fuzzy, Linear, Lorentz, Poly, spec_for_class

ROOT = Path(__file__).resolve().parents[1]

#: One spec per built-in family, by registry key (a new built-in must be added here).
SPECS = {"linear": Linear(), "poly": Poly(), "lorentz": Lorentz(), "ts-fuzzy": Fuzzy(),
         "rbf": RBF(), "mlp": MLP(), "gru": GRU()}


class _Checked(thermonet.DriftEstimator):
    """DriftEstimator with scikit-learn's 2-D-array tag lifted (module docstring)."""

    def __sklearn_tags__(self):  # noqa: ANN204
        tags = super().__sklearn_tags__()
        tags.input_tags.two_d_array = True
        return tags


#: fit takes recordings (a Recording, a list of them or a Dataset: the drift and the
#: temperature the families need are in them), not a 2-D feature array X
_RECORDINGS = "fit takes recordings, not a 2-D array X"
#: scikit-learn's checks that cannot apply: each fits (or predicts on) an array X.
EXPECTED_FAILED = {name: _RECORDINGS for name in (
    "check_complex_data", "check_dict_unchanged", "check_dont_overwrite_parameters",
    "check_dtype_object", "check_estimator_sparse_array", "check_estimator_sparse_matrix",
    "check_estimator_sparse_tag", "check_estimators_dtypes",
    "check_estimators_empty_data_messages", "check_estimators_fit_returns_self",
    "check_estimators_nan_inf", "check_estimators_overwrite_params", "check_estimators_pickle",
    "check_f_contiguous_array_estimator", "check_fit2d_1feature", "check_fit2d_1sample",
    "check_fit2d_predict1d", "check_fit_check_is_fitted", "check_fit_idempotent",
    "check_fit_score_takes_y", "check_methods_sample_order_invariance",
    "check_methods_subset_invariance", "check_n_features_in", "check_n_features_in_after_fitting",
    "check_pipeline_consistency", "check_positive_only_tag_during_fit",
    "check_readonly_memmap_input", "check_regressor_data_not_an_array", "check_regressors_int",
    "check_regressors_no_decision_function", "check_regressors_train", "check_supervised_y_2d")}
#: predict before fit raises thermonet's NotFittedError (an AttributeError and a ValueError, as
#: scikit-learn's is), not scikit-learn's class itself: thermonet.api does not import
#: scikit-learn (test_the_api_follows_scikit_learns_protocol_without_importing_it)
EXPECTED_FAILED["check_estimators_unfitted"] = "thermonet's NotFittedError, not scikit-learn's"


def test_the_check_list_is_the_one_expected():
    """Every family runs the same checks: those that must pass and the expected failures."""
    names = {_check_name(c) for c in _CASES}
    assert len(_ALL_CHECKS.args[1]) - len(_CASES) == len(SPECS)     # one array-API check each
    assert set(EXPECTED_FAILED) <= names
    assert {"check_no_attributes_set_in_init", "check_parameters_default_constructible",
            "check_get_params_invariance", "check_set_params",
            "check_do_not_raise_errors_in_init_or_set_params", "check_estimator_cloneable",
            "check_estimator_repr", "check_fit1d"} <= names - set(EXPECTED_FAILED)


def test_every_built_in_family_has_a_spec():
    assert list(SPECS) == list(registry.BUILTIN) == list(registry.FAMILIES)[:len(SPECS)]
    for key, spec in SPECS.items():
        assert spec.key == key and registry.spec_class(key) is type(spec)


def _check_name(case) -> str:
    check = (case.values if hasattr(case, "values") else case)[1]
    return getattr(check, "func", check).__name__


with warnings.catch_warnings():   # the protocol without the class: scikit-learn warns once
    warnings.filterwarnings("ignore", "Estimator _Checked does not inherit from", UserWarning)
    _ALL_CHECKS = parametrize_with_checks(
        [_Checked(spec, "dT", max_epochs=2) for spec in SPECS.values()],
        expected_failed_checks=lambda est: EXPECTED_FAILED, xfail_strict=True)
#: scikit-learn skips its array-API check unless SCIPY_ARRAY_API is set before scipy loads;
#: it feeds arrays too (cannot apply), so it is left out rather than reported as skipped.
_SKIPPED_BY_SCIKIT_LEARN = "check_array_api_input"
_CASES = [c for c in _ALL_CHECKS.args[1] if _check_name(c) != _SKIPPED_BY_SCIKIT_LEARN]


@pytest.mark.parametrize(_ALL_CHECKS.args[0], _CASES, ids=_ALL_CHECKS.kwargs["ids"])
def test_scikit_learns_estimator_checks(estimator, check):
    check(estimator)


def test_the_real_estimator_declares_its_input_is_no_array():
    tags = thermonet.DriftEstimator("poly").__sklearn_tags__()
    assert tags.input_tags.two_d_array is False and tags.target_tags.required is False


def test_the_api_follows_scikit_learns_protocol_without_importing_it():
    code = ("import sys\n"
            "import thermonet\n"
            "from thermonet.api import DriftEstimator, NotFittedError, Poly\n"
            "est = DriftEstimator(Poly(degree=2), 'dT')\n"
            "est.set_params(family__degree=4, max_epochs=3)\n"
            "p = est.get_params()\n"
            "print(p['family__degree'], p['max_epochs'], 'sklearn' in sys.modules, "
            "'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    assert out.stdout.split() == ["4", "3", "False", "False"]
    with pytest.raises(thermonet.NotFittedError) as err:
        thermonet.DriftEstimator("poly").predict(toy_dataset(n_runs=1)[0])
    assert isinstance(err.value, AttributeError) and isinstance(err.value, ValueError)


# ------------------------------------------------------------------ torch-free
def test_the_specs_import_without_torch_or_scikit_learn():
    code = ("import sys\n"
            "from thermonet.models.specs import Poly, RBF\n"
            "from thermonet.models.registry import make_spec\n"
            "spec = make_spec('rbf', {'n_centres': 8})\n"
            "spec.check(2)\n"
            "print(spec == RBF(n_centres=8), Poly(degree=2), "
            "'torch' in sys.modules, 'sklearn' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    assert out.stdout.split() == ["True", "Poly(degree=2)", "False", "False"]


# ------------------------------------------------------------- the spec itself
@pytest.mark.parametrize("key", list(SPECS))
def test_a_spec_builds_its_family_with_its_hyper_parameters(key):
    spec = SPECS[key]
    fam = spec.build(n_inputs=1, n_outputs=2)
    assert type(fam).__name__ == spec.target.split(":")[1] and fam.name == key
    # the family states the spec's values (its own normalised forms: a list for a tuple)
    stated = fam.hyper()
    for name, value in spec.hyper().items():
        if name in stated:
            want = list(value) if isinstance(value, tuple) else value
            assert stated[name] == want, (name, stated[name], want)


def test_the_documented_specs_are_the_declared_defaults():
    """configs/README.md's table of specs (each written out with its defaults) states what
    each spec declares: every cell, evaluated, is the spec with its declared defaults."""
    from thermonet.models import specs

    text = (ROOT / "configs" / "README.md").read_text(encoding="utf-8")
    section = text.split("### Family specs: the same family in a config and in Python", 1)[1]
    table = section.split("| key | spec", 1)[1].split("\n\n", 1)[0]
    rows = table.splitlines()[2:]
    cells = dict((c.strip().strip("`") for c in row.strip("|").split("|")[:2]) for row in rows)
    assert list(cells) == list(SPECS)
    for key, cell in cells.items():
        made = eval(cell, vars(specs))                  # noqa: S307 - the docs' own text
        assert type(made) is type(SPECS[key]) and made.get_params() == type(made).defaults(), key


def test_a_spec_stores_its_keywords_and_checks_them_when_asked():
    spec = Poly(degree=40, cross="no")                 # stored as given (scikit-learn)
    assert spec.get_params() == {"degree": 40, "cross": "no", "mix": None}
    with pytest.raises(ConfigError, match=r"^poly: degree must be an integer in 1\.\.12, got 40$"):
        spec.check(1)
    with pytest.raises(ConfigError, match=r"model 'lorentz' takes at most 1 input\(s\), got 2"):
        Lorentz().check(2)
    with pytest.raises(ConfigError, match=r"model 'poly': unknown hyper-parameter 'degre' "
                                          r"\(valid: degree, cross, mix\)"):
        Poly().set_params(degre=3)
    with pytest.raises(TypeError):
        Poly(degre=3)                                   # a constructor of explicit keywords
    assert Poly(degree=2).set_params(degree=4) == Poly(degree=4) != Poly(degree=2)
    assert repr(RBF(n_centres=8, tail=3)) == "RBF(n_centres=8, tail=3)" and repr(Linear()) == \
        "Linear()"
    twin = clone(RBF(n_centres=8))
    assert twin == RBF(n_centres=8) and twin is not RBF(n_centres=8)


def test_a_plug_in_class_gets_a_generic_spec_from_its_constructor():
    class Mine:
        max_inputs, default_inputs = 1, ["T"]

        def __init__(self, *, n_inputs, n_outputs, scale=1.0, order=2):
            pass

    cls = spec_for_class("mine", Mine)
    spec = cls(scale=3.0)
    assert cls.param_names() == ("scale", "order") and cls.defaults() == {"scale": 1.0, "order": 2}
    assert spec.get_params() == {"scale": 3.0, "order": 2} and spec.key == "mine"
    assert (cls.max_inputs, cls.default_inputs) == (1, ("T",)) and repr(spec) == "Mine(scale=3.0)"
    with pytest.raises(ConfigError, match=r"model 'mine': unknown hyper-parameter 'scal' "
                                          r"\(valid: scale, order\)"):
        cls(scal=3.0)
    assert clone(spec) == spec


def test_register_family_is_the_one_way_in(monkeypatch):
    monkeypatch.setattr(registry, "FAMILIES", dict(registry.FAMILIES))

    class Cubic(Poly):
        key = "cubic-only"

    assert registry.register_family(Cubic) is Cubic
    assert registry.FAMILIES["cubic-only"] is Cubic and "cubic-only" in registry.family_names()
    assert registry.make_spec("cubic-only", {"degree": 2}) == Cubic(degree=2)
    with pytest.raises(ValueError, match="'poly' is already registered"):
        registry.register_family(Poly)
    # a torch family class registers as it is: a generic spec made from its constructor
    from thermonet.models.poly import Poly as TorchPoly

    class Square(TorchPoly):         # keeps poly's own name for poly's value checks
        def __init__(self, *, n_inputs, n_outputs, cross=False):
            super().__init__(n_inputs=n_inputs, n_outputs=n_outputs, degree=2, cross=cross)

    registry.register_family(Square, name="square")
    spec = registry.make_spec("square", {"cross": True})
    assert type(spec).param_names() == ("cross",) and spec.key == "square"
    fam = spec.build(n_inputs=2, n_outputs=1)
    assert type(fam) is Square and fam.hyper()["degree"] == 2 and fam.hyper()["cross"] is True
    assert registry.get_family("square") is Square


# -------------------------------------------- one rule for the config and the API
def test_a_family_by_name_is_its_spec_with_the_defaults_and_is_not_rewritten():
    est = thermonet.DriftEstimator("rbf")
    assert est.family == "rbf" and est.get_params()["family"] == "rbf"   # stored as given
    assert est._family_spec() == RBF() and est._resolved_inputs(RBF()) == ["dT", "dT2"]
    assert thermonet.DriftEstimator("poly", degree=2).family == Poly(degree=2)
    spec = Poly(degree=2)
    est = thermonet.DriftEstimator(spec, degree=3)                       # a copy, not the spec
    assert est.family == Poly(degree=3) and spec == Poly(degree=2)


def test_a_config_entry_is_the_same_spec():
    from thermonet.training.config import FamilyConfig, config_from_mapping

    cfg = config_from_mapping({"families": [
        {"family": "poly", "params": {"degree": 2, "cross": True}, "inputs": ["dT", "rate"]},
        {"family": "ts-fuzzy", "params": {"n_sets": 4}, "inputs": ["T"]}]})
    assert cfg.families[0].spec() == Poly(degree=2, cross=True)
    assert cfg.families[1].spec() == Fuzzy(n_sets=4)
    assert FamilyConfig(family="rbf", tune={"n_centres": [4, 8]}).spec({"n_centres": 4}) == \
        RBF(n_centres=4)


@pytest.mark.parametrize("family, params, said", [
    ("poly", {"degree": 40}, "poly: degree must be an integer in 1..12, got 40"),
    ("rbf", {"tail": 3, "init": "random"}, "rbf: a polynomial tail needs init 'kmeans' or 'quantiles'"),
    ("mlp", {"activation": "sigmoid"}, "mlp: activation must be one of tanh, relu, silu"),
    ("gru", {"hidden": 0}, "gru: hidden must be an integer in [1, 64], got 0"),
    ("ts-fuzzy", {"n_set": 4}, "model 'ts-fuzzy': unknown hyper-parameter 'n_set' (valid: "
                               "n_sets, universe)"),
])
def test_the_config_and_the_api_refuse_a_value_in_the_same_words(family, params, said):
    from thermonet.training.config import config_from_mapping

    with pytest.raises(ConfigError) as cfg_err:
        config_from_mapping({"families": [{"family": family, "params": params,
                                           "inputs": ["dT"]}]})
    with pytest.raises(ConfigError) as api_err:
        thermonet.DriftEstimator(family, "dT", **params).fit(None)
    assert said in str(cfg_err.value) and said in str(api_err.value)
    assert str(cfg_err.value).startswith("config: key 'families[0]")


# ------------------------------------------- scikit-learn's fit rules, on recordings
def test_fit_keeps_scikit_learns_rules_on_recordings():
    """What the array checks above would ask of fit, asked with recordings: fit returns self,
    leaves every parameter (the spec too) as given, is idempotent, and the fitted estimator
    pickles to one that predicts the same; nested grid names reach the spec."""
    from sklearn.model_selection import GridSearchCV

    ds = toy_dataset(n_runs=2)
    spec = Poly(degree=2)
    est = thermonet.DriftEstimator(spec, "dT", max_epochs=0)
    before = {k: repr(v) for k, v in est.get_params().items()}
    assert est.fit(ds[0]) is est
    assert {k: repr(v) for k, v in est.get_params().items()} == before and est.family is spec
    first = est.predict(ds[1])
    np.testing.assert_array_equal(est.fit(ds[0]).predict(ds[1]), first)
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(est)).predict(ds[1]), first)
    blocks = thermonet.time_blocks(ds[0], n_blocks=10)
    search = GridSearchCV(thermonet.DriftEstimator("poly", "dT", max_epochs=0),
                          {"family__degree": [1, 2]}, cv=thermonet.TimeBlockSplit(n_splits=2))
    search.fit(blocks)
    # the toy drift is quadratic: degree 2 wins, and the refitted spec says so
    assert search.best_params_ == {"family__degree": 2}
    assert search.best_estimator_.family == Poly(degree=2)


# ------------------------------------------------------------- one registry shape
def test_every_registry_is_a_dict_and_one_register_function(monkeypatch):
    """Families, split strategies, export formats and dynamic inputs: a dict by name and one
    register function that refuses a name taken twice; what is registered is found by name."""
    from thermonet.exporting import FORMATS, ExportFormat, register_format
    from thermonet.features import dynamics
    from thermonet.training.splits import SPLITS, register_split

    with pytest.raises(ValueError, match="already registered"):
        registry.register_family(Poly)
    with pytest.raises(ValueError, match="already registered"):
        register_split("runs")(lambda runs, cfg, source: [])
    with pytest.raises(ValueError):
        register_format(ExportFormat("onnx", "again", "x:y"))
    with pytest.raises(ValueError, match="already registered"):
        dynamics.register_input(dynamics.Lag)
    assert {"poly", "gru"} <= set(registry.FAMILIES) and "runs" in SPLITS and "onnx" in FORMATS
    assert set(dynamics.INPUTS) == {"rate", "lag", "delayed", "play"}
    # a new kind of dynamic input: registered, its names parse (with the constant required)
    monkeypatch.setattr(dynamics, "INPUTS", dict(dynamics.INPUTS))

    class Slow(dynamics.Lag):
        kind = "slow"

    dynamics.register_input(Slow)
    got = dynamics.parse_dynamic("slow_600")
    assert isinstance(got, Slow) and got.name == "slow_600"
    assert dynamics.parse_dynamic("slow") is None and dynamics.parse_dynamic("slowly") is None
    rate = dynamics.parse_dynamic("rate")
    assert isinstance(rate, dynamics.Rate) and rate.constants()["name"] == "rate"
    with pytest.raises(ConfigError, match="positive"):
        dynamics.parse_dynamic("lag_0")
