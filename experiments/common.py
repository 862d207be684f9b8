"""Shared bits of the benchmarks: where results go, which machine made them, how to time.

Timings are medians of repeats with their min–max spread; competing variants
are timed interleaved (A, B, A, B, …) so a change in the machine's load hits
them alike, and their ratio is the median of the per-repeat ratios.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import time
from collections.abc import Callable
from datetime import date
from pathlib import Path
from typing import Any

OUT = Path(__file__).resolve().parent / "out"

#: ``python -c COMPARE_CHILD CONFIG OUT``: one ``thermonet compare --no-track -q`` in a fresh
#: process; prints its return code, wall and CPU seconds and peak resident memory as JSON.
COMPARE_CHILD = """
import json, resource, sys, time
from thermonet.cli import main
t0, c0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
rc = main(["compare", sys.argv[1], "--out", sys.argv[2], "--no-track", "-q"])
c1 = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"rc": rc, "wall_s": time.perf_counter() - t0,
                  "cpu_s": c1.ru_utime + c1.ru_stime - c0.ru_utime - c0.ru_stime,
                  "maxrss_mb": c1.ru_maxrss / 1024.0}))
"""


def machine() -> str:
    """One line naming the machine a figure came from."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        load = "load average {:.1f} / {:.1f} / {:.1f} (1/5/15 min) when saved".format(
            *os.getloadavg())
    except OSError:
        load = "load unknown"
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, " \
           f"Python {platform.python_version()}, {date.today().isoformat()}, {load}"


def spread(values: list[float]) -> dict[str, float]:
    """Median, min and max of repeated measurements."""
    v = sorted(float(x) for x in values)
    n = len(v)
    med = v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])
    return {"median": med, "min": v[0], "max": v[-1], "n": n}


def fmt_spread(s: dict[str, float], scale: float = 1.0, digits: int = 3) -> str:
    """``median (min–max)`` of a :func:`spread`, each times ``scale``."""
    g = f"{{:.{digits}g}}"
    return (g.format(s["median"] * scale) + " (" + g.format(s["min"] * scale) + "–"
            + g.format(s["max"] * scale) + ")")


def interleaved(fns: dict[str, Callable[[], Any]], repeats: int, warmup: int = 1, *,
                cpu: dict[str, list[float]] | None = None) -> dict[str, list[float]]:
    """Wall seconds per call of each function, timed in turn (A, B, C, A, B, C, …).

    ``cpu``, when given, receives the process CPU seconds of each call as well: for a
    single-threaded call this is the work itself, nearly free of what other
    processes on a loaded machine do to the wall time.
    """
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    times: dict[str, list[float]] = {k: [] for k in fns}
    if cpu is not None:
        cpu.update({k: [] for k in fns})
    for _ in range(repeats):
        for k, fn in fns.items():
            c0 = time.process_time()
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
            if cpu is not None:
                cpu[k].append(max(time.process_time() - c0, 1e-9))
    return times


def ratio_spread(num: list[float], den: list[float]) -> dict[str, float]:
    """Spread of the per-repeat ratios num[i] / den[i] (paired, same moment)."""
    return spread([a / b for a, b in zip(num, den, strict=True)])


def save(name: str, data: dict[str, Any], markdown: str) -> Path:
    OUT.mkdir(parents=True, exist_ok=True)
    data = {"machine": machine(), **data}
    (OUT / f"{name}.json").write_text(json.dumps(data, indent=2, default=float))
    text = f"_Machine: {data['machine']}_\n\n{markdown}\n"
    (OUT / f"{name}.md").write_text(text)
    print(text)
    return OUT / f"{name}.md"


def table(header: list[str], rows: list[list[Any]]) -> str:
    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.3g}"
        return str(v)
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def git_rev() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
