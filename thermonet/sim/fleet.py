"""Simulated fleets: many units of one preset, each with its own unit-to-unit draw.

A preset's :class:`~thermonet.sim.device.UnitSpreadConfig` already draws one
unit per seed (law gains, a temperature shift).  A fleet of ``units`` units
derives one seed per unit deterministically from the fleet seed
(:func:`unit_seed`: NumPy's ``SeedSequence([seed, k])``), so unit *k* of a fleet
is the same whatever the fleet's size, and every unit is an independent draw.

Outlier units (``outliers``: the last *K* units) follow a drift law off the
fleet's: every axis's bias law and scale-factor law are multiplied by
``1 + OUTLIER_SIGMAS · σ`` where σ is the preset's unit-to-unit gain spread
(``bias_gain_rel``, at least :data:`MIN_GAIN_SIGMA`), i.e. a unit
:data:`OUTLIER_SIGMAS` standard deviations off, as a faulty die or a bad
mounting gives on a production line.  Their metadata say ``outlier: "1"``.

Device ids are ``<preset>-u000``, ``<preset>-u001`` … (three digits at least).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.errors import ConfigError
from ..core.recording import Dataset
from .device import AnyLaw, LawSum, Lorentz, Polynomial, Sinusoid
from .presets import (
    MAX_RUNS,
    MAX_SAMPLES,
    SimConfig,
    _apply_overrides,
    get_preset,
    request_samples,
    simulate,
)

__all__ = ["simulate_fleet", "unit_seed", "unit_device_id", "outlier_config",
           "OUTLIER_SIGMAS", "MIN_GAIN_SIGMA", "MAX_UNITS"]

#: Most units one fleet may have (a production line's week; the fleet's tables and the
#: per-unit bookkeeping grow with it).  Checked before anything is simulated or listed.
MAX_UNITS = 10_000

#: How far an outlier unit's drift law is off the fleet's, in unit-to-unit standard deviations.
OUTLIER_SIGMAS = 10.0
#: The relative gain spread used for outliers when a preset has none (1 %).
MIN_GAIN_SIGMA = 0.01


def unit_seed(seed: int, unit: int) -> int:
    """The simulator seed of unit ``unit`` of the fleet seeded ``seed`` (a 32-bit integer)."""
    if unit < 0 or seed < 0:
        raise ConfigError(f"seed and unit index must be non-negative, got {seed}, {unit}")
    return int(np.random.SeedSequence([int(seed), int(unit)]).generate_state(1)[0])


def unit_device_id(preset: str, unit: int, n_units: int) -> str:
    """``<preset>-u000``: the unit index zero-padded to the fleet's width (≥ 3 digits)."""
    width = max(3, len(str(max(n_units - 1, 0))))
    return f"{preset}-u{unit:0{width}d}"


def _scaled(law: AnyLaw, factor: float) -> AnyLaw:
    """A drift law multiplied by ``factor`` (every law here is linear in its amplitudes)."""
    if isinstance(law, Polynomial):
        return dataclasses.replace(law, coefficients=tuple(c * factor for c in law.coefficients))
    if isinstance(law, Lorentz):
        return dataclasses.replace(law, y0=law.y0 * factor, area=law.area * factor)
    if isinstance(law, Sinusoid):
        return dataclasses.replace(law, amplitude=law.amplitude * factor)
    if isinstance(law, LawSum):
        return dataclasses.replace(law, parts=tuple(_scaled(p, factor) for p in law.parts))
    raise ConfigError(f"cannot scale drift law {type(law).__name__} for an outlier unit")


def outlier_config(cfg: SimConfig, sigmas: float = OUTLIER_SIGMAS) -> SimConfig:
    """``cfg`` with every axis's bias and scale-factor law scaled ``sigmas`` gain-σ off."""
    sigma = max(float(cfg.unit_spread.bias_gain_rel), MIN_GAIN_SIGMA)
    factor = 1.0 + sigmas * sigma
    axes = tuple(dataclasses.replace(
        ax, bias=_scaled(ax.bias, factor),
        scale_factor_ppm=None if ax.scale_factor_ppm is None else
        _scaled(ax.scale_factor_ppm, factor)) for ax in cfg.axes)
    return dataclasses.replace(cfg, axes=axes)


def simulate_fleet(preset: str | SimConfig, *, units: int, runs: int | None = None,
                   seed: int = 0, outliers: int = 0, unit_indices: list[int] | None = None,
                   **overrides: object) -> Dataset:
    """Simulate ``units`` units of a preset, ``runs`` runs each, as one fleet :class:`Dataset`.

    Parameters
    ----------
    preset : str or SimConfig
    units : int
        Number of units N (≥ 1).
    runs : int, optional
        Runs per unit (default: the preset's).
    seed : int
        Fleet seed; unit *k* is simulated with :func:`unit_seed` ``(seed, k)``.
    outliers : int
        The last ``outliers`` units follow :func:`outlier_config` (0 ≤ K ≤ N).
    unit_indices : list of int, optional
        Simulate only these units of the fleet (a worker simulating its own unit);
        device ids and seeds are those of the whole fleet.
    **overrides
        As :func:`~thermonet.sim.simulate`.
    """
    cfg = get_preset(preset) if isinstance(preset, str) else preset
    for name, value in (("units", units), ("outliers", outliers)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ConfigError(f"{name} must be an integer, got {value!r}")
    if units < 1:
        raise ConfigError(f"units must be at least 1, got {units}")
    if units > MAX_UNITS:
        raise ConfigError(f"units={units} is above the limit of {MAX_UNITS:,} units per fleet "
                          "(bounded so that a request cannot exhaust memory)")
    if not 0 <= outliers <= units:
        raise ConfigError(f"outliers must be between 0 and units ({units}), got {outliers}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
    indices = list(range(units)) if unit_indices is None else list(unit_indices)
    bad = [k for k in indices if not 0 <= k < units]
    if bad:
        raise ConfigError(f"unit index {bad[0]} is outside the fleet of {units} units")
    n_runs = cfg.default_runs if runs is None else int(runs)
    if not 1 <= n_runs <= MAX_RUNS:
        raise ConfigError(f"runs={n_runs} is not in 1..{MAX_RUNS} (runs per unit)")
    # what this call holds at once: every simulated unit's runs, counted before any is made
    held = request_samples(_apply_overrides(cfg, dict(overrides)), n_runs) * len(indices)
    if held > MAX_SAMPLES:
        raise ConfigError(f"{len(indices)} units × {n_runs} runs of preset '{cfg.name}' are "
                          f"{held:,} samples, above the limit of {MAX_SAMPLES:,} per simulation "
                          "(bounded so that a request cannot exhaust memory; simulate fewer "
                          "units, or let `thermonet fleet --units` simulate one unit per worker)")
    odd = outlier_config(cfg) if outliers else cfg
    recs = []
    for k in indices:
        is_outlier = k >= units - outliers
        ds = simulate(odd if is_outlier else cfg, runs=runs, seed=unit_seed(seed, k), **overrides)
        dev = unit_device_id(cfg.name, k, units)
        for r in ds.runs:
            r.device_id = dev
            r.meta.update(unit_index=str(k), fleet_seed=str(seed),
                          outlier="1" if is_outlier else "0",
                          source=f"simulated {cfg.name} {dev} {r.run_id}")
        recs += ds.runs
    return Dataset(runs=recs, meta={"preset": cfg.name, "seed": str(seed), "source": "simulator",
                                    "units": str(units), "outliers": str(outliers)})
