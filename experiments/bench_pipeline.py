"""The whole of each job a user waits for, against the anchor on the same input, same run.

Jobs (each a fresh process, as a user runs it; ``RUNS`` counted runs after one warm-up, the
commands of one job timed in turn A, B, C, A, B, C … so the machine's load hits them alike):

* ``thermonet calibrate`` on a simulated 45-minute ``fc-board`` PX4 log (9 instances × 2,700
  samples), with its per-instance comparison and with ``--no-compare``, against PX4's
  ``process_sensor_caldata.py`` fit (``px4_caldata_anchor.py``) on the same log;
* ``thermonet compare`` with the default family set on the two real BMI270 soaks
  (9,788 rows, ``tests/data/real/bmi270_two_soaks``);
* ``thermonet export`` of that comparison's chosen model to ONNX and to C (parity checks
  included, as a user runs them);
* ``thermonet compare`` of the cubic and the GRU on the ``consumer-imu`` preset (one run).

Per command: wall seconds, CPU seconds (user + system of the child) and peak resident memory,
median (min–max); per job the ratios to the anchor, pair by pair.  Then one ``--profile`` run
of each thermonet command: where its time goes, stage by stage.

``--before DIR`` (a checkout of an earlier commit, e.g. ``git worktree add --detach DIR REV``)
times that code's thermonet commands in the same run, interleaved with this checkout's, each
on its own output directory: the column "after / before" is the median of the pair-by-pair
ratios.

Usage: ``python experiments/bench_pipeline.py [--runs 3] [--before DIR]``
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import fmt_spread, ratio_spread, save, spread, table  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
THERMONET = [PY, "-m", "thermonet.cli"]


def _run(cmd: list[str]) -> dict[str, float]:
    """One fresh process: wall, CPU seconds and peak RSS (MB) of that child alone."""
    if "export" in cmd and "--out" in cmd:   # export replaces a file only with --overwrite,
        out = Path(cmd[cmd.index("--out") + 1])   # which a --before checkout may not know
        if out.is_file():
            out.unlink()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(["/usr/bin/env", *cmd], capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    # ru_maxrss of the children is the largest so far: measured through /proc by the child
    # would need a wrapper; the largest of every run is what a user's machine must hold
    return {"wall_s": wall,
            "cpu_s": (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime),
            "maxrss_mb": after.ru_maxrss / 1024.0}


def _job(cmds: dict[str, list[str]], runs: int) -> dict[str, dict[str, list[float]]]:
    for cmd in cmds.values():          # warm-up: the file cache, compiled bytecode
        _run(cmd)
    out: dict[str, dict[str, list[float]]] = {k: {"wall_s": [], "cpu_s": [], "maxrss_mb": []}
                                              for k in cmds}
    for _ in range(runs):
        for k, cmd in cmds.items():
            r = _run(cmd)
            for m, v in r.items():
                out[k][m].append(v)
    return out


def _profile(cmd: list[str]) -> str:
    """One run of a thermonet command with ``--profile``: its stage table."""
    n = cmd.index("thermonet.cli") + 1
    proc = subprocess.run(["/usr/bin/env", *cmd[:n], "--profile", *cmd[n:]],
                          capture_output=True, text=True, cwd=ROOT)
    lines = proc.stderr.splitlines()
    start = next((i for i, x in enumerate(lines) if "where the time went" in x), None)
    return "\n".join(lines[start:]) if start is not None else proc.stderr[-2000:]


BEFORE = " (before)"


def profiles_cmds(tmp: Path, log: Path, default_families: Path) -> dict[str, list[str]]:
    """The commands profiled stage by stage (one ``--profile`` run each)."""
    return {
        "calibrate": [*THERMONET, "calibrate", str(log), "--out", str(tmp / "cal"),
                      "--overwrite", "-q"],
        "compare": [*THERMONET, "compare", str(default_families), "--out", str(tmp / "cmp"),
                    "--overwrite", "-q", "--no-track"],
        "export onnx": [*THERMONET, "export", str(tmp / "cmp"), "--format", "onnx", "--out",
                        str(tmp / "model.onnx")],
    }


def _with_before(cmds: dict[str, list[str]], before: Path | None) -> dict[str, list[str]]:
    """Each thermonet command twinned with the earlier checkout's (its outputs beside)."""
    if before is None:
        return cmds
    out = dict(cmds)
    n = len(THERMONET)
    for k, cmd in cmds.items():
        if cmd[:n] == THERMONET:
            twin = [a + "-before" if a.startswith(tempfile.gettempdir()) and
                    not a.endswith((".ulg", ".yaml")) else a for a in cmd[n:]]
            # run from that checkout: ``python -m`` puts the working directory first on the
            # path, so from this one it would import this thermonet whatever PYTHONPATH says
            out[k + BEFORE] = ["env", "-C", str(before), f"PYTHONPATH={before}", *THERMONET,
                               *twin]
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--before", type=Path, default=None,
                    help="a checkout of an earlier commit, timed in the same run")
    args = ap.parse_args()
    runs, before = args.runs, args.before
    tmp = Path(tempfile.mkdtemp(prefix="bench-pipeline-"))
    log = tmp / "board.ulg"
    subprocess.run([*THERMONET, "simulate", "fc-board", "--out", str(log), "--seed", "0"],
                   check=True, capture_output=True, cwd=ROOT)
    # the two BMI270 soaks (9,788 rows) with the default family set
    import yaml

    cfg = yaml.safe_load((ROOT / "configs" / "bmi270.yaml").read_text())
    cfg["data"]["paths"] = [str(ROOT / "tests/data/real/bmi270_two_soaks" / Path(p).name)
                            for p in cfg["data"]["paths"]]
    cfg["data"]["mapping"] = str(ROOT / cfg["data"]["mapping"])
    cfg.pop("families", None)
    cfg["baseline"] = "cubic"
    default_families = tmp / "bmi270-default.yaml"
    default_families.write_text(yaml.safe_dump(cfg))
    jobs: dict[str, dict[str, list[str]]] = {
        "calibrate (fc-board log, 9 instances × 2,700 samples)": {
            "thermonet calibrate": [*THERMONET, "calibrate", str(log), "--out",
                                    str(tmp / "cal"), "--overwrite", "-q"],
            "thermonet calibrate --no-compare": [*THERMONET, "calibrate", str(log), "--out",
                                                 str(tmp / "cal-nc"), "--overwrite", "-q",
                                                 "--no-compare"],
            "PX4 process_sensor_caldata.py fit (anchor)": [
                PY, str(ROOT / "experiments" / "px4_caldata_anchor.py"), str(log)]},
        "compare (real BMI270 soaks, 9,788 rows, default families)": {
            "thermonet compare": [*THERMONET, "compare", str(default_families), "--out",
                                  str(tmp / "cmp"), "--overwrite", "-q", "--no-track"]},
    }
    jobs = {job: _with_before(cmds, before) for job, cmds in jobs.items()}
    results: dict[str, Any] = {}
    rows = []

    def vs_before(res: dict[str, Any], k: str) -> str:
        twin = res.get(k + BEFORE)
        return fmt_spread(ratio_spread(res[k]["wall_s"], twin["wall_s"])) if twin else "—"

    for job, cmds in jobs.items():
        res = _job(cmds, runs)
        results[job] = res
        anchor = next((k for k in cmds if "anchor" in k), None)
        for k in cmds:
            r = res[k]
            ratio = (fmt_spread(ratio_spread(r["wall_s"], res[anchor]["wall_s"]))
                     if anchor and k != anchor else "—")
            cpu_ratio = (fmt_spread(ratio_spread(r["cpu_s"], res[anchor]["cpu_s"]))
                         if anchor and k != anchor else "—")
            rows.append([job, k, fmt_spread(spread(r["wall_s"])), fmt_spread(spread(r["cpu_s"])),
                         f"{max(r['maxrss_mb']):.0f}", ratio, cpu_ratio, vs_before(res, k)])
        print(job, "done", flush=True)
    # the GRU, the slowest family, beside the cubic on the consumer-imu preset (one run: its
    # fits take tens of seconds; no warm-up, no before twin)
    gru_cfg = tmp / "gru.yaml"
    gru_cfg.write_text(yaml.safe_dump({
        "data": {"preset": "consumer-imu", "seed": 0},
        "target": {"gyro": "zero", "acc": "at-t-ref"}, "features": {"t_ref": 25.0},
        "baseline": "cubic",
        "families": [{"family": "poly", "name": "cubic", "inputs": ["dT"],
                      "params": {"degree": 3}},
                     {"family": "gru", "name": "gru", "inputs": ["dT"]}]}))
    gru_cmd = [*THERMONET, "compare", str(gru_cfg), "--out", str(tmp / "gru"), "--overwrite",
               "-q", "--no-track"]
    r = _run(gru_cmd)
    results["gru"] = {k: [v] for k, v in r.items()}
    rows.append(["compare, cubic + gru (consumer-imu preset)", "thermonet compare (1 run)",
                 f"{r['wall_s']:.3g}", f"{r['cpu_s']:.3g}", f"{r['maxrss_mb']:.0f}", "—", "—",
                 "—"])
    # exports of the comparison's choice (a per-axis model where the axes chose several)
    exp = {f"thermonet export --format {f}": [*THERMONET, "export", str(tmp / "cmp"),
                                              "--format", f, "--out",
                                              str(tmp / f"model.{'onnx' if f == 'onnx' else 'h'}")]
           for f in ("onnx", "c")}
    exp = _with_before(exp, before)
    res = _job(exp, runs)
    results["export"] = res
    for k in exp:
        rows.append(["export (the comparison's choice)", k,
                     fmt_spread(spread(res[k]["wall_s"])), fmt_spread(spread(res[k]["cpu_s"])),
                     f"{max(res[k]['maxrss_mb']):.0f}", "—", "—", vs_before(res, k)])
    profiles = {k: _profile(cmd) for k, cmd in profiles_cmds(tmp, log, default_families).items()}
    if before is not None:
        for k, cmd in list(profiles_cmds(tmp, log, default_families).items()):
            profiles[k + BEFORE] = _profile(_with_before({k: cmd}, before)[k + BEFORE])
    md = (f"{runs} counted runs after one warm-up, each a fresh process, the commands of a job "
          "in turn; median (min–max). Ratios to the anchor pair by pair (wall and CPU).\n\n"
          + table(["job", "command", "wall s", "CPU s", "peak MB (largest run)",
                   "wall / anchor", "CPU / anchor", "after / before"], rows)
          + "\n\nWhere the time goes (one `--profile` run of each):\n\n"
          + "\n\n".join(f"`{k}`:\n\n```\n{v}\n```" for k, v in profiles.items()))
    save("bench_pipeline", {"runs": runs, "results": results, "profiles": profiles}, md)
    print(json.dumps({"tmp": str(tmp)}))


if __name__ == "__main__":
    main()
