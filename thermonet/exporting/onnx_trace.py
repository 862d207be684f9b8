"""How a drift model's graph becomes an ONNX ``ModelProto`` (:mod:`thermonet.exporting.onnx_export`
writes, seals and checks it): built node by node from the parameters where every family has a
direct graph (:mod:`thermonet.exporting.onnx_graph`), else traced by torch's exporters — the
``torch.export``-based one (``dynamo=True``, optimised by onnxscript, or its constants folded
where the optimised graph is not valid), the TorchScript one as the fallback — with the debug
annotations stripped (:func:`direct_or_traced`, :func:`export_proto`).
"""

from __future__ import annotations

import logging
import tempfile
import warnings
from pathlib import Path
from typing import Any

import torch
from torch import nn

from ..core.errors import ExportError, first_line
from ..models.composite import DriftModels
from .onnx_graph import DIRECT, direct_proto, direct_supported

__all__ = ["OPSET", "export_proto", "direct_or_traced"]

# the exporter's messages keep the logger they always had
_log = logging.getLogger("thermonet.exporting.onnx_export")

# torch's exporter warns once per export that torchvision (not a dependency) is absent
logging.getLogger("torch.onnx._internal.exporter._registration").setLevel(logging.ERROR)


#: ONNX opset of the exported graph.
OPSET = 18


def _strip_debug(proto: Any) -> None:
    """Drop per-node debug annotations and intermediate shapes (size only; semantics kept)."""
    for node in proto.graph.node:
        del node.metadata_props[:]
        node.doc_string = ""
    for value in list(proto.graph.input) + list(proto.graph.output):
        del value.metadata_props[:]
    for init in proto.graph.initializer:
        del init.metadata_props[:]
    del proto.graph.value_info[:]
    del proto.metadata_props[:]
    proto.doc_string = ""


def _dynamo_proto(graph: Any, example: tuple, names: list[str], out_names: list[str]) -> Any:
    """The dynamo exporter's graph, optimised by onnxscript — or, when that graph is not
    valid, the unoptimised export with its constants folded and its common subexpressions
    merged (:func:`_fold_only`), or as exported.

    onnxscript's rewriter fuses each ``Max``/``Min`` pair into a ``Clip`` whose bounds it
    names after the clamped value; where one signal is clamped twice (a per-axis model: each
    part clamps to its own trained range) the second pair of bounds is lost and the graph
    references values nothing defines.  Every variant computes the same operations (the
    export's parity check runs on the result).
    """
    import onnx

    batch = torch.export.Dim("N")
    # traced once (the trace is most of an export's seconds): the unoptimised graph is kept,
    # then optimised in place as torch's own optimize=True would
    program = torch.onnx.export(
        graph, example, None, input_names=names, output_names=out_names,
        opset_version=OPSET, dynamo=True, external_data=False, optimize=False,
        # forward(*inputs): the varargs tuple is one argument
        dynamic_shapes=(tuple({0: batch} for _ in names),), verbose=False)
    if program is None:
        raise ExportError("torch.onnx.export (dynamo) returned no program")
    proto = program.model_proto
    try:
        program.optimize()
        optimised = program.model_proto
        onnx.checker.check_model(optimised)
        return optimised
    except Exception as err:  # noqa: BLE001 - an invalid optimised graph: fold the plain one
        _log.info("optimised ONNX graph is invalid (%s); folding the unoptimised one instead",
                  first_line(err))
    try:
        folded = _fold_only(proto)
        onnx.checker.check_model(folded)
        return folded
    except Exception as err:  # noqa: BLE001 - any optimiser failure: keep the plain graph
        _log.info("folding the unoptimised ONNX graph failed (%s); keeping it as exported",
                  first_line(err))
    return proto


def _fold_only(proto: Any) -> Any:
    """``proto`` with functions inlined, constants folded, constants lifted to (deduplicated)
    initializers and common subexpressions merged: onnxscript's optimiser without its
    pattern rewrites."""
    import onnx_ir as ir
    from onnx_ir.passes import common as cp
    from onnxscript import optimizer

    model = ir.serde.deserialize_model(proto)
    cp.InlinePass()(model)
    optimizer.fold_constants(model)
    ir.passes.Sequential(
        cp.RemoveUnusedNodesPass(),
        cp.LiftConstantsToInitializersPass(lift_all_constants=True, size_limit=0),
        cp.DeduplicateInitializersPass(), cp.CommonSubexpressionEliminationPass(),
        cp.RemoveUnusedNodesPass(), cp.NameFixPass())(model)
    return ir.serde.serialize_model(model)


def export_proto(graph: Any, exporter: str) -> tuple[Any, str]:
    import onnx

    n_ex = 4
    example = tuple(torch.zeros(n_ex) for _ in graph.signals) + \
        (torch.zeros(n_ex, len(graph.outputs), dtype=torch.float64),)
    names = list(graph.signals) + ["raw"]
    out_names = ["compensated", "drift", "out_of_range"]
    if hasattr(graph, "extra_inputs"):  # a recurrent model's state (.recurrent)
        example = example + graph.example_extra(n_ex)
        names += graph.extra_inputs
        out_names += graph.extra_outputs
    errors = []
    order = ["dynamo", "torchscript"] if exporter == "auto" else [exporter]
    for kind in order:
        try:
            with warnings.catch_warnings():
                # Both exporters warn about things that do not apply here (torchvision
                # ops, the legacy path's deprecation); the result is checked by parity.
                warnings.simplefilter("ignore")
                if kind == "dynamo":
                    proto = _dynamo_proto(graph, example, names, out_names)
                else:
                    with tempfile.TemporaryDirectory() as tmp:
                        f = Path(tmp) / "m.onnx"
                        torch.onnx.export(
                            graph, example, str(f), input_names=names, output_names=out_names,
                            opset_version=OPSET, dynamo=False, do_constant_folding=True,
                            dynamic_axes={n: {0: "N"} for n in names + out_names})
                        proto = onnx.load(str(f))
            _strip_debug(proto)
            return proto, kind
        except Exception as exc:  # any exporter failure: record it, try the next exporter
            errors.append(
                f"{kind}: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
            )
            _log.warning("ONNX exporter '%s' failed: %s", kind, errors[-1])
    raise ExportError("torch.onnx.export failed (" + "; ".join(errors) + ")")


def direct_or_traced(model: DriftModels, graph: nn.Module, exporter: str) -> tuple[Any, str]:
    """The graph built directly (:mod:`.onnx_graph`) where ``exporter`` is ``direct``, or
    ``auto`` and the model's families have a direct graph; torch's exporters otherwise."""
    if exporter in ("auto", "direct"):
        why = direct_supported(model)
        if why is None:
            return direct_proto(model, OPSET), DIRECT
        if exporter == "direct":
            raise ExportError(f"no direct ONNX graph for this model: {why} (use exporter "
                              "'auto', 'dynamo' or 'torchscript')")
        exporter = "auto"
    return export_proto(graph, exporter)
