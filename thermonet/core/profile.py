"""Where a command's time goes: named stages, timed when ``--profile`` asks for it.

Every command (``compare``, ``calibrate``, ``export``, ``verify``, ``fleet`` …) marks its steps
with :func:`stage`; with profiling off (the default) a stage costs one attribute lookup.
``thermonet … --profile`` turns it on and prints :func:`report` at the end: per stage its wall
seconds, CPU seconds of this process and how often it ran, beside the process's start-up
(interpreter and imports before the command began, read from ``/proc`` where it exists) and
the whole.  Stages nest: a stage's time includes its children's, and the table indents them.

The figures are one run's; ``experiments/bench_pipeline.py`` repeats whole commands and gives
medians with their spread.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

__all__ = ["stage", "enable", "enabled", "report", "reset", "startup_seconds", "timings"]


@dataclass
class _Stage:
    depth: int
    wall: float = 0.0
    cpu: float = 0.0
    calls: int = 0


_ON = False
_STAGES: dict[str, _Stage] = {}
_LOCAL = threading.local()     # nesting depth per thread (families fit side by side)
_T0: tuple[float, float] | None = None


def enable(on: bool = True) -> None:
    """Start (or stop) recording stages; the whole is timed from here."""
    global _ON, _T0
    _ON = on
    if on:
        _T0 = (time.perf_counter(), time.process_time())


def enabled() -> bool:
    return _ON


def reset() -> None:
    _STAGES.clear()
    _LOCAL.depth = 0


@contextmanager
def stage(name: str) -> Iterator[None]:
    """Time the block as stage ``name`` (accumulated over repeated calls).  CPU seconds are
    the whole process's over the block (with families fitted side by side, a stage's CPU
    includes its neighbours')."""
    if not _ON:
        yield
        return
    depth = getattr(_LOCAL, "depth", 0)
    rec = _STAGES.setdefault(name, _Stage(depth))
    t0, c0 = time.perf_counter(), time.process_time()
    _LOCAL.depth = depth + 1
    try:
        yield
    finally:
        _LOCAL.depth = depth
        rec.wall += time.perf_counter() - t0
        rec.cpu += time.process_time() - c0
        rec.calls += 1


def startup_seconds() -> float | None:
    """Seconds from this process's start to now (Linux ``/proc``; None elsewhere)."""
    try:
        with open("/proc/self/stat", encoding="ascii") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        with open("/proc/uptime", encoding="ascii") as fh:
            uptime = float(fh.read().split()[0])
        ticks = os.sysconf("SC_CLK_TCK")
        return uptime - int(fields[19]) / ticks
    except (OSError, ValueError, IndexError):
        return None


def timings() -> dict[str, dict[str, float]]:
    """``{stage: {"wall_s", "cpu_s", "calls"}}`` in the order the stages began."""
    return {k: {"wall_s": v.wall, "cpu_s": v.cpu, "calls": v.calls} for k, v in _STAGES.items()}


def report(startup_s: float | None = None) -> str:
    """The stage table: wall and CPU seconds, calls, share of the whole."""
    whole = time.perf_counter() - _T0[0] if _T0 else sum(
        v.wall for v in _STAGES.values() if v.depth == 0)
    cpu_whole = time.process_time() - _T0[1] if _T0 else 0.0
    lines = [f"{'stage':<52} {'wall s':>8} {'cpu s':>8} {'calls':>6} {'share':>6}"]
    if startup_s is not None:
        lines.append(f"{'start-up (interpreter, imports)':<52} {startup_s:8.2f} {'':>8} "
                     f"{1:6d} {'':>6}")
    for name, v in _STAGES.items():
        label = "  " * v.depth + name
        share = 100.0 * v.wall / whole if whole > 0 else 0.0
        lines.append(f"{label[:52]:<52} {v.wall:8.2f} {v.cpu:8.2f} {v.calls:6d} {share:5.1f}%")
    lines.append(f"{'whole command':<52} {whole:8.2f} {cpu_whole:8.2f} {1:6d} {100.0:5.1f}%")
    return "\n".join(lines)
