"""What ``thermonet learn`` (:mod:`thermonet.workflows.learn`) weighs besides the logs: the
directory's previous results and the vehicle's sensors it could not learn.

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
from ..data.logs.info import autopilot_article

__all__ = ["previous", "check_previous", "not_learned"]


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


def not_learned(sensors: dict[str, int], docs: dict[str, dict[str, Any]], autopilot: str
                ) -> list[dict[str, Any]]:
    """The vehicle's gyros and accelerometers no log revealed a drift of: per sensor its
    name, device id, why, and what the parameter file does about it."""
    fitted = {n for n, d in docs.items() if d.get("status") == "fitted"}
    kinds = {n.rstrip("0123456789") for n in fitted}
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
            letter = "A" if kind == "acc" else "G"
            then = (f"px4.params clears the other TC_{letter} slots: loaded, it has no thermal "
                    "correction" if kind in kinds else
                    f"TC_{letter}* are not written: the board keeps its own")
        out.append({"name": name, "device_id": dev, "reason": why, "parameter_file": then})
    return out
