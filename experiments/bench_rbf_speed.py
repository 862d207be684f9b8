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

import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import save, table  # noqa: E402
from thermonet.config import load_config  # noqa: E402
from thermonet.evaluate import build_part, load_data, make_splits  # noqa: E402
from thermonet.features import FeatureSpec, reference_values  # noqa: E402
from thermonet.train import TrainConfig, fit  # noqa: E402

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "patent-gyro.yaml"


def run(init: str, config: TrainConfig, target: float | None = None) -> dict:
    cfg = load_config(CONFIG)
    ds = load_data(cfg.data)
    split = make_splits(ds, cfg.split)[0]
    inputs = ["dT", "dT2"]
    t_ref, proxy_ref = reference_values(split.train, inputs, t_ref="start")
    spec = FeatureSpec(inputs=inputs, t_ref=t_ref, proxy_ref=proxy_ref)
    outputs = ds.axes
    kw = dict(signals=spec.signals, outputs=outputs, target="drift", rate_window_s=60.0)
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
    plain = run("random", TrainConfig(**adam))
    target = plain["final_heldout_mse"]
    ours = run("kmeans", TrainConfig(), target=target)
    ours_adam = run("kmeans", TrainConfig(**adam), target=target)

    def speed(r: dict) -> str:
        return f"{plain['seconds_total'] / r['seconds_to_target']:.0f}×" if r["reached_target"] \
            else "not reached"
    rows = [["plain Adam (lr 0.01), random centres", plain["epochs"], plain["seconds_total"],
             plain["final_heldout_mse"], "—"]]
    for label, r in (("thermonet start + L-BFGS (default)", ours),
                     ("thermonet start + Adam (lr 0.01)", ours_adam)):
        rows.append([label, r["epochs_to_target"], r["seconds_to_target"],
                     f"≤ {target:.3g} at that epoch", speed(r)])
    speedup = plain["seconds_total"] / ours["seconds_to_target"] if ours["reached_target"] else 0.0
    md = ("### RBF training speed (patent-gyro, RBF[ΔT, ΔT²], 16 centres, one torch thread)\n\n"
          + table(["fit", "epochs to plain's final error", "seconds", "held-out MSE (std. units)",
                   "speed-up"], rows))
    save("rbf_speed", {"plain": plain, "thermonet": ours, "thermonet_adam": ours_adam,
                       "speedup": speedup}, md)


if __name__ == "__main__":
    main()
