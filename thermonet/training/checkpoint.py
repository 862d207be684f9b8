"""Checkpoints that carry their own config (nanoGPT style) and load with ``weights_only=True``.

A checkpoint is a ``torch.save`` of a plain dict::

    {state_dict, family, hyper, inputs, signals, outputs,
     spec: {t_ref, proxy_ref}, config, epoch, best_val, extra, format}

A per-axis model (:class:`~thermonet.models.composite.AxisModels`, family ``per-axis``)
is one checkpoint too: the same keys (``state_dict`` holds every part's tensors under
``parts.<k>.``; ``inputs``/``signals`` are the union, ``spec`` the union's references), plus
``parts`` (per part: ``family``, ``hyper``, ``inputs``, ``signals``, ``outputs``, ``spec``, as
a single-family checkpoint stores them), ``owner`` (per output axis, the index of the part
that compensates it, or None: left raw) and ``labels`` (the parts' candidate labels).  The
digest covers all of it: an edited owner table is refused like an edited weight.  On load
the owner table is checked (one entry per axis, indices of existing parts, every part owning
an axis), the parts must be composable (:func:`~thermonet.models.composite.composable`), and
each part's stored ``compensate`` mask must be the owner table's.

Only tensors, numbers, strings, None, lists and dicts are stored, so
``torch.load(path, weights_only=True)`` can read it without executing code.
Writes are atomic (temporary file in the same folder, then ``os.replace``):
a crash never leaves a half-written checkpoint under the final name.

Integrity.  Every checkpoint carries ``sha256``, a SHA-256 digest over everything
else it stores (each tensor's name, dtype, shape and bytes; the config, spec,
names and metadata), and :func:`load_checkpoint` recomputes it before anything
is built from the file: a checkpoint edited after it was written (a weight
×1000, a changed config) or damaged is refused in one line naming the file —
standalone files as well as those inside a comparison (whose ``results.json``
also records the file's SHA-256).  A checkpoint *without* a digest (written
before thermonet stored one, or with it removed) is refused too, never loaded
with a warning: removing the key would otherwise be all an edit needs.  A file
you trust (your own older checkpoint, or one you edited on purpose) is sealed
again with :func:`seal_checkpoint`.  The digest detects edits and damage, not
a forger: anyone who can write the file can also recompute it (that would take
a signature with a key, which thermonet does not manage).
"""

from __future__ import annotations

import hashlib
import math
import os
import pickle
import re
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..core.errors import ConfigError, ExportError, InputError, ThermonetError
from ..core.fileio import atomic_path, not_a_file
from ..features.inputs import FeatureSpec
from ..features.target import MODE_CODES
from ..models import DriftModel, build_family
from ..models.composite import PER_AXIS, AxisModels, DriftModels, composable
from ..models.shipped import MODEL_KINDS
from .checkpoint_payload import check_payload, state_mismatch

__all__ = ["save_checkpoint", "load_checkpoint", "seal_checkpoint", "checkpoint_digest",
           "checkpoint_kind", "CHECKPOINT_FORMAT", "DIGEST_KEY"]

#: Bumped when the layout changes incompatibly.
CHECKPOINT_FORMAT = 1

_KEYS = ("state_dict", "family", "hyper", "inputs", "signals", "outputs", "spec", "config",
         "epoch", "best_val", "extra")
#: Key of the integrity digest (:func:`checkpoint_digest`) in a checkpoint's payload.
DIGEST_KEY = "sha256"


def _feed(h: Any, value: Any, where: str) -> None:
    """Feed ``value`` to the hash ``h`` in a canonical, type-tagged, length-prefixed form."""
    if value is None:
        h.update(b"N")
    elif isinstance(value, bool):
        h.update(b"T" if value else b"F")
    elif isinstance(value, int):
        h.update(b"i%d;" % value)
    elif isinstance(value, float):
        h.update(b"f" + float.hex(value).encode("ascii") + b";")
    elif isinstance(value, str):
        data = value.encode("utf-8", "surrogatepass")
        h.update(b"s%d:" % len(data) + data)
    elif isinstance(value, (list, tuple)):
        h.update(b"l%d:" % len(value))
        for i, v in enumerate(value):
            _feed(h, v, f"{where}[{i}]")
    elif isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise ValueError(f"'{where}' has a key that is not a string")
        h.update(b"d%d:" % len(value))
        for k in sorted(value):
            _feed(h, k, where)
            _feed(h, value[k], f"{where}.{k}")
    elif isinstance(value, torch.Tensor):
        if value.layout != torch.strided or value.is_quantized:
            raise ValueError(f"'{where}' is not a dense tensor")
        t = value.detach().cpu().contiguous()
        head = f"{t.dtype}{tuple(t.shape)}".encode("ascii")
        h.update(b"t%d:" % len(head) + head)
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    else:
        raise ValueError(f"'{where}' holds a {type(value).__name__}")


def checkpoint_digest(payload: dict) -> str:
    """SHA-256 (hex) over every key of a checkpoint payload but :data:`DIGEST_KEY`.

    Canonical: keys sorted, every value tagged with its type and length, floats
    by their exact hex form, tensors by dtype, shape and raw bytes — so the same
    content gives the same digest whatever pickle made of it.

    Raises
    ------
    ValueError
        A value that is not plain data (numbers, strings, lists, dicts, dense tensors).
    """
    h = hashlib.sha256(b"thermonet-checkpoint\0")
    _feed(h, {k: v for k, v in payload.items() if k != DIGEST_KEY}, "checkpoint")
    return h.hexdigest()


def _plain(value: Any, where: str) -> Any:
    """``value`` as plain data (numpy scalars/arrays become numbers/lists)."""
    # numpy scalars first: np.float64 is also a float, but pickles as a numpy
    # global that weights_only loading refuses.
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise ExportError(f"checkpoint: key {k!r} in '{where}' is not a string")
            out[k] = _plain(v, f"{where}.{k}")
        return out
    raise ExportError(f"checkpoint: '{where}' holds a {type(value).__name__}; only numbers, "
                      "strings, lists and dicts can be stored")


def save_checkpoint(path: str | os.PathLike, model: DriftModels, *, config: dict,
                    extra: dict | None = None, epoch: int | None = None,
                    best_val: float | None = None) -> Path:
    """Write ``model`` with its config to ``path`` atomically; return the path.

    Parameters
    ----------
    path : path-like
    model : DriftModel or AxisModels
        A per-axis composite is stored with its parts, owner table and labels (module
        docstring).
    config : dict
        The resolved run configuration (plain data).
    extra : dict, optional
        Anything else worth keeping (metrics, data hashes), plain data.
    epoch, best_val : optional
        Best epoch and its validation loss (standardised MSE).

    Raises
    ------
    ExportError
        A parameter or buffer holding NaN (or ±inf outside the signal range),
        or a config/extra value that is not plain data.
    """
    state = {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}
    for name, tensor in state.items():
        if tensor.is_floating_point() and torch.isnan(tensor).any():
            raise ExportError(f"checkpoint: model parameter '{name}' holds NaN; refusing to save")
        if tensor.is_floating_point() and not name.startswith("sig_") \
                and not torch.isfinite(tensor).all():
            raise ExportError(f"checkpoint: model parameter '{name}' is infinite; refusing to save")
    payload = {
        "format": CHECKPOINT_FORMAT,
        "state_dict": state,
        "family": model.family_name,
        "hyper": _plain(model.family.hyper(), "hyper"),
        "inputs": list(model.inputs),
        "signals": list(model.signals),
        "outputs": list(model.outputs),
        "spec": model.spec.to_dict(),
        "config": _plain(dict(config), "config"),
        "epoch": None if epoch is None else int(epoch),
        "best_val": None if best_val is None or not math.isfinite(best_val) else float(best_val),
        "extra": _plain(dict(extra or {}), "extra"),
    }
    if isinstance(model, AxisModels):
        payload["parts"] = [_part_entry(p) for p in model.parts]
        payload["owner"] = list(model.owner)
        payload["labels"] = list(model.labels)
    payload[DIGEST_KEY] = checkpoint_digest(payload)
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


def _part_entry(part: Any) -> dict:
    """What a per-axis checkpoint stores of one part beside its tensors (a single-family
    checkpoint's descriptive keys)."""
    return {"family": part.family_name, "hyper": _plain(part.family.hyper(), "hyper"),
            "inputs": list(part.inputs), "signals": list(part.signals),
            "outputs": list(part.outputs), "spec": part.spec.to_dict()}


def seal_checkpoint(path: str | os.PathLike) -> Path:
    """Store a fresh integrity digest in the checkpoint at ``path`` (atomic); return the path.

    For a file you trust and that :func:`load_checkpoint` refuses for its digest:
    a checkpoint written before thermonet stored one, or one edited on purpose.
    Nothing else is checked here (the next load checks everything).

    Raises
    ------
    InputError
        A file that is not a readable checkpoint payload.
    """
    path = Path(path)
    payload = _read_payload(path)
    try:
        payload[DIGEST_KEY] = checkpoint_digest(payload)
    except ValueError as err:
        raise InputError.at(path, f"not a thermonet checkpoint ({err})") from None
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


#: torch's weights-only refusals of a global ("Unsupported global: GLOBAL x", "unsupported
#: GLOBAL x whose module is blocked"): the callable or class a pickle names.
_UNSAFE_GLOBAL = re.compile(r"\bGLOBAL ([\w.]+)", re.IGNORECASE)


def checkpoint_kind(path: str | os.PathLike) -> str:
    """The model kind (a key of :data:`thermonet.models.shipped.MODEL_KINDS`) whose
    checkpoint format the file at ``path`` carries: what loads it.  ``"bias"`` for a file it
    cannot read or a format no kind names — the bias loader then says what is wrong."""
    try:
        payload = torch.load(Path(path), map_location="cpu", weights_only=True)
    except Exception:  # not ours to diagnose here: the loader says what is wrong
        return "bias"
    fmt = payload.get("format", CHECKPOINT_FORMAT) if isinstance(payload, dict) else None
    kinds = {k.checkpoint_format: name for name, k in MODEL_KINDS.items()}
    return kinds.get(fmt, "bias") if isinstance(fmt, (int, str)) else "bias"


def load_torch_file(path: Path, what: str = "checkpoint") -> Any:
    """``torch.load(path, weights_only=True)`` of a file a user gave, its refusals in one line
    of thermonet's own: a pickle naming code or a class to rebuild (a hostile or foreign
    pickle, which the safe loader never runs) is said to be no thermonet ``what`` and why —
    never with torch's advice to load it again unsafely (``weights_only=False``)."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several unrelated types for a bad file
        raise _refusal(path, what, err) from None


def _refusal(path: Path, what: str, err: Exception) -> InputError:
    """Why torch could not load ``path`` as a ``what``, in one line: an ONNX file said to be
    one (:func:`_is_onnx`), an unsafe or foreign pickle (:func:`_unreadable`), else torch's
    first line."""
    if _is_onnx(path):
        return InputError.at(path, f"an ONNX file (an exported model), not a thermonet {what}: "
                             "load the .pt checkpoint it was exported from (compare's "
                             "models/<label>.pt, DriftEstimator.save), or run the ONNX file "
                             "with export/thermonet_runtime.py")
    if isinstance(err, pickle.UnpicklingError):
        return _unreadable(path, what, err)
    first = str(err).splitlines()[0] if str(err) else ""
    first = "" if "weights_only" in first else first
    return InputError.at(path, f"not a readable {what} ({type(err).__name__}"
                         f"{': ' + first if first else ''})")


def _is_onnx(path: Path) -> bool:
    """Whether ``path`` is an ONNX model: a protobuf ModelProto's first fields (``ir_version``,
    a varint: 0x08 and one byte, then ``producer_name``: 0x12), or the name ``.onnx`` on a
    file that is neither a zip ('PK', torch's format) nor a pickle (0x80)."""
    try:
        with path.open("rb") as f:
            head = f.read(3)
    except OSError:
        return False
    if len(head) == 3 and head[0] == 0x08 and head[1] < 0x80 and head[2] == 0x12:
        return True
    return path.suffix.lower() == ".onnx" and not head.startswith((b"PK", b"\x80"))


def _unreadable(path: Path, what: str, err: pickle.UnpicklingError) -> InputError:
    """A pickle torch's safe loader refused, in one line of thermonet's own."""
    text = str(err)
    glob = _UNSAFE_GLOBAL.search(text)
    name = glob.group(1) if glob else _pickle_global(path)
    if name:
        return InputError.at(path, f"not a thermonet {what}: it is a pickle that names "
                             f"Python code to run or a class to rebuild ({name}), "
                             f"which a {what} never holds (an unsafe pickle); refused "
                             "unread, nothing in it was run")
    detail = text.split("WeightsUnpickler error:", 1)[-1].strip().splitlines()
    detail = [d for d in detail if d.strip() and "weights_only" not in d]
    return InputError.at(path, f"not a readable {what} (not a pickle of tensors and plain "
                         f"data{': ' + detail[0].strip() if detail else ''})")


def _pickle_global(path: Path) -> str | None:
    """The first callable or class a plain pickle file names (``GLOBAL`` / ``STACK_GLOBAL``),
    read by :mod:`pickletools` without running anything; None where there is none or the
    file is no plain pickle (torch's safe loader stops at an opcode it does not read before
    it reaches the global, so this names it)."""
    import pickletools

    try:
        strings: list[str] = []
        with path.open("rb") as f:
            for op, arg, _ in pickletools.genops(f):
                if op.name == "GLOBAL":
                    return str(arg).replace(" ", ".")
                if op.name == "STACK_GLOBAL" and len(strings) >= 2:
                    return f"{strings[-2]}.{strings[-1]}"
                if isinstance(arg, str):
                    strings.append(arg)
    except Exception:   # not a pickle, or damaged: named by the caller as unreadable
        return None
    return None


def _read_payload(path: Path) -> dict:
    """The dict a checkpoint file holds (``weights_only``), with every key of :data:`_KEYS`."""
    why = not_a_file(path, "checkpoint file")
    if why:
        raise InputError.at(path, why)
    payload = load_torch_file(path)
    if not isinstance(payload, dict) or any(k not in payload for k in _KEYS):
        missing = [k for k in _KEYS if not isinstance(payload, dict) or k not in payload]
        raise InputError.at(path, f"not a thermonet checkpoint (missing {', '.join(missing)})")
    return payload


def _check_digest(path: Path, payload: dict) -> None:
    """The stored digest against the content (see the module docstring)."""
    stored = payload.get(DIGEST_KEY)
    if stored is None:
        raise InputError.at(path, "checkpoint carries no integrity digest ('sha256'; written "
                            "by an older thermonet, or removed), so it cannot be verified; if "
                            "you trust this file, seal it with "
                            "thermonet.training.checkpoint.seal_checkpoint(path)")
    try:
        actual = checkpoint_digest(payload)
    except ValueError as err:
        raise InputError.at(path, f"not a thermonet checkpoint ({err})") from None
    if not isinstance(stored, str) or stored != actual:
        raise InputError.at(path, "content does not match the checkpoint's SHA-256 digest "
                            "(edited or damaged after it was written); refusing to load it")


def load_checkpoint(path: str | os.PathLike) -> tuple[DriftModels, dict]:
    """Rebuild the model saved by :func:`save_checkpoint` (``weights_only=True``).

    Returns
    -------
    (DriftModel or AxisModels, dict)
        The model in eval mode on CPU (an :class:`~thermonet.models.composite.AxisModels`
        for a ``per-axis`` checkpoint), and the checkpoint's metadata (every key but
        ``state_dict``; ``sha256`` is the verified digest).

    Raises
    ------
    InputError
        Missing/unreadable file, a payload that is not a thermonet checkpoint, or
        one whose ``sha256`` digest is missing or does not match its content
        (:func:`seal_checkpoint` re-seals a file you trust).
    """
    path = Path(path)
    payload = _read_payload(path)
    if payload.get("format", CHECKPOINT_FORMAT) != CHECKPOINT_FORMAT:
        raise InputError.at(path, f"checkpoint format {payload.get('format')!r}; this thermonet "
                            f"reads format {CHECKPOINT_FORMAT}")
    _check_digest(path, payload)
    check_payload(path, payload)
    model: DriftModels
    if payload["family"] == PER_AXIS:
        model = _build_axis_models(path, payload)
    else:
        model = _build_part(path, payload, "")
    try:
        model.load_state_dict(payload["state_dict"], strict=True)
    except RuntimeError as err:
        said = state_mismatch(model, payload["state_dict"]) or str(err).splitlines()[0]
        raise InputError.at(path, "parameters do not match the stored family "
                            f"'{payload['family']}' ({said})") from err
    for part in model.parts if isinstance(model, AxisModels) else [model]:
        lo, hi = part.sig_lo.detach(), part.sig_hi.detach()
        bad = torch.isnan(lo) | torch.isnan(hi) | (lo > hi)
        if bool(bad.any()):
            j = int(torch.nonzero(bad)[0, 0])
            raise InputError.at(path, f"trained range of signal '{part.signals[j]}' is "
                                f"[{float(lo[j]):g}, {float(hi[j]):g}] (low must be <= high)")
        _check_target_buffers(path, part)
    if isinstance(model, AxisModels):
        _check_axis_models(path, model)
    model.eval()
    meta = {k: v for k, v in payload.items() if k != "state_dict"}  # the digest included
    return model, meta


def _build_part(path: Path, p: dict, where: str) -> DriftModel:
    """A fresh DriftModel of the stored family, inputs and spec (``where``: the key prefix
    named in errors, ``parts[k].`` for a per-axis part)."""
    try:
        spec = FeatureSpec.from_dict({**p["spec"], "inputs": p["inputs"]}, source="spec")
    except ConfigError as err:
        raise InputError.at(path, f"{where}{err}" if where else str(err)) from None
    try:
        family = build_family(p["family"], n_inputs=len(p["inputs"]),
                              n_outputs=len(p["outputs"]), hyper=p["hyper"])
        model = DriftModel(family=family, spec=spec, outputs=p["outputs"])
    except (ThermonetError, TypeError, ValueError) as err:  # the names passed, the combination not
        raise InputError.at(path, f"key '{where}family'/'{where}hyper'/'{where}inputs': "
                            f"{err}") from None
    if list(model.signals) != list(p["signals"]):
        raise InputError.at(path, f"key '{where}signals': {p['signals']} do not match the inputs "
                            f"{p['inputs']} (expected {list(model.signals)})")
    return model


def _build_axis_models(path: Path, payload: dict) -> AxisModels:
    """The parts, owner table and labels of a ``per-axis`` checkpoint (checked by
    :func:`~thermonet.training.checkpoint_payload.check_payload`), as a fresh composite
    (tensors loaded after)."""
    parts = [_build_part(path, entry, f"parts[{k}].")
             for k, entry in enumerate(payload["parts"])]
    if recurrent := [p.family_name for p in parts if p.family.recurrent]:
        raise InputError.at(path, f"key 'parts': part {recurrent[0]} is recurrent; a per-axis "
                            "model holds point-wise families only")
    try:
        model = AxisModels(parts, payload["owner"], payload["labels"])
    except ConfigError as err:
        raise InputError.at(path, f"key 'owner'/'parts': {err}") from None
    for key in ("inputs", "signals"):
        if list(getattr(model, key)) != list(payload[key]):
            raise InputError.at(path, f"key '{key}': {payload[key]} is not the union of the "
                                f"parts' ({list(getattr(model, key))})")
    if list(model.outputs) != list(payload["outputs"]):
        raise InputError.at(path, f"key 'outputs': {payload['outputs']} are not the parts' "
                            f"{list(model.outputs)}")
    return model


def _check_axis_models(path: Path, model: AxisModels) -> None:
    """A loaded composite whose tensors say what its owner table says: each part's
    ``compensate`` mask is its own axes, and the parts (their loaded references and ranges)
    are still composable."""
    for k, part in enumerate(model.parts):
        want = [o == k for o in model.owner]
        if part.compensated_axes != want:
            raise InputError.at(path, f"part {k} ({model.labels[k]}) compensates "
                                f"{part.compensated_axes}, but the owner table gives it {want}")
    why = composable(list(model.parts))
    if why:
        raise InputError.at(path, f"the per-axis parts cannot be one model: {why}")


def _check_target_buffers(path: Path, model: DriftModel) -> None:
    """Target buffers read from the file: known mode codes, a 0/1 mask, finite constants."""
    codes = model.target_code.tolist()
    bad = [c for c in codes if c not in MODE_CODES.values()]
    if bad:
        raise InputError.at(path, f"buffer 'target_code' holds {bad[0]}, not a target mode code "
                            f"({', '.join(f'{v} {k}' for k, v in MODE_CODES.items())})")
    mask = model.compensate.detach()
    if not bool(((mask == 0) | (mask == 1)).all()):
        raise InputError.at(path, f"buffer 'compensate' is {mask.tolist()}, expected 0 or 1 per "
                            "axis")
    for name in ("y_offset", "y_ref", "sig_ref"):
        if not bool(torch.isfinite(getattr(model, name).detach()).all()):
            raise InputError.at(path, f"buffer '{name}' holds a non-finite value")
