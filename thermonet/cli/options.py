"""Options several commands share (``compare``, ``train`` and ``fleet`` write a tracked
comparison directory)."""

from __future__ import annotations

import argparse


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

