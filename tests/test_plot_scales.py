"""Plot scales: readable whatever the rate and length of the recording.

A 500 Hz, 200 s fast ramp whose white noise is ten times the drift, with one candidate that
diverges: the y-scale of every time and temperature plot comes from binned means of raw, the
baseline and the chosen model (it holds them, and is a few times the drift's range, not the
noise's nor the diverging candidate's, which is marked off scale); the time axis runs in the
unit that suits the length.  Real matplotlib figures (Agg canvas) and real PNG files.
"""

from __future__ import annotations

import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np
import pytest

from thermonet.reporting.plots import (
    DPI,
    FIGSIZE_IN,
    LIMIT_BINS,
    OFF_SCALE,
    drift_vs_temperature_figure,
    plot_drift_vs_temperature,
    time_unit,
    y_limits,
)
from thermonet.reporting.residual_plots import (
    plot_residual_vs_temperature,
    plot_residual_vs_time,
    residual_vs_temperature_figure,
    residual_vs_time_figure,
)
from thermonet.scoring.metrics import binned_means

RATE_HZ = 500.0
SPAN_S = 200.0
DRIFT_PP_MG = 4.0                  # the correction the report must show
NOISE_MG = 10.0 * DRIFT_PP_MG      # white noise, 1 sigma per sample: ten times the drift
DIVERGED_MG = 350.0                # where the diverging candidate ends (ratio ~87)
COLOURS = {"cubic": "#1f77b4", "rbf": "#ff7f0e", "poly3-rate": "#2ca02c", "poly2": "#9467bd"}
STYLE = {"chosen": "rbf", "baseline": "cubic", "colours": COLOURS}


@pytest.fixture(scope="module")
def ramp():
    """The plot inputs compare builds (workflows/compare_plots.py ``plot_jobs``): the test part's
    ``bin_by`` (temperature), ``time_s`` and ``target`` (the observed drift); per family its
    prediction on ``bin_by`` as the curve and ``target - prediction`` as the residual."""
    rng = np.random.default_rng(19)
    n = int(RATE_HZ * SPAN_S)
    time_s = 1.7e9 + np.arange(n) / RATE_HZ            # epoch stamps, like a real log
    u = np.arange(n) / (n - 1)
    truth_c = 24.5 + 11.0 * u                          # 3.3 °C/min, 1 °C bins half-full at the ends
    temperature_c = truth_c + 0.02 * rng.normal(size=n)  # thermometer noise
    drift = DRIFT_PP_MG * ((truth_c - 24.5) / 11.0) ** 2
    target = 981.0 + drift + NOISE_MG * rng.normal(size=n)  # gravity's projection: removed in plots
    preds = {
        "cubic": 0.9 * drift + 0.1 * DRIFT_PP_MG * u,  # baseline: close
        "rbf": drift,                                  # chosen: the drift
        "poly3-rate": drift + DIVERGED_MG * u ** 8,    # a rate input blowing up at the end
        "poly2": 0.85 * drift,                         # a weaker candidate inside the frame
    }
    return {
        "time_s": time_s, "temperature_c": temperature_c, "target": target, "drift": drift,
        "curves": {k: (temperature_c, p) for k, p in preds.items()},
        "residuals": {k: target - p for k, p in preds.items()},
    }


def _family_labels(ax):
    """Legend label per family (the raw output's entries left out)."""
    labels = [lab for lab in ax.get_legend_handles_labels()[1] if "raw output" not in lab]
    return {name: next(lab for lab in labels
                       if lab.split(": ")[-1].split(" ")[0] == name) for name in COLOURS}


def _time_bins(x, y, nb=LIMIT_BINS):
    """Means in ``nb`` equal time bins, computed here independently of plots.py."""
    edges = np.linspace(x.min(), x.max(), nb + 1)
    idx = np.clip(np.digitize(x, edges) - 1, 0, nb - 1)
    return np.bincount(idx, weights=y, minlength=nb) / np.bincount(idx, minlength=nb)


def _check_scale(ax, binned_curves, *, noise_pp, diverged):
    lo, hi = ax.get_ylim()
    span = hi - lo
    for name, curve in binned_curves.items():   # the binned means of raw, baseline, chosen …
        assert lo < np.nanmin(curve) and np.nanmax(curve) < hi, (name, lo, hi)
    # … set the scale: a few times the drift's range, not the noise's nor the divergence's
    assert DRIFT_PP_MG <= span <= 5.0 * DRIFT_PP_MG, span
    assert span < 0.1 * noise_pp
    assert hi < 0.1 * diverged
    labels = _family_labels(ax)
    assert labels["poly3-rate"].endswith(OFF_SCALE)
    for name in ("rbf", "cubic", "poly2"):
        assert OFF_SCALE not in labels[name], labels[name]
    assert "(chosen)" in labels["rbf"] and "(baseline)" in labels["cubic"]
    return span


def _centred(y):
    return y - y.mean()


def test_residual_vs_time_scale_and_unit(ramp):
    fig = residual_vs_time_figure(time_s=ramp["time_s"], raw_error=ramp["target"],
                                  compensated=ramp["residuals"], axis="acc_z", units="mg",
                                  **STYLE)
    ax = fig.axes[0]
    x = (ramp["time_s"] - ramp["time_s"][0])
    binned = {"raw": _time_bins(x, _centred(ramp["target"])),
              "rbf": _time_bins(x, _centred(ramp["residuals"]["rbf"])),
              "cubic": _time_bins(x, _centred(ramp["residuals"]["cubic"]))}
    raw_pp = float(np.ptp(_centred(ramp["target"])))
    assert raw_pp > 300.0  # the samples' spread that used to set the scale
    span = _check_scale(ax, binned, noise_pp=raw_pp,
                        diverged=float(np.ptp(ramp["residuals"]["poly3-rate"])))
    # the raw drift (4 mg over the ramp) fills a good part of the height: not a flat line
    assert np.ptp(_time_bins(x, _centred(ramp["drift"]))) / span > 0.2
    # 200 s in seconds: the axis runs 0–200 s, not 0–0.056 h
    assert ax.get_xlabel() == "time from start (s)"
    x0, x1 = ax.get_xlim()
    assert -15.0 < x0 <= 0.0 and 199.0 < x1 < 215.0
    # the binned means are 1 s means (200 bins over 200 s) drawn over the faint samples
    assert "1 s means" in ax.get_title()


def test_drift_vs_temperature_scale(ramp):
    fig = drift_vs_temperature_figure(temperature_c=ramp["temperature_c"],
                                      observed_drift=ramp["target"], curves=ramp["curves"],
                                      axis="acc_z", units="mg", **STYLE)
    ax = fig.axes[0]
    t = ramp["temperature_c"]
    _, raw_binned = binned_means(t, _centred(ramp["target"]), 1.0)
    assert raw_binned.size == 12  # 24.5–35.5 °C: half-full bins at both ends
    span = _check_scale(ax, {"raw": raw_binned,
                             "rbf": _centred(ramp["curves"]["rbf"][1]),
                             "cubic": _centred(ramp["curves"]["cubic"][1])},
                        noise_pp=float(np.ptp(ramp["target"])),
                        diverged=float(np.ptp(ramp["curves"]["poly3-rate"][1])))
    # the chosen model's 4 mg correction spans most of the height
    assert DRIFT_PP_MG / span > 0.5
    assert ax.get_xlabel() == "temperature (°C)"


def test_residual_vs_temperature_scale(ramp):
    fig = residual_vs_temperature_figure(temperature_c=ramp["temperature_c"],
                                         raw_error=ramp["target"],
                                         compensated=ramp["residuals"], axis="acc_z",
                                         units="mg", **STYLE)
    ax = fig.axes[0]
    t = ramp["temperature_c"]
    binned = {name: binned_means(t, _centred(y), 1.0)[1] for name, y in
              (("raw", ramp["target"]), ("rbf", ramp["residuals"]["rbf"]),
               ("cubic", ramp["residuals"]["cubic"]))}
    span = _check_scale(ax, binned, noise_pp=float(np.ptp(ramp["target"])),
                        diverged=float(np.ptp(ramp["residuals"]["poly3-rate"])))
    assert np.ptp(binned["raw"]) / span > 0.5


def test_pngs_show_the_chosen_correction(tmp_path, ramp):
    """Real files: the documented size, and in the drift plot the chosen model's curve (its
    own colour) covers a good part of the plot's height instead of one flat row of pixels."""
    before = set(plt.get_fignums())
    p1 = plot_drift_vs_temperature(tmp_path / "drift.png", temperature_c=ramp["temperature_c"],
                                   observed_drift=ramp["target"], curves=ramp["curves"],
                                   axis="acc_z", units="mg", **STYLE)
    p2 = plot_residual_vs_time(tmp_path / "time.png", time_s=ramp["time_s"],
                               raw_error=ramp["target"], compensated=ramp["residuals"],
                               axis="acc_z", units="mg", **STYLE)
    p3 = plot_residual_vs_temperature(tmp_path / "rt.png", temperature_c=ramp["temperature_c"],
                                      raw_error=ramp["target"], compensated=ramp["residuals"],
                                      axis="acc_z", units="mg", **STYLE)
    assert set(plt.get_fignums()) == before
    for p in (p1, p2, p3):
        img = mpimg.imread(p)
        assert img.shape[:2] == (int(FIGSIZE_IN[1] * DPI), int(FIGSIZE_IN[0] * DPI))
        assert img[..., :3].std() > 0.05
    img = mpimg.imread(p1)[..., :3]
    orange = np.array([int(COLOURS["rbf"][i:i + 2], 16) / 255 for i in (1, 3, 5)])
    rows = np.flatnonzero((np.abs(img - orange).max(axis=2) < 0.08).any(axis=1))
    # the axes are about 460 px high (matplotlib's default subplot box on 600 px)
    assert rows.size > 150, rows.size


@pytest.mark.parametrize(("span_s", "unit", "seconds"), [
    (200.0, "s", 1.0), (600.0, "s", 1.0), (601.0, "min", 60.0), (3600.0, "min", 60.0),
    (3 * 3600.0, "min", 60.0), (3 * 3600.0 + 1, "h", 3600.0), (36000.0, "h", 3600.0),
    (0.0, "s", 1.0), (float("nan"), "s", 1.0)])
def test_time_unit_suits_the_length(span_s, unit, seconds):
    assert time_unit(span_s) == (unit, seconds)


@pytest.mark.parametrize(("span_s", "rate_hz", "unit", "end"), [
    (200.0, 500.0, "s", 200.0), (3600.0, 10.0, "min", 60.0), (36000.0, 1.0, "h", 10.0)])
def test_time_axis_in_the_unit_that_suits_the_length(span_s, rate_hz, unit, end):
    n = int(span_s * rate_hz) + 1
    rng = np.random.default_rng(3)
    t = 5000.0 + np.arange(n) / rate_hz
    raw = 0.01 * (t - t[0]) / span_s + 0.05 * rng.normal(size=n)
    fig = residual_vs_time_figure(time_s=t, raw_error=raw, compensated={"cubic": raw * 0.5},
                                  axis="gyro_x", units="deg/s", chosen="cubic")
    ax = fig.axes[0]
    assert ax.get_xlabel() == f"time from start ({unit})"
    x0, x1 = ax.get_xlim()
    assert end <= x1 <= 1.07 * end and -0.07 * end <= x0 <= 0.0
    ticks = [v for v in ax.get_xticks() if x0 <= v <= x1]
    assert 4 <= len(ticks) <= 12, ticks
    # the binned lines end at the end of the recording, in that unit
    xs = [line.get_xdata() for line in ax.get_lines()]
    assert max(np.nanmax(np.asarray(v, dtype=float)) for v in xs) == pytest.approx(end, rel=0.01)


def test_y_limits_are_the_binned_range_with_a_margin():
    lo, hi = y_limits([np.array([0.0, 1.0, np.nan]), np.array([3.0, -1.0])], margin=0.1)
    assert (lo, hi) == pytest.approx((-1.4, 3.4))
    assert y_limits([np.array([np.nan])]) is None
    assert y_limits([np.array([2.0, 2.0])]) is None  # no range: matplotlib autoscales


def test_a_few_samples_keep_the_whole_chosen_curve_in_frame():
    """Ten soaks (one sample each, like the four-position target): the curves are not
    averaged into one bin, so the chosen model's full 4 mg stays inside the frame."""
    temps = np.linspace(-20.0, 70.0, 10)
    drift = DRIFT_PP_MG * ((temps + 20.0) / 90.0) ** 3
    curves = {"cubic": (temps, drift), "rbf": (temps, 1.02 * drift),
              "poly3-rate": (temps, drift + DIVERGED_MG * (temps > 60))}
    fig = drift_vs_temperature_figure(temperature_c=temps, observed_drift=drift + 0.05,
                                      curves=curves, axis="acc_x.bias", units="mg",
                                      chosen="rbf", baseline="cubic", bin_width=1.0)
    lo, hi = fig.axes[0].get_ylim()
    rbf = 1.02 * drift - np.mean(1.02 * drift)
    assert lo < rbf.min() and rbf.max() < hi
    assert hi - lo < 1.3 * np.ptp(rbf)
    assert [lab for lab in fig.axes[0].get_legend_handles_labels()[1] if OFF_SCALE in lab] == [
        "predicted drift: poly3-rate (off scale)"]


def test_window_labels_in_natural_units():
    """A 1-hour log at 50 Hz drawn in minutes: its time windows are 3600 s / LIMIT_BINS long
    and the title says so in seconds ("18 s means" for 200 bins), never "0.3 min means"."""
    from thermonet.reporting.plot_style import duration_text

    t = np.arange(0.0, 3600.0, 0.02)
    err = 0.01 * np.sin(t / 600.0)
    fig = residual_vs_time_figure(time_s=t, raw_error=err, compensated={"cubic": 0.1 * err},
                                  axis="gyro_x", units="deg/s", chosen="cubic")
    ax = fig.axes[0]
    assert ax.get_xlabel() == "time from start (min)"
    window_s = (t[-1] - t[0]) / LIMIT_BINS                 # equal bins over the span
    assert f"{window_s:.3g} s means" in ax.get_title() and "min means" not in ax.get_title()
    plt.close(fig)
    assert [duration_text(s) for s in (5.574, 90.0, 750.0, 12600.0)] == [
        "5.57 s", "90 s", "12.5 min", "3.5 h"]


def test_a_model_on_dynamic_inputs_is_drawn_as_means_at_each_temperature():
    """Temperature cycled up and down: a model on the rate predicts another drift heating than
    cooling at one temperature.  Drawn sample by sample its curve zigzags into a filled
    wedge; it is drawn as its means in equal temperature bins (numpy's, by hand), while a
    model of temperature alone keeps its exact curve."""
    from thermonet.reporting.plots import depends_on_more_than, drift_vs_temperature_figure

    t = np.arange(0.0, 20000.0, 5.0)
    temp = 20.0 + 15.0 * np.sin(2 * np.pi * t / 5000.0)
    rate = np.gradient(temp, t) * 60.0                           # °C/min
    static = 1e-3 * (temp - 20.0) ** 2
    dynamic = static + 0.05 * rate
    assert depends_on_more_than(temp, dynamic) and not depends_on_more_than(temp, static)
    fig = drift_vs_temperature_figure(
        temperature_c=temp, observed_drift=dynamic, axis="gyro_x", units="deg/s",
        curves={"cubic": (temp, static), "poly3-rate": (temp, dynamic)}, chosen="poly3-rate",
        baseline="cubic")
    lines = {ln.get_label().split(": ", 1)[-1]: ln for ln in fig.axes[0].get_lines()}
    dyn = next(ln for k, ln in lines.items() if k.startswith("poly3-rate"))
    assert "(means at each temperature)" in dyn.get_label()
    x, y = dyn.get_xdata(), dyn.get_ydata()
    assert np.all(np.diff(x) > 0)                                  # one value per temperature
    edges = np.linspace(temp.min(), temp.max(), LIMIT_BINS + 1)
    k = np.clip(np.searchsorted(edges, temp, side="right") - 1, 0, LIMIT_BINS - 1)
    centred = dynamic - dynamic.mean()
    want = np.array([centred[k == b].mean() for b in range(LIMIT_BINS) if np.any(k == b)])
    np.testing.assert_allclose(y[np.isfinite(y)], want, rtol=1e-9, atol=1e-12)
    cub = next(ln for k, ln in lines.items() if k.startswith("cubic"))
    assert "means at each" not in cub.get_label()
    assert np.all(np.diff(cub.get_xdata()) >= 0) and len(cub.get_xdata()) > LIMIT_BINS
    plt.close(fig)


def test_the_y_scale_note_never_covers_the_legend_or_the_x_label(ramp):
    """With a curve off scale the figure explains its y-scale in a note: drawn in the figure's
    bottom margin, its box (as the renderer lays it out) overlaps neither the legend, nor the
    plotting area, nor the x label, and lies inside the figure."""
    from thermonet.reporting.plot_style import Y_SCALE_NOTE

    fig = residual_vs_time_figure(time_s=ramp["time_s"], raw_error=ramp["target"],
                                  compensated=ramp["residuals"], axis="acc_z", units="mg",
                                  **STYLE)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    ax = fig.axes[0]
    notes = [t for t in fig.texts if t.get_gid() == Y_SCALE_NOTE]
    assert len(notes) == 1 and "leave the frame" in notes[0].get_text()
    note = notes[0].get_window_extent(renderer)
    for other in (ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer),
                  ax.xaxis.label.get_window_extent(renderer)):
        assert not note.overlaps(other), (note, other)
    assert fig.bbox.contains(note.x0, note.y0) and fig.bbox.contains(note.x1, note.y1)
    plt.close(fig)


def test_high_rate_samples_are_drawn_as_a_binned_band(ramp):
    """The ramp's samples (more than the plots draw one by one) are a light band — mean ± sd
    in LIMIT_BINS equal bins, as numpy computes them bin by bin — not a cloud of dots that
    paints a solid block; in both the temperature and the time figure."""
    from thermonet.reporting.plots import MAX_SCATTER_POINTS, drift_vs_temperature_figure
    from thermonet.reporting.residual_plots import band_of

    temp, target = ramp["temperature_c"], ramp["target"]
    assert temp.size > MAX_SCATTER_POINTS
    centred = target - target.mean()
    cx, lo, hi = band_of(temp, centred)
    edges = np.linspace(temp.min(), temp.max(), LIMIT_BINS + 1)
    k = np.clip(np.searchsorted(edges, temp, side="right") - 1, 0, LIMIT_BINS - 1)
    for b in (0, LIMIT_BINS // 2, LIMIT_BINS - 1):
        v = centred[k == b]
        np.testing.assert_allclose([lo[b], hi[b]], [v.mean() - v.std(), v.mean() + v.std()],
                                   rtol=1e-9, atol=1e-9)
    figs = [drift_vs_temperature_figure(temperature_c=temp, observed_drift=target,
                                        curves=ramp["curves"], axis="acc_z", units="mg",
                                        **STYLE),
            residual_vs_time_figure(time_s=ramp["time_s"], raw_error=target,
                                    compensated=ramp["residuals"], axis="acc_z", units="mg",
                                    **STYLE)]
    for fig in figs:
        ax = fig.axes[0]
        bands = [c for c in ax.collections if "mean ± sd" in str(c.get_label())]
        assert len(bands) == 1
        assert not [c for c in ax.collections if c.get_label().startswith("raw output error (")
                    and "mean ± sd" not in c.get_label()]          # no scatter of samples
        plt.close(fig)
