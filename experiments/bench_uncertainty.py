"""Does the residual-drift band cover what it says?  Empirical coverage on held-out data.

For every device (realistic presets at reduced sample rates, ≥ 10 seeds each; the real
recordings' honest splits from ``bench_selection.real_splits``) one ``compare`` with the
preset's config; the shipped model's band (``results.json`` ``band``, nominal 90 %) is then
checked on the comparison's own held-out test part, which neither the fit nor the
out-of-fold residuals saw: per axis, the test residual's window means (the band's
``window_s``) about the test part's mean, and the fraction of windows inside the band at the
window's mean temperature (windows inside the trained range).

* **coverage** per preset (all windows of all devices and axes pooled; target 85–95 %);
* **width** over an oracle band made from the held-out residuals themselves (per band bin the
  same conformal quantile of the test windows' scores), median over axes (target ≤ 1.5);
* **past the edge**: a second comparison per device on the training runs cut at
  ``T ≤ T_max − 6 °C``, judged on an extra simulated run of the same device over the whole
  range: coverage of the windows up to 5 °C past the trained edge (target ≥ 80 %).

``BENCH_UNCERTAINTY_SEEDS`` sets the seeds per preset (default 10), ``BENCH_UNCERTAINTY_EDGE``
how many of them also run the edge experiment (default all).  ``stress``: the band on new
excursions, every split of ``bench_selection.py --stress`` (``BENCH_STRESS_SEEDS`` units).
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
from thermonet.api.estimator import DriftEstimator  # noqa: E402
from thermonet.core.recording import Dataset  # noqa: E402
from thermonet.scoring.band import (  # noqa: E402
    conformal_quantile,
    evaluate_tables,
    outside_holds,
    sample_directions,
    window_directions,
    window_means,
    window_rates,
)
from thermonet.scoring.fold_plan import window_labels  # noqa: E402
from thermonet.sim import simulate  # noqa: E402
from thermonet.training.config import CompareConfig, load_config  # noqa: E402
from thermonet.training.train import predict  # noqa: E402
from thermonet.workflows.compare import run_compare  # noqa: E402
from thermonet.workflows.compare_plan import plan  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SEEDS = int(os.environ.get("BENCH_UNCERTAINTY_SEEDS", "10"))
EDGE = int(os.environ.get("BENCH_UNCERTAINTY_EDGE", str(SEEDS)))
#: (preset, config, runs, sample rate Hz) as bench_selection simulates them
PRESETS = [("consumer-imu", "configs/consumer-imu.yaml", 2, 0.2),
           ("patent-gyro", "configs/default.yaml", 5, 0.1),
           ("accel-ramp", None, 1, 0.5)]
EDGE_CUT_C = 6.0
EDGE_SPAN_C = 5.0


def _config(path: str | None) -> CompareConfig:
    return load_config(ROOT / path) if path else CompareConfig()


def _windows(est: DriftEstimator, rec: Any) -> dict[str, Any] | None:
    """Per window of ``rec``: the residual's mean (W, A), the band signal's mean, samples."""
    band = est.band_
    model = est.model_
    part = est._part(rec, est.spec_, est.outputs_)
    pred = predict(model, part.signals, part.time_s)
    e = np.asarray(part.target, dtype=np.float64) - pred
    x = np.asarray(part.signals[:, list(model.signals).index(band.signal)], dtype=np.float64)
    ok = np.isfinite(e).all(axis=1) & np.isfinite(x)
    if ok.sum() < 2:
        return None
    wl = window_labels(np.asarray(part.time_s)[ok], band.window_s)
    means, n = window_means(np.column_stack([e[ok], x[ok]]), wl)
    # each window's rate and whether it lies outside what the band states (holds_for)
    rate = window_rates(np.asarray(part.time_s)[ok], x[ok], wl)
    dirs = window_directions(sample_directions(x)[ok], wl)
    return {"e": means[:, :-1], "x": means[:, -1], "n": n,
            "outside": outside_holds(band.holds_for, rate, dirs)}


def _judge(est: DriftEstimator, rec: Any) -> dict[str, Any]:
    """Per axis: windows inside the trained range, covered, band and oracle widths; windows
    past the edge (≤ EDGE_SPAN_C) and covered."""
    band = est.band_
    w = _windows(est, rec)
    out: dict[str, Any] = {}
    if w is None:
        return out
    for a, axis in enumerate(est.outputs_):
        b = band.axes[axis]
        lo, hi = b.edges[0], b.edges[-1]
        inr = (w["x"] >= lo) & (w["x"] <= hi)
        if inr.sum() < 2:
            continue
        mbar = float((w["e"][inr, a] * w["n"][inr]).sum() / w["n"][inr].sum())
        s = np.abs(w["e"][:, a] - mbar)
        half = evaluate_tables(w["x"], b.edges, b.half, b.grow_lo, b.grow_hi)
        k = np.clip(np.searchsorted(np.asarray(b.edges[1:-1]), w["x"], side="right"), 0,
                    len(b.half) - 1)
        oracle = np.full(w["x"].size, np.nan)
        for j in range(len(b.half)):
            m = inr & (k == j)
            if m.sum():
                q = conformal_quantile(s[m], band.level)
                # too few held-out windows for a finite quantile: their largest score
                oracle[m] = q if np.isfinite(q) else s[m].max()
        d = np.where(w["x"] < lo, lo - w["x"], w["x"] - hi)
        past = (d > 0) & (d <= EDGE_SPAN_C)
        cov, off = s <= half, w["outside"]
        out[axis] = {"n": int(inr.sum()), "covered": int((s[inr] <= half[inr]).sum()),
                     "n_stated": int((inr & ~off).sum()),
                     "covered_stated": int((cov & inr & ~off).sum()),
                     "width": float(np.mean(half[inr])), "oracle": float(np.mean(oracle[inr])),
                     "n_past": int(past.sum()), "covered_past": int((s[past] <= half[past]).sum())}
    return out


def _shipped(cfg: CompareConfig, ds: Any, tmp: Path) -> tuple[DriftEstimator | None, str]:
    res = run_compare(cfg, tmp / "out", dataset=ds, track=False, quiet=True, plots=False)
    chosen = res.get("chosen")
    if chosen is None:
        return None, "nothing shipped"
    band = res["families"][chosen].get("band") or {}
    if band.get("status") != "ok":
        return None, f"no band: {band.get('reason')}"
    est = DriftEstimator.load(res["families"][chosen]["checkpoint"])
    return est, chosen


def _device(name: str, cfg: CompareConfig, ds: Any) -> dict[str, Any]:
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        est, what = _shipped(cfg, ds, Path(tmp))
        if est is None:
            print(f"{name}: {what}", flush=True)
            return {"device": name, "skipped": what}
        test = plan(cfg, ds).splits[-1].test
        axes = _judge(est, test)
    row = {"device": name, "chosen": what, "axes": axes, "seconds": time.perf_counter() - t0}
    n = sum(v["n"] for v in axes.values())
    c = sum(v["covered"] for v in axes.values())
    print(f"{name}: {what}, coverage {c}/{n}, width/oracle "
          f"{np.median([v['width'] / v['oracle'] for v in axes.values() if v['oracle'] > 0]):.2f}"
          f" ({row['seconds']:.0f} s)", flush=True)
    return row


def _edge(name: str, preset: str, config: str | None, runs: int, rate: float,
          seed: int) -> dict[str, Any]:
    """Trained on runs cut at T ≤ T_max − EDGE_CUT_C; judged on an extra run past the edge."""
    full = simulate(preset, runs=runs + 1, seed=seed, sample_rate_hz=rate)
    recs = list(full)
    tmax = max(float(np.nanmax(r.temperature_c)) for r in recs[:runs])
    cut = [r.select(np.asarray(r.temperature_c) <= tmax - EDGE_CUT_C, f"{r.run_id}-cut")
           for r in recs[:runs]]
    with tempfile.TemporaryDirectory() as tmp:
        try:
            est, what = _shipped(_config(config), Dataset(cut), Path(tmp))
        except Exception as err:   # a cut that leaves a split impossible: said, not hidden
            print(f"{name} edge: {type(err).__name__}: {err}", flush=True)
            return {"device": name, "skipped": str(err)}
        if est is None:
            return {"device": name, "skipped": what}
        axes = _judge(est, recs[-1])
    n = sum(v["n_past"] for v in axes.values())
    c = sum(v["covered_past"] for v in axes.values())
    print(f"{name} edge: {what}, past-edge coverage {c}/{n}", flush=True)
    return {"device": name, "chosen": what, "axes": axes}


def _pool(rows: list[dict[str, Any]]) -> dict[str, Any]:
    ok = [r for r in rows if "axes" in r and r["axes"]]
    n = sum(v["n"] for r in ok for v in r["axes"].values())
    c = sum(v["covered"] for r in ok for v in r["axes"].values())
    ratios = [v["width"] / v["oracle"] for r in ok for v in r["axes"].values()
              if v["oracle"] > 0]
    per_dev = [sum(v["covered"] for v in r["axes"].values()) /
               max(sum(v["n"] for v in r["axes"].values()), 1) for r in ok]
    ns = sum(v.get("n_stated", 0) for r in ok for v in r["axes"].values())
    cs = sum(v.get("covered_stated", 0) for r in ok for v in r["axes"].values())
    npast = sum(v["n_past"] for r in ok for v in r["axes"].values())
    cpast = sum(v["covered_past"] for r in ok for v in r["axes"].values())
    return {"devices": len(ok), "skipped": len(rows) - len(ok), "windows": n,
            "coverage": c / n if n else float("nan"),
            "stated_windows": ns, "coverage_stated": cs / ns if ns else float("nan"),
            "coverage_outside": (c - cs) / (n - ns) if n > ns else float("nan"),
            "coverage_device_min": min(per_dev) if per_dev else float("nan"),
            "width_over_oracle_median": float(np.median(ratios)) if ratios else float("nan"),
            "past_windows": npast, "past_coverage": cpast / npast if npast else float("nan")}


_BAND_ENTRY = """
float mcu_band_x, mcu_band_out[THERMONET_N_AXES];
void mcu_band(void);
void mcu_band(void)
{
    thermonet_band(mcu_band_x, mcu_band_out);
}
"""


def main_mcu() -> None:
    """The band's cost on the emulated Cortex-M4F (float path, -O2, strict warnings): Thumb
    instructions of one ``thermonet_band`` call against one ``thermonet_step`` of the same
    header (a consumer-imu device's shipped model, 6 axes), over a temperature sweep from
    10 °C below to 10 °C above the trained range; and the emulated band against Python."""
    import struct

    from thermonet.exporting.c_stream_render import stream_signature_has_proxies
    from thermonet.exporting.mcu import Emulator, cross_compile
    from thermonet.scoring.band import shipped_band

    ds = simulate("consumer-imu", runs=2, seed=0, sample_rate_hz=0.2)
    with tempfile.TemporaryDirectory() as tmp:
        est, what = _shipped(_config("configs/consumer-imu.yaml"), ds, Path(tmp))
        assert est is not None, what
        header = est.export(Path(tmp) / "m.h", "c").read_text()
        assert shipped_band({"band": {"status": "ok", **est.band_.to_json()}}) is not None
        end = "#endif /* THERMONET_MODEL_H */"
        head, _, tail = header.rpartition(end)
        text = head + _BAND_ENTRY + "\n" + end + tail
        build = cross_compile(text, "cortex-m4f", Path(tmp) / "m4",
                              has_proxies=stream_signature_has_proxies(est.model_))
        model = est.model_
        emu = Emulator(build, len(model.signals), len(model.outputs))
        b = next(iter(est.band_.axes.values()))
        temps = np.linspace(b.edges[0] - 10.0, b.edges[-1] + 10.0, 41)
        raw = np.zeros(len(model.outputs))
        steps, bands, worst = [], [], 0.0
        for i, temp in enumerate(temps):
            steps.append(emu.step(int(i * 1_000_000), float(temp), raw, None,
                                  count=True).instructions)
            emu.uc.mem_write(emu.sym["mcu_band_x"], struct.pack("<f", float(temp)))
            emu._call("mcu_band", count=True)
            bands.append(sum(emu._attribute().values()))
            got = np.array(struct.unpack(f"<{len(model.outputs)}f", bytes(emu.uc.mem_read(
                emu.sym["mcu_band_out"], 4 * len(model.outputs)))))
            want = est.band_.evaluate(np.array([np.float32(temp)], dtype=np.float64),
                                      est.outputs_)[0]
            worst = max(worst, float(np.max(np.abs(got - want) / np.maximum(want, 1e-30))))
    ratio = float(np.median(bands)) / float(np.median(steps))
    data = {"model": what, "axes": len(model.outputs), "step_median": float(np.median(steps)),
            "band_median": float(np.median(bands)), "band_max": int(max(bands)),
            "band_over_step": ratio, "worst_relative_error": worst,
            "code_bytes": build.code_bytes, "const_bytes": build.const_bytes}
    md = ("Residual-drift band on the emulated Cortex-M4F (float path, -O2; consumer-imu "
          f"device, {what}, {len(model.outputs)} axes, 41 temperatures across and 10 °C past "
          "the trained range)\n\n" + table(
              ["step instructions (median)", "band instructions (median / max)",
               "band / step", "band vs Python (worst relative)"],
              [[data["step_median"], f"{data['band_median']:.0f} / {data['band_max']}",
                ratio, worst]]))
    save("bench_uncertainty_mcu", data, md)


def main() -> None:
    t0 = time.perf_counter()
    results: dict[str, Any] = {"level": 0.9, "seeds": SEEDS, "presets": {}, "edge": {}}
    rows_md = []
    for preset, config, runs, rate in PRESETS:
        rows = [_device(f"{preset}#{s}", _config(config),
                        simulate(preset, runs=runs, seed=s, sample_rate_hz=rate))
                for s in range(SEEDS)]
        edge = [_edge(f"{preset}#{s}", preset, config, runs, rate, s) for s in range(EDGE)]
        results["presets"][preset] = {"summary": _pool(rows), "devices": rows}
        results["edge"][preset] = {"summary": _pool(edge), "devices": edge}
        s, e = results["presets"][preset]["summary"], results["edge"][preset]["summary"]
        rows_md.append([preset, s["devices"], s["windows"], s["coverage"],
                        s["coverage_device_min"], s["width_over_oracle_median"],
                        e["past_windows"], e["past_coverage"],
                        "ok" if 0.85 <= s["coverage"] <= 0.95 else "FAIL"])
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_selection import real_splits

    real = [_device(f"real:{name}", cfg, ds) for name, cfg, ds in real_splits()]
    results["real"] = {"summary": _pool(real), "devices": real}
    s = results["real"]["summary"]
    rows_md.append(["real recordings", s["devices"], s["windows"], s["coverage"],
                    s["coverage_device_min"], s["width_over_oracle_median"], "-", "-",
                    "ok" if 0.85 <= s["coverage"] <= 0.95 else "FAIL"])
    results["seconds"] = time.perf_counter() - t0
    md = (f"Nominal 90 % band, held-out coverage ({SEEDS} seeds per preset, "
          f"{results['seconds'] / 60:.0f} min, load: other engineers' jobs on 2 cores)\n\n"
          + table(["data", "devices", "windows", "coverage", "worst device", "width / oracle",
                   "windows ≤ 5 °C past edge", "coverage past edge", "85–95 %"], rows_md))
    save("bench_uncertainty", results, md)


def main_stress() -> None:
    """The band on new excursions: every split of the new-excursion stress bench
    (``bench_selection.stress_splits``: another cycle at another rate, heating-only then
    cooling, one cycle and two; default rule), the shipped model's nominal 90 % band checked
    on the held-out run as above."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_selection import _stress_config, stress_splits

    seeds = int(os.environ.get("BENCH_STRESS_SEEDS", "3"))
    rows = [_device(f"{name} #{seed}", _stress_config(name, ds, True), ds)
            for seed in range(seeds) for name, ds in stress_splits(seed)]
    s = _pool(rows)
    md = ("Nominal 90 % band on new excursions (`stress-imu`, "
          f"{seeds} units, every split of `bench_selection.py --stress`)\n\n"
          + table(["data", "devices", "windows", "coverage", "worst device", "width / oracle",
                   "windows where the band states it holds", "coverage there",
                   "coverage elsewhere"],
                  [["stress-imu", s["devices"], s["windows"], s["coverage"],
                    s["coverage_device_min"], s["width_over_oracle_median"],
                    s["stated_windows"], s["coverage_stated"], s["coverage_outside"]]])
          + "\n\nPer split (every axis's windows):\n\n" + table(
              ["split", "shipped", "windows", "coverage", "stated windows", "coverage there"],
              [[r["device"], r.get("chosen", r.get("skipped")),
                sum(v["n"] for v in r.get("axes", {}).values()),
                _share(r, "covered", "n"), sum(v["n_stated"] for v in r.get("axes", {}).values()),
                _share(r, "covered_stated", "n_stated")] for r in rows]))
    save("bench_uncertainty_stress", {"summary": s, "devices": rows}, md)


def _share(row: dict[str, Any], num: str, den: str) -> str:
    n = sum(v[den] for v in row.get("axes", {}).values())
    return f"{sum(v[num] for v in row.get('axes', {}).values()) / n:.1%}" if n else "-"


if __name__ == "__main__":
    args = sys.argv[1:]
    main_mcu() if args == ["mcu"] else main_stress() if args == ["stress"] else main()
