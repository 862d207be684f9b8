"""``thermonet fleet``, ``learn``, ``prior`` and ``station``: many units in one job, a
vehicle's flight logs, a fleet prior and the units calibrated from it (their options and
handlers)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ..core.errors import ThermonetError
from .options import overwrite_arg, refuse_existing, tracking_args


def _cmd_learn(args: argparse.Namespace) -> int:
    from ..workflows.learn import format_learn_report, learn  # lazy: off the --help path

    say = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    doc = learn(args.logs, args.out, executor=args.executor, workers=args.workers,
                ray_address=args.ray_address, compare=not args.no_compare,
                export=not args.no_export, say=say, overwrite=args.overwrite)
    if not args.quiet:
        print(format_learn_report(doc, args.out), end="")
        print(f"results: {Path(args.out) / 'results.json'}")
    return 0


def _cmd_fleet(args: argparse.Namespace) -> int:
    from ..training.config import load_config  # lazy: loads yaml
    from ..training.loader import load_fleet_data  # lazy: loads yaml
    from ..workflows.fleet import (  # lazy: loads yaml
        EXIT_LIMITS_FAILED,
        FleetOptions,
        run_fleet,
    )
    from ..workflows.fleet_units import (  # lazy: loads yaml
        sources_from_dataset,
        sources_from_files,
        sources_from_simulation,
    )

    cfg = load_config(args.config)
    opts = FleetOptions(executor=args.executor, workers=args.workers,
                        ray_address=args.ray_address, family=args.family, folds=args.folds)
    if args.units is not None:
        if cfg.data.paths:
            raise ThermonetError(f"{args.config}: --units simulates a fleet of the config's "
                                 "preset; this config reads files (data.paths)")
        sources = sources_from_simulation(cfg.data.preset or "", units=args.units,
                                          runs=cfg.data.runs, seed=cfg.data.seed,
                                          outliers=args.outliers)
    else:
        if args.outliers:
            raise ThermonetError("--outliers needs --units (outliers are simulated units)")
        # one thermonet Parquet file per unit: each worker reads its own file; otherwise the
        # driver reads the data and sends each unit's runs to its worker
        by_file = sources_from_files(cfg.data.paths) if cfg.data.paths and not (
            cfg.data.mapping or cfg.data.outputs) else None
        sources = by_file or sources_from_dataset(load_fleet_data(cfg, source=str(args.config)),
                                                  files=cfg.data.paths)
        for s in sources:
            if s.error is not None:  # that unit fails alone; the fleet goes on
                print(f"thermonet: warning: {s.error}", file=sys.stderr)
    results = run_fleet(cfg, args.out, sources, options=opts,
                        track=False if args.no_track else None,
                        tracking_uri=args.tracking_uri, quiet=args.quiet,
                        overwrite=args.overwrite, plots=not args.no_plots)
    if not args.quiet:
        print(f"\nresults: {Path(args.out) / 'results.json'}")
    return 0 if results["fleet"]["all_passed"] else EXIT_LIMITS_FAILED


def _station_sources(args: argparse.Namespace, cfg: Any) -> list[Any]:
    """Units for ``prior`` / ``station``: simulated (``--units``) or the config's data."""
    from ..training.loader import load_fleet_data  # lazy: loads yaml
    from ..workflows.fleet_units import (  # lazy: off the --help path
        sources_from_dataset,
        sources_from_simulation,
    )

    if args.units is None:
        for opt in ("outliers", "clusters", "test"):
            if getattr(args, opt, None):
                raise ThermonetError(f"--{opt} needs --units (it shapes simulated units)")
        return sources_from_dataset(load_fleet_data(cfg, source=str(args.config)),
                                    files=cfg.data.paths)
    if cfg.data.paths:
        raise ThermonetError(f"{args.config}: --units simulates units of the config's preset; "
                             "this config reads files (data.paths)")
    return sources_from_simulation(cfg.data.preset or "", units=args.units,
                                   runs=cfg.data.runs if getattr(args, "test", None) is None
                                   else None, seed=cfg.data.seed, outliers=args.outliers,
                                   clusters=args.clusters, test=getattr(args, "test", None))


def _short_tests(args: argparse.Namespace, cfg: Any) -> Any:
    """The prior's units' short tests (``--short-test``): simulated by the spec with
    ``--units`` (the same units), else read from the file with the config's mapping."""
    import dataclasses

    from ..core.recording import Dataset  # lazy: off the --help path
    from ..training.loader import load_fleet_data  # lazy: loads yaml
    from ..workflows.fleet_units import sources_from_simulation  # lazy: off the --help path

    spec = args.short_test
    if spec is None:
        return None
    if not spec:
        raise ThermonetError("--short-test is empty: give the units' short tests (a file, or "
                             "with --units a test such as cycle:-20,75,10)")
    if args.units is not None:
        sources = sources_from_simulation(cfg.data.preset or "", units=args.units,
                                          seed=cfg.data.seed, outliers=args.outliers,
                                          clusters=args.clusters, test=spec)
        return Dataset(runs=[r for s in sources for r in s.load(cfg)])
    if not Path(spec).is_file():
        raise ThermonetError(f"{spec}: --short-test: no such file (the prior's units' short "
                             "tests, one run per unit; with --units, a test such as "
                             "cycle:-20,75,10)")
    data = dataclasses.replace(cfg.data, paths=[spec], preset=None)
    return load_fleet_data(dataclasses.replace(cfg, data=data), source=spec)


def _cmd_prior(args: argparse.Namespace) -> int:
    from ..core.fileio import atomic_write_text, check_out_file  # lazy: off the --help path
    from ..core.recording import Dataset  # lazy: off the --help path
    from ..scoring.prior_design import soak_plan  # lazy: off the --help path
    from ..scoring.prior_io import DIGEST_KEY, prior_digest  # lazy: off the --help path
    from ..training.config import load_config  # lazy: loads yaml
    from ..workflows.station import (  # lazy: off the --help path
        build_prior,
        format_prior,
        parse_station_limits,
        prior_summary,
    )
    from ..workflows.station_prior import PLAN_SOAKS, PLAN_STEP_C  # lazy: off the --help path

    cfg = load_config(args.config)
    out = check_out_file(args.out)      # before any unit is read or fitted
    refuse_existing([out], args.overwrite)
    sources = _station_sources(args, cfg)
    ds = Dataset(runs=[r for s in sources for r in s.load(cfg)])
    fp = build_prior(cfg, ds, source=str(args.config), short=_short_tests(args, cfg))
    data = fp.to_dict()
    data["summary"] = prior_summary(fp, parse_station_limits(cfg))
    data["three_soak_plan_c"] = soak_plan(fp, PLAN_SOAKS, step_c=PLAN_STEP_C)
    data = json.loads(json.dumps(data))       # the content as it will be read back
    data[DIGEST_KEY] = prior_digest(data)
    atomic_write_text(out, json.dumps(data, indent=2))
    if not args.quiet:
        print(f"wrote {out}: " + format_prior(fp, data["summary"], data["three_soak_plan_c"]))
    return 0


def _read_prior(path: str) -> Any:
    from ..scoring.prior_io import check_digest, prior_from_dict  # lazy: off the --help path

    p = Path(path)
    if p.is_dir():
        raise ThermonetError(f"{p}: --prior is a directory; give the prior file (prior.json)")
    if not p.is_file():
        raise ThermonetError(f"{p}: --prior: no such file (write one with `thermonet prior`)")
    if p.stat().st_size > 16_000_000:
        raise ThermonetError(f"{p}: --prior: {p.stat().st_size:,} bytes is not a prior file")
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, ValueError) as err:
        raise ThermonetError(f"{p}: --prior: not JSON ({str(err).splitlines()[0]})") from None
    warning = check_digest(data, str(p))
    fp = prior_from_dict(data, str(p))
    if warning is not None:
        print(f"thermonet: warning: {warning}", file=sys.stderr)
    return fp


def _check_station_data(path: str) -> None:
    """A station config must name its units' data: without a ``data`` section the config's
    defaults would simulate the default preset's units, not the line's."""
    from ..core.yamlio import load_yaml  # lazy: loads yaml

    raw = load_yaml(path)
    data = raw.get("data") if isinstance(raw, dict) else None
    if not isinstance(data, dict) or not (data.get("paths") or data.get("preset")):
        raise ThermonetError(f"{path}: config names no data (data.paths or data.preset): "
                             "the station calibrates the units whose data it is given")


def _cmd_station(args: argparse.Namespace) -> int:
    from ..training.config import load_config  # lazy: loads yaml
    from ..workflows.station import (  # lazy: off the --help path
        EXIT_STATION_FAILED,
        StationOptions,
        format_station,
        run_station,
    )

    cfg = load_config(args.config)
    _check_station_data(args.config)
    fp = _read_prior(args.prior)
    sources = _station_sources(args, cfg)
    res = run_station(cfg, fp, sources, Path(args.out), overwrite=args.overwrite,
                      opts=StationOptions(args.executor, args.workers, args.ray_address,
                                          args.prior),
                      say=(lambda *_: None) if args.quiet else print)
    if not args.quiet:
        print(format_station(res))
        print(f"\nresults: {Path(args.out) / 'results.json'}")
    return 0 if res["summary"]["failed"] == 0 else EXIT_STATION_FAILED


def _sim_unit_args(q: argparse.ArgumentParser, test: bool) -> None:
    q.add_argument("--units", type=int, default=None,
                   help="simulate N units of the config's preset instead of reading data")
    q.add_argument("--outliers", type=int, default=0, help="with --units: K outlier units")
    q.add_argument("--clusters", type=int, default=0,
                   help="with --units: a structured fleet of K clusters of drift shapes")
    if test:
        q.add_argument("--test", default=None, help="with --units: the short test simulated "
                       "(soaks:T1,T2,..., ramp:FROM,TO,MINUTES or cycle:FROM,TO,MINUTES)")


def add_prior(sub: Any) -> None:
    """``thermonet prior``: a fleet prior from calibrated units."""
    q = sub.add_parser("prior", help="a fleet prior from calibrated units (for the station)",
                       description="Fit every unit of CONFIG's data (a fleet, device id per "
                                   "run) and write the population of their drift curves "
                                   "(configs/README.md#fleet-prior-and-station).")
    q.add_argument("config", help="comparison YAML whose data hold the calibrated units")
    q.add_argument("--out", required=True, help="the prior file to write (prior.json)")
    overwrite_arg(q, "an existing prior file")
    _sim_unit_args(q, test=False)
    q.add_argument("--short-test", default=None,
                   help="the same units' short tests, one run per unit (a file read with the "
                        "config's mapping; with --units, a test simulated: soaks:..., ramp:... "
                        "or cycle:...): the prior learns how that test reads each unit's "
                        "drift, and the station calibrates new units through it")
    q.add_argument("-q", "--quiet", action="store_true", help="no summary on stdout")
    q.set_defaults(func=_cmd_prior)


def add_station(sub: Any) -> None:
    """``thermonet station``: new units calibrated from a short test and a fleet prior."""
    q = sub.add_parser("station", help="calibrate new units from a short test and a prior",
                       description="Calibrate each unit of CONFIG's data from its short test "
                                   "and the fleet prior; judge it on held-out temperatures and "
                                   "against station.limits; write a file per unit. Exit 0: "
                                   "every unit passed; 3: some unit failed (one whose data "
                                   "fail a check fails alone, with its reason; the others "
                                   "finish); 1: bad input, nothing written.")
    q.add_argument("config", help="comparison YAML whose data hold the new units' tests")
    q.add_argument("--prior", required=True, help="prior file from `thermonet prior`")
    q.add_argument("--out", required=True, help="output directory")
    _sim_unit_args(q, test=True)
    q.add_argument("--executor", choices=["process", "serial", "ray"], default="process",
                   help="process pool (default), this process, or a Ray cluster")
    q.add_argument("--workers", type=int, default=None, help="worker processes (default: all)")
    q.add_argument("--ray-address", default=None, help="Ray cluster address")
    q.add_argument("--overwrite", action="store_true", help="replace a previous station output")
    q.add_argument("-q", "--quiet", action="store_true", help="no table on stdout")
    q.set_defaults(func=_cmd_station)


def add_learn(sub: Any) -> None:
    """``thermonet learn``: the drift from a vehicle's ordinary flight logs."""
    k = sub.add_parser("learn", help="learn each sensor's drift from a vehicle's flight logs",
                       description="Learn every gyro's and accelerometer's temperature drift "
                                   "from ordinary PX4 / ArduPilot flight logs of one vehicle "
                                   "(the estimator's biases, the still gyro on the ground): "
                                   "the parameter file, ONNX, C and a coverage map in --out. "
                                   "Exit codes: 0 done (refused logs are listed), 1: no log "
                                   "to learn from or bad input.")
    k.add_argument("logs", nargs="+", help="flight logs (.ulg / .bin) and directories of them")
    k.add_argument("--out", required=True,
                   help="output directory (its cache/ keeps every log read: run again with "
                        "more logs and only the new ones are read)")
    k.add_argument("--executor", choices=["process", "serial", "ray"], default="process",
                   help="where the logs are read (as fleet)")
    k.add_argument("--workers", type=int, default=None, help="processes reading logs")
    k.add_argument("--ray-address", default=None, help="Ray cluster (with --executor ray)")
    k.add_argument("--no-compare", action="store_true",
                   help="the firmware form only (no comparison of the families)")
    k.add_argument("--no-export", action="store_true", help="no ONNX / C of the chosen models")
    k.add_argument("--overwrite", action="store_true",
                   help="replace what --out learned for another vehicle")
    k.add_argument("-q", "--quiet", action="store_true", help="no progress or summary")
    k.set_defaults(func=_cmd_learn)


def add_fleet(sub: Any) -> None:
    """``thermonet fleet``: many units in one job, with pass/fail limits."""
    f = sub.add_parser("fleet", help="calibrate many units in one job, with pass/fail limits",
                       description="Run the comparison of CONFIG on every unit (device id) of "
                                   "the data, summarise the fleet (coefficient spread, robust "
                                   "outliers, leave-units-out) and judge the config's limits. "
                                   "Exit 0: every unit passed; 3: some unit failed its limits "
                                   "or could not be calibrated; 1: bad input.")
    f.add_argument("config", help="comparison YAML (its data holds several units, or --units)")
    tracking_args(f)
    f.add_argument("--units", type=int, default=None,
                   help="simulate N units of the config's preset instead of reading data")
    f.add_argument("--outliers", type=int, default=0, help="with --units: K outlier units")
    f.add_argument("--executor", choices=["process", "serial", "ray"], default="process",
                   help="process pool (default), this process, or a Ray cluster")
    f.add_argument("--workers", type=int, default=None,
                   help="worker processes / local Ray CPUs (default: all cores; 0: one per "
                        "CPU this process may use, as compare)")
    f.add_argument("--ray-address", default=None,
                   help="Ray cluster address (default: start a local Ray)")
    f.add_argument("--family", default=None,
                   help="fleet family for spread and leave-units-out (default: the baseline)")
    f.add_argument("--folds", type=int, default=5,
                   help="leave-units-out groups (0: skip)")
    f.set_defaults(func=_cmd_fleet)

