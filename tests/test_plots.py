"""Plots: readable PNGs of the documented size, distinct colours, no figure leak."""

from __future__ import annotations

import matplotlib.colors as mcolors
import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np
import pytest

from thermonet.reporting.plot_style import _gap_breaks, _minmax_indices
from thermonet.reporting.plots import (
    DPI,
    FIGSIZE_IN,
    MAX_LINE_POINTS,
    _binned,
    family_colours,
    plot_allan,
    plot_drift_vs_temperature,
)
from thermonet.reporting.residual_plots import plot_residual_vs_temperature, plot_residual_vs_time

N = 50_000
RATE_HZ = 10.0
EXPECTED_SHAPE = (int(FIGSIZE_IN[1] * DPI), int(FIGSIZE_IN[0] * DPI))


@pytest.fixture(scope="module")
def run():
    rng = np.random.default_rng(0)
    time_s = np.arange(N) / RATE_HZ
    temperature_c = -20.0 + 80.0 * np.arange(N) / N
    drift = 0.002 * (temperature_c - 25.0) + 1e-4 * (temperature_c - 25.0) ** 2
    raw_error = drift + 0.01 * rng.normal(size=N)
    return time_s, temperature_c, drift, raw_error


def _read_png(path):
    assert path.stat().st_size > 10_000
    img = mpimg.imread(path)
    assert img.shape[:2] == EXPECTED_SHAPE
    # Something was drawn: the image is not one flat colour.
    assert img[..., :3].std() > 0.05
    return img


def test_drift_vs_temperature(tmp_path, run):
    time_s, temp, drift, raw_error = run
    grid = np.linspace(-20, 60, 200)
    curves = {"linear": (grid, 0.002 * (grid - 25.0)),
              "quadratic": (grid[::-1], (0.002 * (grid - 25.0) + 1e-4 * (grid - 25.0) ** 2)[::-1])}
    before = set(plt.get_fignums())
    path = plot_drift_vs_temperature(tmp_path / "new" / "dir" / "drift.png", temperature_c=temp,
                                     observed_drift=raw_error + 9.81, curves=curves,
                                     axis="acc_z", units="m/s^2", chosen="quadratic",
                                     baseline="linear")
    assert path == tmp_path / "new" / "dir" / "drift.png"
    _read_png(path)
    assert set(plt.get_fignums()) == before


def test_residual_vs_time_and_allan(tmp_path, run):
    time_s, temp, drift, raw_error = run
    residuals = {"linear": raw_error - 0.002 * (temp - 25.0), "perfect": raw_error - drift}
    p1 = plot_residual_vs_time(tmp_path / "res.png", time_s=time_s + 2.5655e8,
                               raw_error=raw_error, compensated=residuals, axis="gyro_x",
                               units="deg/s", chosen="perfect")
    p2 = plot_allan(str(tmp_path / "allan.png"), rate_hz=RATE_HZ, raw_error=raw_error,
                    compensated=residuals, axis="gyro_x", units="deg/s")
    p3 = plot_residual_vs_temperature(tmp_path / "rt.png", temperature_c=temp,
                                      raw_error=raw_error, compensated=residuals, axis="gyro_x",
                                      units="deg/s", chosen="perfect", baseline="linear")
    for p in (p1, p2, p3):
        _read_png(p)


def test_every_family_gets_its_own_colour_never_raw_grey():
    labels = [f"family{i}" for i in range(40)]
    colours = family_colours(labels)
    rgb = np.array([mcolors.to_rgb(colours[k]) for k in labels])
    # distinct (no wrapping at 10 or 20) …
    dist = np.abs(rgb[:, None, :] - rgb[None, :, :]).max(axis=2) + np.eye(len(labels))
    assert dist.min() > 0.05
    # … and none a grey like the raw output's (saturation well above 0)
    sat = np.array([mcolors.rgb_to_hsv(c)[1] for c in rgb])
    assert sat.min() > 0.2
    assert family_colours(["a", "b"]) == {"a": colours["family0"], "b": colours["family1"]}


def test_binned_means_do_not_bridge_empty_temperature_ranges():
    t = np.r_[np.full(50, 13.2), np.full(50, 48.4)]  # two isothermal soaks
    y = np.r_[np.zeros(50), np.ones(50)]
    x, m = _binned(t, y, 1.0)
    assert np.isnan(x).sum() == 1 and np.isnan(m).sum() == 1
    np.testing.assert_allclose(m[~np.isnan(m)], [0.0, 1.0])


def test_lines_keep_about_two_points_per_pixel_column():
    assert MAX_LINE_POINTS == 2 * FIGSIZE_IN[0] * DPI


def test_many_calls_leak_no_figures(tmp_path):
    before = set(plt.get_fignums())
    y = np.random.default_rng(1).normal(size=500)
    for i in range(10):
        plot_allan(tmp_path / f"a{i}.png", rate_hz=1.0, raw_error=y, compensated={},
                   axis="acc_z", units="mg")
    assert set(plt.get_fignums()) == before
    assert len(list(tmp_path.glob("a*.png"))) == 10


def test_minmax_decimation_keeps_the_envelope_and_gaps():
    rng = np.random.default_rng(2)
    y = rng.normal(size=100_003)
    y[54_321] = 40.0  # a spike plain striding would miss
    keep = _minmax_indices(y, 8000)
    assert keep.size <= 8000
    assert np.all(np.diff(keep) > 0)
    assert y[keep].max() == 40.0 and y[keep].min() == y.min()
    # A burst log: 1 s steps with one 1000 s pause after sample 60_000.
    t = np.arange(y.size, dtype=float)
    t[60_000:] += 1000.0
    breaks = _gap_breaks(t, keep)
    assert breaks.size == 1
    assert keep[breaks[0] - 1] < 60_000 <= keep[breaks[0]]


def test_mismatched_lengths_name_the_series(tmp_path):
    with pytest.raises(ValueError, match=r"compensated\['lorentz'\]' has 9 samples"):
        plot_residual_vs_time(tmp_path / "x.png", time_s=np.arange(10.0),
                              raw_error=np.zeros(10), compensated={"lorentz": np.zeros(9)},
                              axis="acc_x", units="mg")
    with pytest.raises(ValueError, match="curve 'linear'"):
        plot_drift_vs_temperature(tmp_path / "y.png", temperature_c=np.arange(10.0),
                                  observed_drift=np.zeros(10), curves={"linear": (np.arange(3.0),)},
                                  axis="acc_x", units="mg")


def test_accuracy_against_cost_marks_the_front_and_the_chosen(tmp_path):
    """Held-out error against operations per sample, log x; the front joins the
    families nothing beats on both (here linear, cubic, rbf — not mlp: rbf is cheaper and
    better); a family without a known cost is left out; the chosen one is ringed."""
    from thermonet.reporting.plots import accuracy_cost_figure, plot_accuracy_cost

    points = {"linear": (2.0, 0.9), "cubic": (5.0, 0.5), "rbf": (125.0, 0.45),
              "mlp": (144.0, 0.6), "plug-in": (None, 0.3)}
    fig = accuracy_cost_figure(points, chosen="rbf", baseline="cubic")
    ax = fig.axes[0]
    assert ax.get_xscale() == "log"
    front, = (ln for ln in ax.get_lines() if ln.get_label().startswith("front"))
    assert list(front.get_xdata()) == [2.0, 5.0, 125.0]
    assert list(front.get_ydata()) == [0.9, 0.5, 0.45]
    offsets = {c.get_label(): tuple(c.get_offsets()[0]) for c in ax.collections}
    assert offsets == {"linear": (2.0, 0.9), "cubic (baseline)": (5.0, 0.5),
                       "rbf (chosen)": (125.0, 0.45), "mlp": (144.0, 0.6)}
    ringed = [c.get_label() for c in ax.collections
              if c.get_linewidths()[0] > 0 and mcolors.to_hex(c.get_edgecolors()[0]) == "#000000"]
    assert ringed == ["rbf (chosen)"]
    path = plot_accuracy_cost(tmp_path / "front.png", points, chosen="rbf", baseline="cubic")
    assert mpimg.imread(path).shape[:2] == (600, 1000)


def test_a_title_placed_at_its_default_draws_the_same_pixels(tmp_path):
    """plot_style._title names y=1.0 (skipping matplotlib's search for decorations above the
    axes, a fifth of a figure's drawing); the figure is pixel for pixel the one the default
    placement draws."""
    from thermonet.reporting.plot_style import _new_figure, _save, _title

    images = []
    for named in (False, True):
        fig, ax = _new_figure()
        ax.plot(np.linspace(0.0, 1.0, 50), np.sin(np.linspace(0.0, 6.0, 50)), label="a")
        ax.legend()
        ax.set_xlabel("x")
        text = "gyro_x: a title long enough to matter (about its mean)"
        if named:
            _title(ax, text)
        else:
            ax.set_title(text)
        images.append(mpimg.imread(_save(fig, tmp_path / f"t{named}.png")))
    assert images[0].shape == images[1].shape
    np.testing.assert_array_equal(images[0], images[1])
