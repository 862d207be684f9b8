"""A fleet's units and the work done per unit: where each unit's runs come from
(:class:`UnitSource`: a file, a split dataset, a simulation), the per-unit task (its own
comparison, :func:`thermonet.workflows.compare.compare_result`, and the physical coefficients of
its model) and the per-fold task of leave-units-out (one pooled fleet model fitted through the
one split pipeline, :mod:`thermonet.training.pipeline`, and judged on each held-out unit next to
the unit's own model).  Tasks are plain picklable items, run by :mod:`thermonet.core.executors`.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError
from ..core.recording import Dataset, split_units
from ..reporting.results import ComparisonResult as TypedResult
from ..sim.fleet import simulate_fleet, unit_device_id
from ..sim.presets import get_preset
from ..training.config import CompareConfig, FamilyConfig, outputs_of, train_config_of
from ..training.loader import load_unit_file
from ..training.parts import build_part, make_splits, targets_for
from .compare import compare_result
from .steps import Outcome

__all__ = ["UnitSource", "sources_from_dataset", "sources_from_files", "sources_from_simulation",
           "physical_coefficients", "COEF_T0_C", "UnitItem", "unit_task", "FoldItem",
           "fold_task", "fold_items"]


#: Reference temperature of the fleet's physical coefficients (°C).
COEF_T0_C = 25.0


@dataclass
class UnitSource:
    """Where a worker finds one unit's data: the runs themselves, or simulator arguments."""

    device_id: str
    dataset: Dataset | None = None
    sim: dict[str, Any] | None = None   # simulate_fleet kwargs with unit_indices=[k]
    error: str | None = None            # why this unit's data cannot be used (it fails alone)
    path: str | None = None             # the unit's own thermonet Parquet file: the worker
    #                                     reads it (only the path crosses the network)
    axes: list[str] | None = None       # its output channels where known before it is read
    #                                     (the limits' axes are checked against them)

    def load(self, cfg: CompareConfig | None = None) -> Dataset:
        """The unit's runs; a file of more than ``cfg.data.in_memory_samples`` samples is
        streamed and reduced to window means in the worker, as ``compare`` does
        (:func:`thermonet.training.loader.load_unit_file`)."""
        if self.error is not None:
            raise InputError(self.error)
        if self.dataset is not None:
            return self.dataset
        if self.path is not None:
            ds = load_unit_file(cfg, self.path)
            if ds.device_id != self.device_id or ds.is_fleet:
                raise InputError(f"{self.path}: holds unit(s) {ds.unit_ids}, expected "
                                 f"'{self.device_id}' alone (the file changed since the "
                                 "fleet started?)")
            return ds

        if self.sim is None:
            raise InputError(f"unit '{self.device_id}': no data")
        return simulate_fleet(**self.sim)


def _no_rows(dev: str, runs: list[Any], files: Sequence[str]) -> str | None:
    """Why a unit is a name without data: a unit (or a run of it) a file's metadata lists
    with no rows, naming the file; None where every run has rows."""
    empty = [r for r in runs if r.n_samples == 0]
    if not empty or not files:      # data not read from files: validation says "0 samples"
        return None
    src = str(empty[0].meta.get("source", ""))
    where = (src if src in files else files[0] if len(files) == 1 else
             f"its file (one of {', '.join(files)})")
    if len(empty) == len(runs):   # "unit '<id>': " as the unit's other reasons begin
        return f"unit '{dev}': no rows in {where} (the file's metadata lists the unit)"
    return f"unit '{dev}': run '{empty[0].run_id}' has no rows in {where}"


def sources_from_dataset(ds: Dataset, source: str = "", *, files: Sequence[str] = ()
                         ) -> list[UnitSource]:
    """One source per unit of a dataset, each unit validated on its own.

    A unit whose runs fail validation (too few samples, no temperature span,
    bad time stamps …) becomes a source that fails with the reason, naming the
    unit, so the fleet goes on without it; the units left must agree with each
    other (same outputs, proxies and units of measure), else one line names both.
    A unit (or run) with no rows at all says so, naming the file it was read from
    (``files``: the data's paths).
    """
    by_unit: dict[str, list[Any]] = {}
    for r in ds.runs:
        by_unit.setdefault(r.device_id, []).append(r)
    bad: dict[str, str] = {}
    for dev, runs in by_unit.items():
        why = _no_rows(dev, runs, [str(f) for f in files])
        if why is not None:
            bad[dev] = why
            continue
        try:
            Dataset(runs=runs, meta=dict(ds.meta)).validate(source)
        except InputError as err:
            bad[dev] = f"unit '{dev}': {err}"
    good = [r for r in ds.runs if r.device_id not in bad]
    units = split_units(Dataset(runs=good, meta=dict(ds.meta)).validate(source)) if good else {}
    return [UnitSource(dev, error=bad[dev]) if dev in bad else
            UnitSource(dev, dataset=units[dev], axes=list(units[dev].axes)) for dev in by_unit]


def sources_from_files(paths: list[str]) -> list[UnitSource] | None:
    """One source per file when every file is a thermonet Parquet file holding one unit
    (read from the files' footers alone, :func:`thermonet.data.chunks.open_parquet`), else
    None (the driver reads the data and splits it: :func:`sources_from_dataset`).

    Each worker then reads its own unit's file — the path is all that goes to it, so a
    fleet of recordings larger than the driver's memory runs on storage every worker
    mounts.  The units must carry the same outputs, proxies and units of measure (from
    their metadata; one line names both files otherwise); a file whose data fails
    validation fails alone, in its worker.
    """
    from ..data.chunks import open_parquet  # lazy: loads pandas, pyarrow

    sources, first = [], None
    for p in paths:
        path = Path(p)
        if path.suffix.lower() not in (".parquet", ".pq") or not path.is_file():
            return None
        layout = open_parquet(path)
        if layout is None or len({e["device_id"] for e in layout.runs}) != 1:
            return None
        e = layout.runs[0]
        shape = (sorted(e["outputs"]), sorted(e["proxies"]),
                 {k: v for k, v in e["units"].items()})
        if first is None:
            first = (p, shape)
        elif shape[:2] != first[1][:2] or any(
                first[1][2].get(k, v) != v for k, v in shape[2].items()):
            raise InputError(f"{p}: unit '{e['device_id']}' has outputs {shape[0]}, proxies "
                             f"{shape[1]} and units {shape[2]}; {first[0]} has "
                             f"{first[1][0]}, {first[1][1]} and {first[1][2]} (the units of "
                             "one fleet must carry the same channels)")
        sources.append(UnitSource(e["device_id"], path=str(path), axes=list(e["outputs"])))
    return sources


def sources_from_simulation(preset: str, *, units: int, runs: int | None = None, seed: int = 0,
                            outliers: int = 0, **overrides: Any) -> list[UnitSource]:
    """Sources for a simulated fleet: each worker simulates its own unit.

    ``overrides`` go to the simulator (``sample_rate_hz=0.1``, ``white_noise=False``).
    """
    # the arguments (a short test's spec too) checked here, once, before any worker starts
    simulate_fleet(preset, units=units, runs=1, seed=seed, outliers=outliers,
                   unit_indices=[], **overrides)
    axes = [ax.name for ax in get_preset(preset).axes]   # the preset's output channels
    return [UnitSource(unit_device_id(preset, k, units),
                       sim={"preset": preset, "units": units, "runs": runs, "seed": seed,
                            "outliers": outliers, "unit_indices": [k], **overrides},
                       axes=list(axes))
            for k in range(units)]


# ------------------------------------------------------------------ workers
def _family(cfg: CompareConfig, label: str) -> FamilyConfig:
    return next(f for f in cfg.families if f.label == label)


def _buffer(model: Any, name: str) -> np.ndarray:
    """A model buffer as float64 NumPy (the trained signal range ``sig_lo``/``sig_hi``)."""
    return np.asarray(getattr(model, name).detach().cpu().numpy(), dtype=np.float64)


def physical_coefficients(model: Any, t0_c: float = COEF_T0_C) -> dict[str, float]:
    """Polynomial coefficients of a temperature-only model's drift in (T − t0), per axis.

    ``{"<axis>.c<k>": value}`` in output unit / °C^k; empty when the model takes
    other signals than the temperature.  Degree: the family's own
    (:meth:`thermonet.models.Family.coefficient_degree`: a polynomial's degree on ``T`` or
    ``dT`` alone, else 3 — then a summary of the curve, not its parameters).
    """
    from ..training.train import predict  # torch boundary

    if list(model.signals) != ["temperature_c"]:
        return {}
    lo, hi = (float(v) for v in np.concatenate([_buffer(model, "sig_lo")[:1],
                                                 _buffer(model, "sig_hi")[:1]]))
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        return {}
    degree = int(model.family.coefficient_degree(list(model.inputs)))  # the family's own say
    grid = np.linspace(lo, hi, 201)
    if model.family.recurrent:  # its curve after a long soak at each temperature
        import torch

        with torch.no_grad():
            drift = model.drift64(torch.as_tensor(grid[:, None], dtype=torch.float32)).numpy()
    else:
        drift = predict(model, grid[:, None])
    out: dict[str, float] = {}
    for j, axis in enumerate(model.outputs):
        c = np.polynomial.polynomial.polyfit(grid - t0_c, drift[:, j].astype(np.float64), degree)
        out.update({f"{axis}.c{k}": float(v) for k, v in enumerate(c)})
    return out


def _load_bias(path: str) -> Any:
    from ..training.checkpoint import load_checkpoint  # torch boundary

    return load_checkpoint(path)[0]


def _load_sensor(path: str) -> Any:
    from ..training.sensor_checkpoint import load_sensor  # torch boundary

    return load_sensor(path)[0]


def _residual_std(model: Any, part: Any) -> np.ndarray:
    from ..training.train import predict  # torch boundary

    return np.std(part.target - predict(model, part.signals, part.time_s), axis=0)


def _test_part(cfg: CompareConfig, ds: Dataset, model: Any) -> Any:
    where = f"unit '{ds.device_id}'"
    split = make_splits(ds, cfg.split, source=where)[-1]
    outputs = list(model.outputs)
    return build_part(split.test, signals=list(model.signals), outputs=outputs,
                      target=targets_for(ds, cfg.target, outputs, source=where),
                      gap_s=model.spec.gap_s)


@dataclass
class UnitItem:
    cfg: CompareConfig
    source: UnitSource
    family: str
    plots: bool = True


def unit_task(item: UnitItem) -> dict[str, Any]:
    """One unit in a worker: compare in a private temp dir, return plain data."""
    ds = item.source.load(item.cfg)
    if ds.is_fleet:
        raise InputError(f"unit '{item.source.device_id}': its data holds several devices")
    tmp = Path(tempfile.mkdtemp(prefix="thermonet-unit-"))
    try:
        udir = tmp / "unit"
        outcome = compare_result(item.cfg, udir, dataset=ds, track=False, quiet=True,
                                 plots=item.plots,
                                 workers=1)   # units run side by side, not families
        # the unit's document: the fleet's results.json holds it (with the limits' verdicts)
        results = outcome.to_json() if isinstance(outcome, TypedResult) else outcome
        files = {p.relative_to(udir).as_posix(): p.read_bytes()
                 for p in sorted(udir.rglob("*")) if p.is_file()}
        temps = [r.temperature_c for r in ds if r.temperature_c is not None]
        span = float(max(t.max() for t in temps) - min(t.min() for t in temps)) \
            if temps and len(temps) == len(ds) else None
        payload: dict[str, Any] = {"results": results, "files": files, "root": str(udir),
                                   "temperature_span_c": span, "coefficients": {},
                                   "n_runs": len(ds), "temperature_range_c": None,
                                   "own_model": None}
        ckpt = _checkpoint(outcome, item.family)
        if ckpt:
            kind = UNIT_KINDS[item.cfg.model]
            own = kind.load(ckpt)
            payload["own_model"] = own  # for leave-units-out, evaluated by the fold tasks
            curves = kind.curves(own)
            payload["coefficients"] = {k: v for m in curves
                                       for k, v in physical_coefficients(m).items()}
            lo, hi = float(_buffer(curves[0], "sig_lo")[0]), float(_buffer(curves[0],
                                                                           "sig_hi")[0])
            if list(own.signals) == ["temperature_c"] and np.isfinite([lo, hi]).all():
                payload["temperature_range_c"] = [lo, hi]
        return payload
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _checkpoint(outcome: Outcome, family: str) -> str | None:
    """The checkpoint of ``family`` where it was fitted: from the typed result (a bias
    comparison's), or the whole-sensor model's document."""
    if isinstance(outcome, TypedResult):
        f = outcome.families.get(family)
        return f.checkpoint if f is not None and f.ok else None
    doc = outcome["families"].get(family) or {}
    return doc.get("checkpoint") if doc.get("status") == "ok" else None


@dataclass
class FoldItem:
    cfg: CompareConfig
    family: str
    fold: int
    sources: list[UnitSource] = field(default_factory=list)       # the fleet model's units
    held_out: list[tuple[UnitSource, Any]] = field(default_factory=list)  # (unit, own model)


def fold_task(item: FoldItem) -> dict[str, Any]:
    """Fit one fleet model of the fleet family on other units' calibration runs, and
    evaluate it on each held-out unit's test run next to the unit's own model."""
    cfg = item.cfg
    return UNIT_KINDS[cfg.model].fold_task(item, _family(cfg, item.family))


def _bias_fold_task(item: FoldItem, fam: FamilyConfig) -> dict[str, Any]:
    """:func:`fold_task` for ``model: bias``: one fleet model of the fleet family fitted on
    the other units' calibration runs, and on each held-out unit's test run the standard
    deviation of the residual with it and with the unit's own model."""
    from ..training.pipeline import fit_split, split_parts, split_spec  # torch boundary

    cfg = item.cfg
    train, val = [], []
    outputs: list[str] = []
    target: Any = cfg.target
    for src in item.sources:
        ds = src.load(cfg)
        split = make_splits(ds, cfg.split, source=f"unit '{src.device_id}'")[-1]
        outputs = outputs_of(cfg, ds)   # the same outputs and train section as a unit's
        target = targets_for(ds, cfg.target, outputs, source=f"unit '{src.device_id}'")
        train += split.train
        if split.val is not None:
            val.append(split.val)
    spec = split_spec(fam.inputs, train, t_ref=cfg.features.t_ref,
                     window_min=cfg.features.t_ref_window_min, gap_s=cfg.features.gap_s)
    parts = split_parts(spec, train, outputs=outputs, target=target)
    vparts = split_parts(spec, val, outputs=outputs, target=target).train
    v = (np.concatenate([p.signals for p in vparts]), np.concatenate([p.target for p in vparts])) \
        if vparts else None
    fitted = fit_split(parts, family=fam.family, outputs=outputs, hyper=fam.params,
                      config=train_config_of(cfg, fam), val=v, windows=False)
    evaluations = {}
    for src, own in item.held_out:  # one unit's data at a time
        test = _test_part(cfg, src.load(cfg), own)
        s_own, s_fleet = _residual_std(own, test), _residual_std(fitted.model, test)
        s_raw = np.std(test.target, axis=0)
        evaluations[src.device_id] = {
            "fold": item.fold, "family": item.family,
            "fitted_on": [s.device_id for s in item.sources], "axes": {
                a: {"std_raw": float(s_raw[j]), "std_own": float(s_own[j]),
                    "std_fleet": float(s_fleet[j]),
                    "ratio": float(s_fleet[j] / s_own[j]) if s_own[j] > 0 else None}
                for j, a in enumerate(own.outputs)}}
    return {"units": [s.device_id for s in item.sources], "fold": item.fold,
            "evaluations": evaluations}


def _sensor_fold_task(item: FoldItem, fam: FamilyConfig) -> dict[str, Any]:
    """:func:`fold_task` for ``model: sensor``: one sensor model of the fleet family fitted
    on the other units' training runs pooled (without a validation part: the units' own
    validation runs are separate recordings, so every element is kept and the loop stops on
    its training loss), and on each held-out unit's test run the standard deviation of
    ``compensated − ref`` with it and with the unit's own sensor model (``std_raw``: of
    ``raw − ref``)."""
    from ..models.sensor import triads_of  # torch boundary
    from ..training.pipeline import split_spec  # torch boundary
    from ..training.sensor import fit_sensor, sensor_run  # torch boundary

    cfg = item.cfg
    train = []
    outputs: list[str] = []
    for src in item.sources:
        ds = src.load(cfg)
        train += make_splits(ds, cfg.split, source=f"unit '{src.device_id}'")[-1].train
        outputs = [o for t in triads_of(outputs_of(cfg, ds)) for o in t]
    triads = triads_of(outputs)
    spec = split_spec(fam.inputs, train, t_ref=cfg.features.t_ref,
                     window_min=cfg.features.t_ref_window_min, gap_s=cfg.features.gap_s)
    fleet = fit_sensor(family=fam.family, spec=spec, outputs=outputs, triads=triads,
                       train=[sensor_run(r, spec, outputs) for r in train], val=None,
                       hyper=fam.params, config=train_config_of(cfg, fam)).model
    evaluations = {}
    for src, own in item.held_out:  # one unit's data at a time
        ds = src.load(cfg)
        test = make_splits(ds, cfg.split, source=f"unit '{src.device_id}'")[-1].test
        std = {}
        for name, model in (("own", own), ("fleet", fleet)):
            r = sensor_run(test, model.bias.spec, outputs)
            std[name] = np.std(model.compensate(r.signals, r.raw) - r.ref, axis=0)
        s_raw = np.std(r.raw - r.ref, axis=0)
        evaluations[src.device_id] = {
            "fold": item.fold, "family": item.family,
            "fitted_on": [s.device_id for s in item.sources], "axes": {
                a: {"std_raw": float(s_raw[j]), "std_own": float(std["own"][j]),
                    "std_fleet": float(std["fleet"][j]),
                    "ratio": float(std["fleet"][j] / std["own"][j])
                    if std["own"][j] > 0 else None}
                for j, a in enumerate(outputs)}}
    return {"units": [s.device_id for s in item.sources], "fold": item.fold,
            "evaluations": evaluations}


def fold_items(cfg: CompareConfig, family: str, sources: list[UnitSource], k: int,
                per_fit: int, own: dict[str, Any], excluded: set[str]) -> list[FoldItem]:
    """Unit *i* is in group *i* mod k; each group's fleet model is fitted on up to
    ``per_fit`` units of the other groups (evenly spaced), leaving out ``excluded`` units
    (flagged outliers, failed units)."""
    items = []
    for f in range(k):
        others = [s for i, s in enumerate(sources)
                  if i % k != f and s.device_id not in excluded]
        if len(others) > per_fit:  # evenly spaced, deterministic
            pick = np.linspace(0, len(others) - 1, per_fit).round().astype(int)
            others = [others[i] for i in sorted(set(pick.tolist()))]
        held = [(s, own[s.device_id]) for i, s in enumerate(sources)
                if i % k == f and own.get(s.device_id) is not None]
        if others and held:
            items.append(FoldItem(cfg=cfg, family=family, fold=f, sources=others,
                                   held_out=held))
    return items


@dataclass(frozen=True)
class UnitKind:
    """What a fleet unit's model kind differs in: how its checkpoint loads, the curves its
    physical coefficients are read from, and its leave-units-out fold task."""

    load: Callable[[str], Any]
    curves: Callable[[Any], list[Any]]
    fold_task: Callable[[FoldItem, FamilyConfig], dict[str, Any]]


#: A unit's model kind, by the config's ``model:`` value (results.json's ``model``).
UNIT_KINDS: dict[str, UnitKind] = {
    "bias": UnitKind(load=_load_bias, curves=lambda m: [m], fold_task=_bias_fold_task),
    # a sensor model's curves: its bias b(T) per axis and each element of E(T)
    "sensor": UnitKind(load=_load_sensor, curves=lambda m: [m.bias, m.elements],
                       fold_task=_sensor_fold_task),
}
