"""Beating the anchor: PX4's / ArduPilot's calibration vs thermonet on a heat/cool cycling gyro.

The autopilots fit a cubic in temperature on heating data only, clamp silently
outside the calibrated range and validate nothing numerically.  This benchmark
takes the `patent-gyro` device, puts it through heat/cool cycles
(−20 → 50 → −20 °C at 18 °C/h, 1 h soaks, two cycles per run) with a hysteresis
of 0.02 °/s between heating and cooling branches (a play operator 2 °C wide)
besides its rate term, and compares on the held-out run:

* ``px4``: cubic on ΔT fitted on heating samples only (the anchor);
* ``cubic``: the same cubic on all samples;
* ``rbf-rate``: RBF on [ΔT, ΔT², dT/dt] — the rate tells heating from cooling.

Split by run (4 runs: train run0, run1; validate run2; test run3).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import OUT, save, table  # noqa: E402
from thermonet.sim import PRESETS, simulate  # noqa: E402
from thermonet.sim.chamber import ChamberProfile, cycle  # noqa: E402
from thermonet.sim.device import HysteresisConfig  # noqa: E402
from thermonet.training.config import CompareConfig, FamilyConfig  # noqa: E402
from thermonet.workflows.compare import run_compare  # noqa: E402


def cycling_device():
    base = PRESETS["patent-gyro"]
    profile = ChamberProfile(name="heat/cool cycles -20..50 C", start_c=-20.0,
                             segments=cycle(-20.0, 50.0, rate_c_per_h=18.0, soak_h=1.0, cycles=2))
    axes = tuple(dataclasses.replace(a, hysteresis=HysteresisConfig(amplitude=0.02, width_c=2.0))
                 for a in base.axes)
    return dataclasses.replace(base, name="patent-gyro-cycling", procedures=(profile,), axes=axes,
                               default_runs=4)


def main() -> None:
    ds = simulate(cycling_device(), seed=0)
    cfg = CompareConfig(families=[
        FamilyConfig(family="poly", name="px4", inputs=["dT"], params={"degree": 3},
                     train_on="heating"),
        FamilyConfig(family="poly", name="cubic", inputs=["dT"], params={"degree": 3}),
        FamilyConfig(family="rbf", name="rbf-rate", inputs=["dT", "dT2", "rate"],
                     params={"n_centres": 16}),
    ], baseline="px4")
    res = run_compare(cfg, OUT / "anchor", overwrite=True, track=False, quiet=True, dataset=ds)
    rows = []
    for name, fam in res["families"].items():
        for axis, m in fam["axes"].items():
            rows.append([name + (" (chosen)" if name == res["chosen"] else ""), axis,
                         m["pp_comp"], m["msd_comp"], m["drift_error_rms"],
                         m.get("pp_ratio_vs_baseline", float("nan"))])
    md = (
        "### Against the PX4/ArduPilot anchor on a heat/cool cycling gyro (hysteresis 0.02 °/s)\n\n"
        + table(
            ["family", "axis", "pp comp [°/s]", "msd comp", "drift err rms [°/s]", "pp / anchor's"],
            rows,
        )
    )
    save("anchor", {"results": res}, md)


if __name__ == "__main__":
    main()
