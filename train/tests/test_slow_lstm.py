"""`lstm_slow`: the LSTM whose state steps once per block of control steps. Its served graph
does the block bookkeeping itself (the state moves only when a block completes), matches the
framework's predictions step for step, survives a non-finite sample, takes kinematics only,
and learns the synthetic sponge far better than its mean. On the synthetic dataset (10 kHz,
blocks of 10 steps here so it runs in seconds)."""

import numpy as np
import pytest

from haptics_train.closed_loop import OnnxStepper
from haptics_train.contract import validate_model
from haptics_train.export import provenance, to_contract_onnx
from haptics_train.models import TrainConfig, fit_recordings, make_model, parse_spec

CFG = TrainConfig(progress=False)
SMALL = {"hidden": 12, "head": 12, "state_step_s": 0.001, "horizon_s": 0.05, "burn_in_s": 0.01,
         "streams": 8, "iterations": 250, "lr": 1e-2}  # fmt: skip


@pytest.fixture(scope="module")
def fitted(synth, fused_ops):  # the default export is the fused node (fused-ops/)
    m = make_model("lstm_slow", "x_v", hyper=SMALL)
    fit_recordings(m, synth.train, CFG)
    om = to_contract_onnx(m, provenance(m, CFG, synth, None))
    return m, om


def test_lstm_slow_is_kinematics_only_and_x_v_by_default():
    assert parse_spec("lstm_slow").features == ("position_x", "velocity")
    assert parse_spec("lstm_slow").name == "lstm_slow"  # the spec is the name, as the scripts use
    assert parse_spec("lstm_slow:xva").name == "lstm_slow_xva"
    with pytest.raises(ValueError, match="kinematics only"):
        make_model("lstm_slow", "six")  # the previous force would come back through the state


def test_lstm_slow_learns_the_sponge(fitted, synth):
    m, _ = fitted
    assert m.block_rows_ == 10 and m.train_info_["horizon_s_effective"] == pytest.approx(0.05)
    rec = synth.test[0]
    y = rec.target()
    p = m.predict(rec.matrix(m.features))
    rmse = float(np.sqrt(np.mean((p - y) ** 2)))
    assert rmse < 0.3 * float(np.std(y)), (rmse, float(np.std(y)))


def test_lstm_slow_served_graph_steps_its_state_once_per_block(fitted, synth):
    m, om = fitted
    meta = validate_model(om)
    assert meta["haptics.kind"] == "stateful"
    assert meta["haptics.state_size"] == str(12 + 2 + 1) == str(m.state_size)
    X = synth.test[0].matrix(m.features)[:400]
    st = OnnxStepper(om)
    got, lstm_state = [], []
    for row in X.astype(np.float32):
        got.append(st.step(row))
        lstm_state.append(st.h[0, 0, :12].copy())
    np.testing.assert_allclose(got, m.predict(X), atol=1e-4)
    moved = np.flatnonzero(np.any(np.diff(np.array(lstm_state), axis=0) != 0, axis=1)) + 1
    # the LSTM part of the state changes on the step that completes a block (steps 9, 19, ...)
    # and never in between
    assert set(moved) <= set(range(9, 400, 10)) and len(moved) >= 30, moved
    assert st.h[0, 0, -1] == 400 % 10  # the block's step count


def test_lstm_slow_served_state_survives_a_non_finite_sample(fitted, synth):
    _, om = fitted
    X = synth.test[0].matrix(("position_x", "velocity"))[:60].astype(np.float32)
    X[25, 1] = np.nan
    X[33, 0] = np.inf
    st = OnnxStepper(om)
    out = [st.step(r) for r in X]
    assert np.isfinite(out).all() and np.isfinite(st.h).all() and np.isfinite(st.c).all()


def test_lstm_slow_fused_node_equals_its_graph_and_predict(fitted, synth):
    """The fused node (the default export) and the multi-node graph each match `predict`
    within 1e-4 N, and each other, stepped from zero state over rows that reach contact."""
    m, om = fitted
    assert [(n.domain, n.op_type) for n in om.graph.node] == [("ai.haptics", "SlowLstmStep")]
    graph = to_contract_onnx(m, provenance(m, CFG, synth, None), fused=False)
    assert len(graph.graph.node) > 20
    rec = synth.test[0]
    y = rec.target()
    start = max(0, int(np.argmax(y > 0.5)) - 200)
    X = rec.matrix(m.features)[start : start + 3000]
    assert (y[start : start + 3000] > 0.5).sum() > 1000  # pressed rows, not zeros
    ref = m.predict(X)
    st_f, st_g = OnnxStepper(om), OnnxStepper(graph)
    fused = np.array([st_f.step(r) for r in X.astype(np.float32)])
    graphs = np.array([st_g.step(r) for r in X.astype(np.float32)])
    np.testing.assert_allclose(fused, ref, atol=1e-4)
    np.testing.assert_allclose(graphs, ref, atol=1e-4)
    np.testing.assert_allclose(fused, graphs, atol=1e-4)
