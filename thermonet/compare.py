"""``thermonet compare``: every configured family fitted, judged on held-out data, tracked, plotted.

``results.json`` schema (version 1)::

    {
      "schema": 1,
      "thermonet_version": str,
      "config": {...resolved config...},
      "device": str, "data_hash": str, "target": "drift" | "four-position",
      "split": {"strategy": str, "folds": [{"train": ..., "val": ..., "test": ...}]},
      "units": {axis: unit},
      "targets": {axis: "channel" | "zero" | "at-t-ref" | "four-position"},  # thermonet.target
      "chosen": name | null,          # by validation error only
      "chosen_reason": str,           # why (or why none: "do no harm")
      "baseline": name | null,        # PX4/ArduPilot's cubic, for the ratios below
      "families": {
        name: {
          "family": registry key, "inputs": [...], "params": {...},
          "status": "ok" | "failed", "reason": str | null,
          "fit_seconds": s, "n_params": k, "best_epoch": int,
          "val_score": float,         # mean over axes of val msd_comp / msd_raw (< 1 beats raw)
          "checkpoint": path | null, "mlflow_run_id": str | null,
          "axes": {axis: {"rms_raw", "rms_comp", "pp_raw", "pp_comp", "msd_raw", "msd_comp",
                          "noise_floor", "bias_instability_raw", "bias_instability_comp",
                          "drift_error_rms" (simulated data), "ppm_per_c_raw", "ppm_per_c_comp"
                          (scale-factor outputs), "pp_ratio_vs_baseline"}}
        }
      }
    }

With leave-one-run-out the per-axis metrics are means over folds,
``folds`` under each family holds the per-fold values, and the checkpoint is
the last fold's model.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .config import CompareConfig, FamilyConfig, from_dict, to_dict
from .errors import ConfigError, FitError, ThermonetError
from .evaluate import (
    FOURPOS_SUFFIXES,
    Part,
    Split,
    build_part,
    data_hash,
    heating_only,
    load_data,
    make_splits,
    targets_for,
)
from .fileio import atomic_write_text
from .recording import Dataset

__all__ = ["run_compare", "format_table", "Progress"]


class Progress:
    """One status line per family on stderr (rewritten in place on a terminal); silent if quiet."""

    def __init__(self, quiet: bool = False, stream: Any = None) -> None:
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._last = 0.0

    def epoch(self, label: str, epoch: int, train_loss: float, val_loss: float | None) -> None:
        if self.quiet or not self.tty:
            return
        now = time.monotonic()
        if now - self._last < 0.2:
            return
        self._last = now
        val = f"{val_loss:.4g}" if val_loss is not None else "-"
        self.stream.write(f"\r  {label:<14} epoch {epoch:5d}  train {train_loss:.4g}  val {val}   ")
        self.stream.flush()

    def line(self, text: str) -> None:
        if self.quiet:
            return
        if self.tty:
            self.stream.write("\r" + " " * 78 + "\r")
        self.stream.write(text + "\n")
        self.stream.flush()


def _outputs(ds: Dataset, cfg: CompareConfig) -> list[str]:
    axes = cfg.data.outputs or ds.axes
    if cfg.target == "four-position":
        return [f"{a}{s}" for a in axes for s in FOURPOS_SUFFIXES]
    return list(axes)


def _train_config(cfg: CompareConfig, fam: FamilyConfig) -> Any:
    """The ``train`` section with the family's own overrides applied."""
    from .train import TrainConfig

    return from_dict(TrainConfig, {**to_dict(cfg.train), **fam.train},
                     source="config", prefix=f"families[{fam.label}].train")


def _per_soak_metrics(k: np.ndarray, pred: np.ndarray, temps: np.ndarray, scale: bool
                      ) -> dict[str, float]:
    """Metrics of per-soak four-position estimates (study 000).

    Bias K0: the raw error is K0 itself, compensated K0 − K̂0.  Scale factor
    K1: its nominal value is no error, so raw is K1 − mean(K1); compensated
    is K1 − K̂1(T) (+ mean(K1) for the ppm/°C coefficient, which needs the
    nominal scale factor in its denominator).
    """
    from .metrics import rms, scale_factor_tempco_ppm_per_c

    nominal = float(np.mean(k)) if scale else 0.0
    raw, comp = k - nominal, k - pred
    m = {"rms_raw": rms(raw), "rms_comp": rms(comp), "pp_raw": float(np.ptp(raw)),
         "pp_comp": float(np.ptp(comp)), "msd_raw": float(np.mean(raw ** 2)),
         "msd_comp": float(np.mean(comp ** 2))}
    if scale:
        m["ppm_per_c_raw"] = scale_factor_tempco_ppm_per_c(temps, k)
        m["ppm_per_c_comp"] = scale_factor_tempco_ppm_per_c(temps, comp + nominal)
    return m


def _evaluate_part(model: Any, part: Part) -> tuple[np.ndarray, dict[str, dict[str, float]]]:
    from .metrics import axis_metrics
    from .train import predict

    pred = predict(model, part.signals)
    out: dict[str, dict[str, float]] = {}
    for j, axis in enumerate(part.outputs):
        if part.per_soak:
            m = _per_soak_metrics(part.target[:, j], pred[:, j], part.bin_by,
                                  scale=axis.endswith(".scale"))
        else:
            raw = part.target[:, j]
            m = axis_metrics(
                bin_by=part.bin_by, time_s=part.time_s, raw=raw,
                reference=np.zeros_like(raw), predicted_drift=pred[:, j],
                true_drift=None if part.true_drift is None else part.true_drift[:, j],
                rate_hz=part.rate_hz, bin_width=part.bin_width)
        out[axis] = {k: float(v) for k, v in m.items()}
    return pred, out


def _val_score(model: Any, part: Part) -> float:
    """Mean over axes of msd_comp / msd_raw on the validation part (< 1: better than raw)."""
    from .train import predict

    pred = predict(model, part.signals)
    ratios = []
    for j in range(part.target.shape[1]):
        y = part.target[:, j]
        r = y - pred[:, j]
        if part.offset_free(j):  # a scale factor's nominal value, gravity (at-t-ref): no error
            y = y - np.mean(y)
            r = r - np.mean(r) if not part.per_soak else r
        raw = float(np.mean(y ** 2))
        comp = float(np.mean(r ** 2))
        ratios.append(comp / raw if raw > 0 else float("inf"))
    return float(np.mean(ratios))


@dataclass
class _FamilyOutcome:
    result: dict[str, Any]
    model: Any = None
    test_parts: list[Part] = field(default_factory=list)
    test_preds: list[np.ndarray] = field(default_factory=list)
    history: list[dict[str, Any]] | None = None
    best_val: float | None = None


class _Parts:
    """Signals and targets of each (run, signals) pair, built once for all families."""

    def __init__(self, cfg: CompareConfig, outputs: list[str], targets: Any = None) -> None:
        self.cfg, self.outputs = cfg, outputs
        # thermonet.target.Target, or the config's plain kind ("drift" / "four-position")
        self.targets: Any = targets if targets is not None else cfg.target
        self._cache: dict[tuple[int, tuple[str, ...]], Part] = {}

    def __call__(self, rec: Any, signals: list[str]) -> Part:
        key = (id(rec), tuple(signals))
        if key not in self._cache:
            self._cache[key] = build_part(rec, signals=signals, outputs=self.outputs,
                                          target=self.targets,
                                          rate_window_s=self.cfg.features.rate_window_s)
        return self._cache[key]


def _fit_family(cfg: CompareConfig, fam: FamilyConfig, splits: list[Split], outputs: list[str],
                progress: Progress, parts: _Parts) -> _FamilyOutcome:
    from .features import FeatureSpec, reference_values, signals_for
    from .train import fit

    res: dict[str, Any] = {"family": fam.family, "inputs": list(fam.inputs),
                           "params": dict(fam.params), "train_on": fam.train_on,
                           "status": "ok", "reason": None}
    fold_axes, scores, seconds = [], [], 0.0
    outcome = _FamilyOutcome(res, test_parts=[], test_preds=[])
    try:
        tcfg = _train_config(cfg, fam)
        for split in splits:
            # T_ref also for a model on T alone: at-t-ref axes are normalised there
            ref_inputs = list(fam.inputs) + (["dT"] if "temperature_c" in signals_for(fam.inputs)
                                             else [])
            t_ref, proxy_ref = reference_values(split.train, ref_inputs, t_ref=cfg.features.t_ref,
                                                window_min=cfg.features.t_ref_window_min)
            spec = FeatureSpec(inputs=list(fam.inputs), t_ref=t_ref, proxy_ref=proxy_ref)
            train_parts = [parts(r, spec.signals) for r in split.train]
            if fam.train_on == "heating":
                train_parts = [heating_only(p, r, cfg.features.rate_window_s)
                               for p, r in zip(train_parts, split.train, strict=True)]
            val_part = parts(split.val, spec.signals) if split.val is not None else None
            test_part = parts(split.test, spec.signals)
            fitted = fit(family=fam.family, inputs=list(fam.inputs), outputs=outputs,
                         train=[(p.signals, p.target) for p in train_parts],
                         val=(val_part.signals, val_part.target) if val_part else None,
                         spec=spec, hyper=dict(fam.params), config=tcfg,
                         on_epoch=lambda e, tl, vl: progress.epoch(fam.label, e, tl, vl),
                         target=getattr(parts.targets, "modes", None))
            seconds += fitted.fit_seconds
            scores.append(_val_score(fitted.model, val_part if val_part else train_parts[-1]))
            pred, axes = _evaluate_part(fitted.model, test_part)
            fold_axes.append(axes)
            outcome.model, outcome.history = fitted.model, fitted.history
            outcome.best_val = fitted.best_val_loss
            outcome.test_parts.append(test_part)
            outcome.test_preds.append(pred)
            res.update(n_params=int(fitted.n_params), best_epoch=int(fitted.best_epoch))
    except FitError as err:  # this data cannot carry the family: reported, the comparison goes on
        res.update(status="failed", reason=str(err))
        outcome.model = None
        return outcome
    res["fit_seconds"] = seconds
    res["val_score"] = float(np.mean(scores))
    res["axes"] = {a: {k: float(np.mean([f[a][k] for f in fold_axes])) for k in fold_axes[0][a]}
                   for a in outputs}
    if len(fold_axes) > 1:
        res["folds"] = fold_axes
    return outcome


def _family_config(cfg: CompareConfig, fam: FamilyConfig) -> dict[str, Any]:
    """What a family's checkpoint carries: its own resolved config, not the whole comparison's
    (the same layout :meth:`thermonet.DriftEstimator.save` writes)."""
    return {"family": to_dict(fam), "train": to_dict(_train_config(cfg, fam)),
            "features": to_dict(cfg.features), "target": cfg.target,
            "tracking": to_dict(cfg.tracking)}


def _choose(families: dict[str, dict[str, Any]]) -> tuple[str | None, str]:
    ok = {k: v for k, v in families.items()
          if v["status"] == "ok" and math.isfinite(v.get("val_score", float("nan")))}
    if not ok:
        if any(v["status"] == "ok" for v in families.values()):
            # fitted, but msd_raw was exactly 0 on validation: the score is undefined
            return None, ("nothing to compensate: the raw output has exactly zero error on "
                          "the validation data (every family fitted)")
        return None, "no family could be fitted"
    best = min(ok, key=lambda k: ok[k]["val_score"])
    score = ok[best]["val_score"]
    if score >= 1.0:
        return None, (f"do no harm: no family beats the raw output on validation "
                      f"(best {best}: msd ratio {score:.3g} ≥ 1)")
    return best, f"lowest validation msd ratio ({score:.3g} of raw)"


def run_compare(cfg: CompareConfig, out_dir: str | Path, *, overwrite: bool = False,
                **kwargs: Any) -> dict[str, Any]:
    """Fit every family of ``cfg``, judge on held-out data, write ``out_dir``; return results.

    The output appears whole or not at all (:mod:`thermonet.outdir`): it is
    built in a staging directory beside ``out_dir`` and moved into place when
    complete; ``results.json`` records each checkpoint's SHA-256.  A non-empty
    ``out_dir`` that is not a complete comparison is refused; a previous
    comparison is replaced only with ``overwrite=True``.

    Keyword arguments: ``track``, ``tracking_uri``, ``quiet``, ``progress``,
    ``dataset`` (replaces the configured data — benchmarks feed variants of
    one simulation this way; the config's ``data`` section is then ignored).
    """
    from .outdir import staged_output

    with staged_output(out_dir, overwrite=overwrite) as stage:
        results = _run_compare_in(cfg, stage.path, **kwargs)
        stage.finish(results, _clean)
    return results


def _run_compare_in(cfg: CompareConfig, out_dir: str | Path, *, track: bool | None = None,
                    tracking_uri: str | None = None, quiet: bool = False,
                    progress: Progress | None = None, dataset: Dataset | None = None
                    ) -> dict[str, Any]:
    """The comparison itself, written into ``out_dir`` (a staging directory)."""
    from .checkpoint import save_checkpoint
    from .config import check_families
    from .features import signals_for
    from .tracking import Tracker

    progress = progress or Progress(quiet)
    source = getattr(cfg, "_source", "config")
    check_families(cfg, source=source)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: --out must be a directory, and this is a file")
    ds = dataset if dataset is not None else load_data(cfg.data, source=source)
    for i, fam in enumerate(cfg.families):
        for sig in signals_for(fam.inputs):
            if sig in ("temperature_c", "rate_c_per_min"):
                if any(r.temperature_c is None for r in ds):
                    raise ConfigError(f"{source}: key 'families[{i}].inputs': {fam.inputs} need "
                                      "a thermometer in °C and the data has none (proxies: "
                                      f"{', '.join(sorted(ds[0].proxies)) or 'none'})")
            elif sig not in ds[0].proxies:
                raise ConfigError(f"{source}: key 'families[{i}].inputs': no proxy channel "
                                  f"'{sig}' in the data (proxies: "
                                  f"{', '.join(sorted(ds[0].proxies)) or 'none'})")
    outputs = _outputs(ds, cfg)
    targets = targets_for(ds, cfg.target, outputs, source=source)
    splits = make_splits(ds, cfg.split, source=source)
    out.mkdir(parents=True, exist_ok=True)
    dhash = data_hash(ds)
    units = {o: ds[0].units.get(o.split(".")[0], "") for o in outputs}
    for o in outputs:
        if o.endswith(".scale"):
            units[o] = "1"
    tracker = Tracker(enabled=cfg.tracking.enabled if track is None else track,
                      uri=tracking_uri or cfg.tracking.uri, experiment=cfg.tracking.experiment)
    preset = ds.runs[0].meta.get("preset", "")
    tags = {"device": ds.device_id, "preset": preset, "data_hash": dhash,
            "target": targets.kind}
    resolved = to_dict(cfg)
    results: dict[str, Any] = {
        "schema": 1, "thermonet_version": __version__, "config": resolved,
        "device": ds.device_id, "data_hash": dhash, "target": targets.kind,
        "split": {"strategy": splits[0].label if len(splits) == 1 else "leave-one-run-out",
                  "folds": [s.describe for s in splits]},
        "units": units, "targets": targets.as_dict(), "baseline": cfg.baseline,
        "families": {},
    }
    progress.line(f"thermonet compare: {ds.device_id} ({len(ds)} runs, outputs "
                  f"{', '.join(outputs)}), split {results['split']['strategy']}")
    outcomes: dict[str, _FamilyOutcome] = {}
    parts = _Parts(cfg, outputs, targets)
    with tracker.run(f"compare-{ds.device_id}", params=resolved, tags=tags) as parent_id:
        results["mlflow_run_id"] = parent_id
        for fam in cfg.families:
            with tracker.run(fam.label, params={"family": fam.family, "inputs": fam.inputs,
                                                "params": fam.params},
                             tags={**tags, "family": fam.family}, nested=True) as run_id:
                oc = _fit_family(cfg, fam, splits, outputs, progress, parts)
                r = oc.result
                r["mlflow_run_id"] = run_id
                r["checkpoint"] = None
                if r["status"] == "ok":
                    tracker.log_history(list(oc.history or []))
                    tracker.log_metrics({f"test/{a}/{k}": v for a, m in r["axes"].items()
                                         for k, v in m.items()})
                    tracker.log_metrics({"val/score": r["val_score"],
                                         "fit_seconds": r["fit_seconds"]})
                    ckpt = out / "models" / f"{fam.label}.pt"
                    try:
                        save_checkpoint(ckpt, oc.model, config=_family_config(cfg, fam),
                                        epoch=r["best_epoch"], best_val=oc.best_val,
                                        extra={"label": fam.label, "device_id": ds.device_id,
                                               "data_hash": dhash, "units": units,
                                               "signal_units": {p: ds[0].units.get(p, "")
                                                                for p in ds[0].proxies},
                                               "val_score": r["val_score"],
                                               "test_metrics": r["axes"],
                                               "mlflow_run_id": run_id or ""})
                        r["checkpoint"] = str(ckpt)
                        tracker.log_artifact(ckpt, "model")
                    except ThermonetError as err:  # a NaN model is never saved
                        r.update(status="failed", reason=str(err))
                    progress.line(f"  {fam.label:<14} fitted in {r['fit_seconds']:.2f} s, "
                                  f"{r['n_params']} params, val msd ratio {r['val_score']:.3g}")
                else:
                    tracker.set_tags({"status": "failed"})
                    progress.line(f"  {fam.label:<14} not fitted: {r['reason']}")
                results["families"][fam.label] = r
                outcomes[fam.label] = oc
        chosen, why = _choose(results["families"])
        results["chosen"], results["chosen_reason"] = chosen, why
        _baseline_ratios(results)
        plots = _plots(out, outcomes, results, ds)
        atomic_write_text(out / "results.json", json.dumps(_clean(results), indent=2))
        atomic_write_text(out / "config.resolved.yaml", _yaml(resolved))
        tracker.set_tags({"chosen": chosen or "none"})
        tracker.log_artifact(out / "results.json")
        tracker.log_artifact(out / "config.resolved.yaml")
        for p in plots:
            tracker.log_artifact(p, "plots")
    return results


def _baseline_ratios(results: dict[str, Any]) -> None:
    base = results["families"].get(results.get("baseline") or "")
    if not base or base["status"] != "ok":
        return
    for fam in results["families"].values():
        if fam["status"] != "ok":
            continue
        for axis, m in fam["axes"].items():
            b = base["axes"][axis]
            m["pp_ratio_vs_baseline"] = (
                (m["pp_comp"] / b["pp_comp"]) if b["pp_comp"] > 0 else float("nan")
            )


def _plots(out: Path, outcomes: dict[str, _FamilyOutcome], results: dict[str, Any],
           ds: Dataset) -> list[Path]:
    from .plots import plot_allan, plot_drift_vs_temperature, plot_residual_vs_time

    fitted = {k: oc for k, oc in outcomes.items() if oc.model is not None and oc.test_parts}
    if not fitted:
        return []
    paths: list[Path] = []
    any_oc = next(iter(fitted.values()))
    part = any_oc.test_parts[-1]
    pdir = out / "plots"
    for j, axis in enumerate(part.outputs):
        unit = results["units"].get(axis, "")
        curves = {}
        order = np.argsort(part.bin_by)
        for label, oc in fitted.items():
            curves[label] = (part.bin_by[order], oc.test_preds[-1][order, j])
        safe = axis.replace(".", "_")
        paths.append(plot_drift_vs_temperature(
            pdir / f"drift_vs_temperature_{safe}.png", temperature_c=part.bin_by,
            observed_drift=part.target[:, j], curves=curves, axis=axis, units=unit))
        if results["target"] == "drift":
            resid = {
                label: part.target[:, j] - oc.test_preds[-1][:, j] for label, oc in fitted.items()
            }
            paths.append(plot_residual_vs_time(
                pdir / f"residual_vs_time_{safe}.png", time_s=part.time_s,
                raw_error=part.target[:, j], compensated=resid, axis=axis, units=unit))
            paths.append(plot_allan(pdir / f"allan_{safe}.png", rate_hz=part.rate_hz,
                                    raw_error=part.target[:, j], compensated=resid,
                                    axis=axis, units=unit))
    return paths


def _clean(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.generic):
        return _clean(obj.item())
    return obj


def _yaml(data: Any) -> str:
    import yaml

    return yaml.safe_dump(data, sort_keys=False)


_METRIC_COLS = ("rms_raw", "rms_comp", "pp_raw", "pp_comp", "msd_raw", "msd_comp",
                "drift_error_rms", "ppm_per_c_raw", "ppm_per_c_comp")


def format_table(results: dict[str, Any]) -> str:
    """The comparison as a text table: family × axis × metrics, failures with their reason."""
    fams = results["families"]
    axes = list(results["units"])
    cols = [c for c in _METRIC_COLS
            if any(c in f.get("axes", {}).get(a, {}) for f in fams.values() for a in axes)]
    head = f"{'family':<14} {'axis':<14} {'fit s':>6} {'params':>6} {'val':>7} " + \
        " ".join(f"{c:>12}" for c in cols)
    lines = [head, "-" * len(head)]
    for name, f in fams.items():
        if f["status"] != "ok":
            lines.append(f"{name:<14} not fitted: {f['reason']}")
            continue
        for i, a in enumerate(axes):
            m = f["axes"][a]
            pre = (
                (
                    f"{name:<14} {a:<14} {f['fit_seconds']:6.2f} {f['n_params']:6d} "
                    f"{f['val_score']:7.3g} "
                )
                if i == 0
                else f"{'':<14} {a:<14} {'':>6} {'':>6} {'':>7} "
            )
            lines.append(pre + " ".join(f"{m.get(c, float('nan')):12.4g}" for c in cols))
    chosen = results.get("chosen")
    lines.append("")
    lines.append(f"chosen: {chosen or 'none'} — {results.get('chosen_reason', '')}")
    lines.append("units: " + ", ".join(f"{a} [{u}]" for a, u in results["units"].items()))
    return "\n".join(lines)
