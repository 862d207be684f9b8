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

This package holds the parser, :func:`main` (signals, warnings, errors to exit codes) and
:func:`run` (the console script); each command's options and handler live in the module of
its group: :mod:`.recordings` (simulate, info, convert), :mod:`.comparison` (compare, train,
export), :mod:`.autopilot` (calibrate, verify), :mod:`.fleet` (fleet, learn, prior,
station); options several commands share in :mod:`.options`.
"""

from __future__ import annotations

import argparse
import gc
import os
import signal
import sys
import warnings
from collections.abc import Sequence
from typing import Any

from ..core import profile
from ..core.errors import Interrupted, ThermonetError, clear_interrupt, request_interrupt
from ..core.version import __version__
from .autopilot import add_calibrate, add_verify
from .comparison import add_compare, add_export
from .fleet import add_fleet, add_learn, add_prior, add_station
from .recordings import add_convert, add_info, add_simulate

# Imports of thermonet's own modules stay inside the command that needs them where they
# would load numpy, pandas, pyarrow, yaml or heavier (torch, MLflow, matplotlib,
# scikit-learn) at start: `thermonet --help` and a refused option then answer in ~0.05 s
# (`python -X importtime -m thermonet.cli --help`: data.io alone costs ~0.7 s).  The
# command modules imported above hold only argparse and those lazy imports.

__all__ = ["main", "build_parser", "run"]


def build_parser() -> argparse.ArgumentParser:
    """The ``thermonet`` parser: global options, then one sub-parser per command, added in
    the order ``--help`` lists them (each by its ``add_<command>``, in the
    module of its group of commands)."""
    p = argparse.ArgumentParser(
        prog="thermonet",
        description="Train, judge and export temperature-drift models for inertial sensors.")
    p.add_argument("--version", action="version", version=f"thermonet {__version__}")
    p.add_argument("--profile", action="store_true",
                   help="print where the command's time went: start-up and each stage's wall "
                        "and CPU seconds (on stderr, after the command)")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in (add_simulate, add_info, add_convert, add_compare, add_export,
                add_calibrate, add_verify, add_fleet, add_learn, add_prior, add_station):
        add(sub)
    return p


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
    for opt in ("out", "prior", "mapping"):      # "" would be read as "." (or fail later)
        value = getattr(args, opt, None)
        if isinstance(value, str) and not value.strip():
            print(f"thermonet: error: --{opt} is empty: give a path", file=sys.stderr)
            return 1
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
    # -q silences progress and tables, never a warning: a unit clash or an extrapolation is
    # what a script running quietly must still see (on stderr, one line each)
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
    except BrokenPipeError:  # the reader left (`| head`): stop quietly, as a Unix tool does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())   # no flush error at exit
        return 128 + int(signal.SIGPIPE)
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

