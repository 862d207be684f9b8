"""``thermonet calibrate`` and ``verify``: a PX4 / ArduPilot thermal calibration written
from a log and checked on a new one (their options and handlers)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from ..workflows.calibrate import (  # lazy: off the --help path
        calibrate,
        format_report,
        format_summary,
    )
    from ..workflows.magnetometer import parse_thermometers  # lazy: off the --help path

    doc = calibrate(args.log, args.out, overwrite=args.overwrite, compare=not args.no_compare,
                    mag_thermometers=parse_thermometers(args.mag_thermometer or []),
                    workers=args.workers)
    if not args.quiet:      # one line per instance; each one's detail with --detail
        print(format_report(doc) if args.detail else format_summary(
            doc, detail=f"{Path(args.out) / 'report.txt'} (or calibrate --detail)"), end="")
        print(f"results: {Path(args.out) / 'results.json'}")
    return 0


def _cmd_verify(args: argparse.Namespace) -> int:
    from ..workflows.verify import (  # lazy: off the --help path
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


def add_calibrate(sub: Any) -> None:
    """``thermonet calibrate``: PX4 / ArduPilot thermal calibration from a log."""
    k = sub.add_parser("calibrate", help="PX4 / ArduPilot thermal calibration from a log",
                       description="Fit every sensor instance of a PX4 ULog (.ulg) or "
                                   "ArduPilot DataFlash log (.bin) in the autopilot's own form "
                                   "and side by side with thermonet's families, judge on "
                                   "held-out blocks, write px4.params or ardupilot.parm, "
                                   "results.json, report.html and report.txt to --out.")
    k.add_argument("log", nargs="+",
                   help="flight-controller log(s) recorded while the board warmed at rest (a "
                        "log of the vehicle moving is refused: flight logs are for thermonet "
                        "learn); several "
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


def add_verify(sub: Any) -> None:
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

