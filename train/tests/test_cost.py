"""The cost measured at export (haptics_train.cost): per call, as infer-server steps a model."""

import numpy as np

from haptics_train.cost import COST_KEY, measure_cost
from haptics_train.export import provenance, to_contract_onnx
from haptics_train.models import TrainConfig, make_model


def test_cost_is_measured_per_call():
    m = make_model("sd_poly2")
    x = np.linspace(0.0, 0.02, 500)
    X = np.column_stack([x, np.gradient(x)])
    m.fit(X, 800 * x)
    om = to_contract_onnx(m, provenance(m, TrainConfig(progress=False), None, None))
    cost = measure_cost(om, calls=200)
    assert 0 < cost["p50_us"] <= cost["p99_us"] <= cost["p999_us"]
    assert cost["calls"] == 200 and "onnxruntime" in cost["measured_by"]
    assert COST_KEY == "haptics.cost"
