"""What the drift of each output is relative to: the per-axis target modes.

A drift model predicts, per output axis, what must be subtracted from the raw
output.  *Relative to what* depends on what is known about the true input:

``channel``
    A reference channel ``ref_<axis>`` holds the true input (a turntable's
    rate, the gravity projection of a multi-position test): the drift is
    ``output − ref_<axis>``, constant included.
``zero``
    The true input is zero (a static gyro: the Earth's rate is below the
    noise of the sensors thermonet is for), so the absolute output is drift,
    constant bias included — what PX4's gyro calibration assumes: it fits the
    raw static rate against temperature and keeps the constant term ``X0``
    (``src/modules/temperature_compensation/temperature_calibration/gyro.cpp``,
    ``finish_sensor_instance``, PX4-Autopilot commit 25ed6b67).
``at-t-ref``
    The true input is an unknown constant (gravity's projection on a level or
    tilted accelerometer, an inclinometer's 1 g, a magnetometer's field, a
    pressure): only the *change* with temperature is drift.  The model is
    normalised to zero at :math:`T_{ref}` (dynamic inputs at rest: rate 0) —
    PX4's accelerometer calibration does the same: ``res[i][3] = 0.0; //
    normalise the correction to be zero at the reference temperature``
    (``temperature_calibration/accel.cpp``, same function and commit).  The
    compensated output keeps gravity.
``four-position``
    Study 000's per-soak bias ``<axis>.bias`` and scale factor
    ``<axis>.scale`` from a static multi-position test (config ``target:
    four-position``); a scale factor's nominal value is not an error.

Config (``target`` section of a comparison)::

    target: {gyro: zero, acc: at-t-ref, acc_z: channel}   # per output kind or name
    target: four-position                                   # study 000's procedure
    target: drift                                           # every axis at its default

A name wins over its kind, a kind over the default.  Defaults: an axis with a
``ref_<axis>`` channel in the data → ``channel``; otherwise ``gyro`` → ``zero``
and every other kind (``acc``, ``mag``, ``baro``, ``out``) → ``at-t-ref``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..core.errors import ConfigError

__all__ = ["CHANNEL", "ZERO", "AT_T_REF", "FOUR_POSITION", "MODES", "MODE_CODES", "Target",
           "resolve_targets", "FOURPOS_SUFFIXES", "modelled_outputs", "output_units"]

CHANNEL, ZERO, AT_T_REF, FOUR_POSITION = "channel", "zero", "at-t-ref", "four-position"
#: Modes a config may name per output (``four-position`` is a whole-comparison target).
MODES = (CHANNEL, ZERO, AT_T_REF)
#: Integer code of each mode as stored in a model's ``target_code`` buffer (checkpoints, exports).
MODE_CODES = {CHANNEL: 0, ZERO: 1, AT_T_REF: 2, FOUR_POSITION: 3}
#: Output-name suffixes of the four-position target: per axis its bias K0 and scale factor K1.
FOURPOS_SUFFIXES = (".bias", ".scale")


def modelled_outputs(axes: Sequence[str], target: Any) -> list[str]:
    """The outputs a model of ``axes`` fits: for the four-position target each axis's bias and
    scale factor (``<axis>.bias``, ``<axis>.scale``), else the axes themselves — the one rule
    for a comparison (:func:`thermonet.training.config.outputs_of`) and the API."""
    if target == FOUR_POSITION:
        return [f"{a}{s}" for a in axes for s in FOURPOS_SUFFIXES]
    return list(axes)


def output_units(outputs: Sequence[str], units: Mapping[str, str]) -> dict[str, str]:
    """Unit per modelled output from the data's ``units`` per channel: the axis's own
    (``gyro_x.bias`` is ``gyro_x``'s), ``"1"`` for a scale factor (``<axis>.scale``), ``""``
    where the data says none — one rule for a comparison and the API."""
    return {o: "1" if o.endswith(FOURPOS_SUFFIXES[1]) else units.get(o.split(".")[0], "")
            for o in outputs}


def _kind(output: str) -> str:
    return output.split(".", 1)[0].split("_", 1)[0]


@dataclass(frozen=True)
class Target:
    """Resolved target: one mode per output axis, in output order.

    Attributes
    ----------
    outputs : list of str
        Output names (``gyro_x``; ``acc_x.bias``/``acc_x.scale`` for four-position).
    modes : list of str
        One of :data:`MODES` or ``four-position`` per output.
    """

    outputs: list[str]
    modes: list[str]
    kind: str = "drift"                  # "drift" or "four-position" (the whole comparison)
    _index: dict[str, int] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        if len(self.outputs) != len(self.modes):
            raise ConfigError(f"target: {len(self.modes)} modes for {len(self.outputs)} outputs")
        for o, m in zip(self.outputs, self.modes, strict=True):
            if m not in MODE_CODES:
                raise ConfigError(f"target: output '{o}': mode {m!r} is not one of "
                                  f"{', '.join(MODE_CODES)}")
        self._index.update({o: i for i, o in enumerate(self.outputs)})

    def mode(self, output: str) -> str:
        """The mode of one output."""
        return self.modes[self._index[output]]

    @property
    def codes(self) -> list[int]:
        """Integer codes (:data:`MODE_CODES`) per output, for the model's buffer."""
        return [MODE_CODES[m] for m in self.modes]

    def offset_free(self, output: str) -> bool:
        """True where a constant in the target is not an error (at-t-ref axes, scale factors)."""
        return self.mode(output) == AT_T_REF or output.endswith(".scale")

    def as_dict(self) -> dict[str, str]:
        """``{output: mode}`` for results.json and export metadata."""
        return dict(zip(self.outputs, self.modes, strict=True))

    @classmethod
    def uniform(cls, outputs: Sequence[str], mode: str) -> Target:
        """Every output in one mode."""
        return cls(list(outputs), [mode] * len(outputs),
                   kind=FOUR_POSITION if mode == FOUR_POSITION else "drift")


def resolve_targets(spec: str | Mapping[str, Any] | None, outputs: Sequence[str], *,
                    has_reference: Mapping[str, bool], source: str = "config") -> Target:
    """Per-output target modes from the config's ``target`` value.

    Parameters
    ----------
    spec : str, mapping or None
        ``"drift"`` / None (every axis at its default), ``"four-position"``, or a
        mapping ``{kind or output name: mode}``.
    outputs : sequence of str
        The modelled outputs (``<axis>.bias``/``.scale`` for four-position).
    has_reference : mapping output -> bool
        Whether the data carry ``ref_<output>`` (in any run).
    source : str
        Names the config file in errors.

    Raises
    ------
    ConfigError
        An unknown mode, a key that names no output or kind of the data, or
        ``channel`` for an output without a reference channel.
    """
    if spec == FOUR_POSITION:
        return Target.uniform(outputs, FOUR_POSITION)
    if spec is None or spec == "drift":
        given: dict[str, str] = {}
    elif isinstance(spec, Mapping):
        given = {}
        kinds = {_kind(o) for o in outputs}
        for key, mode in spec.items():
            if not isinstance(key, str) or (key not in outputs and key not in kinds):
                raise ConfigError(f"{source}: key 'target.{key}': names no output or output "
                                  f"kind of the data (outputs: {', '.join(outputs)})")
            if mode not in MODES:
                raise ConfigError(f"{source}: key 'target.{key}': {mode!r} is not one of "
                                  f"{', '.join(MODES)}")
            given[key] = mode
    else:
        raise ConfigError(f"{source}: key 'target': {spec!r} is not 'drift', 'four-position' "
                          f"or a mapping {{kind or output: {' | '.join(MODES)}}}")
    modes = []
    for o in outputs:
        mode = given.get(o, given.get(_kind(o)))
        if mode is None:
            mode = CHANNEL if has_reference.get(o) else (ZERO if _kind(o) == "gyro" else AT_T_REF)
        if mode == CHANNEL and not has_reference.get(o):
            key = o if o in given else _kind(o)
            raise ConfigError(f"{source}: key 'target.{key}': 'channel' needs a reference "
                              f"column ref_{o} and the data has none")
        modes.append(mode)
    return Target(list(outputs), modes)
