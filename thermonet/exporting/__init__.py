"""Export a trained drift model for use on board: one registry of formats.

:data:`FORMATS` maps a format's name (what ``thermonet export --format`` and
:meth:`thermonet.DriftEstimator.export` take) to an :class:`ExportFormat`: a
one-line description (the CLI's help is built from it) and its exporter,
``exporter(model, out, request) -> Path``.  Built-in exporters are named as
``"module:function"`` and imported only when used, so this registry (and the
CLI that lists it) stays light; a new format is a module with its exporter and
one :func:`register_format` line below.

* ``onnx`` — an ONNX file with the features, the clamp to the trained range and
  the out-of-range flag inside the graph, checked against torch with
  onnxruntime before it is written (run it with ``export/thermonet_runtime.py``);
* ``c`` — a C99 header, no heap: the model in float32, raw and drift in double on a host
  or a double-precision FPU (``expf``/``expm1f`` from libm) and in float on a
  single-precision microcontroller (its own ``expf``/``expm1f``, no libm);
* ``px4-params`` / ``ardupilot-params`` — the autopilots' own thermal-calibration
  parameter files, for a family that has a polynomial form in one temperature input.

The heavy functions of the sub-modules (:func:`export_onnx`,
:func:`export_c_header`, ...) are importable from here too; they load on
first access.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from ..core.errors import ExportError, InputError
from ..models.shipped import ShippedModel, model_kind

if TYPE_CHECKING:
    from ..models.composite import DriftModels

__all__ = [
    "ExportFormat", "ExportRequest", "Exporter", "FORMATS", "register_format", "get_format",
    "MAX_DEVICE_ID",
    "is_device_id",
    "export_source", "resolve_checkpoint",
    "CompensatorGraph", "export_onnx", "parity_check", "log_onnx_to_mlflow", "onnx_file_size",
    "log_onnx_model", "onnx_of_checkpoint",
    "export_c_header", "render_c_header",
    "AutopilotCoefficients", "autopilot_coefficients", "export_px4_params",
    "export_ardupilot_params", "read_px4_params", "read_ardupilot_params",
]


#: The largest sensor device id: PX4's ``TC_*_ID`` and ArduPilot's ids are 32-bit (what
#: ``thermonet verify`` reads back: :func:`thermonet.workflows.verify_params._device_id`).
MAX_DEVICE_ID = 2 ** 32 - 1


def is_device_id(value: Any) -> bool:
    """A PX4 / ArduPilot sensor device id: a number whose integer is in
    1..:data:`MAX_DEVICE_ID` (not a bool)."""
    return not isinstance(value, bool) and 1 <= int(value) <= MAX_DEVICE_ID


@dataclass(frozen=True)
class ExportRequest:
    """What an exporter receives beside the model and the output path.

    Attributes
    ----------
    meta : dict
        The checkpoint's metadata (``extra`` holds units, device id, data hash,
        the training run id, validation metrics); empty for an in-memory model.
    device_id : int or None
        PX4's ``TC_*_ID`` of the sensor (``px4-params``).
    instance : int or None
        PX4 calibration slot 0..3 (default 0) or ArduPilot IMU 1..3 (default 1).
    tracking_uri : str or None
        MLflow store to log the exported file to (``onnx``).
    source : str or None
        Where the model came from (its checkpoint file), named in errors; None for
        an in-memory model.
    prefix : str or None
        The C symbols' prefix (``c``; None: ``thermonet``).
    """

    meta: dict[str, Any] = field(default_factory=dict)
    device_id: int | None = None
    instance: int | None = None
    tracking_uri: str | None = None
    source: str | None = None
    prefix: str | None = None

    @property
    def extra(self) -> dict[str, Any]:
        return dict(self.meta.get("extra") or {})

    @property
    def output_units(self) -> dict[str, str]:
        return dict(self.extra.get("units") or {})


#: ``exporter(model, out, request) -> written path``: ``model`` a shipped model of the kind
#: the exporter is registered for (:class:`thermonet.models.shipped.ShippedModel`).
Exporter = Callable[[Any, Path, ExportRequest], Path]


@dataclass(frozen=True)
class ExportFormat:
    """One export format: its name, a one-line description and its exporter.

    ``exporter`` is a callable or ``"package.module:function"`` (imported on
    first use, which keeps the registry free of torch and onnx).
    """

    name: str
    description: str
    exporter: str | Exporter
    #: The exporters of the other model kinds (a shipped model's ``kind``,
    #: :data:`thermonet.models.shipped.MODEL_KINDS`), by kind; ``exporter`` is the bias
    #: kind's (a :class:`~thermonet.models.drift_model.DriftModel` or per-axis model).
    kinds: Mapping[str, str | Exporter] = field(default_factory=dict)

    def resolve(self, kind: str = "bias", source: str | None = None) -> Exporter:
        """The exporter function of the model kind ``kind`` (importing its module when named
        as a string); an :class:`ExportError` naming ``source`` where this format has none
        for the kind."""
        exporters = {"bias": self.exporter, **self.kinds}
        if kind not in exporters:
            have = [f.name for f in FORMATS.values() if kind in {"bias", *f.kinds}]
            raise ExportError(f"{source or 'model'}: format '{self.name}' is not available for "
                              f"a {kind} model; export it as {' or '.join(have) or 'nothing'}")
        exporter = exporters[kind]
        if not isinstance(exporter, str):
            return exporter
        module, _, attr = exporter.partition(":")
        fn: Exporter = getattr(importlib.import_module(module), attr)
        return fn

    def write(self, model: ShippedModel, out: str | Path, request: ExportRequest | None = None
              ) -> Path:
        """Export ``model`` to ``out``; return the written path.

        Every format passes here: the model's output is first checked on its trained
        range (finite, within the training targets' mean ± K std —
        :func:`thermonet.exporting.domain.check_output_range`), so no format writes a
        model whose drift is absurd; nothing is written when it is refused.  ``model`` is a
        :class:`~thermonet.models.drift_model.DriftModel` or a per-axis
        :class:`~thermonet.models.composite.AxisModels` (every built-in format takes both;
        the autopilot files only where each owned axis is a cubic on temperature).
        """
        from .domain import check_output_range  # lazy: importing it loads numpy

        request = request or ExportRequest()
        kind = getattr(model, "kind", "bias")
        exporter = self.resolve(kind, request.source)
        if model_kind(kind).output_range_checked:
            check_output_range(cast("DriftModels", model), units=request.output_units,
                               source=request.source or f"model '{model.family_name}' (in memory)")
        return exporter(model, Path(out), request)


#: Registered export formats, by name.
FORMATS: dict[str, ExportFormat] = {}


def register_format(fmt: ExportFormat) -> ExportFormat:
    """Add ``fmt`` to :data:`FORMATS` (a name registered twice is a ``ValueError``)."""
    if fmt.name in FORMATS:
        raise ValueError(f"export format {fmt.name!r} is already registered")
    FORMATS[fmt.name] = fmt
    return fmt


def get_format(name: str) -> ExportFormat:
    """The format registered as ``name``; an unknown name is an :class:`InputError` listing them."""
    try:
        return FORMATS[name]
    except KeyError:
        raise InputError(f"unknown export format '{name}' (formats: {', '.join(FORMATS)})"
                         ) from None


_SENSOR = "thermonet.exporting.sensor_export"
register_format(ExportFormat(
    "onnx", "ONNX graph with features, clamp and out-of-range flag (onnxruntime, "
    "export/thermonet_runtime.py)", "thermonet.exporting.source:write_onnx",
    kinds={"sensor": f"{_SENSOR}:write_sensor_onnx"}))
register_format(ExportFormat(
    "c", "C99 header, no heap: the model in float32; raw/drift double on a host (libm "
    "expf/expm1f), float on a single-precision MCU (no libm)",
    "thermonet.exporting.source:write_c", kinds={"sensor": f"{_SENSOR}:write_sensor_c"}))
register_format(ExportFormat(
    "px4-params", "PX4 thermal-calibration parameters TC_* (a polynomial of degree <= 3 in T; "
    "needs --device-id)", "thermonet.exporting.source:write_px4_params",
    kinds={"sensor": f"{_SENSOR}:refuse_px4_params"}))
register_format(ExportFormat(
    "ardupilot-params", "ArduPilot INS_TCAL* parameters (a polynomial of degree <= 3 in T)",
    "thermonet.exporting.source:write_ardupilot_params",
    kinds={"sensor": f"{_SENSOR}:refuse_ardupilot_params"}))


_LAZY = {
    "export_source": "source", "resolve_checkpoint": "source",
    "CompensatorGraph": "onnx_export", "export_onnx": "onnx_export",
    "parity_check": "parity", "log_onnx_to_mlflow": "onnx_mlflow",
    "onnx_file_size": "onnx_export", "log_onnx_model": "onnx_mlflow",
    "onnx_of_checkpoint": "source",
    "export_c_header": "c_export", "render_c_header": "c_header",
    "AutopilotCoefficients": "autopilot", "autopilot_coefficients": "autopilot",
    "export_px4_params": "autopilot", "export_ardupilot_params": "autopilot",
    "read_px4_params": "autopilot_read", "read_ardupilot_params": "autopilot_read",
}


def __getattr__(name: str) -> Any:
    """Load the heavy export functions (torch, onnx) on first access only."""
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
