"""The suite's tolerance policy: how every test compares computed floats.

The suite passes on any x86-64 CPU — Intel with AVX-512, AMD with AVX2 and FMA, an old CPU
without AVX — and under ``qemu-x86_64 -cpu EPYC-Rome`` / ``-cpu Nehalem`` (``make
test-cpus``).  What changes between those CPUs is how a float computation is *rounded*: the
vector width decides how a sum is split into partial sums and where a batch's scalar tail
starts, fused multiply-add rounds once instead of twice, and the math libraries (oneDNN,
MKL, SLEEF, glibc's libm, onnxruntime's MLAS) dispatch different kernels for ``exp``, ``tanh``
and matrix products.  None of that is a bug, so no test may depend on it:

1. **float32 paths** (torch float32, onnxruntime, numpy float32, the C header in ``float``)
   are compared with :func:`assert_f32_close`: ``|got − want| ≤ depth · ε32 · scale`` with
   ε32 = 2⁻²³ ≈ 1.19e-7, ``scale`` the magnitude of the quantity compared (per axis, the largest
   ``|want|``: an absolute bound at the output's scale, because drift curves cross zero where a
   relative bound would demand more than float32 holds), and ``depth`` the number of rounding
   steps on the longest path with a margin: :data:`DEPTH` per kind of computation.  A formula
   error is ≥ 1e-3 of the scale, four orders of magnitude above any of these bounds.
2. **float64 paths** (the numpy reference formulas, float64 constants, least-squares solves of
   well-conditioned systems, the dynamic inputs' recursions) are compared with
   :func:`assert_f64_close`: relative ``1e-12`` (≈ 4500 ε64) unless a site says why it needs more.
3. **Exact equality** only where the code promises bit-identity, each place commented:
   integer and boolean results (flags, masks, counts, indices); a masked axis that is exactly
   0; the same computation on the same inputs in the same batch shape and position (a seeded
   simulator run twice, a model saved and loaded, a clamp whose input becomes the edge value
   itself); values copied, not computed (timestamps passed through, parameters written and read
   back as text with ``repr`` precision).  *Two different computations* — a batch of 6 against
   a batch of 2, a graph against numpy, a vectorised path against a loop — are never compared
   exactly.
4. **Statistical tolerances** (noise, bootstrap, the Allan deviation's scatter, recovered
   coefficients of a noisy law) come from the noise, not from the precision, and are
   explained where they are used.
5. **Decisions** (which family, which axes, which verdict) are discrete and compared exactly;
   the code makes them CPU-independent (:data:`thermonet.scoring.verdicts.DECISION_RTOL`), and
   ``tests/test_cpu_choices.py`` checks them against the choices recorded in
   ``tests/data/cpu_choices.json``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: float32 and float64 machine epsilon (2⁻²³, 2⁻⁵²).
EPS32 = float(np.finfo(np.float32).eps)
EPS64 = float(np.finfo(np.float64).eps)

#: Rounding depth (in ε32 at the output's scale) per kind of float32 computation.  Each is the
#: count of rounded operations on the longest path, doubled for error growth and rounded up:
#: ``affine``: features, standardise, one product, de-standardise (~8); ``family``: the deepest
#: exported family, a 16-centre RBF on [ΔT, ΔT²] — standardisation, a 3-term exponent per
#: centre, ``exp`` (≤ 2 ulp, amplified by the exponent's magnitude ≤ ~8), a 16-term output sum,
#: de-standardise — ≈ 64 steps; ``dynamic``: a family on dynamic inputs whose float32 recursion
#: (exponential lag, rate) runs over the whole sequence, 2× ``family``.
DEPTH = {"affine": 16, "family": 128, "dynamic": 256}


def f32_atol(want: Any, depth: int | str, *, axis: int | None = 0) -> np.ndarray:
    """Absolute tolerance ``depth · ε32 · max|want|`` (per column with ``axis=0``)."""
    d = DEPTH[depth] if isinstance(depth, str) else int(depth)
    w = np.abs(np.asarray(want, dtype=np.float64))
    w = np.where(np.isfinite(w), w, 0.0)
    scale = w.max() if axis is None or w.ndim == 0 else w.max(axis=axis, keepdims=True)
    return d * EPS32 * np.maximum(scale, np.finfo(np.float32).tiny)


def assert_f32_close(got: Any, want: Any, depth: int | str, *, axis: int | None = 0,
                     scale: Any = None, err_msg: str = "") -> None:
    """``got`` equals ``want`` to float32 rounding of a computation ``depth`` steps deep.

    NaN must match NaN at the same places.  ``scale`` overrides the magnitude the bound is
    taken at (e.g. the drift's scale when ``want`` is raw counts − drift).
    """
    g = np.asarray(got, dtype=np.float64)
    w = np.asarray(want, dtype=np.float64)
    ref = w if scale is None else np.broadcast_to(np.asarray(scale, dtype=np.float64), w.shape)
    atol = f32_atol(ref, depth, axis=axis)
    _assert_columns(g, w, np.broadcast_to(atol, w.shape), err_msg)


def _assert_columns(g: np.ndarray, w: np.ndarray, atol: np.ndarray, err_msg: str) -> None:
    nan_g, nan_w = np.isnan(g), np.isnan(w)
    np.testing.assert_array_equal(nan_g, nan_w, err_msg=f"NaN places differ {err_msg}")
    ok = nan_w | (g == w) | (np.abs(g - w) <= atol)     # g == w: equal infinities
    if not ok.all():
        bad = np.argwhere(~ok)[:5]
        worst = float(np.max(np.where(ok, 0.0, np.abs(g - w) / atol)))
        raise AssertionError(f"not equal to float32 rounding {err_msg}: at {bad.tolist()} "
                             f"error {worst:.3g}× the tolerance")


def assert_f64_close(got: Any, want: Any, *, rtol: float = 1e-12, atol: float = 0.0,
                     err_msg: str = "") -> None:
    """``got`` equals ``want`` to float64 rounding (relative ``rtol``, 1e-12 by default)."""
    np.testing.assert_allclose(np.asarray(got, dtype=np.float64),
                               np.asarray(want, dtype=np.float64), rtol=rtol, atol=atol,
                               err_msg=err_msg)
