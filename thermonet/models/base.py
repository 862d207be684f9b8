"""The contract every model family follows (:class:`Family`) and what the families share.

A :class:`Family` is the core of one model family.  It works in
**standardised** units: features :math:`z = (x - \\bar x)/s_x` in, standardised
drift :math:`(y - \\bar y)/s_y` out.  :class:`~thermonet.models.drift_model.DriftModel`
wraps it into a drift model of physical signals (the clamp, the joint guard, the features,
the standardisation, the target): see :mod:`thermonet.models.drift_model`.

Training runs the family on the standardised feature matrix
(:meth:`Family.forward`); evaluation runs :meth:`Family.drift`, axis-major, the
de-standardisation folded into its last matrix product.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from ..core.errors import ConfigError, ExportError, FitError
from .cgen import CBody, c_constant_bytes
from .lstsq import NormalEquations, least_squares
from .specs import FamilySpec, declared_spec, spec_for_class

__all__ = ["TINY", "LOG_CLIP", "Family", "distinct_levels", "as_numpy",
           "least_squares", "NormalEquations", "output_layer", "check_output_shape"]

#: Guard for every denominator (lmfit's ``max(tiny, sigma)``); float32-safe:
#: its square (1e-12) is still a normal float32.
TINY = 1e-6
#: Bound on a log-parametrised quantity before ``exp`` (e^±60 stays a normal float32).
LOG_CLIP = 60.0


def as_numpy(a: object) -> np.ndarray:
    """float64 copy of a tensor or array."""
    if isinstance(a, torch.Tensor):
        return a.detach().cpu().double().numpy()
    return np.asarray(a, dtype=np.float64)


def distinct_levels(values: np.ndarray, resolution: float = 0.005, *,
                    cap: int | None = None) -> int:
    """Number of distinct levels of a 1-D series.

    Sorted values are grouped greedily: a group holds every value within
    ``resolution`` × the series' span of its smallest member.  Sensor noise
    around one soak temperature thus counts as one level, while a ramp counts
    as up to ``1/resolution + 1`` levels.  A constant series has one level.

    ``cap``: counting stops there (``min(levels, cap)``) — what a family's "at least k
    levels" check needs, without walking a ramp's up to 201 groups on every fit.
    """
    v = np.sort(np.asarray(values, dtype=np.float64).ravel())
    v = v[np.isfinite(v)]
    if v.size == 0:
        return 0
    tol = resolution * float(v[-1] - v[0])
    if tol <= TINY * max(1.0, float(np.max(np.abs(v)))) * resolution:
        return 1
    levels, i = 0, 0
    top = v.size if cap is None else cap
    while i < v.size and levels < top:  # at most 1/resolution + 1 iterations
        levels += 1
        i = int(np.searchsorted(v, v[i] + tol, side="right"))
    return levels


def output_layer(weight: torch.Tensor, bias: torch.Tensor, y_std: torch.Tensor,
                 y_mean: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """A last linear layer's weights (A, K) and bias (A,) in output units: the
    de-standardisation :math:`y = \\hat y_z s_y + \\bar y` folded in, one row per axis
    (the axis-major layout of :meth:`Family.drift`: ``addmm(b[:, None], w, rows)``)."""
    return weight * y_std[:, None], bias * y_std + y_mean


#: Rows of the probe :func:`check_output_shape` runs (a few: a wrong row count shows).
PROBE_ROWS = 7


def _shape_said(out: object) -> str:
    return str(tuple(out.shape)) if isinstance(out, torch.Tensor) else type(out).__name__


def check_output_shape(fam: Family, z: torch.Tensor, label: str) -> None:
    """Refuse a family whose output has the wrong shape, before it is fitted further.

    Run on up to :data:`PROBE_ROWS` rows of the standardised features ``z`` (N, F) after
    :meth:`Family.initialize`: :meth:`Family.forward` must give an (N, A) tensor and, for a
    family evaluated sample by sample, :meth:`Family.drift` an (A, N) one, A the family's
    ``n_outputs`` — an (N, 1) drift for three axes would otherwise be broadcast over them,
    fitted and scored.  Every family is probed, built-in or plug-in; a wrong shape, or a
    probe that raises, is a :class:`~thermonet.core.errors.FitError` naming ``label``.
    """
    zp = torch.as_tensor(z)[:PROBE_ROWS]
    n, a = int(zp.shape[0]), fam.n_outputs
    checks: list[tuple[str, Any, tuple[int, int]]] = [("forward", lambda: fam(zp), (n, a))]
    if not fam.recurrent:
        ones = torch.ones(a, dtype=zp.dtype)
        checks.append(("drift", lambda: fam.drift(list(zp.unbind(1)), ones, 0.0 * ones),
                       (a, n)))
    for what, call, want in checks:
        try:
            with torch.no_grad():
                out = call()
        except Exception as err:
            raise FitError(f"model '{label}': its {what}() failed on {n} rows of "
                           f"{fam.n_inputs} input(s) ({type(err).__name__}: {err})") from None
        if not isinstance(out, torch.Tensor) or tuple(out.shape) != want:
            raise FitError(f"model '{label}': its {what}() gave {_shape_said(out)} for {n} rows "
                           f"and {a} output axes, expected a tensor of shape {want}; refusing "
                           "it before fitting (a family must give one column per axis)")


class Family(nn.Module):
    """Core of one model family, in standardised units.

    A built-in family names its spec (``spec = specs.Poly``,
    :mod:`thermonet.models.specs`), the one source of its ``name``, ``max_inputs``,
    ``default_inputs``, hyper-parameters, their defaults and their rules: its constructor
    takes ``**hyper`` and hands them to :meth:`take_hyper` (checked, the defaults filled
    in, each stored under its name), and :meth:`hyper` states them back.  A plug-in may
    instead set ``name`` and ``max_inputs`` and take its hyper-parameters as keyword-only
    arguments (the generic spec is read from that signature) and implement :meth:`hyper`.
    Either way the hyper-parameters are turned into parameters of a shape fixed by
    ``n_inputs``, ``n_outputs`` and the hyper-parameters so a checkpoint's ``state_dict``
    loads into a fresh instance; every family implements :meth:`forward`,
    :meth:`initialize` and :meth:`check_fittable`.

    Parameters
    ----------
    n_inputs : int
        Number of features F.
    n_outputs : int
        Number of output axes A.
    """

    name: ClassVar[str] = ""
    max_inputs: ClassVar[int | None] = None
    #: Inputs a config gets when it names none (study 003's RBF: ``[dT, dT2]``).
    default_inputs: ClassVar[list[str]] = ["dT"]
    #: Whether the family carries a state from sample to sample (the GRU): it is then
    #: evaluated on a stream with time (:mod:`thermonet.models.sequence`), trained on
    #: sequences, and exported with its state as explicit inputs and outputs.
    recurrent: ClassVar[bool] = False
    #: The family's spec class (:mod:`thermonet.models.specs`), where it has one: a built-in
    #: names it (``spec = specs.Poly``); a class that declares its hyper-parameters in its own
    #: body (``knee: float = param(default=25.0, rule=number(...))``) gets one made from
    #: them (:func:`~thermonet.models.specs.declared_spec`).  ``name``, ``max_inputs`` and
    #: ``default_inputs`` are then the spec's.
    spec: ClassVar[type[FamilySpec] | None] = None

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        spec = vars(cls).get("spec") or declared_spec(cls)
        if spec is not None:   # the spec is the one source of the name and the inputs
            cls.spec = spec
            cls.name, cls.max_inputs = spec.key, spec.max_inputs
            cls.default_inputs = list(spec.default_inputs)

    def __init__(self, *, n_inputs: int, n_outputs: int) -> None:
        super().__init__()
        if int(n_inputs) < 1 or int(n_outputs) < 1:
            raise ConfigError(f"model '{self.name}' needs at least one input and one output, "
                              f"got {n_inputs} inputs, {n_outputs} outputs")
        if self.max_inputs is not None and n_inputs > self.max_inputs:
            raise ConfigError(f"model '{self.name}' takes at most {self.max_inputs} input(s), "
                              f"got {n_inputs}")
        self.n_inputs = int(n_inputs)
        self.n_outputs = int(n_outputs)

    def initialize(self, x: torch.Tensor, y: torch.Tensor, *, seed: int = 0,
                   x_mean: np.ndarray | None = None, x_std: np.ndarray | None = None) -> None:
        """Closed-form or heuristic start from standardised data.

        Parameters
        ----------
        x : (N, F) standardised features
        y : (N, A) standardised targets
        seed : int
            For anything random (k-means).  Draw from generators made from it
            (numpy, scikit-learn ``random_state``), never from torch's or numpy's
            global random state: the families of a comparison may be fitted side by
            side in threads (:func:`thermonet.workflows.compare.family_workers`).
        x_mean, x_std : (F,)
            The standardisation, for hyper-parameters given in physical
            feature units (the fuzzy universe).
        """
        raise NotImplementedError

    def check_fittable(self, x: torch.Tensor) -> str | None:
        """Why this data cannot carry the family, or None when it can."""
        return None

    def take_hyper(self, given: Mapping[str, Any]) -> dict[str, Any]:
        """The hyper-parameters given to the constructor, through the family's :attr:`spec`
        (:meth:`~thermonet.models.specs.FamilySpec.resolve`: an unknown name refused, the
        defaults filled in, every value checked against its rule), each stored as an
        attribute of the same name; returns them."""
        spec = type(self).spec
        if spec is None:
            raise TypeError(f"{type(self).__name__} declares no spec: take its hyper-parameters "
                            "as keyword-only arguments instead")
        values = spec.resolve(given)
        for key, value in values.items():
            setattr(self, key, value)
        return values

    def hyper(self) -> dict[str, Any]:
        """JSON-able hyper-parameters; ``type(self)(n_inputs=, n_outputs=, **hyper())``
        rebuilds the same architecture.  By default each of the spec's hyper-parameters
        (:meth:`take_hyper` stored them); for a family without a spec, each of its
        constructor's keyword-only arguments (the generic spec's,
        :func:`~thermonet.models.specs.spec_for_class`) read back from the attribute of the
        same name — one it does not store is a :class:`ConfigError` (a checkpoint could not
        rebuild the family): store it under its name, or override this method."""
        cls = type(self)
        if cls.spec is not None:
            return {k: getattr(self, k) for k in cls.spec.param_names()}
        names = spec_for_class(self.name or cls.__name__, cls).param_names()
        missing = [k for k in names if not hasattr(self, k)]
        if missing:
            raise ConfigError(
                f"model family '{self.name or cls.__name__}': keyword-only argument "
                f"'{missing[0]}' of {cls.__name__}.__init__ is not stored as an attribute "
                f"of that name, so a checkpoint cannot rebuild the family; store it "
                f"(self.{missing[0]} = {missing[0]}) or define hyper()")
        return {k: getattr(self, k) for k in names}

    def coefficient_degree(self, inputs: Sequence[str]) -> int:
        """Degree of the polynomial in (T − t0) that summarises this family's curve as
        physical coefficients (a fleet's per-unit ``c0``, ``c1``, ...): a cubic, unless the
        family *is* a polynomial in the temperature alone, whose own degree is then exact."""
        return 3

    def drift(self, z: Sequence[torch.Tensor], y_std: torch.Tensor,
              y_mean: torch.Tensor) -> torch.Tensor:
        """Drift in output units, **axis-major** (A, N), from standardised feature
        columns (each (N,)).

        The same function as ``(forward(z) * y_std + y_mean).T``, laid out for
        evaluation: families fold ``y_std``/``y_mean`` into their last matrix
        product, and every intermediate is a row over the N samples — a (K, N)
        matrix broadcasts a per-row constant over N contiguous values, which
        onnxruntime runs as one vector operation per row, where an (N, K) matrix
        with a (K,) constant costs one short call per sample (measured: the
        float64 constant's Add took 26 % of the RBF graph in the (N, A) layout).
        Contract: a NaN in ``z[0]`` gives NaN on every axis of that sample
        (how :class:`DriftModel` marks a non-finite signal; the export's parity
        check verifies it).  This default stacks the columns and calls :meth:`forward`.
        """
        return (self(torch.stack(list(z), dim=1)) * y_std + y_mean).T

    def emit_c(self, prefix: str, y_std: torch.Tensor, y_mean: torch.Tensor) -> CBody:
        """The C99 constants and body of :meth:`drift` (see :mod:`.cgen`).

        A family without one cannot be exported as a C header.
        """
        raise ExportError(f"model family '{self.name}' has no C emitter")

    def trainable(self) -> bool:
        """Whether the training loop refines :meth:`initialize`'s fit by gradient descent
        (False: the closed-form fit is final, the loop records epoch 0 only)."""
        return True

    def tuned(self) -> dict[str, Any]:
        """Hyper-parameters the family chose itself on its training data (inner
        cross-validation), JSON-able; empty when it chooses none."""
        return {}

    def penalty(self) -> torch.Tensor | None:
        """A regularisation term the training loop adds to the loss it minimises, or None.

        A scalar tensor in the loss's units (the mean squared error in standardised units)
        built from this family's parameters, so its gradient reaches them: the MLP's
        ``weight_decay`` is :math:`\\lambda \\sum W^2` over its weight matrices.  Only the
        optimizer sees it: the losses the loop records and early stopping monitors stay
        the plain mean squared error, comparable between families.
        """
        return None

    def n_effective(self) -> int:
        """Parameters the fitted family computes with (its trainable ones; a family whose fit
        can switch a part off — the RBF's ridge ∞ — counts what is left)."""
        return int(sum(p.numel() for p in self.parameters() if p.requires_grad))

    def op_count(self) -> tuple[int, int] | None:
        """``(ops, transcendentals)`` of one sample of :meth:`emit_c`'s body, counted from
        this family's own shapes (see :meth:`cost`); None where the family does not count."""
        return None

    def cost(self) -> dict[str, int | None]:
        """What one sample costs on board: the family's share of the C header.

        ``ops_per_sample``
            Floating-point operations of :meth:`emit_c`'s body for one sample (features
            ``z`` in, drift ``y`` out), counted from the model's own shapes
            (:meth:`op_count`): a multiply-add (one term of :func:`~.cgen.c_affine`, fused
            where the FPU fuses) is one, so is a lone multiply, add, division or clamp
            (``max``), and so is each call of a transcendental (``exp``, ``expm1``).
        ``transcendentals``
            The calls of a transcendental among them (each costs tens of instructions on a
            Cortex-M4F: the header's polynomial ``expf``).
        ``c_bytes``
            The constant data of the family's arrays in the header
            (:func:`~.cgen.c_constant_bytes` of :meth:`emit_c`'s constants).

        Not counted: integer work (loop counters, indices), comparisons and copies, and the
        part of the header every family shares (clamp the signals, features, standardise,
        add the drift constant, ``raw − drift``).  None where the family does not count
        (a plug-in without :meth:`op_count`) or has no C emitter.
        """
        counted = self.op_count()
        ones = torch.ones(self.n_outputs)
        try:  # the shapes, not the values, decide the size: any scaling will do
            with torch.no_grad():
                body = self.emit_c("thermonet", ones, 0.0 * ones)
            c_bytes: int | None = c_constant_bytes(body.constants)
        except ExportError:
            c_bytes = None
        return {"ops_per_sample": None if counted is None else int(counted[0]),
                "transcendentals": None if counted is None else int(counted[1]),
                "c_bytes": c_bytes}

    def polynomial_form(self) -> np.ndarray | None:
        """Coefficients (A, degree + 1), ascending in the one standardised input z,
        when this fitted family *is* a polynomial in one input; None otherwise.

        Exporters that need a polynomial (PX4's and ArduPilot's parameter files)
        ask for it here instead of checking the family's name.
        """
        return None

    def extra_repr(self) -> str:
        try:
            hyper: object = self.hyper()
        except ConfigError:   # a plug-in that does not store a hyper-parameter: said at save
            hyper = "{?}"
        return f"n_inputs={self.n_inputs}, n_outputs={self.n_outputs}, {hyper}"
