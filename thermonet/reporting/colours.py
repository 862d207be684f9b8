"""The families' colours in every figure and report, without matplotlib: a comparison
computes them once for all its figures (drawn in other processes,
:mod:`thermonet.reporting.plot_workers`), so every figure gives a family the same colour."""

from __future__ import annotations

import colorsys
from collections.abc import Sequence

import numpy as np

__all__ = ["PALETTE", "GRADE_COLOURS", "family_colours"]

#: Distinct, saturated qualitative colours: tab10 without its grey, Dark2 without its grey,
#: then a dozen strong web colours; no greys, so no family looks like the raw output.
PALETTE = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22",
    "#17becf", "#1b9e77", "#d95f02", "#7570b3", "#e7298a", "#66a61e", "#e6ab02", "#a6761d",
    "#6a3d9a", "#000080", "#808000", "#800000", "#008080", "#ff1493", "#00ff7f", "#ffd700",
    "#4b0082", "#7fff00", "#ff6347", "#00bfff",
)

#: A result cell's background by the held-out check's grade of its worst axis (verify's test):
#: green where every axis passes with margin, amber where one is marginal (a new log may FAIL
#: it), red where one fails; the green and red are the comparison report's better / worse.
GRADE_COLOURS = {"fine": "#c8e6c9", "marginal": "#ffe0b2", "fails": "#ffcdd2"}

# Two colours closer than this (largest RGB channel difference) count as the same.
_MIN_COLOUR_DISTANCE = 0.06


def _hex_rgb(colour: str) -> np.ndarray:
    return np.array([int(colour[i:i + 2], 16) / 255.0 for i in (1, 3, 5)])


def family_colours(labels: Sequence[str]) -> dict[str, str]:
    """A distinct colour per family label, in order; never a grey.

    The first ``len(PALETTE)`` families take :data:`PALETTE`; beyond it, hues
    step by the golden angle at high saturation, skipping any candidate within
    0.06 (largest RGB channel difference) of a colour already given.
    """
    out: dict[str, str] = {}
    taken = [_hex_rgb(c) for c in PALETTE]
    k = 0
    for i, label in enumerate(labels):
        if i < len(PALETTE):
            out[label] = PALETTE[i]
            continue
        while True:
            h = (k * 0.618033988749895) % 1.0
            value = (0.55, 0.75, 0.95)[(k // 5) % 3]
            rgb = np.array(colorsys.hsv_to_rgb(h, 0.85, value))
            k += 1
            far = min(float(np.abs(rgb - t).max()) for t in taken) > _MIN_COLOUR_DISTANCE
            if far or k > 100 * len(labels):  # hundreds of families: accept near colours
                break
        taken.append(rgb)
        out[label] = "#" + "".join(f"{int(round(c * 255)):02x}" for c in rgb)
    return out
