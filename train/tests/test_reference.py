"""Reference steps for a graph of one's own (`reference.press_rows`, `add_reference_rows`): an
ONNX object has no recording to take rows from (docs/laws/onnx.md), so rows along a press are
stepped instead, and `check_reference` (infer-server's and rt-loop's check, in Python) holds."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from haptics_train.reference import (
    REFERENCE_KEY,
    add_reference_rows,
    check_reference,
    press_rows,
    write_entry,
)


def spring() -> onnx.ModelProto:
    """force = 300 N/m * x + 2 N s/m * v, on (velocity, position_x) in that order."""
    w = numpy_helper.from_array(np.array([[2.0], [300.0]], np.float32), "w")
    g = helper.make_graph(
        [helper.make_node("MatMul", ["features", "w"], ["force"])], "spring",
        [helper.make_tensor_value_info("features", TensorProto.FLOAT, [1, 2])],
        [helper.make_tensor_value_info("force", TensorProto.FLOAT, [1, 1])], [w],
    )  # fmt: skip
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    return m


def test_press_rows_follow_the_features_order_and_press_and_release() -> None:
    rows = press_rows(("velocity", "position_x"), depth_m=0.01, speed_m_s=0.02, steps=8)
    assert rows.shape == (8, 2) and rows.dtype == np.float32
    assert rows[:, 1].max() == pytest.approx(0.01) and rows[0, 1] == 0 and rows[-1, 1] == 0
    assert (rows[:4, 0] == np.float32(0.02)).all() and (rows[4:, 0] == np.float32(-0.02)).all()
    with pytest.raises(ValueError, match="press rows feed"):
        press_rows(("position_x", "f_previous"))


def test_added_rows_check_and_a_spoiled_force_is_found() -> None:
    m = spring()
    entry = add_reference_rows(m, press_rows(("velocity", "position_x")), "test press")
    assert len(entry["force"]) == 32 and entry["source"] == "test press"
    assert max(entry["force"]) == pytest.approx(300 * 0.015 + 2 * 0.02, rel=1e-5)
    assert check_reference(m) is None
    add_reference_rows(m, press_rows(("velocity", "position_x"), steps=4), "again")
    assert [p.key for p in m.metadata_props].count(REFERENCE_KEY) == 1  # replaced, not added
    doc = json.loads(next(p.value for p in m.metadata_props if p.key == REFERENCE_KEY))
    doc["force"][2] += 0.01
    write_entry(m, doc)
    assert "step 2 of 4" in (check_reference(m) or "")
