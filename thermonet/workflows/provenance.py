"""What a run actually used, written beside its results: the data's source (files and their
hashes, a simulation's preset and seed, a dataset's sources), each family's resolved config, and
the resolved config file (``config.yaml``) that ``load_config`` reads back — shared by
``compare`` and ``fleet``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core.errors import counted
from ..core.outdir import sha256_file
from ..core.recording import Dataset
from ..training.config import (
    CompareConfig,
    FamilyConfig,
    to_dict,
    train_config_of,
)

__all__ = ["data_source", "resolved_config", "resolved_yaml", "family_config"]


def family_config(cfg: CompareConfig, fam: FamilyConfig,
                   tracking: dict[str, Any] | None = None) -> dict[str, Any]:
    """What a family's checkpoint carries: its own resolved config, not the whole comparison's
    (the same layout :meth:`thermonet.DriftEstimator.save` writes); ``tracking`` as it was
    actually used (:func:`resolved_config`)."""
    return {"family": to_dict(fam), "train": to_dict(train_config_of(cfg, fam)),
            "features": to_dict(cfg.features), "target": cfg.target,
            "tracking": to_dict(cfg.tracking) if tracking is None else dict(tracking)}


def data_source(cfg: CompareConfig, ds: Dataset | None, *, given: bool) -> dict[str, Any]:
    """Where the data of a comparison actually came from, for ``results.json``'s
    ``provenance`` and each checkpoint: the files with their SHA-256 (and the mapping's),
    or the simulator's preset, run count and seed, or a dataset the caller passed in."""
    def file(path: str | Path) -> dict[str, Any]:
        p = Path(path)
        return {"path": str(path), "sha256": sha256_file(p) if p.is_file() else None}

    if given and ds is not None:
        sources = sorted({r.meta.get("source", "") for r in ds} - {""})
        return {"kind": "dataset", "device": ds.device_id, "runs": [r.run_id for r in ds],
                "preset": ds.meta.get("preset") or None, "sources": sources[:20]}
    if cfg.data.paths:
        skipped = None if ds is None else ds.meta.get("skipped_rows")
        return {"kind": "files", "files": [file(p) for p in cfg.data.paths],
                "mapping": None if cfg.data.mapping is None else file(cfg.data.mapping),
                # rows a mapping's ``malformed_rows: skip`` dropped (None: none could be)
                "skipped_rows": None if skipped is None else int(skipped)}
    return {"kind": "simulated", "preset": cfg.data.preset,
            "runs": cfg.data.runs if ds is None else len(ds), "seed": cfg.data.seed}


def resolved_config(cfg: CompareConfig, ds: Dataset | None, *, given: bool,
                    tracking_enabled: bool,
                    tracking_uri: str | None, workers: int) -> dict[str, Any]:
    """The config as the comparison actually used it — ``config.resolved.yaml``, results.json's
    ``config``, the MLflow params — and still a config ``load_config`` reads back.

    Not the config's defaults where they did not apply: a comparison on files has no
    ``preset``, ``runs`` or ``seed``, nor has one on a dataset the caller passed (a
    calibrate instance) unless the data say which preset made them; ``tracking.enabled``
    is false under ``--no-track``
    and ``tracking.uri`` is the store written to (None when none was); ``workers`` is the
    number of families actually fitted side by side; a simulated comparison names the runs
    simulated.
    """
    d = to_dict(cfg)
    if cfg.data.paths:
        d["data"] = {"preset": None, "paths": list(cfg.data.paths), "mapping": cfg.data.mapping,
                     "outputs": list(cfg.data.outputs)}
    elif given:  # the caller's dataset (a fleet unit, a calibrate instance): not the default
        preset = None if ds is None else (ds.meta.get("preset") or ds[0].meta.get("preset"))
        d["data"] = {"preset": preset or None, "outputs": list(cfg.data.outputs)}
        if preset and ds is not None:
            d["data"]["runs"] = len(ds)
    elif ds is not None:
        d["data"]["runs"] = len(ds)
    d["tracking"] = {"enabled": bool(tracking_enabled),
                     "uri": tracking_uri if tracking_enabled else None,
                     "experiment": cfg.tracking.experiment}
    d["workers"] = int(workers)
    return d


def resolved_yaml(resolved: dict[str, Any], provenance: dict[str, Any]) -> str:
    """``config.resolved.yaml``: the resolved config, headed by comments saying where the
    data came from (with digests) and the options as given."""
    src = provenance["data"]
    lines = [f"# thermonet {provenance['thermonet_version']}: the configuration this comparison "
             "actually used"]
    if src["kind"] == "files":
        lines.append("# data files (sha256  path):")
        lines += [f"#   {f['sha256'] or 'missing'}  {f['path']}" for f in src["files"]]
        if src["mapping"]:
            lines.append(f"# mapping: {src['mapping']['sha256'] or 'missing'}  "
                         f"{src['mapping']['path']}")
    elif src["kind"] == "simulated":
        lines.append(f"# data: simulated, preset {src['preset']}, "
                     f"{counted(int(src['runs']), 'run')}, seed {src['seed']}")
    else:
        lines.append(f"# data: a dataset passed by the caller (device {src['device']}, "
                     f"runs {', '.join(src['runs'])})")
    t = provenance["tracking"]
    lines.append("# tracking: " + (f"MLflow at {t['uri']}" if t["enabled"] else "off"))
    given = {k: v for k, v in provenance["options"].items() if v is not None}
    lines.append("# options as given: " + (", ".join(f"{k}={v!r}" for k, v in given.items())
                                           or "none (the defaults)"))
    return "\n".join(lines) + "\n" + _yaml_text(resolved)


def _yaml_text(data: Any) -> str:
    import yaml

    return yaml.safe_dump(data, sort_keys=False)
