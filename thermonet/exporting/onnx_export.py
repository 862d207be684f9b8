"""ONNX export of a drift model, with the features, clamp and flag inside the graph.

The exported graph is what runs on board (``export/thermonet_runtime.py``):

.. math::

    \\text{drift} = f(\\operatorname{clip}(s, s_{lo}, s_{hi})), \\qquad
    \\text{compensated} = \\text{raw} - \\text{drift}

with one float32 [N] graph input per physical signal the model reads
(``temperature_c``, ``rate_c_per_min``, proxies such as ``freq_hz``) plus
``raw`` float64 [N, A]; outputs ``compensated`` float64 [N, A], ``drift``
float64 [N, A] and ``out_of_range`` bool [N].  The model runs in float32 on
the drift relative to its per-axis constant (:mod:`thermonet.models.base`);
the constant (an output's 1e6 counts, 4,517 Hz) is added and ``raw − drift``
computed in float64, so a large constant costs no precision (format 2; format 1
files had a float32 ``raw``).  The metadata carry each axis's target mode
(``targets``: channel, zero, at-t-ref — :mod:`thermonet.features.target`), whether it is
compensated (``compensate``: an axis where the chosen model does not beat the
raw output has drift 0), the float64 constant (``drift_constant``) and the
signals at rest where ``at-t-ref`` axes are zero (``rest_signals``).
``out_of_range`` is true where a signal lay outside the trained range (the
drift is then the edge value, PX4-style) or was not finite (NaN/±inf: the
drift and the compensated output are then NaN, so a broken thermometer can
never yield a plausible-looking correction).

Exporter.  The families that ship most (linear, poly — dynamic inputs included —, rbf,
lorentz, ts-fuzzy, and per-axis models of them) are written node by node from their parameters
(:mod:`thermonet.exporting.onnx_graph`, ``exporter`` ``direct``: no trace, the same
operations torch's exporter writes; a fraction of a second instead of three).  Every other
family goes through torch: its 2.13 default ``torch.export``-based exporter (``dynamo=True``,
onnxscript) is used with a dynamic batch dimension and opset 18; the
TorchScript exporter (``dynamo=False``, deprecated since torch 2.9) is the
fallback when the first fails, and ``metadata_props['exporter']`` says which
one wrote the file.  The debug annotations the dynamo exporter attaches to every
node (source stack traces, original names) and the intermediate ``value_info``
are stripped: they triple the file size and mean nothing on board.  Weights are
stored inside the file (no external data), constants folded by the exporter.

Parity tolerance.  onnxruntime and torch evaluate the same float32 graph with
different kernels (fused ops, other summation orders), so they differ by a few
float32 rounding steps of the *intermediate* values, whose size is that of the
output's scale (``y_std``, ``y_mean``), not of one small output value.  The check
is, per axis :math:`a` over the check points,

.. math::

    |d_{ort} - d_{torch}| \\le \\max\\big(10^{-5} \\max_k |d_{torch,k,a}|,\\;
    4 \\max_k |d_{torch,k,a} - d_{float64,k,a}|\\big)

i.e. 1e-5 relative to the axis's largest drift on the checked set — about 80
float32 ulps, far above kernel-order noise (≈ 1e-7 relative) and far below any
real graph error (a wrong sign, a missing clamp, a wrong reference: ≥ 1e-3
relative) — unless the model is itself more sensitive to float32 rounding than
that: a narrow Lorentz peak on a 4,500 Hz proxy turns one ulp of an intermediate
into 2e-5 of the output.  The same parameters evaluated in float64 measure that
sensitivity (:func:`float32_tolerance`), and a second float32 implementation may
differ from torch by four times torch's own rounding error, never more.

Integrity.  The file carries its own SHA-256 in ``metadata_props['thermonet_sha256']``:
the digest of the file's bytes with those 64 hex digits written as zeros
(:func:`~thermonet.exporting.onnx_seal.seal_onnx`).  The runtime recomputes it after its metadata checks and
refuses a file whose weights, graph or metadata were edited after export (a weight
set to 3e38 by hand), or that carries no digest; :func:`~thermonet.exporting.onnx_seal.seal_onnx`
re-seals a file edited on purpose.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from ..core.errors import ExportError
from ..core.fileio import atomic_path
from ..core.names import (
    AXIS,
    LABEL,
    SIGNAL,
    TEXT_ID,
    check_model_names,
    check_name,
    check_names,
    check_units,
)
from ..core.version import __version__
from ..models import DriftModel
from ..models.composite import AxisModels, DriftModels
from .onnx_mlflow import log_onnx_model
from .onnx_seal import DIGEST_KEY, UNSEALED, seal_bytes, seal_onnx
from .onnx_trace import OPSET, direct_or_traced
from .parity import parity_check, trained_range
from .recurrent import RecurrentGraph, recurrent_metadata, recurrent_parity_check

__all__ = [
    "THERMONET_FORMAT",
    "OPSET",
    "SIGNAL_UNITS",
    "CompensatorGraph",
    "export_onnx",
    "check_model_finite",
    "family_name",
    "target_metadata",
    "onnx_file_size",
    "log_onnx_model",
    "seal_onnx",
    "DIGEST_KEY",
]
# log_onnx_model (onnx_mlflow) and seal_onnx (onnx_seal) stay importable from here:
# workflows/compare_track.py imports the first, export/README.md names the second

_log = logging.getLogger(__name__)


#: Format marker written to ``metadata_props['thermonet_format']`` (2: float64 raw/outputs).
THERMONET_FORMAT = 2


#: Units of the signals thermonet itself defines; proxies take theirs from metadata.
SIGNAL_UNITS = {"temperature_c": "degC", "rate_c_per_min": "degC/min"}


def family_name(model: DriftModels) -> str:
    """The registered family name of a DriftModel (``model.family`` is the family module)."""
    name = getattr(model, "family_name", None)
    if name is None:
        name = getattr(model.family, "name", model.family)
    return str(name)


def check_model_finite(model: DriftModels) -> None:
    """Refuse a model with a NaN/inf parameter or buffer (:class:`ExportError` naming it)."""
    for name, tensor in list(model.named_parameters()) + list(model.named_buffers()):
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise ExportError(f"model parameter '{name}' contains NaN or inf; refusing to export "
                              "(retrain the model)")


class CompensatorGraph(nn.Module):
    """The on-board graph: signals and raw outputs in, compensated outputs out.

    Parameters
    ----------
    model : DriftModel
        ``forward(signals (N, S)) -> drift (N, A)`` with the clamp inside,
        ``out_of_range(signals) -> bool (N,)``, attributes ``signals`` and
        ``outputs``.

    Notes
    -----
    ``forward(*signals, raw)`` takes one [N] tensor per entry of
    ``model.signals`` (in that order) then ``raw`` [N, A], and returns
    ``(compensated, drift, out_of_range)``.
    """

    def __init__(self, model: DriftModels) -> None:
        super().__init__()
        self.model = model
        self.signals = list(model.signals)
        self.outputs = list(model.outputs)

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        *signal_list, raw = inputs
        # The signals stay 1-D columns; DriftModel.evaluate adds s - s (NaN for NaN/±inf)
        # to the drift so a broken thermometer never gives a plausible clamped correction.
        rel, flag = self.model.evaluate(signal_list)
        # the per-axis constant joins in float64 (a large offset keeps the drift's
        # precision) while the drift is still axis-major (A, N): one row-wise add per
        # axis, then a single transpose to the (N, A) outputs
        drift = (rel.to(torch.float64) + self.model.constant()[:, None]).T
        return raw.to(torch.float64) - drift, drift, flag


def _json(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value, sort_keys=True, default=float)


def _check_metadata(model: DriftModels, meta: Mapping[str, Any]) -> None:
    """Names and provenance strings by :mod:`thermonet.core.names` before they enter the file.

    Structured values are JSON-encoded; plain strings (device id, run id, data
    hash) are stored as they are, which is safe because they were checked here.
    """
    check_model_names(model, error=ExportError)
    if isinstance(model, AxisModels):
        check_names(model.labels, LABEL, "per-axis labels", error=ExportError)
    for key in ("device_id", "training_run_id", "data_hash"):
        if meta.get(key) not in (None, ""):
            check_name(meta[key], TEXT_ID, f"ONNX metadata '{key}'", error=ExportError)
    for key, names in (("signal_units", SIGNAL), ("output_units", AXIS)):
        if meta.get(key):
            check_units(meta[key], names, f"ONNX metadata '{key}'", error=ExportError)


def _metadata_props(model: DriftModels, metadata: Mapping[str, Any], exporter: str
                    ) -> dict[str, str]:
    meta = dict(metadata)
    _check_metadata(model, meta)
    spec = getattr(model, "spec", None)
    t_ref = getattr(spec, "t_ref", None)
    proxy_ref = getattr(spec, "proxy_ref", {}) or {}
    signal_units = dict(SIGNAL_UNITS)
    signal_units.update(meta.pop("signal_units", {}) or {})
    output_units = dict(meta.pop("output_units", {}) or {})
    props = {
        "thermonet_format": str(THERMONET_FORMAT),
        "thermonet_version": __version__,
        "onnx_opset": str(OPSET),
        "exporter": exporter,
        "family": family_name(model),
        "inputs": _json(list(model.inputs)),
        "signals": _json(list(model.signals)),
        "signal_units": _json({s: signal_units.get(s, "") for s in model.signals}),
        "outputs": _json(list(model.outputs)),
        "output_units": _json({a: output_units.get(a, "") for a in model.outputs}),
        "t_ref": "" if t_ref is None else repr(float(t_ref)),
        "proxy_ref": _json({k: float(v) for k, v in dict(proxy_ref).items()}),
        "trained_range": _json({k: list(v) for k, v in trained_range(model).items()}),
        **target_metadata(model),
        "device_id": _json(meta.pop("device_id", "")),
        "training_run_id": _json(meta.pop("training_run_id", meta.pop("run_id", ""))),
        "validation_metrics": _json(meta.pop("validation_metrics", {})),
        "data_hash": _json(meta.pop("data_hash", "")),
        DIGEST_KEY: UNSEALED,  # filled in by seal_bytes once the file is written
    }
    if isinstance(model, AxisModels):
        props.update(axis_models_metadata(model))
    if isinstance(model, DriftModel) and model.family.recurrent:
        # the runtime carries the state between calls with these constants
        props["recurrent"] = _json(recurrent_metadata(model))
    dynamic = spec.dynamic if spec is not None else None
    if dynamic is not None:
        # the runtime computes these signals from time_s with exactly these constants
        props["dynamic_inputs"] = _json(dynamic)
        for d in dynamic["inputs"]:
            props["signal_units"] = _json({**json.loads(props["signal_units"]),
                                           d["signal"]: d["unit"]})
    for key, value in meta.items():
        if key in props:
            raise ExportError(f"metadata key '{key}' is reserved (written by thermonet itself)")
        props[str(key)] = _json(value)
    return props


def axis_models_metadata(model: AxisModels) -> dict[str, str]:
    """What a per-axis model's file says of its parts.

    ``axis_models`` {axis: label of the candidate that computes it, or null: left raw};
    ``axis_model_parts`` [{label, family, inputs, signals}] in part order (the graph sums the
    parts' drifts; a part's drift is exactly 0 on the axes it does not own).
    """
    parts = [{"label": lab, "family": p.family_name, "inputs": list(p.inputs),
              "signals": list(p.signals)} for lab, p in zip(model.labels, model.parts,
                                                           strict=True)]
    return {"axis_models": json.dumps(model.axis_table()),
            "axis_model_parts": json.dumps(parts)}


def target_metadata(model: DriftModels) -> dict[str, str]:
    """What each axis's drift is relative to, as metadata strings (ONNX, C comments).

    ``targets`` {axis: channel | zero | at-t-ref | four-position}, ``compensate``
    {axis: bool}, ``drift_constant`` {axis: float64 constant added to the float32
    drift}, ``rest_signals`` {signal: value where at-t-ref axes are zero}.
    """
    outputs = list(model.outputs)
    const = model.constant().detach().cpu().double().numpy()
    rest = model.sig_ref.detach().cpu().double().numpy()
    return {
        "targets": _json(dict(zip(outputs, model.target_modes, strict=True))),
        "compensate": _json(dict(zip(outputs, model.compensated_axes, strict=True))),
        "drift_constant": json.dumps({a: float(c) for a, c in zip(outputs, const, strict=True)},
                                     sort_keys=True),
        "rest_signals": _json({sig: float(v) for sig, v in zip(model.signals, rest, strict=True)}),
    }


def export_onnx(model: DriftModels, path: str | Path, *, metadata: Mapping[str, Any] | None = None,
                check: bool = True, exporter: str = "auto", seed: int = 0) -> Path:
    """Export a drift model to ``path`` as a self-describing ONNX file.

    Parameters
    ----------
    model : DriftModel or AxisModels
        A trained model (any registered family), or a per-axis model: one graph over the
        union of its parts' signals, summing their drifts (each part's is exactly 0 on the
        axes it does not own), with ``axis_models`` in the metadata
        (:func:`axis_models_metadata`).
    path : str or Path
        Destination ``.onnx``; written atomically (temp file + ``os.replace``),
        so a failed export or parity check never leaves a half-written file.
    metadata : dict, optional
        Provenance written to ``metadata_props``: ``device_id``,
        ``training_run_id``, ``validation_metrics`` (dict), ``data_hash``,
        ``signal_units`` / ``output_units`` (dicts name → unit); any other
        key is written as given (JSON when not a string).
    check : bool
        Run :func:`parity_check` before the file is moved into place.
    exporter : {"auto", "direct", "dynamo", "torchscript"}
        ``auto``: the graph built directly from the parameters where every family has one
        (:mod:`thermonet.exporting.onnx_graph`: linear, poly, rbf, lorentz, ts-fuzzy and
        per-axis models of them), else the dynamo exporter, then the TorchScript one.  ``direct``
        refuses a model without a direct graph.  ``metadata_props['exporter']`` says which
        wrote the file; every one passes the same parity check.
    seed : int
        Seed of the random parity points.

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    ExportError
        NaN parameters, an exporter failure or a failed parity check.
    """
    import onnx

    if exporter not in ("auto", "direct", "dynamo", "torchscript"):
        raise ExportError("exporter must be 'auto', 'direct', 'dynamo' or 'torchscript', got "
                          f"'{exporter}'")
    check_model_finite(model)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    was_training = model.training
    model.eval()
    try:
        recurrent = isinstance(model, DriftModel) and model.family.recurrent
        if isinstance(model, DriftModel) and recurrent:
            graph: nn.Module = RecurrentGraph(model).eval()
        else:
            graph = CompensatorGraph(model).eval()
        proto, used = direct_or_traced(model, graph, exporter)
        for key, value in _metadata_props(model, metadata or {}, used).items():
            entry = proto.metadata_props.add()
            entry.key, entry.value = key, value
        proto.producer_name = "thermonet"
        proto.producer_version = __version__
        with atomic_path(path) as tmp:
            onnx.save_model(proto, str(tmp), save_as_external_data=False)
            seal_bytes(Path(tmp))
            onnx.checker.check_model(str(tmp))
            if check:
                stats = (recurrent_parity_check(model, tmp, seed=seed)
                         if isinstance(model, DriftModel) and recurrent
                         else parity_check(model, tmp, seed=seed))
                _log.info("ONNX parity: %d points, max |diff| %.3g (rel %.3g)",
                          int(stats["n_points"]), stats["max_abs_diff"], stats["max_rel_diff"])
    finally:
        model.train(was_training)
    return path


def onnx_file_size(path: str | Path) -> int:
    """Size of an exported file in bytes (for the size benchmark)."""
    return Path(path).stat().st_size
