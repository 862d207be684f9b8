"""``DIR/report.html`` of a ``model: sensor`` comparison: self-contained, one figure.

Sections: the chosen family, how it was chosen (the rule's sentence; with cross-validation
each family's out-of-fold score, its interval and per-fold scores), the sensor model's targets (bias-only / sensor residual ≥ 5 on every
axis, compensated scale-factor tempco ≤ 15 ppm/°C); per family a table per axis (residual
RMS raw, bias-only, sensor model; ratios and verdicts against raw and the bias-only model;
scale-factor tempco raw / bias-only / compensated) and a table of the misalignments (mean
and spread over the soaks, mrad, raw and compensated); the elements do-no-harm left at
identity / zero; the chosen family's per-soak scale factors and misalignments against
temperature, raw and compensated (:func:`plot_sensor_soaks`, embedded as base64 PNG).
Every string from the results is HTML-escaped.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.fileio import atomic_write_text
from .report import _CSS, VERDICT_COLOURS

__all__ = ["render_sensor_report", "write_sensor_report", "plot_sensor_soaks"]


def plot_sensor_soaks(path: str | Path, title: str,
                      soaks: Sequence[tuple[list[str], np.ndarray, np.ndarray, np.ndarray]]
                      ) -> Path:
    """Per triad: the per-soak scale-factor error (ppm) and misalignments (mrad) against
    temperature, raw (dashed) and compensated (solid), on the held-out run.

    ``soaks``: per triad ``(axes, temperatures (G,), M raw (G, k, k), M compensated)``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 3.6 * len(soaks)), layout="constrained")
    FigureCanvasAgg(fig)
    axs = fig.subplots(len(soaks), 2, squeeze=False)
    for row, (axes, temps, m_raw, m_comp) in enumerate(soaks):
        o = np.argsort(temps)
        k = len(axes)
        for i, a in enumerate(axes):
            line = axs[row, 0].plot(temps[o], (m_raw[o, i, i] - 1) * 1e6, "--", label=f"{a} raw")
            axs[row, 0].plot(temps[o], (m_comp[o, i, i] - 1) * 1e6, "-",
                             color=line[0].get_color(), label=f"{a} compensated")
            for j in range(k):
                if i != j:
                    ln = axs[row, 1].plot(temps[o], m_raw[o, i, j] * 1e3, "--",
                                          label=f"{a}<-{axes[j]} raw")
                    axs[row, 1].plot(temps[o], m_comp[o, i, j] * 1e3, "-",
                                     color=ln[0].get_color())
        axs[row, 0].set(xlabel="temperature (°C)", ylabel="scale-factor error (ppm)",
                        title=f"{title}: scale factor per soak")
        axs[row, 1].set(xlabel="temperature (°C)", ylabel="misalignment (mrad)",
                        title="misalignment per soak (dashed raw, solid comp.)")
        axs[row, 0].legend(fontsize=7, ncol=2)
        axs[row, 1].legend(fontsize=6, ncol=2)
        for ax in axs[row]:
            ax.grid(alpha=0.3)
    out = Path(path)
    fig.savefig(out, dpi=90)
    return out


def _e(x: object) -> str:
    return html.escape(str(x), quote=True)


def _n(x: Any, fmt: str = ".4g") -> str:
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else \
        format(float(x), fmt)


def _v(ratio: float, verdict: str, ci: list[float]) -> str:
    return (f'<td style="background:{VERDICT_COLOURS.get(verdict, "#fff")}">{_n(ratio, ".3g")}'
            f' [{_n(ci[0], ".3g")}, {_n(ci[1], ".3g")}] {_e(verdict)}</td>')


def render_sensor_report(res: dict[str, Any], plots: Sequence[str | Path] = ()) -> str:
    units = res.get("units", {})
    parts = [f"<h1>thermonet: sensor model, {_e(res.get('device'))}</h1>",
             f"<p>chosen family: <b>{_e(res.get('chosen'))}</b>; split "
             f"{_e(res.get('split', {}).get('strategy'))}; triads {_e(res.get('triads'))}</p>"]
    parts += _choice(res)
    for w in res.get("warnings") or []:
        parts.append(f"<p><b>warning:</b> {_e(w)}</p>")
    onnx = res.get("onnx") or {}
    parts.append(f"<p>ONNX: {_e(onnx.get('status'))} {_e(onnx.get('path', onnx.get('reason', '')))}"
                 "</p>")
    for name, f in res.get("families", {}).items():
        parts.append(f"<h2>{_e(name)} ({_e(f.get('family'))}, inputs {_e(f.get('inputs'))})</h2>")
        if f.get("status") != "ok":
            parts.append(f"<p>not fitted: {_e(f.get('reason'))}</p>")
            continue
        parts.append("<table><tr><th>axis</th><th>unit</th><th>residual raw</th>"
                     "<th>bias-only</th><th>sensor</th><th>vs raw</th><th>vs bias-only</th>"
                     "<th>SF ppm/°C raw</th><th>bias-only</th><th>sensor</th></tr>")
        for a, m in f["axes"].items():
            parts.append(
                f"<tr><td>{_e(a)}</td><td>{_e(units.get(a, ''))}</td>"
                f"<td>{_n(m['residual_rms_raw'])}</td><td>{_n(m['residual_rms_bias_only'])}</td>"
                f"<td>{_n(m['residual_rms_comp'])}</td>"
                + _v(m["ratio_vs_raw"], m["verdict_vs_raw"], m["ci_vs_raw"])
                + _v(m["ratio_vs_bias"], m["verdict_vs_bias"], m["ci_vs_bias"])
                + f"<td>{_n(m.get('sf_ppm_per_c_raw'), '.3g')}</td>"
                f"<td>{_n(m.get('sf_ppm_per_c_bias_only'), '.3g')}</td>"
                f"<td>{_n(m.get('sf_ppm_per_c_comp'), '.3g')}</td></tr>")
        parts.append("</table><table><tr><th>element</th><th>misalignment mrad raw</th>"
                     "<th>spread raw</th><th>compensated</th><th>spread compensated</th></tr>")
        for k, m in f.get("misalignment", {}).items():
            parts.append(f"<tr><td>{_e(k)}</td><td>{_n(m['misalignment_mrad_raw'], '.3g')}</td>"
                         f"<td>{_n(m['misalignment_spread_mrad_raw'], '.3g')}</td>"
                         f"<td>{_n(m['misalignment_mrad_comp'], '.3g')}</td>"
                         f"<td>{_n(m['misalignment_spread_mrad_comp'], '.3g')}</td></tr>")
        off = [k for k, v in f.get("elements_kept", {}).items() if not v]
        parts.append(f"</table><p>elements left at identity / zero (do no harm): "
                     f"{_e(', '.join(off) or 'none')}</p>")
    for p in plots:
        data = base64.b64encode(Path(p).read_bytes()).decode("ascii")
        parts.append(f"<div><img alt='{_e(Path(p).stem)}' src='data:image/png;base64,{data}'>"
                     "</div>")
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>thermonet sensor model"
            f"</title><style>{_CSS}</style></head><body>{''.join(parts)}</body></html>")


def _choice(res: dict[str, Any]) -> list[str]:
    """How the family was chosen: the rule's sentence and, with cross-validation, each
    candidate's out-of-fold score (of raw) with its interval and per-fold scores."""
    sel = res.get("selection") or {}
    out = [f"<p>choice: {_e(res.get('chosen_reason') or sel.get('note') or '')}</p>"]
    cands = sel.get("candidates") or {}
    if cands:
        out.append(f"<table><tr><th>family</th><th>out-of-fold score ({_e(sel.get('kind'))}, "
                   f"{_e(sel.get('folds'))} folds)</th><th>interval</th><th>per fold</th></tr>")
        for name, c in cands.items():
            if c.get("status") != "ok":
                out.append(f"<tr><td>{_e(name)}</td><td colspan=3>not a candidate: "
                           f"{_e(c.get('reason'))}</td></tr>")
                continue
            out.append(f"<tr><td>{_e(name)}</td><td>{_n(c['score'], '.4g')}</td>"
                       f"<td>[{_n(c['interval'][0], '.4g')}, {_n(c['interval'][1], '.4g')}]"
                       f"</td><td>{_e(' '.join(format(x, '.3g') for x in c['fold_scores']))}"
                       "</td></tr>")
        out.append("</table>")
    return out


def write_sensor_report(path: str | Path, res: dict[str, Any],
                        plots: Sequence[str | Path] = ()) -> Path:
    return atomic_write_text(path, render_sensor_report(res, plots))
