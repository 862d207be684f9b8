"""What a family hands the C-header generator: its constants and the body that evaluates it.

Each :class:`~thermonet.models.base.Family` owns its C code
(:meth:`~thermonet.models.base.Family.emit_c`); the generator in
:mod:`thermonet.exporting.c_header` only assembles the header around it.  A
body reads the standardised features ``z[0 .. N_FEATURES-1]`` and writes the
drift in the output's own units to ``y[0 .. N_AXES-1]``; it may use the loop
variables ``f`` and ``a`` (declared ``int`` by the generator) and declares
anything else inside its own block.  Constants are ``static const`` arrays
named ``<prefix>_<family tag>_<name>``; their values come from the same torch
expressions the family's exported graph evaluates (:meth:`Family.drift`), so
nothing numeric is restated in C.

This module needs only numpy, so the families can import it without pulling
in the export layer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import ExportError

__all__ = ["CBody", "c_float", "c_array", "as_float32"]


@dataclass
class CBody:
    """A family's share of the header.

    Attributes
    ----------
    constants : list of str
        C declarations (``#define`` lines, ``static const`` arrays) placed
        before the function.
    body : str
        C statements (indented four spaces) computing ``y[a]`` from ``z[f]``.
    """

    constants: list[str] = field(default_factory=list)
    body: str = ""


def c_float(value: float) -> str:
    """A float32 literal that round-trips exactly (9 significant digits).

    Raises
    ------
    ExportError
        For a NaN or infinite value (a header cannot carry it).
    """
    v = float(np.float32(value))
    if not math.isfinite(v):
        raise ExportError(f"non-finite constant {v!r} cannot be written to a C header")
    return f"{v:.9e}f"


def c_array(name: str, values: object, ctype: str = "float") -> str:
    """``static const <ctype> name[..][..] = {...};`` for a 1-D or 2-D array."""
    arr = np.asarray(values, dtype=np.float64)
    shape = "".join(f"[{n}]" for n in arr.shape)

    def fmt(v: float) -> str:
        return c_float(v) if ctype == "float" else str(int(v))

    def rows(a: np.ndarray) -> str:
        if a.ndim == 1:
            return "{" + ", ".join(fmt(v) for v in a) + "}"
        return "{\n    " + ",\n    ".join(rows(r) for r in a) + "}"

    return f"static const {ctype} {name}{shape} = {rows(arr)};"


def as_float32(tensor: torch.Tensor) -> np.ndarray:
    """A tensor's float32 values (as the graph stores them) in a float64 array."""
    return tensor.detach().cpu().to(torch.float32).numpy().astype(np.float64)
