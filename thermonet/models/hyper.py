"""The rules a family's hyper-parameter values follow, checked without torch.

A :class:`Rule` says in words which values a hyper-parameter takes and checks one value,
returning it as the family stores it (``[lo, hi]`` a list of floats, an integer an ``int``):
:func:`integer`, :func:`number`, :func:`boolean`, :func:`choice` and the built-in families' own
(:func:`universe`, :func:`layer_sizes`, :func:`ridge`, :func:`bounded`).  Each family's spec
(:mod:`thermonet.models.specs`) declares one next to each hyper-parameter's default, and the
spec is the one source of both: the config loader checks values through it before any data is
read or torch is imported, and the family's constructor checks its arguments through the same
spec.  A value outside its rule is one :class:`HyperError` (a ``ConfigError``) naming the
family and the key: ``poly: degree must be an integer in 1..12, got 99``; its ``key``
attribute lets a config name the dotted key (``families[0].params.degree``).  ``bool`` is
never a number, and a number is never a ``bool``.

A plug-in family made from a constructor alone checks its own values there; the registry
builds it to ask.  A plug-in that declares a spec (:class:`thermonet.models.specs.FamilySpec`
with :func:`~thermonet.models.specs.param`) gets its values checked like a built-in's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ..core.errors import ConfigError

__all__ = ["HyperError", "Invalid", "Rule", "check_rules", "integer", "number", "boolean",
           "choice", "universe", "layer_sizes", "ridge", "bounded", "weights", "MLP_ACTIVATIONS",
           "MLP_MAX_LAYERS", "MLP_MAX_WIDTH", "RBF_INITS"]

#: The MLP's activations (:data:`thermonet.models.mlp.ACTIVATIONS` holds their gains).
MLP_ACTIVATIONS = ("tanh", "relu", "silu")
#: Bounds on the MLP's architecture: a network for a microcontroller, not a research model.
MLP_MAX_LAYERS, MLP_MAX_WIDTH = 4, 256
#: How the RBF places its centres.
RBF_INITS = ("kmeans", "quantiles", "random")


class HyperError(ConfigError):
    """A family hyper-parameter with a value outside its rule (``key`` names it)."""

    def __init__(self, family: str, key: str, rule: str, value: Any) -> None:
        super().__init__(f"{family}: {key} must be {rule}, got {value!r}")
        self.family, self.key = family, key


class Invalid(Exception):
    """Raised by a rule's check for a value outside the rule (:func:`check_rules` turns it into
    a :class:`HyperError` in the rule's words)."""


@dataclass(frozen=True)
class Rule:
    """Which values a hyper-parameter takes: ``said`` completes "``<key>`` must be …";
    ``check`` returns the value as the family stores it, or raises :class:`Invalid`."""

    said: str
    check: Callable[[Any], Any]


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def integer(lo: int, hi: int, said: str | None = None) -> Rule:
    """An ``int`` (never a ``bool``) in ``lo..hi``."""
    def check(v: Any) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise Invalid
        return int(v)
    return Rule(said or f"an integer in {lo}..{hi}", check)


def number(lo: float, hi: float, said: str, *, lo_open: bool = False) -> Rule:
    """A finite ``int`` or ``float`` (never a ``bool``) in ``[lo, hi]`` (``(lo, hi]`` with
    ``lo_open``), stored as a ``float``."""
    def check(v: Any) -> float:
        if not _is_number(v) or not math.isfinite(v) or not lo <= v <= hi \
                or (lo_open and v == lo):
            raise Invalid
        return float(v)
    return Rule(said, check)


def boolean() -> Rule:
    """``True`` or ``False`` only."""
    def check(v: Any) -> bool:
        if not isinstance(v, bool):
            raise Invalid
        return v
    return Rule("true or false", check)


def choice(options: Sequence[str]) -> Rule:
    """One of the strings ``options``."""
    def check(v: Any) -> str:
        if not isinstance(v, str) or v not in options:
            raise Invalid
        return v
    return Rule(f"one of {', '.join(options)}", check)


def universe() -> Rule:
    """``[lo, hi]`` of finite numbers, ``lo < hi``, or ``None`` (the TS-fuzzy universe)."""
    def check(v: Any) -> list[float] | None:
        if v is None:
            return None
        if isinstance(v, (str, bytes, Mapping)) or not isinstance(v, Sequence) or len(v) != 2 \
                or not all(_is_number(x) and math.isfinite(x) for x in v) or not v[0] < v[1]:
            raise Invalid
        return [float(v[0]), float(v[1])]
    return Rule("[lo, hi] with finite numbers lo < hi, or null (the trained range)", check)


def layer_sizes() -> Rule:
    """The MLP's hidden layer sizes: 1 … :data:`MLP_MAX_LAYERS` integers in
    1..:data:`MLP_MAX_WIDTH`, stored as a list."""
    def check(v: Any) -> list[int]:
        if isinstance(v, (str, bytes, Mapping)) or not isinstance(v, Sequence) \
                or not 1 <= len(v) <= MLP_MAX_LAYERS \
                or any(isinstance(h, bool) or not isinstance(h, int)
                       or not 1 <= h <= MLP_MAX_WIDTH for h in v):
            raise Invalid
        return [int(h) for h in v]
    return Rule(f"a list of 1 … {MLP_MAX_LAYERS} layer sizes, each an integer in "
                f"1..{MLP_MAX_WIDTH}", check)


def ridge() -> Rule:
    """``"cv"`` or a finite number ≥ 0 (the RBF's ridge)."""
    def check(v: Any) -> float | str:
        if v == "cv" and isinstance(v, str):
            return v
        if not _is_number(v) or not math.isfinite(v) or v < 0:
            raise Invalid
        return float(v)
    return Rule("'cv' or a finite number >= 0", check)


def weights() -> Rule:
    """``None``, or a list of two or more weights in [0, 1] summing to 1 (within 1e-9),
    stored as floats (the polynomial's ``mix``)."""
    def check(v: Any) -> list[float] | None:
        if v is None:
            return None
        if isinstance(v, (str, bytes, Mapping)) or not isinstance(v, Sequence) or len(v) < 2 \
                or not all(_is_number(x) and math.isfinite(x) and 0 <= x <= 1 for x in v) \
                or abs(sum(v) - 1.0) > 1e-9:
            raise Invalid
        return [float(x) for x in v]
    return Rule("null or a list of one weight in [0, 1] per input, summing to 1", check)


def bounded(lo: float, hi: float, integer_only: bool) -> Rule:
    """An integer or a number in ``[lo, hi]``, said as such (the GRU's bounds)."""
    kind = "an integer" if integer_only else "a number"
    said = f"{kind} in [{lo:g}, {hi:g}]"
    if integer_only:
        return integer(int(lo), int(hi), said)
    return number(lo, hi, said)


def check_rules(family: str, rules: Mapping[str, Rule], hyper: Mapping[str, Any]
                ) -> dict[str, Any]:
    """``hyper`` checked against ``rules`` (name -> :class:`Rule`), as the family stores them;
    a name without a rule passes through unchanged.  The first value outside its rule is a
    :class:`HyperError` naming ``family`` and the key."""
    out: dict[str, Any] = {}
    for key, value in hyper.items():
        rule = rules.get(key)
        if rule is None:
            out[key] = value
            continue
        try:
            out[key] = rule.check(value)
        except Invalid:
            raise HyperError(family, key, rule.said, value) from None
    return out
