"""Thermal-chamber simulator, the four study presets and two realistic ones.

``simulate(preset, runs=, seed=, **overrides) -> Dataset``; many units in one
dataset: ``simulate_fleet(preset, units=, runs=, seed=, outliers=)``
(:mod:`thermonet.sim.fleet`).  The runs of one
call are one device: its unit-to-unit spread is drawn once per seed, and each
run (power-up) adds its own turn-on bias offset.  Presets (study numbers each
reproduced within 10 %, checked in ``tests/test_presets.py``):

``accel`` (study 000)
    Single-axis accelerometer ``acc_x`` (g) at 0.2 Hz; −20…60 °C in 10 °C steps,
    10 °C/h ramps, each point 1 h soak + four-position test (+1, 0, −1, 0 g,
    15 min each, ``ref_acc_x``).  Per-soak bias pp 14 mg, linear-fit residual
    6.9 mg, Lorentz residual 1.3 mg; scale-factor coefficient 151.6 ppm/°C
    (→ ≈46 linear, ≈12 Lorentz).  3 runs by default.
``hrg`` (study 001)
    HRG ``gyro_x`` (°/h) at 0.1 Hz, proxy ``freq_hz`` = 4517 Hz + 0.4 Hz/°C of
    the resonator temperature, 0.03 Hz resolution; case thermometer lags.
    run0: soaks −10, 5, 25, 45, 60 °C × 4 h; run1: validation −10 / 25 °C 15 h /
    60 °C.  Bias 30 °/h pp over −10…60 °C, quadratic-in-Δf fit leaves 2.8 °/h.
``mems-gyro`` (study 002)
    ADIS16355-like ``gyro_x`` (°/s) at 1 Hz; run0 soaks 25/45/50/55/65/70 °C ×
    1 h, run1 closed-box self-heating 25 → 45 °C in 2 h; further runs alternate
    the two procedures.  Bias 0.025 °/s at 65 °C relative to 25 °C.  Allan bias
    stability = minimum of the overlapping Allan deviation over τ ≤ 1000 s ≈
    0.0075 °/s (ARW 4.2 °/√h, flicker floor 0.0072 °/s).
``patent-gyro`` (study 003)
    Three axes ``gyro_x/y/z`` (°/s) at 1 Hz; −20 °C stable 1 h, 18 °C/h to 50 °C,
    hold 1 h; turntable at a random constant rate per run and axis; drift
    c0 + c1 ΔT + c2 ΔT² (ΔT from −20 °C) + scale factor·rate; drift RMS ≈ 100×
    white σ, i.e. msd improves ≈1e4 with a perfect model; 5 runs.

Realistic presets (what real chamber data does; no study to reproduce):

``imu-multiposition`` (the full sensor model, :mod:`thermonet.sim.multiposition`)
    A 6-axis IMU (``gyro_x/y/z`` °/s, ``acc_x/y/z`` g) at 0.2 Hz; soaks −40…85 °C in
    12.5 °C steps, at each soak the six static faces (±1 g per axis) and turntable
    poses (±100 °/s about each axis); bias, scale factor (≈140 ppm/°C) and
    misalignment (1.5–3 mrad, 20–40 µrad/°C) polynomial in temperature; reference
    vectors in ``ref_*``; 4 runs, climbing and descending alternately.

``consumer-imu``
    A consumer 6-axis IMU (``gyro_x/y/z`` °/s, ``acc_x/y/z`` m/s²) at 1 Hz in a
    climate chamber: 50 → −20 → 75 → 35 °C at 1 °C/min, 30 min holds.  No
    reference channel: the unit sits level, ``acc_z`` reads −1 g, ``acc_x/y`` a
    small tilt (0.12 and −0.08 m/s²).  Offset tempcos 0.15–0.35 mg/K and
    0.0015–0.003 °/s/K with curvature, path-dependent hysteresis (play operator):
    on ``gyro_x`` 40 °C wide and opposed to its static tempco, so on the last
    cooling branch (after the 75 °C excursion) the two nearly cancel and a
    temperature-only model fitted on the rest of the cycle is *worse* than raw
    there (std 1.3× on seed 0), as the issue's real unit was; 8 °C wide on the
    other axes; a turn-on bias per run (σ 0.05 in the output unit); ``gyro_z``
    has no temperature drift at all.  Consumer
    noise (0.007 °/s/√Hz, 160 µg/√Hz); 2 runs.
``accel-ramp``
    A static inclinometer axis ``acc_x`` (g) at +1 g, 2 Hz, one slow ramp
    15 → 45 °C at 15 °C/h: 4 mg of drift under 20 mg of per-sample noise;
    1 run (split inside the run).
"""

from .chamber import Approach, ChamberProfile, Ramp, Soak, cycle, staircase
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
)
from .fleet import simulate_fleet, unit_seed
from .fourpos import four_position_estimates
from .generator import RunTruth, SimConfig, Switches, TableConfig, simulate_run
from .multiposition import IMU_MULTIPOSITION  # registers preset 'imu-multiposition'
from .presets import PRESETS, get_preset, simulate

__all__ = [
    "simulate", "simulate_run", "simulate_fleet", "unit_seed", "get_preset", "PRESETS",
    "SimConfig", "Switches", "TableConfig",
    "RunTruth", "ChamberProfile", "Soak", "Ramp", "Approach", "staircase", "cycle",
    "AxisConfig", "ThermalConfig", "ThermometerConfig", "ProxyConfig", "SelfHeatingConfig",
    "HysteresisConfig", "RateTermConfig", "NoiseConfig", "UnitSpreadConfig",
    "Polynomial", "Lorentz", "Sinusoid", "LawSum",
    "four_position_estimates", "IMU_MULTIPOSITION",
]
