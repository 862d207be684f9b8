"""The C header written and checked (:func:`export_c_header`): rendered
(:func:`thermonet.exporting.c_header.render_c_header`), then compiled with the system C
compiler and compared with torch on the ONNX check's points (:func:`c_parity_check`), its
streaming ``step()`` on a sequence (point-wise and recurrent), the float path, and the band's
tables — and written only when every check passes (nothing half-written)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..core.errors import ExportError
from ..core.fileio import atomic_write_text
from ..features import dynamics
from ..models import DriftModel
from ..models.composite import DriftModels
from .c_band import check_band_c, insert_band
from .c_driver import PARITY_DRIVER, c_compiler, run_c_driver
from .c_header import render_c_header
from .c_recurrent import c_step_parity_check, check_recurrent_stream
from .c_stream import REAL_FLAGS, check_stream, float_path_slack
from .parity import (
    check_drift_parity,
    check_flags,
    check_points,
    float32_tolerance,
    trained_range,
)

__all__ = ["export_c_header", "c_parity_check"]


def c_parity_check(model: DriftModels, header_text: str, *, prefix: str = "thermonet",
                   seed: int = 0, real: str = "auto") -> dict[str, float] | None:
    """Compile the header with the system C compiler and compare it with torch.

    The points are the ONNX check's (grid and random points in range, float32);
    the tolerance is :func:`~.parity.float32_tolerance`.  Returns ``None``
    (and logs it) when no C compiler is found — the header is then unchecked.
    ``real="float"`` compiles the header's float path on the host
    (``-DTHERMONET_USE_FLOAT``: float raw/drift/compensated, the fast ``expf``), with
    :func:`float_path_slack` added to the tolerance; ``"double"`` forces double.

    Raises
    ------
    ExportError
        The header does not compile, or a drift or flag differs from torch.
    """
    import logging

    cc = c_compiler()
    if cc is None:
        logging.getLogger(__name__).warning("no C compiler found: the C header is not checked")
        return None
    points = check_points(list(trained_range(model).values()), seed)
    n, n_axes = points.shape[0], len(model.outputs)
    const = model.constant().detach().cpu().double().numpy()
    with torch.no_grad():  # float32 drift relative to the float64 constant
        d_torch = model.relative(torch.from_numpy(points)).double().numpy()
    tol = float32_tolerance(model, points, d_torch)
    if real == "float":
        tol = tol + float_path_slack(const, d_torch)
    rows = np.zeros(n, dtype=[("s", np.float32, len(model.signals)),
                              ("raw", np.float64, n_axes)])
    rows["s"], rows["raw"] = points, const
    c_out = run_c_driver(cc, header_text, PARITY_DRIVER, rows,
                         [("comp", np.float64, n_axes), ("drift", np.float64, n_axes),
                          ("flag", np.int32)], prefix=prefix, cflags=("-O2", *REAL_FLAGS[real]))
    err = check_drift_parity(model, points, c_out["drift"] - const, d_torch, tol,
                             what="C header", who="C")
    # raw = the constant: compensated is minus the relative drift, computed in double (on
    # the float path raw is the constant rounded to float: raw - hi is exact, lo remains)
    raw_used = const.astype(np.float32).astype(np.float64) if real == "float" else const
    if not bool(np.all(np.abs(c_out["comp"] - (raw_used - const - d_torch)) <= tol)):
        raise ExportError("C header parity check failed: 'compensated' is not raw - drift")
    check_flags(model, points, c_out["flag"], what="C header", who="C")
    return {"n_points": float(n), "max_abs_diff": float(err.max())}


def export_c_header(model: DriftModels, path: str | Path, *, prefix: str = "thermonet",
                    check: bool = True, band: Mapping[str, Any] | None = None,
                    units: Mapping[str, str] | None = None) -> Path:
    """Write the model as a C99 header (atomic: temp file + ``os.replace``).

    Parameters
    ----------
    model : DriftModel or AxisModels
        Any family with a C emitter (:meth:`Family.emit_c`), or a per-axis model whose
        parts all have one (:func:`render_axis_models_c`).
    path : str or Path
        Destination ``.h``.
    prefix : str
        Prefix of every symbol (``<prefix>_compensate``, ``<PREFIX>_N_AXES``, the include
        guard ``<PREFIX>_MODEL_H`` and id ``<PREFIX>_MODEL_ID``); a C identifier.  Two
        headers in one program need two prefixes: a second header of another model under
        the same prefix is a compile error (:func:`.c_header.guard_open`).
    check : bool
        Compile the header and compare it with torch before writing
        (:func:`c_parity_check`, and for dynamic inputs the streaming ``step()`` on a
        sequence, :func:`.c_stream.check_stream`), on its double path and on its float
        path (``-DTHERMONET_USE_FLOAT``); skipped with a warning when no C compiler exists.

    Returns
    -------
    Path

    Raises
    ------
    ExportError
        Unknown family, NaN/inf parameters, a prefix that is not a C identifier, or a
        failed parity check (nothing is written then).

    ``band``: the residual-drift band's tables (:func:`thermonet.scoring.band.shipped_band`):
    written as constants with ``<prefix>_band()`` and ``<prefix>_band_signal()`` (its
    argument after a step: the delayed temperature of a model on one; :mod:`.c_band`),
    checked against Python.
    ``units``: per axis the unit of raw and drift (the checkpoint's ``units``), written in
    the comment and as ``<PREFIX>_AXIS_UNITS``.  The first line names the file written.
    """
    text = render_c_header(model, prefix=prefix, units=units, file_name=Path(path).name)
    checks: list[Callable[[], object]] = []
    recurrent = isinstance(model, DriftModel) and model.family.recurrent
    if band is not None:
        # the streaming form's dynamic inputs (a recurrent model's state keeps none of them):
        # <prefix>_band_signal reads the band's from the state
        dyn = [] if recurrent else dynamics.dynamic_signals(model.inputs)
        text = insert_band(text, band, prefix, list(model.outputs), list(model.signals), dyn)
        checks.append(partial(check_band_c, band, text, prefix))
    # both arithmetic paths: the host's double and the float path a single-precision
    # microcontroller compiles (-DTHERMONET_USE_FLOAT: float outputs, fast exp)
    for real in ("auto", "float"):
        if isinstance(model, DriftModel) and recurrent:  # state, stream
            checks += [partial(c_step_parity_check, model, text, prefix=prefix, real=real),
                       partial(check_recurrent_stream, model, text, prefix=prefix, real=real)]
        else:  # batch, and step(): dynamic inputs in C
            checks += [partial(c_parity_check, model, text, prefix=prefix, real=real),
                       partial(check_stream, model, text, prefix=prefix, real=real)]
    if check:
        _run_checks(checks, parallel=not recurrent)
    return atomic_write_text(path, text)


def _run_checks(checks: list[Callable[[], object]], *, parallel: bool) -> None:
    """Run every check; raise the first failure in list order.

    Each check spends most of its time waiting for the C compiler and its driver (separate
    processes), so the checks of a point-wise model run side by side in threads (their torch
    evaluations only read the model); a recurrent model's run one after the other.
    """
    if not parallel or len(checks) < 2:
        for run in checks:
            run()
        return
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=min(len(checks), 4)) as pool:
        futures = [pool.submit(run) for run in checks]
        for f in futures:  # the first failure in list order, as a serial run would report
            f.result()
