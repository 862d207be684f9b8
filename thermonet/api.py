"""The researcher's Python API: :class:`DriftEstimator`, :func:`simulate`, :func:`read`.

A drift model in the scikit-learn / skorch mould::

    import thermonet

    ds = thermonet.simulate("patent-gyro", runs=3, seed=0)
    est = thermonet.DriftEstimator("poly", ["dT"], degree=3).fit(ds[0], val=ds[1])
    drift = est.predict(ds[2])                 # (N, axes), in the outputs' units
    print(est.score(ds[2]))                    # 1 − msd after / msd before, mean over axes
    est.save("cubic.pt")
    est.export("cubic.onnx", format="onnx")

The constructor only stores its arguments; :meth:`DriftEstimator.fit`
resolves the feature references from the training runs
(:meth:`~thermonet.features.inputs.FeatureSpec.from_recordings`), builds each run's
signals and targets (:func:`~thermonet.training.parts.build_part`, the function
``compare`` uses) and runs the one training loop
(:func:`thermonet.training.train.fit`).  Learned state ends in ``_``.  A saved
estimator is an ordinary thermonet checkpoint (``thermonet export`` reads it).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .core.errors import ThermonetError
from .core.recording import Dataset, Recording
from .core.trainconfig import TrainConfig

if TYPE_CHECKING:
    from .features.inputs import FeatureSpec
    from .models import DriftModel

__all__ = ["DriftEstimator", "NotFittedError", "simulate", "read"]

_TARGETS = ("drift", "four-position")


class NotFittedError(ThermonetError, AttributeError):
    """``predict``/``compensate``/``score``/``save``/``export`` before ``fit``."""


def _runs(data: Dataset | Recording | Iterable[Recording], what: str) -> list[Recording]:
    """The runs of ``data``: each a :class:`Recording` with samples, else one ValueError line."""
    expected = "expected a Dataset, a Recording or a list of Recordings"
    if isinstance(data, Recording):
        runs = [data]
    elif isinstance(data, (str, bytes, os.PathLike)) or not isinstance(data, Iterable):
        hint = " (read files with thermonet.read(paths, mapping))" \
            if isinstance(data, (str, bytes, os.PathLike)) else ""
        raise ThermonetError(f"{what}: {expected}, got {type(data).__name__}{hint}")
    else:
        runs = list(data)
    if not runs:
        raise ThermonetError(f"{what}: no recordings (an empty {type(data).__name__}); "
                             "give at least one run")
    for i, r in enumerate(runs):
        if not isinstance(r, Recording):
            raise ThermonetError(f"{what}: {expected}; item {i} is a {type(r).__name__}")
        _has_samples(r, what)
    return runs


def _data_source(runs: list[Recording], val: list[Recording] | None) -> dict[str, Any]:
    """What a fit was given (a checkpoint's ``extra.provenance.data``): the runs, where they
    came from (the files read, or the simulator) and the digest of their samples."""
    from .training.parts import data_hash

    every = runs + list(val or [])
    return {"kind": "dataset", "device": runs[0].device_id,
            "runs": [r.run_id for r in runs], "val": [r.run_id for r in val or []],
            "sources": sorted({r.meta.get("source", "") for r in every} - {""})[:20],
            "preset": runs[0].meta.get("preset") or None,
            "data_hash": data_hash(Dataset(every))}


def _has_samples(rec: Recording, what: str) -> Recording:
    if rec.n_samples == 0:
        raise ThermonetError(f"{what}: run '{rec.run_id}' has no samples")
    return rec


def _recording(data: Any, what: str) -> Recording:
    """``data`` when it is one :class:`Recording`, else one ValueError line saying what to pass."""
    if isinstance(data, Recording):
        return data
    hint = " (one run at a time: pass ds[i], or loop over the Dataset)" \
        if isinstance(data, Dataset) or isinstance(data, (list, tuple)) else ""
    raise ThermonetError(f"{what}: expected a Recording, got {type(data).__name__}{hint}")


def _needs_outputs(rec: Recording, outputs: Sequence[str], what: str) -> None:
    """Every output channel the model needs (``gyro_x`` for ``gyro_x.bias`` too) is in ``rec``."""
    needed = list(dict.fromkeys(o.split(".")[0] for o in outputs))
    missing = [a for a in needed if a not in rec.outputs]
    if missing:
        raise ThermonetError(f"{what}: run '{rec.run_id}' has no output channel '{missing[0]}' "
                             f"(the model needs {', '.join(needed)}; the run has "
                             f"{', '.join(rec.outputs) or 'none'})")


class DriftEstimator:
    """One model family fitted to drift vs temperature (or a proxy).

    Parameters
    ----------
    family : str
        A name in :data:`thermonet.models.MODELS` (``linear``, ``poly``, ...).
    inputs : list of str, optional
        Features (``T``, ``dT``, ``dT2``, ``rate``, ``d_<proxy>``...); default
        the family's own (``default_inputs``).
    t_ref : "start" or float
        :math:`T_{ref}` in °C, or the mean over the first ``t_ref_window_min``
        minutes of the first training run.
    target : "drift" or "four-position"
        What is fitted: per-sample drift (output − reference), or study 000's
        per-soak bias and scale factor (outputs ``<axis>.bias``/``<axis>.scale``).
    train : TrainConfig, optional
        The training loop's settings (default ``TrainConfig()``).
    outputs : list of str, optional
        Output axes to model (default: every output of the training data).
    train_on : "all" or "heating"
        ``heating`` fits only samples with dT/dt > −0.05 °C/min (PX4/ArduPilot practice).
    gap_s : float or "auto"
        Dynamic inputs (``rate``, ``lag_<tau>``, ``play_<w>``, :mod:`thermonet.features.dynamics`):
        a time step over ``gap_s`` seconds restarts their state; ``"auto"`` is
        :data:`thermonet.features.dynamics.GAP_FACTOR` × the first training run's median
        sample interval.  Stored with the model.
    t_ref_window_min : float
        Minutes averaged for ``t_ref="start"``.
    **hyper
        The family's hyper-parameters (``degree=3``, ``n_centres=16``...).

    Attributes
    ----------
    model_ : DriftModel
        The fitted torch module (eval mode, CPU).
    spec_ : FeatureSpec
        Inputs and the references resolved from the training runs.
    outputs_ : list of str
    units_ : dict
        Unit per output (from the training data).
    history_ : list of dict
        Per epoch ``train_loss`` and ``val_loss`` (standardised MSE); epoch 0 is
        the closed-form start.
    best_epoch_ : int
    best_val_ : float or None
        Validation loss at ``best_epoch_`` (None without a validation run).
    n_params_ : int
    fit_seconds_ : float
    """

    def __init__(self, family: str, inputs: Sequence[str] | None = None, *,
                 t_ref: str | float = "start", target: str = "drift",
                 train: TrainConfig | None = None, outputs: Sequence[str] | None = None,
                 train_on: str = "all", gap_s: float | str = "auto",
                 t_ref_window_min: float = 10.0, **hyper: Any) -> None:
        self.family = family
        self.inputs = inputs
        self.t_ref = t_ref
        self.target = target
        self.train = train
        self.outputs = outputs
        self.train_on = train_on
        self.gap_s = gap_s
        self.t_ref_window_min = t_ref_window_min
        self.hyper = hyper

    def __repr__(self) -> str:
        hyper = "".join(f", {k}={v!r}" for k, v in self.hyper.items())
        return f"DriftEstimator({self.family!r}, {self.inputs!r}{hyper})"

    # ------------------------------------------------------------------ fitting
    def _resolved_inputs(self) -> list[str]:
        if self.inputs is not None:
            return list(self.inputs)
        from .models import get_family

        return list(get_family(self.family).default_inputs)

    def _outputs_for(self, runs: list[Recording]) -> list[str]:
        from .training.parts import FOURPOS_SUFFIXES

        axes = list(self.outputs) if self.outputs is not None else list(runs[0].axes)
        if self.target == "four-position":
            return [f"{a}{s}" for a in axes for s in FOURPOS_SUFFIXES]
        return axes

    def fit(self, train: Dataset | Recording | Iterable[Recording],
            val: Dataset | Recording | Iterable[Recording] | None = None) -> DriftEstimator:
        """Fit on ``train``; stop early on ``val`` (held-out runs) when given.

        Without ``val`` the loop stops on a training-loss plateau; thermonet
        never carves validation samples at random (see :mod:`thermonet.training.splits`
        for contiguous blocks).

        Returns
        -------
        DriftEstimator
            ``self``, fitted.

        Raises
        ------
        ConfigError
            Unknown family, input, hyper-parameter, target or ``train_on``.
        FitError
            The data cannot carry the family (reason given).
        """
        from .core.errors import ConfigError
        from .training.fold import fit_fold, fold_parts, fold_spec
        from .training.splits import stack_blocks

        if self.target not in _TARGETS:
            raise ConfigError(f"target: {self.target!r} is not one of {', '.join(_TARGETS)}")
        if self.train_on not in ("all", "heating"):
            raise ConfigError(f"train_on: {self.train_on!r} is not 'all' or 'heating'")
        if "rate_window_s" in self.hyper:
            raise ConfigError("rate_window_s was removed: 'rate' is a causal filtered derivative "
                              "with a 60 s time constant (thermonet.features.dynamics); use the input "
                              "'rate_<tau>' (e.g. rate_30) for another time constant")
        runs = _runs(train, "fit(train)")
        val_runs = None if val is None else _runs(val, "fit(val)")
        inputs = self._resolved_inputs()
        outputs = self._outputs_for(runs)
        for r in runs:
            _needs_outputs(r, outputs, "fit(train)")
        for r in val_runs or []:
            _needs_outputs(r, outputs, "fit(val)")
        config = self.train if self.train is not None else TrainConfig()
        spec = fold_spec(inputs, runs, t_ref=self.t_ref, window_min=self.t_ref_window_min,
                         gap_s=self.gap_s)
        val_rec = None
        if val_runs is not None:
            val_rec = stack_blocks(val_runs, "val") if len(val_runs) > 1 else val_runs[0]
        parts = fold_parts(spec, runs, outputs=outputs, target=self.target, val=val_rec,
                           train_on=self.train_on, gap_s=self.gap_s)
        result = fit_fold(parts, family=self.family, outputs=outputs, hyper=self.hyper,
                          config=config)
        self.model_: DriftModel = result.model
        self.spec_: FeatureSpec = spec
        self.outputs_: list[str] = outputs
        self.units_: dict[str, str] = {o: ("1" if o.endswith(".scale")
                                           else runs[0].units.get(o.split(".")[0], ""))
                                       for o in outputs}
        self.signal_units_: dict[str, str] = {p: runs[0].units.get(p, "")
                                              for p in runs[0].proxies}
        self.device_id_: str = runs[0].device_id
        self.data_source_: dict[str, Any] = _data_source(runs, val_runs)
        self.train_config_: TrainConfig = config
        self.history_: list[dict[str, Any]] = list(result.history)
        self.best_epoch_: int = int(result.best_epoch)
        self.best_val_: float | None = result.best_val_loss
        self.n_params_: int = int(result.n_params)
        self.fit_seconds_: float = float(result.fit_seconds)
        return self

    def _part(self, rec: Recording, spec: FeatureSpec, outputs: list[str]) -> Any:
        from .training.parts import build_part

        return build_part(rec, signals=spec.signals, outputs=outputs, target=self.target,
                          gap_s=spec.gap_s)

    def _check_fitted(self, what: str) -> DriftModel:
        model = getattr(self, "model_", None)
        if model is None:
            raise NotFittedError(f"this DriftEstimator({self.family!r}) is not fitted yet; "
                                 f"call fit(...) before {what}()")
        return model

    # --------------------------------------------------------------- prediction
    def predict(self, recording: Recording) -> np.ndarray:
        """Predicted drift (N, axes) of ``recording``, float64, in the outputs' units.

        Evaluated as on board: signals clamped to the trained range
        (``model_.out_of_range`` flags the samples outside it).
        """
        model = self._check_fitted("predict")
        from .features.inputs import signal_matrix
        from .training.train import predict

        recording = _recording(recording, "predict")
        signals = signal_matrix(recording, self.spec_.signals, self.spec_.gap_s)
        return predict(model, signals)

    def compensate(self, recording: Recording) -> Recording:
        """A copy of ``recording`` with the predicted drift subtracted from each modelled output."""
        self._check_fitted("compensate")
        if self.target != "drift":
            raise ThermonetError("compensate: a four-position model predicts per-soak bias and "
                                 "scale factor, not a drift to subtract sample by sample")
        recording = _recording(recording, "compensate")
        _needs_outputs(recording, self.outputs_, "compensate")
        drift = self.predict(recording)
        outputs = dict(recording.outputs)
        for j, axis in enumerate(self.outputs_):
            outputs[axis] = recording.outputs[axis] - drift[:, j]
        return replace(recording, outputs=outputs, run_id=f"{recording.run_id}[compensated]")

    def score(self, recording: Recording) -> float:
        """Fraction of the drift's mean square removed, mean over axes (higher is better).

        .. math:: s = 1 - \\frac{1}{A}\\sum_a \\frac{\\overline{(y_a - \\hat y_a)^2}}
                                                  {\\overline{y_a^2}}

        with :math:`y_a` the observed drift (output − reference; for a scale
        factor its deviation from the mean, which is no error).  1 is perfect,
        0 no better than the raw output, negative worse.  ``compare`` chooses
        on the same ratio (its ``val_score`` is :math:`1 - s`).
        """
        model = self._check_fitted("score")
        from .training.train import predict

        recording = _has_samples(_recording(recording, "score"), "score")
        _needs_outputs(recording, self.outputs_, "score")
        part = self._part(recording, self.spec_, self.outputs_)
        pred = predict(model, part.signals)
        ratios = []
        for j, axis in enumerate(self.outputs_):
            y = part.target[:, j]
            raw_err = y - np.mean(y) if axis.endswith(".scale") else y
            raw = float(np.mean(raw_err ** 2))
            comp = float(np.mean((y - pred[:, j]) ** 2))
            ratios.append(comp / raw if raw > 0 else float("inf"))
        return 1.0 - float(np.mean(ratios))

    # ---------------------------------------------------------------- save, load
    def _checkpoint_config(self) -> dict[str, Any]:
        """The family's resolved configuration, as a checkpoint stores it."""
        return {
            "family": {"family": self.family, "inputs": list(self.spec_.inputs),
                       "params": dict(self.hyper), "train_on": self.train_on},
            "train": asdict(self.train_config_),
            "features": {"t_ref": self.t_ref, "t_ref_window_min": self.t_ref_window_min,
                         "gap_s": self.gap_s},
            "target": self.target,
        }

    def _extra(self) -> dict[str, Any]:
        extra = {"units": self.units_, "signal_units": self.signal_units_,
                 "device_id": self.device_id_, "history": self.history_}
        source = getattr(self, "data_source_", None)  # an estimator made by load() has none
        if source is not None:  # provenance: what it was fitted on (as compare records it)
            extra.update(data_hash=source["data_hash"], provenance={"data": source})
        return extra

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the fitted model as a thermonet checkpoint (atomic; loads with
        ``weights_only=True``; ``thermonet export`` reads it)."""
        model = self._check_fitted("save")
        from .training.checkpoint import save_checkpoint

        return save_checkpoint(path, model, config=self._checkpoint_config(), extra=self._extra(),
                               epoch=self.best_epoch_, best_val=self.best_val_)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> DriftEstimator:
        """An estimator fitted as the checkpoint at ``path`` (also one ``compare`` wrote)."""
        from .training.checkpoint import load_checkpoint
        from .training.config import from_dict

        model, meta = load_checkpoint(path)
        config = meta.get("config") or {}
        fam = config.get("family") or {}
        features = config.get("features") or {}
        extra = meta.get("extra") or {}
        train = from_dict(TrainConfig, config.get("train") or {}, source=str(path),
                          prefix="config.train")
        est = cls(meta["family"], list(meta["inputs"]),
                  t_ref=features.get("t_ref", "start"), target=config.get("target", "drift"),
                  train=train, outputs=list(meta["outputs"]),
                  train_on=fam.get("train_on", "all"),
                  gap_s=features.get("gap_s", "auto"),
                  t_ref_window_min=float(features.get("t_ref_window_min", 10.0)),
                  **dict(meta["hyper"]))
        est.model_ = model
        est.spec_ = model.spec
        est.outputs_ = list(meta["outputs"])
        est.units_ = dict(extra.get("units") or {})
        est.signal_units_ = dict(extra.get("signal_units") or {})
        est.device_id_ = str(extra.get("device_id", ""))
        est.train_config_ = train
        est.history_ = list(extra.get("history") or [])
        prov = extra.get("provenance")
        source = prov.get("data") if isinstance(prov, dict) else None
        if isinstance(source, dict):  # kept, so that saving it again keeps the record
            est.data_source_ = {**source, "data_hash": str(extra.get("data_hash") or "")}
        est.best_epoch_ = int(meta["epoch"]) if meta.get("epoch") is not None else 0
        est.best_val_ = meta.get("best_val")
        est.n_params_ = int(model.n_params)
        est.fit_seconds_ = float("nan")
        return est

    def export(self, path: str | os.PathLike[str], format: str = "onnx", *,
               device_id: int | None = None, instance: int | None = None) -> Path:
        """Export through the format registry (:data:`thermonet.exporting.FORMATS`).

        ``device_id``/``instance`` apply to the autopilot formats (see
        ``thermonet export --help``).
        """
        model = self._check_fitted("export")
        from .exporting import ExportRequest, get_format

        meta = {"config": self._checkpoint_config(), "extra": self._extra()}
        return get_format(format).write(model, Path(path), ExportRequest(
            meta=meta, device_id=device_id, instance=instance))


def simulate(preset: str, runs: int | None = None, seed: int = 0) -> Dataset:
    """A simulated chamber test from a study preset (``patent-gyro``, ``accel``...).

    Same preset, runs and seed give identical data.
    """
    from .sim import simulate as _simulate

    return _simulate(preset, runs=runs, seed=seed)


def read(paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
         mapping: str | os.PathLike[str] | None = None) -> Dataset:
    """Recordings from CSV/TSV/Parquet files (one run per file unless a ``run`` column),
    through a YAML column mapping when the columns are not thermonet's own."""
    from .data.io import read_datasets

    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    return read_datasets([Path(p) for p in paths], mapping=None if mapping is None
                         else Path(mapping))
