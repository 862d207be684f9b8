"""The hand-built ONNX graphs against torch's trace: what a user waits for an export.

``thermonet/exporting/onnx_graph.py`` writes the ONNX graph of the closed-form families
(linear, poly, rbf, lorentz, ts-fuzzy and per-axis models of them) node by node; every other
family goes through torch's exporter (``torch.export``, decompositions, onnxscript's
optimiser).  Both paths end in the same parity check.  This script measures what the second
writer buys, on the composition the default families chose per axis on the real BMI270 soaks
(Lorentz, poly3-hyst, linear; fitted here on the simulated ``patent-gyro`` preset): a fresh
process loads the checkpoint and calls ``export_onnx`` with ``exporter="auto"`` (the direct
graph) or ``"dynamo"`` (the trace), the two interleaved; the export call's seconds and the
whole process's.  Writes ``out/bench_onnx_direct.{json,md}``.

    .venv/bin/python experiments/bench_onnx_direct.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import fmt_spread, git_rev, ratio_spread, save, spread, table

#: One export in a fresh process: prints the export call's seconds and the exporter used.
CHILD = """
import json, sys, time
from thermonet.exporting import export_onnx
from thermonet.training.checkpoint import load_checkpoint
model, _ = load_checkpoint(sys.argv[1])
t0 = time.perf_counter()
path = export_onnx(model, sys.argv[2], exporter=sys.argv[3])
dt = time.perf_counter() - t0
import onnx
meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
print(json.dumps({"export_s": dt, "exporter": meta["exporter"]}))
"""

#: (label, family, inputs, hyper): the parts, axis by axis.
PARTS = [("lorentz", "lorentz", ["dT"], {}),
         ("poly3-hyst", "poly", ["dT", "rate", "play_1"], {"degree": 3, "cross": True}),
         ("linear", "linear", ["dT"], {})]


def per_axis_checkpoint(path: Path) -> Path:
    """The per-axis model of :data:`PARTS` fitted on ``patent-gyro`` (3 runs), saved."""
    import thermonet
    from thermonet.models.composite import AxisModels
    from thermonet.training.checkpoint import save_checkpoint

    ds = thermonet.simulate("patent-gyro", runs=3, seed=0)
    parts = [thermonet.DriftEstimator(family, inputs, **hyper).fit(ds[0], val=ds[1]).model_
             for _, family, inputs, hyper in PARTS]
    model = AxisModels(parts, list(range(len(parts))), [label for label, *_ in PARTS]).eval()
    return save_checkpoint(path, model, config={})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    root = Path(__file__).resolve().parents[1]
    runs: dict[str, dict[str, list[float]]] = {k: {"export_s": [], "process_s": []}
                                              for k in ("auto", "dynamo")}
    with tempfile.TemporaryDirectory() as tmp:
        ckpt = per_axis_checkpoint(Path(tmp) / "per-axis.pt")
        for _ in range(args.repeats):
            for exporter in runs:
                t0 = time.perf_counter()
                out = subprocess.run([sys.executable, "-c", CHILD, str(ckpt),
                                      str(Path(tmp) / f"{exporter}.onnx"), exporter],
                                     capture_output=True, text=True, check=True, cwd=root)
                runs[exporter]["process_s"].append(time.perf_counter() - t0)
                got = json.loads(out.stdout.strip().splitlines()[-1])
                assert got["exporter"] == ("direct" if exporter == "auto" else "dynamo"), got
                runs[exporter]["export_s"].append(got["export_s"])
    rows = [[name, fmt_spread(spread(runs[k]["export_s"])), fmt_spread(spread(runs[k]["process_s"]))]
            for name, k in (("direct (hand-built graph)", "auto"), ("traced (torch's exporter)", "dynamo"))]
    rows.append(["direct / traced (paired)",
                 fmt_spread(ratio_spread(runs["auto"]["export_s"], runs["dynamo"]["export_s"])),
                 fmt_spread(ratio_spread(runs["auto"]["process_s"], runs["dynamo"]["process_s"]))])
    md = (f"Per-axis model (Lorentz, poly3-hyst, linear), {args.repeats} interleaved runs each, "
          f"fresh processes, median (min–max), commit {git_rev()}:\n\n"
          + table(["ONNX export", "export_onnx call, s", "whole process, s"], rows))
    save("bench_onnx_direct", {"repeats": args.repeats, "runs": runs, "commit": git_rev()}, md)


if __name__ == "__main__":
    main()
