"""The model families, by name: the fourth layer, above :mod:`thermonet.features`.

``FAMILIES`` maps the lowercase name a config uses to the family's torch-free spec class
(:mod:`thermonet.models.specs`: ``Poly(degree=3)``, what ``DriftEstimator(family=...)`` and a
config's ``{family: poly, params: {...}}`` both become); :func:`register_family` adds one.
A family's hyper-parameters are declared once, in its spec, each with its default and rule
(:func:`param`, the rules of :mod:`thermonet.models.hyper`).  ``MODELS`` maps the same names to the torch :class:`Family` subclass — the
built-in ones (``linear``, ``poly``, ``lorentz``, ``ts-fuzzy``, ``rbf``, ``mlp``, ``gru``) and every
family an installed package registers under the entry-point group ``thermonet.families``
(:mod:`thermonet.models.registry`); tests parametrise over it, so registering a family is
what makes it tested (fit, predict, save/load, ONNX parity).  The names here load on first
access: the registry itself (:func:`get_family`, :func:`build_family`) is torch-free until a
family is built, so a config is checked without loading torch; :func:`unregister_family`
takes one out again.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .registry import (
    ENTRY_POINT_GROUP,
    FAMILIES,
    build_family,
    family_names,
    get_family,
    make_spec,
    models,
    register_family,
    unregister_family,
)
from .specs import FamilySpec, param

if TYPE_CHECKING:
    from .base import TINY, Family
    from .drift_model import DriftModel
    from .fuzzy import TSFuzzy
    from .gru import GRU
    from .linear import Linear
    from .lorentz import Lorentz
    from .mlp import MLP
    from .poly import Poly
    from .rbf import RBF

    MODELS: dict[str, type[Family]]

__all__ = ["MODELS", "FAMILIES", "register_family", "unregister_family", "make_spec", "FamilySpec", "param", "get_family",
           "build_family", "family_names", "ENTRY_POINT_GROUP",
           "Family", "DriftModel", "TINY", "Linear", "Poly", "Lorentz", "TSFuzzy", "RBF",
           "MLP", "GRU"]

_LAZY = {
    "Family": "base", "DriftModel": "drift_model", "TINY": "base",
    "Linear": "linear", "Poly": "poly", "Lorentz": "lorentz", "TSFuzzy": "fuzzy", "RBF": "rbf",
    "MLP": "mlp", "GRU": "gru",
}


def __getattr__(name: str) -> Any:
    if name == "MODELS":  # every registered family, built-in and plug-in, imported now
        return models()
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
