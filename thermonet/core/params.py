"""scikit-learn's parameter protocol without importing scikit-learn.

:class:`Params` gives a class ``get_params(deep=True)`` and ``set_params(**params)`` exactly as
:class:`sklearn.base.BaseEstimator` defines them: the parameters are the constructor's keyword
arguments (read with :func:`inspect.signature`, ``**kwargs`` excluded), each stored under its
own name; ``deep`` adds a nested object's own parameters as ``<name>__<key>``, and
``set_params`` sets those on the nested object.  So :func:`sklearn.base.clone`,
``GridSearchCV`` and scikit-learn's estimator checks work on it as on a ``BaseEstimator``.

Why not ``BaseEstimator`` itself: importing scikit-learn costs about a second, and thermonet
loads it only where it is used (``thermonet.api`` stays light; ``KMeans`` loads with an RBF).
"""

from __future__ import annotations

import inspect
from typing import Any

from .errors import ConfigError

__all__ = ["Params"]


class Params:
    """``get_params``/``set_params`` of scikit-learn's ``BaseEstimator`` (module docstring)."""

    @classmethod
    def _get_param_names(cls) -> list[str]:
        """The constructor's keyword names, sorted (scikit-learn's order)."""
        init = cls.__init__
        if init is object.__init__:
            return []
        params = [p for p in inspect.signature(init).parameters.values()
                  if p.name != "self" and p.kind != p.VAR_KEYWORD]
        if any(p.kind == p.VAR_POSITIONAL for p in params):
            raise RuntimeError(f"{cls.__name__}: parameters must be named in the constructor's "
                               "signature (no *args)")
        return sorted(p.name for p in params)

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """Every constructor parameter by name; with ``deep``, a nested object's parameters too
        (``family__degree``)."""
        out: dict[str, Any] = {}
        for key in self._get_param_names():
            value = getattr(self, key)
            if deep and hasattr(value, "get_params") and not isinstance(value, type):
                out.update((f"{key}__{k}", v) for k, v in value.get_params().items())
            out[key] = value
        return out

    def set_params(self, **params: Any) -> Any:
        """Set parameters by name, nested ones as ``<name>__<key>``; returns ``self``.  A name
        that is not a parameter is one :class:`ConfigError` (a ``ValueError``) naming the valid
        ones."""
        if not params:
            return self
        valid = self.get_params(deep=True)
        nested: dict[str, dict[str, Any]] = {}
        for full_key, value in params.items():
            key, delim, sub_key = full_key.partition("__")
            if key not in valid:
                raise ConfigError(f"set_params: {key!r} is not a parameter of "
                                  f"{type(self).__name__} (valid: "
                                  f"{', '.join(self._get_param_names())})")
            if delim:
                nested.setdefault(key, {})[sub_key] = value
            else:
                setattr(self, key, value)
                valid[key] = value
        for key, sub_params in nested.items():
            valid[key].set_params(**sub_params)
        return self
