"""The ``thermonet`` command line.

Exit codes: 0 success, 1 bad input (file, column, config key or value — one
line on stderr naming it), 2 usage error (argparse), 3 (``fleet``) some
unit failed its limits or could not be calibrated, (``verify``) an axis failed
its limits (``verify``'s 1 also covers a log it cannot judge), 130 interrupted by SIGINT (Ctrl-C), 143 terminated by SIGTERM.  An interrupted command prints
one line, not a traceback; its open MLflow runs are ended as KILLED and a
comparison's ``--out`` is left as it was (see :mod:`thermonet.core.outdir`).

A Python warning raised while a command runs (thermonet's own, or a library's) reaches the
console as one line, ``thermonet: warning: <its first line>``, never Python's file:line and
source line; ``-q`` silences them (:func:`main`, for every command).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import signal
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .core import profile
from .core.errors import Interrupted, ThermonetError, clear_interrupt, request_interrupt
from .core.fileio import refuse_overwriting_inputs
from .core.names import path_components
from .core.version import __version__
from .exporting import FORMATS, export_source  # the registry only: no torch, no onnx

# Imports of thermonet's own modules stay inside the command that needs them where they
# would load numpy, pandas, pyarrow, yaml or heavier (torch, MLflow, matplotlib,
# scikit-learn) at start: `thermonet --help` and a refused option then answer in ~0.05 s
# (`python -X importtime -m thermonet.cli --help`: data.io alone costs ~0.7 s).

__all__ = ["main", "build_parser"]


def _cmd_simulate(args: argparse.Namespace) -> int:
    from .data.io import write_csv, write_parquet  # lazy: loads pandas, pyarrow, yaml
    from .data.logs import is_log  # lazy: off the --help path
    from .sim import simulate, simulate_fleet  # lazy: off the --help path
    from .sim.fcboard import BOARD_PRESETS, MAX_BOARD_RUNS  # lazy: off the --help path
    from .sim.presets import MAX_RUNS  # lazy: off the --help path

    if args.preset == "fc-board-flights" or args.flights is not None or args.format:
        return _simulate_flights(args)       # flights of one vehicle: logs with its estimator
    if args.runs is not None and not 1 <= args.runs <= MAX_RUNS:
        raise ThermonetError(f"--runs {args.runs}: not in 1..{MAX_RUNS} (the upper bound keeps "
                             "a request within memory)")
    if args.preset in BOARD_PRESETS:
        # a board log is one board (--runs: several warm-ups of it): options it does not use
        # are refused, not ignored
        unused = [f"--{name} {value}" for name, value in (("units", args.units),
                                                           ("outliers", args.outliers or None))
                  if value is not None]
        if unused:
            raise ThermonetError(f"{unused[0]}: preset '{args.preset}' simulates one board "
                                 "(one log per warm-up); it takes only --seed, --runs and --out")
        if args.runs is not None and args.runs > MAX_BOARD_RUNS:
            raise ThermonetError(f"--runs {args.runs}: preset '{args.preset}' writes at most "
                                 f"{MAX_BOARD_RUNS} logs (one file per warm-up)")
    if args.seed < 0:
        raise ThermonetError(f"--seed {args.seed}: must be a non-negative integer")
    if args.preset in BOARD_PRESETS or is_log(args.out):
        return _simulate_board(args)
    for opt in ("outliers", "clusters", "test"):
        if args.units is None and getattr(args, opt):
            raise ThermonetError(f"--{opt} needs --units (it shapes the units of a fleet)")
    if args.units is None:
        ds = simulate(args.preset, runs=args.runs, seed=args.seed)
    else:
        ds = simulate_fleet(args.preset, units=args.units, runs=args.runs, seed=args.seed,
                            outliers=args.outliers, clusters=args.clusters, test=args.test)
    path = (write_csv if Path(args.out).suffix.lower() == ".csv" else write_parquet)(ds, args.out)
    n = sum(r.n_samples for r in ds)
    fleet = f"{len(ds.unit_ids)} units ({args.outliers} outliers), " if args.units else ""
    print(f"wrote {path}: preset {args.preset}, {fleet}{len(ds)} runs, {n} samples, "
          f"outputs {', '.join(ds.axes)}")
    return 0


def _simulate_board(args: argparse.Namespace) -> int:
    from .data.logs import is_log  # lazy: off the --help path
    from .data.logs.writers import write_log  # lazy: off the --help path
    from .sim.fcboard import BOARD_PRESETS, simulate_board  # lazy: off the --help path

    if args.preset not in BOARD_PRESETS:
        raise ThermonetError(f"{args.out}: only the flight-controller presets "
                             f"({', '.join(BOARD_PRESETS)}) are written as .ulg / .bin logs")
    if not is_log(args.out):
        raise ThermonetError(f"{args.out}: preset '{args.preset}' is a flight-controller log: "
                             "write it as FILE.ulg (PX4) or FILE.bin (ArduPilot)")
    out = Path(args.out)
    autopilot = "px4" if out.suffix.lower() == ".ulg" else "ardupilot"
    # --runs N: N logs of the same board (same ids and drift laws, new warm-ups and noise),
    # FILE_run1.ulg .. FILE_runN.ulg; one log (no --runs, or --runs 1): FILE itself
    paths = [out] if args.runs is None or args.runs == 1 else [
        out.with_name(f"{out.stem}_run{k}{out.suffix}") for k in range(1, args.runs + 1)]
    for run, target in enumerate(paths):
        log = simulate_board(args.preset, autopilot=autopilot, seed=args.seed, run=run)
        path = write_log(log, target)
        print(f"wrote {path}: preset {args.preset} ({autopilot}), run {run + 1} of "
              f"{len(paths)}, {len(log.instances)} sensor instances, "
              f"{log.instances[0].n_samples} samples each")
    return 0


def _simulate_flights(args: argparse.Namespace) -> int:
    """``simulate fc-board-flights --flights N --out DIR [--format ulg|bin]``."""
    from .data.logs.flight_writers import write_flight  # lazy: off the --help path
    from .sim.flights import simulate_flights  # lazy: off the --help path

    if args.preset != "fc-board-flights":
        raise ThermonetError(f"--flights / --format: only preset 'fc-board-flights' writes "
                             f"flights (got '{args.preset}')")
    if args.flights is None:
        raise ThermonetError("fc-board-flights: give --flights N (the number of logs)")
    unused = [f"--{name} {value}" for name, value in (("runs", args.runs), ("units", args.units))
              if value is not None]
    if unused:      # refused, not ignored
        raise ThermonetError(f"{unused[0]}: fc-board-flights writes --flights N logs of one "
                             "vehicle; it takes only --flights, --seed, --format and --out")
    if args.seed < 0:
        raise ThermonetError(f"--seed {args.seed}: must be a non-negative integer")
    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ThermonetError(f"{out}: --out must be a new or empty directory (one log a flight)")
    ext = args.format or "ulg"
    flights = simulate_flights(args.flights, seed=args.seed,
                               autopilot="px4" if ext == "ulg" else "ardupilot")
    for k, f in enumerate(flights):
        write_flight(f.log, f.biases, out / f"flight{k + 1:04d}.{ext}")
    print(f"wrote {out}: {len(flights)} flights of one vehicle (fc-board, seed {args.seed}) "
          f"as .{ext}, ambient {min(f.ambient_c for f in flights):.0f}.."
          f"{max(f.ambient_c for f in flights):.0f} °C")
    return 0


def _cmd_learn(args: argparse.Namespace) -> int:
    from .workflows.learn import format_learn_report, learn  # lazy: off the --help path

    say = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    doc = learn(args.logs, args.out, executor=args.executor, workers=args.workers,
                ray_address=args.ray_address, compare=not args.no_compare,
                export=not args.no_export, say=say)
    if not args.quiet:
        print(format_learn_report(doc), end="")
        print(f"results: {Path(args.out) / 'results.json'}")
    return 0


def _cmd_fleet(args: argparse.Namespace) -> int:
    from .training.config import load_config  # lazy: loads yaml
    from .training.loader import load_fleet_data  # lazy: loads yaml
    from .workflows.fleet import (  # lazy: loads yaml
        EXIT_LIMITS_FAILED,
        FleetOptions,
        run_fleet,
    )
    from .workflows.fleet_units import (  # lazy: loads yaml
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
        sources = by_file or sources_from_dataset(load_fleet_data(cfg, source=str(args.config)))
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
    from .training.loader import load_fleet_data  # lazy: loads yaml
    from .workflows.fleet_units import (  # lazy: off the --help path
        sources_from_dataset,
        sources_from_simulation,
    )

    if args.units is None:
        for opt in ("outliers", "clusters", "test"):
            if getattr(args, opt, None):
                raise ThermonetError(f"--{opt} needs --units (it shapes simulated units)")
        return sources_from_dataset(load_fleet_data(cfg, source=str(args.config)))
    if cfg.data.paths:
        raise ThermonetError(f"{args.config}: --units simulates units of the config's preset; "
                             "this config reads files (data.paths)")
    return sources_from_simulation(cfg.data.preset or "", units=args.units,
                                   runs=cfg.data.runs if getattr(args, "test", None) is None
                                   else None, seed=cfg.data.seed, outliers=args.outliers,
                                   clusters=args.clusters, test=getattr(args, "test", None))


def _cmd_prior(args: argparse.Namespace) -> int:
    import json

    from .core.fileio import atomic_write_text  # lazy: off the --help path
    from .core.recording import Dataset  # lazy: off the --help path
    from .training.config import load_config  # lazy: loads yaml
    from .workflows.station import (  # lazy: off the --help path
        build_prior,
        format_prior,
        parse_station_limits,
        prior_summary,
    )

    cfg = load_config(args.config)
    out = Path(args.out)
    if out.is_dir():
        raise ThermonetError(f"{out}: --out must be a file (prior.json), and this is a directory")
    sources = _station_sources(args, cfg)
    ds = Dataset(runs=[r for s in sources for r in s.load(cfg)])
    fp = build_prior(cfg, ds, source=str(args.config))
    data = fp.to_dict()
    data["summary"] = prior_summary(fp, parse_station_limits(cfg))
    atomic_write_text(out, json.dumps(data, indent=2))
    if not args.quiet:
        print(f"wrote {out}: " + format_prior(fp, data["summary"]))
    return 0


def _read_prior(path: str) -> Any:
    import json

    from .scoring.prior import FleetPrior  # lazy: off the --help path

    p = Path(path)
    if not p.is_file():
        raise ThermonetError(f"{p}: --prior: no such file (write one with `thermonet prior`)")
    if p.stat().st_size > 16_000_000:
        raise ThermonetError(f"{p}: --prior: {p.stat().st_size:,} bytes is not a prior file")
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, ValueError) as err:
        raise ThermonetError(f"{p}: --prior: not JSON ({str(err).splitlines()[0]})") from None
    return FleetPrior.from_dict(data, str(p))


def _cmd_station(args: argparse.Namespace) -> int:
    from .training.config import load_config  # lazy: loads yaml
    from .workflows.station import (  # lazy: off the --help path
        EXIT_STATION_FAILED,
        StationOptions,
        format_station,
        run_station,
    )

    cfg = load_config(args.config)
    fp = _read_prior(args.prior)
    sources = _station_sources(args, cfg)
    res = run_station(cfg, fp, sources, Path(args.out), overwrite=args.overwrite,
                      opts=StationOptions(args.executor, args.workers, args.ray_address),
                      say=(lambda *_: None) if args.quiet else print)
    if not args.quiet:
        print(format_station(res))
        print(f"\nresults: {Path(args.out) / 'results.json'}")
    return 0 if res["summary"]["failed"] == 0 else EXIT_STATION_FAILED


def _cmd_info(args: argparse.Namespace) -> int:
    from .data.logs import is_log  # lazy: off the --help path
    from .workflows.info import format_summary  # lazy: loads yaml

    if any(is_log(f) for f in args.files):
        from .data.logs.info import format_log_summary, summarize_log  # lazy: off the --help path

        if len(args.files) != 1 or args.mapping:
            raise ThermonetError("info reads one flight-controller log at a time, with no "
                                 "mapping")
        s = summarize_log(args.files[0])
        print(json.dumps(s, indent=2) if args.json else format_log_summary(s))
        return 0
    if args.chunk_rows is not None and args.chunk_rows < 1:
        raise ThermonetError(f"--chunk-rows must be >= 1, got {args.chunk_rows}")
    from .data.chunks import DEFAULT_CHUNK_ROWS, open_source  # lazy: loads pandas, pyarrow, yaml
    from .data.mapping import load_mapping  # lazy: loads yaml
    from .workflows.info_chunked import summarize_parquet  # lazy: loads pandas, pyarrow, yaml

    # every tabular file: one chunked pass (two for a file without thermonet's metadata),
    # memory bounded by the chunk
    chunk = args.chunk_rows or DEFAULT_CHUNK_ROWS
    mapping = load_mapping(args.mapping) if args.mapping else None
    summary = summarize_parquet([open_source(f, mapping, chunk_rows=chunk) for f in args.files],
                                chunk_rows=chunk)
    print(json.dumps(summary, indent=2, default=str) if args.json else format_summary(summary))
    return 0


def _cmd_convert(args: argparse.Namespace) -> int:
    """Recordings (CSV, mapped files, Parquet) to one thermonet Parquet file, read and
    written a chunk at a time (flight logs: read whole), or to a CSV with thermonet's column
    names (``--out x.csv``: the input ``export/thermonet_runtime.py`` reads; read whole)."""
    from .data.chunks import (  # lazy: loads pandas, pyarrow, yaml
        DEFAULT_CHUNK_ROWS,
        open_source,
        write_streamed,
    )
    from .data.io import (  # lazy: loads pandas, pyarrow, yaml
        read_datasets,
        write_csv,
        write_parquet,
    )
    from .data.logs import is_log  # lazy: off the --help path
    from .data.mapping import load_mapping  # lazy: loads yaml

    out = Path(args.out)
    refuse_overwriting_inputs(out, [*args.files, *([args.mapping] if args.mapping else [])])
    if out.exists() and not args.overwrite:
        raise ThermonetError(f"{out}: already exists (give --overwrite to replace it)")
    if args.chunk_rows is not None and args.chunk_rows < 1:
        raise ThermonetError(f"--chunk-rows must be >= 1, got {args.chunk_rows}")
    if out.suffix.lower() == ".csv" or any(is_log(f) for f in args.files):
        # a .csv: the runtime's input (export/thermonet_runtime.py reads a CSV whole, so
        # this one is read whole too); a flight log: read whole
        ds = read_datasets(args.files, mapping=args.mapping)
        (write_csv if out.suffix.lower() == ".csv" else write_parquet)(ds, out)
        n_runs, n = len(ds), sum(r.n_samples for r in ds)
    else:
        chunk = args.chunk_rows or DEFAULT_CHUNK_ROWS
        mapping = load_mapping(args.mapping) if args.mapping else None
        layouts = [open_source(f, mapping, chunk_rows=chunk) for f in args.files]
        n_runs, n = write_streamed(layouts, out, chunk_rows=chunk)
    print(f"{n_runs} run(s), {n} samples -> {out}")
    return 0


def _compare_common(args: argparse.Namespace, only: str | None = None) -> int:
    from .training.config import load_config  # lazy: loads yaml

    # the config is checked whole before the comparison machinery (torch) is imported:
    # a wrong key or value is refused in a fraction of a second
    cfg = load_config(args.config)
    from .workflows.compare import format_table, run_compare  # lazy: loads yaml

    if only is not None:
        fams = [f for f in cfg.families if f.label == only]
        if not fams:
            raise ThermonetError(f"{args.config}: no family named '{only}' (families: "
                                 f"{', '.join(f.label for f in cfg.families)})")
        cfg.families = fams
        cfg.baseline = None
    results = run_compare(cfg, args.out, overwrite=args.overwrite,
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


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from .workflows.calibrate import (  # lazy: off the --help path
        calibrate,
        format_report,
        format_summary,
    )
    from .workflows.magnetometer import parse_thermometers  # lazy: off the --help path

    doc = calibrate(args.log, args.out, overwrite=args.overwrite, compare=not args.no_compare,
                    mag_thermometers=parse_thermometers(args.mag_thermometer or []),
                    workers=args.workers)
    if not args.quiet:      # one line per instance; each one's detail with --detail
        print(format_report(doc) if args.detail else format_summary(
            doc, detail=f"{Path(args.out) / 'report.txt'} (or calibrate --detail)"), end="")
        print(f"results: {Path(args.out) / 'results.json'}")
    return 0


def _cmd_verify(args: argparse.Namespace) -> int:
    from .workflows.verify import (  # lazy: off the --help path
        EXIT_FAILED,
        Limits,
        format_verify_report,
        verify,
    )

    limits = Limits()                       # the documented defaults, where not given
    if args.min_cut is not None:
        limits.min_cut = args.min_cut
    for kind in ("gyro", "acc", "baro", "mag"):
        value = getattr(args, f"{kind}_floor")
        if value is not None:
            limits.floor[kind] = value
    doc = verify(args.params, args.log, args.out, limits=limits, overwrite=args.overwrite)
    if not args.quiet:
        print(format_verify_report(doc), end="")
        print(f"report: {Path(args.out) / 'report.html'}")
    return 0 if doc["passed"] else EXIT_FAILED


def build_parser() -> argparse.ArgumentParser:
    """The ``thermonet`` parser: global options, then one sub-parser per command, added in
    the order ``--help`` lists them (each by its ``_add_<command>``)."""
    p = argparse.ArgumentParser(
        prog="thermonet",
        description="Train, judge and export temperature-drift models for inertial sensors.")
    p.add_argument("--version", action="version", version=f"thermonet {__version__}")
    p.add_argument("--profile", action="store_true",
                   help="print where the command's time went: start-up and each stage's wall "
                        "and CPU seconds (on stderr, after the command)")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in (_add_simulate, _add_info, _add_convert, _add_compare, _add_export,
                _add_calibrate, _add_verify, _add_fleet, _add_learn, _add_prior, _add_station):
        add(sub)
    return p


def _preset_names() -> list[str]:
    """Every simulator preset: the registry's (``thermonet.sim.presets.PRESETS``, filled as
    :mod:`thermonet.sim` is imported), then the flight-controller boards."""
    from .sim import PRESETS  # lazy: numpy and the simulator, only for simulate's help
    from .sim.fcboard import BOARD_PRESETS  # lazy: as above

    return [*PRESETS, *(b for b in BOARD_PRESETS if b not in PRESETS)]


class _PresetsHelp(argparse.HelpFormatter):
    """``simulate --help``: ``{presets}`` in a help text becomes the registry's presets,
    looked up only when that help is shown (``thermonet --help`` and every command's start
    import no simulator)."""

    def _expand_help(self, action: argparse.Action) -> str:
        text = super()._expand_help(action)
        return text.replace("{presets}", " | ".join(_preset_names())) \
            if "{presets}" in text else text


def _add_simulate(sub: Any) -> None:
    """``thermonet simulate``: a study preset written as a recording."""
    s = sub.add_parser("simulate", help="simulate a thermal-chamber test (a study preset)",
                       formatter_class=_PresetsHelp,
                       description="Simulate a thermal-chamber test from a study preset "
                                   "and write it as a thermonet Parquet file (or, with --out "
                                   "FILE.csv, as CSV: the runtime's input).")
    s.add_argument("preset", help="{presets} (fc-board and fc-board-cycle: --out FILE.ulg "
                                  "or FILE.bin)")
    s.add_argument("--runs", type=int, default=None,
                   help="number of runs (default: the preset's); fc-board: N logs of the same "
                        "board, written as FILE itself when N is 1 and as FILE_run1 .. "
                        "FILE_runN (beside FILE, its suffix kept) when N > 1")
    s.add_argument("--seed", type=int, default=0, help="random seed (same seed, same file)")
    s.add_argument("--flights", type=int, default=None,
                   help="fc-board-flights: N flight logs of one vehicle across the seasons, "
                        "written into the directory --out (for `thermonet learn`)")
    s.add_argument("--format", choices=["ulg", "bin"], default=None,
                   help="fc-board-flights: ulg (PX4, the default) or bin (ArduPilot)")
    s.add_argument("--out", required=True,
                   help="output .parquet file, or .csv (conventional column names, one row a "
                        "sample: what export/thermonet_runtime.py reads); .ulg / .bin for fc-board")
    s.add_argument("--units", type=int, default=None,
                   help="simulate a fleet of N units (device ids <preset>-u000 …), each with "
                        "the preset's unit-to-unit spread")
    s.add_argument("--outliers", type=int, default=0,
                   help="with --units: the last K units follow a drift law 10σ off the fleet's")
    s.add_argument("--clusters", type=int, default=0,
                   help="with --units: a structured fleet of K clusters of drift shapes "
                        "(polynomial presets; for `thermonet prior`)")
    s.add_argument("--test", default=None,
                   help="with --units: a short production test instead of the preset's "
                        "programme: soaks:T1,T2,... (20-min soaks) or ramp:FROM,TO,MINUTES")
    s.set_defaults(func=_cmd_simulate)


def _add_info(sub: Any) -> None:
    """``thermonet info``: what recordings hold."""
    i = sub.add_parser("info", help="summarise recordings",
                       description="Channels, units, runs, duration, rate, temperature span, "
                                   "noise floor and binned peak-to-peak per channel.")
    i.add_argument("files", nargs="+", help="recording files (one run per file unless the file "
                                            "has a 'run' column)")
    i.add_argument("--mapping", default=None, help="YAML column mapping (configs/data/*.yaml)")
    i.add_argument("--json", action="store_true", help="print the summary as JSON")
    i.add_argument("--chunk-rows", type=int, default=None, metavar="N",
                   help="rows read at a time (default 65536; memory stays bounded by it, "
                        "whatever the files' length)")
    i.set_defaults(func=_cmd_info)


def _add_convert(sub: Any) -> None:
    """``thermonet convert``: recordings to one thermonet Parquet file."""
    v = sub.add_parser("convert", help="recordings to one thermonet Parquet file",
                       description="Read recording files (CSV, a mapping's format, Parquet) "
                                   "a chunk at a time and write them as one thermonet Parquet "
                                   "file (row groups of about --chunk-rows rows): memory stays "
                                   "bounded by one chunk, whatever the files' size; or, "
                                   "with --out NAME.csv, as one CSV with thermonet's column "
                                   "names, the input of export/thermonet_runtime.py (read "
                                   "whole).")
    v.add_argument("files", nargs="+", help="recording files (one run per file unless the file "
                                            "has a 'run' column)")
    v.add_argument("--mapping", default=None, help="YAML column mapping (configs/data/*.yaml)")
    v.add_argument("--out", required=True, help="output .parquet file, or .csv (the runtime's input)")
    v.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    v.add_argument("--chunk-rows", type=int, default=None, metavar="N",
                   help="rows read (and written per row group) at a time (default 65536)")
    v.set_defaults(func=_cmd_convert)


def _family_workers_arg(q: argparse.ArgumentParser) -> None:
    """``--workers``: families fitted side by side (``compare``, ``train``)."""
    q.add_argument("--workers", type=int, default=None, metavar="N",
                   help="families fitted side by side (default: the config's 'workers', "
                        "0 = one per CPU)")


def _tracking_args(q: argparse.ArgumentParser) -> None:
    """The options of every command that writes a tracked comparison directory."""
    q.add_argument("--out", required=True, help="output directory (created whole when the "
                                                "comparison finishes)")
    q.add_argument("--overwrite", action="store_true",
                   help="replace a previous comparison in --out (removed only once the new "
                        "one is complete)")
    q.add_argument("--no-track", action="store_true", help="do not record the run in MLflow")
    q.add_argument("--tracking-uri", default=None,
                   help="MLflow tracking URI (default sqlite:///mlflow.db in the working dir)")
    q.add_argument("-q", "--quiet", action="store_true", help="no progress, no table")
    q.add_argument("--no-plots", action="store_true",
                   help="write no PNG plots (report.html then has no figures)")


def _add_compare(sub: Any) -> None:
    """``thermonet compare`` and ``thermonet train`` (one family of a config)."""
    c = sub.add_parser("compare", help="fit every family, judge on held-out runs",
                       description="Fit every model family of CONFIG, judge them on held-out "
                                   "data, write results.json, plots and checkpoints to --out.")
    c.add_argument("config", nargs="?", default=None,
                   help="comparison YAML (default: built-in, the patent-gyro simulator)")
    _tracking_args(c)
    _family_workers_arg(c)
    c.set_defaults(func=_cmd_compare)

    t = sub.add_parser("train", help="fit one family of a config",
                       description="Fit and judge one family of CONFIG (by its name).")
    t.add_argument("config", help="comparison YAML")
    t.add_argument("--family", required=True, help="the family's name in the config")
    _tracking_args(t)
    _family_workers_arg(t)
    t.set_defaults(func=_cmd_train)


def _add_export(sub: Any) -> None:
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


def _add_calibrate(sub: Any) -> None:
    """``thermonet calibrate``: PX4 / ArduPilot thermal calibration from a log."""
    k = sub.add_parser("calibrate", help="PX4 / ArduPilot thermal calibration from a log",
                       description="Fit every sensor instance of a PX4 ULog (.ulg) or "
                                   "ArduPilot DataFlash log (.bin) in the autopilot's own form "
                                   "and side by side with thermonet's families, judge on "
                                   "held-out blocks, write px4.params or ardupilot.parm, "
                                   "results.json, report.html and report.txt to --out.")
    k.add_argument("log", nargs="+",
                   help="flight-controller log(s) recorded while the board warmed; several "
                        "logs of one board: fitted on all but the last, checked on the last "
                        "with verify's test (one log: on a quarter of it in time blocks), the "
                        "files refitted on all; the same log twice is refused")
    k.add_argument("--out", required=True, help="output directory (created whole at the end)")
    k.add_argument("--overwrite", action="store_true",
                   help="replace a previous calibration in --out (its own files only; removed "
                        "only once the new one is complete)")
    k.add_argument("--no-compare", action="store_true",
                   help="fit the firmware form only (no side-by-side comparison with "
                        "thermonet's families: faster, no instances/ folder)")
    k.add_argument("--workers", type=int, default=None, metavar="N",
                   help="processes comparing instances side by side (default: one per CPU, "
                        "at most 3; 1: this one alone)")
    k.add_argument("--mag-thermometer", action="append", metavar="MAG=SENSOR",
                   help="the thermometer lent to a magnetometer without one, e.g. mag1=baro0 "
                        "(repeatable; default: baro0, else gyro0, else acc0); its lag is "
                        "fitted")
    say = k.add_mutually_exclusive_group()
    say.add_argument("-q", "--quiet", action="store_true", help="no report on stdout")
    say.add_argument("-v", "--detail", action="store_true",
                     help="after the one line per instance, each instance's detail (its "
                          "verdict, held-out check per axis, notes: report.txt)")
    k.set_defaults(func=_cmd_calibrate)


def _add_verify(sub: Any) -> None:
    """``thermonet verify``: a calibration checked on a new log."""
    v = sub.add_parser("verify", help="check a PX4 / ArduPilot thermal calibration on a new log",
                       description="Apply a px4.params or ardupilot.parm (thermonet's or the "
                                   "autopilot's own tool's) to a log of the same board through "
                                   "the autopilot's own formula (T clamped to TMIN/TMAX, TREF, "
                                   "the polynomial, the sensor matched by device id); report the "
                                   "binned drift before/after per instance and axis, PASS/FAIL "
                                   "(an instance too short or narrow to judge: 'not judged'). "
                                   "Exit 0 PASS, 3 FAIL (an axis fails, NaN/inf included), "
                                   "1 refused (a damaged parameter file, named by line and "
                                   "parameter; nothing of the log can be judged; bad input).")
    v.add_argument("params", help="px4.params (QGC format) or ardupilot.parm")
    v.add_argument("log", help="a new log of the same board (.ulg / .bin)")
    v.add_argument("--out", required=True, help="output directory (created whole at the end)")
    v.add_argument("--min-cut", type=float, default=None,
                   help="an axis passes when its binned drift is cut at least this much "
                        "(default 3)")
    v.add_argument("--gyro-floor", type=float, default=None,
                   help="... or left below this, rad/s (default 5e-4)")
    v.add_argument("--acc-floor", type=float, default=None,
                   help="... or left below this, m/s^2 (default 5e-3)")
    v.add_argument("--baro-floor", type=float, default=None,
                   help="... or left below this, Pa (default 1)")
    v.add_argument("--mag-floor", type=float, default=None,
                   help="... or left below this, µT (default 0.5; PX4 TC_M*)")
    v.add_argument("--overwrite", action="store_true",
                   help="replace a previous verification in --out")
    v.add_argument("-q", "--quiet", action="store_true", help="no report on stdout")
    v.set_defaults(func=_cmd_verify)


def _sim_unit_args(q: argparse.ArgumentParser, test: bool) -> None:
    q.add_argument("--units", type=int, default=None,
                   help="simulate N units of the config's preset instead of reading data")
    q.add_argument("--outliers", type=int, default=0, help="with --units: K outlier units")
    q.add_argument("--clusters", type=int, default=0,
                   help="with --units: a structured fleet of K clusters of drift shapes")
    if test:
        q.add_argument("--test", default=None, help="with --units: the short test simulated "
                       "(soaks:T1,T2,... or ramp:FROM,TO,MINUTES)")


def _add_prior(sub: Any) -> None:
    """``thermonet prior``: a fleet prior from calibrated units."""
    q = sub.add_parser("prior", help="a fleet prior from calibrated units (for the station)",
                       description="Fit every unit of CONFIG's data (a fleet, device id per "
                                   "run) and write the population of their drift curves "
                                   "(configs/README.md#fleet-prior-and-station).")
    q.add_argument("config", help="comparison YAML whose data hold the calibrated units")
    q.add_argument("--out", required=True, help="the prior file to write (prior.json)")
    _sim_unit_args(q, test=False)
    q.add_argument("-q", "--quiet", action="store_true", help="no summary on stdout")
    q.set_defaults(func=_cmd_prior)


def _add_station(sub: Any) -> None:
    """``thermonet station``: new units calibrated from a short test and a fleet prior."""
    q = sub.add_parser("station", help="calibrate new units from a short test and a prior",
                       description="Calibrate each unit of CONFIG's data from its short test "
                                   "and the fleet prior; judge it on held-out temperatures and "
                                   "against station.limits; write a file per unit. Exit 0: "
                                   "every unit passed; 3: some unit failed; 1: bad input.")
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


def _add_learn(sub: Any) -> None:
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
    k.add_argument("-q", "--quiet", action="store_true", help="no progress or summary")
    k.set_defaults(func=_cmd_learn)


def _add_fleet(sub: Any) -> None:
    """``thermonet fleet``: many units in one job, with pass/fail limits."""
    f = sub.add_parser("fleet", help="calibrate many units in one job, with pass/fail limits",
                       description="Run the comparison of CONFIG on every unit (device id) of "
                                   "the data, summarise the fleet (coefficient spread, robust "
                                   "outliers, leave-units-out) and judge the config's limits. "
                                   "Exit 0: every unit passed; 3: some unit failed its limits "
                                   "or could not be calibrated; 1: bad input.")
    f.add_argument("config", help="comparison YAML (its data holds several units, or --units)")
    _tracking_args(f)
    f.add_argument("--units", type=int, default=None,
                   help="simulate N units of the config's preset instead of reading data")
    f.add_argument("--outliers", type=int, default=0, help="with --units: K outlier units")
    f.add_argument("--executor", choices=["process", "serial", "ray"], default="process",
                   help="process pool (default), this process, or a Ray cluster")
    f.add_argument("--workers", type=int, default=None,
                   help="worker processes / local Ray CPUs (default: all cores)")
    f.add_argument("--ray-address", default=None,
                   help="Ray cluster address (default: start a local Ray)")
    f.add_argument("--family", default=None,
                   help="fleet family for spread and leave-units-out (default: the baseline)")
    f.add_argument("--folds", type=int, default=5,
                   help="leave-units-out groups (0: skip)")
    f.set_defaults(func=_cmd_fleet)


def _raise_interrupted(signum: int, frame: object) -> None:
    # recorded too: where the raise lands inside a garbage-collection callback Python prints
    # "Exception ignored" and goes on; the training loops poll the record each epoch
    request_interrupt(signum)
    raise Interrupted(signum)


def _show_warning(message: Warning | str, category: type[Warning], filename: str,
                  lineno: int, file: Any = None, line: str | None = None) -> None:
    """A Python warning (thermonet's own or a library's) as one line in thermonet's voice:
    its first line of text, without the file, line and source line Python prints."""
    text = next((ln.strip() for ln in str(message).splitlines() if ln.strip()),
                category.__name__)
    try:
        print(f"thermonet: warning: {text}", file=sys.stderr if file is None else file)
    except (OSError, ValueError):   # a closed stream: nothing left to say
        pass


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    previous: dict[signal.Signals, Any] = {}
    try:
        # SIGINT and SIGTERM both unwind like Ctrl-C (finally blocks run, runs end KILLED,
        # staging removed). SIGINT is set explicitly too: a process started with SIGINT
        # ignored (a parent's SIG_IGN is inherited across exec, as under pytest-xdist's
        # workers or a non-interactive shell's `&`) would otherwise never see Ctrl-C and run on.
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, _raise_interrupted)
    except ValueError:  # not the main thread (an embedding application): leave signals alone
        pass
    if args.profile:
        profile.enable()
        startup = profile.startup_seconds()
    clear_interrupt()
    caught = warnings.catch_warnings()   # the policy below holds for this command only
    caught.__enter__()
    if getattr(args, "quiet", False):
        warnings.simplefilter("ignore")  # -q: no warnings either
    else:
        warnings.showwarning = _show_warning
    try:
        return int(args.func(args))
    except (KeyboardInterrupt, Interrupted) as err:
        signum = err.signum if isinstance(err, Interrupted) else int(signal.SIGINT)
        print(f"thermonet: interrupted by {signal.Signals(signum).name}; stopped (outputs are "
              "written whole or not at all)", file=sys.stderr)
        return 128 + signum
    except ThermonetError as err:
        print(f"thermonet: error: {err}", file=sys.stderr)
        return 1
    except OSError as err:  # a path that cannot be read or written: one line, not a traceback
        print(f"thermonet: error: {err.filename or ''}: {err.strerror or err}", file=sys.stderr)
        return 1
    finally:
        caught.__exit__(None, None, None)
        clear_interrupt()
        for sig, handler in previous.items():  # None: not set from Python; default is closest
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
        if args.profile:
            print(f"thermonet {args.command}: where the time went\n"
                  + profile.report(startup), file=sys.stderr)
            profile.enable(False)
            profile.reset()


def run() -> None:
    """The ``thermonet`` command (console script, ``python -m thermonet``): :func:`main`,
    then the interpreter's own exit with its code.

    Everything alive at the end is frozen first (:func:`gc.freeze`): the interpreter's
    final collections would otherwise walk every object torch, pandas and matplotlib
    created — 0.4-0.7 s after the command has finished, a tenth of a calibration.  Exit
    handlers, finalizers and the flushing of output run as usual.  :func:`main` itself
    (what tests and embedding programs call) leaves the collector alone.
    """
    rc = main()
    gc.freeze()
    sys.exit(rc)


if __name__ == "__main__":
    run()
