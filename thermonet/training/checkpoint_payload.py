"""A loaded checkpoint's payload checked before anything is built from it
(:func:`thermonet.training.checkpoint.load_checkpoint`): a checkpoint is data from a file, not
code, and its strings reach generated C source and ONNX metadata, so every name and value is
checked with the rule it was created under (:mod:`thermonet.core.names`) — the family, inputs,
signals and outputs, the spec's references, the metadata, the test metrics and the band — and
a per-axis payload's parts, owner table and labels likewise (:func:`check_payload`).  Torch-free.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core.errors import InputError
from ..core.names import (
    AXIS,
    FAMILY,
    FEATURE,
    HASH,
    LABEL,
    RUN_ID,
    SIGNAL,
    TEXT_ID,
    check_finite,
    check_name,
    check_names,
    check_units,
)
from ..models.registry import PER_AXIS
from ..scoring.band import band_problem

__all__ = ["check_payload", "state_mismatch", "MAX_PARTS"]


def check_payload(path: Path, p: dict, prefix: str = "") -> None:
    """Every name and value of a loaded payload against :mod:`thermonet.core.names`.

    A checkpoint is data from a file, not code: its strings reach generated C
    source and ONNX metadata, so each is checked with the rule it was created
    under before anything is built from it.
    """
    def at(key: str) -> str:
        return f"{path}: key '{prefix}{key}'"

    check_name(p["family"], FAMILY, at("family"))
    check_names(p["inputs"], FEATURE, at("inputs"))
    check_names(p["signals"], SIGNAL, at("signals"))
    check_names(p["outputs"], AXIS, at("outputs"))
    if not isinstance(p["hyper"], dict):
        raise InputError(f"{at('hyper')}: expected a mapping, got {type(p['hyper']).__name__}")
    spec = p["spec"]
    # t_ref and proxy_ref, plus the dynamic-input constants (checked against their
    # definitions by FeatureSpec.from_dict) and, in newer files, the inputs again
    if (not isinstance(spec, dict) or not {"t_ref", "proxy_ref"} <= set(spec)
            or not set(spec) <= {"t_ref", "proxy_ref", "dynamic", "inputs"}):
        raise InputError(f"{at('spec')}: expected a mapping with t_ref and proxy_ref "
                         "(and optionally the dynamic-input constants)")
    if spec["t_ref"] is not None:
        check_finite(spec["t_ref"], at("spec.t_ref"))
    if not isinstance(spec["proxy_ref"], dict):
        raise InputError(f"{at('spec.proxy_ref')}: expected a mapping signal -> number")
    for name, value in spec["proxy_ref"].items():
        check_name(name, SIGNAL, at("spec.proxy_ref"))
        check_finite(value, at(f"spec.proxy_ref.{name}"))
    if not isinstance(p["config"], dict):
        raise InputError(f"{at('config')}: expected a mapping")
    if not isinstance(p["state_dict"], dict):
        raise InputError(f"{at('state_dict')}: expected a mapping name -> tensor")
    if p["epoch"] is not None and (isinstance(p["epoch"], bool) or not isinstance(p["epoch"], int)):
        raise InputError(f"{at('epoch')}: {p['epoch']!r} is not an integer")
    if p["best_val"] is not None:
        check_finite(p["best_val"], at("best_val"))
    if p["family"] == PER_AXIS:
        _check_per_axis_payload(path, p)
    extra = p["extra"]
    if not isinstance(extra, dict):
        raise InputError(f"{at('extra')}: expected a mapping")
    for key, pattern in (("label", LABEL), ("device_id", TEXT_ID), ("data_hash", HASH),
                         ("mlflow_run_id", RUN_ID)):
        if extra.get(key) not in (None, ""):
            check_name(extra[key], pattern, at(f"extra.{key}"))
    if "units" in extra:
        check_units(extra["units"], AXIS, at("extra.units"))
    if "signal_units" in extra:
        check_units(extra["signal_units"], SIGNAL, at("extra.signal_units"))
    if extra.get("val_score") is not None:
        _number(extra["val_score"], at("extra.val_score"))
    if "band" in extra:
        why = band_problem(extra["band"])
        if why:
            raise InputError(f"{at('extra.band')}: {why}")
    metrics = extra.get("test_metrics", {})
    if not isinstance(metrics, dict):
        raise InputError(f"{at('extra.test_metrics')}: expected a mapping axis -> metrics")
    for axis, values in metrics.items():
        check_name(axis, AXIS, at("extra.test_metrics"))
        if not isinstance(values, dict):
            raise InputError(f"{at(f'extra.test_metrics.{axis}')}: expected a mapping")
        for k, v in values.items():
            check_name(k, SIGNAL, at(f"extra.test_metrics.{axis}"))
            _metric(v, at(f"extra.test_metrics.{axis}.{k}"))


#: Most parts a per-axis checkpoint may hold (one per distinct candidate).
MAX_PARTS = 64


def _check_per_axis_payload(path: Path, p: dict) -> None:
    """The per-axis keys of a payload: the parts' descriptions (each checked as a
    single-family checkpoint's keys), the owner table and the labels."""
    def at(key: str) -> str:
        return f"{path}: key '{key}'"

    parts, owner, labels = p.get("parts"), p.get("owner"), p.get("labels")
    if not isinstance(parts, list) or not 1 <= len(parts) <= MAX_PARTS:
        raise InputError(f"{at('parts')}: expected a list of 1..{MAX_PARTS} part descriptions")
    for k, entry in enumerate(parts):
        where = f"parts[{k}]"
        if not isinstance(entry, dict) or set(entry) != {"family", "hyper", "inputs",
                                                         "signals", "outputs", "spec"}:
            raise InputError(f"{at(where)}: expected a mapping with family, hyper, inputs, "
                             "signals, outputs and spec")
        if entry["family"] == PER_AXIS:
            raise InputError(f"{at(where + '.family')}: a part cannot itself be per-axis")
        check_payload(path, {**entry, "config": {}, "state_dict": {}, "epoch": None,
                              "best_val": None, "extra": {}}, prefix=f"{where}.")
    if not isinstance(labels, list) or len(labels) != len(parts):
        raise InputError(f"{at('labels')}: expected one label per part ({len(parts)})")
    check_names(labels, LABEL, at("labels"))
    if not isinstance(owner, list) or len(owner) != len(p["outputs"]):
        raise InputError(f"{at('owner')}: expected one entry per output axis "
                         f"({len(p['outputs'])})")
    for a, o in enumerate(owner):
        if o is not None and (isinstance(o, bool) or not isinstance(o, int)
                              or not 0 <= o < len(parts)):
            raise InputError(f"{at('owner')}: axis {a} names part {o!r} (parts 0.."
                             f"{len(parts) - 1}, or null for an axis left raw)")


_VERDICT_WORDS = ("better", "worse", "indistinguishable")


def _metric(value: Any, where: str) -> None:
    """A test metric of results.json: a number, an interval (two numbers), a verdict word,
    the ``compensate`` flag, a verdict against the baseline (a mapping of those) or null."""
    if value is None or isinstance(value, bool):
        return
    if isinstance(value, str):
        if value not in _VERDICT_WORDS:
            raise InputError(f"{where}: {value!r} is not a verdict "
                             f"({', '.join(_VERDICT_WORDS)})")
        return
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise InputError(f"{where}: expected an interval of two numbers")
        for i, v in enumerate(value):
            _number(v, f"{where}[{i}]")
        return
    if isinstance(value, dict):
        for k, v in value.items():
            if k not in ("ratio", "interval", "verdict"):
                raise InputError(f"{where}: unexpected key {str(k)[:40]!r}")
            _metric(v, f"{where}.{k}")
        return
    _number(value, where)


def _number(value: Any, where: str) -> None:
    """A metric: any real number (NaN/inf included: a metric may be undefined)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{where}: {value!r} is not a number")


def state_mismatch(model: Any, state: dict) -> str:
    """The first difference between ``model``'s parameters and a stored ``state_dict``: a
    parameter missing, one unexpected, or one whose shape differs (both shapes); ``""`` when
    names and shapes agree."""
    own = model.state_dict()
    for name, tensor in own.items():
        if name not in state:
            return f"parameter '{name}' is missing"
        theirs = getattr(state[name], "shape", None)
        if theirs is not None and tuple(theirs) != tuple(tensor.shape):
            return (f"parameter '{name}' is stored with shape {tuple(theirs)}, the family "
                    f"rebuilt from the checkpoint has {tuple(tensor.shape)}")
    extra = [k for k in state if k not in own]
    return f"unexpected parameter '{extra[0]}'" if extra else ""
