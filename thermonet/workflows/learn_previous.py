"""What ``thermonet learn`` (:mod:`thermonet.workflows.learn`) weighs besides the logs: the
directory's previous results, the vehicle's sensors it could not learn, and the board's PX4
slots (:func:`board_slots`, :func:`px4_plans`: a sensor not in the file keeps its slot).

**The logs given are the flights learned.**  The directory's cache only spares reading a log
again; a flight learned before that is not among the logs given is left out of the new fit
(said in a warning naming it and the command that keeps it: give the earlier logs again with
the new ones).  So a bad flight is dropped by leaving it out, and nothing is learned from a
log the run was not given.  A run whose logs are of another vehicle than the one the
directory learned before (another autopilot, other device ids, another board id) is refused
in one line: its results would silently replace the other vehicle's parameter file
(``--overwrite``: learn this vehicle there all the same).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..core.errors import InputError, counted
from ..data.firmware import FirmwareFit, Px4Slot, px4_active_slots, px4_slot_plan
from ..data.logs.info import autopilot_article

__all__ = ["previous", "check_previous", "not_learned", "board_slots", "px4_plans"]


def previous(out: Path) -> dict[str, Any] | None:
    """The directory's previous results (``results.json`` of ``learn``), else None."""
    try:
        doc = json.loads((out / "results.json").read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("kind") == "learn" else None


def _other_vehicle(old: dict[str, Any], ap: str, sensors: dict[str, int],
                   board: str | None) -> str | None:
    """How the vehicle learned before differs from these logs' (one phrase), or None."""
    was: dict[str, Any] = old["vehicle"] if isinstance(old.get("vehicle"), dict) else {}
    old_ap = was.get("autopilot") or old.get("autopilot")
    if old_ap and old_ap != ap:
        return (f"{autopilot_article(str(old_ap))} vehicle; these are "
                f"{autopilot_article(ap)} vehicle's logs")
    ids = was.get("sensors")
    if not isinstance(ids, dict):      # results of an older thermonet: the instances learned
        ids = {n: d.get("device_id") for n, d in (old.get("instances") or {}).items()
               if isinstance(d, dict)}
        same = all(sensors.get(n) == dev for n, dev in ids.items())
    else:
        same = ids == sensors
    if not same:
        return ("of sensors with other device ids ("
                + ", ".join(f"{k} {v}" for k, v in sorted(ids.items()))
                + "; these logs': " + ", ".join(f"{k} {v}" for k, v in sorted(sensors.items()))
                + ")")
    old_board = was.get("board_id")
    if old_board and board and old_board != board:
        return f"of board {old_board}; these logs are board {board}"
    return None


def check_previous(old: dict[str, Any] | None, out: Path, ap: str, sensors: dict[str, int],
                   board: str | None, logs: list[dict[str, Any]]) -> list[str]:
    """Refuse (:class:`InputError`, one line) logs of another vehicle than the one ``out``
    learned before; return the warnings: the flights learned before that are not among the
    logs given (left out of this fit)."""
    if not old:
        return []
    why = _other_vehicle(old, ap, sensors, board)
    if why:
        raise InputError(f"{out}: learned before from another vehicle ({why}): its parameter "
                         f"file would be replaced by this one's — give these logs another "
                         "--out, or pass --overwrite to learn this vehicle there")
    names = [str(n) for n in old.get("logs") or []]
    sums = old.get("logs_sha256")
    if isinstance(sums, list) and len(sums) == len(names):
        now = {lg.get("sha256") for lg in logs}
        dropped = [n for n, h in zip(names, sums, strict=True) if h not in now]
    else:                               # results of an older thermonet: by path
        now = {str(lg["path"]) for lg in logs}
        dropped = [n for n in names if n not in now]
    if not dropped:
        return []
    shown = ", ".join(Path(n).name for n in dropped[:4]) + (", …" if len(dropped) > 4 else "")
    where = " ".join(sorted({str(Path(n).parent) for n in dropped}))
    return [f"{counted(len(dropped), 'flight')} learned before (of {len(names)}) "
            f"{'is' if len(dropped) == 1 else 'are'} not among the logs given and left out of "
            f"this fit: {shown} — learn fits the logs given (the cache only spares reading "
            f"them again): to keep them, give them with the new ones (thermonet learn {where} "
            f"NEW_LOGS --out {out})"]


#: The PX4 kinds ``learn`` writes, with their parameter letter.
_PX4_KINDS = {"gyro": "G", "acc": "A"}


def board_slots(logs: list[dict[str, Any]]) -> dict[str, list[int] | None]:
    """Per kind, the board's active PX4 slots (:func:`~thermonet.data.firmware.px4_active_slots`)
    as the last log that records them has them, or None where no log records the kind's
    ``TC_<k>*`` (where the board keeps a sensor's calibration is then unknown).  ``logs``: the
    logs' summaries in the flights' order, each with the ``tc`` parameters its log recorded."""
    out: dict[str, list[int] | None] = {}
    for kind in _PX4_KINDS:
        out[kind] = next((s for lg in reversed(logs)
                          for s in [px4_active_slots(lg.get("tc") or {}, kind)]
                          if s is not None), None)
    return out


def px4_plans(fits: dict[str, list[FirmwareFit]], sensors: dict[str, int],
              board: dict[str, list[int] | None]
              ) -> tuple[dict[str, list[Px4Slot]], dict[str, str]]:
    """Where each fit goes in ``px4.params`` (:func:`~thermonet.data.firmware.px4_slot_plan`)
    and, per sensor of the vehicle not in the file, what the file does about it: a kind with
    nothing fitted is not written; within a written kind, a sensor left out keeps its slot
    where the board's active slots (``board``, :func:`board_slots`) hold it — that slot is not
    written — and the fits take the slots the board has for them."""
    plans: dict[str, list[Px4Slot]] = {}
    words: dict[str, str] = {}
    for kind, t in _PX4_KINDS.items():
        done = {f.device_id for f in fits.get(kind, [])}
        out = {n: d for n, d in sensors.items() if n.rstrip("0123456789") == kind
               and d not in done}
        if not fits.get(kind):
            words.update({n: f"TC_{t}* are not written: the board keeps its own" for n in out})
            continue
        plans[kind] = px4_slot_plan(fits[kind], board[kind], set(out.values()))
        for name, dev in out.items():
            slot = next((s for s, x in enumerate(plans[kind]) if x == dev
                         and isinstance(x, int)), None)
            if slot is not None:
                words[name] = (f"TC_{t}{slot}_* are not written: the board keeps its own (its "
                               f"slot, TC_{t}{slot}_ID {dev} in the last log)")
            elif board[kind] is None:
                words[name] = (f"px4.params rewrites the TC_{t} slots whole (no log records "
                               f"TC_{t}*, so where the board keeps it is unknown): loaded, it "
                               "has no thermal correction")
            else:
                words[name] = (f"no active TC_{t} slot of the board holds it (the last log's "
                               f"TC_{t}_ENABLE / TC_{t}*_ID): it has no thermal correction, "
                               "before loading or after")
    return plans, words


def not_learned(sensors: dict[str, int], docs: dict[str, dict[str, Any]], autopilot: str,
                px4_words: dict[str, str] | None = None) -> list[dict[str, Any]]:
    """The vehicle's gyros and accelerometers no log revealed a drift of: per sensor its
    name, device id, why, and what the parameter file does about it (PX4: ``px4_words``, as
    :func:`px4_plans` says it)."""
    fitted = {n for n, d in docs.items() if d.get("status") == "fitted"}
    imus = {n[-1] for n in fitted}
    mask = "EK3_IMU_MASK" if autopilot == "ardupilot" else "EKF2_MULTI_IMU"
    out = []
    for name, dev in sorted(sensors.items()):
        if name in docs:
            continue
        kind = "acc" if name.startswith("acc") else "gyro"
        why = (f"no log has an estimator bias for it (the estimator runs on other IMUs: "
               f"{mask})" + (", and an accelerometer at rest shows gravity, not its bias"
                             if kind == "acc" else ", and it was never still for 10 s"))
        if autopilot == "ardupilot":
            group = f"INS_TCAL{int(name[-1]) + 1}" if name[-1].isdigit() else "INS_TCAL"
            then = (f"{group}_{'ACC' if kind == 'acc' else 'GYR'}* are not written: the board "
                    "keeps its own" if name[-1] in imus else f"no {group}_* in the file")
        else:
            then = (px4_words or {}).get(name) or (
                f"TC_{_PX4_KINDS[kind]}* are not written: the board keeps its own")
        out.append({"name": name, "device_id": dev, "reason": why, "parameter_file": then})
    return out
