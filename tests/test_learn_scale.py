"""``thermonet learn`` over many logs: what the job holds is bounded by a cap on the windows
(:class:`thermonet.workflows.learn_data.WindowFold`), not by the logs, and the logs read on
the process pool or a real local Ray give the serial result.

The expectations are independent of the fold's code: merging windows in pairs keeps each
flight's seconds and its seconds-weighted mean time, temperature and drift (the sums the fit
rests on), the number of windows at a level is each series's count halved and rounded up that
many times, and the fold of the same logs in another order is the same fold."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from thermonet.core.executors import run_tasks
from thermonet.data.firmware import FirmwareFit
from thermonet.data.logs.flight_writers import write_flight
from thermonet.sim.flights import EKF_TAU_S, simulate_flights
from thermonet.workflows import learn_data
from thermonet.workflows.learn import learn
from thermonet.workflows.learn_data import WindowFold, gather, vehicle_key
from thermonet.workflows.learn_fit import binned_pp
from thermonet.workflows.learn_reduce import LAG_GRID_S, WINDOW_S, reduce_log
from thermonet.workflows.magnetometer import fit_correction
from thermonet.workflows.verify import Limits

#: bytes of one window the fold holds: flight, series (int64), time, temperature, seconds
#: (float64), still (bool), the drift for every lag (3 float32 each)
ROW_BYTES = 8 + 8 + 3 * 8 + 1 + 3 * 4 * len(LAG_GRID_S)


@pytest.fixture(scope="module")
def docs(tmp_path_factory) -> list[dict]:
    """Six flights of one vehicle, each reduced by the reader as a worker returns it."""
    root = tmp_path_factory.mktemp("logs")
    out = []
    for k, f in enumerate(simulate_flights(6, seed=3)):
        out.append(reduce_log(str(write_flight(f.log, f.biases, root / f"f{k}.ulg"))))
    return out


def _fold(docs: list[dict], cap: int | None, order: list[int]) -> dict[str, object]:
    fold = WindowFold(cap)
    for k in order:
        fold.add(k, docs[k])
    insts = fold.instances({vehicle_key(d) for d in docs}, list(range(len(docs))),
                           [d["path"] for d in docs], docs[0]["sensors"])
    return {i.name: i for i in insts}


def test_a_capped_fold_keeps_each_flights_seconds_and_mean_drift(docs):
    """Capped at 300 windows an instance: the level is the first at which every series's
    windows, halved and rounded up that many times, number 300 or fewer; each flight's and
    source's seconds, and its seconds-weighted mean time, temperature and drift for every lag,
    are those of the reader's windows (float32 drifts: to 1e-6 of the drift's range)."""
    full = {i.name: i for i in gather(docs)}
    capped = _fold(docs, 300, list(range(len(docs))))
    assert set(capped) == set(full)
    for name, got in capped.items():
        ref = full[name]
        groups = sorted({(int(f), bool(s)) for f, s in zip(ref.flight, ref.still, strict=True)})
        sizes = [int(((ref.flight == f) & (ref.still == s)).sum()) for f, s in groups]
        level = next(lv for lv in range(20) if sum(math.ceil(n / 2 ** lv) for n in sizes) <= 300)
        assert level >= 1, name                  # the cap is reached: windows were merged
        assert got.window_s == WINDOW_S * 2 ** level
        assert got.time_s.size == sum(math.ceil(n / 2 ** level) for n in sizes) <= 300
        for f, s in groups:
            a = (ref.flight == f) & (ref.still == s)
            b = (got.flight == f) & (got.still == s)
            wa, wb = ref.weight[a], got.weight[b]
            assert math.isclose(wb.sum(), wa.sum(), rel_tol=1e-12)
            for x, y in ((ref.time_s, got.time_s), (ref.temp, got.temp)):
                assert math.isclose((y[b] * wb).sum() / wb.sum(), (x[a] * wa).sum() / wa.sum(),
                                    rel_tol=1e-12, abs_tol=1e-9)
            for lag, d in ref.drifts.items():
                tol = 1e-6 * max(float(np.ptp(d, axis=0).max()), 1e-9)
                np.testing.assert_allclose(
                    (got.drifts[lag][b] * wb[:, None]).sum(0) / wb.sum(),
                    (d[a] * wa[:, None]).sum(0) / wa.sum(), rtol=0, atol=tol)


def test_below_the_cap_the_windows_are_the_readers(docs):
    """Uncapped, every instance's windows are each series's windows (an estimator window near
    a still one left out), flight after flight: seconds equal to the reader's per series."""
    full = {i.name: i for i in gather(docs)}
    for name, inst in full.items():
        assert inst.window_s == WINDOW_S
        kind = "gyro" if name.startswith("gyro") else "acc"
        dev = inst.device_id
        for k, d in enumerate(docs):
            for s in d["series"]:
                if s["kind"] == kind and s["device_id"] == dev and s["source"] == "still":
                    sel = (inst.flight == k) & inst.still
                    np.testing.assert_array_equal(inst.time_s[sel], s["t"])
                    np.testing.assert_array_equal(inst.weight[sel], s["weight"])
        assert np.all(np.diff(inst.flight) >= 0)


def test_the_fold_is_the_same_whatever_order_the_logs_arrive_in(docs):
    """The pool hands logs over in any order: folded in order, reversed and shuffled, with a
    cap the merges happen at other moments, yet every array is the same, bit for bit."""
    n = len(docs)
    ref = _fold(docs, 300, list(range(n)))
    for order in (list(reversed(range(n))), [3, 0, 5, 1, 4, 2]):
        got = _fold(docs, 300, order)
        for name, a in ref.items():
            b = got[name]
            assert a.window_s == b.window_s
            for x, y in ((a.flight, b.flight), (a.time_s, b.time_s), (a.temp, b.temp),
                         (a.weight, b.weight), (a.still, b.still)):
                np.testing.assert_array_equal(x, y)
            for lag in a.drifts:
                np.testing.assert_array_equal(a.drifts[lag], b.drifts[lag])


def test_what_the_fold_holds_is_bounded_by_the_cap(docs):
    """Thirty logs folded (the six again and again): capped at 200 windows an instance, what
    is held never passes 200 windows × its bytes per instance; uncapped it grows with every
    log (the same fold without the cap, as the job held before)."""
    capped, free = WindowFold(200), WindowFold(10 ** 9)
    instances = len(gather(docs[:1]))
    sizes = []
    for k in range(30):
        capped.add(k, docs[k % len(docs)])
        free.add(k, docs[k % len(docs)])
        assert capped.nbytes <= 200 * ROW_BYTES * instances
        sizes.append(free.nbytes)
    assert sizes[-1] > 4 * 200 * ROW_BYTES * instances
    assert all(b > a for a, b in zip(sizes, sizes[1:], strict=False))


def test_results_handed_over_and_not_held():
    """``run_tasks(..., keep=False)`` on the process pool: each result reaches ``on_done``,
    none is returned."""
    got: dict[int, int] = {}
    out = run_tasks(math.factorial, [3, 4, 5, 6], workers=2, on_done=got.__setitem__,
                    keep=False)
    assert out == [None] * 4 and got == {0: 6, 1: 24, 2: 120, 3: 720}


def test_merged_windows_still_learn_the_drift(tmp_path, monkeypatch):
    """Capped so that every flight's windows are merged three times (80-s windows, as 1,000
    half-hour logs are): learned from 19 flights (on 2 pool workers), the 20th's binned true
    drift is at most 0.3× raw per axis above verify's floor, and the lag is found near the
    estimator's — what the reader's 10-s windows give (tests/test_learn.py)."""
    monkeypatch.setattr(learn_data, "MAX_WINDOWS", 450)
    flights = simulate_flights(20, seed=7)
    (tmp_path / "logs").mkdir()
    paths = [write_flight(f.log, f.biases, tmp_path / "logs" / f"f{k:02d}.ulg")
             for k, f in enumerate(flights[:-1])]
    doc = learn(paths, tmp_path / "out", workers=2, compare=False)
    held = flights[-1]
    for inst in held.log.instances:
        if inst.name not in ("gyro0", "gyro1", "acc0", "acc1"):
            continue
        d = doc["instances"][inst.name]
        kind = inst.kind
        assert d["window_s"] == 80.0 and d["windows"] <= 450, inst.name
        assert 0.7 * EKF_TAU_S[kind] <= d["lag_s"] <= 1.5 * EKF_TAU_S[kind], inst.name
        f = d["firmware"]
        fit = FirmwareFit(kind, d["device_id"], f["t_ref"], f["t_min"], f["t_max"],
                          np.asarray(f["coef"]))
        truth = held.truth[inst.name]
        left = truth - fit_correction(fit, inst.temperature_c)
        for raw, got in zip(binned_pp(inst.temperature_c, truth),
                            binned_pp(inst.temperature_c, left), strict=True):
            if raw > Limits().floor[kind]:
                assert got <= 0.3 * raw, (inst.name, raw, got)


def _flights(tmp_path: Path, n: int) -> list[Path]:
    (tmp_path / "logs").mkdir()
    return [write_flight(f.log, f.biases, tmp_path / "logs" / f"f{k}.ulg")
            for k, f in enumerate(simulate_flights(n, seed=11))]


def test_the_process_pool_gives_the_serial_result(tmp_path):
    """Four logs read on 2 pool workers (results handed over as they come, in any order):
    the results document is the serial one's."""
    paths = _flights(tmp_path, 4)
    serial = learn(paths, tmp_path / "serial", executor="serial", compare=False)
    pooled = learn(paths, tmp_path / "pool", executor="process", workers=2, compare=False)
    assert pooled == serial


@pytest.mark.slow
def test_a_real_local_ray_gives_the_serial_result(tmp_path):
    """Four logs read on a real local Ray (2 CPUs, started and stopped by the job): the
    results document is the serial one's."""
    paths = _flights(tmp_path, 4)
    serial = learn(paths, tmp_path / "serial", executor="serial", compare=False)
    rayed = learn(paths, tmp_path / "ray", executor="ray", workers=2, compare=False)
    assert rayed == serial
