"""Preset ``imu-multiposition``: a 6-axis IMU's full thermal calibration test.

A navigation-grade chamber test as IMU makers run it at the factory: soaks from −40 to
85 °C in 12.5 °C steps (11 levels, 40 °C/h ramps), 1.5 h each; in the last hour of every
soak the table runs twelve poses of 5 min each:

* the six faces, static: the accelerometer's reference is +1 g or −1 g along one axis
  (the known direction of gravity), the gyro's is zero (the Earth's rate is left out:
  15 °/h is below this preset's gyro noise per pose);
* six turntable poses: each axis in turn vertical (accelerometer +1 g on it) and the
  table turning at +100 °/s then −100 °/s about it.

The laws (die temperature T in °C, reference 25 °C) are polynomials, so the sensor model's
``poly`` family can recover them: per axis a bias (cubic), a scale factor of study 000's
magnitude (≈140 ppm/°C by study 000's ΔK definition, from about +1.1 % at −40 °C to
−0.65 % at 85 °C, with curvature) and two cross-axis sensitivities (misalignment) of
1.5–3 mrad drifting by 20–40 µrad/°C.  Noise is modest (white 45 µg and 0.0022 °/s per
sample at 0.2 Hz) so that what separates a full sensor model from a bias-only one is the
laws, not the noise.

Two procedures alternate: run0, run2 … climb from −40 °C, run1, run3 … descend from
85 °C; 4 runs by default (the ``runs`` split trains on two, validates on the third and
tests on the fourth).  The reference vectors are in ``ref_*`` columns.

This module registers the preset in :data:`thermonet.sim.presets.PRESETS` when imported
(:mod:`thermonet.sim` imports it); ``presets.py`` itself is at its size limit.
"""

from __future__ import annotations

from .chamber import ChamberProfile, staircase
from .device import (
    AxisConfig,
    NoiseConfig,
    Polynomial,
    ThermalConfig,
    ThermometerConfig,
    UnitSpreadConfig,
)
from .generator import SimConfig, TableConfig
from .presets import PRESETS

__all__ = ["IMU_MULTIPOSITION", "POSES", "RATE_DEG_S"]

#: Turntable rate of the gyro poses, °/s.
RATE_DEG_S = 100.0
_LEVELS = tuple(-40.0 + 12.5 * i for i in range(11))

_AXES = ("x", "y", "z")


def _poses() -> tuple[tuple[float, ...], ...]:
    """Twelve poses, each (gyro_x, gyro_y, gyro_z, acc_x, acc_y, acc_z)."""
    out: list[tuple[float, ...]] = []
    for k in range(3):  # six static faces
        for sign in (1.0, -1.0):
            acc = [0.0, 0.0, 0.0]
            acc[k] = sign
            out.append((0.0, 0.0, 0.0, *acc))
    for k in range(3):  # axis k vertical, table turning about it both ways
        for sign in (1.0, -1.0):
            gyro = [0.0, 0.0, 0.0]
            gyro[k] = sign * RATE_DEG_S
            acc = [0.0, 0.0, 0.0]
            acc[k] = 1.0
            out.append((*gyro, *acc))
    return tuple(out)


#: The table programme: six static faces then six turntable poses.
POSES = _poses()


def _axis(kind: str, k: int, unit: str, bias: tuple[float, ...], sf: tuple[float, ...],
          cross: tuple[tuple[float, float], tuple[float, float]],
          noise: NoiseConfig) -> AxisConfig:
    others = [a for a in _AXES if a != _AXES[k]]
    return AxisConfig(
        name=f"{kind}_{_AXES[k]}", unit=unit, bias_reference_c=None,
        bias=Polynomial(coefficients=bias, reference_c=25.0),
        scale_factor_ppm=Polynomial(coefficients=sf, reference_c=25.0),
        cross_axis_urad=tuple((f"{kind}_{o}", Polynomial(coefficients=c, reference_c=25.0))
                              for o, c in zip(others, cross, strict=True)),
        reference_level=1.0 if (kind == "acc" and k == 2) else 0.0,  # +z up between poses
        noise=noise)


_GYRO_NOISE = NoiseConfig(white_density=0.005, bias_instability=5e-4, rate_random_walk=0.0)
_ACC_NOISE = NoiseConfig(white_density=1e-4, bias_instability=2e-5, rate_random_walk=0.0)

IMU_MULTIPOSITION = SimConfig(
    name="imu-multiposition", sensor_kind="imu", sample_rate_hz=0.2, default_runs=4,
    procedures=(
        ChamberProfile(name="soaks -40..85 C up, 12 poses each", start_c=-40.0,
                       segments=staircase(_LEVELS, soak_h=1.5, ramp_rate_c_per_h=40.0,
                                          four_position=True)),
        ChamberProfile(name="soaks 85..-40 C down, 12 poses each", start_c=85.0,
                       segments=staircase(tuple(reversed(_LEVELS)), soak_h=1.5,
                                          ramp_rate_c_per_h=40.0, four_position=True))),
    axes=(
        # gyro (°/s): bias c0 + c1 ΔT + c2 ΔT² + c3 ΔT³; scale factor in ppm; cross µrad
        _axis("gyro", 0, "deg/s", (0.05, 3.0e-3, 2.0e-5, -1.0e-7), (1200.0, -140.0, 0.30),
              ((2500.0, 30.0), (-1500.0, -25.0)), _GYRO_NOISE),
        _axis("gyro", 1, "deg/s", (-0.08, -2.0e-3, 3.0e-5, 0.0), (-800.0, -150.0, 0.25),
              ((1800.0, -35.0), (3000.0, 20.0)), _GYRO_NOISE),
        _axis("gyro", 2, "deg/s", (0.02, 4.0e-3, -1.5e-5, 5.0e-8), (500.0, -130.0, 0.35),
              ((-2000.0, 40.0), (2200.0, -30.0)), _GYRO_NOISE),
        # accelerometer (g)
        _axis("acc", 0, "g", (2.0e-3, 1.5e-4, 2.0e-6, -1.5e-8), (900.0, -140.0, 0.30),
              ((2000.0, 30.0), (-2500.0, 25.0)), _ACC_NOISE),
        _axis("acc", 1, "g", (-1.5e-3, -1.0e-4, 1.5e-6, 0.0), (-600.0, -145.0, 0.28),
              ((1600.0, -20.0), (2800.0, 35.0)), _ACC_NOISE),
        _axis("acc", 2, "g", (3.0e-3, 2.0e-4, -1.0e-6, 1.0e-8), (300.0, -135.0, 0.32),
              ((-1800.0, 25.0), (1500.0, -40.0)), _ACC_NOISE)),
    thermal=ThermalConfig(die_lag_s=120.0, case_lag_s=150.0),
    thermometer=ThermometerConfig(lag_s=20.0, resolution_c=0.01, noise_c=0.0),
    table=TableConfig(program="multi_position", poses=POSES, dwell_s=300.0),
    # a small turn-on offset per run (same number in °/s and g: negligible for both)
    unit_spread=UnitSpreadConfig(bias_offset=2e-5),
)

PRESETS[IMU_MULTIPOSITION.name] = IMU_MULTIPOSITION
