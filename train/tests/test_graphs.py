"""The hand-built ONNX graphs (models/onnx_graph.py and the builders beside it): every one
matches its model's `predict` within 1e-4 N stepped as infer-server steps it, computes nothing
from shapes at run time, and stays a few dozen nodes; the structured model's permanent-set law
(left out of the graph when its fitted magnitude is 0) is checked with a magnitude forced on,
and its equilibrium with every plateau and pole weighted (one per densification exponent)."""

import numpy as np
import onnx
import pytest

from haptics_train.closed_loop import OnnxStepper, session
from haptics_train.data import SequenceInfo
from haptics_train.export import provenance, to_contract_onnx
from haptics_train.models import TrainConfig, make_model

RATE = 1000.0
CFG = TrainConfig(progress=False)
PARITY_N = 1e-4
SHAPE_OPS = {"Shape", "ConstantOfShape", "Size", "Expand", "Range", "NonZero"}


def presses(depths: list[float], period_s: float) -> np.ndarray:
    t = np.arange(0, period_s, 1 / RATE)
    x = np.concatenate([-0.002 + (d + 0.002) * 0.5 * (1 - np.cos(2 * np.pi * t / period_s))
                        for d in depths])  # fmt: skip
    return np.column_stack([x, np.gradient(x, 1 / RATE)])


def foam(X: np.ndarray) -> np.ndarray:
    e = np.maximum(X[:, 0], 0.0)
    feq = 3.0 * np.tanh(e / 0.004) + 0.5 * ((1 - e / 0.04) ** -2 - 1)
    return feq + 0.3 * np.tanh(X[:, 1] / 1e-3)


def info(n: int) -> SequenceInfo:
    return SequenceInfo(sample_rate_hz=RATE, duration_s=n / RATE, stride=1, row_step=1,
                        contact_off_n=0.05, loop_rate_hz=RATE)  # fmt: skip


def served(m: object, X: np.ndarray) -> np.ndarray:
    return getattr(m, "predict_served", m.predict)(X)  # type: ignore[attr-defined]


def stepped(om: onnx.ModelProto, X: np.ndarray) -> np.ndarray:
    st = OnnxStepper(om)
    return np.array([st.step(r) for r in X.astype(np.float32)])


def check_graph(om: onnx.ModelProto, max_nodes: int) -> None:
    ops = {n.op_type for n in om.graph.node}
    assert not ops & SHAPE_OPS, ops & SHAPE_OPS
    assert len(om.graph.node) <= max_nodes, [n.op_type for n in om.graph.node]


@pytest.fixture(scope="module")
def train_x() -> np.ndarray:
    return presses([0.01, 0.02, 0.015, 0.025], 2.0)


@pytest.mark.parametrize("set_max_m,every_column,indentation", [
    (0.0, False, False), (0.0025, False, False), (0.0025, True, False), (0.0025, True, True)])
def test_structured_graph_matches_predict(train_x, set_max_m, every_column, indentation,
                                          fused_ops):  # fmt: skip
    """The fused node (the default export) and the multi-node graph each match `predict`
    within 1e-4 N, and each other, stepped through ONNX Runtime; with the indentation
    elements too (powers of the depth, branches whose time follows it, emptied out of
    contact: the presses below leave the object between each)."""
    small = {"yield_frac": [0.1, 0.2], "densification_frac": [1.1, 1.6],
             "densification_exponents": [1.0, 2.0, 3.0], "taus_s": [0.1, 1.0],
             "hysteresis_frac": [0.04, 0.16], "friction_lengths_m": [2e-5],
             "set_frac": [0.0], "set_exponent": [1.5],
             # not 0.5: the second press peaks at exactly half the first's depth, a tie that
             # float32 and float64 break apart (a step of set growth more or less)
             "set_loaded_fraction": [0.6]}  # fmt: skip
    if indentation:
        small |= {"power_exponents": [1.0, 1.5, 2.0], "depth_taus_s": [0.03, 1.0]}
    m = make_model("structured", hyper=small)
    m.fit([train_x], [foam(train_x)], info=[info(len(train_x))])
    m.set_max_m_ = set_max_m  # the set law's path, whatever the fit chose
    if every_column:  # every plateau, pole and power weighted: each exponent's path
        m.a_ = m.a_ + 1e-3
    if indentation:  # every branch weighted, the depth-scaled ones (the last two) the most
        m.g_ = m.g_ + np.array([1e-3, 1e-3, 0.2, 0.3])
        assert len(m.a_) == 2 + 6 + 3 and m.state_size == 4 + 2 + 3
    prov = provenance(m, CFG, None, None)
    fused, graph = to_contract_onnx(m, prov), to_contract_onnx(m, prov, fused=False)
    assert [(n.domain, n.op_type) for n in fused.graph.node] == [("ai.haptics", "StructuredStep")]
    check_graph(graph, 70 if indentation else 60)  # the indentation elements: 9 nodes more
    X = presses([0.02, 0.01, 0.03, 0.005], 2.0)
    ref = served(m, X)
    assert ref.max() > 1.0  # in contact, deep enough for the densification
    if every_column:  # past 0.95 d of the shallowest pole: its linear continuation
        assert X[:, 0].max() > 0.95 * min(m.basis_["densification_m"])
    got_fused, got_graph = stepped(fused, X), stepped(graph, X)
    np.testing.assert_allclose(got_fused, ref, atol=PARITY_N)
    np.testing.assert_allclose(got_graph, ref, atol=PARITY_N)
    np.testing.assert_allclose(got_fused, got_graph, atol=PARITY_N)


def test_a_fused_node_with_a_bad_attribute_fails_the_session_in_one_line(train_x, fused_ops):
    m = make_model("structured", hyper={"yield_frac": [0.1], "densification_frac": [1.6],
                                        "densification_exponents": [2.0], "taus_s": [0.1],
                                        "hysteresis_frac": [0.04], "friction_lengths_m": [2e-5],
                                        "set_frac": [0.0]})  # fmt: skip
    m.fit([train_x], [foam(train_x)], info=[info(len(train_x))])
    om = m.to_onnx()
    next(a for a in om.graph.node[0].attribute if a.name == "taus_s").floats[0] = -0.1
    want = r"StructuredStep: attribute `taus_s` = -0.1\d* is not positive"
    with pytest.raises(Exception, match=want):
        session(om)


def test_a_missing_library_says_how_to_build_it(monkeypatch, train_x, tmp_path):
    from haptics_train.ort_ops import FusedOpsMissing

    m = make_model("lawfree", hyper={"taus_s": [0.1], "play_frac": [0.1],
                                     "friction_lengths_m": [2e-5]})  # fmt: skip
    m.fit([train_x], [foam(train_x)], info=[info(len(train_x))])
    monkeypatch.setenv("HAPTICS_FUSED_OPS_LIB", str(tmp_path / "absent.so"))
    fused = m.to_onnx()
    onnx.save(fused, str(tmp_path / "lawfree.onnx"))
    want = r"run `cargo build --release -p haptics-fused-ops`"
    for model in (fused, fused.SerializeToString(), str(tmp_path / "lawfree.onnx")):
        with pytest.raises(FusedOpsMissing, match=want) as e:
            session(model)
        assert "\n" not in str(e.value)  # one line
    session(m.to_onnx(fused=False))  # a model without the fused node needs no library


def test_prony_fused_node_and_graph_match_predict(train_x, fused_ops):
    """The fused node (the default export) and the multi-node graph each match `predict`
    within 1e-4 N stepped as infer-server steps them, and each other."""
    m = make_model("prony")
    m.fit([train_x], [foam(train_x)], info=[info(len(train_x))])
    prov = provenance(m, CFG, None, None)
    fused, graph = to_contract_onnx(m, prov), to_contract_onnx(m, prov, fused=False)
    assert [(n.domain, n.op_type) for n in fused.graph.node] == [("ai.haptics", "PronyStep")]
    check_graph(graph, 12)
    X = presses([0.02, 0.01], 2.0)
    ref = m.predict(X)
    got_fused, got_graph = stepped(fused, X), stepped(graph, X)
    assert (ref > 0.5).sum() > 1000  # the check compares pressed rows, not zeros
    np.testing.assert_allclose(got_fused, ref, atol=PARITY_N)
    np.testing.assert_allclose(got_graph, ref, atol=PARITY_N)
    np.testing.assert_allclose(got_fused, got_graph, atol=PARITY_N)


def test_prony_fused_node_with_a_bad_attribute_fails_in_one_line(train_x, fused_ops):
    m = make_model("prony")
    m.fit([train_x], [foam(train_x)], info=[info(len(train_x))])
    om = m.to_onnx()
    next(a for a in om.graph.node[0].attribute if a.name == "branch_weights").floats.pop()
    want = r"PronyStep: attribute `branch_weights` has 5 values, `taus_s` has 6: they pair up"
    with pytest.raises(Exception, match=want):
        session(om)


@pytest.mark.parametrize("algo", ["sd_const", "sd_poly1", "sd_poly2"])
def test_spring_damper_fused_node_and_graph_match_predict(train_x, algo, fused_ops):
    """The default export is one `SpringDamperStep` node; it and the five-node graph
    (`fused=False`) both give `predict`, for a batch of rows as for one."""
    m = make_model(algo)
    m.fit(train_x, foam(train_x))
    prov = provenance(m, CFG, None, None)
    fused, graph = to_contract_onnx(m, prov), to_contract_onnx(m, prov, fused=False)
    assert [n.op_type for n in fused.graph.node] == ["SpringDamperStep"]
    check_graph(graph, 6)
    X = presses([0.03], 1.0)
    want = m.predict(X)
    assert np.abs(want).max() > 1.0, "the presses push"
    for om in (fused, graph):
        got = session(om).run(None, {"features": X.astype(np.float32)})[0][:, 0]
        np.testing.assert_allclose(got, want, atol=PARITY_N)
        one = session(om).run(None, {"features": X[200:201].astype(np.float32)})[0][:, 0]
        np.testing.assert_allclose(one, want[200:201], atol=PARITY_N)


def test_spring_damper_fused_node_with_a_bad_attribute_fails_in_one_line(train_x, fused_ops):
    m = make_model("sd_poly2")
    m.fit(train_x, foam(train_x))
    om = m.to_onnx()
    next(a for a in om.graph.node[0].attribute if a.name == "b").floats.pop()
    want = r"SpringDamperStep: attribute `b` has 2 values, `k \(the same order\)` has 3"
    with pytest.raises(Exception, match=want):
        session(om)


def _dense_rows(n: int, seed: int = 0) -> np.ndarray:
    """The six features as the loop computes them: x, v, a and the previous force over each
    (huge near zero divisors, zero rows among them)."""
    rng = np.random.default_rng(seed)
    x, v = rng.uniform(-0.002, 0.03, n), rng.normal(0, 0.02, n)
    a, f = rng.normal(0, 0.5, n), rng.uniform(0, 14, n)
    v[::50] = 1e-25
    x[::70] = 0.0
    return np.column_stack([x, v, a, _ratios(f, np.column_stack([x, v, a]))])


def _ratios(f: np.ndarray, kin: np.ndarray) -> np.ndarray:
    """F / each kinematic column, 0 where it is 0."""
    safe = np.where(kin != 0, kin, 1.0)
    return np.where(kin != 0, f[:, None] / safe, 0.0)


@pytest.mark.parametrize("hyper", [{"hidden": [24, 16, 8], "epochs": 2},
                                   {"arch": "thesis", "epochs": 1}])  # fmt: skip
def test_dense_fused_node_matches_the_graph_and_predict(hyper, fused_ops):
    """The fused node (the default export, any number of rows) and the multi-node graph each
    match `predict` within 1e-4 N, and each other; the thesis network (sigmoid output, the
    target scaling not foldable into a Linear) as well as the default SiLU one."""
    X = _dense_rows(3000)
    y = 50 * X[:, 0] + 2 * np.tanh(X[:, 1] / 0.01)
    m = make_model("dnn", "six", hyper=hyper)
    m.fit(X, y)
    prov = provenance(m, CFG, None, None)
    fused, graph = to_contract_onnx(m, prov), to_contract_onnx(m, prov, fused=False)
    assert [(n.domain, n.op_type) for n in fused.graph.node] == [("ai.haptics", "DenseStep")]
    Xt = _dense_rows(2000, seed=1)
    ref = m.predict(Xt)
    feats = {"features": Xt.astype(np.float32)}
    got_fused = session(fused).run(None, feats)[0][:, 0]
    got_graph = session(graph).run(None, feats)[0][:, 0]
    np.testing.assert_allclose(got_fused, ref, atol=PARITY_N)
    np.testing.assert_allclose(got_fused, got_graph, atol=PARITY_N)
    one = session(fused).run(None, {"features": Xt[:1].astype(np.float32)})[0]
    assert one.shape == (1, 1) and abs(one[0, 0] - ref[0]) < PARITY_N
    none = session(fused).run(None, {"features": Xt[:0].astype(np.float32)})[0]
    assert none.shape == (0, 1)


def test_dense_fused_node_with_a_bad_attribute_fails_in_one_line(fused_ops):
    X = _dense_rows(500)
    m = make_model("dnn", "six", hyper={"hidden": [8], "epochs": 1})
    m.fit(X, X[:, 0])
    om = m.to_onnx()
    next(a for a in om.graph.node[0].attribute if a.name == "activations").s = b"silu,gelu"
    want = r"DenseStep: attribute `activations` = 1 is the index of a name other than"
    with pytest.raises(Exception, match=want):
        session(om)


@pytest.mark.parametrize("fset", ["x_v", "six"])
def test_lstm_fused_node_matches_the_graph_and_predict(train_x, fset, fused_ops):
    """The fused LSTM step (the default export) and the multi-node graph (ONNX's LSTM op) each
    match `predict` within 1e-4 N stepped as infer-server steps them, and each other; with
    `six` the ratio features go through the kernel's asinh."""
    X = train_x if fset == "x_v" else _press_six(train_x)
    m = make_model("lstm", fset, hyper={"iterations": 30, "streams": 8, "chunk": 20,
                                         "hidden": 24})  # fmt: skip
    m.fit([X], [foam(train_x)], [info(len(X))])
    prov = provenance(m, CFG, None, None)
    fused, graph = to_contract_onnx(m, prov), to_contract_onnx(m, prov, fused=False)
    assert [(n.domain, n.op_type) for n in fused.graph.node] == [("ai.haptics", "LstmStep")]
    Xt = X[: len(X) // 2]
    ref = m.predict(Xt)
    got_fused, got_graph = stepped(fused, Xt), stepped(graph, Xt)
    assert (foam(train_x[: len(Xt)]) > 0.5).sum() > 1000  # rows past first contact
    np.testing.assert_allclose(got_fused, ref, atol=PARITY_N)
    np.testing.assert_allclose(got_fused, got_graph, atol=PARITY_N)


def _press_six(xv: np.ndarray) -> np.ndarray:
    """The six features along the presses: x, v, a and the previous force over each."""
    kin = np.column_stack([xv, np.gradient(xv[:, 1], 1 / RATE)])
    return np.column_stack([kin, _ratios(np.r_[0.0, foam(xv)[:-1]], kin)])


def test_lstm_fused_node_with_a_bad_attribute_fails_in_one_line(train_x, fused_ops):
    m = make_model("lstm", "x_v", hyper={"iterations": 2, "streams": 4, "chunk": 20,
                                         "hidden": 4})  # fmt: skip
    m.fit([train_x], [foam(train_x)], [info(len(train_x))])
    om = m.to_onnx()
    next(a for a in om.graph.node[0].attribute if a.name == "head_weights").floats.pop()
    want = r"LstmStep: attribute `head_weights` has 3 values, `H` has 4: they pair up"
    with pytest.raises(Exception, match=want):
        session(om)


def test_svr_fused_node_matches_predict_and_the_graph(fused_ops):
    """The fused RBF SVR (the default export, any number of rows) matches scikit-learn's
    float64 `predict` within 1e-4 N, closer than skl2onnx's float32 graph (kept by
    `fused=False`), and a bad attribute refuses the session in one line."""
    X = _dense_rows(3000)
    y = 50 * X[:, 0] + 2 * np.tanh(X[:, 1] / 0.01)
    m = make_model("svr", "six", hyper={"max_rows": 800})
    m.fit(X, y)
    prov = provenance(m, CFG, None, None)
    fused, graph = to_contract_onnx(m, prov), to_contract_onnx(m, prov, fused=False)
    assert [(n.domain, n.op_type) for n in fused.graph.node] == [("ai.haptics", "SvrStep")]
    Xt = _dense_rows(2000, seed=1)
    ref = m.predict(Xt)
    feats = {"features": Xt.astype(np.float32)}
    got_fused = session(fused).run(None, feats)[0][:, 0]
    got_graph = session(graph).run(None, feats)[0][:, 0]
    assert len(m.estimator_[-1].support_) > 100
    np.testing.assert_allclose(got_fused, ref, atol=PARITY_N)
    np.testing.assert_allclose(got_graph, ref, atol=5e-3)
    next(a for a in fused.graph.node[0].attribute if a.name == "gamma").f = -1.0
    with pytest.raises(Exception, match=r"SvrStep: attribute `gamma` = -1 is not positive"):
        session(fused)
