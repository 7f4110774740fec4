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
                        contact_off_n=0.05)  # fmt: skip


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


@pytest.mark.parametrize("set_max_m,every_column", [(0.0, False), (0.0025, False), (0.0025, True)])
def test_structured_graph_matches_predict(train_x, set_max_m, every_column, fused_ops):
    """The fused node (the default export) and the multi-node graph each match `predict`
    within 1e-4 N, and each other, stepped through ONNX Runtime."""
    small = {"yield_frac": [0.1, 0.2], "densification_frac": [1.1, 1.6],
             "densification_exponents": [1.0, 2.0, 3.0], "taus_s": [0.1, 1.0],
             "hysteresis_frac": [0.04, 0.16], "friction_lengths_m": [2e-5],
             "set_frac": [0.0], "set_exponent": [1.5],
             # not 0.5: the second press peaks at exactly half the first's depth, a tie that
             # float32 and float64 break apart (a step of set growth more or less)
             "set_loaded_fraction": [0.6]}  # fmt: skip
    m = make_model("structured", hyper=small)
    m.fit([train_x], [foam(train_x)], info=[info(len(train_x))])
    m.set_max_m_ = set_max_m  # the set law's path, whatever the fit chose
    if every_column:  # every plateau and pole weighted: each exponent's path, the linear part
        m.a_ = m.a_ + 1e-3
    prov = provenance(m, CFG, None, None)
    fused, graph = to_contract_onnx(m, prov), to_contract_onnx(m, prov, fused=False)
    assert [(n.domain, n.op_type) for n in fused.graph.node] == [("ai.haptics", "StructuredStep")]
    check_graph(graph, 60)
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


def test_prony_graph_matches_predict(train_x):
    m = make_model("prony")
    m.fit([train_x], [foam(train_x)], info=[info(len(train_x))])
    om = to_contract_onnx(m, provenance(m, CFG, None, None))
    check_graph(om, 12)
    X = presses([0.02, 0.01], 2.0)
    np.testing.assert_allclose(stepped(om, X), m.predict(X), atol=PARITY_N)


@pytest.mark.parametrize("algo", ["sd_const", "sd_poly1", "sd_poly2"])
def test_spring_damper_graph_matches_predict(train_x, algo):
    m = make_model(algo)
    m.fit(train_x, foam(train_x))
    om = to_contract_onnx(m, provenance(m, CFG, None, None))
    check_graph(om, 6)
    X = presses([0.03], 1.0)
    got = session(om).run(None, {"features": X.astype(np.float32)})[0][:, 0]
    np.testing.assert_allclose(got, m.predict(X), atol=PARITY_N)
