"""``thermonet calibrate``'s comparison: thermonet's families beside the firmware form, per
sensor instance, and the instances compared side by side in helper processes.

:func:`compare_or_why` runs :func:`thermonet.workflows.compare.compare_result` on one instance
(the firmware's polynomial as the baseline family, a line, the RBF on [ΔT, ΔT²] with the
cubic tail, its centres at ΔT's quantiles), judged on held-out contiguous time blocks;
:func:`verdict` says whether the firmware form helps and what thermonet's best adds.
:func:`compare_all` shares the instances between the command and its helpers
(:mod:`thermonet.core.helpers`, :func:`helper_count` of them): each helper imports this module
and the comparison (the first reads the logs before, while the command imports them:
:func:`import_comparison`), then compares instances from the back of the list while the
command takes them from the front.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path
from typing import Any, cast

import numpy as np

from ..core.errors import ThermonetError
from ..core.helpers import Helpers, usable_cores, value_or_none
from ..core.outdir import relocate_json
from ..core.profile import stage as profile_stage
from ..data.logs import SensorInstance
from ..reporting.results import ComparisonResult as TypedResult
from ..reporting.results import clean
from ..scoring.verdicts import below

__all__ = ["BETTER_BY", "HELPER_IMPORTS", "MAX_WORKERS", "compare_all", "compare_or_why",
           "helper_count", "import_comparison", "verdict"]

#: A thermonet family is reported as better only when its validation score ratio is below
#: this fraction of the firmware form's (smaller differences are within the noise of a split).
BETTER_BY = 0.8


#: Most processes comparing instances side by side by default: each holds torch (~250 MB;
#: three, ~760 MB in all, stay within the memory a comparison took before they existed) and
#: pays its import (~0.8 s of CPU), which a board's few instances repay only a few times over.
MAX_WORKERS = 3
#: What a helper imports (the first after reading the logs, while the command imports the
#: same: :func:`import_comparison`): everything an instance's comparison needs.
HELPER_IMPORTS = ("thermonet.workflows.calibrate_compare", "thermonet.workflows.compare",
                  "thermonet.training.train")


def import_comparison() -> None:
    """Import now what an instance's comparison needs (:data:`HELPER_IMPORTS`: torch and the
    fit among them) — the command does while its first helper reads the logs, so that the
    logs are read off the way to the first comparison."""
    from ..training import train  # noqa: F401 - the torch boundary: the fit, imported ahead
    from . import compare  # noqa: F401 - lazy: importing it loads yaml


def helper_count(compare: bool, workers: int | None) -> int:
    """How many helper processes (:mod:`thermonet.core.helpers`) to start: none without the
    comparison or off POSIX (the workers' signal mask, :mod:`thermonet.core.helpers`).  By default
    (``workers`` None or 0) also none where this process has torch loaded already — a
    program calibrating again, a test — whose comparisons start at once: a helper would be
    ready only after about a second of imports, to compare perhaps one instance of the
    board; ``workers`` > 1 asks for them anyway."""
    if not compare or os.name != "posix":
        return 0
    if not workers:
        if "torch" in sys.modules:
            return 0
        return max(0, min(usable_cores(), MAX_WORKERS) - 1)
    return workers - 1


def compare_all(tasks: list[dict[str, Any]], helpers: Helpers | None = None
                ) -> dict[str, dict[str, Any] | str]:
    """Every task's :func:`compare_or_why`, by instance name.

    The command takes the tasks from the front of the list; per helper process, a thread
    hands the pool tasks from the back, one at a time, from the moment a helper's imports
    are done (the thread waits on the pool's futures, so it costs the command nothing
    meanwhile).  The same comparison either way (the same code on the same data: a test
    compares the two); a task a helper did not finish — it raised, died, or was not ready
    before the command had done the rest — is done here, where a genuine error is raised
    as it would have been.  Each helper's task is a ``--profile`` stage ``<instance>:
    compare … (helper)``: its wall time as the command waited for it."""
    out: dict[int, dict[str, Any] | str] = {}
    lock = threading.Lock()
    edge = [0, len(tasks)]                      # [next from the front, one past the back]

    def left() -> bool:
        with lock:
            return edge[0] < edge[1]

    def feed(h: Helpers) -> None:
        while not h.ready():                    # its imports: wait, unless the work is done
            if not left() or h.failed():
                return
            time.sleep(0.05)
        while True:
            with lock:
                if edge[0] >= edge[1]:
                    return
                edge[1] -= 1
                k = edge[1]
            with profile_stage(f"{tasks[k]['inst'].name}: compare thermonet's families "
                               "(helper)"):
                value = value_or_none(h.submit(__name__, "compare_or_why", **tasks[k]))
            if value is None:                   # raised or died: the command does the rest
                return
            out[k] = value

    n = helpers.size if helpers is not None and len(tasks) > 1 else 0
    feeders = [threading.Thread(target=feed, args=(helpers,), daemon=True) for _ in range(n)]
    for f in feeders:
        f.start()
    try:
        while True:
            with lock:
                if edge[0] >= edge[1]:
                    break
                k = edge[0]
                edge[0] += 1
            out[k] = compare_or_why(**tasks[k])
        for f in feeders:
            f.join()
        for k, task in enumerate(tasks):         # what the helpers did not finish
            if k not in out:
                out[k] = compare_or_why(**task)
    finally:
        # done (or interrupted): ended now, before the staging directory they write into is
        # removed or moved
        if helpers is not None:
            helpers.kill()
        for f in feeders:
            f.join()
    return {task["inst"].name: out[k] for k, task in enumerate(tasks)}


def compare_or_why(inst: SensorInstance, autopilot: str, where: Path, source: str, *,
                   final: Path) -> dict[str, Any] | str:
    """One instance's comparison (:func:`_compare`): its summary, or the one line of a
    :class:`ThermonetError` that stopped it."""
    try:
        with profile_stage(f"{inst.name}: compare thermonet's families"):
            return _compare(inst, autopilot, where, source, final=final)
    except ThermonetError as err:   # this instance cannot be judged: reported, skipped
        return str(err)


def _compare(inst: SensorInstance, autopilot: str, out: Path, source: str,
             final: Path | None = None) -> dict[str, Any]:
    """Compare the families on ``inst`` into ``out`` (inside the staging directory); paths
    recorded in its results name ``final``, where ``out`` will be once the output is moved."""
    from ..training.config import (  # lazy: importing it loads yaml
        CompareConfig,
        FamilyConfig,
        SplitConfig,
        TrackingConfig,
    )
    from .compare import compare_result  # lazy: importing it loads yaml

    fw = ("px4-poly5" if inst.kind == "baro" else "px4-cubic") \
        if autopilot == "px4" or inst.kind == "mag" else "ardupilot-cubic"
    families = [
        FamilyConfig(family="poly", name=fw, inputs=["dT"],
                     params={"degree": 5 if fw == "px4-poly5" else 3}),
        FamilyConfig(family="linear", name="linear", inputs=["dT"]),
        # the RBF with the cubic tail: a closed-form fit (its ridge chosen on the training
        # rows), at worst the cubic — not the gradient-trained network, which cost ~90 % of
        # a calibration's CPU time for a verdict it seldom changed; its centres at the
        # quantiles of ΔT, not by k-means: the same held-out scores on the boards
        # (experiments/bench_rbf_centres.py) without scikit-learn's 0.7 s import
        FamilyConfig(family="rbf", name="rbf", inputs=["dT", "dT2"],
                     params={"n_centres": 8, "tail": 3, "init": "quantiles"}),
    ]
    if inst.unlagged_c is not None and inst.lag_s > 0:
        # a lent thermometer through the fitted lag: the models take the thermometer as read
        # and compute the lag themselves (the lag_<tau> dynamic input, in the runtime and C
        # too); the baseline is PX4's cubic at the lagged temperature, T - lag = EMA_tau(T)
        lag = f"lag_{inst.lag_s:g}"
        fw = "px4-cubic-lag"
        families = [
            FamilyConfig(family="poly", name=fw, inputs=["dT", lag],
                         params={"degree": 3, "cross": True}),
            FamilyConfig(family="poly", name="px4-cubic-no-lag", inputs=["dT"],
                         params={"degree": 3}),
            # the lag interpolated along ΔT at the centres: the same held-out scores as
            # k-means on the simulated boards' lagged magnetometers (bench_rbf_centres.py)
            FamilyConfig(family="rbf", name="rbf", inputs=["dT", "dT2", lag],
                         params={"n_centres": 8, "tail": 3, "init": "quantiles"}),
        ]
        inst = SensorInstance(inst.kind, inst.instance, inst.device_id, inst.time_s,
                              inst.unlagged_c, inst.values, notes=list(inst.notes),
                              truth=inst.truth, thermometer=inst.thermometer,
                              starts=inst.starts)
    # workers=1: the three closed-form families one after the other — side by side in
    # threads they hold Python's lock in turn, and were slower (3.6 against 3.45 s a
    # calibration of the 9-instance bench log, idle)
    cfg = CompareConfig(
        split=SplitConfig(strategy="time-blocks", n_blocks=20), families=families,
        tracking=TrackingConfig(enabled=False), baseline=fw, workers=1)
    ds = inst.to_dataset(source).validate(source)
    # built inside calibrate's own staging directory (a fresh one on every run); no figures
    # per instance (the calibration's report has its own tables): the comparison is a verdict
    res = compare_result(cfg, out, overwrite=True, track=False, quiet=True, dataset=ds,
                         plots=False)
    if final is not None:
        relocate_json(out / "results.json", out, final)
    return _summary(cast(TypedResult, res), fw, str(final or out))   # model: bias: typed


def _summary(res: TypedResult, fw: str, where: str) -> dict[str, Any]:
    """What calibrate keeps of one instance's comparison ``res`` (the firmware form ``fw``,
    written to ``where``): the choice, the firmware form's band, per family its validation
    score and held-out binned drift, raw and compensated, as results.json holds them."""
    fams = res.families
    summary: dict[str, Any] = {"dir": where, "chosen": res.chosen,
                               "chosen_reason": res.chosen_reason, "firmware_family": fw,
                               "families": {}}
    # the firmware form's residual-drift band (thermonet.scoring.band): the EKF
    # recommendation written beside the parameter file
    band = (fams[fw].band if fw in fams else None) or {}
    if band.get("status") == "ok":
        summary["band"] = {"units": dict(res.units), **band}
    for label, fr in fams.items():
        if not fr.ok:
            summary["families"][label] = {"status": fr.status, "reason": fr.reason}
            continue
        axes = fr.axes
        summary["families"][label] = {
            "status": "ok", "val_score": clean(fr.val_score),
            "held_out_pp_raw": {a: m.metrics["pp_raw"] for a, m in axes.items()},
            "held_out_pp_comp": {a: m.metrics["pp_comp"] for a, m in axes.items()}}
    return summary


def verdict(summary: dict[str, Any]) -> tuple[bool, str]:
    """Whether the firmware form helps on held-out data, and a one-line verdict."""
    fw = summary["firmware_family"]
    f = summary["families"].get(fw, {})
    if f.get("status") != "ok":
        return False, f"the firmware form could not be fitted ({f.get('reason')})"
    axes = list(f["held_out_pp_raw"])
    raw = np.array(list(f["held_out_pp_raw"].values()))
    comp = np.array(list(f["held_out_pp_comp"].values()))
    cut = raw / np.maximum(comp, 1e-300)
    # "helps" beyond the decision margin (thermonet.scoring.verdicts.DECISION_RTOL), never by rounding
    helps = below(f["val_score"], 1.0) and all(below(c, r) for c, r in zip(comp, raw, strict=True))
    # the comparison's own split, to rank the families: what verify will demand is the
    # held-out check's grade (fine / marginal / fails), not this
    line = (f"{fw} on the comparison's held-out blocks (ranking the families; the held-out "
            f"check below is verify's test): binned drift p-p cut "
            f"{', '.join(f'{c:.1f}x' for c in cut)}"
            f" (val score ratio {f['val_score']:.3g})")
    if not helps:       # say where it fails, and nothing that reads as a recommendation
        worse = [f"{a} {c:.1f}x" for a, c, r, m in zip(axes, cut, raw, comp, strict=True)
                 if not below(m, r)]
        line += (f"; it does not cut {', '.join(worse)}" if worse else
                 f"; its val score ratio {f['val_score']:.3g} is not below 1")
    chosen = summary.get("chosen")
    if chosen and chosen != fw:
        other = summary["families"][chosen]
        if other["val_score"] < BETTER_BY * f["val_score"]:
            line += (f"; thermonet's {chosen} does better on validation "
                     f"({other['val_score']:.3g}), which the parameter file cannot carry — "
                     f"export it as ONNX or C from {summary['dir']}")
        elif helps:
            line += (f"; thermonet's best ({chosen}, {other['val_score']:.3g}) is within "
                     f"{100 * (1 - BETTER_BY):.0f} % of it: the firmware form is enough")
    return helps, line
