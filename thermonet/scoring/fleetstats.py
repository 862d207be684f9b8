"""Fleet statistics: coefficient spread, robust outlier flags, pass/fail limits, HTML fragment.

Spread of a quantity over units: median, MAD (median absolute deviation, raw,
not scaled), min, max and the number of units.  Outlier rule (robust z-score,
Iglewicz & Hoaglin's modified z):

.. math:: z_u = \\frac{|x_u - \\operatorname{median}(x)|}{1.4826 \\cdot \\operatorname{MAD}(x)}

a unit is flagged when :math:`z_u > 3.5` for any quantity the fleet judges
(:func:`thermonet.workflows.fleet.run_fleet`: the fleet family's curve at five
temperatures of the common range — well conditioned, unlike the higher
polynomial coefficients, which are reported but do not flag — and, one-sided,
the held-out errors: a unit better than its peers is no outlier).
1.4826·MAD estimates σ for normal data, so 3.5 is ≈3.5σ, and
one wild unit cannot hide itself by inflating the spread as it does with
mean ± k·std).  A quantity whose MAD is 0 (every unit equal) flags nothing, and
fewer than :data:`MIN_UNITS_FOR_OUTLIERS` units flag nothing (with three units
the MAD is the gap to the nearer neighbour and z-scores run into thousands).

Limits (the ``limits:`` config section) turn a unit's held-out results into
PASS/FAIL, per output axis or ``"*"`` for every axis (an axis entry overrides
``*`` key by key; an axis that is not an output of the data is refused,
:func:`check_limit_axes`, rather than judging nothing):

``max_pp``
    maximum peak-to-peak of the 1 °C-binned compensated error (``pp_comp``), output unit;
``max_std``
    maximum standard deviation of the compensated error (``rms_comp``), output unit;
``max_ratio_to_raw``
    maximum ``pp_comp / pp_raw`` (1 = no better than uncompensated);
``min_temperature_span_c``
    minimum temperature span covered by the unit's runs, °C.

They are judged on the chosen family's **held-out** metrics (production test
frameworks judge on the fitted data, which flatters every fit).  A unit whose
choice is ``none`` ships uncompensated and is judged on its raw error.  A unit
that could not be calibrated fails.
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, TypeVar

import numpy as np

from ..core.errors import ConfigError
from ..core.schema import from_dict

__all__ = ["LimitSpec", "parse_limits", "check_limit_axes", "limits_for", "merged_limits",
           "judge_unit", "spread", "robust_z", "flag_outliers", "ROBUST_Z_THRESHOLD",
           "MAD_TO_SIGMA",
           "MIN_UNITS_FOR_OUTLIERS", "quantity_label",
           "fleet_html_fragment"]

_L = TypeVar("_L")

#: Units whose robust z-score exceeds this are flagged (Iglewicz & Hoaglin).
ROBUST_Z_THRESHOLD = 3.5
#: MAD × this estimates the standard deviation of normal data.
MAD_TO_SIGMA = 1.4826
#: Below this many units no unit is flagged as an outlier.
MIN_UNITS_FOR_OUTLIERS = 5


@dataclass
class LimitSpec:
    """Pass/fail limits of one axis (None: not checked); see the module docstring."""

    max_pp: float | None = None                 # output unit
    max_std: float | None = None                # output unit
    max_ratio_to_raw: float | None = None       # pp_comp / pp_raw
    min_temperature_span_c: float | None = None  # °C

    def __post_init__(self) -> None:
        for name in ("max_pp", "max_std", "max_ratio_to_raw", "min_temperature_span_c"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"key '{name}': must be a finite number ≥ 0, got {v!r}")


def parse_limits(raw: Any, *, source: str = "config") -> dict[str, LimitSpec]:
    """Check the ``limits`` section (axis or ``*`` → limits); errors name the key."""
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: key 'limits': expected a mapping axis -> limits, "
                          f"got {raw!r}")
    out = {}
    for axis, spec in raw.items():
        if not isinstance(axis, str) or not axis:
            raise ConfigError(f"{source}: key 'limits': axis name {axis!r} is not a string")
        try:
            out[axis] = from_dict(LimitSpec, spec, source=source, prefix=f"limits.{axis}")
        except ConfigError as err:
            msg = str(err)
            raise ConfigError(msg if msg.startswith(source) else f"{source}: {msg}") from None
    return out


def check_limit_axes(limits: Mapping[str, Any], outputs: list[str], *,
                     source: str = "config") -> None:
    """Refuse, in one line naming the key, a ``limits`` entry that is not ``*`` and not one of
    ``outputs`` (the outputs the units' models fit): such limits would judge nothing, and
    every unit would pass them."""
    unknown = [a for a in limits if a != "*" and a not in outputs]
    if unknown:
        raise ConfigError(f"{source}: key 'limits.{unknown[0]}': not an output of the data "
                          f"(its outputs: {', '.join(outputs) or 'none'}; '*' for every one)")


def merged_limits(limits: Mapping[str, _L], axis: str, kind: type[_L]) -> _L:
    """The limits of ``axis``: its own entry over ``*``, key by key (``kind``: a dataclass
    of optional limits, every field defaulting to None — a fleet's :class:`LimitSpec`, a
    station's :class:`~thermonet.scoring.prior.StationLimit`)."""
    base, own = limits.get("*", kind()), limits.get(axis, kind())
    return kind(**{f.name: getattr(own, f.name) if getattr(own, f.name) is not None
                   else getattr(base, f.name) for f in fields(kind)})  # type: ignore[arg-type]


def limits_for(limits: dict[str, LimitSpec], axis: str) -> LimitSpec:
    """The limits of ``axis``: its own entry over ``*``, key by key."""
    return merged_limits(limits, axis, LimitSpec)


def judge_unit(unit: dict[str, Any], limits: dict[str, LimitSpec]) -> dict[str, Any]:
    """PASS/FAIL of one unit against ``limits``.

    Parameters
    ----------
    unit : dict
        A unit's results (``run_compare``'s dict plus ``temperature_span_c``), or
        a failed unit (``status: "failed"``, ``reason``).

    Returns
    -------
    dict
        ``{"verdict": "PASS"|"FAIL"|"NOT JUDGED", "axes": {axis: {"verdict",
        "checks": [{"limit", "value", "max"|"min", "ok"}]}}, "reasons": [...]}``.
    """
    if unit.get("status") == "failed":
        return {"verdict": "FAIL", "axes": {}, "reasons": [f"not calibrated: {unit['reason']}"]}
    if not limits:
        return {"verdict": "NOT JUDGED", "axes": {}, "reasons": ["no limits configured"]}
    chosen = unit.get("chosen")
    fam = unit["families"].get(chosen) if chosen else None
    any_fam = next((f for f in unit["families"].values() if f.get("status") == "ok"), None)
    axes_src = (fam or any_fam or {}).get("axes", {})
    reasons: list[str] = []
    out_axes: dict[str, Any] = {}
    for axis in unit["units"]:
        lim = limits_for(limits, axis)
        m = axes_src.get(axis)
        checks: list[dict[str, Any]] = []
        if m is None:
            checks.append({"limit": "calibrated", "value": None, "ok": False})
        else:
            # what the unit ships: an axis its model leaves uncompensated stays raw
            shipped = bool(fam) and m.get("compensate", True)
            pp = m["pp_comp"] if shipped else m["pp_raw"]
            std = m["rms_comp"] if shipped else m["rms_raw"]
            ratio = pp / m["pp_raw"] if m["pp_raw"] > 0 else float("inf")
            for name, value, bound in (("max_pp", pp, lim.max_pp), ("max_std", std, lim.max_std),
                                       ("max_ratio_to_raw", ratio, lim.max_ratio_to_raw)):
                if bound is not None:
                    checks.append({"limit": name, "value": value, "max": bound,
                                   "ok": bool(value <= bound)})
        if lim.min_temperature_span_c is not None:
            span = unit["temperature_span_c"]
            checks.append({"limit": "min_temperature_span_c", "value": span,
                           "min": lim.min_temperature_span_c,
                           "ok": span is not None and span >= lim.min_temperature_span_c})
        ok = all(c["ok"] for c in checks)
        out_axes[axis] = {"verdict": "PASS" if ok else "FAIL", "checks": checks}
        for c in checks:
            if not c["ok"]:
                bound = c.get("max", c.get("min"))
                val = "n/a" if c["value"] is None else f"{c['value']:.4g}"
                reasons.append(f"{axis}: {c['limit']} {val} vs {bound}")
    verdict = "PASS" if all(a["verdict"] == "PASS" for a in out_axes.values()) else "FAIL"
    if chosen is None:
        reasons.append("no family chosen: judged on the raw (uncompensated) error")
    return {"verdict": verdict, "axes": out_axes, "reasons": reasons}


def spread(values: dict[str, float]) -> dict[str, Any]:
    """Median, MAD, min, max and count of per-unit values (non-finite values left out)."""
    v = np.array([x for x in values.values() if x is not None and math.isfinite(x)])
    if v.size == 0:
        return {"n": 0, "median": None, "mad": None, "min": None, "max": None}
    med = float(np.median(v))
    return {"n": int(v.size), "median": med, "mad": float(np.median(np.abs(v - med))),
            "min": float(v.min()), "max": float(v.max())}


def robust_z(values: dict[str, float]) -> dict[str, float]:
    """Signed (x − median) / (1.4826 · MAD) per unit; empty when MAD is 0 or fewer than
    :data:`MIN_UNITS_FOR_OUTLIERS` units."""
    s = spread(values)
    if s["n"] < MIN_UNITS_FOR_OUTLIERS or not s["mad"]:
        return {}
    scale = MAD_TO_SIGMA * s["mad"]
    return {u: (x - s["median"]) / scale for u, x in values.items()
            if x is not None and math.isfinite(x)}


def flag_outliers(quantities: dict[str, dict[str, float]],
                  threshold: float = ROBUST_Z_THRESHOLD, *,
                  high_only: set[str] | frozenset[str] = frozenset()
                  ) -> dict[str, list[dict[str, Any]]]:
    """Units with a robust |z| above ``threshold`` on any quantity.

    Parameters
    ----------
    quantities : dict
        quantity name → {unit → value}.
    threshold : float
    high_only : set of str
        Quantities flagged only above the median (errors: lower is not a fault).

    Returns
    -------
    dict
        unit → [{"quantity", "value", "z"}] (z signed), only flagged units, largest |z| first.
    """
    flags: dict[str, list[dict[str, Any]]] = {}
    for name, values in quantities.items():
        for unit, z in robust_z(values).items():
            if (z if name in high_only else abs(z)) > threshold:
                flags.setdefault(unit, []).append({"quantity": name, "value": values[unit],
                                                   "z": z})
    return {u: sorted(f, key=lambda d: -abs(d["z"])) for u, f in sorted(flags.items())}


def quantity_label(name: str) -> str:
    """A quantity's name as text shows it: ``cubic.acc_x.drift@-20C`` (the results.json key)
    reads ``cubic.acc_x.drift@-20 °C``; other names are shown as they are."""
    head, at, temp = name.rpartition(".drift@")
    return f"{head}{at}{temp[:-1]} °C" if at and temp.endswith("C") else name


def fleet_html_fragment(results: dict[str, Any], spread_png: str | None = None) -> str:
    """An HTML fragment for the report: the unit × axis verdict table and the spread plot.

    ``results`` is a fleet ``results.json``; ``spread_png`` a path (relative to the
    page) of the coefficient-spread plot.  Every value is escaped.
    """
    e = html.escape
    units = results.get("units", {})
    axes: list[str] = []
    for u in units.values():
        axes += [a for a in u.get("limits", {}).get("axes", {}) if a not in axes]
        axes += [a for a in (u.get("units") or {}) if a not in axes]
    flagged = results.get("fleet", {}).get("outliers", {})
    rows = ["<tr><th>unit</th><th>chosen</th>" + "".join(f"<th>{e(a)}</th>" for a in axes)
            + "<th>verdict</th><th>outlier</th></tr>"]
    for dev, u in units.items():
        lim = u.get("limits", {})
        cells = []
        for a in axes:
            ax = lim.get("axes", {}).get(a)
            if ax is None:
                cells.append("<td>—</td>")
            else:
                cls = "pass" if ax["verdict"] == "PASS" else "fail"
                cells.append(f'<td class="{cls}">{e(ax["verdict"])}</td>')
        verdict = lim.get("verdict", "—")
        cls = {"PASS": "pass", "FAIL": "fail"}.get(verdict, "")
        why = "; ".join(lim.get("reasons", []))
        out = ", ".join(f"{quantity_label(f['quantity'])} z={f['z']:.1f}"
                        for f in flagged.get(dev, []))
        rows.append(f"<tr><td>{e(dev)}</td><td>{e(str(u.get('chosen') or 'none'))}</td>"
                    + "".join(cells) + f'<td class="{cls}" title="{e(why)}">{e(verdict)}</td>'
                    f"<td>{e(out)}</td></tr>")
    parts = ['<section class="fleet"><h2>Fleet</h2>',
             f"<p>{len(units)} units; outlier rule: robust z = |x − median| / (1.4826·MAD) "
             f"&gt; {ROBUST_Z_THRESHOLD}.</p>",
             '<table class="fleet-verdicts">' + "".join(rows) + "</table>"]
    if spread_png:
        parts.append(f'<img alt="coefficient spread over units" src="{e(spread_png)}">')
    parts.append("</section>")
    return "\n".join(parts)
