"""A comparison's figures drawn side by side by helper processes started before the fits.

Drawing is a comparison's largest single stage once the fits are cheap (13 PNG files on
three axes: ~1.6 s, a third of the command), and it runs on one core while the fits before
it leave the other idle (they hold Python's lock).  :class:`PlotWorkers` starts its helpers
(:class:`thermonet.core.helpers.Helpers`, a process pool) when the comparison starts: each
imports matplotlib and the plotting module while the data load and the families fit, and
then draws the figures handed to the pool, each named by the function of
:mod:`thermonet.reporting.plots` and its keyword arguments.  The figures are the same files
as drawn in the command (the same function on the same arguments, Agg).  A figure a helper
fails to deliver (an error, a helper that died) is drawn in the command itself, where a
genuine plotting error is raised as before.

The first helper can also be given a *first call* (``first=``), run as it starts, before it
imports matplotlib: ``compare`` has it read the data while the command imports torch
(:meth:`PlotWorkers.first_result`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..core.helpers import Call, Helpers, value_or_none

__all__ = ["PlotWorkers", "PlotJob", "draw_here"]

#: One figure: the name of a function of :mod:`thermonet.reporting.plots` and its keyword
#: arguments (its first, the PNG path, among them as ``path``).
PlotJob = tuple[str, dict[str, Any]]
_PLOTS = "thermonet.reporting.plots"


def draw_here(jobs: Sequence[PlotJob]) -> list[Path]:
    """Every figure drawn in this process, in order."""
    if not jobs:
        return []
    from . import plots  # lazy: loads matplotlib

    return [Path(getattr(plots, name)(**kwargs)) for name, kwargs in jobs]


class PlotWorkers:
    """``n`` helpers that import the plotting code now and draw figures later.

    ``n`` below 2 starts none: :meth:`draw` then draws in this process.  Use as a context
    manager; leaving it on an error or an interrupt kills the helpers at once (before the
    caller removes the directory they write into)."""

    def __init__(self, n: int, first: Call | None = None) -> None:
        """``first``: a call for the first helper to run as it starts (:meth:`first_result`);
        the others then start at :meth:`start_rest` — once the caller's own imports are done
        (compare: torch; three processes importing at once on two cores slowed its import by
        a fifth, 3.24 → 2.99 s a comparison) — or, at the latest, at :meth:`draw`."""
        self._helpers: Helpers | None = None
        self._first = None
        if n < 2 or os.name != "posix":      # the workers' signal mask: POSIX only
            return
        try:
            self._helpers = Helpers(n, [_PLOTS], first=first)
        except OSError:          # no process to be had (a limit, a sandbox): this process
            return               # draws (and reads, without the first)
        self._first = self._helpers.first

    def start_rest(self) -> None:
        """Start the helpers not started yet (none where they are all running)."""
        if self._helpers is not None:
            self._helpers.start()

    @property
    def has_first(self) -> bool:
        """Whether a helper was given the first call (its result not yet taken)."""
        return self._first is not None

    def first_result(self, valid: Callable[[Any], bool] = lambda _: True) -> Any:
        """The first call's value, waited for (:func:`~thermonet.core.helpers.value_or_none`):
        None without one, or where it did not come back as ``valid`` asks (the caller then
        does the work itself)."""
        f, self._first = self._first, None
        return value_or_none(f, valid)

    def draw(self, jobs: Sequence[PlotJob]) -> list[Path]:
        """Every figure, handed to the helpers (in this process without them); the files'
        paths in the order of ``jobs``."""
        self.start_rest()
        helpers, self._helpers = self._helpers, None
        out: list[Path | None] = [None] * len(jobs)
        if helpers is not None and len(jobs) > 1:
            try:
                futures = [helpers.submit(_PLOTS, name, **kwargs) for name, kwargs in jobs]
                for i, f in enumerate(futures):
                    value = value_or_none(f)
                    out[i] = None if value is None else Path(value)
            finally:
                helpers.kill()             # none has a figure in hand any more
        elif helpers is not None:
            helpers.kill()
        missing = [i for i, p in enumerate(out) if p is None]
        for i, path in zip(missing, draw_here([jobs[i] for i in missing]), strict=True):
            out[i] = path
        return [p for p in out if p is not None]

    def close(self) -> None:
        helpers, self._helpers = self._helpers, None
        if helpers is not None:
            helpers.kill()

    def __enter__(self) -> PlotWorkers:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
