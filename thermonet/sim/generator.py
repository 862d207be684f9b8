"""What one simulated device and its test procedure are (:class:`SimConfig`: the chamber
programmes, the axes' drift laws, the thermal path and thermometer, the test table's
programme, every physical part's :class:`Switches`) and the generator of one run from it
(:func:`simulate_run`: the chamber, die, case and thermometer temperatures, each axis's drift,
reference and noise, with the hidden states in :class:`RunTruth`).  The presets and
:func:`~thermonet.sim.presets.simulate` are :mod:`thermonet.sim.presets`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.recording import Recording
from .chamber import ChamberProfile, Soak
from .device import (
    AxisConfig,
    ProxyConfig,
    SelfHeatingConfig,
    ThermalConfig,
    ThermometerConfig,
    UnitSpreadConfig,
    first_order_lag,
    play_operator,
    quantise,
    sensor_noise,
)

__all__ = ["TableConfig", "Switches", "SimConfig", "RunTruth", "simulate_run"]


@dataclass(frozen=True, kw_only=True)
class TableConfig:
    """The test table's programme, i.e. the reference input of every axis.

    ``static``: each axis at its ``reference_level``; ``four_position``: the
    levels in ``positions`` for ``dwell_s`` each at the end of every soak marked
    ``four_position`` (gravity projection, study 000); ``multi_position``: the
    same with ``poses``, one reference value per axis (in ``axes`` order) for each
    pose: the six faces of a 6-axis IMU and turntable rates (``imu-multiposition``);
    ``constant_rate``: one
    random rate per run and axis, magnitude uniform in [rate_min, rate_max],
    random sign (turntable, study 003).
    """

    program: str = "static"  # 'static' | 'four_position' | 'multi_position' | 'constant_rate'
    positions: tuple[float, ...] = (1.0, 0.0, -1.0, 0.0)  # output unit (g)
    poses: tuple[tuple[float, ...], ...] = ()  # multi_position: per pose, one value per axis
    dwell_s: float = 900.0  # s per position
    rate_min: float = 10.0  # output unit (°/s)
    rate_max: float = 100.0  # output unit (°/s)


@dataclass(frozen=True, kw_only=True)
class Switches:
    """Every physical part can be switched off (``simulate(..., hysteresis=False)``)."""

    thermal_lag: bool = True
    thermometer_lag: bool = True
    thermometer_quantisation: bool = True
    thermometer_noise: bool = True
    proxy_quantisation: bool = True
    self_heating: bool = True
    scale_factor: bool = True
    misalignment: bool = True
    hysteresis: bool = True
    rate_term: bool = True
    white_noise: bool = True
    flicker_noise: bool = True
    random_walk_noise: bool = True
    unit_spread: bool = True


@dataclass(frozen=True, kw_only=True)
class SimConfig:
    """Everything one simulated device and its test procedure need.

    ``procedures`` are chamber programmes; run *i* follows procedure
    ``i % len(procedures)``.  All runs of one :func:`simulate` call are the same
    unit (unit spread is drawn once per seed); each run has its own turn-on
    bias offset (``unit_spread.bias_offset``, run-to-run repeatability).
    """

    name: str = "custom"
    sensor_kind: str = "gyro"
    sample_rate_hz: float = 1.0  # Hz
    procedures: tuple[ChamberProfile, ...] = ()
    default_runs: int = 1
    axes: tuple[AxisConfig, ...] = (AxisConfig(),)
    thermal: ThermalConfig = ThermalConfig()
    thermometer: ThermometerConfig = ThermometerConfig()
    proxy: ProxyConfig | None = None
    self_heating: SelfHeatingConfig = SelfHeatingConfig()
    table: TableConfig = TableConfig()
    unit_spread: UnitSpreadConfig = UnitSpreadConfig()
    switches: Switches = field(default_factory=Switches)


@dataclass
class RunTruth:
    """Hidden states of a simulated run (°C), for tests and plots."""

    chamber_c: np.ndarray
    die_c: np.ndarray
    case_c: np.ndarray
    thermometer_c: np.ndarray


def _reference(cfg: SimConfig, profile: ChamberProfile, t: np.ndarray, k_axis: int,
               rate: float) -> np.ndarray:
    axis = cfg.axes[k_axis]
    ref = np.full(t.shape, float(axis.reference_level))
    if cfg.table.program == "constant_rate":
        ref[:] = rate
    elif cfg.table.program in ("four_position", "multi_position"):
        if cfg.table.program == "four_position":
            seq = np.asarray(cfg.table.positions, dtype=np.float64)
        else:
            if not cfg.table.poses or any(len(p) != len(cfg.axes) for p in cfg.table.poses):
                raise ConfigError(f"table.poses: need at least one pose of {len(cfg.axes)} "
                                  "values (one per axis) for program 'multi_position'")
            seq = np.asarray([p[k_axis] for p in cfg.table.poses], dtype=np.float64)
        for _t0, t1, _, seg in profile.bounds():
            if isinstance(seg, Soak) and seg.four_position:
                start = t1 - seq.size * cfg.table.dwell_s
                m = (t >= start) & (t < t1)
                k = np.clip(((t[m] - start) // cfg.table.dwell_s).astype(int), 0, seq.size - 1)
                ref[m] = seq[k]
    elif cfg.table.program != "static":
        raise ConfigError(f"table.program '{cfg.table.program}' is unknown "
                          "(valid: static, four_position, multi_position, constant_rate)")
    return ref


def simulate_run(cfg: SimConfig, run_index: int, seed: int = 0) -> tuple[Recording, RunTruth]:
    """Simulate run ``run_index`` of ``cfg``; the generator is seeded by ``(seed, run_index)``.

    Every random draw happens whatever the switches say, so turning one part
    off leaves all other parts bit-identical.
    """
    if not cfg.procedures:
        raise ConfigError(f"preset '{cfg.name}': no procedures (chamber profiles) given")
    sw = cfg.switches
    fs = float(cfg.sample_rate_hz)
    if not fs > 0:
        raise ConfigError(f"sample_rate_hz must be positive, got {cfg.sample_rate_hz!r}")
    dt = 1.0 / fs
    profile = cfg.procedures[run_index % len(cfg.procedures)]
    n = int(np.floor(profile.duration_s * fs)) + 1
    t = np.arange(n) * dt
    rng = np.random.default_rng([int(seed), int(run_index)])

    us = cfg.unit_spread
    # The runs of one dataset are one device: its law gains and temperature shift are
    # drawn once per seed (another seed is another unit of the same type).  Each run
    # (each power-up) adds its own turn-on bias offset: run-to-run repeatability.
    spread = rng.standard_normal(4) * sw.unit_spread
    unit = np.random.default_rng([int(seed)]).standard_normal(4) * sw.unit_spread
    bias_gain = 1.0 + unit[0] * us.bias_gain_rel
    bias_offset = spread[1] * us.bias_offset
    scale_gain = 1.0 + unit[2] * us.scale_gain_rel
    t_shift = unit[3] * us.temperature_shift_c
    th = cfg.thermometer
    th_offset = rng.uniform(-1.0, 1.0) * th.offset_spread_c
    rates = rng.uniform(cfg.table.rate_min, cfg.table.rate_max, len(cfg.axes)) \
        * rng.choice([-1.0, 1.0], len(cfg.axes))

    chamber, die, case, reading = _temperatures(cfg, profile.temperature(t), t, th_offset, rng)

    proxies: dict[str, np.ndarray] = {}
    units: dict[str, str] = {"time_s": "s", "temperature_c": "degC"}
    proxy_noise = rng.standard_normal(n)
    if cfg.proxy is not None:
        p = cfg.proxy
        val = p.value_at_reference + p.slope_per_c * (die - p.reference_c) + proxy_noise * p.noise
        proxies[p.name] = quantise(val, p.resolution) if sw.proxy_quantisation else val
        units[p.name] = p.unit

    rate_c_per_h = np.gradient(die, dt) * 3600.0
    t_law = die - t_shift
    outputs, references, drift = {}, {}, {}
    refs = {ax.name: _reference(cfg, profile, t, k, float(rates[k]))
            for k, ax in enumerate(cfg.axes)}
    for ax in cfg.axes:
        ref = refs[ax.name]
        d = _axis_drift(ax, sw, t_law, die, rate_c_per_h, refs,
                        gains=(bias_gain, bias_offset, scale_gain))
        noise = sensor_noise(ax.noise, n, fs, rng, white=sw.white_noise,
                             flicker=sw.flicker_noise, random_walk=sw.random_walk_noise)
        outputs[ax.name] = ref + d + noise
        drift[f"drift_{ax.name}"] = d
        units[ax.name] = units[f"drift_{ax.name}"] = ax.unit
        if cfg.table.program != "static":
            references[f"ref_{ax.name}"] = ref
            units[f"ref_{ax.name}"] = ax.unit

    meta = {"preset": cfg.name, "seed": str(seed), "run_index": str(run_index),
            "procedure": profile.name, "source": f"simulated {cfg.name} run{run_index}",
            "unit_bias_gain": f"{bias_gain:.6g}", "unit_scale_gain": f"{scale_gain:.6g}",
            "unit_bias_offset": f"{bias_offset:.6g}", "unit_temperature_shift_c": f"{t_shift:.6g}"}
    if cfg.table.program == "constant_rate":
        meta["reference_rates"] = ",".join(f"{r:.6g}" for r in rates)
    rec = Recording(time_s=t, temperature_c=reading, outputs=outputs, references=references,
                    proxies=proxies, drift=drift, units=units, device_id=cfg.name,
                    sensor_kind=cfg.sensor_kind, run_id=f"run{run_index}",
                    sample_rate_hz=fs, meta=meta)
    return rec, RunTruth(chamber_c=chamber, die_c=die, case_c=case, thermometer_c=reading)


def _temperatures(cfg: SimConfig, chamber: np.ndarray, t: np.ndarray, th_offset: float,
                  rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """(chamber, die, case, thermometer reading) of one run: the lags, the self-heating,
    and the thermometer's lag, offset, noise (one draw, whatever the switches) and step."""
    sw, th = cfg.switches, cfg.thermometer
    dt = 1.0 / float(cfg.sample_rate_hz)   # as simulate_run's (checked positive there)
    lag = sw.thermal_lag
    die = first_order_lag(chamber, cfg.thermal.die_lag_s if lag else 0.0, dt)
    if sw.self_heating and cfg.self_heating.rise_c:
        die = die + cfg.self_heating.rise_c * (1.0 - np.exp(-t / cfg.self_heating.tau_s))
    case = first_order_lag(chamber, cfg.thermal.case_lag_s if lag else 0.0, dt)
    reading = first_order_lag(case, th.lag_s if sw.thermometer_lag else 0.0, dt) + th_offset
    reading = reading + rng.standard_normal(t.size) * th.noise_c * sw.thermometer_noise
    if sw.thermometer_quantisation:
        reading = quantise(reading, th.resolution_c)
    return chamber, die, case, reading


def _axis_drift(ax: Any, sw: Switches, t_law: np.ndarray, die: np.ndarray,
                rate_c_per_h: np.ndarray, refs: dict[str, np.ndarray], *,
                gains: tuple[float, float, float]) -> np.ndarray:
    """One axis's drift: the bias law (anchored, with the unit's gain and the run's offset),
    the scale factor on its reference, the cross-axis terms, hysteresis and the rate term
    (each where its switch is on).  ``gains``: (bias gain, bias offset, scale gain)."""
    bias_gain, bias_offset, scale_gain = gains
    ref = refs[ax.name]
    raw_bias = ax.bias(t_law)
    anchor_c = 25.0 if ax.bias_reference_c is None else ax.bias_reference_c
    anchor = float(ax.bias(np.array([anchor_c]))[0])
    keep = 0.0 if ax.bias_reference_c is not None else anchor
    d = keep + bias_gain * (raw_bias - anchor) + bias_offset
    if ax.scale_factor_ppm is not None and sw.scale_factor:
        d = d + scale_gain * ax.scale_factor_ppm(t_law) * 1e-6 * ref
    for other, law in ax.cross_axis_urad:
        if other not in refs:
            raise ConfigError(f"axis '{ax.name}': cross_axis_urad names no axis '{other}' "
                              f"(axes: {', '.join(refs)})")
        if sw.misalignment:
            d = d + law(t_law) * 1e-6 * refs[other]
    if sw.hysteresis and ax.hysteresis.amplitude:
        d = d + ax.hysteresis.amplitude * play_operator(die, ax.hysteresis.width_c)
    if sw.rate_term and ax.rate_term.coefficient_per_c_per_h:
        d = d + ax.rate_term.coefficient_per_c_per_h * rate_c_per_h
    return d
