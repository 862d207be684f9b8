"""PX4 and ArduPilot parameter files read back into ``{name: value}``: a QGroundControl
``.params`` file (:func:`read_px4_params`: ``Vehicle-Id Component-Id Name Value Type`` lines)
or ArduPilot's ``NAME,VALUE`` / ``NAME VALUE`` lines (:func:`read_ardupilot_params`), comments
skipped, a line or value that is not one refused naming the file, the line and the parameter.
What :mod:`thermonet.exporting.autopilot` writes; torch-free.  :func:`stamp_unit` names the
unit a per-unit file of a fleet is for in a ``# unit <id>`` comment line (both formats take
``#`` comments, and both readers skip them).
"""

from __future__ import annotations

from pathlib import Path

from ..core.errors import ExportError
from ..core.fileio import atomic_write_text

__all__ = ["read_px4_params", "read_ardupilot_params", "stamp_unit", "unit_comment"]

#: Characters of a unit id a comment line keeps (the rest of a long id is cut).
UNIT_ID_CHARS = 120


def unit_comment(unit_id: str) -> str:
    """``# unit <id>``: the id's printable ASCII kept, anything else (a line break that would
    end the comment) as ``?``."""
    safe = "".join(ch if " " <= ch <= "~" else "?" for ch in str(unit_id)[:UNIT_ID_CHARS])
    return f"# unit {safe}"


def stamp_unit(path: str | Path, unit_id: str) -> Path:
    """Put :func:`unit_comment` first in the parameter file at ``path`` (rewritten whole)."""
    text = _text(path)
    return atomic_write_text(Path(path), unit_comment(unit_id) + "\n" + text)


def read_px4_params(path: str | Path) -> dict[str, float]:
    """Parse a QGC ``.params`` file into ``{name: value}`` (comments skipped)."""
    out: dict[str, float] = {}
    for no, line in enumerate(_text(path).splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 5:
            raise ExportError(f"{path}: line {no}: expected 5 fields "
                              f"(Vehicle-Id Component-Id Name Value Type), got {len(parts)}")
        out[parts[2]] = _number(path, no, parts[2], parts[3])
    return out


def read_ardupilot_params(path: str | Path) -> dict[str, float]:
    """Parse ArduPilot ``NAME,VALUE`` or ``NAME VALUE`` lines into ``{name: value}``."""
    out: dict[str, float] = {}
    for no, line in enumerate(_text(path).splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) != 2:
            raise ExportError(f"{path}: line {no}: expected NAME,VALUE, got {line!r}")
        out[parts[0]] = _number(path, no, parts[0], parts[1])
    return out


def _text(path: str | Path) -> str:
    """The file's text; a UTF-8 byte-order mark (Windows Notepad writes one) is dropped."""
    return Path(path).read_text(encoding="utf-8-sig")


def _number(path: str | Path, no: int, name: str, value: str) -> float:
    """``value`` as a float; otherwise an error naming the file, the line and the parameter."""
    try:
        return float(value)
    except ValueError:
        raise ExportError(f"{path}: line {no}: parameter {name}: value {value[:40]!r} is not a "
                          "number") from None
