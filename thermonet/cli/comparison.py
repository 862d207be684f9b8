"""``thermonet compare``, ``train`` and ``export``: families fitted and judged, a fitted
model exported (their options and handlers)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from ..core.errors import ThermonetError
from ..core.names import path_components
from ..exporting import FORMATS, export_source  # the registry only: no torch, no onnx
from .options import tracking_args


def _compare_common(args: argparse.Namespace, only: str | None = None) -> int:
    from ..training.config import load_config  # lazy: loads yaml

    # the config is checked whole before the comparison machinery (torch) is imported:
    # a wrong key or value is refused in a fraction of a second
    if args.workers is not None and args.workers < 0:
        raise ThermonetError(f"--workers {args.workers}: must be an integer >= 0 (0: one per "
                             "CPU)")
    cfg = load_config(args.config)
    from ..workflows.compare import compare_result, format_table  # lazy: loads yaml

    if only is not None:
        fams = [f for f in cfg.families if f.label == only]
        if not fams:
            raise ThermonetError(f"{args.config}: no family named '{only}' (families: "
                                 f"{', '.join(f.label for f in cfg.families)})")
        cfg.families = fams
        cfg.baseline = None
    results = compare_result(cfg, args.out, overwrite=args.overwrite,
                             track=False if args.no_track else None,
                             tracking_uri=args.tracking_uri, quiet=args.quiet,
                             plots=not args.no_plots, workers=args.workers)
    if not args.quiet:
        print(format_table(results))
        print(f"\nresults: {Path(args.out) / 'results.json'}, report: "
              f"{Path(args.out) / 'report.html'}")
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    return _compare_common(args)


def _cmd_train(args: argparse.Namespace) -> int:
    return _compare_common(args, only=args.family)


_EXTENSIONS = {"onnx": ".onnx", "c": ".h", "px4-params": ".params",
               "ardupilot-params": ".parm"}


def _export_all_units(args: argparse.Namespace) -> int:
    """One file per unit of a fleet directory, ``OUT/<device_id><ext>``; each verified as a
    single export is.  Units that cannot be exported are listed; exit 1 if any."""

    src = Path(args.source)
    try:
        units = json.loads((src / "results.json").read_text())["units"]
        if not isinstance(units, dict):
            raise TypeError("'units' is not a mapping")
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ThermonetError(f"{src}: not a fleet directory (results.json with 'units': "
                             f"{err})") from None
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ThermonetError(f"{out}: --out must be a directory with --all-units")
    # a device id read from results.json never becomes a path as it is: the same safe
    # file name as `fleet` gave its unit directory (thermonet.core.names.path_component)
    names = path_components(units)
    ext = _EXTENSIONS.get(args.format, "." + args.format)
    # file names come from the data, so a file already there is never replaced: it may be
    # the user's (refused before anything is written)
    taken = [f"{names[d]}{ext}" for d in units if os.path.lexists(out / f"{names[d]}{ext}")]
    if taken:
        more = f" and {len(taken) - 1} more" if len(taken) > 1 else ""
        raise ThermonetError(f"{out}: already holds {taken[0]}{more}; --all-units writes only "
                             "new files: choose an empty --out or remove them")
    out.mkdir(parents=True, exist_ok=True)
    failed = 0
    for dev in units:
        udir = src / "units" / names[dev]
        if not udir.resolve().is_relative_to(src.resolve()) or not udir.is_dir():
            print(f"thermonet: {dev}: skipped (no unit directory {udir})", file=sys.stderr)
            failed += 1
            continue
        try:
            path = export_source(str(udir), fmt=args.format, out=out / f"{names[dev]}{ext}",
                                 family=args.family,
                                 device_id=args.device_id, instance=args.instance)
            print(f"wrote {path}")
        except ThermonetError as err:
            print(f"thermonet: {dev}: not exported: {err}", file=sys.stderr)
            failed += 1
    print(f"{len(units) - failed} of {len(units)} units exported to {out}")
    return 1 if failed else 0


def _cmd_export(args: argparse.Namespace) -> int:
    if args.all_units:
        return _export_all_units(args)
    path = export_source(args.source, fmt=args.format, out=args.out, family=args.family,
                         tracking_uri=args.tracking_uri, device_id=args.device_id,
                         instance=args.instance)
    print(f"wrote {path}")
    return 0


def _family_workers_arg(q: argparse.ArgumentParser) -> None:
    """``--workers``: families fitted side by side (``compare``, ``train``)."""
    q.add_argument("--workers", type=int, default=None, metavar="N",
                   help="families fitted side by side (default: the config's 'workers', "
                        "0 = one per CPU)")


def add_compare(sub: Any) -> None:
    """``thermonet compare`` and ``thermonet train`` (one family of a config)."""
    c = sub.add_parser("compare", help="fit every family, judge on held-out runs",
                       description="Fit every model family of CONFIG, judge them on held-out "
                                   "data, write results.json, plots and checkpoints to --out.")
    c.add_argument("config", nargs="?", default=None,
                   help="comparison YAML (default: built-in, the patent-gyro simulator)")
    tracking_args(c)
    _family_workers_arg(c)
    c.set_defaults(func=_cmd_compare)

    t = sub.add_parser("train", help="fit one family of a config",
                       description="Fit and judge one family of CONFIG (by its name).")
    t.add_argument("config", help="comparison YAML")
    t.add_argument("--family", required=True, help="the family's name in the config")
    tracking_args(t)
    _family_workers_arg(t)
    t.set_defaults(func=_cmd_train)


def add_export(sub: Any) -> None:
    """``thermonet export``: a fitted model in one of :data:`FORMATS`."""
    e = sub.add_parser("export", help=f"export a fitted model ({', '.join(FORMATS)})",
                       description="Export a model from a compare directory (its chosen family, "
                                   "or its per-axis model, by default), a checkpoint, or an "
                                   "MLflow run id.",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="formats:\n" + "\n".join(f"  {f.name:<18} {f.description}"
                                                        for f in FORMATS.values()))
    e.add_argument("source", help="compare output dir, checkpoint .pt, or MLflow run id")
    e.add_argument("--format", required=True, choices=list(FORMATS),
                   help="export format (listed below)")
    e.add_argument("--out", required=True,
                   help="output file (with --all-units: output directory)")
    e.add_argument("--all-units", action="store_true",
                   help="SOURCE is a fleet directory: write one file per unit, "
                        "OUT/<device_id>.<ext>")
    e.add_argument("--family", default=None, help="family name in a compare dir (default: chosen)")
    e.add_argument("--tracking-uri", default=None, help="MLflow URI for a run-id source")
    e.add_argument("--device-id", type=int, default=None,
                   help="px4-params: the sensor's device id (TC_*_ID; 'listener sensor_gyro')")
    e.add_argument("--instance", type=int, default=None,
                   help="px4-params: calibration slot 0..3 (default 0); "
                        "ardupilot-params: IMU 1..3 (default 1)")
    e.set_defaults(func=_cmd_export)

