"""A fitted model's parameters in physical units, with standard errors (``est.parameters_``).

One row per axis and named parameter: columns ``axis, name, value, stderr, unit, note``.
``note`` names the method that computed ``stderr`` where it was computed (``ols`` or
``block-bootstrap``, :data:`STDERR_METHODS`), followed by ``; within 2 SE of zero``
(:data:`NEAR_ZERO`) for a coefficient with ``|value| < 2 stderr`` — one the data cannot
tell from none; it is :data:`FIXED` for a coefficient fixed by construction (stderr 0), and
otherwise says why ``stderr`` is NaN (:data:`NO_SE`).

The standard errors are computed once, on the rows the model was fitted on, and sealed into
its checkpoint with the covariance (``extra.parameters``, :func:`sealed_parameters`): a model
loaded with ``DriftEstimator.load`` — or one ``compare`` returns, which computes them for every
family it fits, as ``DriftEstimator.fit`` of the same runs does — states what the fit stated.

Polynomials in one input (``poly``, ``linear`` and any family whose
:meth:`~thermonet.models.Family.polynomial_form` says it is one)
    ``c0 … cN``, the coefficients of

    .. math:: d_a(x) = \\sum_{k=0}^{N} c_{a,k}\\,(x - x_{ref})^k

    in output unit / input unit^k (the output unit alone for a proxy without a unit, ``1``),
    with :math:`x_{ref}` = :math:`T_{ref}` for ``T`` and ``dT`` (unit °C), the proxy's
    reference for ``d_<proxy>``, 0 for a dynamic input.
    The values are the model's own (its float32 parameters, every scaling and the
    float64 offset included), read off the model evaluated in float64 at ``N + 1``
    Chebyshev points of the trained range: exact for a polynomial, to rounding.

    **Standard errors** are those of ordinary least squares on the data the model was
    fitted on (after ``train.average_s`` averaging):

    .. math:: \\operatorname{Cov}(c_a) = s_a^2\\,(D^T D)^{-1},\\qquad
              s_a^2 = \\frac{\\sum_i r_{a,i}^2}{n - (N + 1)}

    with :math:`D` the design :math:`[(x_i - x_{ref})^k]` and :math:`r` the model's
    residuals on those samples; ``est.covariance_[axis]`` is the matrix.  It assumes
    independent residuals of equal variance.  **The residuals of a time series are not
    independent**: slow noise (bias instability, random walk) and a model that does not
    quite fit leave residuals correlated over minutes, and the least-squares standard
    errors are then too small — by about :math:`\\sqrt{\\tau_c / \\Delta t}` for a
    correlation time :math:`\\tau_c` and sampling interval :math:`\\Delta t`.  Read them as
    a lower bound unless the residuals are white (check
    ``np.corrcoef(r[:-1], r[1:])``), or judge the model on held-out runs
    (``thermonet.compare``), which does not rest on this assumption.

    On an ``at-t-ref`` axis (an accelerometer: the change from :math:`T_{ref}` is the drift,
    gravity is not) the model is zero at :math:`x_{ref}` by construction: ``c0`` is 0 with
    stderr 0, and the residuals are taken about their mean (the unknown constant).

    ``DriftEstimator(..., stderr="block-bootstrap")`` does not assume white residuals: a
    moving-block residual bootstrap (Künsch 1989, :func:`block_bootstrap_cov`) keeps the
    design, resamples the residuals in contiguous blocks inside each run — each block
    :func:`block_length` samples long, twice the residuals' integrated autocorrelation time
    (at least :math:`n^{1/3}`) — adds them to the fitted curve and refits, :data:`N_BOOTSTRAP`
    times (seeded by the training seed); the covariance is that of the refitted
    coefficients.  With white residuals it agrees with least squares; with correlated ones
    it is larger, as it should be (``tests/test_api_contract.py`` measures both against the
    spread over seeds).  It still needs many blocks: a run a few correlation times long
    cannot say how uncertain its curve is.

    The training loop may polish the closed-form fit; the covariance is that of the
    least-squares solution about the coefficients reported.

Lorentz (``lorentz``)
    ``y0`` (output unit), ``amplitude`` :math:`A` (output unit × input unit: the area of
    Origin's curve :math:`y_0 + \\frac{2A}{\\pi}\\frac{w}{4(x - x_c)^2 + w^2}`), ``centre``
    :math:`x_c` (°C for ``T`` and ``dT``: the absolute temperature; input units otherwise)
    and ``width`` :math:`w` (FWHM, input units).
RBF (``rbf``)
    ``bias`` and ``w<k>`` (output unit), and ``centre<k>`` (input units: °C for ``T``,
    °C about :math:`T_{ref}` for ``dT``) and ``sigma<k>`` (input units) of each
    Gaussian, with one input; in standardised units (unit ``standardised``) with several.
Other families
    Their torch parameters as they are stored: **not physical quantities** (unit
    ``standardised``, axis empty, note :data:`NO_SE` ``["standardised"]``: the family works on
    standardised features and targets, :mod:`thermonet.models.base`); the model's curve, not
    its weights, is what such a family reports.

Every family but the polynomials reports ``stderr`` NaN: no covariance is computed for
a nonlinear fit (a profile or a bootstrap would be needed, and is not made here).
"""

from __future__ import annotations

import copy
import math
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import InputError
from ..features.inputs import TEMPERATURE, dynamic_signal, parse_feature
from .block_bootstrap import STDERR_METHODS, block_bootstrap_cov

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["parameter_table", "parameter_rows", "polynomial_coefficients", "sealed_parameters",
           "with_sealed", "COLUMNS", "FIXED", "NO_SE", "NEAR_ZERO"]

#: The columns of ``est.parameters_``.
COLUMNS = ["axis", "name", "value", "stderr", "unit", "note"]

#: ``note`` of a coefficient fixed by construction (``c0`` of an ``at-t-ref`` axis: stderr 0).
FIXED = "fixed"
#: Added to ``note`` (after the method) where a coefficient lies within 2 standard errors of 0.
NEAR_ZERO = "within 2 SE of zero"
#: ``note`` where no standard error can be computed, by reason (stderr NaN).
NO_SE = {
    "nonlinear": "no standard error: nonlinear fit (no covariance computed)",
    "standardised": "not a physical parameter: the family's internal weight on standardised "
                    "features and targets (no standard error)",
    "raw": "no standard error: axis left raw (the model does not compensate it)",
    "samples": "no standard error: no more samples than coefficients",
    "unstored": "no standard error: this checkpoint holds none (written before they were "
                "stored with the model)",
}


def _input_of(model: Any, signal_units: dict[str, str]) -> tuple[str, float, str]:
    """The one signal of a one-input model, its expansion point and its unit."""
    signal, _, _ = parse_feature(model.inputs[0])
    spec = model.spec
    dyn = dynamic_signal(signal)
    if signal == TEMPERATURE or (dyn is not None and dyn.is_temperature):
        return signal, float(spec.t_ref) if spec.t_ref is not None else 0.0, "°C"
    if dyn is not None:
        return signal, 0.0, "°C/min" if dyn.kind == "rate" else "°C"
    return signal, float(spec.proxy_ref.get(signal, 0.0)), signal_units.get(signal, "") or "1"


def _drift64(model: Any, signals: np.ndarray) -> np.ndarray:
    """The model's drift in float64 (its float32 parameters evaluated in float64)."""
    import torch

    m = copy.deepcopy(model).double().eval()
    with torch.no_grad():
        return np.asarray(m.drift64(torch.as_tensor(np.asarray(signals, dtype=np.float64)))
                          .numpy(), dtype=np.float64)


#: Input units that are no unit: a coefficient per such input is in the output's unit.
DIMENSIONLESS = ("", "1")


def _power_unit(out: str, unit: str, k: int) -> str:
    """Unit of the k-th coefficient: output unit / input unit^k — the output's unit alone
    where the input has none (a proxy of unit ``1``: ``rad/s``, not ``rad/s/1``)."""
    if k == 0 or unit in DIMENSIONLESS:
        return out
    return f"{out}/{unit}" if k == 1 else f"{out}/{unit}^{k}"


def polynomial_coefficients(model: Any, signal_units: dict[str, str] | None = None
                            ) -> tuple[np.ndarray, float, str] | None:
    """``(coefficients (A, N + 1), x_ref, input unit)`` of a model that is a polynomial in
    one input, ascending in :math:`x - x_{ref}`; None for any other model."""
    form = model.family.polynomial_form()
    if form is None or len(model.signals) != 1:
        return None
    degree = int(np.asarray(form).shape[1]) - 1
    signal, ref, unit = _input_of(model, signal_units or {})
    lo, hi = float(model.sig_lo[0]), float(model.sig_hi[0])
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        return None
    # Chebyshev points of the trained range (clamped outside it: the polynomial lives inside)
    n = degree + 1
    nodes = 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.cos(np.pi * (np.arange(n) + 0.5) / n)
    drift = _drift64(model, nodes[:, None])                      # (n, A)
    h = max(abs(lo - ref), abs(hi - ref), 1e-12)                  # scale: a well-posed solve
    v = np.vander((nodes - ref) / h, n, increasing=True)
    coef = np.linalg.solve(v, drift) / (h ** np.arange(n))[:, None]  # (n, A)
    return coef.T, ref, unit


def _polynomial_rows(model: Any, units: dict[str, str], signal_units: dict[str, str],
                     train: tuple[np.ndarray, ...] | None, method: str = "ols",
                     seed: int = 0) -> tuple[list[dict[str, Any]], dict[str, np.ndarray]] | None:
    got = polynomial_coefficients(model, signal_units)
    if got is None:
        return None
    coef, ref, unit = got
    n = coef.shape[1]
    cov: dict[str, np.ndarray] = {}
    stderr = np.full(coef.shape, np.nan)
    notes = np.full(coef.shape, NO_SE["unstored"], dtype=object)
    fixed = np.array([m == "at-t-ref" for m in model.target_modes])
    if train is not None:
        notes[:] = NO_SE["samples"]
        signals, target = (np.asarray(a, dtype=np.float64) for a in train[:2])
        runs = list(train[2]) if len(train) > 2 else [signals.shape[0]]
        ok = np.all(np.isfinite(signals), axis=1) & np.all(np.isfinite(target), axis=1)
        if not ok.all():  # a run's share of the samples dropped
            bounds = np.cumsum([0] + runs)
            runs = [int(ok[s:e].sum()) for s, e in zip(bounds[:-1], bounds[1:], strict=True)]
        signals, target = signals[ok], target[ok]
        if signals.shape[0] > n:
            u = signals[:, 0] - ref
            h = max(float(np.max(np.abs(u))), 1e-12)
            d = np.vander(u / h, n, increasing=True)
            unscale = np.outer(h ** np.arange(n), h ** np.arange(n))
            fitted = _drift64(model, signals)
            resid = target - fitted
            # an at-t-ref axis's target holds an unknown constant (gravity) the model does
            # not predict: its residuals are taken about their mean, and its c0 is 0 by
            # definition (the change from x_ref), with no uncertainty
            resid[:, fixed] -= resid[:, fixed].mean(axis=0)
            fitted[:, fixed] += (target - fitted)[:, fixed].mean(axis=0)
            if method == "block-bootstrap":
                covs = block_bootstrap_cov(d, fitted, resid, runs, seed=seed)
            else:
                inv = np.linalg.pinv(d.T @ d)
                inv = 0.5 * (inv + inv.T)
                s2 = np.sum(resid ** 2, axis=0) / (signals.shape[0] - n)
                covs = [s2[j] * inv for j in range(resid.shape[1])]
            for j, axis in enumerate(model.outputs):
                cov[axis] = covs[j] / unscale
                if fixed[j]:
                    cov[axis][0, :] = cov[axis][:, 0] = 0.0
                stderr[j] = np.sqrt(np.clip(np.diag(cov[axis]), 0.0, None))
                notes[j] = ""
    notes[fixed, 0] = FIXED           # c0 of an at-t-ref axis: 0 by definition, stderr 0
    stderr[fixed, 0] = 0.0
    for j, keep in enumerate(getattr(model, "compensated_axes", [True] * len(model.outputs))):
        if not keep:                  # masked: the model's curve there is 0, not a fit
            stderr[j], notes[j] = np.nan, NO_SE["raw"]
            cov.pop(model.outputs[j], None)
    rows = [{"axis": axis, "name": f"c{k}", "value": float(coef[j, k]),
             "stderr": float(stderr[j, k]), "unit": _power_unit(units.get(axis, ""), unit, k),
             "note": str(notes[j, k])}
            for j, axis in enumerate(model.outputs) for k in range(n)]
    return rows, cov


def _lorentz_rows(model: Any, units: dict[str, str], signal_units: dict[str, str],
                  warn: bool = True
                  ) -> list[dict[str, Any]]:
    import torch

    fam = model.family
    _, ref, unit = _input_of(model, signal_units)
    relative = model.inputs[0] != "T" and unit == "°C"          # dT: centre about T_ref
    with torch.no_grad():
        scale, shift = (t.double() for t in model.output_scaling())
        y0, k, xc, hh = (np.asarray(t.double().numpy()) for t in fam.output_form(scale, shift))
    const = np.asarray(model.constant().double().numpy())
    xm, xs = float(model.x_mean[0]), float(model.x_std[0])
    width = 2.0 * np.sqrt(hh) * xs                                # FWHM in input units
    amplitude = k * xs * xs * 2.0 * np.pi / np.maximum(width, 1e-300)
    centre = xc * xs + xm + (ref if relative else 0.0)
    lo, hi = float(model.sig_lo[0]), float(model.sig_hi[0])
    span = hi - lo if math.isfinite(hi - lo) and hi > lo else math.nan
    drift_pp = np.ptp(_drift64(model, np.linspace(lo, hi, 65)[:, None]), axis=0) \
        if math.isfinite(span) else np.full(len(model.outputs), np.nan)
    rows = []
    for j, axis in enumerate(model.outputs):
        out = units.get(axis, "")
        note = NO_SE["nonlinear"]
        why = implausible_lorentz(float(amplitude[j]), float(width[j]), span,
                                  float(drift_pp[j]), unit, out)
        if why:
            note = f"{why}; {note}"
            if warn:
                warnings.warn(f"lorentz on {axis}: {why}", UserWarning, stacklevel=2)
        for name, value, u in (("y0", y0[j] + const[j], out),
                               ("amplitude", amplitude[j],
                                out if unit in DIMENSIONLESS else f"{out}*{unit}"),
                               ("centre", centre[j], unit), ("width", width[j], unit)):
            rows.append({"axis": axis, "name": name, "value": float(value),
                         "stderr": math.nan, "unit": u, "note": note})
    return rows


#: A Lorentz width more than this many times the trained span is implausible as a peak.
LORENTZ_MAX_WIDTH_SPANS = 10.0
#: An amplitude over the span more than this many times the drift's range is implausible.
LORENTZ_MAX_AMPLITUDE_DRIFTS = 1000.0


def implausible_lorentz(amplitude: float, width: float, span: float, drift_pp: float,
                        unit: str, out: str) -> str:
    """Why a fitted Lorentz's constants are not a physical peak ("" if they may be): a width
    far beyond the data (:data:`LORENTZ_MAX_WIDTH_SPANS` × the trained span) or an amplitude
    (output × input unit) that, spread over the span, is :data:`LORENTZ_MAX_AMPLITUDE_DRIFTS`
    times the drift's peak-to-peak there — the flank of a peak far outside the data, whose
    curve inside the range is fine but whose constants mean nothing."""
    if not (math.isfinite(span) and span > 0):
        return ""
    why = []
    if width > LORENTZ_MAX_WIDTH_SPANS * span:
        why.append(f"width {width:.4g} {unit} is {width / span:.0f}× the trained span "
                   f"{span:.4g} {unit}")
    if math.isfinite(drift_pp) and drift_pp > 0 and \
            abs(amplitude) / span > LORENTZ_MAX_AMPLITUDE_DRIFTS * drift_pp:
        why.append(f"amplitude {amplitude:.4g} {out}*{unit} is {abs(amplitude) / span / drift_pp:.0f}× "
                   f"the drift's range ({drift_pp:.3g} {out}) over the span")
    return ("implausible as physical constants: " + " and ".join(why)) if why else ""


def _rbf_rows(model: Any, units: dict[str, str], signal_units: dict[str, str]
              ) -> list[dict[str, Any]] | None:
    import torch

    fam = model.family
    if fam.n_inputs != 1 or getattr(fam, "tail", 0):
        return None
    _, _, unit = _input_of(model, signal_units)
    xm, xs = float(model.x_mean[0]), float(model.x_std[0])
    with torch.no_grad():
        scale, shift = (np.asarray(t.double().numpy()) for t in model.output_scaling())
        centres = np.asarray(fam.centres.double().numpy())[:, 0] * xs + xm
        sigma = np.exp(np.asarray(fam.log_sigma.double().numpy())) * xs
        w = np.asarray(fam.weight.double().numpy()) * scale[:, None]
        b = np.asarray(fam.bias.double().numpy()) * scale + shift
    const = np.asarray(model.constant().double().numpy())
    rows = []
    for j, axis in enumerate(model.outputs):
        out = units.get(axis, "")
        note = NO_SE["nonlinear"]
        rows.append({"axis": axis, "name": "bias", "value": float(b[j] + const[j]),
                     "stderr": math.nan, "unit": out, "note": note})
        for c in range(centres.size):
            rows += [{"axis": axis, "name": f"centre{c}", "value": float(centres[c]),
                      "stderr": math.nan, "unit": unit, "note": note},
                     {"axis": axis, "name": f"sigma{c}", "value": float(sigma[c]),
                      "stderr": math.nan, "unit": unit, "note": note},
                     {"axis": axis, "name": f"w{c}", "value": float(w[j, c]),
                      "stderr": math.nan, "unit": out, "note": note}]
    return rows


def _raw_rows(model: Any) -> list[dict[str, Any]]:
    """The family's torch parameters as stored (standardised units), one row per entry."""
    rows = []
    for pname, p in model.family.named_parameters():
        values = np.asarray(p.detach().double().numpy())
        for idx in np.ndindex(values.shape):
            index = ",".join(str(i) for i in idx)
            rows.append({"axis": "", "name": f"{pname}[{index}]" if index else pname,
                         "value": float(values[idx]), "stderr": math.nan,
                         "unit": "standardised", "note": NO_SE["standardised"]})
    return rows


#: A parameter table without pandas: one dict per row, keys :data:`COLUMNS`.
Rows = list[dict[str, Any]]


def _computed_note(value: float, stderr: float, note: str, method: str) -> str:
    """A row's ``note``: where its standard error was computed (note empty, stderr finite
    and positive), the method, and :data:`NEAR_ZERO` where ``|value| < 2 stderr``."""
    if note or not (math.isfinite(stderr) and stderr > 0):
        return note
    return f"{method}; {NEAR_ZERO}" if abs(value) < 2.0 * stderr else method


def parameter_rows(model: Any, units: dict[str, str], signal_units: dict[str, str],
                   train: tuple[Any, ...] | None = None, *, method: str = "ols",
                   seed: int = 0, parts: Sequence[tuple[Rows, dict[str, np.ndarray]]]
                   | None = None, warn: bool = True) -> tuple[Rows, dict[str, np.ndarray]]:
    """:func:`parameter_table`'s rows and covariance, without pandas (what ``compare``
    and ``calibrate`` seal into their checkpoints: importing pandas costs ~0.3 s).
    ``warn``: a Lorentz's implausible constants are also a warning (else only its rows'
    note: ``compare`` warns for the model that ships alone, and fits families in threads,
    where no warnings filter may be changed).

    A per-axis model (:class:`~thermonet.models.composite.AxisModels`) takes ``parts``:
    each part's own rows and covariance as its fit computed them (else its parts' rows
    without data)."""
    from ..models.composite import AxisModels  # torch boundary (pyproject.toml): loads torch

    cov: dict[str, np.ndarray] = {}
    if isinstance(model, AxisModels):
        # each part's own table, on the axes it owns (and its shared rows), names prefixed
        # with the part's label
        rows: Rows = []
        for k, part in enumerate(model.parts):
            table, part_cov = parts[k] if parts is not None else parameter_rows(
                part, units, signal_units, None, method=method, seed=seed, warn=warn)
            mine = [a for a, o in zip(model.outputs, model.owner, strict=True) if o == k]
            keep = {*mine, ""}
            rows += [{**r, "name": f"{model.labels[k]}.{r['name']}"} for r in table
                     if r["axis"] in keep]
            cov.update({a: c for a, c in part_cov.items() if a in mine})
        return [{c: r[c] for c in COLUMNS} for r in rows], cov
    poly = _polynomial_rows(model, units, signal_units, train, method, seed)
    if poly is not None:
        rows, cov = poly
    elif model.family.name == "lorentz":
        rows = _lorentz_rows(model, units, signal_units, warn)
    else:
        rows = (_rbf_rows(model, units, signal_units) if model.family.name == "rbf" else None) \
            or _raw_rows(model)
    return [{**{c: r[c] for c in COLUMNS},
             "note": _computed_note(r["value"], r["stderr"], r["note"], method)}
            for r in rows], cov


def _as_rows(table: Any) -> Rows:
    """A parameter table's rows: a DataFrame's records, or the rows themselves."""
    if isinstance(table, list):
        return table
    return [dict(zip(table.columns, r, strict=True))
            for r in table.itertuples(index=False, name=None)]


def parameter_table(model: Any, units: dict[str, str], signal_units: dict[str, str],
                    train: tuple[Any, ...] | None = None, *, method: str = "ols",
                    seed: int = 0, parts: Sequence[tuple[pd.DataFrame, dict[str, np.ndarray]]]
                    | None = None) -> tuple[pd.DataFrame, dict[str, np.ndarray]]:
    """The parameter table of a fitted model (module docstring) and, for a polynomial,
    its per-axis covariance.

    ``train`` = (signals, targets[, samples per run]) the model was fitted on (None: no
    standard errors, note :data:`NO_SE` ``["unstored"]``); ``method``: ``"ols"`` or
    ``"block-bootstrap"`` (seeded by ``seed``).  A per-axis model
    (:class:`~thermonet.models.composite.AxisModels`) takes ``parts``: each part's own table
    and covariance as its fit computed them (else its parts' tables without data).
    """
    import pandas as pd

    rows, cov = parameter_rows(model, units, signal_units, train, method=method, seed=seed,
                               parts=None if parts is None else
                               [(_as_rows(t), c) for t, c in parts])
    return pd.DataFrame(rows, columns=COLUMNS), cov


def sealed_parameters(table: pd.DataFrame | Rows, cov: dict[str, np.ndarray], method: str
                      ) -> dict[str, Any]:
    """The standard errors of a fitted model's table as its checkpoint stores them (``extra
    .parameters``): per row its axis, name, stderr and note, the per-axis covariance
    matrices and the method — computed once on the training data, so that a loaded model
    (``DriftEstimator.load``, ``compare``'s estimators) states what the fit stated."""
    rows = [{"axis": str(r["axis"]), "name": str(r["name"]), "stderr": float(r["stderr"]),
             "note": str(r["note"])} for r in _as_rows(table)]
    return {"method": method, "rows": rows,
            "covariance": {a: np.asarray(c, dtype=np.float64).tolist() for a, c in cov.items()}}


def with_sealed(table: pd.DataFrame, cov: dict[str, np.ndarray], stored: Any, where: str
                ) -> tuple[pd.DataFrame, dict[str, np.ndarray], str | None]:
    """``table`` (recomputed from the loaded model: its values) with the standard errors,
    notes and covariance of the checkpoint's ``extra.parameters`` (:func:`sealed_parameters`);
    unchanged where the checkpoint holds none.  Returns ``(table, cov, method)``.

    Raises
    ------
    InputError
        ``extra.parameters`` is not what :func:`sealed_parameters` writes, or names other
        rows than the model's.
    """
    if stored is None:
        return table, cov, None

    def bad(why: str) -> InputError:
        return InputError(f"{where}: key 'extra.parameters': {why}")

    if not isinstance(stored, dict) or not isinstance(stored.get("rows"), list) \
            or not isinstance(stored.get("covariance"), dict) \
            or stored.get("method") not in STDERR_METHODS:
        raise bad("expected {method, rows, covariance} as thermonet writes it")
    rows = stored["rows"]
    keys = list(zip(table["axis"].astype(str), table["name"].astype(str), strict=True))
    if len(rows) != len(keys) or not all(
            isinstance(r, dict) and (r.get("axis"), r.get("name")) == k
            and isinstance(r.get("stderr"), float) and isinstance(r.get("note"), str)
            for r, k in zip(rows, keys, strict=False)):
        raise bad("its rows are not the model's parameters (axis, name, stderr, note)")
    out = table.copy()
    # an axis the model leaves raw (compare's mask, applied after the fit) keeps its note
    raw = (table["note"] == NO_SE["raw"]).to_numpy()
    out["stderr"] = np.where(raw, table["stderr"], [r["stderr"] for r in rows])
    # a checkpoint sealed before the note named the method: named now (its stored method)
    out["note"] = np.where(raw, table["note"], [
        _computed_note(v, r["stderr"], r["note"], str(stored["method"]))
        for v, r in zip(table["value"], rows, strict=True)])
    masked = set(table.loc[raw, "axis"])
    covs: dict[str, np.ndarray] = {}
    for axis, c in stored["covariance"].items():
        if axis in masked:
            continue
        m = np.asarray(c, dtype=np.float64) if isinstance(c, list) else np.empty(0)
        n = int((out["axis"] == axis).sum())
        if m.shape != (n, n) or n == 0:
            raise bad(f"covariance of axis {axis!r} is not {n} × {n}")
        covs[axis] = m
    return out, covs, str(stored["method"])
