"""The estimator's ``family`` given with hyper-parameter keywords
(``DriftEstimator("poly", degree=3)``): folded into a new spec where they make one, else
kept as given (:class:`FamilyKeywords`) so that the constructor never raises and
:meth:`~thermonet.api.DriftEstimator.fit` refuses them, naming what is wrong."""

from __future__ import annotations

from typing import Any

from ..core.errors import ConfigError
from ..models.registry import spec_of

__all__ = ["FamilyKeywords", "with_keywords"]


class FamilyKeywords:
    """A family given as a name and hyper-parameter keywords that do not make a spec
    (``DriftEstimator("poly", degre=3)``, an unknown family): kept as given, so that the
    constructor never raises; :meth:`DriftEstimator.fit` refuses it, naming what is wrong."""

    def __init__(self, name: Any, params: dict[str, Any]) -> None:
        self.name = name
        self.params = params

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        return {"name": self.name, "params": self.params}

    def set_params(self, **params: Any) -> FamilyKeywords:
        self.params = {**self.params, **params}
        return self

    def __eq__(self, other: object) -> bool:
        return isinstance(other, FamilyKeywords) and \
            (self.name, self.params) == (other.name, other.params)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return ", ".join([repr(self.name), *(f"{k}={v!r}" for k, v in self.params.items())])


def with_keywords(family: Any, hyper: dict[str, Any]) -> Any:
    """``family`` (a name or a spec) with hyper-parameter keywords folded in: a new spec
    (``"poly", degree=3`` is ``Poly(degree=3)``), or, where they do not make one, both kept
    as given for :meth:`DriftEstimator.fit` to refuse."""
    try:
        base = spec_of(family)
        spec = type(base)(**base.get_params())
        return spec.set_params(**hyper)
    except (ConfigError, TypeError):
        return FamilyKeywords(family, dict(hyper))
