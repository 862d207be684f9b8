"""Recordings larger than memory: peak memory and wall time against the number of
samples, and the streaming runtime against batch.

Three parts; the file parts in fresh child processes, each reporting its own peak resident
memory (``VmHWM`` for info, ``ru_maxrss`` for compare, forked from a small parent so the
figure is the child's own); medians of repeats with min–max:

``info``
    ``thermonet info`` on one Parquet file of 1, 2, 10 and 20 M samples (patent-gyro, 5 runs of
    5.9 h, 3 axes with references and simulated drift: 12 columns, ≈ 50 B a sample on disk) —
    the chunked pass (:mod:`thermonet.workflows.info_chunked`, default 65,536-row chunks) at
    every size, the whole-file summary (``read_dataset`` + ``summarize``) at 1 and 2 M for
    comparison.  Bytes per extra sample: the slope of peak RSS between the smallest and the
    largest size.
``compare``
    ``thermonet compare`` of the default config (the default families, tracking off) on the
    file streamed in 65,536-row chunks and reduced to 1 s window means
    (:mod:`thermonet.features.windows`, ``data.in_memory_samples: 0``) at 1, 2, 10 and 20 M
    samples, and — for contrast — the comparison holding every sample at 1 M (over
    ``data.in_memory_samples``' default, 1 M, only the streamed one runs).  Bytes per extra
    sample: the slope of peak RSS between 1 and 20 M, streamed.
``runtime``
    The torch-free runtime on 1 M samples of a model with dynamic inputs (a poly on
    ``dT, rate, lag_300, play_0.5``, 3 axes): one ``compensate`` call on the whole array
    (batch) against ``step_block`` in blocks of 1,024 / 4,096 / 65,536 samples (the state
    carried), and ``step`` one sample at a time (on 5,000 samples); throughput in samples/s,
    interleaved repeats, and the paired ratio streaming / batch.

``plain``
    Files that are not thermonet's own stream too: ``thermonet compare`` (the default config,
    ``data.in_memory_samples: 0``) on the same recording written as a plain Parquet file (no
    ``thermonet`` metadata: conventional column names and a ``run`` column) and as a CSV
    file, at ``BENCH_PLAIN_SIZES`` samples (default 2, 10 and 20 M; one run each);
    ``thermonet convert`` of the 10 M-sample plain Parquet and CSV files (peak RSS of a
    fresh process, ``VmHWM``); and the agreement of the comparison on the 2 M-sample CSV
    streamed directly with the comparison on the same CSV converted first.

``python experiments/bench_scaling.py [info] [compare] [runtime] [plain]`` (default: the
first three); ``BENCH_SCALING_REPEATS`` (default 3; compare uses 2).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import (  # noqa: E402
    COMPARE_CHILD,
    fmt_spread,
    interleaved,
    ratio_spread,
    save,
    spread,
    table,
)

ROOT = Path(__file__).resolve().parents[1]
#: target samples; 5 patent-gyro runs of 21,200 s at the rate that gives them
SIZES = [1_000_000, 2_000_000, 10_000_000, 20_000_000]
RUNS, RUN_S = 5, 21_200.0
COMPARE_SIZES = SIZES
#: the in-memory comparison, for contrast: at 1 M only (≈ 760 B a sample: 1.5 GB)
IN_MEMORY_SIZES = SIZES[:1]
WHOLE_INFO_SIZES = SIZES[:2]
REPEATS = int(os.environ.get("BENCH_SCALING_REPEATS", "3"))

#: one summary in a fresh process: chunked (argv[2] == "chunked") or whole-file
INFO_CHILD = """
import json, sys, time
t0 = time.perf_counter()
if sys.argv[2] == "chunked":
    from thermonet.workflows.info_chunked import summarize_parquet
    s = summarize_parquet(sys.argv[1])
else:
    from thermonet.data.io import read_dataset
    from thermonet.workflows.info import summarize
    s = summarize(read_dataset(sys.argv[1]))
wall = time.perf_counter() - t0
# VmHWM: this process's own peak (ru_maxrss would keep the parent's at fork across exec)
hwm = next(int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmHWM"))
print(json.dumps({"wall_s": wall, "maxrss_mb": hwm / 1024.0,
                  "samples": sum(r["samples"] for r in s["runs"])}))
"""


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _child(code: str, *args: str, cwd: Path | None = None) -> dict:
    out = subprocess.run([sys.executable, "-c", code, *args], check=True, text=True,
                         capture_output=True, env=_env(), cwd=cwd)
    return json.loads(out.stdout.strip().splitlines()[-1])


def simulate_file(samples: int, path: Path) -> int:
    rate = samples / (RUNS * RUN_S)
    code = ("import sys; from thermonet.sim import simulate; "
            "from thermonet.data.io import write_parquet; "
            f"ds = simulate('patent-gyro', runs={RUNS}, seed=0, sample_rate_hz={rate!r});"
            "write_parquet(ds, sys.argv[1]); print(sum(r.n_samples for r in ds.runs))")
    out = subprocess.run([sys.executable, "-c", code, str(path)], check=True, text=True,
                         capture_output=True, env=_env()).stdout
    return int(out.strip().splitlines()[-1])


def compare_once(data: Path, work: Path, streamed: bool) -> dict:
    cfg = work / "config.yaml"
    limit = 0 if streamed else 10 ** 12
    cfg.write_text((ROOT / "configs" / "default.yaml").read_text().replace(
        "data:\n  preset: patent-gyro\n  seed: 0\n",
        f"data:\n  paths: [{data}]\n  in_memory_samples: {limit}\n"))
    res = _child(COMPARE_CHILD, str(cfg), str(work / "out"), cwd=work)
    if res["rc"] != 0:
        raise RuntimeError(f"compare failed on {data}")
    return res


def _slope(points: list[tuple[int, float]]) -> float:
    """Bytes per extra sample between the smallest and the largest size (MB → B)."""
    (n0, m0), (n1, m1) = points[0], points[-1]
    return (m1 - m0) * 1024.0 * 1024.0 / (n1 - n0)


def bench_files(parts: set[str], tmp: Path) -> tuple[list[str], dict]:
    md, data = [], {"info": {}, "compare": {}}
    info_rows, cmp_rows = [], []
    info_pts: dict[str, list[tuple[int, float]]] = {"chunked": [], "whole": []}
    cmp_pts: list[tuple[int, float]] = []
    for target in SIZES:
        if "compare" not in parts and "info" not in parts:
            break
        if "info" not in parts and target not in COMPARE_SIZES:
            continue
        f = tmp / f"pg_{target}.parquet"
        n = simulate_file(target, f)
        if "info" in parts:
            for mode in ("chunked", "whole"):
                if mode == "whole" and target not in WHOLE_INFO_SIZES:
                    continue
                res = [_child(INFO_CHILD, str(f), mode) for _ in range(REPEATS)]
                wall, mem = spread([r["wall_s"] for r in res]), spread([r["maxrss_mb"]
                                                                         for r in res])
                data["info"][f"{mode}_{n}"] = {"samples": n, "wall_s": wall, "maxrss_mb": mem}
                info_pts[mode].append((n, mem["median"]))
                info_rows.append([f"{n / 1e6:.2f} M", mode, fmt_spread(wall),
                                  fmt_spread(mem, digits=4)])
        if "compare" in parts and target in COMPARE_SIZES:
            for mode in ("streamed", "in memory"):
                if mode == "in memory" and target not in IN_MEMORY_SIZES:
                    continue
                res = []
                for k in range(2):
                    work = tmp / f"w_{target}_{mode[:2]}_{k}"
                    work.mkdir()
                    res.append(compare_once(f, work, mode == "streamed"))
                wall, cpu = spread([r["wall_s"] for r in res]), spread([r["cpu_s"] for r in res])
                mem = spread([r["maxrss_mb"] for r in res])
                data["compare"][f"{mode}_{n}"] = {"samples": n, "mode": mode, "wall_s": wall,
                                                  "cpu_s": cpu, "maxrss_mb": mem}
                if mode == "streamed":
                    cmp_pts.append((n, mem["median"]))
                cmp_rows.append([f"{n / 1e6:.2f} M", mode, fmt_spread(wall), fmt_spread(cpu),
                                 fmt_spread(mem, digits=4)])
        f.unlink()
    if info_rows:
        slopes = {m: _slope(p) for m, p in info_pts.items() if len(p) > 1}
        data["info"]["bytes_per_extra_sample"] = slopes
        md.append("### `thermonet info` on one Parquet file\n\n" + table(
            ["samples", "pass", "wall s", "peak RSS MB"], info_rows) + "\n\nBytes per extra "
            "sample (peak RSS slope): " + ", ".join(f"{m} {v:.1f} B" for m, v in slopes.items()))
    if cmp_rows:
        slope = _slope(cmp_pts) if len(cmp_pts) > 1 else float("nan")
        data["compare"]["bytes_per_extra_sample"] = slope
        md.append("### `thermonet compare` (default config)\n\n" + table(
            ["samples", "data", "wall s", "CPU s", "peak RSS MB"], cmp_rows)
            + f"\n\nBytes per extra sample (peak RSS slope, streamed): {slope:.1f} B")
    return md, data


PLAIN_SIZES = [int(x) for x in os.environ.get(
    "BENCH_PLAIN_SIZES", "2000000,10000000,20000000").split(",")]
CONVERT_SAMPLES = int(os.environ.get("BENCH_CONVERT_SAMPLES", "10000000"))

#: the thermonet file argv[1] rewritten, streamed, as plain Parquet (argv[2]) and CSV (argv[3])
PLAIN_CHILD = """
import sys
import pyarrow.csv as pacsv, pyarrow.parquet as pq
pf = pq.ParquetFile(sys.argv[1])
schema = pf.schema_arrow.remove_metadata()
w = pq.ParquetWriter(sys.argv[2], schema)
c = pacsv.CSVWriter(sys.argv[3], schema, write_options=pacsv.WriteOptions(quoting_style="none"))
for b in pf.iter_batches(batch_size=65536):
    b = b.replace_schema_metadata(None)
    w.write_batch(b)
    c.write_batch(b)
w.close()
c.close()
print("{}")
"""

#: one ``thermonet convert`` in a fresh process: wall and VmHWM
CONVERT_CHILD = """
import json, sys, time
from thermonet.cli import main
t0 = time.perf_counter()
rc = main(["convert", sys.argv[1], "--out", sys.argv[2], "--overwrite"])
wall = time.perf_counter() - t0
hwm = next(int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmHWM"))
print(json.dumps({"rc": rc, "wall_s": wall, "maxrss_mb": hwm / 1024.0}))
"""


def bench_plain(tmp: Path) -> tuple[list[str], dict]:
    rows, conv_rows, data = [], [], {"compare": {}, "convert": {}}
    pts: dict[str, list[tuple[int, float]]] = {"plain Parquet": [], "CSV": []}
    agreement: dict = {}
    for target in sorted(set(PLAIN_SIZES) | {CONVERT_SAMPLES}):
        src = tmp / f"pg_{target}.parquet"
        n = simulate_file(target, src)
        plain, csv = tmp / f"plain_{target}.parquet", tmp / f"plain_{target}.csv"
        _child(PLAIN_CHILD, str(src), str(plain), str(csv))
        src.unlink()
        sizes = {"plain Parquet": plain.stat().st_size, "CSV": csv.stat().st_size}
        for kind, f in (("plain Parquet", plain), ("CSV", csv)):
            if target in PLAIN_SIZES:
                work = tmp / f"w_{target}_{kind[:3]}"
                work.mkdir()
                r = compare_once(f, work, True)
                data["compare"][f"{kind}_{n}"] = {"samples": n, **r,
                                                  "file_mb": sizes[kind] / 2 ** 20}
                pts[kind].append((n, r["maxrss_mb"]))
                rows.append([f"{n / 1e6:.2f} M", kind, f"{sizes[kind] / 2 ** 20:.0f}",
                             f"{r['wall_s']:.1f}", f"{r['cpu_s']:.1f}",
                             f"{r['maxrss_mb']:.0f}"])
                if target == min(PLAIN_SIZES) and kind == "CSV":
                    agreement = _agreement(f, work, tmp)
            if target == CONVERT_SAMPLES:
                r = _child(CONVERT_CHILD, str(f), str(tmp / "converted.parquet"))
                data["convert"][f"{kind}_{n}"] = {"samples": n, **r}
                conv_rows.append([f"{n / 1e6:.2f} M", kind, f"{r['wall_s']:.1f}",
                                  f"{r['maxrss_mb']:.0f}"])
                (tmp / "converted.parquet").unlink()
        plain.unlink()
        csv.unlink()
    slopes = {k: _slope(p) for k, p in pts.items() if len(p) > 1}
    data["compare"]["bytes_per_extra_sample"] = slopes
    data["agreement"] = agreement
    md = ["### `thermonet compare` streaming files that are not thermonet's own\n\n" + table(
        ["samples", "file", "file MB", "wall s", "CPU s", "peak RSS MB"], rows)
        + "\n\nBytes per extra sample (peak RSS slope): "
        + ", ".join(f"{k} {v:.1f} B" for k, v in slopes.items())]
    if conv_rows:
        md.append("### `thermonet convert` (streamed)\n\n" + table(
            ["samples", "input", "wall s", "peak RSS MB"], conv_rows))
    if agreement:
        md.append("Streamed CSV against the same CSV converted first (2 M samples): "
                  f"chosen {agreement['chosen']}; largest relative difference of a score "
                  f"ratio {agreement['max_rel_score_ratio']:.2e}, of a raw score "
                  f"{agreement['max_rel_score_raw']:.2e}")
    return md, data


def _agreement(csv: Path, work: Path, tmp: Path) -> dict:
    conv = tmp / "agree.parquet"
    _child(CONVERT_CHILD, str(csv), str(conv))
    w2 = tmp / "w_agree"
    w2.mkdir()
    compare_once(conv, w2, True)
    a = json.loads((work / "out" / "results.json").read_text())
    b = json.loads((w2 / "out" / "results.json").read_text())
    conv.unlink()
    rel: dict[str, float] = {"score_ratio": 0.0, "score_raw": 0.0}
    for fam, fa in a["families"].items():
        for axis, xa in (fa.get("axes") or {}).items():
            xb = b["families"][fam]["axes"][axis]
            for k in rel:
                if xa.get(k) is not None and xb.get(k) is not None:
                    d = abs(xa[k] - xb[k]) / max(abs(xb[k]), 1e-300)
                    rel[k] = max(rel[k], d)
    return {"chosen": "the same" if a["chosen"] == b["chosen"] else
            f"differs: {a['chosen']} / {b['chosen']}",
            "max_rel_score_ratio": rel["score_ratio"], "max_rel_score_raw": rel["score_raw"]}


def bench_runtime(tmp: Path) -> tuple[list[str], dict]:
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "export"))
    import numpy as np

    import thermonet_runtime as rt
    from thermonet.exporting import export_onnx
    from thermonet.features import dynamics
    from thermonet.features.inputs import FeatureSpec
    from thermonet.training.train import TrainConfig, fit

    inputs = ["dT", "rate", "lag_300", "play_0.5"]
    t = np.arange(0.0, 30000.0, 2.0)
    temp = 20.0 + 20.0 * np.sin(t / 3000.0)
    sig, _ = dynamics.compute(t, temp, inputs, 5.0)
    spec = FeatureSpec(inputs=inputs, t_ref=20.0, gap_s=5.0)
    s = np.column_stack([temp] + [sig[x] for x in spec.signals[1:]])
    y = np.column_stack([0.01 * temp, 0.02 * sig["rate_c_per_min"], 0.003 * sig["play_0.5_c"]])
    model = fit(family="poly", inputs=inputs, outputs=["gyro_x", "gyro_y", "gyro_z"],
                train=[(s, y)], val=None, spec=spec, hyper={"degree": 2, "cross": True},
                config=TrainConfig(max_epochs=0)).model
    comp = rt.Compensator(export_onnx(model, tmp / "m.onnx"))
    n = 1_000_000
    times = np.arange(n) * 0.01
    temps = 20.0 + 20.0 * np.sin(times / 300.0)
    raw = np.zeros((n, 3))

    def batch() -> None:
        comp.compensate(temperature_c=temps, raw=raw, time_s=times)

    def blocks(b: int):
        def run() -> None:
            comp.reset()
            for a in range(0, n, b):
                comp.step_block(times[a:a + b], temps[a:a + b], raw[a:a + b])
        return run

    m = 5000

    def one_by_one() -> None:
        comp.reset()
        for k in range(m):
            comp.step(times[k], temps[k], raw[k])

    fns = {"batch": batch, **{f"step_block {b}": blocks(b) for b in (1024, 4096, 65536)}}
    wall = interleaved(fns, repeats=max(REPEATS, 5))
    step_wall = interleaved({"step": one_by_one}, repeats=3)["step"]
    rows, data = [], {}
    for k, v in wall.items():
        rate = spread([n / x for x in v])
        ratio = ratio_spread(wall["batch"], v)
        data[k] = {"samples_per_s": rate, "vs_batch": ratio}
        rows.append([k, fmt_spread(rate, 1e-6), fmt_spread(ratio)])
    rate = spread([m / x for x in step_wall])
    data["step (one sample a call)"] = {"samples_per_s": rate}
    rows.append(["step, one sample a call", fmt_spread(rate, 1e-6), "—"])
    md = ["### Runtime: streaming in blocks against batch (1 M samples, dynamic inputs)\n\n"
          + table(["mode", "M samples/s", "× batch (paired)"], rows)]
    return md, {"runtime": data}


def main() -> None:
    parts = set(sys.argv[1:]) or {"info", "compare", "runtime"}
    if parts == {"plain"}:
        with tempfile.TemporaryDirectory() as tmp_dir:
            t0 = time.perf_counter()
            md, data = bench_plain(Path(tmp_dir))
            data["bench_wall_s"] = time.perf_counter() - t0
        save("scaling_plain", data, "\n\n".join(md))
        return
    md, data = [], {}
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        t0 = time.perf_counter()
        # the files first: the runtime part grows this process, and a child forked from a
        # large parent would report the parent's size as its ru_maxrss (compare's figure)
        m, d = bench_files(parts, tmp)
        md += m
        data.update(d)
        if "runtime" in parts:
            m, d = bench_runtime(tmp)
            md = m + md
            data.update(d)
        data["bench_wall_s"] = time.perf_counter() - t0
    save("scaling", data, "\n\n".join(md))


if __name__ == "__main__":
    main()
