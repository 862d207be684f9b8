"""``thermonet.compare``: the command line's comparison from Python, with typed results.

:func:`compare` runs :func:`thermonet.workflows.compare.compare_result` — the comparison
``thermonet compare`` runs, nothing re-implemented — and returns a :class:`ComparisonResult`
around its typed result (:class:`thermonet.reporting.results.ComparisonResult`, not read back
from ``results.json``): ``.chosen``, ``.families[name]`` (scores, verdicts,
per-axis metrics), ``.warnings``, ``.estimator(name)`` (a fitted
:class:`~thermonet.api.DriftEstimator` loaded from the family's checkpoint) and ``.table()``
(the command line's table).  Files are written only where ``out`` names a directory;
without it the comparison runs in a temporary directory that is removed before
:func:`compare` returns (the checkpoints are loaded first, no plots are drawn).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Mapping
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core.errors import ConfigError, ThermonetError
from ..core.outdir import check_target
from ..core.recording import Dataset
from ..reporting.results import AxisResult, FamilyResult
from ..reporting.results import ComparisonResult as TypedResult
from .checks import flag, text, whole
from .checks import path as a_path
from .data import runs_of
from .estimator import DriftEstimator

if TYPE_CHECKING:
    import pandas as pd

    from .estimator import DriftEstimator

__all__ = ["compare", "ComparisonResult", "SensorComparisonResult", "FamilySummary",
           "AxisSummary"]


#: One family on one axis of the held-out test data: the comparison's own typed record
#: (``score_ratio``, ``interval``, ``verdict``, ``compensate``, ``vs_baseline``, ``metrics``).
AxisSummary = AxisResult
#: One configured family of a comparison: the comparison's own typed record (``name``,
#: ``family``, ``inputs``, ``params``, ``status``, ``reason``, ``val_score``, ``test_score``,
#: ``n_params``, ``fit_seconds``, ``axes``; ``ok``).
FamilySummary = FamilyResult


class SensorComparisonResult:
    """What :func:`compare` returns for ``model: sensor`` (:mod:`thermonet.workflows.sensor`).

    ``results`` is the ``results.json`` document; ``model(name)`` the fitted
    :class:`~thermonet.models.sensor.SensorModel` (``compensate(signals, raw)``);
    :meth:`residuals` one row per family and axis.
    """

    def __init__(self, results: dict[str, Any], models: dict[str, Any], out: Path | None
                 ) -> None:
        self.results, self.out, self._models = results, out, models
        self.chosen: str | None = results.get("chosen")
        self.units: dict[str, str] = dict(results.get("units") or {})

    def __repr__(self) -> str:
        return f"SensorComparisonResult(chosen={self.chosen!r}, families={list(self._models)})"

    def model(self, name: str) -> Any:
        if name not in self._models:
            raise ThermonetError(f"model: no fitted family named {name!r} (fitted: "
                                 f"{', '.join(self._models) or 'none'})")
        return self._models[name]

    def residuals(self) -> pd.DataFrame:
        """Held-out residual RMS (raw, bias-only, sensor), ratios, verdicts, SF tempco."""
        import pandas as pd

        rows = [{"family": name, "axis": a, **{k: v for k, v in m.items()
                                                  if not isinstance(v, list)}}
                for name, f in self.results["families"].items() if f.get("status") == "ok"
                for a, m in f["axes"].items()]
        return pd.DataFrame(rows).set_index(["family", "axis"])


class ComparisonResult:
    """What :func:`compare` returns: the comparison's typed result (``record``), its fitted
    estimators and where its files are; ``results`` is its ``results.json`` document.

    Attributes
    ----------
    chosen : str or None
        The family that ships (None: none beats raw; see ``chosen_reason``).
    chosen_reason : str
    baseline : str or None
    families : dict of str to FamilyResult
    record : thermonet.reporting.results.ComparisonResult
        The whole comparison, typed (what ``results`` is the document of; a document given
        in its place is read once).
    warnings : list of str
    units : dict of str to str
    out : Path or None
        Where the files are (None: nothing was kept).
    results : dict
    """

    def __init__(self, results: TypedResult | Mapping[str, Any],
                 estimators: dict[str, DriftEstimator], out: Path | None) -> None:
        self.out = out
        self._estimators = estimators
        try:
            #: the comparison's typed record (thermonet.reporting.results): compare's own
            self.record = results if isinstance(results, TypedResult) else \
                TypedResult.from_json(results)
        except ValueError as err:
            raise ThermonetError(str(err)) from None
        self.chosen: str | None = self.record.chosen
        self.chosen_reason: str = self.record.chosen_reason
        self.baseline: str | None = self.record.baseline
        self.warnings: list[str] = list(self.record.warnings)
        self.units: dict[str, str] = dict(self.record.units)
        self.families: dict[str, FamilyResult] = dict(self.record.families)

    @cached_property
    def results(self) -> dict[str, Any]:
        """The ``results.json`` document (``record.to_json()``: what compare wrote)."""
        return self.record.to_json()

    def __repr__(self) -> str:
        return (f"ComparisonResult(chosen={self.chosen!r}, families={list(self.families)}, "
                f"warnings={len(self.warnings)})")

    def estimator(self, name: str) -> DriftEstimator:
        """The fitted estimator of family ``name`` (the model ``compare`` saved for it)."""
        if name not in self.families:
            raise ThermonetError(f"estimator: no family named {name!r} (families: "
                                 f"{', '.join(self.families)})")
        if name not in self._estimators:
            f = self.families[name]
            raise ThermonetError(f"estimator: family {name!r} was not fitted "
                                 f"({f.reason or f.status})")
        return self._estimators[name]

    def scores(self) -> pd.DataFrame:
        """One row per family and axis: ``family, axis, score_ratio, low, high, verdict,
        compensate`` (held-out test data; ratio < 1 is better than raw)."""
        import pandas as pd

        rows = [{"family": name, "axis": axis, "score_ratio": a.score_ratio,
                 "low": a.interval[0], "high": a.interval[1], "verdict": a.verdict,
                 "compensate": a.compensate}
                for name, f in self.families.items() for axis, a in f.axes.items()]
        return pd.DataFrame(rows, columns=["family", "axis", "score_ratio", "low", "high",
                                           "verdict", "compensate"])

    def table(self) -> str:
        """The comparison as the command line prints it."""
        from ..workflows.compare import format_table  # lazy: importing it loads yaml

        return format_table(self.record)


def _config(config: Any) -> Any:
    from ..training.config import (  # lazy: importing it loads yaml
        CompareConfig,
        config_from_mapping,
        load_config,
    )

    if isinstance(config, str) and not config.strip():
        raise ConfigError("compare(config): an empty path (None is the built-in default)")
    if config is None or isinstance(config, (str, os.PathLike)):
        return load_config(None if config is None else Path(config))
    if isinstance(config, CompareConfig):
        return config
    if isinstance(config, dict):
        return config_from_mapping(config, source="compare(config)")
    raise ConfigError(f"compare(config): expected a config file's path, a dict of config "
                      f"sections or a CompareConfig, got {type(config).__name__}")


def compare(config: Any = None, data: Any = None, out: str | os.PathLike[str] | None = None,
            track: bool = False, *, tracking_uri: str | None = None, overwrite: bool = False,
            plots: bool = True, workers: int | None = None,
            quiet: bool = True) -> ComparisonResult | SensorComparisonResult:
    """Compare model families as ``thermonet compare`` does; return the typed results
    (a :class:`SensorComparisonResult` for ``model: sensor``).

    Parameters
    ----------
    config : path, dict or CompareConfig, optional
        A config file, the same sections as a dict (``{"families": [...], "split": ...}``,
        checked as a file is), or a loaded config; None is the built-in default.
    data : Dataset, Recording or list of Recordings, optional
        The data, in place of the config's ``data`` section (validated as read data is).
    out : path, optional
        Directory for ``results.json``, the report, plots and checkpoints; None writes
        nothing that outlives the call.
    track : bool
        ``True`` or ``False`` only (``"no"`` is refused, not read as true): log to MLflow
        as the command line does, in ``tracking_uri``, else the config's
        ``tracking.uri``, else ``sqlite:///mlflow.db`` in the working directory.
    tracking_uri : str, optional
        The MLflow store; giving it does not turn tracking on (``track`` does).
    overwrite, plots, quiet : bool
        As ``thermonet compare``'s ``--overwrite``, ``--no-plots`` and ``--quiet`` (quiet
        by default here; ``plots`` only where ``out`` is given).
    workers : int, optional
        Families fitted side by side, as ``--workers``: a whole number >= 1, ``0`` for one
        per CPU, None for the config's ``workers``.

    Every argument is checked before the config's data are read or anything is fitted
    (:mod:`thermonet.api.checks`; an error names the argument), and so are the config's
    families, inputs and hyper-parameter names and values.
    """
    from ..training.config import check_families  # lazy: importing it loads yaml
    from ..workflows.compare import compare_result  # lazy: importing it loads yaml

    a_path(out, "compare(out)", none=True)
    flag(track, "compare(track)")
    text(tracking_uri, "compare(tracking_uri)", none=True, rule="an MLflow tracking URI")
    for value, name in ((overwrite, "overwrite"), (plots, "plots"), (quiet, "quiet")):
        flag(value, f"compare({name})")
    whole(workers, "compare(workers)", 0, none=True, note=" (0: one per CPU)")
    cfg = _config(config)
    check_families(cfg, source=getattr(cfg, "_source", "compare(config)"), build=False)
    dataset = None
    if data is not None:
        dataset = Dataset(runs_of(data, "compare(data)")).validate("compare(data)")
    tmp = None
    if out is None:
        tmp = Path(tempfile.mkdtemp(prefix="thermonet-compare-"))
        target = tmp / "out"
    else:
        target = Path(out)
        # refused in the API's words (compare(out), overwrite=True), not the command line's
        check_target(target, bool(overwrite), names=("compare(out)", "overwrite=True"))
    try:
        results = compare_result(cfg, target, overwrite=bool(overwrite), track=bool(track),
                                 tracking_uri=tracking_uri, quiet=bool(quiet),
                                 dataset=dataset, plots=bool(plots) and out is not None,
                                 workers=None if workers is None else int(workers))
        # the model kind's result (by the config's ``model``): a bias comparison's is typed
        return _RESULTS[cfg.model](results, target, None if out is None else target)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def _sensor_result(results: dict[str, Any], target: Path, out: Path | None
                   ) -> SensorComparisonResult:
    """A whole-sensor comparison: its fitted sensor models, loaded from ``target`` (before a
    temporary ``target`` is removed)."""
    from ..training.sensor_checkpoint import load_sensor  # torch boundary

    models = {name: load_sensor(target / "models" / f"{name}.pt")[0]
              for name, f in results["families"].items() if f.get("status") == "ok"}
    return SensorComparisonResult(results, models, out)


def _bias_result(results: TypedResult, target: Path, out: Path | None) -> ComparisonResult:
    """A bias comparison: a :class:`DriftEstimator` per fitted family, loaded from its
    checkpoint in ``target`` (before a temporary ``target`` is removed)."""
    estimators = {}
    for name, f in results.families.items():
        ckpt = f.checkpoint
        if f.ok and ckpt:
            path = Path(ckpt)
            if not path.is_absolute() or not path.exists():
                path = target / "models" / f"{name}.pt"
            estimators[name] = DriftEstimator.load(path)
    return ComparisonResult(results, estimators, out)


#: What ``compare`` returns per model kind, by the config's ``model`` (a bias comparison's
#: typed result; the whole-sensor model's ``results.json`` document).
_RESULTS: dict[str, Any] = {"bias": _bias_result, "sensor": _sensor_result}
