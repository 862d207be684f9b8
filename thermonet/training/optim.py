"""torch's optimizers without ``torch._dynamo``: its import costs about 0.9 s, and thermonet
never compiles a model (``torch.compile``), which is all it serves in an optimizer.

* :func:`optimizer_without_dynamo`: inside, the optimizer's methods (``zero_grad``,
  ``add_param_group``, ``state_dict`` …) call what they wrap without importing it;
* :func:`optimizer_step`: the optimizer's own ``step`` under ``torch.no_grad``, stepping over
  the wrapper that imports ``torch._dynamo`` for a graph break (Adam's; L-BFGS has none).

Every fit steps through both (the point-wise families in
:mod:`thermonet.training.train`, the GRU in :mod:`thermonet.training.recurrent`), so that
training never imports ``torch._dynamo``; the parameters are those torch's own calls give,
bit for bit (``tests/test_boundary.py`` fits both ways).

Kept when issue 51 asked for torch's optimizers as they are, on a measurement: without it
``thermonet compare`` on the whole-job bench (the two BMI270 soaks, default families; 2-core
Intel Xeon VM, 5 paired runs) imports ``torch._dynamo`` — wall ×1.23 (1.04–1.42) pair by
pair, +2.1 s CPU, +69 MB peak — above the 1 s the issue allows (``experiments/README.md``,
the whole-job table).  ``calibrate`` runs no optimizer (its families are solved in closed
form): unchanged either way.
"""

from __future__ import annotations

import contextlib
import inspect
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any

import torch

__all__ = ["optimizer_step", "optimizer_without_dynamo"]

_NO_DYNAMO_LOCK = threading.Lock()
_NO_DYNAMO_USERS = 0
_NO_DYNAMO_SET: list[Any] = []


@contextlib.contextmanager
def optimizer_without_dynamo() -> Iterator[None]:
    """Inside, torch's optimizers run without importing ``torch._dynamo`` (about 0.9 s).

    ``torch.optim.Optimizer``'s methods (``add_param_group``, ``zero_grad``, ``state_dict``
    …) are wrapped by ``torch._disable_dynamo``, whose wrapper imports ``torch._dynamo`` on
    its first call only to build ``torch._dynamo.disable(fn)`` — a function that, outside
    ``torch.compile`` (which thermonet never uses), calls ``fn``.  The wrapper first looks
    for that function on ``fn.__dynamo_disable``; storing ``fn`` itself there makes it call
    ``fn`` at once, the same call (``step`` itself: :func:`optimizer_step`).  Only
    wrappers recognised as torch 2.x's (``torch/_compile.py``'s ``inner``) are touched,
    nothing once
    ``torch._dynamo`` is imported (another torch only makes the first optimizer slower),
    and what was stored is removed when the last fit inside leaves (fits in threads share
    it): the process's own ``torch.compile`` afterwards sees torch's wrappers as shipped.
    """
    global _NO_DYNAMO_USERS
    with _NO_DYNAMO_LOCK:
        if _NO_DYNAMO_USERS == 0 and "torch._dynamo" not in sys.modules:
            for attr in vars(torch.optim.Optimizer).values():
                code = getattr(attr, "__code__", None)
                fn = getattr(attr, "__wrapped__", None)
                if code is None or fn is None or code.co_name != "inner" or not \
                        code.co_filename.replace("\\", "/").endswith("torch/_compile.py"):
                    continue
                if getattr(fn, "__dynamo_disable", None) is None:
                    setattr(fn, "__dynamo_disable", fn)  # noqa: B010 - the name torch reads
                    _NO_DYNAMO_SET.append(fn)
        _NO_DYNAMO_USERS += 1
    try:
        yield
    finally:
        with _NO_DYNAMO_LOCK:
            _NO_DYNAMO_USERS -= 1
            if _NO_DYNAMO_USERS == 0:
                for fn in _NO_DYNAMO_SET:
                    if getattr(fn, "__dynamo_disable", None) is fn:
                        delattr(fn, "__dynamo_disable")
                _NO_DYNAMO_SET.clear()


def optimizer_step(opt: torch.optim.Optimizer, closure: Callable[[], Any] | None = None
                   ) -> Any:
    """``opt.step(closure)`` without importing ``torch._dynamo``.

    torch wraps each optimizer's ``step`` twice: a hook runner (the optimizer step pre/post
    hooks and the profiler's label; thermonet registers no hook) and, for Adam and most
    others, ``_use_grad_for_differentiable``, which imports ``torch._dynamo`` on every call
    for a graph break that matters only under ``torch.compile``, then runs the step with
    gradients off (``differentiable`` is False unless asked).  Here the step itself
    (``inspect.unwrap``) runs under ``torch.no_grad`` — what the wrapper does, without the
    import.  Torch's own call where ``torch._dynamo`` is imported already (nothing left to
    save; the process may compile), for a differentiable optimizer, and for one whose
    ``step`` has no wrapper to step over."""
    step = inspect.unwrap(type(opt).step)
    if "torch._dynamo" in sys.modules or opt.defaults.get("differentiable") \
            or step is type(opt).step:
        return opt.step(closure)
    with torch.no_grad():
        return step(opt, closure)
