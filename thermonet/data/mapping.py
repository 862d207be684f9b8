"""Column mappings: how a foreign recording file becomes thermonet channels.

A mapping is a small, strict YAML file.  Every key is optional except
``channels``; unknown keys, wrong types and unknown units are refused with one
line naming the mapping file and the key (:class:`MappingError`, which is both
an :class:`~thermonet.core.errors.InputError` and a
:class:`~thermonet.core.errors.ConfigError`).

Schema
------
.. code-block:: yaml

    format: auto            # auto (by extension) | csv | tsv | parquet
    separator: auto         # auto (sniffed from the data) or one character, e.g. ","
    skip_lines: 1           # banner lines before the header (or before the data)
    header: false           # true: the first line after the banner names the columns
    n_fields: 7             # fields per well-formed row (default: header length, or
                            # the most common field count when there is no header)
    malformed_rows: skip    # error (default) | skip: drop rows with a wrong field
                            # count or a non-numeric / non-finite cell; the count is
                            # logged and kept in Dataset.meta['skipped_rows']
    time:                   # either a time column ...
      column: "time (ms)"   # a header name, or a 0-based index
      unit: ms              # s | ms | us | min | h (µs accepted)
    sample_rate_hz: 50.0    # ... or a fixed rate when there is no time column:
                            # t = (data row - 1) / rate, so a skipped row leaves a gap
    run_column: null        # optional column whose values split the file into runs
    device_column: null     # optional column naming each row's unit (a fleet file): runs are
                            # then told apart by unit and run; device_id is the default unit
    channels:               # thermonet channel name -> source column
      gyro_x:
        column: "gyrox rad/s"   # header name, or 0-based index
        unit: rad/s             # one of thermonet.core.recording.KNOWN_UNITS
        scale: 0.5              # value = raw * scale + offset
        offset: 0.0
      temp_raw: {column: temp, unit: counts}      # a proxy (name matches no pattern)
      freq_drive: {column: 3, unit: Hz, proxy: true}
    device_id: pan-etu      # defaults: "device", the outputs' kind, the file stem
    sensor_kind: gyro
    run_id: null
    meta: {campaign: "2020-03-07 TVAC"}

Channel roles follow the names (:mod:`thermonet.core.recording`): ``temperature_c``
(unit must be ``degC``), outputs ``<kind>_<axis>``, references ``ref_<output>``,
simulated truth ``drift_<output>``; any other name, or ``proxy: true``, is a
proxy.  A channel without ``unit`` gets :func:`default_unit` of its name.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ..core.errors import ConfigError, InputError
from ..core.fileio import not_a_file
from ..core.names import TEXT_ID
from ..core.recording import KNOWN_UNITS, OUTPUT_NAME
from ..core.yamlio import YamlRefusal, load_yaml
from .diagnostics import RATE_HZ_POSSIBLE

__all__ = [
    "MappingError",
    "ChannelSpec",
    "TimeSpec",
    "ColumnMapping",
    "TIME_UNITS",
    "FORMATS",
    "channel_role",
    "case_slip",
    "default_unit",
    "UNIT_IN_DEFAULT",
    "unit_factor",
    "header_unit_clashes",
    "load_mapping",
]

#: Time units a mapping may name, as seconds per unit.
TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "μs": 1e-6,
                                "min": 60.0, "h": 3600.0}
#: Values of the ``format`` key.
FORMATS = ("auto", "csv", "tsv", "parquet")
_MALFORMED = ("error", "skip")
_CHANNEL_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}")  # fullmatch: no trailing newline
_RESERVED = ("time_s", "run", "device")


class MappingError(InputError, ConfigError):
    """A mapping file with an unknown key, a wrong type or a bad value.

    Both an input error (the mapping describes an input file) and a config
    error (it is a configuration file), so callers may catch either.
    """


def channel_role(name: str, *, proxy: bool = False) -> str:
    """Role of a channel from its name: ``temperature``, ``output``, ``reference``,
    ``drift`` or ``proxy``."""
    if proxy:
        return "proxy"
    if name == "temperature_c":
        return "temperature"
    if OUTPUT_NAME.match(name):
        return "output"
    if name.startswith("ref_") and OUTPUT_NAME.match(name[4:]):
        return "reference"
    if name.startswith("drift_") and OUTPUT_NAME.match(name[6:]):
        return "drift"
    return "proxy"


def case_slip(name: str) -> str | None:
    """The thermonet name ``name`` differs from in letter case only (``Gyro_X`` →
    ``gyro_x``, ``temperature_C`` → ``temperature_c``, ``Time_s`` → ``time_s``), else None.
    thermonet's names are lower case; a name it does not know is read as a temperature
    proxy, so such a slip would otherwise drop an axis from the fit without a word."""
    low = name.lower()
    if low == name:
        return None
    known = low in _RESERVED or channel_role(low) in ("temperature", "output", "reference",
                                                       "drift")
    return low if known else None


_KIND_UNITS = {"gyro": "deg/s", "acc": "g", "mag": "uT", "baro": "Pa", "out": "1"}
#: What each kind of channel measures (its unit's dimension, core.recording.KNOWN_UNITS).
_KIND_DIMENSION = {"gyro": "rate", "acc": "acceleration", "mag": "field", "baro": "pressure"}
_KIND_NAME = {"gyro": "a gyro", "acc": "an accelerometer", "mag": "a magnetometer",
              "baro": "a barometer"}


#: A value in each unit of a physical channel is this many of its dimension's default unit
#: (:func:`default_unit`: rate deg/s, acceleration g, field uT, pressure Pa).
UNIT_IN_DEFAULT: dict[str, float] = {
    "deg/s": 1.0, "deg/h": 1.0 / 3600.0, "rad/s": 180.0 / math.pi,
    "g": 1.0, "mg": 1e-3, "m/s^2": 1.0 / 9.80665, "T": 1e6, "uT": 1.0, "Pa": 1.0, "hPa": 100.0}


def unit_factor(unit: str, want: str) -> float | None:
    """The factor that turns a value in ``unit`` into ``want`` (1 when equal), or None where no
    conversion is known (other dimensions, raw counts, a unit outside
    :data:`UNIT_IN_DEFAULT`)."""
    if unit == want:
        return 1.0
    if unit in UNIT_IN_DEFAULT and want in UNIT_IN_DEFAULT and \
            KNOWN_UNITS[unit] == KNOWN_UNITS[want]:
        return UNIT_IN_DEFAULT[unit] / UNIT_IN_DEFAULT[want]
    return None


#: Units a column header may carry in brackets, as written by loggers, and the unit each
#: is (``degF``/``K`` are temperatures thermonet does not take: ``temperature_c`` is °C).
_HEADER_UNIT = {"°C": "degC", "degC": "degC", "°F": "degF", "degF": "degF", "K": "K",
                "Kelvin": "K", "°/s": "deg/s", "dps": "deg/s", "°/h": "deg/h",
                "m/s²": "m/s^2", "m/s2": "m/s^2", "µT": "uT", "μT": "uT", "mbar": "hPa",
                **{u: u for u in KNOWN_UNITS if u not in ("s", "1")}}
_HEADER_BRACKET = re.compile(r"[\[(]\s*([^\[\]()]+?)\s*[\])]\s*$")


def header_unit_clashes(mapping: ColumnMapping) -> list[str]:
    """The mapped columns whose header names a unit in brackets (``Temp [°F]``, ``Druck
    (hPa)``) that is a recognised unit other than the channel's, read with no scale or offset
    (a channel with either converts on purpose): ``'<column>' says <unit>, mapped as <unit>``
    each.  Headers are free text: this is for a warning, not a refusal."""
    out = []
    for ch in mapping.channels:
        if not isinstance(ch.column, str) or (ch.scale, ch.offset) != (1.0, 0.0):
            continue
        m = _HEADER_BRACKET.search(ch.column)
        said = _HEADER_UNIT.get(m.group(1)) if m else None
        if said is not None and said != ch.unit:
            out.append(f"'{ch.column}' says {m.group(1) if m else said}, mapped as {ch.unit}")
    return out


def default_unit(name: str, *, proxy: bool = False) -> str:
    """Unit assumed when none is given: ``degC`` for temperature, ``deg/s`` gyro,
    ``g`` acc, ``uT`` mag, ``1`` out; proxies ``Hz`` (``*_hz``), ``counts``
    (``*_raw``) or ``1``."""
    role = channel_role(name, proxy=proxy)
    if role == "temperature":
        return "degC"
    if role in ("output", "reference", "drift"):
        base = name.split("_", 1)[1] if role != "output" else name
        m = OUTPUT_NAME.match(base)
        return _KIND_UNITS[m.group(1)] if m else "1"
    if name.endswith("_hz"):
        return "Hz"
    if name.endswith("_raw"):
        return "counts"
    return "1"


@dataclass(frozen=True, kw_only=True)
class ChannelSpec:
    """One thermonet channel read from one source column.

    .. math:: v = s \\cdot r + o

    with ``r`` the raw cell, ``s`` = ``scale`` and ``o`` = ``offset`` (in the
    channel's ``unit``).
    """

    name: str
    column: str | int
    unit: str
    scale: float = 1.0
    offset: float = 0.0
    proxy: bool = False

    @property
    def role(self) -> str:
        return channel_role(self.name, proxy=self.proxy)


@dataclass(frozen=True, kw_only=True)
class TimeSpec:
    """The time column and its unit (``s``, ``ms``, ``us``, ``min``, ``h``)."""

    column: str | int
    unit: str = "s"

    @property
    def seconds_per_unit(self) -> float:
        return TIME_UNITS[self.unit]


@dataclass(frozen=True, kw_only=True)
class ColumnMapping:
    """A parsed, checked column mapping (see the module docstring for the YAML)."""

    channels: tuple[ChannelSpec, ...]
    format: str = "auto"
    separator: str | None = None
    skip_lines: int = 0
    header: bool = True
    n_fields: int | None = None
    malformed_rows: str = "error"
    time: TimeSpec | None = None
    sample_rate_hz: float | None = None
    run_column: str | int | None = None
    device_column: str | int | None = None
    device_id: str = "device"
    sensor_kind: str | None = None  # None: the kind of the outputs (gyro_x -> gyro)
    run_id: str | None = None  # None: the file stem
    meta: dict[str, str] = field(default_factory=dict)
    source: str = "<mapping>"

    @classmethod
    def from_dict(cls, raw: object, *, source: str = "<mapping>") -> ColumnMapping:
        """Check a mapping read from YAML; raise :class:`MappingError` naming the key."""
        return _Parser(source).mapping(raw)


def load_mapping(path: str | Path) -> ColumnMapping:
    """Read and check a YAML mapping file."""
    path = Path(path)
    why = not_a_file(path, "mapping file")
    if why:
        if why.endswith("not found") and not path.is_absolute():
            why += (f" (a relative path is resolved against the current directory {Path.cwd()}"
                    ", a config's data.mapping as --mapping; give it from there, or absolute)")
        raise MappingError.at(path, why)
    try:
        raw = load_yaml(path)
    except YamlRefusal as err:
        raise MappingError.at(path, str(err)) from None
    except yaml.YAMLError as err:
        line = getattr(getattr(err, "problem_mark", None), "line", None)
        raise MappingError.at(path, f"not valid YAML ({getattr(err, 'problem', err)})",
                              row=None if line is None else line + 1) from err
    return ColumnMapping.from_dict(raw, source=str(path))


class _Parser:
    """Strict YAML-to-dataclass checks; every error names ``source`` and the key."""

    _TOP = {"format", "separator", "skip_lines", "header", "n_fields", "malformed_rows",
            "time", "sample_rate_hz", "run_column", "device_column", "channels", "device_id",
            "sensor_kind", "run_id", "meta"}
    _CHANNEL = {"column", "unit", "scale", "offset", "proxy"}
    _TIME = {"column", "unit"}

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, message: str) -> MappingError:
        return MappingError(f"{self.source}: key '{key}': {message}")

    def keys(self, raw: dict, allowed: set[str], prefix: str) -> None:
        for k in raw:
            if k not in allowed:
                raise self.fail(f"{prefix}{k}", "unknown key (allowed: "
                                f"{', '.join(sorted(allowed))})")

    def typed(self, key: str, value: Any, kinds: tuple[type, ...], what: str) -> Any:
        # YAML's booleans are ints to Python; a `true` scale is a typo, not 1.
        if isinstance(value, bool) and bool not in kinds:
            raise self.fail(key, f"expected {what}, got {value!r}")
        if not isinstance(value, kinds):
            raise self.fail(key, f"expected {what}, got {value!r}")
        return value

    def number(self, key: str, value: Any) -> float:
        v = float(self.typed(key, value, (int, float), "a number"))
        if not math.isfinite(v):
            raise self.fail(key, f"expected a finite number, got {value!r}")
        return v

    def column(self, key: str, value: Any, header: bool) -> str | int:
        col = self.typed(key, value, (str, int), "a column name or 0-based index")
        if isinstance(col, int) and col < 0:
            raise self.fail(key, f"column index must be >= 0, got {col}")
        if isinstance(col, str) and not header:
            raise self.fail(key, f"column '{col}' given by name but 'header' is false "
                            "(use a 0-based index)")
        return col

    def mapping(self, raw: object) -> ColumnMapping:
        if not isinstance(raw, dict):
            raise MappingError.at(self.source, "a mapping file must be a YAML mapping "
                                  f"of keys, got {type(raw).__name__}")
        self.keys(raw, self._TOP, "")
        kw: dict[str, Any] = {"source": self.source}
        fmt = self.typed("format", raw.get("format", "auto"), (str,), "a string")
        if fmt not in FORMATS:
            raise self.fail("format", f"unknown format '{fmt}' (known: {', '.join(FORMATS)})")
        kw["format"] = fmt
        sep = raw.get("separator", "auto")
        if sep is not None and sep != "auto":
            sep = self.typed("separator", sep, (str,), "one character or 'auto'")
            if len(sep) != 1:
                raise self.fail("separator", f"expected one character or 'auto', got {sep!r}")
            kw["separator"] = sep
        skip = self.typed("skip_lines", raw.get("skip_lines", 0), (int,), "an integer")
        if skip < 0:
            raise self.fail("skip_lines", f"must be >= 0, got {skip}")
        kw["skip_lines"] = skip
        header = kw["header"] = self.typed("header", raw.get("header", True), (bool,),
                                           "true or false")
        if raw.get("n_fields") is not None:
            n = self.typed("n_fields", raw["n_fields"], (int,), "an integer")
            if n < 1:
                raise self.fail("n_fields", f"must be >= 1, got {n}")
            kw["n_fields"] = n
        mal = self.typed("malformed_rows", raw.get("malformed_rows", "error"), (str,),
                         "'error' or 'skip'")
        if mal not in _MALFORMED:
            raise self.fail("malformed_rows", f"expected 'error' or 'skip', got '{mal}'")
        kw["malformed_rows"] = mal
        kw["time"] = self.time(raw.get("time"), header)
        if raw.get("sample_rate_hz") is not None:
            rate = self.number("sample_rate_hz", raw["sample_rate_hz"])
            if rate <= 0:
                raise self.fail("sample_rate_hz", f"must be > 0, got {rate:g}")
            if not RATE_HZ_POSSIBLE[0] <= rate <= RATE_HZ_POSSIBLE[1]:
                raise self.fail("sample_rate_hz", f"{rate:g} Hz is not a possible sample rate "
                                f"of a thermal test (expected {RATE_HZ_POSSIBLE[0]:g} … "
                                f"{RATE_HZ_POSSIBLE[1]:g} Hz)")
            kw["sample_rate_hz"] = rate
        if (kw["time"] is None) == ("sample_rate_hz" not in kw):
            raise self.fail("time", "give exactly one of 'time' (a time column) and "
                            "'sample_rate_hz' (a fixed rate)")
        if raw.get("run_column") is not None:
            kw["run_column"] = self.column("run_column", raw["run_column"], header)
        if raw.get("device_column") is not None:
            kw["device_column"] = self.column("device_column", raw["device_column"], header)
        for key in ("device_id", "sensor_kind", "run_id"):
            if raw.get(key) is not None:
                kw[key] = str(self.typed(key, raw[key], (str, int, float), "a string"))
                if TEXT_ID.fullmatch(kw[key]) is None:  # it reaches results, metadata, exports
                    raise self.fail(key, f"{kw[key]!r} is not printable text of 1 to 128 "
                                    "characters")
        meta = raw.get("meta") or {}
        self.typed("meta", meta, (dict,), "a mapping of strings")
        kw["meta"] = {str(k): str(v) for k, v in meta.items()}
        kw["channels"] = self.channels(raw.get("channels"), header)
        return ColumnMapping(**kw)

    def time(self, raw: Any, header: bool) -> TimeSpec | None:
        if raw is None:
            return None
        if not isinstance(raw, dict):
            # A bare column name would force a guess of its unit (s? ms?), and a
            # wrong guess scales every rate by 1000: ask for the unit explicitly.
            raise self.fail("time", f"expected a mapping with 'column' and 'unit', got {raw!r}")
        self.keys(raw, self._TIME, "time.")
        if "column" not in raw:
            raise self.fail("time.column", "missing (the source column of time)")
        unit = self.typed("time.unit", raw.get("unit", "s"), (str,), "a time unit")
        if unit not in TIME_UNITS:
            raise self.fail("time.unit", f"unknown time unit '{unit}' "
                            f"(known: {', '.join(TIME_UNITS)})")
        return TimeSpec(column=self.column("time.column", raw["column"], header), unit=unit)

    def channels(self, raw: Any, header: bool) -> tuple[ChannelSpec, ...]:
        if not raw:
            raise self.fail("channels", "missing or empty (map at least one output channel)")
        if not isinstance(raw, dict):
            raise self.fail("channels", f"expected a mapping channel -> spec, got {raw!r}")
        out = []
        for name, spec in raw.items():
            key = f"channels.{name}"
            if not isinstance(name, str) or not _CHANNEL_NAME.fullmatch(name) \
                    or name in _RESERVED:
                raise self.fail(key, "invalid channel name (letters, digits, '_'; "
                                "not 'time_s', 'run' or 'device')")
            if not isinstance(spec, dict):
                raise self.fail(key, f"expected a mapping with 'column', got {spec!r}")
            self.keys(spec, self._CHANNEL, key + ".")
            if "column" not in spec:
                raise self.fail(key + ".column", "missing (the source column)")
            proxy = self.typed(key + ".proxy", spec.get("proxy", False), (bool,),
                               "true or false")
            if proxy and name == "temperature_c":
                raise self.fail(key + ".proxy", "temperature_c cannot be a proxy")
            slip = case_slip(name)
            if slip and not proxy:
                raise self.fail(key, f"'{name}' is not a thermonet channel name: did you mean "
                                f"'{slip}'? (names are lower case; to keep it as a proxy, "
                                "say 'proxy: true')")
            unit = spec.get("unit")
            unit = default_unit(name, proxy=proxy) if unit is None else \
                self.typed(key + ".unit", unit, (str,), "a unit string")
            if unit not in KNOWN_UNITS:
                raise self.fail(key + ".unit", f"unknown unit '{unit}' "
                                f"(known: {', '.join(sorted(KNOWN_UNITS))})")
            if not proxy and channel_role(name) == "proxy" and KNOWN_UNITS[unit] not in (
                    "frequency", "raw", "dimensionless"):
                raise self.fail(key, f"'{name}' is not a thermonet channel name "
                                "(temperature_c, <kind>_<axis>, ref_…, drift_…); a proxy in "
                                f"'{unit}' must say 'proxy: true' — or is it a misspelling?")
            role = channel_role(name, proxy=proxy)
            kind = OUTPUT_NAME.match(name.split("_", 1)[1] if role in ("reference", "drift")
                                     else name)
            what = kind.group(1) if kind and role != "proxy" else ""
            dim = _KIND_DIMENSION.get(what)
            if dim and KNOWN_UNITS[unit] not in (dim, "raw", "dimensionless"):
                fits = ", ".join(u for u, d in KNOWN_UNITS.items() if d == dim)
                raise self.fail(key + ".unit", f"'{unit}' is a unit of {KNOWN_UNITS[unit]}, and "
                                f"{name} is {_KIND_NAME[what]} channel (its units: {fits}; "
                                "or counts / 1 for raw values)")
            if name == "temperature_c" and unit != "degC":
                raise self.fail(key + ".unit", f"temperature_c must be in degC, got '{unit}' "
                                "(convert with scale/offset, or map it as a proxy)")
            scale = self.number(key + ".scale", spec.get("scale", 1.0))
            if scale == 0.0:
                raise self.fail(key + ".scale", "is 0: every value of the channel would be its "
                                "offset")
            out.append(ChannelSpec(
                name=name, column=self.column(key + ".column", spec["column"], header),
                unit=unit, scale=scale,
                offset=self.number(key + ".offset", spec.get("offset", 0.0)), proxy=proxy))
        if not any(c.role == "output" for c in out):
            raise self.fail("channels", "no output channel (need at least one "
                            "<kind>_<axis>, e.g. gyro_x)")
        return tuple(out)
