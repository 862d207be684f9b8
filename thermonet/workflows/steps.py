"""The one pipeline's steps, for every model kind: plan → fit → judge → write → track.

A model kind's comparison is a class with the five steps (:class:`Steps`), registered by the
config's ``model:`` value in :data:`thermonet.workflows.compare.PIPELINES` (``bias``:
compare's own, :mod:`thermonet.workflows.compare`; ``sensor``: the whole-sensor model,
:class:`thermonet.workflows.sensor.SensorSteps`).  :func:`thermonet.workflows.compare.compare_result`
looks the class up, and runs the one driver (:func:`run_steps`) in the same staging
directory, thread limits and figure helpers for every kind; what differs between the kinds
is each class's steps and its data (:attr:`Steps.helpers`: whether the figures are drawn by
helper processes, which also read the data while torch is imported).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, Union

if TYPE_CHECKING:
    from ..core.recording import Dataset
    from ..reporting.plot_workers import PlotWorkers
    from ..reporting.results import ComparisonResult
    from ..training.config import CompareConfig

__all__ = ["RunOptions", "Steps", "run_steps", "Outcome"]

#: What a model kind's comparison returns: the typed result (a bias comparison,
#: :class:`thermonet.reporting.results.ComparisonResult`), or the ``results.json`` document
#: of a kind that has none (the whole-sensor model's).
Outcome = Union["ComparisonResult", dict[str, Any]]


@dataclass(frozen=True)
class RunOptions:
    """What a caller of ``compare_result`` chose, handed to every kind's steps."""

    track: bool | None = None
    tracking_uri: str | None = None
    quiet: bool = False
    progress: Any = None              # thermonet.workflows.compare_fit.Progress, or None
    dataset: Dataset | None = None
    plots: bool = True
    workers: int | None = None
    #: the command that asked (``compare``, ``train``): the banner's first word after
    #: ``thermonet``
    command: str = "compare"


class Steps(Protocol):
    """One model kind's comparison: constructed on the config, the (staging) output
    directory, the figure helpers and the options; then its five steps in order, each
    keeping what the next needs; :meth:`track` returns its :data:`Outcome`."""

    #: Whether figures are drawn by helper processes (and the first reads the data).
    helpers: bool

    def __init__(self, cfg: CompareConfig, out: Path, *, drawers: PlotWorkers,
                 options: RunOptions) -> None: ...

    @staticmethod
    def check(cfg: CompareConfig) -> None:
        """The config checked before any process starts (torch-free)."""

    def plan(self) -> None: ...

    def fit(self) -> None: ...

    def judge(self) -> None: ...

    def write(self) -> None: ...

    def track(self) -> Outcome: ...

    def abort(self, err: BaseException) -> None:
        """Undo what was started (an open MLflow run) when a step raised ``err``."""


def run_steps(steps: Steps) -> Outcome:
    """plan → fit → judge → write → track; returns the kind's :data:`Outcome`.  A step
    that raises aborts what the steps started (:meth:`Steps.abort`) and the error goes on."""
    try:
        steps.plan()
        steps.fit()
        steps.judge()
        steps.write()
        return steps.track()
    except BaseException as err:
        steps.abort(err)
        raise
