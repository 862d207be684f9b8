"""Family specs: each model family as a small torch-free object of explicit keyword parameters,
the one source of its hyper-parameters, their defaults and their rules.

A spec names one registered family and its hyper-parameters, nothing else: ``Poly(degree=3)``,
``RBF(n_centres=8, tail=3)``, ``Linear()``.  It is what the API takes
(``DriftEstimator(family=Poly(degree=3))``, nested parameters ``family__degree`` for
scikit-learn's ``get_params``/``set_params``/``clone``/``GridSearchCV``) and what a config's
``{family: poly, params: {degree: 3}}`` becomes (:func:`thermonet.models.registry.make_spec`),
so the API and the config are checked by one rule.

A spec class declares each hyper-parameter once, as a field with its default and its rule
(:func:`param`, the rules of :mod:`thermonet.models.hyper`)::

    class Poly(FamilySpec):
        key, target = "poly", "thermonet.models.poly:Poly"
        degree: int = param(default=3, rule=integer(1, 12))
        cross: bool = param(default=False, rule=boolean())

and everything else is derived from those fields: the keyword constructor (a dataclass's),
:meth:`~FamilySpec.param_names`, :meth:`~FamilySpec.defaults`, :meth:`~FamilySpec.rules`, the
config's torch-free checks and the torch family's own: a built-in family class names its spec
(``spec = specs.Poly``) and takes from it its name, its inputs, its hyper-parameters' defaults
and their checks (:meth:`FamilySpec.resolve`, :meth:`thermonet.models.base.Family.take_hyper`).

A spec

* stores its keywords and checks nothing when made (scikit-learn's rule: ``set_params`` and
  ``clone`` never raise on a value); :meth:`FamilySpec.check` checks them — names, the input
  count against :attr:`~FamilySpec.max_inputs`, and values against the declared rules (a
  :class:`~thermonet.models.hyper.HyperError` naming the key);
* knows its family's inputs: :attr:`~FamilySpec.max_inputs` and
  :attr:`~FamilySpec.default_inputs`;
* builds the torch module (:meth:`FamilySpec.build`), importing torch only then — this module
  imports neither torch nor scikit-learn.

One class per built-in family, named after its registry key (``ts-fuzzy`` is :class:`Fuzzy`).
A plug-in family is either a spec of its own (declared as above, its ``target`` or
``family_cls`` its torch class) or a torch family class alone, which gets a generic spec made
from its constructor's keyword-only arguments (:func:`spec_for_class`); its constructor then
checks its values.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar, dataclass_transform

from ..core.errors import ConfigError
from .hyper import (
    MLP_ACTIVATIONS,
    RBF_INITS,
    Rule,
    boolean,
    bounded,
    check_rules,
    choice,
    integer,
    layer_sizes,
    number,
    ridge,
    universe,
    weights,
)

__all__ = ["FamilySpec", "Linear", "Poly", "Lorentz", "Fuzzy", "RBF", "MLP", "GRU", "BUILTIN_SPECS",
           "spec_for_class", "declared_spec", "SHAPE", "set_builder", "param"]

#: Keyword arguments of every family's constructor that are not hyper-parameters.
SHAPE = ("n_inputs", "n_outputs")

_KEYWORDS = (inspect.Parameter.KEYWORD_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)

#: What builds a family by name (``name, n_inputs=, n_outputs=, hyper=`` -> the torch module):
#: :func:`thermonet.models.registry.build_family`, which looks the name up among the
#: registered families and plug-ins and names a failing plug-in.  The registry sets it when
#: it loads (it imports this module; this module never imports it, so the two are no circle),
#: and it always loads first: ``thermonet.models`` imports it before any of its modules.
#: (A family is typed ``Any`` here: :mod:`thermonet.models.base` imports this module, for the
#: spec a family class names or declares, so this one never imports it.)
_builder: Callable[..., Any] | None = None


def set_builder(builder: Callable[..., Any]) -> None:
    """Make ``builder`` what :meth:`FamilySpec.build` calls (the registry's, once)."""
    global _builder
    _builder = builder


def param(*, default: Any, rule: Rule | None = None) -> Any:
    """One hyper-parameter of a spec class: its ``default`` and its ``rule`` (a
    :class:`~thermonet.models.hyper.Rule`; None: checked by building the family)."""
    return dataclasses.field(default=default, metadata={"rule": rule})


@dataclass_transform(kw_only_default=True, eq_default=False, field_specifiers=(param,))
class FamilySpec:
    """One family and its hyper-parameters (module docstring).  Subclasses declare their
    hyper-parameters as fields, ``name: type = param(default=..., rule=...)``: each subclass is
    made a keyword-only dataclass (its own ``__init__``, where it has one, is kept)."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        dataclasses.dataclass(kw_only=True, eq=False, repr=False)(cls)

    #: The registry name (``poly``, ``ts-fuzzy``...).
    key: ClassVar[str] = ""
    #: The torch family, ``"module:Class"``, imported by :meth:`family_class`.
    target: ClassVar[str] = ""
    #: Most inputs the family takes (None: any number).
    max_inputs: ClassVar[int | None] = None
    #: The inputs the API uses when none are given.
    default_inputs: ClassVar[tuple[str, ...]] = ("dT",)

    @classmethod
    def param_names(cls) -> tuple[str, ...]:
        """The hyper-parameters' names, in the constructor's order."""
        return tuple(name for name, p in inspect.signature(cls.__init__).parameters.items()
                     if name != "self" and p.kind in _KEYWORDS)

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """Each hyper-parameter's default (those without one are left out)."""
        params = inspect.signature(cls.__init__).parameters
        return {k: params[k].default for k in cls.param_names()
                if params[k].default is not inspect.Parameter.empty}

    # ------------------------------------------------ scikit-learn's parameter protocol
    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """The hyper-parameters by name (``deep`` changes nothing: a spec nests nothing)."""
        return {k: getattr(self, k) for k in self.param_names() if hasattr(self, k)}

    def set_params(self, **params: Any) -> FamilySpec:
        """Set hyper-parameters by name (values are checked by :meth:`check`); a name the
        family does not take is one :class:`ConfigError` naming the valid ones."""
        valid = self.param_names()
        for key, value in params.items():
            if key not in valid:
                raise ConfigError(f"model '{self.key}': unknown hyper-parameter '{key}' "
                                  f"(valid: {', '.join(valid) or 'none'})")
            setattr(self, key, value)
        return self

    def hyper(self) -> dict[str, Any]:
        """The hyper-parameters as the family's constructor takes them."""
        return dict(self.get_params())

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self.get_params() == other.get_params()

    __hash__ = None  # type: ignore[assignment]  # mutable, as a scikit-learn estimator

    def __repr__(self) -> str:
        defaults = self.defaults()
        shown = [f"{k}={v!r}" for k, v in self.get_params().items()
                 if k not in defaults or not _same(v, defaults[k])]
        return f"{type(self).__name__}({', '.join(shown)})"

    # ---------------------------------------------------------------- checks, build
    def check(self, n_inputs: int | None = None, *, values: bool = True) -> dict[str, Any]:
        """Refuse too many inputs and (with ``values``) a value the family does not take;
        returns the hyper-parameters.  A spec whose every hyper-parameter has a rule (every
        built-in's) checks its values without torch (:meth:`checked`); a generic plug-in's by
        building it (its constructor checks them)."""
        if n_inputs is not None and self.max_inputs is not None and n_inputs > self.max_inputs:
            raise ConfigError(f"model '{self.key}' takes at most {self.max_inputs} input(s), "
                              f"got {n_inputs}")
        hyper = self.hyper()
        if values:
            if self.rules() is not None:
                self.checked()
            else:
                self.build(n_inputs=max(int(n_inputs or 1), 1), n_outputs=1)
        return hyper

    @classmethod
    def rules(cls) -> dict[str, Rule] | None:
        """Each hyper-parameter's rule, declared with :func:`param`; None where one has none,
        and for a generic spec made from a constructor (the family's constructor checks)."""
        if cls.from_constructor or not dataclasses.is_dataclass(cls):
            return None
        out = {f.name: f.metadata.get("rule") for f in dataclasses.fields(cls)}
        if set(out) != set(cls.param_names()) or any(r is None for r in out.values()):
            return None
        return {k: r for k, r in out.items() if r is not None}

    def joint(self, values: dict[str, Any]) -> None:
        """A rule between hyper-parameters (each already checked): raise a ConfigError where
        ``values`` break it.  None here; the RBF has one."""

    def checked(self) -> dict[str, Any]:
        """Every hyper-parameter checked against its rule, as the family stores it (``[lo,
        hi]`` a list of floats, an integer an ``int``), then the joint rule; a value outside
        is a :class:`~thermonet.models.hyper.HyperError` naming the family and the key."""
        values = check_rules(self.key, self.rules() or {}, self.hyper())
        self.joint(values)
        return values

    @classmethod
    def resolve(cls, given: Mapping[str, Any]) -> dict[str, Any]:
        """What a family's constructor does with its hyper-parameter keywords: a name the
        family does not take is one :class:`ConfigError` naming the valid ones, a missing one
        takes the spec's default, and every value is checked (:meth:`checked`)."""
        valid = cls.param_names()
        for key in given:
            if key not in valid:
                raise ConfigError(f"model '{cls.key}': unknown hyper-parameter '{key}' "
                                  f"(valid: {', '.join(valid) or 'none'})")
        return cls(**given).checked()

    #: The torch family class itself, where the spec was made from it (:func:`spec_for_class`,
    #: :func:`declared_spec`).
    family_cls: ClassVar[type | None] = None
    #: Whether the spec was read from a constructor's signature (:func:`spec_for_class`): no
    #: rules then, the family's constructor checks its values.
    from_constructor: ClassVar[bool] = False

    @classmethod
    def family_class(cls) -> type:
        """The torch family class, a :class:`thermonet.models.base.Family` (imports it, and
        torch)."""
        if cls.family_cls is not None:
            return cls.family_cls
        module, _, attr = cls.target.partition(":")
        obj: Any = importlib.import_module(module)
        for part in attr.split("."):
            obj = getattr(obj, part)
        return obj

    def build(self, *, n_inputs: int, n_outputs: int) -> Any:
        """The torch module for ``n_inputs`` inputs and ``n_outputs`` outputs (imports torch
        now) through the registry's :func:`~thermonet.models.registry.build_family`
        (:func:`set_builder`): a plug-in's failure is one line naming it (its guard)."""
        if _builder is None:  # only where thermonet.models.registry was never imported
            raise RuntimeError("thermonet.models.registry is not loaded: import thermonet.models")
        return _builder(self.key, n_inputs=n_inputs, n_outputs=n_outputs, hyper=self.hyper())


def _same(a: Any, b: Any) -> bool:
    try:
        return bool(a == b) and type(a) is type(b)
    except Exception:  # an array-like: compare as shown
        return repr(a) == repr(b)


class Linear(FamilySpec):
    """``linear``: a straight line in every input (no hyper-parameters)."""

    key, target = "linear", "thermonet.models.linear:Linear"
    max_inputs, default_inputs = None, ("T",)


class Poly(FamilySpec):
    """``poly``: a polynomial of ``degree`` (1..12) in the inputs; ``cross`` adds the
    monomials mixing several inputs (total degree ≤ ``degree``); ``mix`` (one weight per
    input, summing to 1; no cross terms) fits each input's polynomial alone and ships their
    weighted sum (:class:`thermonet.models.poly.Poly`)."""

    key, target = "poly", "thermonet.models.poly:Poly"
    max_inputs, default_inputs = None, ("dT",)

    degree: int = param(default=3, rule=integer(1, 12))
    cross: bool = param(default=False, rule=boolean())
    mix: list[float] | None = param(default=None, rule=weights())


class Lorentz(FamilySpec):
    """``lorentz``: Origin's Lorentzian peak in one input; ``xc_margin`` bounds the centre
    to the data span widened by this fraction on each side."""

    key, target = "lorentz", "thermonet.models.lorentz:Lorentz"
    max_inputs, default_inputs = 1, ("T",)

    xc_margin: float = param(default=1.0, rule=number(
        0.0, 100.0, "a number in [0, 100] (fraction of the data span)"))


class Fuzzy(FamilySpec):
    """``ts-fuzzy``: a Takagi–Sugeno fuzzy model of ``n_sets`` (2..64) membership sets over
    ``universe`` ([lo, hi], None: the trained range), one input."""

    key, target = "ts-fuzzy", "thermonet.models.fuzzy:TSFuzzy"
    max_inputs, default_inputs = 1, ("T",)

    n_sets: int = param(default=6, rule=integer(2, 64))
    universe: Sequence[float] | None = param(default=None, rule=universe())


class RBF(FamilySpec):
    """``rbf``: ``n_centres`` Gaussians (``init`` kmeans, quantiles or random, widths × ``width_scale``)
    with a polynomial ``tail`` (0..3) in the first input and a ``ridge`` (``"cv"``: chosen
    by inner cross-validation)."""

    key, target = "rbf", "thermonet.models.rbf:RBF"
    max_inputs, default_inputs = None, ("dT", "dT2")

    n_centres: int = param(default=16, rule=integer(1, 4096))
    init: str = param(default="kmeans", rule=choice(RBF_INITS))
    width_scale: float = param(default=1.0, rule=number(0.0, float("inf"), "a finite number > 0",
                                                        lo_open=True))
    tail: int = param(default=0, rule=integer(0, 3, "an integer in 0..3 (the degree of the "
                                                    "polynomial in the first input; 0: none)"))
    ridge: float | str = param(default="cv", rule=ridge())

    def joint(self, values: dict[str, Any]) -> None:
        """A tail needs a closed-form fit: ``init`` kmeans or quantiles."""
        if values.get("tail", 0) and values.get("init", "kmeans") == "random":
            raise ConfigError("rbf: a polynomial tail needs init 'kmeans' or 'quantiles' (a "
                              "closed-form fit)")


class MLP(FamilySpec):
    """``mlp``: a small multilayer perceptron (``hidden`` layer sizes, ``activation``,
    ``weight_decay``)."""

    key, target = "mlp", "thermonet.models.mlp:MLP"
    max_inputs, default_inputs = None, ("dT",)

    hidden: Sequence[int] = param(default=(8, 8), rule=layer_sizes())
    activation: str = param(default="tanh", rule=choice(MLP_ACTIVATIONS))
    weight_decay: float = param(default=1e-6, rule=number(0.0, float("inf"),
                                                          "a finite number >= 0"))


class GRU(FamilySpec):
    """``gru``: a recurrent model (``hidden`` units stepped every ``step_s`` seconds, restarted
    after gaps over ``gap_s``; trained on ``chunk``-step windows after ``warmup`` steps with
    its own ``lr`` and ``weight_decay``)."""

    key, target = "gru", "thermonet.models.gru:GRU"
    max_inputs, default_inputs = None, ("dT",)

    hidden: int = param(default=8, rule=bounded(1, 64, True))
    step_s: float = param(default=10.0, rule=bounded(1e-3, 86400.0, False))
    gap_s: float = param(default=60.0, rule=bounded(1e-3, 1e7, False))
    chunk: int = param(default=64, rule=bounded(2, 100_000, True))
    warmup: int = param(default=30, rule=bounded(0, 100_000, True))
    lr: float = param(default=3e-3, rule=bounded(1e-6, 1.0, False))
    weight_decay: float = param(default=1e-6, rule=bounded(0.0, 1e3, False))


#: The built-in families' specs, in the registry's order.
BUILTIN_SPECS: tuple[type[FamilySpec], ...] = (Linear, Poly, Lorentz, Fuzzy, RBF, MLP, GRU)


def declared_spec(cls: type) -> type[FamilySpec] | None:
    """The spec a family class declares in its own body — its hyper-parameters as
    :func:`param` fields (``knee: float = param(default=25.0, rule=number(...))``) — made into
    a spec class of its ``name``, ``max_inputs`` and ``default_inputs`` (the fields move
    there); None where the body declares none.  Reached as ``cls.spec``
    (:class:`thermonet.models.base.Family` calls this when a subclass is defined)."""
    own = {k: v for k, v in vars(cls).items() if isinstance(v, dataclasses.Field)}
    if not own:
        return None
    hints = vars(cls).get("__annotations__", {})
    for k in own:
        delattr(cls, k)
    name = str(getattr(cls, "name", "") or cls.__name__)
    return type(cls.__name__, (FamilySpec,), {
        **own, "__annotations__": {k: hints.get(k, "Any") for k in own},
        "key": name, "target": f"{cls.__module__}:{cls.__qualname__}",
        "max_inputs": getattr(cls, "max_inputs", None),
        "default_inputs": tuple(getattr(cls, "default_inputs", ("dT",))), "family_cls": cls,
        "__doc__": f"The spec of family {name!r}, declared in {cls.__qualname__}.",
        "__module__": cls.__module__, "__qualname__": f"{cls.__qualname__}.spec"})


def spec_for_class(key: str, cls: type, target: str = "") -> type[FamilySpec]:
    """The spec class of a family class (a plug-in's): the one it declares (its own ``spec``,
    :func:`declared_spec`), under ``key``; else a generic one whose hyper-parameters are the
    constructor's keyword-only arguments other than ``n_inputs``/``n_outputs``, with their
    defaults (read with :func:`inspect.signature` on the imported class)."""
    own = vars(cls).get("spec")
    if isinstance(own, type) and issubclass(own, FamilySpec):
        return own if own.key == key else type(own.__name__, (own,), {
            "key": key, "__module__": own.__module__, "__qualname__": own.__qualname__})
    sig = inspect.signature(cls.__init__)  # type: ignore[misc]
    params = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for name, p in sig.parameters.items()
              if p.kind is inspect.Parameter.KEYWORD_ONLY and name not in SHAPE]
    names = [p.name for p in params]

    def __init__(self: FamilySpec, **kwargs: Any) -> None:
        for p in params:
            if p.name in kwargs:
                setattr(self, p.name, kwargs.pop(p.name))
            elif p.default is not inspect.Parameter.empty:
                setattr(self, p.name, p.default)
        if kwargs:
            raise ConfigError(f"model '{key}': unknown hyper-parameter '{next(iter(kwargs))}' "
                              f"(valid: {', '.join(names) or 'none'})")

    __init__.__signature__ = inspect.Signature(  # type: ignore[attr-defined]
        [inspect.Parameter("self", inspect.Parameter.POSITIONAL_OR_KEYWORD), *params])
    default_inputs = getattr(cls, "default_inputs", ("dT",))
    return type(getattr(cls, "__name__", "Family"), (FamilySpec,), {
        "__init__": __init__, "key": key, "target": target or f"{cls.__module__}:{cls.__qualname__}",
        "max_inputs": getattr(cls, "max_inputs", None),
        "default_inputs": tuple(default_inputs), "family_cls": cls, "from_constructor": True,
        "__doc__": f"The spec of family {key!r} ({cls.__module__}.{cls.__qualname__}).",
        "__module__": __name__})
