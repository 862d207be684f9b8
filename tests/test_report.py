"""report.html: one self-contained page, parsed and rendered in a real headless chromium."""

from __future__ import annotations

import base64
import shutil
import subprocess
from html.parser import HTMLParser

import matplotlib.image as mpimg
import numpy as np
import pytest

from conftest import toy_dataset
from thermonet.data.io import write_parquet
from thermonet.reporting.report import VERDICT_COLOURS, render_report
from thermonet.training.config import CompareConfig, FamilyConfig, TrainConfig
from thermonet.training.config_sections import DataConfig
from thermonet.workflows.compare import run_compare


class _Page(HTMLParser):
    """Collects what a reader sees: tags, image sources, table cells, external references."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[str] = []
        self.images: list[str] = []
        self.cells: list[str] = []
        self.external: list[str] = []
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        a = dict(attrs)
        if tag == "img":
            self.images.append(a.get("src", ""))
        for key in ("src", "href"):
            if a.get(key) and not a[key].startswith("data:"):
                self.external.append(a[key])
        if tag == "td":
            self._cell = []

    def handle_endtag(self, tag):
        if tag == "td" and self._cell is not None:
            self.cells.append(" ".join(self._cell))
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data.strip())


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("report")
    path = write_parquet(toy_dataset(n_runs=3), tmp / "toy.parquet")
    fams = [FamilyConfig(family="poly", name="cubic", params={"degree": 3}),
            FamilyConfig(family="linear", name="linear.co-1")]  # markup in names is refused (names.py)
    cfg = CompareConfig(data=DataConfig(paths=[str(path)]), families=fams,
                        train=TrainConfig(max_epochs=15, patience=4), baseline="cubic")
    res = run_compare(cfg, tmp / "out", track=False, quiet=True)
    return res, tmp / "out" / "report.html"


def test_report_is_one_self_contained_page(report):
    res, path = report
    page = _Page()
    page.feed(path.read_text(encoding="utf-8"))
    assert page.tags[0] == "html" and "table" in page.tags
    assert page.external == []  # nothing outside the file: no link, no script, no remote image
    assert "script" not in page.tags
    # every plot embedded as a PNG
    n_plots = len(list((path.parent / "plots").glob("*.png")))
    assert n_plots == 5 and len(page.images) == n_plots  # 4 per axis + accuracy vs cost
    for src in page.images:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    # the verdict table: the cubic beats raw on the quadratic drift, with its interval
    cubic = res["families"]["cubic"]["axes"]["gyro_x"]
    lo, hi = cubic["interval"]
    assert f"better {cubic['score_ratio']:.3g} [{lo:.3g}, {hi:.3g}]" in page.cells
    text = path.read_text(encoding="utf-8")
    assert f"background:{VERDICT_COLOURS['better']}" in text
    assert "linear.co-1" in text
    assert "Chosen: <b>cubic</b>" in text


def test_report_renders_in_headless_chromium(report, tmp_path):
    _, path = report
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.fail("chromium is not installed: the report must be checked in a real browser "
                    "(apt-get install chromium; the Makefile's test set-up does it)")
    shot = tmp_path / "shot.png"
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--no-first-run", f"--user-data-dir={tmp_path / 'profile'}",
           f"--screenshot={shot}", "--window-size=1200,1600", path.as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    img = mpimg.imread(shot)[..., :3]
    assert img.shape[:2] == (1600, 1200)
    # not blank: text, coloured verdict cells and plots vary the pixels …
    assert img.std() > 0.08
    dark = (img.mean(axis=2) < 0.5).mean()
    assert 0.01 < dark < 0.5
    # … and the green of a "better" cell is on screen
    green = np.array([int(VERDICT_COLOURS["better"][i:i + 2], 16) / 255 for i in (1, 3, 5)])
    assert (np.abs(img - green).max(axis=2) < 0.02).sum() > 500


def test_render_report_without_plots_and_with_a_failed_family():
    res = {"device": "d", "units": {"acc_x": "mg"}, "baseline": None, "chosen": None,
           "chosen_reason": "do no harm", "warnings": ["a <warning>"],
           "families": {"poly6": {"status": "failed", "reason": "3 distinct temperatures"}}}
    html = render_report(res)
    assert "not fitted: 3 distinct temperatures" in html
    assert "a &lt;warning&gt;" in html and "<img" not in html


def test_the_report_says_what_the_gate_held_back_and_why():
    """issue 48: where the pool only heats, a model reading the rate is held back — the report
    says so beside the candidate and once below the table, with the folds' note; a candidate
    the gate found worse on a fold says its own reason."""
    why_rate = ("the training data hold only heating: a model reading the rate, a lag or a "
                "hysteresis memory cannot be judged on cooling")
    sel = {"kind": "excursions", "folds": 3, "purge_s": 180.0, "window_s": 60.0,
           "note": "2 heating legs, 1 cooling leg", "rule": "chose cubic",
           "candidates": {
               "cubic": {"status": "ok", "n_params": 4, "score": 0.3, "interval": [0.2, 0.4],
                         "fold_scores": [0.3, 0.31, 0.29], "axes": {}},
               "poly3-rate": {"status": "ok", "n_params": 8, "score": 0.2,
                              "interval": [0.1, 0.3], "fold_scores": [0.2, 0.2, 0.2],
                              "axes": {}, "not_eligible": why_rate},
               "rbf": {"status": "ok", "n_params": 30, "score": 0.25, "interval": [0.2, 0.3],
                       "fold_scores": [0.2, 0.4, 0.2], "axes": {},
                       "not_eligible": "gate: not better than the baseline cubic everywhere"}},
           "held_back": {"candidates": ["poly3-rate"], "why": why_rate,
                         "by_candidate": {"poly3-rate": why_rate}}}
    page = _Page()
    page.feed(render_report({"device": "d", "units": {}, "baseline": "cubic", "chosen": "cubic",
                             "chosen_reason": "chose cubic", "families": {},
                             "selection": sel}))
    html = "".join(page.cells)
    assert "held back (below)" in page.cells
    assert "gate: not better than the baseline cubic everywhere" in page.cells
    text = render_report({"device": "d", "units": {}, "baseline": "cubic", "chosen": "cubic",
                          "families": {}, "selection": sel})
    assert f"<b>poly3-rate</b>: {why_rate}" in text and "Folds: 2 heating legs" in text
    assert why_rate not in html                      # said once, below the table


@pytest.mark.parametrize("members, listed", [
    ({"cubic": {}}, None),                      # no member was tuned: no line at all
    ({"cubic": {}, "poly3-rate": {"degree": 2, "tuning": {"grid": {"degree=2": 0.41},
                                                          "rule": "chose degree=2"}}},
     "<li><b>per-axis</b>: poly3-rate: degree=2</li>"),
])
def test_the_per_axis_models_tuning_is_its_members_or_nothing(members, listed):
    """The per-axis model's ``tuned`` is {member: its tuned values} (as results.json writes it):
    the hyper-parameter list names each tuned member, and says nothing where none was tuned
    (was '<b>per-axis</b>: ' with nothing after it)."""
    axis = {"score_ratio": 0.5, "interval": [0.4, 0.6], "verdict": "better", "compensate": True}
    res = {"device": "d", "units": {"gyro_x": "deg/s"}, "baseline": None, "chosen": "per-axis",
           "chosen_reason": "each axis its own model", "families": {
               "poly3-rate": {"status": "ok", "axes": {"gyro_x": axis},
                              "tuned": members.get("poly3-rate", {})},
               "per-axis": {"status": "ok", "axes": {"gyro_x": axis}, "tuned": members}}}
    page = render_report(res)
    assert "<b>per-axis</b>: </li>" not in page
    items = [li for li in page.split("<li>")[1:] if li.startswith("<b>per-axis</b>")]
    assert ["<li>" + li.split("</ul>")[0] for li in items] == ([listed] if listed else [])


#: Measures the page as laid out: the document's scroll and client widths, and the right edge
#: of the widest element against the body's (appended to a copy of the report only: the
#: report itself carries no script).
_MEASURE = ("<script>var b = document.body.getBoundingClientRect().right, m = 0;"
            "document.querySelectorAll('body *').forEach(function (e) {"
            "m = Math.max(m, e.getBoundingClientRect().right); });"
            "document.body.setAttribute('data-measure', [document.documentElement.scrollWidth,"
            "document.documentElement.clientWidth, Math.ceil(m), Math.ceil(b)].join(' '));"
            "</script></body>")


@pytest.fixture(scope="module")
def six_axis_report(tmp_path_factory):
    """A six-axis IMU (3 gyros, 3 accelerometers) with a baseline: the widest verdict table."""
    from thermonet.sim import simulate

    tmp = tmp_path_factory.mktemp("six")
    ds = simulate("consumer-imu", runs=3, seed=0, sample_rate_hz=0.2)
    cfg = CompareConfig(families=[
        FamilyConfig(family="poly", name="cubic", inputs=["dT"], params={"degree": 3}),
        FamilyConfig(family="linear", name="line", inputs=["dT"])], baseline="cubic")
    res = run_compare(cfg, tmp / "out", dataset=ds, track=False, quiet=True)
    return res, tmp / "out" / "report.html"


@pytest.mark.parametrize("width", [1280, 1600])
def test_six_axis_report_reads_without_scrolling_sideways(six_axis_report, width, tmp_path):
    """Laid out by chromium at 1,280 and 1,600 px: nothing is wider than the window and no
    element sticks out of the page's body (the verdict table is stacked per sensor: one for
    the gyros, one for the accelerometers, each with every family)."""
    res, path = six_axis_report
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium is not None, "chromium is needed (the Makefile's test set-up installs it)"
    text = path.read_text(encoding="utf-8")
    assert text.count("<th>family</th><th>params</th><th>validation score</th>") == 2
    probe = tmp_path / "probe.html"
    probe.write_text(text.replace("</body>", _MEASURE), encoding="utf-8")
    proc = subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu",
                           "--no-first-run", f"--user-data-dir={tmp_path / 'profile'}",
                           f"--window-size={width},2000", "--dump-dom", probe.as_uri()],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    import re

    found = re.search(r'data-measure="(\d+) (\d+) (\d+) (\d+)"', proc.stdout)
    assert found, proc.stdout[-500:]
    scroll, client, widest, body = (int(v) for v in found.groups())
    # the window less its vertical scroll bar (the page is long), and no horizontal one
    assert width - 20 <= client <= width and scroll <= client
    assert widest <= body                                 # nothing drawn past the body


@pytest.fixture(scope="module")
def calibration_report(tmp_path_factory):
    """A real calibration of a simulated flight-controller board (PX4, nine instances; seed 0
    leaves three axes marginal in the held-out check)."""
    import json

    from thermonet.cli import main

    tmp = tmp_path_factory.mktemp("cal")
    assert main(["simulate", "fc-board", "--runs", "1", "--seed", "0",
                 "--out", str(tmp / "b.ulg")]) == 0
    assert main(["calibrate", str(tmp / "b.ulg"), "--out", str(tmp / "cal"), "--no-compare",
                 "-q"]) == 0
    return json.loads((tmp / "cal" / "results.json").read_text()), tmp / "cal" / "report.html"


def test_a_marginal_axis_has_its_own_colour(calibration_report):
    """A fitted instance's result cell takes its worst held-out grade's colour: amber where an
    axis is marginal (was green, like fine ones), green where every axis is fine."""
    import re

    from thermonet.reporting.colours import GRADE_COLOURS

    doc, path = calibration_report
    cells = dict(re.findall(r'<tr><td>(\w+)</td>.*?background:(#[0-9a-f]{6})',
                            path.read_text(encoding="utf-8")))
    grades = {n: d["held_out"]["grades"] for n, d in doc["instances"].items()
              if (d.get("held_out") or {}).get("status") == "judged"}
    marginal = sorted(n for n, g in grades.items() if "marginal" in g and "fails" not in g)
    fine = sorted(n for n, g in grades.items() if set(g) == {"fine"})
    assert marginal and fine                                   # this board has both
    assert {cells[n] for n in marginal} == {GRADE_COLOURS["marginal"]}
    assert {cells[n] for n in fine} == {GRADE_COLOURS["fine"]}
    assert len(set(GRADE_COLOURS.values())) == 3


#: The calibration page as chromium lays it out: the most line boxes any device-id cell takes,
#: the text report's scroll and client widths, and the document's.
_MEASURE_CAL = (
    "<script>var most = 0;"
    "document.querySelectorAll('table tr').forEach(function (r) {"
    "var c = r.cells[2]; if (!c || c.tagName != 'TD') return;"
    "var g = document.createRange(); g.selectNodeContents(c); var ys = {};"
    "Array.prototype.forEach.call(g.getClientRects(), function (q) {"
    "ys[Math.round(q.top)] = 1; });"
    "most = Math.max(most, Object.keys(ys).length); });"
    "var p = document.querySelector('pre');"
    "document.body.setAttribute('data-measure', [most, p.scrollWidth, p.clientWidth,"
    "document.documentElement.scrollWidth, document.documentElement.clientWidth].join(' '));"
    "</script></body>")


def test_the_calibration_report_reads_at_1400_px(calibration_report, tmp_path):
    """Laid out by chromium at 1,400 px: every device id on one line (was one or two digits a
    line), and the text report wrapped, never scrolled sideways (was 3,000 px wide)."""
    import re

    _, path = calibration_report
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium is not None, "chromium is needed (the Makefile's test set-up installs it)"
    probe = tmp_path / "probe.html"
    probe.write_text(path.read_text(encoding="utf-8").replace("</body>", _MEASURE_CAL),
                     encoding="utf-8")
    proc = subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu",
                           "--no-first-run", f"--user-data-dir={tmp_path / 'profile'}",
                           "--window-size=1400,2000", "--dump-dom", probe.as_uri()],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    found = re.search(r'data-measure="(\d+) (\d+) (\d+) (\d+) (\d+)"', proc.stdout)
    assert found, proc.stdout[-500:]
    id_lines, pre_scroll, pre_client, scroll, client = (int(v) for v in found.groups())
    assert id_lines == 1
    assert pre_scroll <= pre_client and scroll <= client
