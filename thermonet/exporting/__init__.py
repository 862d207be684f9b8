"""Export a trained drift model for use on board.

* :func:`export_onnx` — an ONNX file with the features, the clamp to the trained
  range and the out-of-range flag inside the graph, checked against torch with
  onnxruntime before it is written (run it with ``export/thermonet_runtime.py``);
* :func:`export_c_header` — a dependency-free C99 header, float32, no heap;
* :func:`export_px4_params` / :func:`export_ardupilot_params` — the autopilots'
  own thermal-calibration parameter files, for the cubic-on-temperature model.
"""

from .autopilot import (
    AutopilotCoefficients,
    autopilot_coefficients,
    export_ardupilot_params,
    export_px4_params,
    read_ardupilot_params,
    read_px4_params,
)
from .c_header import export_c_header, render_c_header
from .source import FORMATS, export_source, resolve_checkpoint
from .onnx_export import (
    CompensatorGraph,
    export_onnx,
    log_onnx_to_mlflow,
    onnx_file_size,
    parity_check,
    time_onnxruntime,
)

__all__ = [
    "FORMATS",
    "export_source",
    "resolve_checkpoint",
    "CompensatorGraph",
    "export_onnx",
    "parity_check",
    "log_onnx_to_mlflow",
    "onnx_file_size",
    "time_onnxruntime",
    "export_c_header",
    "render_c_header",
    "AutopilotCoefficients",
    "autopilot_coefficients",
    "export_px4_params",
    "export_ardupilot_params",
    "read_px4_params",
    "read_ardupilot_params",
]
