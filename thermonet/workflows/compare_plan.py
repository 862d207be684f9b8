"""``thermonet compare``, step 1 — the plan: the config checked against the data before anything
is fitted or written (a ``baseline`` that names no family is an error; inputs the data cannot
supply are errors), the splits made, the folds of cross-validated selection laid out, and
warnings about implausible inputs collected (:mod:`thermonet.data.diagnostics`).  The parts
each family is fitted on are built once and shared (:class:`PartCache`).
"""

from __future__ import annotations

import dataclasses
import functools
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, InputError
from ..core.recording import MIN_TEMPERATURE_SPAN_C, Dataset
from ..data.diagnostics import input_warnings
from ..features.dynamics import RATE_TAU_S, dynamic_signals, input_set_warnings
from ..features.inputs import dynamic_signal, signals_for
from ..features.target import Target, output_units
from ..scoring.fold_plan import plan_folds, validation_stretches, window_rule
from ..training.config import (
    CompareConfig,
    check_families,
    outputs_of,
)
from ..training.loader import load_compare_data, streamed_data
from ..training.parts import (
    Part,
    Split,
    build_part,
    make_splits,
    targets_for,
)

#: A streamed run reduced to fewer window-mean rows than this is warned about: the folds and
#: the bootstrap blocks are made of rows.
MIN_STREAMED_ROWS = 1000

__all__ = ["PartCache", "Plan", "check_plan", "plan", "data_summary", "load_compare_data",
           "streamed_data"]


class PartCache:
    """Signals and targets of each (run, signals) pair, built once for all families."""

    def __init__(self, cfg: CompareConfig, outputs: list[str], targets: Any = None) -> None:
        self.cfg, self.outputs = cfg, outputs
        # thermonet.features.target.Target, or the config's plain kind ("drift" / "four-position")
        self.targets: Any = targets if targets is not None else cfg.target
        self._cache: dict[tuple[int, tuple[str, ...], float | None], Part] = {}
        # a run's target and simulated drift do not depend on the signals: one (read-only)
        # copy per run, shared by the parts of every signal set (memory: 48 B a sample of a
        # 3-axis run for each further signal set the families read)
        self._shared: dict[int, tuple[np.ndarray, np.ndarray | None]] = {}
        # families fitted side by side ask for the same parts: each is built once
        self._lock = threading.Lock()

    def __call__(self, rec: Any, signals: list[str], gap_s: float | None = None) -> Part:
        key = (id(rec), tuple(signals), gap_s)
        with self._lock:
            if key not in self._cache:
                part = build_part(rec, signals=signals, outputs=self.outputs,
                                  target=self.targets, gap_s=gap_s)
                if not part.per_soak:
                    part = self._share(id(rec), part)
                self._cache[key] = part
            return self._cache[key]

    def _share(self, rec_id: int, part: Part) -> Part:
        shared = self._shared.get(rec_id)
        if shared is None:
            for a in (part.target, part.true_drift):
                if a is not None:
                    a.setflags(write=False)   # shared from now on: nothing may write into it
            self._shared[rec_id] = (part.target, part.true_drift)
            return part
        same = np.array_equal(shared[0], part.target, equal_nan=True) and (
            (shared[1] is None and part.true_drift is None) or (
                shared[1] is not None and part.true_drift is not None
                and np.array_equal(shared[1], part.true_drift, equal_nan=True)))
        return dataclasses.replace(part, target=shared[0], true_drift=shared[1]) if same \
            else part


# ------------------------------------------------------------------------------------ plan
@dataclass
class Plan:
    """Everything decided before fitting."""

    cfg: CompareConfig
    ds: Dataset
    outputs: list[str]
    targets: Target
    splits: list[Split]
    units: dict[str, str]
    source: str
    warnings: list[str] = field(default_factory=list)
    folds: Any = None                # thermonet.scoring.fold_plan.FoldPlan of the last split's pool
    fold_note: str = ""              # why there is none (the single validation part decides)


def _baseline_named(cfg: CompareConfig) -> bool:
    """Whether the config file names ``baseline`` itself (rather than taking the default)."""
    import yaml

    src = getattr(cfg, "_source", None)
    if not src or not Path(src).is_file():
        return cfg.baseline != _DEFAULT_BASELINE
    try:
        data = yaml.safe_load(Path(src).read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError):  # load_config read it already; be conservative
        return True
    return isinstance(data, dict) and "baseline" in data


_DEFAULT_BASELINE = CompareConfig.__dataclass_fields__["baseline"].default


def _check_baseline(cfg: CompareConfig, source: str) -> None:
    """A ``baseline`` the config names must be one of its families (an error before fitting);
    the default (``cubic``, PX4/ArduPilot's anchor) applies only where such a family exists."""
    labels = [f.label for f in cfg.families]
    if cfg.baseline is not None and cfg.baseline not in labels and not _baseline_named(cfg):
        cfg.baseline = None
        return
    if cfg.baseline is not None and cfg.baseline not in labels:
        raise ConfigError(f"{source}: key 'baseline': no family named '{cfg.baseline}' "
                          f"(families: {', '.join(labels)}); name one of them or set "
                          "'baseline: null'")


def _check_training_spans(splits: list[Split], source: str) -> None:
    """Each split's *training* data must span what the whole dataset must (the API checks its
    training runs the same way): a wide dataset whose training part is one soak cannot carry
    a thermal model, whatever the test part spans."""
    for split in splits:
        temps = [r.temperature_c for r in split.train if r.temperature_c is not None]
        if not temps or len(temps) != len(split.train) or any(r.proxies for r in split.train):
            continue            # no thermometer, or a proxy carries the model: as validate()
        span = max(float(np.nanmax(t)) for t in temps) - min(float(np.nanmin(t)) for t in temps)
        if span < MIN_TEMPERATURE_SPAN_C:
            runs = ", ".join(sorted({r.run_id for r in split.train}))
            raise InputError.at(source, f"split '{split.label}': the training data (runs "
                                f"{runs}) span only {span:.3g} °C (need at least "
                                f"{MIN_TEMPERATURE_SPAN_C:g} °C to fit a thermal model; "
                                "choose a split that trains on more of the temperature range)",
                                column="temperature_c")


def check_plan(cfg: CompareConfig, *, build: bool = True) -> None:
    """What :func:`plan` checks of ``cfg`` before it reads any data (its families and
    baseline): a config error said before anything slow starts.  ``build=False`` leaves
    out building the families (the check that imports torch: a plug-in's values), which
    :func:`plan` does."""
    source = getattr(cfg, "_source", "config")
    check_families(cfg, source=source, build=build)
    _check_baseline(cfg, source)


def plan(cfg: CompareConfig, dataset: Dataset | None = None, *,
         loaded: Dataset | None = None) -> Plan:
    """Check ``cfg`` against the data, make the splits, collect input warnings (no fitting).

    ``dataset``: the caller's data (the API, a fleet unit, a calibrate instance), recorded
    as given; ``loaded``: the config's own data as :func:`load_compare_data` read it
    elsewhere (a helper process, while this one imported torch), treated as read here;
    neither: read here."""
    source = getattr(cfg, "_source", "config")
    check_plan(cfg)
    ds = dataset if dataset is not None else \
        loaded if loaded is not None else load_compare_data(cfg, source)
    signals: set[str] = set()
    for i, fam in enumerate(cfg.families):
        for sig in signals_for(fam.inputs):
            signals.add(sig)
            if sig == "temperature_c" or dynamic_signal(sig) is not None:
                if any(r.temperature_c is None for r in ds):
                    raise ConfigError(f"{source}: key 'families[{i}].inputs': {fam.inputs} need "
                                      "a thermometer in °C and the data has none (proxies: "
                                      f"{', '.join(sorted(ds[0].proxies)) or 'none'})")
            elif sig not in ds[0].proxies:
                raise ConfigError(f"{source}: key 'families[{i}].inputs': no proxy channel "
                                  f"'{sig}' in the data (proxies: "
                                  f"{', '.join(sorted(ds[0].proxies)) or 'none'})")
    outputs = outputs_of(cfg, ds)
    targets = targets_for(ds, cfg.target, outputs, source=source)
    splits = make_splits(ds, cfg.split, source=source)
    _check_training_spans(splits, source)
    units = output_units(outputs, ds[0].units)

    warns = input_warnings(ds, signals=signals, rate_window_s=RATE_TAU_S)
    warns += input_set_warnings(
        {fam.label: list(fam.inputs) for fam in cfg.families},
        {r.run_id: float(r.time_s[-1] - r.time_s[0]) for r in ds if r.time_s.size > 1})
    held = sum(r.n_samples for r in ds if r.windows is None)
    if dataset is None and cfg.data.paths and held > cfg.data.in_memory_samples:
        warns.append(f"{held} samples were read whole (over data.in_memory_samples, "
                     f"{cfg.data.in_memory_samples}): flight-controller logs are not "
                     "streamed, only tabular files (Parquet, CSV, TSV) are")
    few = [(r, r.windows) for r in ds
           if r.windows is not None and r.n_samples < MIN_STREAMED_ROWS]
    if few:
        r, win = few[0]
        warns.append(f"run '{r.run_id}' was streamed into only {r.n_samples} rows of "
                     f"{win.window_s:g} s window means ({win.source_samples} "
                     "samples): cross-validation and verdicts count rows, so a short "
                     "recording is better held whole (raise 'data.in_memory_samples')")
    folds, note = _fold_plan(cfg, splits, source)
    return Plan(cfg, ds, outputs, targets, splits, units, source, warns, folds, note)


def _thermal_signal(cfg: CompareConfig, rec: Any) -> np.ndarray | None:
    """The temperature trace whose excursions the folds hold out: the thermometer in °C, or
    else the first proxy a family reads (the cubesat's raw counts), or None."""
    if rec.temperature_c is not None:
        return np.asarray(rec.temperature_c, dtype=np.float64)
    for sig in signals_for([i for fam in cfg.families for i in fam.inputs]):
        if sig in rec.proxies:
            return np.asarray(rec.proxies[sig], dtype=np.float64)
    return None


def _fold_plan(cfg: CompareConfig, splits: list[Split], source: str = "config"
               ) -> tuple[Any, str]:
    """The cross-validation folds of the last split's pool (thermonet.scoring.selection), or why not."""
    sel = cfg.selection
    if sel.folds == 0:
        return None, "selection.folds is 0: chosen on the split's validation part"
    if cfg.target == "four-position":
        return None, ("the four-position target has one sample per soak: chosen on the "
                      "split's validation part")
    tau = max((d.memory_s for fam in cfg.families for d in dynamic_signals(fam.inputs)),
              default=0.0)
    # the folds look like the test: whole runs left out where the test is a run of its own,
    # blocks inside the runs where the test is blocks inside them (a time-block split)
    pool = splits[-1].pool
    plan_of = functools.partial(
        plan_folds, pool, folds=sel.folds, blocks_per_fold=sel.blocks_per_fold, tau_s=tau,
        window_s=sel.window_s, by_run=splits[-1].label != "time-blocks",
        hold_out=sel.hold_out, gate=sel.gate,
        temperatures=[_thermal_signal(cfg, r) for r, _ in pool])
    # a purge the user set (or a window, which the purge follows) that leaves too little
    # training data where the rule's would not is the config's doing: said by its key, not
    # as a fallback to the validation part
    key = "purge_s" if sel.purge_s else "window_s" if sel.window_s is not None else ""
    ruled = None
    try:
        plan = plan_of(purge_s=sel.purge_s)
        if plan is None and key:
            ruled = plan_of(**({"purge_s": None} if key == "purge_s" else
                               {"purge_s": sel.purge_s, "window_s": None}))
    except ValueError as err:     # hold_out: excursions, and the data hold none to hold out
        raise ConfigError(f"{source}: key 'selection.hold_out': excursions, but the training "
                          f"data hold {err}") from None
    if ruled is not None:
        _refuse_windows(sel, ruled, pool, source, purged=key)
    if plan is None:
        return None, (f"too little training data for {sel.folds} cross-validation folds: "
                      "chosen on the split's validation part")
    if sel.window_s is not None:
        _refuse_windows(sel, plan, pool, source)
    return plan, ""


def _refuse_windows(sel: Any, plan: Any, pool: list[Any], source: str,
                    purged: str = "") -> None:
    """One line naming ``selection.purge_s`` or ``selection.window_s`` where the value set
    leaves a fold too little training data (``purged``: that key; ``plan``: the folds by the
    rule in its place, which could be made) or too few score windows (two or more in every
    fold: a fold scores the spread of its window means), with what the data hold."""
    windows, longest = validation_stretches(plan, [r.time_s for r, _ in pool])
    rate = float(np.median([r.effective_rate_hz for r, _ in pool]))
    hold = (f"the longest validation stretch of each of the {plan.k} folds: "
            + ", ".join(f"{x:.6g}" for x in longest) + " s")
    if purged == "purge_s":
        raise ConfigError(
            f"{source}: key 'selection.purge_s': {sel.purge_s:g} s purged on each side of every "
            f"validation stretch leaves too little training data for {plan.k} "
            f"cross-validation folds ({hold}); use a shorter purge, or remove the key "
            "(the rule: max(3 τ, window_s))")
    if purged or min(windows) < 2:
        why = ("purged on each side of every validation stretch (the purge follows the "
               f"window) leave too little training data for {plan.k} cross-validation folds"
               if purged else "are longer than the validation data hold: a fold's score is "
               "the spread of two or more window means")
        raise ConfigError(
            f"{source}: key 'selection.window_s': {sel.window_s:g} s windows {why} ({hold}); "
            f"use at most {min(longest) / 2:.6g} s, or remove the key (the rule gives "
            f"{window_rule(rate, plan.block_s):g} s here)")


def data_summary(ds: Dataset) -> list[dict[str, Any]]:
    """Per run: samples, duration, rate and temperature range (of a reduced run: the samples
    it was streamed from, the rows and their window; its temperatures are window means)."""
    rows = []
    for r in ds:
        t = r.temperature_c
        row = {"run_id": r.run_id, "samples": int(r.n_samples),
               "duration_s": float(r.duration_s), "rate_hz": float(r.effective_rate_hz),
               "temperature_min_c": None if t is None else float(np.nanmin(t)),
               "temperature_max_c": None if t is None else float(np.nanmax(t))}
        if r.windows is not None:
            row.update(samples=int(r.windows.source_samples),
                       rate_hz=float(r.windows.source_rate_hz), rows=int(r.n_samples),
                       window_s=float(r.windows.window_s))
        rows.append(row)
    return rows
