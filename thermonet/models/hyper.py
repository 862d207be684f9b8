"""The built-in families' hyper-parameters: what each takes, checked without torch.

One table (:data:`SPECS`) says, per built-in family and hyper-parameter, which values are
allowed; the family's constructor checks its arguments through it (:func:`check_values`)
and so does a config before any data is read or torch is imported
(:func:`thermonet.models.registry.check_hyper`, :func:`thermonet.training.config.check_families`).
A value outside the rule is one :class:`HyperError` (a ``ConfigError``) naming the family
and the key: ``poly: degree must be an integer in 1..12, got 99``; its ``key`` attribute
lets a config name the dotted key (``families[0].params.degree``).  ``bool`` is never a
number, and a number is never a ``bool``.

A plug-in family checks its own values in its constructor; the registry builds it to ask.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from ..core.errors import ConfigError

__all__ = ["HyperError", "SPECS", "check_values", "MLP_ACTIVATIONS", "MLP_MAX_LAYERS",
           "MLP_MAX_WIDTH", "RBF_INITS"]

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


class _Bad(Exception):
    """A value outside the rule (internal)."""


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _integer(lo: int, hi: int, rule: str | None = None) -> tuple[str, Callable[[Any], Any]]:
    def check(v: Any) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise _Bad
        return int(v)
    return rule or f"an integer in {lo}..{hi}", check


def _number(lo: float, hi: float, rule: str, *, lo_open: bool = False
            ) -> tuple[str, Callable[[Any], Any]]:
    def check(v: Any) -> float:
        if not _is_number(v) or not math.isfinite(v) or not lo <= v <= hi \
                or (lo_open and v == lo):
            raise _Bad
        return float(v)
    return rule, check


def _boolean() -> tuple[str, Callable[[Any], Any]]:
    def check(v: Any) -> bool:
        if not isinstance(v, bool):
            raise _Bad
        return v
    return "true or false", check


def _choice(options: Sequence[str]) -> tuple[str, Callable[[Any], Any]]:
    def check(v: Any) -> str:
        if not isinstance(v, str) or v not in options:
            raise _Bad
        return v
    return f"one of {', '.join(options)}", check


def _universe() -> tuple[str, Callable[[Any], Any]]:
    def check(v: Any) -> list[float] | None:
        if v is None:
            return None
        if isinstance(v, (str, bytes, Mapping)) or not isinstance(v, Sequence) or len(v) != 2 \
                or not all(_is_number(x) and math.isfinite(x) for x in v) or not v[0] < v[1]:
            raise _Bad
        return [float(v[0]), float(v[1])]
    return "[lo, hi] with finite numbers lo < hi, or null (the trained range)", check


def _hidden() -> tuple[str, Callable[[Any], Any]]:
    def check(v: Any) -> list[int]:
        if isinstance(v, (str, bytes, Mapping)) or not isinstance(v, Sequence) \
                or not 1 <= len(v) <= MLP_MAX_LAYERS \
                or any(isinstance(h, bool) or not isinstance(h, int)
                       or not 1 <= h <= MLP_MAX_WIDTH for h in v):
            raise _Bad
        return [int(h) for h in v]
    return (f"a list of 1 … {MLP_MAX_LAYERS} layer sizes, each an integer in "
            f"1..{MLP_MAX_WIDTH}"), check


def _ridge() -> tuple[str, Callable[[Any], Any]]:
    def check(v: Any) -> float | str:
        if v == "cv" and isinstance(v, str):
            return v
        if not _is_number(v) or not math.isfinite(v) or v < 0:
            raise _Bad
        return float(v)
    return "'cv' or a finite number >= 0", check


def _gru(lo: float, hi: float, integer: bool) -> tuple[str, Callable[[Any], Any]]:
    kind = "an integer" if integer else "a number"
    rule = f"{kind} in [{lo:g}, {hi:g}]"
    if integer:
        return _integer(int(lo), int(hi), rule)
    return _number(lo, hi, rule)


#: Per built-in family: hyper-parameter -> (rule as said in errors, check returning the value).
SPECS: dict[str, dict[str, tuple[str, Callable[[Any], Any]]]] = {
    "linear": {},
    "poly": {"degree": _integer(1, 12), "cross": _boolean()},
    "lorentz": {"xc_margin": _number(0.0, 100.0, "a number in [0, 100] (fraction of the "
                                     "data span)")},
    "ts-fuzzy": {"n_sets": _integer(2, 64), "universe": _universe()},
    "rbf": {"n_centres": _integer(1, 4096), "init": _choice(RBF_INITS),
            "width_scale": _number(0.0, math.inf, "a finite number > 0", lo_open=True),
            "tail": _integer(0, 3, "an integer in 0..3 (the degree of the polynomial in the "
                                   "first input; 0: none)"),
            "ridge": _ridge()},
    "mlp": {"hidden": _hidden(), "activation": _choice(MLP_ACTIVATIONS),
            "weight_decay": _number(0.0, math.inf, "a finite number >= 0")},
    "gru": {"hidden": _gru(1, 64, True), "step_s": _gru(1e-3, 86400.0, False),
            "gap_s": _gru(1e-3, 1e7, False), "chunk": _gru(2, 100_000, True),
            "warmup": _gru(0, 100_000, True), "lr": _gru(1e-6, 1.0, False),
            "weight_decay": _gru(0.0, 1e3, False)},
}


def _rbf_joint(values: dict[str, Any]) -> None:
    if values.get("tail", 0) and values.get("init", "kmeans") == "random":
        raise ConfigError("rbf: a polynomial tail needs init 'kmeans' or 'quantiles' (a "
                          "closed-form fit)")


#: Rules between hyper-parameters of one family (each given the values it was given).
_JOINT: dict[str, Callable[[dict[str, Any]], None]] = {"rbf": _rbf_joint}


def check_values(family: str, hyper: Mapping[str, Any]) -> dict[str, Any]:
    """``hyper`` of built-in ``family`` checked against :data:`SPECS`, as the family stores
    them (``[lo, hi]`` a list of floats, an integer an ``int``); a name the family does not
    take passes through (the registry refuses it by name, naming the valid ones)."""
    spec = SPECS[family]
    out: dict[str, Any] = {}
    for key, value in hyper.items():
        if key not in spec:
            out[key] = value
            continue
        rule, check = spec[key]
        try:
            out[key] = check(value)
        except _Bad:
            raise HyperError(family, key, rule, value) from None
    joint = _JOINT.get(family)
    if joint is not None:
        joint(out)
    return out
