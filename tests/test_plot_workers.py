"""Figures drawn by child processes (thermonet.reporting.plot_workers, on core.helpers' process
pool): the same files as drawn in the command, every error raised as the command would raise
it, no child left behind."""

from __future__ import annotations

import os
import time

import matplotlib.image as mpimg
import numpy as np
import pytest

from thermonet.core.helpers import Helpers, value_or_none
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


def _procs(helpers: Helpers | None) -> list:
    """The pool's worker processes (started so far)."""
    assert helpers is not None and helpers._pool is not None
    return list(helpers._pool._processes.values())


def _until_gone(procs: list) -> bool:
    """Whether every worker process has ended, waited for (at most 60 s): once a worker dies
    the pool's own thread reaps it, and ``Process.is_alive`` asked from here meanwhile can
    lose that race for the exit status and say "alive" for good — so the process table is
    asked (a reaped pid is gone)."""
    deadline = time.monotonic() + 60
    while True:
        alive = []
        for p in procs:
            try:
                os.kill(p.pid, 0)
            except ProcessLookupError:
                continue
            if p.exitcode is None:            # not reaped yet: a zombie or still running
                alive.append(p)
        if not alive or time.monotonic() > deadline:
            return not alive
        time.sleep(0.02)


def _until_ready(h: Helpers) -> None:
    deadline = time.monotonic() + 120
    while not h.ready():
        assert time.monotonic() < deadline and not h.failed(), "the helpers did not start"
        time.sleep(0.02)


def test_children_draw_the_figures_the_command_draws(tmp_path):
    here = draw_here(_jobs(tmp_path / "here"))
    with PlotWorkers(2) as drawers:
        procs = _procs(drawers._helpers)
        assert len(procs) == 2
        there = drawers.draw(_jobs(tmp_path / "there"))
        assert drawers._helpers is None                # ended once they have drawn
    assert all(not p.is_alive() for p in procs)
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
    assert drawers._helpers is None


def test_leaving_on_an_error_kills_the_children_at_once():
    drawers = PlotWorkers(2)
    procs = _procs(drawers._helpers)
    with pytest.raises(RuntimeError), drawers:
        raise RuntimeError("the comparison failed before its figures")
    assert procs and all(not p.is_alive() for p in procs)


def test_one_worker_or_fewer_draws_in_this_process(tmp_path):
    drawers = PlotWorkers(1)
    assert drawers._helpers is None
    assert [p.name for p in drawers.draw(_jobs(tmp_path, 1))] == ["res_0.png", "allan_0.png"]


def test_helpers_import_first_then_run_calls_and_leave_a_failed_call_to_the_caller():
    """A call that raises, or whose worker dies, gives None (the caller does that work,
    where a genuine error is raised in its own one line); a dead worker breaks the pool:
    every later call gives None, none hangs."""
    with Helpers(1, ["json"]) as h:
        _until_ready(h)
        assert value_or_none(h.submit("json", "dumps", obj={"b": [1, 2.5]}, sort_keys=True)) \
            == '{"b": [1, 2.5]}'
        assert value_or_none(h.submit("json", "loads", s="{not json")) is None
        procs = _procs(h)
        assert value_or_none(h.submit("os", "_exit", status=3)) is None   # dies in the call
        assert value_or_none(h.submit("json", "dumps", obj=[1])) is None
        assert _until_gone(procs)
    assert h.failed() and not h.ready()


def test_a_helpers_first_call_is_answered_before_its_imports():
    """``first=``: the call is run as the first worker starts, before its imports (they are
    queued at :meth:`Helpers.start`); a value larger than a pipe holds comes back whole; a
    first call that raises gives None and the workers still become ready."""
    with Helpers(1, ["json"], first=("thermonet.core.names", "path_component",
                                     {"name": "a/b"})) as h:
        assert not h.ready()                       # nothing imported before start()
        assert value_or_none(h.first) == _path_component("a/b")
        h.start()
        _until_ready(h)
        assert value_or_none(h.submit("json", "dumps", obj=[1])) == "[1]"
    big = "x" * (1 << 20)                           # 1 MB: many times a pipe's buffer
    with Helpers(1, ["json"], first=("builtins", "str", {"object": big})) as h:
        assert value_or_none(h.first) == big
    with Helpers(1, ["json"], first=("json", "loads", {"s": "{"})) as h:
        assert value_or_none(h.first) is None
        h.start()
        _until_ready(h)


def _path_component(name: str) -> str:
    from thermonet.core.names import path_component

    return path_component(name)


def test_a_first_call_pickle_cannot_carry_is_left_to_the_caller():
    """A first call with an argument pickle refuses (a lambda) gives None (the caller does
    that work); the drawers still start and draw."""
    call = ("builtins", "len", {"obj": lambda: 0})
    with Helpers(1, ["json"], first=call) as h:
        assert value_or_none(h.first) is None
        h.start()
        _until_ready(h)
        assert value_or_none(h.submit("json", "dumps", obj=[3])) == "[3]"
    with PlotWorkers(2, first=call) as drawers:
        assert drawers.first_result() is None
        drawers.start_rest()
        assert len(_procs(drawers._helpers)) == 2


def test_with_a_first_call_the_other_drawers_start_later(tmp_path):
    """With a first call only the first drawer starts at once; the others start at
    ``start_rest`` (compare: once torch is imported) or, at the latest, when the figures
    are drawn — the same figures either way."""
    with PlotWorkers(2, first=("json", "dumps", {"obj": 1})) as drawers:
        assert len(_procs(drawers._helpers)) == 1 and drawers.first_result() == "1"
        got = drawers.draw(_jobs(tmp_path, 2))
    assert [p.name for p in got] == [p.name for p in draw_here(_jobs(tmp_path / "here", 2))]


def test_a_first_result_pickle_cannot_carry_is_left_to_the_caller():
    """The first call's result cannot be pickled (a lock): None, and the workers still
    serve calls."""
    with Helpers(1, ["json"], first=("threading", "Lock", {})) as h:
        assert value_or_none(h.first) is None
        h.start()
        _until_ready(h)
        assert value_or_none(h.submit("json", "dumps", obj=[2])) == "[2]"


def test_what_a_call_logs_is_said_by_the_command_when_it_takes_the_result(caplog, capfd):
    """A call that logs a warning in the helper (a file's skipped rows, a damaged log): the
    child does not print it; the command logs it — same logger, level and message — when
    it takes the result, as if the call had run there."""
    import logging

    with caplog.at_level(logging.WARNING), \
            Helpers(1, ["json"], first=("logging", "warning", {"msg": "said in the helper"})) as h:
        assert value_or_none(h.first) is None          # logging.warning returns None
    said = [(r.name, r.levelno, r.getMessage()) for r in caplog.records]
    assert said == [("root", logging.WARNING, "said in the helper")]
    assert "said in the helper" not in capfd.readouterr().err


def test_a_script_without_a_main_guard_gets_no_workers(tmp_path):
    """A ``spawn`` worker imports a main script run by path again: without
    ``if __name__ == "__main__":`` its body would run in every worker, so none is started
    there (the command draws alone); a guarded script, ``-c`` and ``-m`` get them."""
    import subprocess
    import sys

    use = "from thermonet.reporting.plot_workers import PlotWorkers\n"
    scripts = {"plain": use + "with PlotWorkers(2) as d:\n    print(d._helpers is not None)\n",
               "guarded": use + "if __name__ == '__main__':\n    with PlotWorkers(2) as d:\n"
                                "        print(d._helpers is not None)\n"}
    got = {}
    for name, text in scripts.items():
        script = tmp_path / f"{name}.py"
        script.write_text(text)
        r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                           timeout=300)
        got[name] = (r.returncode, r.stdout.strip(), "Traceback" in r.stderr)
    assert got == {"plain": (0, "False", False), "guarded": (0, "True", False)}
