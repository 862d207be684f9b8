"""Figures drawn by child processes (thermonet.reporting.plot_workers): the same files as drawn
in the command, every error raised as the command would raise it, no child left behind."""

from __future__ import annotations

import matplotlib.image as mpimg
import numpy as np
import pytest

from thermonet.reporting.colours import family_colours
from thermonet.reporting.plot_workers import PlotWorkers, draw_here


def _jobs(out, n_series: int = 3):
    rng = np.random.default_rng(4)
    t = np.linspace(-10.0, 60.0, 3000)
    raw = 0.01 * np.sin(t / 9.0) + rng.normal(0.0, 0.002, t.size)
    comp = {"cubic": raw - 0.01 * np.sin(t / 9.0), "linear": raw - 0.0002 * t}
    colours = family_colours(list(comp))
    jobs = []
    for k in range(n_series):
        jobs.append(("plot_residual_vs_temperature", dict(
            path=out / f"res_{k}.png", temperature_c=t, raw_error=raw + k * 1e-3,
            compensated=comp, axis=f"gyro_{k}", units="°/s", bin_width=1.0,
            x_label="temperature (°C)", chosen="cubic", baseline="cubic", colours=colours)))
        jobs.append(("plot_allan", dict(
            path=out / f"allan_{k}.png", rate_hz=10.0, raw_error=raw, compensated=comp,
            axis=f"gyro_{k}", units="°/s", chosen="cubic", colours=colours)))
    return jobs


def test_children_draw_the_figures_the_command_draws(tmp_path):
    here = draw_here(_jobs(tmp_path / "here"))
    with PlotWorkers(2) as drawers:
        procs = [h._proc for h in drawers._helpers]
        assert len(procs) == 2
        there = drawers.draw(_jobs(tmp_path / "there"))
        assert drawers._helpers == []                  # ended once they have drawn
    assert all(p is not None and p.poll() is not None for p in procs)
    assert [p.name for p in there] == [p.name for p in here]      # the order of the jobs
    for a, b in zip(here, there, strict=True):
        assert b.parent == tmp_path / "there"
        np.testing.assert_array_equal(mpimg.imread(a), mpimg.imread(b))


def test_a_figure_that_fails_in_a_child_is_drawn_here_and_raises_as_here(tmp_path):
    jobs = _jobs(tmp_path)
    bad = dict(jobs[2][1], compensated={"cubic": np.zeros(5)})     # lengths do not match
    jobs[2] = ("plot_residual_vs_temperature", bad)
    with PlotWorkers(2) as drawers, pytest.raises(ValueError, match=r"'compensated\['cubic'\]' has 5"):
        drawers.draw(jobs)
    assert drawers._helpers == []


def test_leaving_on_an_error_kills_the_children_at_once():
    drawers = PlotWorkers(2)
    procs = [h._proc for h in drawers._helpers]
    with pytest.raises(RuntimeError), drawers:
        raise RuntimeError("the comparison failed before its figures")
    assert all(p is not None and p.poll() is not None for p in procs)


def test_one_worker_or_fewer_draws_in_this_process(tmp_path):
    drawers = PlotWorkers(1)
    assert drawers._helpers == []
    assert [p.name for p in drawers.draw(_jobs(tmp_path, 1))] == ["res_0.png", "allan_0.png"]


def test_a_helper_imports_first_then_runs_calls_and_reports_errors_in_one_line():
    import select as sel

    from thermonet.core.helpers import Helper, HelperGone

    with Helper(["json"]) as h:
        stream = h.stream()
        assert stream is not None
        while not h.ready():                       # event-driven: wait for its "ready"
            sel.select([stream], [], [], 5.0)
        h.submit("json", "dumps", obj={"b": [1, 2.5]}, sort_keys=True)
        assert not h.ready()                       # busy until its result is taken
        assert h.result() == (True, '{"b": [1, 2.5]}')
        h.submit("json", "loads", s="{not json")
        ok, line = h.result()
        assert not ok and line.startswith("JSONDecodeError: ") and "\n" not in line
        proc = h._proc
        h.submit("os", "_exit", status=3)          # the child dies in the call
        with pytest.raises(HelperGone):
            h.result()
        assert proc is not None and proc.poll() is not None and h.stream() is None
        assert not h.ready()


def test_a_helpers_first_call_is_answered_before_its_imports():
    """``first=``: the call is run as the child starts, before its imports — its reply (one
    larger than a pipe holds, sent while the child imports) comes first, then the child says
    it is ready and serves calls as any helper; a first call that raises comes back as one
    line and the child still becomes ready."""
    import select as sel

    from thermonet.core.helpers import Helper

    with Helper(["json"], first=("thermonet.core.names", "path_component",
                                 {"name": "a/b"})) as h:
        assert not h.ready()                       # the first call is in flight
        ok, value = h.result()
        assert ok and value == _path_component("a/b")
        while not h.ready():
            sel.select([h.stream()], [], [], 5.0)
        h.submit("json", "dumps", obj=[1])
        assert h.result() == (True, "[1]")
    big = "x" * (1 << 20)                           # 1 MB: many times a pipe's buffer
    with Helper(["json"], first=("builtins", "str", {"object": big})) as h:
        assert h.result() == (True, big)
        h.stream()
        while not h.ready():
            sel.select([h.stream()], [], [], 5.0)
    with Helper(["json"], first=("json", "loads", {"s": "{"})) as h:
        ok, line = h.result()
        assert not ok and line.startswith("JSONDecodeError: ")
        while not h.ready():
            sel.select([h.stream()], [], [], 5.0)


def _path_component(name: str) -> str:
    from thermonet.core.names import path_component

    return path_component(name)


def test_a_first_call_pickle_cannot_carry_is_left_to_the_caller():
    """A first call with an argument pickle refuses (a lambda) is refused before any process
    starts (ValueError); the drawers then start without it and the caller does that work."""
    from thermonet.core.helpers import Helper

    call = ("builtins", "len", {"obj": lambda: 0})
    with pytest.raises(ValueError, match="cannot be sent"):
        Helper(["json"], first=call)
    with PlotWorkers(2, first=call) as drawers:
        assert not drawers.has_first and drawers.first_result() is None
        assert len(drawers._helpers) == 1          # the other waits for start_rest
        drawers.start_rest()
        assert len(drawers._helpers) == 2


def test_with_a_first_call_the_other_drawers_start_later(tmp_path):
    """With a first call only the first drawer starts at once; the others start at
    ``start_rest`` (compare: once torch is imported) or, at the latest, when the figures
    are drawn — the same figures either way."""
    with PlotWorkers(2, first=("json", "dumps", {"obj": 1})) as drawers:
        assert len(drawers._helpers) == 1 and drawers.first_result() == "1"
        got = drawers.draw(_jobs(tmp_path, 2))
    assert [p.name for p in got] == [p.name for p in draw_here(_jobs(tmp_path / "here", 2))]


def test_a_first_result_pickle_cannot_carry_comes_back_as_one_line():
    """The first call's result cannot be pickled (a lock): the child says so in one
    line instead of sending it, and still becomes ready and serves calls."""
    import select as sel

    from thermonet.core.helpers import Helper

    with Helper(["json"], first=("threading", "Lock", {})) as h:
        ok, line = h.result()
        assert not ok and "cannot be sent" in line and "\n" not in line
        while not h.ready():
            sel.select([h.stream()], [], [], 5.0)
        h.submit("json", "dumps", obj=[2])
        assert h.result() == (True, "[2]")


def test_what_a_call_logs_is_said_by_the_command_when_it_takes_the_result(caplog, capfd):
    """A call that logs a warning in the helper (a file's skipped rows, a damaged log): the
    child does not print it; the command logs it — same logger, level and message — when
    it takes the result, as if the call had run there."""
    import logging

    from thermonet.core.helpers import Helper

    with caplog.at_level(logging.WARNING), \
            Helper(["json"], first=("logging", "warning", {"msg": "said in the helper"})) as h:
        assert h.result() == (True, None)
    said = [(r.name, r.levelno, r.getMessage()) for r in caplog.records]
    assert said == [("root", logging.WARNING, "said in the helper")]
    assert "said in the helper" not in capfd.readouterr().err
