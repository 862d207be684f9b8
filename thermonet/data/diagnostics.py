"""Warnings about the data a comparison was given: implausible inputs and extrapolation.

Each check returns plain sentences naming the run, signal or key; ``compare``
prints them and lists them under ``"warnings"`` in ``results.json``, and
``thermonet info`` shows the same sentences from the same function
(:func:`input_warnings`).  None of them stops a comparison: the data may be right
(a cryogenic test, a one-day soak), and the person reading the report decides.
Settings that cannot be right (a mapping's ``sample_rate_hz`` outside
:data:`RATE_HZ_POSSIBLE`) are refused where they are read, not warned about here.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from ..core.errors import counted
from ..core.recording import RATE, Dataset, contiguous_segments

__all__ = ["TEMPERATURE_PLAUSIBLE_C", "MAX_RAMP_C_PER_MIN", "MAX_DURATION_S",
           "RATE_HZ_PLAUSIBLE", "RATE_HZ_POSSIBLE", "VALUE_PLAUSIBLE_MAX", "UNIT_PLAUSIBLE_MAX",
           "OUTSIDE_RANGE_WARN",
           "input_warnings", "run_warnings", "temperature_hint", "outside_fraction", "outside_distance",
           "RANGE_ROUNDING", "extrapolation_warnings"]

#: Temperatures outside this range (°C) are implausible for a sensor test (Kelvin? m°C?).
TEMPERATURE_PLAUSIBLE_C = (-100.0, 200.0)
#: A mean temperature change faster than this (°C/min) over a run suggests the time stamps
#: are too short by a time-unit factor (s read as ms…); chambers ramp at ≤ ~10 °C/min.
MAX_RAMP_C_PER_MIN = 30.0
#: A run longer than this (s, 60 days) suggests ms or µs read as s.
MAX_DURATION_S = 60 * 86400.0
#: Sample rates outside this range (Hz) suggest a time-unit factor.
RATE_HZ_PLAUSIBLE = (1e-3, 1e5)
#: A configured sample rate outside this range (Hz: a sample every 11.6 days … 1 GHz) is
#: refused: no thermal test is sampled so.
RATE_HZ_POSSIBLE = (1e-6, 1e9)
#: Output, reference or proxy values beyond this magnitude (in any unit thermonet knows:
#: °/s, g, Pa, Hz, counts) suggest a wrong scale or a corrupt file.
VALUE_PLAUSIBLE_MAX = 1e12
#: Per unit of a physical channel, a magnitude no sensor of its kind reads (generous: a
#: projectile's gyro, a shock accelerometer, a magnetometer beside a magnet, 100 bar): a
#: reading beyond it is a wrong unit or scale (a gyro in millidegrees read as °/s).
UNIT_PLAUSIBLE_MAX = {"deg/s": 2e4, "deg/h": 7.2e7, "rad/s": 350.0, "g": 1e5, "mg": 1e8,
                      "m/s^2": 1e6, "T": 0.1, "uT": 1e5, "Pa": 1e7, "hPa": 1e5}
#: Warn when at least this fraction of the test samples lies outside the trained range.
OUTSIDE_RANGE_WARN = 0.01


def temperature_hint(lo: float, hi: float) -> str:
    """What a temperature span outside :data:`TEMPERATURE_PLAUSIBLE_C` may be in: every unit
    (Kelvin, °F, m°C) whose conversion lands the whole span in the plausible range."""
    lo_ok, hi_ok = TEMPERATURE_PLAUSIBLE_C
    hints = []
    if lo > 0.0 and lo_ok <= lo - 273.15 and hi - 273.15 <= hi_ok:
        hints.append("Kelvin? subtract 273.15")
    if lo_ok <= (lo - 32.0) * 5.0 / 9.0 and (hi - 32.0) * 5.0 / 9.0 <= hi_ok:
        hints.append("°F? subtract 32, then multiply by 5/9")
    if max(abs(lo), abs(hi)) > 1000.0 and lo_ok <= lo / 1000.0 and hi / 1000.0 <= hi_ok:
        hints.append("m°C? divide by 1000")
    return "; or ".join(hints) if hints else "check the mapping's temperature unit and scale"


@np.errstate(over="ignore", invalid="ignore")
def run_warnings(name: str, meta: dict[str, str], units: dict[str, str],
                 temperature: tuple[float, float, float] | None, peaks: dict[str, float],
                 duration_s: float, rate_hz: float) -> list[str]:
    """:func:`input_warnings` of one run from its summary numbers (what a chunked pass over a
    recording larger than memory accumulates: :mod:`thermonet.workflows.info`).

    ``temperature``: (min, max, max − min) of its temperature, or None; ``peaks``: the
    largest |value| of each output, reference and proxy channel.
    """
    out: list[str] = []
    lo_ok, hi_ok = TEMPERATURE_PLAUSIBLE_C
    if meta.get("numeric_header"):
        first = ", ".join(meta["numeric_header"].split(",")[:4])
        out.append(f"{name}: the header line of {meta.get('source', 'the file')} ({first}"
                   " …) is all numbers: a file without a header, whose first sample was "
                   "read as column names? set 'header: false' in the mapping")
    if meta.get("header_units"):
        out.append(f"{name}: in {meta.get('source', 'the file')} the headers name other "
                   f"units than the mapping ({meta['header_units']}); is the mapping's unit "
                   "right? (convert with scale/offset where the header is)")
    if temperature is not None:
        lo, hi = temperature[0], temperature[1]
        if lo < lo_ok or hi > hi_ok:
            out.append(f"{name}: temperature_c spans {lo:.4g} … {hi:.4g} °C, outside the "
                       f"plausible {lo_ok:g} … {hi_ok:g} °C ({temperature_hint(lo, hi)})")
    for ch, big in peaks.items():
        unit = units.get(ch, "")
        top = UNIT_PLAUSIBLE_MAX.get(unit, VALUE_PLAUSIBLE_MAX)
        if big > top:
            out.append(f"{name}: {ch} reaches {big:.4g} {unit}".rstrip()
                       + f", beyond any plausible reading (|value| > {top:g} {unit}".rstrip()
                       + "); a wrong unit or scale in the mapping, or a corrupt file?")
    dur, rate = duration_s, rate_hz
    if dur > MAX_DURATION_S:
        out.append(f"{name}: time_s spans {dur / 86400.0:.3g} days; are the time stamps "
                   "ms or µs read as seconds? (check the mapping's time unit)")
    if not RATE_HZ_PLAUSIBLE[0] <= rate <= RATE_HZ_PLAUSIBLE[1]:
        out.append(f"{name}: sample rate {rate:.4g} Hz is outside {RATE_HZ_PLAUSIBLE[0]:g} … "
                   f"{RATE_HZ_PLAUSIBLE[1]:g} Hz; is the time column's unit (or the "
                   "mapping's sample_rate_hz) right?")
    if temperature is not None and dur > 0:
        ramp = temperature[2] / (dur / 60.0)
        if ramp > MAX_RAMP_C_PER_MIN:
            out.append(f"{name}: temperature_c changes {temperature[2]:.3g} °C in {dur:.3g} s "
                       f"({ramp:.3g} °C/min); are the time stamps too short by a "
                       "time-unit factor (s read as ms)?")
    return out


@np.errstate(over="ignore", invalid="ignore")  # 1e306 values are what it warns about
def input_warnings(ds: Dataset, *, signals: Iterable[str] = (),
                   rate_window_s: float | None = None) -> list[str]:
    """Implausible inputs: temperature units, value magnitudes, time units, a header that
    is a data row, the rate input across gaps.

    Parameters
    ----------
    ds : Dataset
    signals : iterable of str
        Every signal the configured families read (``rate_c_per_min`` triggers the gap
        check); ``thermonet info``, which fits nothing, passes none.
    rate_window_s : float, optional
        Window of the rate input, s (needed for the gap check).
    """
    out: list[str] = []
    wants_rate = RATE in set(signals) and rate_window_s is not None
    for r in ds:
        name = f"run '{r.run_id}'"
        temp = r.temperature_c
        span = None
        ext = r.windows.extremes if r.windows is not None else {}
        if ext:   # a run streamed into window means: its samples' extremes, not the means'
            if temp is not None:
                lo, hi = ext["temperature_c"]
                span = (lo, hi, hi - lo)
            peaks = {ch: max(abs(ext[ch][0]), abs(ext[ch][1]))
                     for ch in {**r.outputs, **r.references, **r.proxies}}
            t0, t1 = ext["time_s"]
            out += run_warnings(name, r.meta, r.units, span, peaks, t1 - t0,
                                r.windows.source_rate_hz if r.windows is not None
                                else r.effective_rate_hz)
            continue
        if temp is not None and temp.size:
            span = (float(np.nanmin(temp)), float(np.nanmax(temp)), float(np.ptp(temp)))
        peaks = {ch: float(np.nanmax(np.abs(v))) if v.size else 0.0
                 for ch, v in {**r.outputs, **r.references, **r.proxies}.items()}
        out += run_warnings(name, r.meta, r.units, span, peaks, r.duration_s,
                            r.effective_rate_hz)
        if wants_rate and r.time_s.size > 1:
            gap = float(np.max(np.diff(r.time_s)))
            if rate_window_s is not None and gap > rate_window_s:
                segs = contiguous_segments(r.time_s)
                longest = max(float(r.time_s[s.stop - 1] - r.time_s[s.start]) for s in segs)
                out.append(f"{name}: the rate input (dT/dt over {rate_window_s:g} s) is used on "
                           f"data with gaps up to {gap:.3g} s and "
                           f"{counted(len(segs), 'contiguous segment')} (longest "
                           f"{longest:.3g} s): dT/dt restarts at every gap and is noisy on "
                           "short bursts")
    return out


#: A sample within this fraction of the range's own magnitude beyond its edge is inside: the
#: trained range is stored in float32 (a model's ``sig_lo`` / ``sig_hi``), whose rounding
#: (about 6e-8 of the value) would otherwise put a soak at the range's edge outside it.
RANGE_ROUNDING = 1e-6


def _widened(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[lo, hi]`` widened on each side by :data:`RANGE_ROUNDING` of its magnitude."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    tol = RANGE_ROUNDING * np.maximum(np.abs(lo), np.abs(hi))
    tol = np.where(np.isfinite(tol), tol, 0.0)
    return lo - tol, hi + tol


def outside_fraction(signals: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(S,) fraction of samples of each signal column outside ``[lo, hi]`` (NaN counts
    outside; a sample within float32 rounding of an edge, :data:`RANGE_ROUNDING`, inside)."""
    s = np.asarray(signals, dtype=np.float64)
    if s.shape[0] == 0:
        return np.zeros(s.shape[1])
    lo, hi = _widened(lo, hi)
    inside = (s >= lo[None, :]) & (s <= hi[None, :])
    return 1.0 - inside.mean(axis=0)


def outside_distance(signals: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(S,) farthest distance of a sample of each signal column outside ``[lo, hi]`` (0 when
    every finite sample is inside, or within float32 rounding of an edge; NaN samples are
    not a distance)."""
    s = np.asarray(signals, dtype=np.float64)
    if s.shape[0] == 0:
        return np.zeros(s.shape[1])
    wlo, whi = _widened(lo, hi)
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    beyond = (s < wlo[None, :]) | (s > whi[None, :])
    d = np.maximum(lo[None, :] - s, s - hi[None, :])
    d = np.where(np.isfinite(d) & beyond, d, 0.0)
    return np.maximum(d.max(axis=0), 0.0)


def percent(x: float) -> str:
    """A fraction as a percentage with two significant digits, so that a small one never reads
    as "0%": 0.0031 → "0.31 %", 0.47 → "47 %", 1 → "100 %"."""
    if not math.isfinite(x):
        return "nan %"
    pct = 100.0 * x
    return f"{pct:.0f} %" if pct >= 10 else f"{pct:.2g} %"


def extrapolation_warnings(fractions: dict[str, float], ranges: dict[str, tuple[float, float]],
                           distances: dict[str, float] | None = None,
                           units: dict[str, str] | None = None) -> list[str]:
    """One sentence per signal whose test samples lie outside the trained range: how many, and
    how far (in the signal's unit and as a fraction of the trained span)."""
    out = []
    for sig, frac in fractions.items():
        if frac >= OUTSIDE_RANGE_WARN:
            lo, hi = ranges.get(sig, (float("nan"), float("nan")))
            # other signals (a raw-count proxy) carry no unit here: the number alone
            unit = (units or {}).get(sig) or ("°C" if sig == "temperature_c" else "")
            far = ""
            if distances and distances.get(sig, 0.0) > 0.0:
                d = distances[sig]
                span = hi - lo
                rel = f" ({percent(d / span)} of the trained span)" if span > 0 else ""
                far = f", up to {d:.3g}{' ' + unit if unit else ''} beyond it{rel}"
            out.append(f"extrapolation: {percent(frac)} of the test samples of {sig} lie outside the "
                       f"trained range {lo:.4g} … {hi:.4g}{' ' + unit if unit else ''}{far}; "
                       "the models clamp there, so "
                       "those samples get the drift at the range's edge")
    return out
