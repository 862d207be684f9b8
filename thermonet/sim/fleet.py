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

**Structured fleets** (``clusters=K`` ≥ 1, for the fleet prior, :mod:`thermonet.scoring.prior`):
every axis's polynomial bias law gets a cubic term and the fleet falls into K clusters —
cluster *c* (unit *k* is in cluster ``k mod K``) multiplies each temperature coefficient
c₁, c₂ by ``1 + CLUSTER_REL · z`` and sets c₃ = ``CUBIC_REL · c₂ · z`` (°C⁻¹) with z drawn
from ``SeedSequence([seed, c, 7])`` — and every unit scatters each coefficient by a further
``UNIT_COEF_REL · z`` (its own draw) on top of the preset's gain and temperature shift,
which move the coefficients together (correlated).  Presets whose bias laws are not
polynomials are refused.  A short production test (:func:`short_test`, ``--test``)
replaces the preset's chamber programme: ``soaks:T1,T2,…`` (20-min soaks, the chamber
jumping between them), ``ramp:FROM,TO,MINUTES`` or ``cycle:FROM,TO,MINUTES`` (up and back).

Device ids are ``<preset>-u000``, ``<preset>-u001`` … (three digits at least).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.errors import ConfigError
from ..core.recording import Dataset
from .chamber import ChamberProfile, Ramp, Soak
from .device import AnyLaw, LawSum, Lorentz, Polynomial, Sinusoid
from .generator import SimConfig
from .presets import (
    MAX_RUNS,
    MAX_SAMPLES,
    _apply_overrides,
    get_preset,
    request_samples,
    simulate,
)

__all__ = ["simulate_fleet", "unit_seed", "short_test", "structured_config", "CLUSTER_REL",
           "UNIT_COEF_REL", "CUBIC_REL", "SOAK_MIN", "unit_device_id", "outlier_config",
           "OUTLIER_SIGMAS", "MIN_GAIN_SIGMA", "MAX_UNITS"]

#: Most units one fleet may have (a production line's week; the fleet's tables and the
#: per-unit bookkeeping grow with it).  Checked before anything is simulated or listed.
MAX_UNITS = 10_000

#: How far an outlier unit's drift law is off the fleet's, in unit-to-unit standard deviations.
OUTLIER_SIGMAS = 10.0
#: The relative gain spread used for outliers when a preset has none (1 %).
MIN_GAIN_SIGMA = 0.01

#: Structured fleets: relative spread of a cluster's coefficients, of a unit's, and the
#: cubic term per cluster (c₃ = CUBIC_REL · c₂ · z, °C⁻¹).
CLUSTER_REL = 0.3
UNIT_COEF_REL = 0.05
CUBIC_REL = 0.01
#: Minutes of each soak of a ``soaks:`` short test.
SOAK_MIN = 20.0
#: The fastest chamber ramp a ``ramp:`` or ``cycle:`` test may ask for (°C/min): rapid-rate
#: chambers reach 15–30 °C/min; beyond that a test is a thermal shock (the part is moved, not
#: the air ramped), which the chamber model does not simulate.
MAX_CHAMBER_RATE_C_PER_MIN = 60.0
#: The clusters' draw (fixed: a sensor type's clusters do not change with the fleet seed).
CLUSTER_SEED = 2018


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


def _poly_axes(cfg: SimConfig, z: np.ndarray, rel: float, cubic: float) -> SimConfig:
    """``cfg`` with axis *j*'s polynomial bias coefficients scaled by ``1 + rel·z[j, k]``."""
    axes = []
    for j, ax in enumerate(cfg.axes):
        if not isinstance(ax.bias, Polynomial):
            raise ConfigError(f"preset '{cfg.name}': axis {ax.name}'s bias law is not a "
                              "polynomial; structured fleets (--clusters) need one")
        c = list(ax.bias.coefficients) + [0.0] * max(0, 4 - len(ax.bias.coefficients))
        c[1] *= 1.0 + rel * z[j, 0]
        c[2] *= 1.0 + rel * z[j, 1]
        c[3] = c[3] * (1.0 + rel * z[j, 2]) + cubic * c[2] * z[j, 2]
        axes.append(dataclasses.replace(ax, bias=dataclasses.replace(ax.bias,
                                                                     coefficients=tuple(c))))
    return dataclasses.replace(cfg, axes=tuple(axes))


def structured_config(cfg: SimConfig, seed: int, unit: int, clusters: int) -> SimConfig:
    """Unit ``unit``'s drift laws in a fleet of ``clusters`` clusters (module docstring)."""
    n = len(cfg.axes)
    # the clusters are the sensor type's (its production lines), not the draw's: the same
    # for every fleet seed, so units simulated with another seed are of the same population
    zc = np.random.default_rng(np.random.SeedSequence([CLUSTER_SEED, unit % clusters, 7])
                               ).standard_normal((n, 3))
    zu = np.random.default_rng(np.random.SeedSequence([seed, unit, 11])).standard_normal((n, 3))
    return _poly_axes(_poly_axes(cfg, zc, CLUSTER_REL, CUBIC_REL), zu, UNIT_COEF_REL, 0.0)


def short_test(spec: str) -> ChamberProfile:
    """A short production test: ``soaks:T1,T2,…`` (°C), ``ramp:FROM,TO,MINUTES`` (a 2-min
    soak at FROM, then one ramp) or ``cycle:FROM,TO,MINUTES`` (a 2-min soak at FROM, then
    up to TO and back to FROM at one rate, MINUTES for both ways: its fast samples pair,
    :func:`~thermonet.scoring.prior_points.bin_points`)."""
    kind, _, rest = str(spec).partition(":")
    try:
        vals = [float(v) for v in rest.split(",")] if rest else []
    except ValueError:
        vals = []
    again = [b for a, b in zip(vals, vals[1:], strict=False) if a == b]
    if kind == "soaks" and again:
        raise ConfigError(f"--test {spec!r}: {again[0]:g} °C twice in a row is one longer soak, "
                          "not two points; give each soak once (a return to a temperature "
                          "after another is a second point)")
    if kind == "soaks" and 1 <= len(vals) <= 20 and all(-60 <= v <= 150 for v in vals):
        return ChamberProfile(name=f"short test: soaks {rest} C", start_c=vals[0], segments=tuple(
            Soak(temperature_c=v, duration_h=SOAK_MIN / 60.0) for v in vals))
    if kind in ("ramp", "cycle") and len(vals) == 3 and vals[2] > 0 and vals[0] != vals[1] \
            and all(-60 <= v <= 150 for v in vals[:2]) and vals[2] <= 24 * 60:
        a, b, minutes = vals
        legs = 1 if kind == "ramp" else 2
        rate = abs(b - a) * legs / minutes * 60.0
        if rate > MAX_CHAMBER_RATE_C_PER_MIN * 60.0:
            raise ConfigError(f"--test {spec!r}: the chamber would ramp at {rate / 60.0:.3g} "
                              f"°C/min, above {MAX_CHAMBER_RATE_C_PER_MIN:g} °C/min (a thermal "
                              f"shock, not a ramp): give at least "
                              f"{abs(b - a) * legs / MAX_CHAMBER_RATE_C_PER_MIN:.3g} minutes")
        ramps = (Ramp(to_c=b, rate_c_per_h=rate),) + ((Ramp(to_c=a, rate_c_per_h=rate),)
                                                       if legs == 2 else ())
        what = f"{a:g} -> {b:g}" + (f" -> {a:g}" if legs == 2 else "")
        return ChamberProfile(name=f"short test: {kind} {what} C in {minutes:g} min",
                              start_c=a, segments=(Soak(temperature_c=a, duration_h=2.0 / 60.0),)
                              + ramps)
    raise ConfigError(f"--test {spec!r}: expected soaks:T1,T2,... (°C, -60..150), "
                      "ramp:FROM,TO,MINUTES or cycle:FROM,TO,MINUTES (FROM != TO, -60..150 °C; "
                      "0 < MINUTES <= 1440)")


def simulate_fleet(preset: str | SimConfig, *, units: int, runs: int | None = None,
                   seed: int = 0, outliers: int = 0, unit_indices: list[int] | None = None,
                   clusters: int = 0, test: str | None = None,
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
    clusters : int
        ≥ 1: a structured fleet of that many clusters (module docstring); 0: the preset's
        unit spread alone.
    test : str, optional
        A short production test (:func:`short_test`) instead of the preset's programme.
    **overrides
        As :func:`~thermonet.sim.simulate`.
    """
    cfg = get_preset(preset) if isinstance(preset, str) else preset
    if test is not None:
        cfg = dataclasses.replace(cfg, procedures=(short_test(test),), default_runs=1)
    for name, value in (("units", units), ("outliers", outliers), ("clusters", clusters)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ConfigError(f"--{name} must be an integer, got {value!r}")
    if units < 1:
        raise ConfigError(f"--units must be at least 1, got {units}")
    if units > MAX_UNITS:
        raise ConfigError(f"units={units} is above the limit of {MAX_UNITS:,} units per fleet "
                          "(bounded so that a request cannot exhaust memory)")
    if not 0 <= clusters <= units:
        raise ConfigError(f"--clusters must be between 0 and units (--units {units}), got "
                          f"{clusters}")
    if not 0 <= outliers <= units:
        raise ConfigError(f"--outliers must be between 0 and units (--units {units}), got "
                          f"{outliers}")
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
    recs = []
    for k in indices:
        is_outlier = k >= units - outliers
        ucfg = structured_config(cfg, seed, k, clusters) if clusters else cfg
        ucfg = outlier_config(ucfg) if is_outlier else ucfg
        ds = simulate(ucfg, runs=runs, seed=unit_seed(seed, k), **overrides)
        dev = unit_device_id(cfg.name, k, units)
        for r in ds.runs:
            r.device_id = dev
            r.meta.update(unit_index=str(k), fleet_seed=str(seed),
                          outlier="1" if is_outlier else "0",
                          cluster=str(k % clusters) if clusters else "",
                          source=f"simulated {cfg.name} {dev} {r.run_id}")
        recs += ds.runs
    return Dataset(runs=recs, meta={"preset": cfg.name, "seed": str(seed), "source": "simulator",
                                    "units": str(units), "outliers": str(outliers)})
