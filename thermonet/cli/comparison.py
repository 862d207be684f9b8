"""``thermonet compare``, ``train`` and ``export``: families fitted and judged, a fitted
model exported (their options and handlers)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from ..core.errors import ThermonetError, failures_line
from ..core.fileio import refuse_overwriting_inputs
from ..core.names import path_components
from ..exporting import FORMATS, export_source  # the registry only: no torch, no onnx
from .options import overwrite_arg, refuse_existing, tracking_args


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
                             plots=not args.no_plots, workers=args.workers,
                             command="compare" if only is None else "train")
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


def _fleet_units(src: Path) -> dict[str, Any]:
    """The units of the fleet directory ``src`` (its results.json's ``units``); a compare
    directory, or anything else, refused in one line."""
    try:
        results = json.loads((src / "results.json").read_text())
        if not isinstance(results, dict):
            raise TypeError("not a mapping")
    except (OSError, ValueError, TypeError) as err:
        raise ThermonetError(f"{src}: not a fleet directory (results.json with 'units': "
                             f"{err})") from None
    if results.get("kind") == "station":
        raise ThermonetError(f"{src}: a station directory, not a fleet: each unit's "
                             "calibration is already written there (units/<id>/calibration."
                             "json and thermonet_cal.h, the firmware's C header); a station "
                             "writes no autopilot parameters")
    if results.get("kind") != "fleet" and isinstance(results.get("families"), dict):
        raise ThermonetError(f"{src}: a compare directory, not a fleet: export it without "
                             "--all-units (--out a file)")
    units = results.get("units")
    if results.get("kind") != "fleet" or not isinstance(units, dict):
        raise ThermonetError(f"{src}: not a fleet directory (its results.json is not a "
                             "fleet's: no kind 'fleet' with a mapping of units)")
    return units


def _export_all_units(args: argparse.Namespace) -> int:
    """One file per unit of a fleet directory, ``OUT/<device_id><ext>``; each verified as a
    single export is.  Units that cannot be exported are listed; exit 1 if any; when none
    was, one line says why and nothing is left (an --out made for them is removed)."""
    from ..exporting.source import check_export_request  # lazy: as export_source

    src = Path(args.source)
    units = _fleet_units(src)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ThermonetError(f"{out}: --out must be a directory with --all-units")
    # a device id read from results.json never becomes a path as it is: the same safe
    # file name as `fleet` gave its unit directory (thermonet.core.names.path_component)
    names = path_components(units)
    ext = _EXTENSIONS.get(args.format, "." + args.format)
    # file names come from the data, so a file already there is replaced only with
    # --overwrite, and never one that is not a plain file (refused before anything is written)
    taken = [f"{names[d]}{ext}" for d in units if os.path.lexists(out / f"{names[d]}{ext}")]
    odd = [t for t in taken if (out / t).is_symlink() or not (out / t).is_file()]
    if odd or (taken and not args.overwrite):
        first = (odd or taken)[0]
        more = f" and {len(odd or taken) - 1} more" if len(odd or taken) > 1 else ""
        raise ThermonetError(f"{out}: already holds {first}{more}" + (
            " (not a plain file: never replaced); choose another --out" if odd else
            "; choose an empty --out, remove them, or pass --overwrite to replace them"))
    if units:   # the options, once, before anything is written
        check_export_request(fmt=args.format, out=out / f"{names[next(iter(units))]}{ext}",
                             family=args.family, device_id=args.device_id,
                             instance=args.instance, prefix=args.prefix)
    made = [d for d in (out, *out.parents) if not d.exists()]   # removed if nothing is written
    out.mkdir(parents=True, exist_ok=True)
    bad: list[tuple[str, str]] = []
    alike: list[tuple[str, str]] = []   # the reasons with the unit's own directory taken off
    for dev, unit in units.items():
        udir = src / "units" / names[dev]
        why = _export_unit(args, src, (dev, unit), udir, out / f"{names[dev]}{ext}")
        if why is not None:
            bad.append((dev, why))
            alike.append((dev, why.replace(f"{udir}{os.sep}", "").replace(f"{udir}: ", "")))
    if len(bad) == len(units):     # nothing written: the directories made for it go too
        for d in made:
            try:
                d.rmdir()
            except OSError:
                break
        raise ThermonetError(f"{src}: no unit exported, nothing written: "
                             + failures_line(alike, "unit"))
    for dev, why in bad:
        print(f"thermonet: {dev}: {why}", file=sys.stderr)
    print(f"{len(units) - len(bad)} of {len(units)} units exported to {out}")
    return 1 if bad else 0


def _export_unit(args: argparse.Namespace, src: Path, dev_unit: tuple[str, Any], udir: Path,
                 out: Path) -> str | None:
    """One unit of ``--all-units`` exported to ``out``: None when written, else why not; an
    autopilot file gets a ``# unit <id>`` line, and the console names the unit."""
    dev, unit = dev_unit
    if isinstance(unit, dict) and unit.get("status") == "failed":
        return f"skipped (the fleet could not calibrate it: {str(unit.get('reason'))[:200]})"
    if not udir.resolve().is_relative_to(src.resolve()) or not udir.is_dir():
        return f"skipped (no unit directory {udir})"
    try:
        path = export_source(str(udir), fmt=args.format, out=out, family=args.family,
                             device_id=args.device_id, instance=args.instance,
                             prefix=args.prefix)
    except ThermonetError as err:
        return f"not exported: {err}"
    if args.format in ("px4-params", "ardupilot-params"):
        from ..exporting.autopilot_read import stamp_unit  # lazy: torch-free, off --help

        stamp_unit(path, dev)     # the file says which unit it is for
    shown = "".join(ch if ch.isprintable() else "?" for ch in dev)   # an id from the data
    print(f"unit {shown}: wrote {path}")
    return None


def _cmd_export(args: argparse.Namespace) -> int:
    _options_apply(args)
    if args.all_units:
        return _export_all_units(args)
    src = Path(args.source)
    # an input named as --out is said as such, --overwrite or not (export_source checks the
    # checkpoint it resolves again)
    refuse_overwriting_inputs(args.out, [src, src / "results.json",
                                         *(sorted((src / "models").glob("*.pt"))
                                           if src.is_dir() else [])])
    refuse_existing([Path(args.out)], args.overwrite)
    path = export_source(args.source, fmt=args.format, out=args.out, family=args.family,
                         tracking_uri=args.tracking_uri, device_id=args.device_id,
                         instance=args.instance, prefix=args.prefix)
    print(f"wrote {path}{_recorded_words(args.source, args.format)}")
    return 0


def _recorded_words(source: str, fmt: str) -> str:
    """`` (gyro1, device 3670050: IMU 2, as its calibration records)`` where an autopilot file
    was written for the sensor an instance directory records, else ""."""
    if fmt not in ("px4-params", "ardupilot-params"):
        return ""
    from ..data.firmware import PX4_LETTER  # lazy, as the rest: off the --help path
    from ..exporting.autopilot_read import recorded_sensor, recorded_slot  # torch-free

    rec = recorded_sensor(source)
    if rec is None:
        return ""
    slot = recorded_slot(rec, fmt)
    where = f"TC_{PX4_LETTER[rec['kind']]}{slot}" if fmt == "px4-params" else \
        f"IMU {slot}, INS_TCAL{slot}"
    return f" ({rec['name']}, device {rec['device_id']}: {where}, as its calibration records)"


def _options_apply(args: argparse.Namespace) -> None:
    """--device-id, --instance and --prefix given to a format that has no use for them: refused, not
    ignored without a word (the Python API takes them for every format, so a loop may pass
    them alike)."""
    if args.device_id is not None and args.format != "px4-params":
        raise ThermonetError(f"--device-id applies to --format px4-params only (PX4's "
                             f"TC_*_ID); {args.format} " + (
                                 "follows the IMU number: --instance"
                                 if args.format == "ardupilot-params" else "names no sensor"))
    if args.instance is not None and args.format not in ("px4-params", "ardupilot-params"):
        raise ThermonetError(f"--instance applies to --format px4-params and "
                             f"ardupilot-params only; {args.format} names no calibration slot")
    from ..exporting.source import check_prefix  # lazy: off the --help path

    check_prefix(args.format, args.prefix)


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
    overwrite_arg(e, "an existing --out file (with --all-units: the units' files in --out)")
    e.add_argument("--prefix", default=None, metavar="NAME",
                   help="c: the prefix of every C symbol (default thermonet); one per header "
                        "in a program")
    e.add_argument("--family", default=None, help="family name in a compare dir (default: chosen)")
    e.add_argument("--tracking-uri", default=None, help="MLflow URI for a run-id source")
    e.add_argument("--device-id", type=int, default=None,
                   help="px4-params: the sensor's device id (TC_*_ID; 'listener sensor_gyro'); "
                        "from a calibrate/learn instances/<name> directory: its own, another "
                        "refused")
    e.add_argument("--instance", type=int, default=None,
                   help="px4-params: calibration slot 0..3 (default 0); "
                        "ardupilot-params: IMU 1..3 (default 1); from a calibrate/learn "
                        "instances/<name> directory: its sensor's, another refused")
    e.set_defaults(func=_cmd_export)

