"""What a flight-controller log holds for thermal calibration: sensor instances and parameters.

One :class:`SensorInstance` per physical sensor (a gyro, an accelerometer, a
barometer, a magnetometer), identified by the autopilot's device id, with its
own thermometer.  Units are SI as both autopilots log and compensate them:
gyro rad/s (kept in rad/s: the parameters PX4 and ArduPilot load are in rad/s),
accelerometer m/s², barometer Pa, magnetometer µT (PX4 logs ``sensor_mag`` in gauss,
ArduPilot ``MAG`` in milligauss: both converted on reading, 1 gauss = 100 µT).  A
magnetometer without a thermometer of its own is read with ``temperature_c`` None; a
calibration may lend it another sensor's thermometer (:func:`lend_thermometer`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...core.errors import InputError, counted
from ...core.recording import Dataset, Recording

__all__ = ["SensorInstance", "FlightLog", "AXES", "UNITS", "temperature_step", "screen_samples",
           "drop_phantoms", "MAX_DAMAGED_FRACTION", "MAX_UNREAD_FRACTION", "FULL_SCALE",
           "TEMPERATURE_RANGE_C", "TEMPERATURE_SPIKE_C", "MAX_INSTANCE", "time_gaps",
           "byte_ranges_note", "UT_PER_GAUSS", "lend_thermometer", "MAX_CLOCK_BACK_S",
           "clock_jump_back"]

#: Output channels per sensor kind.
AXES = {"gyro": ("x", "y", "z"), "acc": ("x", "y", "z"), "mag": ("x", "y", "z"), "baro": ("p",)}
#: thermonet unit per sensor kind (SI, as the autopilots log and compensate them).
UNITS = {"gyro": "rad/s", "acc": "m/s^2", "baro": "Pa", "mag": "uT"}
#: µT per gauss (PX4 ``sensor_mag`` and its ``TC_M*`` coefficients are in gauss).
UT_PER_GAUSS = 100.0

# ---- damaged logs: what a sample must satisfy to be trusted (see screen_samples)
#: Largest magnitude a sensor can report, per kind (gyro 100 rad/s ≈ 5,700 °/s, over any MEMS
#: gyro's 4,000 °/s full scale; accelerometer 1,000 m/s² ≈ 100 g; magnetometer 100 gauss = 10,000 µT);
#: a barometer reads 1 kPa..200 kPa.  A flipped exponent byte lands far outside.
FULL_SCALE = {"gyro": (-100.0, 100.0), "acc": (-1000.0, 1000.0), "mag": (-1e4, 1e4),
              "baro": (1e3, 2e5)}
#: A sensor thermometer reads inside this range (°C); outside, the sample is damaged.
TEMPERATURE_RANGE_C = (-80.0, 200.0)
#: A temperature this far (°C) from the median of its five neighbours is a damaged sample:
#: a board warms by a few °C per minute, its thermometer never jumps.
TEMPERATURE_SPIKE_C = 5.0
#: Highest instance number an autopilot logs per sensor kind (PX4: 4 per topic, 0..3;
#: ArduPilot: 3 IMUs and 3 barometers, 0..2); a higher one is a damaged instance field.
MAX_INSTANCE = {"px4": 3, "ardupilot": 2}
#: An instance that loses more than this fraction of its samples to damage is not trusted.
MAX_DAMAGED_FRACTION = 0.10
#: A log of which more than this fraction of the bytes could not be read is refused.
MAX_UNREAD_FRACTION = 0.50


def _median5(x: np.ndarray) -> np.ndarray:
    """Median of each value and its four nearest neighbours (edges repeated)."""
    if x.size == 0:
        return x.copy()
    padded = np.pad(x, 2, mode="edge")
    return np.median(np.lib.stride_tricks.sliding_window_view(padded, 5), axis=1)


def _spikes(x: np.ndarray, tol: float) -> np.ndarray:
    """True where ``x`` is more than ``tol`` from the median of itself and four neighbours.

    A monotonic series is its own running median exactly, so a clean clock or a
    steadily warming thermometer never trips it; one damaged sample does.
    """
    return np.abs(x - _median5(x)) > tol


def _span(t: np.ndarray) -> str:
    t = t[np.isfinite(t)]
    if t.size == 0:
        return ""
    lo, hi = float(t.min()), float(t.max())
    return f" at t = {lo:.1f} s" if hi - lo < 0.05 else f" at t = {lo:.1f}..{hi:.1f} s"


def screen_samples(kind: str, time_s: np.ndarray, values: np.ndarray,
                   temperature_c: np.ndarray | None,
                   device_ids: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """Which samples of one sensor instance can be trusted, and what was not, in words.

    The arrays are in the log's own order (before any sorting).  A sample is
    dropped when its time, value or temperature is not finite (the firmware
    logs NaN for a sensor without a thermometer: a temperature that is NaN
    throughout is no damage); its time breaks the clock's order (more than
    three sample intervals from the median of its neighbours: a flipped time
    byte); a value lies outside :data:`FULL_SCALE`; its temperature lies
    outside :data:`TEMPERATURE_RANGE_C` or jumps :data:`TEMPERATURE_SPIKE_C`
    from its neighbours (a thermometer in kelvin, :func:`kelvin_span`, judged in °C: a
    unit is no damage, :func:`flag_kelvin` says it); or (PX4) its ``device_id`` is not the instance's.

    Returns
    -------
    (keep, notes)
        ``keep`` a boolean mask over the samples; ``notes`` one phrase per
        reason with its count and where (seconds since the log started).
    """
    t = np.asarray(time_s, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64).reshape(t.shape[0], -1)
    n = t.shape[0]
    reasons: list[tuple[str, np.ndarray]] = []
    finite = np.isfinite(t) & np.all(np.isfinite(v), axis=1)
    if temperature_c is not None:
        finite &= np.isfinite(temperature_c)
    reasons.append(("a time, value or temperature that is not a number", ~finite))
    bad = ~finite
    idx = np.flatnonzero(~bad)
    if idx.size >= 3:
        tf = t[idx]
        dt = np.diff(tf)
        step = float(np.median(np.abs(dt))) if dt.size else 0.0
        jump = np.zeros(n, dtype=bool)
        jump[idx] = _spikes(tf, 3.0 * step + 1e-6)
        reasons.append(("a time out of the clock's order", jump))
        bad |= jump
    lo, hi = FULL_SCALE[kind]
    scale = ~bad & np.any((v < lo) | (v > hi), axis=1)
    reasons.append((f"a value outside the sensor's full scale ({lo:g}..{hi:g} {UNITS[kind]})",
                    scale))
    bad |= scale
    if temperature_c is not None:
        temp = np.asarray(temperature_c, dtype=np.float64)
        if kelvin_span(temp) is not None:   # a unit, not damage: judged in °C (flag_kelvin)
            temp = temp - KELVIN_OFFSET
        tlo, thi = TEMPERATURE_RANGE_C
        out = ~bad & ((temp < tlo) | (temp > thi))
        reasons.append((f"a temperature outside {tlo:g}..{thi:g} °C", out))
        bad |= out
        idx = np.flatnonzero(~bad)
        if idx.size >= 3:
            spike = np.zeros(n, dtype=bool)
            spike[idx] = _spikes(temp[idx], TEMPERATURE_SPIKE_C)
            reasons.append((f"a temperature {TEMPERATURE_SPIKE_C:g} °C or more off its "
                            "neighbours", spike))
            bad |= spike
    if device_ids is not None and n:
        ids = np.asarray(device_ids)
        vals, counts = np.unique(ids[~bad] if np.any(~bad) else ids, return_counts=True)
        other = ~bad & (ids != vals[np.argmax(counts)])
        reasons.append(("another sensor's device id", other))
        bad |= other
    notes = [f"{int(mask.sum())} sample{'s' if mask.sum() != 1 else ''} with {why}"
             f"{_span(t[mask])}" for why, mask in reasons if mask.any()]
    return ~bad, notes


#: Kelvin is told from °C by the log's median: above :data:`TEMPERATURE_RANGE_C`'s top no
#: board soaks, and the whole span (1st..99th percentile) less 273.15 lies inside it.
KELVIN_OFFSET = 273.15


def kelvin_span(temperature: np.ndarray | None) -> tuple[float, float] | None:
    """(low, high) of a thermometer that reads in kelvin (1st and 99th percentiles of its
    finite samples), or None when it reads °C (or nothing): the plausibility rule of
    thermonet's other unit checks (:func:`thermonet.data.diagnostics.temperature_hint`) —
    a median no sensor test reaches in °C, whose whole span less 273.15 does."""
    if temperature is None:
        return None
    t = np.asarray(temperature, dtype=np.float64)
    t = t[np.isfinite(t)]
    if t.size == 0:
        return None
    tlo, thi = TEMPERATURE_RANGE_C
    lo, hi = (float(x) for x in np.percentile(t, [1.0, 99.0]))
    if float(np.median(t)) <= thi or lo - KELVIN_OFFSET < tlo or hi - KELVIN_OFFSET > thi:
        return None
    return lo, hi


def flag_kelvin(inst: SensorInstance) -> None:
    """An instance whose thermometer reads in kelvin is not calibrated: the autopilot's
    thermal compensation reads that same value, so parameters fitted in °C would not match
    what the vehicle applies them to.  Its samples are kept (never dropped as a temperature
    no sensor reports); ``untrusted`` says why, in one phrase naming kelvin."""
    span = kelvin_span(inst.temperature_c)
    if span is None:
        return
    lo, hi = span
    inst.untrusted = (f"its thermometer reads {lo:.1f}..{hi:.1f}: kelvin "
                      f"({lo - KELVIN_OFFSET:.1f}..{hi - KELVIN_OFFSET:.1f} °C), where the "
                      "autopilot reports °C; its thermal compensation would read the same "
                      "kelvin, so no calibration in °C can match it — fix the driver's "
                      "temperature unit")
    inst.notes.append(f"temperature logged in kelvin ({lo:.1f}..{hi:.1f} K): not calibrated")


def temperature_step(temperature_c: np.ndarray | None) -> float | None:
    """The quantisation step of a thermometer, °C: the most common spacing of its distinct values.

    A sensor that reports whole degrees gives 1.0; a float thermometer gives a
    tiny value.  None when fewer than two distinct values exist.
    """
    if temperature_c is None:
        return None
    u = np.unique(np.round(np.asarray(temperature_c, dtype=np.float64), 6))
    if u.size < 2:
        return None
    d = np.round(np.diff(u), 6)
    vals, counts = np.unique(d, return_counts=True)
    return float(vals[np.argmax(counts)])


@dataclass
class SensorInstance:
    """One sensor of a flight-controller log.

    Attributes
    ----------
    kind : str
        ``gyro``, ``acc``, ``baro`` or ``mag``.
    instance : int
        The autopilot's instance number (PX4 multi id; ArduPilot IMU index, 0-based).
    device_id : int
        The sensor's device id (PX4 ``device_id``; ArduPilot ``INS_GYR_ID`` …; 0 if unknown).
    time_s : array (n,)
        Seconds since the log started.
    temperature_c : array (n,) or None
        The sensor's own thermometer, °C (None: the sensor has none).
    values : array (n, axes)
        The output in :data:`UNITS`.
    notes : list of str
        What was done to the data (unit conversion, calibration undone, …).
    truth : array (n, axes) or None
        The simulated drift (simulator logs only, not read from files).
    damaged : int
        Samples read but dropped as damaged (:func:`screen_samples`; the notes say why).
    untrusted : str or None
        Why the instance as a whole cannot be trusted (more than
        :data:`MAX_DAMAGED_FRACTION` of its samples damaged), else None.
    thermometer : str or None
        None: ``temperature_c`` is the sensor's own thermometer; else the name of the
        instance whose thermometer was lent to it (``baro0``, ``gyro0``:
        :func:`lend_thermometer`), interpolated to this sensor's sample times.
    lag_s : float
        With a lent thermometer: the time constant (s) of the first-order lag through
        which ``temperature_c`` now follows it (0: none; set by a calibration).
    unlagged_c : array (n,) or None
        With a lag: the lent thermometer as read, before the lag (what a model with a
        ``lag_<tau>`` dynamic input takes as its temperature).
    starts : tuple of int
        Several logs joined into one instance (``thermonet.workflows.calibrate_logs.merge_logs``):
        the sample index where each log after the first begins; a check that follows the
        signal in time (a magnetometer's motion) looks within each log, never across a
        join.  Empty: one log.
    """

    kind: str
    instance: int
    device_id: int
    time_s: np.ndarray
    temperature_c: np.ndarray | None
    values: np.ndarray
    notes: list[str] = field(default_factory=list)
    truth: np.ndarray | None = None
    damaged: int = 0
    untrusted: str | None = None
    thermometer: str | None = None
    lag_s: float = 0.0
    unlagged_c: np.ndarray | None = None
    starts: tuple[int, ...] = ()

    def segments(self) -> list[slice]:
        """The samples of each log this instance joins (one slice for one log)."""
        edges = [0, *self.starts, self.n_samples]
        return [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]

    def mark_damage(self, n_read: int, dropped: list[str]) -> None:
        """Record ``n_read − n_samples`` damaged samples (``dropped``: why, with counts);
        more than :data:`MAX_DAMAGED_FRACTION` of them makes the instance untrusted."""
        self.damaged = int(n_read - self.n_samples)
        if not self.damaged:
            return
        what = "; ".join(dropped)
        self.notes.append(f"damaged: {self.damaged} of {n_read} samples dropped ({what})")
        if self.damaged > MAX_DAMAGED_FRACTION * n_read:
            self.untrusted = (f"damaged: {self.damaged} of {n_read} samples could not be trusted "
                              f"({what}); more than {MAX_DAMAGED_FRACTION:.0%} of an instance "
                              "damaged leaves the rest in doubt")

    @property
    def name(self) -> str:
        """``gyro0``, ``acc1``, ``baro0`` …"""
        return f"{self.kind}{self.instance}"

    @property
    def n_samples(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def channels(self) -> list[str]:
        return [f"{self.kind}_{a}" for a in AXES[self.kind]]

    def to_dataset(self, source: str = "") -> Dataset:
        """One run of this sensor as a thermonet :class:`Dataset` (not validated).

        Gyro drift is the output itself (the board is still: the true rate is
        zero, the autopilots fit the whole offset).  Accelerometer and baro
        outputs carry gravity and the weather: their reference is the median
        of the log, as PX4's ``process_sensor_caldata.py`` subtracts it, so that
        only the change with temperature is drift.  A magnetometer carries the
        Earth's field: it has no reference channel, so its target is thermonet's
        ``at-t-ref`` (:mod:`thermonet.features.target`) — the change from its value at
        T_ref, zero there, as PX4's ``TC_M*`` (``X0 = 0``) — and the field stays.
        """
        outputs = {c: self.values[:, j].astype(np.float64) for j, c in enumerate(self.channels)}
        refs: dict[str, np.ndarray] = {}
        if self.kind in ("acc", "baro"):
            refs = {f"ref_{c}": np.full(self.n_samples, float(np.median(v)))
                    for c, v in outputs.items()}
        drift = {} if self.truth is None else {
            f"drift_{c}": self.truth[:, j] - float(np.median(self.truth[:, j]))
            if self.kind in ("acc", "baro", "mag") else self.truth[:, j]
            for j, c in enumerate(self.channels)}
        units = {"time_s": "s", "temperature_c": "degC",
                 **{c: UNITS[self.kind] for c in self.channels}}
        meta = {"source": source, "instance": self.name, "log_notes": "; ".join(self.notes)}
        if self.thermometer:
            meta["thermometer"] = self.thermometer
        rec = Recording(time_s=self.time_s.astype(np.float64), temperature_c=self.temperature_c,
                        outputs=outputs, references=refs, drift=drift, units=units,
                        device_id=str(self.device_id), sensor_kind=self.kind,
                        run_id=self.name, meta=meta)
        return Dataset(runs=[rec], meta={"source": source, "log_notes": "; ".join(self.notes)})


@dataclass
class FlightLog:
    """A flight-controller log: its sensor instances and the parameters it recorded."""

    path: Path
    autopilot: str                     # "px4" or "ardupilot"
    instances: list[SensorInstance]
    params: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: What the reader found damaged in the file and where (byte offsets, instances dropped).
    damage: list[str] = field(default_factory=list)
    #: Fraction of the file's bytes that could not be read as messages (0 for a sound log).
    unread_fraction: float = 0.0
    #: The board's own id where the log holds one (None: it does not), told apart from the
    #: sensors' device ids, which two boards of one model share: PX4's ``sys_uuid`` info
    #: field (the MCU's unique id, hex); ArduPilot's system-id ``MSG`` line
    #: (``Util::get_system_id``: the board's short name and its MCU's unique id in three
    #: eight-digit hex words, ``CubeOrange 00340036 3137510B 33393538``).
    board_id: str | None = None

    def check(self) -> FlightLog:
        """Refuse a log with no usable sensor data: one line naming the file and what is missing.

        A damaged log is refused, saying so and where, when more than
        :data:`MAX_UNREAD_FRACTION` of it could not be read, when the damage
        left no sensor data, or when every instance with a thermometer is
        untrusted; otherwise what was dropped is in :attr:`damage` and each
        instance's notes.
        """
        where = "; ".join(self.damage)
        if self.unread_fraction > MAX_UNREAD_FRACTION:
            raise InputError.at(self.path, f"damaged: {self.unread_fraction:.0%} of the file could "
                                f"not be read ({where}); too little is left to trust")
        if self.damage and not any(i.n_samples for i in self.instances):
            what = ("no sensor topics (sensor_gyro / sensor_accel / sensor_baro; DataFlash IMU / "
                    "BARO) could be read" if not self.instances else "no sensor data could be read")
            raise InputError.at(self.path, f"damaged: {what} ({where})")
        thermo = [i for i in self.instances if i.temperature_c is not None and i.n_samples]
        if thermo and all(i.untrusted for i in thermo):
            raise InputError.at(self.path, "damaged: too little is left to trust in any sensor "
                                f"instance ({'; '.join(f'{i.name}: {i.untrusted}' for i in thermo)})")
        if not self.instances:
            raise InputError.at(self.path, "no sensor topics (sensor_gyro / sensor_accel / "
                                "sensor_baro; DataFlash IMU / BARO) in the log")
        if all(i.temperature_c is None for i in self.instances):
            raise InputError.at(self.path, "no sensor reports a temperature: nothing to "
                                "calibrate against")
        live = [i for i in self.instances if i.n_samples and np.any(i.values != 0)]
        if not live:
            raise InputError.at(self.path, "every sensor reads exactly zero (a SITL log?): "
                                "no real sensor data")
        dropped = sum(i.damaged for i in self.instances)
        if self.damage or dropped:
            import logging

            untrusted = [i.name for i in self.instances if i.untrusted]
            logging.getLogger("thermonet.data.logs").warning(
                "%s: damaged log: %s%s%s", self.path, "; ".join(self.damage) or "",
                f"{'; ' if self.damage else ''}{dropped} damaged samples dropped" if dropped
                else "", f"; not trusted: {', '.join(untrusted)}" if untrusted else "")
        return self


def byte_ranges_note(ranges: list[tuple[int, int]], size: int) -> str:
    """``[start, end)`` byte ranges a reader skipped, as one phrase (the first three listed)."""
    total = sum(b - a for a, b in ranges)
    where = ", ".join(f"{a:,}..{b:,}" for a, b in ranges[:3]) + (", …" if len(ranges) > 3 else "")
    cut = "; the file ends inside a message: cut short?" if ranges[-1][1] >= size else ""
    share = total / max(size, 1)
    share_text = f"{share:.1%}" if share >= 0.001 else "under 0.1%"
    return (f"{len(ranges)} damaged stretch{'es' if len(ranges) > 1 else ''} not readable as "
            f"messages, {total:,} byte{'s' * (total != 1)} ({share_text} of the file) skipped "
            f"at bytes {where}{cut}")


#: A sensor's clock stepping back by more than this (s), once damaged samples are dropped,
#: is a clock jump: sorted, two stretches of time would interleave (the readers refuse it).
MAX_CLOCK_BACK_S = 1.0


def clock_jump_back(time_s: np.ndarray, what: str) -> str | None:
    """The largest step back of a sensor's clock (in the log's own order, damaged samples
    already dropped) beyond :data:`MAX_CLOCK_BACK_S`, in words naming ``what``; else None."""
    t = np.asarray(time_s, dtype=np.float64)
    if t.size < 2:
        return None
    dt = np.diff(t)
    k = int(np.argmin(dt))
    if dt[k] >= -MAX_CLOCK_BACK_S:
        return None
    return (f"the clock jumps back by {-dt[k]:.1f} s at t = {t[k]:.1f} s ({what}): sorted, the "
            "samples before and after the jump would interleave — record the warm-up again, "
            "or cut the log at the jump and give the parts as separate logs")


def time_gaps(instances: list[SensorInstance]) -> list[str]:
    """Holes in the log's time (what a cut-out slice or a skipped stretch leaves), in words.

    Judged on the instance with the most samples: a step over ten median
    sample intervals (and over a second) is a gap.
    """
    if not instances:
        return []
    inst = max(instances, key=lambda i: i.n_samples)
    if inst.n_samples < 3:
        return []
    dt = np.diff(inst.time_s)
    big = np.flatnonzero(dt > max(10.0 * float(np.median(dt)), 1.0))
    if not big.size:
        return []
    longest = int(big[np.argmax(dt[big])])
    return [f"{big.size} gap{'s' if big.size > 1 else ''} in the samples ({inst.name}), the "
            f"longest {dt[longest]:.1f} s from t = {inst.time_s[longest]:.1f} s: nothing was "
            "logged or read there"]


def drop_phantoms(instances: list[SensorInstance], autopilot: str) -> tuple[
        list[SensorInstance], list[str]]:
    """Instances that only a damaged instance field can have made, removed, with a note each.

    A phantom has an instance number the autopilot never logs
    (:data:`MAX_INSTANCE`), or a handful of samples (under 20, and under 1 %)
    where another instance of its kind holds thousands: samples of a real
    instance whose instance byte was flipped.  Left in, it would take a
    calibration slot.
    """
    keep, notes = [], []
    for inst in instances:
        most = max((i.n_samples for i in instances if i.kind == inst.kind), default=0)
        if inst.instance > MAX_INSTANCE[autopilot]:
            why = (f"instance number {inst.instance} (the autopilot logs "
                   f"0..{MAX_INSTANCE[autopilot]})")
        elif inst.n_samples < 20 and most >= 1000 and 100 * inst.n_samples < most:
            why = f"{counted(inst.n_samples, 'sample')} where another {inst.kind} has {most}"
        else:
            keep.append(inst)
            continue
        notes.append(f"{inst.name} dropped: {why}, a damaged instance field")
    return keep, notes



def lend_thermometer(inst: SensorInstance, donor: SensorInstance) -> SensorInstance:
    """``inst`` (a sensor without a thermometer) with ``donor``'s thermometer: the donor's
    temperature linearly interpolated to ``inst``'s sample times (held at its first and
    last value outside the donor's time span); ``thermometer`` names the donor."""
    if donor.temperature_c is None or not donor.n_samples:
        raise InputError(f"{donor.name} has no thermometer to lend to {inst.name}")
    temp = np.interp(np.asarray(inst.time_s, dtype=np.float64),
                     np.asarray(donor.time_s, dtype=np.float64),
                     np.asarray(donor.temperature_c, dtype=np.float64))
    return SensorInstance(inst.kind, inst.instance, inst.device_id, inst.time_s, temp,
                          inst.values, notes=list(inst.notes) + [
                              f"no thermometer of its own: {donor.name}'s lent (interpolated "
                              "to its sample times)"],
                          truth=inst.truth, damaged=inst.damaged, untrusted=inst.untrusted,
                          thermometer=donor.name)
