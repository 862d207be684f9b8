"""Typed dataclasses from YAML mappings: unknown keys and wrong types refused with the key.

:func:`from_dict` builds a dataclass from a mapping, checking each value against its
annotation (unions, literals, lists, nested dataclasses); every error is one
:class:`~thermonet.core.errors.ConfigError` line naming the file and the dotted key.
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing
from typing import Any, Literal, Union

from .errors import ConfigError

__all__ = ["from_dict", "to_dict"]


#: How a value of each plain type is asked for in a message: words, not Python's names.
_WORDS: dict[Any, str] = {float: "a number", int: "a whole number", str: "text",
                          type(None): "null", list: "a list", dict: "a mapping",
                          Any: "any value"}


def _alternatives(tp: Any) -> list[str]:
    """What annotation ``tp`` accepts, in words, one entry per alternative (a union's and a
    literal's alternatives listed each: ``float | Literal['start']`` → ``["a number",
    "'start'"]``)."""
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        return [w for alt in typing.get_args(tp) for w in _alternatives(alt)]
    if origin is Literal:
        return [repr(a) for a in typing.get_args(tp)]
    if tp is bool:
        return ["true", "false"]
    if origin is not None:
        tp = origin                         # list[str] → list, dict[str, Any] → dict
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return ["a mapping"]
    return [_WORDS.get(tp) or getattr(tp, "__name__", None) or str(tp).replace("typing.", "")]


def _type_name(tp: Any) -> str:
    """What annotation ``tp`` accepts, in plain words: ``a whole number or null``,
    ``a number or 'start'``, ``'a', 'b' or 'c'``."""
    words = list(dict.fromkeys(_alternatives(tp)))
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} or {words[-1]}"


def _coerce(value: Any, tp: Any, key: str, source: str) -> Any:
    """Check ``value`` against the annotation ``tp``; return the typed value."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (Union, types.UnionType):
        errors = []
        for alt in args:
            try:
                return _coerce(value, alt, key, source)
            except ConfigError as err:
                errors.append(err)
        raise ConfigError(f"{source}: key '{key}': expected {_type_name(tp)}, got {value!r}")
    if tp is type(None):
        if value is None:
            return None
        raise ConfigError(f"{source}: key '{key}': expected null, got {value!r}")
    if origin is Literal:
        if value in args:
            return value
        raise ConfigError(f"{source}: key '{key}': {value!r} is not one of "
                          f"{', '.join(repr(a) for a in args)}")
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return from_dict(tp, value, source=source, prefix=key)
    if origin is list:
        if not isinstance(value, list):
            raise ConfigError(f"{source}: key '{key}': expected a list, got {value!r}")
        return [_coerce(v, args[0], f"{key}[{i}]", source) for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{source}: key '{key}': expected a mapping, got {value!r}")
        return dict(value)
    if tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif tp is str:
        if isinstance(value, str):
            return value
    raise ConfigError(f"{source}: key '{key}': expected {_type_name(tp)}, got {value!r}")


def from_dict(cls: type, data: Any, *, source: str = "config", prefix: str = "") -> Any:
    """Build dataclass ``cls`` from a mapping, refusing unknown keys and wrong types."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: key '{prefix or '<top>'}': expected a mapping, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    kwargs = {}
    for key, value in data.items():
        dotted = f"{prefix}.{key}" if prefix else str(key)
        if key not in names:
            raise ConfigError(f"{source}: key '{dotted}': unknown key (known: "
                              f"{', '.join(sorted(names))})" + _mapping_hint(data, names, prefix))
        kwargs[key] = _coerce(value, hints[key], dotted, source)
    try:
        return cls(**kwargs)
    except ConfigError as err:  # a dataclass's own value check: add the file name
        raise ConfigError(f"{source}: {_under(str(err), prefix)}") from None


#: Top-level keys of a column mapping (:mod:`thermonet.data.mapping`) no config has.
_MAPPING_KEYS = {"channels", "time", "separator", "format", "skip_lines", "header", "n_fields",
                 "malformed_rows", "sample_rate_hz", "run_column", "device_column"}


def _mapping_hint(data: dict, names: set[str], prefix: str) -> str:
    """A column mapping given where a comparison config (its ``data`` and ``families``
    sections) was expected: say so, and where a mapping goes."""
    mine = _MAPPING_KEYS & {str(k) for k in data}
    if prefix or not {"data", "families"} <= names or not ("channels" in mine or
                                                           len(mine) > 1):
        return ""
    return ("; this looks like a column mapping, not a config: name it under data.mapping in "
            "a config (with data.paths), or pass it with --mapping to thermonet info/convert")


def _under(msg: str, prefix: str) -> str:
    """A dataclass's own message (``key 'max_pp': …``, ``key 'train.lr': …``) with its key
    where the config holds it: under ``prefix`` (``limits.*.max_pp``), its own section name
    replaced by the prefix's path (``families[0].train.lr``)."""
    m = re.match(r"key '([^']*)'", msg)
    if not prefix or m is None or m[1] == prefix or m[1].startswith(prefix + "."):
        return msg
    head = prefix.rsplit(".", 1)[-1] + "."
    key = m[1][len(head):] if m[1].startswith(head) else m[1]
    return f"key '{prefix}.{key}'{msg[m.end():]}"


def to_dict(obj: Any) -> Any:
    """The resolved config as plain data (for YAML, JSON and MLflow params)."""
    return dataclasses.asdict(obj)
