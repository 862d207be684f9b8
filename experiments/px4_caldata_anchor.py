"""PX4's ``Tools/process_sensor_caldata.py`` fit, as a script: the anchor ``bench_pipeline.py``
times ``thermonet calibrate`` against.

Re-implemented from PX4/PX4-Autopilot commit 00f5c319563d03d2ce482dbd1b53dff25b5a7f34 (the
same reading as ``tests/test_autopilot_parity.py``, which checks thermonet's coefficients
against it): the log read with pyulog; per gyro/accel/baro instance TMIN/TMAX the logged
extremes and TREF their mean; ``scipy.signal.medfilt(data, 31)``; accel less its median;
``resampleWithDeltaX`` (2,000 temperature bins, a Python loop as in the script);
``np.polyfit`` order 3 (baro 5, on ``100 * (pressure - median)``); the parameters printed as
the script prints them.  The script's plots (matplotlib, written to a PDF) are left out: the
anchor is its fit, which is what a user waits for.  This module is also the oracle
``tests/test_autopilot_parity.py`` and ``tests/test_verify.py`` check thermonet against (one
re-implementation: ``fit(..., pad="edge")`` is the one change thermonet makes, its median
filter's end padding).

Usage: ``python experiments/px4_caldata_anchor.py LOG.ulg``
"""

from __future__ import annotations

import sys

import numpy as np
from pyulog import ULog
from scipy.signal import medfilt


def resample_with_delta_x(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``resampleWithDeltaX`` as the script writes it (a loop over samples)."""
    x_min, x_max = np.amin(x), np.amax(x)
    nb = 2000
    interval = (x_max - x_min) / nb
    ry, rx, rc = np.zeros(nb), np.zeros(nb), np.zeros(nb)
    for idx in range(len(x)):
        if x[idx] < x_min:
            b = 0
        elif x[idx] < x_max:
            b = int((x[idx] - x_min) / interval)
        else:
            b = nb - 1
        ry[b] += y[idx]
        rx[b] += x[idx]
        rc[b] += 1
    keep = np.where(rc != 0)
    return rx[keep] / rc[keep], ry[keep] / rc[keep]


def medfilt_edge(v: np.ndarray) -> np.ndarray:
    """``medfilt(v, 31)`` with the ends padded by the nearest value instead of zeros."""
    return medfilt(np.pad(v, 15, mode="edge"), 31)[15:-15]


def fit(ulg: str, pad: str = "zeros") -> dict[str, float]:
    """The parameters ``process_sensor_caldata.py`` writes for every gyro/accel/baro;
    ``pad="edge"``: the one change thermonet makes (its median filter's end padding)."""
    median_filter = (lambda v: medfilt(v, 31)) if pad == "zeros" else medfilt_edge
    ulog = ULog(str(ulg), ["sensor_gyro", "sensor_accel", "sensor_baro"])
    out: dict[str, float] = {}
    for d in ulog.data_list:
        t = {"sensor_gyro": "G", "sensor_accel": "A", "sensor_baro": "B"}[d.name]
        pre = f"TC_{t}{d.multi_id}_"
        temp = d.data["temperature"].astype(np.float64)
        out[pre + "ID"] = int(np.median(d.data["device_id"]))
        tmin, tmax = np.amin(temp), np.amax(temp)
        tref = 0.5 * (tmin + tmax)
        out.update({pre + "TMIN": tmin, pre + "TMAX": tmax, pre + "TREF": tref})
        rel = temp - tref
        if t == "B":
            p = median_filter(d.data["pressure"].astype(np.float64))
            xr, yr = resample_with_delta_x(rel, 100 * (p - np.median(p)))  # "hPa to Pa"
            coef = np.polyfit(xr, yr, 5)
            out.update({f"{pre}X{k}": coef[5 - k] for k in range(6)})
            continue
        for i, ax in enumerate("xyz"):
            v = median_filter(d.data[ax].astype(np.float64))
            if t == "A":
                v = v - np.median(v)
            xr, yr = resample_with_delta_x(rel, v)
            coef = np.polyfit(xr, yr, 3)
            out.update({f"{pre}X{k}_{i}": coef[3 - k] for k in range(4)})
    return out


if __name__ == "__main__":
    for name, value in fit(sys.argv[1]).items():
        print(f"1\t1\t{name}\t{value:.10g}\t{6 if name.endswith('_ID') else 9}")
