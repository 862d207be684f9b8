"""A comparison's figures drawn side by side by helper processes started before the fits.

Drawing is a comparison's largest single stage once the fits are cheap (13 PNG files on
three axes: ~1.6 s, a third of the command), and it runs on one core while the fits before
it leave the other idle (they hold Python's lock).  :class:`PlotWorkers` starts its helpers
(:class:`thermonet.core.helpers.Helper`) when the comparison starts: each imports
matplotlib and the plotting module while the data load and the families fit, and then draws
figures one at a time as they are handed out, each named by the function of
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
import select
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..core.helpers import Helper, HelperGone, value_or_none

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

    def __init__(self, n: int, first: tuple[str, str, dict[str, Any]] | None = None) -> None:
        """``first``: a call for the first helper to run as it starts (:meth:`first_result`);
        the others then start at :meth:`start_rest` — once the caller's own imports are done
        (compare: torch; three processes importing at once on two cores slowed its import by
        a fifth, 3.24 → 2.99 s a comparison) — or, at the latest, at :meth:`draw`."""
        self._helpers: list[Helper] = []
        self._first: Helper | None = None
        self._rest = 0
        # helpers wait on their pipes with select(), which takes pipes on POSIX only
        if n < 2 or os.name != "posix":
            return
        try:
            try:
                self._helpers.append(Helper([_PLOTS], first=first))
                self._first = self._helpers[0] if first is not None else None
            except (ValueError, HelperGone):   # a first call it cannot take: the caller does it
                self._helpers.append(Helper([_PLOTS]))
        except OSError:          # no process to be had (a limit, a sandbox): this process
            return               # draws (and reads, without the first)
        self._rest = n - 1
        if first is None:
            self.start_rest()

    def start_rest(self) -> None:
        """Start the helpers not started yet (none where they are all running)."""
        n, self._rest = self._rest, 0
        try:
            for _ in range(n):
                self._helpers.append(Helper([_PLOTS]))
        except OSError:          # no process to be had: those started draw, this one the rest
            pass

    @property
    def has_first(self) -> bool:
        """Whether a helper was given the first call (its result not yet taken)."""
        return self._first is not None

    def first_result(self, valid: Callable[[Any], bool] = lambda _: True) -> Any:
        """The first call's value, waited for (:func:`~thermonet.core.helpers.value_or_none`):
        None without one, or where it did not come back as ``valid`` asks (the caller then
        does the work itself)."""
        h, self._first = self._first, None
        return value_or_none(h, valid)

    def draw(self, jobs: Sequence[PlotJob]) -> list[Path]:
        """Every figure, handed out to the helpers as they come free (in this process
        without them); the files' paths in the order of ``jobs``."""
        self.start_rest()
        helpers, self._helpers = self._helpers, []
        out: list[Path | None] = [None] * len(jobs)
        try:
            self._hand_out(helpers, jobs, out)
        finally:
            for h in helpers:          # none has a figure in hand any more
                h.kill()
        missing = [i for i, p in enumerate(out) if p is None]
        for i, path in zip(missing, draw_here([jobs[i] for i in missing]), strict=True):
            out[i] = path
        return [p for p in out if p is not None]

    @staticmethod
    def _hand_out(helpers: list[Helper], jobs: Sequence[PlotJob],
                  out: list[Path | None]) -> None:
        todo = list(range(len(jobs))) if len(jobs) > 1 else []
        active: dict[int, int] = {}                 # helper index -> job index
        alive = list(range(len(helpers)))
        while (todo or active) and alive:
            moved = False
            for k in list(alive):
                h = helpers[k]
                try:
                    if k in active and h.done():
                        ok, value = h.result()
                        i = active.pop(k)
                        out[i] = Path(value) if ok else None
                        moved = True
                    if k not in active and todo and h.ready():
                        i = todo.pop(0)
                        h.submit(_PLOTS, jobs[i][0], **jobs[i][1])
                        active[k] = i
                        moved = True
                except HelperGone:                   # its figure is drawn here afterwards
                    alive.remove(k)
                    active.pop(k, None)
            if not moved and alive:
                streams = [s for s in (helpers[k].stream() for k in alive) if s is not None]
                if streams:
                    select.select(streams, [], [], 0.2)

    def close(self) -> None:
        self._rest = 0
        helpers, self._helpers = self._helpers, []
        for h in helpers:
            h.kill()

    def __enter__(self) -> PlotWorkers:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
