"""thermonet's version, in the bottom layer so that every layer can stamp its outputs with it
(checkpoints, ONNX metadata, C headers, reports) without importing the package root.

``thermonet.__version__`` re-exports it; keep it equal to ``version`` in pyproject.toml
(tests/test_layers.py checks).
"""

from __future__ import annotations

__all__ = ["__version__"]

__version__ = "0.1.0"
