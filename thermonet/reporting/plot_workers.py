"""A comparison's figures drawn side by side by child processes started before the fits.

Drawing is a comparison's largest single stage once the fits are cheap (13 PNG files on
three axes: ~1.6 s, a third of the command), and it runs on one core while the fits before
it leave the other idle (they hold Python's lock).  :class:`PlotWorkers` starts its
children (``python -m thermonet.reporting.plot_workers``) when the comparison starts: each
imports matplotlib and the plotting module while the data load and the families fit, and
then draws its share of the figures, named by the function of
:mod:`thermonet.reporting.plots` and its keyword arguments.  The figures are the same
files as drawn in the command (the same function on the same arguments, Agg).

The children are plain subprocesses (no multiprocessing: nothing imports the caller's main
module); a job goes down a pipe as one pickle from the parent that started the child and
comes back the same way — nothing is read from a file.  A child runs in its own session
(Ctrl-C reaches the command, which ends it) and exits when its pipe closes, so a killed
command leaves none behind.  :meth:`PlotWorkers.draw` gives up on any child that fails
(an error, a crash) and draws what it had not delivered in the command itself, where a
genuine plotting error is raised as before.
"""

from __future__ import annotations

import os
import pickle
import struct
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

__all__ = ["PlotWorkers", "PlotJob", "draw_here"]

#: One figure: the name of a function of :mod:`thermonet.reporting.plots` and its keyword
#: arguments (its first, the PNG path, among them as ``path``).
PlotJob = tuple[str, dict[str, Any]]

_HEADER = struct.Struct("<Q")


def _send(stream: IO[bytes], obj: Any) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(data)) + data)
    stream.flush()


def _receive(stream: IO[bytes]) -> Any:
    head = stream.read(_HEADER.size)
    if len(head) < _HEADER.size:
        raise EOFError("plot worker pipe closed")
    size = _HEADER.unpack(head)[0]
    data = stream.read(size)
    if len(data) < size:
        raise EOFError("plot worker pipe closed")
    return pickle.loads(data)  # noqa: S301 - our own child's reply on a private pipe


def draw_here(jobs: Sequence[PlotJob]) -> list[Path]:
    """Every figure drawn in this process, in order."""
    if not jobs:
        return []
    from . import plots  # lazy: loads matplotlib

    return [Path(getattr(plots, name)(**kwargs)) for name, kwargs in jobs]


def usable_cores() -> int:
    """The CPUs this process may run on (its affinity on Linux, else ``os.cpu_count()``)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:            # not on Linux
        return os.cpu_count() or 1


class PlotWorkers:
    """``n`` child processes that import the plotting code now and draw figures later.

    ``n`` below 2 starts none: :meth:`draw` then draws in this process.  Use as a context
    manager; leaving it on an error or an interrupt kills the children at once (before the
    caller removes the directory they write into)."""

    def __init__(self, n: int) -> None:
        self._procs: list[subprocess.Popen[bytes]] = []
        if n < 2:
            return
        root = str(Path(__file__).resolve().parents[2])   # this thermonet, not another
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            [root, *filter(None, [os.environ.get("PYTHONPATH")])])}
        for _ in range(n):
            self._procs.append(subprocess.Popen(
                [sys.executable, "-m", "thermonet.reporting.plot_workers"], env=env,
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True))

    def draw(self, jobs: Sequence[PlotJob]) -> list[Path]:
        """Every figure, shared among the children (in this process without them); the
        files' paths in the order of ``jobs``."""
        procs, self._procs = self._procs, []
        if not procs or len(jobs) < 2:
            self._end(procs, kill=True)
            return draw_here(jobs)
        shares = [list(range(k, len(jobs), len(procs))) for k in range(len(procs))]
        out: list[Path | None] = [None] * len(jobs)
        try:
            for proc, share in zip(procs, shares, strict=True):
                assert proc.stdin is not None
                _send(proc.stdin, [jobs[i] for i in share])
            for proc, share in zip(procs, shares, strict=True):
                assert proc.stdout is not None
                reply = _receive(proc.stdout)
                for i, (ok, value) in zip(share, reply, strict=False):
                    if ok:
                        out[i] = Path(value)
        except (OSError, EOFError, pickle.PickleError, ValueError):
            pass                    # what a child did not deliver is drawn below
        finally:
            self._end(procs, kill=False)
        missing = [i for i, p in enumerate(out) if p is None]
        for i, path in zip(missing, draw_here([jobs[i] for i in missing]), strict=True):
            out[i] = path
        return [p for p in out if p is not None]

    @staticmethod
    def _end(procs: list[subprocess.Popen[bytes]], *, kill: bool) -> None:
        for proc in procs:
            try:
                if proc.stdin is not None:
                    proc.stdin.close()
            except OSError:
                pass
            if kill:
                proc.kill()
        for proc in procs:
            try:
                proc.wait(timeout=None if not kill else 10)
            except subprocess.TimeoutExpired:   # pragma: no cover - a child ignoring SIGKILL
                pass
            for stream in (proc.stdout,):
                if stream is not None:
                    stream.close()

    def close(self, *, kill: bool = True) -> None:
        procs, self._procs = self._procs, []
        self._end(procs, kill=kill)

    def __enter__(self) -> PlotWorkers:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close(kill=True)


def _serve(requests: IO[bytes], replies: IO[bytes]) -> int:
    """The child: import the plotting code, then draw each batch of jobs it is sent."""
    from . import plots  # matplotlib: what the child is for, imported before any job

    while True:
        try:
            jobs = _receive(requests)
        except EOFError:
            return 0
        done: list[tuple[bool, str]] = []
        for name, kwargs in jobs:
            try:
                done.append((True, str(getattr(plots, name)(**kwargs))))
            except Exception as err:  # noqa: BLE001 - the command redraws it and raises it
                done.append((False, f"{type(err).__name__}: {err}"))
        _send(replies, done)


def main() -> None:
    """Entry point of a child: requests on stdin, replies on a private copy of stdout
    (anything printed goes to stderr)."""
    replies = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    code = _serve(sys.stdin.buffer, replies)
    replies.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
