"""The recording: one thermal-test run of one device, in memory.

A :class:`Recording` holds time (s), the temperature the device's thermometer
read (°C), the sensor's output channels, optional reference channels (what the
output should read: turntable rate, gravity projection), optional proxy
channels (a resonator frequency in Hz, raw thermometer counts), the simulated
ground-truth drift where it is known, per-channel units and metadata.  Several
runs of one device form a :class:`Dataset`.

Channel names follow the on-disk convention (see :mod:`thermonet.data.io`):
outputs ``<kind>_<axis>`` (``gyro_x``, ``acc_z``), references
``ref_<kind>_<axis>``, true drift ``drift_<kind>_<axis>``, proxies by their
own name (``freq_hz``, ``temp_raw``).
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import InputError, counted

__all__ = [
    "Recording",
    "WindowStats",
    "Dataset",
    "DEFAULT_DEVICE",
    "OUTPUT_NAME",
    "KNOWN_UNITS",
    "MIN_SAMPLES",
    "MIN_TEMPERATURE_SPAN_C",
    "GAP_FACTOR",
    "TEMPERATURE",
    "RATE",
    "contiguous_segments",
    "output_kind",
    "split_units",
]

#: The device id of a recording that names none.
DEFAULT_DEVICE = "device"

#: An output channel is ``<kind>_<axis>``: ``gyro_x``, ``acc_z``, ``mag_y``, ``baro_p`` (a
#: barometer's pressure: the absolute value is the weather, only its change with T is drift).
OUTPUT_NAME = re.compile(r"^(gyro|acc|mag|baro|out)_([a-z0-9]+)\Z")  # \Z: no trailing newline

#: Units thermonet understands, per physical quantity.  Anything else is refused
#: so that a typo ("deg/sec") never silently changes the meaning of a number.
KNOWN_UNITS: dict[str, str] = {
    "s": "time",
    "degC": "temperature",
    "deg/s": "rate",
    "deg/h": "rate",
    "rad/s": "rate",
    "g": "acceleration",
    "mg": "acceleration",
    "m/s^2": "acceleration",
    "T": "field",
    "uT": "field",
    "Pa": "pressure",
    "hPa": "pressure",
    "Hz": "frequency",
    "counts": "raw",
    "1": "dimensionless",
}

#: Below this many samples a recording cannot carry a thermal model.
MIN_SAMPLES = 10
#: A recording whose temperature moves less than this has no thermal information.
MIN_TEMPERATURE_SPAN_C = 1.0

#: A time step over this many median steps is a gap in a log (burst mode, a pause between
#: soaks, held-out blocks cut out of a run): rates restart there, plotted lines break there.
GAP_FACTOR = 5.0


def output_kind(name: str) -> str:
    """Return the sensor kind (``gyro``, ``acc`` …) of an output channel name."""
    m = OUTPUT_NAME.match(name)
    if not m:
        raise InputError(f"output channel '{name}' is not named <kind>_<axis> "
                         "(kind one of gyro, acc, mag, baro, out)")
    return m.group(1)


def _as_1d(name: str, values: object, n: int | None, source: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 1:
        raise InputError.at(source, f"expected a 1-D series, got shape {arr.shape}", column=name)
    if n is not None and arr.shape[0] != n:
        raise InputError.at(source, f"has {counted(arr.shape[0], 'sample')}, time has {n}",
                            column=name)
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise InputError.at(
            source, f"non-finite value {arr[bad[0]]!r}", column=name, row=int(bad[0])
        )
    return arr


@dataclass
class WindowStats:
    """What a recording reduced to window means keeps of the samples it averaged
    (:mod:`thermonet.features.windows`: a recording larger than memory, streamed once).

    Row ``k`` of the reduced :class:`Recording` is the mean of the ``n[k]`` samples of
    one window.  ``signals`` holds the window means of the dynamic inputs, computed on
    the samples at their own rate (never from the means); ``gap_s`` the gap limit they
    were computed with.  ``ss[axis]`` is the sum of squared deviations from the window
    mean of the axis' observed drift (output − reference) inside each window, and
    ``ss_output[axis]`` that of the output alone where a reference exists: with them a
    held-out score over the samples is recovered from the rows
    (:func:`thermonet.training.pipeline.score_part`).  ``source_samples`` and
    ``source_rate_hz`` describe the samples the rows stand for.

    ``extremes`` holds each channel's (min, max) over the samples (the plausibility
    warnings, :func:`thermonet.data.diagnostics.input_warnings`).

    ``signal_names`` are the columns a model may read (temperature, proxies, the dynamic
    inputs); ``sxx`` (rows, S, S) their co-moments inside each window and ``sxd[axis]``
    (rows, S) theirs with the axis' target (``sxd_output``: with the output alone): with
    the model's slope they give the residual's spread inside a window to first order
    (:func:`thermonet.training.pipeline.residual_spread`).
    """

    window_s: float
    n: np.ndarray
    signals: dict[str, np.ndarray]
    gap_s: float
    ss: dict[str, np.ndarray]
    ss_output: dict[str, np.ndarray] = field(default_factory=dict)
    source_samples: int = 0
    source_rate_hz: float = float("nan")
    signal_names: list[str] = field(default_factory=list)
    sxx: np.ndarray | None = None
    sxd: dict[str, np.ndarray] = field(default_factory=dict)
    sxd_output: dict[str, np.ndarray] = field(default_factory=dict)
    #: (min, max) over the samples of time and of every channel: the whole-file reader's
    #: plausibility warnings from the samples, not the means (empty once rows are selected)
    extremes: dict[str, tuple[float, float]] = field(default_factory=dict)

    #: the per-row column dicts (dynamic signals, per-axis sums) that select and concat carry
    _COLUMNS = ("signals", "ss", "ss_output", "sxd", "sxd_output")

    def select(self, mask: np.ndarray) -> WindowStats:
        """The rows where ``mask`` is true (or the indices it lists)."""
        n = self.n[mask]
        groups = {g: {k: v[mask] for k, v in getattr(self, g).items()} for g in self._COLUMNS}
        return WindowStats(self.window_s, n, gap_s=self.gap_s, source_samples=int(n.sum()),
                           source_rate_hz=self.source_rate_hz,
                           signal_names=list(self.signal_names),
                           sxx=None if self.sxx is None else self.sxx[mask], **groups)

    @staticmethod
    def concat(parts: list[WindowStats]) -> WindowStats:
        """Rows of several reduced recordings one after the other (stacked held-out blocks)."""
        first = parts[0]
        groups: dict[str, Any] = {g: {k: np.concatenate([getattr(p, g)[k] for p in parts])
                                      for k in getattr(first, g)} for g in WindowStats._COLUMNS}
        n = np.concatenate([p.n for p in parts])
        sxx = None if any(p.sxx is None for p in parts) else \
            np.concatenate([p.sxx for p in parts if p.sxx is not None])
        return WindowStats(first.window_s, n, gap_s=first.gap_s, source_samples=int(n.sum()),
                           source_rate_hz=first.source_rate_hz,
                           signal_names=list(first.signal_names), sxx=sxx, **groups)


@dataclass
class Recording:
    """One thermal-test run of one device.

    Parameters
    ----------
    time_s : array, shape (n,)
        Sample times in seconds, strictly increasing.
    temperature_c : array, shape (n,), or None
        What the device's thermometer read, in °C.  None when the recording has
        no thermometer in °C, only a proxy (raw counts, a frequency): then at
        least one proxy channel is required and models use the proxy.
    outputs : mapping name -> array (n,)
        Sensor outputs, ``<kind>_<axis>``.
    references : mapping name -> array (n,)
        True input per output channel (``ref_gyro_x`` …); absent means zero
        (a static gyro) or unknown.
    proxies : mapping name -> array (n,)
        Temperature proxies (``freq_hz``, ``temp_raw``).
    drift : mapping name -> array (n,)
        The exact simulated drift per output (``drift_gyro_x`` …), simulator only.
    units : mapping channel -> unit
        Units per channel, from :data:`KNOWN_UNITS`.
    device_id, sensor_kind, run_id : str
        Metadata; ``run_id`` is unique within a dataset.
    sample_rate_hz : float or None
        Nominal sample rate (None: derive from ``time_s``).
    meta : mapping str -> str
        Anything else worth keeping (preset, seed, source file).
    windows : WindowStats or None
        Set where each row is the mean of a window of samples (a recording larger
        than memory, reduced while it was streamed: :mod:`thermonet.features.windows`).
    """

    time_s: np.ndarray
    temperature_c: np.ndarray | None
    outputs: dict[str, np.ndarray]
    references: dict[str, np.ndarray] = field(default_factory=dict)
    proxies: dict[str, np.ndarray] = field(default_factory=dict)
    drift: dict[str, np.ndarray] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    device_id: str = DEFAULT_DEVICE
    sensor_kind: str = "gyro"
    run_id: str = "run0"
    sample_rate_hz: float | None = None
    meta: dict[str, str] = field(default_factory=dict)
    windows: WindowStats | None = None

    # ------------------------------------------------------------------ checks
    def validate(self, source: str = "", *, min_span_c: float = MIN_TEMPERATURE_SPAN_C,
                 require_temperature_span: bool = False) -> Recording:
        """Check shapes, finiteness, time order and units; return ``self``.

        The temperature span is checked per dataset (:meth:`Dataset.validate`):
        an isothermal soak is a valid run when other runs of the device cover
        other temperatures (the two BMI270 soaks).

        Raises
        ------
        InputError
            One line naming ``source``, the column and the row at fault.
        """
        source = source or self.meta.get("source", "")
        source = f"{source}, run '{self.run_id}'" if source else f"run '{self.run_id}'"
        self.time_s = _as_1d("time_s", self.time_s, None, source)
        n = self.time_s.shape[0]
        if n < MIN_SAMPLES:
            raise InputError.at(source, f"too few samples: {n} (need at least {MIN_SAMPLES})")
        dt = np.diff(self.time_s)
        bad = np.flatnonzero(dt <= 0)
        if bad.size:
            kind = "duplicate" if dt[bad[0]] == 0 else "decreasing"
            raise InputError.at(source, f"{kind} timestamp {self.time_s[bad[0] + 1]!r} "
                                "(time must increase strictly)", column="time_s",
                                row=int(bad[0] + 1))
        if self.temperature_c is None:
            if not self.proxies:
                raise InputError.at(source, "no temperature: need column 'temperature_c' "
                                    "or a proxy channel (e.g. raw thermometer counts)")
        else:
            self.temperature_c = _as_1d("temperature_c", self.temperature_c, n, source)
        if not self.outputs:
            raise InputError.at(source, "no output channel (need at least one <kind>_<axis>)")
        for group in (self.outputs, self.references, self.proxies, self.drift):
            for name in list(group):
                group[name] = _as_1d(name, group[name], n, source)
        for name in self.outputs:
            output_kind(name)
        for name in self.references:
            if not name.startswith("ref_") or name[4:] not in self.outputs:
                raise InputError.at(source, "reference channel has no matching output "
                                    f"(expected ref_<output>, outputs: {sorted(self.outputs)})",
                                    column=name)
        for name in self.drift:
            if not name.startswith("drift_") or name[6:] not in self.outputs:
                raise InputError.at(source, "drift channel has no matching output", column=name)
        for name, unit in self.units.items():
            if unit not in KNOWN_UNITS:
                raise InputError.at(source, f"unknown unit '{unit}' (known: "
                                    f"{', '.join(sorted(KNOWN_UNITS))})", column=name)
        if require_temperature_span and self.temperature_c is not None:
            span = float(np.ptp(self.temperature_c))
            if span < min_span_c:
                raise InputError.at(source, f"temperature spans only {span:.3g} °C "
                                    f"(need at least {min_span_c:g} °C to fit a thermal model)",
                                    column="temperature_c")
        return self

    def __repr__(self) -> str:
        """One line, not every array (``print(thermonet.read(...))``)."""
        t = self.temperature_c
        span = "" if t is None or not np.isfinite(t).any() else \
            f", {np.nanmin(t):.4g}..{np.nanmax(t):.4g} °C"
        return (f"Recording(run '{self.run_id}' of unit '{self.device_id}', {self.n_samples} "
                f"samples{span}, outputs {', '.join(self.outputs) or 'none'})")

    # ------------------------------------------------------------ properties
    @property
    def n_samples(self) -> int:
        return int(np.asarray(self.time_s).shape[0])

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    @property
    def effective_rate_hz(self) -> float:
        """Nominal sample rate, or the median rate of the time stamps."""
        if self.sample_rate_hz:
            return float(self.sample_rate_hz)
        return float(1.0 / np.median(np.diff(self.time_s)))

    @property
    def axes(self) -> list[str]:
        """Output channel names in a stable order."""
        return list(self.outputs)

    def reference(self, output: str) -> np.ndarray:
        """Reference of an output channel (zeros where none was recorded)."""
        ref = self.references.get(f"ref_{output}")
        return np.zeros(self.n_samples) if ref is None else ref

    def drift_observed(self, output: str) -> np.ndarray:
        """Observed drift = output − reference (the training target)."""
        return self.outputs[output] - self.reference(output)

    def channel(self, name: str) -> np.ndarray:
        """Any channel by its on-disk name."""
        if name == "time_s":
            return self.time_s
        if name == "temperature_c" and self.temperature_c is not None:
            return self.temperature_c
        for group in (self.outputs, self.references, self.proxies, self.drift):
            if name in group:
                return group[name]
        raise KeyError(name)

    def select(self, mask: np.ndarray, run_id: str | None = None) -> Recording:
        """A new recording holding the samples where ``mask`` is true (a contiguous block
        in practice: thermonet never splits by random sample)."""
        def sub(d: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
            return {k: v[mask] for k, v in d.items()}
        return Recording(
            time_s=self.time_s[mask],
            temperature_c=None if self.temperature_c is None else self.temperature_c[mask],
            outputs=sub(self.outputs), references=sub(self.references),
            proxies=sub(self.proxies), drift=sub(self.drift), units=dict(self.units),
            device_id=self.device_id, sensor_kind=self.sensor_kind,
            run_id=run_id or self.run_id, sample_rate_hz=self.sample_rate_hz,
            meta=dict(self.meta),
            windows=None if self.windows is None else self.windows.select(mask))


@dataclass
class Dataset:
    """Several runs of one device (each a :class:`Recording`)."""

    runs: list[Recording]
    meta: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # a run is named by its unit and its id: a fleet file holds run0 of every unit
        seen: set[tuple[str, str]] = set()
        for r in self.runs:
            if (r.device_id, r.run_id) in seen:
                where = f" of unit '{r.device_id}'" if self.is_fleet else ""
                raise InputError(f"duplicate run id '{r.run_id}'{where} in dataset")
            seen.add((r.device_id, r.run_id))

    def __repr__(self) -> str:
        """One line per run, not every array (``print(thermonet.read(...))``)."""
        return (f"Dataset({len(self.runs)} run{'s' if len(self.runs) != 1 else ''}"
                + "".join(f"\n  {r!r}" for r in self.runs) + ")")

    def __iter__(self) -> Iterator[Recording]:
        return iter(self.runs)

    def __len__(self) -> int:
        return len(self.runs)

    def __getitem__(self, key: int | str) -> Recording:
        if isinstance(key, str):
            for r in self.runs:
                if r.run_id == key:
                    return r
            raise KeyError(f"no run '{key}' (runs: {[r.run_id for r in self.runs]})")
        return self.runs[key]

    def validate(self, source: str = "", *, min_span_c: float = MIN_TEMPERATURE_SPAN_C
                 ) -> Dataset:
        """Validate every run, check they share channels, and that the runs together
        span at least ``min_span_c`` °C (or carry a proxy); return ``self``."""
        if not self.runs:
            raise InputError.at(source, "no runs")
        for r in self.runs:
            r.validate(source or r.meta.get("source", ""))
        first = self.runs[0]
        fleet = self.is_fleet
        what = "units of one fleet" if fleet else "runs of one device"

        def who(r: Recording) -> str:
            return f"unit '{r.device_id}' run '{r.run_id}'" if fleet else f"run '{r.run_id}'"

        for r in self.runs[1:]:
            where = source or r.meta.get("source", "")
            # references and simulated drift may be absent in some runs (absent reference:
            # a static input; absent drift: truth unknown); outputs and proxies may not
            for group in ("outputs", "proxies"):
                mine, theirs = sorted(getattr(r, group)), sorted(getattr(first, group))
                if mine != theirs:
                    raise InputError.at(where, f"{who(r)} has {group} {mine}, "
                                        f"{who(first)} has {theirs} (the {what} "
                                        "must carry the same channels)")
            if (r.temperature_c is None) != (first.temperature_c is None):
                raise InputError.at(where, f"{who(r)} and {who(first)} differ in "
                                    "having a temperature_c channel", column="temperature_c")
            for name, unit in r.units.items():
                other = first.units.get(name)
                if other is not None and other != unit:
                    raise InputError.at(where, f"{who(r)} is in '{unit}', {who(first)} "
                                        f"in '{other}' (convert one with a "
                                        "mapping scale)", column=name)
        temps = [r.temperature_c for r in self.runs if r.temperature_c is not None]
        if temps and len(temps) == len(self.runs):
            lo = min(float(t.min()) for t in temps)
            hi = max(float(t.max()) for t in temps)
            if hi - lo < min_span_c:
                raise InputError.at(source or first.meta.get("source", ""),
                                    f"temperature spans only {hi - lo:.3g} °C over all runs "
                                    f"(need at least {min_span_c:g} °C to fit a thermal model; "
                                    "load several soaks together)", column="temperature_c")
        return self

    @property
    def run_ids(self) -> list[str]:
        return [r.run_id for r in self.runs]

    @property
    def device_id(self) -> str:
        return self.runs[0].device_id if self.runs else DEFAULT_DEVICE

    @property
    def unit_ids(self) -> list[str]:
        """Device ids of the units in this dataset, in order of first appearance."""
        return list(dict.fromkeys(r.device_id for r in self.runs))

    @property
    def is_fleet(self) -> bool:
        """True when the runs come from more than one device (unit)."""
        return len({r.device_id for r in self.runs}) > 1

    @property
    def axes(self) -> list[str]:
        return self.runs[0].axes if self.runs else []


def split_units(ds: Dataset) -> dict[str, Dataset]:
    """The runs of each unit (device id) as its own :class:`Dataset`, in order of appearance.

    A dataset of one device gives one entry.  The dataset's ``meta`` is copied to
    every unit.
    """
    out: dict[str, list[Recording]] = {}
    for r in ds.runs:
        out.setdefault(r.device_id, []).append(r)
    return {dev: Dataset(runs=runs, meta=dict(ds.meta)) for dev, runs in out.items()}


#: Signal name of the device thermometer (°C).
TEMPERATURE = "temperature_c"
#: Signal name of the temperature rate (°C/min).
RATE = "rate_c_per_min"


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
