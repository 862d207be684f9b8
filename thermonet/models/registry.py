"""The family registry: one dict of family specs by name, one register function, plug-ins by
entry point (torch-free).

:data:`FAMILIES` maps the lowercase name a config uses to the family's spec class
(:mod:`thermonet.models.specs`: torch-free, explicit keyword hyper-parameters, input limits,
builds the torch module); :func:`register_family` adds one (a spec class, or a
:class:`thermonet.models.Family` subclass, which gets a generic spec made from its
constructor).  The built-ins are registered here; a researcher's own family, in their own
installed package, joins through the entry-point group :data:`ENTRY_POINT_GROUP`
(``thermonet.families``)::

    [project.entry-points."thermonet.families"]
    my-family = "my_package.family:MyFamily"

The same shape as the other registries: export formats (``thermonet.exporting.FORMATS``,
``register_format``), split strategies (``thermonet.training.splits.SPLITS``,
``register_split``) and dynamic inputs (``thermonet.features.dynamics.INPUTS``,
``register_input``).

Names are listed without importing anything; a family's torch class is imported when it is
built.  :func:`models` is the registry as one dict of torch classes
(``thermonet.models.MODELS``): once it exists, a family set into it (``MODELS["mine"] =
Mine``) is registered too.  :func:`make_spec` turns a name and a dict of hyper-parameters (a
config's ``family`` and ``params``) into the family's spec, refusing an unknown name; the
spec's :meth:`~thermonet.models.specs.FamilySpec.check` checks input count and values — one
rule for the config and the API.  A plug-in cannot take a built-in's name.

A plug-in fails like a bad config: whatever its module or constructor raises while it is
imported or built — any exception, a ``SyntaxError``, even ``sys.exit()`` — is one
:class:`ConfigError` line naming the family and its entry point (the command line exits 1,
the API raises it).  ``KeyboardInterrupt`` (Ctrl-C) is let through.
"""

from __future__ import annotations

import functools
import inspect
import re
import warnings
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import TYPE_CHECKING, Any

from ..core.errors import ConfigError
from .specs import BUILTIN_SPECS, FamilySpec, set_builder, spec_for_class

if TYPE_CHECKING:
    from .base import Family

__all__ = ["FAMILIES", "BUILTIN", "ENTRY_POINT_GROUP", "PER_AXIS", "FamilySignature", "register_family",
           "unregister_family",
           "family_names", "get_family", "spec_class", "make_spec", "spec_of", "build_family",
           "family_signature", "check_hyper", "models"]

#: The name of the per-axis composite (:class:`thermonet.models.composite.AxisModels`, each
#: axis its own family): its family in checkpoints, ONNX metadata and C comments, its label
#: and checkpoint name in a comparison (``models/per-axis.pt``), ``results.json``'s ``chosen``
#: and ``thermonet export --family``.  Defined here, torch-free, for every layer above.
PER_AXIS = "per-axis"

#: Every registered family's spec class by name (the built-ins, then what
#: :func:`register_family` adds; installed plug-ins are found by entry point on use).
FAMILIES: dict[str, type[FamilySpec]] = {}


def register_family(spec: type, name: str | None = None) -> type:
    """Add a family to :data:`FAMILIES` under ``name`` (default: the spec's ``key``, or the
    family class's ``name``): a :class:`~thermonet.models.specs.FamilySpec` subclass, or a
    :class:`~thermonet.models.Family` subclass (its spec: the one it names or declares in its
    body, :func:`~thermonet.models.specs.declared_spec`, else a generic one made from its
    constructor).  A new family is thus one class and this one call.
    A name registered twice is a ``ValueError``.  Returns ``spec`` (usable as a decorator)."""
    if isinstance(spec, type) and issubclass(spec, FamilySpec):
        cls = spec
        key = name or spec.key
    else:
        from .base import Family  # torch boundary: a family class is a torch module

        if not (inspect.isclass(spec) and issubclass(spec, Family)):
            raise ConfigError(f"register_family: {getattr(spec, '__name__', spec)!r} is neither a "
                              "thermonet.models.Family subclass nor a family spec")
        key = name or str(getattr(spec, "name", ""))
        cls = spec_for_class(key, spec)
    if not key:
        raise ValueError("register_family: the family needs a name")
    if key in FAMILIES:
        raise ValueError(f"model family {key!r} is already registered")
    FAMILIES[key] = cls
    return spec


def unregister_family(name: str) -> None:
    """Remove a family :func:`register_family` added (from :data:`FAMILIES`, and from the
    dict of classes where it was made); a built-in cannot be removed (``ValueError``), an
    unknown name is a ``KeyError``."""
    if name in BUILTIN:
        raise ValueError(f"model family {name!r} is built in")
    del FAMILIES[name]
    if _MODELS is not None:
        _MODELS.pop(name, None)
    for key in [k for k in _GENERIC if k[0] == name]:
        del _GENERIC[key]


for _spec in BUILTIN_SPECS:
    register_family(_spec)

#: The built-in families (name -> spec class), in the order the registry lists them.
BUILTIN: dict[str, type[FamilySpec]] = dict(FAMILIES)

#: The entry-point group a package registers its own families in (name -> Family subclass).
ENTRY_POINT_GROUP = "thermonet.families"

#: The registry as classes, made on first use of :func:`models` (it imports every family).
_MODELS: dict[str, type[Family]] | None = None


@functools.cache
def _plugins() -> dict[str, EntryPoint]:
    """The installed plug-in families (the first of a name wins; built-in names are kept),
    read once per process."""
    out: dict[str, EntryPoint] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name not in FAMILIES and ep.name not in out:
            out[ep.name] = ep
    return out


def family_names() -> list[str]:
    """Every registered family's name: the built-ins, then the installed plug-ins."""
    if _MODELS is not None:   # the dict of classes, and any family registered after it was made
        return [*_MODELS, *(k for k in FAMILIES if k not in _MODELS)]
    return [*FAMILIES, *_plugins()]


def _plugin_said(name: str) -> str:
    """``model family 'x' (plug-in entry point 'x = pkg.mod:Cls' of distribution d 0.1)``."""
    ep = _plugins().get(name)
    if ep is None:
        return f"model family {name!r}"
    dist = getattr(ep, "dist", None)
    of = f" of distribution {dist.name} {dist.version}" if dist is not None else ""
    return f"model family {name!r} (plug-in entry point '{ep.name} = {ep.value}'{of})"


def _guarded(name: str, doing: str, call: Any) -> Any:
    """``call()``; anything a plug-in raises there — an exception, ``SystemExit`` — is one
    ConfigError naming the family and its entry point (``KeyboardInterrupt`` goes through)."""
    try:
        return call()
    except ConfigError as err:
        if name in BUILTIN:
            raise
        raise ConfigError(f"{_plugin_said(name)}: {err}") from None
    except SystemExit as err:
        raise ConfigError(f"{_plugin_said(name)}: called sys.exit({err.code!r}) while "
                          f"{doing}; refusing it") from None
    except Exception as err:
        if name in BUILTIN and doing != "importing":
            raise
        raise ConfigError(f"{_plugin_said(name)}: failed while {doing} "
                          f"({type(err).__name__}: {err})") from None


def _unknown(name: Any) -> ConfigError:
    hint = ""
    if isinstance(name, str) and re.fullmatch(r"(cubic|poly\d).*", name.strip().lower()):
        # the default set's labels (cubic, cubic-delayed-2min, poly3-rate …) are what results
        # and reports name; each is the family `poly` with its inputs and degree
        hint = ("; the default set's 'cubic' and its other names are labels of the family "
                "'poly': DriftEstimator('poly', 'dT', degree=3), in a config {family: poly, "
                "name: cubic, inputs: [dT], params: {degree: 3}} (configs/README.md, "
                "\"Default families\")")
    return ConfigError(f"unknown model family {name!r} (valid: {', '.join(family_names())})"
                       + hint)


def _target(name: str) -> str:
    if isinstance(name, str):
        if name in FAMILIES:
            return FAMILIES[name].target
        ep = _plugins().get(name) if _MODELS is None else None
        if ep is not None:
            return str(ep.value)
    raise _unknown(name)


def get_family(name: str) -> type[Family]:
    """The torch family class registered as ``name`` (imported now).

    Raises
    ------
    ConfigError
        (a ``ValueError``) naming the valid families; or naming a plug-in whose entry point
        does not load or is not a :class:`~thermonet.models.Family` subclass.
    """
    if _MODELS is not None and isinstance(name, str) and name in _MODELS:
        return _MODELS[name]
    target = _target(name)          # an unknown name is refused before torch loads
    from .base import Family  # torch boundary

    load = FAMILIES[name].family_class if name in FAMILIES else _loader(target)
    obj = _guarded(name, "importing", load)
    if not (inspect.isclass(obj) and issubclass(obj, Family)):
        raise ConfigError(f"{_plugin_said(name)}: {target!r} is not a subclass "
                          "of thermonet.models.Family")
    return obj


def _loader(target: str) -> Any:
    """A callable importing ``"module:Class"`` (the attribute path may be dotted)."""
    import importlib

    module, _, attr = target.partition(":")

    def load() -> Any:
        obj: Any = importlib.import_module(module)
        for part in attr.split("."):
            obj = getattr(obj, part)
        return obj

    return load


def models() -> dict[str, type[Family]]:
    """Every registered family by name, each class imported: the one registry dict of torch
    classes (``thermonet.models.MODELS``), made on first use."""
    global _MODELS
    if _MODELS is None:
        out: dict[str, type[Family]] = {}
        for name in family_names():
            try:
                out[name] = get_family(name)
            except ConfigError as err:  # a broken plug-in is said, the others still work
                if name in BUILTIN:
                    raise
                warnings.warn(str(err), stacklevel=2)
        _MODELS = out
    return _MODELS


#: Generic specs made for family classes (a plug-in's, one set into ``MODELS``), per class.
_GENERIC: dict[tuple[str, type], type[FamilySpec]] = {}


def spec_class(name: str) -> type[FamilySpec]:
    """The spec class of family ``name``: a built-in's without importing anything; a
    plug-in's made from its imported class's constructor (a failure is one line naming it)."""
    if _MODELS is not None and isinstance(name, str) and name in _MODELS:
        cls = _MODELS[name]
        own = FAMILIES.get(name)
        if own is not None and own.target == f"{cls.__module__}:{cls.__qualname__}":
            return own
    elif name in FAMILIES:
        return FAMILIES[name]
    else:
        cls = get_family(name)
    key = (name, cls)
    if key not in _GENERIC:
        _GENERIC[key] = _guarded(name, "reading its constructor",
                                 lambda: spec_for_class(name, cls))
    return _GENERIC[key]


def make_spec(name: str, params: dict[str, Any] | None = None) -> FamilySpec:
    """Family ``name``'s spec with ``params`` (a config's ``family`` and ``params``): an unknown
    family or hyper-parameter name is one :class:`ConfigError` naming the valid ones; values
    are stored unchecked (:meth:`~thermonet.models.specs.FamilySpec.check` checks them)."""
    if not isinstance(name, str):
        raise _unknown(name)
    cls = spec_class(name)
    valid = cls.param_names()
    for key in dict(params or {}):
        if key not in valid:
            raise ConfigError(f"model '{name}': unknown hyper-parameter '{key}' "
                              f"(valid: {', '.join(valid) or 'none'})")
    return cls(**dict(params or {}))


def spec_of(family: str | FamilySpec) -> FamilySpec:
    """A family as a spec: a spec as it is, a name as its spec with the defaults."""
    if isinstance(family, FamilySpec):
        return family
    return make_spec(family)


@dataclass(frozen=True)
class FamilySignature:
    """What a config may give a family: its hyper-parameters' names and its input limit."""

    hyper: tuple[str, ...]
    max_inputs: int | None


def family_signature(name: str) -> FamilySignature:
    """Hyper-parameter names and input limit of family ``name`` (its spec's) — for a built-in,
    without importing it (torch); raises :class:`ConfigError` for an unknown name."""
    cls = spec_class(name)
    return FamilySignature(hyper=cls.param_names(), max_inputs=cls.max_inputs)


def check_hyper(name: str, hyper: dict | None, n_inputs: int, *, values: bool = True
                ) -> None:
    """Refuse an unknown family, an unknown hyper-parameter, too many inputs and (with
    ``values``) a hyper-parameter value the family does not take: :func:`make_spec` then
    :meth:`~thermonet.models.specs.FamilySpec.check` (torch-free for the built-in families,
    a :class:`~thermonet.models.hyper.HyperError` whose ``key`` names the value; a plug-in is
    built with one output to ask its constructor)."""
    make_spec(name, hyper).check(n_inputs, values=values)


def build_family(name: str, *, n_inputs: int, n_outputs: int,
                 hyper: dict | None = None) -> Family:
    """Instantiate family ``name`` with ``hyper``; an unknown hyper-parameter is a
    :class:`ConfigError` naming it and the valid ones."""
    cls = get_family(name)
    hyper = dict(hyper or {})
    valid = spec_class(name).param_names()
    for key in hyper:
        if key not in valid:
            raise ConfigError(f"model '{name}': unknown hyper-parameter '{key}' "
                              f"(valid: {', '.join(valid) or 'none'})")
    return _guarded(name, "building", lambda: cls(n_inputs=n_inputs, n_outputs=n_outputs,
                                                  **hyper))


set_builder(build_family)   # a spec builds through the registry (specs never imports it)
