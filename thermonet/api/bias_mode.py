""":class:`~thermonet.api.DriftEstimator` with ``model="bias"`` (the default): a drift model per
axis (one family's :class:`~thermonet.models.drift_model.DriftModel`, or a per-axis
composite loaded from ``compare``) fitted, applied, scored, reported, saved and exported.

The estimator's methods look this module up in :data:`thermonet.api.modes.MODES` by its
``model`` (``"bias"``), as they look up :mod:`thermonet.api.sensor_mode` for
``model="sensor"``: the same functions, each kind's own bodies.  Saving, loading and
exporting are :mod:`thermonet.api.persistence`'s (the thermonet checkpoint, the format
registry :data:`thermonet.exporting.FORMATS`).
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ThermonetError
from ..core.recording import Dataset, Recording
from ..features.inputs import signal_matrix
from ..training.splits import stack_blocks
from . import persistence
from .data import BLOCK_RUN, Data, needs_outputs, runs_of, same_units
from .state import State

__all__ = ["fit", "predict", "compensate", "variances", "report", "save", "export", "load"]


def fit(est: Any, train: Data, val: Data | None, *, config: Any, inputs: list[str],
        family: Any, track: bool, tracking_uri: str | None, experiment: str) -> None:
    """Fit ``est`` on one split through the one split pipeline (arguments already checked by
    the estimator; ``family`` its spec); logged to MLflow when asked."""
    from ..training.pipeline import fit_split, split_parts, split_spec  # torch boundary

    runs, val_runs, outputs, targets = est._training_data(train, val)
    spec = split_spec(inputs, runs, t_ref=est.t_ref, window_min=est.t_ref_window_min,
                      gap_s=est.gap_s, reference_for_targets=True)
    val_rec = None
    if val_runs is not None:
        val_rec = stack_blocks(val_runs, "val") if len(val_runs) > 1 else val_runs[0]
    parts = split_parts(spec, runs, outputs=outputs, target=targets, val=val_rec,
                        train_on=est.train_on, gap_s=est.gap_s)
    result = fit_split(parts, family=family.key, outputs=outputs, hyper=family.hyper(),
                       config=config, target_modes=targets.modes)
    est._learned(result, spec, targets, outputs, runs, val_runs, config)
    est._parameter_table(parts, config)
    if track or tracking_uri:
        persistence.track(est, tracking_uri, experiment)


def predict(est: Any, data: Data, *, return_band: bool = False) -> Any:
    """Predicted drift (N, axes), float64, run after run; with ``return_band`` also the
    band's half-width per row (the estimator has checked it carries one)."""
    from ..training.train import predict as drift_of  # torch boundary

    model, band = est.model_, est.__dict__.get("band_")
    out, widths = [], []
    for rec in runs_of(data, "predict", allow_empty=True):
        # the drift needs no output channel, but one the run carries is in the drift's unit
        same_units(rec, est.units_, "predict", "the model was trained")
        same_units(rec, est.signal_units_, "predict", "the model was trained on it")
        # the model's own signal order (a per-axis model's union of its parts' signals)
        sig = signal_matrix(rec, list(model.signals), est.spec_.gap_s)
        out.append(drift_of(model, sig, rec.time_s))
        if return_band:
            assert band is not None
            col = list(model.signals).index(band.signal)
            widths.append(band.evaluate(sig[:, col], est.outputs_))
    drift = out[0] if len(out) == 1 else np.concatenate(out)
    if return_band:
        return drift, (widths[0] if len(widths) == 1 else np.concatenate(widths))
    return drift


def compensate(est: Any, data: Data) -> Any:
    """``data`` with the predicted drift subtracted from each modelled output."""
    if est.targets_.kind == "four-position":
        raise ThermonetError("compensate: a four-position model predicts per-soak bias and "
                             "scale factor, not a drift to subtract sample by sample")
    done = []
    for rec in runs_of(data, "compensate", allow_empty=True):
        needs_outputs(rec, est.outputs_, "compensate")
        same_units(rec, est.units_, "compensate", "the model was trained")
        drift = est.predict(rec)
        outputs = dict(rec.outputs)
        for j, axis in enumerate(est.outputs_):
            outputs[axis] = rec.outputs[axis] - drift[:, j]
        done.append(replace(rec, outputs=outputs, run_id=f"{rec.run_id}[compensated]"))
    if isinstance(data, Recording):
        return done[0]
    return Dataset(done) if isinstance(data, Dataset) else done


def variances(est: Any, data: Data, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Per axis, the error's sum of squares after and before (each run about its mean)."""
    from ..training.pipeline import residual_spread  # torch boundary
    from ..training.train import predict as drift_of  # torch boundary

    model = est.model_
    sums: dict[str, list[np.ndarray]] = {}     # per source run: n, Σy, Σy², Σe, Σe²
    for rec in runs_of(data, what):
        needs_outputs(rec, est.outputs_, what)
        same_units(rec, est.units_, what, "the model was trained")
        same_units(rec, est.signal_units_, what, "the model was trained on it")
        part = est._part(rec, est.spec_, est.outputs_)
        target = np.asarray(part.target, dtype=np.float64)
        err = target - drift_of(model, part.signals, part.time_s)
        acc = sums.setdefault(rec.meta.get(BLOCK_RUN, rec.run_id),
                              [np.zeros(target.shape[1]) for _ in range(5)])
        # rows that are window means (thermonet.read(..., window_s=...)): each weighs its
        # samples, and the spread inside it is added back (the target's, and the
        # residual's from the model's slope: training.pipeline.residual_spread)
        spread = residual_spread(model, part)
        if part.weight is None or part.within_ss is None or spread is None:
            terms = (np.full(target.shape[1], target.shape[0]), target.sum(0),
                     (target ** 2).sum(0), err.sum(0), (err ** 2).sum(0))
        else:
            w = part.weight
            terms = (np.full(target.shape[1], w.sum()), w @ target,
                     w @ target ** 2 + part.within_ss.sum(0), w @ err,
                     w @ err ** 2 + spread.sum(0))
        for k, v in enumerate(terms):
            acc[k] += v
    raw = sum(a[2] - a[1] ** 2 / a[0] for a in sums.values())
    comp = sum(a[4] - a[3] ** 2 / a[0] for a in sums.values())
    return np.asarray(comp, dtype=np.float64), np.asarray(raw, dtype=np.float64)


def report(est: Any) -> str:
    """lmfit's manner: the family, data and fit, then per axis each parameter's value ±
    standard error and unit."""
    table = est.parameters_
    lines = [f"[[Model]] {est!r}",
             f"[[Fit]] inputs {', '.join(est.spec_.inputs)}; t_ref "
             f"{est.spec_.t_ref if est.spec_.t_ref is not None else '-'} °C; "
             f"{est.n_params_} parameters; best epoch {est.best_epoch_}",
             "[[Parameters]] (stderr: " + ("least squares, white residuals assumed"
                                          if est.stderr == "ols" else
                                          "moving-block residual bootstrap")
             + " — see thermonet.api.parameters)"]
    for axis, rows in table.groupby("axis", sort=False):
        lines.append(f"  {axis}:")
        for r in rows.itertuples():
            err = "" if not np.isfinite(r.stderr) else f" +/- {r.stderr:.4g}"
            rel = "" if not (np.isfinite(r.stderr) and r.value) else \
                f" ({abs(r.stderr / r.value):.2%})"
            lines.append(f"    {r.name:<12} {r.value: .6g}{err}{rel} {r.unit}")
    return "\n".join(lines)


def save(est: Any, path: str | os.PathLike[str]) -> Path:
    """The thermonet checkpoint (:func:`thermonet.api.persistence.save`)."""
    return persistence.save(est, path)


def export(est: Any, path: str | os.PathLike[str], fmt: str, *, device_id: int | None,
           instance: int | None) -> Path:
    """Through the format registry (:func:`thermonet.api.persistence.export`)."""
    return persistence.export(est, path, fmt, device_id=device_id, instance=instance)


def load(cls: type[State], path: str | os.PathLike[str]) -> State:
    """An estimator fitted as the checkpoint at ``path`` (:func:`persistence.load`)."""
    return persistence.load(cls, path)
