"""The simulated device: thermal lags, thermometer, drift laws and noise.

Signal chain of one run (all vectorised over samples, except the
rate-independent hysteresis which needs the sample order):

.. math::

    T_{die} &= \\mathrm{lag}_{\\tau_d}(T_{chamber}) + \\Delta T_{self}(t) \\\\
    T_{read} &= Q_{r}\\big(\\mathrm{lag}_{\\tau_t}(\\mathrm{lag}_{\\tau_c}(T_{chamber}))
                + e\\big) \\\\
    d(t) &= b(T_{die}) + s(T_{die})\\,10^{-6}\\,x_{ref} + h(T_{die}) + k\\,\\dot T_{die} \\\\
    y(t) &= x_{ref} + d(t) + n(t)

with ``lag`` a first-order lag, ``Q_r`` quantisation to the thermometer's
resolution, ``b`` the bias law, ``s`` the scale-factor law (ppm), ``h`` the
hysteresis, ``k`` the temperature-rate coefficient and ``n`` the noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..features.recurrences import play_state

__all__ = [
    "Law", "Polynomial", "Lorentz", "Sinusoid", "LawSum",
    "ThermalConfig", "ThermometerConfig", "ProxyConfig", "SelfHeatingConfig",
    "HysteresisConfig", "RateTermConfig", "NoiseConfig", "UnitSpreadConfig", "AxisConfig",
    "first_order_lag", "quantise", "play_operator", "white_noise", "flicker_noise",
    "random_walk_noise", "sensor_noise",
]


# --------------------------------------------------------------------- laws
class Law(Protocol):
    """A drift law: value (output unit, or ppm for a scale factor) at temperature (°C)."""

    def __call__(self, temperature_c: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True, kw_only=True)
class Polynomial:
    """Polynomial in the offset from ``reference_c``.

    .. math:: f(T) = \\sum_k c_k (T - T_{ref})^k
    """

    coefficients: tuple[float, ...]  # c_0, c_1 per °C, c_2 per °C², ...
    reference_c: float = 25.0  # °C

    def __call__(self, temperature_c: np.ndarray) -> np.ndarray:
        x = np.asarray(temperature_c, dtype=np.float64) - self.reference_c
        return np.polynomial.polynomial.polyval(x, np.asarray(self.coefficients, dtype=np.float64))


@dataclass(frozen=True, kw_only=True)
class Lorentz:
    """Origin's Lorentz peak (study 000).

    .. math:: f(T) = y_0 + \\frac{2A}{\\pi} \\frac{w}{4 (T - x_c)^2 + w^2}
    """

    y0: float  # output unit
    area: float  # output unit · °C
    center_c: float  # °C
    width_c: float  # °C, full width at half maximum

    def __call__(self, temperature_c: np.ndarray) -> np.ndarray:
        t = np.asarray(temperature_c, dtype=np.float64)
        w = max(abs(self.width_c), 1e-12)  # a zero width would divide by zero at the centre
        return self.y0 + 2.0 * self.area / np.pi * w / (4.0 * (t - self.center_c) ** 2 + w * w)


@dataclass(frozen=True, kw_only=True)
class Sinusoid:
    """A ripple no smooth low-order family captures (the non-Lorentz part of study 000).

    .. math:: f(T) = a \\sin\\big(2\\pi (T - T_0) / P\\big)
    """

    amplitude: float  # output unit
    period_c: float  # °C
    phase_c: float = 0.0  # °C, T_0

    def __call__(self, temperature_c: np.ndarray) -> np.ndarray:
        t = np.asarray(temperature_c, dtype=np.float64)
        return self.amplitude * np.sin(2.0 * np.pi * (t - self.phase_c) / self.period_c)


@dataclass(frozen=True, kw_only=True)
class LawSum:
    """Sum of laws."""

    parts: tuple[AnyLaw, ...]

    def __call__(self, temperature_c: np.ndarray) -> np.ndarray:
        t = np.asarray(temperature_c, dtype=np.float64)
        out = np.zeros_like(t)
        for p in self.parts:
            out = out + p(t)
        return out


AnyLaw = Polynomial | Lorentz | Sinusoid | LawSum


# ------------------------------------------------------------ configuration
@dataclass(frozen=True, kw_only=True)
class ThermalConfig:
    """How the device follows the chamber (first-order lags)."""

    die_lag_s: float = 120.0  # s, chamber → sensing element (resonator, proof mass)
    case_lag_s: float = 300.0  # s, chamber → case where the thermometer sits


@dataclass(frozen=True, kw_only=True)
class ThermometerConfig:
    """The device's thermometer: reads the case through its own lag, quantised."""

    lag_s: float = 60.0  # s, case → reading
    resolution_c: float = 0.01  # °C, quantisation step
    noise_c: float = 0.0  # °C, white noise σ per reading
    offset_spread_c: float = 0.0  # °C, per-run calibration offset, uniform ±value


@dataclass(frozen=True, kw_only=True)
class ProxyConfig:
    """A temperature proxy tracking the die temperature without lag (HRG frequency, study 001).

    .. math:: p = Q_r\\big(p_0 + k (T_{die} - T_{ref})\\big)
    """

    name: str = "freq_hz"
    unit: str = "Hz"
    value_at_reference: float = 4517.0  # proxy unit at reference_c
    slope_per_c: float = 0.4  # proxy unit / °C
    reference_c: float = 25.0  # °C
    resolution: float = 0.03  # proxy unit, quantisation step
    noise: float = 0.0  # proxy unit, white σ


@dataclass(frozen=True, kw_only=True)
class SelfHeatingConfig:
    """Power-on warm-up of the die above its surroundings.

    .. math:: \\Delta T_{self}(t) = R\\,(1 - e^{-t/\\tau})
    """

    rise_c: float = 0.0  # °C, final rise R
    tau_s: float = 600.0  # s


@dataclass(frozen=True, kw_only=True)
class HysteresisConfig:
    """Heating/cooling difference: ``amplitude`` × normalised play operator of width ``width_c``."""

    amplitude: float = 0.0  # output unit; + on heating, − on cooling
    width_c: float = 2.0  # °C, temperature reversal needed to switch branch


@dataclass(frozen=True, kw_only=True)
class RateTermConfig:
    """Drift proportional to the die's temperature rate (thermal gradients)."""

    coefficient_per_c_per_h: float = 0.0  # output unit per (°C/h)


@dataclass(frozen=True, kw_only=True)
class NoiseConfig:
    """Noise in datasheet terms (IEEE 952 / Allan-variance coefficients).

    ``white_density`` N is the angle/velocity random walk in output unit·√s
    (= output unit/√Hz; a gyro's ARW in °/√h is N·60 for a °/s output); the
    per-sample σ is N·√fs and the Allan deviation N/√τ.  ``bias_instability``
    B is the flicker coefficient: the Allan deviation's flicker floor is
    :math:`B\\sqrt{2\\ln 2/\\pi} \\approx 0.664 B`.  ``rate_random_walk`` K
    (output unit/√s) gives :math:`K\\sqrt{\\tau/3}`.
    """

    white_density: float = 0.0  # output unit · √s
    bias_instability: float = 0.0  # output unit
    rate_random_walk: float = 0.0  # output unit / √s


@dataclass(frozen=True, kw_only=True)
class UnitSpreadConfig:
    """Unit-to-unit spread of the law coefficients (1σ values).

    Gains and the temperature shift are drawn once per seed (one unit per
    dataset); ``bias_offset`` is drawn per run (turn-on repeatability).
    """

    bias_gain_rel: float = 0.0  # relative, multiplies the bias law's temperature dependence
    bias_offset: float = 0.0  # output unit, turn-on bias added per run
    scale_gain_rel: float = 0.0  # relative, multiplies the scale-factor law
    temperature_shift_c: float = 0.0  # °C, shifts the laws along temperature


@dataclass(frozen=True, kw_only=True)
class AxisConfig:
    """One output channel: its unit, drift laws, hysteresis, rate term and noise."""

    name: str = "gyro_x"
    unit: str = "deg/s"
    bias: AnyLaw = Polynomial(coefficients=(0.0,))
    scale_factor_ppm: AnyLaw | None = None  # ppm of the reference, None: no scale-factor error
    bias_reference_c: float | None = (
        None  # °C; bias taken relative to its value here (None: absolute)
    )
    hysteresis: HysteresisConfig = HysteresisConfig()
    rate_term: RateTermConfig = RateTermConfig()
    noise: NoiseConfig = NoiseConfig()
    reference_level: float = 0.0  # output unit, static input (e.g. 0 °/s)
    # misalignment: (other axis, law in µrad) pairs; the output gains law(T)·1e-6 × that
    # axis's reference (a cross-axis sensitivity, the off-diagonal of the sensor's M(T))
    cross_axis_urad: tuple[tuple[str, AnyLaw], ...] = ()


# ---------------------------------------------------------------- processes
def first_order_lag(x: np.ndarray, tau_s: float, dt_s: float) -> np.ndarray:
    """First-order lag of ``x`` sampled every ``dt_s``, starting in equilibrium.

    Exact for a piecewise-linear input (first-order-hold discretisation), so on
    a ramp the output trails by exactly ``tau_s``.

    .. math:: \\tau \\dot y = x - y
    """
    x = np.asarray(x, dtype=np.float64)
    if tau_s <= 0 or x.size < 2:
        return x.copy()
    a = np.exp(-dt_s / tau_s)
    c = tau_s / dt_s * (1.0 - a)
    b0, b1 = 1.0 - c, c - a
    zi = np.array([x[0] * (1.0 - b0)])  # steady state y = x[0]: y0 = b0 x0 + z
    from scipy.signal import lfilter  # loaded when simulating, not at import

    y, _ = lfilter([b0, b1], [1.0, -a], x, zi=zi)
    return y


def quantise(x: np.ndarray, step: float) -> np.ndarray:
    """Round to the nearest multiple of ``step`` (no-op for ``step <= 0``)."""
    x = np.asarray(x, dtype=np.float64)
    return np.round(x / step) * step if step > 0 else x.copy()


def play_operator(x: np.ndarray, width: float) -> np.ndarray:
    """Rate-independent hysteresis: the play (backlash) operator, normalised to [−1, 1].

    The state follows ``x`` only once ``x`` has moved ``width/2`` past it, so
    the output is +1 while heating, −1 while cooling and keeps its last value
    in a soak (memory).  The state is :func:`thermonet.features.recurrences.play_state` of
    half-width ``width/2`` — the same definition as the ``play_<w>`` model input
    (``play_<width/2>`` sees exactly this shape, in °C).
    """
    x = np.asarray(x, dtype=np.float64)
    if width <= 0 or x.size == 0:
        return np.zeros_like(x)
    half = width / 2.0
    restart = np.zeros(x.size, dtype=bool)
    restart[0] = True
    return (x - play_state(x, restart, half)) / half


def white_noise(n: int, fs_hz: float, density: float, rng: np.random.Generator) -> np.ndarray:
    """White noise of density ``density`` (unit·√s): per-sample σ = density·√fs."""
    return rng.standard_normal(n) * density * np.sqrt(fs_hz)


def flicker_noise(n: int, fs_hz: float, bias_instability: float,
                  rng: np.random.Generator) -> np.ndarray:
    """1/f noise whose Allan-deviation floor is ≈ 0.664 × ``bias_instability``.

    FFT-shaped Gaussian noise with one-sided PSD (IEEE 952's two-sided
    :math:`B^2/(2\\pi f)` folded onto positive frequencies)

    .. math:: S_1(f) = \\frac{B^2}{\\pi f}
    """
    if n < 2:
        return np.zeros(n)
    # Shaped on a fast FFT length (5-smooth, ≥ n) and truncated: a stretch of a stationary
    # series has the same statistics, and an awkward n (a large prime factor) costs
    # 10-50× more than the next fast length.  Same n, same seed -> same noise.
    import scipy.fft  # loaded when simulating, not at import

    m = scipy.fft.next_fast_len(n, real=True)
    f = np.fft.rfftfreq(m, d=1.0 / fs_hz)
    psd = np.zeros_like(f)
    psd[1:] = bias_instability ** 2 / (np.pi * f[1:])
    # E|X_k|^2 = S(f_k) m fs / 2 for the unnormalised rfft of a one-sided PSD
    sigma = np.sqrt(psd * m * fs_hz / 2.0)
    spec = sigma * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)) / np.sqrt(2.0)
    return scipy.fft.irfft(spec, n=m)[:n]


def random_walk_noise(n: int, fs_hz: float, k: float, rng: np.random.Generator) -> np.ndarray:
    """Rate (velocity) random walk: a cumulative sum with step σ = K/√fs."""
    return np.cumsum(rng.standard_normal(n) * k / np.sqrt(fs_hz))


def sensor_noise(noise: NoiseConfig, n: int, fs_hz: float, rng: np.random.Generator, *,
                 white: bool = True, flicker: bool = True, random_walk: bool = True
                 ) -> np.ndarray:
    """Sum of the switched-on noise components (each draw happens regardless of the
    switch, so switching one part off leaves the others bit-identical)."""
    w = white_noise(n, fs_hz, noise.white_density, rng)
    f = flicker_noise(n, fs_hz, noise.bias_instability, rng)
    r = random_walk_noise(n, fs_hz, noise.rate_random_walk, rng)
    return w * white + f * flicker + r * random_walk
