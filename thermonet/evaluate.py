"""Honest evaluation: data loading, splits by run or contiguous time, targets, per-axis metrics.

Splits never sample at random.  ``auto`` picks by the number of runs:

* ≥ 3 runs: by run — train on all but the last two, stop early on the
  second-to-last, report on the last (or ``leave-one-run-out``);
* 2 runs: train on the first, report on the second (study 001 and 002's
  procedure: calibration run, then a verification run); early stopping
  watches interleaved contiguous blocks of the first run (below);
* 1 run: interleaved contiguous blocks of that run.

Interleaved contiguous blocks: the run is cut by time into ``n_blocks``
equal blocks; in every group of five, the third validates and the fifth
tests, the rest train (20 % / 20 % / 60 %).  Every held-out block is a
contiguous stretch of minutes to hours, and the held-out blocks sample the
whole temperature range, so a soak-by-soak recording is not judged on
temperatures it never trained on.  ``time-blocks`` applies the same cut to
every run (e.g. two isothermal soaks that only together span the range).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .config import DataConfig, SplitConfig
from .errors import ConfigError
from .recording import Dataset, Recording

__all__ = ["Split", "Part", "load_data", "make_splits", "build_part", "data_hash",
           "heating_only", "FOURPOS_SUFFIXES", "HEATING_MIN_RATE_C_PER_MIN"]

#: Samples with dT/dt above this count as heating (or soaking) for ``train_on: heating``.
HEATING_MIN_RATE_C_PER_MIN = -0.05

#: Output names of the four-position target: per axis its bias K0 and scale factor K1.
FOURPOS_SUFFIXES = (".bias", ".scale")


def load_data(cfg: DataConfig, *, source: str = "config", allow_fleet: bool = False
              ) -> Dataset:
    """The configured recordings: files (with an optional mapping) or the simulator.

    Data holding several units (device ids) is refused unless ``allow_fleet``
    (``thermonet fleet`` calibrates them one by one).
    """
    if cfg.paths:
        from .io import read_datasets

        ds = read_datasets(cfg.paths, mapping=cfg.mapping)
    else:
        from .sim import simulate

        if not cfg.preset:
            raise ConfigError(f"{source}: key 'data': give 'paths' or a simulator 'preset'")
        ds = simulate(cfg.preset, runs=cfg.runs, seed=cfg.seed)
    if cfg.outputs:
        missing = [o for o in cfg.outputs if o not in ds.axes]
        if missing:
            raise ConfigError(f"{source}: key 'data.outputs': no output '{missing[0]}' in the data "
                              f"(outputs: {', '.join(ds.axes)})")
    if ds.is_fleet and not allow_fleet:
        ids = ds.unit_ids
        raise ConfigError(f"{source}: the data holds {len(ids)} units ({', '.join(ids[:3])}"
                          f"{', …' if len(ids) > 3 else ''}); calibrate them with "
                          "'thermonet fleet'")
    return ds


def data_hash(ds: Dataset) -> str:
    """SHA-256 (first 16 hex digits) over every run's samples, in run order."""
    h = hashlib.sha256()
    for r in ds:
        h.update(r.run_id.encode())
        chans = [r.time_s] + ([r.temperature_c] if r.temperature_c is not None else [])
        for group in (r.outputs, r.references, r.proxies):
            chans += [group[k] for k in sorted(group)]
        for c in chans:
            h.update(np.ascontiguousarray(c, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


@dataclass
class Split:
    """One train / validate / test assignment."""

    train: list[Recording]
    val: Recording | None
    test: Recording
    label: str = "split"
    describe: dict[str, Any] = field(default_factory=dict)


def _blocks(rec: Recording, n_blocks: int, *, with_test: bool = True
            ) -> tuple[Recording, Recording, Recording | None]:
    """Interleaved contiguous train | val | test blocks of one run (cut on time)."""
    t = rec.time_s
    # cut on time, not on sample index, so gaps (burst recordings) do not skew the blocks
    block = np.minimum(((t - t[0]) / max(t[-1] - t[0], 1e-12) * n_blocks).astype(int), n_blocks - 1)
    role = block % 5
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
    parts = [_blocks(r, n_blocks, with_test=False) for r in train]
    return [p[0] for p in parts], _stack([p[1] for p in parts], "val")


def make_splits(ds: Dataset, cfg: SplitConfig, *, source: str = "config") -> list[Split]:
    """Splits for the configured strategy (one split, or one per fold).

    ``source`` names the config file in error messages.
    """
    runs = list(ds)
    ids = [r.run_id for r in runs]
    strategy = cfg.strategy
    if strategy == "auto":
        strategy = {1: "time-blocks", 2: "train-then-verify"}.get(len(runs), "runs")
    if strategy == "train-then-verify":
        if len(runs) != 2:
            raise ConfigError(f"{source}: key 'split.strategy': train-then-verify needs exactly "
                              f"2 runs, the data has {len(runs)}")
        (train,), val = _carve_val([runs[0]], cfg.n_blocks)
        return [Split([train], val, runs[1], "train-then-verify",
                      {"train": train.run_id, "val": val.run_id, "test": runs[1].run_id})]
    if strategy == "runs":
        if cfg.train or cfg.val or cfg.test:
            for key, names in (("train", cfg.train), ("val", [cfg.val] if cfg.val else []),
                               ("test", [cfg.test] if cfg.test else [])):
                for name in names:
                    if name not in ids:
                        raise ConfigError(f"{source}: key 'split.{key}': no run '{name}' "
                                          f"(runs: {', '.join(ids)})")
            if not cfg.test:
                raise ConfigError(f"{source}: key 'split.test': name the held-out test run")
            train_ids = cfg.train or [i for i in ids if i not in (cfg.val, cfg.test)]
            for key, name in (("test", cfg.test), ("val", cfg.val)):
                if name in train_ids:
                    raise ConfigError(f"{source}: key 'split.{key}': run '{name}' is also a "
                                      "training run")
            if cfg.val is not None and cfg.val == cfg.test:
                raise ConfigError(f"{source}: key 'split.val': run '{cfg.val}' is also the test run")
            if not train_ids:
                raise ConfigError(f"{source}: key 'split.train': no training run left")
            train = [ds[i] for i in train_ids]
            if cfg.val:
                val = ds[cfg.val]
            else:  # never choose on training data: validate on blocks cut out of it
                train, val = _carve_val(train, cfg.n_blocks)
            return [Split(train, val, ds[cfg.test], "runs",
                          {"train": [r.run_id for r in train], "val": val.run_id,
                           "test": cfg.test})]
        if len(runs) < 3:
            raise ConfigError(f"{source}: key 'split.strategy': 'runs' needs at least 3 runs, "
                              f"the data has {len(runs)} (use 'time-blocks')")
        return [Split(runs[:-2], runs[-2], runs[-1], "runs",
                      {"train": ids[:-2], "val": ids[-2], "test": ids[-1]})]
    if strategy == "leave-one-run-out":
        if len(runs) < 3:
            raise ConfigError(f"{source}: key 'split.strategy': leave-one-run-out needs at "
                              f"least 3 runs, the data has {len(runs)}")
        splits = []
        for k, test in enumerate(runs):
            val = runs[k - 1]  # the previous run (cyclically) validates
            train = [r for r in runs if r is not test and r is not val]
            splits.append(Split(train, val, test, f"fold{k}",
                                {"train": [r.run_id for r in train], "val": val.run_id,
                                 "test": test.run_id}))
        return splits
    # time-blocks: every run gives interleaved train, val and test blocks
    if len(runs) == 1:
        train, val, test = _blocks(runs[0], cfg.n_blocks)
        return [Split([train], val, test, "time-blocks",
                      {"train": train.run_id, "val": val.run_id, "test": test.run_id})]
    trains, vals, tests = [], [], []
    for r in runs:
        tr, va, te = _blocks(r, cfg.n_blocks)
        trains.append(tr), vals.append(va), tests.append(te)
    return [Split(trains, _stack(vals, "val"), _stack(tests, "test"), "time-blocks",
                  {"train": [r.run_id for r in trains], "val": [r.run_id for r in vals],
                   "test": [r.run_id for r in tests]})]


def _stack(parts: list[Recording], run_id: str) -> Recording:
    """Several held-out blocks judged as one: samples concatenated in run order.

    Time is shifted so it keeps increasing across blocks; per-sample metrics
    do not depend on it, and the Allan deviation is computed per block only
    through the samples (documented in :mod:`thermonet.metrics`).
    """
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    times, offset = [], 0.0
    for p in parts:
        t = p.time_s - p.time_s[0] + offset
        times.append(t)
        offset = t[-1] + 1.0 / p.effective_rate_hz

    def cat(name_group: str) -> dict[str, np.ndarray]:
        keys = getattr(first, name_group).keys()
        return {k: np.concatenate([getattr(p, name_group)[k] for p in parts]) for k in keys}

    # a run without a reference had a static input (zeros); truth is kept only where
    # every run has it
    references = {f"ref_{a}": np.concatenate([p.reference(a) for p in parts])
                  for a in first.outputs if any(f"ref_{a}" in p.references for p in parts)}
    drift = {k: np.concatenate([p.drift[k] for p in parts]) for k in first.drift
             if all(k in p.drift for p in parts)}

    temps = None
    if first.temperature_c is not None:
        temps = np.concatenate([p.temperature_c for p in parts])
    return Recording(time_s=np.concatenate(times), temperature_c=temps,
                     outputs=cat("outputs"), references=references,
                     proxies=cat("proxies"), drift=drift, units=dict(first.units),
                     device_id=first.device_id, sensor_kind=first.sensor_kind,
                     run_id=run_id, sample_rate_hz=first.sample_rate_hz, meta=dict(first.meta))


@dataclass
class Part:
    """One recording turned into model inputs and targets.

    ``signals`` (n, S) physical signals; ``target`` (n, A) the observed
    drift (or per-soak K0/K1); ``raw_error`` (n, A) what an uncompensated
    sensor would be wrong by; ``bin_by`` the variable for 1-unit bins
    (°C, or the proxy); ``true_drift`` (n, A) where simulated.
    """

    signals: np.ndarray
    target: np.ndarray
    time_s: np.ndarray
    bin_by: np.ndarray
    bin_width: float
    rate_hz: float
    true_drift: np.ndarray | None
    outputs: list[str]
    per_soak: bool = False               # one sample per soak (four-position target)


def build_part(rec: Recording, *, signals: list[str], outputs: list[str], target: str,
               rate_window_s: float) -> Part:
    """Signals and targets of one recording for the configured target."""
    from .features import signal_matrix

    if target == "four-position":
        return _fourpos_part(rec, signals=signals, outputs=outputs)
    sig = signal_matrix(rec, signals, rate_window_s=rate_window_s)
    y = np.column_stack([rec.drift_observed(a) for a in outputs])
    true = None
    if all(f"drift_{a}" in rec.drift for a in outputs):
        true = np.column_stack([rec.drift[f"drift_{a}"] for a in outputs])
    if rec.temperature_c is not None:
        bin_by, width = rec.temperature_c, 1.0
    else:
        name = sorted(rec.proxies)[0]
        bin_by = rec.proxies[name]
        # one bin per 1/50 of the proxy's span: about the resolution of 1 °C bins
        # over a 50 °C test when the proxy's scale to °C is unknown
        width = max(float(np.ptp(bin_by)) / 50.0, 1e-12)
    return Part(sig, y, rec.time_s, bin_by, width, rec.effective_rate_hz, true, outputs)


def _fourpos_part(rec: Recording, *, signals: list[str], outputs: list[str]) -> Part:
    from .sim.fourpos import four_position_estimates

    if signals != ["temperature_c"]:
        raise ConfigError("config: key 'target': four-position models take temperature inputs "
                          f"only (T, dT, dT2), got signals {signals}")
    axes = sorted({o.rsplit(".", 1)[0] for o in outputs})
    cols: dict[str, np.ndarray] = {}
    temps = None
    for axis in axes:
        est = np.asarray(four_position_estimates(rec, axis), dtype=np.float64)
        if temps is None:
            temps = est[:, 0]
        cols[f"{axis}.bias"] = est[:, 1]
        cols[f"{axis}.scale"] = est[:, 2]
    assert temps is not None
    y = np.column_stack([cols[o] for o in outputs])
    return Part(temps[:, None], y, np.arange(temps.size, dtype=np.float64), temps, 1.0,
                float("nan"), None, outputs, per_soak=True)


def heating_only(part: Part, rec: Recording, rate_window_s: float) -> Part:
    """The samples of ``part`` where ``rec``'s temperature is not falling (PX4/ArduPilot practice)."""
    from .features import RATE, signal_matrix

    if part.per_soak:
        raise ConfigError("config: key 'train_on': 'heating' applies to per-sample targets, "
                          "not to the four-position target")
    rate = signal_matrix(rec, [RATE], rate_window_s=rate_window_s)[:, 0]
    keep = rate > HEATING_MIN_RATE_C_PER_MIN
    if keep.sum() < 10:
        raise ConfigError(f"train_on 'heating': run '{rec.run_id}' has {int(keep.sum())} heating "
                          "samples")
    return Part(part.signals[keep], part.target[keep], part.time_s[keep], part.bin_by[keep],
                part.bin_width, part.rate_hz, None if part.true_drift is None
                else part.true_drift[keep], part.outputs)
