"""Papercuts of `fleet`, `export`, `simulate` and `prior`: limits on an axis the data lacks,
an --out that cannot be made (refused before any unit is fitted), "-0" in a quantity's name,
--workers 0, device ids beyond 32 bits, --all-units on the wrong directory, a four-position
model as autopilot parameters, and files replaced only with --overwrite."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from thermonet.cli import main
from thermonet.core.errors import ConfigError, InputError
from thermonet.scoring.fleetstats import fleet_html_fragment
from thermonet.sim import simulate_fleet
from thermonet.training.config import CompareConfig, FamilyConfig
from thermonet.workflows.fleet import FleetOptions, run_fleet
from thermonet.workflows.fleet_summary import fleet_summary, format_fleet_table
from thermonet.workflows.fleet_units import UnitSource, sources_from_dataset
from thermonet.workflows.verify_params import read_param_file

FOURPOS = ("target: four-position\nfeatures: {t_ref: 20.0}\n"
           "families:\n  - {name: cubic, family: poly}\n")
#: What a four-position unit's px4-params export says (after its checkpoint's path).
FOURPOS_PX4 = ("a four-position model (bias and scale factor per axis: acc_x.bias, acc_x.scale) "
               "cannot be written as px4-params: PX4/ArduPilot files hold a per-axis offset "
               "polynomial in temperature; export it as ONNX or C (--format onnx or --format c)")


def _line(capsys: pytest.CaptureFixture[str]) -> str:
    """The one line on stderr."""
    lines = [ln for ln in capsys.readouterr().err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    return lines[0]


def _cubic() -> CompareConfig:
    cfg = CompareConfig(families=[FamilyConfig(family="poly", name="cubic", inputs=["dT"],
                                               params={"degree": 3})])
    cfg.tracking.enabled = False
    return cfg


@pytest.fixture(scope="module")
def accel_fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two simulated accelerometer units, four runs each, in one Parquet file."""
    root = tmp_path_factory.mktemp("accel2")
    assert main(["simulate", "accel", "--units", "2", "--runs", "4", "--seed", "0",
                 "--out", str(root / "a2.parquet")]) == 0
    return root / "a2.parquet"


@pytest.fixture(scope="module")
def fourpos_fleet(accel_fleet: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fleet of the two units, each a four-position (bias and scale factor) model."""
    root = tmp_path_factory.mktemp("fourpos")
    cfg = root / "f.yaml"
    cfg.write_text(f"data:\n  paths: [{accel_fleet}]\n" + FOURPOS)
    assert main(["fleet", str(cfg), "--out", str(root / "f1"), "--no-track", "--executor",
                 "serial", "--folds", "0", "--no-plots", "-q"]) == 0
    return root / "f1"


@pytest.fixture(scope="module")
def cubic_compare(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A comparison of one cubic on the accel preset (a model PX4 can hold)."""
    root = tmp_path_factory.mktemp("cmp")
    cfg = root / "c.yaml"
    cfg.write_text("data: {preset: accel, seed: 0, runs: 4}\n"
                   "families:\n  - {name: cubic, family: poly}\n")
    assert main(["compare", str(cfg), "--out", str(root / "cmp"), "--no-track", "-q",
                 "--no-plots"]) == 0
    return root / "cmp"


# ------------------------------------------------------------------ fleet: limits' axes
def test_fleet_limits_on_an_axis_the_data_lacks_are_refused(accel_fleet, tmp_path, capsys):
    cfg = tmp_path / "f.yaml"
    cfg.write_text(f"data:\n  paths: [{accel_fleet}]\n" + FOURPOS
                   + "limits:\n  acc_x.bais: {max_pp: 0.00001}\n  gyro_x: {max_pp: 0.00001}\n")
    out = tmp_path / "f1"
    assert main(["fleet", str(cfg), "--out", str(out), "--no-track", "--executor",
                 "serial"]) == 1
    assert _line(capsys) == (f"thermonet: error: {cfg}: key 'limits.acc_x.bais': not an output "
                             "of the data (its outputs: acc_x.bias, acc_x.scale; '*' for "
                             "every one)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.yaml"]   # nothing written
    # a simulated fleet (--units): the preset's channels
    sim = tmp_path / "s.yaml"
    sim.write_text("data: {preset: accel, runs: 4}\nlimits:\n  '*': {max_pp: 1.0}\n"
                   "  gyro_x: {max_pp: 0.00001}\n")
    assert main(["fleet", str(sim), "--units", "2", "--out", str(out), "--no-track"]) == 1
    assert _line(capsys) == (f"thermonet: error: {sim}: key 'limits.gyro_x': not an output of "
                             "the data (its outputs: acc_x; '*' for every one)")
    assert not out.exists()


def test_fleet_limits_are_checked_before_any_unit_is_read(tmp_path):
    # these units' data cannot be read: a plan that fitted them first would report them
    # failed; the limits are refused before
    cfg = _cubic()
    cfg.limits = {"gyro_y": {"max_pp": 1.0}}
    sources = [UnitSource(d, error=f"unit '{d}': never read", axes=["gyro_x"]) for d in "ab"]
    with pytest.raises(ConfigError) as err:
        run_fleet(cfg, tmp_path / "f1", sources, quiet=True)
    assert str(err.value) == ("config: key 'limits.gyro_y': not an output of the data (its "
                              "outputs: gyro_x; '*' for every one)")
    assert list(tmp_path.iterdir()) == []


def test_fleet_limits_checked_after_fitting_where_the_plan_could_not_tell(tmp_path):
    ds = simulate_fleet("accel", units=2, runs=4, seed=0)
    sources = sources_from_dataset(ds)
    for s in sources:
        s.axes = None       # outputs not known before the units are fitted
    cfg = _cubic()
    cfg.limits = {"acc_y": {"max_pp": 1.0}}
    with pytest.raises(ConfigError, match=r"^config: key 'limits\.acc_y': not an output of "
                                          r"the data \(its outputs: acc_x; "):
        run_fleet(cfg, tmp_path / "f1", sources, quiet=True,
                  options=FleetOptions(executor="serial", folds=0), plots=False)
    assert list(tmp_path.iterdir()) == []   # no fleet, no staging directory left


# ------------------------------------------------------------------ fleet: --out, --workers
def test_fleet_out_that_cannot_be_made_is_refused_before_fitting(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("mine")
    sources = [UnitSource("a", error="unit 'a': never read", axes=["gyro_x"])]
    with pytest.raises(InputError) as err:
        run_fleet(_cubic(), blocker / "f1", sources, quiet=True)
    assert str(err.value) == f"{blocker / 'f1'}: --out cannot be created: {blocker} is not a " \
                             "directory"
    if not Path("/proc/self").is_dir():
        pytest.skip("no /proc: no directory that not even root can write")
    # /proc exists and takes no new directory (not even root's): the fleet's own --out named,
    # not its staging directory, and before the units run
    out = Path("/proc") / "thermonet-papercut-f1"
    cfg = tmp_path / "s.yaml"
    cfg.write_text("data: {preset: accel, runs: 4}\n")
    assert main(["fleet", str(cfg), "--units", "2", "--out", str(out), "--no-track",
                 "--executor", "serial"]) == 1
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"thermonet: error: {out}: --out cannot be "
                                                   "created (")
    assert ".partial" not in lines[0] and "chosen" not in captured.out


def test_fleet_workers_0_is_one_per_cpu_as_compare(tmp_path):
    with pytest.raises(ConfigError) as err:
        FleetOptions(workers=-1)
    assert str(err.value) == "--workers -1: must be an integer >= 0 (0: one per CPU)"
    sources = [UnitSource(d, error=f"unit '{d}': no data here", axes=["gyro_x"]) for d in "ab"]
    res = run_fleet(_cubic(), tmp_path / "f1", sources, quiet=True, plots=False,
                    options=FleetOptions(executor="serial", workers=0, folds=0))
    assert [u["reason"] for u in res["units"].values()] == ["unit 'a': no data here",
                                                            "unit 'b': no data here"]
    written = json.loads((tmp_path / "f1" / "results.json").read_text())
    assert written["options"]["workers"] == 0 and written["kind"] == "fleet"


# ------------------------------------------------------------------ fleet: names shown
def _unit(c0: float) -> dict:
    return {"status": "ok", "temperature_range_c": [-20.02, 19.98], "families": {},
            "coefficients": {"gyro_x.c0": c0, "gyro_x.c1": 0.0}}


def test_fleet_curve_points_have_no_minus_zero_and_text_shows_degrees():
    units = {f"u{k}": _unit(c0) for k, c0 in enumerate((1.0, 1.01, 0.99, 1.005, 0.995, 9.0))}
    summary = fleet_summary(units, "cubic", {}, {})
    # linspace(-20.02, 19.98, 5) rounded to 0.1 °C: -20, -10, -0.0 (printed "-0"), 10, 20
    assert sorted(q for q in summary["spread"] if "drift@" in q) == sorted(
        f"cubic.gyro_x.drift@{t}C" for t in ("-20", "-10", "0", "10", "20"))
    flags = summary["outliers"]["u5"]
    assert sorted(f["quantity"] for f in flags) == sorted(
        f"cubic.gyro_x.drift@{t}C" for t in ("-20", "-10", "0", "10", "20"))
    for u in units.values():
        u["limits"] = {"verdict": "NOT JUDGED", "axes": {}, "reasons": []}
    results = {"units": units, "fleet": summary, "fleet_family": "cubic"}
    row = next(ln for ln in format_fleet_table(results).splitlines() if ln.startswith("u5 "))
    z = flags[0]["z"]
    assert row.endswith(f"cubic.gyro_x.drift@-20 °C z={z:.1f}, "
                        f"cubic.gyro_x.drift@-10 °C z={z:.1f}")
    assert "cubic.gyro_x.drift@0 °C z=" in fleet_html_fragment(results)


# ------------------------------------------------------------------ export: device ids
def test_export_device_id_must_be_a_32_bit_id(cubic_compare, tmp_path, capsys):
    out = tmp_path / "t.params"
    argv = ["export", str(cubic_compare), "--format", "px4-params", "--out", str(out)]
    assert main([*argv, "--device-id", "99999999999"]) == 1
    assert _line(capsys) == ("thermonet: error: --device-id must be the sensor's positive "
                             "device id, got 99999999999: PX4 and ArduPilot device ids are "
                             "32-bit, 1..4294967295")
    assert main(argv) == 1
    assert _line(capsys) == ("thermonet: error: --device-id is required with --format "
                             "px4-params: PX4 applies the TC_* parameters only to the sensor "
                             "whose device id equals TC_*_ID (read it with 'listener "
                             "sensor_gyro' / 'listener sensor_accel')")
    assert not out.exists()
    # the largest id: PX4's INT32 parameter holds it as -1, which verify reads back as it
    assert main([*argv, "--device-id", "4294967295"]) == 0
    assert "1\t1\tTC_A0_ID\t-1\t6" in out.read_text().splitlines()
    assert ("acc", 4294967295) in read_param_file(out).by_id


# ------------------------------------------------------------------ export: fleets
def test_export_all_units_of_a_compare_directory_is_refused(cubic_compare, tmp_path, capsys):
    out = tmp_path / "xx"
    assert main(["export", str(cubic_compare), "--all-units", "--format", "onnx",
                 "--out", str(out)]) == 1
    assert _line(capsys) == (f"thermonet: error: {cubic_compare}: a compare directory, not a "
                             "fleet: export it without --all-units (--out a file)")
    assert list(tmp_path.iterdir()) == []


def test_export_all_units_of_a_station_directory_says_what_it_holds(tmp_path, capsys):
    """A station's output was "not a fleet directory": it says what it is and offers."""
    st = tmp_path / "st"
    (st / "units" / "1001").mkdir(parents=True)
    (st / "results.json").write_text(json.dumps({"schema": 1, "kind": "station", "units": {
        "1001": {"verdict": "PASS", "files": "units/1001"}}}))
    assert main(["export", str(st), "--all-units", "--format", "px4-params", "--out",
                 str(tmp_path / "px4")]) == 1
    assert _line(capsys) == (f"thermonet: error: {st}: a station directory, not a fleet: each "
                             "unit's calibration is already written there (units/<id>/"
                             "calibration.json and thermonet_cal.h, the firmware's C header); "
                             "a station writes no autopilot parameters")
    assert not (tmp_path / "px4").exists()


def test_export_of_a_fleet_directory_points_to_all_units(fourpos_fleet, tmp_path, capsys):
    assert main(["export", str(fourpos_fleet), "--format", "onnx",
                 "--out", str(tmp_path / "f.onnx")]) == 1
    assert _line(capsys) == (f"thermonet: error: {fourpos_fleet}: a fleet directory, not one "
                             "comparison: export every unit with --all-units (--out a "
                             f"directory), or one unit from {fourpos_fleet}/units/<device id>")
    assert list(tmp_path.iterdir()) == []


def test_export_of_a_calibrate_directory_says_what_to_use(tmp_path, capsys):
    """A calibrate directory given to export was "results.json: key 'families': not a
    mapping of family results": it now says what the directory is and what to use — its
    parameter file as it is, or one instance's comparison with the firmware family."""
    from thermonet.data.logs.writers import write_log
    from thermonet.sim.fcboard import simulate_board
    from thermonet.workflows.calibrate import calibrate

    log = write_log(simulate_board(seed=2, rate_hz=0.5, autopilot="ardupilot"),
                    tmp_path / "b.bin")
    cal = tmp_path / "cal"
    calibrate(log, cal, compare=False)
    argv = ["export", str(cal), "--format", "ardupilot-params", "--out", str(tmp_path / "a.parm")]
    assert main(argv) == 1
    assert _line(capsys) == (f"thermonet: error: {cal}: a calibrate directory (one parameter "
                             f"file for every sensor), not one comparison: load its parameter "
                             f"file {cal / 'ardupilot.parm'} as it is; it holds no per-instance "
                             "comparison to export (run it without --no-compare for "
                             "instances/<name>/)")
    for name in ("gyro0", "acc0"):           # what calibrate's comparison leaves there
        (cal / "instances" / name).mkdir(parents=True)
    assert main(argv) == 1
    assert _line(capsys).endswith(f"as it is, or export one instance's comparison: thermonet "
                                  f"export {cal / 'instances' / 'acc0'} --family ardupilot-cubic "
                                  "(instances: acc0, gyro0)")
    assert not (tmp_path / "a.parm").exists()


def test_export_all_units_that_exports_nothing_leaves_nothing(fourpos_fleet, tmp_path, capsys):
    out = tmp_path / "a" / "px4"
    assert main(["export", str(fourpos_fleet), "--all-units", "--format", "px4-params",
                 "--device-id", "1", "--out", str(out)]) == 1
    assert _line(capsys) == (f"thermonet: error: {fourpos_fleet}: no unit exported, nothing "
                             "written: 2 units ('accel-u000', 'accel-u001'): not exported: "
                             f"models/cubic.pt: {FOURPOS_PX4}")
    assert list(tmp_path.iterdir()) == []     # neither px4/ nor the a/ made for it


def test_export_four_position_unit_as_autopilot_parameters_says_why(fourpos_fleet, tmp_path,
                                                                    capsys):
    unit = fourpos_fleet / "units" / "accel-u000"
    assert main(["export", str(unit), "--format", "px4-params", "--device-id", "1",
                 "--out", str(tmp_path / "u.params")]) == 1
    assert _line(capsys) == f"thermonet: error: {unit}/models/cubic.pt: {FOURPOS_PX4}"
    assert main(["export", str(unit), "--format", "ardupilot-params",
                 "--out", str(tmp_path / "u.parm")]) == 1
    assert _line(capsys) == (f"thermonet: error: {unit}/models/cubic.pt: "
                             + FOURPOS_PX4.replace("px4-params", "ardupilot-params"))
    assert list(tmp_path.iterdir()) == []
    # what the line says can be written: ONNX
    assert main(["export", str(unit), "--format", "onnx", "--out", str(tmp_path / "u.onnx")]) == 0


# ------------------------------------------------------------------ one file: --overwrite
def test_simulate_replaces_a_file_only_with_overwrite(tmp_path, capsys):
    mine = tmp_path / "mine.csv"
    mine.write_text("mine\n")
    argv = ["simulate", "accel", "--runs", "1", "--out", str(mine)]
    assert main(argv) == 1
    assert _line(capsys) == f"thermonet: error: {mine}: already exists (give --overwrite to " \
                            "replace it)"
    assert mine.read_text() == "mine\n"
    assert main([*argv, "--overwrite"]) == 0
    assert capsys.readouterr().out.startswith(f"wrote {mine}: preset accel, 1 run, ")
    assert mine.read_text().startswith("run,device,time_s,temperature_c,acc_x,")   # + its id
    # a board's logs: each one it would write is checked before any is simulated
    (tmp_path / "b_run2.ulg").write_text("mine")
    assert main(["simulate", "fc-board", "--runs", "2", "--out", str(tmp_path / "b.ulg")]) == 1
    assert _line(capsys) == f"thermonet: error: {tmp_path / 'b_run2.ulg'}: already exists " \
                            "(give --overwrite to replace it)"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b_run2.ulg", "mine.csv"]


def test_export_replaces_a_file_only_with_overwrite(cubic_compare, tmp_path, capsys):
    out = tmp_path / "m.h"
    argv = ["export", str(cubic_compare), "--format", "c", "--out", str(out)]
    assert main(argv) == 0
    first = out.read_bytes()
    out.write_text("/* edited */")
    assert main(argv) == 1
    assert _line(capsys) == f"thermonet: error: {out}: already exists (give --overwrite to " \
                            "replace it)"
    assert out.read_text() == "/* edited */"
    assert main([*argv, "--overwrite"]) == 0
    assert out.read_bytes() == first


def test_prior_replaces_a_file_only_with_overwrite(tmp_path, capsys):
    cfg = tmp_path / "p.yaml"
    cfg.write_text("data: {preset: accel, seed: 0, runs: 1}\nfeatures: {t_ref: 25.0}\n")
    out = tmp_path / "prior.json"
    out.write_text("{}")
    argv = ["prior", str(cfg), "--units", "10", "--out", str(out), "-q"]
    assert main(argv) == 1
    assert _line(capsys) == f"thermonet: error: {out}: already exists (give --overwrite to " \
                            "replace it)"
    assert out.read_text() == "{}"
    assert main([*argv, "--overwrite"]) == 0
    assert json.loads(out.read_text())["kind"] == "fleet-prior"


# ------------------------------------------------------------------ messages name the flag
@pytest.mark.parametrize("argv, line", [
    (["--units", "0"], "--units must be at least 1, got 0"),
    (["--units", "6", "--clusters", "20"], "--clusters must be between 0 and units "
                                           "(--units 6), got 20"),
])
def test_simulate_fleet_sizes_name_the_flag(tmp_path, capsys, argv, line):
    assert main(["simulate", "accel", *argv, "--out", str(tmp_path / "z.parquet")]) == 1
    assert _line(capsys) == f"thermonet: error: {line}"
    assert list(tmp_path.iterdir()) == []


def test_export_of_a_data_file_says_what_it_is(tmp_path, capsys):
    """A recording given where a model is expected: one line saying it is data to compare
    first (was torch's "Unsupported operand 80"), nothing written."""
    data = tmp_path / "pg.parquet"
    assert main(["simulate", "patent-gyro", "--runs", "1", "--out", str(data)]) == 0
    capsys.readouterr()
    assert main(["export", str(data), "--format", "onnx", "--out", str(tmp_path / "m.onnx")]) == 1
    assert _line(capsys) == (f"thermonet: error: {data}: a data file, not a compare directory, "
                             "checkpoint (.pt) or MLflow run id: run 'thermonet compare' on it "
                             "first")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pg.parquet"]


@pytest.mark.parametrize("argv, line", [
    (["--format", "ardupilot-params", "--device-id", "7"],
     "--device-id applies to --format px4-params only (PX4's TC_*_ID); ardupilot-params follows "
     "the IMU number: --instance"),
    (["--format", "onnx", "--device-id", "7"],
     "--device-id applies to --format px4-params only (PX4's TC_*_ID); onnx names no sensor"),
    (["--format", "c", "--instance", "1"],
     "--instance applies to --format px4-params and ardupilot-params only; c names no "
     "calibration slot"),
    (["--format", "onnx", "--prefix", "imu1"],
     "--prefix applies to --format c only (the C symbols' prefix); onnx has no symbols"),
    (["--format", "c", "--prefix", "1imu"],
     "--prefix '1imu' is not a C identifier (letters, digits and '_', not starting with a "
     "digit), e.g. imu0"),
])
def test_export_options_a_format_has_no_use_for_are_refused(tmp_path, capsys, argv, line):
    """Was: taken and ignored without a word."""
    assert main(["export", str(tmp_path / "nothing-read"), *argv, "--out",
                 str(tmp_path / "x.out")]) == 1
    assert _line(capsys) == f"thermonet: error: {line}"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, line", [
    (["station", "c.yaml", "--prior", "p.json", "--out", ""], "--out is empty: give a path"),
    (["prior", "c.yaml", "--out", " "], "--out is empty: give a path"),
    (["station", "c.yaml", "--prior", "", "--out", "st"], "--prior is empty: give a path"),
    (["station", "c.yaml", "--prior", ".", "--out", "st"],
     ".: --prior is a directory; give the prior file (prior.json)"),
])
def test_an_empty_path_or_a_directory_for_a_file_is_named(tmp_path, monkeypatch, capsys, argv,
                                                         line):
    """Was: "" read as "." ("--out is not empty …"), a directory for --prior "no such file"."""
    monkeypatch.chdir(tmp_path)
    Path("c.yaml").write_text("data: {preset: consumer-imu, runs: 1}\n"
                              "target: {gyro: zero, acc: at-t-ref}\n")
    assert main(argv) == 1
    assert _line(capsys) == f"thermonet: error: {line}"
    assert [p.name for p in tmp_path.iterdir()] == ["c.yaml"]


def test_export_c_prefix_names_every_symbol(cubic_compare, tmp_path, capsys):
    """``--prefix``: two IMUs' headers in one program need their own symbols and guard (the
    default prefix twice is a compile error: exporting.c_header.guard_open)."""
    assert main(["export", str(cubic_compare), "--format", "c", "--prefix", "imu1",
                 "--out", str(tmp_path / "imu1.h")]) == 0
    text = (tmp_path / "imu1.h").read_text()
    assert "IMU1_N_AXES" in text and "imu1_step(" in text and "THERMONET_N_AXES" not in text


def test_a_four_position_model_runs_as_export_readme_says(fourpos_fleet, accel_fleet,
                                                         tmp_path, capsys):
    """export/README.md: a four-position model given the temperature and 0 in its
    ``<axis>.bias`` / ``<axis>.scale`` columns returns K0(T) and K1(T) as their ``_drift``
    (was undocumented: the runtime asked for a column 'acc_x.bias' a user's data lack).  The
    independent expectation: the unit's own per-soak four-position estimates
    (thermonet.sim.fourpos: y = K0 + K1·x_ref regressed in each soak)."""
    import numpy as np

    from conftest import load_runtime
    from thermonet.data.io import read_dataset
    from thermonet.sim.fourpos import four_position_estimates

    unit = fourpos_fleet / "units" / "accel-u000"
    assert main(["export", str(unit), "--format", "onnx", "--out", str(tmp_path / "u.onnx")]) == 0
    capsys.readouterr()
    comp = load_runtime().Compensator(str(tmp_path / "u.onnx"))
    assert comp.outputs == ["acc_x.bias", "acc_x.scale"]
    runs = [r for r in read_dataset(accel_fleet) if r.device_id == "accel-u000"]
    est = np.array([e for r in runs for e in four_position_estimates(r)])
    got = comp.compensate(temperature_c=est[:, 0], raw=np.zeros((len(est), 2))).drift
    # the model follows the soaks' own K0(T) and K1(T) to a tenth of their range over T
    assert np.all(np.abs(got - est[:, 1:]) < 0.1 * np.ptp(est[:, 1:], axis=0)), (got, est)
    assert abs(float(np.median(got[:, 1])) - 1.0) < 0.05     # a scale factor, not its change


def test_export_of_a_held_back_family_says_so(tmp_path, capsys):
    """A family the comparison's gate held back (toy ramps heat only: a model reading the rate
    cannot be judged on cooling) is exported as asked with ``--family``, with one warning
    saying it was held back and why; the baseline's export says nothing."""
    from conftest import toy_dataset
    from thermonet.workflows.compare import run_compare

    cfg = CompareConfig(families=[
        FamilyConfig(family="poly", name="cubic", inputs=["dT"], params={"degree": 3}),
        FamilyConfig(family="poly", name="rate", inputs=["dT", "rate"], params={"degree": 2})],
        baseline="cubic")
    cfg.tracking.enabled = False
    cfg.train.max_epochs = 20
    res = run_compare(cfg, tmp_path / "cmp", dataset=toy_dataset(dt_s=10.0), quiet=True,
                      plots=False)
    why = res["selection"]["held_back"]["by_candidate"]["rate"]
    assert why.startswith("the training data hold only heating")
    capsys.readouterr()
    assert main(["export", str(tmp_path / "cmp"), "--family", "rate", "--format", "onnx",
                 "--out", str(tmp_path / "rate.onnx")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"thermonet: warning: {tmp_path / 'cmp' / 'results.json'}: family 'rate' "
                   f"was held back by the comparison ({why}); exported as asked, but nothing "
                   "showed it beats the baseline there, and its out_of_range flag is set "
                   "wherever its dynamic inputs leave what training held"], err
    assert (tmp_path / "rate.onnx").stat().st_size > 0
    assert main(["export", str(tmp_path / "cmp"), "--family", "cubic", "--format", "onnx",
                 "--out", str(tmp_path / "cubic.onnx")]) == 0
    assert capsys.readouterr().err == ""
