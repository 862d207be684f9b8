"""The check every export passes before it is written: the exported graph against torch.

Points on a grid over each signal's trained range (every signal swept with the others at mid
range) and uniformly random inside it (:func:`check_points`) are evaluated by the exported
file (onnxruntime) and by the model in float64; they must agree within the float32 rounding of
the model's own evaluation (:func:`float32_tolerance`) — an export that does not is refused.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from ..core.errors import ExportError
from ..models.composite import DriftModels

__all__ = ["PARITY_RTOL", "trained_range", "check_points", "float32_tolerance", "check_drift_parity",
           "check_flags",
           "parity_check"]

#: Relative parity tolerance (see the module docstring).
PARITY_RTOL = 1e-5


#: Points per signal on the parity grid and random parity points.
GRID_POINTS = 201


RANDOM_POINTS = 10_000


def trained_range(model: DriftModels) -> dict[str, tuple[float, float]]:
    """Trained range ``{signal: (lo, hi)}`` from the model's ``sig_lo``/``sig_hi`` buffers."""
    lo = model.sig_lo.detach().cpu().double().numpy().reshape(-1)
    hi = model.sig_hi.detach().cpu().double().numpy().reshape(-1)
    return {s: (float(lo[i]), float(hi[i])) for i, s in enumerate(model.signals)}


def check_points(ranges: Sequence[tuple[float, float]], seed: int) -> np.ndarray:
    """Grid over the trained range (full product up to 2 signals, else per-signal sweeps)
    plus seeded uniform random points in range; float32 (N, S)."""
    lo = np.array([r[0] for r in ranges])
    hi = np.array([r[1] for r in ranges])
    axes = [np.linspace(a, b, GRID_POINTS) for a, b in zip(lo, hi, strict=True)]
    if len(ranges) <= 2:
        grid = np.stack([g.reshape(-1) for g in np.meshgrid(*axes, indexing="ij")], axis=1)
    else:
        mid = (lo + hi) / 2
        sweeps = []
        for i, ax in enumerate(axes):
            block = np.tile(mid, (GRID_POINTS, 1))
            block[:, i] = ax
            sweeps.append(block)
        grid = np.concatenate(sweeps)
    rng = np.random.default_rng(seed)
    rand = rng.uniform(lo, hi, size=(RANDOM_POINTS, len(ranges)))
    return np.concatenate([grid, rand]).astype(np.float32)


def float32_tolerance(model: DriftModels, points: np.ndarray, d_float32: np.ndarray, *,
                      rtol: float = PARITY_RTOL) -> np.ndarray:
    """Per-axis tolerance of a float32 evaluation of ``model`` at ``points``.

    ``max(rtol · max|d|, 4 · max|d_float32 − d_float64|)`` per axis: ``rtol`` of the
    axis's largest drift, unless the model itself is more sensitive to float32
    rounding than that (a narrow Lorentz peak or a proxy near 4,500 Hz amplifies
    one ulp of an intermediate value).  The float64 evaluation of the same
    parameters measures that sensitivity, so a second float32 implementation
    (onnxruntime, the C header) may differ from torch by a few times what torch's
    own float32 rounding costs, and no more.
    """
    import copy

    with torch.no_grad():  # relative drifts: the float64 constant is exact in every format
        d64 = copy.deepcopy(model).double().relative(torch.from_numpy(points.astype(np.float64)))
    rounding = np.abs(d_float32 - d64.numpy()).max(axis=0)
    return np.maximum(rtol * np.abs(d_float32).max(axis=0), 4.0 * rounding)


def check_drift_parity(model: DriftModels, points: np.ndarray, got: np.ndarray,
                       want: np.ndarray, tol: np.ndarray, *, what: str, who: str) -> np.ndarray:
    """``|got − want| ≤ tol`` per axis at every point, else :class:`ExportError` naming the
    worst point (signal values, axis, both drifts); returns the absolute errors."""
    got = np.asarray(got, dtype=np.float64)
    err = np.abs(got - want)
    excess = np.where(np.isfinite(got), err - tol, np.inf)
    k, a = np.unravel_index(int(np.argmax(excess)), excess.shape)
    if excess[k, a] > 0:
        where = ", ".join(f"{s}={points[k, i]:.6g}" for i, s in enumerate(model.signals))
        raise ExportError(f"{what} parity check failed at {where}, axis '{model.outputs[a]}': "
                          f"{who} {got[k, a]:.9g} vs torch {want[k, a]:.9g} "
                          f"(tolerance {tol[a]:.3g})")
    return err


def check_flags(model: DriftModels, points: np.ndarray, got: np.ndarray, *, what: str,
                who: str) -> None:
    """The out-of-range flag ``got`` at ``points`` is torch's exactly (inside the trained
    range it is the joint guard's alone: a dynamic input outside what was trained near that
    temperature), else :class:`ExportError` naming the first point that differs."""
    with torch.no_grad():
        want = model.out_of_range(torch.from_numpy(points)).numpy()
    got = np.asarray(got).astype(bool)
    if not np.array_equal(got, want):
        k = int(np.argmax(got != want))
        where = ", ".join(f"{s}={points[k, i]:.6g}" for i, s in enumerate(model.signals))
        raise ExportError(f"{what} out_of_range flag differs from torch's at {where} "
                          f"({who} {bool(got[k])}, torch {bool(want[k])})")


def parity_check(model: DriftModels, onnx_path: str | Path, *, seed: int = 0,
                 rtol: float = PARITY_RTOL) -> dict[str, float]:
    """Compare onnxruntime (CPU) with torch on the grid and the random points.

    Also checks the out-of-range flag on points just outside the range and on
    NaN.  Returns ``{"n_points", "max_abs_diff", "max_rel_diff"}``.

    Raises
    ------
    ExportError
        Naming the worst point (signal values, axis, both drift values).
    """
    import onnxruntime as ort

    ranges = list(trained_range(model).values())
    points = check_points(ranges, seed)
    n, n_axes = points.shape[0], len(model.outputs)
    const = model.constant().detach().cpu().double().numpy()
    # raw around the constant (a 1e6-count output is fed 1e6 + noise): compensated must
    # keep the precision of the float64 input
    raw = np.random.default_rng(seed + 1).normal(size=(n, n_axes)) + const
    with torch.no_grad():  # drift relative to the float64 constant, as computed in float32
        d_torch = model.relative(torch.from_numpy(points)).double().numpy()
    tol = float32_tolerance(model, points, d_torch, rtol=rtol)
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    sess = ort.InferenceSession(str(onnx_path), sess_options=opts,
                                providers=["CPUExecutionProvider"])
    feeds = {s: np.ascontiguousarray(points[:, i]) for i, s in enumerate(model.signals)}
    comp, d_ort, flag = sess.run(None, {**feeds, "raw": raw})
    d_ort = d_ort.astype(np.float64) - const
    scale = np.maximum(np.abs(d_torch), np.abs(d_torch).max(axis=0, keepdims=True))
    err = check_drift_parity(model, points, d_ort, d_torch, tol, what="ONNX", who="onnxruntime")
    # compensated = raw − constant − relative drift, in float64: only the float32 drift's
    # parity tolerance and float64 rounding of the raw value may separate them
    comp_err = np.abs(comp.astype(np.float64) - ((raw - const) - d_torch))
    if not bool(np.all(comp_err <= tol + 4 * np.finfo(np.float64).eps * np.abs(raw) + 1e-30)):
        raise ExportError("ONNX parity check failed: 'compensated' is not raw - drift")
    check_flags(model, points, flag, what="ONNX", who="onnxruntime")
    # One signal at a time just outside each side of the range (the clamp: drift must
    # equal torch's clamped value), then NaN, +inf and -inf (drift must be NaN); the
    # flag must be set on every one of these rows.
    lo = np.array([r[0] for r in ranges])
    hi = np.array([r[1] for r in ranges])
    span = np.maximum(hi - lo, 1e-3)
    rows, finite = [], []
    for i in range(len(ranges)):
        for value, ok in ((lo[i] - 0.1 * span[i], True), (hi[i] + 0.1 * span[i], True),
                          (np.nan, False), (np.inf, False), (-np.inf, False)):
            row = (lo + hi) / 2.0
            row[i] = value
            rows.append(row)
            finite.append(ok)
    outside = np.array(rows, dtype=np.float32)
    finite_rows = np.array(finite)
    _, d_out, f_out = sess.run(None, {**{s: np.ascontiguousarray(outside[:, i])
                                         for i, s in enumerate(model.signals)},
                                      "raw": np.zeros((len(rows), n_axes))})
    d_out = d_out - const
    if not bool(f_out.all()):
        k = int(np.argmin(f_out))
        raise ExportError("ONNX out_of_range flag not set at "
                          + ", ".join(f"{s}={outside[k, i]:.6g}"
                                      for i, s in enumerate(model.signals)))
    with torch.no_grad():
        d_clamped = model.relative(torch.from_numpy(outside[finite_rows])).double().numpy()
    bad = np.abs(d_out[finite_rows].astype(np.float64) - d_clamped) > tol
    if bool(bad.any()):
        k, a = np.argwhere(bad)[0]
        raise ExportError(f"ONNX drift outside the trained range is not the clamped value "
                          f"(axis '{model.outputs[a]}': onnxruntime {d_out[finite_rows][k, a]:.9g} "
                          f"vs torch {d_clamped[k, a]:.9g})")
    if not bool(np.isnan(d_out[~finite_rows]).all()):
        raise ExportError("ONNX graph does not return NaN drift for a NaN or infinite signal")
    return {"n_points": float(n), "max_abs_diff": float(err.max()),
            "max_rel_diff": float((err / np.maximum(scale, 1e-30)).max())}
