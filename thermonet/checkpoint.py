"""Checkpoints that carry their own config (nanoGPT style) and load with ``weights_only=True``.

A checkpoint is a ``torch.save`` of a plain dict::

    {state_dict, family, hyper, inputs, signals, outputs,
     spec: {t_ref, proxy_ref}, config, epoch, best_val, extra, format}

Only tensors, numbers, strings, None, lists and dicts are stored, so
``torch.load(path, weights_only=True)`` can read it without executing code.
Writes are atomic (temporary file in the same folder, then ``os.replace``):
a crash never leaves a half-written checkpoint under the final name.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .errors import ExportError, InputError
from .features import FeatureSpec
from .fileio import atomic_path
from .models import DriftModel, build_family

__all__ = ["save_checkpoint", "load_checkpoint", "CHECKPOINT_FORMAT"]

#: Bumped when the layout changes incompatibly.
CHECKPOINT_FORMAT = 1

_KEYS = ("state_dict", "family", "hyper", "inputs", "signals", "outputs", "spec", "config",
         "epoch", "best_val", "extra")


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


def save_checkpoint(path: str | os.PathLike, model: DriftModel, *, config: dict,
                    extra: dict | None = None, epoch: int | None = None,
                    best_val: float | None = None) -> Path:
    """Write ``model`` with its config to ``path`` atomically; return the path.

    Parameters
    ----------
    path : path-like
    model : DriftModel
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
        "spec": {"t_ref": model.spec.t_ref, "proxy_ref": dict(model.spec.proxy_ref)},
        "config": _plain(dict(config), "config"),
        "epoch": None if epoch is None else int(epoch),
        "best_val": None if best_val is None or not math.isfinite(best_val) else float(best_val),
        "extra": _plain(dict(extra or {}), "extra"),
    }
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


def load_checkpoint(path: str | os.PathLike) -> tuple[DriftModel, dict]:
    """Rebuild the model saved by :func:`save_checkpoint` (``weights_only=True``).

    Returns
    -------
    (DriftModel, dict)
        The model in eval mode on CPU, and the checkpoint's metadata (every
        key but ``state_dict``).

    Raises
    ------
    InputError
        Missing/unreadable file or a payload that is not a thermonet checkpoint.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError.at(path, "no such checkpoint file")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several unrelated types for a bad file
        raise InputError.at(path, f"not a readable checkpoint ({type(err).__name__}: "
                            f"{str(err).splitlines()[0] if str(err) else ''})") from err
    if not isinstance(payload, dict) or any(k not in payload for k in _KEYS):
        missing = [k for k in _KEYS if not isinstance(payload, dict) or k not in payload]
        raise InputError.at(path, f"not a thermonet checkpoint (missing {', '.join(missing)})")
    if payload.get("format", CHECKPOINT_FORMAT) != CHECKPOINT_FORMAT:
        raise InputError.at(path, f"checkpoint format {payload.get('format')!r}; this thermonet "
                            f"reads format {CHECKPOINT_FORMAT}")
    spec = FeatureSpec(inputs=payload["inputs"], t_ref=payload["spec"]["t_ref"],
                       proxy_ref=payload["spec"]["proxy_ref"])
    family = build_family(payload["family"], n_inputs=len(payload["inputs"]),
                          n_outputs=len(payload["outputs"]), hyper=payload["hyper"])
    model = DriftModel(family=family, spec=spec, outputs=payload["outputs"])
    try:
        model.load_state_dict(payload["state_dict"], strict=True)
    except RuntimeError as err:
        raise InputError.at(path, "parameters do not match the stored family "
                            f"'{payload['family']}' ({str(err).splitlines()[0]})") from err
    model.eval()
    meta = {k: v for k, v in payload.items() if k != "state_dict"}
    return model, meta
