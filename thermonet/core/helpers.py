"""Helper processes that import what a job needs while the job starts, then run its calls.

A command's main thread holds Python's lock, so on a machine with two cores or more one core
sits idle while it imports torch and fits.  :class:`Helpers` is a standard process pool
(:class:`concurrent.futures.ProcessPoolExecutor`, ``spawn`` start method, as the fleet's
:mod:`thermonet.core.executors`) started at the beginning of a job: each worker imports the
named modules (:meth:`Helpers.start`) on that idle core, then runs calls named by module and
function (``submit``: the command need not import what the call needs) and returns
:class:`~concurrent.futures.Future` objects.  ``compare`` has two draw its figures
(:mod:`thermonet.reporting.plot_workers`); ``calibrate`` has one per further CPU compare
instances beside it (:func:`thermonet.workflows.calibrate_compare.compare_all`).  A *first
call* (``first=``) is submitted before the imports: the first worker runs it as it starts
(compare: the data read, calibrate: the logs) while the command imports torch.

What the caller keeps: :func:`value_or_none` takes a call's value where it came back, else
None — it raised, its worker died, it could not be pickled — and the caller does that work
itself, where a genuine error is raised in its own one line.  What a call logs comes back
with its value and is said by the command as it takes it (:func:`value_or_none`).  The
workers ignore Ctrl-C (SIGINT is blocked while they start and ignored in them: the command
alone stops, then ends them, :meth:`Helpers.kill`, before it removes what it was writing),
and a worker whose command was killed outright ends itself (multiprocessing's resource
tracker then says it cleaned up the pool's semaphores).  POSIX only (the signal mask).
A ``spawn`` worker imports the program's main script again: a script run by path without
``if __name__ == "__main__":`` would run its body in every worker, so there none is started
(:func:`spawn_is_safe`; the caller works alone, as where no process can be had).

This replaced a pickle-over-pipe protocol of its own (framing, ``select``, a ready message,
a reply thread; 320 lines) in issue 51: the cost in the whole-job table of
``experiments/README.md``.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import multiprocessing
import os
import re
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path
from typing import Any

__all__ = ["Call", "Helpers", "spawn_is_safe", "usable_cores", "value_or_none"]

#: A call by name: ``(module, function, keyword arguments)``.
Call = tuple[str, str, dict[str, Any]]


def usable_cores() -> int:
    """The CPUs this process may run on (its affinity on Linux, else ``os.cpu_count()``)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:            # not on Linux
        return os.cpu_count() or 1


_GUARD = re.compile(r"""if\s+__name__\s*==\s*["']__main__["']""")


def spawn_is_safe() -> bool:
    """Whether a ``spawn`` worker starts without running this program's body again: true
    for ``thermonet`` itself, ``python -m``, ``-c``, notebooks and a script guarded by
    ``if __name__ == "__main__":`` (multiprocessing imports a main script run by path in
    each worker)."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if main is None or getattr(main, "__spec__", None) is not None or path is None:
        return True
    try:
        return bool(_GUARD.search(Path(path).read_text(errors="replace")))
    except OSError:                     # <stdin>, a deleted script: nothing to judge by
        return False


@contextlib.contextmanager
def _sigint_blocked() -> Iterator[None]:
    """SIGINT held back in this thread: a process started meanwhile inherits the mask (a
    Ctrl-C during its start-up then never reaches it); this one gets it when it leaves."""
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _worker_start() -> None:
    """A worker's initializer: in a session of its own, off the terminal (Ctrl-C and job
    control are the command's; on Linux its own scheduling group beside the other
    sessions, as a command's child started with ``start_new_session`` would be); Ctrl-C
    ignored, then unblocked; the worker ends when its command is gone (killed outright:
    no pipe tells it)."""
    os.setsid()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    parent = multiprocessing.parent_process()
    if parent is not None:
        threading.Thread(target=_end_with, args=(parent,), daemon=True).start()


def _end_with(parent: Any) -> None:
    parent.join()                       # returns once the command has exited
    os.kill(os.getpid(), signal.SIGKILL)


def _import(modules: Sequence[str]) -> None:
    for name in modules:
        importlib.import_module(name)


class _Collect(logging.Handler):
    """Keeps what a call logs — ``(logger name, level, message)`` — for its value."""

    def __init__(self) -> None:
        super().__init__()
        self.records: list[tuple[str, int, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append((record.name, record.levelno, record.getMessage()))


def _call(module: str, function: str, kwargs: dict[str, Any]
          ) -> tuple[Any, list[tuple[str, int, str]]]:
    """In a worker: ``module.function(**kwargs)`` and what it logged (not printed here)."""
    collect = _Collect()
    root = logging.getLogger()
    root.addHandler(collect)
    try:
        return getattr(importlib.import_module(module), function)(**kwargs), collect.records
    finally:
        root.removeHandler(collect)


def _ok(f: Future[Any]) -> bool:
    return f.done() and not f.cancelled() and f.exception() is None


class Helpers:
    """``n`` worker processes that import ``preload`` and run calls by name.

    ``first``: a call submitted now, before the imports (:attr:`first`, a future); without
    it the workers start at once, with it at :meth:`start` (a caller's own imports done:
    three processes importing at once on two cores slowed compare's by a fifth).  Use as a
    context manager: leaving kills the workers, whatever they are doing.  OSError where no
    process can be had (a limit, a sandbox, a script a worker would run again)."""

    def __init__(self, n: int, preload: Sequence[str], first: Call | None = None) -> None:
        if not spawn_is_safe():
            raise OSError("no helper process: a worker would run this program's script again")
        self._pool: ProcessPoolExecutor | None = ProcessPoolExecutor(
            max_workers=n, mp_context=multiprocessing.get_context("spawn"),
            initializer=_worker_start)
        self._n, self._preload = n, tuple(preload)
        self._warm: list[Future[Any]] = []
        self.first: Future[Any] | None = None
        if first is not None:
            self.first = self.submit(first[0], first[1], **first[2])
        else:
            self.start()

    @property
    def size(self) -> int:
        """How many worker processes the pool runs (at most)."""
        return self._n

    def start(self) -> None:
        """Start every worker not started yet; each imports ``preload`` (:meth:`ready`)."""
        while self._pool is not None and len(self._warm) < self._n:
            try:
                with _sigint_blocked():     # an idle worker takes it, else one is started
                    self._warm.append(self._pool.submit(_import, self._preload))
            except (OSError, RuntimeError):  # no process to be had, or the pool broken
                return

    def ready(self) -> bool:
        """True once a worker has imported ``preload`` (never waits)."""
        return self._pool is not None and any(_ok(f) for f in self._warm)

    def failed(self) -> bool:
        """True where no worker can be of use: ended, or every one's imports failed."""
        return self._pool is None or (len(self._warm) == self._n and all(
            f.done() and not _ok(f) for f in self._warm))

    def submit(self, module: str, function: str, **kwargs: Any) -> Future[Any]:
        """``module.function(**kwargs)`` in a worker; the future of ``(value, logged)``
        (:func:`value_or_none`).  Its exception where the pool is ended or broken."""
        if self._pool is None:
            f: Future[Any] = Future()
            f.set_exception(RuntimeError("the helpers have been ended"))
            return f
        try:
            with _sigint_blocked():
                return self._pool.submit(_call, module, function, kwargs)
        except (OSError, RuntimeError) as err:   # no process to be had, a broken pool
            f = Future()
            f.set_exception(err)
            return f

    def kill(self) -> None:
        """End the workers now, whatever they are doing (before the caller removes what
        they write into); calls not done are cancelled or fail."""
        pool, self._pool = self._pool, None
        if pool is None:
            return
        # the pool's own processes (ProcessPoolExecutor.kill_workers from Python 3.14):
        # killed first, then reaped by the pool's own thread alone (shutdown waits for it) —
        # a second waiter (our join beside it) could lose the race for the exit status and
        # leave the process object saying it still runs
        procs = list((getattr(pool, "_processes", None) or {}).values())
        for p in procs:
            p.kill()
        pool.shutdown(wait=True, cancel_futures=True)
        for p in procs:
            p.join()

    def __enter__(self) -> Helpers:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.kill()


def value_or_none(future: Future[Any] | None, valid: Callable[[Any], bool] = lambda _: True
                  ) -> Any:
    """The value of a :meth:`Helpers.submit` call, waited for, where it came back and passes
    ``valid`` (what it logged said here, as if it had run here); None where there is no
    call, its worker died, it raised, or the value is not what was asked for — the caller
    then does that work itself, where a genuine error is raised in its own words."""
    if future is None:
        return None
    try:
        value, logged = future.result()
    except Exception:  # noqa: BLE001 - raised, died, unpicklable: the caller does the work
        return None
    if not valid(value):
        return None
    for name, level, message in logged:
        logging.getLogger(str(name)).log(int(level), "%s", message)
    return value
