"""Typed configuration: dataclasses hold the defaults, YAML files only override them.

The comparison config (:class:`CompareConfig`) and its families (:class:`FamilyConfig`), loaded
from YAML and checked whole; its other sections are
:mod:`thermonet.training.config_sections`', the split's :mod:`thermonet.training.splits`' and
the training settings :class:`~thermonet.core.trainconfig.TrainConfig`.

A comparison config (``configs/*.yaml``) has the sections below; every key is
optional and falls back to the dataclass default.  Unknown keys and wrong
types are errors that name the file and the dotted key
(``configs/x.yaml: key 'families[1].param': unknown key``).  The resolved
config (defaults filled in) is saved with every run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import yaml

from ..core.errors import ConfigError
from ..core.fileio import not_a_file
from ..core.names import LABEL
from ..core.schema import from_dict, to_dict
from ..core.trainconfig import TrainConfig  # the ``train`` section is TrainConfig itself
from ..core.yamlio import YamlRefusal, load_yaml
from ..features.inputs import signals_for
from ..features.target import MODES, modelled_outputs
from ..models.hyper import HyperError
from ..models.registry import make_spec
from ..models.shipped import MODEL_KINDS
from ..scoring.fleetstats import parse_limits
from ..sim.presets import MAX_RUNS, preset_problem
from .config_sections import (  # the other sections: their own module
    BandConfig,
    DataConfig,
    FeatureConfig,
    SelectionConfig,
    StationConfig,
    TrackingConfig,
)
from .splits import SplitConfig  # the split section: the strategies' own module

if TYPE_CHECKING:
    from ..models.specs import FamilySpec

# TrackingConfig: workflows/calibrate_compare.py and learn.py build a CompareConfig with it
__all__ = [
    "SplitConfig", "FamilyConfig", "TrainConfig", "TrackingConfig", "CompareConfig",
    "load_config", "from_dict", "to_dict", "outputs_of", "train_config_of",
    "config_from_mapping", "tune_points",
]


@dataclass
class FamilyConfig:
    """One entry of the comparison: a registered family with its inputs and hyper-parameters."""

    family: str = "poly"
    name: str | None = None              # label in reports (default: the family name)
    inputs: list[str] = field(default_factory=lambda: ["dT"])
    params: dict[str, Any] = field(default_factory=dict)   # family hyper-parameters
    # hyper-parameter -> values tried by cross-validation on the training pool (compare
    # chooses one; configs/README.md "Tuning"); the values override `params`
    tune: dict[str, list[Any]] = field(default_factory=dict)
    train: dict[str, Any] = field(default_factory=dict)    # overrides of the `train` section
    # "heating": fit only on samples where the temperature is not falling (dT/dt > −0.05 °C/min),
    # as PX4's and ArduPilot's calibrations do — to reproduce that anchor faithfully
    train_on: Literal["all", "heating"] = "all"

    @property
    def label(self) -> str:
        return self.name or self.family

    def spec(self, point: dict[str, Any] | None = None) -> FamilySpec:
        """This entry as its family's spec (:mod:`thermonet.models.specs`) with ``params``
        (and a ``tune`` grid point over them): ``{family: poly, params: {degree: 3}}`` is
        ``Poly(degree=3)``, what ``DriftEstimator(family=...)`` takes — one rule for both.
        Names are checked (an unknown family or hyper-parameter is a ConfigError), values by
        the spec's :meth:`~thermonet.models.specs.FamilySpec.check`."""
        return make_spec(self.family, {**self.params, **(point or {})})


#: The default set's delays (minutes) of the cubic at the delayed temperature (a 1-2-5
#: series): a sensing element a minute to five behind its thermometer (the package, the
#: board); the folds are purged by 3 τ of the longest, so a longer one costs the folds data.
DELAYS_MIN = (1, 2, 5)


def _default_families() -> list[FamilyConfig]:
    """The recommended set a config gets when it names no families (configs/README.md, "Default families").

    * ``cubic``: PX4's / ArduPilot's cubic in ΔT — the baseline every report compares with;
    * the studies' families: ``linear``, ``lorentz`` (000), ``ts-fuzzy`` (002), ``rbf`` on
      [ΔT, ΔT²] (003) with the cubic in ΔT as its unpenalised tail and the Gaussian part's
      ridge and width chosen by inner cross-validation (:mod:`thermonet.models.rbf`): at
      worst it is the cubic; its centres at ΔT's quantiles (``init: quantiles``: as good as
      k-means' or better on held-out data, ``experiments/bench_rbf_centres.py``, the same on
      every run and without scikit-learn's import);
    * models with dynamic inputs (:mod:`thermonet.features.dynamics`): ``poly3-rate`` (all monomials
      of total degree ≤ 3 in ΔT and dT/dt: the cubic plus rate, rate², rate³ and the cross
      terms) and ``poly3-hyst`` (the same on [ΔT, dT/dt, play_1]: a hysteresis memory of
      half-width 1 °C that tells the heating from the cooling branch and keeps it through a
      soak); ``cubic-delayed-1min``, ``-2min``, ``-5min``: the cubic at the temperature
      delayed by a first-order lag of 1, 2 or 5 minutes (``delayed_<τ>``: a sensing element
      that lags its thermometer; one input, so no joint envelope).  All fit in closed form
      (least squares) in about a second; an RBF on dynamic
      inputs fits no better on the heat/cool benchmark and costs minutes, so it is not in the
      default set (name it in a config).
    """
    return [
        FamilyConfig(family="poly", name="cubic", inputs=["dT"], params={"degree": 3}),
        FamilyConfig(family="linear", name="linear", inputs=["dT"]),
        FamilyConfig(family="lorentz", name="lorentz", inputs=["dT"],
                     tune={"xc_margin": [0.25, 1.0, 4.0]}),
        FamilyConfig(family="ts-fuzzy", name="ts-fuzzy", inputs=["dT"], params={"n_sets": 6},
                     tune={"n_sets": [3, 4, 6, 8]}),
        FamilyConfig(family="rbf", name="rbf", inputs=["dT", "dT2"],
                     params={"n_centres": 16, "tail": 3, "init": "quantiles"},
                     tune={"n_centres": [8, 16]}),
        *(FamilyConfig(family="poly", name=f"cubic-delayed-{m}min", inputs=[f"delayed_{60 * m}"],
                       params={"degree": 3}) for m in DELAYS_MIN),
        FamilyConfig(family="poly", name="poly3-rate", inputs=["dT", "rate"],
                     params={"degree": 3, "cross": True}, tune={"degree": [1, 2, 3]}),
        FamilyConfig(family="poly", name="poly3-hyst", inputs=["dT", "rate", "play_1"],
                     params={"degree": 3, "cross": True}, tune={"degree": [1, 2, 3]}),
    ]


@dataclass
class CompareConfig:
    """A whole comparison: data, split, features, families, training, tracking."""

    data: DataConfig = field(default_factory=DataConfig)
    split: SplitConfig = field(default_factory=SplitConfig)
    selection: SelectionConfig = field(default_factory=SelectionConfig)
    band: BandConfig = field(default_factory=BandConfig)
    station: StationConfig = field(default_factory=StationConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    families: list[FamilyConfig] = field(default_factory=_default_families)
    train: TrainConfig = field(default_factory=TrainConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    # What each output's drift is relative to (thermonet.features.target): "drift" = every axis at its
    # default (a ref_ channel → channel; gyro → zero; acc/mag/baro/out → at-t-ref), or a
    # mapping {kind or output name: channel | zero | at-t-ref}.  four-position: per soak, the
    # bias K0 and scale factor K1 of each axis from a static multi-position test (study 000);
    # outputs `<axis>.bias` and `<axis>.scale` are then modelled together.
    target: Literal["drift", "four-position"] | dict[str, str] = "drift"
    # "bias" (default): every family models each axis's drift, compensated = raw − drift.
    # "sensor": the full sensor model per triad, compensated = M(s)⁻¹ (raw − b(s)), bias b and
    # M = I + E (scale factors, misalignment) each a function of the inputs from the family;
    # needs reference channels with known excitation (thermonet.training.sensor, configs/README.md)
    model: Literal["bias", "sensor"] = "bias"
    baseline: str | None = "cubic"       # the family label the report compares against (PX4/ArduPilot's)
    description: str = ""
    # pass/fail limits per output axis or "*" (thermonet.scoring.fleetstats.LimitSpec), judged per
    # unit on held-out data by `thermonet fleet`
    limits: dict[str, Any] = field(default_factory=dict)
    # families fitted side by side (threads; thermonet.workflows.compare_fit.family_workers): 0 = one per
    # CPU this process may use, 1 = one after another.  `thermonet fleet` runs units side
    # by side instead and fits each unit's families one after another.
    workers: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) \
                or self.workers < 0:
            raise ConfigError(f"key 'workers': must be an integer >= 0 (0: one per "
                              f"CPU), got {self.workers!r}")


# ----------------------------------------------------------------- loading
def outputs_of(cfg: CompareConfig, ds: Any) -> list[str]:
    """The outputs a comparison fits: the config's ``data.outputs`` or the data's axes (each
    axis's bias and scale for the four-position target)."""
    return modelled_outputs(cfg.data.outputs or ds.axes, cfg.target)


def train_config_of(cfg: CompareConfig, fam: FamilyConfig) -> TrainConfig:
    """The ``train`` section with the family's own overrides applied."""
    return from_dict(TrainConfig, {**to_dict(cfg.train), **fam.train},
                     source="config", prefix=f"families[{fam.label}].train")


def load_config(path: str | Path | None) -> CompareConfig:
    """Load a comparison config and check all of it; ``None`` gives the built-in default.

    Everything a config can get wrong is found here, before any data is read,
    any directory created or anything logged: unknown keys and wrong types
    (every family's ``train:`` overrides included), family names that are not
    safe file names (:data:`thermonet.core.names.LABEL`), duplicate names or
    inputs, unknown families, inputs or hyper-parameters, and a ``baseline``
    that names no family, and a ``target`` mode that does not exist (whether
    a ``target`` key names an output is checked against the data, once read).
    An empty file is an error (it would otherwise run the built-in simulator
    comparison without a word); only *no* config argument runs the default.
    """
    if path is None:
        return CompareConfig()
    p = Path(path)
    why = not_a_file(p, "config file")
    if why:
        raise ConfigError(f"{p}: {why}")
    try:
        data = load_yaml(p)
    except YamlRefusal as err:
        raise ConfigError(f"{p}: {err}") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{p}:{where} not valid YAML ({getattr(err, 'problem', err)})") from None
    if data is None:
        raise ConfigError(f"{p}: empty config file (give at least one section; run "
                          "'thermonet compare' without a config for the built-in default)")
    return config_from_mapping(data, source=str(p))


def config_from_mapping(data: Any, *, source: str = "config") -> CompareConfig:
    """A comparison config from a mapping (a config file's content, or a dict in Python),
    checked as :func:`load_config` checks a file; ``source`` names it in errors."""
    p = source
    cfg = from_dict(CompareConfig, data, source=p)
    labels = [f.label for f in cfg.families]
    dup = sorted({x for x in labels if labels.count(x) > 1})
    if dup:
        raise ConfigError(
            f"{p}: key 'families': duplicate family name {dup[0]!r} (give each a distinct 'name')"
        )
    if not cfg.families:
        raise ConfigError(f"{p}: key 'families': empty list (need at least one family)")
    check_families(cfg, source=p, build=False)  # torch-free; compare builds them
    if cfg.selection.per_axis and len(cfg.families) < 2:
        raise ConfigError(f"{p}: key 'selection.per_axis': a per-axis choice needs two or more "
                          f"families to choose from (families: {', '.join(labels)})")
    if cfg.band.level is not None and cfg.selection.folds == 0:
        raise ConfigError(f"{p}: key 'band.level': the band is estimated from out-of-fold "
                          "residuals, and selection.folds is 0 (none); set selection.folds "
                          ">= 2 or remove band.level")
    _check_data(cfg.data, p)
    _check_target(cfg.target, p)
    for key, (want, why) in MODEL_KINDS[cfg.model].config_requires.items():  # the kind's data
        got = _dotted(cfg, key)
        if got != want:
            raise ConfigError(f"{p}: key '{key}': " + why.format(got=got))
    if data.get("baseline") is not None and cfg.baseline not in labels:  # the default may lapse
        raise ConfigError(f"{p}: key 'baseline': no family named {cfg.baseline!r} (families: "
                          f"{', '.join(labels)})")

    parse_limits(cfg.limits, source=p)
    cfg._source = p  # not a field: names the file in later errors
    return cfg


def check_families(cfg: CompareConfig, *, source: str = "config", build: bool = True) -> None:
    """Refuse an unknown family, input or hyper-parameter before any data is read.

    A family that cannot be fitted *on the data* is reported by ``compare`` and
    the comparison goes on; a family the config names wrongly is an error.  Names,
    inputs and input counts are checked without torch; ``build`` (what ``compare``,
    ``fleet`` and the API do before reading data) also builds each family, which checks
    the hyper-parameters' values.
    """
    for i, fam in enumerate(cfg.families):
        key = f"families[{i}]"
        if LABEL.fullmatch(fam.label) is None:  # the label names models/<label>.pt
            raise ConfigError(f"{source}: key '{key}.name': {fam.label[:60]!r} is not a safe "
                              "family name (letters, digits, '_', '.', '-', not starting with "
                              "'.' or '-', at most 64 characters)")
        if isinstance(fam.inputs, list) and not fam.inputs:   # every model reads one or more
            raise ConfigError(f"{source}: key '{key}.inputs': an empty list; name at least one "
                              "input (such as [dT]), or leave the key out for [dT]")
        if len(set(fam.inputs)) != len(fam.inputs):
            raise ConfigError(f"{source}: key '{key}.inputs': {fam.inputs} names an input twice")
        from_dict(TrainConfig, {**to_dict(cfg.train), **fam.train}, source=source,
                  prefix=f"{key}.train")
        try:
            signals_for(fam.inputs)
        except ConfigError as err:
            raise ConfigError(f"{source}: key '{key}.inputs': {err}") from None
        if not isinstance(fam.family, str):
            raise ConfigError(f"{source}: key '{key}.family': expected a family name such "
                              f"as 'poly', got {fam.family!r}")
        # the family's spec (thermonet.models.specs), as DriftEstimator(family=...) takes it:
        # names, then the input count, then values — the API's rule
        try:
            fam.spec().check(len(fam.inputs), values=False)
        except ConfigError as err:
            raise ConfigError(f"{source}: key '{key}': {err}") from None
        try:
            make_spec(fam.family, {k: None for k in fam.tune})
        except ConfigError as err:
            raise ConfigError(f"{source}: key '{key}.tune': {err}") from None
        points = tune_points(fam, source, key)
        # every value, each grid point's with the fixed ones: a built-in's without torch
        # (thermonet.models.hyper), a plug-in's by building it — before any data is read
        for point in points:
            try:
                fam.spec(point).check(len(fam.inputs))
            except HyperError as err:
                sub = f"tune.{err.key}" if err.key in point else f"params.{err.key}"
                raise ConfigError(f"{source}: key '{key}.{sub}': {err}") from None
            except ConfigError as err:
                sub = "tune" if point else "params"
                raise ConfigError(f"{source}: key '{key}.{sub}': {err}") from None
            except TypeError as err:  # a hyper-parameter of the wrong type
                raise ConfigError(f"{source}: key '{key}.params': {err}") from None
        if not build:
            continue
        for point in points:
            sub = f"{key}.tune" if fam.tune else f"{key}.params"
            try:
                fam.spec(point).build(n_inputs=len(fam.inputs), n_outputs=1)
            except ConfigError as err:
                raise ConfigError(f"{source}: key '{sub}': {err}") from None
            except TypeError as err:  # a hyper-parameter of the wrong type
                raise ConfigError(f"{source}: key '{sub}': {err}") from None


#: The most grid points one family may ask to be cross-validated (each costs K fits).
MAX_TUNE_POINTS = 16


def tune_points(fam: FamilyConfig, source: str = "config", key: str = "families") -> list[dict[str, Any]]:
    """The grid points of ``fam.tune`` (``[{}]`` without one), its shape checked."""
    import itertools

    n = 1
    for name, values in fam.tune.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f"{source}: key '{key}.tune.{name}': give a non-empty list of "
                              f"values to try, got {values!r}")
        n *= len(values)
    if n > MAX_TUNE_POINTS:
        raise ConfigError(f"{source}: key '{key}.tune': {n} grid points (at most "
                          f"{MAX_TUNE_POINTS}: each costs one fit per cross-validation fold)")
    keys = list(fam.tune)
    return [dict(zip(keys, c, strict=True)) for c in itertools.product(*fam.tune.values())]


def _check_data(data: DataConfig, source: str) -> None:
    """Bounds of the ``data`` section that need no data: the preset's name (when no
    ``paths`` are given: the preset is then simulated), run count, seed."""
    if not data.paths and data.preset is not None:
        why = preset_problem(data.preset)
        if why:
            raise ConfigError(f"{source}: key 'data.preset': {why}")
    if data.runs is not None and not 1 <= data.runs <= MAX_RUNS:
        raise ConfigError(f"{source}: key 'data.runs': {data.runs} is not in 1..{MAX_RUNS} "
                          "(the upper bound keeps a request within memory)")
    if data.seed < 0:
        raise ConfigError(f"{source}: key 'data.seed': {data.seed} is negative")
    for key, low in (("in_memory_samples", 0), ("chunk_rows", 1), ("max_rows", 1000)):
        value = getattr(data, key)
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ConfigError(f"{source}: key 'data.{key}': {value!r} is not a whole number "
                              f">= {low}")


def _dotted(cfg: Any, key: str) -> Any:
    """The config's value at a dotted key (``tracking.register``)."""
    for part in key.split("."):
        cfg = getattr(cfg, part)
    return cfg


def _check_target(target: str | dict[str, str], source: str) -> None:
    """The ``target`` section's modes (its keys name outputs: checked once the data are read)."""
    if not isinstance(target, dict):
        return  # a Literal: already checked by from_dict
    for key, mode in target.items():
        if not isinstance(key, str) or not key:
            raise ConfigError(f"{source}: key 'target': {key!r} is not an output or kind name")
        if mode not in MODES:
            raise ConfigError(f"{source}: key 'target.{key[:64]}': {mode!r} is not one of "
                              f"{', '.join(MODES)}")
