"""The one split pipeline: parts → fit → score, run by compare, fleet and the Python API.

One split (:class:`thermonet.training.splits.Split`: training runs, a validation run or
none, a held-out run) is a family fitted on the training runs (stopping early on the
validation run where there is one) and judged on the held-out run.  "Fold" in thermonet means
only a cross-validation fold (:mod:`thermonet.scoring.folds`); a comparison's folds each run
this pipeline on their own training and validation data.  It imports the fit
(:mod:`thermonet.training.train`, torch) at the top: this module is on the torch side of the
boundary (pyproject.toml's import-linter contract), and its callers load it where they fit:

1. :func:`split_spec` — the feature references (:math:`T_{ref}`, proxy references) and the
   dynamic inputs' gap limit, from the training runs only;
2. :func:`split_parts` — each run's signal and target matrices (:mod:`thermonet.training.parts`),
   the training runs cut to their heating samples for ``train_on: heating``;
3. :func:`fit_split` — the family fitted (:func:`thermonet.training.train.fit`) on the
   training parts, each averaged into ``train.average_s`` windows once (a part's windows
   are cached on it and shared by the families of a comparison);
4. :func:`score_part` and :func:`block_sums` — a held-out part's per-axis metrics and its
   per-block sums, what the verdicts (:mod:`thermonet.scoring.verdicts`) are drawn from.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..core.recording import Recording
from ..core.trainconfig import TrainConfig
from ..features.inputs import FeatureSpec, reference_values, resolve_gap_s, signals_for
from ..features.target import FOUR_POSITION, Target
from ..scoring.axis_metrics import axis_metrics, window_axis_metrics
from ..scoring.metrics import rms, scale_factor_tempco_ppm_per_c
from ..scoring.verdicts import block_labels, block_stats
from .parts import Part, build_part, fit_arrays, heating_keep, heating_only, join_parts, rows_of
from .train import fit, predict

__all__ = ["SplitParts", "PartBuilder", "split_spec", "split_parts", "fit_split", "score_part",
           "block_sums", "per_soak_metrics", "residual_spread"]

#: ``(recording, signals, gap_s) -> Part``: how a split gets a run's part (compare shares
#: one cache between its families).
PartBuilder = Callable[[Recording, list[str], "float | None"], Part]


def split_spec(inputs: Sequence[str], train: Sequence[Recording], *, t_ref: str | float = "start",
              window_min: float = 10.0, gap_s: str | float | None = "auto",
              reference_for_targets: bool = False) -> FeatureSpec:
    """The feature spec of a split: references and gap limit from its training runs.

    ``reference_for_targets``: compute :math:`T_{ref}` also for a model on the absolute
    temperature alone (``T``) — a comparison's at-t-ref targets are normalised there.
    """
    ref_inputs = list(inputs)
    if reference_for_targets and "temperature_c" in signals_for(inputs):
        ref_inputs.append("dT")
    t_value, proxy_ref = reference_values(train, ref_inputs, t_ref=t_ref, window_min=window_min)
    return FeatureSpec(inputs=list(inputs), t_ref=t_value, proxy_ref=proxy_ref,
                       gap_s=resolve_gap_s(gap_s, train, inputs))


@dataclass
class SplitParts:
    """The parts of one split: training parts, the validation part (or None) and the test
    part (or None)."""

    spec: FeatureSpec
    train: list[Part]
    val: Part | None = None
    test: Part | None = None


def split_parts(spec: FeatureSpec, train: Sequence[Recording], *, outputs: list[str],
               target: Target | str, val: Recording | None = None,
               test: Recording | None = None, train_on: str = "all",
               gap_s: str | float | None = "auto", part: PartBuilder | None = None,
               whole: Sequence[tuple[Recording, np.ndarray]] = ()) -> SplitParts:
    """Each run's part for ``spec``; with ``train_on == "heating"`` the training parts keep
    the samples where the temperature is not falling (its rate's gap limit from
    ``gap_s``, the configured setting, as the dynamic inputs').

    ``whole`` (a time-block split's :attr:`~thermonet.training.splits.Split.whole`): the
    parts are built on each whole run and cut into its training (roles 0, 1, 3), validation
    (2) and test (4) rows, so that a dynamic input's state at a block's first row is carried
    in from the rows before it, as the board computes it (the carved ``train``, ``val`` and
    ``test`` recordings would restart it at every block)."""
    if part is None:
        def part(rec: Recording, signals: list[str], gap: float | None) -> Part:
            return build_part(rec, signals=signals, outputs=outputs, target=target, gap_s=gap)

    gap = spec.gap_s
    per_soak = target == FOUR_POSITION if isinstance(target, str) else \
        target.kind == FOUR_POSITION
    if whole and not per_soak:      # a four-position part has a row per soak, not per sample
        return _whole_run_parts(spec, whole, part, train_on, gap_s)
    train_parts = [part(r, spec.signals, gap) for r in train]
    if train_on == "heating":
        heat_gap = resolve_gap_s(gap_s, train, ["rate"])
        train_parts = [heating_only(q, r, heat_gap) for q, r in zip(train_parts, train, strict=True)]
    return SplitParts(spec=spec, train=train_parts,
                     val=part(val, spec.signals, gap) if val is not None else None,
                     test=part(test, spec.signals, gap) if test is not None else None)


def _whole_run_parts(spec: FeatureSpec, whole: Sequence[tuple[Recording, np.ndarray]],
                     part: PartBuilder, train_on: str, gap_s: str | float | None
                     ) -> SplitParts:
    """:func:`split_parts` of a time-block split: each whole run's part cut by role."""
    runs = [r for r, _ in whole]
    parts = [part(r, spec.signals, spec.gap_s) for r in runs]
    heat_gap = resolve_gap_s(gap_s, runs, ["rate"]) if train_on == "heating" else None
    train, val, test = [], [], []
    for (rec, role), q in zip(whole, parts, strict=True):
        keep = np.isin(role, (0, 1, 3))
        if train_on == "heating":
            keep &= heating_keep(rec, heat_gap)
        train.append(rows_of(q, keep))
        val.append(rows_of(q, role == 2))
        test.append(rows_of(q, role == 4))
    return SplitParts(spec=spec, train=train, val=join_parts(val), test=join_parts(test))


def fit_split(parts: SplitParts, *, family: str, outputs: list[str], hyper: dict | None,
             config: TrainConfig, target_modes: Sequence[str] | None = None,
             on_epoch: Callable[[int, float, float | None], None] | None = None,
             val: tuple[np.ndarray, ...] | None = None, windows: bool = True) -> Any:
    """Fit ``family`` on a split's training parts, stopping early on its validation part
    (or on ``val``, arrays given whole); returns the :class:`~thermonet.training.train.FitResult`.

    ``windows``: each part goes with its time, averaged into ``config.average_s`` windows
    (once per part and window length); False gives the arrays without time, so the fit
    thins them to its sample budget instead (the fleet's pooled model).
    """
    spec = parts.spec
    if windows:
        avg = config.average_s
        train = [fit_arrays(q, avg) for q in parts.train]
        if val is None and parts.val is not None:
            val = fit_arrays(parts.val, avg)
        config = replace(config, average_s=0.0)  # already averaged: fit applies the budget
    else:
        train = [(q.signals, q.target) for q in parts.train]
        if val is None and parts.val is not None:
            val = (parts.val.signals, parts.val.target)
    return fit(family=family, inputs=list(spec.inputs), outputs=outputs, train=train, val=val,
               spec=spec, hyper=dict(hyper or {}), config=config, on_epoch=on_epoch,
               target=target_modes)


def per_soak_metrics(k: np.ndarray, pred: np.ndarray, temps: np.ndarray, scale: bool
                     ) -> dict[str, float]:
    """Metrics of per-soak four-position estimates (study 000).

    Bias K0: the raw error is K0 itself, compensated K0 − K̂0.  Scale factor
    K1: its nominal value is no error, so raw is K1 − mean(K1); compensated
    is K1 − K̂1(T) (+ mean(K1) for the ppm/°C coefficient, which needs the
    nominal scale factor in its denominator).
    """
    nominal = float(np.mean(k)) if scale else 0.0
    raw, comp = k - nominal, k - pred
    m = {"rms_raw": rms(raw), "rms_comp": rms(comp), "pp_raw": float(np.ptp(raw)),
         "pp_comp": float(np.ptp(comp)), "msd_raw": float(np.mean(raw ** 2)),
         "msd_comp": float(np.mean(comp ** 2))}
    if scale:
        m["ppm_per_c_raw"] = scale_factor_tempco_ppm_per_c(temps, k)
        m["ppm_per_c_comp"] = scale_factor_tempco_ppm_per_c(temps, comp + nominal)
    return m


def residual_spread(model: Any, part: Part) -> np.ndarray | None:
    """Per row and axis of a part of window means, the residual's sum of squares about its
    mean inside the row, to first order in the signals' spread there (None for a part of
    samples; the target's own where the co-moments are not known):

    .. math:: S_{rr} = S_{yy} - 2\\, J^\\top S_{xy} + J^\\top S_{xx} J,

    :math:`J` the model's slope in each signal at the row's means, by central differences
    one pooled within-window standard deviation of that signal to each side.  The drift
    that moves inside a window with the temperature (a fast ramp, a low-noise sensor) is
    thus taken out of the residual as the model takes it out of the samples.
    """
    if part.within_ss is None or part.weight is None:
        return None
    if part.within_sxx is None or part.within_sxy is None:
        return part.within_ss
    n_sig = part.signals.shape[1]
    dof = max(float(np.clip(part.weight - 1.0, 0.0, None).sum()), 1.0)
    slope = np.zeros((part.signals.shape[0], n_sig, part.within_ss.shape[1]))
    for s in range(n_sig):
        h = float(np.sqrt(max(float(part.within_sxx[:, s, s].sum()) / dof, 0.0)))
        if not h > 0:
            continue
        up, down = part.signals.copy(), part.signals.copy()
        up[:, s] += h
        down[:, s] -= h
        slope[:, s, :] = (predict(model, up, part.time_s)
                          - predict(model, down, part.time_s)) / (2.0 * h)
    cross = np.einsum("nsa,nsa->na", slope, part.within_sxy)
    quad = np.einsum("nsa,nst,nta->na", slope, part.within_sxx, slope)
    return np.maximum(part.within_ss - 2.0 * cross + quad, 0.0)


def score_part(model: Any, part: Part, spread: np.ndarray | None = None
               ) -> tuple[np.ndarray, dict[str, dict[str, float]]]:
    """The model's predicted drift on a held-out part and the per-axis metrics (``spread``:
    :func:`residual_spread` of the part, where the caller has it already)."""
    pred = predict(model, part.signals, part.time_s)
    if spread is None:
        spread = residual_spread(model, part)
    out: dict[str, dict[str, float]] = {}
    for j, axis in enumerate(part.outputs):
        if part.per_soak:
            m = per_soak_metrics(part.target[:, j], pred[:, j], part.bin_by,
                                 scale=axis.endswith(".scale"))
        elif part.weight is not None and part.within_ss is not None and spread is not None:
            m = window_axis_metrics(   # rows: window means
                bin_by=part.bin_by, raw=part.target[:, j], predicted_drift=pred[:, j],
                weight=part.weight, within_ss=part.within_ss[:, j],
                within_ss_comp=spread[:, j],
                true_drift=None if part.true_drift is None else part.true_drift[:, j],
                rate_hz=part.rate_hz, bin_width=part.bin_width)
        else:
            raw = part.target[:, j]
            m = axis_metrics(
                bin_by=part.bin_by, time_s=part.time_s, raw=raw,
                reference=np.zeros_like(raw), predicted_drift=pred[:, j],
                true_drift=None if part.true_drift is None else part.true_drift[:, j],
                rate_hz=part.rate_hz, bin_width=part.bin_width)
        out[axis] = {k: float(v) for k, v in m.items()}
    return pred, out


def block_sums(part: Part, pred: np.ndarray, spread: np.ndarray | None = None) -> Any:
    """Block sums of one held-out part (:class:`~thermonet.scoring.verdicts.BlockStats`):
    raw error = the target, residual = target − drift (of a part of window means: the
    residual's spread inside each row is ``spread``, the model's :func:`residual_spread`;
    the target's own without it)."""
    raw = part.target.copy()
    for j in range(len(part.outputs)):
        if part.offset_free(j):  # a scale factor's nominal value, gravity (at-t-ref): no error
            raw[:, j] -= np.average(raw[:, j], weights=part.weight)
    if spread is None:
        spread = part.within_ss
    return block_stats(raw, pred - (part.target - raw), block_labels(part.time_s),
                       weight=part.weight, within_ss=part.within_ss, within_ss_comp=spread)
