"""Regret of the selection rules: cross-validation against one validation part.

Over simulated devices from the realistic presets (different seeds: heat/cool paths,
hysteresis, turn-on biases, noise) and the real recordings in ``tests/data/real/`` (copies of
``../shared/data/real/`` with their licences), every device is compared once with the default
family set; ``results.json`` records what the new rule (purged blocked cross-validation,
``selection.folds: 5``) and the single validation part (the rule before cross-validated selection,
``selection.folds: 0``) choose from the same fits, and the held-out test part judges, once,
what each rule shipped.

Per axis, the test error of a rule is the test score of the family it chose, on that axis —
the raw score where its mask leaves the axis raw, or where it chose nothing (do no harm) —
and the *regret* is that error over the best any candidate achieved on the axis in hindsight
(its test score, compensated, or raw if nothing beats raw).  Rules: the new one, the old one,
and always-cubic with every axis compensated (what PX4 and ArduPilot ship).

``--real``: only the honest splits of the real recordings (:func:`real_splits`); ``--simulated``:
only the simulated devices; ``--stress``: the new-excursion stress bench (:func:`stress_splits`:
``stress-imu``, every split whose test is a new excursion, the new rule against the rule before
on the same data; ``BENCH_STRESS_SEEDS`` units, ``BENCH_STRESS_RULES`` which rules, default
``new,before``); ``--states``: the dynamic inputs' state on held-out blocks carried in
against restarted (:func:`main_states`); neither (``make bench``): the real splits and the
simulated devices.

Goal: median regret ≤ 1.05 and ≤ 1.10 on 90 % of devices for the new rule
(a device's regret: the mean over its axes).  ``BENCH_SELECTION_DEVICES`` sets the number of
simulated devices per preset (default 8, 8, 4).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import save, table  # noqa: E402
from thermonet.sim import simulate  # noqa: E402
from thermonet.training.config import CompareConfig, load_config  # noqa: E402
from thermonet.workflows.compare import run_compare  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
N = int(os.environ.get("BENCH_SELECTION_DEVICES", "8"))

#: (preset, config, runs, sample rate Hz, devices): rates cut from the presets' so that forty
#: comparisons run in minutes on two cores; the procedures and laws are the presets'.
SIMULATED = [("consumer-imu", "configs/consumer-imu.yaml", 2, 0.2, N),
             ("patent-gyro", "configs/default.yaml", 5, 0.1, N),
             ("accel-ramp", None, 1, 0.5, max(N // 2, 1))]


def _errors(res: dict[str, Any], family: str | None, masked: bool = True) -> np.ndarray:
    """Per-axis test error of ``family`` (raw where masked out or None)."""
    any_fam = next(f for f in res["families"].values() if f.get("status") == "ok")
    axes = list(any_fam["axes"])
    raw = np.array([any_fam["axes"][a]["score_raw"] for a in axes])
    if family is None or res["families"].get(family, {}).get("status") != "ok":
        return raw
    ax = res["families"][family]["axes"]
    comp = np.array([ax[a]["score_comp"] for a in axes])
    if not masked:
        return comp
    keep = np.array([ax[a]["compensate"] for a in axes])
    return np.where(keep, comp, raw)


def _best(res: dict[str, Any]) -> np.ndarray:
    errs = [_errors(res, None)] + [_errors(res, k, masked=False) for k, f in
                                   res["families"].items() if f.get("status") == "ok"]
    return np.min(errs, axis=0)


def _run(cfg: CompareConfig, ds: Any) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        return run_compare(cfg, Path(tmp) / "out", dataset=ds, track=False, quiet=True,
                           plots=False)


def _single(res: dict[str, Any]) -> dict[str, Any]:
    """The comparison as the single-validation-part rule would have shipped it (the same
    fits: results.json records that rule's choice and masks beside the new one's)."""
    alt = res["selection"]["single_split"]
    fams = {}
    for k, f in res["families"].items():
        if f.get("status") != "ok" or k not in alt["compensate"]:   # per-axis: not a candidate
            fams[k] = f
            continue
        fams[k] = {**f, "axes": {a: {**m, "compensate": alt["compensate"][k][a]}
                                 for a, m in f["axes"].items()}}
    return {**res, "families": fams, "chosen": alt["chosen"]}


def _device(name: str, cfg: CompareConfig, ds: Any) -> dict[str, Any]:
    t0 = time.perf_counter()
    new = _run(cfg, ds)
    old = _single(new)
    best = _best(new)
    out = {"device": name, "chosen_new": new["chosen"], "chosen_old": old["chosen"],
           "seconds": time.perf_counter() - t0}
    whole = (new["selection"].get("whole_recording") or {}).get("chosen", new["chosen"])
    out["chosen_whole"] = whole
    for rule, res, fam, masked in (("new", new, new["chosen"], True),
                                   ("whole", new, whole, True),
                                   ("old", old, old["chosen"], True),
                                   ("cubic", new, "cubic", False)):
        r = _errors(res, fam, masked) / np.maximum(best, 1e-300)
        out[f"regret_{rule}_axes"] = r.tolist()
        out[f"regret_{rule}"] = float(np.mean(r))
        out[f"worse_than_cubic_{rule}"] = bool(
            (_errors(res, fam, masked) > _errors(new, "cubic", False) * (1 + 1e-9)).any())
    # the refit on training + validation (selection.refit, the default) against the fit on the
    # training part alone: the chosen model's test error, per axis, refit / no refit
    import copy

    cfg_nr = copy.deepcopy(cfg)
    cfg_nr.selection.refit = False
    nr = _run(cfg_nr, ds)
    if new["chosen"] is not None and nr["chosen"] == new["chosen"]:
        gain = _errors(new, new["chosen"]) / np.maximum(_errors(nr, nr["chosen"]), 1e-300)
        out["refit_ratio_axes"] = gain.tolist()
        out["refit_ratio"] = float(np.mean(gain))
    print(f"{name}: new {out['chosen_new']} {out['regret_new']:.3f}, old {out['chosen_old']} "
          f"{out['regret_old']:.3f}, cubic {out['regret_cubic']:.3f} "
          f"({out['seconds']:.0f} s)", flush=True)
    return out


def _devices() -> list[tuple[str, CompareConfig, Any]]:
    items = []
    for preset, config, runs, rate, count in SIMULATED:
        for seed in range(count):
            ds = simulate(preset, runs=runs, seed=seed, sample_rate_hz=rate)
            def mk(c: str | None = config) -> CompareConfig:
                return load_config(ROOT / c) if c else CompareConfig()

            items.append((f"{preset}#{seed}", mk(), ds))
    # the real recordings with their configs' splits: the BMI270 soaks with the default family
    # set, the cubesat gyro (temperature only as raw counts) with its config's proxy families
    for cfg_name in ("bmi270", "pan-tvac"):
        def mk_real(name: str = cfg_name) -> CompareConfig:
            cfg = load_config(ROOT / "configs" / f"{name}.yaml")
            cfg.data.paths = [str(ROOT / p) for p in cfg.data.paths]   # repository-relative
            if cfg.data.mapping:
                cfg.data.mapping = str(ROOT / cfg.data.mapping)
            if name == "bmi270":
                cfg.families, cfg.baseline = CompareConfig().families, "cubic"
            return cfg
        from thermonet.training.parts import load_data

        cfg = mk_real()
        items.append((f"real:{cfg_name}", cfg, load_data(cfg.data)))
    return items


def _refit_summary(rows: list[dict[str, Any]]) -> str:
    r = np.array([x["refit_ratio"] for x in rows if "refit_ratio" in x])
    if r.size == 0:
        return "no device to compare."
    ax = np.concatenate([x["refit_ratio_axes"] for x in rows if "refit_ratio" in x])
    return (f"median {np.median(r):.4f} (min {r.min():.4f}, max {r.max():.4f}) over {r.size} "
            f"devices; per axis {int((ax < 1 - 1e-9).sum())} better, "
            f"{int((ax > 1 + 1e-9).sum())} worse, {int(ax.size)} in all.")


# ------------------------------------------------------------ real recordings, honest splits
def _real_config(name: str) -> tuple[CompareConfig, Any]:
    """A real recording's config (data read from ``tests/data/real/``) with the cubic — PX4's
    and ArduPilot's form, in the recording's own temperature signal — among the candidates."""
    from thermonet.training.config import FamilyConfig
    from thermonet.training.parts import load_data

    cfg = load_config(ROOT / "configs" / f"{name}.yaml")
    cfg.data.paths = [str(ROOT / p) for p in cfg.data.paths]   # repository-relative
    if cfg.data.mapping:
        cfg.data.mapping = str(ROOT / cfg.data.mapping)
    if name == "bmi270":
        cfg.families = CompareConfig().families
    else:       # the cubesat: temperature only as raw counts — the cubic in them
        cfg.families.append(FamilyConfig(family="poly", name="cubic", inputs=["d_temp_raw"],
                                         params={"degree": 3}))
    cfg.baseline = "cubic"
    return cfg, load_data(cfg.data)


def _halves(ds: Any, reverse: bool) -> Any:
    """One run cut at its middle into two contiguous runs: train on one, verify on the other."""
    from thermonet.core.recording import Dataset

    (rec,) = list(ds)
    t = np.asarray(rec.time_s)
    mid = t[0] + 0.5 * (t[-1] - t[0])
    a, b = rec.select(t <= mid, f"{rec.run_id}-first"), rec.select(t > mid,
                                                                  f"{rec.run_id}-second")
    return Dataset([b, a] if reverse else [a, b])


def real_splits() -> list[tuple[str, CompareConfig, Any]]:
    """Every honest split of the real recordings: time blocks at three block counts (the test
    is blocks inside the runs), and train-then-verify in both directions (the cubesat's ramp
    cut at its middle, each half verified by the other)."""
    import copy

    out = []
    for name in ("pan-tvac", "bmi270"):
        cfg, ds = _real_config(name)
        for n in (10, 20, 30):
            c = copy.deepcopy(cfg)
            c.split.strategy, c.split.n_blocks = "time-blocks", n
            out.append((f"{name} time-blocks {n}", c, ds))
        if name == "bmi270":
            # two isothermal soaks (13 °C, 47.6 °C): a model trained on one spans 0.3 °C and
            # compare refuses it (no thermal model from one temperature); the honest splits of
            # these soaks are the time blocks inside both
            continue
        for reverse in (False, True):
            c = copy.deepcopy(cfg)
            c.split.strategy = "train-then-verify"
            c.split.n_blocks = 5     # bursts of 5 s every 300 s: a half holds about 12
            d = _halves(ds, reverse)
            what = "second half → first" if reverse else "first half → second"
            out.append((f"{name} {what}", c, d))
    return out


def _axis_ratios(res: dict[str, Any]) -> dict[str, list[float]]:
    """Per axis: shipped / cubic, shipped / raw and regret (shipped over the best candidate in
    hindsight) on the test part; an axis shipped raw counts as raw."""
    shipped = _errors(res, res["chosen"])
    cubic = _errors(res, "cubic", masked=False)
    raw = _errors(res, None)
    best = _best(res)
    return {"vs_cubic": (shipped / np.maximum(cubic, 1e-300)).tolist(),
            "vs_raw": (shipped / np.maximum(raw, 1e-300)).tolist(),
            "regret": (shipped / np.maximum(best, 1e-300)).tolist()}


def main_real() -> None:
    rows = []
    for name, cfg, ds in real_splits():
        t0 = time.perf_counter()
        res = _run(cfg, ds)
        r = _axis_ratios(res)
        axes = list(res["units"])
        per_axis = (res["selection"].get("per_axis") or {}).get("chosen", {})
        rows.append({"split": name, "chosen": res["chosen"], "axes": axes, **r,
                     "per_axis": per_axis, "seconds": time.perf_counter() - t0})
        print(f"{name}: {res['chosen']} {per_axis} vs cubic "
              + " ".join(f"{x:.4f}" for x in r["vs_cubic"]), flush=True)
    vc = np.concatenate([r["vs_cubic"] for r in rows])
    head = ["split", "axis", "shipped", "shipped / cubic", "shipped / raw", "regret"]
    body = [[r["split"], a, r["per_axis"].get(a) or "raw" if r["per_axis"] else r["chosen"],
             r["vs_cubic"][i], r["vs_raw"][i], r["regret"][i]]
            for r in rows for i, a in enumerate(r["axes"])]
    md = (f"{len(rows)} honest splits of the real recordings in `tests/data/real/` "
          f"({vc.size} axes): shipped / cubic ≤ 1.00 on {int((vc <= 1 + 1e-9).sum())} axes, "
          f"≤ 0.8 on {int((vc <= 0.8).sum())}; max {vc.max():.3f}, median "
          f"{np.median(vc):.3f}.\n\n" + table(head, body))
    save("bench_selection_real", {"splits": rows}, md)


# ------------------------------------------------- new excursions: the stress bench
def _legs_as_runs(rec: Any, keep: str) -> Any:
    """One run's heating legs (``keep="heating"``) or cooling legs as a run of their own."""
    from thermonet.scoring.folds import excursions

    legs = excursions(np.asarray(rec.temperature_c))
    want = 1 if keep == "heating" else -1
    mask = np.zeros(rec.n_samples, dtype=bool)
    for leg in legs:
        if leg.direction == want:
            mask[leg.start:leg.stop] = True
    return rec.select(mask, f"{rec.run_id}-{keep}")


def stress_splits(seed: int, rate_hz: float = 0.1) -> list[tuple[str, Any]]:
    """Every new-excursion split of one simulated ``stress-imu`` unit (runs: fast, slow, fast
    cycles): another cycle at another rate (both ways), two cycles then a third, heating-only
    calibration then its own cooling, and time blocks inside one cycle and inside two."""
    from thermonet.core.recording import Dataset

    ds = simulate("stress-imu", runs=3, seed=seed, sample_rate_hz=rate_hz)
    fast, slow, fast2 = list(ds)
    return [("fast cycle -> slow cycle", Dataset([fast, slow])),
            ("slow cycle -> fast cycle", Dataset([slow, fast])),
            ("fast + slow -> fast", Dataset([fast, slow, fast2])),
            ("heating only -> cooling", Dataset([_legs_as_runs(fast, "heating"),
                                                 _legs_as_runs(fast, "cooling")])),
            ("time blocks, one cycle", Dataset([fast])),
            ("time blocks, two cycles", Dataset([fast, slow]))]


def _stress_config(name: str, ds: Any, new: bool) -> CompareConfig:
    cfg = CompareConfig()
    runs = list(ds)
    cfg.split.strategy = ("time-blocks" if name.startswith("time blocks") else
                          {2: "train-then-verify"}.get(len(runs), "runs"))
    if len(runs) == 3:
        cfg.split.train = [runs[0].run_id, runs[1].run_id]
        cfg.split.test = runs[2].run_id
    if not new:      # the rule before: interleaved blocks, the one-SE rule alone
        cfg.selection.hold_out, cfg.selection.gate = "blocks", False
    return cfg


def main_stress() -> None:
    """Per split and axis: shipped / cubic by the new rule (excursions held out, the gate)
    and by the rule before (interleaved blocks, one-SE), on the same data, worst axis first;
    the share of the hindsight gain over the cubic kept where a candidate beat it."""
    rows = []
    seeds = int(os.environ.get("BENCH_STRESS_SEEDS", "2"))
    for seed in range(seeds):
        for name, ds in stress_splits(seed):
            for rule in os.environ.get("BENCH_STRESS_RULES", "new,before").split(","):
                t0 = time.perf_counter()
                res = _run(_stress_config(name, ds, rule == "new"), ds)
                r = _axis_ratios(res)
                best = _best(res)
                cubic = _errors(res, "cubic", masked=False)
                shipped = _errors(res, res["chosen"])
                gain = np.where(best < cubic * (1 - 1e-9),
                                (cubic - shipped) / np.maximum(cubic - best, 1e-300), np.nan)
                per_axis = (res["selection"].get("per_axis") or {}).get("chosen", {})
                rows.append({"split": f"{name} #{seed}", "rule": rule, "axes": list(res["units"]),
                             "chosen": res["chosen"], "per_axis": per_axis,
                             "kind": res["selection"].get("kind"), **r,
                             "gain_kept": gain.tolist(),
                             "seconds": time.perf_counter() - t0})
                print(f"{name} #{seed} [{rule}]: {res['chosen']} worst "
                      f"{max(r['vs_cubic']):.3f} "
                      + " ".join(f"{x:.3f}" for x in r["vs_cubic"]), flush=True)

    def summary(rule: str) -> list[Any]:
        rs = [r for r in rows if r["rule"] == rule]
        vc = np.concatenate([r["vs_cubic"] for r in rs])
        g = np.concatenate([r["gain_kept"] for r in rs])
        g = g[np.isfinite(g)]
        return [rule, len(rs), int(vc.size), int((vc > 1 + 1e-9).sum()), float(vc.max()),
                float(np.median(vc)), int((vc <= 0.8).sum()),
                float(np.median(g)) if g.size else float("nan")]

    head = ["rule", "splits", "axes", "axes worse than cubic", "worst shipped / cubic",
            "median", "axes ≤ 0.8× cubic", "median share of hindsight gain kept"]
    body = []
    for r in sorted(rows, key=lambda x: -max(x["vs_cubic"])):
        i = int(np.argmax(r["vs_cubic"]))
        body.append([r["split"], r["rule"], r["kind"], r["axes"][i],
                     (r["per_axis"].get(r["axes"][i]) or "raw") if r["per_axis"]
                     else r["chosen"] or "raw", r["vs_cubic"][i],
                     " ".join(f"{x:.3f}" for x in r["vs_cubic"])])
    md = ("`stress-imu` (sensing element 7 min behind its thermometer, fast and slow cycles), "
          f"{seeds} units at 0.1 Hz, every new-excursion split; shipped / cubic per axis on the "
          "held-out run (an axis shipped raw counts as raw).\n\n"
          + table(head, [summary(r) for r in ("new", "before")
                         if any(x["rule"] == r for x in rows)])
          + "\n\nEach split's worst axis, worst first:\n\n"
          + table(["split", "rule", "folds", "worst axis", "shipped there", "shipped / cubic",
                   "every axis"], body))
    save("bench_selection_stress", {"splits": rows}, md)


def main_states() -> None:
    """The dynamic inputs' state on a time-block split's held-out blocks: carried in from the
    rows before each block (the rule: parts built on the whole run, then cut) against
    restarted at every block's start (the carved blocks, the rule before).  Per dynamic
    family and axis, the held-out score ratio (to raw) under each, on the time-block splits of
    the stress bench (one cycle, two cycles) and of ``consumer-imu`` (one run)."""
    import copy
    from dataclasses import replace

    from thermonet.core.recording import Dataset
    from thermonet.training.splits import SPLITS, register_split

    if "time-blocks-restarted" not in SPLITS:
        @register_split("time-blocks-restarted")
        def _restarted(runs: Any, cfg: Any, source: str) -> Any:
            return [replace(sp, whole=[]) for sp in SPLITS["time-blocks"](runs, cfg, source)]

    cases = []
    for seed in range(int(os.environ.get("BENCH_STRESS_SEEDS", "3"))):
        for name, ds in stress_splits(seed):
            if name.startswith("time blocks"):
                cases.append((f"stress-imu {name} #{seed}", ds))
        ci = simulate("consumer-imu", runs=1, seed=seed, sample_rate_hz=0.2)
        cases.append((f"consumer-imu one run #{seed}", Dataset(list(ci))))
    rows = []
    for name, ds in cases:
        got = {}
        for rule in ("time-blocks", "time-blocks-restarted"):
            cfg = copy.deepcopy(_stress_config("time blocks", ds, True))
            cfg.split.strategy = rule
            res = _run(cfg, ds)
            got[rule] = {k: [f["axes"][a]["score_comp"] / f["axes"][a]["score_raw"]
                             for a in res["units"]]
                         for k, f in res["families"].items()
                         if f.get("status") == "ok" and k in ("poly3-rate", "poly3-hyst")}
        for fam in got["time-blocks"]:
            a, b = np.array(got["time-blocks"][fam]), np.array(got["time-blocks-restarted"][fam])
            rows.append({"case": name, "family": fam, "carried": a.tolist(),
                         "restarted": b.tolist()})
            print(f"{name} {fam}: carried / restarted "
                  + " ".join(f"{x:.3f}" for x in a / b), flush=True)
    r = np.concatenate([np.array(x["carried"]) / np.array(x["restarted"]) for x in rows])
    md = (f"Held-out score ratio of the dynamic families (poly3-rate, poly3-hyst) on {len(cases)} "
          f"time-block comparisons, {r.size} family-axes: state carried in / restarted at each "
          f"block: median {np.median(r):.3f}, 10th–90th percentile {np.quantile(r, 0.1):.3f}–"
          f"{np.quantile(r, 0.9):.3f}, min {r.min():.3f}, max {r.max():.3f}.\n\n"
          + table(["case", "family", "carried / restarted per axis"],
                  [[x["case"], x["family"], " ".join(
                      f"{c / d:.3f}" for c, d in zip(x["carried"], x["restarted"], strict=True))]
                   for x in rows]))
    save("bench_selection_states", {"rows": rows}, md)


def main() -> None:
    if "--states" in sys.argv[1:]:
        main_states()
        return
    if "--stress" in sys.argv[1:]:
        main_stress()
        return
    if "--real" in sys.argv[1:]:
        main_real()
        return
    if "--simulated" not in sys.argv[1:]:    # make bench: both parts
        main_real()
    rows = [_device(*item) for item in _devices()]
    sim = [r for r in rows if not r["device"].startswith("real:")]

    def summary(rule: str, rs: list[dict[str, Any]]) -> list[Any]:
        reg = np.array([r[f"regret_{rule}"] for r in rs])
        return [rule, float(np.median(reg)), float(np.quantile(reg, 0.9)), float(reg.max()),
                sum(r[f"worse_than_cubic_{rule}"] for r in rs)]

    head = ["rule", "median regret", "90th percentile", "max", "devices worse than cubic on an axis"]
    md = (f"{len(sim)} simulated devices (realistic presets, different seeds) and "
          f"{len(rows) - len(sim)} real recordings; regret = test error of the chosen model "
          "over the best candidate's in hindsight, mean over axes.\n\n"
          + table(head, [summary(k, sim) for k in ("new", "whole", "old", "cubic")])
          + "\n\nThe refit (`selection.refit`, default) against the fit on the training part "
          "alone: the chosen model's test error, refit / no refit, mean over axes — "
          + _refit_summary(rows)
          + "\n\nPer device:\n\n"
          + table(["device", "per axis chose", "regret", "one family", "regret",
                   "old rule chose", "regret", "always cubic", "refit / no refit"],
                  [[r["device"], r["chosen_new"] or "none", r["regret_new"],
                    r["chosen_whole"] or "none", r["regret_whole"],
                    r["chosen_old"] or "none", r["regret_old"], r["regret_cubic"],
                    r.get("refit_ratio", float("nan"))]
                   for r in rows]))
    save("bench_selection", {"devices": rows}, md)


if __name__ == "__main__":
    main()
