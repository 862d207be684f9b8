"""An output directory (comparison, fleet, calibration) appears whole or not at all.

``compare`` / ``train`` build their output (checkpoints, plots,
``results.json``) in a staging directory beside ``--out``
(``.<name>.<random>.partial``, same file system) and rename it into place only
when everything is written.  So:

* an interrupted run (Ctrl-C, SIGTERM, an error) leaves ``--out`` as it was;
  the staging directory is removed on the way out.  After a SIGKILL or a power
  cut (no chance to clean up) a hidden ``.<name>.*.partial`` directory may be
  left beside ``--out``; it is never read and may be deleted;
* a non-empty ``--out`` that is not a complete thermonet comparison (no
  readable ``results.json`` with ``schema`` and ``families``) is refused;
* a previous comparison is replaced only with ``--overwrite``
  (``overwrite=True``), and the old one is removed only after the new one is
  complete.  Between the two renames ``--out`` is briefly absent, never mixed.
  Only thermonet's own outputs are replaced (:data:`KINDS`: ``results.json``,
  ``report.html``, ``models/`` …); any other entry the user put beside them is
  moved into the new directory, never deleted.

``fleet`` (``kind="fleet"``), ``calibrate`` (``kind="calibration"``) and ``verify``
(``kind="verification"``, its ``results.json`` says so) follow the same rules with their
own outputs.

``results.json`` records each checkpoint's SHA-256 (``checkpoint_sha256``);
``thermonet export DIR`` refuses a checkpoint whose content does not match it,
so a checkpoint from another comparison is never shipped by mistake.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .errors import InputError, ThermonetError
from .fileio import _umask, atomic_write_text

__all__ = ["staged_output", "is_comparison", "is_output", "check_target", "install", "make_stage",
           "relocate_json", "sha256_file", "Stage", "KINDS"]


def sha256_file(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's content."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def relocate_json(path: Path, old: Path, new: Path) -> None:
    """Rewrite the JSON file ``path`` so that every string naming ``old`` or a path under it
    names the same place under ``new`` (an output built in a staging directory)."""
    prefix, target = str(old), str(new)

    def move(obj: Any) -> Any:
        if isinstance(obj, str) and (obj == prefix or obj.startswith(prefix + os.sep)):
            return target + obj[len(prefix):]
        if isinstance(obj, dict):
            return {k: move(v) for k, v in obj.items()}
        if isinstance(obj, list):
            return [move(v) for v in obj]
        return obj

    data = json.loads(path.read_text(encoding="utf-8"))
    atomic_write_text(path, json.dumps(move(data), indent=2))


def is_comparison(path: Path) -> bool:
    """True when ``path`` holds a complete comparison (a parseable ``results.json``)."""
    try:
        data = json.loads((path / "results.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and "schema" in data and isinstance(data.get("families"), dict)


def _results(path: Path) -> dict[str, Any]:
    try:
        data = json.loads((path / "results.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


#: What each kind of output directory holds at its top level: only these entries are
#: thermonet's own (replaced with ``--overwrite``); anything else there is the user's.
KINDS: dict[str, frozenset[str]] = {
    "comparison": frozenset({"results.json", "report.html", "config.resolved.yaml", "plots",
                             "models"}),
    "fleet": frozenset({"results.json", "fleet.html", "plots", "units"}),
    "calibration": frozenset({"results.json", "report.html", "report.txt", "px4.params",
                              "ardupilot.parm", "ekf-recommendation.txt", "instances"}),
    "verification": frozenset({"results.json", "report.html", "report.txt"}),
    "station": frozenset({"results.json", "units"}),
}


def is_output(path: Path, kind: str) -> bool:
    """True when ``path`` holds a complete thermonet output of ``kind`` (see :data:`KINDS`)."""
    if kind == "comparison":
        return is_comparison(path)
    data = _results(path)
    if kind in ("fleet", "station"):
        return data.get("kind") == kind and isinstance(data.get("units"), dict)
    if (data.get("kind") == "verification") != (kind == "verification"):
        return False
    return "schema" in data and isinstance(data.get("instances"), dict) \
        and "autopilot" in data


def check_target(out: Path, overwrite: bool, kind: str = "comparison", *,
                 names: tuple[str, str] = ("--out", "--overwrite")) -> None:
    """Refuse an ``--out`` that is a file, or a non-empty directory that is not a previous
    output of ``kind`` (or is one and ``overwrite`` is false): one line naming it.  ``names``:
    how the caller spells the two options (the Python API: ``compare(out)`` and
    ``overwrite=True``), so the message names what the user can give."""
    o, w = names
    if not out.exists():
        return
    if not out.is_dir():
        raise ThermonetError(f"{out}: {o} must be a directory, and this is a file")
    if not any(out.iterdir()):
        return
    if not is_output(out, kind):
        other = next((k for k in KINDS if k != kind and is_output(out, k)), None)
        raise ThermonetError(f"{out}: {o} holds a thermonet {other}, not a {kind}; choose "
                             f"another {o}" if other else
                             f"{out}: {o} is not empty and holds no thermonet {kind} "
                             "(no complete results.json); refusing to write into it")
    if not overwrite:
        raise ThermonetError(f"{out}: {o} holds a previous {kind}; pass {w} to replace it, "
                             f"or choose another {o}")


class Stage:
    """The staging directory of one comparison (``path``) and its final place (``out``)."""

    def __init__(self, out: Path, path: Path) -> None:
        self.out, self.path = out, path
        self.finished = False

    def final_checkpoint(self, staged: str) -> tuple[str, str]:
        """Where the staged checkpoint ``staged`` will be once the output is moved, and its
        SHA-256 (recorded in results.json as ``checkpoint`` and ``checkpoint_sha256``)."""
        return str(self.out / "models" / Path(staged).name), sha256_file(staged)

    def finish(self, results: dict[str, Any]) -> None:
        """Write the finished ``results.json`` (a JSON-ready document, its checkpoints at
        their final paths: :meth:`final_checkpoint`) and mark the stage complete."""
        atomic_write_text(self.path / "results.json", json.dumps(results, indent=2))
        self.finished = True

    def done(self) -> None:
        """Mark the staging directory complete (outputs that record no checkpoints)."""
        self.finished = True


@contextmanager
def staged_output(out_dir: str | os.PathLike, *, overwrite: bool = False,
                  kind: str = "comparison") -> Iterator[Stage]:
    """Yield a :class:`Stage`; on success (and ``Stage.finish``/``done``) move it to ``out_dir``.

    ``kind`` (a key of :data:`KINDS`) says what a previous output looks like and
    which of its entries are thermonet's own.

    Raises
    ------
    ThermonetError
        ``out_dir`` is a file, a non-empty directory that is not a comparison,
        a comparison and ``overwrite`` is false, or cannot be created (the
        message names ``out_dir``, never the staging directory).
    """
    out = Path(out_dir)
    check_target(out, overwrite, kind)
    parent = out.absolute().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=parent))
        os.chmod(stage, 0o777 & ~_umask())
    except OSError as err:
        raise ThermonetError(f"{out}: cannot create the output directory "
                             f"({err.strerror or err})") from None
    st = Stage(out, stage)
    try:
        yield st
        if not st.finished:
            raise ThermonetError(f"{out}: the {kind} did not finish its output")
        install(stage, out, overwrite, kind)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def make_stage(out: Path) -> Path:
    """A staging directory beside ``out`` (its parents created), made before the work that
    fills it; an ``--out`` that cannot be created is refused in one line naming it, never the
    staging directory (fleet, station)."""
    parent = out.absolute().parent
    for d in (parent, *parent.parents):
        if d.is_dir():
            break
        if os.path.lexists(d):
            raise InputError(f"{out}: --out cannot be created: {d} is not a directory")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=parent))
        os.chmod(stage, 0o777 & ~_umask())
    except OSError as err:
        raise InputError(f"{out}: --out cannot be created ({err.strerror or err})") from None
    return stage


def install(stage: Path, out: Path, overwrite: bool, kind: str = "comparison") -> None:
    """Move the complete ``stage`` to ``out`` (checked again), replacing a previous output of
    ``kind`` only with ``overwrite``; the user's entries beside it are carried over."""
    check_target(out, overwrite, kind)  # again: another process may have written there meanwhile
    try:
        if out.exists() and any(out.iterdir()):
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old",
                                        dir=out.absolute().parent))
            previous = old / "previous"
            os.rename(out, previous)
            try:
                os.rename(stage, out)
            except OSError:
                os.rename(previous, out)  # put the previous output back as it was
                raise
            # the user's own files beside the previous output move into the new one;
            # until they have, they stay in the hidden .old directory (never deleted)
            kept = True
            for entry in sorted(previous.iterdir()):
                if entry.name in KINDS[kind]:
                    continue
                if os.path.lexists(out / entry.name):
                    kept = False
                    continue
                try:
                    os.rename(entry, out / entry.name)
                except OSError:
                    kept = False
            if kept:
                shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(stage, out)  # over an empty directory too (POSIX rename)
    except OSError as err:
        raise ThermonetError(f"{out}: cannot move the finished {kind} into place "
                             f"({err.strerror or err})") from None
