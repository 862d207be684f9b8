"""The torch boundary and the version's home (pyproject.toml's import-linter contracts hold
the imports; these check what a user sees)."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import thermonet
from thermonet.core.version import __version__

ROOT = Path(__file__).resolve().parents[1]


def test_the_version_lives_in_core_and_matches_the_package_metadata():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert __version__ == project["version"]
    assert thermonet.__version__ is __version__


def test_the_command_line_starts_without_torch_or_scikit_learn():
    code = ("import sys, runpy\n"
            "sys.argv = ['thermonet', '--help']\n"
            "try:\n    runpy.run_module('thermonet.cli', run_name='__main__')\n"
            "except SystemExit:\n    pass\n"
            "print(sorted(m for m in ('torch', 'sklearn', 'pandas') if m in sys.modules),"
            " file=sys.stderr)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    assert "usage: thermonet" in out.stdout
    assert out.stderr.strip().splitlines()[-1] == "[]"
