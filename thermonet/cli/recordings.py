"""``thermonet simulate``, ``info`` and ``convert``: recordings written, summarised and
converted (their options and handlers)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from ..core.errors import ThermonetError, counted
from ..core.fileio import refuse_overwriting_inputs
from .options import overwrite_arg, refuse_existing

#: The preset that writes flights of one vehicle (logs with its estimator), not a run.
FLIGHTS_PRESET = "fc-board-flights"


def _cmd_simulate(args: argparse.Namespace) -> int:
    from ..data.io import write_csv, write_parquet  # lazy: loads pandas, pyarrow, yaml
    from ..data.logs import is_log  # lazy: off the --help path
    from ..sim import simulate, simulate_fleet  # lazy: off the --help path
    from ..sim.fcboard import BOARD_PRESETS, MAX_BOARD_RUNS  # lazy: off the --help path
    from ..sim.presets import MAX_RUNS  # lazy: off the --help path

    if args.preset == FLIGHTS_PRESET or args.flights is not None or args.format:
        return _simulate_flights(args)       # flights of one vehicle: logs with its estimator
    if args.runs is not None and not 1 <= args.runs <= MAX_RUNS:
        raise ThermonetError(f"--runs {args.runs}: not in 1..{MAX_RUNS} (the upper bound keeps "
                             "a request within memory)")
    if args.preset in BOARD_PRESETS:
        # a board log is one board (--runs: several warm-ups of it): options it does not use
        # are refused, not ignored
        unused = _given(args, takes=("runs",))
        if unused:
            raise ThermonetError(f"{unused[0]}: preset '{args.preset}' simulates one board "
                                 "(one log per warm-up); it takes only --seed, --runs, --out "
                                 "and --overwrite")
        if args.runs is not None and args.runs > MAX_BOARD_RUNS:
            raise ThermonetError(f"--runs {args.runs}: preset '{args.preset}' writes at most "
                                 f"{MAX_BOARD_RUNS} logs (one file per warm-up)")
    elif args.preset.lower() not in _preset_names():
        raise ThermonetError(f"unknown preset '{args.preset}' (valid: "
                             f"{', '.join(_preset_names())})")
    if args.seed < 0:
        raise ThermonetError(f"--seed {args.seed}: must be a non-negative integer")
    if args.preset in BOARD_PRESETS or is_log(args.out):
        return _simulate_board(args)
    for opt in ("outliers", "clusters", "test"):
        if args.units is None and getattr(args, opt):
            raise ThermonetError(f"--{opt} needs --units (it shapes the units of a fleet)")
    refuse_existing([Path(args.out)], args.overwrite)   # before anything is simulated
    if args.units is None:
        ds = simulate(args.preset, runs=args.runs, seed=args.seed)
    else:
        ds = simulate_fleet(args.preset, units=args.units, runs=args.runs, seed=args.seed,
                            outliers=args.outliers, clusters=args.clusters, test=args.test)
    path = (write_csv if Path(args.out).suffix.lower() == ".csv" else write_parquet)(ds, args.out)
    n = sum(r.n_samples for r in ds)
    fleet = f"{counted(len(ds.unit_ids), 'unit')} ({counted(args.outliers, 'outlier')}), " \
        if args.units else ""
    print(f"wrote {path}: preset {args.preset}, {fleet}{counted(len(ds), 'run')}, "
          f"{counted(n, 'sample')}, outputs {', '.join(ds.axes)}")
    return 0


def _simulate_board(args: argparse.Namespace) -> int:
    from ..data.logs import is_log  # lazy: off the --help path
    from ..data.logs.writers import write_log  # lazy: off the --help path
    from ..sim.fcboard import BOARD_PRESETS, simulate_board  # lazy: off the --help path

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
    refuse_existing(paths, args.overwrite)
    for run, target in enumerate(paths):
        log = simulate_board(args.preset, autopilot=autopilot, seed=args.seed, run=run)
        path = write_log(log, target)
        print(f"wrote {path}: preset {args.preset} ({autopilot}), run {run + 1} of "
              f"{len(paths)}, {len(log.instances)} sensor instances, "
              f"{log.instances[0].n_samples} samples each")
    return 0


def _simulate_flights(args: argparse.Namespace) -> int:
    """``simulate fc-board-flights --flights N --out DIR [--format ulg|bin]``."""
    from ..data.logs.flight_writers import write_flight  # lazy: off the --help path
    from ..sim.flights import simulate_flights  # lazy: off the --help path

    if args.preset != FLIGHTS_PRESET:
        raise ThermonetError(f"--flights / --format: only preset 'fc-board-flights' writes "
                             f"flights (got '{args.preset}')")
    if args.flights is None:
        raise ThermonetError("fc-board-flights: give --flights N (the number of logs)")
    unused = _given(args, takes=("flights", "format"))
    if unused:      # refused, not ignored
        raise ThermonetError(f"{unused[0]}: fc-board-flights writes --flights N logs of one "
                             "vehicle; it takes only --flights, --seed, --format and --out")
    if args.seed < 0:
        raise ThermonetError(f"--seed {args.seed}: must be a non-negative integer")
    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ThermonetError(f"{out}: --out must be a new or empty directory (one log a flight"
                             + ("; --overwrite replaces no directory)" if args.overwrite
                                else ")"))
    ext = args.format or "ulg"
    flights = simulate_flights(args.flights, seed=args.seed,
                               autopilot="px4" if ext == "ulg" else "ardupilot")
    for k, f in enumerate(flights):
        write_flight(f.log, f.biases, out / f"flight{k + 1:04d}.{ext}")
    lo, hi = (f"{g(f.ambient_c for f in flights):.0f}" for g in (min, max))
    print(f"wrote {out}: {counted(len(flights), 'flight')} of one vehicle "
          f"(fc-board, seed {args.seed}) as .{ext}, ambient "
          f"{lo if lo == hi else lo + '..' + hi} °C")
    return 0


#: simulate's options beside the preset, --seed and --out, and their defaults (not given).
_OPTIONS = {"runs": None, "units": None, "outliers": 0, "clusters": 0, "test": None,
            "flights": None, "format": None}


def _given(args: argparse.Namespace, takes: tuple[str, ...]) -> list[str]:
    """The options given (not at their default) that a preset does not take, as typed."""
    return [f"--{k} {getattr(args, k)}" for k, default in _OPTIONS.items()
            if k not in takes and getattr(args, k) != default]


def _cmd_info(args: argparse.Namespace) -> int:
    from ..data.logs import is_log_source  # lazy: off the --help path
    from ..workflows.info import format_summary  # lazy: loads yaml

    if any(is_log_source(f) for f in args.files):      # a log, or LOG#instance
        from ..data.logs.info import format_log_summary, summarize_log  # lazy: off the --help path

        if len(args.files) != 1:
            raise ThermonetError(f"info reads one flight-controller log at a time "
                                 f"({len(args.files)} files given): run it once per log")
        if args.mapping:
            raise ThermonetError(f"--mapping {args.mapping}: a flight-controller log takes no "
                                 "mapping (its topics name every column)")
        s = summarize_log(args.files[0])
        print(json.dumps(s, indent=2) if args.json else format_log_summary(s))
        return 0
    if args.chunk_rows is not None and args.chunk_rows < 1:
        raise ThermonetError(f"--chunk-rows must be >= 1, got {args.chunk_rows}")
    from ..data.chunks import DEFAULT_CHUNK_ROWS, open_source  # lazy: loads pandas, pyarrow, yaml
    from ..data.mapping import load_mapping  # lazy: loads yaml
    from ..workflows.info_chunked import summarize_parquet  # lazy: loads pandas, pyarrow, yaml

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
    from ..data.chunks import (  # lazy: loads pandas, pyarrow, yaml
        DEFAULT_CHUNK_ROWS,
        open_source,
        write_streamed,
    )
    from ..data.io import (  # lazy: loads pandas, pyarrow, yaml
        in_default_units,
        read_datasets,
        write_csv,
        write_parquet,
    )
    from ..data.logs import is_log_source  # lazy: off the --help path
    from ..data.mapping import load_mapping  # lazy: loads yaml

    out = Path(args.out)
    # what --out must be, said before whether it exists (--overwrite would not help)
    if out.suffix.lower() not in (".parquet", ".pq", ".csv"):
        raise ThermonetError(f"{out}: --out must end in .parquet (or .pq), a thermonet "
                             "recording, or .csv, the runtime's input")
    if out.is_dir():
        raise ThermonetError(f"{out}: is a directory; --out names a .parquet or .csv file")
    refuse_overwriting_inputs(out, [*args.files, *([args.mapping] if args.mapping else [])])
    refuse_existing([out], args.overwrite)
    if args.chunk_rows is not None and args.chunk_rows < 1:
        raise ThermonetError(f"--chunk-rows must be >= 1, got {args.chunk_rows}")
    if out.suffix.lower() == ".csv" or any(is_log_source(f) for f in args.files):
        # a .csv: the runtime's input (export/thermonet_runtime.py reads a CSV whole, so
        # this one is read whole too); a flight log: read whole
        ds = read_datasets(args.files, mapping=args.mapping)
        if out.suffix.lower() == ".csv":
            # a CSV carries no units: each channel written in the unit it is read back in
            ds, converted = in_default_units(ds, out)
            if converted:
                print(f"{out}: written in the default units a CSV is read back in: "
                      f"{', '.join(converted)}")
        (write_csv if out.suffix.lower() == ".csv" else write_parquet)(ds, out)
        n_runs, n = len(ds), sum(r.n_samples for r in ds)
    else:
        chunk = args.chunk_rows or DEFAULT_CHUNK_ROWS
        mapping = load_mapping(args.mapping) if args.mapping else None
        layouts = [open_source(f, mapping, chunk_rows=chunk) for f in args.files]
        n_runs, n = write_streamed(layouts, out, chunk_rows=chunk)
    print(f"{n_runs} run(s), {counted(n, 'sample')} -> {out}")
    return 0


def _preset_names() -> list[str]:
    """Every simulator preset: the registry's (``thermonet.sim.presets.PRESETS``, filled as
    :mod:`thermonet.sim` is imported), then the flight-controller boards."""
    from ..sim import PRESETS  # lazy: numpy and the simulator, only for simulate's help
    from ..sim.fcboard import BOARD_PRESETS  # lazy: as above

    return [*PRESETS, *(b for b in (*BOARD_PRESETS, FLIGHTS_PRESET) if b not in PRESETS)]


class _PresetsHelp(argparse.HelpFormatter):
    """``simulate --help``: ``{presets}`` in a help text becomes the registry's presets,
    looked up only when that help is shown (``thermonet --help`` and every command's start
    import no simulator)."""

    def _expand_help(self, action: argparse.Action) -> str:
        text = super()._expand_help(action)
        return text.replace("{presets}", " | ".join(_preset_names())) \
            if "{presets}" in text else text


def add_simulate(sub: Any) -> None:
    """``thermonet simulate``: a study preset written as a recording."""
    s = sub.add_parser("simulate", help="simulate a thermal-chamber test (a study preset)",
                       formatter_class=_PresetsHelp,
                       description="Simulate a thermal-chamber test from a study preset "
                                   "and write it as a thermonet Parquet file (or, with --out "
                                   "FILE.csv, as CSV: the runtime's input).")
    s.add_argument("preset", help="{presets} (fc-board and fc-board-cycle: --out FILE.ulg "
                                  "or FILE.bin; fc-board-flights: --flights N --out DIR)")
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
    overwrite_arg(s, "an existing --out file (.parquet, .csv, .ulg / .bin logs)")
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
                        "programme: soaks:T1,T2,... (20-min soaks), ramp:FROM,TO,MINUTES or "
                        "cycle:FROM,TO,MINUTES (up and back)")
    s.set_defaults(func=_cmd_simulate)


def add_info(sub: Any) -> None:
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


def add_convert(sub: Any) -> None:
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

