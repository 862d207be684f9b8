"""One board's logs as ``thermonet calibrate`` (:mod:`thermonet.workflows.calibrate`) takes
them: several logs of the board joined into one (:func:`merge_logs`, refused where they are
not of one board), or one log cut into its training and held-out time blocks
(:func:`held_out_blocks`, :data:`HELD_OUT_BLOCKS`, :data:`HELD_OUT_EVERY`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core.errors import InputError
from ..core.recording import GAP_FACTOR
from ..data.logs import FlightLog, SensorInstance
from ..data.logs.info import autopilot_article
from .firmware_fit import FIT_KINDS, MIN_SAMPLES

__all__ = ["merge_logs", "held_out_blocks", "HELD_OUT_BLOCKS", "HELD_OUT_EVERY", "HELD_OUT_COUNT",
           "MIN_GRADED_LOG_SAMPLES"]


def _board_ids(log: FlightLog) -> list[tuple[str, int]]:
    return sorted((i.name, i.device_id) for i in log.instances if i.kind in FIT_KINDS)


def _join_gap(t: np.ndarray) -> float:
    """Seconds between one log's last sample and the next log's first, joined: a gap (over
    :data:`~thermonet.core.recording.GAP_FACTOR` median steps) at which the dynamic inputs
    (a lag, a rate) restart, as after any pause, instead of running through the jump from
    one log's end to the next one's start; at least 1 s."""
    step = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    return max(1.0, 2.0 * GAP_FACTOR * step)


def merge_logs(logs: Sequence[FlightLog]) -> FlightLog:
    """Several logs of one board as one: the instances joined in the order given (time
    restarted after a gap, :func:`_join_gap`, past the previous log's end; each log's first
    sample recorded in ``starts``).  Refuses logs of another autopilot or
    board (different instances or device ids; or, where both logs hold the board's own id,
    ``FlightLog.board_id``, different ones), naming both logs' ids."""
    first = logs[0]
    for log in logs[1:]:
        if log.autopilot != first.autopilot:
            raise InputError(f"{log.path}: {autopilot_article(log.autopilot)} log; "
                             f"{first.path} is {autopilot_article(first.autopilot)} "
                             "log (one board, one autopilot)")
        if _board_ids(log) != _board_ids(first):
            def ids(lg: FlightLog) -> str:
                return ", ".join(f"{n} {d}" for n, d in _board_ids(lg))
            raise InputError(f"{log.path}: not the same board as {first.path} (device ids "
                             f"{ids(log)} vs {ids(first)})")
        if log.board_id and first.board_id and log.board_id != first.board_id:
            raise InputError(f"{log.path}: not the same board as {first.path} (board id "
                             f"{log.board_id!r} vs {first.board_id!r}: two boards of one model, "
                             "with the same sensors' device ids); calibrate each board's logs "
                             "on their own")
    if len(logs) == 1:
        return first
    instances = []
    for inst in first.instances:
        parts = [next(i for i in lg.instances if i.name == inst.name
                      and i.device_id == inst.device_id) for lg in logs]
        times, t0 = [], 0.0
        for part in parts:
            t = np.asarray(part.time_s, dtype=np.float64)
            times.append(t - (t[0] if t.size else 0.0) + t0)
            t0 = (times[-1][-1] + _join_gap(t)) if t.size else t0
        temps = None if any(p.temperature_c is None for p in parts) else np.concatenate(
            [np.asarray(p.temperature_c) for p in parts])
        truth = None if any(p.truth is None for p in parts) else np.concatenate(
            [np.asarray(p.truth) for p in parts])
        notes = [f"{lg.path.name}: {n}" for lg, p in zip(logs, parts, strict=True)
                 for n in p.notes]
        untrusted = "; ".join(p.untrusted for p in parts if p.untrusted) or None
        unlagged = None if any(p.unlagged_c is None for p in parts) else np.concatenate(
            [np.asarray(p.unlagged_c) for p in parts])
        sizes = np.cumsum([p.n_samples for p in parts])[:-1]
        instances.append(SensorInstance(inst.kind, inst.instance, inst.device_id,
                                        np.concatenate(times), temps,
                                        np.concatenate([p.values for p in parts]),
                                        notes=notes, truth=truth,
                                        damaged=sum(p.damaged for p in parts),
                                        untrusted=untrusted, thermometer=inst.thermometer,
                                        lag_s=inst.lag_s, unlagged_c=unlagged,
                                        starts=tuple(int(k) for k in sizes)))
    return FlightLog(path=first.path, autopilot=first.autopilot, instances=instances,
                     params=dict(logs[-1].params),
                     notes=[f"{lg.path.name}: {n}" for lg in logs for n in lg.notes],
                     damage=[f"{lg.path.name}: {d}" for lg in logs for d in lg.damage],
                     board_id=next((lg.board_id for lg in logs if lg.board_id), None))


#: One log: its samples in this many equal time blocks, every :data:`HELD_OUT_EVERY`-th
#: held out (blocks 3, 7, 11, 15, 19 of 20 counted from 1: a quarter of the log, never its
#: first or last block, so the fit is not extrapolated to them).
HELD_OUT_BLOCKS = 20
HELD_OUT_EVERY = 4
#: How many of the :data:`HELD_OUT_BLOCKS` are held out (5: a quarter of the log).
HELD_OUT_COUNT = sum(1 for b in range(HELD_OUT_BLOCKS) if b % HELD_OUT_EVERY == HELD_OUT_EVERY // 2)
#: About the fewest samples (per instance, logged evenly in time) one log needs for its
#: held-out blocks, a quarter of it, to reach the
#: :data:`~thermonet.workflows.firmware_fit.MIN_SAMPLES` verify's test judges: 800 (the
#: blocks' edges let 791 evenly logged samples through, 790 not): a log under it is not graded,
#: and calibrate says not to load its file.
MIN_GRADED_LOG_SAMPLES = -(-MIN_SAMPLES * HELD_OUT_BLOCKS // HELD_OUT_COUNT)


def held_out_blocks(log: FlightLog) -> tuple[FlightLog, FlightLog]:
    """One log as (training, held-out): per instance, the samples of the held-out time
    blocks (:data:`HELD_OUT_BLOCKS`, :data:`HELD_OUT_EVERY`) and the rest."""
    train: list[SensorInstance] = []
    test: list[SensorInstance] = []
    for inst in log.instances:
        t = np.asarray(inst.time_s, dtype=np.float64)
        span = float(t[-1] - t[0]) if t.size else 0.0
        block = np.zeros(t.size, dtype=np.int64) if span <= 0 else np.minimum(
            ((t - t[0]) / span * HELD_OUT_BLOCKS).astype(np.int64), HELD_OUT_BLOCKS - 1)
        held = block % HELD_OUT_EVERY == HELD_OUT_EVERY // 2
        for part, keep in ((train, ~held), (test, held)):
            part.append(SensorInstance(
                inst.kind, inst.instance, inst.device_id, t[keep],
                None if inst.temperature_c is None else np.asarray(inst.temperature_c)[keep],
                np.asarray(inst.values)[keep], notes=list(inst.notes),
                truth=None if inst.truth is None else np.asarray(inst.truth)[keep],
                damaged=inst.damaged, untrusted=inst.untrusted, thermometer=inst.thermometer,
                lag_s=inst.lag_s,
                unlagged_c=None if inst.unlagged_c is None else inst.unlagged_c[keep]))
    return (FlightLog(log.path, log.autopilot, train, dict(log.params), board_id=log.board_id),
            FlightLog(log.path, log.autopilot, test, dict(log.params), board_id=log.board_id))
