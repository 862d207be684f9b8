"""Averaging instead of thinning: a 100 Hz recording, fitted both ways, on several devices.

The patent-gyro preset simulated at 100 Hz (3 runs of 5.9 h, 2.1 M samples each;
train on run 0, validate on run 1, test on run 2), ``SEEDS`` simulated devices.
RBF[ΔT, ΔT²] with 16 centres and the PX4/ArduPilot cubic are fitted on

* **thinning** (thermonet before): every k-th sample, down to the 20,000-sample budget;
* **averaging** (the default now): 1 s windows (``train.average_s``), then windows of k
  of those down to the same budget — computed once per run and shared by both
  families, as ``compare`` does (:func:`thermonet.training.parts.fit_arrays`).

Reported per family: fit CPU seconds (one torch thread; the averaging pass counted
in full with the first family that needs it), and on the held-out run at full
resolution the RMS of predicted − true drift per axis; ratios averaging / thinning
paired by device (and axis), median (min–max).  Target: both families together fit
faster, and no worse, than with thinning.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import fmt_spread, save, spread, table  # noqa: E402
from thermonet.features.inputs import FeatureSpec, reference_values  # noqa: E402
from thermonet.sim import simulate  # noqa: E402
from thermonet.training.config import SplitConfig  # noqa: E402
from thermonet.training.parts import build_part, fit_arrays, make_splits  # noqa: E402
from thermonet.training.train import TrainConfig, fit, predict  # noqa: E402

RATE_HZ = 100.0
SEEDS = int(os.environ.get("BENCH_AVERAGING_SEEDS", "5"))
FAMILIES = {"rbf16": ("rbf", ["dT", "dT2"], {"n_centres": 16}),
            "cubic": ("poly", ["dT"], {"degree": 3})}
WAYS = ("thinning to 20k (before)", "averaging 1 s, then to 20k (default)")


def one_device(seed: int) -> dict:
    ds = simulate("patent-gyro", runs=3, seed=seed, sample_rate_hz=RATE_HZ)
    split = make_splits(ds, SplitConfig())[0]
    cfg = TrainConfig()
    out: dict = {"train_samples": split.train[0].n_samples}
    parts = {}
    for way in WAYS:
        averaged = way.startswith("averaging")
        for label, (family, inputs, hyper) in FAMILIES.items():
            t_ref, proxy_ref = reference_values(split.train, inputs, t_ref="start")
            spec = FeatureSpec(inputs=inputs, t_ref=t_ref, proxy_ref=proxy_ref)
            key = tuple(spec.signals)
            if key not in parts:     # the signals and targets: built once, as compare does
                kw = dict(signals=spec.signals, outputs=ds.axes, target="drift")
                parts[key] = [build_part(r, **kw) for r in (split.train[0], split.val, split.test)]
            tr, va, te = parts[key]
            c0 = time.process_time()
            if averaged:            # the window means are cached on the parts (first use pays)
                train = [fit_arrays(tr, cfg.average_s)]
                val = fit_arrays(va, cfg.average_s)
                fcfg = TrainConfig(average_s=0.0)
            else:
                train, val, fcfg = [(tr.signals, tr.target)], (va.signals, va.target), cfg
            res = fit(family=family, inputs=inputs, outputs=ds.axes, train=train, val=val,
                      spec=spec, hyper=hyper, config=fcfg)
            cpu = time.process_time() - c0
            pred = predict(res.model, te.signals)
            err = np.sqrt(np.mean((pred - te.true_drift) ** 2, axis=0))
            out[(label, way)] = {"cpu_s": cpu, "err": err, "best_epoch": res.best_epoch}
    return out


def main() -> None:
    torch.set_num_threads(1)
    devices = []
    for seed in range(SEEDS):
        devices.append(one_device(seed))
        print(f"device {seed} done", flush=True)
    rows, data = [], {"rate_hz": RATE_HZ, "seeds": SEEDS,
                      "train_samples": devices[0]["train_samples"], "families": {}}
    before, after = WAYS
    for label in [*FAMILIES, "both families"]:
        labels = list(FAMILIES) if label == "both families" else [label]
        cpu = {w: [sum(d[(lb, w)]["cpu_s"] for lb in labels) for d in devices] for w in WAYS}
        time_ratio = [a / b for a, b in zip(cpu[after], cpu[before], strict=True)]
        err_ratio = [float(x) for d in devices for lb in labels
                     for x in d[(lb, after)]["err"] / d[(lb, before)]["err"]]
        err = {w: [float(x) for d in devices for lb in labels for x in d[(lb, w)]["err"]]
               for w in WAYS}
        data["families"][label] = {
            w: {"fit_cpu_s": spread(cpu[w]), "drift_error_rms": spread(err[w])} for w in WAYS}
        data["families"][label]["cpu_ratio"] = spread(time_ratio)
        data["families"][label]["error_ratio"] = spread(err_ratio)
        data["families"][label]["error_ratio_mean"] = float(np.mean(err_ratio))
        for w in WAYS:
            rows.append([label, w, fmt_spread(spread(cpu[w])), fmt_spread(spread(err[w]))])
        rows.append([label, "**averaging / thinning**",
                     f"**{fmt_spread(spread(time_ratio))}**",
                     f"**{fmt_spread(spread(err_ratio))}** (mean {np.mean(err_ratio):.3f})"])
    md = (f"### Averaging instead of thinning: patent-gyro at {RATE_HZ:g} Hz "
          f"({data['train_samples']:,} training samples a run), {SEEDS} simulated devices\n\n"
          "Fit CPU seconds (one torch thread; averaging counted in full) and drift error on "
          "the held-out run at full resolution: median over devices (errors: over devices "
          "and axes) with min–max; ratios paired by device (and axis).\n\n"
          + table(["family", "training data", "fit CPU s", "drift error rms [°/s]"], rows))
    save("averaging", data, md)


if __name__ == "__main__":
    main()
