"""Helper processes that import what a job needs while the job starts, then run its calls.

A command's main thread holds Python's lock, so on a machine with two cores or more one core
sits idle while it imports torch and fits.  A :class:`Helper` is a child process
(``python -m thermonet.core.helpers MODULE ...``) started at the beginning of a job: it
imports the named modules at once, on that idle core, says it is ready, then runs calls
(``module``, ``function``, keyword arguments) one at a time and sends each result back.
``compare`` has two draw its figures (:mod:`thermonet.reporting.plot_workers`);
``calibrate`` has one per further CPU compare instances beside it, the first of them reading
the logs before its imports while the command imports torch (a *first call*, ``first=``)
(:func:`thermonet.workflows.calibrate_compare.compare_all`: 2.45 → 2.0 s on the 2-core benchmark
board, once the comparison no longer imported scikit-learn and SciPy — before, the helper's
imports took as long as the command's and it saved 0.1-0.2 s of 3.5).  A helper whose imports
fail exits without a word: the command does its work.

The child is a plain subprocess (no ``multiprocessing``: nothing imports the caller's main
module, so a script without ``if __name__ == "__main__":`` is safe); calls and results go
down private pipes as pickles between this process and the child it started — nothing is
read from a file.  The child runs in its own session (Ctrl-C reaches the command, which then
kills it: :meth:`Helper.kill`, before the command removes what it was writing) and exits
when its pipe closes, so a command killed outright leaves none behind.  What a call logs
comes back with its result and is said by the command as it takes it.  A call that raises
comes back as one line; a child that dies reports :class:`HelperGone`: the caller then does
that work itself, where a genuine error is raised as it would have been.  POSIX only: the
command waits on the helpers' pipes with ``select``.
"""

from __future__ import annotations

import importlib
import logging
import os
import pickle
import select
import struct
import subprocess
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any

__all__ = ["Helper", "HelperGone", "usable_cores", "value_or_none"]

_HEADER = struct.Struct("<Q")
_READY = "ready"
_FIRST = "--first"          # the child's argument: answer one call before the imports


class HelperGone(Exception):
    """The helper process exited or broke its pipe; its work is to be done elsewhere."""


def usable_cores() -> int:
    """The CPUs this process may run on (its affinity on Linux, else ``os.cpu_count()``)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:            # not on Linux
        return os.cpu_count() or 1


def _frame(obj: Any) -> bytes:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    return _HEADER.pack(len(data)) + data


def _send(stream: IO[bytes], obj: Any) -> None:
    stream.write(_frame(obj))
    stream.flush()


def _write(stream: IO[bytes], message: bytes) -> None:
    """Write a framed message; a pipe the command has closed ends it quietly."""
    try:
        stream.write(message)
        stream.flush()
    except (OSError, ValueError):
        pass


def _read_exact(stream: IO[bytes], n: int) -> bytes:
    """``n`` bytes (a pipe read unbuffered may return fewer at a time); EOFError at its end."""
    parts, got = [], 0
    while got < n:
        chunk = stream.read(n - got)
        if not chunk:
            raise EOFError("helper pipe closed")
        parts.append(chunk)
        got += len(chunk)
    return b"".join(parts)


def _receive(stream: IO[bytes]) -> Any:
    size = _HEADER.unpack(_read_exact(stream, _HEADER.size))[0]
    return pickle.loads(_read_exact(stream, size))  # noqa: S301 - a private pipe, our child


class Helper:
    """One child process that imports ``preload`` now and runs calls later.

    :meth:`ready` says (without waiting) whether it has finished its imports and is free;
    :meth:`submit` sends it a call; :meth:`done` says (without waiting) whether the result is
    back; :meth:`result` waits for it.  Use as a context manager: leaving kills the child.

    ``first``: a call ``(module, function, kwargs)`` the child runs as soon as it starts,
    *before* its imports (it is submitted now: :meth:`result` returns it) — work the
    command needs early from a light module, done while the command imports what it
    needs itself.  A first call that cannot be pickled raises ``ValueError`` before any
    process starts."""

    def __init__(self, preload: Sequence[str],
                 first: tuple[str, str, dict[str, Any]] | None = None) -> None:
        message = None
        if first is not None:
            try:
                message = _frame(first)
            except Exception as err:  # noqa: BLE001 - whatever pickle refuses to carry
                raise ValueError(f"the first call cannot be sent to a helper: {err}") from None
        root = str(Path(__file__).resolve().parents[2])   # this thermonet, not another
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            [root, *filter(None, [os.environ.get("PYTHONPATH")])])}
        self._proc: subprocess.Popen[bytes] | None = subprocess.Popen(
            [sys.executable, "-m", "thermonet.core.helpers",
             *([_FIRST] if first is not None else []), *preload], env=env,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True,
            bufsize=0)    # unbuffered: select() on the pipe then sees every reply
        self._started = False       # the child has said it is ready
        self._busy = False
        if message is not None:
            assert self._proc.stdin is not None
            try:
                self._proc.stdin.write(message)
                self._proc.stdin.flush()
            except (OSError, ValueError):
                self.kill()
                raise HelperGone("the helper could not be given its first call") from None
            self._busy = True

    # --------------------------------------------------------------- the command's side
    def _readable(self, timeout: float | None) -> bool:
        if self._proc is None or self._proc.stdout is None:
            raise HelperGone("the helper has been ended")
        return bool(select.select([self._proc.stdout], [], [], timeout)[0])

    def _get(self) -> Any:
        assert self._proc is not None and self._proc.stdout is not None
        try:
            return _receive(self._proc.stdout)
        except (OSError, EOFError, pickle.PickleError) as err:
            self.kill()
            raise HelperGone(str(err)) from None

    def stream(self) -> IO[bytes] | None:
        """The pipe its replies come on (for ``select``), None once it has been ended."""
        return None if self._proc is None else self._proc.stdout

    def ready(self) -> bool:
        """True when the child has imported its modules and runs nothing (never waits)."""
        if self._proc is None or self._busy:
            return False
        if not self._started:
            try:
                if not self._readable(0.0):
                    return False
                if self._get() != _READY:
                    self.kill()
                    return False
            except HelperGone:
                return False
            self._started = True
        return True

    def submit(self, module: str, function: str, **kwargs: Any) -> None:
        """Send ``module.function(**kwargs)`` to the child (it must be :meth:`ready`)."""
        if not self.ready():
            raise HelperGone("the helper is not ready")
        assert self._proc is not None and self._proc.stdin is not None
        try:
            _send(self._proc.stdin, (module, function, kwargs))
        except (OSError, ValueError) as err:
            self.kill()
            raise HelperGone(str(err)) from None
        self._busy = True

    def done(self) -> bool:
        """True when the submitted call's result is back (never waits)."""
        return self._busy and self._readable(0.0)

    def result(self) -> tuple[bool, Any]:
        """``(True, value)`` of the submitted call, or ``(False, one line)`` if it raised;
        waits for it.  :class:`HelperGone` if the child died meanwhile."""
        if not self._busy:
            raise HelperGone("nothing was submitted")
        reply = self._get()
        if not (isinstance(reply, tuple) and len(reply) == 3
                and isinstance(reply[2], list)):                   # not a call's reply
            self.kill()
            raise HelperGone("the helper sent something that is not a reply")
        self._busy = False
        ok, value, logged = reply
        if ok:    # what the call logged, said here as if the call had run here
            for name, level, message in logged:
                logging.getLogger(str(name)).log(int(level), "%s", message)
        return ok, value

    def kill(self) -> None:
        """End the child now, whatever it is doing."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        proc.kill()
        proc.wait()
        for stream in (proc.stdin, proc.stdout):
            try:
                if stream is not None:
                    stream.close()
            except OSError:
                pass

    def __enter__(self) -> Helper:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.kill()


def value_or_none(helper: Helper | None, valid: Callable[[Any], bool] = lambda _: True
                  ) -> Any:
    """The value of ``helper``'s submitted call, waited for, where it came back and passes
    ``valid``; None where there is no helper, it died, the call raised, or the value is not
    what was asked for — the caller then does that work itself, where a genuine error is
    raised in its own words."""
    if helper is None:
        return None
    try:
        ok, value = helper.result()
    except HelperGone:
        return None
    return value if ok and valid(value) else None


# ------------------------------------------------------------------------ the child's side
class _Collect(logging.Handler):
    """Keeps what a call logs — ``(logger name, level, message)`` — for its reply."""

    def __init__(self) -> None:
        super().__init__()
        self.records: list[tuple[str, int, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append((record.name, record.levelno, record.getMessage()))


def _call(requests: IO[bytes]) -> tuple[bool, Any, list[tuple[str, int, str]]] | None:
    """Run the next call: its reply — ``(ok, value or one line, what it logged)`` — or None
    once the pipe has closed.  What the call logs (warnings: a file's skipped rows, a
    damaged log) is not printed here but sent with the reply and said by the command when
    it takes the result, as if the call had run there (and not at all if the command
    does the work again itself)."""
    try:
        module, function, kwargs = _receive(requests)
    except EOFError:
        return None
    collect = _Collect()
    root = logging.getLogger()
    root.addHandler(collect)
    try:
        return True, getattr(importlib.import_module(module), function)(**kwargs), \
            collect.records
    except Exception as err:  # noqa: BLE001 - the command redoes the work and raises it
        text = str(err).strip().splitlines()
        return False, f"{type(err).__name__}: {text[0] if text else ''}", []
    finally:
        root.removeHandler(collect)


def _serve(preload: Sequence[str], requests: IO[bytes], replies: IO[bytes], *,
           first: bool = False) -> int:
    sending = None
    if first:
        reply = _call(requests)
        if reply is None:
            return 0
        try:
            message = _frame(reply)
        except Exception as err:  # noqa: BLE001 - a result pickle cannot carry: said, not sent
            message = _frame((False, f"{type(err).__name__}: the result cannot be sent", []))
        # written beside the imports: a reply larger than the pipe holds waits there until the
        # command reads it, which it does once its own imports are done
        sending = threading.Thread(target=_write, args=(replies, message), daemon=True)
        sending.start()
        del reply, message      # held by the writer alone: freed once it is written
    try:
        for name in preload:
            importlib.import_module(name)
    except Exception:  # noqa: BLE001 - the command sees the pipe close and does the work
        return 1       # itself, where a genuine error is raised once (no traceback here)
    finally:
        if sending is not None:
            sending.join()
    _send(replies, _READY)
    while (reply := _call(requests)) is not None:
        _send(replies, reply)
    return 0


def main() -> None:
    """Entry point of a helper: calls on stdin, results on a private copy of stdout
    (anything printed goes to stderr)."""
    replies = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    args = sys.argv[1:]
    first = bool(args) and args[0] == _FIRST
    code = _serve(args[1:] if first else args, sys.stdin.buffer, replies, first=first)
    replies.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
