"""What a fleet run reports: the per-unit curves and the fleet summary (spread, outliers,
limits), the table printed on stdout and the coefficient-spread figure.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..scoring.fleetstats import (
    MIN_UNITS_FOR_OUTLIERS,
    ROBUST_Z_THRESHOLD,
    flag_outliers,
    quantity_label,
    robust_z,
    spread,
)
from .fleet_units import COEF_T0_C

__all__ = ["fleet_summary", "format_fleet_table", "plot_coefficient_spread", "clean"]


def _curve_points(ok: dict[str, Any], family: str) -> dict[str, dict[str, float]]:
    """The fleet family's curve of every unit at five temperatures of the range all units
    were trained on (from the physical coefficients)."""
    ranges = [u["temperature_range_c"] for u in ok.values() if u.get("temperature_range_c")]
    if len(ranges) < len(ok) or not ranges:
        return {}
    lo, hi = max(r[0] for r in ranges), min(r[1] for r in ranges)
    if not hi > lo:
        return {}
    out: dict[str, dict[str, float]] = {}
    for t in np.round(np.linspace(lo, hi, 5), 1) + 0.0:   # + 0.0: no "-0" in a name
        for dev, u in ok.items():
            coefs: dict[str, dict[int, float]] = {}
            for name, v in u["coefficients"].items():
                axis, _, k = name.rpartition(".c")
                coefs.setdefault(axis, {})[int(k)] = v
            for axis, c in coefs.items():
                value = sum(v * (t - COEF_T0_C) ** k for k, v in c.items())
                out.setdefault(f"{family}.{axis}.drift@{t:g}C", {})[dev] = float(value)
    return out


def fleet_summary(units: dict[str, Any], family: str, folds: dict[str, Any],
             limits: dict[str, Any]) -> dict[str, Any]:
    ok = {d: u for d, u in units.items() if u.get("status") == "ok"}
    coefficients: dict[str, dict[str, float]] = {}
    for dev, u in ok.items():
        for name, v in u.get("coefficients", {}).items():
            coefficients.setdefault(f"{family}.{name}", {})[dev] = v
    quantities = _curve_points(ok, family)
    errors: set[str] = set()
    for dev, u in ok.items():
        fam = u["families"].get(family, {})
        for axis, m in fam.get("axes", {}).items():
            for metric in ("rms_comp", "pp_comp"):
                if metric in m:
                    errors.add(f"{family}.{axis}.{metric}")
                    quantities.setdefault(f"{family}.{axis}.{metric}", {})[dev] = m[metric]
    luo_ratios: dict[str, list[float]] = {}
    for u in ok.values():
        for axis, a in ((u.get("leave_units_out") or {}).get("axes") or {}).items():
            if a.get("ratio") is not None:
                luo_ratios.setdefault(axis, []).append(a["ratio"])
    verdicts: dict[str, int] = {}
    for u in units.values():
        if "limits" in u:
            v = u["limits"]["verdict"]
            verdicts[v] = verdicts.get(v, 0) + 1
    n_failed = len(units) - len(ok)
    all_passed = n_failed == 0 and verdicts.get("FAIL", 0) == 0
    return {
        "n_units": len(units), "n_failed": n_failed, "family": family,
        "spread": {q: spread(v) for q, v in {**coefficients, **quantities}.items()},
        "outliers": flag_outliers(quantities, high_only=errors),
        "outlier_rule": f"robust z = |x - median| / (1.4826 * MAD) > {ROBUST_Z_THRESHOLD} on the "
                        "fleet family's curve at five temperatures of the common range, or "
                        "above the median on its held-out rms_comp / pp_comp (at least "
                        f"{MIN_UNITS_FOR_OUTLIERS} units; coefficients are reported, not "
                        "flagged: the higher ones are ill-conditioned)",
        "leave_units_out": {
            "family": family, "folds": folds,
            "median_ratio": {a: float(np.median(r)) for a, r in luo_ratios.items()},
            "meaning": "std of the compensated held-out error with a fleet model fitted on "
                       "other units / with the unit's own calibration of the same family"},
        "limits_configured": bool(limits), "verdicts": verdicts, "all_passed": all_passed,
    }


def format_fleet_table(results: dict[str, Any]) -> str:
    """Unit × verdict table, then the fleet summary, as text."""
    fleet = results["fleet"]
    lines = [f"{'unit':<22} {'status':<7} {'chosen':<10} {'verdict':<10} "
             f"{'fleet/own':>9}  outlier"]
    for dev, u in results["units"].items():
        luo = (u.get("leave_units_out") or {}).get("axes") or {}
        ratios = [a["ratio"] for a in luo.values() if a.get("ratio") is not None]
        r = f"{max(ratios):9.3g}" if ratios else f"{'—':>9}"
        flag = ", ".join(f"{quantity_label(f['quantity'])} z={f['z']:.1f}" for f in
                         fleet["outliers"].get(dev, [])[:2])
        lines.append(f"{dev:<22} {u.get('status', ''):<7} {str(u.get('chosen') or 'none'):<10} "
                     f"{u['limits']['verdict']:<10} {r}  {flag}")
        if u.get("status") == "failed":
            lines.append(f"{'':<22} reason: {u['reason']}")
    lines.append("")
    lines.append(f"{fleet['n_units']} units, {fleet['n_failed']} failed to calibrate; verdicts "
                 + ", ".join(f"{k} {v}" for k, v in sorted(fleet["verdicts"].items()))
                 + f"; outliers: {', '.join(fleet['outliers']) or 'none'}")
    med = fleet["leave_units_out"]["median_ratio"]
    if med:
        lines.append(f"leave-units-out ({fleet['family']}): median std ratio fleet/own "
                     + ", ".join(f"{a} {v:.3g}" for a, v in med.items()))
    return "\n".join(lines)


def plot_coefficient_spread(path: Path, results: dict[str, Any]) -> Path | None:
    """Strip plot: each coefficient's per-unit values as robust z, outliers in red."""
    quantities: dict[str, dict[str, float]] = {}
    for dev, u in results["units"].items():
        for name, v in (u.get("coefficients") or {}).items():
            quantities.setdefault(name, {})[dev] = v
    zs = {q: robust_z(v) for q, v in quantities.items()}
    zs = {q: z for q, z in zs.items() if z}
    if not zs:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    signed = zs
    fig, ax = plt.subplots(figsize=(max(4.0, 0.8 * len(signed) + 2), 4.0))
    for i, z in enumerate(signed.values()):
        vals = np.array(list(z.values()))
        jitter = np.linspace(-0.15, 0.15, len(vals)) if len(vals) > 1 else np.zeros(1)
        out = np.abs(vals) > ROBUST_Z_THRESHOLD
        ax.scatter(i + jitter[~out], vals[~out], s=12, color="tab:blue")
        ax.scatter(i + jitter[out], vals[out], s=24, color="tab:red")
    for y in (-ROBUST_Z_THRESHOLD, ROBUST_Z_THRESHOLD):
        ax.axhline(y, color="grey", lw=0.8, ls="--")
    ax.set_xticks(range(len(signed)), list(signed), rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("signed robust z = (x − median) / (1.4826·MAD)")
    ax.set_title(f"Coefficient spread over {len(results['units'])} units "
                 f"({results['fleet_family']}, T0 = {COEF_T0_C:g} °C)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def clean(obj: Any) -> Any:
    """JSON-safe plain data: non-finite floats become null, NumPy scalars Python ones."""
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean(v) for v in obj]
    return obj
