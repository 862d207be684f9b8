"""A sensor model's checkpoint (``models/<label>.pt`` of a ``model: sensor`` comparison): the
fitted :class:`~thermonet.models.sensor.SensorModel` written with its family, inputs, spec,
triads and what do-no-harm kept, sealed by the bias checkpoints' own SHA-256 digest
(:func:`save_sensor`), and read back only after the digest and every name are checked
(:func:`load_sensor`; a hostile pickle is one line, never run)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from ..core.errors import FitError, InputError, first_line
from ..core.fileio import atomic_path
from ..core.names import AXIS, FAMILY, check_name, check_names
from ..features.inputs import FeatureSpec
from ..models import DriftModel, build_family
from ..models.sensor import SensorModel, element_names
from .checkpoint import (
    DIGEST_KEY,
    _check_digest,
    checkpoint_digest,
    checkpoint_kind,
    load_checkpoint,
    load_torch_file,
)

if TYPE_CHECKING:
    from .sensor import SensorFit

__all__ = ["SENSOR_FORMAT", "save_sensor", "load_sensor", "load_shipped", "LOADERS"]


#: ``format`` of a sensor-model checkpoint (``models/<label>.pt`` of a ``model: sensor`` run).
SENSOR_FORMAT = "thermonet-sensor-1"


def save_sensor(path: str | Path, fitted: SensorFit, *, family: str, hyper: dict | None,
                extra: dict | None = None) -> Path:
    """Write a sensor model (weights only: ``torch.load(weights_only=True)`` reads it back)."""
    model = fitted.model
    for name, t in list(model.named_parameters()) + list(model.named_buffers()):
        if t.is_floating_point() and not bool(torch.isfinite(t).all()):
            raise FitError(f"{path}: parameter '{name}' is not finite; a NaN model is never "
                           "written")
    spec = model.bias.spec
    payload = {"format": SENSOR_FORMAT, "family": family, "hyper": dict(hyper or {}),
               "inputs": list(spec.inputs), "spec": spec.to_dict(),
               "triads": model.triads, "kept": dict(fitted.kept),
               "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
               "extra": dict(extra or {})}

    try:
        payload[DIGEST_KEY] = checkpoint_digest(payload)  # the bias checkpoints' own digest
    except ValueError as err:
        raise FitError(f"{path}: {err}") from None
    out = Path(path)
    with atomic_path(out) as tmp:
        torch.save(payload, tmp)
    return out


def load_sensor(path: str | Path) -> tuple[SensorModel, dict]:
    """A sensor model written by :func:`save_sensor`, and its payload (without weights).

    The file's SHA-256 digest (over its content, as for bias checkpoints) must match, and
    its names pass :mod:`thermonet.core.names` before anything is built from them."""
    p = Path(path)
    payload = load_torch_file(p, "sensor model")   # a hostile pickle: one line, never run
    if not isinstance(payload, dict) or payload.get("format") != SENSOR_FORMAT:
        raise InputError(f"{p}: not a thermonet sensor model (format "
                         f"{payload.get('format') if isinstance(payload, dict) else None!r})")

    _check_digest(p, payload)  # edited or damaged since it was written: refused
    check_name(payload.get("family"), FAMILY, f"{p}: key 'family'")
    triads = [list(t) for t in payload["triads"]]
    outputs = [o for t in triads for o in t]
    check_names(outputs, AXIS, f"{p}: key 'triads'")
    spec = FeatureSpec.from_dict({**payload["spec"], "inputs": payload["inputs"]},
                                 source=f"{p}: spec")
    names_e = [e for t in triads for e in element_names(t)]
    hyper = dict(payload["hyper"])
    fam = payload["family"]
    model = SensorModel(
        bias=DriftModel(family=build_family(fam, n_inputs=len(spec.inputs),
                                            n_outputs=len(outputs), hyper=hyper),
                        spec=spec, outputs=outputs),
        elements=DriftModel(family=build_family(fam, n_inputs=len(spec.inputs),
                                                n_outputs=len(names_e), hyper=hyper),
                            spec=spec, outputs=names_e),
        triads=triads)
    try:
        model.load_state_dict(payload["state_dict"])
    except (RuntimeError, KeyError, TypeError) as err:
        raise InputError(f"{p}: parameters do not match the stored family '{fam}' "
                         f"({first_line(err)})"
                         ) from None
    model.eval()
    return model, {k: v for k, v in payload.items() if k != "state_dict"}


#: Each model kind's checkpoint loader, by kind (:data:`thermonet.models.shipped.MODEL_KINDS`):
#: ``loader(path) -> (model, metadata)``.
LOADERS = {"bias": load_checkpoint, "sensor": load_sensor}


def load_shipped(path: str | Path) -> tuple[Any, dict]:
    """Any shipped model's checkpoint (:class:`~thermonet.models.shipped.ShippedModel`) and
    its metadata, loaded by the kind its ``format`` names
    (:func:`~thermonet.training.checkpoint.checkpoint_kind`)."""
    return LOADERS[checkpoint_kind(path)](path)
