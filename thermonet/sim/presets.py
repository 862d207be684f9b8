"""Simulation configuration, the run generator and the four study presets.

Sample rates (kept moderate so that comparing every model family over a
whole preset stays well under a minute on two cores):

========== ======= ==========================================================
preset     rate    why
========== ======= ==========================================================
accel      0.2 Hz  2 h per temperature point (1 h soak + 4 × 15 min positions)
hrg        0.1 Hz  4 h soaks and a 15 h validation soak; slow thermal physics
mems-gyro  1 Hz    1 h soaks; Allan deviation needs τ down to seconds
patent-gyro 1 Hz   the patent's thermometer reads at 1 Hz
consumer-imu 1 Hz  a 4.6 h climate cycle; 1 °C/min ramps need no more
accel-ramp 2 Hz    noise-dominated on purpose: 14,400 samples per run
========== ======= ==========================================================
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from ..core.errors import ConfigError
from ..core.recording import Dataset, Recording
from .chamber import Approach, ChamberProfile, Ramp, Soak, staircase
from .device import (
    AxisConfig,
    HysteresisConfig,
    LawSum,
    Lorentz,
    NoiseConfig,
    Polynomial,
    ProxyConfig,
    RateTermConfig,
    SelfHeatingConfig,
    Sinusoid,
    ThermalConfig,
    ThermometerConfig,
    UnitSpreadConfig,
    first_order_lag,
    play_operator,
    quantise,
    sensor_noise,
)

__all__ = ["TableConfig", "Switches", "SimConfig", "RunTruth", "PRESETS", "get_preset",
           "simulate", "simulate_run"]


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


def _apply_overrides(cfg: SimConfig, overrides: dict[str, Any]) -> SimConfig:
    """Top-level fields (``sample_rate_hz=0.5``), switches (``hysteresis=False``) and
    nested fields as ``section__field`` (``thermal__die_lag_s=60``)."""
    top = {f.name for f in dataclasses.fields(SimConfig)}
    sw_names = {f.name for f in dataclasses.fields(Switches)}
    sw_changes: dict[str, Any] = {}
    for key, value in overrides.items():
        if key in sw_names:
            if not isinstance(value, bool):
                raise ConfigError(f"switch '{key}' must be true or false, got {value!r}")
            sw_changes[key] = value
        elif key in top:
            cfg = dataclasses.replace(cfg, **{key: value})
        elif "__" in key and key.split("__", 1)[0] in top:
            section, sub = key.split("__", 1)
            part: Any = getattr(cfg, section)
            if part is None or not dataclasses.is_dataclass(part) or \
                    sub not in {f.name for f in dataclasses.fields(part)}:
                raise ConfigError(f"unknown simulation setting '{key}'")
            new_part: Any = dataclasses.replace(cast(Any, part), **{sub: value})
            cfg = dataclasses.replace(cfg, **{section: new_part})
        else:
            raise ConfigError(f"unknown simulation setting '{key}' (valid: "
                              f"{', '.join(sorted(top | sw_names))}, or section__field)")
    if sw_changes:
        cfg = dataclasses.replace(cfg, switches=dataclasses.replace(cfg.switches, **sw_changes))
    return cfg


def get_preset(name: str) -> SimConfig:
    """The preset called ``name``; an unknown name raises ``ValueError`` listing the valid ones."""
    key = str(name).lower()
    if key not in PRESETS:
        raise ConfigError(f"unknown preset '{name}' (valid: {', '.join(sorted(PRESETS))})")
    return PRESETS[key]


#: Bounds of one simulation request: what it may allocate is known before it starts, so an
#: absurd request (100,000 runs) is refused at once with the reason, not after a minute of
#: swapping.  50 M samples × (time, temperature, outputs, truth) is a few GB at most.
MAX_RUNS = 1000
MAX_SAMPLES = 50_000_000


def request_samples(cfg: SimConfig, n_runs: int) -> int:
    """Samples that ``n_runs`` runs of ``cfg`` hold (0 when the rate or procedures are invalid:
    :func:`simulate_run` says why), computed before anything is allocated."""
    fs = float(cfg.sample_rate_hz)
    if not fs > 0 or not math.isfinite(fs) or not cfg.procedures:
        return 0
    per = [int(np.floor(p.duration_s * fs)) + 1 for p in cfg.procedures]
    full, rest = divmod(int(n_runs), len(per))
    return full * sum(per) + sum(per[:rest])


def _check_request_size(cfg: SimConfig, n_runs: int) -> None:
    if n_runs > MAX_RUNS:
        raise ConfigError(f"runs={n_runs} is above the limit of {MAX_RUNS} runs per simulation "
                          "(bounded so that a request cannot exhaust memory)")
    total = request_samples(cfg, n_runs)
    if total > MAX_SAMPLES:
        raise ConfigError(f"{n_runs} runs of preset '{cfg.name}' are {total:,} samples, above the "
                          f"limit of {MAX_SAMPLES:,} per simulation (bounded so that a request "
                          "cannot exhaust memory)")


def simulate(preset: str | SimConfig, *, runs: int | None = None, seed: int = 0,
             **overrides: object) -> Dataset:
    """Simulate a device's thermal test as a :class:`~thermonet.core.recording.Dataset`.

    Parameters
    ----------
    preset : str or SimConfig
        A name from :data:`PRESETS` or a full configuration.
    runs : int, optional
        Number of runs (``run0`` …); default: the preset's ``default_runs``.
    seed : int
        Same seed → bit-identical data; run *i* draws from ``(seed, i)``.
    **overrides
        Switches (``hysteresis=False``), top-level fields, or ``section__field``.
    """
    cfg = get_preset(preset) if isinstance(preset, str) else preset
    cfg = _apply_overrides(cfg, overrides)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
    n_runs = cfg.default_runs if runs is None else int(runs)
    if n_runs < 1:
        raise ConfigError(f"runs must be at least 1, got {runs!r}")
    _check_request_size(cfg, n_runs)
    recs = [simulate_run(cfg, i, seed)[0] for i in range(n_runs)]
    return Dataset(runs=recs, meta={"preset": cfg.name, "seed": str(seed), "source": "simulator"})


# ================================================================== presets
_ACCEL_LEVELS = tuple(float(v) for v in range(-20, 61, 10))

ACCEL = SimConfig(
    name="accel", sensor_kind="acc", sample_rate_hz=0.2, default_runs=3,
    procedures=(ChamberProfile(name="staircase -20..60 C", start_c=-20.0,
                               segments=staircase(_ACCEL_LEVELS, soak_h=2.0,
                                                  ramp_rate_c_per_h=10.0, four_position=True)),),
    axes=(AxisConfig(
        name="acc_x", unit="g",
        # tuned on the nine soak temperatures: per-soak pp 14.2 mg, linear-fit
        # residual pp 6.8 mg, best-Lorentz residual pp 1.30 mg, linear slope
        # −0.149 mg/°C (paper −0.153); the sinusoid is the non-Lorentz part
        bias=LawSum(parts=(Lorentz(y0=-0.385e-3, area=-0.8409834, center_c=64.3856,
                                   width_c=33.9582),
                           Sinusoid(amplitude=-0.59625e-3, period_c=40.0, phase_c=-20.0))),
        # ΔK 151.6 ppm/°C raw, 45.4 after linear, 11.9 after Lorentz (9 soaks)
        scale_factor_ppm=LawSum(parts=(Lorentz(y0=-15400.0, area=1819200.08, center_c=50.1141,
                                               width_c=75.1951),
                                       Sinusoid(amplitude=463.951, period_c=30.0,
                                                phase_c=-20.0))),
        noise=NoiseConfig(white_density=1e-4, bias_instability=2e-5, rate_random_walk=0.0)),),
    thermal=ThermalConfig(die_lag_s=120.0, case_lag_s=300.0),
    thermometer=ThermometerConfig(lag_s=60.0, resolution_c=0.01, noise_c=0.0),
    table=TableConfig(program="four_position", positions=(1.0, 0.0, -1.0, 0.0), dwell_s=900.0),
    unit_spread=UnitSpreadConfig(bias_gain_rel=0.02, bias_offset=0.5e-3, scale_gain_rel=0.02,
                                 temperature_shift_c=0.3),
)

_HRG_CAL = ChamberProfile(name="calibration soaks -10/5/25/45/60 C", start_c=-10.0,
                          segments=staircase((-10.0, 5.0, 25.0, 45.0, 60.0), soak_h=4.0,
                                             ramp_rate_c_per_h=10.0))
_HRG_VAL = ChamberProfile(name="validation -10 / room 15 h / 60 C", start_c=-10.0, segments=(
    Soak(temperature_c=-10.0, duration_h=4.0), Ramp(to_c=25.0, rate_c_per_h=10.0),
    Soak(temperature_c=25.0, duration_h=15.0), Ramp(to_c=60.0, rate_c_per_h=10.0),
    Soak(temperature_c=60.0, duration_h=4.0)))

HRG = SimConfig(
    name="hrg", sensor_kind="gyro", sample_rate_hz=0.1, default_runs=2,
    procedures=(_HRG_CAL, _HRG_VAL),
    axes=(AxisConfig(
        name="gyro_x", unit="deg/h",
        # quadratic in Δf = 0.4 Hz/°C·(T − 25) plus a small cubic remainder: pp 30 °/h
        # over the soaks −10…60 °C, quadratic-fit residual pp 2.8 °/h (the paper's result)
        bias=Polynomial(coefficients=(0.0, 0.0892641, 0.018, 1.12554e-4), reference_c=25.0),
        noise=NoiseConfig(white_density=1.2, bias_instability=0.05, rate_random_walk=0.0)),),
    # the resonator follows the chamber faster than the case thermometer does
    thermal=ThermalConfig(die_lag_s=300.0, case_lag_s=1200.0),
    thermometer=ThermometerConfig(lag_s=300.0, resolution_c=0.0625, noise_c=0.0),
    proxy=ProxyConfig(name="freq_hz", unit="Hz", value_at_reference=4517.0, slope_per_c=0.4,
                      reference_c=25.0, resolution=0.03),
    unit_spread=UnitSpreadConfig(bias_gain_rel=0.02, bias_offset=0.5, temperature_shift_c=0.2),
)

_MEMS_SOAKS = ChamberProfile(name="soaks 25/45/50/55/65/70 C", start_c=25.0,
                             segments=staircase((25.0, 45.0, 50.0, 55.0, 65.0, 70.0), soak_h=1.0,
                                                ramp_rate_c_per_h=60.0))
_MEMS_SELF = ChamberProfile(name="self-heating closed box 25 -> 45 C", start_c=25.0,
                            segments=(Approach(target_c=45.4, tau_h=0.5, duration_h=2.0),))

MEMS_GYRO = SimConfig(
    name="mems-gyro", sensor_kind="gyro", sample_rate_hz=1.0, default_runs=2,
    procedures=(_MEMS_SOAKS, _MEMS_SELF),
    axes=(AxisConfig(
        name="gyro_x", unit="deg/s",
        # nonlinear, 0.025 °/s at 65 °C relative to 25 °C
        bias=Polynomial(coefficients=(0.0, 1.0e-4, 1.0e-5, 7.8125e-8), reference_c=25.0),
        # ARW 4.2 °/√h (ADIS16355 datasheet) = 0.07 °/s·√s; flicker floor
        # 0.664·B = 0.0072 °/s, so the Allan minimum over τ ≤ ~1000 s is ≈0.0075 °/s
        noise=NoiseConfig(white_density=0.07, bias_instability=0.0108, rate_random_walk=0.0)),),
    thermal=ThermalConfig(die_lag_s=60.0, case_lag_s=120.0),
    # ADIS16355 temperature output: 0.136 °C per LSB
    thermometer=ThermometerConfig(lag_s=30.0, resolution_c=0.136),
    unit_spread=UnitSpreadConfig(bias_gain_rel=0.03, bias_offset=0.002, temperature_shift_c=0.5),
)

_PATENT = ChamberProfile(name="-20 C stable, 18 C/h to 50 C, hold 1 h", start_c=-20.0, segments=(
    Soak(temperature_c=-20.0, duration_h=1.0), Ramp(to_c=50.0, rate_c_per_h=18.0),
    Soak(temperature_c=50.0, duration_h=1.0)))


def _patent_axis(name: str, c: tuple[float, float, float]) -> AxisConfig:
    return AxisConfig(
        name=name, unit="deg/s", bias_reference_c=None,
        bias=Polynomial(coefficients=c, reference_c=-20.0),  # E = c0 + c1 ΔT + c2 ΔT²
        scale_factor_ppm=Polynomial(coefficients=(0.0, 0.3), reference_c=-20.0),
        rate_term=RateTermConfig(coefficient_per_c_per_h=2e-4),
        # I3G4250D-like noise density 0.01 °/s/√Hz → σ 0.01 °/s per 1 Hz sample
        noise=NoiseConfig(white_density=0.01, bias_instability=0.001, rate_random_walk=0.0))


PATENT_GYRO = SimConfig(
    name="patent-gyro", sensor_kind="gyro", sample_rate_hz=1.0, default_runs=5,
    procedures=(_PATENT,),
    # scaled so that the drift RMS over a run is ≈100× the white σ (msd ratio ≈1e4)
    axes=(_patent_axis("gyro_x", (0.30, 0.0260, -1.2e-4)),
          _patent_axis("gyro_y", (-0.20, -0.0190, -2.5e-4)),
          _patent_axis("gyro_z", (0.10, 0.0300, -0.8e-4))),
    thermal=ThermalConfig(die_lag_s=300.0, case_lag_s=200.0),
    # case-mounted precision thermometer, ±0.01 °C at 1 Hz
    thermometer=ThermometerConfig(lag_s=30.0, resolution_c=0.01, noise_c=0.003,
                                  offset_spread_c=0.01),
    table=TableConfig(program="constant_rate", rate_min=10.0, rate_max=100.0),
    unit_spread=UnitSpreadConfig(bias_gain_rel=0.01, bias_offset=0.005, temperature_shift_c=0.2),
)

# ------------------------------------------------ realistic presets (no study to reproduce)
# A climate chamber (not a precision thermal test): 50 → −20 → 75 → 35 °C at 1 °C/min,
# 30 min holds at the turning points.  The final cooling branch starts from a hotter
# excursion (75 °C) than the first one (50 °C): a bias with thermal history differs there.
_CLIMATE_CYCLE = ChamberProfile(name="climate cycle 50 -> -20 -> 75 -> 35 C at 1 C/min",
                                start_c=50.0, segments=(
    Soak(temperature_c=50.0, duration_h=0.5), Ramp(to_c=-20.0, rate_c_per_h=60.0),
    Soak(temperature_c=-20.0, duration_h=0.5), Ramp(to_c=75.0, rate_c_per_h=60.0),
    Soak(temperature_c=75.0, duration_h=0.5), Ramp(to_c=35.0, rate_c_per_h=60.0),
    Soak(temperature_c=35.0, duration_h=0.5)))

_G = 9.80665  # m/s² per g


def _consumer_gyro(name: str, c1: float, c2: float, hysteresis: float,
                   width_c: float = 8.0) -> AxisConfig:
    # BMI270/ICM-42688-class: 0.003–0.004 °/s/K offset tempco, 0.007 °/s/√Hz noise density
    return AxisConfig(
        name=name, unit="deg/s", bias_reference_c=25.0,
        bias=Polynomial(coefficients=(0.0, c1, c2), reference_c=25.0),
        hysteresis=HysteresisConfig(amplitude=hysteresis, width_c=width_c),
        noise=NoiseConfig(white_density=0.007, bias_instability=0.002, rate_random_walk=0.0))


def _consumer_acc(name: str, level: float, c1: float, c2: float,
                  hysteresis: float) -> AxisConfig:
    # 0.15–0.35 mg/K offset tempco with curvature, 160 µg/√Hz noise density (in m/s²);
    # ``level`` is the static input: gravity on z, a small tilt on x and y (no reference channel)
    return AxisConfig(
        name=name, unit="m/s^2", bias_reference_c=25.0, reference_level=level,
        bias=Polynomial(coefficients=(0.0, c1 * 1e-3 * _G, c2 * 1e-3 * _G), reference_c=25.0),
        hysteresis=HysteresisConfig(amplitude=hysteresis * 1e-3 * _G, width_c=8.0),
        noise=NoiseConfig(white_density=160e-6 * _G, bias_instability=40e-6 * _G,
                          rate_random_walk=0.0))


CONSUMER_IMU = SimConfig(
    name="consumer-imu", sensor_kind="imu", sample_rate_hz=1.0, default_runs=2,
    procedures=(_CLIMATE_CYCLE,),
    # gyro_x: a bias that depends on thermal history — a wide hysteresis (40 °C) against
    # its static tempco: on the last cooling branch (after 75 °C) the two nearly cancel, so
    # a temperature-only model does worse than the raw output there (as on real units)
    axes=(_consumer_gyro("gyro_x", 0.0015, 1e-5, -0.03, width_c=40.0),
          _consumer_gyro("gyro_y", -0.003, 4e-5, 0.015),
          # essentially no drift: only noise and the turn-on bias (do-no-harm must fire)
          _consumer_gyro("gyro_z", 0.0, 0.0, 0.0),
          _consumer_acc("acc_x", 0.12, 0.25, 2e-3, 0.3),    # tilt ≈ 0.7°
          _consumer_acc("acc_y", -0.08, -0.15, 1.5e-3, 0.2),
          _consumer_acc("acc_z", -_G, 0.35, -2.5e-3, 0.4)),  # level: z reads −1 g
    thermal=ThermalConfig(die_lag_s=60.0, case_lag_s=90.0),
    # on-die thermometer: 1/512 °C steps, a little noise, lags the die slightly
    thermometer=ThermometerConfig(lag_s=20.0, resolution_c=1.0 / 512.0, noise_c=0.02),
    # per power-up offset (turn-on bias) 0.05 °/s or 0.05 m/s² (5 mg): draw per run
    unit_spread=UnitSpreadConfig(bias_gain_rel=0.05, bias_offset=0.05,
                                 temperature_shift_c=0.5),
)

_ACCEL_RAMP = ChamberProfile(name="slow ramp 15 -> 45 C at 15 C/h", start_c=15.0, segments=(
    Soak(temperature_c=15.0, duration_h=0.25), Ramp(to_c=45.0, rate_c_per_h=15.0),
    Soak(temperature_c=45.0, duration_h=0.25)))

ACCEL_RAMP = SimConfig(
    name="accel-ramp", sensor_kind="acc", sample_rate_hz=2.0, default_runs=1,
    procedures=(_ACCEL_RAMP,),
    # a static inclinometer axis at +1 g: 4 mg of drift over 30 °C under 20 mg of
    # per-sample noise (white density 14 mg·√s at 2 Hz) — only binned means show it
    axes=(AxisConfig(name="acc_x", unit="g", bias_reference_c=30.0, reference_level=1.0,
                     bias=Polynomial(coefficients=(0.0, 1.2e-4, 1.0e-6), reference_c=30.0),
                     noise=NoiseConfig(white_density=0.0141, bias_instability=1e-4,
                                       rate_random_walk=0.0)),),
    thermal=ThermalConfig(die_lag_s=120.0, case_lag_s=180.0),
    thermometer=ThermometerConfig(lag_s=30.0, resolution_c=0.0625, noise_c=0.0),
    unit_spread=UnitSpreadConfig(bias_offset=0.5e-3),
)

# ------------------------------------------- the new-excursion stress bench (issue: next warm-up)
# What interleaved cross-validation cannot see: the sensing element lags the thermometer by
# minutes (die 420 s behind the chamber, the thermometer's case 60 s), so the bias read against
# the thermometer depends on the direction and rate of change, and the runs alternate a fast
# and a slow cycle.  A model trained on one rate (or one direction) meets another on the test.
def _cycle(rate_c_per_h: float) -> ChamberProfile:
    return ChamberProfile(
        name=f"cycle 25 -> -10 -> 60 -> 25 C at {rate_c_per_h / 60:g} C/min", start_c=25.0,
        segments=(Soak(temperature_c=25.0, duration_h=1 / 3),
                  Ramp(to_c=-10.0, rate_c_per_h=rate_c_per_h),
                  Soak(temperature_c=-10.0, duration_h=1 / 3),
                  Ramp(to_c=60.0, rate_c_per_h=rate_c_per_h),
                  Soak(temperature_c=60.0, duration_h=1 / 3),
                  Ramp(to_c=25.0, rate_c_per_h=rate_c_per_h),
                  Soak(temperature_c=25.0, duration_h=1 / 3)))


STRESS_IMU = SimConfig(
    name="stress-imu", sensor_kind="imu", sample_rate_hz=1.0, default_runs=3,
    procedures=(_cycle(90.0), _cycle(30.0)),          # fast (1.5 °C/min), slow (0.5 °C/min)
    axes=(_consumer_gyro("gyro_x", 0.004, 2e-5, 0.01, width_c=6.0),
          _consumer_gyro("gyro_y", -0.003, 4e-5, 0.0),
          _consumer_gyro("gyro_z", 0.0008, 0.0, 0.0),
          _consumer_acc("acc_x", 0.12, 0.25, 2e-3, 0.0),
          _consumer_acc("acc_y", -0.08, -0.35, 1.5e-3, 0.3),
          _consumer_acc("acc_z", -_G, 0.35, -2.5e-3, 0.0)),
    thermal=ThermalConfig(die_lag_s=420.0, case_lag_s=60.0),
    thermometer=ThermometerConfig(lag_s=20.0, resolution_c=1.0 / 512.0, noise_c=0.02),
    unit_spread=UnitSpreadConfig(bias_gain_rel=0.05, bias_offset=0.05,
                                 temperature_shift_c=0.5),
)

#: name → preset; docstrings of the study numbers are in :mod:`thermonet.sim`.
PRESETS: dict[str, SimConfig] = {
    "accel": ACCEL, "hrg": HRG, "mems-gyro": MEMS_GYRO, "patent-gyro": PATENT_GYRO,
    "consumer-imu": CONSUMER_IMU, "accel-ramp": ACCEL_RAMP, "stress-imu": STRESS_IMU,
}
