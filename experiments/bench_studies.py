"""Accuracy on each study preset's held-out run, and the study-by-study reproduction table.

For every study config in ``configs/`` this runs ``thermonet compare`` (no
tracking) and reports, for the chosen family on the held-out run:

* the cut in peak-to-peak of 1 °C-binned bias, ``pp_raw / pp_comp`` (target ≥ 10×);
* ``drift_error_rms`` against what the noise allows (target ≤ 1.5×).  "What the
  noise allows" is ``sqrt(e_oracle² + B²)``: ``e_oracle`` is the drift error of
  the same family fitted on the same runs with the noise removed (outputs =
  reference + exact simulated drift: the error the family makes when noise
  costs nothing), and ``B`` is the bias instability (minimum of the
  overlapping Allan deviation) of the held-out run's noise — slow wander that
  no function of temperature can take out;
* on ``patent-gyro``: msd of RBF[ΔT, ΔT²] vs RBF[ΔT] vs the cubic.

Run: ``.venv/bin/python experiments/bench_studies.py`` (a few minutes on 2 cores).
"""

from __future__ import annotations

import copy
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import OUT, save, table  # noqa: E402

from thermonet.compare import run_compare  # noqa: E402
from thermonet.config import load_config  # noqa: E402
from thermonet.evaluate import load_data, make_splits  # noqa: E402
from thermonet.metrics import bias_instability  # noqa: E402
from thermonet.recording import Dataset  # noqa: E402

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
STUDIES = ["accel", "hrg", "mems-gyro", "patent-gyro"]


def noise_free(ds: Dataset) -> Dataset:
    """The same runs with outputs = reference + exact drift (no noise)."""
    runs = []
    for r in ds:
        c = copy.deepcopy(r)
        for axis in c.outputs:
            c.outputs[axis] = c.reference(axis) + c.drift[f"drift_{axis}"]
        runs.append(c)
    return Dataset(runs, meta=dict(ds.meta))


def test_noise_instability(ds: Dataset, cfg) -> dict[str, float]:
    test = make_splits(ds, cfg.split)[0].test
    out = {}
    for axis in test.outputs:
        noise = test.outputs[axis] - test.reference(axis) - test.drift[f"drift_{axis}"]
        out[axis] = bias_instability(noise, test.effective_rate_hz)
    return out


def main() -> None:
    rows, repro, data = [], [], {}
    for study in STUDIES:
        cfg = load_config(CONFIGS / f"{study}.yaml")
        ds = load_data(cfg.data)
        t0 = time.perf_counter()
        res = run_compare(cfg, OUT / "studies" / study, track=False, quiet=True, dataset=ds)
        seconds = time.perf_counter() - t0
        chosen = res["chosen"]
        entry = {"seconds": seconds, "chosen": chosen, "families": {}}
        if cfg.target == "drift":
            oracle = run_compare(cfg, OUT / "studies" / f"{study}-noise-free", track=False,
                                 quiet=True, dataset=noise_free(ds))
            bi = test_noise_instability(ds, cfg)
        for name, fam in res["families"].items():
            if fam["status"] != "ok":
                entry["families"][name] = {"status": fam["status"], "reason": fam["reason"]}
                continue
            for axis, m in fam["axes"].items():
                pp_cut = m["pp_raw"] / m["pp_comp"] if m["pp_comp"] > 0 else math.inf
                ratio = float("nan")
                allowed = float("nan")
                if cfg.target == "drift":
                    o = oracle["families"][name]
                    e_oracle = o["axes"][axis]["drift_error_rms"] if o["status"] == "ok" else math.nan
                    allowed = math.sqrt(e_oracle ** 2 + bi[axis] ** 2)
                    ratio = m["drift_error_rms"] / allowed
                entry["families"].setdefault(name, {})[axis] = {
                    **m, "pp_cut": pp_cut, "noise_allowed": allowed, "error_vs_allowed": ratio}
                rows.append([study, name + (" (chosen)" if name == chosen else ""), axis,
                             m["pp_raw"], m["pp_comp"], pp_cut, m.get("drift_error_rms", math.nan),
                             allowed, ratio, m["msd_comp"],
                             m.get("ppm_per_c_raw", math.nan), m.get("ppm_per_c_comp", math.nan)])
        data[study] = entry
    md = ["### Accuracy on each study preset's held-out run\n",
          table(["preset", "family", "axis", "pp raw", "pp comp", "pp cut ×", "drift err rms",
                 "noise allows", "err / allowed", "msd comp", "ppm/°C raw", "ppm/°C comp"], rows)]
    save("studies", data, "\n".join(md))


if __name__ == "__main__":
    main()
