"""What the sensor model's exports are checked on, shared by the ONNX export
(:mod:`thermonet.exporting.sensor_export`) and the C header (:mod:`thermonet.exporting.sensor_c`):
the probe samples and the parity tolerances (batch, and the C header's streaming step)."""

from __future__ import annotations

import numpy as np
import torch

from ..models.sensor import SensorModel

__all__ = ["PARITY_EPS32", "STREAM_RTOL", "probe"]

#: Parity tolerance in units of float32's epsilon, times the output's magnitude (the raw
#: value plus the bias): the graph computes b and E in float32 as torch does, the inverse in
#: float64; what differs is the order of float32 operations in the two runtimes.
PARITY_EPS32 = 256.0

#: The streaming ``step()``'s tolerance beyond that, relative to each axis's drift terms
#: (|b| + Σ|E x|): the C header's dynamic inputs run in float32 recurrences, torch reads the
#: float64 ones — the bias header's ``check_stream`` bound (its ``rtol``), for b and E alike.
STREAM_RTOL = 1e-4


def probe(model: SensorModel, n: int = 257, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Signals across the trained range (edges included, a little outside) and raw outputs."""
    lo = model.bias.sig_lo.detach().double().numpy()
    hi = model.bias.sig_hi.detach().double().numpy()
    rng = np.random.default_rng(seed)
    span = np.where(hi > lo, hi - lo, 1.0)
    sig = lo + rng.uniform(-0.05, 1.05, (n, lo.size)) * span
    sig[0], sig[1] = lo, hi
    with torch.no_grad():
        b = model.bias.drift64(torch.as_tensor(sig, dtype=torch.float32)).numpy()
    scale = np.maximum(np.abs(b).max(axis=0), 1.0)
    raw = b + rng.uniform(-100.0, 100.0, b.shape) * scale
    return sig, raw
