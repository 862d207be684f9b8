"""Family specs: each model family as a small torch-free object of explicit keyword parameters.

A spec names one registered family and its hyper-parameters, nothing else: ``Poly(degree=3)``,
``RBF(n_centres=8, tail=3)``, ``Linear()``.  It is what the API takes
(``DriftEstimator(family=Poly(degree=3))``, nested parameters ``family__degree`` for
scikit-learn's ``get_params``/``set_params``/``clone``/``GridSearchCV``) and what a config's
``{family: poly, params: {degree: 3}}`` becomes (:func:`thermonet.models.registry.make_spec`),
so the API and the config are checked by one rule.

A spec

* stores its keywords and checks nothing when made (scikit-learn's rule: ``set_params`` and
  ``clone`` never raise on a value); :meth:`FamilySpec.check` checks them — names, the input
  count against :attr:`~FamilySpec.max_inputs`, and values against
  :mod:`thermonet.models.hyper` (a :class:`~thermonet.models.hyper.HyperError` naming the key);
* knows its family's inputs: :attr:`~FamilySpec.max_inputs` and
  :attr:`~FamilySpec.default_inputs`;
* builds the torch module (:meth:`FamilySpec.build`), importing torch only then — this module
  imports neither torch nor scikit-learn.

One class per built-in family, named after its registry key (``ts-fuzzy`` is :class:`Fuzzy`);
their defaults are the family constructors' own (``tests/test_specs.py`` holds them equal).  A
plug-in family (entry-point group ``thermonet.families``) gets a generic spec made from its
constructor's keyword-only arguments (:func:`spec_for_class`).
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, ClassVar

from ..core.errors import ConfigError
from .hyper import SPECS as RULES
from .hyper import check_values

if TYPE_CHECKING:
    from .base import Family

__all__ = ["FamilySpec", "Linear", "Poly", "Lorentz", "Fuzzy", "RBF", "MLP", "GRU", "BUILTIN_SPECS",
           "spec_for_class", "SHAPE", "set_builder"]

#: Keyword arguments of every family's constructor that are not hyper-parameters.
SHAPE = ("n_inputs", "n_outputs")

_KEYWORDS = (inspect.Parameter.KEYWORD_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)

#: What builds a family by name (``name, n_inputs=, n_outputs=, hyper=`` -> the torch module):
#: :func:`thermonet.models.registry.build_family`, which looks the name up among the
#: registered families and plug-ins and names a failing plug-in.  The registry sets it when
#: it loads (it imports this module; this module never imports it, so the two are no circle),
#: and it always loads first: ``thermonet.models`` imports it before any of its modules.
_builder: Callable[..., Family] | None = None


def set_builder(builder: Callable[..., Family]) -> None:
    """Make ``builder`` what :meth:`FamilySpec.build` calls (the registry's, once)."""
    global _builder
    _builder = builder


class FamilySpec:
    """One family and its hyper-parameters (module docstring).  Subclasses declare their
    hyper-parameters as ``__init__`` keywords with defaults and store each under its name."""

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
        returns the hyper-parameters.  A built-in's values are checked without torch
        (:mod:`thermonet.models.hyper`); a plug-in's by building it (its constructor
        checks them)."""
        if n_inputs is not None and self.max_inputs is not None and n_inputs > self.max_inputs:
            raise ConfigError(f"model '{self.key}' takes at most {self.max_inputs} input(s), "
                              f"got {n_inputs}")
        hyper = self.hyper()
        if values:
            if self.key in RULES and type(self) in BUILTIN_SPECS:
                check_values(self.key, hyper)
            else:
                self.build(n_inputs=max(int(n_inputs or 1), 1), n_outputs=1)
        return hyper

    #: The torch family class itself, where the spec was made from it (:func:`spec_for_class`).
    family_cls: ClassVar[type | None] = None

    @classmethod
    def family_class(cls) -> type[Family]:
        """The torch family class (imports it, and torch)."""
        if cls.family_cls is not None:
            return cls.family_cls
        module, _, attr = cls.target.partition(":")
        obj: Any = importlib.import_module(module)
        for part in attr.split("."):
            obj = getattr(obj, part)
        return obj

    def build(self, *, n_inputs: int, n_outputs: int) -> Family:
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

    def __init__(self) -> None:
        pass


class Poly(FamilySpec):
    """``poly``: a polynomial of ``degree`` (1..12) in the inputs; ``cross`` adds the
    monomials mixing several inputs (total degree ≤ ``degree``)."""

    key, target = "poly", "thermonet.models.poly:Poly"
    max_inputs, default_inputs = None, ("dT",)

    def __init__(self, *, degree: int = 3, cross: bool = False) -> None:
        self.degree = degree
        self.cross = cross


class Lorentz(FamilySpec):
    """``lorentz``: Origin's Lorentzian peak in one input; ``xc_margin`` bounds the centre
    to the data span widened by this fraction on each side."""

    key, target = "lorentz", "thermonet.models.lorentz:Lorentz"
    max_inputs, default_inputs = 1, ("T",)

    def __init__(self, *, xc_margin: float = 1.0) -> None:
        self.xc_margin = xc_margin


class Fuzzy(FamilySpec):
    """``ts-fuzzy``: a Takagi–Sugeno fuzzy model of ``n_sets`` (2..64) membership sets over
    ``universe`` ([lo, hi], None: the trained range), one input."""

    key, target = "ts-fuzzy", "thermonet.models.fuzzy:TSFuzzy"
    max_inputs, default_inputs = 1, ("T",)

    def __init__(self, *, n_sets: int = 6, universe: Sequence[float] | None = None) -> None:
        self.n_sets = n_sets
        self.universe = universe


class RBF(FamilySpec):
    """``rbf``: ``n_centres`` Gaussians (``init`` kmeans, quantiles or random, widths × ``width_scale``)
    with a polynomial ``tail`` (0..3) in the first input and a ``ridge`` (``"cv"``: chosen
    by inner cross-validation)."""

    key, target = "rbf", "thermonet.models.rbf:RBF"
    max_inputs, default_inputs = None, ("dT", "dT2")

    def __init__(self, *, n_centres: int = 16, init: str = "kmeans", width_scale: float = 1.0,
                 tail: int = 0, ridge: float | str = "cv") -> None:
        self.n_centres = n_centres
        self.init = init
        self.width_scale = width_scale
        self.tail = tail
        self.ridge = ridge


class MLP(FamilySpec):
    """``mlp``: a small multilayer perceptron (``hidden`` layer sizes, ``activation``,
    ``weight_decay``)."""

    key, target = "mlp", "thermonet.models.mlp:MLP"
    max_inputs, default_inputs = None, ("dT",)

    def __init__(self, *, hidden: Sequence[int] = (8, 8), activation: str = "tanh",
                 weight_decay: float = 1e-6) -> None:
        self.hidden = hidden
        self.activation = activation
        self.weight_decay = weight_decay


class GRU(FamilySpec):
    """``gru``: a recurrent model (``hidden`` units stepped every ``step_s`` seconds, restarted
    after gaps over ``gap_s``; trained on ``chunk``-step windows after ``warmup`` steps with
    its own ``lr`` and ``weight_decay``)."""

    key, target = "gru", "thermonet.models.gru:GRU"
    max_inputs, default_inputs = None, ("dT",)

    def __init__(self, *, hidden: int = 8, step_s: float = 10.0, gap_s: float = 60.0,
                 chunk: int = 64, warmup: int = 30, lr: float = 3e-3,
                 weight_decay: float = 1e-6) -> None:
        self.hidden = hidden
        self.step_s = step_s
        self.gap_s = gap_s
        self.chunk = chunk
        self.warmup = warmup
        self.lr = lr
        self.weight_decay = weight_decay


#: The built-in families' specs, in the registry's order.
BUILTIN_SPECS: tuple[type[FamilySpec], ...] = (Linear, Poly, Lorentz, Fuzzy, RBF, MLP, GRU)


def spec_for_class(key: str, cls: type, target: str = "") -> type[FamilySpec]:
    """A generic spec class for a family class (a plug-in's): its hyper-parameters are the
    constructor's keyword-only arguments other than ``n_inputs``/``n_outputs``, with their
    defaults (read with :func:`inspect.signature` on the imported class)."""
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
        "default_inputs": tuple(default_inputs), "family_cls": cls,
        "__doc__": f"The spec of family {key!r} ({cls.__module__}.{cls.__qualname__}).",
        "__module__": __name__})
