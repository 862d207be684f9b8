"""The sections of a comparison config (:class:`~thermonet.training.config.CompareConfig`)
besides its families, split and training settings, each a dataclass holding the defaults and
refusing a bad value in one line naming the dotted key: where the recordings come from
(:class:`DataConfig`), how the model that ships is chosen (:class:`SelectionConfig`) and its
residual-drift band (:class:`BandConfig`), the fleet prior and station
(:class:`StationConfig`), the shared feature layer (:class:`FeatureConfig`) and MLflow tracking
(:class:`TrackingConfig`, with MLflow's registered-model name rules:
:func:`register_name_problem`).  Torch-free.
"""

from __future__ import annotations

import math
import posixpath
import unicodedata
from dataclasses import dataclass, field
from typing import Any, Literal

from ..core.errors import ConfigError
from ..core.schema import from_dict
from ..data.diagnostics import TEMPERATURE_PLAUSIBLE_C
from ..scoring.band import check_level
from ..scoring.prior import StationLimit

__all__ = ["DataConfig", "SelectionConfig", "BandConfig", "StationConfig", "FeatureConfig",
           "TrackingConfig", "register_name_problem", "MAX_REGISTER_NAME"]


@dataclass
class DataConfig:
    """Where the recordings come from: the simulator (default) or files."""

    preset: str | None = "patent-gyro"   # simulator preset; ignored when `paths` is set
    runs: int | None = None              # simulated runs (None: the preset's own number)
    seed: int = 0                        # simulator seed
    paths: list[str] = field(default_factory=list)  # recording files (one run per file)
    mapping: str | None = None           # YAML column mapping for non-native files
    outputs: list[str] = field(default_factory=list)  # axes to model (empty: all outputs)
    # recordings larger than memory (thermonet.features.windows): recording files (any tabular
    # format, through the mapping) of more samples than this are streamed and reduced to
    # window means (0: always); the decision: thermonet.training.loader
    in_memory_samples: int = 1_000_000
    chunk_rows: int = 65_536             # rows read at a time while streaming
    max_rows: int = 500_000              # most reduced rows (wider windows beyond)


@dataclass
class SelectionConfig:
    """How the model that ships is chosen (:mod:`thermonet.scoring.selection`).

    ``folds``: K of the purged, blocked cross-validation over the training data (one run:
    ``folds × blocks_per_fold`` short contiguous blocks dealt round-robin; several runs:
    leave one run out); 0 chooses on the split's single validation part instead (the rule
    before cross-validated selection).  ``purge_s`` and ``window_s``: ``None`` takes the documented rules.
    ``refit``: with cross-validation, every family is refitted on the split's whole pool
    (training and validation data) by the procedure the folds judged, and that model is
    the one the test verdicts judge and the exports ship; False keeps the fit on the
    training part with early stopping on the validation part.  ``per_axis``: each output
    axis gets its own candidate by the same rule (:func:`thermonet.scoring.selection.
    choose_per_axis`), shipped as one model; False chooses one family for every axis (the
    whole-recording choice); ``None`` (default) is per axis with two or more families.
    ``hold_out``: what a fold holds out of one run (or of a time-block split's runs) —
    ``excursions``: whole thermal excursions (a heating or cooling leg with its soak), the
    next warm-up a user's test will be; ``blocks``: short blocks dealt round-robin
    (interpolation); ``auto`` (default): excursions where two or more can be held out, else
    blocks.  With several runs and a split by run, one run is left out whatever it says.
    ``gate``: the baseline stays on an axis until a candidate beats it in every fold, and a
    model reading the direction of change (rate, lag, hysteresis) is not shipped over a static
    one where the training data hold one direction only
    (:data:`thermonet.scoring.gate.GATE_RULE`); False: the one-SE rule alone (the rule
    before, for comparison).
    """

    folds: int = 5
    blocks_per_fold: int = 8
    purge_s: float | None = None
    window_s: float | None = None
    refit: bool = True
    per_axis: bool | None = None
    hold_out: str = "auto"
    gate: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.gate, bool):
            raise ConfigError(f"key 'selection.gate': must be true or false, got {self.gate!r}")
        if self.hold_out not in ("auto", "excursions", "blocks"):
            raise ConfigError(f"key 'selection.hold_out': must be auto, excursions or blocks, "
                              f"got {self.hold_out!r}")
        if self.per_axis is not None and not isinstance(self.per_axis, bool):
            raise ConfigError(f"key 'selection.per_axis': must be true, false or null (per axis "
                              f"when there are two or more families), got {self.per_axis!r}")
        for key, lo, hi in (("folds", 0, 50), ("blocks_per_fold", 1, 100)):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(f"key 'selection.{key}': must be an integer from {lo} to "
                                  f"{hi}, got {v!r}")
        if self.folds == 1:
            raise ConfigError("key 'selection.folds': 1 fold validates on nothing; use 0 (the "
                              "split's validation part) or 2 and more")
        for key in ("purge_s", "window_s"):
            v = getattr(self, key)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int | float)
                                  or not math.isfinite(v) or v < 0):
                raise ConfigError(f"key 'selection.{key}': must be a number of seconds >= 0 "
                                  f"or null (the documented rule), got {v!r}")


@dataclass
class BandConfig:
    """The residual-drift band per axis (:mod:`thermonet.scoring.band`), from the shipped
    model's out-of-fold residuals.

    ``level``: nominal coverage strictly between 0 and 1; ``None`` (default) is 0.9 where the
    selection has cross-validation folds and no band otherwise — a level given asks for the
    band and is refused without folds.  ``bins``: temperature bins over the trained range
    before merging (each bin needs enough windows for its conformal quantile).
    """

    level: float | None = None
    bins: int = 4

    def __post_init__(self) -> None:
        if self.level is not None:
            check_level(self.level)
        if isinstance(self.bins, bool) or not isinstance(self.bins, int) or \
                not 1 <= self.bins <= 50:
            raise ConfigError(f"key 'band.bins': must be an integer from 1 to 50, got "
                              f"{self.bins!r}")


@dataclass
class StationConfig:
    """The fleet prior and the production station (:mod:`thermonet.workflows.station`).

    ``degree``: the prior's polynomial degree in temperature (3: the autopilots' cubic);
    ``limits``: axis or ``"*"`` → :class:`thermonet.scoring.prior.StationLimit` keys;
    ``flag_unlike_fleet``: a unit unlike every cluster of the prior fails.
    """

    degree: int = 3
    limits: dict[str, Any] = field(default_factory=dict)
    flag_unlike_fleet: bool = True

    def __post_init__(self) -> None:
        if isinstance(self.degree, bool) or not isinstance(self.degree, int) or \
                not 1 <= self.degree <= 5:
            raise ConfigError(f"key 'station.degree': must be an integer from 1 to 5, got "
                              f"{self.degree!r}")
        if not isinstance(self.limits, dict):
            raise ConfigError("key 'station.limits': expected a mapping axis -> limits, got "
                              f"{self.limits!r}")
        for axis, spec in self.limits.items():
            from_dict(StationLimit, spec, source="config", prefix=f"station.limits.{axis}")


@dataclass
class FeatureConfig:
    """The one feature layer shared by every family."""

    t_ref: float | Literal["start"] = (
        "start"  # °C, or mean of the first minutes of the first training run
    )
    t_ref_window_min: float = 10.0             # minutes averaged for t_ref "start"
    # dynamic inputs (rate, lag_<tau>, play_<w>): a time step over gap_s seconds restarts their
    # state; "auto": 5 × the median sample interval of the first training run (thermonet.features.dynamics)
    gap_s: float | Literal["auto"] = "auto"
    rate_window_s: float | None = None         # removed (the Savitzky–Golay rate): an error if set

    def __post_init__(self) -> None:
        if self.rate_window_s is not None:
            raise ConfigError("key 'features.rate_window_s' was removed: 'rate' is now a causal "
                              "filtered derivative with a 60 s time constant stored in the model "
                              "(thermonet.features.dynamics); name the input 'rate_<tau>' (e.g. rate_30) "
                              "for another time constant")
        if not isinstance(self.gap_s, str) and not 1e-6 <= self.gap_s <= 1e7:
            raise ConfigError(f"key 'features.gap_s': {self.gap_s!r} is not a number of seconds "
                              "in 1e-06 … 1e+07 (a µs … 116 days) or 'auto'")
        if not isinstance(self.t_ref, str):
            lo, hi = TEMPERATURE_PLAUSIBLE_C
            if not lo <= self.t_ref <= hi:  # NaN fails too
                raise ConfigError(f"key 'features.t_ref': {self.t_ref!r} °C is not a reference "
                                  f"temperature in {lo:g} … {hi:g} °C (or 'start')")
        if not 0 < self.t_ref_window_min <= 1440:
            raise ConfigError(f"key 'features.t_ref_window_min': {self.t_ref_window_min!r} is "
                              "not a number of minutes in (0, 1440]")


#: The longest registered-model name: MLflow's SQL stores hold it in a ``String(256)`` column
#: (``mlflow.store.model_registry.dbmodels.models.SqlRegisteredModel.name``).
MAX_REGISTER_NAME = 256


def register_name_problem(name: str) -> str | None:
    """Why ``name`` cannot be a registered-model name (None: it can).

    MLflow's own rules are the reference (``mlflow.utils.validation._validate_model_name``
    and the file store's ``_validate_model_name``, MLflow 3.x): not empty or blank, no ``/``
    or ``:``, no path separator (``\\``) or ``%``, nothing that resolves as a path to
    another name (``posixpath.normpath(name) != name``, ``.``, a name starting with ``..``),
    at most 256 characters (the SQL stores' column).  thermonet adds one of its own: no
    control character (a newline, a tab, DEL, C1, a Unicode line separator), which MLflow
    registers as it is, to break every listing and log line that shows the name.
    """
    if not name.strip():
        return "is empty (give the name to register the chosen model under, or leave it out)"
    bad = next((c for c in name if unicodedata.category(c) in ("Cc", "Zl", "Zp")), None)
    if bad is not None:
        return (f"holds the control character {bad!r} (a model name is one line of printable "
                "text)")
    bad = next((c for c in name if c in "/:\\%"), None)
    if bad is not None:
        return (f"holds {bad!r}; MLflow's model names cannot hold '/', ':', '\\' or '%' "
                "(they name paths and URIs: models:/NAME@alias)")
    norm = posixpath.normpath(name)
    if norm != name or norm == "." or norm.startswith(".."):
        return ("would resolve to another name as a path (MLflow refuses '.', '..' and names "
                "starting with '..')")
    if len(name) > MAX_REGISTER_NAME:
        return f"has {len(name)} characters (MLflow's stores hold at most {MAX_REGISTER_NAME})"
    return None


@dataclass
class TrackingConfig:
    """MLflow tracking (embedded SQLite store in the working directory by default).

    ``register`` names the registered model the chosen model is added to (a bias
    comparison's; MLflow's name rules, :func:`register_name_problem`), checked when the
    config is loaded.  It needs tracking: with ``enabled: false`` in the same config it is
    refused at load; with tracking turned off for one run (``--no-track``,
    ``thermonet.compare(track=False)``) it is ignored, and the comparison says so in one
    warning line (and in results.json's ``warnings``).
    """

    enabled: bool = True
    uri: str | None = None               # None: sqlite:///mlflow.db in the working directory
    experiment: str = "thermonet"
    register: str | None = None          # register the chosen model under this name

    def __post_init__(self) -> None:
        if self.register is None:
            return
        if not isinstance(self.register, str):
            raise ConfigError(f"key 'tracking.register': expected a model name, got "
                              f"{self.register!r}")
        why = register_name_problem(self.register)
        if why is not None:
            raise ConfigError(f"key 'tracking.register': {self.register[:60]!r} {why}")
        if self.enabled is False:
            raise ConfigError(f"key 'tracking.register': {self.register!r} needs tracking, and "
                              "tracking.enabled is false (nothing would be registered); remove "
                              "one of them")
