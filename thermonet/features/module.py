"""The features inside the exported graph: :class:`Features`, a torch module.

The names and references come from :class:`thermonet.features.inputs.FeatureSpec` (torch-free);
this module evaluates them on a signal tensor with gather, subtract and multiply only.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from ..core.recording import TEMPERATURE
from .inputs import FeatureSpec, parse_feature

__all__ = ["Features"]


class Features(nn.Module):
    """Signals (N, S) → features (N, F), inside the exported graph.

    Each feature is a signal minus its reference, optionally squared:

    .. math:: x_f = (s_{i_f} - r_f)^{q_f}, \\quad q_f \\in \\{1, 2\\}

    Buffers ``index``, ``ref``, ``square`` hold :math:`i_f, r_f, q_f - 1` (the
    checkpoint's record of the layout); :meth:`columns` evaluates the features
    as 1-D columns — one subtraction per feature and one multiplication per
    squared feature, the fewest passes over a batch.
    """

    index: torch.Tensor      # buffers, declared for the type checker
    ref: torch.Tensor
    square: torch.Tensor

    def __init__(self, spec: FeatureSpec) -> None:
        super().__init__()
        spec.check_references()
        signals = spec.signals
        index, ref, square = [], [], []
        for name in spec.inputs:
            sig, rel, sq = parse_feature(name)
            index.append(signals.index(sig))
            if not rel:
                ref.append(0.0)
            elif sig == TEMPERATURE:
                ref.append(float(spec.t_ref))  # type: ignore[arg-type]
            else:
                ref.append(spec.proxy_ref[sig])
            square.append(1.0 if sq else 0.0)
        # the layout as Python values: it fixes the graph's structure, not its numbers
        self._layout = [(i, bool(q), r != 0.0) for i, q, r in zip(index, square, ref, strict=True)]
        self.register_buffer("index", torch.tensor(index, dtype=torch.int64))
        self.register_buffer("ref", torch.tensor(ref, dtype=torch.float32))
        self.register_buffer("square", torch.tensor(square, dtype=torch.float32))

    def columns(self, signals: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        """Feature columns (each (N,)) from one (N,) column per signal."""
        out = []
        for f, (i, squared, relative) in enumerate(self._layout):
            d = signals[i] - self.ref[f] if relative else signals[i]
            out.append(d * d if squared else d)
        return out

    def forward(self, signals: torch.Tensor) -> torch.Tensor:
        return torch.stack(self.columns(signals.unbind(1)), dim=1)
