"""A recurrent family on a stream with time: the reference of what a board computes.

The definition is the GRU's (:mod:`thermonet.models.gru`, "Time" and "Start-up"): the
finite samples (every signal finite) are cut into segments wherever the time since the
previous finite sample exceeds ``gap_s``; a segment starts at :math:`h = 0` at its first
time :math:`t_0`; its samples fall into windows :math:`k = \\lfloor (t - t_0)/s \\rfloor`
(``s`` = ``step_s``); a sample's drift is the step of the model on the running mean of
its window's signals so far from the state committed after the previous window, and
the state after a window is that step on the window's full mean.  A non-finite sample
gives NaN drift and changes nothing; the first sample of every segment but the first
raises the flag (a gap), as every clamped or non-finite one does.

:func:`stream_windows` is the bookkeeping (numpy, float64 time), :func:`stream_relative`
the evaluation (torch: the committed states by PyTorch's fused GRU over each segment's
window means, the per-sample steps in one batch through :meth:`DriftModel.evaluate_state
<thermonet.models.drift_model.DriftModel.evaluate_state>`).  The training loop's windows
(:func:`thermonet.training.recurrent.sequences`) are the same windows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from ..core.errors import InputError
from ..features.dynamics import check_time

if TYPE_CHECKING:
    from .drift_model import DriftModel

__all__ = ["StreamWindows", "stream_windows", "running_means", "stream_relative"]


@dataclass
class StreamWindows:
    """Where the finite samples of a stream fall.

    Attributes
    ----------
    index : (M,) int
        The finite samples' positions in the stream.
    restart : (M,) bool
        True at a segment's first sample.
    window : (M,) int
        Window number, counted over the whole stream (0, 1, ...; a new segment opens a
        new window).
    segment : (W,) int
        Each window's segment.
    """

    index: np.ndarray
    restart: np.ndarray
    window: np.ndarray
    segment: np.ndarray

    @property
    def ends(self) -> np.ndarray:
        """Position (in the finite samples) of each window's last sample."""
        w = self.window
        return np.flatnonzero(np.append(w[1:] != w[:-1], True)) if w.size else w


def stream_windows(time_s: np.ndarray, finite: np.ndarray, step_s: float, gap_s: float
                   ) -> StreamWindows:
    """Segments and windows of a stream (see the module docstring)."""
    t = np.asarray(time_s, dtype=np.float64)
    idx = np.flatnonzero(np.asarray(finite, dtype=bool))
    tf = t[idx]
    restart = np.ones(tf.size, dtype=bool)
    restart[1:] = np.diff(tf) > gap_s
    seg = np.cumsum(restart) - 1
    t0 = tf[restart][seg] if tf.size else tf
    k = np.floor((tf - t0) / step_s).astype(np.int64)
    new = restart.copy()
    new[1:] |= k[1:] != k[:-1]
    window = np.cumsum(new) - 1
    return StreamWindows(index=idx, restart=restart, window=window, segment=seg[new])


def running_means(values: np.ndarray, window: np.ndarray) -> np.ndarray:
    """Running mean (M, S) of ``values`` (M, S) within each window, float64: the window's
    first sample plus the mean of the deviations from it (what the C step accumulates)."""
    v = np.asarray(values, dtype=np.float64)
    if v.shape[0] == 0:
        return v.copy()
    start = np.flatnonzero(np.append(True, window[1:] != window[:-1]))
    first_of = start[np.cumsum(np.append(True, window[1:] != window[:-1])) - 1]
    dev = v - v[first_of]
    cs = np.cumsum(dev, axis=0)
    before = cs[first_of] - dev[first_of]
    count = (np.arange(v.shape[0]) - first_of + 1).astype(np.float64)
    return v[first_of] + (cs - before) / count[:, None]


def stream_relative(model: DriftModel, time_s: np.ndarray, signals: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Relative drift (N, A) (float64 copy of the model's float32 arithmetic, NaN where a
    signal is not finite) and flag (N,) of a recurrent model on one stream.

    Raises
    ------
    InputError
        Time not finite and strictly increasing, or signals of the wrong shape.
    """
    fam: Any = model.family  # a recurrent family (hidden, step_s, gap_s, scan)
    t = check_time(time_s, "time_s")
    s = np.asarray(signals, dtype=np.float64)
    if s.ndim != 2 or s.shape != (t.size, len(model.signals)):
        raise InputError(f"signals have shape {s.shape}, expected ({t.size}, "
                         f"{len(model.signals)}) for {model.signals}")
    n, n_axes = s.shape[0], len(model.outputs)
    rel = np.full((n, n_axes), np.nan)
    flag = np.ones(n, dtype=bool)
    lay = stream_windows(t, np.all(np.isfinite(s), axis=1), fam.step_s, fam.gap_s)
    if lay.index.size == 0:
        return rel, flag
    means = running_means(s[lay.index], lay.window)
    dtype = model.sig_lo.dtype
    with torch.no_grad():
        ends = lay.ends
        z_end, _ = model.standardise(torch.as_tensor(means[ends], dtype=dtype).unbind(1))
        z_end_t = torch.stack(z_end, dim=1)                              # (W, F)
        before = torch.zeros(len(ends), fam.hidden, dtype=dtype)
        for sg in np.unique(lay.segment):
            rows = np.flatnonzero(lay.segment == sg)
            states, _ = fam.scan(z_end_t[rows][None])
            before[rows[1:]] = states[0, :-1]
        h = before[torch.as_tensor(lay.window)].T.contiguous()            # (H, M)
        drift, fl, _ = model.evaluate_state(
            torch.as_tensor(means, dtype=dtype).unbind(1), h)
    rel[lay.index] = drift.T.double().numpy()
    gap = lay.restart.copy()
    gap[0] = False
    flag[lay.index] = fl.numpy() | gap
    return rel, flag
