"""Static multi-position test: bias K0 and scale factor K1 per soak (study 000).

In each settled soak the output is regressed on the reference (the gravity
projection of the table's positions):

.. math:: y = K_0 + K_1\\, x_{ref}

and the scale-factor temperature coefficient over the soaks is study 000's
:math:`\\Delta K`, defined once in
:func:`thermonet.scoring.metrics.scale_factor_tempco_ppm_per_c` (ppm/°C, positive for a
negative scale factor too).
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..core.recording import Recording

__all__ = ["four_position_estimates"]


def _blocks(mask: np.ndarray) -> list[tuple[int, int]]:
    """Start/stop indices (stop exclusive) of the runs of True in ``mask``."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(),
                    strict=False))


def four_position_estimates(recording: Recording, output: str | None = None, *,
                            max_rate_c_per_h: float = 1.0, window_s: float = 600.0,
                            settle_s: float = 600.0, min_levels: int = 2
                            ) -> list[tuple[float, float, float]]:
    """Per-soak ``(temperature_c, K0_bias, K1_scale)`` from a multi-position test.

    A soak is a stretch where the thermometer's temperature, smoothed over
    ``window_s``, changes slower than ``max_rate_c_per_h`` (°C/h); its first
    ``settle_s`` seconds are dropped (the sensing element still follows the
    chamber).  Soaks in which the reference takes fewer than ``min_levels``
    distinct values are skipped (no scale factor can be measured there).

    Returns
    -------
    list of (float, float, float)
        Mean thermometer temperature (°C), K0 (output unit), K1 (output unit
        per reference unit), in time order.

    Raises
    ------
    InputError
        No temperature, no reference channel for ``output``, or no soak found.
    """
    src = recording.meta.get("source", "") or f"run '{recording.run_id}'"
    output = output or recording.axes[0]
    if output not in recording.outputs:
        raise InputError.at(src, f"no output '{output}' (outputs: {sorted(recording.outputs)})")
    if f"ref_{output}" not in recording.references:
        raise InputError.at(src, "a four-position test needs the reference channel",
                            column=f"ref_{output}")
    if recording.temperature_c is None:
        raise InputError.at(
            src, "a four-position test needs the thermometer", column="temperature_c"
        )
    t = np.asarray(recording.time_s, dtype=np.float64)
    temp = np.asarray(recording.temperature_c, dtype=np.float64)
    y = np.asarray(recording.outputs[output], dtype=np.float64)
    ref = recording.references[f"ref_{output}"]
    dt = float(np.median(np.diff(t)))
    w = min(max(3, int(round(window_s / dt))), len(t))  # a run shorter than the window
    # a moving mean over the window hides thermometer quantisation steps
    smooth = np.convolve(temp, np.ones(w) / w, mode="same")
    rate = np.abs(np.gradient(smooth, t)) * 3600.0
    half = w // 2
    rate[:half] = rate[half]
    rate[-half:] = rate[-half - 1]
    out = []
    for i0, i1 in _blocks(rate < max_rate_c_per_h):
        m = np.zeros(t.size, dtype=bool)
        m[i0:i1] = True
        m &= t >= t[i0] + settle_s
        if np.unique(np.round(ref[m], 9)).size < min_levels:
            continue
        A = np.c_[np.ones(int(m.sum())), ref[m]]
        (k0, k1), *_ = np.linalg.lstsq(A, y[m], rcond=None)
        out.append((float(temp[m].mean()), float(k0), float(k1)))
    if not out:
        raise InputError.at(src, f"no settled soak with at least {min_levels} reference levels "
                            f"(temperature rate below {max_rate_c_per_h:g} °C/h)",
                            column="temperature_c")
    return out
