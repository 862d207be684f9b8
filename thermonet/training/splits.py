"""Split strategies: which runs (or contiguous blocks of them) train, validate and test.

Splits never sample at random.  Each strategy is a small function registered
in :data:`SPLITS` under the name a config's ``split.strategy`` uses;
:func:`make_splits` looks the name up, so a new strategy is one function and
one registration line (:func:`register_split`).

* ``auto`` — by the number of runs: ≥ 3 → ``runs``; 2 → ``train-then-verify``;
  1 → ``time-blocks``;
* ``runs`` — train on all but the last two runs, stop early on the
  second-to-last, report on the last (or on the run ids named in ``train``,
  ``val``, ``test``);
* ``train-then-verify`` — train on the first of two runs, report on the second
  (study 001 and 002's procedure: calibration run, then a verification run);
  early stopping watches interleaved contiguous blocks of the first run;
* ``time-blocks`` — every run cut into interleaved contiguous blocks (below);
* ``leave-one-run-out`` — each run is the test run once, the previous run
  (cyclically) validates.

Interleaved contiguous blocks: the run is cut by time into ``n_blocks``
equal blocks; in every group of five, the third validates and the fifth
tests, the rest train (20 % / 20 % / 60 %).  Every held-out block is a
contiguous stretch of minutes to hours, and the held-out blocks sample the
whole temperature range, so a soak-by-soak recording is not judged on
temperatures it never trained on.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.recording import Dataset, Recording, WindowStats

__all__ = ["Split", "SplitConfig", "MAX_BLOCKS", "SplitStrategy", "SPLITS", "register_split", "make_splits",
           "time_blocks", "block_roles", "stack_blocks", "stacked_times"]


@dataclass
class Split:
    """One train / validate / test assignment."""

    train: list[Recording]
    val: Recording | None
    test: Recording
    label: str = "split"
    describe: dict[str, Any] = field(default_factory=dict)
    #: The data model selection may use (:mod:`thermonet.scoring.selection`): every run that is not
    #: the test run, *whole* (dynamic inputs are computed on the whole run before any cut),
    #: with a mask of its rows that are not test rows.
    pool: list[tuple[Recording, np.ndarray]] = field(default_factory=list)
    #: Where the parts are rows of whole runs (a time-block split): per run, the run whole
    #: and the role of each row (0, 1, 3 train, 2 validation, 4 test: :func:`block_roles`).
    #: The parts are then built on each whole run and cut (:func:`thermonet.training.
    #: pipeline.split_parts`): a dynamic input's state runs on through the blocks, as on the
    #: board — never restarted at a block's start.
    whole: list[tuple[Recording, np.ndarray]] = field(default_factory=list)


#: A strategy: (runs, split config, source for error messages) -> splits.
SplitStrategy = Callable[[list[Recording], "SplitConfig", str], list[Split]]

#: Registered strategies, by the name ``split.strategy`` uses.
SPLITS: dict[str, SplitStrategy] = {}


def register_split(name: str) -> Callable[[SplitStrategy], SplitStrategy]:
    """Decorator registering a strategy under ``name`` (refuses a name taken twice)."""
    def deco(fn: SplitStrategy) -> SplitStrategy:
        if name in SPLITS:
            raise ValueError(f"split strategy {name!r} is already registered")
        SPLITS[name] = fn
        return fn
    return deco


#: Most contiguous time blocks per run (``split.n_blocks``): beyond it a block is a few samples.
MAX_BLOCKS = 1000


@dataclass
class SplitConfig:
    """How runs are split; never by random sample (see :mod:`thermonet.training.splits`).

    ``auto``: ≥ 3 runs → ``runs``; 2 runs → ``train-then-verify``; 1 run →
    ``time-blocks``.  ``runs``: train on all but the last two runs, validate on
    the second-to-last, test on the last — or on the run ids named in
    ``train``, ``val``, ``test`` (without ``val``, interleaved blocks of the
    training runs validate; runs may not be in two roles).  ``train-then-verify``: train on
    the first run (validating on interleaved contiguous blocks of it), test on the
    second.  ``time-blocks``: every run cut into ``n_blocks`` contiguous time
    blocks, interleaved train / val / test (60 / 20 / 20 %).
    ``leave-one-run-out``: each run is the test run once (≥ 3 runs), the
    previous run validates; the report gives the mean over folds.
    """

    strategy: str = "auto"               # a name in SPLITS
    train: list[str] = field(default_factory=list)
    val: str | None = None
    test: str | None = None
    n_blocks: int = 20                   # contiguous time blocks per run (time-blocks)

    def __post_init__(self) -> None:
        if self.strategy not in SPLITS:
            raise ConfigError(f"key 'split.strategy': {self.strategy!r} is not one of "
                              f"{', '.join(repr(k) for k in SPLITS)}")
        if isinstance(self.n_blocks, bool) or not isinstance(self.n_blocks, int):
            raise ConfigError(f"key 'split.n_blocks': {self.n_blocks!r} is not an integer")
        if self.n_blocks < 5:
            raise ConfigError(f"key 'split.n_blocks': {self.n_blocks} is below 5 (every group "
                              "of five blocks gives one validation and one test block)")
        if self.n_blocks > MAX_BLOCKS:
            raise ConfigError(f"key 'split.n_blocks': {self.n_blocks} is above {MAX_BLOCKS} "
                              "(blocks that short put correlated neighbouring samples in "
                              "train and test: a split by sample in disguise)")


def make_splits(ds: Dataset | list[Recording], cfg: SplitConfig, *, source: str = "config"
                ) -> list[Split]:
    """Splits for the configured strategy (one split, or one per fold).

    ``source`` names the config file in error messages.

    Raises
    ------
    ConfigError
        An unregistered strategy (naming the valid ones), or data the strategy
        cannot split (naming the key).
    """
    try:
        strategy = SPLITS[cfg.strategy]
    except KeyError:
        raise ConfigError(f"{source}: key 'split.strategy': unknown strategy {cfg.strategy!r} "
                          f"(valid: {', '.join(SPLITS)})") from None
    return strategy(list(ds), cfg, source)


def _whole(runs: list[Recording]) -> list[tuple[Recording, np.ndarray]]:
    return [(r, np.ones(r.n_samples, dtype=bool)) for r in runs]


def block_roles(rec: Recording, n_blocks: int) -> np.ndarray:
    """Role of every sample in :func:`time_blocks`: 0, 1, 3 train, 2 val, 4 test."""
    t = rec.time_s
    # cut on time, not on sample index, so gaps (burst recordings) do not skew the blocks
    span = max(float(t[-1] - t[0]), 1e-12)
    block = np.minimum(((t - t[0]) / span * n_blocks).astype(int), n_blocks - 1)
    return np.asarray(block % 5)


def time_blocks(rec: Recording, n_blocks: int, *, with_test: bool = True
                ) -> tuple[Recording, Recording, Recording | None]:
    """Interleaved contiguous train | val | test blocks of one run (cut on time)."""
    role = block_roles(rec, n_blocks)
    is_val = role == 2
    is_test = (role == 4) if with_test else np.zeros_like(is_val)
    is_train = ~(is_val | is_test)
    train = rec.select(is_train, run_id=f"{rec.run_id}[train]")
    val = rec.select(is_val, run_id=f"{rec.run_id}[val]")
    test = rec.select(is_test, run_id=f"{rec.run_id}[test]") if with_test else None
    for part in (train, val) + ((test,) if test is not None else ()):
        if part.n_samples < 10:
            raise ConfigError(f"split: run '{rec.run_id}' has too few samples ({rec.n_samples}) "
                              f"for {n_blocks} contiguous train/val/test blocks")
    return train, val, test


def _carve_val(train: list[Recording], n_blocks: int) -> tuple[list[Recording], Recording]:
    """Validation from interleaved contiguous blocks of the training runs."""
    parts = [time_blocks(r, n_blocks, with_test=False) for r in train]
    return [p[0] for p in parts], stack_blocks([p[1] for p in parts], "val")


def _ids(runs: list[Recording]) -> list[str]:
    return [r.run_id for r in runs]


@register_split("auto")
def _auto(runs: list[Recording], cfg: SplitConfig, source: str) -> list[Split]:
    name = {1: "time-blocks", 2: "train-then-verify"}.get(len(runs), "runs")
    return SPLITS[name](runs, cfg, source)


@register_split("train-then-verify")
def _train_then_verify(runs: list[Recording], cfg: SplitConfig, source: str) -> list[Split]:
    if len(runs) != 2:
        raise ConfigError(f"{source}: key 'split.strategy': train-then-verify needs exactly "
                          f"2 runs, the data has {len(runs)}")
    (train,), val = _carve_val([runs[0]], cfg.n_blocks)
    return [Split([train], val, runs[1], "train-then-verify",
                  {"train": train.run_id, "val": val.run_id, "test": runs[1].run_id},
                  pool=_whole([runs[0]]))]


def _named_runs(runs: list[Recording], cfg: SplitConfig, source: str) -> list[Split]:
    """``runs`` with the run ids named in the config."""
    by_id = {r.run_id: r for r in runs}
    for key, names in (("train", cfg.train), ("val", [cfg.val] if cfg.val else []),
                       ("test", [cfg.test] if cfg.test else [])):
        for name in names:
            if name not in by_id:
                raise ConfigError(f"{source}: key 'split.{key}': no run '{name}' "
                                  f"(runs: {', '.join(by_id)})")
    if not cfg.test:
        raise ConfigError(f"{source}: key 'split.test': name the held-out test run")
    train_ids: list[str] = cfg.train or [i for i in by_id if i not in (cfg.val, cfg.test)]
    for key, run in (("test", cfg.test), ("val", cfg.val)):
        if run is not None and run in train_ids:
            raise ConfigError(f"{source}: key 'split.{key}': run '{run}' is also a training run")
    if cfg.val is not None and cfg.val == cfg.test:
        raise ConfigError(f"{source}: key 'split.val': run '{cfg.val}' is also the test run")
    if not train_ids:
        raise ConfigError(f"{source}: key 'split.train': no training run left")
    train = [by_id[i] for i in train_ids]
    pool = _whole(train + ([by_id[cfg.val]] if cfg.val else []))
    if cfg.val:
        val = by_id[cfg.val]
    else:  # never choose on training data: validate on blocks cut out of it
        train, val = _carve_val(train, cfg.n_blocks)
    return [Split(train, val, by_id[cfg.test], "runs",
                  {"train": _ids(train), "val": val.run_id, "test": cfg.test}, pool=pool)]


@register_split("runs")
def _runs(runs: list[Recording], cfg: SplitConfig, source: str) -> list[Split]:
    if cfg.train or cfg.val or cfg.test:
        return _named_runs(runs, cfg, source)
    if len(runs) < 3:
        raise ConfigError(f"{source}: key 'split.strategy': 'runs' needs at least 3 runs, "
                          f"the data has {len(runs)} (use 'time-blocks')")
    ids = _ids(runs)
    return [Split(runs[:-2], runs[-2], runs[-1], "runs",
                  {"train": ids[:-2], "val": ids[-2], "test": ids[-1]}, pool=_whole(runs[:-1]))]


@register_split("leave-one-run-out")
def _leave_one_run_out(runs: list[Recording], cfg: SplitConfig, source: str) -> list[Split]:
    if len(runs) < 3:
        raise ConfigError(f"{source}: key 'split.strategy': leave-one-run-out needs at "
                          f"least 3 runs, the data has {len(runs)}")
    splits = []
    for k, test in enumerate(runs):
        val = runs[k - 1]  # the previous run (cyclically) validates
        train = [r for r in runs if r is not test and r is not val]
        splits.append(Split(train, val, test, f"fold{k}",
                            {"train": _ids(train), "val": val.run_id, "test": test.run_id},
                            pool=_whole([r for r in runs if r is not test])))
    return splits


@register_split("time-blocks")
def _time_blocks(runs: list[Recording], cfg: SplitConfig, source: str) -> list[Split]:
    blocks = [time_blocks(r, cfg.n_blocks) for r in runs]
    pool = [(r, block_roles(r, cfg.n_blocks) != 4) for r in runs]
    trains = [b[0] for b in blocks]
    vals = [b[1] for b in blocks]
    tests = [b[2] for b in blocks if b[2] is not None]
    whole = [(r, block_roles(r, cfg.n_blocks)) for r in runs]
    if len(runs) == 1:
        return [Split(trains, vals[0], tests[0], "time-blocks",
                      {"train": trains[0].run_id, "val": vals[0].run_id,
                       "test": tests[0].run_id}, pool=pool, whole=whole)]
    return [Split(trains, stack_blocks(vals, "val"), stack_blocks(tests, "test"), "time-blocks",
                  {"train": _ids(trains), "val": _ids(vals), "test": _ids(tests)}, pool=pool,
                  whole=whole)]


def stacked_times(times: Sequence[np.ndarray], steps: Sequence[float]) -> list[np.ndarray]:
    """Times of held-out pieces judged as one: each shifted to start one of its sample
    intervals (``steps``) after the piece before it ends, the first at 0."""
    out, offset = [], 0.0
    for t, step in zip(times, steps, strict=True):
        t = np.asarray(t, dtype=np.float64)
        t = t - (t[0] if t.size else 0.0) + offset
        out.append(t)
        offset = (float(t[-1]) if t.size else offset) + step
    return out


def stack_blocks(parts: list[Recording], run_id: str) -> Recording:
    """Several held-out blocks judged as one: samples concatenated in run order.

    Time is shifted so it keeps increasing across blocks; per-sample metrics
    do not depend on it, and the Allan deviation is computed per block only
    through the samples (documented in :mod:`thermonet.scoring.metrics`).  The first
    sample index of each block is kept in ``meta["segment_starts"]`` (comma-separated):
    the dynamic inputs restart there (:func:`thermonet.features.inputs.signal_matrix`),
    never carrying state from one block into an unrelated one.
    """
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    times = stacked_times([p.time_s for p in parts], [1.0 / p.effective_rate_hz for p in parts])

    def cat(group: str) -> dict[str, np.ndarray]:
        keys = getattr(first, group).keys()
        return {k: np.concatenate([getattr(p, group)[k] for p in parts]) for k in keys}

    # a run without a reference had a static input (zeros); truth is kept only where
    # every run has it
    references = {f"ref_{a}": np.concatenate([p.reference(a) for p in parts])
                  for a in first.outputs if any(f"ref_{a}" in p.references for p in parts)}
    drift = {k: np.concatenate([p.drift[k] for p in parts]) for k in first.drift
             if all(k in p.drift for p in parts)}

    temps = None
    if first.temperature_c is not None:
        temps = np.concatenate([p.temperature_c for p in parts
                                if p.temperature_c is not None])
    windows = None
    if all(p.windows is not None for p in parts):
        windows = WindowStats.concat([p.windows for p in parts if p.windows is not None])
    return Recording(time_s=np.concatenate(times), temperature_c=temps,
                     outputs=cat("outputs"), references=references,
                     proxies=cat("proxies"), drift=drift, units=dict(first.units),
                     device_id=first.device_id, sensor_kind=first.sensor_kind,
                     run_id=run_id, sample_rate_hz=first.sample_rate_hz,
                     meta={**first.meta, "segment_starts": ",".join(
                         str(int(x)) for x in np.cumsum([0] + [p.n_samples for p in parts[:-1]]))},
                     windows=windows)
