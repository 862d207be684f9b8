"""Signals, features and targets: what a drift model reads and what it predicts.

A drift model maps **physical signals** — what the device itself produces on
board — to the drift of each output axis.  Signals are named:

``temperature_c``
    The device thermometer, °C.
``rate_c_per_min``, ``lag_<tau>_c``, ``play_<w>_c``
    Dynamic signals computed from time and ``temperature_c`` by the causal
    recurrences of :mod:`thermonet.features.dynamics` (one definition, mirrored by the
    runtime and the C header).
``<proxy>``
    A temperature proxy channel by its own name (``freq_hz``, ``temp_raw``).

A model's ``inputs`` are **features** of those signals:

=============== ======================================= ==================
feature         value                                   signal
=============== ======================================= ==================
``T``           :math:`T` (°C)                          ``temperature_c``
``dT``          :math:`\\Delta T = T - T_{ref}` (°C)     ``temperature_c``
``dT2``         :math:`\\Delta T^2` (°C²)                ``temperature_c``
``rate``        filtered :math:`dT/dt` (°C/min)         ``rate_c_per_min``
``rate_<tau>``  the same, time constant ``tau`` s        ``rate_<tau>_c_per_min``
``lag_<tau>``   :math:`T - EMA_\tau(T)` (°C)             ``lag_<tau>_c``
``play_<w>``    :math:`T - P_w(T)` (°C)                  ``play_<w>_c``
``d_<proxy>``   :math:`p - p_{ref}` (proxy units)       ``<proxy>``
``d_<proxy>2``  :math:`(p - p_{ref})^2`                 ``<proxy>``
=============== ======================================= ==================

A name ``d_<x>2`` always means the *square* of proxy ``<x>``; a proxy whose
own name ends in ``2`` therefore cannot be used as a feature (rename it).

This module is torch-free (a config is checked against it without loading torch); the
:class:`thermonet.features.module.Features` module computes the features from a signal
tensor inside the exported graph.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from ..core.errors import ConfigError, InputError
from ..core.recording import (  # the signal names and segments live with the data
    RATE,
    TEMPERATURE,
    Dataset,
    Recording,
    contiguous_segments,
)
from . import dynamics

__all__ = [
    "TEMPERATURE",
    "RATE",
    "FeatureSpec",
    "parse_feature",
    "valid_inputs",
    "signals_for",
    "dynamic_signal",
    "joint_columns",
    "resolve_gap_s",
    "contiguous_segments",
    "reference_values",
    "signal_matrix",
    "target_matrix",
]


_TEMPERATURE_FEATURES = {"T": (False, False), "dT": (True, False), "dT2": (True, True)}


def parse_feature(name: str) -> tuple[str, bool, bool]:
    """Split a feature name into ``(signal, relative, squared)``.

    ``relative`` says the reference (T_ref or the proxy reference) is
    subtracted; ``squared`` that the difference is squared.

    Raises
    ------
    ConfigError
        For a name that is none of :func:`valid_inputs` (``T, dT, dT2, rate, rate_<tau>,
        lag_<tau>, delayed_<tau>, play_<w>, d_<proxy>, d_<proxy>2``).
    """
    if name in _TEMPERATURE_FEATURES:
        rel, sq = _TEMPERATURE_FEATURES[name]
        return TEMPERATURE, rel, sq
    dyn = dynamics.parse_dynamic(name)
    if dyn is not None:
        return dyn.signal, False, False
    if name.startswith("d_") and len(name) > 2:
        proxy = name[2:]
        if proxy.endswith("2"):
            if len(proxy) == 1:
                raise ConfigError(f"input '{name}': empty proxy name")
            return proxy[:-1], True, True
        return proxy, True, False
    raise ConfigError(f"unknown model input '{name}' (valid: {', '.join(valid_inputs())})")


#: How a dynamic kind's constant is written in :func:`_dynamic_forms` (``lag_<tau>``, ``play_<w>``).
_PLACEHOLDERS = {"tau_s": "tau", "half_width_c": "w"}


def _dynamic_forms() -> list[str]:
    """Every dynamic input's name forms, from the registry (:data:`~thermonet.features.
    dynamics.INPUTS`, so a kind registered later is listed too): ``rate``, ``rate_<tau>``,
    ``lag_<tau>``, ``delayed_<tau>``, ``play_<w>`` — what an error listing the valid inputs
    names."""
    out = []
    for kind, (cls, default) in dynamics.INPUTS.items():
        if default is not None:
            out.append(kind)
        out.append(f"{kind}_<{_PLACEHOLDERS.get(cls.param_key, cls.param_key)}>")
    return out


def valid_inputs() -> list[str]:
    """Every form a model input may take, from one source: the temperature features, the
    dynamic inputs' registry (:func:`_dynamic_forms`), a proxy's."""
    return [*_TEMPERATURE_FEATURES, *_dynamic_forms(), "d_<proxy>", "d_<proxy>2"]


def signals_for(inputs: Iterable[str]) -> list[str]:
    """Physical signals the features need, in the fixed order
    ``temperature_c, rate_c_per_min, <other dynamic signals sorted>, <proxies sorted>``."""
    inputs = list(inputs)
    needed = {parse_feature(f)[0] for f in inputs}
    dyn = {d.signal for d in dynamics.dynamic_signals(inputs)}
    fixed = [s for s in (TEMPERATURE, RATE) if s in needed]
    return fixed + sorted(dyn - {RATE}) + sorted(needed - dyn - {TEMPERATURE})


def joint_columns(signals: Sequence[str]) -> tuple[int | None, list[int]]:
    """The columns of ``signals`` the joint envelope relates: the temperature's (None without
    one) and every dynamic input's (rate, lag, play), whose trained range depends on the
    temperature (:class:`thermonet.scoring.selection.Envelope`, the model's guard)."""
    names = list(signals)
    t_col = names.index(TEMPERATURE) if TEMPERATURE in names else None
    joint = [i for i, name in enumerate(names) if name == RATE or dynamic_signal(name) is not None]
    return t_col, (joint if t_col is not None else [])


def dynamic_signal(name: str) -> dynamics.DynamicInput | None:
    """The dynamic input whose signal is ``name`` (``lag_300_c`` → ``lag_300``), or None."""
    for suffix in ("_c_per_min", "_c"):
        if name.endswith(suffix):
            stem = name[: -len(suffix)]
            d = dynamics.parse_dynamic("rate" if name == RATE else stem)
            if d is not None and d.signal == name:
                return d
    return None


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
    gap_s : float or None
        Gap limit of the dynamic inputs (s, see :mod:`thermonet.features.dynamics`),
        stored with the model; None with dynamic inputs means
        :data:`thermonet.features.dynamics.DEFAULT_GAP_S` (``compare`` derives it from
        the data, config ``features.gap_s``).

    Attributes
    ----------
    signals : list of str
        The physical signals these inputs need (derived, fixed order).
    """

    inputs: list[str]
    t_ref: float | None = None
    proxy_ref: dict[str, float] = field(default_factory=dict)
    gap_s: float | None = None

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
        if self.gap_s is None and dynamics.dynamic_signals(self.inputs):
            self.gap_s = dynamics.DEFAULT_GAP_S
        if self.gap_s is not None:
            gap = float(self.gap_s)
            if not (np.isfinite(gap) and gap > 0):
                raise ConfigError(f"gap_s must be a positive number of seconds, got {self.gap_s!r}")
            self.gap_s = gap

    @property
    def signals(self) -> list[str]:
        return signals_for(self.inputs)

    @property
    def dynamic(self) -> dict | None:
        """The dynamic inputs' constants (:func:`thermonet.features.dynamics.constants`), or None."""
        if not dynamics.dynamic_signals(self.inputs):
            return None
        return dynamics.constants(self.inputs, float(self.gap_s or dynamics.DEFAULT_GAP_S))

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
        out = {"inputs": list(self.inputs), "t_ref": self.t_ref,
               "proxy_ref": dict(self.proxy_ref)}
        if self.dynamic is not None:
            out["dynamic"] = self.dynamic
        return out

    @classmethod
    def from_dict(cls, data: dict, source: str = "model") -> FeatureSpec:
        """Inverse of :meth:`to_dict`; dynamic constants are checked against their definitions."""
        inputs = list(data["inputs"])
        gap = None
        if dynamics.dynamic_signals(inputs):
            gap = dynamics.from_constants(data.get("dynamic"), inputs, source)
        return cls(inputs=inputs, t_ref=data.get("t_ref"), proxy_ref=data.get("proxy_ref", {}),
                   gap_s=gap)

    @classmethod
    def from_recordings(cls, inputs: Sequence[str], recordings: object, *,
                        t_ref: str | float = "start", proxy_ref: object = "start",
                        window_min: float = 10.0, gap_s: str | float = "auto") -> FeatureSpec:
        """Spec whose references come from :func:`reference_values` (gap_s "auto":
        :func:`thermonet.features.dynamics.default_gap_s` of the first run)."""
        tr, pr = reference_values(recordings, inputs, t_ref=t_ref, window_min=window_min,
                                  proxy_ref=proxy_ref)
        return cls(inputs=list(inputs), t_ref=tr, proxy_ref=pr,
                   gap_s=resolve_gap_s(gap_s, recordings, inputs))


def resolve_gap_s(gap_s: str | float | None, recordings: object, inputs: Sequence[str]
                  ) -> float | None:
    """The gap limit a spec stores: None without dynamic inputs, "auto" →
    :data:`thermonet.features.dynamics.GAP_FACTOR` × the first run's median sample interval."""
    if not dynamics.dynamic_signals(inputs):
        return None
    _check_streamed(_first_run(recordings), inputs)
    if gap_s is None or gap_s == "auto":
        return dynamics.default_gap_s([_first_run(recordings)])
    if isinstance(gap_s, str):
        raise ConfigError(f"gap_s must be a number of seconds or 'auto', got '{gap_s}'")
    if not (np.isfinite(float(gap_s)) and float(gap_s) > 0):
        raise ConfigError(f"gap_s must be a positive number of seconds, got {gap_s!r}")
    return float(gap_s)


def _check_streamed(run: Recording, inputs: Sequence[str]) -> None:
    """A run reduced to window means holds only the dynamic inputs computed on its samples
    while it was streamed: one lacking an input is refused naming it and how to read it (was:
    'gap_s must be a positive number of seconds, got 0.0', the gap of a run streamed
    without dynamic inputs, where the user gave no gap_s)."""
    win = run.windows
    if win is None:
        return
    missing = [d.name for d in dynamics.dynamic_signals(inputs) if d.signal not in win.signals]
    if missing:
        where = run.meta.get("source", "") or "the data"
        raise InputError(f"run '{run.run_id}' of {where}: reduced to {win.window_s:g}-s window "
                         f"means without the dynamic input(s) {missing}, which are computed on "
                         "the samples while the file is streamed: read it with them named "
                         f"(read(..., window_s={win.window_s:g}, inputs={list(inputs)!r}))")


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
    v = np.asarray(values, dtype=np.float64)[mask]
    if rec.windows is not None:  # rows are window means: each weighs its samples
        return float(np.average(v, weights=rec.windows.n[mask]))
    return float(np.mean(v))


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


def _segment_starts(recording: Recording, n: int, source: str) -> list[int]:
    """0, the indices of ``meta["segment_starts"]`` (comma-separated) inside the run, and n."""
    text = str(recording.meta.get("segment_starts", ""))
    try:
        idx = [int(i) for i in text.split(",") if i.strip()]
    except ValueError:
        raise InputError.at(source, f"meta 'segment_starts' {text!r} is not a comma-separated "
                            "list of sample indices") from None
    return sorted({0, *(i for i in idx if 0 < i < n)}) + [n]


def signal_matrix(recording: Recording, signals: Sequence[str], gap_s: float | None = None
                  ) -> np.ndarray:
    """Physical signals of a recording as a matrix.

    Dynamic signals (``rate_c_per_min``, ``lag_<tau>_c``, ``play_<w>_c``) are
    computed from ``time_s`` and ``temperature_c`` by
    :func:`thermonet.features.dynamics.compute` — causal, as the board computes them,
    the state restarting at the run's start and after every gap longer than
    ``gap_s`` seconds (None: :func:`thermonet.features.dynamics.default_gap_s` of this
    recording), and at every index of ``recording.meta["segment_starts"]``
    (comma-separated; held-out blocks stacked into one recording).

    Returns
    -------
    ndarray, shape (n, S), float64
    """
    source = recording.meta.get("source", "") or f"run '{recording.run_id}'"
    dyn = {s: d for s in signals if (d := dynamic_signal(s)) is not None}
    computed: dict[str, np.ndarray] = {}
    if dyn and recording.windows is not None:
        # window means of the signals computed on the samples while the file was streamed
        # (thermonet.features.windows): never recomputed from the means
        win = recording.windows
        if gap_s is not None and not math.isclose(gap_s, win.gap_s, rel_tol=1e-9):
            raise ConfigError(f"{source}: the dynamic inputs were computed with gap_s "
                              f"{win.gap_s:g} s while the file was streamed, not {gap_s:g} s")
        for s, d in dyn.items():
            if d.signal not in win.signals:
                raise InputError.at(source, "this signal was not computed while the file was "
                                    "streamed", column=s)
            computed[d.signal] = win.signals[d.signal]
    elif dyn:
        if recording.temperature_c is None:
            raise InputError.at(source, f"signals {sorted(dyn)} need a thermometer in °C",
                                column=TEMPERATURE)
        gap = dynamics.default_gap_s([recording]) if gap_s is None else gap_s
        names = [d.name for d in dyn.values()]
        n = recording.n_samples
        starts = _segment_starts(recording, n, source)
        parts: list[dict[str, np.ndarray]] = []
        try:
            for a, b in zip(starts[:-1], starts[1:], strict=True):
                parts.append(dynamics.compute(recording.time_s[a:b],
                                              recording.temperature_c[a:b], names, gap)[0])
        except InputError as err:
            raise InputError(f"{source}: {err}") from None
        computed = {s: np.concatenate([p[s] for p in parts]) for s in parts[0]}
    cols = []
    for name in signals:
        if name == TEMPERATURE:
            if recording.temperature_c is None:
                raise InputError.at(source, f"signal '{name}' needs a thermometer in °C",
                                    column=TEMPERATURE)
            cols.append(np.asarray(recording.temperature_c, dtype=np.float64))
        elif name in computed:
            cols.append(computed[name])
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
