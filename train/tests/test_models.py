"""Every algorithm trains on the synthetic dataset, exports to a contract-valid ONNX file and
agrees with its framework in ONNX Runtime."""

import numpy as np
import onnx
import pytest
import torch

from haptics_train.closed_loop import OnnxStepper, session, simulate
from haptics_train.contract import validate_model
from haptics_train.data import recording_from_columns
from haptics_train.evaluate import evaluate
from haptics_train.export import onnx_predict, parity, provenance, to_contract_onnx
from haptics_train.features import NINE
from haptics_train.models import TrainConfig, fit_recordings, make_model
from haptics_train.models.sklearn_models import thresholds_down

CFG = TrainConfig(decimate=5, progress=False)
SMALL = {
    "rf": {"n_estimators": 20, "max_depth": 8},
    "svr": {"max_rows": 1500},
    "dnn": {"epochs": 4},
    "lstm": {"iterations": 40, "streams": 32, "chunk": 40},
}


@pytest.fixture(scope="module")
def trained(synth, fused_ops):  # the networks' default export is a fused node (fused-ops/)
    out = {}
    for algo, fs in [("sd_poly2", "x_v"), ("lr", "six"), ("svr", "six"), ("rf", "six"),
                     ("dnn", "six"), ("lstm", "six"), ("dnn", "xva_f")]:  # fmt: skip
        m = make_model(algo, fs, hyper=SMALL.get(algo))
        fit_recordings(m, synth.train, CFG)
        out[m.name] = (m, to_contract_onnx(m, provenance(m, CFG, synth, None)))
    return out


def test_every_model_exports_a_contract_valid_onnx(trained):
    assert set(trained) == {"sd_poly2", "lr_six", "svr_six", "rf_six", "dnn_six", "lstm_six",
                            "dnn_xva_f"}  # fmt: skip
    for name, (m, om) in trained.items():
        meta = validate_model(om)
        assert meta["haptics.features"] == ",".join(m.features), name
        assert meta["haptics.kind"] == ("stateful" if name.startswith("lstm") else "stateless")
        assert meta["haptics.units"] == "N"
        ops = {o.domain or "": o.version for o in om.opset_import}
        # exporters write the lowest opsets that suffice, never above the pinned ones
        assert ops[""] <= 17, (name, ops)
        assert ops.get("ai.onnx.ml", 0) <= 3, (name, ops)
        if name.startswith(("svr", "dnn", "lstm", "rf")):  # one fused node (fused-ops/)
            assert [n.domain for n in om.graph.node] == ["ai.haptics"], (name, ops)
        assert om.ir_version <= 10, (name, om.ir_version)


def test_onnx_parity_with_the_framework(trained, synth):
    tol = {"lr_six": 1e-3}
    for name, (m, om) in trained.items():
        p = parity(m, om, synth.test[0], stateful_limit=3000)
        assert p["all_finite"], name
        assert p["max_abs_diff"] < tol.get(name, 1e-4), (name, p)
        # the comparison covers forces, not only the zeros before the first contact
        assert p["rows_with_force"] > 1000, (name, p)
        if m.kind == "stateful":  # the stepped prefix reaches past the probe's first contact
            x = synth.test[0].column("position_x")
            assert p["rows"] > p["first_contact_row"] and x[p["first_contact_row"]] > 0, p


def test_forest_fused_node_and_graph_take_the_branches_of_predict(trained, synth):
    """On a recording's rows, the fused `ForestStep` node (the default export), skl2onnx's
    graph (`fused=False`) and scikit-learn's `predict` agree: the forest is trained on float32
    features and the fused node's thresholds are rounded down to float32, so every row takes
    the same branches and only the leaves' float32 sum differs."""
    m, om = trained["rf_six"]
    assert [(n.domain, n.op_type) for n in om.graph.node] == [("ai.haptics", "ForestStep")]
    graph = to_contract_onnx(m, provenance(m, CFG, synth, None), fused=False)
    assert "TreeEnsembleRegressor" in [n.op_type for n in graph.graph.node]
    rec = synth.test[0]
    ref = m.predict(rec.matrix(m.features))
    fused, tree_graph = onnx_predict(om, rec, m.features), onnx_predict(graph, rec, m.features)
    assert np.count_nonzero(np.abs(ref) >= 0.01) > 1000  # forces, not only the approach
    np.testing.assert_allclose(fused, ref, atol=1e-5)
    np.testing.assert_allclose(tree_graph, ref, atol=1e-5)
    np.testing.assert_allclose(fused, tree_graph, atol=1e-5)


def test_forest_thresholds_round_down_to_the_same_branches():
    """`thresholds_down`: for float32 x next to each threshold, `x <= t32` is `x <= t64`."""
    rng = np.random.default_rng(0)
    t = rng.normal(size=2000) * 10.0 ** rng.integers(-6, 3, 2000)
    t32 = thresholds_down(t)
    assert t32.dtype == np.float32 and np.all(t32.astype(np.float64) <= t)
    for k in (-2, -1, 0, 1, 2):
        x = t.astype(np.float32)
        for _ in range(abs(k)):
            x = np.nextafter(x, np.float32(np.sign(k) * np.inf))
        np.testing.assert_array_equal(x <= t32, x.astype(np.float64) <= t)


def test_forest_fused_node_with_a_bad_attribute_fails_in_one_line(trained, fused_ops):
    _, om = trained["rf_six"]
    bad = onnx.ModelProto()
    bad.CopyFrom(om)
    attr = next(a for a in bad.graph.node[0].attribute if a.name == "split_features")
    attr.ints[0] = 99
    with pytest.raises(Exception, match=r"ForestStep: attribute `split_features` = 0 is the "
                                        r"index of a node whose feature is not below n_features"):
        session(bad)


def test_lstm_stateful_export_carries_its_state(trained, synth):
    m, om = trained["lstm_six"]
    rec = synth.test[0]
    x = rec.matrix(m.features)[:500]
    ref = m.predict(x)  # torch over the sequence, state carried
    st = OnnxStepper(om)
    stepped = np.array([st.step(r) for r in x])
    np.testing.assert_allclose(stepped, ref, atol=1e-4)
    # resetting the state to zeros matters: a fresh stepper started mid-way disagrees
    st2 = OnnxStepper(om)
    late = np.array([st2.step(r) for r in x[250:]])
    assert np.max(np.abs(late[:5] - ref[250:255])) > 1e-4


def test_learned_models_beat_the_mean_on_held_out_data(trained, synth):
    rec = synth.test[0]
    for name, (m, om) in trained.items():
        res, _ = evaluate(m, om, rec, CFG, closed_loop=False)
        assert res["one_step"]["r2"] > 0.5, (name, res["one_step"])


def test_closed_loop_evaluation_uses_the_onnx_model_fed_back(trained, synth):
    m, om = trained["dnn_six"]
    rec = synth.test[0]
    res, preds = evaluate(m, om, rec, CFG)
    assert not res["closed_loop_same_as_one_step"]
    assert not np.allclose(preds["closed_loop"], preds["one_step"])
    # the closed loop is exactly a simulation with the framework model stepped row by row
    # (checked on a causal prefix: torch row by row is slow)
    n = 3000
    fw = simulate(_FrameworkStepper(m), rec.head(n), m.features)
    np.testing.assert_allclose(preds["closed_loop"][:n], fw, atol=2e-3)


class _FrameworkStepper:
    def __init__(self, m):
        self.m = m

    def reset(self):
        pass

    def step(self, row):
        return float(self.m.predict(row[None, :])[0])


def test_spring_damper_recovers_known_coefficients():
    rng = np.random.default_rng(3)
    n = 5000
    x = rng.uniform(0, 0.03, n)
    v = rng.uniform(-0.05, 0.05, n)
    k = np.array([200.0, 3000.0, 1e5])
    b = np.array([20.0, -100.0, 5000.0])
    f = (k[0] + k[1] * x + k[2] * x**2) * x + (b[0] + b[1] * x + b[2] * x**2) * v
    cols = {"time": np.arange(n) * 1e-4, "rtob_force": f, "position_x": x, "velocity": v,
            "acceleration": np.zeros(n), **{c: np.zeros(n) for c in NINE[3:]}}  # fmt: skip
    rec = recording_from_columns("exact", cols)
    m = make_model("sd_poly2")
    fit_recordings(m, [rec], TrainConfig(decimate=1, progress=False))
    np.testing.assert_allclose(m.k_, k, rtol=1e-6)
    np.testing.assert_allclose(m.b_, b, rtol=1e-6)
    const = make_model("sd_const")
    fit_recordings(const, [rec], TrainConfig(decimate=1, progress=False))
    assert const.k_.shape == (1,) and const.b_.shape == (1,)
    om = onnx.load_from_string(m.to_onnx().SerializeToString())
    from haptics_train.closed_loop import session

    got = session(om).run(None, {"features": np.column_stack([x, v]).astype(np.float32)})[0]
    np.testing.assert_allclose(got[:, 0], f, atol=1e-4)


def test_spring_damper_ignores_rows_out_of_contact():
    """A free-air recording (the bench's friction, x < 0) beside the contact rows leaves the
    contact law as fitted on the contact rows alone: a spring-damper holds no friction."""
    rng = np.random.default_rng(4)
    n = 4000
    x = np.concatenate([rng.uniform(0, 0.03, n), rng.uniform(-0.04, -0.004, n)])
    v = rng.uniform(-0.05, 0.05, 2 * n)
    law = 500.0 * x + 4e4 * x**2 * np.sign(x) + 30.0 * v
    f = np.where(x > 0, law, 0.9 * np.sign(v) + 5.0 * v)  # out of contact: friction only
    cols = {"time": np.arange(2 * n) * 1e-4, "rtob_force": f, "position_x": x, "velocity": v,
            "acceleration": np.zeros(2 * n), **{c: np.zeros(2 * n) for c in NINE[3:]}}  # fmt: skip
    m = make_model("sd_poly2")
    rec = recording_from_columns("mixed", cols)
    fit_recordings(m, [rec], TrainConfig(decimate=1, progress=False))
    np.testing.assert_allclose(m.k_, [500.0, 4e4, 0.0], atol=1e-6)
    np.testing.assert_allclose(m.b_, [30.0, 0.0, 0.0], atol=1e-6)
    assert m.train_info_["rows"] == n


def test_feature_sets_and_presets():
    from haptics_train.features import FEATURE_SETS

    assert FEATURE_SETS["six"].features == NINE[:6]
    assert FEATURE_SETS["x_v"].features == ("position_x", "velocity")
    assert make_model("rf", "six", preset="thesis").hyper["n_estimators"] == 1000
    assert make_model("svr", "six", preset="thesis").hyper["C"] == 0.1
    assert make_model("dnn", "six", preset="thesis").hyper["lr"] == 1e-6
    with pytest.raises(ValueError, match="unknown feature set"):
        make_model("rf", "seven")
    with pytest.raises(ValueError, match="unknown algorithm"):
        make_model("xgb", "six")


def test_network_survives_extreme_ratio_features(trained):
    """Near-zero velocities make F/v ~ 1e20-1e30 in real recordings: still finite, in parity."""
    m, om = trained["dnn_six"]
    from haptics_train.closed_loop import session

    x = np.array([
        [0.01, 1e-22, 1e-25, 300.0, 5e22, 4e25],
        [0.01, -1e-30, 1e-3, 300.0, -3e30, 3e3],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    ])  # fmt: skip
    ref = m.predict(x)
    got = session(om).run(None, {"features": x.astype(np.float32)})[0][:, 0]
    assert np.isfinite(ref).all() and np.isfinite(got).all()
    np.testing.assert_allclose(got, ref, atol=1e-3)


def test_perturb_previous_force_recomputes_ratios_and_holds_on_zero_divisors():
    import torch

    from haptics_train.models.networks import perturb_previous_force

    feats = ("position_x", "f_previous_x", "f_previous_v", "f_previous")
    x = torch.tensor([[0.01, 100.0, 20.0, 1.0], [0.0, 7.0, 5.0, 2.0]])
    aux = torch.tensor([[1.0, 0.01, 0.05, 3.0], [2.0, 0.0, 0.4, 1.0]])  # F(t-1), x, v, a
    out = perturb_previous_force(x, feats, aux, torch.tensor([0.5, -1.0]))
    torch.testing.assert_close(out[0], torch.tensor([0.01, 1.5 / 0.01, 1.5 / 0.05, 1.5]))
    # x = 0: f_previous_x keeps the recorded (held) value; v != 0: recomputed
    torch.testing.assert_close(out[1], torch.tensor([0.0, 7.0, 1.0 / 0.4, 1.0]))


def test_feedback_noise_training_improves_the_closed_loop(synth):
    """dnn_fb learns to correct an erroneous previous force: its closed loop (own predictions
    fed back) is better than the plain network's, at a small one-step cost."""
    res = {}
    for algo in ("dnn", "dnn_fb"):
        m = make_model(algo, "six", hyper={"epochs": 6})
        fit_recordings(m, synth.train, CFG)
        om = to_contract_onnx(m, provenance(m, CFG, synth, None))
        r, _ = evaluate(m, om, synth.test[0], CFG)
        res[algo] = r
    assert res["dnn_fb"]["closed_loop"]["rmse"] < 0.8 * res["dnn"]["closed_loop"]["rmse"], res


@pytest.mark.parametrize("algo", ["dnn", "lstm", "svr"])
def test_thesis_presets_train_and_export(synth, algo):
    small = {"dnn": {"epochs": 1}, "lstm": {"iterations": 3, "streams": 4, "chunk": 20},
             "svr": {"max_rows": 500}}[algo]  # fmt: skip
    m = make_model(algo, "six", preset="thesis", hyper=small)
    fit_recordings(m, synth.train, TrainConfig(decimate=50, progress=False))
    om = to_contract_onnx(m, provenance(m, CFG, synth, None))
    validate_model(om)
    p = parity(m, om, synth.test[0], stateful_limit=500)
    assert p["all_finite"] and p["max_abs_diff"] < 5e-3, p
    if algo == "dnn":
        # 150 sigmoid - dropout - 25 tanh - dropout - 1 sigmoid, output min-max scaled
        lin = [mod for mod in m.net_.body if isinstance(mod, torch.nn.Linear)]
        assert [lin_.out_features for lin_ in lin] == [150, 25, 1]
        assert isinstance(m.net_.body[-1], torch.nn.Sigmoid)


def test_forest_grown_with_progress_equals_one_fit():
    """The progress bar grows the forest in chunks (warm start); the trees are the same."""
    rng = np.random.default_rng(3)
    X = rng.normal(size=(400, 3))
    y = X[:, 0] * 2 + np.sin(X[:, 1]) + 0.1 * rng.normal(size=400)
    a = make_model("rf", "x_v", hyper={"n_estimators": 25, "max_depth": 5})
    b = make_model("rf", "x_v", hyper={"n_estimators": 25, "max_depth": 5})
    a.progress, b.progress = False, True
    a.fit(X[:, :2], y)
    b.fit(X[:, :2], y)
    assert len(b.estimator_.estimators_) == 25 and not b.estimator_.warm_start
    for ta, tb in zip(a.estimator_.estimators_, b.estimator_.estimators_, strict=True):
        np.testing.assert_array_equal(ta.tree_.threshold, tb.tree_.threshold)
        np.testing.assert_array_equal(ta.tree_.value, tb.tree_.value)
    # the mean over the trees is summed in another order: equal to rounding
    np.testing.assert_allclose(a.predict(X[:, :2]), b.predict(X[:, :2]), rtol=1e-12, atol=1e-12)
