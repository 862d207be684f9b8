"""Exporting a recurrent family (the GRU): its state as explicit graph inputs and outputs.

The ONNX graph of a recurrent model is one **step**, vectorised over N independent
samples: inputs the signal columns (float32 [N]), ``raw`` (float64 [N, A]) and ``state``
(float32 [N, H]); outputs ``compensated``, ``drift``, ``out_of_range`` as for every model,
and ``state_out`` (float32 [N, H]) — :meth:`DriftModel.evaluate_state
<thermonet.models.drift_model.DriftModel.evaluate_state>`.  Which state a sample gets and which
signals (the running mean of its ``step_s`` window) is the stream's bookkeeping
(:mod:`thermonet.models.sequence`), which the runtime (``export/thermonet_runtime.py``)
and the C header's ``<prefix>_step`` repeat; the metadata key ``recurrent`` carries its
constants (``hidden``, ``step_s``, ``gap_s``, the graph names).

:func:`recurrent_parity_check` compares onnxruntime's step with torch's at the parity
points of every model (:func:`~.parity.check_points`) paired with seeded random states in
(−1, 1) (a GRU's state lies there), plus a NaN signal and signals outside the range;
:func:`check_recurrent_stream` (in :mod:`.c_stream_recurrent`) compares the C stream with
torch's over a sequence with a gap and a NaN sample.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import nn

from ..core.errors import ExportError
from .parity import PARITY_RTOL, check_drift_parity, check_points, trained_range

if TYPE_CHECKING:
    from ..models import DriftModel

__all__ = ["RecurrentGraph", "STATE_INPUT", "STATE_OUTPUT", "RECURRENT_VERSION",
           "recurrent_metadata", "recurrent_parity_check", "step_reference", "hidden_size"]

STATE_INPUT = "state"
STATE_OUTPUT = "state_out"
#: Version of the ``recurrent`` metadata block.
RECURRENT_VERSION = 1


def hidden_size(model: DriftModel) -> int:
    """The state's size H of a recurrent model."""
    fam: Any = model.family
    return int(fam.hidden)


class RecurrentGraph(nn.Module):
    """``forward(*signals, raw, state) -> (compensated, drift, out_of_range, state_out)``."""

    def __init__(self, model: DriftModel) -> None:
        super().__init__()
        self.model = model
        self.signals = list(model.signals)
        self.outputs = list(model.outputs)
        self.hidden = hidden_size(model)
        self.extra_inputs = [STATE_INPUT]
        self.extra_outputs = [STATE_OUTPUT]

    def example_extra(self, n: int) -> tuple[torch.Tensor, ...]:
        return (torch.zeros(n, self.hidden),)

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        *signal_list, raw, state = inputs
        rel, flag, nxt = self.model.evaluate_state(signal_list, state.T)
        drift = (rel.to(torch.float64) + self.model.constant()[:, None]).T
        return raw.to(torch.float64) - drift, drift, flag, nxt.T


def recurrent_metadata(model: DriftModel) -> dict[str, Any]:
    """The ``recurrent`` metadata block: what the runtime needs to run the stream."""
    fam: Any = model.family
    return {"version": RECURRENT_VERSION, "hidden": int(fam.hidden),
            "step_s": float(fam.step_s), "gap_s": float(fam.gap_s),
            "state_input": STATE_INPUT, "state_output": STATE_OUTPUT}


def step_reference(model: DriftModel, points: np.ndarray, states: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """torch's step at ``points`` (N, S) from ``states`` (N, H): relative drift (N, A),
    flag (N,), next state (N, H), in the model's float32."""
    with torch.no_grad():
        cols = torch.from_numpy(np.asarray(points, dtype=np.float32)).unbind(1)
        rel, flag, nxt = model.evaluate_state(
            cols, torch.from_numpy(np.asarray(states, dtype=np.float32)).T)
    return rel.T.double().numpy(), flag.numpy(), nxt.T.double().numpy()


def _tolerance(model: DriftModel, points: np.ndarray, states: np.ndarray, d32: np.ndarray,
               h32: np.ndarray, rtol: float) -> tuple[np.ndarray, float]:
    """Per-axis drift tolerance and the state's, as :func:`~.parity.float32_tolerance`:
    ``rtol`` of the largest value, or 4 × torch's own float32 rounding (float64 copy)."""
    m64 = copy.deepcopy(model).double()
    with torch.no_grad():
        cols = torch.from_numpy(points.astype(np.float64)).unbind(1)
        rel, _, nxt = m64.evaluate_state(cols, torch.from_numpy(states.astype(np.float64)).T)
    d64, h64 = rel.T.numpy(), nxt.T.numpy()
    tol = np.maximum(rtol * np.abs(d32).max(axis=0), 4.0 * np.abs(d32 - d64).max(axis=0))
    h_tol = max(rtol, 4.0 * float(np.abs(h32 - h64).max()))
    return tol, h_tol


def recurrent_parity_check(model: DriftModel, onnx_path: str | Path, *, seed: int = 0,
                           rtol: float = PARITY_RTOL) -> dict[str, float]:
    """onnxruntime's step against torch's (module docstring).

    Raises
    ------
    ExportError
        A drift, state or flag that differs, naming the worst point.
    """
    import onnxruntime as ort

    ranges = list(trained_range(model).values())
    points = check_points(ranges, seed)
    lo = np.array([r[0] for r in ranges])
    hi = np.array([r[1] for r in ranges])
    mid = ((lo + hi) / 2.0).astype(np.float32)
    extra = np.array([mid, mid, mid], dtype=np.float32)
    extra[0, 0] = np.nan                                   # a broken thermometer
    extra[1, 0] = lo[0] - 0.1 * max(hi[0] - lo[0], 1e-3)   # outside: the clamp
    extra[2, 0] = hi[0] + 0.1 * max(hi[0] - lo[0], 1e-3)
    points = np.concatenate([points, extra]).astype(np.float32)
    n, n_axes = points.shape[0], len(model.outputs)
    hidden = hidden_size(model)
    states = np.random.default_rng(seed + 2).uniform(-1.0, 1.0, (n, hidden)).astype(np.float32)
    d_torch, f_torch, h_torch = step_reference(model, points, states)
    finite = np.all(np.isfinite(points), axis=1)
    tol, h_tol = _tolerance(model, points[finite], states[finite], d_torch[finite],
                            h_torch[finite], rtol)
    const = model.constant().detach().cpu().double().numpy()
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    sess = ort.InferenceSession(str(onnx_path), sess_options=opts,
                                providers=["CPUExecutionProvider"])
    feeds = {s: np.ascontiguousarray(points[:, i]) for i, s in enumerate(model.signals)}
    raw = np.zeros((n, n_axes)) + const
    comp, d_ort, flag, h_ort = sess.run(None, {**feeds, "raw": raw, STATE_INPUT: states})
    d_ort = d_ort.astype(np.float64) - const
    err = check_drift_parity(model, points[finite], d_ort[finite], d_torch[finite], tol,
                             what="ONNX (recurrent step)", who="onnxruntime")
    if not bool(np.isnan(d_ort[~finite]).all()):
        raise ExportError("ONNX graph does not return NaN drift for a NaN signal")
    h_err = np.abs(h_ort[finite].astype(np.float64) - h_torch[finite])
    if float(h_err.max()) > h_tol:
        raise ExportError(f"ONNX parity check failed: state_out differs from torch by "
                          f"{float(h_err.max()):.3g} (tolerance {h_tol:.3g})")
    if not np.array_equal(flag.astype(bool), f_torch.astype(bool)):
        raise ExportError("ONNX parity check failed: out_of_range flag differs from torch")
    if not np.allclose(comp[finite], raw[finite] - const - d_torch[finite], rtol=0.0,
                       atol=float(tol.max()) + 1e-12):
        raise ExportError("ONNX parity check failed: 'compensated' is not raw - drift")
    return {"n_points": float(n), "max_abs_diff": float(err.max()),
            "max_rel_diff": float((err / np.maximum(np.abs(d_torch[finite]).max(axis=0),
                                                    1e-30)).max())}
