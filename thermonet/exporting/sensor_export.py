"""Exporting a full sensor model (``model: sensor``): ONNX, and the autopilot refusal.

A sensor model (``kind`` ``sensor``; its checkpoint
:func:`thermonet.training.sensor_checkpoint.save_sensor`, format ``thermonet-sensor-1``) is
exported through the format registry as every model is
(:meth:`thermonet.exporting.ExportFormat.write`): each format's exporter for the kind is
here (:func:`write_sensor_onnx`, :func:`write_sensor_c`, the two refusals), and
:func:`export_sensor_source` is a sensor checkpoint loaded and handed to the registry:

``onnx``
    The graph of :meth:`thermonet.models.sensor.SensorModel.columns` with the bias models'
    interface (:class:`thermonet.exporting.onnx_export.CompensatorGraph`): one [N] input per
    signal then ``raw`` [N, O] float64; outputs ``compensated`` [N, O] = M(s)⁻¹(raw − b(s)),
    ``drift`` = raw − compensated (the correction applied) and ``out_of_range`` [N].  So the
    torch-free runtime and any host that runs a bias model's graph run this one unchanged.
    The 3 × 3 inverse is the adjugate in float64 (element-wise Mul/Sub/Div).  Written only
    after parity with torch (:func:`sensor_parity`) on samples spanning the trained range.
``px4-params``, ``ardupilot-params``
    Refused with one line: their parameters hold a bias polynomial per axis, no scale factor
    or misalignment.  The refusal names the bias-only model fitted beside the sensor model
    on the same data (``models/<label>.bias-only.pt``, a plain bias checkpoint) and the
    command that exports it.
``c``
    The C99 header of :mod:`thermonet.exporting.sensor_c` (two bias bodies, the 3 × 3 solve,
    and every header's ``init``/``step``/``step_block``: the dynamic inputs computed once for
    b and E), compiled and checked against torch before it is written, batch and ``step()``,
    on the double and the float path.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ..core.errors import ExportError
from ..core.fileio import atomic_path
from ..models.sensor import SensorModel, check_invertible
from ..training.sensor_checkpoint import load_sensor
from . import ExportRequest, get_format
from .onnx_export import _metadata_props
from .onnx_seal import seal_bytes
from .onnx_trace import export_proto
from .sensor_c import export_sensor_c
from .sensor_probe import PARITY_EPS32, probe

__all__ = ["SensorGraph", "export_sensor_onnx", "sensor_parity", "export_sensor_source",
           "bias_only_path", "write_sensor_onnx", "write_sensor_c", "refuse_px4_params",
           "refuse_ardupilot_params"]

class SensorGraph(nn.Module):
    """``forward(*signals, raw) -> (compensated, drift, out_of_range)`` (see module doc)."""

    def __init__(self, model: SensorModel) -> None:
        super().__init__()
        self.model = model
        self.signals = list(model.signals)
        self.outputs = list(model.outputs)

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        *signal_list, raw = inputs
        comp, flag = self.model.columns(signal_list, raw)
        return comp, raw.to(torch.float64) - comp, flag


def bias_only_path(sensor_ckpt: str | Path) -> Path:
    """Where the bias-only model fitted beside a sensor model is saved."""
    p = Path(sensor_ckpt)
    return p.with_name(f"{p.stem}.bias-only.pt")


def sensor_parity(model: SensorModel, path: str | Path) -> dict[str, float]:
    """Run the ONNX file in onnxruntime against torch on :func:`~.sensor_probe.probe` samples; raise
    :class:`ExportError` beyond :data:`PARITY_EPS32` × ε32 × (|raw| + |b|)."""
    import onnxruntime as ort

    sig, raw = probe(model)
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    feeds: dict[str, Any] = {n: sig[:, i].astype(np.float32) for i, n in enumerate(model.signals)}
    feeds["raw"] = raw
    comp_o, drift_o, flag_o = sess.run(["compensated", "drift", "out_of_range"], feeds)
    with torch.no_grad():
        comp_tt, flag_t = model.columns(torch.as_tensor(sig, dtype=torch.float32).unbind(1),
                                        torch.as_tensor(raw))
        b = model.bias.drift64(torch.as_tensor(sig, dtype=torch.float32)).numpy()
    comp_t = comp_tt.numpy()
    tol = PARITY_EPS32 * float(np.finfo(np.float32).eps) * (np.abs(raw) + np.abs(b))
    err = np.abs(comp_o - comp_t)
    if not np.all(err <= tol) or not np.array_equal(flag_o.astype(bool), flag_t.numpy()):
        i, j = np.unravel_index(int(np.argmax(err / tol)), err.shape)
        raise ExportError(f"sensor ONNX parity failed: output '{model.outputs[j]}' differs "
                          f"from torch by {err[i, j]:.3g} (tolerance {tol[i, j]:.3g}); "
                          "the file was not written")
    if not np.allclose(drift_o, raw - comp_o, rtol=0, atol=float(tol.max())):
        raise ExportError("sensor ONNX parity failed: drift != raw - compensated")
    return {"max_abs_error": float(err.max()), "max_error_over_tolerance":
            float((err / tol).max()), "samples": float(sig.shape[0])}


def export_sensor_onnx(model: SensorModel, path: str | Path, *,
                       metadata: dict[str, Any] | None = None) -> dict[str, Any]:
    """Write the sensor model's ONNX graph to ``path`` (atomic, only after parity and the
    invertibility check on the trained range); returns what results.json records."""
    import onnx

    for name, p in list(model.named_parameters()) + list(model.named_buffers()):
        if p.is_floating_point() and bool(torch.isnan(p).any()):
            raise ExportError(f"sensor model parameter '{name}' holds NaN; refusing to export")
    sig, _ = probe(model)
    check_invertible(model, sig, what="sensor model")
    graph = SensorGraph(model).eval()
    # the TorchScript exporter: the dynamo one writes an invalid graph for two DriftModels
    # reading the same inputs (onnxruntime: "Node input 'inputs_0_min_1' is not a graph
    # input"), measured with this repository's torch; parity below checks the result either way
    proto, exporter = export_proto(graph, "torchscript")
    # the bias model's metadata (signals, outputs, units, T_ref, trained range, digest), so
    # the torch-free runtime reads this file as it reads a bias model's, plus what makes it a
    # sensor model; "family" names the family of every element
    props = _metadata_props(model.bias, dict(metadata or {}), exporter)
    props.update({"model": "sensor", "triads": json.dumps(model.triads),
                  "elements": json.dumps(model.element_outputs),
                  "elements_compensated": json.dumps(dict(zip(
                      model.element_outputs, model.elements.compensated_axes, strict=True)))})
    for k, v in props.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = k, v
    proto.producer_name = "thermonet"
    out = Path(path)
    with atomic_path(out) as tmp:
        onnx.save_model(proto, str(tmp), save_as_external_data=False)
        seal_bytes(Path(tmp))
        onnx.checker.check_model(str(tmp))
        parity = sensor_parity(model, tmp)
    return {"status": "ok", "path": str(out), "exporter": exporter, "parity": parity}


def write_sensor_onnx(model: SensorModel, out: Path, request: ExportRequest) -> Path:
    """``onnx`` of a sensor model (the format registry's exporter for ``kind`` ``sensor``):
    :func:`export_sensor_onnx` with the checkpoint's device id, units and validation score."""
    extra = request.extra
    export_sensor_onnx(model, out, metadata={
        "device_id": extra.get("device_id", ""), "output_units": extra.get("units", {}),
        "validation_metrics": {"val_score": extra.get("val_score")}})
    return Path(out)


def write_sensor_c(model: SensorModel, out: Path, request: ExportRequest) -> Path:
    """``c`` of a sensor model: :func:`thermonet.exporting.sensor_c.export_sensor_c`, with
    the checkpoint's units and the request's prefix."""
    return export_sensor_c(model, out, prefix=request.prefix or "thermonet",
                           units=request.output_units)


def _refuse_autopilot(fmt: str, request: ExportRequest) -> Path:
    source = request.source or "model"
    raise ExportError(
        f"{source}: a sensor model (bias, scale factor and misalignment per triad) cannot be "
        f"written as {fmt}: those parameters hold a bias polynomial per axis only; export "
        f"the bias-only model fitted beside it: thermonet export {bias_only_path(source)} "
        f"--format {fmt}")


def refuse_px4_params(model: SensorModel, out: Path, request: ExportRequest) -> Path:
    """``px4-params`` of a sensor model: refused in one line naming the bias-only model
    fitted beside it and the command that exports it."""
    return _refuse_autopilot("px4-params", request)


def refuse_ardupilot_params(model: SensorModel, out: Path, request: ExportRequest) -> Path:
    """``ardupilot-params`` of a sensor model: refused as :func:`refuse_px4_params`."""
    return _refuse_autopilot("ardupilot-params", request)


def export_sensor_source(ckpt: Path, *, fmt: str, out: str | Path) -> Path:
    """A sensor checkpoint exported through the format registry (the module docstring)."""
    model, payload = load_sensor(ckpt)
    return get_format(fmt).write(model, out, ExportRequest(meta=payload, source=str(ckpt)))
