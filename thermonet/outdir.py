"""A comparison's output directory appears whole or not at all.

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
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .errors import ThermonetError
from .fileio import _umask, atomic_write_text

__all__ = ["staged_output", "is_comparison", "sha256_file", "Stage"]


def sha256_file(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's content."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def is_comparison(path: Path) -> bool:
    """True when ``path`` holds a complete comparison (a parseable ``results.json``)."""
    try:
        data = json.loads((path / "results.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and "schema" in data and isinstance(data.get("families"), dict)


def _check_target(out: Path, overwrite: bool) -> None:
    if not out.exists():
        return
    if not out.is_dir():
        raise ThermonetError(f"{out}: --out must be a directory, and this is a file")
    if not any(out.iterdir()):
        return
    if not is_comparison(out):
        raise ThermonetError(f"{out}: --out is not empty and holds no thermonet comparison "
                             "(no complete results.json); refusing to write into it")
    if not overwrite:
        raise ThermonetError(f"{out}: --out holds a previous comparison; pass --overwrite to "
                             "replace it, or choose another --out")


class Stage:
    """The staging directory of one comparison (``path``) and its final place (``out``)."""

    def __init__(self, out: Path, path: Path) -> None:
        self.out, self.path = out, path
        self.finished = False

    def finish(self, results: dict[str, Any], clean: Callable[[Any], Any]) -> None:
        """Point ``results`` at the final checkpoint paths, add their SHA-256, rewrite the file."""
        for fam in results.get("families", {}).values():
            staged = fam.get("checkpoint")
            if staged:
                fam["checkpoint_sha256"] = sha256_file(staged)
                fam["checkpoint"] = str(self.out / "models" / Path(staged).name)
        atomic_write_text(self.path / "results.json", json.dumps(clean(results), indent=2))
        self.finished = True


@contextmanager
def staged_output(out_dir: str | os.PathLike, *, overwrite: bool = False) -> Iterator[Stage]:
    """Yield a :class:`Stage`; on success (and ``Stage.finish``) move it to ``out_dir``.

    Raises
    ------
    ThermonetError
        ``out_dir`` is a file, a non-empty directory that is not a comparison,
        a comparison and ``overwrite`` is false, or cannot be created (the
        message names ``out_dir``, never the staging directory).
    """
    out = Path(out_dir)
    _check_target(out, overwrite)
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
            raise ThermonetError(f"{out}: the comparison did not finish its output")
        _install(stage, out, overwrite)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _install(stage: Path, out: Path, overwrite: bool) -> None:
    _check_target(out, overwrite)  # again: another process may have written there meanwhile
    try:
        if out.exists() and any(out.iterdir()):
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old",
                                        dir=out.absolute().parent))
            os.rename(out, old / "previous")
            os.rename(stage, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(stage, out)  # over an empty directory too (POSIX rename)
    except OSError as err:
        raise ThermonetError(f"{out}: cannot move the finished comparison into place "
                             f"({err.strerror or err})") from None
