"""The model families, by name.

``MODELS`` maps the lowercase name a config uses to the :class:`Family`
subclass; tests parametrise over it, so registering a family here is what
makes it tested (fit, predict, save/load, ONNX parity).
"""

from __future__ import annotations

import inspect

from ..errors import ConfigError
from .base import TINY, DriftModel, Family
from .fuzzy import TSFuzzy
from .linear import Linear
from .lorentz import Lorentz
from .poly import Poly
from .rbf import RBF

__all__ = ["MODELS", "get_family", "build_family", "Family", "DriftModel", "TINY",
           "Linear", "Poly", "Lorentz", "TSFuzzy", "RBF"]

MODELS: dict[str, type[Family]] = {
    "linear": Linear,
    "poly": Poly,
    "lorentz": Lorentz,
    "ts-fuzzy": TSFuzzy,
    "rbf": RBF,
}


def get_family(name: str) -> type[Family]:
    """The family class registered as ``name``.

    Raises
    ------
    ConfigError
        (a ``ValueError``) naming the valid families.
    """
    try:
        return MODELS[name]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown model family {name!r} (valid: {', '.join(MODELS)})") from None


def build_family(name: str, *, n_inputs: int, n_outputs: int,
                 hyper: dict | None = None) -> Family:
    """Instantiate family ``name`` with ``hyper``; an unknown hyper-parameter is a
    :class:`ConfigError` naming it and the valid ones."""
    cls = get_family(name)
    hyper = dict(hyper or {})
    params = inspect.signature(cls.__init__).parameters
    valid = [k for k, p in params.items()
             if p.kind is inspect.Parameter.KEYWORD_ONLY and k not in ("n_inputs", "n_outputs")]
    for key in hyper:
        if key not in valid:
            raise ConfigError(f"model '{name}': unknown hyper-parameter '{key}' "
                              f"(valid: {', '.join(valid) or 'none'})")
    return cls(n_inputs=n_inputs, n_outputs=n_outputs, **hyper)
