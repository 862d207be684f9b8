"""Honest evaluation: data loading, hashing, targets, per-axis metrics.

Splits (never random: by run or contiguous time) live in
:mod:`thermonet.training.splits`, one registered function per strategy;
:class:`~thermonet.training.splits.Split` and :func:`~thermonet.training.splits.make_splits`
are re-exported here.
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.recording import Dataset, Recording
from ..features.inputs import RATE, signal_matrix
from ..features.target import CHANNEL, FOUR_POSITION, FOURPOS_SUFFIXES, Target, resolve_targets
from ..sim import simulate
from ..sim.fourpos import four_position_estimates
from .config_sections import DataConfig
from .splits import Split, make_splits, stacked_times

__all__ = ["Split", "Part", "load_data", "make_splits", "build_part", "data_hash",
           "heating_only", "heating_keep", "rows_of", "join_parts", "fit_arrays", "rows_average_s", "FOURPOS_SUFFIXES",
           "HEATING_MIN_RATE_C_PER_MIN", "targets_for", "check_loaded"]

#: Samples with dT/dt above this count as heating (or soaking) for ``train_on: heating``.
HEATING_MIN_RATE_C_PER_MIN = -0.05



def load_data(cfg: DataConfig, *, source: str = "config", allow_fleet: bool = False
              ) -> Dataset:
    """The configured recordings: files (with an optional mapping) or the simulator.

    Data holding several units (device ids) is refused unless ``allow_fleet``
    (``thermonet fleet`` calibrates them one by one).
    """
    if cfg.paths:
        from ..data.io import read_datasets  # lazy: file readers load pyarrow (~0.2 s)

        # a fleet is validated unit by unit (thermonet.workflows.fleet_units.sources_from_dataset)
        ds = read_datasets(cfg.paths, mapping=cfg.mapping, validate=not allow_fleet)
    else:
        if not cfg.preset:
            raise ConfigError(f"{source}: key 'data': give 'paths' or a simulator 'preset'")
        ds = simulate(cfg.preset, runs=cfg.runs, seed=cfg.seed)
    return check_loaded(ds, cfg, source, allow_fleet=allow_fleet)


def check_loaded(ds: Dataset, cfg: DataConfig, source: str, *, allow_fleet: bool = False
                 ) -> Dataset:
    """The data as read, against the config: every output ``data.outputs`` names, and one
    unit unless ``allow_fleet`` (``thermonet fleet`` calibrates several); returns ``ds``."""
    if cfg.outputs:
        missing = [o for o in cfg.outputs if o not in ds.axes]
        if missing:
            raise ConfigError(f"{source}: key 'data.outputs': no output '{missing[0]}' in the data "
                              f"(outputs: {', '.join(ds.axes)})")
    if not allow_fleet and ds.is_fleet:
        ids = ds.unit_ids
        raise ConfigError(f"{source}: the data holds {len(ids)} units ({', '.join(ids[:3])}"
                          f"{', …' if len(ids) > 3 else ''}); calibrate them with "
                          "'thermonet fleet'")
    return ds


def data_hash(ds: Dataset) -> str:
    """SHA-256 (first 16 hex digits) over every run's samples, in run order (of a run streamed
    into window means: over its rows and their sample counts)."""
    h = hashlib.sha256()
    for r in ds:
        h.update(r.run_id.encode())
        chans = [r.time_s] + ([r.temperature_c] if r.temperature_c is not None else [])
        for group in (r.outputs, r.references, r.proxies):
            chans += [group[k] for k in sorted(group)]
        if r.windows is not None:
            chans.append(r.windows.n)
        for c in chans:
            h.update(np.ascontiguousarray(c, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


_AVERAGE_LOCK = threading.Lock()


@dataclass
class Part:
    """One recording turned into model inputs and targets.

    ``signals`` (n, S) physical signals; ``target`` (n, A) the observed
    drift (or per-soak K0/K1); ``raw_error`` (n, A) what an uncompensated
    sensor would be wrong by; ``bin_by`` the variable for 1-unit bins
    (°C, or the proxy); ``true_drift`` (n, A) where simulated.

    A part of a recording reduced to window means (:mod:`thermonet.features.windows`)
    has ``weight`` (n,), the samples of each row, ``within_ss`` (n, A), each row's
    sum of squared deviations of the target about its mean, ``within_sxx`` (n, S, S) and
    ``within_sxy`` (n, S, A), the co-moments inside each row of the signals with each
    other and with the target, and ``window_s``, the windows' length; a part of samples
    has None for each and 0.
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
    targets: Target | None = None        # per-axis target modes (None: every axis 'channel')
    weight: np.ndarray | None = None     # samples per row (a reduced recording's windows)
    within_ss: np.ndarray | None = None  # per row and axis: Σ (target − row mean)² inside it
    within_sxx: np.ndarray | None = None  # per row: signals' co-moments inside it (n, S, S)
    within_sxy: np.ndarray | None = None  # per row: signals × target co-moments (n, S, A)
    window_s: float = 0.0                # the rows' window length (0: rows are samples)
    # fit_arrays' window means, per window length: computed once, shared by every family
    _averaged: dict[float, tuple[np.ndarray, ...]] = field(default_factory=dict, repr=False,
                                                            compare=False)

    def offset_free(self, j: int) -> bool:
        """True where a constant in axis ``j``'s target is no error (``at-t-ref``, a scale factor)."""
        if self.targets is not None:
            return self.targets.offset_free(self.outputs[j])
        return self.outputs[j].endswith(FOURPOS_SUFFIXES[1])


def targets_for(ds: Dataset, spec: Any, outputs: list[str], *, source: str = "config") -> Target:
    """The per-output target modes of a comparison (:func:`thermonet.features.target.resolve_targets`)
    with the reference channels the dataset carries (in any of its runs)."""
    has_ref = {o: any(f"ref_{o}" in r.references for r in ds) for o in outputs}
    return resolve_targets(spec, outputs, has_reference=has_ref, source=source)


def build_part(rec: Recording, *, signals: list[str], outputs: list[str],
               target: Target | str, gap_s: float | None = None) -> Part:
    """Signals and targets of one recording for the configured target.

    Per axis the target is ``output − ref_<axis>`` (mode ``channel``) or the
    output itself (``zero``, ``at-t-ref``: the model's normalisation at
    :math:`T_{ref}` then removes the unknown constant, see
    :mod:`thermonet.features.target`).  A plain string is the whole-comparison kind
    (``"drift"``: every axis ``channel``, the reference being zero where none
    was recorded; ``"four-position"``).  ``gap_s`` is the dynamic inputs' gap
    limit (:func:`thermonet.features.inputs.signal_matrix`).
    """
    if isinstance(target, str):
        target = Target.uniform(outputs, FOUR_POSITION if target == FOUR_POSITION else CHANNEL)
    if target.kind == FOUR_POSITION:
        return _fourpos_part(rec, signals=signals, outputs=outputs)
    sig = signal_matrix(rec, signals, gap_s)
    y = np.column_stack([rec.drift_observed(a) if target.mode(a) == CHANNEL
                         else np.asarray(rec.outputs[a], dtype=np.float64) for a in outputs])
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
    weight = within = sxx = sxy = None
    window_s = 0.0
    if rec.windows is not None:
        win = rec.windows
        weight, window_s = win.n.astype(np.float64), win.window_s
        channel = [target.mode(a) == CHANNEL for a in outputs]
        within = np.column_stack([win.ss[a] if c else win.ss_output.get(a, win.ss[a])
                                  for a, c in zip(outputs, channel, strict=True)])
        if win.sxx is not None and all(s in win.signal_names for s in signals):
            idx = [win.signal_names.index(s) for s in signals]
            sxx = win.sxx[:, idx][:, :, idx]
            sxy = np.stack([(win.sxd[a] if c else win.sxd_output.get(a, win.sxd[a]))[:, idx]
                            for a, c in zip(outputs, channel, strict=True)], axis=2)
    return Part(sig, y, rec.time_s, bin_by, width, rec.effective_rate_hz, true, outputs,
                targets=target, weight=weight, within_ss=within, within_sxx=sxx,
                within_sxy=sxy, window_s=window_s)


def _fourpos_part(rec: Recording, *, signals: list[str], outputs: list[str]) -> Part:
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
                float("nan"), None, outputs, per_soak=True,
                targets=Target.uniform(outputs, FOUR_POSITION))


def heating_keep(rec: Recording, gap_s: float | None = None) -> np.ndarray:
    """The samples of ``rec`` where its temperature is not falling (PX4/ArduPilot way);
    ConfigError where fewer than 10."""
    rate = signal_matrix(rec, [RATE], gap_s)[:, 0]
    keep = rate > HEATING_MIN_RATE_C_PER_MIN
    if keep.sum() < 10:
        raise ConfigError(f"train_on 'heating': run '{rec.run_id}' has {int(keep.sum())} heating "
                          "samples")
    return keep


def heating_only(part: Part, rec: Recording, gap_s: float | None = None) -> Part:
    """The samples of ``part`` where ``rec``'s temperature is not falling (PX4/ArduPilot way)."""
    if part.per_soak:
        raise ConfigError("config: key 'train_on': 'heating' applies to per-sample targets, "
                          "not to the four-position target")
    return rows_of(part, heating_keep(rec, gap_s))


def rows_of(part: Part, keep: np.ndarray) -> Part:
    """The rows ``keep`` (a boolean mask) of ``part``, every per-row array cut alike.  Cut
    from a part of a whole run, the rows keep the dynamic inputs' state carried in from the
    rows before them, as on the board."""
    keep = np.asarray(keep, dtype=bool)

    def cut(x: np.ndarray | None) -> np.ndarray | None:
        return None if x is None else x[keep]

    return Part(part.signals[keep], part.target[keep], part.time_s[keep], part.bin_by[keep],
                part.bin_width, part.rate_hz, cut(part.true_drift), part.outputs,
                per_soak=part.per_soak, targets=part.targets, weight=cut(part.weight),
                within_ss=cut(part.within_ss), within_sxx=cut(part.within_sxx),
                within_sxy=cut(part.within_sxy), window_s=part.window_s)


def join_parts(parts: list[Part]) -> Part:
    """Parts of several runs judged as one, in order: time shifted so that it keeps
    increasing, one sample interval after the part before (as
    :func:`thermonet.training.splits.stack_blocks` stacks held-out blocks)."""
    if len(parts) == 1:
        return parts[0]
    times = stacked_times([q.time_s for q in parts],
                          [1.0 / q.rate_hz if q.rate_hz and np.isfinite(q.rate_hz) else 1.0
                           for q in parts])
    first = parts[0]

    def cat(name: str) -> np.ndarray | None:
        xs = [getattr(q, name) for q in parts]
        return None if any(x is None for x in xs) else np.concatenate(xs)

    return Part(np.concatenate([q.signals for q in parts]),
                np.concatenate([q.target for q in parts]), np.concatenate(times),
                np.concatenate([q.bin_by for q in parts]), first.bin_width, first.rate_hz,
                cat("true_drift"), first.outputs, per_soak=first.per_soak,
                targets=first.targets, weight=cat("weight"), within_ss=cat("within_ss"),
                within_sxx=cat("within_sxx"), within_sxy=cat("within_sxy"),
                window_s=first.window_s)


def rows_average_s(part: Part, average_s: float) -> float:
    """The averaging window a fit applies to ``part``'s rows: 0 where they are window means
    at least ``average_s`` long already (a reduced recording), else ``average_s``."""
    return 0.0 if part.window_s > 0 and average_s <= part.window_s * (1 + 1e-9) else average_s


def fit_arrays(part: Part, average_s: float = 0.0) -> tuple[np.ndarray, ...]:
    """What :func:`thermonet.training.train.fit` takes for one run: signals, targets and the time
    in s (per-sample targets); a per-soak part is one sample per soak already and goes
    without its time.

    With ``average_s`` > 0 the arrays are already averaged into windows of that length
    (:func:`thermonet.training.train.average_windows`, what ``fit`` would do with
    ``train.average_s``), computed once per part and window and cached on it: the
    families of a comparison share one pass over a long recording instead of one each
    (``fit``'s own averaging then finds one sample per window, a cheap pass).
    """
    if part.per_soak:
        return part.signals, part.target
    average_s = rows_average_s(part, average_s)
    if average_s > 0:
        with _AVERAGE_LOCK:      # families fitted side by side share one computation
            if average_s not in part._averaged:
                from .train import average_windows  # torch boundary: train imports torch

                part._averaged[average_s] = average_windows(part.signals, part.target,
                                                            part.time_s, average_s)
            return part._averaged[average_s]
    return part.signals, part.target, part.time_s
