import json

import numpy as np
import onnx
import pytest
import torch

from haptics_train.contract import ContractError, validate_model
from haptics_train.models.torch_export import export_stateless


def _linear_model(n=2, meta=None):
    m = export_stateless(torch.nn.Linear(n, 1), n)
    base = {
        "haptics.features": "position_x,velocity",
        "haptics.kind": "stateless",
        "haptics.units": "N",
        "haptics.provenance": json.dumps({"model": "test"}),
    }
    base.update(meta or {})
    for k, v in base.items():
        if v is not None:
            m.metadata_props.add(key=k, value=v)
    return m


def test_valid_stateless_model_passes():
    meta = validate_model(_linear_model())
    assert meta["haptics.kind"] == "stateless"


@pytest.mark.parametrize(
    ("meta", "msg"),
    [
        ({"haptics.kind": None}, "haptics.kind missing"),
        ({"haptics.kind": "sometimes"}, "not in"),
        ({"haptics.features": "position_x"}, "shape"),
        ({"haptics.features": "position_x,position_x"}, "unique"),
        ({"haptics.units": None}, "haptics.units missing"),
        ({"haptics.kind": "stateful"}, "state_size"),
    ],
)
def test_broken_metadata_is_refused_with_the_reason(meta, msg):
    with pytest.raises(ContractError, match=msg):
        validate_model(_linear_model(meta=meta))


def test_wrong_input_name_is_refused():
    m = _linear_model()
    m.graph.input[0].name = "x"
    for node in m.graph.node:
        node.input[:] = ["x" if i == "features" else i for i in node.input]
    with pytest.raises(ContractError, match="expected 'features'"):
        validate_model(m)


def test_schema_check():
    with pytest.raises(ContractError, match="not in the schema"):
        validate_model(_linear_model(), schema=["position_x"])
    validate_model(_linear_model(), schema=["position_x", "velocity", "acceleration"])


def test_non_finite_warm_up_is_refused():
    lin = torch.nn.Linear(2, 1)
    with torch.no_grad():
        lin.bias.fill_(float("nan"))
    m = export_stateless(lin, 2)
    for k, v in {"haptics.features": "position_x,velocity", "haptics.kind": "stateless",
                 "haptics.units": "N", "haptics.provenance": "{}"}.items():  # fmt: skip
        m.metadata_props.add(key=k, value=v)
    with pytest.raises(ContractError, match="finite"):
        validate_model(m)
    assert np.isnan(float(lin.bias.detach()))
    assert isinstance(m, onnx.ModelProto)
