"""The family registry: the built-in families by name, plug-ins by entry point (torch-free).

A family is a subclass of :class:`thermonet.models.Family` registered under the lowercase
name a config uses.  The built-in ones are listed in :data:`BUILTIN` as ``"module:Class"``;
a researcher's own family, in their own installed package, joins through the entry-point
group :data:`ENTRY_POINT_GROUP` (``thermonet.families``)::

    [project.entry-points."thermonet.families"]
    my-family = "my_package.family:MyFamily"

Names are listed without importing anything; a family's class is imported when it is
built.  :func:`models` is the registry as one dict of classes (``thermonet.models.MODELS``):
once it exists, a family set into it (``MODELS["mine"] = Mine``) is registered too.  :func:`family_signature` reads a family's hyper-parameter names and input limit from
its source without importing it where it can (the built-ins: a config is checked before
torch loads) and imports the class otherwise.  A plug-in cannot take a built-in's name.

A plug-in fails like a bad config: whatever its module or constructor raises while it is
imported or built — any exception, a ``SyntaxError``, even ``sys.exit()`` — is one
:class:`ConfigError` line naming the family and its entry point (the command line exits 1,
the API raises it).  ``KeyboardInterrupt`` (Ctrl-C) is let through.  :func:`check_hyper`
checks hyper-parameter values too: a built-in's against :mod:`thermonet.models.hyper`
without torch, a plug-in's by building it.
"""

from __future__ import annotations

import ast
import functools
import importlib
import importlib.util
import inspect
import warnings
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import TYPE_CHECKING, Any

from ..core.errors import ConfigError
from .hyper import SPECS, check_values

if TYPE_CHECKING:
    from .base import Family

__all__ = ["BUILTIN", "ENTRY_POINT_GROUP", "FamilySignature", "family_names", "get_family",
           "build_family", "family_signature", "check_hyper", "models"]

#: The built-in families: name -> ``"module:Class"``.
BUILTIN: dict[str, str] = {
    "linear": "thermonet.models.linear:Linear",
    "poly": "thermonet.models.poly:Poly",
    "lorentz": "thermonet.models.lorentz:Lorentz",
    "ts-fuzzy": "thermonet.models.fuzzy:TSFuzzy",
    "rbf": "thermonet.models.rbf:RBF",
    "mlp": "thermonet.models.mlp:MLP",
    "gru": "thermonet.models.gru:GRU",
}

#: The entry-point group a package registers its own families in (name -> Family subclass).
ENTRY_POINT_GROUP = "thermonet.families"

#: Keyword arguments of every family's constructor that are not hyper-parameters.
_SHAPE = ("n_inputs", "n_outputs")


#: The registry as classes, made on first use of :func:`models` (it imports every family).
_MODELS: dict[str, type[Family]] | None = None


@functools.cache
def _plugins() -> dict[str, EntryPoint]:
    """The installed plug-in families (the first of a name wins; built-in names are kept),
    read once per process."""
    out: dict[str, EntryPoint] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name not in BUILTIN and ep.name not in out:
            out[ep.name] = ep
    return out


def family_names() -> list[str]:
    """Every registered family's name: the built-ins, then the installed plug-ins."""
    if _MODELS is not None:
        return list(_MODELS)
    return [*BUILTIN, *_plugins()]


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


def _target(name: str) -> str:
    if isinstance(name, str) and _MODELS is None:
        if name in BUILTIN:
            return BUILTIN[name]
        ep = _plugins().get(name)
        if ep is not None:
            return str(ep.value)
    raise ConfigError(f"unknown model family {name!r} (valid: {', '.join(family_names())})")


def get_family(name: str) -> type[Family]:
    """The family class registered as ``name`` (imported now).

    Raises
    ------
    ConfigError
        (a ``ValueError``) naming the valid families; or naming a plug-in whose entry point
        does not load or is not a :class:`~thermonet.models.Family` subclass.
    """
    from .base import Family

    if _MODELS is not None:
        try:
            return _MODELS[name]
        except (KeyError, TypeError):
            raise ConfigError(f"unknown model family {name!r} "
                              f"(valid: {', '.join(family_names())})") from None
    target = _target(name)
    module, _, attr = target.partition(":")

    def load() -> Any:
        obj: Any = importlib.import_module(module)
        for part in attr.split("."):
            obj = getattr(obj, part)
        return obj

    obj = _guarded(name, "importing", load)
    if not (inspect.isclass(obj) and issubclass(obj, Family)):
        raise ConfigError(f"{_plugin_said(name)}: {target!r} is not a subclass "
                          "of thermonet.models.Family")
    return obj


def models() -> dict[str, type[Family]]:
    """Every registered family by name, each class imported: the one registry dict
    (``thermonet.models.MODELS``), made on first use."""
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


@dataclass(frozen=True)
class FamilySignature:
    """What a config may give a family: its hyper-parameters' names and its input limit."""

    hyper: tuple[str, ...]
    max_inputs: int | None


def _signature_of_class(cls: type) -> FamilySignature:
    params = inspect.signature(cls.__init__).parameters  # type: ignore[misc]
    hyper = tuple(k for k, p in params.items()
                  if p.kind is inspect.Parameter.KEYWORD_ONLY and k not in _SHAPE)
    return FamilySignature(hyper=hyper, max_inputs=getattr(cls, "max_inputs", None))


def _signature_from_source(target: str) -> FamilySignature | None:
    """The signature read from the class's own source, or None where that is not certain
    (no ``__init__`` or no literal ``max_inputs`` in the class body, ``**kwargs``)."""
    module, _, attr = target.partition(":")
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin or not spec.origin.endswith(".py"):
        return None
    with open(spec.origin, encoding="utf-8") as fh:
        tree = ast.parse(fh.read(), spec.origin)
    cls = next((n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == attr), None)
    if cls is None:
        return None
    init = next((n for n in cls.body if isinstance(n, ast.FunctionDef)
                 and n.name == "__init__"), None)
    max_inputs: Any = ...
    for node in cls.body:
        target_names: list[str] = []
        value = None
        if isinstance(node, ast.Assign):
            target_names = [t.id for t in node.targets if isinstance(t, ast.Name)]
            value = node.value
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            target_names, value = [node.target.id], node.value
        if "max_inputs" in target_names and isinstance(value, ast.Constant):
            max_inputs = value.value
    if init is None or init.args.kwarg is not None or max_inputs is ...:
        return None
    if not (max_inputs is None or isinstance(max_inputs, int)):
        return None
    hyper = tuple(a.arg for a in init.args.kwonlyargs if a.arg not in _SHAPE)
    return FamilySignature(hyper=hyper, max_inputs=max_inputs)


def family_signature(name: str) -> FamilySignature:
    """Hyper-parameter names and input limit of family ``name`` — for a built-in, without
    importing it (torch); raises :class:`ConfigError` for an unknown name."""
    if _MODELS is not None:
        return _signature_of_class(get_family(name))
    target = _target(name)
    if name in BUILTIN:
        sig = _signature_from_source(target)
        if sig is not None:
            return sig
    return _signature_of_class(get_family(name))


def check_hyper(name: str, hyper: dict | None, n_inputs: int, *, values: bool = True
                ) -> None:
    """Refuse an unknown family, an unknown hyper-parameter, too many inputs and (with
    ``values``) a hyper-parameter value the family does not take: torch-free for the
    built-in families (:mod:`thermonet.models.hyper`: a
    :class:`~thermonet.models.hyper.HyperError` whose ``key`` names it); a plug-in is built
    with one output to ask its constructor."""
    sig = family_signature(name)
    for key in dict(hyper or {}):
        if key not in sig.hyper:
            raise ConfigError(f"model '{name}': unknown hyper-parameter '{key}' "
                              f"(valid: {', '.join(sig.hyper) or 'none'})")
    if sig.max_inputs is not None and n_inputs > sig.max_inputs:
        raise ConfigError(f"model '{name}' takes at most {sig.max_inputs} input(s), "
                          f"got {n_inputs}")
    if not values:
        return
    if _MODELS is None and name in SPECS:
        check_values(name, dict(hyper or {}))
    else:
        build_family(name, n_inputs=max(int(n_inputs), 1), n_outputs=1, hyper=hyper)


def build_family(name: str, *, n_inputs: int, n_outputs: int,
                 hyper: dict | None = None) -> Family:
    """Instantiate family ``name`` with ``hyper``; an unknown hyper-parameter is a
    :class:`ConfigError` naming it and the valid ones."""
    cls = get_family(name)
    hyper = dict(hyper or {})
    valid = _signature_of_class(cls).hyper
    for key in hyper:
        if key not in valid:
            raise ConfigError(f"model '{name}': unknown hyper-parameter '{key}' "
                              f"(valid: {', '.join(valid) or 'none'})")
    return _guarded(name, "building", lambda: cls(n_inputs=n_inputs, n_outputs=n_outputs,
                                                  **hyper))
