"""Start-up cost of the command line: what ``thermonet info`` and a config error take.

Targets: ``thermonet info`` on a small file < 1 s; a config error < 1 s.  Each
command is a fresh process (start-up and imports included), run ``RUNS`` times after one
warm-up, alternating with the same command on a baseline tree (``--baseline DIR``, e.g. a
checkout of the commit before the light-import work) so the ratio is taken pair by pair.
Figures: median wall seconds with min–max; the heavy modules each command imported.

Usage: ``python experiments/bench_imports.py [--runs 7] [--baseline /path/to/old/checkout]``
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import save, table  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT / "tests" / "data" / "real"
HEAVY = ("torch", "allantools", "scipy.signal", "sklearn", "pandas", "matplotlib", "mlflow",
         "onnx")


def _commands(tmp: Path) -> dict[str, list[str]]:
    bad_key = tmp / "bad_key.yaml"
    bad_key.write_text("split: {strategy: random}\n")
    bad_family = tmp / "bad_family.yaml"
    bad_family.write_text("families: [{family: spline}]\n")
    return {
        "thermonet --help": ["--help"],
        "thermonet info (BMI270 soak, 1 file + mapping)": [
            "info", str(REAL / "bmi270_two_soaks" / "BMI_270_cold_test_.csv"),
            "--mapping", str(ROOT / "configs" / "data" / "bmi270.yaml")],
        "config error: wrong value (split.strategy)": ["compare", str(bad_key), "--out",
                                                       str(tmp / "o")],
        "config error: unknown family": ["compare", str(bad_family), "--out", str(tmp / "o")],
    }


def _run(tree: Path, args: list[str]) -> tuple[float, float]:
    """Wall seconds and CPU seconds (user + system, the OS's accounting of the child):
    on a shared machine the CPU figure is the one that does not grow with the load."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "thermonet.cli", *args], cwd=tree, env=env,
                   capture_output=True, check=False)
    wall = time.perf_counter() - t0
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime)


def _heavy_imports(tree: Path, args: list[str]) -> list[str]:
    """Heavy modules loaded by the command (run in-process under a module snapshot)."""
    code = ("import sys\nfrom thermonet.cli import main\n"
            f"try:\n    main({args!r})\nexcept SystemExit:\n    pass\n"
            f"print('HEAVY=' + ','.join(m for m in {HEAVY!r} if m in sys.modules))")
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run([sys.executable, "-c", code], cwd=tree, env=env, capture_output=True,
                         text=True, check=False)
    line = [ln for ln in out.stdout.splitlines() if ln.startswith("HEAVY=")]
    return [m for m in line[-1][len("HEAVY="):].split(",") if m] if line else []


def _fmt(xs: list[float]) -> str:
    return f"{statistics.median(xs):.2f} ({min(xs):.2f}–{max(xs):.2f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--baseline", type=Path, default=None,
                    help="another checkout to compare with (its thermonet/ is put on the path)")
    args = ap.parse_args()
    rows, data = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, cmd in _commands(Path(tmp)).items():
            _run(ROOT, cmd)
            if args.baseline:
                _run(args.baseline, cmd)
            ours, base = [], []
            for _ in range(args.runs):          # alternate, so drift hits both alike
                ours.append(_run(ROOT, cmd))
                if args.baseline:
                    base.append(_run(args.baseline, cmd))
            heavy = _heavy_imports(ROOT, cmd)
            wall, cpu = [w for w, _ in ours], [c for _, c in ours]
            entry = {"wall_s": wall, "cpu_s": cpu, "heavy_imports": heavy}
            row = [label, _fmt(wall), _fmt(cpu), ", ".join(heavy) or "none"]
            if args.baseline:
                b_cpu = [c for _, c in base]
                ratios = [b / o for o, b in zip(cpu, b_cpu, strict=True)]
                b_heavy = _heavy_imports(args.baseline, cmd)
                entry.update(baseline_wall_s=[w for w, _ in base], baseline_cpu_s=b_cpu,
                             cpu_speedup=ratios, baseline_heavy_imports=b_heavy)
                row += [_fmt(b_cpu), ", ".join(b_heavy) or "none",
                        f"{statistics.median(ratios):.1f}×"]
            data[label] = entry
            rows.append(row)
    header = ["command", "wall s, median (min–max)", "CPU s", "heavy modules loaded"]
    if args.baseline:
        header += ["baseline CPU s", "baseline heavy modules", "CPU ratio (pairwise median)"]
    save("bench_imports", {"runs": args.runs, "results": data},
         "### Command start-up — `bench_imports.py`\n\n" + table(header, rows))


if __name__ == "__main__":
    main()
