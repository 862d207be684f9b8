"""What a dataset holds, at a glance: the ``thermonet info`` summary.

:func:`summarize` returns a JSON-able dict; :func:`format_summary` renders it
as a text table.  Per output channel it reports the white-noise floor
(:func:`thermonet.scoring.metrics.noise_floor`, per run then averaged) and the thermal
drift seen in the data, the peak-to-peak of 1 °C-binned means of the observed
drift over all runs (:func:`thermonet.scoring.metrics.binned_peak_to_peak`).  The noise
floor is a standard deviation per sample at the file's own sample rate (not a
density: the same sensor logged at 4× the rate shows about twice the floor).
``warnings`` are the plausibility sentences ``compare`` gives, from the same
function (:func:`thermonet.data.diagnostics.input_warnings`): temperatures that look
like Kelvin, °F or m°C, absurd values or rates, a header line that is a data row.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..core.recording import Dataset
from ..data.diagnostics import input_warnings
from ..data.mapping import channel_role
from ..scoring.metrics import binned_peak_to_peak, noise_floor

__all__ = ["summarize", "format_summary"]


def _num(x: float) -> float | None:
    """JSON has no NaN: unknown numbers become None."""
    x = float(x)
    return x if math.isfinite(x) else None


@np.errstate(over="ignore", invalid="ignore")  # absurd values: warned about, not a traceback
def summarize(dataset: Dataset, *, bin_c: float = 1.0) -> dict[str, Any]:
    """Summarize channels, runs and per-output noise and drift.

    Parameters
    ----------
    dataset : Dataset
    bin_c : float
        Temperature bin width in °C for the drift peak-to-peak.

    Returns
    -------
    dict
        ``device_id``, ``channels`` (name, role, unit), ``runs`` (run_id,
        samples, duration_s, sample_rate_hz, temperature_min_c/max_c or None,
        proxies {name: [min, max]}, skipped_rows), ``outputs`` (name, unit,
        noise_floor, drift_peak_to_peak; units of the channel; the latter None
        without a °C thermometer), ``temperature_range_c`` ([min, max] or None),
        ``skipped_rows`` (int or None when no row could be skipped),
        ``noise_floor_basis`` (what the noise floor is: 1σ per sample at which rate),
        ``warnings`` (plausibility sentences, as ``compare`` gives them).

    Notes
    -----
    Noise floor per run, averaged over runs:

    .. math:: \\sigma_w = \\frac{1}{R}\\sum_r \\operatorname{std}(\\Delta y_r)/\\sqrt{2}

    Drift peak-to-peak over the dataset, with :math:`\\bar d_k` the mean observed
    drift (output − reference) in temperature bin :math:`k`:

    .. math:: \\Delta_{pp} = \\max_k \\bar d_k - \\min_k \\bar d_k
    """
    runs = list(dataset)
    first = runs[0]
    channels, units = _channels(runs)
    run_rows = []
    for r in runs:
        t = r.temperature_c
        run_rows.append({
            "run_id": r.run_id, "unit": r.device_id, "samples": r.n_samples,
            "duration_s": r.duration_s,
            "sample_rate_hz": r.effective_rate_hz,
            "temperature_min_c": None if t is None else float(t.min()),
            "temperature_max_c": None if t is None else float(t.max()),
            "proxies": {k: [float(v.min()), float(v.max())] for k, v in r.proxies.items()},
            "skipped_rows": int(r.meta["skipped_rows"]) if "skipped_rows" in r.meta else None,
        })
    with_t = [r for r in runs if r.temperature_c is not None]
    outputs = _output_rows(runs, units, bin_c)
    t_range = None
    if with_t:
        temps = [r.temperature_c for r in with_t if r.temperature_c is not None]
        t_range = [min(float(t.min()) for t in temps), max(float(t.max()) for t in temps)]
    skipped = dataset.meta.get("skipped_rows")

    rates = sorted({float(f"{r.effective_rate_hz:.4g}") for r in runs})
    at = f"{rates[0]:g} Hz" if len(rates) == 1 else f"each run's rate ({rates[0]:g} … " \
        f"{rates[-1]:g} Hz)"
    return {"device_id": dataset.device_id, "sensor_kind": first.sensor_kind,
            "n_runs": len(runs), "channels": channels, "runs": run_rows,
            "outputs": outputs, "temperature_range_c": t_range, "bin_c": bin_c,
            "skipped_rows": None if skipped is None else int(skipped),
            "noise_floor_basis": f"1 sigma per sample at {at}",
            "warnings": input_warnings(dataset)}


def _channels(runs: list[Any]) -> tuple[list[dict[str, str]], dict[str, str]]:
    """Every channel of the runs, in first-seen order, with its role and unit; the units."""
    names: list[str] = []
    units: dict[str, str] = {}
    for r in runs:
        for n in ["time_s"] + (["temperature_c"] if r.temperature_c is not None else []) \
                + list(r.outputs) + list(r.references) + list(r.drift) + list(r.proxies):
            if n not in names:
                names.append(n)
                units[n] = r.units.get(n, "s" if n == "time_s" else "?")
    channels = [{"name": n, "role": "time" if n == "time_s" else
                 ("proxy" if any(n in r.proxies for r in runs) else channel_role(n)),
                 "unit": units[n]} for n in names]
    return channels, units


@np.errstate(over="ignore", invalid="ignore")  # as summarize: absurd values are warned about
def _output_rows(runs: list[Any], units: dict[str, str], bin_c: float) -> list[dict[str, Any]]:
    """Per output of the first run: its noise floor (mean over runs) and the binned drift
    peak-to-peak over the runs with a °C thermometer (None without one)."""
    with_t = [r for r in runs if r.temperature_c is not None]
    outputs = []
    for name in runs[0].outputs:
        floors = [noise_floor(r.drift_observed(name)) for r in runs]
        floors = [f for f in floors if math.isfinite(f)]
        pp = None
        if with_t:
            pp = _num(binned_peak_to_peak(np.concatenate([r.temperature_c for r in with_t]),
                                          np.concatenate([r.drift_observed(name) for r in with_t]),
                                          bin_c))
        outputs.append({"name": name, "unit": units.get(name, "?"),
                        "noise_floor": _num(float(np.mean(floors))) if floors else None,
                        "drift_peak_to_peak": pp})
    return outputs


def _fmt(x: float | None, spec: str = ".4g") -> str:
    return "n/a" if x is None else format(x, spec)


def _c(x: float) -> str:
    """A temperature: 2 decimals, or 4 digits where it is absurd (1e306 °C is one line)."""
    return f"{x:.2f}" if abs(x) < 1e6 else f"{x:.4g}"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h)
              for i, h in enumerate(header)]

    def line(cells: list[str]) -> str:
        return "  ".join(c.ljust(w) for c, w in zip(cells, widths, strict=False)).rstrip()

    return [line(header), line(["-" * w for w in widths])] + [line(r) for r in rows]


def format_summary(summary: dict[str, Any]) -> str:
    """Render :func:`summarize`'s dict as readable text tables."""
    units = list(dict.fromkeys(r.get("unit", summary["device_id"]) for r in summary["runs"]))
    fleet = len(units) > 1        # a fleet's file: each run's unit named, the drift pooled
    head = (f"{len(units)} {summary['sensor_kind']} units ({units[0]} … {units[-1]})" if fleet
            else f"device {summary['device_id']} ({summary['sensor_kind']})")
    out = [f"{head}, {summary['n_runs']} run(s)", ""]
    out += _table(["channel", "role", "unit"],
                  [[c["name"], c["role"], c["unit"]] for c in summary["channels"]])
    out.append("")
    rows = []
    for r in summary["runs"]:
        if r["temperature_min_c"] is not None:
            temp = f"{_c(r['temperature_min_c'])}..{_c(r['temperature_max_c'])}"
        else:
            proxy = "; ".join(f"{k} {lo:.6g}..{hi:.6g}" for k, (lo, hi) in r["proxies"].items())
            temp = f"n/a (no °C thermometer; proxy: {proxy or 'none'})"
        rows.append([*([str(r.get("unit"))] if fleet else []), r["run_id"], str(r["samples"]),
                     f"{r['duration_s']:.1f}", f"{r['sample_rate_hz']:.4g}", temp,
                     "" if r["skipped_rows"] is None else str(r["skipped_rows"])])
    out += _table([*(["unit"] if fleet else []), "run", "samples", "duration s", "rate Hz",
                   "temperature °C", "skipped rows"], rows)
    out.append("")
    rows = [[o["name"], o["unit"], _fmt(o["noise_floor"]),
             _fmt(o["drift_peak_to_peak"]) if o["drift_peak_to_peak"] is not None
             else "n/a (no °C thermometer)"] for o in summary["outputs"]]
    out += _table(["output", "unit", "noise floor",
                   f"drift p-p ({summary['bin_c']:g} °C bins"
                   + (", every unit pooled: `thermonet fleet` fits each)" if fleet else ")")],
                  rows)
    out.append(f"noise floor: {summary['noise_floor_basis']} (a standard deviation, not a "
               "density)")
    if summary["temperature_range_c"] is not None:
        lo, hi = summary["temperature_range_c"]
        out += ["", f"temperature range {_c(lo)}..{_c(hi)} °C over all runs"]
    if summary["skipped_rows"] is not None:
        out.append(f"skipped malformed rows: {summary['skipped_rows']}")
    if summary["warnings"]:
        out.append("")
        out += [f"warning: {w}" for w in summary["warnings"]]
    return "\n".join(out)
