"""Signals, features and targets: what a drift model reads and what it predicts.

A drift model maps **physical signals** — what the device itself produces on
board — to the drift of each output axis.  Signals are named:

``temperature_c``
    The device thermometer, °C.
``rate_c_per_min``
    Its time derivative dT/dt, °C/min (computed by :func:`signal_matrix`).
``<proxy>``
    A temperature proxy channel by its own name (``freq_hz``, ``temp_raw``).

A model's ``inputs`` are **features** of those signals:

=============== ======================================= ==================
feature         value                                   signal
=============== ======================================= ==================
``T``           :math:`T` (°C)                          ``temperature_c``
``dT``          :math:`\\Delta T = T - T_{ref}` (°C)     ``temperature_c``
``dT2``         :math:`\\Delta T^2` (°C²)                ``temperature_c``
``rate``        :math:`dT/dt` (°C/min)                  ``rate_c_per_min``
``d_<proxy>``   :math:`p - p_{ref}` (proxy units)       ``<proxy>``
``d_<proxy>2``  :math:`(p - p_{ref})^2`                 ``<proxy>``
=============== ======================================= ==================

A name ``d_<x>2`` always means the *square* of proxy ``<x>``; a proxy whose
own name ends in ``2`` therefore cannot be used as a feature (rename it).

The :class:`Features` module computes features from a signal tensor inside the
exported graph, so it uses only gather, subtract and multiply.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np
import torch
from torch import nn

from .errors import ConfigError, InputError
from .recording import GAP_FACTOR, Dataset, Recording

__all__ = [
    "TEMPERATURE",
    "RATE",
    "FeatureSpec",
    "parse_feature",
    "signals_for",
    "reference_values",
    "signal_matrix",
    "target_matrix",
    "Features",
]

#: Signal name of the device thermometer (°C).
TEMPERATURE = "temperature_c"
#: Signal name of the temperature rate (°C/min).
RATE = "rate_c_per_min"

_TEMPERATURE_FEATURES = {"T": (False, False), "dT": (True, False), "dT2": (True, True)}


def parse_feature(name: str) -> tuple[str, bool, bool]:
    """Split a feature name into ``(signal, relative, squared)``.

    ``relative`` says the reference (T_ref or the proxy reference) is
    subtracted; ``squared`` that the difference is squared.

    Raises
    ------
    ConfigError
        For a name that is none of ``T, dT, dT2, rate, d_<proxy>, d_<proxy>2``.
    """
    if name in _TEMPERATURE_FEATURES:
        rel, sq = _TEMPERATURE_FEATURES[name]
        return TEMPERATURE, rel, sq
    if name == "rate":
        return RATE, False, False
    if name.startswith("d_") and len(name) > 2:
        proxy = name[2:]
        if proxy.endswith("2"):
            if len(proxy) == 1:
                raise ConfigError(f"input '{name}': empty proxy name")
            return proxy[:-1], True, True
        return proxy, True, False
    raise ConfigError(f"unknown model input '{name}' (valid: T, dT, dT2, rate, "
                      "d_<proxy>, d_<proxy>2)")


def signals_for(inputs: Iterable[str]) -> list[str]:
    """Physical signals the features need, in the fixed order
    ``temperature_c, rate_c_per_min, <proxies sorted by name>``."""
    needed = {parse_feature(f)[0] for f in inputs}
    fixed = [s for s in (TEMPERATURE, RATE) if s in needed]
    return fixed + sorted(needed - {TEMPERATURE, RATE})


@dataclass
class FeatureSpec:
    """Which features a model reads and the references they are taken from.

    Parameters
    ----------
    inputs : list of str
        Feature names (see the module docstring), in the model's input order.
    t_ref : float or None
        Reference temperature :math:`T_{ref}` in °C for ``dT``/``dT2``.
    proxy_ref : dict str -> float
        Reference value per proxy for ``d_<proxy>``/``d_<proxy>2``, in the
        proxy's units.

    Attributes
    ----------
    signals : list of str
        The physical signals these inputs need (derived, fixed order).
    """

    inputs: list[str]
    t_ref: float | None = None
    proxy_ref: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if isinstance(self.inputs, str) or not list(self.inputs):
            raise ConfigError(f"inputs must be a non-empty list of feature names, "
                              f"got {self.inputs!r}")
        self.inputs = list(self.inputs)
        if len(set(self.inputs)) != len(self.inputs):
            raise ConfigError(f"inputs {self.inputs} name a feature twice")
        for name in self.inputs:
            parse_feature(name)
        self.t_ref = None if self.t_ref is None else float(self.t_ref)
        self.proxy_ref = {str(k): float(v) for k, v in dict(self.proxy_ref).items()}

    @property
    def signals(self) -> list[str]:
        return signals_for(self.inputs)

    def check_references(self) -> None:
        """Raise :class:`ConfigError` when a relative feature has no reference."""
        for name in self.inputs:
            sig, rel, _ = parse_feature(name)
            if not rel:
                continue
            if sig == TEMPERATURE and self.t_ref is None:
                raise ConfigError(f"input '{name}' needs t_ref (a temperature in °C or 'start')")
            if sig != TEMPERATURE and sig not in self.proxy_ref:
                raise ConfigError(f"input '{name}' needs a reference for proxy '{sig}' "
                                  f"(have: {sorted(self.proxy_ref)})")

    def to_dict(self) -> dict:
        """Plain-data form (for checkpoints and the saved config)."""
        return {"inputs": list(self.inputs), "t_ref": self.t_ref,
                "proxy_ref": dict(self.proxy_ref)}

    @classmethod
    def from_recordings(cls, inputs: Sequence[str], recordings: object, *,
                        t_ref: str | float = "start", proxy_ref: object = "start",
                        window_min: float = 10.0) -> FeatureSpec:
        """Spec whose references come from :func:`reference_values`."""
        tr, pr = reference_values(recordings, inputs, t_ref=t_ref, window_min=window_min,
                                  proxy_ref=proxy_ref)
        return cls(inputs=list(inputs), t_ref=tr, proxy_ref=pr)


def _first_run(recordings: object) -> Recording:
    if isinstance(recordings, Recording):
        return recordings
    runs = list(recordings.runs if isinstance(recordings, Dataset)
                else cast(Iterable[Recording], recordings))
    if not runs:
        raise InputError("no training run to take the reference values from")
    return runs[0]


def _start_mean(rec: Recording, values: np.ndarray, window_min: float) -> float:
    t = np.asarray(rec.time_s, dtype=np.float64)
    # The first sample always counts, so a run sampled slower than the window
    # still has a reference.
    mask = (t - t[0]) <= window_min * 60.0
    mask[0] = True
    return float(np.mean(np.asarray(values, dtype=np.float64)[mask]))


def reference_values(recordings: object, spec_inputs: Sequence[str], t_ref: str | float = "start",
                     window_min: float = 10.0, *, proxy_ref: object = "start"
                     ) -> tuple[float | None, dict[str, float]]:
    """Reference temperature and proxy references for the relative features.

    ``"start"`` means the mean over the first ``window_min`` minutes of the
    **first** training run — study 003's "stable temperature at the start of
    the run".  A number is taken as given (°C for ``t_ref``; for ``proxy_ref``
    a mapping proxy -> value, e.g. study 001's room-temperature frequency f0).

    .. math:: T_{ref} = \\frac{1}{|W|} \\sum_{t_k - t_0 \\le 60\\,w} T_k

    Parameters
    ----------
    recordings : Recording, Dataset or sequence of Recording
        The training runs (only the first is read for ``"start"``).
    spec_inputs : sequence of str
        The model's feature names; references are computed only for what
        they need (``t_ref`` is None when no input is ``dT``/``dT2``).
    t_ref : "start" or float
        °C.
    window_min : float
        Length of the start window, minutes.
    proxy_ref : "start" or mapping str -> float
        Proxy references (proxy units).

    Returns
    -------
    (t_ref, proxy_ref) : (float or None, dict str -> float)
    """
    if window_min <= 0:
        raise ConfigError(f"window_min must be > 0 minutes, got {window_min!r}")
    parsed = [parse_feature(f) for f in spec_inputs]
    need_t = any(sig == TEMPERATURE and rel for sig, rel, _ in parsed)
    proxies = sorted({sig for sig, rel, _ in parsed if rel and sig != TEMPERATURE})
    t_value: float | None = None
    if need_t:
        if isinstance(t_ref, str):
            if t_ref != "start":
                raise ConfigError(f"t_ref must be a temperature in °C or 'start', got '{t_ref}'")
            rec = _first_run(recordings)
            if rec.temperature_c is None:
                raise InputError.at(f"run '{rec.run_id}'", "no temperature to take t_ref from",
                                    column=TEMPERATURE)
            t_value = _start_mean(rec, rec.temperature_c, window_min)
        else:
            t_value = float(t_ref)
    p_values: dict[str, float] = {}
    if proxies:
        if isinstance(proxy_ref, str):
            if proxy_ref != "start":
                raise ConfigError(f"proxy_ref must be a mapping or 'start', got '{proxy_ref}'")
            rec = _first_run(recordings)
            for p in proxies:
                if p not in rec.proxies:
                    raise InputError.at(f"run '{rec.run_id}'", "no such proxy channel "
                                        f"(proxies: {sorted(rec.proxies)})", column=p)
                p_values[p] = _start_mean(rec, rec.proxies[p], window_min)
        else:
            given = dict(proxy_ref)  # type: ignore[call-overload]
            for p in proxies:
                if p not in given:
                    raise ConfigError(f"proxy_ref has no value for proxy '{p}'")
                p_values[p] = float(given[p])
    return t_value, p_values


def contiguous_segments(time_s: np.ndarray, gap_factor: float = GAP_FACTOR) -> list[slice]:
    """Slices of contiguous sampling: a step over ``gap_factor`` × the median step is a gap
    (burst recordings, held-out time blocks cut out of a run)."""
    t = np.asarray(time_s, dtype=np.float64)
    if t.size < 2:
        return [slice(0, t.size)]
    dt = np.diff(t)
    cuts = np.flatnonzero(dt > gap_factor * np.median(dt)) + 1
    edges = np.concatenate([[0], cuts, [t.size]])
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def _segment_rate(temp: np.ndarray, time_s: np.ndarray, fs: float, window_s: float) -> np.ndarray:
    """Causal dT/dt (°C/min) of one contiguous segment.

    At each sample, the slope at that sample of a least-squares parabola through the
    last ``window_s`` seconds (Savitzky–Golay, order 2, evaluated at the window's
    newest end) — what a device can compute on board, with no look-ahead.  Before
    a full window has passed, the mean slope since the segment's start.
    """
    n = temp.shape[0]
    rate = np.zeros(n)
    if n < 2:
        return rate
    # an odd window longer than the polynomial order; in seconds, so independent of the rate
    win = max(int(round(window_s * fs)) | 1, 5)
    start = 1
    if win <= n:
        from scipy.signal import savgol_coeffs  # scipy.signal loads only when a rate is computed

        coef = savgol_coeffs(win, 2, deriv=1, delta=1.0 / fs, pos=win - 1, use="dot")
        rate[win - 1:] = np.correlate(temp, coef, mode="valid")
        start, stop = 1, win - 1
    else:
        stop = n
    k = np.arange(start, stop)
    rate[k] = (temp[k] - temp[0]) / (time_s[k] - time_s[0])
    rate[0] = rate[1] if n > 1 else 0.0
    return rate * 60.0


def _rate_c_per_min(rec: Recording, window_s: float) -> np.ndarray:
    temp = np.asarray(rec.temperature_c, dtype=np.float64)
    fs = rec.effective_rate_hz
    rate = np.empty_like(temp)
    # per contiguous segment: a derivative across a gap would mix two distant moments
    for seg in contiguous_segments(rec.time_s):
        rate[seg] = _segment_rate(temp[seg], rec.time_s[seg], fs, window_s)
    return rate


def signal_matrix(recording: Recording, signals: Sequence[str], rate_window_s: float = 60.0
                  ) -> np.ndarray:
    """Physical signals of a recording as a matrix.

    ``rate_c_per_min`` is causal, as a device computes it on board: at each
    sample, the slope at that sample of a least-squares parabola through the
    last ``rate_window_s`` seconds of ``temperature_c`` (Savitzky–Golay, order
    2, evaluated at the newest end of the window; rounded to an odd sample
    count, at least 5); before a full window has passed, the mean slope since
    the start of the segment:

    .. math:: \\dot T_k = 60 \\cdot \\frac{d}{dt} \\hat T_{[t_k - w,\\, t_k]}(t_k) \\quad [°C/min]

    It assumes near-uniform sampling (the median sample interval) within each
    contiguous segment and is computed segment by segment
    (:func:`contiguous_segments`): a burst recording, or a run with held-out
    time blocks cut out, never differentiates across a gap.

    Returns
    -------
    ndarray, shape (n, S), float64
    """
    source = recording.meta.get("source", "") or f"run '{recording.run_id}'"
    cols = []
    for name in signals:
        if name in (TEMPERATURE, RATE):
            if recording.temperature_c is None:
                raise InputError.at(source, f"signal '{name}' needs a thermometer in °C",
                                    column=TEMPERATURE)
            if name == TEMPERATURE:
                cols.append(np.asarray(recording.temperature_c, dtype=np.float64))
            else:
                if rate_window_s <= 0:
                    raise ConfigError(f"rate_window_s must be > 0 s, got {rate_window_s!r}")
                cols.append(_rate_c_per_min(recording, rate_window_s))
        elif name in recording.proxies:
            cols.append(np.asarray(recording.proxies[name], dtype=np.float64))
        else:
            raise InputError.at(source, f"no such signal (proxies: {sorted(recording.proxies)})",
                                column=name)
    return np.stack(cols, axis=1) if cols else np.zeros((recording.n_samples, 0))


def target_matrix(recording: Recording, outputs: Sequence[str]) -> np.ndarray:
    """Observed drift (output − reference) per axis, shape (n, A), float64."""
    source = recording.meta.get("source", "") or f"run '{recording.run_id}'"
    cols = []
    for name in outputs:
        if name not in recording.outputs:
            raise InputError.at(source, f"no such output (outputs: {sorted(recording.outputs)})",
                                column=name)
        cols.append(np.asarray(recording.drift_observed(name), dtype=np.float64))
    return np.stack(cols, axis=1)


class Features(nn.Module):
    """Signals (N, S) → features (N, F), inside the exported graph.

    Each feature is a signal minus its reference, optionally squared:

    .. math:: x_f = (s_{i_f} - r_f)^{q_f}, \\quad q_f \\in \\{1, 2\\}

    Buffers ``index``, ``ref``, ``square`` hold :math:`i_f, r_f, q_f - 1` (the
    checkpoint's record of the layout); :meth:`columns` evaluates the features
    as 1-D columns — one subtraction per feature and one multiplication per
    squared feature, the fewest passes over a batch.
    """

    index: torch.Tensor      # buffers, declared for the type checker
    ref: torch.Tensor
    square: torch.Tensor

    def __init__(self, spec: FeatureSpec) -> None:
        super().__init__()
        spec.check_references()
        signals = spec.signals
        index, ref, square = [], [], []
        for name in spec.inputs:
            sig, rel, sq = parse_feature(name)
            index.append(signals.index(sig))
            if not rel:
                ref.append(0.0)
            elif sig == TEMPERATURE:
                ref.append(float(spec.t_ref))  # type: ignore[arg-type]
            else:
                ref.append(spec.proxy_ref[sig])
            square.append(1.0 if sq else 0.0)
        # the layout as Python values: it fixes the graph's structure, not its numbers
        self._layout = [(i, bool(q), r != 0.0) for i, q, r in zip(index, square, ref, strict=True)]
        self.register_buffer("index", torch.tensor(index, dtype=torch.int64))
        self.register_buffer("ref", torch.tensor(ref, dtype=torch.float32))
        self.register_buffer("square", torch.tensor(square, dtype=torch.float32))

    def columns(self, signals: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        """Feature columns (each (N,)) from one (N,) column per signal."""
        out = []
        for f, (i, squared, relative) in enumerate(self._layout):
            d = signals[i] - self.ref[f] if relative else signals[i]
            out.append(d * d if squared else d)
        return out

    def forward(self, signals: torch.Tensor) -> torch.Tensor:
        return torch.stack(self.columns(signals.unbind(1)), dim=1)
