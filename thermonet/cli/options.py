"""Options several commands share (``compare``, ``train`` and ``fleet`` write a tracked
comparison directory; ``simulate``, ``export`` and ``prior`` write a file, replaced only with
``--overwrite``)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..core.errors import ThermonetError


def tracking_args(q: argparse.ArgumentParser) -> None:
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



def overwrite_arg(q: argparse.ArgumentParser, what: str = "an existing --out file") -> None:
    """``--overwrite`` of a command that writes one file (``simulate``, ``export``,
    ``prior``): without it an existing file is refused (:func:`refuse_existing`)."""
    q.add_argument("--overwrite", action="store_true", help=f"replace {what}")


def refuse_existing(paths: list[Path], overwrite: bool) -> None:
    """Refuse, in one line naming it, to replace a file already there without
    ``--overwrite`` (checked before any work; a directory is left to the command's own
    check of --out)."""
    if overwrite:
        return
    for p in paths:
        if os.path.lexists(p) and not p.is_dir():
            raise ThermonetError(f"{p}: already exists (give --overwrite to replace it)")
