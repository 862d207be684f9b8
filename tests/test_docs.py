"""The documentation: every relative link in every markdown file of the repository resolves,
README.md stays a front page (at most 300 lines), and configs/README.md documents every key
the config loader accepts.

Links are read from the real files: inline links and images ``[text](target)`` and reference
definitions ``[id]: target`` outside code; a target with a scheme (``https:``, ``mailto:``) is
not followed. A relative target must name a file or folder inside the repository (a fresh clone
has nothing beside it); a ``#anchor`` into a markdown file must name one of its headings, as
GitHub makes the anchor from the heading (lower case, punctuation dropped, spaces as hyphens,
``-1``, ``-2`` … for repeats) or an explicit ``<a name=…>``/``id=…``.
"""

from __future__ import annotations

import dataclasses
import importlib
import re
import subprocess
import unicodedata
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]
README_MAX_LINES = 300

_FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})")
_INLINE_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*(<[^>]*>|[^()\s]+)"
                          r"(?:\s+(?:\"[^\"]*\"|'[^']*'))?\s*\)")
_REF_DEF = re.compile(r"^ {0,3}\[[^\]]+\]:\s*(<[^>]*>|\S+)")
_CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1")
_HEADING = re.compile(r"^ {0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
_HTML_ANCHOR = re.compile(r"""<a\s[^>]*(?:name|id)\s*=\s*["']([^"']+)["']""", re.I)
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")


def markdown_files() -> list[Path]:
    """Every markdown file git tracks (and new ones it would track), else every one on disk
    outside hidden and build folders (a copy without ``.git``)."""
    try:
        out = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z", "--",
                              "*.md"], cwd=ROOT, capture_output=True, check=True)
        names = [n for n in out.stdout.decode().split("\0") if n]
        files = [ROOT / n for n in names if (ROOT / n).is_file()]
    except (OSError, subprocess.CalledProcessError):
        skip = {"runs", "mlruns", "build", "dist", "node_modules"}
        files = [p for p in ROOT.rglob("*.md")
                 if not any(part.startswith(".") or part in skip or part.endswith(".egg-info")
                            for part in p.relative_to(ROOT).parts[:-1])]
    return sorted(files)


def _prose_lines(text: str, blank_code: bool = True) -> list[tuple[int, str]]:
    """(line number, line) outside fenced code blocks, inline code spans blanked."""
    out, fence = [], None
    for no, line in enumerate(text.splitlines(), 1):
        m = _FENCE.match(line)
        if fence is None and m:
            fence = m.group(1)[0] * len(m.group(1))
            continue
        if fence is not None:
            if line.strip().startswith(fence) and set(line.strip()) <= {fence[0]}:
                fence = None
            continue
        out.append((no, _CODE_SPAN.sub(lambda s: " " * len(s.group(0)), line)
                    if blank_code else line))
    return out


def links(path: Path) -> list[tuple[int, str]]:
    """(line number, target) of every link in a markdown file."""
    found = []
    for no, line in _prose_lines(path.read_text(encoding="utf-8")):
        for m in _INLINE_LINK.finditer(line):
            found.append((no, m.group(1)))
        m = _REF_DEF.match(line)
        if m:
            found.append((no, m.group(1)))
    return [(no, t[1:-1] if t.startswith("<") and t.endswith(">") else t) for no, t in found]


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading's text (as github-slugger makes it)."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)   # links: their text
    text = re.sub(r"<[^>]+>", "", text)                            # inline HTML
    text = text.replace("`", "").replace("*", "").lower()
    kept = "".join(c for c in text
                   if c in " -_" or unicodedata.category(c)[0] in "LNM")
    return kept.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every anchor a markdown file offers: its headings' slugs (repeats numbered) and
    explicit HTML anchors."""
    seen: dict[str, int] = {}
    out: set[str] = set()
    for _, line in _prose_lines(path.read_text(encoding="utf-8"), blank_code=False):
        m = _HEADING.match(line)
        if m:
            slug = github_slug(m.group(2))
            n = seen.get(slug, 0)
            seen[slug] = n + 1
            out.add(slug if n == 0 else f"{slug}-{n}")
        out.update(_HTML_ANCHOR.findall(line))
    return out


def broken_links(path: Path, root: Path = ROOT) -> list[str]:
    """One line per link of ``path`` (a file under ``root``) that does not resolve."""
    bad = []
    rel = path.relative_to(root)
    for no, target in links(path):
        if not target or _SCHEME.match(target) or target.startswith("//"):
            continue
        where = f"{rel}:{no}: ({target})"
        file_part, _, anchor = target.partition("#")
        file_part = unquote(file_part.split("?", 1)[0])
        if file_part.startswith("/"):
            bad.append(f"{where} is absolute: write it relative to {rel}")
            continue
        dest = (path.parent / file_part).resolve() if file_part else path
        if dest != root and root not in dest.parents:
            bad.append(f"{where} leaves the repository")
        elif not dest.exists():
            bad.append(f"{where}: no such file or folder")
        elif anchor and dest.suffix.lower() == ".md" and dest.is_file() \
                and unquote(anchor) not in anchors(dest):
            bad.append(f"{where}: no heading with anchor #{anchor} in {dest.relative_to(root)}")
    return bad


# ------------------------------------------------------------------ the checker itself
def test_slugs_follow_github():
    assert github_slug("Two commands") == "two-commands"
    assert github_slug("From a PX4 or ArduPilot log") == "from-a-px4-or-ardupilot-log"
    assert github_slug("Command start-up — `bench_imports.py`") == \
        "command-start-up--bench_importspy"
    assert github_slug("Default comparison (`make demo`) — `bench_default.py`") == \
        "default-comparison-make-demo--bench_defaultpy"
    assert github_slug("On any x86-64 CPU") == "on-any-x86-64-cpu"
    assert github_slug("Targets: what the drift is relative to") == \
        "targets-what-the-drift-is-relative-to"


def test_the_checker_finds_a_broken_link_and_a_missing_heading(tmp_path):
    """The checker on real files in a scratch tree: good links pass, each kind of bad one is
    named with its line."""
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "a.md").write_text("# Alpha\n## Beta: two\n## Beta: two\n")
    doc = tmp_path / "doc.md"
    doc.write_text("# Doc\n[ok](sub/a.md#beta-two-1) [ok](#doc) [web](https://x.invalid/y)\n"
                   "`[not a link](nowhere.md)`\n```\n[nor this](nowhere.md)\n```\n"
                   "[gone](sub/b.md) [bad](sub/a.md#gamma) [out](../x.md) [ok](sub)\n"
                   "[ref]: sub/a.md#alpha\n")
    bad = broken_links(doc, root=tmp_path)
    assert len(bad) == 3, bad
    assert bad[0].startswith("doc.md:7: (sub/b.md)") and "no such file" in bad[0]
    assert "#gamma" in bad[1] and "leaves the repository" in bad[2]


# ------------------------------------------------------------------ the repository's docs
@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(path):
    bad = broken_links(path)
    assert not bad, "\n".join(bad)


def test_the_markdown_files_are_found():
    names = {str(p.relative_to(ROOT)) for p in markdown_files()}
    assert {"README.md", "configs/README.md", "export/README.md", "experiments/README.md",
            "tests/README.md"} <= names


def test_readme_is_a_front_page():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, \
        f"README.md has {len(lines)} lines; move detail next to what it documents"


# ------------------------------------------------------------------ every config key
def _default_config():
    """The built-in default config, through the public loader where there is one."""
    import thermonet

    load = getattr(thermonet, "load_config", None)
    if load is None:
        load = importlib.import_module("thermonet.training.config").load_config
    return load(None)


def _keys(obj, prefix: str = ""):
    for f in dataclasses.fields(obj):
        key = f"{prefix}{f.name}"
        yield key
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            yield from _keys(value, f"{key}.")
        elif isinstance(value, list) and value and dataclasses.is_dataclass(value[0]):
            yield from _keys(value[0], f"{key}[].")


def test_configs_readme_documents_every_key():
    """Each key the loader accepts (its dataclasses, walked from the default config) appears
    in configs/README.md as a dotted key in code (`train.average_s`, `families[].inputs`)."""
    text = (ROOT / "configs" / "README.md").read_text(encoding="utf-8")
    keys = list(_keys(_default_config()))
    assert len(keys) > 30
    missing = [k for k in keys if f"`{k}`" not in text]
    assert not missing, f"configs/README.md does not document: {missing}"


# ------------------------------------------------------------------ no tracking store in git
def test_no_tracking_store_is_committed():
    """The MLflow store a run leaves in the working directory (``mlflow.db``, its lock file and
    SQLite's journals, ``mlruns/``) is ignored by git, and none of it is tracked."""
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    try:
        tracked = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                                 check=True).stdout.decode().split("\0")
        ignored = subprocess.run(["git", "check-ignore", "--no-index", "mlflow.db",
                                  "mlflow.db.lock", "mlflow.db-journal", "mlruns/0/meta.yaml"],
                                 cwd=ROOT, capture_output=True, text=True).stdout.split()
    except OSError:
        pytest.skip("git is not installed")
    store = [n for n in tracked if re.search(r"(^|/)(mlflow\.db[^/]*|mlruns/.*)$", n)]
    assert not store, f"tracking-store files committed: {store}"
    assert set(ignored) == {"mlflow.db", "mlflow.db.lock", "mlflow.db-journal",
                            "mlruns/0/meta.yaml"}


# ------------------------------------------------------------------ the front page's first steps
def _first_steps() -> list[str]:
    """The shell commands of README.md's "First steps" block, as written."""
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("First steps after"))
    fence = next(i for i in range(start, len(lines)) if lines[i].startswith("```sh"))
    end = next(i for i in range(fence + 1, len(lines)) if lines[i].startswith("```"))
    return [line.split("  #")[0].strip() for line in lines[fence + 1:end] if line.strip()]


def _demo_command() -> str:
    """The Makefile's own ``make demo`` command, with the clone's ``.venv``."""
    make = (ROOT / "Makefile").read_text(encoding="utf-8")
    return re.search(r"^demo:.*\n\t(.+)$", make, re.M).group(1).replace("$(VENV)", ".venv")


def _clone_layout(tmp_path: Path) -> None:
    """``tmp_path`` laid out as a fresh clone: the repository's configs and runtime."""
    for name in ("configs", "export"):
        (tmp_path / name).symlink_to(ROOT / name)


def _check_first_steps_output(tmp_path: Path) -> None:
    """The runtime's output is the checkpoint's prediction: ``<axis>_drift`` equals
    ``DriftEstimator.load(...).predict`` on the simulated CSV, ``<axis>_comp`` is raw − drift,
    and the compensated unit is closer to the simulator's true rate than the raw one."""
    import json

    import numpy as np
    import pandas as pd

    from thermonet import DriftEstimator, read
    from tolerances import assert_f32_close

    got = pd.read_csv(tmp_path / "runs" / "compensated.csv")
    inp = pd.read_csv(tmp_path / "runs" / "input.csv")
    assert len(got) == len(inp)
    chosen = json.loads((tmp_path / "runs" / "demo" / "results.json").read_text())["chosen"]
    est = DriftEstimator.load(tmp_path / "runs" / "demo" / "models" / f"{chosen}.pt")
    want = np.asarray(est.predict(read(tmp_path / "runs" / "input.csv")))
    axes = ["gyro_x", "gyro_y", "gyro_z"]
    drift = got[[f"{a}_drift" for a in axes]].to_numpy()
    ok = got["out_of_range"].to_numpy() == 0
    assert ok.mean() > 0.99
    assert_f32_close(drift[ok], want[ok], "dynamic")
    for a in axes:
        comp, raw, ref = got[f"{a}_comp"], inp[a], inp[f"ref_{a}"]
        # the runtime subtracts its float32 drift from the raw value: float32 rounding at the
        # raw value's scale
        assert_f32_close(comp.to_numpy(), (raw - got[f"{a}_drift"]).to_numpy(), "affine",
                         scale=raw.abs().max())
        assert (comp - ref).std() < 0.1 * (raw - ref).std()


@pytest.mark.slow
def test_readme_first_steps_run_as_written(tmp_path):
    """In a directory laid out as a fresh clone after ``make demo`` (the repository's configs and
    runtime, ``runs/demo`` from the Makefile's own demo command), every first-steps command runs
    as written, each in a fresh process, and the runtime's output is the checkpoint's
    prediction (``_check_first_steps_output``).  `make test-slow`; its fast twin is below."""
    import os
    import shlex
    import sys

    _clone_layout(tmp_path)
    venv = tmp_path / ".venv" / "bin"
    venv.mkdir(parents=True)
    # the test's interpreter stands in for the clone's .venv
    for tool, run in (("python", ""), ("thermonet", " -m thermonet.cli")):
        (venv / tool).write_text(f'#!/bin/sh\nexec "{sys.executable}"{run} "$@"\n')
        (venv / tool).chmod(0o755)
    env = {**os.environ, "PYTHONPATH": str(ROOT),
           "MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path / 'mlflow.db'}"}
    steps = _first_steps()
    assert any("runs/input.csv" in s and "simulate" in s for s in steps)
    for cmd in [_demo_command(), *steps]:
        out = subprocess.run(shlex.split(cmd), cwd=tmp_path, env=env, capture_output=True,
                             text=True, timeout=600)
        assert out.returncode == 0, f"{cmd}\n{out.stdout[-2000:]}\n{out.stderr[-2000:]}"
    _check_first_steps_output(tmp_path)


#: The fast twin's ``runs/demo``: the default config with two of its families (the cubic
#: baseline and the dynamic-input ``poly3-rate`` the full default set chooses), not all seven.
SMALL_DEMO = """
families:
  - {name: cubic, family: poly, inputs: [dT], params: {degree: 3}}
  - {name: poly3-rate, family: poly, inputs: [dT, rate], params: {degree: 3, cross: true}}
"""


def test_readme_first_steps_run_in_process(tmp_path, monkeypatch):
    """The fast twin of the test above: the same first-steps commands, each command line as
    written, run in this process (``.venv/bin/thermonet ARGS`` as ``thermonet.cli.main(ARGS)``,
    ``.venv/bin/python export/thermonet_runtime.py ARGS`` as the runtime's ``main(ARGS)``),
    after a smaller ``make demo`` (two families of the default config); the same checks of
    the runtime's output."""
    import shlex

    from conftest import load_runtime
    from thermonet.cli import main

    _clone_layout(tmp_path)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    demo = _demo_command()
    assert "configs/default.yaml" in demo
    (tmp_path / "demo.yaml").write_text(
        (ROOT / "configs" / "default.yaml").read_text(encoding="utf-8") + SMALL_DEMO)
    runtime = load_runtime()
    steps = _first_steps()
    assert any("runs/input.csv" in s and "simulate" in s for s in steps)
    for cmd in [demo.replace("configs/default.yaml", "demo.yaml"), *steps]:
        argv = shlex.split(cmd)
        if argv[0] == ".venv/bin/thermonet":
            rc = main(argv[1:])
        else:
            assert argv[:2] == [".venv/bin/python", "export/thermonet_runtime.py"], cmd
            rc = runtime.main(argv[2:])
        assert rc == 0, cmd
    _check_first_steps_output(tmp_path)


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "configs").glob("*.yaml")))
def test_config_data_paths_exist_in_a_clone(name):
    """Every recording and mapping a shipped config names is in the repository, relative to its
    root as configs/README.md says (the real recordings ship in ``tests/data/real/``); a file
    under ``runs/`` is one the config's comment has ``thermonet simulate`` write first."""
    from thermonet.training.config import load_config

    data = load_config(ROOT / "configs" / name).data
    for p in [*data.paths, *([data.mapping] if data.mapping else [])]:
        if Path(p).parts[0] == "runs":
            assert "thermonet simulate" in (ROOT / "configs" / name).read_text()
            continue
        assert not Path(p).is_absolute() and (ROOT / p).is_file(), f"{name}: {p}"


def _module_rows() -> dict[str, list[str]]:
    """tests/README.md's module table: module → the test names in its two columns."""
    text = (ROOT / "tests" / "README.md").read_text()
    section = text.split("## Which tests exercise each module", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        if line.startswith("| `"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            names = [n.strip() for c in cells[1:] for n in c.split(",")]
            rows[cells[0].strip("`")] = [n for n in names if n and not n.startswith("(")]
    return rows


def test_every_module_has_its_tests_named():
    """Each module of thermonet/ has one row in tests/README.md's map, each row a module that
    exists, and each test it names a test file that exists."""
    rows = _module_rows()
    modules = {"thermonet (package)"} | {
        ".".join(p.relative_to(ROOT / "thermonet").with_suffix("").parts).removesuffix(
            ".__init__") for p in (ROOT / "thermonet").rglob("*.py")
        if p.name != "__init__.py" or p.parent != ROOT / "thermonet"}
    assert sorted(modules - set(rows)) == [], "modules without a row in tests/README.md"
    assert sorted(set(rows) - modules) == [], "rows naming no module"
    named = {n.split(" ")[0] for names in rows.values() for n in names}
    missing = sorted(n for n in named if not (ROOT / "tests" / f"test_{n}.py").is_file())
    assert missing == [], "rows naming no test file"
