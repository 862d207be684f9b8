"""The ONNX graphs built without torch's exporter (thermonet.exporting.onnx_graph) against the
graph torch's exporter writes for the same model, family by family.

Each model is exported twice — ``exporter="auto"`` (the direct graph for these families) and
``exporter="dynamo"`` (torch's trace) — and both files run in onnxruntime on the same inputs:
points across and beyond the trained range, NaN and ±inf in each signal, raw outputs around a
large constant.  Flags must be identical, drifts equal to float32 rounding (and both equal
to the torch model), the metadata identical but for the exporter's name and the file's seal.
"""

from __future__ import annotations

import copy

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from thermonet.core.errors import ExportError
from thermonet.core.trainconfig import TrainConfig
from thermonet.exporting import export_onnx
from thermonet.exporting.onnx_graph import direct_supported
from thermonet.exporting.onnx_seal import DIGEST_KEY
from thermonet.exporting.parity import float32_tolerance
from thermonet.features import dynamics
from thermonet.features.inputs import FeatureSpec
from thermonet.models.composite import AxisModels
from thermonet.training.train import fit
from tolerances import assert_f32_close

#: run again under emulated CPUs (make test-cpus; tests/tolerances.py)
pytestmark = pytest.mark.numerics

AXES = ["gyro_x", "gyro_y", "gyro_z"]
T_REF, GAP_S = 20.0, 5.0
META = {"device_id": "IMU-7", "training_run_id": "run42", "data_hash": "sha256:abc",
        "validation_metrics": {"val/rms": 0.0012},
        "output_units": {a: "deg/s" for a in AXES}}


def _device() -> dict[str, np.ndarray]:
    """Heat/cool triangles with every signal the cases read, and a 3-axis drift that depends
    on temperature, rate and the heating/cooling branch (a hysteresis)."""
    t = np.arange(0.0, 24000.0, 2.0)
    phase = (t % 6000.0) / 6000.0
    temp = -10.0 + 70.0 * (1.0 - np.abs(2.0 * phase - 1.0))
    dyn = dynamics.compute(t, temp, ["rate", "play_1"], GAP_S)[0]
    dt = temp - T_REF
    y = np.column_stack([0.01 * dt - 2e-4 * dt ** 2 + 3e-6 * dt ** 3,
                         0.02 * np.tanh(dt / 10.0) + 0.01 * dyn["play_1_c"],
                         0.005 * dt + 0.03 * dyn["rate_c_per_min"]])
    return {"temperature_c": temp, "rate_c_per_min": dyn["rate_c_per_min"],
            "play_1_c": dyn["play_1_c"], "y": y}


def _fit(family: str, inputs: list[str], hyper: dict | None = None):
    d = _device()
    spec = FeatureSpec(inputs=inputs, t_ref=T_REF, gap_s=GAP_S)
    s = np.column_stack([d[x] for x in spec.signals])
    return fit(family=family, inputs=inputs, outputs=AXES, train=[(s, d["y"])], val=None,
               spec=spec, hyper=hyper or {}, config=TrainConfig(max_epochs=3, seed=0)).model


#: (family, inputs, hyper): what the default family set and the configs ship
SINGLE = {
    "linear": ("linear", ["dT"], {}),
    "linear-T-dT2": ("linear", ["T", "dT2"], {}),
    "cubic": ("poly", ["dT"], {"degree": 3}),
    "poly2-no-cross": ("poly", ["dT", "rate"], {"degree": 2}),
    "poly3-rate": ("poly", ["dT", "rate"], {"degree": 3, "cross": True}),
    "poly3-hyst": ("poly", ["dT", "rate", "play_1"], {"degree": 3, "cross": True}),
    "rbf-tail": ("rbf", ["dT", "dT2"], {"n_centres": 8, "tail": 3}),
    "rbf": ("rbf", ["dT"], {"n_centres": 6}),
    "lorentz": ("lorentz", ["dT"], {}),
    "ts-fuzzy": ("ts-fuzzy", ["dT"], {"n_sets": 4}),
}


@pytest.fixture(scope="module")
def models():
    out = {name: _fit(*case) for name, case in SINGLE.items()}
    # what the default families chose per axis on the real BMI270 soaks: three parts,
    # dynamic inputs in one, each part clamped to its own range
    out["per-axis"] = AxisModels([copy.deepcopy(out[k]) for k in ("lorentz", "poly3-hyst",
                                                                  "linear")], [0, 1, 2],
                                 ["lorentz", "poly3-hyst", "linear"]).eval()
    out["per-axis-raw"] = AxisModels([copy.deepcopy(out[k]) for k in ("rbf-tail", "poly3-rate")],
                                     [1, None, 0], ["rbf-tail", "poly3-rate"]).eval()
    out["per-axis-fuzzy"] = AxisModels([copy.deepcopy(out[k]) for k in ("ts-fuzzy", "cubic")],
                                       [0, 1, 0], ["ts-fuzzy", "cubic"]).eval()
    # a large float64 constant and an axis relative to the reference temperature
    big = copy.deepcopy(out["cubic"])
    big.set_target(modes=["channel", "at-t-ref", "zero"], offset=np.array([1e6, 0.0, 4517.0]),
                   rest=np.array([T_REF]))
    out["cubic-offset-at-t-ref"] = big
    return out


def _feeds(model, seed: int = 0) -> dict[str, np.ndarray]:
    """Each signal across 1.4× its trained range (both sides beyond it), then NaN, +inf and
    -inf in each signal in turn; raw around the model's constant."""
    rng = np.random.default_rng(seed)
    lo, hi = model.sig_lo.double().numpy(), model.sig_hi.double().numpy()
    n = 4001
    cols = {s: rng.uniform(lo[i] - 0.2 * (hi[i] - lo[i]), hi[i] + 0.2 * (hi[i] - lo[i]), n)
            for i, s in enumerate(model.signals)}
    for i, s in enumerate(model.signals):
        cols[s][:201] = np.linspace(lo[i], hi[i], 201)   # the range itself, edges included
        cols[s][201 + 3 * i:204 + 3 * i] = [np.nan, np.inf, -np.inf]
    feeds = {s: c.astype(np.float32) for s, c in cols.items()}
    const = model.constant().double().numpy()
    feeds["raw"] = rng.normal(size=(n, len(model.outputs))) + const
    return feeds


def _run(path, feeds):
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, feeds)


def _meta(path) -> dict[str, str]:
    return {p.key: p.value for p in onnx.load(str(path)).metadata_props}


CASES = [*SINGLE, "per-axis", "per-axis-raw", "per-axis-fuzzy", "cubic-offset-at-t-ref"]


@pytest.mark.parametrize("case", CASES)
def test_direct_graph_equals_torch_export(models, case, tmp_path):
    model = models[case]
    assert direct_supported(model) is None
    direct = export_onnx(model, tmp_path / "direct.onnx", metadata=META)      # parity checked
    traced = export_onnx(model, tmp_path / "traced.onnx", metadata=META, exporter="dynamo")
    md, mt = _meta(direct), _meta(traced)
    assert (md["exporter"], mt["exporter"]) == ("direct", "dynamo")
    differ = sorted(k for k in md.keys() | mt.keys() if md.get(k) != mt.get(k))
    assert differ == sorted(["exporter", DIGEST_KEY])
    gd, gt = onnx.load(str(direct)).graph, onnx.load(str(traced)).graph
    for a, b in ((gd.input, gt.input), (gd.output, gt.output)):   # the same interface
        assert [(v.name, v.type.tensor_type.elem_type) for v in a] == \
               [(v.name, v.type.tensor_type.elem_type) for v in b]

    feeds = _feeds(model)
    comp_d, drift_d, flag_d = _run(direct, feeds)
    comp_t, drift_t, flag_t = _run(traced, feeds)
    np.testing.assert_array_equal(flag_d, flag_t)                # booleans: identical
    lo, hi = model.sig_lo.numpy(), model.sig_hi.numpy()
    sig = np.column_stack([feeds[s] for s in model.signals])
    inside = np.all((sig >= lo) & (sig <= hi), axis=1)           # NaN compares false
    np.testing.assert_array_equal(flag_d, ~inside)
    const = model.constant().double().numpy()
    # the drift relative to its float64 constant, as both graphs compute it in float32; the
    # torch model clamps itself, so the same signals go to it
    with torch.no_grad():
        ref = model.relative(torch.from_numpy(sig)).double().numpy()
    finite = np.all(np.isfinite(sig), axis=1)
    # float32 rounding of the model's evaluation on these points (the export's parity
    # tolerance: a narrow RBF amplifies one ulp of an exponent coefficient)
    tol = float32_tolerance(model, sig[finite], ref[finite])
    for drift in (drift_d, drift_t):
        rel = drift - const
        assert np.isnan(rel[~finite]).all() and np.isfinite(rel[finite]).all()
        assert (np.abs(rel[finite] - ref[finite]) <= tol).all(), case
    # the direct graph is the model's own float32 arithmetic: within float32 rounding of torch
    scale = np.abs(ref[finite]).max(0)
    assert_f32_close(drift_d[finite] - const, ref[finite], "family", scale=scale)
    # compensated = raw − drift in float64 in both
    np.testing.assert_array_equal(comp_d[finite], (feeds["raw"] - drift_d)[finite])
    assert_f32_close(comp_d[finite] - const, comp_t[finite] - const, "family",
                     scale=scale + tol)


def test_every_hand_built_graph_is_checked_here():
    """Each family with a hand-built graph (onnx_graph's table) has a case above, so no
    graph is written that is not compared with torch's export and the torch model — the one
    source of the family's math."""
    from thermonet.exporting import onnx_graph
    from thermonet.models.registry import get_family

    assert {get_family(family) for family, _, _ in SINGLE.values()} == set(onnx_graph._FAMILIES)


def test_dynamic_batch_and_empty_batch(models, tmp_path):
    model = models["poly3-hyst"]
    path = export_onnx(model, tmp_path / "m.onnx")
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    for n in (0, 1, 7, 5000):
        feeds = {s: np.zeros(n, np.float32) for s in model.signals}
        out = sess.run(None, {**feeds, "raw": np.zeros((n, 3))})
        assert out[0].shape == (n, 3) and out[1].shape == (n, 3) and out[2].shape == (n,)


def test_families_without_a_direct_graph_use_torch(tmp_path):
    mlp = _fit("mlp", ["dT"])
    assert "mlp" in (direct_supported(mlp) or "")
    path = export_onnx(mlp, tmp_path / "f.onnx")
    assert _meta(path)["exporter"] == "dynamo"
    target = tmp_path / "d.onnx"
    with pytest.raises(ExportError, match="no direct ONNX graph.*mlp"):
        export_onnx(mlp, target, exporter="direct")
    assert not target.exists()
    # a per-axis model with such a part goes through torch as a whole
    lin = _fit("linear", ["dT"])
    mixed = AxisModels([lin, copy.deepcopy(mlp)], [0, 1, None], ["linear", "mlp"])
    assert "mlp" in (direct_supported(mixed) or "")
    # a float64 copy computes in float64: torch's exporter writes what it computes
    assert "float32" in (direct_supported(copy.deepcopy(lin).double()) or "")


def test_a_wrong_direct_graph_is_never_written(models, tmp_path, monkeypatch):
    """The parity check runs on the direct graph: a graph with a wrong constant is refused
    and nothing is written."""
    from thermonet.exporting import onnx_graph

    real = onnx_graph._linear

    def off_by_a_bit(g, fam, z, scale, shift):
        return real(g, fam, z, scale * 1.001, shift)

    monkeypatch.setitem(onnx_graph._FAMILIES, type(models["linear"].family), off_by_a_bit)
    target = tmp_path / "m.onnx"
    with pytest.raises(ExportError, match="parity check failed"):
        export_onnx(models["linear"], target)
    assert list(tmp_path.iterdir()) == []


def test_exporting_loads_only_what_it_uses(models, tmp_path):
    """``thermonet export`` of a per-axis model of closed-form families, to ONNX and to C, in a
    fresh process: torch (the checkpoint), onnx and onnxruntime (the parity check) load;
    torch's exporter (torch.onnx, torch._dynamo, onnxscript), MLflow (no run to log to),
    scikit-learn and scipy.stats do not."""
    import subprocess
    import sys
    from pathlib import Path

    from thermonet.training.checkpoint import save_checkpoint

    ckpt = save_checkpoint(tmp_path / "per-axis.pt", models["per-axis"], config={})
    code = ("import sys\nfrom thermonet.cli import main\n"
            f"assert main(['export', {str(ckpt)!r}, '--format', 'onnx', '--out', "
            f"{str(tmp_path / 'm.onnx')!r}]) == 0\n"
            f"assert main(['export', {str(ckpt)!r}, '--format', 'c', '--out', "
            f"{str(tmp_path / 'm.h')!r}]) == 0\n"
            "print(sorted(m for m in ('torch', 'onnx', 'onnxruntime', 'torch.onnx', "
            "'torch._dynamo', 'onnxscript', 'mlflow', 'sklearn', 'scipy.stats') "
            "if m in sys.modules))")
    root = Path(__file__).resolve().parent.parent
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root)
    assert out.returncode == 0, out.stderr[-500:]
    assert out.stdout.strip().splitlines()[-1] == str(["onnx", "onnxruntime", "torch"])
    assert _meta(tmp_path / "m.onnx")["exporter"] == "direct"
