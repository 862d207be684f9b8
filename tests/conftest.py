"""Shared fixtures: small recordings the tests make themselves.

Every float comparison in the suite follows the tolerance policy in ``tests/tolerances.py``
(float32 and float64 bounds derived from the precision, exact equality only where the code
promises bit-identity), so the suite passes on any x86-64 CPU; the header of every run names
the CPU and the kernels torch and numpy dispatch on it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from thermonet.core.recording import Dataset, Recording
from thermonet.data.io import write_parquet


def pytest_report_header(config: pytest.Config) -> list[str]:
    """The CPU the floats were computed on (``make test-cpus`` runs the suite as on others)."""
    import platform

    import torch

    model = next((ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text()
                  .splitlines() if ln.startswith("model name")), platform.processor()) \
        if Path("/proc/cpuinfo").exists() else platform.processor()
    simd = np.__config__.CONFIG.get("SIMD Extensions", {}) if hasattr(np.__config__, "CONFIG") \
        else {}
    found = ",".join(simd.get("found", [])[-3:]) if isinstance(simd, dict) else ""
    return [f"cpu: {model}; torch kernels: {torch.backends.cpu.get_cpu_capability()}; "
            f"numpy dispatch (last 3): {found or 'baseline'}"]


#: The torch-free runtime shipped beside exported models (export/thermonet_runtime.py).
RUNTIME = Path(__file__).resolve().parents[1] / "export" / "thermonet_runtime.py"


def load_runtime() -> ModuleType:
    """Import export/thermonet_runtime.py as ``thermonet_runtime`` (it is not a package)."""
    import importlib.util
    import sys

    spec = importlib.util.spec_from_file_location("thermonet_runtime", RUNTIME)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["thermonet_runtime"] = mod
    spec.loader.exec_module(mod)
    return mod


#: Real recordings copied into the repository with their licences (tests/data/real/README.md).
REAL_DATA = Path(__file__).resolve().parent / "data" / "real"


def toy_dataset(*, n_runs: int = 4, drift_scale: float = 1.0, noise: float = 0.002,
                seed: int = 0, soak_levels: list[float] | None = None,
                law: Callable[[np.ndarray], np.ndarray] | None = None, dt_s: float = 1.0,
                run_step_c: float = 0.2, device_id: str = "toy") -> Dataset:
    """A 1-axis gyro on 2-hour ramps −20 → 50 °C (each run ``run_step_c`` warmer, a sample
    every ``dt_s``), drift 0.05 + 0.01·ΔT − 2e-4·ΔT² deg/s — or ``law(T)``.

    With ``soak_levels`` the temperature steps through those levels instead
    (few distinct temperatures, for the can-not-fit cases).
    """
    rng = np.random.default_rng(seed)
    runs = []
    for k in range(n_runs):
        t = np.arange(0.0, 2 * 3600.0, dt_s)
        if soak_levels:
            temp = np.repeat(soak_levels, int(np.ceil(t.size / len(soak_levels))))[: t.size]
            temp = temp + rng.normal(0, 0.01, t.size)
        else:
            temp = -20.0 + 70.0 * t / t[-1] + run_step_c * k
        d = temp + 20.0
        drift = law(temp) if law is not None else \
            drift_scale * (0.05 + 0.01 * d - 2e-4 * d ** 2)
        runs.append(Recording(
            time_s=t, temperature_c=temp,
            outputs={"gyro_x": drift + rng.normal(0.0, noise, t.size)},
            drift={"drift_gyro_x": drift}, units={"gyro_x": "deg/s", "temperature_c": "degC"},
            device_id=device_id, run_id=f"run{k}", sample_rate_hz=1.0 / dt_s))
    return Dataset(runs)


@pytest.fixture
def toy_parquet(tmp_path: Path) -> Path:
    return write_parquet(toy_dataset(), tmp_path / "toy.parquet")


def pointwise_families() -> list[str]:
    """Every registered family that is evaluated sample by sample: what the generic fit,
    checkpoint, export and layout tests parametrise over.  A recurrent family (the GRU)
    is trained on runs with time and exported with its state as inputs and outputs; those
    paths are its own, and tests/test_gru.py checks them (fit, stream, ONNX, runtime, C)."""
    from thermonet.models import MODELS

    return [name for name, cls in MODELS.items() if not cls.recurrent]
