"""What every shipped model answers, and what tells the model kinds apart, as data.

**The protocol.**  :class:`ShippedModel` is the few operations every caller of a fitted
model needs, whatever model it is: a family's
:class:`~thermonet.models.drift_model.DriftModel`, the per-axis composite
(:class:`~thermonet.models.composite.AxisModels`), the whole-sensor model
(:class:`~thermonet.models.sensor.SensorModel`) and so a fleet unit's own model (one of
those, loaded from the unit's checkpoint):

* ``kind`` — its key in :data:`MODEL_KINDS` (``"bias"`` or ``"sensor"``), the one thing a
  caller looks up to find the pieces that differ;
* ``inputs``, ``signals``, ``outputs``, ``family_name``, ``n_params`` — what it computes
  (its output axes), from what (the family's inputs; the signals it reads, in column
  order);
* ``compensated(signals, raw)`` — the compensated outputs (N, O), float64, NumPy in and out
  (point-wise: a recurrent family's stream in time is
  :func:`thermonet.training.train.predict` with the samples' times);
* ``out_of_range(signals)`` — the per-row flag of the trained range (the clamp's flag);
* saved through the checkpoint format: ``training.sensor_checkpoint.load_shipped`` reads
  any checkpoint back by its ``format``, the kind's :attr:`ModelKind.checkpoint_format`;
* exported through the format registry: every export is
  ``thermonet.exporting.FORMATS[name].write(model, out, request)``, which picks the
  format's exporter for ``model.kind`` (a format with none for the kind refuses it in one
  line).

**The kinds.**  :data:`MODEL_KINDS` is keyed by the config's ``model:`` value (and
``DriftEstimator(model=...)``); each :class:`ModelKind` carries what differs between the
kinds as data: the settings the kind requires (config keys and the estimator's arguments,
each with the sentence that refuses another value), its checkpoint format, whether the
format registry checks its output range before an export (a sensor model's exporters check
its invertibility and parity themselves), and what its per-axis results hold.  The strategies of
the layers above (the workflow's steps, the estimator's methods, the exporters) are dicts
keyed by the same string: a lookup, not a switch.  Torch-free: the config, the API and
the CLI read it at start-up.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:
    import numpy as np

__all__ = ["ShippedModel", "ModelKind", "MODEL_KINDS", "model_kind"]


@runtime_checkable
class ShippedModel(Protocol):
    """What every shipped model answers (module docstring)."""

    kind: str
    outputs: list[str]
    signals: list[str]

    @property
    def inputs(self) -> list[str]: ...

    @property
    def family_name(self) -> str: ...

    @property
    def n_params(self) -> int: ...

    def compensated(self, signals: np.ndarray, raw: np.ndarray) -> np.ndarray: ...

    def out_of_range(self, signals: Any) -> Any: ...


@dataclass(frozen=True)
class ModelKind:
    """One model kind's differences, as data (module docstring).

    ``config_requires`` and ``estimator_requires`` map a setting (a dotted config key; a
    ``DriftEstimator`` argument) to the one value the kind takes and the sentence that
    refuses another (``{got!r}`` is the value given).  ``output_range_checked``: every
    export first checks the model's drift on its trained range
    (:func:`thermonet.exporting.domain.check_output_range`).  ``metrics_numeric_only``: its
    per-axis results hold verdicts and intervals beside the numbers (only the floats are
    logged as metrics).  ``banner``: what a command's first console line adds to name the
    kind (none for the default, ``bias``).
    """

    name: str
    checkpoint_format: int | str
    config_requires: Mapping[str, tuple[Any, str]] = field(default_factory=dict)
    estimator_requires: Mapping[str, tuple[Any, str]] = field(default_factory=dict)
    output_range_checked: bool = True
    metrics_numeric_only: bool = False
    banner: str = ""


#: The model kinds, by the config's ``model:`` value.
MODEL_KINDS: dict[str, ModelKind] = {
    "bias": ModelKind(name="bias", checkpoint_format=1),
    "sensor": ModelKind(
        name="sensor", checkpoint_format="thermonet-sensor-1",
        config_requires={
            "target": ("drift", "model 'sensor' fits bias, scale factor and misalignment "
                                "against the reference channels itself; leave 'target' at "
                                "'drift' (got {got!r})"),
            "tracking.register": (None, "model 'sensor' logs its runs but registers no model "
                                        "(a bias comparison registers its chosen one); remove "
                                        "tracking.register")},
        estimator_requires={
            "target": ("drift", "target: {got!r} with model='sensor' (the sensor model's "
                                "target is its references' error, raw − ref_<axis>: 'drift')"),
            "train_on": ("all", "train_on: {got!r} with model='sensor' (its scale factor needs "
                                "every position at every soak: 'all')")},
        output_range_checked=False, metrics_numeric_only=True, banner=" (model: sensor)"),
}


def model_kind(name: str) -> ModelKind:
    """The kind registered as ``name`` (a ``KeyError`` naming the kinds otherwise)."""
    try:
        return MODEL_KINDS[name]
    except KeyError:
        raise KeyError(f"model kind {name!r} is not one of {', '.join(MODEL_KINDS)}") from None
