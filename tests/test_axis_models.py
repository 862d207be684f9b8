"""A per-axis model (:class:`thermonet.models.composite.AxisModels`) shipped as one artifact.

A synthetic 4-axis device whose axes want different families: ``gyro_x`` a cubic in ΔT,
``gyro_y`` a saturating curve (an RBF), ``gyro_z`` a term in the heating rate (a poly on
``dT`` and the dynamic input ``rate``), ``acc_x`` nothing worth compensating (left raw).
The three candidates are fitted on every axis, composed with the owner table
``[poly3, rbf, poly3-rate, raw]``, and the composite goes everywhere a single-family model
goes: its checkpoint (round trip, the seal), the ONNX graph (onnxruntime per axis), the
torch-free runtime (batch, ``step``, ``step_block``), the C header (batch and stream, the
double and the float path) and ``thermonet export`` from a compare-like directory.
"""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import torch

from conftest import load_runtime
from thermonet.core.errors import ConfigError, ExportError, InputError
from thermonet.core.trainconfig import TrainConfig
from thermonet.exporting import export_onnx
from thermonet.exporting.c_stream import float_path_slack
from thermonet.exporting.parity import float32_tolerance
from thermonet.features import dynamics
from thermonet.features.inputs import FeatureSpec
from thermonet.models.composite import AxisModels
from thermonet.training.checkpoint import (
    checkpoint_digest,
    load_checkpoint,
    save_checkpoint,
)
from thermonet.training.train import fit
from tolerances import assert_f32_close

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

AXES = ["gyro_x", "gyro_y", "gyro_z", "acc_x"]
LABELS = ["poly3", "rbf", "poly3-rate"]
OWNER = [0, 1, 2, None]
GAP_S = 5.0

rt = load_runtime()


def _device() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Time, temperature (heat/cool triangles), the rate signal and the 4 axes' drift."""
    t = np.arange(0.0, 30000.0, 2.0)
    phase = (t % 8000.0) / 8000.0
    temp = -10.0 + 70.0 * (1.0 - np.abs(2.0 * phase - 1.0))
    rate = dynamics.compute(t, temp, ["rate"], GAP_S)[0]["rate_c_per_min"]
    dT = temp - 20.0
    y = np.column_stack([0.01 * dT - 2e-4 * dT ** 2 + 3e-6 * dT ** 3,
                         0.02 * np.tanh(dT / 10.0),
                         0.005 * dT + 0.03 * rate,
                         1e-4 * np.sin(temp)])
    return t, temp, rate, y


def _fit(family: str, inputs: list[str], hyper: dict):
    _, temp, rate, y = _device()
    spec = FeatureSpec(inputs=inputs, t_ref=20.0, gap_s=GAP_S)
    cols = {"temperature_c": temp, "rate_c_per_min": rate}
    s = np.column_stack([cols[x] for x in spec.signals])
    return fit(family=family, inputs=inputs, outputs=AXES, train=[(s, y)], val=None, spec=spec,
               hyper=hyper, config=TrainConfig(max_epochs=3, seed=0)).model


@pytest.fixture(scope="module")
def parts():
    """The three candidates, each fitted on every axis (unmasked)."""
    return [_fit("poly", ["dT"], {"degree": 3}), _fit("rbf", ["dT"], {}),
            _fit("poly", ["dT", "rate"], {"degree": 2, "cross": True})]


@pytest.fixture(scope="module")
def composite(parts):
    return AxisModels(copy.deepcopy(parts), OWNER, LABELS).eval()


@pytest.fixture(scope="module")
def onnx_path(composite, tmp_path_factory):
    return export_onnx(composite, tmp_path_factory.mktemp("axis") / "per-axis.onnx")


def _stream(seed: int = 0, n: int = 2000):
    """A jittered stream inside the trained range, with a gap and a missing temperature."""
    rng = np.random.default_rng(seed)
    t = 1.7e9 + np.cumsum(rng.uniform(0.5, 1.5, n))
    t[n // 2:] += 4 * GAP_S
    phase = ((t - t[0]) % 3000.0) / 3000.0
    temp = -5.0 + 60.0 * (1.0 - np.abs(2.0 * phase - 1.0))
    temp[n // 3] = np.nan
    raw = rng.normal(0.0, 0.01, (n, len(AXES)))
    return t, temp, raw


def _signals(model, t: np.ndarray, temp: np.ndarray) -> np.ndarray:
    """The model's signal matrix of a stream (float64 dynamic inputs)."""
    dyn, _ = dynamics.compute(t, temp, model.inputs, GAP_S)
    cols = {"temperature_c": temp, **dyn}
    return np.column_stack([cols[s] for s in model.signals])


def _grid(model, n: int = 3000, seed: int = 1) -> np.ndarray:
    lo = model.sig_lo.double().numpy()
    hi = model.sig_hi.double().numpy()
    return np.random.default_rng(seed).uniform(lo, hi, (n, lo.size))


def _tolerance(model, pts: np.ndarray) -> np.ndarray:
    """Per axis, the export's own parity tolerance (a second float32 implementation against
    torch: 1e-5 of the axis's largest drift, or 4× torch's own float32 rounding against a
    float64 evaluation where the model is more sensitive; tests/test_c_header.py)."""
    with torch.no_grad():
        d = model.relative(torch.from_numpy(pts.astype(np.float32))).double().numpy()
    return float32_tolerance(model, pts.astype(np.float32), d)


# -- the composite itself -----------------------------------------------------------------
def test_each_axis_is_its_owners_drift_exactly_and_the_raw_axis_is_zero(composite):
    s = torch.from_numpy(_grid(composite))
    with torch.no_grad():
        whole = composite.drift64(s).numpy()
        for a, k in enumerate(OWNER):
            if k is None:
                # a masked axis is exactly 0 in every part: the sum is exactly 0
                assert np.array_equal(whole[:, a], np.zeros(len(s)))
                continue
            part = composite.parts[k]
            own = part.drift64(s[:, composite.columns[k]]).numpy()[:, a]
            # the other parts add exact zeros: bit-identical to the owner's drift
            assert np.array_equal(whole[:, a], own), AXES[a]
    assert composite.axis_table() == dict(zip(AXES, ["poly3", "rbf", "poly3-rate", None],
                                              strict=True))
    assert composite.signals == ["temperature_c", "rate_c_per_min"]
    assert composite.spec.dynamic is not None and composite.spec.gap_s == GAP_S


def test_nan_signal_gives_nan_on_every_axis_and_sets_the_flag(composite):
    s = torch.tensor([[20.0, 0.1], [float("nan"), 0.1], [20.0, float("nan")], [99.0, 0.0]])
    with torch.no_grad():
        d = composite.drift64(s).numpy()
        flag = composite.out_of_range(s).numpy()
    assert np.isfinite(d[0]).all() and np.isnan(d[1]).all() and np.isnan(d[2]).all()
    assert flag.tolist() == [False, True, True, True]   # booleans


def test_parts_that_cannot_be_composed_are_refused(parts):
    with pytest.raises(ConfigError, match="owns no axis"):
        AxisModels(copy.deepcopy(parts), [0, 0, 2, None], LABELS)
    with pytest.raises(ConfigError, match="names no part"):
        AxisModels(copy.deepcopy(parts), [0, 1, 3, None], LABELS)


# -- checkpoint ---------------------------------------------------------------------------
def test_checkpoint_round_trip_gives_the_same_outputs(composite, tmp_path):
    path = save_checkpoint(tmp_path / "per-axis.pt", composite, config={"model": "per-axis"},
                           extra={"label": "per-axis"})
    loaded, meta = load_checkpoint(path)
    assert isinstance(loaded, AxisModels)
    assert meta["family"] == "per-axis" and meta["owner"] == OWNER and meta["labels"] == LABELS
    assert loaded.axis_table() == composite.axis_table()
    s = torch.from_numpy(_grid(composite))
    with torch.no_grad():   # the same parameters, the same batch: bit-identical
        assert torch.equal(loaded.drift64(s), composite.drift64(s))
        assert torch.equal(loaded.out_of_range(s), composite.out_of_range(s))


def _edited(path, tmp_path, edit, *, reseal: bool):
    payload = torch.load(path, weights_only=True)
    edit(payload)
    if reseal:
        payload["sha256"] = checkpoint_digest(payload)
    out = tmp_path / "edited.pt"
    torch.save(payload, out)
    return out


def test_an_edited_owner_table_or_part_is_refused(composite, tmp_path):
    path = save_checkpoint(tmp_path / "per-axis.pt", composite, config={})

    def swap(p):
        p["owner"] = [1, 0, 2, None]

    def weight(p):
        key = next(k for k in p["state_dict"] if k.startswith("parts.1.family"))
        p["state_dict"][key] = p["state_dict"][key] * 1000

    for edit in (swap, weight):
        with pytest.raises(InputError, match="does not match the checkpoint's SHA-256"):
            load_checkpoint(_edited(path, tmp_path, edit, reseal=False))
    # re-sealed edits (a file someone trusted on purpose) are still checked for sense
    with pytest.raises(InputError, match=r"part 0 \(poly3\) compensates"):
        load_checkpoint(_edited(path, tmp_path, swap, reseal=True))

    def out_of_range(p):
        p["owner"] = [0, 1, 7, None]

    with pytest.raises(InputError, match="axis 2 names part 7"):
        load_checkpoint(_edited(path, tmp_path, out_of_range, reseal=True))

    def short(p):
        p["owner"] = [0, 1, 2]

    with pytest.raises(InputError, match="one entry per output axis"):
        load_checkpoint(_edited(path, tmp_path, short, reseal=True))

    def bad_label(p):
        p["labels"] = ["poly3", "../rbf", "poly3-rate"]

    with pytest.raises(InputError, match="labels"):
        load_checkpoint(_edited(path, tmp_path, bad_label, reseal=True))

    def nested(p):
        p["parts"][1]["family"] = "per-axis"

    with pytest.raises(InputError, match="cannot itself be per-axis"):
        load_checkpoint(_edited(path, tmp_path, nested, reseal=True))


# -- ONNX and the runtime -----------------------------------------------------------------
def test_onnx_metadata_names_each_axis_candidate(onnx_path):
    import onnx

    meta = {p.key: p.value for p in onnx.load(str(onnx_path)).metadata_props}
    assert meta["family"] == "per-axis"
    assert json.loads(meta["axis_models"]) == {"gyro_x": "poly3", "gyro_y": "rbf",
                                               "gyro_z": "poly3-rate", "acc_x": None}
    assert json.loads(meta["compensate"]) == {"gyro_x": True, "gyro_y": True, "gyro_z": True,
                                              "acc_x": False}
    assert json.loads(meta["signals"]) == ["temperature_c", "rate_c_per_min"]
    assert json.loads(meta["dynamic_inputs"])["gap_s"] == GAP_S
    parts = json.loads(meta["axis_model_parts"])
    assert [p["label"] for p in parts] == LABELS and parts[2]["inputs"] == ["dT", "rate"]


def test_onnxruntime_matches_torch_per_axis(composite, onnx_path):
    import onnxruntime as ort

    pts = _grid(composite).astype(np.float32)
    sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    raw = np.zeros((len(pts), len(AXES)))
    _, drift, flag = sess.run(None, {"temperature_c": pts[:, 0], "rate_c_per_min": pts[:, 1],
                                     "raw": raw})
    with torch.no_grad():
        want = composite.drift64(torch.from_numpy(pts)).numpy()
    tol = _tolerance(composite, pts)
    for a, k in enumerate(OWNER):
        if k is None:   # the raw axis: every part's coefficients are 0 there
            assert np.array_equal(drift[:, a], np.zeros(len(pts)))
        else:
            err = np.abs(drift[:, a] - want[:, a])
            assert (err <= tol[a]).all(), (AXES[a], err.max(), tol[a])
    assert not flag.any()


def test_runtime_batch_step_and_step_block(composite, onnx_path):
    comp = rt.Compensator(onnx_path)
    assert comp.family == "per-axis"
    assert comp.axis_models == {"gyro_x": "poly3", "gyro_y": "rbf", "gyro_z": "poly3-rate",
                                "acc_x": None}
    assert comp.dynamic_signals == ["rate_c_per_min"] and comp.needs == ["time_s",
                                                                         "temperature_c"]
    t, temp, raw = _stream()
    whole = comp.compensate(temperature_c=temp, raw=raw, time_s=t)
    sig = _signals(composite, t, temp)
    with torch.no_grad():
        want = composite.drift64(torch.from_numpy(sig)).numpy()
    ok = np.isfinite(temp)
    assert np.array_equal(np.isnan(whole.drift), np.isnan(want))
    # per axis, against torch on the same float32 signals: the export's parity tolerance
    tol = _tolerance(composite, sig[ok])
    err = np.abs(whole.drift[ok] - want[ok]).max(axis=0)
    assert (err <= tol).all(), (err, tol)
    assert np.isnan(whole.drift[len(t) // 3]).all()
    assert whole.out_of_range[len(t) // 2] and whole.out_of_range[len(t) // 3]
    assert np.array_equal(whole.drift[ok, 3], np.zeros(int(ok.sum())))   # the raw axis
    # step sample by sample, then step_block, carry the same state
    comp.reset()
    one = [comp.step(t[k], temp[k], raw[k]) for k in range(300)]
    rest = comp.step_block(t[300:], temp[300:], raw[300:])
    drift = np.concatenate([np.array([r.drift for r in one]), rest.drift])
    assert_f32_close(drift, whole.drift, "dynamic")
    flags = np.concatenate([[r.out_of_range for r in one], rest.out_of_range])
    assert np.array_equal(flags, whole.out_of_range)


def test_runtime_refuses_an_axis_table_that_does_not_fit(onnx_path, tmp_path):
    import onnx

    from thermonet.exporting.onnx_seal import seal_onnx

    proto = onnx.load(str(onnx_path))
    for p in proto.metadata_props:
        if p.key == "axis_models":
            p.value = json.dumps({"gyro_x": "poly3"})
    out = tmp_path / "bad.onnx"
    onnx.save(proto, str(out))
    seal_onnx(out)
    with pytest.raises(rt.RuntimeInputError, match="'axis_models' is not a mapping"):
        rt.Compensator(out)


# -- the C header -------------------------------------------------------------------------
@pytest.fixture(scope="module")
def header(composite, tmp_path_factory):
    from thermonet.exporting import export_c_header

    # export_c_header runs c_parity_check and check_stream on both arithmetic paths
    return export_c_header(composite, tmp_path_factory.mktemp("axis_c") / "model.h").read_text()


def _c_batch(header: str, pts: np.ndarray, raw: np.ndarray, real: str) -> dict:
    from thermonet.exporting.c_driver import PARITY_DRIVER, c_compiler, run_c_driver
    from thermonet.exporting.c_stream import REAL_FLAGS

    rows = np.zeros(len(pts), dtype=[("s", np.float32, pts.shape[1]),
                                     ("raw", np.float64, raw.shape[1])])
    rows["s"], rows["raw"] = pts, raw
    cc = c_compiler()
    assert cc is not None
    return run_c_driver(cc, header, PARITY_DRIVER, rows,
                        [("comp", np.float64, raw.shape[1]), ("drift", np.float64, raw.shape[1]),
                         ("flag", np.int32)],
                        cflags=("-O2", "-Wall", "-Wextra", "-Wshadow", "-Werror",
                                *REAL_FLAGS[real]))


@pytest.mark.parametrize("real", ["double", "float"])
def test_c_batch_matches_torch_per_axis(composite, header, real):
    assert header.count("static inline int thermonet_compensate(") == 1
    assert "thermonet_part2_compensate" in header and header.count("} thermonet_state;") == 1
    pts = _grid(composite).astype(np.float32)
    pts = np.concatenate([pts, [[np.nan, 0.0], [20.0, np.nan], [99.0, 0.0]]]).astype(np.float32)
    raw = np.random.default_rng(2).normal(0.0, 0.01, (len(pts), len(AXES)))
    out = _c_batch(header, pts, raw, real)
    with torch.no_grad():
        want = composite.drift64(torch.from_numpy(pts)).numpy()
        flag = composite.out_of_range(torch.from_numpy(pts)).numpy()
    fin = np.isfinite(pts).all(axis=1)
    tol = _tolerance(composite, pts[fin])
    if real == "float":   # its drift output is a float: rounded at the constant's magnitude
        tol = tol + float_path_slack(composite.constant().numpy(), want[fin])
    for a, k in enumerate(OWNER):
        if k is None:   # raw axis: drift exactly 0 and compensated the raw value
            assert np.array_equal(out["drift"][fin, a], np.zeros(int(fin.sum())))
            want_raw = raw[fin, a].astype(np.float32) if real == "float" else raw[fin, a]
            assert np.array_equal(out["comp"][fin, a], want_raw)
        else:
            err = np.abs(out["drift"][fin, a] - want[fin, a])
            assert (err <= tol[a]).all(), (AXES[a], err.max(), tol[a])
    assert np.isnan(out["drift"][-3:-1]).all() and np.isnan(out["comp"][-3:-1]).all()
    assert np.array_equal(out["flag"].astype(bool), flag)   # booleans


@pytest.mark.parametrize("real", ["double", "float"])
def test_c_step_and_step_block_match_torch_per_axis(composite, header, real):
    from thermonet.exporting.c_stream import REAL_FLAGS, run_stream_c

    t, temp, raw = _stream()
    flags = ("-O2", *REAL_FLAGS[real])
    one = run_stream_c(composite, header, t, temp, raw, cflags=flags)
    blk = run_stream_c(composite, header, t, temp, raw, cflags=flags, block=7)
    # step_block calls step on each sample in order: the same operations, bitwise
    np.testing.assert_array_equal(blk["drift"], one["drift"])
    assert np.array_equal(blk["flag"], one["flag"]) and (one["ret"] == 0).all()
    with torch.no_grad():
        want = composite.drift64(torch.from_numpy(_signals(composite, t, temp))).numpy()
    for a in range(len(AXES)):
        assert_f32_close(one["drift"][:, a], want[:, a], "dynamic", err_msg=AXES[a])
    assert one["flag"][len(t) // 2] and one["flag"][len(t) // 3]
    assert np.isnan(one["drift"][len(t) // 3]).all()


# -- thermonet export from a compare directory, the autopilot files, the estimator --------
def _compare_dir(composite, root, *, sha: str | None = None):
    """What compare writes for a per-axis choice: models/per-axis.pt and results.json."""
    from thermonet.core.outdir import sha256_file

    (root / "models").mkdir(parents=True)
    ckpt = save_checkpoint(root / "models" / "per-axis.pt", composite, config={},
                           extra={"units": {"gyro_x": "deg/s", "gyro_y": "deg/s",
                                            "gyro_z": "deg/s", "acc_x": "m/s^2"}})
    results = {"schema": 3, "chosen": "per-axis",
               "families": {"per-axis": {"family": "per-axis", "status": "ok",
                                         "checkpoint": "models/per-axis.pt",
                                         "checkpoint_sha256": sha or sha256_file(ckpt),
                                         "params": {"axes": composite.axis_table()}}},
               "selection": {"per_axis": {"candidates": LABELS}}}
    (root / "results.json").write_text(json.dumps(results))
    return root


def test_export_from_a_compare_directory_that_chose_per_axis(composite, tmp_path):
    from thermonet.exporting import export_source

    src = _compare_dir(composite, tmp_path / "cmp")
    path = export_source(str(src), fmt="onnx", out=tmp_path / "out.onnx")
    comp = rt.Compensator(path)
    assert comp.axis_models == composite.axis_table()
    header = export_source(str(src), fmt="c", out=tmp_path / "out.h").read_text()
    assert "per-axis" in header and "thermonet_part1_compensate" in header
    # the autopilot files hold a cubic on temperature: the RBF and the rate term are not one
    with pytest.raises(ExportError, match=r"firmware-form cubic .* 'gyro_y' with 'rbf' .*"
                                          r"--family"):
        export_source(str(src), fmt="px4-params", out=tmp_path / "out.params", device_id=1)


def test_the_autopilot_refusal_of_a_proxy_input_names_the_input_not_the_family(parts, tmp_path):
    """A linear fit on a proxy (``d_temp_raw``) is a polynomial of degree 1: what PX4 and
    ArduPilot cannot read is its input, so the refusal names the input and says they read the
    temperature (dT or T), alone and as a part of a per-axis model (was: 'linear on [...]'
    beside 'the firmware-form cubic', or the input list without why)."""
    from thermonet.exporting.autopilot import autopilot_coefficients

    _, temp, _, y = _device()
    spec = FeatureSpec(inputs=["d_temp_raw"], t_ref=20.0, gap_s=GAP_S,
                       proxy_ref={"temp_raw": 200.0})
    lin = fit(family="linear", inputs=["d_temp_raw"], outputs=AXES,
              train=[((10.0 * temp)[:, None], y)], val=None, spec=spec, hyper={},
              config=TrainConfig(max_epochs=0, seed=0)).model
    per_axis = AxisModels([copy.deepcopy(parts[0]), lin], [0, 1, 0, None],
                          ["cubic", "lin-raw"]).eval()
    for model in (lin, per_axis):
        with pytest.raises(ExportError) as info:
            autopilot_coefficients(model, output_units="deg/s")
        msg = str(info.value)
        assert "reads ['d_temp_raw'] — 'd_temp_raw' is the proxy 'temp_raw', not the " \
               "temperature, and PX4/ArduPilot read only the sensor's temperature" in msg, msg
        assert "need one input, dT or T" in msg, msg
        assert "linear" not in msg and "\n" not in msg, msg
    assert "'gyro_y' with 'lin-raw'" in msg


def test_a_replaced_per_axis_checkpoint_or_a_missing_block_is_refused(composite, tmp_path):
    from thermonet.exporting import export_source

    src = _compare_dir(composite, tmp_path / "cmp", sha="0" * 64)
    with pytest.raises(ExportError, match="does not match the SHA-256"):
        export_source(str(src), fmt="onnx", out=tmp_path / "out.onnx")
    results = json.loads((src / "results.json").read_text())
    del results["families"]["per-axis"]
    (src / "results.json").write_text(json.dumps(results))
    with pytest.raises(InputError, match="no 'families.per-axis' mapping"):
        export_source(str(src), fmt="onnx", out=tmp_path / "out.onnx")
    assert not (tmp_path / "out.onnx").exists()


def test_autopilot_files_when_every_owned_axis_is_a_cubic(parts, tmp_path):
    from thermonet.exporting.autopilot import autopilot_coefficients, export_px4_params

    units = {"gyro_x": "deg/s", "gyro_y": "deg/s", "gyro_z": "deg/s", "acc_x": "m/s^2"}
    quad = _fit("poly", ["dT"], {"degree": 2})
    cubics = AxisModels([copy.deepcopy(parts[0]), quad], [0, 1, None, None], ["poly3", "poly2"])
    co = autopilot_coefficients(cubics, output_units=units)
    own = [autopilot_coefficients(p, output_units=units, t_ref=co.t_ref) for p in cubics.parts]
    # each axis's cubic is its owner's, copied (the same computation: exact)
    assert np.array_equal(co.coef["gyro"][0], own[0].coef["gyro"][0])
    assert np.array_equal(co.coef["gyro"][1], own[1].coef["gyro"][1])
    assert np.array_equal(co.coef["gyro"][2], np.zeros(4))   # left raw: zero
    assert np.array_equal(co.coef["acc"][0], np.zeros(4))
    text = export_px4_params(cubics, tmp_path / "tc.params", output_units=units,
                             device_id=7).read_text()
    assert "TC_G0_X1_0" in text and "TC_G0_X1_1" in text


def test_estimator_loads_a_per_axis_checkpoint(composite, tmp_path):
    from thermonet.api import DriftEstimator
    from thermonet.core.recording import Recording

    path = save_checkpoint(tmp_path / "per-axis.pt", composite, config={})
    est = DriftEstimator.load(path)
    assert est.axis_models_ == composite.axis_table()
    t, temp, _ = _stream(n=500)
    temp[np.isnan(temp)] = 20.0
    rec = Recording(time_s=t - t[0], temperature_c=temp,
                    outputs={a: np.zeros(t.size) for a in AXES}, run_id="r0")
    got = est.predict(rec)
    with torch.no_grad():
        want = composite.drift64(torch.from_numpy(_signals(composite, t - t[0], temp))).numpy()
    np.testing.assert_array_equal(got, want)   # the same model on the same signals, batch
    rec = Recording(time_s=rec.time_s, temperature_c=temp, run_id="r0",
                    outputs={a: want[:, j] + 0.01 * np.sin(temp) for j, a in enumerate(AXES)})
    assert np.isfinite(est.score(rec))   # scored on the model's own signal order
    table = est.parameters_
    assert set(table["axis"]) <= {*AXES[:3], ""} and table["name"].str.startswith(
        tuple(f"{lab}." for lab in LABELS)).all()
    with pytest.raises(ConfigError, match="chosen by compare"):
        DriftEstimator("per-axis").fit(rec)
    single = DriftEstimator.load(save_checkpoint(tmp_path / "p.pt", composite.parts[0],
                                                 config={}))
    assert single.axis_models_ is None


def test_header_cross_compiles_for_cortex_m(composite, header, tmp_path):
    """Firmware-grade like every header (tests/test_mcu.py): compensate and step built for
    each Cortex-M target under -Werror, float-only where the FPU is single precision."""
    from thermonet.exporting.mcu import FLOAT_TARGETS, TARGETS, cross_compile

    for target in TARGETS:
        build = cross_compile(header, target, tmp_path / target)
        assert build.code_bytes > 0
        assert build.soft_double == [], (target, build.soft_double)
        if target in FLOAT_TARGETS:
            assert build.libm == [], (target, build.libm)


def test_header_names_its_own_file_and_refuses_fast_math_once(composite, header, tmp_path):
    """The first line names the file written (was ``/* thermonet.h: …`` whatever --out
    was), each part says whose part it is, and the -ffast-math refusal names no file (was
    ``thermonet_part0.h``, which does not exist) and is said once, however many parts."""
    import subprocess

    lines = header.splitlines()
    assert lines[0].startswith("/* model.h: temperature-drift compensation")
    assert "thermonet_part0.h" not in header and "thermonet.h" not in header
    assert "/* part 0 (" in header and ") of this per-axis model: " in header
    # the model id is the same whatever the file is called: only the first line names it
    from thermonet.exporting import render_c_header

    assert render_c_header(composite, file_name="other.h").splitlines()[1:] == lines[1:]
    (tmp_path / "model.h").write_text(header)
    (tmp_path / "use.c").write_text('#include "model.h"\nint main(void) { return 0; }\n')
    fast = subprocess.run(["gcc", "-std=c99", "-Ofast", "-c", "use.c", "-o", "use.o"],
                          capture_output=True, text=True, cwd=tmp_path)
    errors = [ln for ln in fast.stderr.splitlines() if "#error" in ln and "error:" in ln]
    assert fast.returncode != 0 and len(errors) == 1, fast.stderr
    assert "a thermonet header must not be compiled with -ffast-math / -Ofast" in errors[0]
    # -ffinite-math-only alone: refused too, once however many parts
    finite = subprocess.run(["gcc", "-std=c99", "-O2", "-ffinite-math-only", "-c", "use.c",
                             "-o", "use.o"], capture_output=True, text=True, cwd=tmp_path)
    errors = [ln for ln in finite.stderr.splitlines() if "#error" in ln and "error:" in ln]
    assert finite.returncode != 0 and len(errors) == 1, finite.stderr
    assert "must not be compiled with -ffinite-math-only" in errors[0]


def test_parts_whose_union_puts_temperature_second(parts, tmp_path):
    """The first part reads only the rate: the union's signals are [rate, temperature], not
    the order a single spec would give; every path reads them by the model's own order."""
    from thermonet.api import DriftEstimator
    from thermonet.core.recording import Recording
    from thermonet.exporting import render_c_header
    from thermonet.exporting.c_stream import run_stream_c

    rate_only = _fit("poly", ["rate"], {"degree": 1})
    model = AxisModels([rate_only, copy.deepcopy(parts[0])], [None, 1, 0, None],
                       ["rate1", "poly3"]).eval()
    assert model.signals == ["rate_c_per_min", "temperature_c"]
    assert model.spec.signals == ["temperature_c", "rate_c_per_min"]
    t, temp, raw = _stream(n=600)
    with torch.no_grad():
        want = model.drift64(torch.from_numpy(_signals(model, t, temp))).numpy()
    comp = rt.Compensator(export_onnx(model, tmp_path / "m.onnx"))
    got = comp.compensate(temperature_c=temp, raw=raw, time_s=t).drift
    ok = np.isfinite(temp)
    assert (np.abs(got[ok] - want[ok]).max(axis=0) <= _tolerance(model, _signals(
        model, t, temp)[ok])).all()
    c = run_stream_c(model, render_c_header(model), t, temp, raw)
    assert_f32_close(c["drift"], want, "dynamic")
    est = DriftEstimator.load(save_checkpoint(tmp_path / "m.pt", model, config={}))
    rec = Recording(time_s=t - t[0], temperature_c=np.where(ok, temp, 20.0), run_id="r",
                    outputs={a: np.zeros(t.size) for a in AXES})
    with torch.no_grad():
        ref = model.drift64(torch.from_numpy(_signals(model, rec.time_s,
                                                      rec.temperature_c))).numpy()
    np.testing.assert_array_equal(est.predict(rec), ref)   # same model, signals, batch


def test_parameter_rows_are_the_parameter_table_without_pandas(parts, composite):
    """compare seals parameter_rows (no pandas); the API shows parameter_table: the same
    rows, values and standard errors, for single families (with data: standard errors) and
    for the per-axis composite built from its parts' own rows."""
    from thermonet.training.parameters import COLUMNS, parameter_rows, parameter_table

    units = {a: "°/s" for a in AXES}
    _, temp, _, y = _device()
    train = (temp[:, None], y)
    for model, data in ((parts[0], train), (parts[1], None), (composite, None)):
        rows, cov = parameter_rows(model, units, {}, data)
        table, cov_t = parameter_table(model, units, {}, data)
        assert list(table.columns) == COLUMNS and len(rows) == len(table) > 0
        for r, t in zip(rows, table.to_dict("records"), strict=True):
            assert list(r) == COLUMNS
            for c in COLUMNS:
                assert r[c] == t[c] or (r[c] != r[c] and t[c] != t[c]), (c, r, t)   # NaN
        assert cov.keys() == cov_t.keys()
        for a in cov:
            np.testing.assert_array_equal(cov[a], cov_t[a])
    rows0, cov0 = parameter_rows(parts[0], units, {}, train)
    assert any(r["stderr"] > 0 for r in rows0)                     # standard errors computed
    table, _ = parameter_table(composite, units, {}, parts=[
        (parameter_table(p, units, {}, train if k == 0 else None)[0], cov0 if k == 0 else {})
        for k, p in enumerate(parts)])
    rows, _ = parameter_rows(composite, units, {}, parts=[
        (parameter_rows(p, units, {}, train if k == 0 else None)[0], cov0 if k == 0 else {})
        for k, p in enumerate(parts)])
    assert [r["name"] for r in rows] == list(table["name"])
    assert [r["name"] for r in rows if r["name"].startswith(LABELS[0] + ".")]
