"""The gate (:data:`GATE_RULE`): the baseline (the cubic) stays on an axis until a candidate
beats it everywhere — better overall with a worst held-out fold no worse than the
baseline's, judged on at least :data:`MIN_GATE_FOLDS` folds (on two, by
:data:`TWO_FOLD_MARGIN` on each); a candidate reading the
direction of change ships only where held-out excursions of both directions judged it, and
nothing replaces the baseline on interleaved blocks (:func:`held_back`).  What the gate reads
per candidate and fold is a :class:`Gate`; :mod:`thermonet.scoring.selection` applies it
before the one choice rule (:func:`thermonet.scoring.verdicts.one_se`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import counted
from .fold_plan import (
    MEMORY_STEP,
    MIN_GATE_FOLDS,
    RATE_SPREAD,
    TWO_FOLD_MARGIN,
    FoldPlan,
    memory_judgeable,
    rate_spread,
)
from .folds import DIRECTION_NAMES
from .verdicts import DECISION_RTOL, above, below

if TYPE_CHECKING:
    from .oof_pool import CandidateOOF, Pooled

__all__ = ["MIN_GATE_FOLDS", "RATE_SPREAD", "TWO_FOLD_MARGIN", "GATE_RULE", "Gate",
           "one_direction", "one_rate", "worst_fold_not_worse", "clear_on_each",
           "beats_in_every_fold", "base_worse_than_raw", "pp_not_worse_note", "gate_axis",
           "gate_note", "held_back", "held_back_record", "reason_groups"]


#: The gate, as results.json and the report state it.
GATE_RULE = ("the baseline stays until beaten everywhere: a candidate replaces it on an axis "
             f"only if it was judged on at least {MIN_GATE_FOLDS} folds, its out-of-fold ratio "
             "is lower overall, and its worst fold is no worse than the baseline's worst fold "
             f"(on the same folds; ties within {DECISION_RTOL:g} are not worse); judged on two "
             f"folds only (two runs), it must be at least {1 - TWO_FOLD_MARGIN:.0%} better on "
             "each; where the baseline is within one standard error of the best, it stays (a "
             "simpler candidate does not replace it for its simplicity); a model reading "
             "the direction of change must also have been judged on held-out excursions of both "
             "directions and the training data must ramp at two rates or more (their 90th "
             f"percentile at least {RATE_SPREAD:g}x the 10th) — at one rate only a step toward "
             f"memory (at most {MEMORY_STEP:.2g} of its drift read from it) is judged; where the "
             "folds are interleaved "
             "blocks (no excursion could be held out) the baseline is not replaced; where the "
             "baseline is worse than raw out of fold (its score not below 1 and its interval "
             "above 1 or its binned peak-to-peak larger than raw's), raw is the reference")


def one_direction(directions: Sequence[int]) -> str:
    """Why a direction-carrying candidate cannot be judged ("" where the pool holds heating
    and cooling)."""
    if len(set(directions)) >= 2:
        return ""
    if not directions:
        return ("the training data hold no heating or cooling excursion (soaks only): a model "
                "reading the rate, a lag, a delayed temperature or a hysteresis memory cannot be "
                "judged on one")
    held, other = DIRECTION_NAMES[directions[0]], DIRECTION_NAMES[-directions[0]]
    return (f"the training data hold only {held}: a model reading the rate, a lag, a delayed "
            f"temperature or a hysteresis memory cannot be judged on {other}, so it does not "
            "ship over a static model")


def one_rate(rates: Sequence[float]) -> str:
    """Why a candidate with memory cannot be judged at another ramp rate ("" where the pool's
    ramp rates spread by :data:`RATE_SPREAD` or more, :func:`rate_spread`).  A lag's error
    grows with the rate and a
    hysteresis' does not: at one rate the two are the same correction, and which one the
    sensor has decides whether the model helps or harms at the next rate (``stress-imu``: a
    cubic at the delayed temperature fitted on one fast cycle was 0.24–0.48× the cubic's
    error on four axes of a slow cycle and 1.34–1.43× on ``gyro_x``, whose hysteresis it
    took for lag; ``bench_selection.py --stress``)."""
    spread = rate_spread(rates)
    if spread >= RATE_SPREAD:
        return ""
    if np.isnan(spread):                # no leg whose rate could be timed
        return ("no heating or cooling leg of the training data could be timed: a model "
                "reading the rate, a lag, a delayed temperature or a hysteresis memory cannot "
                "be judged at another rate and does not ship over a static model")
    return (f"the training data ramp at one rate (their 90th percentile {spread:.2g}x the 10th, "
            f"under {RATE_SPREAD:g}x): a lag and a hysteresis cannot be told apart "
            "there, so a model reading the rate, a lag, a delayed temperature or a hysteresis "
            "memory cannot be judged at another rate and does not ship over a static model "
            f"(a step of {MEMORY_STEP:.2g} may: it is no worse than the static model at up to "
            f"{2 / MEMORY_STEP:.2g}x the rate either way)")


def worst_fold_not_worse(cand: np.ndarray, ref: np.ndarray) -> bool:
    """On the folds where both are finite (at least one), ``cand``'s worst fold is no worse
    than ``ref``'s worst fold (ties within the decision margin are not worse): the minimax
    reading of "beaten everywhere" — a challenger may trade one excursion against another, but
    its worst held-out excursion must be no worse than the baseline's."""
    both = np.isfinite(cand) & np.isfinite(ref)
    if not both.any():
        return False
    return not above(float(np.max(cand[both])), float(np.max(ref[both])))


def clear_on_each(cand: np.ndarray, ref: np.ndarray) -> bool:
    """On exactly two folds where both are finite, ``cand`` is at most
    :data:`TWO_FOLD_MARGIN` times ``ref`` on each: what two folds must show for a candidate to
    replace its reference (two runs, each the other's new excursion)."""
    both = np.isfinite(cand) & np.isfinite(ref)
    return int(both.sum()) == 2 and bool(np.all(cand[both] <= TWO_FOLD_MARGIN * ref[both]))


def beats_in_every_fold(cand: np.ndarray, ref: np.ndarray) -> bool:
    """``cand`` (per-fold ratios) is nowhere above ``ref`` (ties within the decision margin
    are not worse) on the folds where both are finite, and there is at least one."""
    both = np.isfinite(cand) & np.isfinite(ref)
    if not both.any():
        return False
    return not any(above(float(c), float(r)) for c, r in zip(cand[both], ref[both], strict=True))


@dataclass
class Gate:
    """What the gate (:data:`GATE_RULE`) reads, per candidate and fold: ``own`` (K, A), its
    masked ratio to raw on its own domain; ``pair`` (K, A, 2), its and the baseline's masked
    ratios to raw on the windows inside both domains; NaN where it was not judged on the fold
    (fewer than two rows there); ``base_judged`` (K,): the baseline was judged on the fold."""

    own: dict[str, np.ndarray]
    pair: dict[str, np.ndarray]
    base_judged: np.ndarray
    fold_directions: list[set[int]] = field(default_factory=list)
    directional: set[str] = field(default_factory=set)

    @staticmethod
    def of(pooled: Pooled, masks: Mapping[str, list[bool]], baseline: str | None,
           fold_directions: Sequence[set[int]] = ()) -> Gate:
        """The baseline's column is unmasked: on an axis where it is the reference it ships
        (it is the reference only where it is not worse than raw out of fold)."""
        A = pooled.pp_raw.size
        K = len(pooled.base_judged)
        own: dict[str, np.ndarray] = {}
        pair: dict[str, np.ndarray] = {}
        bmask = np.ones(A, dtype=bool)
        with np.errstate(divide="ignore", invalid="ignore"):
            for k, mask in masks.items():
                keep = np.array(mask)
                o = np.full((K, A), np.nan)
                pr = np.full((K, A, 2), np.nan)
                for f in range(K):
                    g = pooled.gate_own[k][f]
                    if g is not None:
                        o[f] = np.where(keep, np.sqrt(g[0] / g[1]), 1.0)
                    h = pooled.gate_pair[k][f]
                    if h is not None:
                        pr[f, :, 0] = np.where(keep, np.sqrt(h[0] / h[2]), 1.0)
                        pr[f, :, 1] = np.where(bmask, np.sqrt(h[1] / h[2]), 1.0)
                own[k], pair[k] = o, pr
        return Gate(own, pair, np.array(pooled.base_judged, dtype=bool), list(fold_directions))

    def passes(self, k: str, a: int | None, against_baseline: bool) -> bool:
        """``k`` passes the gate against its reference (:meth:`refusal` is empty)."""
        return not self.refusal(k, a, against_baseline)

    def refusal(self, k: str, a: int | None, against_baseline: bool) -> str:
        """Which condition of the gate ``k`` fails against its reference, "" where it passes:
        judged on at least :data:`MIN_GATE_FOLDS` folds (or on two, better than its reference
        by :data:`TWO_FOLD_MARGIN` on each: :func:`clear_on_each`) and nowhere worse than its
        reference on the folds where both were judged; a candidate reading the direction of
        change also judged on a held-out excursion of every direction its reference was
        judged on (a model reading the rate is not judged on heating where no fold trained it
        on heating; ``a``: one axis; None: the mean over axes).  The first condition that
        fails is named, with its figures."""
        ref = "the baseline" if against_baseline else "raw"
        if against_baseline:
            p = self.pair[k] if a is None else self.pair[k][:, a:a + 1]
            c, b = p[:, :, 0].mean(axis=1), p[:, :, 1].mean(axis=1)
            ref_judged = self.base_judged
        else:
            c = self.own[k].mean(axis=1) if a is None else self.own[k][:, a]
            b = np.ones_like(c)
            ref_judged = np.ones(c.size, dtype=bool)
        judged = np.isfinite(c) & np.isfinite(b)
        n = int(judged.sum())
        if n < MIN_GATE_FOLDS and not clear_on_each(c, b):
            if n == 2:
                return (f"judged on two folds, it is not {1 - TWO_FOLD_MARGIN:.0%} better than "
                        f"{ref} on each (on the windows both were judged on: " + ", ".join(
                            f"{x:.3g} vs {y:.3g}" for x, y in zip(c[judged], b[judged],
                                                                  strict=True)) + " of raw)")
            return f"judged on {counted(n, 'fold')}, fewer than {MIN_GATE_FOLDS}"
        if k in self.directional and self.fold_directions:
            need = set().union(*(d for d, r in zip(self.fold_directions, ref_judged,
                                                   strict=True) if r))
            have = set().union(*(d for d, j in zip(self.fold_directions, judged, strict=True)
                                 if j))
            if not need <= have:
                return ("never judged on a held-out " + " or ".join(
                    DIRECTION_NAMES[d] for d in sorted(need - have)) + " excursion")
        if not worst_fold_not_worse(c, b):
            if not judged.any():
                return "judged on no fold beside its reference"
            where = "windows both were judged on" + (", the mean over the axes" if a is None
                                                     else "")
            return (f"its worst fold ({np.max(c[judged]):.3g} of raw) is worse than {ref}'s "
                    f"worst ({np.max(b[judged]):.3g} of raw), on the {where}")
        return ""


def gate_axis(sc: dict[str, float], a: int, gate: Gate, baseline: str | None,
               directional: set[str] | frozenset[str], base_ratio: float | None = None,
               base_kept: bool = False) -> tuple[dict[str, float], list[str]]:
    """The candidates of axis ``a`` that pass the gate (the reference among them where it
    compensates), and those it held back.  ``base_ratio``: the baseline's unmasked
    out-of-fold ratio on the axis (its own domain) — it is the reference wherever that is
    below 1; ``base_kept``: the baseline's own mask (its interval reaches 1 *and* its binned
    peak-to-peak out of fold is no larger than raw's) — it is the reference there too, even
    with a ratio not below 1 (a cubic within the noise of raw stays).

    The decision (the promise: never worse than the cubic, raw only where the cubic is worse
    than raw out of fold): the cubic is worse than raw out of fold where its score does not
    beat raw's *and* its interval lies above 1 or its binned peak-to-peak is larger than
    raw's.  The peak-to-peak guard alone does not set aside a cubic whose score beats raw out
    of fold: on ``consumer-imu``'s ``gyro_x`` (hysteresis) the cubic's binned peak-to-peak
    out of fold was 1.9x raw's at 0.82 of raw by score, yet it beat raw on the held-out run
    of both seeds — raw there was worse than the cubic (``tests/test_never_worse.py``).  The
    axis's sentence says so (:func:`pp_not_worse_note`)."""
    base = baseline or ""
    if base_ratio is not None and base in sc and below(base_ratio, 1.0):
        sc = {**sc, base: min(sc[base], base_ratio)}
    base_on = base in sc and (below(sc[base], 1.0) or base_kept)
    ref_score = sc[base] if base_on else 1.0
    kept: dict[str, float] = {}
    gated: list[str] = []
    for k, v in sc.items():
        if base_on and k == baseline:
            kept[k] = v
        elif k in directional:
            gated.append(k)
        elif k in gate.own and below(v, ref_score) and gate.passes(k, a, base_on):
            kept[k] = v
        elif k != baseline:
            gated.append(k)
    return kept, gated


def base_worse_than_raw(baseline: str, ratio: np.ndarray, pp_ratio: np.ndarray | None,
                        a: int) -> str:
    """Why axis ``a`` is left raw where raw is its reference and nothing passed the gate, for
    its sentence: the baseline does not beat raw out of fold (``ratio``, per axis: on its own
    domain), with its binned peak-to-peak where that is larger than raw's too (``pp_ratio``,
    per axis: the guard of :func:`thermonet.scoring.selection.pp_guard`; None: not
    checked)."""
    pp = None if pp_ratio is None else float(pp_ratio[a])
    more = (f", its binned peak-to-peak {pp:.3g}x raw's" if pp is not None
            and math.isfinite(pp) and above(pp, 1.0) else "")
    return (f"the baseline {baseline} does not beat raw out of fold ({float(ratio[a]):.4g} of "
            f"raw{more}) and no candidate passes the gate against raw")


def pp_not_worse_note(baseline: str, pp_ratio: float | None) -> str:
    """The baseline kept on an axis where its peak-to-peak guard failed (its score beats raw
    out of fold: :func:`gate_axis`), for the axis's sentence ("" where the guard passed)."""
    if pp_ratio is None or not math.isfinite(pp_ratio) or not above(pp_ratio, 1.0):
        return ""
    return (f" [{baseline}'s binned peak-to-peak out of fold is {pp_ratio:.3g}x raw's, but its "
            "score beats raw out of fold: the baseline stays the reference]")


def gate_note(gated: list[str], directional: set[str] | frozenset[str]) -> str:
    """What the gate held back on an axis, for the rule's sentence (the reason for the held
    back ones is said once, in the selection's ``held_back``)."""
    if not gated:
        return ""
    held = [k for k in gated if k not in directional]
    parts = []
    if held:
        parts.append(f"not better everywhere: {', '.join(held)}")
    dirs = [k for k in gated if k in directional]
    if dirs:
        parts.append(f"held back: {', '.join(dirs)}")
    return " [gate: " + "; ".join(parts) + "]"


def held_back(ok: Mapping[str, CandidateOOF], baseline: str | None, plan: FoldPlan,
               gate: bool) -> dict[str, str]:
    """Per candidate the gate holds back before any score is compared, why: one reading the
    direction of change where the pool holds one direction only (:func:`one_direction`) or
    ramps at one rate (:func:`one_rate`);
    every challenger where the folds are interleaved blocks."""
    if baseline is None or not gate:
        return {}
    # the folds' purge follows the same test (fold_plan.memory_judgeable): one definition
    one_way = "" if memory_judgeable(plan.directions, plan.rates) else (
        one_direction(plan.directions) or one_rate(plan.rates))
    # one rate, both directions: a step toward memory is judged (fold_plan.MEMORY_STEP: at
    # another rate it is no worse than the static model, the sensor lagging or not)
    rate_only = bool(one_way) and not one_direction(plan.directions)
    held = {k: one_way for k, c in ok.items() if c.directional
            and not (rate_only and c.memory_share <= MEMORY_STEP + 1e-12)} if one_way else {}
    if baseline in ok and plan.kind == "blocks":
        # interleaved blocks judge interpolation between training data, never the next
        # excursion: on a heating-only ramp, static candidates that beat the cubic in five of
        # five such folds were 5–10 % worse than it on the cooling after (bench_selection.py
        # --stress); so no excursion to hold out, no challenger
        blocks = ("no excursion could be held out (the folds are interleaved blocks, which "
                  "judge interpolation, not the next warm-up): the baseline stays")
        for k in ok:
            if k != baseline:
                held[k] = f"{held[k]}; {blocks}" if k in held else blocks
    return held


def reason_groups(held: Mapping[str, str]) -> dict[str, list[str]]:
    """Each hold-back reason once (in the order first met) with the candidates it holds,
    sorted: what results.json's ``why``, the console and the report say (``held``:
    candidate -> why, results.json's ``held_back.by_candidate``)."""
    groups: dict[str, list[str]] = {}
    for k, why in held.items():
        groups.setdefault(why, []).append(k)
    return {why: sorted(ks) for why, ks in groups.items()}


def held_back_record(held: Mapping[str, str]) -> dict[str, Any]:
    """results.json's ``held_back``: the candidates, each reason once with the candidates it
    holds (``why``, one sentence per reason) and each candidate's (``by_candidate``)."""
    groups = reason_groups(held)
    if len(groups) == 1:
        why = next(iter(groups))
    else:
        why = " | ".join(f"{', '.join(ks)}: {w}" for w, ks in groups.items())
    return {"candidates": sorted(held), "why": why, "by_candidate": dict(held)}
