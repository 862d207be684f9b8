"""Atomic file writes: a file thermonet writes is complete or absent, never half-written."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from .errors import InputError

__all__ = ["atomic_path", "atomic_write_text", "not_a_file", "check_out_file", "same_file",
           "refuse_overwriting_inputs"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path: str | os.PathLike, *, make_parents: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success move it over ``path``.

    Whatever the body writes to the temporary path (and whatever it checks
    there: parity, schema) becomes ``path`` only if the body finishes without
    an exception; otherwise the temporary file is removed and an existing file
    at ``path`` is left untouched.  An ``OSError`` creating or renaming the
    temporary file names ``path`` (the user's ``--out``), not the hidden name.  The result gets the usual permissions
    (0666 less the umask), not ``mkstemp``'s private 0600.
    """
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as err:  # name the file the user asked for, not the hidden temporary one
        raise type(err)(err.errno, err.strerror, str(path)) from None
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())
        try:
            os.replace(tmp, path)
        except OSError as err:
            raise type(err)(err.errno, err.strerror, str(path)) from None
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; return the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def check_out_file(out: str | os.PathLike[str]) -> Path:
    """A command's ``--out`` file, refused in one line naming it before any work when no
    file can be written there: a directory, something not a regular file, a path below
    something that is not a directory, or a directory that cannot be written (missing
    directories are created when the file is written)."""
    path = Path(out)
    if path.is_dir():
        raise InputError(f"{path}: --out is a directory; give a file name")
    if os.path.lexists(path) and not path.is_file():
        raise InputError(f"{path}: --out {not_a_file(path, 'file')}")
    for parent in path.absolute().parents:
        if parent.is_dir():
            if not os.access(parent, os.W_OK | os.X_OK):
                raise InputError(f"{path}: --out cannot be written: {parent} is not writable")
            break
        if os.path.lexists(parent):
            raise InputError(f"{path}: --out cannot be created: {parent} is not a directory")
    return path


def not_a_file(path: str | os.PathLike, what: str = "file") -> str | None:
    """Why ``path`` cannot be read as a regular file, or None when it can.

    Says what the path is — ``<what> not found``, ``is a directory``, ``is a
    FIFO``, ``is a device`` — instead of a misleading "file not found"; a FIFO
    is refused before it is opened (reading one would block).
    """
    import stat

    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return f"{what} not found"
    except OSError as err:
        return f"cannot read ({err.strerror or err})"
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return f"is a directory, not a {what}"
    if stat.S_ISFIFO(mode):
        return f"is a FIFO, not a {what}"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return f"is a device, not a {what}"
    return f"is not a regular file, not a {what}"


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when ``a`` and ``b`` are the same file (``os.path.samefile``: hard links and
    symbolic links too); for a path that does not exist, when both resolve to one path."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


def refuse_overwriting_inputs(out: str | os.PathLike, inputs: Iterable[str | os.PathLike], *,
                              owned: Iterable[str] = ()) -> None:
    """Refuse, in one line naming both, an output that would overwrite one of ``inputs``:
    ``out`` is an input, or (an output directory) one of its entries ``owned`` — those
    thermonet replaces — is or holds an input.  Called before anything is written."""
    target = Path(out)
    for given in inputs:
        inp = Path(given)
        if not os.path.lexists(inp):
            continue
        if same_file(target, inp):
            raise InputError(f"{target}: the output is the input {inp}; refusing to overwrite "
                             "an input (nothing written)")
        for entry in owned:
            place = target / entry
            if os.path.lexists(place) and (same_file(place, inp) or inp.resolve().is_relative_to(
                    place.resolve())):
                raise InputError(f"{target}: writing the output would replace {place}, which "
                                 f"is or holds the input {inp} (nothing written)")
