"""Averaging instead of thinning: a 100 Hz recording, fitted three ways.

The patent-gyro preset simulated at 100 Hz (3 runs of 5.9 h: 2.1 M samples
each; train on run 0, validate on run 1, test on run 2), RBF[ΔT, ΔT²] with 16
centres and the PX4/ArduPilot cubic, fitted with

* **thinning** (thermonet before): every k-th sample, down to the 20,000-sample budget;
* **thinning, 10× budget**: every k-th sample down to 200,000;
* **averaging** (the default now): 1 s windows (``train.average_s``), then
  windows of k samples down to the same 20,000 budget.

Reported: fit seconds (median of ``REPEATS`` interleaved fits, min–max; one
torch thread) and, on the held-out run at full resolution (2.1 M samples), the
RMS of predicted − true drift per axis.  Target: averaging no slower than the
thinning that gives the same or worse error, and no worse than thinning.
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
from thermonet.config import SplitConfig  # noqa: E402
from thermonet.evaluate import build_part, make_splits  # noqa: E402
from thermonet.features import FeatureSpec, reference_values  # noqa: E402
from thermonet.sim import simulate  # noqa: E402
from thermonet.train import TrainConfig, fit, predict  # noqa: E402

RATE_HZ = 100.0
REPEATS = int(os.environ.get("BENCH_AVERAGING_REPEATS", "3"))
FAMILIES = {"rbf16": ("rbf", ["dT", "dT2"], {"n_centres": 16}),
            "cubic": ("poly", ["dT"], {"degree": 3})}
WAYS = {
    "thinning to 20k (before)": (False, TrainConfig()),
    "thinning to 200k": (False, TrainConfig(max_train_samples=200_000)),
    "averaging 1 s, then to 20k (default)": (True, TrainConfig()),
}


def main() -> None:
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    ds = simulate("patent-gyro", runs=3, seed=0, sample_rate_hz=RATE_HZ)
    sim_s = time.perf_counter() - t0
    split = make_splits(ds, SplitConfig())[0]
    rows, data = [], {"rate_hz": RATE_HZ, "simulate_seconds": sim_s,
                      "train_samples": split.train[0].n_samples, "families": {}}
    for label, (family, inputs, hyper) in FAMILIES.items():
        t_ref, proxy_ref = reference_values(split.train, inputs, t_ref="start")
        spec = FeatureSpec(inputs=inputs, t_ref=t_ref, proxy_ref=proxy_ref)
        kw = dict(signals=spec.signals, outputs=ds.axes, target="drift", rate_window_s=60.0)
        tr, va, te = (build_part(r, **kw) for r in (split.train[0], split.val, split.test))
        seconds: dict[str, list[float]] = {w: [] for w in WAYS}
        errors: dict[str, np.ndarray] = {}
        for _ in range(REPEATS):
            for way, (timed, cfg) in WAYS.items():
                train = [(tr.signals, tr.target, tr.time_s)] if timed else [(tr.signals, tr.target)]
                val = (va.signals, va.target, va.time_s) if timed else (va.signals, va.target)
                t1 = time.perf_counter()
                res = fit(family=family, inputs=inputs, outputs=ds.axes, train=train, val=val,
                          spec=spec, hyper=hyper, config=cfg)
                seconds[way].append(time.perf_counter() - t1)
                pred = predict(res.model, te.signals)
                errors[way] = np.sqrt(np.mean((pred - te.true_drift) ** 2, axis=0))
        data["families"][label] = {w: {"fit_seconds": spread(seconds[w]),
                                       "drift_error_rms": errors[w].tolist()} for w in WAYS}
        for way in WAYS:
            rows.append([label, way, fmt_spread(spread(seconds[way])),
                         " / ".join(f"{e:.3g}" for e in errors[way])])
    md = (f"### Averaging instead of thinning: patent-gyro at {RATE_HZ:g} Hz "
          f"({data['train_samples']:,} training samples)\n\n"
          f"Fit seconds: median of {REPEATS} interleaved fits (min–max), one torch thread; "
          "drift error on the held-out run at full resolution.\n\n"
          + table(["family", "training data", "fit s", "drift error rms x / y / z [°/s]"], rows))
    save("averaging", data, md)


if __name__ == "__main__":
    main()
