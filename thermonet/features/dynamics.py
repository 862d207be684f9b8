"""Dynamic inputs: temperature rate, thermal lag, delayed temperature and hysteresis memory,
one definition each.

A *dynamic input* depends on the temperature's past, not only on its present
value.  Each is a causal recurrence with O(1) state per sample — what a
microcontroller runs — defined once here (evaluated for training by
:mod:`thermonet.features.recurrences`); the training features
(:func:`thermonet.features.inputs.signal_matrix`), the torch-free runtime
(``export/thermonet_runtime.py``, its own copy, checked against this module by
the tests) and the C header's ``<prefix>_step`` compute the same numbers.

=================== ============================================ ====================== =====
feature             value                                        signal                 unit
=================== ============================================ ====================== =====
``rate``            :math:`\\dot T`, filtered, τ = 60 s            ``rate_c_per_min``      °C/min
``rate_<tau>``      the same with time constant ``tau`` s         ``rate_<tau>_c_per_min`` °C/min
``lag_<tau>``       :math:`T - \\mathrm{EMA}_\\tau(T)`              ``lag_<tau>_c``          °C
``delayed_<tau>``   :math:`\\mathrm{EMA}_\\tau(T)`                  ``delayed_<tau>_c``      °C
``play_<w>``        :math:`T - P_w(T)`, play of half-width w °C   ``play_<w>_c``           °C
=================== ============================================ ====================== =====

``tau`` and ``w`` are written as decimal numbers (``lag_300``, ``play_0.5``).

**Lag** (first-order thermal lag).  :math:`E` follows :math:`\\tau\\,\\dot E = T - E`
with :math:`T` linear between samples (exact for any sample interval
:math:`\\Delta t_k`).  With :math:`e = T - E`, :math:`h = \\Delta t_k/\\tau` and
:math:`g(h) = (1 - e^{-h})/h`:

.. math:: e_k = e_{k-1} + g(h)\\,\\big[(T_k - T_{k-1}) - h\\, e_{k-1}\\big]

(the same as :math:`e_k = e^{-h} e_{k-1} + (T_k - T_{k-1})\\, g(h)`, written so
float32 keeps its precision when :math:`h \\ll 1`).  On a ramp of slope
:math:`r`, :math:`e \\to r\\tau`: ``lag_<tau>`` is the case-to-die gradient a
thermometer with time constant τ lags behind.

**Delayed temperature** is :math:`E = T - e`: the temperature a sensing element
that lags its thermometer by a first-order τ sees.  A model of ``delayed_<tau>``
alone (``cubic-delayed-3min`` in the default set: the cubic at E) is a function of
one temperature, so its domain is E's trained range, with no joint envelope: on a
new excursion at another rate or in the other direction E stays inside it, and a
sensor that lags its thermometer is corrected as the physics says, where a cubic in
T is off by the lag times the slope, with opposite signs heating and cooling.

**Rate** is the time derivative of that filtered temperature,
:math:`\\dot E = e/\\tau`, in °C/min: :math:`\\text{rate} = 60\\, e/\\tau_r`.  It is
exact (after ~5 τ) on a ramp, lags a change of slope by τ, and turns white
thermometer noise σ into about :math:`60\\,σ/\\tau_r` °C/min.  Default τ_r = 60 s
(:data:`RATE_TAU_S`): chamber ramps change over minutes to hours.

**Play** (backlash, the simulator's own hysteresis model,
:func:`thermonet.sim.device.play_operator`): the state follows T only once T
has moved more than w away from it,

.. math:: P_k = \\min(\\max(P_{k-1},\\, T_k - w),\\, T_k + w),

and the input is :math:`T_k - P_k \\in [-w, w]`: +w while heating, −w while
cooling, and in a soak the value the last excursion left behind (memory).

**Start-up and gaps.**  The first sample of a stream, and the first sample after
a gap (time since the last sample with a finite temperature > ``gap_s``, stored
with the model), start the state afresh: :math:`E = T` (lag 0, rate 0) and
:math:`P = T` (play 0).  A sample after a gap raises the out-of-range flag.
**Missing temperature** (NaN/inf) gives NaN dynamic inputs (so NaN drift, flag
set) and leaves the state untouched.  **Time** must be finite and strictly
increasing: anything else is refused (:class:`TimeError`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..core.errors import ConfigError, InputError

# ``gap_s`` "auto" is GAP_FACTOR × the median sample interval of the first training run: the
# same factor that cuts a log into contiguous segments (re-exported here)
from ..core.recording import GAP_FACTOR
from .recurrences import lag_error, play_state

__all__ = ["RATE_TAU_S", "DEFAULT_GAP_S", "GAP_FACTOR", "TimeError", "DynamicInput", "Rate",
           "Lag", "Delayed", "Play", "INPUTS", "register_input", "compute", "DynamicStream",
           "parse_dynamic", "is_dynamic", "check_time",
           "dynamic_signals", "default_gap_s", "constants", "from_constants",
           "saturation_margin", "input_set_warnings",
           "SETTLE_TIME_CONSTANTS"]

#: Time constant of ``rate`` (s).
RATE_TAU_S = 60.0
#: Gap limit (s) of a spec built without data and without an explicit ``gap_s``.
DEFAULT_GAP_S = 10.0
#: Format of the constants block stored with a model.
CONSTANTS_VERSION = 1

_NUM = r"(\d+(?:\.\d+)?)"


class TimeError(InputError):
    """Time that is not finite and strictly increasing."""


def check_time(time_s: np.ndarray, source: str = "time_s") -> np.ndarray:
    """float64 copy of ``time_s`` after checking it is finite and strictly increasing.

    Raises
    ------
    TimeError
        Naming the first bad index (0-based) and the values.
    """
    t = np.asarray(time_s, dtype=np.float64)
    if t.ndim != 1:
        raise TimeError(f"{source}: expected a 1-D array of seconds, got shape {t.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise TimeError(f"{source}: sample {int(bad[0])}: time is {float(t[bad[0]])!r} "
                        "(must be finite seconds)")
    dt = np.diff(t)
    back = np.flatnonzero(dt <= 0)
    if back.size:
        k = int(back[0]) + 1
        what = "repeated" if dt[k - 1] == 0 else "decreasing"
        raise TimeError(f"{source}: sample {k}: time {what} ({float(t[k - 1])!r} then "
                        f"{float(t[k])!r} s); "
                        "time must increase strictly")
    return t


@dataclass(frozen=True)
class DynamicInput:
    """One dynamic input: its feature name, signal name, unit and constants."""

    name: str
    kind: ClassVar[str] = ""
    unit: ClassVar[str] = "degC"
    #: Name of the field holding the recurrence's one constant (``tau_s``, ``half_width_c``).
    param_key: ClassVar[str] = ""
    #: A temperature (°C about t_ref), not a difference or a rate (``delayed``).
    is_temperature: ClassVar[bool] = False

    @property
    def signal(self) -> str:
        return f"{self.name}_c"

    @property
    def param(self) -> float:
        """The one constant of the recurrence (τ in s, or w in °C)."""
        return float(getattr(self, self.param_key))

    def constants(self) -> dict[str, Any]:
        """What the model stores and every mirror (runtime, C) reads back."""
        return {"name": self.name, "kind": self.kind, "signal": self.signal,
                "unit": self.unit, self.param_key: getattr(self, self.param_key)}

    def from_state(self, temperature: Any, e: Any) -> Any:
        """The input's value from the temperature and the lag state e (the EMA kinds; arrays
        or floats alike)."""
        raise NotImplementedError

    @property
    def memory_s(self) -> float:
        """How long the input remembers (the folds' purge): τ for the EMA kinds, 0 for play."""
        return 0.0


@dataclass(frozen=True)
class _EMA(DynamicInput):
    """An input of the lag state e of :math:`\\mathrm{EMA}_\\tau(T)` (rate, lag, delayed)."""

    tau_s: float = RATE_TAU_S
    param_key: ClassVar[str] = "tau_s"

    def from_state(self, temperature: Any, e: Any) -> Any:
        return e

    @property
    def memory_s(self) -> float:
        return float(self.tau_s)


@dataclass(frozen=True)
class Rate(_EMA):
    """Filtered dT/dt in °C/min: :math:`60\\, e_\\tau / \\tau`."""

    kind: ClassVar[str] = "rate"
    unit: ClassVar[str] = "degC/min"

    def from_state(self, temperature: Any, e: Any) -> Any:
        return 60.0 * e / self.tau_s

    @property
    def signal(self) -> str:
        return "rate_c_per_min" if self.name == "rate" else f"{self.name}_c_per_min"


@dataclass(frozen=True)
class Lag(_EMA):
    """:math:`T - \\mathrm{EMA}_\\tau(T)` in °C."""

    kind: ClassVar[str] = "lag"


@dataclass(frozen=True)
class Delayed(_EMA):
    """:math:`\\mathrm{EMA}_\\tau(T) = T - e` in °C: the temperature delayed by a first-order
    lag τ (a temperature, so a one-input model's parameters expand about t_ref)."""

    kind: ClassVar[str] = "delayed"
    is_temperature: ClassVar[bool] = True

    def from_state(self, temperature: Any, e: Any) -> Any:
        return temperature - e


@dataclass(frozen=True)
class Play(DynamicInput):
    """:math:`T - P_w(T)` in °C, the play operator of half-width ``w``."""

    half_width_c: float = 0.5
    kind: ClassVar[str] = "play"
    param_key: ClassVar[str] = "half_width_c"


def _positive(name: str, text: str) -> float:
    v = float(text)
    if not (math.isfinite(v) and v > 0):
        raise ConfigError(f"input '{name}': the constant must be a positive number, got {text}")
    return v


#: The dynamic inputs by kind (the feature name ``<kind>_<constant>``): the class and the
#: constant the kind alone takes (None: the constant must be written; ``rate`` alone has
#: τ = :data:`RATE_TAU_S`).  The same shape as the other registries (families, split
#: strategies, export formats): a dict and one register function.
INPUTS: dict[str, tuple[type[DynamicInput], float | None]] = {}

_CONSTANT = re.compile(rf"^{_NUM}$")


def register_input(cls: type[DynamicInput], *, default: float | None = None
                   ) -> type[DynamicInput]:
    """Add a dynamic input kind (``cls.kind``) to :data:`INPUTS`; ``default`` is the constant
    of the kind's name alone (None: none).  A kind registered twice is a ``ValueError``."""
    if not cls.kind or "_" in cls.kind:
        raise ValueError(f"dynamic input kind {cls.kind!r}: a name without '_'")
    if cls.kind in INPUTS:
        raise ValueError(f"dynamic input kind {cls.kind!r} is already registered")
    INPUTS[cls.kind] = (cls, default)
    return cls


register_input(Rate, default=RATE_TAU_S)
register_input(Lag)
register_input(Delayed)
register_input(Play)


def parse_dynamic(name: str) -> DynamicInput | None:
    """The dynamic input a feature name denotes, or None for a static feature."""
    kind, sep, text = name.partition("_")
    entry = INPUTS.get(kind)
    if entry is None:
        return None
    cls, default = entry
    if not sep:
        return cls(name, **{cls.param_key: default}) if default is not None else None
    m = _CONSTANT.match(text)
    return cls(name, **{cls.param_key: _positive(name, m.group(1))}) if m else None


def is_dynamic(name: str) -> bool:
    return parse_dynamic(name) is not None


def dynamic_signals(inputs: Sequence[str]) -> list[DynamicInput]:
    """The dynamic inputs among feature names, in input order."""
    out = []
    for name in inputs:
        d = parse_dynamic(name)
        if d is not None:
            out.append(d)
    return out


def default_gap_s(runs: Sequence[Any]) -> float:
    """``gap_s`` "auto": :data:`GAP_FACTOR` × the median sample interval of the first run
    (of a run reduced to window means: the gap its dynamic inputs were computed with)."""
    windows = getattr(runs[0], "windows", None)
    if windows is not None:
        return float(windows.gap_s)
    t = np.asarray(runs[0].time_s, dtype=np.float64)
    if t.size < 2:
        raise InputError(f"run '{runs[0].run_id}': one sample; cannot derive a sample interval "
                         "for the dynamic inputs' gap rule")
    return float(GAP_FACTOR * np.median(np.diff(t)))


def constants(inputs: Sequence[str], gap_s: float) -> dict[str, Any]:
    """The block stored with a model (checkpoint, ONNX metadata ``dynamic_inputs``, C header)."""
    return {"version": CONSTANTS_VERSION, "gap_s": float(gap_s),
            "start": "E = T (lag 0, rate 0), P = T (play 0)",
            "gap": "dt since the last finite-temperature sample > gap_s: restart, flag set",
            "inputs": [d.constants() for d in dynamic_signals(inputs)]}


def from_constants(block: Any, inputs: Sequence[str], source: str = "model") -> float:
    """Check a stored constants block against the inputs' own definitions; return gap_s.

    Raises
    ------
    ConfigError
        A missing or malformed block, or constants that differ from this
        version's definition of the input (a model is never re-interpreted).
    """
    if not isinstance(block, dict) or block.get("version") != CONSTANTS_VERSION:
        raise ConfigError(f"{source}: dynamic-input constants missing or of an unknown version "
                          f"(need version {CONSTANTS_VERSION}); refit the model")
    gap = block.get("gap_s")
    if isinstance(gap, bool) or not isinstance(gap, (int, float)) or not (
            math.isfinite(gap) and gap > 0):
        raise ConfigError(f"{source}: dynamic-input constant gap_s {gap!r} is not a positive "
                          "number")
    expected = constants(inputs, gap)["inputs"]
    if block.get("inputs") != expected:
        raise ConfigError(f"{source}: stored dynamic-input constants {block.get('inputs')!r} "
                          f"differ from the definitions {expected!r}")
    return float(gap)


def saturation_margin(inputs: Sequence[str], signals: Sequence[str], lo: np.ndarray,
                      hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The trained range with a margin where a ``play_<w>`` input reached its bound ±w.

    ``T − P`` sits exactly at ±w on every steady ramp; a float32 board computes it
    a few ulps of T away, which must not raise the out-of-range flag on every
    heating sample.  A reached bound moves out by 0.1 % of w (the input can never
    exceed ±w, so the clamp is unchanged in effect); an unreached one stays.
    """
    lo, hi = np.array(lo, dtype=np.float64), np.array(hi, dtype=np.float64)
    for d in dynamic_signals(inputs):
        if isinstance(d, Play) and d.signal in signals:
            j, w = list(signals).index(d.signal), d.half_width_c
            if hi[j] >= w * (1 - 1e-6):
                hi[j] = w * (1 + 1e-3)
            if lo[j] <= -w * (1 - 1e-6):
                lo[j] = -w * (1 + 1e-3)
    return lo, hi


class DynamicStream:
    """The dynamic inputs of one stream computed chunk by chunk, the state carried across
    chunk edges (a recording larger than memory, read in row groups).

    The state is what the C header's state struct holds: whether the stream has
    started, the last time seen (time must keep increasing across chunks), time and
    temperature of the last finite-temperature sample and one value per recurrence
    (e per time constant, P per play width).  Each :meth:`push` runs the same
    vectorised block scans as a whole array, started from that state, so the result
    equals :func:`compute` on the concatenated chunks: bitwise for ``play`` (comparisons
    only), within float64 rounding of the signal for ``rate``/``lag`` (the blocked
    scan composes its block maps in a different order; tests/test_dynamics.py).
    A chunk that is refused (time not finite or not increasing) leaves the state as
    it was.
    """

    def __init__(self, inputs: Sequence[str], gap_s: float) -> None:
        if not (math.isfinite(gap_s) and gap_s > 0):
            raise ConfigError(f"gap_s must be a positive number of seconds, got {gap_s!r}")
        self.inputs = dynamic_signals(inputs)
        self.gap_s = float(gap_s)
        self.started = False
        self.t_last = -math.inf
        self.t_prev = 0.0
        self.temp_prev = 0.0
        #: e per time constant (rate, lag) and P per half-width (play)
        self.state: dict[tuple[str, float], float] = {}
        self.n_seen = 0

    def push(self, time_s: np.ndarray, temperature_c: np.ndarray
             ) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """The signals of the next chunk (see :func:`compute`); updates the state."""
        t = check_time(time_s)
        if t.size and t[0] <= self.t_last:
            what = "repeated" if t[0] == self.t_last else "decreasing"
            raise TimeError(f"time_s: sample {self.n_seen}: time {what} ({self.t_last!r} then "
                            f"{float(t[0])!r} s across a chunk edge); time must increase "
                            "strictly")
        temp = np.asarray(temperature_c, dtype=np.float64)
        if temp.shape != t.shape:
            raise InputError(f"temperature_c has shape {temp.shape}, time_s {t.shape}")
        valid = np.isfinite(temp)
        tv, Tv = t[valid], temp[valid]
        restart = np.ones(tv.size, dtype=bool)
        restart[1:] = np.diff(tv) > self.gap_s
        cont = self.started and tv.size > 0
        if cont:
            restart[0] = (tv[0] - self.t_prev) > self.gap_s
        n = valid.size
        out: dict[str, np.ndarray] = {}
        new: dict[tuple[str, float], float] = {}
        cache: dict[float, np.ndarray] = {}
        for d in self.inputs:
            col = np.full(n, np.nan)
            if tv.size:
                if isinstance(d, Play):
                    key = ("play", d.half_width_c)
                    p = play_state(Tv, restart, d.half_width_c, self.state.get(key, 0.0))
                    new[key] = float(p[-1])
                    col[valid] = Tv - p
                else:
                    tau = d.param
                    if tau not in cache:
                        prev = (self.t_prev, self.temp_prev, self.state.get(("e", tau), 0.0)) \
                            if cont else None
                        cache[tau] = lag_error(tv, Tv, restart, tau, prev)
                        new[("e", tau)] = float(cache[tau][-1])
                    col[valid] = d.from_state(Tv, cache[tau])
            out[d.signal] = col
        gap = np.zeros(n, dtype=bool)
        idx = np.flatnonzero(valid)
        if idx.size:
            gap[idx] = restart
            gap[idx[0]] = cont and restart[0]
        # commit the state only once every step has succeeded
        if t.size:
            self.t_last = float(t[-1])
        if tv.size:
            self.started, self.t_prev, self.temp_prev = True, float(tv[-1]), float(Tv[-1])
            self.state.update(new)
        self.n_seen += n
        return out, gap


def compute(time_s: np.ndarray, temperature_c: np.ndarray, inputs: Sequence[str],
            gap_s: float) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Every dynamic signal of ``inputs`` for one stream, vectorised, O(N).

    One :meth:`DynamicStream.push` of the whole array (use a :class:`DynamicStream` to
    compute a longer stream chunk by chunk).

    Parameters
    ----------
    time_s : (N,) s, finite and strictly increasing
    temperature_c : (N,) °C; NaN/inf samples are missing
    inputs : feature names (static ones are ignored)
    gap_s : the gap limit, s

    Returns
    -------
    signals : dict signal name -> (N,) float64 (NaN where T is missing)
    gap : (N,) bool, true at the first sample after a gap (start-up excluded)
    """
    return DynamicStream(inputs, gap_s).push(time_s, temperature_c)


#: A time-constant input settles (its start-up transient falls below e⁻³ ≈ 5 %) in this many
#: time constants; a run shorter than that never shows it settled.
SETTLE_TIME_CONSTANTS = 3.0


def input_set_warnings(inputs_by_family: dict[str, list[str]],
                       run_durations_s: dict[str, float]) -> list[str]:
    """Inputs that cannot carry what they are meant to (cross-validation warnings).

    * **The same signal twice.** ``rate_<τ>`` is ``60 · lag_<τ> / τ`` exactly (both are the
      lag error e of one EMA, :data:`module docstring <thermonet.features.dynamics>`), so a
      family that reads both with the same τ (or ``rate`` and ``rate_60``) reads one signal
      up to a constant factor: its least squares are singular in that direction.
    * **A clock.** An input with a time constant τ longer than a run / :data:`SETTLE_TIME_CONSTANTS`
      never settles in that run: its start-up transient follows the time since the start, so
      a model can fit elapsed time through it, which a board that runs longer will not repeat.
    """
    out: list[str] = []
    shortest = min(run_durations_s.items(), key=lambda kv: kv[1]) if run_durations_s else None
    for label, names in inputs_by_family.items():
        seen: dict[float, str] = {}
        for name in names:
            dyn = parse_dynamic(name)
            if dyn is None or dyn.memory_s == 0.0:
                continue
            tau = dyn.param
            if dyn.is_temperature:      # T − e: a different signal from e (rate, lag)
                pass
            elif tau in seen:
                out.append(f"family '{label}': inputs '{seen[tau]}' and '{name}' are the same "
                           f"signal up to a constant factor (one lag error of τ = {tau:g} s): "
                           "drop one")
            else:
                seen[tau] = name
            if shortest is not None and SETTLE_TIME_CONSTANTS * tau > shortest[1]:
                out.append(f"family '{label}': input '{name}' has a time constant of {tau:g} s, "
                           f"and run '{shortest[0]}' lasts {shortest[1]:.4g} s (< "
                           f"{SETTLE_TIME_CONSTANTS:g} τ): it never settles there and acts as "
                           "a clock (time since the start), which a longer run will not repeat")
    return out
