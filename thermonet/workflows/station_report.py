"""What a station run keeps and prints (:mod:`thermonet.workflows.station`): a unit's summary
in ``results.json`` (:func:`unit_summary`), the run's (:func:`station_summary`) and the
console's lines (:func:`format_station`): per unit its verdict, worst held-out residual,
the limits it failed, a dead axis in words, and for a failed axis the temperatures to
measure next; a unit built from several runs says which.  A unit whose own data failed a
check before it could be calibrated (:func:`failed_unit`: measured outside the prior's range,
a dead thermometer, no rows…) is a FAIL with its reason (``error``), no axes and no firmware
file; ``summary.not_calibrated`` lists those units."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core.errors import counted
from ..core.outdir import sha256_file
from ..core.recording import Dataset
from ..scoring.prior import FleetPrior
from .station_checks import run_sources, runs_line

__all__ = ["unit_summary", "station_summary", "format_station", "failed_unit", "DEAD_AXIS"]

#: The check a dead or stuck axis fails (:func:`thermonet.workflows.station_checks.dead_axes`).
DEAD_AXIS = "dead_axis"


def failed_unit(dev: str, reason: str, ds: Dataset | None = None) -> dict[str, Any]:
    """A unit whose own data failed a check before it was calibrated (``reason``, one
    line): its verdict FAIL, no axes and no firmware file; ``ds``: its runs, where read."""
    return {"device_id": dev, "verdict": "FAIL", "error": reason, "axes": {},
            "runs": None if ds is None else len(ds),
            "run_sources": [] if ds is None else run_sources(ds),
            "temperature_span_c": None, "test_kind": None, "short_test_map": None,
            "firmware_header": f"not written: {reason}", "header": None}


def _reason(dev: str, u: dict[str, Any]) -> str:
    """A failed unit's reason without its own "unit '<id>': " prefix (its line names it)."""
    return str(u["error"]).removeprefix(f"unit '{dev}': ")


def unit_summary(r: dict[str, Any], rel: str) -> dict[str, Any]:
    """What results.json keeps of a unit: verdicts, held-out residuals, flags, its files."""
    return {"device_id": r["device_id"], "verdict": r["verdict"], "error": r.get("error"),
            "runs": r["runs"],
            "run_sources": r.get("run_sources", []),
            "temperature_span_c": r["temperature_span_c"], "test_kind": r["test_kind"],
            "short_test_map": r["short_test_map"], "files": rel,
            "firmware_header": r.get("firmware_header"),
            "axes": {a: {"verdict": x["verdict"], "held_out_rms": x["held_out_rms"],
                         "held_out_not_judged": x["held_out_not_judged"],
                         "p_value": x["p_value"],
                         "flagged_unlike_fleet": x["flagged_unlike_fleet"],
                         "fleet_not_compared": x["fleet_not_compared"],
                         "dead_axis": x.get("dead_axis"),
                         "next_temperatures_c": x.get("next_temperatures_c"),
                         "failed": [c["limit"] for c in x["checks"] if not c["ok"]]}
                     for a, x in r["axes"].items()}}


def station_summary(prior: FleetPrior, units: dict[str, dict[str, Any]],
                    seconds: float, prior_file: str = "") -> dict[str, Any]:
    n_fail = sum(u["verdict"] != "PASS" for u in units.values())
    digest = sha256_file(prior_file) if prior_file and Path(prior_file).is_file() else None
    return {"schema": 1, "kind": "station", "prior": prior.source,
            "prior_file": prior_file or None, "prior_sha256": digest,
            "prior_units": prior.n_units, "units_of_measure": prior.units, "units": units,
            "summary": {"n_units": len(units), "passed": len(units) - n_fail,
                        "failed": n_fail,
                        "flagged_unlike_fleet": sorted(
                            d for d, u in units.items()
                            if any(a["flagged_unlike_fleet"] for a in u["axes"].values())),
                        "not_compared_with_fleet": sorted(
                            d for d, u in units.items()
                            if any(a["fleet_not_compared"] for a in u["axes"].values())),
                        "dead_axes": sorted(
                            d for d, u in units.items()
                            if any(a.get("dead_axis") for a in u["axes"].values())),
                        "several_runs": sorted(d for d, u in units.items()
                                               if (u["runs"] or 0) > 1),
                        "not_calibrated": sorted(d for d, u in units.items() if u.get("error")),
                        "seconds": seconds,
                        "units_per_minute": 60.0 * len(units) / max(seconds, 1e-9)}}


def _next_text(axes: dict[str, Any]) -> str:
    """Where a unit's failed axes should be measured next, axes of one plan together:
    "next -20, 75 °C (gyro_x, gyro_y)"; "" where no failed axis has a plan."""
    plans: dict[tuple[float, ...], list[str]] = {}
    for a, r in axes.items():
        nxt = r.get("next_temperatures_c")
        if nxt is not None:      # set on a failed axis alone
            plans.setdefault(tuple(nxt), []).append(a)
    parts = [(f"next {', '.join(f'{t:g}' for t in temps)} °C" if temps else
              "no temperature left to measure (its test covers the range)")
             + f" ({', '.join(names)})" for temps, names in plans.items()]
    return "; ".join(parts)


def _fail_text(a: str, r: dict[str, Any], lim: str, unjudged: dict[str, str]) -> str:
    if lim == DEAD_AXIS:
        return str(r.get("dead_axis") or f"{a}: a dead axis")
    if lim == "like_its_fleet":
        return f"{a}: unlike its fleet (p={r['p_value']:.2g})"
    return f"{a}: " + lim + (f": not judged ({unjudged[a]})" if lim == "max_residual"
                             and a in unjudged else "")


def _unit_line(dev: str, u: dict[str, Any], uom: dict[str, str]) -> str:
    """A unit's verdict, its worst held-out residual per unit of measure (°/s and m/s² are
    not compared) or why none could be judged, the limits it failed (a dead axis first, in
    words) and where to measure next; a unit not calibrated, its reason."""
    if u.get("error"):
        return f"{dev}: FAIL  not calibrated: {_reason(dev, u)}"
    axes = u["axes"]
    judged = {a: r for a, r in axes.items() if r["held_out_rms"] is not None}
    unjudged = {a: r.get("held_out_not_judged") or "no value" for a, r in axes.items()
                if r["held_out_rms"] is None}
    if judged:
        by_unit: dict[str, tuple[str, float]] = {}   # the worst axis of each unit of measure
        for a, r in judged.items():
            m = uom.get(a, "")
            if m not in by_unit or r["held_out_rms"] > by_unit[m][1]:
                by_unit[m] = (a, r["held_out_rms"])
        worst = "worst held-out residual " + ", ".join(
            f"{a} {v:.3g} {m}".rstrip() for m, (a, v) in by_unit.items())
        if unjudged:
            worst += f" ({', '.join(unjudged)} not judged)"
    else:
        worst = f"held-out residual not judged ({'; '.join(dict.fromkeys(unjudged.values()))})"
    failed = sorted(((a, r, lim) for a, r in axes.items() for lim in r["failed"]),
                    key=lambda x: x[2] != DEAD_AXIS)
    fails = [_fail_text(a, r, lim, unjudged) for a, r, lim in failed]
    nxt = _next_text(axes)
    return (f"{dev}: {u['verdict']}  {worst}" + (f"  [{'; '.join(fails[:3])}]" if fails else "")
            + (f"  {nxt}" if nxt else ""))


def format_station(results: dict[str, Any]) -> str:
    """One line per unit: verdict, worst held-out residual, flags; a line per unit of several
    runs naming them; then the totals."""
    uom = results.get("units_of_measure") or {}
    lines = [_unit_line(dev, u, uom) for dev, u in results["units"].items()]
    lines += [ln for dev, u in results["units"].items()
              if (ln := runs_line(dev, u.get("run_sources") or [])) is not None]
    s = results["summary"]
    bad = s.get("not_calibrated") or []
    lines.append(f"{s['passed']} of {s['n_units']} units passed"
                 + (f" ({len(bad)} not calibrated: their data failed a check)" if bad else "")
                 + "; "
                 f"{len(s['flagged_unlike_fleet'])} unlike their fleet; "
                 f"{s['units_per_minute']:.0f} units/min")
    by_reason: dict[str, int] = {}      # units of one test kind share their reason
    for dev in s.get("not_compared_with_fleet") or []:
        why = next(a["fleet_not_compared"] for a in results["units"][dev]["axes"].values()
                   if a["fleet_not_compared"])
        by_reason[why] = by_reason.get(why, 0) + 1
    lines += [f"{counted(n, 'unit')} not compared with the fleet: {why}"
              for why, n in by_reason.items()]
    maps = [u.get("short_test_map") for u in results["units"].values() if not u.get("error")]
    if any(maps):
        used = maps.count("used")
        lines.append(f"{used} of {len(maps)} calibrated through the fleet's short test"
                     + "".join(f"; {counted(maps.count(m), 'unit')} from their points ("
                               f"{m.removeprefix('not used: ')})"
                               for m in dict.fromkeys(maps) if m and m != "used"))
    return "\n".join(lines)
