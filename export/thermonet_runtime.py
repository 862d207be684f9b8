"""Run a thermonet drift-compensation model on board: numpy + onnxruntime only.

This file is the whole runtime.  Copy it next to the ``.onnx`` file a
thermonet training run exported; it never imports torch or thermonet.

.. math::

    \\text{compensated} = \\text{raw} - \\text{drift}(\\text{signals})

The graph evaluates the features (ΔT, ΔT², Δproxy …), the model and the
clamp of every signal to the range it was trained on; ``out_of_range`` is true
where a signal was outside that range (the drift is then the edge value) or
was not finite (the drift and the compensated output are then NaN).

Dynamic inputs (``rate``, ``lag_<tau>``, ``play_<w>``: see ``README.md``) are
computed here from ``time_s`` and ``temperature_c`` by the same causal
recurrences as in training (``thermonet.features.dynamics``, mirrored below and checked
against it by thermonet's tests), with the constants stored in the model's
metadata ``dynamic_inputs``; a sample after a gap in time also raises
``out_of_range``.

Python use::

    from thermonet_runtime import Compensator
    comp = Compensator("model.onnx")
    res = comp.compensate(temperature_c=41.2, raw=[0.011, -0.004, 0.002])
    res.compensated, res.drift, res.out_of_range
    # a model with dynamic inputs: whole sequences with time, or one sample at a time
    res = comp.compensate(temperature_c=temps, raw=raws, time_s=times)
    for t, temp, raw in stream:
        res = comp.step(t, temp, raw)
    # a long recording, block by block (state carried, one graph call per block)
    for times, temps, raws in blocks:
        res = comp.step_block(times, temps, raws)

Command line::

    python thermonet_runtime.py model.onnx input.csv --out output.csv

A CSV with a ``run`` column (``thermonet convert --out x.csv`` of several runs) is read run
by run: each run's rows are one sequence, the dynamic inputs' and a recurrent model's state
restarting at its first row, as in training (never carried across runs).

See ``README.md`` beside this file for units, the flag and threading.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import re
import signal
import stat
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

__all__ = ["Compensator", "Compensation", "RuntimeInputError", "SUPPORTED_FORMATS",
           "SUPPORTED_OPSETS", "DYNAMIC_VERSION", "RECURRENT_VERSION", "dynamic_signals",
           "recurrent_windows", "parse_number", "time_batch", "main"]

#: Metadata format versions this runtime understands (``thermonet_format``).
SUPPORTED_FORMATS = ("1", "2")  # 2: float64 raw, compensated and drift (large constants)
#: ONNX opsets the exporter writes and this runtime was checked against.
SUPPORTED_OPSETS = (17, 18, 19, 20, 21)
#: Name of the raw-output graph input and the three graph outputs.
RAW_INPUT = "raw"
GRAPH_OUTPUTS = ("compensated", "drift", "out_of_range")
#: A band half-width (or a growth rate across the trained span) over this many times the
#: model's largest drift on its trained range is refused: the band comes from the model's
#: residuals (the export's own check bounds a drift at its targets' mean +- 1000 std).
BAND_MAX_FACTOR = 1000.0
FLOAT32_MAX = float(np.finfo(np.float32).max)
#: Keyword aliases accepted by :meth:`Compensator.compensate`.
_ALIASES = {"rate": "rate_c_per_min"}
#: Version of the ``dynamic_inputs`` metadata block this runtime computes.
DYNAMIC_VERSION = 1
_DYNAMIC_KINDS = {"rate": "tau_s", "lag": "tau_s", "delayed": "tau_s", "play": "half_width_c"}
#: A CSV cell the command reads as a number: a decimal number (ASCII digits, optional sign,
#: fraction and exponent), as CSV writers and pandas' reader mean one — never Python's
#: literal syntax ('1_000'), other scripts' digits ('١٢٣'), hex or complex numbers.
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
#: Infinity as pandas reads it: inf / infinity, any case, optional sign.
_INFINITY = re.compile(r"([+-]?)(?:inf|infinity)", re.IGNORECASE)
#: A missing sample (NaN: drift NaN, flag set): an empty cell or pandas' default
#: missing-value spellings (``read_csv`` ``na_values``), exactly as written there.
_MISSING = frozenset({"", "#N/A", "#N/A N/A", "#NA", "-1.#IND", "-1.#QNAN", "-NaN", "-nan",
                      "1.#IND", "1.#QNAN", "<NA>", "N/A", "NA", "NULL", "NaN", "None", "n/a",
                      "nan", "null"})


def parse_number(cell: str) -> float:
    """A CSV cell as a number, as a CSV reader (pandas) reads a numeric field.

    Spaces and tabs around the value are ignored.  Accepted: a decimal number
    with an optional exponent (``-1.5e-3``, ``.5``, ``5.``); ``inf``/``infinity``
    in any case with an optional sign; and, as a missing sample (NaN), an
    empty cell or one of pandas' missing-value spellings (``nan``, ``NaN``,
    ``-nan``, ``NA``, ``N/A``, ``NULL``, ``None`` …, :data:`_MISSING`).
    Everything else raises ``ValueError`` — Python's literal syntax (``1_000``),
    non-ASCII digits, hex, complex numbers — and so does a decimal number
    beyond the range of a 64-bit float (``1e400``), which no writer of
    float64 data means.
    """
    text = cell.strip(" \t")
    if text in _MISSING:
        return math.nan
    if _DECIMAL.fullmatch(text):
        value = float(text)
        if math.isinf(value):
            raise ValueError(f"{text!r} is beyond the range of a 64-bit float")
        return value
    m = _INFINITY.fullmatch(text)
    if m:
        return -math.inf if m.group(1) == "-" else math.inf
    raise ValueError(f"not a number {text!r} (a decimal number such as -1.5e-3, inf, "
                     "nan or an empty cell)")


def _scalar(name: str, value: Any) -> float:
    """A single number given to the Python API (a Python or NumPy real, not a string or bool)."""
    arr = np.asarray(value)
    if arr.size != 1 or arr.dtype.kind not in "fiu":
        shown = repr(value) if len(repr(value)) <= 60 else repr(value)[:57] + "..."
        raise RuntimeInputError(f"input '{name}' must be one number, got "
                                f"{type(value).__name__} {shown}")
    return float(arr.reshape(()))


class RuntimeInputError(ValueError):
    """A model file or an input the runtime refuses; the message is one line."""


class Compensation:
    """Result of one :meth:`Compensator.compensate` call.

    Attributes
    ----------
    compensated : numpy.ndarray
        ``raw - drift``, float64 (float32 for a format-1 file), shape (N, A) for a
        batch or (A,) for one sample; units of the raw output (see ``output_units``).
    drift : numpy.ndarray
        The model's drift estimate, same shape and units.
    out_of_range : numpy.ndarray or bool
        (N,) bool for a batch, a plain bool for one sample.
    band : numpy.ndarray or None
        The residual-drift band's half-width at each sample's band signal (metadata
        ``band``: :meth:`Compensator.band`), same shape and units as ``drift``; None for a
        file without a band.  Not one of the graph's outputs (:meth:`as_dict` leaves it out).
    """

    __slots__ = ("compensated", "drift", "out_of_range", "band")

    def __init__(self, compensated: np.ndarray, drift: np.ndarray, out_of_range: Any,
                 band: np.ndarray | None = None) -> None:
        self.compensated = compensated
        self.drift = drift
        self.out_of_range = out_of_range
        self.band = band

    def __getitem__(self, key: str) -> Any:
        if key not in GRAPH_OUTPUTS:
            raise KeyError(f"no result '{key}'; results are {', '.join(GRAPH_OUTPUTS)}")
        return getattr(self, key)

    def as_dict(self) -> dict[str, Any]:
        """The three results as a plain dict."""
        return {k: getattr(self, k) for k in GRAPH_OUTPUTS}


def _meta_json(meta: Mapping[str, str], key: str, path: Path) -> Any:
    if key not in meta:
        raise RuntimeInputError(f"{path}: metadata key '{key}' is missing; "
                                "not a thermonet model (or exported by an older thermonet)")
    try:
        return json.loads(meta[key])
    except json.JSONDecodeError as exc:
        raise RuntimeInputError(
            f"{path}: metadata key '{key}' is not valid JSON ({exc.msg})"
        ) from None


# -- dynamic inputs: a copy of thermonet.features.dynamics (this file imports no thermonet) -----------------
def _check_time(time_s: Any, what: str = "time_s") -> np.ndarray:
    try:
        t = np.asarray(time_s, dtype=np.float64)
    except (TypeError, ValueError):
        raise RuntimeInputError(f"{what}: not numbers") from None
    if t.ndim != 1:
        raise RuntimeInputError(f"{what}: expected shape (N,), got {t.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise RuntimeInputError(f"{what}: sample {int(bad[0])}: time is {float(t[bad[0]])!r} "
                                "(must be finite seconds)")
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        k = int(back[0]) + 1
        how = "repeated" if t[k] == t[k - 1] else "decreasing"
        raise RuntimeInputError(f"{what}: sample {k}: time {how} ({float(t[k - 1])!r} then "
                                f"{float(t[k])!r} s); "
                                "time must increase strictly")
    return t


def _scan(step: Any, first: np.ndarray, second: np.ndarray, pad: tuple[float, float],
          y0: float = 0.0) -> np.ndarray:
    """y_k = step(y_{k-1}, first_k, second_k) (y_{-1} = y0) over √N blocks in three O(N) passes.

    ``step`` is a linear map (y·a + c) or a clamp (min(max(y, lo), hi)); both compose,
    so each block's map is built once, the ≈√N block maps are chained, and every block
    is replayed from its incoming value.
    """
    n = first.size
    if n == 0:
        return np.zeros(0)
    b = min(256, max(16, math.isqrt(n)))
    m = -(-n // b)

    def blocks(x: np.ndarray, fill: float) -> np.ndarray:
        out = np.full(b * m, fill)
        out[:n] = x
        return np.ascontiguousarray(out.reshape(m, b).T)

    f, g = blocks(first, pad[0]), blocks(second, pad[1])
    linear = step is _lin
    ya = np.ones(m) if linear else np.full(m, -np.inf)
    yb = np.zeros(m) if linear else np.full(m, np.inf)
    for i in range(b):  # the composed map of each block: (product, offset) or (low, high)
        if linear:
            ya, yb = ya * f[i], yb * f[i] + g[i]
        else:
            ya, yb = _clamp(ya, f[i], g[i]), _clamp(yb, f[i], g[i])
    inc = np.empty(m)
    s = float(y0)
    for j in range(m):
        inc[j] = s
        s = float(s * ya[j] + yb[j]) if linear else min(max(s, float(ya[j])), float(yb[j]))
    out = np.empty((b, m))
    y = inc
    for i in range(b):
        y = step(y, f[i], g[i])
        out[i] = y
    return out.T.reshape(-1)[:n]


def _lin(y: Any, a: Any, c: Any) -> Any:
    return a * y + c


def _clamp(y: Any, lo: Any, hi: Any) -> Any:
    return np.minimum(np.maximum(y, lo), hi)


def _g(h: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(h > 0, -np.expm1(-h) / h, 1.0)


def _ema_value(kind: str, temp: Any, e: Any, tau: float) -> Any:
    """An EMA kind's value from the temperature and the lag state e: ``rate`` 60·e/τ
    (°C/min), ``lag`` e, ``delayed`` T − e (°C)."""
    if kind == "rate":
        return 60.0 * e / tau
    return temp - e if kind == "delayed" else e


def dynamic_signals(time_s: Any, temperature_c: Any, dynamic: Mapping[str, Any],
                    stream: _Stream | None = None) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Every dynamic signal of one stream from time (s) and temperature (°C).

    ``dynamic`` is the model's ``dynamic_inputs`` metadata.  With e = T − EMA_τ(T)
    (T linear between samples), h = Δt/τ and g(h) = (1 − e^(−h))/h:
    ``e_k = e_{k-1} + g(h)·[(T_k − T_{k-1}) − h·e_{k-1}]``; ``lag`` is e (°C),
    ``rate`` is 60·e/τ (°C/min), ``delayed`` is T − e (°C); ``play`` is T − P with
    ``P_k = min(max(P_{k-1}, T_k − w), T_k + w)`` (°C).  The first sample and the first
    after a gap (Δt since the last finite temperature > ``gap_s``) restart the state
    (e = 0, P = T); a NaN temperature gives NaN and leaves the state alone.

    ``stream``: a block of a longer stream — the scans start from its state (the one
    :meth:`Compensator.step` keeps) and leave it at the block's end; time must go on
    after its last time.  A refused block leaves it unchanged.

    Returns
    -------
    (signals, gap) : dict name -> (N,) float64, and (N,) bool true after a gap
    """
    t = _check_time(time_s)
    temp = np.asarray(temperature_c, dtype=np.float64).reshape(-1)
    if temp.shape != t.shape:
        raise RuntimeInputError(f"temperature_c has {temp.size} samples, time_s {t.size}")
    if stream is not None and t.size and not t[0] > stream.t_last:
        how = "repeated" if t[0] == stream.t_last else "decreasing"
        raise RuntimeInputError(f"time_s: sample 0: time {how} ({stream.t_last!r} then "
                                f"{float(t[0])!r} s, across the block edge); time must "
                                "increase strictly")
    gap_s = float(dynamic["gap_s"])
    valid = np.isfinite(temp)
    tv, tempv = t[valid], temp[valid]
    restart = np.ones(tv.size, dtype=bool)
    restart[1:] = np.diff(tv) > gap_s
    cont = stream is not None and stream.started and tv.size > 0
    if cont:
        restart[0] = (tv[0] - stream.t_prev) > gap_s  # type: ignore[union-attr]
    out: dict[str, np.ndarray] = {}
    last: list[float] = []
    dt = np.diff(tv, prepend=stream.t_prev if cont else tv[:1])  # type: ignore[union-attr]
    dT = np.diff(tempv, prepend=stream.temp_prev if cont else tempv[:1])  # type: ignore[union-attr]
    for j, d in enumerate(dynamic["inputs"]):
        col = np.full(t.size, np.nan)
        y0 = stream.state[j] if cont else 0.0  # type: ignore[union-attr]
        if tv.size and d["kind"] == "play":
            w = float(d["half_width_c"])
            lo = np.where(restart, tempv, tempv - w)
            hi = np.where(restart, tempv, tempv + w)
            p = _scan(_clamp, lo, hi, (-np.inf, np.inf), y0)
            col[valid] = tempv - p
            last.append(float(p[-1]))
        elif tv.size:
            tau = float(d["tau_s"])
            h = dt / tau
            g = _g(h)
            a = np.where(restart, 0.0, 1.0 - h * g)
            c = np.where(restart, 0.0, dT * g)
            e = _scan(_lin, a, c, (1.0, 0.0), y0)
            col[valid] = _ema_value(d["kind"], tempv, e, tau)
            last.append(float(e[-1]))
        out[d["signal"]] = col
    gap = np.zeros(t.size, dtype=bool)
    idx = np.flatnonzero(valid)
    if idx.size:
        gap[idx] = restart
        gap[idx[0]] = cont and restart[0]
    if stream is not None:
        if t.size:
            stream.t_last = float(t[-1])
        if tv.size:
            stream.started, stream.t_prev, stream.temp_prev = True, float(tv[-1]), float(tempv[-1])
            stream.state[:len(last)] = last
    return out, gap


def _next_time(t_last: float, t: float) -> float:
    """``t`` when it may follow ``t_last`` in a stream (finite, strictly later), else the one
    refusal every stream gives (dynamic inputs and the recurrent state alike)."""
    if not math.isfinite(t):
        raise RuntimeInputError(f"time_s is {t!r} (must be finite seconds)")
    if t <= t_last:
        how = "repeated" if t == t_last else "decreasing"
        raise RuntimeInputError(f"time_s {how} ({t_last!r} then {t!r} s); "
                                "time must increase strictly")
    return t


class _Stream:
    """The O(1) state of :meth:`Compensator.step` (what the C header's state struct holds)."""

    __slots__ = ("started", "t_last", "t_prev", "temp_prev", "state")

    def __init__(self, n: int) -> None:
        self.started = False
        self.t_last = -math.inf      # last time seen (any sample): time must increase
        self.t_prev = 0.0            # time and temperature of the last finite-temperature sample
        self.temp_prev = 0.0
        self.state = [0.0] * n

    def update(self, t: float, temp: float, dynamic: Mapping[str, Any]
               ) -> tuple[dict[str, float], bool]:
        self.t_last = _next_time(self.t_last, t)
        items = dynamic["inputs"]
        if not math.isfinite(temp):
            return {d["signal"]: math.nan for d in items}, False
        restart = not self.started or (t - self.t_prev) > float(dynamic["gap_s"])
        gap = self.started and restart
        out = {}
        for j, d in enumerate(items):
            if d["kind"] == "play":
                w = float(d["half_width_c"])
                v = temp if restart else min(max(self.state[j], temp - w), temp + w)
                self.state[j] = v
                out[d["signal"]] = temp - v
            else:
                tau = float(d["tau_s"])
                if restart:
                    e = 0.0
                else:
                    h = (t - self.t_prev) / tau
                    g = -math.expm1(-h) / h
                    e = self.state[j] + g * ((temp - self.temp_prev) - h * self.state[j])
                self.state[j] = e
                out[d["signal"]] = float(_ema_value(d["kind"], temp, e, tau))
        self.started, self.t_prev, self.temp_prev = True, t, temp
        return out, gap


def _check_dynamic(block: Any, signals: list[str], path: Path) -> dict[str, Any] | None:
    """The validated ``dynamic_inputs`` metadata block (None when the model has none)."""
    if block is None:
        return None
    if not isinstance(block, dict) or block.get("version") != DYNAMIC_VERSION:
        raise RuntimeInputError(f"{path}: metadata 'dynamic_inputs' is not version "
                                f"{DYNAMIC_VERSION}; this runtime cannot compute its inputs")
    gap = block.get("gap_s")
    if isinstance(gap, bool) or not isinstance(gap, (int, float)) or not (
            math.isfinite(gap) and gap > 0):
        raise RuntimeInputError(f"{path}: metadata 'dynamic_inputs': gap_s {gap!r} is not a "
                                "positive number of seconds")
    items = block.get("inputs")
    if not isinstance(items, list) or not items:
        raise RuntimeInputError(f"{path}: metadata 'dynamic_inputs' lists no inputs")
    for d in items:
        key = _DYNAMIC_KINDS.get(d.get("kind")) if isinstance(d, dict) else None
        if key is None:
            raise RuntimeInputError(f"{path}: metadata 'dynamic_inputs': unknown entry {d!r}")
        value = d.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                math.isfinite(value) and value > 0):
            raise RuntimeInputError(f"{path}: metadata 'dynamic_inputs': {d.get('name')!r} has "
                                    f"{key} {value!r} (must be a positive number)")
        if d.get("signal") not in signals:
            raise RuntimeInputError(f"{path}: metadata 'dynamic_inputs': signal "
                                    f"{d.get('signal')!r} is not a graph input {signals}")
    return block


# ---- recurrent models (the GRU): the state carried between samples and between calls ----
#: Version of the ``recurrent`` metadata block this runtime runs.
RECURRENT_VERSION = 1


def _check_recurrent(block: Any, path: Path) -> dict[str, Any] | None:
    """The validated ``recurrent`` metadata block (None for a model without state)."""
    if block is None:
        return None
    if not isinstance(block, dict) or block.get("version") != RECURRENT_VERSION:
        raise RuntimeInputError(f"{path}: metadata 'recurrent' is not version "
                                f"{RECURRENT_VERSION}; this runtime cannot carry its state")
    hidden = block.get("hidden")
    if isinstance(hidden, bool) or not isinstance(hidden, int) or not 1 <= hidden <= 4096:
        raise RuntimeInputError(f"{path}: metadata 'recurrent': hidden {hidden!r} is not a size")
    for key in ("step_s", "gap_s"):
        v = block.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (
                math.isfinite(v) and v > 0):
            raise RuntimeInputError(f"{path}: metadata 'recurrent': {key} {v!r} is not a "
                                    "positive number of seconds")
    return block


#: The stream of a model without dynamic inputs: no state, so no gap restarts it or is flagged
#: (as the C header's step and the batch call: a pause in a static model's stream is harmless).
_STATIC: dict[str, Any] = {"inputs": [], "gap_s": math.inf}


def recurrent_windows(time_s: np.ndarray, finite: np.ndarray, step_s: float, gap_s: float
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stream of a recurrent model (thermonet.models.sequence, mirrored and checked by
    thermonet's tests): for the finite samples, their positions, whether each restarts the
    state (first sample, or more than ``gap_s`` after the previous finite one) and its
    window number (``floor((t - t_0)/step_s)`` from the restart time ``t_0``, counted over
    the stream)."""
    idx = np.flatnonzero(finite)
    tf = time_s[idx]
    restart = np.ones(tf.size, dtype=bool)
    restart[1:] = np.diff(tf) > gap_s
    seg = np.cumsum(restart) - 1
    t0 = tf[restart][seg] if tf.size else tf
    k = np.floor((tf - t0) / step_s).astype(np.int64)
    new = restart.copy()
    new[1:] |= k[1:] != k[:-1]
    return idx, restart, np.cumsum(new) - 1


class _RecurrentStream:
    """The O(1) state of :meth:`Compensator.step` for a recurrent model (the C header's
    state struct): committed state ``h``, the current window's running mean and the state
    its last sample produced (``h_next``, committed when a later window opens)."""

    __slots__ = ("started", "t_last", "t_prev", "t0", "k", "base", "acc", "count", "h",
                 "h_next")

    def __init__(self, hidden: int) -> None:
        self.started = False
        self.t_last = -math.inf
        self.t_prev = self.t0 = 0.0
        self.k = 0
        self.base = self.acc = np.zeros(0)
        self.count = 0
        self.h = np.zeros(hidden, dtype=np.float32)
        self.h_next = self.h.copy()

    def update(self, t: float, s: np.ndarray, rec: Mapping[str, Any]
               ) -> tuple[np.ndarray | None, bool]:
        """The signals to evaluate (the window's running mean; None for a non-finite
        sample, which changes nothing) and whether this sample restarted after a gap."""
        self.t_last = _next_time(self.t_last, t)
        if not bool(np.all(np.isfinite(s))):
            return None, False
        restart = not self.started or (t - self.t_prev) > float(rec["gap_s"])
        gap = self.started and restart
        k = 0 if restart else int(math.floor((t - self.t0) / float(rec["step_s"])))
        if restart:
            self.h = np.zeros_like(self.h)
            self.t0 = t
        elif k != self.k:
            self.h = self.h_next
        if restart or k != self.k:
            self.k, self.base, self.acc, self.count = k, s.copy(), np.zeros_like(s), 0
        self.acc = self.acc + (s - self.base)
        self.count += 1
        self.started, self.t_prev = True, t
        return self.base + self.acc / self.count, gap


# The runtime's own copy of thermonet.core.names (it imports neither torch nor thermonet):
# metadata is read from a file, so every name is checked before it is used or printed.
_AXIS = re.compile(r"(?=.{1,64}\Z)[a-z][a-z0-9]*_[a-z0-9]+(?:\.bias|\.scale)?")
_SIGNAL = re.compile(r"[A-Za-z][A-Za-z0-9_.]{0,63}")
_FAMILY = re.compile(r"[a-z?][a-z0-9_-]{0,31}")
_LABEL = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
_UNIT = re.compile(r"[A-Za-z0-9°µμΩ%/^._-]{0,32}")


def _meta_name(value: Any, pattern: re.Pattern[str], key: str, path: Path) -> str:
    if not isinstance(value, str) or pattern.fullmatch(value) is None:
        text = repr(value) if len(repr(value)) <= 60 else repr(value)[:57] + "..."
        raise RuntimeInputError(f"{path}: metadata '{key}': {text} is not a valid name")
    return value


def _meta_names(meta: Mapping[str, str], key: str, pattern: re.Pattern[str],
                path: Path) -> list[str]:
    values = _meta_json(meta, key, path)
    if not isinstance(values, list) or not values:
        raise RuntimeInputError(f"{path}: metadata '{key}' is not a non-empty list of names")
    names = [_meta_name(v, pattern, key, path) for v in values]
    if len(set(names)) != len(names):
        raise RuntimeInputError(f"{path}: metadata '{key}' names one entry twice")
    return names


def _meta_units(meta: Mapping[str, str], key: str, pattern: re.Pattern[str],
                path: Path) -> dict[str, str]:
    units = _meta_json(meta, key, path) if key in meta else {}
    if not isinstance(units, dict):
        raise RuntimeInputError(f"{path}: metadata '{key}' is not a mapping name -> unit")
    return {_meta_name(k, pattern, key, path): _meta_name(v, _UNIT, key, path)
            for k, v in units.items()}


def _meta_axis_models(meta: Mapping[str, str], outputs: list[str], path: Path
                      ) -> dict[str, str | None] | None:
    """A per-axis model's ``axis_models`` {axis: candidate label, or null: left raw}; None for
    a single-family file."""
    if "axis_models" not in meta:
        return None
    table = _meta_json(meta, "axis_models", path)
    if not isinstance(table, dict) or sorted(table) != sorted(outputs):
        raise RuntimeInputError(f"{path}: metadata 'axis_models' is not a mapping of the "
                                f"outputs {outputs} to candidate labels")
    return {a: None if table[a] is None else _meta_name(table[a], _LABEL, "axis_models", path)
            for a in outputs}


def _finite_number(x: Any) -> bool:
    return not isinstance(x, bool) and isinstance(x, (int, float)) and math.isfinite(x)


def _meta_band(meta: Mapping[str, str], signals: list[str], outputs: list[str], path: Path
               ) -> dict[str, Any] | None:
    """The validated ``band`` block (None when the file has none): the level, the signal it
    is a function of, per output axis the bin edges, half-widths and growth rates."""
    if "band" not in meta:
        return None
    b = _meta_json(meta, "band", path)
    bad = RuntimeInputError(f"{path}: metadata 'band' is not a band (level in (0, 1), a "
                            "signal of the model, per output axis increasing finite edges, "
                            "finite half-widths and growth rates >= 0)")
    if not isinstance(b, dict) or not _finite_number(b.get("level")) or \
            not 0 < b["level"] < 1 or b.get("signal") not in signals or \
            not isinstance(b.get("axes"), dict) or sorted(b["axes"]) != sorted(outputs):
        raise bad
    for t in b["axes"].values():
        e, h = t.get("edges") if isinstance(t, dict) else None, \
            t.get("half_width") if isinstance(t, dict) else None
        if not isinstance(e, list) or not isinstance(h, list) or len(e) < 2 or \
                len(h) != len(e) - 1 or not all(_finite_number(x) for x in e + h) or \
                any(x2 <= x1 for x1, x2 in zip(e[:-1], e[1:])) or min(h) < 0 or \
                not all(_finite_number(t.get(g)) and t[g] >= 0
                        for g in ("growth_below", "growth_above")):
            raise bad
    held = b.get("holds_for", {})
    if not isinstance(held, dict) or not all(
            held.get(f"{k}_c_per_min") is None or (_finite_number(held[f"{k}_c_per_min"]) and
                                                    held[f"{k}_c_per_min"] >= 0)
            for k in ("heating", "cooling")):
        raise RuntimeInputError(f"{path}: metadata 'band' key 'holds_for' is not a rate >= 0 "
                                "or null per direction (heating_c_per_min, cooling_c_per_min)")
    return b


def band_holds_rule(held: Mapping[str, Any], rate_c_per_min: Any, direction: Any
                    ) -> np.ndarray:
    """Where a band holds (thermonet.scoring.band_rates.outside_holds, the same rule, and
    the C header's <prefix>_band_holds): a window of a temperature that never moved
    (direction 0), or in a judged direction no faster than its judged rate; a direction
    never judged (null), or one that is not −1, 0 or +1, is outside; so is a rate that is
    not finite (NaN: unknown — a window of one time, a NaN temperature — or ±inf), whatever
    the direction.  Nothing stated: wherever the rate is finite."""
    r = np.abs(np.asarray(rate_c_per_min, dtype=np.float64))
    d = np.asarray(direction)
    out = np.broadcast_to(np.isfinite(r), np.broadcast(r, d).shape).copy()
    if not held:
        return out
    out &= np.isin(d, (-1, 0, 1))
    for name, sign in (("heating", 1), ("cooling", -1)):
        top = held.get(f"{name}_c_per_min")
        out &= ~((d == sign) & (True if top is None else r > top))
    return out


def band_tables(x: Any, edges: Sequence[float], half: Sequence[float], grow_lo: float,
                grow_hi: float) -> np.ndarray:
    """The band at ``x``: piecewise constant over ``edges``, growing linearly past them,
    NaN at NaN and at ±inf — a missing or broken reading, as the C header's
    ``<prefix>_band`` (thermonet.scoring.band.evaluate_tables, the same rule inside)."""
    x = np.asarray(x, dtype=np.float64)
    e = np.asarray(edges, dtype=np.float64)
    h = np.asarray(half, dtype=np.float64)
    k = np.clip(np.searchsorted(e[1:-1], x, side="right"), 0, h.size - 1)
    out = np.where(x < e[0], h[0] + grow_lo * (e[0] - x),
                   np.where(x > e[-1], h[-1] + grow_hi * (x - e[-1]), h[k]))
    return np.where(np.isfinite(x), out, np.nan)


def _meta_ranges(meta: Mapping[str, str], path: Path) -> dict[str, list[float]]:
    ranges = _meta_json(meta, "trained_range", path)
    if not isinstance(ranges, dict):
        raise RuntimeInputError(f"{path}: metadata 'trained_range' is not a mapping")
    out: dict[str, list[float]] = {}
    for name, pair in ranges.items():
        _meta_name(name, _SIGNAL, "trained_range", path)
        ok = isinstance(pair, list) and len(pair) == 2 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in pair)
        if not ok or not pair[0] <= pair[1]:
            raise RuntimeInputError(f"{path}: metadata 'trained_range' of '{name}' is "
                                    f"{pair!r}, expected [low, high] with low <= high")
        out[name] = [float(pair[0]), float(pair[1])]
    return out


class Compensator:
    """A loaded thermonet model, checked before its first use.

    Parameters
    ----------
    path : str or Path
        The ``.onnx`` file written by ``thermonet.exporting.export_onnx``.
    providers : sequence of str
        onnxruntime execution providers, in order of preference.  Named
        explicitly (default CPU only) so that a GPU build of onnxruntime does
        not silently move a tiny model onto a device.
    threads : int
        Intra-op threads.  1 (default) suits an on-board loop: these models
        are a few hundred flops per sample and thread start-up costs more.

    Raises
    ------
    RuntimeInputError
        Not a thermonet model, an unknown format or opset, or graph inputs
        and outputs that do not match the metadata (a tampered file).
    """

    def __init__(self, path: str | Path, *, providers: Sequence[str] = ("CPUExecutionProvider",),
                 threads: int = 1) -> None:
        self.path = Path(path)
        _check_regular(self.path, "model file")
        if int(threads) < 1:
            raise RuntimeInputError(f"threads must be >= 1, got {threads}")
        options = ort.SessionOptions()
        options.intra_op_num_threads = int(threads)
        options.inter_op_num_threads = 1
        # Warnings only: onnxruntime's info-level log is noise in a flight log.
        options.log_severity_level = 3
        try:
            self._session = ort.InferenceSession(str(self.path), sess_options=options,
                                                 providers=list(providers))
        except Exception as exc:  # onnxruntime raises its own untyped errors for any bad file
            raise RuntimeInputError(f"{self.path}: onnxruntime cannot load it "
                                    f"({type(exc).__name__}: {str(exc).splitlines()[0]})") from None
        self.metadata: dict[str, str] = dict(self._session.get_modelmeta().custom_metadata_map)
        self._check_metadata()
        self._check_digest()
        self._check_band_scale()

    # -- checks -------------------------------------------------------------------------------
    def _check_band_scale(self) -> None:
        """Band values no residual can make are refused (:data:`BAND_MAX_FACTOR`): a
        half-width, or a growth rate across the signal's trained span, beyond a float32 or
        beyond that factor times the model's own largest drift over its trained range (the
        graph run on every signal's range, raw zero) — the band is estimated from the
        model's residuals, never this much wider than its drift."""
        b = self.band_tables
        if b is None:
            return
        n = 257
        feeds: dict[str, np.ndarray] = {
            s: np.linspace(self.trained_range[s][0], self.trained_range[s][1], n).astype(
                np.float32) for s in self.signals}
        feeds[RAW_INPUT] = np.zeros((n, len(self.outputs)), dtype=self._raw_dtype)
        if self.recurrent:
            feeds[self.recurrent["state_input"]] = np.zeros(
                (n, int(self.recurrent["hidden"])), dtype=np.float32)
        drift = np.asarray(self._session.run(["drift"], feeds)[0], dtype=np.float64)
        lo, hi = self.trained_range[b["signal"]]
        for j, axis in enumerate(self.outputs):
            d = drift[:, j][np.isfinite(drift[:, j])]
            scale = float(max(np.max(np.abs(d)), np.ptp(d))) if d.size else 0.0
            t = b["axes"][axis]
            for what, value in [("half-width", max(t["half_width"]))] + [
                    (f"{g} x the trained span", t[g] * (hi - lo))
                    for g in ("growth_below", "growth_above")]:
                if value > FLOAT32_MAX:
                    why = "beyond a float32"
                elif scale > 0 and value > BAND_MAX_FACTOR * scale:
                    why = (f"{value / scale:.3g} times the model's largest drift over its "
                           f"trained range ({scale:.4g})")
                else:
                    continue
                raise RuntimeInputError(f"{self.path}: metadata 'band' of '{axis}': {what} "
                                        f"{value:.4g} is {why}; no residual of this model "
                                        "makes such a band (edited after export?)")

    def _check_digest(self) -> None:
        """The file's own SHA-256 (``thermonet_sha256``: the digest of its bytes with those 64
        hex digits as zeros): a file edited after export (a weight by hand) is refused, and
        so is one without a digest (re-export it, or re-seal a trusted one with
        ``thermonet.exporting.onnx_export.seal_onnx``)."""
        import hashlib

        path, digest = self.path, self.metadata.get("thermonet_sha256")
        if digest is None:
            raise RuntimeInputError(f"{path}: carries no integrity digest ('thermonet_sha256'; "
                                    "exported by an older thermonet, or removed); re-export "
                                    "the model")
        data = path.read_bytes()
        if re.fullmatch(r"[0-9a-f]{64}", digest) is None or data.count(digest.encode()) != 1 \
                or hashlib.sha256(data.replace(digest.encode(), b"0" * 64)).hexdigest() != digest:
            raise RuntimeInputError(f"{path}: content does not match its SHA-256 digest (edited "
                                    "or damaged after export); refusing to run it")

    def _check_metadata(self) -> None:
        meta, path = self.metadata, self.path
        fmt = meta.get("thermonet_format")
        if fmt is None:
            raise RuntimeInputError(
                f"{path}: not a thermonet model (no 'thermonet_format' metadata)"
            )
        if fmt not in SUPPORTED_FORMATS:
            raise RuntimeInputError(f"{path}: thermonet_format {fmt!r} is not supported by this "
                                    f"runtime (supports {', '.join(SUPPORTED_FORMATS)})")
        try:
            opset = int(meta.get("onnx_opset", ""))
        except ValueError:
            raise RuntimeInputError(
                f"{path}: metadata 'onnx_opset' is missing or not an integer"
            ) from None
        if opset not in SUPPORTED_OPSETS:
            raise RuntimeInputError(f"{path}: ONNX opset {opset} is not supported "
                                    f"(supports {SUPPORTED_OPSETS[0]}..{SUPPORTED_OPSETS[-1]})")
        self.family: str = _meta_name(meta.get("family", "?"), _FAMILY, "family", path)
        self.signals: list[str] = _meta_names(meta, "signals", _SIGNAL, path)
        self.outputs: list[str] = _meta_names(meta, "outputs", _AXIS, path)
        self.trained_range: dict[str, list[float]] = _meta_ranges(meta, path)
        self.signal_units: dict[str, str] = _meta_units(meta, "signal_units", _SIGNAL, path)
        self.output_units: dict[str, str] = _meta_units(meta, "output_units", _AXIS, path)
        if not self.signals or not self.outputs:
            raise RuntimeInputError(f"{path}: metadata lists no signals or no outputs")
        #: A per-axis model (family ``per-axis``: one graph summing several candidates, each
        #: computing the axes it owns): {axis: the candidate's label, or None for an axis
        #: left raw}.  None for a single-family model.
        self.axis_models: dict[str, str | None] | None = _meta_axis_models(
            meta, self.outputs, path)
        if (self.family == "per-axis") != (self.axis_models is not None):
            raise RuntimeInputError(f"{path}: family {self.family!r} with"
                                    f"{'' if self.axis_models is not None else 'out'} an "
                                    "'axis_models' table")
        #: The residual-drift band (metadata ``band``), or None: :meth:`band`.
        self.band_tables: dict[str, Any] | None = _meta_band(meta, self.signals, self.outputs,
                                                              path)
        block = _meta_json(meta, "dynamic_inputs", path) if "dynamic_inputs" in meta else None
        self.dynamic: dict[str, Any] | None = _check_dynamic(block, self.signals, path)
        #: Graph inputs this runtime computes from time_s and temperature_c.
        self.dynamic_signals: list[str] = [d["signal"] for d in (self.dynamic or {}).get(
            "inputs", [])]
        if "rate_c_per_min" in self.signals and "rate_c_per_min" not in self.dynamic_signals:
            raise RuntimeInputError(f"{path}: the model reads rate_c_per_min but its metadata has "
                                    "no 'dynamic_inputs' definition (exported by an older "
                                    "thermonet); export it again")
        #: What the caller supplies: time_s (models with dynamic inputs), temperature, proxies.
        self.needs: list[str] = (["time_s", "temperature_c"] if self.dynamic else []) + [
            x for x in self.signals if x not in self.dynamic_signals
            and not (self.dynamic and x == "temperature_c")]
        self._stream = _Stream(len(self.dynamic_signals))
        block = _meta_json(meta, "recurrent", path) if "recurrent" in meta else None
        #: A recurrent model's stream constants (hidden, step_s, gap_s), None for the others.
        self.recurrent: dict[str, Any] | None = _check_recurrent(block, path)
        if self.recurrent and self.dynamic:
            raise RuntimeInputError(f"{path}: a recurrent model with dynamic inputs is not "
                                    "supported")
        state_io = [self.recurrent["state_input"]] if self.recurrent else []
        if self.recurrent:
            self.needs = ["time_s", *self.needs]
            self._rstream = _RecurrentStream(int(self.recurrent["hidden"]))

        graph_inputs = self._session.get_inputs()
        if self.recurrent:
            state_in = graph_inputs[-1]
            if state_in.name != state_io[0] or state_in.type != "tensor(float)" \
                    or len(state_in.shape) != 2 or state_in.shape[1] != self.recurrent["hidden"]:
                raise RuntimeInputError(f"{path}: graph input '{state_in.name}' "
                                        f"{state_in.type} {state_in.shape} is not the state "
                                        f"[N, {self.recurrent['hidden']}] float")
            graph_inputs = graph_inputs[:-1]
        names = [i.name for i in graph_inputs]
        expected = self.signals + [RAW_INPUT]
        if names != expected:
            raise RuntimeInputError(f"{path}: graph inputs {names} do not match the metadata's "
                                    f"{expected}; the file was modified after export")
        # signals are float32; raw is float64 from format 2 on (the drift's float64 constant
        # and raw - drift keep the precision of a large raw value), float32 in format 1
        raw_type = "tensor(float)" if fmt == "1" else "tensor(double)"
        for inp in graph_inputs:
            want = raw_type if inp.name == RAW_INPUT else "tensor(float)"
            if inp.type != want:
                raise RuntimeInputError(f"{path}: graph input '{inp.name}' is {inp.type}, "
                                        f"expected {want}")
        self._raw_dtype = np.float32 if fmt == "1" else np.float64
        raw_shape = graph_inputs[-1].shape
        if len(raw_shape) != 2 or raw_shape[1] != len(self.outputs):
            raise RuntimeInputError(f"{path}: graph input 'raw' has shape {raw_shape}, expected "
                                    f"[N, {len(self.outputs)}] for outputs {self.outputs}")
        for inp in graph_inputs[:-1]:
            if len(inp.shape) != 1:
                raise RuntimeInputError(f"{path}: graph input '{inp.name}' has shape {inp.shape}, "
                                        "expected [N]")
        outs = [o.name for o in self._session.get_outputs()]
        want_outs = list(GRAPH_OUTPUTS) + ([self.recurrent["state_output"]] if self.recurrent
                                           else [])
        if outs != want_outs:
            raise RuntimeInputError(f"{path}: graph outputs {outs}, expected {want_outs}")
        for name in self.signals:
            if name not in self.trained_range:
                raise RuntimeInputError(
                    f"{path}: metadata 'trained_range' has no entry for '{name}'"
                )

    @staticmethod
    def _as_float32(name: str, values: Any, dtype: Any = np.float32) -> np.ndarray:
        if isinstance(values, np.ma.MaskedArray):
            # a masked sample is a missing sample: NaN in, NaN out, flag set
            values = values.astype(np.float64).filled(np.nan)
        try:
            arr = np.asarray(values)
        except ValueError as exc:  # ragged nested lists
            raise RuntimeInputError(f"input '{name}' is not a rectangular array "
                                    f"({str(exc).splitlines()[0]})") from None
        if arr.dtype == dtype:
            return arr
        if arr.dtype.kind not in "fiu":
            raise RuntimeInputError(f"input '{name}' has dtype {arr.dtype}; expected numbers")
        # Explicit cast to the graph input's type (float32 signals, float64 raw from format 2):
        # onnxruntime refuses any other.  A value beyond float32 (1e39) becomes ±inf, which
        # the graph flags with a NaN drift as any non-finite signal: no numpy warning for it
        with np.errstate(over="ignore"):
            return arr.astype(dtype)

    # -- evaluation ---------------------------------------------------------------------------
    def compensate(self, temperature_c: Any = None, raw: Any = None, *, time_s: Any = None,
                   proxy: Any = None, rate: Any = None, **signals: Any) -> Compensation:
        """Compensate one sample or a batch (a whole sequence for dynamic inputs).

        Parameters
        ----------
        temperature_c : float or array (N,), optional
            Device temperature in °C (when the model uses it).
        raw : array (A,) or (N, A)
            Raw outputs, one column per axis in the order of :attr:`outputs`.
        time_s : array (N,), optional
            Sample times in seconds, finite and strictly increasing; required
            by a model with dynamic inputs (:attr:`dynamic_signals`), which are
            computed from it and ``temperature_c`` as one stream starting at
            the first sample (use :meth:`step` to carry state across calls).
        proxy : float, array (N,) or dict, optional
            The proxy signal (e.g. ``freq_hz`` in Hz) for a model with exactly
            one proxy, or a dict ``{name: values}``.
        rate : never
            Dynamic signals are computed, not passed (kept for a clear error).
        **signals
            Any proxy by its own name (``freq_hz=...``).

        Returns
        -------
        Compensation
            ``compensated``, ``drift`` (float64; float32 for a format-1 file) and
            ``out_of_range`` (bool; also true at the first sample after a gap in
            time).  One sample (scalar signals and 1-D ``raw``) gives 1-D arrays
            and a plain bool.

        Raises
        ------
        RuntimeInputError
            A missing or unknown signal, missing or bad time, a non-numeric
            dtype or inconsistent shapes.
        """
        given = self._collect(temperature_c, proxy, rate, signals)
        raw_arr, single = self._raw(raw)
        gap = None
        if self.recurrent:
            if time_s is None:
                raise RuntimeInputError("missing 'time_s': this model carries a state in time "
                                        "(seconds, strictly increasing)")
            t = self._as_float32("time_s", time_s, np.float64) if np.ndim(time_s) else \
                np.full(1, _scalar("time_s", time_s))
            return self._evaluate_recurrent(given, raw_arr, single, _check_time(t))
        if self.dynamic:
            if time_s is None:
                raise RuntimeInputError(
                    f"missing 'time_s': this model's dynamic input(s) {self.dynamic_signals} "
                    "are computed from time_s (seconds, strictly increasing) and temperature_c")
            temp = self._as_float32("temperature_c", given["temperature_c"]).astype(np.float64)
            t = self._as_float32("time_s", time_s, np.float64) if np.ndim(time_s) else \
                np.full(1, _scalar("time_s", time_s))
            if temp.ndim == 0:
                temp = np.full(t.shape, float(temp))
            if t.shape != (raw_arr.shape[0],) or temp.shape != t.shape:
                raise RuntimeInputError(f"time_s has shape {t.shape}, temperature_c "
                                        f"{temp.shape}; expected ({raw_arr.shape[0]},) to match "
                                        "'raw'")
            values, gap = dynamic_signals(t, temp, self.dynamic)
            given.update(values)
        elif time_s is not None:
            _check_time(np.atleast_1d(self._as_float32("time_s", time_s, np.float64)))
        return self._evaluate(given, raw_arr, single, gap)

    def step(self, time_s: float, temperature_c: float, raw: Any, *, proxy: Any = None,
             **signals: Any) -> Compensation:
        """Compensate one sample of a stream, keeping the dynamic inputs' state.

        The first call (and the first after :meth:`reset`) starts the state;
        a sample whose time is not after the previous one is refused and leaves
        the state unchanged; a sample more than ``gap_s`` after the last one
        with a finite temperature restarts the state and raises the flag.

        Returns
        -------
        Compensation
            1-D ``compensated`` and ``drift`` (A,), plain bool ``out_of_range``.
        """
        given = self._collect(temperature_c, proxy, None, signals)
        raw_arr, single = self._raw(raw)
        if not single:
            raise RuntimeInputError(f"step() takes one sample: 'raw' must have shape "
                                    f"({len(self.outputs)},), got {np.shape(raw)}")
        try:
            t = _scalar("time_s", time_s)
            temp = _scalar("temperature_c", given.get("temperature_c", np.nan))
        except RuntimeInputError as exc:
            raise RuntimeInputError(f"step(): {exc}") from None
        if self.recurrent:
            return self._step_recurrent(t, given, raw_arr)
        values, gap = self._stream.update(t, temp, self.dynamic or _STATIC)
        given.update(values)
        return self._evaluate(given, raw_arr, True, np.array([gap]))

    def step_block(self, time_s: Any, temperature_c: Any, raw: Any, *, proxy: Any = None,
                   **signals: Any) -> Compensation:
        """Compensate the next block of N samples of a stream, carrying the state across blocks.

        The streaming mode for a long recording: the same results as :meth:`step` sample
        by sample (and as one :meth:`compensate` call on the whole sequence, within float64
        rounding of the dynamic inputs), at batch speed — one onnxruntime call per block,
        the dynamic inputs by the vectorised scans started from the carried state.  Blocks
        of any length (1 included) follow one another and :meth:`step` calls; a block is
        refused whole (state unchanged) when its time is not finite and strictly
        increasing from the previous sample on.  ``temperature_c`` is read as float32, as
        :meth:`compensate` reads it.

        Returns
        -------
        Compensation
            ``compensated`` and ``drift`` (N, A), ``out_of_range`` (N,) bool.
        """
        given = self._collect(temperature_c, proxy, None, signals)
        raw_arr, single = self._raw(raw)
        if single:
            raise RuntimeInputError(f"step_block() takes a block: 'raw' must have shape "
                                    f"(N, {len(self.outputs)}), got {np.shape(raw)}")
        t = self._as_float32("time_s", time_s, np.float64)
        temp = self._as_float32("temperature_c", given.get("temperature_c", np.full(
            t.shape, np.nan)), np.float32).astype(np.float64)
        if t.shape != (raw_arr.shape[0],) or temp.shape != t.shape:
            raise RuntimeInputError(f"step_block(): time_s has shape {t.shape}, temperature_c "
                                    f"{temp.shape}; expected ({raw_arr.shape[0]},) to match "
                                    "'raw'")
        if self.recurrent:
            return self._step_block_recurrent(t, given, raw_arr)
        # the block runs on a copy of the state, kept only once the whole block has succeeded
        trial = _Stream(len(self._stream.state))
        for key in _Stream.__slots__:
            setattr(trial, key, getattr(self._stream, key))
        trial.state = list(self._stream.state)
        values, gap = dynamic_signals(t, temp, self.dynamic or _STATIC,
                                      trial)
        given.update(values)
        res = self._evaluate(given, raw_arr, False, gap)
        self._stream = trial
        return res

    def reset(self) -> None:
        """Forget the stream's state: the next :meth:`step` starts afresh."""
        self._stream = _Stream(len(self.dynamic_signals))
        if self.recurrent:
            self._rstream = _RecurrentStream(int(self.recurrent["hidden"]))

    # -- recurrent models: one graph call per window (batch) or per sample (step) ----------
    def _signal_matrix(self, given: Mapping[str, Any], n: int) -> np.ndarray:
        cols = []
        for name in self.signals:
            arr = np.asarray(self._as_float32(name, given[name], np.float64), dtype=np.float64)
            arr = np.full(n, float(arr)) if arr.ndim == 0 else arr
            if arr.shape != (n,):
                raise RuntimeInputError(f"signal '{name}' has shape {arr.shape}; expected ({n},) "
                                        "to match 'raw'")
            cols.append(arr)
        return np.stack(cols, axis=1)

    def _run_step(self, signals: np.ndarray, raw: np.ndarray, state: np.ndarray
                  ) -> list[np.ndarray]:
        rec = self.recurrent or {}
        with np.errstate(over="ignore"):    # beyond float32: ±inf, flagged by the graph
            feeds = {name: np.ascontiguousarray(signals[:, i], dtype=np.float32)
                     for i, name in enumerate(self.signals)}
        feeds[RAW_INPUT] = np.ascontiguousarray(raw)
        feeds[rec["state_input"]] = np.ascontiguousarray(state, dtype=np.float32)
        return list(self._session.run(None, feeds))

    def _evaluate_recurrent(self, given: Mapping[str, Any], raw_arr: np.ndarray, single: bool,
                            t: np.ndarray) -> Compensation:
        """A whole sequence as one stream from a fresh state (``step`` carries it across
        calls): each window's samples in one graph call from the state committed before it."""
        rec = self.recurrent or {}
        n = raw_arr.shape[0]
        if t.shape != (n,):
            raise RuntimeInputError(f"time_s has shape {t.shape}; expected ({n},) to match 'raw'")
        sig = self._signal_matrix(given, n)
        comp = np.full(raw_arr.shape, np.nan, dtype=self._raw_dtype)
        drift = comp.copy()
        flag = np.ones(n, dtype=bool)
        idx, restart, window = recurrent_windows(t, np.all(np.isfinite(sig), axis=1),
                                                 float(rec["step_s"]), float(rec["gap_s"]))
        starts = np.flatnonzero(np.append(True, window[1:] != window[:-1]))
        h = np.zeros(int(rec["hidden"]), dtype=np.float32)
        for a, b in zip(starts, np.append(starts[1:], idx.size)):
            rows = idx[a:b]
            vals = sig[rows]
            mean = vals[0] + np.cumsum(vals - vals[0], axis=0) / np.arange(1, b - a + 1)[:, None]
            if restart[a]:
                h = np.zeros_like(h)
            c, d, f, h_out = self._run_step(mean, raw_arr[rows], np.tile(h, (b - a, 1)))
            comp[rows], drift[rows] = c, d
            flag[rows] = f.astype(bool)
            flag[rows[0]] |= bool(restart[a]) and a > 0          # a gap restarted the state
            h = h_out[-1]
        if single:
            return Compensation(comp[0], drift[0], bool(flag[0]))
        return Compensation(comp, drift, flag)

    def _step_block_recurrent(self, t: np.ndarray, given: Mapping[str, Any],
                              raw_arr: np.ndarray) -> Compensation:
        """A block of a recurrent model: its samples through :meth:`_step_recurrent` one by
        one (the state lives in the graph's input and output, advanced once per window), on a
        copy of the stream kept only once the whole block has succeeded."""
        import copy

        n = t.shape[0]
        sig = self._signal_matrix(given, n)
        saved = copy.deepcopy(self._rstream)
        comp = np.empty((n, len(self.outputs)), dtype=self._raw_dtype)
        drift = np.empty_like(comp)
        flag = np.zeros(n, dtype=bool)
        try:
            for k in range(n):
                one = {name: sig[k, j] for j, name in enumerate(self.signals)}
                r = self._step_recurrent(float(t[k]), one, raw_arr[k:k + 1])
                comp[k], drift[k], flag[k] = r.compensated, r.drift, r.out_of_range
        except RuntimeInputError:
            self._rstream = saved
            raise
        return Compensation(comp, drift, flag)

    def _step_recurrent(self, t: float, given: Mapping[str, Any], raw_arr: np.ndarray
                        ) -> Compensation:
        rec = self.recurrent or {}
        sig = self._signal_matrix(given, 1)[0]
        mean, gap = self._rstream.update(t, sig, rec)
        if mean is None:                    # a missing sample: NaN, flag, state unchanged
            nan = np.full(len(self.outputs), np.nan, dtype=self._raw_dtype)
            return Compensation(nan, nan.copy(), True)
        c, d, f, h_out = self._run_step(mean[None, :], raw_arr, self._rstream.h[None, :])
        self._rstream.h_next = h_out[0]
        return Compensation(c[0], d[0], bool(f[0]) or gap)

    def _collect(self, temperature_c: Any, proxy: Any, rate: Any, signals: Mapping[str, Any]
                 ) -> dict[str, Any]:
        given: dict[str, Any] = {}

        def put(name: str, value: Any) -> None:
            name = _ALIASES.get(name, name)
            if name in given:  # e.g. rate= and rate_c_per_min=: never guess which one is meant
                raise RuntimeInputError(f"signal '{name}' given twice")
            given[name] = value

        for key, value in signals.items():
            put(key, value)
        if temperature_c is not None:
            put("temperature_c", temperature_c)
        if rate is not None:
            put("rate_c_per_min", rate)
        if proxy is not None:
            proxies = [s for s in self.signals
                       if s not in ("temperature_c", "rate_c_per_min", *self.dynamic_signals)]
            if isinstance(proxy, Mapping):
                for key, value in proxy.items():
                    put(key, value)
            elif len(proxies) == 1:
                put(proxies[0], proxy)
            else:
                raise RuntimeInputError(f"proxy= given but the model has proxies {proxies}; "
                                        "pass them by name")
        computed = sorted(set(given) & set(self.dynamic_signals))
        if computed:
            raise RuntimeInputError(f"signal(s) {computed} are computed by the runtime from "
                                    "time_s and temperature_c; pass time_s, not the signal")
        unknown = sorted(set(given) - set(self.signals) - {"temperature_c"})
        if "temperature_c" in given and "temperature_c" not in self.needs:
            unknown = sorted(set(unknown) | {"temperature_c"})
        if unknown:
            raise RuntimeInputError(f"unknown signal(s) {unknown}; this model uses {self.needs}")
        missing = [s for s in self.needs if s != "time_s" and s not in given]
        if missing:
            raise RuntimeInputError(f"missing signal(s) {missing}; this model uses {self.needs}")
        return given

    def _raw(self, raw: Any) -> tuple[np.ndarray, bool]:
        if raw is None:
            raise RuntimeInputError(f"missing 'raw' (one value per axis {self.outputs})")
        n_axes = len(self.outputs)
        raw_arr = self._as_float32("raw", raw, self._raw_dtype)
        single = raw_arr.ndim == 1
        if single:
            raw_arr = raw_arr.reshape(1, -1)
        if raw_arr.ndim != 2 or raw_arr.shape[1] != n_axes:
            raise RuntimeInputError(f"'raw' has shape {np.shape(raw)}; expected ({n_axes},) or "
                                    f"(N, {n_axes}) for axes {self.outputs}")
        return raw_arr, single

    def _evaluate(self, given: Mapping[str, Any], raw_arr: np.ndarray, single: bool,
                  gap: np.ndarray | None) -> Compensation:
        n, n_axes = raw_arr.shape[0], len(self.outputs)
        feeds: dict[str, np.ndarray] = {}
        for name in self.signals:
            arr = self._as_float32(name, given[name])
            if arr.ndim == 0:
                arr = np.full(n, arr, dtype=np.float32) if not single else arr.reshape(1)
            if arr.ndim != 1 or arr.shape[0] != n:
                raise RuntimeInputError(f"signal '{name}' has shape {arr.shape}; expected ({n},) "
                                        "to match 'raw'")
            feeds[name] = np.ascontiguousarray(arr)
        feeds[RAW_INPUT] = np.ascontiguousarray(raw_arr)

        if n == 0:
            # onnxruntime's broadcasting of empty tensors is not uniform across ops; an
            # empty batch has a well-defined answer without running the graph.
            empty = np.zeros((0, n_axes), dtype=self._raw_dtype)
            return Compensation(empty, empty.copy(), np.zeros(0, dtype=bool),
                                None if self.band_tables is None else np.zeros((0, n_axes)))
        comp, drift, flag = self._session.run(list(GRAPH_OUTPUTS), feeds)
        flag = flag.astype(bool)
        if gap is not None:
            flag = flag | gap
        if single:
            res = Compensation(comp[0], drift[0], bool(flag[0]))
            return self._with_band(res, {k: np.asarray(v).reshape(-1)[0] for k, v in
                                         feeds.items() if k != RAW_INPUT})
        return self._with_band(Compensation(comp, drift, flag), feeds)

    def band(self, signal: Any) -> np.ndarray:
        """Half-width of the residual-drift band (A,) for one value or (N, A) for an array of
        the band's signal (``band_tables['signal']``: temperature for most models, another
        signal such as ``freq_hz`` for a model on a proxy, in that signal's unit): a window
        mean of the corrected output's residual lies within ± it of the run's mean residual
        for ``band_tables['level']`` of the windows on runs like the training runs; wider past
        the trained range; NaN at NaN or ±inf.  Refused for a file without one."""
        b = self.band_tables
        if b is None:
            raise RuntimeInputError(f"{self.path}: this model file carries no band (export it "
                                    "from a compare checkpoint made with cross-validation)")
        x = np.asarray(self._as_float32(b["signal"], signal, np.float64), dtype=np.float64)
        cols = [band_tables(x, t["edges"], t["half_width"], t["growth_below"],
                            t["growth_above"]) for t in (b["axes"][a] for a in self.outputs)]
        return np.stack(cols, axis=-1)

    def band_holds(self, rate_c_per_min: Any, direction: Any) -> np.ndarray:
        """Whether the band holds for windows of this temperature rate (°C/min, a window's
        least-squares slope over ``band_tables['window_s']``) and excursion direction (+1
        heating since the last turn, −1 cooling, 0 a temperature that never moved): it was
        judged up to ``band_tables['holds_for']``'s rate per direction, never in a direction
        that is null there (:func:`band_holds_rule`); False for a rate that is not finite
        (NaN: unknown).  A file whose band does not record it: True wherever the rate is
        finite.  Refused for a file without a band."""
        b = self.band_tables
        if b is None:
            raise RuntimeInputError(f"{self.path}: this model file carries no band (export it "
                                    "from a compare checkpoint made with cross-validation)")
        try:
            r = np.asarray(rate_c_per_min, dtype=np.float64)
            d = np.asarray(direction, dtype=np.float64)
            np.broadcast(r, d)
        except (TypeError, ValueError):
            raise RuntimeInputError("band_holds: rate_c_per_min and direction must be numbers "
                                    "(or arrays of one shape)") from None
        if not np.isin(d, (-1.0, 0.0, 1.0)).all():
            bad = d[~np.isin(d, (-1.0, 0.0, 1.0))].ravel()[0]
            raise RuntimeInputError(f"band_holds: direction {bad:g} is not -1 (cooling), 0 "
                                    "(never moved) or +1 (heating)")
        return band_holds_rule(b.get("holds_for") or {}, r, d)

    def _with_band(self, res: Compensation, given: Mapping[str, Any]) -> Compensation:
        if self.band_tables is not None and self.band_tables["signal"] in given:
            x = np.asarray(self._as_float32(self.band_tables["signal"],
                                            given[self.band_tables["signal"]]), np.float64)
            if x.ndim == 0 and np.ndim(res.drift) == 2:
                x = np.full(res.drift.shape[0], float(x))
            res.band = self.band(x)
        return res

    def __repr__(self) -> str:
        return (f"Compensator({str(self.path)!r}, family={self.family!r}, signals={self.signals}, "
                f"outputs={self.outputs})")


def time_batch(compensator: Compensator, batch_size: int = 1000, *, repeats: int = 50,
               seed: int = 0) -> float:
    """Median seconds of one ``compensate`` call on a batch inside the trained range.

    Used by the benchmarks; the first call (graph warm-up) is not counted.
    """
    rng = np.random.default_rng(seed)
    sig: dict[str, Any] = {
        s: rng.uniform(*compensator.trained_range.get(s, (20.0, 30.0)),
                       size=batch_size).astype(np.float32)
        for s in compensator.needs if s != "time_s"}
    if "time_s" in compensator.needs:
        sig["time_s"] = np.arange(batch_size, dtype=np.float64)
    raw = np.zeros((batch_size, len(compensator.outputs)), dtype=compensator._raw_dtype)
    compensator.compensate(raw=raw, **sig)
    times = []
    for _ in range(max(1, int(repeats))):
        t0 = time.perf_counter()
        compensator.compensate(raw=raw, **sig)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


# -- command line -----------------------------------------------------------------------------
def _check_regular(path: Path, what: str) -> None:
    """Refuse a missing path, a directory, a FIFO or a device by what it is (a FIFO would block)."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise RuntimeInputError(f"{path}: no such {what}") from None
    except OSError as exc:
        raise RuntimeInputError(f"{path}: cannot read ({exc.strerror})") from None
    if stat.S_ISDIR(mode):
        raise RuntimeInputError(f"{path}: is a directory, not a {what}")
    if not stat.S_ISREG(mode):
        kind = "a FIFO" if stat.S_ISFIFO(mode) else "a device" if (
            stat.S_ISCHR(mode) or stat.S_ISBLK(mode)) else "not a regular file"
        raise RuntimeInputError(f"{path}: is {kind}, not a {what}")


#: Files the command cannot read, by their first bytes: what each is, and what ``thermonet
#: convert`` needs beside the file to read it (a log's sensor instance, a mapping).
_BINARY = ((b"PAR1", "a Parquet file", "", ""),
           (b"\x89HDF\r\n\x1a\n", "an HDF5 file", "", " --mapping MAP"),
           (b"ULog", "a PX4 ULog flight log", "#<instance>", ""))


def _to_csv(path: Path, instance: str = "", mapping: str = "") -> str:
    """How to make the CSV this runtime reads from a recording it cannot: thermonet (not
    this runtime) reads them all."""
    out = path.with_suffix(".csv") if path.suffix.lower() != ".csv" else path.with_name(
        f"{path.stem}_comma.csv")
    return f"thermonet convert {path}{instance}{mapping} --out {out} writes one"


def _csv_text(path: Path) -> str:
    """The file's text: a UTF-8 CSV; a Parquet or other binary recording, a BOM or another
    encoding refused in one line saying what it is and what to do."""
    _check_regular(path, "CSV file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RuntimeInputError(f"{path}: cannot read ({exc.strerror})") from None
    for magic, what, instance, mapping in _BINARY:
        if data.startswith(magic):
            raise RuntimeInputError(f"{path}: {what}, not CSV; this runtime reads CSV only "
                                    f"(numpy and onnxruntime, no other reader): "
                                    f"{_to_csv(path, instance, mapping)}")
    if data.startswith(b"\xef\xbb\xbf"):
        raise RuntimeInputError(f"{path}: starts with a UTF-8 byte-order mark; save it as plain "
                                "UTF-8 CSV without BOM")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RuntimeInputError(f"{path}: not UTF-8 text (byte {exc.start}): not a CSV file, "
                                "or saved in another encoding; save it as UTF-8 CSV") from None


def _csv_header(path: Path, first: list[str]) -> list[str]:
    """The header's column names: another separator (';', a tab) or a name given twice
    refused in one line naming it."""
    if len(first) == 1:
        for sep, name in ((";", "';'"), ("\t", "tabs (a tab-separated file)")):
            if sep in first[0]:
                raise RuntimeInputError(f"{path}: the header is separated by {name}; this "
                                        "runtime reads comma-separated CSV: save it with ',' "
                                        f"as the separator ({_to_csv(path)})")
    header = [h.strip() for h in first]
    seen: dict[str, int] = {}
    for j, name in enumerate(header):
        if name and name in seen:   # empty names: a trailing separator, never read
            raise RuntimeInputError(f"{path}: column '{name}': duplicate column in the header "
                                    f"(columns {seen[name] + 1} and {j + 1}); rename or remove "
                                    "one")
        seen[name] = j
    return header


def _row(i: int, lines: Sequence[int]) -> str:
    """Data row ``i`` (0-based) as thermonet's readers name a row: the 1-based data row and
    the file line it starts on (blank lines are skipped, a header is line 1)."""
    return f"row {i + 1} (file line {lines[i]})"


def _read_csv(
    path: Path, needed: list[str]
) -> tuple[list[str], list[list[str]], dict[str, np.ndarray], list[int]]:
    reader = csv.reader(_csv_text(path).splitlines())
    rows = [(reader.line_num, r) for r in reader]   # the line a row ends on: one line each
    if not rows:
        raise RuntimeInputError(f"{path}: empty file (expected a header row)")
    header = _csv_header(path, rows[0][1])
    kept = [(n, r) for n, r in rows[1:] if any(c.strip() for c in r)]
    body, lines = [r for _, r in kept], [n for n, _ in kept]
    for name in needed:
        if name not in header:
            raise RuntimeInputError(f"{path}: missing column '{name}' (needs {', '.join(needed)})")
    for i, row in enumerate(body):
        # a trailing separator gives an empty extra cell; anything more is a misaligned row
        if len(row) > len(header) and any(c.strip() for c in row[len(header):]):
            raise RuntimeInputError(f"{path}: {_row(i, lines)}: {len(row)} cells, the header "
                                    f"has {len(header)}")
        if len(row) < len(header):  # a missing sample is an empty cell, never a short row
            raise RuntimeInputError(f"{path}: {_row(i, lines)}: {len(row)} cells, the header "
                                    f"has {len(header)}: a truncated row (write an empty cell "
                                    "for a missing sample)")
        del row[len(header):]
    cols: dict[str, np.ndarray] = {}
    for name in needed:
        j = header.index(name)
        values = np.empty(len(body), dtype=np.float64)
        for i, row in enumerate(body):
            # an empty cell (or nan, NA …) is a missing sample: NaN out, flag set
            try:
                values[i] = parse_number(row[j])
            except ValueError as exc:
                raise RuntimeInputError(f"{path}: column '{name}', {_row(i, lines)}: "
                                        f"{exc}") from None
        cols[name] = values
    return header, body, cols, lines


class _Stopped(BaseException):
    """SIGINT or SIGTERM arrived (raised by the handler :func:`main` installs)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _stop(signum: int, frame: object) -> None:
    raise _Stopped(signum)


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


def _refuse_inputs(out: Path, tmp: Path, inputs: Sequence[Path]) -> None:
    """An output (or its temporary file) that is an input is refused before anything is written."""
    for inp in inputs:
        if not os.path.lexists(inp):
            continue
        for path, what in ((out, "the output"), (tmp, f"the output's temporary file {tmp}")):
            if _same_file(path, inp):
                raise RuntimeInputError(f"{out}: {what} is the input {inp}; refusing to "
                                        "overwrite an input (nothing written)")


def _check_out(out: Path) -> None:
    """An ``--out`` that cannot be created is refused, naming it, before the model is run:
    a directory, or a path whose directory does not exist or is not one."""
    if out.is_dir():
        raise RuntimeInputError(f"{out}: --out is a directory; give a file name")
    parent = out.parent
    if not parent.is_dir():
        what = "does not exist" if not os.path.lexists(parent) else "is not a directory"
        raise RuntimeInputError(f"{out}: cannot be created: its directory {parent} {what}")


#: Temperatures (°C) outside this range are implausible for a sensor (Kelvin? °F? m°C?):
#: thermonet.data.diagnostics.TEMPERATURE_PLAUSIBLE_C, whose hint ``thermonet info`` gives.
TEMPERATURE_PLAUSIBLE_C = (-100.0, 200.0)


def temperature_hint(lo: float, hi: float) -> str:
    """What a temperature span outside :data:`TEMPERATURE_PLAUSIBLE_C` may be in: every unit
    (Kelvin, °F, m°C) whose conversion lands the whole span in the plausible range
    (thermonet.data.diagnostics.temperature_hint, the same rule; checked by its tests)."""
    lo_ok, hi_ok = TEMPERATURE_PLAUSIBLE_C
    hints = []
    if lo > 0.0 and lo_ok <= lo - 273.15 and hi - 273.15 <= hi_ok:
        hints.append("Kelvin? subtract 273.15")
    if lo_ok <= (lo - 32.0) * 5.0 / 9.0 and (hi - 32.0) * 5.0 / 9.0 <= hi_ok:
        hints.append("°F? subtract 32, then multiply by 5/9")
    if max(abs(lo), abs(hi)) > 1000.0 and lo_ok <= lo / 1000.0 and hi / 1000.0 <= hi_ok:
        hints.append("m°C? divide by 1000")
    return "; or ".join(hints) if hints else "check the temperature column's unit and scale"


def _temperature_warning(path: Path, temp: np.ndarray) -> str | None:
    """A line for a temperature column whose finite values leave the plausible range (a file
    in Kelvin: every row out of the trained range, a plausible-looking run otherwise)."""
    finite = temp[np.isfinite(temp)]
    lo_ok, hi_ok = TEMPERATURE_PLAUSIBLE_C
    if finite.size == 0 or (finite.min() >= lo_ok and finite.max() <= hi_ok):
        return None
    lo, hi = float(finite.min()), float(finite.max())
    return (f"{path}: column 'temperature_c' spans {lo:.4g} … {hi:.4g} °C, outside the "
            f"plausible {lo_ok:g} … {hi_ok:g} °C ({temperature_hint(lo, hi)})")


def _time_warning(path: Path, time_s: np.ndarray, runs: Sequence[slice], gap_s: float
                  ) -> str | None:
    """A line for a ``time_s`` column whose median step is longer than the model's
    ``gap_s`` (a file in milliseconds: the gap rule restarts the state and flags nearly
    every row, and the run exits 0): how many rows come more than ``gap_s`` after the
    previous row of their run, and the unit that would bring the median step within it."""
    steps = np.concatenate([np.diff(time_s[r]) for r in runs] + [np.zeros(0)])
    steps = steps[np.isfinite(steps)]
    if steps.size == 0 or not float(np.median(steps)) > gap_s:
        return None
    med = float(np.median(steps))
    n_gap, n = int(np.count_nonzero(steps > gap_s)), int(time_s.size)
    unit = next((f"time_s in {name}? divide by {factor:g}" for name, factor in
                 (("milliseconds", 1e3), ("microseconds", 1e6)) if med / factor <= gap_s),
                "a log sparser than gap_s, or time_s in another unit")
    return (f"{path}: column 'time_s': the gap rule (a step over the model's gap_s = "
            f"{gap_s:g} s restarts the state, flag set) flags {n_gap} of {n} rows "
            f"({100.0 * n_gap / max(n, 1):.0f} %); the median step is {med:.4g} s ({unit})")


def _input_warnings(comp: Compensator, path: Path, cols: Mapping[str, np.ndarray],
                    runs: Sequence[slice]) -> list[str]:
    """The warning lines of a run that went through (a temperature or a time in another
    unit): :func:`_temperature_warning`, :func:`_time_warning`."""
    out = [_temperature_warning(path, cols["temperature_c"]) if "temperature_c" in cols
           else None]
    gap = (comp.dynamic or comp.recurrent or {}).get("gap_s")
    if "time_s" in cols and gap is not None:
        out.append(_time_warning(path, np.asarray(cols["time_s"], np.float64), runs,
                                 float(gap)))
    return [w for w in out if w is not None]


#: The column naming each row's run (``thermonet convert --out x.csv`` writes it): the rows of
#: a run are one sequence, and the dynamic inputs' (and a recurrent model's) state restarts at
#: the first row of each run, as in training — never carried from one run's end into the next.
RUN_COLUMN = "run"


def _run_slices(path: Path, header: list[str], body: list[list[str]], lines: Sequence[int]
                ) -> list[slice]:
    """The rows of each run, in file order: consecutive rows with the same :data:`RUN_COLUMN`
    cell (all rows, one run, in a file without that column).  A run whose rows are not
    together is refused, naming the row where it comes back."""
    if RUN_COLUMN not in header or not body:
        return [slice(0, len(body))]
    j = header.index(RUN_COLUMN)
    ids = [row[j].strip() if j < len(row) else "" for row in body]
    first: dict[str, int] = {}
    out: list[slice] = []
    start = 0
    for i in range(1, len(ids) + 1):
        if i < len(ids) and ids[i] == ids[start]:
            continue
        if ids[start] in first:
            raise RuntimeInputError(
                f"{path}: column '{RUN_COLUMN}', {_row(start, lines)}: run {ids[start]!r} again "
                f"(its rows began at {_row(first[ids[start]], lines)}); a run's rows must be "
                "together — the state restarts at each run")
        first[ids[start]] = start
        out.append(slice(start, i))
        start = i
    return out


def _compensate_runs(comp: Compensator, path: Path, runs: list[slice], raw: np.ndarray,
                     given: Mapping[str, np.ndarray], lines: Sequence[int]) -> Compensation:
    """:meth:`Compensator.compensate` on each run's rows (each a sequence of its own: the
    state starts afresh at its first row), the results joined in file order; a time that is
    not finite and increasing within a run is refused naming its column and row."""
    parts = []
    for rows in runs:
        sub = {s: v[rows] for s, v in given.items()}
        if "time_s" in sub:
            try:
                _check_time(sub["time_s"])
            except RuntimeInputError as exc:  # name the column and the row
                k = rows.start + int(str(exc).split("sample ", 1)[1].split(":", 1)[0])
                reason = str(exc).split(": ", 2)[-1]
                raise RuntimeInputError(f"{path}: column 'time_s', {_row(k, lines)}: "
                                        f"{reason}") from None
        parts.append(comp.compensate(raw=raw[rows], **sub))
    if len(parts) == 1:
        return parts[0]
    bands = [p.band for p in parts if p.band is not None]
    return Compensation(np.concatenate([p.compensated for p in parts]),
                        np.concatenate([p.drift for p in parts]),
                        np.concatenate([np.atleast_1d(p.out_of_range) for p in parts]),
                        np.concatenate(bands) if len(bands) == len(parts) else None)


def main(argv: Sequence[str] | None = None) -> int:
    """Compensate a CSV file; returns the exit status (0 ok, 1 bad input, 128 + the signal
    number when stopped by SIGINT or SIGTERM).

    The output is written to ``OUT.tmp`` and renamed to ``OUT`` when complete; stopped
    (SIGINT, SIGTERM) or failing on the way, the ``.tmp`` is removed and ``OUT`` is left as
    it was."""
    parser = argparse.ArgumentParser(
        prog="thermonet_runtime",
        description="Apply a thermonet drift model (.onnx) to a CSV of raw sensor outputs.")
    parser.add_argument("model", type=Path, help="the exported .onnx file")
    parser.add_argument("input", type=Path, help="CSV with the model's signal columns (time_s "
                        "and temperature_c for a model with dynamic inputs) and one raw column "
                        "per axis (named by the axis, e.g. gyro_x); a 'run' column (as thermonet "
                        "convert writes) makes each run's rows a sequence of its own")
    parser.add_argument("--out", type=Path, required=True, help="output CSV")
    parser.add_argument("--threads", type=int, default=1, help="onnxruntime threads (default 1)")
    args = parser.parse_args(argv)
    tmp = args.out.with_name(args.out.name + ".tmp")
    written = False                 # True once this run has created tmp (removed unless renamed)
    previous: dict[int, Any] = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, _stop)
    except ValueError:              # not the main thread (an embedding program): signals as they are
        pass
    try:
        _refuse_inputs(args.out, tmp, [args.model, args.input])
        _check_out(args.out)
        comp = Compensator(args.model, threads=args.threads)
        header, body, cols, lines = _read_csv(args.input, comp.needs + comp.outputs)
        raw = np.stack([cols[a] for a in comp.outputs], axis=1) if body else \
            np.zeros((0, len(comp.outputs)))
        given = {s: cols[s] for s in comp.needs}
        runs = _run_slices(args.input, header, body, lines)
        res = _compensate_runs(comp, args.input, runs, raw, given, lines)
        # the residual-drift band where the file carries one (metadata 'band'): per axis, the
        # half-width at the row's band signal — how far the compensated value may still be off
        band = res.band
        extra = [f"{a}_comp" for a in comp.outputs] + [f"{a}_drift" for a in comp.outputs] + \
            ["out_of_range"] + ([] if band is None else [f"{a}_band" for a in comp.outputs])
        clash = sorted(set(extra) & set(header))
        if clash:
            raise RuntimeInputError(f"{args.input}: already has output column(s) {clash}; "
                                    "compensate the raw file, not an output")
        written = True
        with tmp.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(header + extra)
            for i, row in enumerate(body):
                row = list(row) + [""] * (len(header) - len(row))
                writer.writerow(row + [repr(float(v)) for v in res.compensated[i]]
                                + [repr(float(v)) for v in res.drift[i]]
                                + [str(int(res.out_of_range[i]))]
                                + ([] if band is None else [repr(float(v)) for v in band[i]]))
        tmp.replace(args.out)
        written = False
        warnings = _input_warnings(comp, args.input, cols, runs)
    except _Stopped as exc:
        print(f"thermonet_runtime: stopped by {signal.Signals(exc.signum).name}; {args.out} not "
              "written", file=sys.stderr)
        return 128 + exc.signum
    except RuntimeInputError as exc:
        print(f"thermonet_runtime: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:   # the output's temporary file is ours: name the user's --out
        name = args.out if exc.filename in (str(tmp), tmp) else exc.filename
        print(f"thermonet_runtime: {name}: {exc.strerror}", file=sys.stderr)
        return 1
    finally:
        if written:
            tmp.unlink(missing_ok=True)
        for sig, handler in previous.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
    for warning in warnings:
        print(f"thermonet_runtime: warning: {warning}", file=sys.stderr)
    n_flag = int(np.count_nonzero(res.out_of_range))
    print(f"{len(body)} rows compensated with {comp.family} model; {n_flag} out of range "
          f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
