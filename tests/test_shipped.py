"""One shipped-model protocol and the model kinds as data (thermonet.models.shipped).

Every shipped model (a family's DriftModel, the per-axis composite, the whole-sensor model)
implements ``ShippedModel``; every layer's strategy table is keyed by the same kinds; the
checkpoint formats agree with the loaders'; every export of every kind passes the format
registry; and no module of thermonet/ switches on a model kind's name.
"""

from __future__ import annotations

import re
import typing
from pathlib import Path

import numpy as np
import pytest

from thermonet.models.shipped import MODEL_KINDS, ShippedModel

ROOT = Path(__file__).resolve().parents[1]


def test_every_layer_keys_its_strategy_by_the_same_model_kinds():
    from thermonet.api.modes import MODES
    from thermonet.training.config import CompareConfig
    from thermonet.training.sensor_checkpoint import LOADERS
    from thermonet.workflows.compare import PIPELINES
    from thermonet.workflows.compare_table import TABLES
    from thermonet.workflows.fleet_units import UNIT_KINDS

    kinds = set(MODEL_KINDS)
    hints = typing.get_type_hints(CompareConfig)
    assert set(typing.get_args(hints["model"])) == kinds
    for table in (MODES, PIPELINES, TABLES, UNIT_KINDS, LOADERS):
        assert set(table) == kinds


def test_the_kinds_checkpoint_formats_are_the_loaders():
    from thermonet.training.checkpoint import CHECKPOINT_FORMAT
    from thermonet.training.sensor_checkpoint import SENSOR_FORMAT

    assert MODEL_KINDS["bias"].checkpoint_format == CHECKPOINT_FORMAT
    assert MODEL_KINDS["sensor"].checkpoint_format == SENSOR_FORMAT


def _drift_model(outputs):
    import torch

    from thermonet.features.inputs import FeatureSpec
    from thermonet.models import DriftModel, build_family

    spec = FeatureSpec(inputs=["dT"], t_ref=25.0)
    m = DriftModel(family=build_family("poly", n_inputs=1, n_outputs=len(outputs),
                                       hyper={"degree": 2}),
                   spec=spec, outputs=list(outputs))
    with torch.no_grad():
        for p in m.family.parameters():
            p.copy_(torch.linspace(-0.3, 0.4, p.numel()).reshape(p.shape))
    m.set_scaling(x_mean=np.zeros(1), x_std=np.ones(1), y_mean=np.zeros(len(outputs)),
                  y_std=np.ones(len(outputs)), sig_lo=np.array([-40.0]),
                  sig_hi=np.array([85.0]))
    return m.eval()


def test_each_shipped_model_implements_the_protocol_and_compensates_as_it_predicts():
    from thermonet.models.composite import AxisModels
    from thermonet.models.sensor import SensorModel, element_names
    from thermonet.training.train import predict

    axes = ["gyro_x", "gyro_y", "gyro_z"]
    bias = _drift_model(axes)
    elements = _drift_model(element_names(axes))
    composite = AxisModels([bias], [0, 0, None], ["quad"])
    sensor = SensorModel(bias=_drift_model(axes), elements=elements, triads=[axes])
    sig = np.linspace(-30.0, 70.0, 9)[:, None]
    raw = np.tile([0.5, -1.0, 2.0], (9, 1))
    for model, kind in ((bias, "bias"), (composite, "bias"), (sensor, "sensor")):
        assert isinstance(model, ShippedModel)
        assert model.kind == kind and model.kind in MODEL_KINDS
        assert list(model.inputs) == ["dT"] and list(model.outputs) == axes
        comp = model.compensated(sig, raw)
        assert comp.dtype == np.float64 and comp.shape == raw.shape
        assert not np.asarray(model.out_of_range(sig)).any()
        assert np.asarray(model.out_of_range(np.array([[100.0]]))).all()
    for model in (bias, composite):      # a drift to subtract: raw − predict, bit for bit
        assert np.array_equal(model.compensated(sig, raw), raw - predict(model, sig))
    assert np.array_equal(sensor.compensated(sig, raw), sensor.compensate(sig, raw))


def test_every_format_has_an_exporter_or_a_refusal_for_every_kind(tmp_path):
    from thermonet.core.errors import ExportError
    from thermonet.exporting import FORMATS, ExportFormat

    for fmt in FORMATS.values():
        for kind in MODEL_KINDS:
            assert callable(fmt.resolve(kind))
    plain = ExportFormat("plain", "a plug-in's format, drift models only", lambda m, o, r: o)
    with pytest.raises(ExportError, match="format 'plain' is not available for a sensor "
                                          "model; export it as onnx or c"):
        plain.resolve("sensor", "x.pt")


def test_no_module_switches_on_a_model_kinds_name():
    """The kinds differ by data and by the strategy tables above, not by comparisons with a
    kind's name (issue 51: at most 2)."""
    switch = re.compile(r"""[!=]=\s*["'](bias|sensor)["']|["'](bias|sensor)["']\s*[!=]=""")
    hits = [f"{p.relative_to(ROOT)}:{i}" for p in sorted((ROOT / "thermonet").rglob("*.py"))
            for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
            if switch.search(line)]
    assert len(hits) <= 2, hits
