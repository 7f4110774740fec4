"""The example ONNX object (haptics_train.objects.hunt_crossley, docs/laws/onnx.md): the graph
steps the law its numpy reference steps, and the committed graph and reference trajectory are
what the script writes (so rt-loop's tests compare against the current law)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort

from haptics_train.objects import hunt_crossley as hc
from haptics_train.reference import REFERENCE_KEY, REFERENCE_STEPS, check_reference

ROOT = Path(__file__).resolve().parents[2]


def test_the_graph_steps_the_reference_law() -> None:
    p = hc.HuntCrossley()
    t, x, force = hc.reference(p)
    s = ort.InferenceSession(hc.build(p).SerializeToString())
    h = np.zeros((1, 1, hc.STATE), np.float32)
    c = h.copy()
    got = np.empty(len(t))
    for j in range(len(t)):
        v = 0.0 if j == 0 else (x[j] - x[j - 1]) * hc.RATE_HZ
        f, h, c = s.run(None, {"features": np.array([[x[j], v]], np.float32), "h_in": h,
                               "c_in": c})  # fmt: skip
        got[j] = f[0, 0]
    assert force.max() > 8.0  # the programme presses
    assert (force[x <= 0] == 0).all() and (got[x <= 0] == 0).all()  # 0 out of contact
    assert np.abs(got - force).max() < 1e-4  # float32 graph vs float64 law


def test_the_committed_graph_and_reference_are_current(tmp_path: Path) -> None:
    onnx_path, ref = tmp_path / "hc.onnx", tmp_path / "ref.csv"
    assert hc.main(["--onnx", str(onnx_path), "--reference", str(ref)]) == 0
    committed = onnx.load(ROOT / "materials/hunt-crossley.onnx")
    assert onnx.load(onnx_path).SerializeToString() == committed.SerializeToString()
    committed_ref = (ROOT / "rt-loop/tests/fixtures/hunt-crossley-reference.csv").read_text()
    assert ref.read_text() == committed_ref
    meta = {e.key: e.value for e in committed.metadata_props}
    assert meta["haptics.features"] == "position_x,velocity"
    # 32 steps of the float64 law, which this machine's ONNX Runtime computes within tolerance
    assert len(json.loads(meta[REFERENCE_KEY])["force"]) == REFERENCE_STEPS
    assert check_reference(committed) is None
    assert meta["haptics.kind"] == "stateful" and meta["haptics.units"] == "N"
