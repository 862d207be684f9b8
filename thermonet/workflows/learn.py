"""``thermonet learn LOG_OR_DIR... --out DIR``: each sensor's temperature drift from ordinary flights.

No chamber: every log of one vehicle is read for the drift it reveals — the estimator's bias
and the still-on-the-ground gyro (:mod:`thermonet.data.logs.bias`: what the log applied is
undone, invalid and unconverged samples rejected) — reduced to window means on the process
pool or Ray, cached per log (:mod:`thermonet.workflows.learn_data`: a stopped job resumes
without reading a log twice, a grown directory reads only its new logs) and folded at once
into a bounded set of windows per instance (memory bounded by its cap, not by the logs),
with the estimator's lag undone and divergences left out.  Then, per sensor instance (gyro,
accelerometer):

1. **The comparison** the chamber path runs (:func:`thermonet.workflows.compare.compare_result`,
   as ``calibrate`` does): the firmware's cubic as the baseline family, a line, the RBF with
   the cubic tail; **one flight = one run**, so the split holds out whole flights
   (``split: runs``: the last flight tests, the one before validates, the selection's folds
   are whole flights), with the per-axis choice and the residual-drift band.  Needs
   :data:`~thermonet.workflows.learn_fit.MIN_COMPARE_FLIGHTS` flights.
2. **The firmware form** (:func:`thermonet.workflows.firmware_fit.fit_firmware`: PX4's
   ``process_sensor_caldata.py`` cubic, ArduPilot's ``tempcal_IMU.py`` cubic) on every
   flight's kept windows, at the temperature as read; **checked on the last flight** fitted on
   the others: the 1 °C-binned drift peak-to-peak before and after.  An instance whose
   held-out drift it raises on some axis by more than verify's floor (5e-4 rad/s, 5e-3 m/s²:
   the flight's windows are estimates, not the truth) is left out of the parameter file.
3. **Files**: ``DIR/px4.params`` or ``DIR/ardupilot.parm`` (by the logs' autopilot, as
   ``calibrate`` writes them), ``DIR/instances/<name>/`` (the comparison, with
   ``model.onnx`` and ``model.h`` of its chosen model), ``DIR/results.json``,
   ``DIR/report.txt``, and the **coverage map**: per 1 °C bin the flights and minutes that
   support it, and the temperatures still missing in plain words.  The parameter file
   carries calibrate's header lines (``# board id:``, ArduPilot's ``# device ids:``) and
   only what was learned: a sensor no log reveals is named with why (``not_learned``), its
   ArduPilot ``INS_TCAL<n>_ACC*``/``GYR*`` not written, a PX4 kind with nothing learned (the
   barometer) left as the board has it, and within a PX4 kind a sensor left out or not
   learned keeps its slot: the one the last log's active ``TC_<k><s>_ID`` gives it is not
   written, and the fitted sensors take the slots the board has for them
   (:func:`~thermonet.workflows.learn_previous.px4_plans`; where no log records the slots,
   the kind is rewritten whole, and the console says the sensor then has no correction).
   The Vehicle-Id is the logs' ``MAV_SYS_ID`` (else 1, said in the file).

Run again on the same ``DIR``, the logs given are the flights learned
(:mod:`thermonet.workflows.learn_previous`: the flights learned before and not given are
named in a warning; logs of another vehicle are refused).

The target is the chamber path's: the gyro's drift as it is (its offset included), the
accelerometer's less its median (gravity and the stored offsets are not drift).  After
loading the file, redo the autopilot's ordinary gyro / accelerometer calibration, as after a
chamber calibration.

Bad input: a log that cannot be learned from (no bias topics, never converged, a clock that
jumps, unreadable), or of another vehicle (other device ids or board id), or of the other
autopilot than most logs, is one line naming it and what it lacks; the others are used and
counted.  No usable log at all: an error listing why.
"""

from __future__ import annotations

import json
import math
import shutil
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError, ThermonetError, counted
from ..core.executors import TaskFailure, run_tasks
from ..core.fileio import atomic_write_text, refuse_overwriting_inputs
from ..core.outdir import sha256_file
from ..core.version import __version__
from ..data.firmware import (
    PX4_LETTER,
    FirmwareFit,
    ardupilot_calibration_text,
    px4_calibration_text,
    px4_vehicle_id,
)
from ..data.logs import is_log
from .learn_data import (
    InstanceWindows,
    WindowFold,
    not_this_vehicle,
    vehicle_key,
    vehicle_of,
)
from .learn_fit import UNITS, instance_doc
from .learn_previous import board_slots, check_previous, not_learned, previous, px4_plans
from .learn_reduce import (
    READER_VERSION,
    cache_path,
    read_cache,
    reduce_for_cache,
    write_cache,
)
from .learn_report import format_learn_report
from .magnetometer import fit_correction

__all__ = ["learn", "format_learn_report", "find_logs"]

_OWNED = ("results.json", "report.txt", "px4.params", "ardupilot.parm", "instances", "cache")


def find_logs(paths: Sequence[str | Path]) -> list[Path]:
    """The logs named: files as given, directories searched (recursively) for ``.ulg`` /
    ``.bin``, sorted by name — the order is the flights' (the last is held out)."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out += sorted(q for q in p.rglob("*") if q.is_file() and is_log(q))
        elif p.is_file():
            out.append(p)
        else:
            raise InputError.at(p, "no such file or directory")
    if not out:
        raise InputError(f"{', '.join(map(str, paths))}: no .ulg or .bin log found")
    return out


def _check_out(out: Path, files: list[Path]) -> None:
    """Refuse an ``out`` that is a log, or a non-empty directory that is not learn's."""
    refuse_overwriting_inputs(out, files, owned=_OWNED)
    if out.exists() and not out.is_dir():
        raise InputError.at(out, "--out must be a directory")
    if out.is_dir() and any(out.iterdir()):
        doc = out / "results.json"
        ours = (out / "cache").is_dir() or (doc.is_file() and '"learn"' in doc.read_text()[:400])
        if not ours:
            raise InputError.at(out, "not empty and not a previous `thermonet learn` directory: "
                                "refusing to write into it")


def _read_all(files: list[Path], out: Path, executor: str, workers: int | None,
              ray_address: str | None, say: Callable[[str], None]
              ) -> tuple[list[dict[str, Any]], WindowFold]:
    """Every log reduced (the cache first, then the rest on the executor, each cached as it
    arrives) and folded at once into the windows the fit needs (:class:`WindowFold`: bounded,
    whatever the number of logs); per log, in the order given, only its summary: path,
    autopilot, device ids, board id and notes, or why it was refused."""
    digests = [sha256_file(f) for f in files]
    fold = WindowFold()
    logs: list[dict[str, Any] | None] = [None] * len(files)

    def take(k: int, doc: dict[str, Any]) -> None:
        doc["path"] = str(files[k])
        if "error" in doc:
            logs[k] = {"index": k, "path": doc["path"], "error": doc["error"]}
            return
        fold.add(k, doc)
        logs[k] = {"index": k, "sha256": digests[k], **{key: doc.get(key) for key in (
            "path", "autopilot", "sensors", "board_id", "notes")},
            # what px4.params is written against: the board's slots and its MAVLink system id
            "tc": {n: v for n, v in (doc.get("params") or {}).items()
                   if n.startswith("TC_") and n.endswith(("_ID", "_ENABLE"))
                   or n == "MAV_SYS_ID"}}

    first: dict[str, int] = {}
    for k, d in enumerate(digests):     # a log given twice is one flight, not two
        if d in first:
            logs[k] = {"index": k, "path": str(files[k]), "error": (
                f"the same log as {files[first[d]]} (identical contents): read once")}
            continue
        first[d] = k
        doc = read_cache(cache_path(out, d))
        if doc is not None:
            take(k, doc)
    todo = [k for k in range(len(files)) if logs[k] is None]
    twins = len(files) - len(first)
    say(f"{counted(len(files), 'log')}: {len(first) - len(todo)} read before (cache), "
        f"{len(todo)} to read"
        + (f", {twins} the same as another" if twins else ""))
    start, done = time.monotonic(), [0]

    def arrived(i: int, value: Any) -> None:
        k = todo[i]
        if isinstance(value, tuple):    # the reduced log and its cache text, as made
            doc, text = value
            write_cache(cache_path(out, digests[k]), text)
        else:                           # a worker that failed is not an answer: not cached
            doc = {"version": READER_VERSION, "path": str(files[k]),
                   "error": value.reason if isinstance(value, TaskFailure) else str(value)}
        take(k, doc)                    # folded: the log's windows are not held as such
        done[0] += 1
        rate = done[0] / max(time.monotonic() - start, 1e-9)
        say(f"[{done[0]}/{len(todo)}] {files[k].name}: "
            f"{'refused' if 'error' in doc else 'read'} ({rate:.1f} logs/s)")

    if todo:
        out.joinpath("cache").mkdir(parents=True, exist_ok=True)
        if executor == "serial":        # here, each log cached the moment it is read
            for i, k in enumerate(todo):
                arrived(i, _reduce_here(files[k]))
        else:                           # each result handed to arrived, none held
            run_tasks(reduce_for_cache, [str(files[k]) for k in todo],
                      executor=executor,  # type: ignore[arg-type]
                      workers=workers, ray_address=ray_address, on_done=arrived, keep=False)
    return [lg for lg in logs if lg is not None], fold


def _reduce_here(path: Path) -> tuple[dict[str, Any], str] | TaskFailure:
    """:func:`~thermonet.workflows.learn_reduce.reduce_for_cache` in this process; an
    unexpected error is the log's failure (not cached, read again next time), as a worker's."""
    try:
        return reduce_for_cache(str(path))
    except Exception as err:  # noqa: BLE001 - one log's bug must not sink the job
        return TaskFailure(f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}")


def _strip(line: str, path: Path) -> str:
    """A refusal without the path it already names (the report names it once)."""
    for p in (str(path), path.name):
        if line.startswith(p + ": "):
            return line[len(p) + 2:]
    return line


def _params_text(autopilot: str, docs: dict[str, dict[str, Any]], header: list[str],
                 logs: list[dict[str, Any]], sensors: dict[str, int]
                 ) -> tuple[str, str, dict[str, str]]:
    """The parameter file of the fitted instances (text, file name) and, PX4, what it does
    about each sensor not in it (:func:`~thermonet.workflows.learn_previous.px4_plans`: a
    sensor left out keeps the slot the board has for it; a kind not learned, the barometer
    always, is left as the board has it)."""
    fits: dict[str, list[FirmwareFit]] = {}
    imus: dict[int, dict[str, FirmwareFit]] = {}
    for name in sorted(docs, key=lambda n: (docs[n]["kind"], n)):
        d = docs[name]
        if d["status"] != "fitted":
            continue
        f = d["firmware"]
        fit = FirmwareFit(d["kind"], d["device_id"], f["t_ref"], f["t_min"], f["t_max"],
                          np.asarray(f["coef"]))
        fits.setdefault(d["kind"], []).append(fit)
        if name[-1].isdigit():
            imus.setdefault(int(name[-1]), {})[d["kind"]] = fit
    if autopilot != "px4":
        return ardupilot_calibration_text(imus, header=header), "ardupilot.parm", {}
    plans, words = px4_plans(fits, sensors, board_slots(logs))
    header = [*header, *(f"TC_{PX4_LETTER[kind]}{s}_*: not written (device {x}, not in this "
                         "file): the board keeps its own" for kind, plan in plans.items()
                         for s, x in enumerate(plan) if isinstance(x, int))]
    return px4_calibration_text(fits, header=header, fitted_kinds_only=True, plans=plans,
                                vehicle_id=px4_vehicle_id({"MAV_SYS_ID": _sys_id(logs)})
                                ), "px4.params", words


def _sys_id(logs: list[dict[str, Any]]) -> float | None:
    """The vehicle's ``MAV_SYS_ID`` as the last log recording it has it (None: none does)."""
    return next((lg["tc"]["MAV_SYS_ID"] for lg in reversed(logs)
                 if "MAV_SYS_ID" in (lg.get("tc") or {})), None)


def _changes(old: dict[str, Any] | None, new: dict[str, Any]) -> list[str]:
    """What changed since the directory's previous results, in words."""
    if not old:
        return []
    n_old, n_new = len(old.get("logs", [])), len(new["logs"])
    out = [f"flights: {n_old} -> {n_new}"] if n_old != n_new else []
    for name, d in new["instances"].items():
        o = (old.get("instances") or {}).get(name)
        if not o:
            out.append(f"{name}: new")
            continue
        was, now = o.get("supported_c"), d.get("supported_c")
        parts = [f"flights {o.get('flights')} -> {d.get('flights')}"] \
            if o.get("flights") != d.get("flights") else []
        if was != now:
            parts.append(f"supported {_span(was)} -> {_span(now)}")
        if o.get("firmware") and d.get("firmware"):
            grid = np.linspace(d["firmware"]["t_min"], d["firmware"]["t_max"], 50)
            fo, fn = (FirmwareFit(d["kind"], 0, x["t_ref"], x["t_min"], x["t_max"],
                                  np.asarray(x["coef"])) for x in (o["firmware"], d["firmware"]))
            delta = float(np.abs(fit_correction(fn, grid) - fit_correction(fo, grid)).max())
            if delta > 0:
                parts.append(f"correction moved by up to {delta:.3g} {UNITS[d['kind']]}")
        if parts:
            out.append(f"{name}: " + ", ".join(parts))
    return out or ["nothing (the same logs as before)"]


def _span(s: list[int] | None) -> str:
    return f"{s[0]}..{s[1]} °C" if s else "no bin"


def learn(paths: Sequence[str | Path], out_dir: str | Path, *, executor: str = "process",
          workers: int | None = None, ray_address: str | None = None, compare: bool = True,
          export: bool = True, say: Callable[[str], None] | None = None,
          overwrite: bool = False) -> dict[str, Any]:
    """Learn every sensor instance's drift from the logs; write ``out_dir``; return results.

    ``paths``: logs and directories of logs (:func:`find_logs`), one vehicle.  ``executor``
    / ``workers`` / ``ray_address``: where the logs are read (as ``fleet``:
    :func:`thermonet.core.executors.run_tasks`).  ``compare`` / ``export``: run the
    comparison per instance, and export its chosen model as ONNX and C.  ``say`` receives
    the progress lines (None: silent).

    Run again on the same ``out_dir``: **the logs given are the flights learned** (the cache
    only spares reading a log again), so give the earlier logs with the new ones; a flight
    learned before and not given is left out, with a warning naming it
    (:mod:`thermonet.workflows.learn_previous`).  Logs of another vehicle than the one
    ``out_dir`` learned before are refused (InputError) unless ``overwrite``.
    """
    say = say or (lambda _line: None)
    files = find_logs(paths)
    out = Path(out_dir)
    _check_out(out, files)
    fresh = not out.exists()
    try:
        read, fold = _read_all(files, out, executor, workers, ray_address, say)
    except BaseException:
        # stopped: the logs read so far stay cached (the next run resumes from them); a new
        # directory that holds none is not left behind
        if fresh and not any((out / "cache").glob("*.json")):
            shutil.rmtree(out, ignore_errors=True)
        raise
    refused = [(lg["path"], _strip(lg["error"], Path(lg["path"]))) for lg in read
               if "error" in lg]
    logs = [lg for lg in read if "error" not in lg]
    if logs:
        ap, sensors, board = vehicle_of(logs)
        kept = []
        for lg in logs:
            why = not_this_vehicle(lg, ap, sensors, board)
            if why:
                refused.append((lg["path"], why))
            else:
                kept.append(lg)
        logs = kept
    if not logs:
        if fresh:                       # nothing learned: no directory left behind
            shutil.rmtree(out, ignore_errors=True)
        raise ThermonetError("no log to learn from: " + "; ".join(
            f"{Path(p).name}: {w}" for p, w in refused))
    old = None if overwrite else previous(out)
    warnings = check_previous(old, out, ap, sensors, board, logs)
    for w in warnings:
        say(f"warning: {w}")
    instances = fold.instances({vehicle_key(lg) for lg in logs}, [lg["index"] for lg in logs],
                               [lg["path"] for lg in logs], sensors)
    stage = out / ".staging"
    shutil.rmtree(stage, ignore_errors=True)
    stage.mkdir(parents=True)
    try:
        doc = _learn_into(logs, instances, refused, (ap, sensors, board), stage, compare,
                          export, say)
        doc["warnings"] = warnings
        doc["changes"] = _changes(old, doc)
        atomic_write_text(stage / "report.txt", format_learn_report(doc))
        atomic_write_text(stage / "results.json", json.dumps(doc, indent=2, default=_json))
        _install(stage, out)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return doc


def _install(stage: Path, out: Path) -> None:
    """Move the staged outputs into ``out``, replacing the previous ones (results.json last,
    so a directory with results.json is complete)."""
    for name in ("instances", "px4.params", "ardupilot.parm", "report.txt", "results.json"):
        target = out / name
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()
        if (stage / name).exists():
            (stage / name).rename(target)


def _learn_into(logs: list[dict[str, Any]], instances: Iterable[InstanceWindows],
                refused: list[tuple[str, str]], vehicle: tuple[str, dict[str, int], str | None],
                stage: Path, do_compare: bool, do_export: bool, say: Callable[[str], None]
                ) -> dict[str, Any]:
    """Every instance learned into ``stage`` (one at a time: each one's windows dropped once
    learned); the results document (without its warnings and changes).  ``vehicle``:
    autopilot, device ids by instance, board id (:func:`vehicle_of`)."""
    autopilot, sensors, board = vehicle
    docs: dict[str, dict[str, Any]] = {}
    for inst in sorted(instances, key=lambda i: i.name):    # acc0, acc1, gyro0, gyro1, …
        say(f"{inst.name}: learning from {counted(int(np.unique(inst.flight).size), 'flight')}")
        docs[inst.name] = instance_doc(inst, autopilot, stage, do_compare, do_export)
    header = [f"thermonet {__version__}: drift learned from {counted(len(logs), 'flight log')} "
              "(estimator biases and still-gyro windows; no chamber)",
              "redo the autopilot's gyro and accelerometer calibration after loading it"]
    header += [f"board id: {board}"] if board else []     # verify matches by it, as calibrate's
    params: str | None = None
    words: dict[str, str] = {}
    if any(d["status"] == "fitted" for d in docs.values()):
        text, fname, words = _params_text(autopilot, docs, header, logs, sensors)
        atomic_write_text(stage / fname, text)
        params = fname
    for name, d in docs.items():      # left out: what the file does about its slot
        if d["status"] != "fitted" and name in words:
            d["parameter_file"] = words[name]
    return {"kind": "learn", "schema": 1, "thermonet_version": __version__,
            "autopilot": autopilot, "logs": [lg["path"] for lg in logs],
            "logs_sha256": [lg["sha256"] for lg in logs],
            "vehicle": {"autopilot": autopilot, "sensors": sensors, "board_id": board},
            "mav_sys_id": _sys_id(logs),
            "refused": [{"log": p, "reason": w} for p, w in refused],
            "params_file": params, "instances": docs,
            "not_learned": not_learned(sensors, docs, autopilot, words),
            "log_notes": sorted({n for lg in logs for n in lg.get("notes", [])})}


def _json(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    raise TypeError(type(obj).__name__)
