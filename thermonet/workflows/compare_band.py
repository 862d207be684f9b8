"""``thermonet compare``: the residual-drift band of each fitted family and of the per-axis
model (:mod:`thermonet.scoring.band`), from the out-of-fold residuals of the folds that chose
it.  Nothing here changes a choice or a verdict: the band is written beside them
(``results.json`` ``band``, each checkpoint's ``extra.band``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ..core.errors import ConfigError
from ..features.inputs import TEMPERATURE
from ..scoring.band import DEFAULT_LEVEL, band_from_oof
from .compare_judge import Fitted
from .compare_plan import Plan

__all__ = ["family_band", "per_axis_band"]


def _level(p: Plan) -> float | None:
    return p.cfg.band.level if p.cfg.band.level is not None else DEFAULT_LEVEL


def _no_band(p: Plan, why: str) -> dict[str, Any]:
    if p.cfg.band.level is not None:      # asked for: refused, naming the key
        raise ConfigError(f"key 'band.level': no band can be estimated: {why}")
    return {"status": "not estimated", "reason": why}


def _band(p: Plan, fitted: Sequence[Fitted | None], compensate: Sequence[bool],
          model: Any) -> dict[str, Any]:
    """The band of ``model`` whose axis ``a`` is shipped from ``fitted[a]``'s out-of-fold
    predictions (None: raw)."""
    import numpy as np

    if p.folds is None:
        return _no_band(p, f"no out-of-fold residuals ({p.fold_note or 'selection.folds is 0'})")
    # temperature where the model reads it, else its first signal (a proxy: raw counts)
    sig = TEMPERATURE if TEMPERATURE in list(model.signals) else list(model.signals)[0]
    # every part's pool is the same rows: the signal's values from a part that reads it (a
    # per-axis model's cubic at the delayed temperature reads no temperature_c itself)
    src = next((f for f in fitted if f is not None and sig in f.pool_signals), None)
    if src is None:
        return _no_band(p, f"no candidate has out-of-fold values of {sig}")
    bad = [f.result.label for f in fitted if f is not None and
           (f.oof is None or f.oof.failed is not None)]
    if bad:
        return _no_band(p, f"{bad[0]} has no out-of-fold predictions")
    col = list(model.signals).index(sig)
    lo = float(np.asarray(model.sig_lo.detach())[col])
    hi = float(np.asarray(model.sig_hi.detach())[col])
    level = _level(p)
    assert level is not None
    try:
        band = band_from_oof(plan=p.folds, targets=src.pool_targets, times=src.pool_times,
                             temps=src.pool_signals[sig],
                             oofs=[None if f is None else f.oof for f in fitted],
                             compensate=compensate, ranges=[(lo, hi)] * len(p.outputs),
                             outputs=p.outputs, level=level, bins=p.cfg.band.bins,
                             signal=sig, units=p.units)
    except ConfigError as err:
        if p.cfg.band.level is not None:
            raise
        return {"status": "not estimated", "reason": str(err)}
    # what the folds held out: a band from interleaved blocks measured interpolation only
    judged = {"leave-one-run-out": "whole runs held out",
              "excursions": "whole thermal excursions held out",
              "blocks": "interleaved blocks: interpolation between training data, not a new "
                        "excursion"}.get(p.folds.kind, p.folds.kind)
    return {"status": "ok", **band.to_json(), "judged_on": judged}


def family_band(p: Plan, f: Fitted, mask: Sequence[bool]) -> dict[str, Any]:
    """One family's band (its own out-of-fold residuals, its compensate mask)."""
    return _band(p, [f] * len(p.outputs), mask, f.model)


def per_axis_band(p: Plan, fitted: Mapping[str, Fitted], owners: Mapping[str, str | None],
                  model: Any) -> dict[str, Any]:
    """The per-axis model's band: each axis from its owner's out-of-fold residuals (an axis
    no part owns: the raw drift's)."""
    own = [None if owners[a] is None else fitted[owners[a]] for a in p.outputs]  # type: ignore[index]
    if all(f is None for f in own):
        return {"status": "not estimated", "reason": "every axis is raw"}
    return _band(p, own, [f is not None for f in own], model)
