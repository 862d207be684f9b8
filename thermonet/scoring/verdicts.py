"""Offset-free scores, block-bootstrap verdicts, per-axis do-no-harm and the tie rule.

The score
---------
What a thermal model can remove is the *temperature-dependent* error, not a
constant offset (a gyro's turn-on bias, gravity's projection on an
accelerometer, a tilt).  The score of a series of errors :math:`e` on held-out
data is therefore its spread about its mean:

.. math::

    S(e) = \\sqrt{\\frac{\\sum_b \\sum_{i \\in b} (e_i - \\bar e_f)^2}{\\sum_b n_b}}

with :math:`b` the contiguous held-out blocks and :math:`\\bar e_f` the mean
of the held-out set of split fold :math:`f` (one held-out run, or the held-out
time blocks of a time-block split).  The mean is removed once per held-out set,
*not* per block and not per run of a stacked set: the blocks of a time-block
split each cover a narrow slice of temperature, and the runs of a soak-by-soak
recording (BMI270: one file at 13 °C, one at 48 °C) are each isothermal — a mean
per block or per run would remove exactly the drift a model is there to remove.

The raw score is :math:`S` of the uncompensated target (output − reference),
the compensated score :math:`S` of the residual after the model.  Their ratio
:math:`S_{comp} / S_{raw}` is < 1 when the model removes temperature-dependent
error.  Selection, do-no-harm, verdicts and plots all use it; the offset is
reported separately (``offset_raw``, ``offset_comp``) where the reference makes
an absolute offset meaningful.

Blocks and the bootstrap
------------------------
A held-out set is cut into contiguous blocks: at time gaps (the held-out
blocks of a time-block split, bursts) and, where that gives fewer than
:data:`MIN_BLOCKS`, each contiguous stretch into pieces of about ``n /
MIN_BLOCKS`` samples.  A non-overlapping block bootstrap (Carlstein) draws
:data:`RESAMPLES` sets of as many blocks with replacement, seeded
(:data:`SEED`), and the same draws serve every family (paired comparisons).
Per draw the ratio is :math:`\\sqrt{\\sum_b c_b\\,SS^{comp}_b / \\sum_b c_b\\,SS^{raw}_b}`
with :math:`c_b` the draw's block counts and :math:`SS_b` the block's sum of
squares about the fold mean.  The interval is the 95 % percentile interval
(2.5th and 97.5th percentiles, :data:`LEVEL`).

Verdicts
--------
``better`` when the whole interval of the ratio lies below 1, ``worse`` when
it lies above 1, ``indistinguishable`` otherwise.  Against the baseline family
the ratio is :math:`S_{family} / S_{baseline}` on the same draws.

Per-axis do-no-harm and ties
----------------------------
An axis is compensated by a family only where that family's *validation*
verdict against raw is ``better``; elsewhere the model leaves it alone (drift 0)
and the family's validation score counts 1 there.  A family's validation score
is the mean over axes of those (masked) ratios.  Families whose validation
score lies within one standard error of the best's (the SE of their paired difference over
the shared draws) are tied with it; among them the one with the fewest parameters is chosen
(the one-standard-error rule, :func:`one_se`: the one rule of every choice).

Decisions that do not depend on the CPU
---------------------------------------
Every decision above compares floats: a score with 1, a score with another, a
score with an interval's edge.  The float32 evaluation differs between CPUs in its
last bits (vector width, fused multiply-add, the math library's dispatch), so two
scores that are equal in exact arithmetic — the ``poly3`` family and the cubic
baseline are the same model — differ by rounding, and a plain ``<`` would let the
instruction set choose.  Every comparison therefore goes through :func:`below`,
:func:`above` and :func:`same` with the relative margin :data:`DECISION_RTOL`
(1e-4, a hundred times the float32 residual's rounding on a fit that removes 99 %
of the drift): a difference inside it is *no* difference, and a documented rule
settles it — ``better``/``worse`` need the interval clear of 1 by the margin;
among scores within the margin of each other the fewest parameters win, then the
family listed first in the config (never the last bits, never the name).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..core.recording import contiguous_segments

__all__ = [
    "MIN_BLOCKS", "RESAMPLES", "LEVEL", "SEED", "BlockStats", "block_labels", "block_stats",
    "pool", "draws", "ratio_interval", "verdict_of", "masked_scores", "choose", "one_se",
    "Choice",
    "DECISION_RTOL", "same", "below", "above",
    "apply_compensate_mask", "VerdictName",
]

VerdictName = Literal["better", "worse", "indistinguishable"]

#: A held-out set is cut into at least this many contiguous blocks for the bootstrap.
MIN_BLOCKS = 20
#: Bootstrap resamples.
RESAMPLES = 1000
#: Coverage of the percentile interval.
LEVEL = 0.95
#: Seed of the bootstrap draws (the same draws for every family: paired comparisons).
SEED = 0


def block_labels(time_s: np.ndarray, *, min_blocks: int = MIN_BLOCKS) -> np.ndarray:
    """Contiguous block index of every held-out sample.

    Cut at time gaps (:func:`thermonet.features.inputs.contiguous_segments`), then each
    stretch longer than ``ceil(n / min_blocks)`` samples into nearly equal pieces.

    Parameters
    ----------
    time_s : ndarray, shape (n,)
        Sample times of one held-out set, s.
    min_blocks : int
        Wanted number of blocks (fewer only when there are fewer samples).

    Returns
    -------
    ndarray of int, shape (n,)
        Block index, 0 … B−1, non-decreasing.
    """
    t = np.asarray(time_s, dtype=np.float64)
    n = t.size
    labels = np.empty(n, dtype=np.int64)
    size = max(1, math.ceil(n / max(min_blocks, 1)))
    nxt = 0
    for seg in contiguous_segments(t):
        m = seg.stop - seg.start
        k = max(1, math.ceil(m / size))
        labels[seg] = nxt + (np.arange(m) * k) // max(m, 1)
        nxt += k
    return labels


@dataclass
class BlockStats:
    """Per-block sums of one held-out set (or several folds' sets, pooled).

    ``n`` (B,) samples per block; ``ss_raw`` and ``ss_comp`` (B, A) sums of
    squares about the fold mean of the raw error and of the residual;
    ``sum_raw`` and ``sum_comp`` (A,) plain sums (for the offsets).
    """

    n: np.ndarray
    ss_raw: np.ndarray
    ss_comp: np.ndarray
    sum_raw: np.ndarray
    sum_comp: np.ndarray

    @property
    def score_raw(self) -> np.ndarray:
        """(A,) offset-free score of the raw error, units of the output."""
        return np.sqrt(self.ss_raw.sum(0) / max(self.n.sum(), 1))

    @property
    def score_comp(self) -> np.ndarray:
        """(A,) offset-free score of the residual, units of the output."""
        return np.sqrt(self.ss_comp.sum(0) / max(self.n.sum(), 1))

    @property
    def offset_raw(self) -> np.ndarray:
        return self.sum_raw / max(self.n.sum(), 1)

    @property
    def offset_comp(self) -> np.ndarray:
        return self.sum_comp / max(self.n.sum(), 1)


def block_stats(raw: np.ndarray, pred: np.ndarray, labels: np.ndarray, *,
                weight: np.ndarray | None = None, within_ss: np.ndarray | None = None,
                within_ss_comp: np.ndarray | None = None) -> BlockStats:
    """Block sums of one fold's held-out set.

    Parameters
    ----------
    raw : ndarray, shape (n, A)
        Uncompensated error (the target), units of each output.
    pred : ndarray, shape (n, A)
        The model's drift; the residual is ``raw - pred``.
    labels : ndarray of int, shape (n,)
        :func:`block_labels` of the set.
    weight, within_ss : ndarray, shapes (n,) and (n, A), optional
        Where each row is the mean of ``weight`` samples (a reduced recording,
        :mod:`thermonet.features.windows`) with ``within_ss`` the sum of squares of the
        target about that mean inside the row: the sums are those of the samples,

        .. math:: SS_b = \\sum_{k \\in b} w_k (\\bar e_k - \\mu)^2 + S_k, \\qquad
                  \\mu = \\frac{\\sum_k w_k \\bar e_k}{\\sum_k w_k},

        with :math:`S_k` the residual's own spread inside the row for the residual
        (``within_ss_comp``, :func:`thermonet.training.pipeline.residual_spread`; default:
        the target's).
    """
    raw = np.asarray(raw, dtype=np.float64)
    comp = raw - np.asarray(pred, dtype=np.float64)
    nb = int(labels.max()) + 1 if labels.size else 0
    w = np.ones(raw.shape[0]) if weight is None else np.asarray(weight, dtype=np.float64)

    def inside(s: np.ndarray | None) -> np.ndarray:
        out = np.zeros((nb, raw.shape[1]))
        if s is not None:
            np.add.at(out, labels, np.asarray(s, dtype=np.float64))
        return out

    def ss(e: np.ndarray, extra: np.ndarray) -> np.ndarray:
        mean = e.mean(axis=0) if weight is None else \
            (w[:, None] * e).sum(0) / max(float(w.sum()), 1e-300)
        c = e - mean
        out = np.zeros((nb, e.shape[1]))
        np.add.at(out, labels, c * c if weight is None else w[:, None] * c * c)
        return out + extra

    def total(e: np.ndarray) -> np.ndarray:
        return e.sum(0) if weight is None else (w[:, None] * e).sum(0)

    return BlockStats(n=np.bincount(labels, weights=w, minlength=nb).astype(np.float64),
                      ss_raw=ss(raw, inside(within_ss)),
                      ss_comp=ss(comp, inside(within_ss if within_ss_comp is None
                                              else within_ss_comp)), sum_raw=total(raw),
                      sum_comp=total(comp))


def pool(stats: Sequence[BlockStats]) -> BlockStats:
    """Several folds' block sums as one set of blocks (each fold keeps its own mean)."""
    return BlockStats(n=np.concatenate([s.n for s in stats]),
                      ss_raw=np.concatenate([s.ss_raw for s in stats]),
                      ss_comp=np.concatenate([s.ss_comp for s in stats]),
                      sum_raw=np.sum([s.sum_raw for s in stats], axis=0),
                      sum_comp=np.sum([s.sum_comp for s in stats], axis=0))


@functools.lru_cache(maxsize=64)
def draws(n_blocks: int, *, resamples: int = RESAMPLES, seed: int = SEED) -> np.ndarray:
    """(resamples, n_blocks) block counts of the bootstrap draws; the same for every family.

    Drawn once per (n_blocks, resamples, seed) in a process and shared (read-only): every
    selection, tuning grid and verdict of a comparison — a calibration's dozens — draws
    the same counts (1.5 ms each time)."""
    rng = np.random.default_rng(seed)
    out = rng.multinomial(n_blocks, np.full(n_blocks, 1.0 / n_blocks), size=resamples
                          ).astype(np.float64)
    out.setflags(write=False)
    return out


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt(num / den)


def ratio_interval(ss_num: np.ndarray, ss_den: np.ndarray, counts: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point ratio, and the bootstrap ratios, of two block sum-of-squares sets.

    Returns
    -------
    ratio : ndarray, shape (A,)
        :math:`\\sqrt{\\sum SS_{num} / \\sum SS_{den}}`.
    boot : ndarray, shape (R, A)
        The same per bootstrap draw.
    interval : ndarray, shape (2, A)
        Percentile interval at :data:`LEVEL`.
    """
    ratio = _ratio(ss_num.sum(0), ss_den.sum(0))
    boot = _ratio(counts @ ss_num, counts @ ss_den)
    q = 100.0 * (1.0 - LEVEL) / 2.0
    interval = np.nanpercentile(boot, [q, 100.0 - q], axis=0) if np.isfinite(boot).any() \
        else np.full((2, ratio.size), np.nan)
    return ratio, boot, np.asarray(interval)


#: Relative margin inside which two scores (or a score and 1) count as equal: see the module
#: docstring, "Decisions that do not depend on the CPU".
DECISION_RTOL = 1e-4


def same(a: float, b: float, rtol: float = DECISION_RTOL) -> bool:
    """``a`` and ``b`` are equal for every decision: within ``rtol`` of the larger magnitude."""
    return abs(a - b) <= rtol * max(abs(a), abs(b))


def below(a: float, b: float, rtol: float = DECISION_RTOL) -> bool:
    """``a < b`` by more than the decision margin (false for NaN)."""
    return bool(a < b) and not same(a, b, rtol)


def above(a: float, b: float, rtol: float = DECISION_RTOL) -> bool:
    """``a > b`` by more than the decision margin (false for NaN)."""
    return bool(a > b) and not same(a, b, rtol)


def verdict_of(low: float, high: float) -> VerdictName:
    """``better`` if the interval lies below 1, ``worse`` above 1, else ``indistinguishable``.

    "Below" and "above" by more than :data:`DECISION_RTOL`: an interval edge at 1 up to
    rounding is ``indistinguishable`` on every CPU.
    """
    if math.isfinite(high) and below(high, 1.0):
        return "better"
    if math.isfinite(low) and above(low, 1.0):
        return "worse"
    return "indistinguishable"


def masked_scores(ratio: np.ndarray, boot: np.ndarray, compensate: np.ndarray
                  ) -> tuple[float, np.ndarray]:
    """A family's validation score and bootstrap draws: mean over axes, 1 where uncompensated."""
    keep = np.asarray(compensate, dtype=bool)
    point = float(np.mean(np.where(keep, ratio, 1.0)))
    per_draw = np.where(keep[None, :], boot, 1.0).mean(axis=1)
    return point, per_draw


@dataclass(frozen=True)
class Choice:
    """What :func:`one_se` decided.

    ``chosen``: the candidate that ships (None: ``status`` says why); ``best``: the lowest
    score (ties within the decision margin: the fewest parameters, then the first listed);
    ``tied``: the candidates within one standard error of the best, the chosen first (empty
    when it stands alone); ``diff``/``se``: per finite candidate, its score minus the best's
    and the standard error of their paired difference; ``blocked``: per candidate left out
    before the rule (held back by the caller, or below the caller's floor), why."""

    chosen: str | None
    best: str | None
    status: Literal["ok", "no candidate", "no harm"]
    tied: list[str]
    diff: dict[str, float]
    se: dict[str, float]
    blocked: dict[str, str]


def one_se(scores: Mapping[str, float], boots: Mapping[str, np.ndarray] | None,
           n_params: Mapping[str, int], *, held: Mapping[str, str] | None = None,
           floor: Callable[[str], str] | None = None, raw: float | None = 1.0,
           keep: str | None = None) -> Choice:
    """The one choice rule, for every scope — the whole recording and each axis out of fold
    (:func:`thermonet.scoring.selection.select`), the single validation part (:func:`choose`),
    the sensor model and the fleet's units.

    1. Candidates with a finite score, less those ``held`` back (candidate → why).
    2. The best: the lowest score (scores within the decision margin are one score: the
       fewest parameters, then the candidate listed first).
    3. Do no harm: nothing unless the best beats raw (its score below ``raw``: 1 for a score
       ratio to raw; None where the scores are no ratios to raw and no do-no-harm applies).
    4. One standard error: every candidate below ``raw`` whose score is within one SE of the best's
       — the SE of their *paired* difference over the shared bootstrap draws ``boots``
       (None: no draws, only scores the same as the best's) — and that ``floor`` does not
       block (a reason string, e.g. worse than the baseline on an axis; never the best).
    5. Among them ``keep`` (the baseline, where the gate holds it: a challenger must beat it
       by more than one SE — a simpler one too), else the fewest parameters, then the lowest
       score, then the first listed.
    """
    order = {k: i for i, k in enumerate(scores)}
    finite = {k: float(v) for k, v in scores.items() if math.isfinite(float(v))}
    blocked = {k: why for k, why in (held or {}).items() if k in finite}
    pool_ = {k: v for k, v in finite.items() if k not in blocked}
    if not pool_:
        return Choice(None, None, "no candidate", [], {}, {}, blocked)
    low = min(pool_.values())
    best = min((k for k, v in pool_.items() if same(v, low)), key=lambda k: (n_params[k], order[k]))
    if raw is not None and not below(pool_[best], raw):
        return Choice(None, best, "no harm", [], {}, {}, blocked)
    diff: dict[str, float] = {}
    se: dict[str, float] = {}
    eligible = []
    for k, v in finite.items():
        se[k] = (float(np.nanstd(np.asarray(boots[k]) - np.asarray(boots[best])))
                 if boots is not None and k != best else 0.0)
        diff[k] = v - finite[best]
        if k in blocked:
            continue
        why = "" if k == best or floor is None else floor(k)
        if why:
            blocked[k] = why
        elif (raw is None or below(v, raw)) and (diff[k] <= se[k] or same(v, finite[best])):
            eligible.append(k)
    fewest = min(n_params[k] for k in eligible)
    cands = [keep] if keep in eligible else [k for k in eligible if n_params[k] == fewest]
    low_c = min(finite[k] for k in cands)
    chosen = min((k for k in cands if same(finite[k], low_c)), key=lambda k: order[k])
    rest = sorted((k for k in eligible if k != chosen),
                  key=lambda k: (n_params[k], finite[k], order[k]))
    return Choice(chosen, best, "ok", [chosen, *rest] if rest else [], diff, se, blocked)


def choose(scores: dict[str, tuple[float, np.ndarray]], n_params: dict[str, int]
           ) -> tuple[str | None, list[str], str]:
    """The single validation part's choice (:func:`one_se` on its block-bootstrap draws): the
    chosen family, the families tied with it, and why.

    Parameters
    ----------
    scores : dict
        Family label → (validation score, its bootstrap draws) from :func:`masked_scores`
        (the same block counts for every family: paired).
    n_params : dict
        Family label → trained parameter count.

    Returns
    -------
    chosen : str or None
        None when no family beats raw on any axis (do no harm).
    tied : list of str
        Families within one standard error of the best one (the chosen first), when more
        than one.
    reason : str
    """
    c = one_se({k: v[0] for k, v in scores.items()}, {k: v[1] for k, v in scores.items()},
               n_params)
    if c.status == "no candidate":
        return None, [], "no family could be fitted"
    if c.chosen is None:
        return None, [], ("do no harm: no family beats the raw output on any axis of the "
                          f"validation data (best {c.best}: score ratio "
                          f"{scores[str(c.best)][0]:.3g})")
    score = scores[c.chosen][0]
    if c.tied:
        return c.chosen, c.tied, (
            f"tie: {', '.join(c.tied)} within one SE of the best on the validation data "
            f"({c.best}: {scores[str(c.best)][0]:.3g}); chose the fewest parameters "
            f"({c.chosen}, {n_params[c.chosen]} params, score {score:.3g})")
    return c.chosen, [], f"lowest validation score ratio ({score:.3g} of raw)"


def apply_compensate_mask(model: object, compensate: Sequence[bool]) -> bool:
    """Leave the axes where ``compensate`` is false uncompensated (drift 0) in ``model``.

    Uses the model's ``set_compensate`` (or sets its ``compensate`` buffer: a
    per-axis mask the exports carry) when the model has one and returns True;
    returns False when it has none, in which case the mask lives only in
    ``results.json`` and the checkpoint's extra data (``compensate``).
    """
    import torch

    setter = getattr(model, "set_compensate", None)
    if callable(setter):  # the DriftModel's own validated setter
        setter(list(compensate))
        return True
    buf = getattr(model, "compensate", None)
    if not isinstance(buf, torch.Tensor):
        return False
    with torch.no_grad():
        buf.copy_(torch.as_tensor(list(compensate), dtype=buf.dtype))
    return True
