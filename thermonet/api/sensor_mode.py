""":class:`~thermonet.api.DriftEstimator` with ``model="sensor"``: the full sensor model
(bias, scale factor and misalignment per triad, :mod:`thermonet.models.sensor`) fitted,
applied, scored, saved and loaded through the estimator's own methods.

It fits exactly what ``compare`` with ``model: sensor`` fits for one family
(:func:`thermonet.training.sensor.fit_sensor` on the training runs, early stopping and do no
harm on the validation runs, the feature references from the training runs), so
``DriftEstimator("poly", ["dT"], model="sensor", degree=3).fit(split.train, split.val)``
compensates as ``compare``'s checkpoint ``models/<label>.pt`` does (tests/test_sensor_pipeline.py).

* :meth:`~thermonet.api.DriftEstimator.predict` returns the sensor's error
  ``raw − compensated`` (N, axes): what the ONNX graph's ``drift`` output is, so that
  ``raw − predict`` is the compensated output as for a bias model;
* :meth:`~thermonet.api.DriftEstimator.compensate` returns the recordings with
  :math:`M(s)^{-1}(r - b(s))` in place of each output;
* :meth:`~thermonet.api.DriftEstimator.score` is the bias model's offset-free score with the
  error ``raw − ref`` as target: :math:`1 - \\text{mean}_a\\, \\text{var}(\\hat x_a - x_a) /
  \\text{var}(r_a - x_a)`, each source run about its own mean;
* :meth:`~thermonet.api.DriftEstimator.save` writes a sensor checkpoint
  (:func:`thermonet.training.sensor_checkpoint.save_sensor`, what ``compare`` writes), and
  :meth:`~thermonet.api.DriftEstimator.load` reads one back as a sensor-mode estimator.

The data needs ``ref_<output>`` channels (the known excitation); ``target`` must be
``"drift"`` and ``train_on`` ``"all"`` (a scale factor needs every position: the sensor
kind's ``estimator_requires`` in :data:`thermonet.models.shipped.MODEL_KINDS`, checked by
:func:`thermonet.api.modes.check_model`).  The estimator reaches these functions through
:data:`thermonet.api.modes.MODES` (``"sensor"``), as it reaches
:mod:`thermonet.api.bias_mode`'s for ``"bias"``: the same functions, each kind's bodies.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, ThermonetError
from ..core.recording import Dataset, Recording
from ..features.inputs import signal_matrix
from ..training.splits import stack_blocks
from .data import (
    BLOCK_RUN,
    Data,
    data_source,
    names_of,
    needs_outputs,
    runs_of,
    same_run,
    same_units,
)
from .state import State

__all__ = ["fit", "predict", "compensate", "variances", "report", "save", "load", "export"]


def fit(est: Any, train: Data, val: Data | None, *, config: Any, inputs: list[str],
        family: Any, track: bool = False, tracking_uri: str | None = None,
        experiment: str = "") -> None:
    """Fit ``est`` as a sensor model (arguments already checked by the estimator; ``family``
    its spec); a sensor-mode fit is not tracked (``track`` or a ``tracking_uri`` refused)."""
    if track or tracking_uri is not None:
        raise ConfigError("fit(track): a sensor-mode fit is not tracked; 'thermonet compare' "
                          "with model: sensor logs its families to MLflow")
    from ..models.sensor import triads_of  # torch boundary
    from ..training.pipeline import split_spec  # torch boundary
    from ..training.sensor import fit_sensor, sensor_run  # torch boundary

    runs = runs_of(train, "fit(train)")
    val_runs = None if val is None else runs_of(val, "fit(val)")
    wanted = names_of(est.outputs, "outputs") or list(runs[0].axes)
    triads = triads_of(wanted, source="DriftEstimator(outputs)")
    outputs = [o for t in triads for o in t]
    for r in runs:
        needs_outputs(r, outputs, "fit(train)")
    for v in val_runs or []:
        needs_outputs(v, outputs, "fit(val)")
        same_units(v, runs[0].units, "fit(val)", f"the training run '{runs[0].run_id}' has it")
        if any(same_run(v, r) for r in runs):
            raise ThermonetError(f"fit(val): run '{v.run_id}' is also a training run "
                                 "(validate on a run the model is not fitted on)")
    Dataset(runs).validate("fit(train)")
    spec = split_spec(inputs, runs, t_ref=est.t_ref, window_min=est.t_ref_window_min,
                     gap_s=est.gap_s)
    va = None
    if val_runs:
        rec = stack_blocks(val_runs, "val") if len(val_runs) > 1 else val_runs[0]
        va = sensor_run(rec, spec, outputs)
    from ..training.scaling import caller_rng_kept  # lazy: loads torch

    with caller_rng_kept():     # the caller's torch random state as it was (as a bias fit)
        fitted = fit_sensor(family=family.key, spec=spec, outputs=outputs, triads=triads,
                            train=[sensor_run(r, spec, outputs) for r in runs], val=va,
                            hyper=family.hyper(), config=config)
    _fitted(est, fitted.model, outputs, runs[0])
    est.sensor_fit_ = fitted
    est.train_config_ = config
    est.history_ = list(fitted.history)
    est.best_epoch_ = int(fitted.best_epoch)
    est.elements_kept_ = dict(fitted.kept)
    est.condition_ = float(fitted.condition)
    est.data_source_ = data_source(runs, val_runs)
    est.val_score_ = None
    if va is not None:        # compare's validation score of a sensor family
        err, raw = fitted.model.compensate(va.signals, va.raw) - va.ref, va.raw - va.ref
        scale = np.std(raw, axis=0)
        est.val_score_ = float(np.mean((err / np.where(scale > 0, scale, 1.0)) ** 2))


def _fitted(est: Any, model: Any, outputs: list[str], first: Recording | None,
            units: dict[str, str] | None = None, signal_units: dict[str, str] | None = None
            ) -> None:
    est.model_ = model
    est.spec_ = model.bias.spec
    est.n_features_in_ = len(model.bias.spec.inputs)
    est.outputs_ = list(outputs)
    est.triads_ = [list(t) for t in model.triads]
    est.n_params_ = int(model.n_params)
    est.units_ = dict(units) if units is not None else {
        o: first.units.get(o, "") for o in outputs} if first is not None else {}
    est.signal_units_ = dict(signal_units) if signal_units is not None else {
        p: first.units.get(p, "") for p in first.proxies} if first is not None else {}
    est.device_id_ = first.device_id if first is not None else ""
    est.band_ = None
    est.mlflow_run_id_ = ""


def _arrays(est: Any, rec: Recording, what: str, *, refs: bool) -> Any:
    """A run's signals, raw outputs and (``refs``) references for the fitted model."""
    from ..training.sensor import SensorRun, sensor_run  # torch boundary

    needs_outputs(rec, est.outputs_, what)
    same_units(rec, est.units_, what, "the model was trained")
    same_units(rec, est.signal_units_, what, "the model was trained on it")
    if refs:
        return sensor_run(rec, est.spec_, est.outputs_)

    sig = signal_matrix(rec, est.spec_.signals, est.spec_.gap_s)
    raw = np.stack([rec.outputs[o] for o in est.outputs_], axis=1).astype(np.float64)
    return SensorRun(sig, raw, raw, np.asarray(rec.time_s, dtype=np.float64), sig[:, 0])


def predict(est: Any, data: Data, *, return_band: bool = False) -> np.ndarray:
    """The sensor's error ``raw − compensated`` (N, axes), float64, run after run (a sensor
    model carries no band: the estimator refuses ``return_band`` before it comes here)."""
    out = []
    for rec in runs_of(data, "predict", allow_empty=True):
        r = _arrays(est, rec, "predict", refs=False)
        out.append(r.raw - est.model_.compensate(r.signals, r.raw))
    return out[0] if len(out) == 1 else np.concatenate(out)


def compensate(est: Any, data: Data) -> Any:
    """``data`` with each modelled output replaced by :math:`M(s)^{-1}(r - b(s))`."""
    from dataclasses import replace

    done = []
    for rec in runs_of(data, "compensate", allow_empty=True):
        r = _arrays(est, rec, "compensate", refs=False)
        comp = est.model_.compensate(r.signals, r.raw)
        outputs = dict(rec.outputs)
        for j, axis in enumerate(est.outputs_):
            outputs[axis] = comp[:, j]
        done.append(replace(rec, outputs=outputs, run_id=f"{rec.run_id}[compensated]"))
    if isinstance(data, Recording):
        return done[0]
    return Dataset(done) if isinstance(data, Dataset) else done


def variances(est: Any, data: Data, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Per axis, the sums of squares of ``compensated − ref`` and ``raw − ref``, each
    source run about its own mean (the bias score's offset-free sums)."""
    sums: dict[str, list[np.ndarray]] = {}
    for rec in runs_of(data, what):
        r = _arrays(est, rec, what, refs=True)
        y = r.raw - r.ref
        e = est.model_.compensate(r.signals, r.raw) - r.ref
        acc = sums.setdefault(rec.meta.get(BLOCK_RUN, rec.run_id),
                              [np.zeros(y.shape[1]) for _ in range(5)])
        for k, v in enumerate((np.full(y.shape[1], y.shape[0]), y.sum(0), (y ** 2).sum(0),
                               e.sum(0), (e ** 2).sum(0))):
            acc[k] += v
    raw = sum(a[2] - a[1] ** 2 / a[0] for a in sums.values())
    comp = sum(a[4] - a[3] ** 2 / a[0] for a in sums.values())
    return np.asarray(comp, dtype=np.float64), np.asarray(raw, dtype=np.float64)


def report(est: Any) -> str:
    """Refused: a sensor model has no per-parameter table."""
    raise ConfigError("report(): a sensor model has no per-parameter table; its "
                      "coefficients are model_.bias and model_.elements, and 'thermonet "
                      "compare' with model: sensor writes its report.html")


def save(est: Any, path: str | os.PathLike[str]) -> Path:
    """The fitted sensor model as a sensor checkpoint (``compare``'s format)."""
    from ..training.sensor import SensorFit  # torch boundary
    from ..training.sensor_checkpoint import save_sensor  # torch boundary

    fitted = est.__dict__.get("sensor_fit_")
    if fitted is None:      # loaded: the model and what was kept
        fitted = SensorFit(model=est.model_, history=list(est.history_), best_epoch=0,
                           n_estimates=0, condition=float("nan"),
                           kept=dict(est.__dict__.get("elements_kept_") or {}))
    source = est.__dict__.get("data_source_")
    extra = {"device_id": est.device_id_, "units": est.units_,
             "signal_units": est.signal_units_, "val_score": est.__dict__.get("val_score_"),
             "history": list(est.history_),
             "estimator": {"t_ref": est.t_ref, "t_ref_window_min": est.t_ref_window_min,
                           "gap_s": est.gap_s}}
    if source is not None:
        extra.update(data_hash=source["data_hash"], provenance={"data": source})
    family = est._family_spec()
    return save_sensor(Path(path), fitted, family=family.key, hyper=family.hyper(), extra=extra)


def export(est: Any, path: str | os.PathLike[str], fmt: str, *, device_id: int | None = None,
           instance: int | None = None) -> Path:
    """Export ``est`` as ``thermonet export`` exports compare's sensor checkpoint: saved,
    loaded and handed to the format registry
    (:func:`thermonet.exporting.sensor_export.export_sensor_source`: the registry's sensor
    exporters, ONNX or the C header, parity-checked before anything is written); the
    autopilot formats refused in one line naming the estimator's alternative."""
    import tempfile

    from ..exporting.sensor_export import export_sensor_source  # torch boundary

    if fmt in ("px4-params", "ardupilot-params"):
        raise ConfigError(f"export(format): {fmt!r} holds a bias polynomial per axis only, not "
                          "a sensor model's scale factor and misalignment; export 'onnx' or "
                          "'c', or fit DriftEstimator(model='bias') for the autopilot file")

    with tempfile.TemporaryDirectory() as tmp:
        ckpt = save(est, Path(tmp) / "sensor.pt")
        return export_sensor_source(ckpt, fmt=fmt, out=Path(path))


def load(cls: type[State], path: str | os.PathLike[str]) -> State:
    """A sensor-mode estimator fitted as the sensor checkpoint at ``path`` (also one
    ``compare`` wrote)."""
    from ..training.sensor_checkpoint import load_sensor  # torch boundary

    model, payload = load_sensor(Path(path))
    extra = payload.get("extra") or {}
    feats = extra.get("estimator") or {}
    spec = model.bias.spec
    new = cls(payload["family"], list(payload["inputs"]), model="sensor",
              outputs=list(model.outputs), t_ref=feats.get("t_ref", "start"),
              gap_s=feats.get("gap_s", "auto"),
              t_ref_window_min=float(feats.get("t_ref_window_min", 10.0)),
              **dict(payload.get("hyper") or {}))
    est: Any = new
    units = {str(k): str(v) for k, v in (extra.get("units") or {}).items()}
    _fitted(est, model, list(model.outputs), None, units,
            {str(k): str(v) for k, v in (extra.get("signal_units") or {}).items()})
    est.spec_ = spec
    est.device_id_ = str(extra.get("device_id", ""))
    est.history_ = list(extra.get("history") or [])
    est.elements_kept_ = dict(payload.get("kept") or {})
    est.val_score_ = extra.get("val_score")
    return new
