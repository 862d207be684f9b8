"""RBF training speed: thermonet's initialisation vs plain Adam from random centres.

Both fit RBF[ΔT, ΔT²] (16 centres) on the `patent-gyro` preset's training runs
(same split as `configs/patent-gyro.yaml`), full batch:

* plain: random centres, unit widths, zero weights; 2,000 epochs, no early stop;
* thermonet: k-means centres, neighbour-distance widths, least-squares weights,
  then thermonet's default refinement (full-batch L-BFGS, `TrainConfig()`),
  timed until the held-out error reaches the plain run's final held-out error;
  the same start refined by Adam (lr 0.01) is reported too.

Held-out error = MSE on the held-out test run in standardised units (both fits
share the standardisation, which comes from the same training data).  The
speed-up is (plain seconds) / (thermonet seconds to reach the same error),
both measured in this process, one after the other, on one torch thread.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import fmt_spread, save, spread, table  # noqa: E402
from thermonet.features.inputs import FeatureSpec, reference_values  # noqa: E402
from thermonet.training.config import load_config  # noqa: E402
from thermonet.training.parts import build_part, load_data, make_splits  # noqa: E402
from thermonet.training.train import TrainConfig, fit  # noqa: E402

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "patent-gyro.yaml"
REPEATS = int(os.environ.get("BENCH_RBF_SPEED_REPEATS", "3"))


def run(init: str, config: TrainConfig, target: float | None = None) -> dict:
    cfg = load_config(CONFIG)
    ds = load_data(cfg.data)
    split = make_splits(ds, cfg.split)[0]
    inputs = ["dT", "dT2"]
    t_ref, proxy_ref = reference_values(split.train, inputs, t_ref="start")
    spec = FeatureSpec(inputs=inputs, t_ref=t_ref, proxy_ref=proxy_ref)
    outputs = ds.axes
    kw = dict(signals=spec.signals, outputs=outputs, target="drift")
    train = [build_part(r, **kw) for r in split.train]
    test = build_part(split.test, **kw)
    marks: list[tuple[int, float, float]] = []
    t0 = time.perf_counter()

    def on_epoch(epoch: int, train_loss: float, val_loss: float | None) -> None:
        marks.append((epoch, time.perf_counter() - t0, float(val_loss)))

    res = fit(family="rbf", inputs=inputs, outputs=outputs,
              train=[(p.signals, p.target) for p in train], val=(test.signals, test.target),
              spec=spec, hyper={"n_centres": 16, "init": init},
              config=config,
              on_epoch=on_epoch)
    total = time.perf_counter() - t0
    out = {
        "init": init,
        "optimizer": config.optimizer,
        "seconds_total": total,
        "epochs": marks[-1][0],
        "final_heldout_mse": marks[-1][2],
        "best_heldout_mse": min(m[2] for m in marks),
        "n_params": res.n_params,
    }
    if target is not None:
        reached = [(e, s) for e, s, v in marks if v <= target]
        out["reached_target"] = bool(reached)
        out["epochs_to_target"] = reached[0][0] if reached else None
        out["seconds_to_target"] = reached[0][1] if reached else None
    return out


def main() -> None:
    torch.set_num_threads(1)
    adam = dict(optimizer="adam", lr=0.01, max_epochs=2000, patience=10 ** 9)
    plains, ours, ours_adam = [], [], []
    for _ in range(REPEATS):            # interleaved: a change of load hits all three alike
        plains.append(run("random", TrainConfig(**adam)))
        target = plains[-1]["final_heldout_mse"]       # the same every repeat (seeded)
        ours.append(run("kmeans", TrainConfig(), target=target))
        ours_adam.append(run("kmeans", TrainConfig(**adam), target=target))
    plain = plains[0]
    target = plain["final_heldout_mse"]

    def speed(rs: list[dict]) -> tuple[str, dict | None]:
        if not all(r["reached_target"] for r in rs):
            return "not reached", None
        ratios = spread([p["seconds_total"] / r["seconds_to_target"]
                         for p, r in zip(plains, rs, strict=True)])
        return fmt_spread(ratios, digits=2) + "×", ratios

    rows = [["plain Adam (lr 0.01), random centres", plain["epochs"],
             fmt_spread(spread([r["seconds_total"] for r in plains])),
             f"{target:.3g}", "—"]]
    speedups = {}
    for label, rs in (("thermonet start + L-BFGS (default)", ours),
                      ("thermonet start + Adam (lr 0.01)", ours_adam)):
        text, ratios = speed(rs)
        speedups[label] = ratios
        secs = [r["seconds_to_target"] for r in rs if r["seconds_to_target"] is not None]
        rows.append([label, rs[0]["epochs_to_target"],
                     fmt_spread(spread(secs)) if secs else "—",
                     f"≤ {target:.3g} at that epoch", text])
    md = ("### RBF training speed (patent-gyro, RBF[ΔT, ΔT²], 16 centres, one torch thread)\n\n"
          f"Seconds (wall, from the start of `fit`: the initialisation included) to reach plain "
          f"Adam's final held-out error: median of {REPEATS} interleaved repeats (min–max); "
          "speed-up: per-repeat ratios.\n\n"
          + table(["fit", "epochs to plain's final error", "seconds", "held-out MSE (std. units)",
                   "speed-up"], rows))
    save("rbf_speed", {"plain": plains, "thermonet": ours, "thermonet_adam": ours_adam,
                       "speedup": speedups}, md)


if __name__ == "__main__":
    main()
