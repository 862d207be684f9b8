"""RBF centres placed at quantiles vs clustered by k-means: the same fits, without scikit-learn.

``thermonet calibrate`` judges each sensor instance by comparing the firmware's cubic with a
line and the RBF on [ΔT, ΔT²] with the cubic tail (8 centres, ridge chosen by inner
cross-validation).  Its centres came from scikit-learn's k-means, whose import (about 0.7 s:
SciPy's statistics and pandas come with it) was a fifth of a calibration.  ``init: quantiles``
(:func:`thermonet.models.rbf_fit.quantile_centres`) places them at the quantiles of ΔT on the
data's curve instead.  This benchmark fits both, side by side in one comparison, on

* every instance calibrate compares on simulated ``fc-board`` boards (PX4 and ArduPilot
  logs, 4 seeds each: gyros, accelerometers, barometers, magnetometers), with calibrate's
  own split (20 contiguous time blocks);
* the real cubesat gyro of ``configs/pan-tvac.yaml`` (raw-count thermometer), with its own
  RBF (6 centres, no tail: its 76 training rows are too few for the tail's ridge choice), on
  10, 15 and 20 contiguous time blocks;
* the presets ``mems-gyro``, ``patent-gyro``, ``consumer-imu`` and ``hrg`` (their configs'
  splits), seeds 0-2, with calibrate's RBF and with the default family set's (16 centres, 8
  or 16 chosen by tuning).

Per dataset: the held-out test score of each (the RMS of the drift left after correction over
the drift before, averaged over the axes; lower is better; the comparison's own test
part, never fitted) and their ratio
quantiles / k-means, with the cubic beside them: quantiles is kept for calibrate only if its ratios
stay near 1 and it never loses to the cubic where k-means does not.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, save, table  # noqa: E402
from thermonet.data.logs import SensorInstance, read_log  # noqa: E402
from thermonet.data.logs.writers import write_log  # noqa: E402
from thermonet.sim.fcboard import simulate_board  # noqa: E402
from thermonet.training.config import (  # noqa: E402
    CompareConfig,
    FamilyConfig,
    SplitConfig,
    load_config,
)
from thermonet.training.config_sections import TrackingConfig  # noqa: E402
from thermonet.workflows.calibrate import _lend_and_lag  # noqa: E402
from thermonet.workflows.compare import run_compare  # noqa: E402
from thermonet.workflows.firmware_fit import check_instance  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SEEDS = (0, 1, 2, 3)


#: The default family set's RBF (thermonet.training.config): 16 centres, 8 or 16 tuned.
DEFAULT_SET = ({"n_centres": 16, "tail": 3}, {"n_centres": [8, 16]})


def families(dt: str, dt2: str, baseline: dict[str, Any],
             rbf: dict[str, Any] | None = None, extra: list[str] | None = None,
             tune: dict[str, list[Any]] | None = None) -> list[FamilyConfig]:
    rbf = rbf or {"n_centres": 8, "tail": 3}
    inputs = [dt, dt2, *(extra or [])]
    return [FamilyConfig(**baseline),
            FamilyConfig(family="rbf", name="rbf-kmeans", inputs=inputs,
                         params={**rbf, "init": "kmeans"}, tune=dict(tune or {})),
            FamilyConfig(family="rbf", name="rbf-quantiles", inputs=inputs,
                         params={**rbf, "init": "quantiles"}, tune=dict(tune or {}))]


def scores(cfg: CompareConfig, fams: list[FamilyConfig], tmp: Path,
           dataset: Any = None) -> dict[str, float]:
    """``cfg`` run with ``fams`` (the cubic its baseline; no tracking, no figures, one
    process): each family's held-out test score (NaN where it could not be fitted)."""
    cfg.families, cfg.baseline, cfg.workers = fams, "cubic", 1
    cfg.tracking = TrackingConfig(enabled=False)
    res = run_compare(cfg, tmp / "cmp", overwrite=True, track=False, quiet=True,
                      dataset=dataset, plots=False)
    return {k: float(f["test_score"]) if f.get("status") == "ok" else float("nan")
            for k, f in res["families"].items()}


def board_rows(tmp: Path) -> list[dict[str, Any]]:
    rows = []
    cubic = {"family": "poly", "name": "cubic", "inputs": ["dT"], "params": {"degree": 3}}
    for autopilot, suffix in (("px4", "ulg"), ("ardupilot", "bin")):
        for seed in SEEDS:
            path = write_log(simulate_board("fc-board", autopilot=autopilot, seed=seed),
                             tmp / f"{autopilot}{seed}.{suffix}")
            # calibrate's own magnetometer step: a lent thermometer through a fitted lag
            (log,), _ = _lend_and_lag([read_log(path)], None)
            for inst in log.instances:
                if check_instance(inst, log.autopilot) is not None:
                    continue
                fams = families("dT", "dT2", cubic)
                if inst.unlagged_c is not None and inst.lag_s > 0:
                    # as calibrate compares it: the models compute the lag themselves
                    lag = f"lag_{inst.lag_s:g}"
                    fams = families("dT", "dT2", {**cubic, "inputs": ["dT", lag],
                                                  "params": {"degree": 3, "cross": True}},
                                    extra=[lag])
                    inst = SensorInstance(inst.kind, inst.instance, inst.device_id,
                                          inst.time_s, inst.unlagged_c, inst.values)
                elif inst.thermometer:
                    continue
                cfg = CompareConfig(split=SplitConfig(strategy="time-blocks", n_blocks=20))
                got = scores(cfg, fams, tmp,
                             dataset=inst.to_dataset(str(path)).validate(str(path)))
                lagged = " lent thermometer, lagged" if inst.kind == "mag" and len(
                    fams[0].inputs) > 1 else ""
                rows.append({"data": f"fc-board {autopilot} seed {seed} {inst.name}",
                             "group": f"fc-board ({autopilot}){lagged}", **got})
    return rows


def config_rows(tmp: Path) -> list[dict[str, Any]]:
    rows = []
    # the real cubesat gyro: 76 training rows, too few for the tail's inner ridge choice, so
    # its own configuration's RBF (6 centres, no tail: least squares, then gradient
    # refinement), on several contiguous-block splits
    base = {"family": "poly", "name": "cubic", "inputs": ["d_temp_raw"], "params": {"degree": 3}}
    for n in (10, 15, 20):
        cfg = load_config(ROOT / "configs/pan-tvac.yaml")
        cfg.split.n_blocks = n
        got = scores(cfg, families("d_temp_raw", "d_temp_raw2", base, {"n_centres": 6}), tmp)
        rows.append({"data": f"real: pan-tvac gyro, {n} time blocks",
                     "group": "real: pan-tvac gyro", **got})
    # the presets, three simulations each: calibrate's RBF (8 centres) and the default
    # set's (16, or 8 by tuning)
    for p in ("mems-gyro", "patent-gyro", "consumer-imu", "hrg"):
        for seed in (0, 1, 2):
            for label, (rbf, tune) in (("8 centres", ({"n_centres": 8, "tail": 3}, None)),
                                       ("default set", DEFAULT_SET)):
                cfg = load_config(ROOT / f"configs/{p}.yaml")
                cfg.data.seed = seed
                cubic = {"family": "poly", "name": "cubic", "inputs": ["dT"],
                         "params": {"degree": 3}}
                got = scores(cfg, families("dT", "dT2", cubic, rbf, tune=tune), tmp)
                rows.append({"data": f"preset {p} seed {seed} ({label})",
                             "group": f"preset {p} ({label})", **got})
    return rows


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="bench-rbf-centres-") as d:
        tmp = Path(d)
        rows = config_rows(tmp) + board_rows(tmp)
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(r["group"], []).append(r)
    out_rows = []
    for g, rs in groups.items():
        ratio = np.array([r["rbf-quantiles"] / r["rbf-kmeans"] for r in rs])
        vs_cubic = np.array([r["rbf-quantiles"] / r["cubic"] for r in rs])
        km_cubic = np.array([r["rbf-kmeans"] / r["cubic"] for r in rs])
        out_rows.append([g, len(rs), f"{np.nanmedian(ratio):.3f} "
                         f"({np.nanmin(ratio):.3f}–{np.nanmax(ratio):.3f})",
                         f"{np.nanmedian(km_cubic):.3f} ({np.nanmax(km_cubic):.3f})",
                         f"{np.nanmedian(vs_cubic):.3f} ({np.nanmax(vs_cubic):.3f})",
                         int(np.sum(np.isnan(ratio)))])
    md = ("Held-out test score (RMS of the drift left after correction over the drift "
          "before, averaged over the axes; lower is better) of the RBF with the cubic tail, k-means vs quantile centres: calibrate's "
          "(8 centres) and the default family set's (16, or 8 by tuning). Machine: "
          f"{machine()}.\n\n" + table(
              ["data", "fits", "quantiles / k-means: median (min–max)",
               "k-means / cubic: median (max)", "quantiles / cubic: median (max)",
               "not fitted"], out_rows))
    print(md)
    save("bench_rbf_centres", {"machine": machine(), "rows": rows}, md)


if __name__ == "__main__":
    main()
