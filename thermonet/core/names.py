"""Names and values read from files: one set of full-match rules, checked before use.

Every name thermonet writes into a file it later reads back (a checkpoint,
``results.json``, ONNX metadata, a Parquet file's ``thermonet`` metadata, a
column mapping) is checked against the same rule when it is read as when it
was created.  A file is never trusted: a checkpoint holds only strings and
tensors, so ``torch.load(weights_only=True)`` accepts one whose axis names
contain C source — the rules below are what stops those names from reaching
generated code.

Rules (``re.fullmatch``; never ``$``, which accepts a trailing newline):

=================== ============================================ ==============================
what                pattern                                      examples
=================== ============================================ ==============================
axis (output)       ``[a-z][a-z0-9]*_[a-z0-9]+`` + optional      ``gyro_x``, ``acc_z.bias``
                    ``.bias`` / ``.scale``; ≤ 64 characters
signal / channel    ``[A-Za-z][A-Za-z0-9_.]{0,63}``              ``temperature_c``, ``freq_hz``
feature (input)     same as a signal                             ``dT``, ``d_freq_hz2``
family (registry)   ``[a-z][a-z0-9_-]{0,31}``                    ``poly``, ``ts-fuzzy``
family label        ``[A-Za-z0-9][A-Za-z0-9_.-]{0,63}``          ``cubic``, ``rbf-16``
unit                ``[A-Za-z0-9°µμΩ%/^._-]{0,32}`` (empty:       ``deg/s``, ``m/s^2``
                    unknown)
device / run id     printable, no control characters, ≤ 128      ``pan-etu``, ``BMI 270 hot``
MLflow run id       ``[0-9a-f]{32}`` or empty
data hash           ``[0-9a-f]{8,128}`` or empty
=================== ============================================ ==============================

A family label becomes a file name (``models/<label>.pt``), so its pattern
admits no ``/``, cannot start with ``.`` (so never ``..``) and is short enough
for every file system.  Axis names must also be unique within a model.

Generated source never relies on these rules alone: :func:`c_comment` and
:func:`c_string` escape what they are given as well (defence in depth).

**Names that become paths.**  A device, run or instance id read from data may
hold ``/``, ``..``, a drive letter or a control character (``TEXT_ID`` admits
them).  Such a name never becomes a path directly: :func:`path_component` turns
it into one safe file-name component (the name itself when it already is one,
else the name with every other character replaced and a digest of the
original appended, so two different names never meet), :func:`path_components`
does so for a set of names (also apart when they differ only by case), and
:func:`inside` joins components under a root and refuses any result that
leaves it (defence in depth).
"""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from .errors import InputError

__all__ = [
    "AXIS", "SIGNAL", "FEATURE", "FAMILY", "LABEL", "UNIT", "TEXT_ID", "RUN_ID", "HASH",
    "check_name", "check_names", "check_units", "check_finite", "c_comment", "c_string",
    "path_component", "path_components", "inside",
]

AXIS = re.compile(r"(?=.{1,64}\Z)[a-z][a-z0-9]*_[a-z0-9]+(?:\.bias|\.scale)?")
SIGNAL = re.compile(r"[A-Za-z][A-Za-z0-9_.]{0,63}")
FEATURE = SIGNAL
FAMILY = re.compile(r"[a-z][a-z0-9_-]{0,31}")
LABEL = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
UNIT = re.compile(r"[A-Za-z0-9°µμΩ%/^._-]{0,32}")
TEXT_ID = re.compile(r"[^\x00-\x1f\x7f-\x9f]{1,128}")
RUN_ID = re.compile(r"(?:[0-9a-f]{32})?")
HASH = re.compile(r"(?:[0-9a-f]{8,128})?")

_WHAT = {id(AXIS): "an axis name (<kind>_<axis>, lowercase, e.g. gyro_x)",
         id(SIGNAL): "a signal/channel name (letters, digits, '_', '.'; ≤ 64)",
         id(FAMILY): "a model family key (lowercase letters, digits, '-', '_')",
         id(LABEL): "a family name (letters, digits, '_', '.', '-'; not starting with "
                    "'.' or '-'; ≤ 64 characters)",
         id(UNIT): "a unit (letters, digits, '/', '^', '.', '_', '-', '°', 'µ', '%'; ≤ 32)",
         id(TEXT_ID): "an id (printable, no control characters, 1 to 128 characters)",
         id(RUN_ID): "an MLflow run id (32 hex digits)",
         id(HASH): "a hex hash"}


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_name(value: Any, pattern: re.Pattern[str], where: str, *,
               error: type[Exception] = InputError) -> str:
    """Return ``value`` if it is a string that fully matches ``pattern``.

    Parameters
    ----------
    value : object
        What the file holds.
    pattern : re.Pattern
        One of the module's patterns.
    where : str
        ``"<file>: key 'x'"`` — the message starts with it.
    error : exception type
        Raised with one line naming ``where`` and the offending value.
    """
    if not isinstance(value, str) or pattern.fullmatch(value) is None:
        raise error(f"{where}: {_short(value)} is not {_WHAT.get(id(pattern), 'valid')}")
    return value


def check_names(values: Any, pattern: re.Pattern[str], where: str, *, unique: bool = True,
                nonempty: bool = True, error: type[Exception] = InputError) -> list[str]:
    """Check a list of names (each with :func:`check_name`, unique unless told otherwise)."""
    if not isinstance(values, (list, tuple)) or (nonempty and not values):
        raise error(f"{where}: expected a non-empty list of names, got {_short(values)}")
    out = [check_name(v, pattern, f"{where}[{i}]", error=error) for i, v in enumerate(values)]
    if unique:
        dup = sorted({v for v in out if out.count(v) > 1})
        if dup:
            raise error(f"{where}: {dup[0]!r} given twice")
    return out


def check_units(values: Any, keys: re.Pattern[str], where: str, *,
                error: type[Exception] = InputError) -> dict[str, str]:
    """Check a mapping ``name -> unit`` (names by ``keys``, units by :data:`UNIT`)."""
    if not isinstance(values, dict):
        raise error(f"{where}: expected a mapping name -> unit, got {_short(values)}")
    return {check_name(k, keys, f"{where} key", error=error):
            check_name(v, UNIT, f"{where}[{k!r}]", error=error) for k, v in values.items()}


def check_finite(value: Any, where: str, *, low: float = -math.inf, high: float = math.inf,
                 error: type[Exception] = InputError) -> float:
    """A real number (not bool) with ``low <= value <= high``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(float(value)) or not low <= float(value) <= high:
        bounds = "" if (low, high) == (-math.inf, math.inf) else f" in [{low:g}, {high:g}]"
        raise error(f"{where}: {_short(value)} is not a finite number{bounds}")
    return float(value)


def c_comment(text: Iterable[str] | str) -> str:
    """Text safe inside a C ``/* ... */`` comment: no ``*/``, ``/*``, line breaks or trigraphs.

    A backslash is replaced too (``\\`` at a line end would splice the next line in).
    """
    s = text if isinstance(text, str) else ", ".join(text)
    s = "".join(ch if ch.isprintable() and ch != "\\" else "?" for ch in s)
    while "??" in s:  # trigraphs (C99): ??/ is a backslash
        s = s.replace("??", "? ?")
    return s.replace("*/", "* /").replace("/*", "/ *")


def c_string(text: str) -> str:
    """A C string literal (with quotes) holding ``text``; non-ASCII as octal escapes."""
    out = []
    for byte in text.encode("utf-8"):
        ch = chr(byte)
        if ch in ('"', "\\", "?"):  # '?' against trigraphs
            out.append("\\" + ch)
        elif 0x20 <= byte < 0x7F:
            out.append(ch)
        else:
            out.append(f"\\{byte:03o}")
    return '"' + "".join(out) + '"'


def check_model_names(model: Any, *, error: type[Exception] = InputError) -> None:
    """A model's features, signals and axes by the rules above (before any export writes them)."""
    check_names(list(model.inputs), FEATURE, "model inputs", error=error)
    check_names(list(model.signals), SIGNAL, "model signals", error=error)
    check_names(list(model.outputs), AXIS, "model axes", error=error)


#: A name that is already a safe file-name component (the family-label rule).
_COMPONENT = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
#: Names Windows reserves for devices, whatever the extension.
_RESERVED = {"con", "prn", "aux", "nul", *(f"com{i}" for i in range(10)),
             *(f"lpt{i}" for i in range(10))}


def path_component(name: Any) -> str:
    """One safe file-name component for ``name`` (an id read from data or a file).

    ``name`` itself when it matches ``[A-Za-z0-9][A-Za-z0-9_.-]{0,63}``, does
    not end in ``.`` and is no Windows device name; otherwise the name's
    letters, digits, ``_``, ``.`` and ``-`` (others become ``_``; leading
    ``.``/``-``/``_`` dropped; at most 40 characters) followed by ``-`` and 8
    hex digits of the SHA-256 of the name: ``../../../X`` → ``X-<hash>``.  Never
    empty, never ``.`` or ``..``, never holds a separator.
    """
    text = str(name)
    if _COMPONENT.fullmatch(text) and not text.endswith(".") \
            and text.split(".")[0].lower() not in _RESERVED:
        return text
    digest = hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()[:8]
    body = re.sub(r"[^A-Za-z0-9_.-]", "_", text).lstrip("._-")[:40].rstrip(".")
    if body.split(".")[0].lower() in _RESERVED:
        body = f"id-{body}"
    return f"{body}-{digest}" if body else f"id-{digest}"


def path_components(names: Iterable[Any]) -> dict[str, str]:
    """``{name: component}`` for several names (order kept), pairwise distinct even on a
    case-insensitive file system: names whose components would meet get the digest form."""
    names = [str(n) for n in names]
    comps = {n: path_component(n) for n in names}
    folded: dict[str, list[str]] = {}
    for n, c in comps.items():
        folded.setdefault(c.lower(), []).append(n)
    for group in folded.values():
        if len(group) > 1:
            for n in group:
                digest = hashlib.sha256(n.encode("utf-8", "surrogatepass")).hexdigest()[:8]
                comps[n] = f"{comps[n][:40].rstrip('.')}-{digest}"
    if len({c.lower() for c in comps.values()}) < len(comps):  # a digest collision: no way on
        raise InputError("names that become file names collide after making them safe: "
                         + ", ".join(repr(n) for n in names[:5]))
    return comps


def inside(root: str | Path, *components: str) -> Path:
    """``root / components...``, refused (:class:`InputError`) unless it stays inside ``root``.

    Each component must be a single safe name (:func:`path_component` makes one);
    the joined path, symbolic links resolved, must lie under ``root``.
    """
    base = Path(root)
    for c in components:
        if not c or c in (".", "..") or "/" in c or "\\" in c or "\x00" in c:
            raise InputError(f"{base}: {_short(c)} is not a single file name")
    path = base.joinpath(*components)
    if not path.resolve().is_relative_to(base.resolve()):
        raise InputError(f"{path}: leaves {base}; refusing to write there")
    return path
