"""The estimator: :class:`DriftEstimator` (see :mod:`thermonet.api`)."""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import os
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ConfigError, ThermonetError
from ..core.recording import Dataset, Recording
from ..core.schema import from_dict
from ..core.trainconfig import TrainConfig
from ..data.diagnostics import TEMPERATURE_PLAUSIBLE_C
from ..features.target import MODES, modelled_outputs, output_units
from ..models.registry import PER_AXIS, make_spec, spec_class, spec_of
from ..models.specs import FamilySpec
from .checks import ArgumentTypeError, flag, gap, input_names, seconds, text
from .checks import path as a_path
from .data import Data, data_source, names_of, needs_outputs, runs_of, same_run, same_units
from .family_keywords import FamilyKeywords, with_keywords
from .fitted import FittedEstimator
from .modes import check_model, load, mode_of
from .parameters import STDERR_METHODS, parameter_table

if TYPE_CHECKING:
    import pandas as pd

    from ..features.inputs import FeatureSpec
    from ..features.target import Target
    from ..models.composite import DriftModels

__all__ = ["DriftEstimator"]

_TARGETS = ("drift", "four-position")

#: The constructor's own keywords (a family's hyper-parameters are the spec's: ``family__<name>``).
_OWN = ("family", "inputs", "t_ref", "target", "outputs", "train_on", "gap_s",
        "t_ref_window_min", "stderr", "train", "model")
#: The training settings, each a keyword of its own (None: from ``train``, else TrainConfig's).
_TRAIN_KEYS = tuple(f.name for f in dataclasses.fields(TrainConfig))


class DriftEstimator(FittedEstimator):
    """One model family fitted to drift vs temperature (or a proxy), scikit-learn style.

    Every argument is a keyword the estimator stores as given (``get_params``,
    ``set_params`` and :func:`sklearn.base.clone` see all of them: scikit-learn's
    ``BaseEstimator`` protocol, :class:`thermonet.core.params.Params`, without importing
    scikit-learn; the family spec's hyper-parameters are the nested ``family__<name>``);
    :meth:`fit` checks them and names the argument at fault.

    Parameters
    ----------
    family : FamilySpec or str
        The family and its hyper-parameters as a spec (:mod:`thermonet.models.specs`:
        ``Poly(degree=3)``, ``RBF(n_centres=8)``, ``Linear()``...), or a registered name
        (``"poly"``: its spec with the defaults).
    inputs : list of str or str, optional
        Features (``T``, ``dT``, ``dT2``, ``rate``, ``d_<proxy>``...); one name may be
        given alone.  Default: the family's own (``default_inputs``).
    t_ref : "start" or float
        :math:`T_{ref}` in °C, or the mean over the first ``t_ref_window_min``
        minutes of the first training run.
    target : "drift", "four-position" or dict
        What is fitted, as a comparison's ``target`` (:mod:`thermonet.features.target`):
        ``"drift"`` puts every axis at its default — ``output − ref_<axis>`` where the data
        has a reference channel, else the output itself for a gyro (``zero``) and its change
        from :math:`T_{ref}` for any other kind (``at-t-ref``: an accelerometer's gravity is
        no drift); a dict ``{"acc": "at-t-ref", "gyro_z": "channel"}`` sets kinds or axes;
        ``"four-position"`` is study 000's per-soak bias and scale factor (outputs
        ``<axis>.bias``/``<axis>.scale``).
    outputs : list of str or str, optional
        Output axes to model (default: every output of the first training run).
    train_on : "all" or "heating"
        ``heating`` fits only samples with dT/dt > −0.05 °C/min (PX4/ArduPilot practice).
    gap_s : float or "auto"
        Dynamic inputs (``rate``, ``lag_<tau>``, ``play_<w>``): a time step over ``gap_s``
        seconds restarts their state; ``"auto"`` is
        :data:`thermonet.features.dynamics.GAP_FACTOR` × the first training run's median
        sample interval.  Stored with the model.
    t_ref_window_min : float
        Minutes averaged for ``t_ref="start"``.
    stderr : "ols" or "block-bootstrap"
        How :attr:`parameters_` gets its standard errors: least squares (white residuals
        assumed), or a moving-block residual bootstrap that keeps the residuals'
        correlation in time (:mod:`thermonet.api.parameters`).
    train : TrainConfig or dict, optional
        The training loop's settings as one object (``{"max_epochs": 5}`` is read as
        ``TrainConfig(max_epochs=5)``); the keywords below override single fields.
    optimizer, lr, max_epochs, patience, min_delta, seed, device, max_train_samples, \
average_s, threads
        The fields of :class:`~thermonet.TrainConfig`, each a keyword of its own (None:
        from ``train``, else TrainConfig's default), so that a hyper-parameter search can
        set them: ``DriftEstimator("mlp", seed=3, max_epochs=200)``.
    model : "bias" or "sensor"
        ``"sensor"``: the full sensor model — bias, scale factor and misalignment per triad,
        every element a function of the inputs — as ``compare`` fits it with ``model:
        sensor`` (:mod:`thermonet.api.sensor_mode`: what predict, score and save mean then).
    **hyper
        Shorthand for the spec's keywords: ``DriftEstimator("poly", degree=3)`` is
        ``DriftEstimator(Poly(degree=3))`` (its ``family`` parameter is that spec).  The
        hyper-parameters are nested parameters: ``get_params()`` lists ``family__degree``,
        ``set_params(family__degree=2)`` sets it (a family given by name becomes its spec
        first), ``est.family.degree`` reads it.  ``set_params(degree=2)`` (and a
        ``GridSearchCV`` grid ``{"degree": [...]}``) is read as ``family__degree``.  A
        keyword the estimator has itself stays its own: ``DriftEstimator("gru", lr=1e-3)``
        sets the training loop's ``lr``; the GRU's own step is ``GRU(lr=1e-3)``
        (``family__lr``), as ``gap_s`` is the estimator's and ``GRU(gap_s=...)`` the GRU's.

    Attributes
    ----------
    model_ : DriftModel or AxisModels
        The fitted torch module (eval mode, CPU); an
        :class:`~thermonet.models.composite.AxisModels` when loaded from a per-axis
        checkpoint (:attr:`axis_models_` says which candidate computes each axis).
    spec_ : FeatureSpec
        Inputs and the references resolved from the training runs.
    n_features_in_ : int
        Number of model inputs (features) the model was fitted on.
    outputs_ : list of str
    units_ : dict
        Unit per output (from the training data); scoring data in another unit is refused.
    parameters_ : pandas.DataFrame
        The fitted parameters in physical units with standard errors: columns ``axis,
        name, value, stderr, unit, note`` (:mod:`thermonet.api.parameters`; ``note`` names
        the method of a computed stderr, ``ols`` or ``block-bootstrap``, with ``; within 2 SE
        of zero`` where ``|value| < 2 stderr``, else says why a stderr is NaN, or ``fixed``);
        saved with the model and loaded back.
    covariance_ : dict of str to ndarray
        Per axis, the covariance of the polynomial coefficients ``c0 … cN`` (families
        that are a polynomial in one input; empty otherwise).
    history_ : list of dict
        Per epoch ``train_loss`` and ``val_loss`` (standardised MSE); epoch 0 is
        the closed-form start.
    best_epoch_ : int
    best_val_ : float or None
        Validation loss at ``best_epoch_`` (None without a validation run).
    val_score_ : float or None
        ``compare``'s validation score on ``val``: the mean over axes of the offset-free
        RMS ratio compensated / raw (< 1 better); ``val_ratios_`` per axis.
    mlflow_run_id_ : str
        The MLflow run of a tracked fit ("" untracked).
    band_ : thermonet.scoring.band.Band or None
        The residual-drift band per axis (``predict(..., return_band=True)``): from
        ``compare``'s out-of-fold residuals, so only a model loaded from a ``compare``
        checkpoint has one; None after :meth:`fit`.
    n_params_ : int
        Parameters the model computes with (an RBF whose ridge is ∞ on every axis is its
        polynomial tail: the cubic's count).
    tuned_ : dict
        What the family chose itself on the training data (the RBF's ``width_scale`` and
        per-axis ``ridge``); a loaded estimator's ``get_params`` states these values where
        they are one value (the checkpoint keeps them).
    fit_seconds_ : float
    """

    def __init__(self, family: FamilySpec | str, inputs: Sequence[str] | str | None = None, *,
                 t_ref: str | float = "start", target: str = "drift",
                 outputs: Sequence[str] | str | None = None, train_on: str = "all",
                 gap_s: float | str = "auto", t_ref_window_min: float = 10.0,
                 stderr: str = "ols", train: TrainConfig | dict[str, Any] | None = None,
                 optimizer: str | None = None, lr: float | None = None,
                 max_epochs: int | None = None, patience: int | None = None,
                 min_delta: float | None = None, seed: int | None = None,
                 device: str | None = None, max_train_samples: int | None = None,
                 average_s: float | None = None, threads: int | None = None,
                 model: str = "bias", **hyper: Any) -> None:
        # keywords of the family fold into its spec; without them ``family`` is kept as given
        self.family = with_keywords(family, hyper) if hyper else family
        self.inputs = inputs
        self.t_ref = t_ref
        self.target = target
        self.outputs = outputs
        self.train_on = train_on
        self.gap_s = gap_s
        self.t_ref_window_min = t_ref_window_min
        self.stderr = stderr
        self.train = train
        self.optimizer = optimizer
        self.lr = lr
        self.max_epochs = max_epochs
        self.patience = patience
        self.min_delta = min_delta
        self.seed = seed
        self.device = device
        self.max_train_samples = max_train_samples
        self.average_s = average_s
        self.threads = threads
        self.model = model           # a kind of thermonet.api.modes.MODES

    # ------------------------------------------------------ scikit-learn's contract
    def set_params(self, **params: Any) -> DriftEstimator:
        """scikit-learn's ``set_params``; returns ``self``.  A family given by name becomes its
        spec with the defaults where a nested ``family__<name>`` is set; a bare hyper-parameter
        name (``degree``, what a grid ``{"degree": [...]}`` sets) is read as
        ``family__degree``.  A name that is neither, for a family spec, is one error naming the
        valid ones; a family that is no spec (an unknown name, a value of the wrong type) keeps
        the names as given, as the constructor does, and :meth:`fit` refuses it."""
        own = _OWN + _TRAIN_KEYS
        fam = params.get("family", self.family)
        nested = {k: v for k, v in params.items() if k.partition("__")[0] not in own}
        if nested or any(k.startswith("family__") for k in params):
            if not isinstance(fam, FamilySpec | FamilyKeywords):
                try:
                    fam = spec_of(fam)
                except ConfigError:
                    fam = FamilyKeywords(fam, {})
            if isinstance(fam, FamilySpec):
                valid = fam.get_params()
                for key in nested:
                    if key not in valid:
                        raise ConfigError(
                            f"set_params: {key!r} is not a parameter of DriftEstimator({fam!r}) "
                            f"(its own: {', '.join(own)}; the family's, as family__<name>: "
                            f"{', '.join(valid) or 'none'})")
            params = {**{k: v for k, v in params.items() if k not in nested},
                      "family": fam, **{f"family__{k}": v for k, v in nested.items()}}
        return super().set_params(**params)

    def __sklearn_tags__(self) -> Any:
        """scikit-learn's tags: a regressor whose ``X`` is recordings and that needs no ``y``."""
        from sklearn.utils import InputTags, RegressorTags, Tags, TargetTags

        return Tags(estimator_type="regressor", target_tags=TargetTags(required=False),
                    regressor_tags=RegressorTags(), non_deterministic=False,
                    input_tags=InputTags(two_d_array=False))

    def __repr__(self) -> str:
        defaults = {"inputs": None, "t_ref": "start", "target": "drift", "outputs": None,
                    "train_on": "all", "gap_s": "auto", "t_ref_window_min": 10.0, "train": None,
                    "stderr": "ols", "model": "bias"}
        shown = [repr(self.family)]
        shown += [f"{k}={getattr(self, k)!r}" for k in _OWN[1:]
                  if getattr(self, k) != defaults.get(k)]
        shown += [f"{k}={getattr(self, k)!r}" for k in _TRAIN_KEYS if getattr(self, k) is not None]
        return f"DriftEstimator({', '.join(shown)})"

    # ------------------------------------------------------------------ fitting
    def _train_config(self) -> TrainConfig:
        """``train`` (a TrainConfig, a dict of its fields or None) with the keywords over it."""
        base = self.train
        if base is None:
            config = TrainConfig()
        elif isinstance(base, TrainConfig):
            config = base
        elif isinstance(base, dict):
            config = from_dict(TrainConfig, base, source="DriftEstimator", prefix="train")
        else:
            raise ConfigError(f"train: expected a TrainConfig or a dict of its fields "
                              f"({', '.join(_TRAIN_KEYS)}), got {type(base).__name__}; or set "
                              "them as keywords (DriftEstimator(..., max_epochs=5))")
        overrides = {k: getattr(self, k) for k in _TRAIN_KEYS if getattr(self, k) is not None}
        try:
            return replace(config, **overrides) if overrides else config
        except ConfigError as err:   # a keyword's value: named first, as every argument is
            key, sep, why = str(err).removeprefix("key '").partition("': ")
            raise ConfigError(f"{key}: {why}" if sep else str(err)) from None

    def _family_spec(self) -> FamilySpec:
        """``family`` as a spec (a name: its spec with the defaults); an unknown family or
        hyper-parameter name, or a family of the wrong type, is one error naming it."""
        fam = self.family
        if isinstance(fam, FamilySpec):
            return fam
        name, params = (fam.name, fam.params) if isinstance(fam, FamilyKeywords) else (fam, {})
        if not isinstance(name, str):
            raise ArgumentTypeError(f"family: expected a family name such as 'poly' or a spec "
                                    f"such as Poly(degree=3), got {name!r} "
                                    f"({type(name).__name__})")
        if "rate_window_s" in params:
            raise ConfigError("rate_window_s was removed: 'rate' is a causal filtered derivative "
                              "with a 60 s time constant (thermonet.features.dynamics); use the "
                              "input 'rate_<tau>' (e.g. rate_30) for another time constant")
        valid = spec_class(name).param_names()
        for key in params:
            if key not in valid:
                own = [k for k in inspect.signature(type(self).__init__).parameters
                       if k not in ("self", "family", "hyper")]
                close = difflib.get_close_matches(key, [*valid, *own], n=1)
                raise ConfigError(f"model '{name}': unknown hyper-parameter '{key}' (valid: "
                                  f"{', '.join(valid) or 'none'}), nor an estimator keyword "
                                  f"({', '.join(own)})"
                                  + (f"; did you mean '{close[0]}'?" if close else ""))
        return make_spec(name, params)

    def _resolved_inputs(self, spec: FamilySpec) -> list[str]:
        if self.inputs is not None:
            return input_names(self.inputs, "inputs")
        return list(spec.default_inputs)

    def _check_params(self) -> tuple[TrainConfig, list[str], FamilySpec]:
        """Every constructor argument checked (what :meth:`fit` does first, before it reads
        any data or builds anything): one error naming the argument and what it takes.
        Returns the training settings, the inputs and the family's spec."""
        spec = self._family_spec()      # an unknown family or hyper-parameter, naming them
        if isinstance(self.target, dict):
            for key, mode in self.target.items():
                if not isinstance(key, str) or not key or mode not in MODES:
                    raise ConfigError(f"target: {{{key!r}: {mode!r}}} is not an output kind "
                                      f"or name mapped to one of {', '.join(MODES)}")
        elif not (isinstance(self.target, str) and self.target in _TARGETS):
            raise ConfigError(f"target: {self.target!r} is not one of {', '.join(_TARGETS)} "
                              "or a mapping {output kind or name: channel | zero | at-t-ref}")
        if self.t_ref != "start":
            lo, hi = TEMPERATURE_PLAUSIBLE_C
            seconds(self.t_ref, "t_ref", lo=lo, hi=hi, lo_open=False, unit="°C (or 'start')")
        seconds(self.t_ref_window_min, "t_ref_window_min", hi=1440.0, unit="minutes")
        gap(self.gap_s, "gap_s")
        if self.outputs is not None:
            names_of(self.outputs, "outputs")
        if not isinstance(self.train_on, str) or self.train_on not in ("all", "heating"):
            raise ConfigError(f"train_on: {self.train_on!r} is not 'all' or 'heating'")
        if not isinstance(self.stderr, str) or self.stderr not in STDERR_METHODS:
            raise ConfigError(f"stderr: {self.stderr!r} is not one of "
                              f"{', '.join(STDERR_METHODS)}")
        check_model(self)
        config = self._train_config()
        inputs = self._resolved_inputs(spec)
        # the family's input count and hyper-parameter values, the config's own rule (a
        # built-in's without torch, a plug-in's by building it), before any data is read
        spec.check(len(inputs))
        return config, inputs, spec

    def _outputs_for(self, runs: list[Recording]) -> list[str]:
        return modelled_outputs(names_of(self.outputs, "outputs") or list(runs[0].axes),
                                self.target)

    def fit(self, train: Data, val: Data | None = None, *, track: bool = False,
            tracking_uri: str | None = None, experiment: str = "thermonet") -> DriftEstimator:
        """Fit on ``train``; stop early on ``val`` (held-out runs) when given.

        ``train`` and ``val`` are each a Recording, a list of them or a Dataset.  Without
        ``val`` the loop stops on a training-loss plateau; thermonet never carves
        validation samples at random (:func:`thermonet.api.time_blocks` cuts contiguous
        blocks).  scikit-learn's tools call ``fit(X, y)`` with ``y=None``: the drift is
        in the recordings, so ``y`` takes the place of ``val`` and must be None there.

        The data is checked as ``compare`` checks what it reads
        (:meth:`~thermonet.core.recording.Dataset.validate`): the training runs must span
        at least :data:`~thermonet.core.recording.MIN_TEMPERATURE_SPAN_C` °C together
        and share channels and units; the validation runs must carry the same units and
        may not be training runs themselves.

        With ``val``, :attr:`val_score_` and :attr:`val_ratios_` are ``compare``'s validation
        score and per-axis ratios on it; they, the data digest and the MLflow run travel with
        every save and export.  ``track=True`` (or a ``tracking_uri``) logs the fit to MLflow
        as ``compare`` logs a family: the parameters, the epoch history, ``val/score`` and
        ``fit_seconds``, the checkpoint as artifact ``model/``; :attr:`mlflow_run_id_` is the
        run (store: ``tracking_uri``, else ``sqlite:///mlflow.db`` in the working directory).

        Every argument is checked first, before any data is read or any model built
        (:mod:`thermonet.api.checks`): the constructor's (the family and its
        hyper-parameters' names and values, the inputs — one name alone is a list of one —,
        ``t_ref``, ``target``, ``gap_s``, the training settings...) and ``track`` (``True``
        or ``False`` only: ``"no"`` is refused, never read as true), ``tracking_uri`` (None
        or a URI) and ``experiment`` (a name).  The constructor itself only stores, as
        scikit-learn asks, so ``set_params`` and ``clone`` never raise on a value.

        Returns
        -------
        DriftEstimator
            ``self``, fitted.

        Raises
        ------
        ConfigError
            Unknown family, input, hyper-parameter, target, ``train_on`` or training setting.
        InputError
            Data that cannot be trained on (too narrow a temperature span, mixed units).
        FitError
            The data cannot carry the family (reason given).
        """
        if self.family == PER_AXIS:
            raise ConfigError("family 'per-axis': a model per axis is chosen by compare "
                              "(thermonet.api.compare) among fitted candidates, not fitted by "
                              "a DriftEstimator; load its checkpoint with DriftEstimator.load")
        config, inputs, family = self._check_params()
        flag(track, "fit(track)")
        text(tracking_uri, "fit(tracking_uri)", none=True, rule="an MLflow tracking URI")
        text(experiment, "fit(experiment)", rule="an MLflow experiment name")
        mode_of(self).fit(self, train, val, config=config, inputs=inputs, family=family,
                          track=track, tracking_uri=tracking_uri, experiment=experiment)
        return self

    def _training_data(self, train: Data, val: Data | None
                       ) -> tuple[list[Recording], list[Recording] | None, list[str], Target]:
        """The training and validation runs, checked (outputs present, no validation run
        that trains, one unit per output), the outputs and their targets resolved as compare
        resolves them (:mod:`thermonet.features.target`: a reference channel, else zero for a
        gyro, else the change from T_ref — an accelerometer's gravity is no drift)."""
        from ..training.parts import targets_for  # lazy: loads yaml

        runs = runs_of(train, "fit(train)")
        val_runs = None if val is None else runs_of(val, "fit(val)")
        outputs = self._outputs_for(runs)
        for r in runs:
            needs_outputs(r, outputs, "fit(train)")
        for v in val_runs or []:
            needs_outputs(v, outputs, "fit(val)")
            for r in runs:
                if same_run(v, r):
                    raise ThermonetError(f"fit(val): run '{v.run_id}' is also a training run "
                                         "(validate on a run the model is not fitted on)")
        Dataset(runs).validate("fit(train)")
        targets = targets_for(Dataset(runs + list(val_runs or [])), self.target, outputs,
                              source="DriftEstimator(target)")
        for v in val_runs or []:
            same_units(v, runs[0].units, "fit(val)",
                       f"the training run '{runs[0].run_id}' has it")
        return runs, val_runs, outputs, targets

    def _learned(self, result: Any, spec: FeatureSpec, targets: Target, outputs: list[str],
                 runs: list[Recording], val_runs: list[Recording] | None,
                 config: TrainConfig) -> None:
        """The learned state (names ending in ``_``) from one split's fit."""
        self.model_: DriftModels = result.model
        self.spec_: FeatureSpec = spec
        self.targets_: Target = targets
        self.n_features_in_: int = len(spec.inputs)
        self.outputs_: list[str] = outputs
        self.units_: dict[str, str] = output_units(outputs, runs[0].units)
        self.signal_units_: dict[str, str] = {p: runs[0].units.get(p, "")
                                              for p in runs[0].proxies}
        self.device_id_: str = runs[0].device_id
        self.data_source_: dict[str, Any] = data_source(runs, val_runs)
        self.train_config_: TrainConfig = config
        self.history_: list[dict[str, Any]] = list(result.history)
        self.best_epoch_: int = int(result.best_epoch)
        self.best_val_: float | None = result.best_val_loss
        self.n_params_: int = int(result.n_params)
        self.tuned_: dict[str, Any] = dict(result.model.family.tuned())
        self.fit_seconds_: float = float(result.fit_seconds)
        self.val_ratios_: dict[str, float] | None = None
        self.val_score_: float | None = None
        if val_runs is not None:   # compare's validation score: mean over axes of RMS ratios
            ratios = np.sqrt(self._ratios(val_runs, "fit(val)"))
            self.val_ratios_ = {a: float(r) for a, r in zip(outputs, ratios, strict=True)}
            self.val_score_ = float(np.mean(ratios))
        self.mlflow_run_id_: str = ""
        self.band_: Any = None      # only compare's out-of-fold residuals give a band

    def _parameter_table(self, parts: Any, config: TrainConfig) -> None:
        """``parameters_`` and ``covariance_``: the coefficients with their standard errors
        (``stderr``'s method) on the training part's arrays."""
        from ..training.parts import fit_arrays  # lazy: loads yaml

        arrays = [fit_arrays(q, config.average_s) for q in parts.train]
        self.parameters_: pd.DataFrame
        self.covariance_: dict[str, np.ndarray]
        self.parameters_, self.covariance_ = parameter_table(
            self.model_, self.units_, self.signal_units_,
            train=(np.concatenate([a[0] for a in arrays]), np.concatenate([a[1] for a in arrays]),
                   [a[0].shape[0] for a in arrays]),
            method=self.stderr, seed=config.seed)

    # ------------------------------------------------------ load (thermonet.api.persistence)
    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> DriftEstimator:
        """An estimator fitted as the checkpoint at ``path`` (also one ``compare`` wrote)."""
        return load(cls, a_path(path, "load(path)"))  # type: ignore[arg-type]
