"""Where the units of a fleet run: in this process, a local process pool, or a Ray cluster.

One start-up per job, not per unit: workers import torch and thermonet once and
then take unit after unit.

``serial``
    In this process, one after the other (torch pinned to one thread meanwhile).
``process`` (default)
    :class:`concurrent.futures.ProcessPoolExecutor` with the ``spawn`` start
    method (a fork of a process that has started torch's thread pools is
    unsafe).  Each worker is pinned to one thread (``torch.set_num_threads(1)``,
    ``OMP_NUM_THREADS=MKL_NUM_THREADS=OPENBLAS_NUM_THREADS=1``), so
    ``workers`` processes use ``workers`` cores and the results do not depend
    on how many threads a reduction was split over.
``ray``
    ``ray.init(address=...)`` — an existing cluster (``"auto"``,
    ``"ray://head:10001"``, ``"head:6379"``) or, with no address, a local Ray
    started for this job.  Tasks ask for one CPU each and are never retried
    (a retried unit could hide a crash); thermonet must be importable on
    every node (installed in the nodes' environment).

Every task returns plain data (dicts, lists, bytes, and torch modules by value)
and writes nothing shared: the driver alone writes files and MLflow.  A task
that raises, or a worker process that dies (killed, out of memory, a segfault
in native code), gives a :class:`TaskFailure` for that item and the other
items finish.  In the process pool a dead worker breaks the pool for every
task in flight: the items a worker had started (shared flags say which) are
re-run one at a time, each in a fresh one-worker pool, so only the item that
kills its worker is reported failed; items not yet started go to a fresh pool.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Literal

from .errors import ThermonetError
from .helpers import usable_cores

__all__ = ["EXECUTORS", "ExecutorError", "TaskFailure", "run_tasks", "pin_one_thread"]

#: Names accepted by ``--executor``.
EXECUTORS = ("process", "serial", "ray")
_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


class ExecutorError(ThermonetError):
    """The executor cannot run at all (Ray cluster not reachable, a bad worker count)."""


@dataclass
class TaskFailure:
    """An item whose task raised or whose worker died; ``reason`` is one line."""

    reason: str


def pin_one_thread() -> None:
    """Pin this process's numerical libraries to one thread (a pool worker's initializer).

    The environment variables are read when torch and NumPy's BLAS start, so a worker that
    imports torch later gets one thread without paying the import here; a process that has
    already imported torch is pinned with ``torch.set_num_threads(1)``.
    """
    import sys

    for var in _THREAD_VARS:
        os.environ[var] = "1"
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)


def _one_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0] if text else ''}".rstrip(": ")


def _call(fn: Callable[[Any], Any], item: Any) -> Any:
    """Run ``fn(item)``; an exception becomes a :class:`TaskFailure` (plain data)."""
    try:
        return fn(item)
    except ThermonetError as err:
        return TaskFailure(str(err))
    except Exception as err:  # any bug in one unit must not sink the fleet: reported per unit
        return TaskFailure(_one_line(err))


def _serial(fn: Callable[[Any], Any], items: Sequence[Any]) -> list[Any]:
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)  # the same arithmetic as a pinned worker
    try:
        return [_call(fn, it) for it in items]
    finally:
        torch.set_num_threads(before)


_STARTED: Any = None  # a worker's view of the pool's shared "started" flags


def _init_worker(started: Any) -> None:
    global _STARTED
    _STARTED = started
    pin_one_thread()


def _tracked(fn: Callable[[Any], Any], i: int, item: Any) -> Any:
    if _STARTED is not None:
        _STARTED[i] = 1
    return _call(fn, item)


def _pool(fn: Callable[[Any], Any], items: Sequence[Any], workers: int,
          on_done: Callable[[int, Any], None] | None, keep: bool = True) -> list[Any]:
    import multiprocessing
    from concurrent.futures import as_completed

    ctx = multiprocessing.get_context("spawn")
    out: list[Any] = [None] * len(items)
    done = [False] * len(items)

    def finish(i: int, value: Any) -> None:
        out[i], done[i] = (value if keep else None), True
        if on_done is not None:
            on_done(i, value)

    todo = list(range(len(items)))
    while todo:
        # shared flags say which items a worker had started when the pool broke: those are
        # the suspects; items never started go to a fresh pool as before
        started = ctx.Array("b", len(items), lock=False)
        try:
            with ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=ctx,
                                     initializer=_init_worker, initargs=(started,)) as pool:
                futures: dict[Future[Any], int] = {pool.submit(_tracked, fn, i, items[i]): i
                                                   for i in todo}
                for fut in as_completed(futures):
                    try:
                        value = fut.result()
                    except BrokenProcessPool:
                        continue
                    finish(futures.pop(fut), value)   # the future held its result
        except BrokenProcessPool:
            pass
        left = [i for i in todo if not done[i]]
        suspects = [i for i in left if started[i]]
        if left and not suspects and len(left) == len(todo):  # no worker even started
            for i in left:
                finish(i, TaskFailure("worker processes could not start"))
            break
        for i in suspects:  # alone in a fresh worker: only the item that kills it fails
            try:
                with ProcessPoolExecutor(max_workers=1, mp_context=ctx,
                                         initializer=pin_one_thread) as solo:
                    value = solo.submit(_call, fn, items[i]).result()
            except BrokenProcessPool:
                value = TaskFailure("worker process died (killed, out of memory or crashed) "
                                    "while running this unit")
            finish(i, value)
        todo = [i for i in left if not started[i]]
    return out


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """A TCP connect to ``host:port`` (or ``ray://host:port``) first: Ray itself retries an
    unreachable head for minutes, logging a warning every few seconds."""
    import socket

    if address == "auto":
        return  # a local cluster found through Ray's own session files
    hostport = address.split("://", 1)[-1]
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        raise ExecutorError(f"--ray-address '{address}': expected host:port, ray://host:port "
                            "or auto")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except OSError as err:
        raise ExecutorError(f"Ray cluster at '{address}' not reachable: {err.strerror or err}"
                            ) from None


def _ray(fn: Callable[[Any], Any], items: Sequence[Any], workers: int, address: str | None,
         on_done: Callable[[int, Any], None] | None, keep: bool = True) -> list[Any]:
    try:
        import ray
    except ImportError as err:  # pragma: no cover - ray is a dependency
        raise ExecutorError(f"--executor ray: ray is not installed ({err})") from None
    env = {"env_vars": {v: "1" for v in _THREAD_VARS}}
    started = False
    if address:
        _check_reachable(address)
    if not ray.is_initialized():
        try:
            if address:
                ray.init(address=address, runtime_env=env, log_to_driver=False,
                         logging_level=logging.ERROR)
            else:
                ray.init(num_cpus=workers, include_dashboard=False, runtime_env=env,
                         log_to_driver=False, logging_level=logging.ERROR)
        except Exception as err:  # ray.init raises a bare Exception when a node cannot start
            where = f"at '{address}'" if address else "(local)"
            raise ExecutorError(f"Ray cluster {where} not reachable or not started: "
                                f"{_one_line(err)}") from None
        started = True
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(_ray_call)
        index = {task.remote(fn, it): i for i, it in enumerate(items)}
        out: list[Any] = [None] * len(items)
        pending = list(index)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            i = index.pop(ready[0])             # no reference left: Ray may free the result
            try:
                value = ray.get(ready[0])
            except ray.exceptions.RayError as err:  # worker died, node lost, task error
                value = TaskFailure(f"Ray task failed: {_one_line(err)}")
            del ready
            if on_done is not None:
                on_done(i, value)
            out[i] = value if keep else None
        return out
    finally:
        if started:
            ray.shutdown()


def _ray_call(fn: Callable[[Any], Any], item: Any) -> Any:
    pin_one_thread()
    return _call(fn, item)


def run_tasks(fn: Callable[[Any], Any], items: Sequence[Any], *,
              executor: Literal["process", "serial", "ray"] = "process",
              workers: int | None = None, ray_address: str | None = None,
              on_done: Callable[[int, Any], None] | None = None,
              keep: bool = True) -> list[Any]:
    """``[fn(item) for item in items]`` on the chosen executor, in the order of ``items``.

    Parameters
    ----------
    fn : callable
        A module-level function (pickled by reference to the workers).
    items : sequence
        Picklable task descriptions.
    executor : {"process", "serial", "ray"}
    workers : int, optional
        Processes (or local Ray CPUs); default ``os.cpu_count()``; 0: one per CPU this
        process may use (:func:`~thermonet.core.helpers.usable_cores`, as ``compare``).
    ray_address : str, optional
        Ray cluster address; None starts a local Ray.
    on_done : callable(index, result), optional
        Called in the driver as each item finishes (progress lines).
    keep : bool
        False: on the process pool and Ray each result is only handed to ``on_done`` and
        not held (the list returned holds None), so a driver that folds the results as they
        arrive holds none of them; serial runs return theirs all the same.

    Returns
    -------
    list
        ``fn(item)``'s value, or a :class:`TaskFailure` for an item whose task
        raised or whose worker died.
    """
    if executor not in EXECUTORS:
        raise ExecutorError(f"unknown executor '{executor}' (valid: {', '.join(EXECUTORS)})")
    n = (os.cpu_count() or 1) if workers is None else int(workers)
    if n == 0:                    # as compare --workers 0: one per CPU this process may use
        n = usable_cores()
    if n < 1:
        raise ExecutorError(f"--workers must be at least 0 (0: one per CPU), got {workers}")
    if not items:
        return []
    if executor == "serial":
        out = _serial(fn, items)
        if on_done is not None:
            for i, r in enumerate(out):
                on_done(i, r)
        return out
    if executor == "ray":
        return _ray(fn, items, n, ray_address, on_done, keep)
    return _pool(fn, items, n, on_done, keep)
