"""The API's arguments checked at the door: one error naming the argument and what it takes.

Every public function and class of :mod:`thermonet.api` checks its arguments' types and
ranges first — before any file is opened, any data is read or reduced, any model is built —
and refuses a bad one in one line: ``read(window_s): expected a number of seconds > 0 or
None, got True (bool)``.  The rules, the same everywhere:

* ``bool`` is not a number: ``window_s=True``, ``workers=True``, ``n_splits=False`` are
  refused (a numpy integer or float is a number);
* a switch (``track``, ``overwrite``, ``plots``, ``quiet``) is ``True`` or ``False`` only:
  ``track="no"`` is refused, not read as true.  A tracking store is ``tracking_uri``;
* a count is a whole number in its range (``workers``: ``0`` is the documented "one per
  CPU", None the config's; ``chunk_rows`` ≥ 1);
* seconds are finite numbers (``gap_s`` also ``"auto"``);
* a path is a ``str`` or ``os.PathLike`` (``read(123)``, ``mapping=5``, ``out=123`` are
  refused); ``paths`` also a non-empty list of them;
* a list of names (``inputs``, ``outputs``) is a list of strings, or one name alone as a
  string (``inputs="dT"`` is ``["dT"]``, never the letters ``d`` and ``T``), and each input
  must be one thermonet knows (:func:`thermonet.features.inputs.signals_for`).

A value of the wrong type raises :class:`ArgumentTypeError`, which is both a ``TypeError``
and thermonet's ``ConfigError`` (a ``ValueError``); a value out of range raises
``ConfigError``.  Either way the message names the argument.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Iterable
from typing import Any

from ..core.errors import ConfigError
from ..features.inputs import signals_for

__all__ = ["ArgumentTypeError", "flag", "whole", "seconds", "path", "paths", "text",
           "input_names", "gap"]


class ArgumentTypeError(ConfigError, TypeError):
    """An API argument of the wrong type: a ``TypeError`` and a ``ConfigError`` (a
    ``ValueError``) at once, its message naming the argument and what it takes."""


def _got(value: Any) -> str:
    shown = repr(value)
    if len(shown) > 80:
        shown = shown[:77] + "..."
    return f"{shown} ({type(value).__name__})"


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) \
        and type(value).__name__ != "bool_"


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) \
        and type(value).__name__ != "bool_"


def flag(value: Any, what: str) -> bool:
    """``True`` or ``False`` (numpy's too); anything else refused."""
    if isinstance(value, bool) or type(value).__name__ == "bool_":
        return bool(value)
    raise ArgumentTypeError(f"{what}: expected True or False, got {_got(value)}")


def whole(value: Any, what: str, lo: int, hi: int | None = None, *, none: bool = False,
          note: str = "") -> int | None:
    """A whole number in ``lo..hi`` (None allowed with ``none``); ``note`` says a sentinel."""
    if value is None and none:
        return None
    span = f">= {lo}" if hi is None else f"in {lo}..{hi}"
    rule = f"a whole number {span}{note}{' or None' if none else ''}"
    if not _is_int(value):
        raise ArgumentTypeError(f"{what}: expected {rule}, got {_got(value)}")
    if value < lo or (hi is not None and value > hi):
        raise ConfigError(f"{what}: expected {rule}, got {value!r}")
    return int(value)


def seconds(value: Any, what: str, *, lo: float = 0.0, hi: float = math.inf,
            lo_open: bool = True, none: bool = False, unit: str = "seconds") -> float | None:
    """A finite number in (``lo``, ``hi``] (``[lo, hi]`` unless ``lo_open``)."""
    if value is None and none:
        return None
    bound = f"{'>' if lo_open else '>='} {lo:g}" + (f" and <= {hi:g}" if math.isfinite(hi)
                                                     else "")
    rule = f"a number of {unit} {bound}{' or None' if none else ''}"
    if not _is_real(value):
        raise ArgumentTypeError(f"{what}: expected {rule}, got {_got(value)}")
    v = float(value)
    if not math.isfinite(v) or v < lo or (lo_open and v == lo) or v > hi:
        raise ConfigError(f"{what}: expected {rule}, got {value!r}")
    return v


def gap(value: Any, what: str) -> float | str:
    """A dynamic input's gap limit: ``"auto"`` or seconds in 1e-6 … 1e7 (the config's rule)."""
    if isinstance(value, str):
        if value != "auto":
            raise ConfigError(f"{what}: expected 'auto' or a number of seconds in 1e-06 … "
                              f"1e+07, got {value!r}")
        return value
    if not _is_real(value):
        raise ArgumentTypeError(f"{what}: expected 'auto' or a number of seconds in 1e-06 … "
                                f"1e+07, got {_got(value)}")
    v = float(value)
    if not (math.isfinite(v) and 1e-6 <= v <= 1e7):
        raise ConfigError(f"{what}: expected 'auto' or a number of seconds in 1e-06 … 1e+07, "
                          f"got {value!r}")
    return v


def path(value: Any, what: str, *, none: bool = False) -> str | os.PathLike[str] | None:
    """A file or directory name: a non-empty ``str`` or an ``os.PathLike``."""
    if value is None and none:
        return None
    if isinstance(value, os.PathLike) and isinstance(os.fspath(value), str):
        return value
    if isinstance(value, str):
        if not value.strip():
            raise ConfigError(f"{what}: an empty path")
        return value
    rule = "a path (str or os.PathLike)" + (" or None" if none else "")
    raise ArgumentTypeError(f"{what}: expected {rule}, got {_got(value)}")


def paths(value: Any, what: str) -> list[str | os.PathLike[str]]:
    """One path, or a non-empty list or tuple of them."""
    if isinstance(value, (str, os.PathLike)):
        return [path(value, what)]  # type: ignore[list-item]
    if not isinstance(value, (list, tuple)):
        raise ArgumentTypeError(f"{what}: expected a path (str or os.PathLike) or a list of "
                                f"them, got {_got(value)}")
    if not value:
        raise ConfigError(f"{what}: an empty list; give at least one file")
    return [path(v, f"{what}[{i}]") for i, v in enumerate(value)]  # type: ignore[misc]


def text(value: Any, what: str, *, none: bool = False, rule: str = "a non-empty string"
         ) -> str | None:
    """A non-empty string (None allowed with ``none``)."""
    if value is None and none:
        return None
    if not isinstance(value, str):
        raise ArgumentTypeError(f"{what}: expected {rule}{' or None' if none else ''}, "
                                f"got {_got(value)}")
    if not value.strip():
        raise ConfigError(f"{what}: expected {rule}, got an empty string")
    return value


def input_names(value: Any, what: str, *, empty: bool = False) -> list[str]:
    """Model inputs: one name or a list of names, each a known input (``T``, ``dT``, ``rate``,
    ``d_<proxy>``…); ``empty`` allows none."""
    if isinstance(value, str):
        names = [value]
    elif isinstance(value, Iterable) and not isinstance(value, (bytes, dict)):
        names = list(value)
        bad = [v for v in names if not isinstance(v, str)]
        if bad:
            raise ArgumentTypeError(f"{what}: expected names (strings), got "
                                    f"{_got(bad[0])} in {names!r}")
    else:
        raise ArgumentTypeError(f"{what}: expected an input name or a list of them, got "
                                f"{_got(value)}")
    if not names:
        if empty:
            return []
        raise ConfigError(f"{what}: an empty list; name at least one input, or leave it None")
    if len(set(names)) != len(names):
        raise ConfigError(f"{what}: {names} names an input twice")
    try:
        signals_for(names)
    except ConfigError as err:
        raise ConfigError(f"{what}: {err}") from None
    return names
