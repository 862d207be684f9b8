"""The harness of every C parity check: the header and a test driver compiled with the
system C compiler, run on packed binary records, its packed output read back.

Every check (:func:`~.c_header.c_parity_check`, the streaming ``step()`` and
``step_block()``, the recurrent step, the sensor model's header) writes ``model.h`` and
``driver.c`` to a temporary directory, compiles them with ``-std=c99`` and its own flags,
feeds the driver ``int n`` then ``n`` packed records (a numpy structured array, no
padding) and reads ``n`` packed records back; only the driver, the records and the
names in the messages differ.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ExportError

__all__ = ["PARITY_DRIVER", "c_compiler", "run_c_driver"]

#: A driver that evaluates the header on points read from a file (parity check, tests).
PARITY_DRIVER = r"""
#include <stdio.h>
#include "model.h"
/* in: int n, then per point S signal floats and A raw doubles;
   out: A comp doubles, A drift doubles, int flag (raw and the outputs converted to and from
   thermonet_real_t: float where the header chose float) */
int main(int argc, char **argv)
{
    FILE *in, *out;
    int n, k, flag;
    float s[PFX_N_SIGNALS];
    double raw_in[PFX_N_AXES], comp_out[PFX_N_AXES], drift_out[PFX_N_AXES];
    thermonet_real_t raw[PFX_N_AXES], comp[PFX_N_AXES], drift[PFX_N_AXES];
    int a;
    if (argc != 3) return 2;
    in = fopen(argv[1], "rb");
    out = fopen(argv[2], "wb");
    if (!in || !out || fread(&n, sizeof n, 1, in) != 1) return 3;
    for (k = 0; k < n; ++k) {
        if (fread(s, sizeof(float), PFX_N_SIGNALS, in) != PFX_N_SIGNALS) return 4;
        if (fread(raw_in, sizeof(double), PFX_N_AXES, in) != PFX_N_AXES) return 4;
        for (a = 0; a < PFX_N_AXES; ++a) raw[a] = (thermonet_real_t)raw_in[a];
        flag = pfx_compensate(s, raw, comp, drift);
        for (a = 0; a < PFX_N_AXES; ++a) {
            comp_out[a] = (double)comp[a];
            drift_out[a] = (double)drift[a];
        }
        fwrite(comp_out, sizeof(double), PFX_N_AXES, out);
        fwrite(drift_out, sizeof(double), PFX_N_AXES, out);
        fwrite(&flag, sizeof flag, 1, out);
    }
    fclose(in);
    fclose(out);
    return 0;
}
"""


def c_compiler() -> str | None:
    """The system C compiler (``cc``, else ``gcc``), or None where there is none."""
    return shutil.which("cc") or shutil.which("gcc")


def run_c_driver(cc: str, header_text: str, driver: str, rows: np.ndarray, out_dtype: Any, *,
                 prefix: str = "thermonet", cflags: Sequence[str] = (),
                 args: Sequence[str] = (), header: str = "the C header",
                 driver_name: str = "the C parity driver") -> np.ndarray:
    """Compile ``header_text`` as ``model.h`` with ``driver`` (``PFX``/``pfx`` replaced by
    ``prefix``), run it on ``rows`` and return its output records of ``out_dtype``.

    Raises
    ------
    ExportError
        "<header> does not compile: <first compiler line>", or "<driver_name> failed
        (exit N)".
    """
    source = driver.replace("PFX", prefix.upper()).replace("pfx", prefix)
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        (tmp / "model.h").write_text(header_text)
        (tmp / "driver.c").write_text(source)
        built = subprocess.run([cc, "-std=c99", *cflags, "-o", str(tmp / "driver"),
                                str(tmp / "driver.c"), "-lm"], capture_output=True, text=True)
        if built.returncode != 0:
            first = (built.stderr.strip().splitlines() or ["?"])[0]
            raise ExportError(f"{header} does not compile: {first}")
        (tmp / "in.bin").write_bytes(np.int32(rows.shape[0]).tobytes() + rows.tobytes())
        run = subprocess.run([str(tmp / "driver"), str(tmp / "in.bin"), str(tmp / "out.bin"),
                              *args], capture_output=True, text=True)
        if run.returncode != 0:
            raise ExportError(f"{driver_name} failed (exit {run.returncode})")
        return np.fromfile(tmp / "out.bin", dtype=out_dtype)
