"""Thermal-chamber temperature programmes and the test table's reference programme.

A :class:`ChamberProfile` is a start temperature followed by segments:
:class:`Soak` (hold), :class:`Ramp` (linear change at a set rate) and
:class:`Approach` (exponential approach to a target, the air of a closed,
unpowered box warmed by the device itself, study 002).  Heat/cool cycles and
soak staircases are built from these by :func:`staircase` and :func:`cycle`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Soak", "Ramp", "Approach", "Segment", "ChamberProfile", "staircase", "cycle"]


@dataclass(frozen=True, kw_only=True)
class Soak:
    """Hold the chamber at ``temperature_c`` for ``duration_h`` hours.

    ``four_position`` marks a soak during which the test table runs its
    position programme (study 000's static four-position test) at the end of the soak.
    """

    temperature_c: float  # °C
    duration_h: float  # h
    four_position: bool = False


@dataclass(frozen=True, kw_only=True)
class Ramp:
    """Change the chamber linearly to ``to_c`` at ``rate_c_per_h`` (sign taken from the target)."""

    to_c: float  # °C
    rate_c_per_h: float = 10.0  # °C/h, magnitude


@dataclass(frozen=True, kw_only=True)
class Approach:
    """Exponential approach to ``target_c`` with time constant ``tau_h`` for ``duration_h``.

    .. math:: T(t) = T_{target} + (T_0 - T_{target})\\, e^{-t/\\tau}
    """

    target_c: float  # °C
    tau_h: float  # h
    duration_h: float  # h


Segment = Soak | Ramp | Approach


def _segment_duration_s(seg: Segment, start_c: float) -> float:
    if isinstance(seg, Soak):
        return seg.duration_h * 3600.0
    if isinstance(seg, Ramp):
        if seg.rate_c_per_h <= 0:
            raise ValueError(f"ramp rate_c_per_h must be positive, got {seg.rate_c_per_h!r}")
        return abs(seg.to_c - start_c) / seg.rate_c_per_h * 3600.0
    if isinstance(seg, Approach):
        if seg.tau_h <= 0:
            raise ValueError(f"approach tau_h must be positive, got {seg.tau_h!r}")
        return seg.duration_h * 3600.0
    raise TypeError(f"unknown chamber segment {seg!r} (use Soak, Ramp or Approach)")


def _segment_end_c(seg: Segment, start_c: float) -> float:
    if isinstance(seg, Soak):
        return seg.temperature_c
    if isinstance(seg, Ramp):
        return seg.to_c
    return seg.target_c + (start_c - seg.target_c) * np.exp(-seg.duration_h / seg.tau_h)


@dataclass(frozen=True, kw_only=True)
class ChamberProfile:
    """A chamber programme: a start temperature and a sequence of segments.

    A :class:`Soak` jumps to its temperature (use a :class:`Ramp` before it for a
    realistic transition); the device's thermal lag smooths any step.
    """

    name: str = "profile"
    start_c: float = 25.0  # °C
    segments: tuple[Segment, ...] = ()

    def bounds(self) -> list[tuple[float, float, float, Segment]]:
        """``(t_start_s, t_end_s, start_c, segment)`` for every segment."""
        out = []
        t, temp = 0.0, self.start_c
        for seg in self.segments:
            d = _segment_duration_s(seg, temp)
            out.append((t, t + d, temp, seg))
            t, temp = t + d, _segment_end_c(seg, temp)
        return out

    @property
    def duration_s(self) -> float:
        b = self.bounds()
        return b[-1][1] if b else 0.0

    def temperature(self, time_s: np.ndarray) -> np.ndarray:
        """Chamber air temperature (°C) at ``time_s`` (s from the start)."""
        t = np.asarray(time_s, dtype=np.float64)
        out = np.full(t.shape, float(self.start_c))
        for t0, t1, c0, seg in self.bounds():
            m = (t >= t0) & (t <= t1)
            dt = t[m] - t0
            if isinstance(seg, Soak):
                out[m] = seg.temperature_c
            elif isinstance(seg, Ramp):
                sign = np.sign(seg.to_c - c0)
                out[m] = c0 + sign * seg.rate_c_per_h * dt / 3600.0
            else:
                out[m] = seg.target_c + (c0 - seg.target_c) * np.exp(-dt / (seg.tau_h * 3600.0))
        # past the programme's end the chamber holds its last value
        b = self.bounds()
        if b:
            out[t > b[-1][1]] = _segment_end_c(b[-1][3], b[-1][2])
        return out


def staircase(levels_c: tuple[float, ...] | list[float], *, soak_h: float,
              ramp_rate_c_per_h: float, four_position: bool = False) -> tuple[Segment, ...]:
    """Soak at each level in turn, ramping between levels at ``ramp_rate_c_per_h`` (°C/h)."""
    segs: list[Segment] = []
    for i, lv in enumerate(levels_c):
        if i:
            segs.append(Ramp(to_c=float(lv), rate_c_per_h=ramp_rate_c_per_h))
        segs.append(Soak(temperature_c=float(lv), duration_h=soak_h, four_position=four_position))
    return tuple(segs)


def cycle(low_c: float, high_c: float, *, rate_c_per_h: float, soak_h: float,
          cycles: int = 1) -> tuple[Segment, ...]:
    """Heat/cool cycles low → high → low with soaks at both ends (for hysteresis tests)."""
    segs: list[Segment] = [Soak(temperature_c=low_c, duration_h=soak_h)]
    for _ in range(int(cycles)):
        segs += [Ramp(to_c=high_c, rate_c_per_h=rate_c_per_h),
                 Soak(temperature_c=high_c, duration_h=soak_h),
                 Ramp(to_c=low_c, rate_c_per_h=rate_c_per_h),
                 Soak(temperature_c=low_c, duration_h=soak_h)]
    return tuple(segs)
