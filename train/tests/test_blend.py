"""`blend` (models/blend.py): the mean of two fitted stateful models, each stepping its own
state; dissipative when its members are, served as one stateful graph in parity with
`predict_served`, refused with why for members it cannot blend; and the study's choice of its
two members (the first of the ranking, and the partner whose blend with it the ranking runs
feel closest) and clean-up of an earlier study's blend."""

import copy
import json

import joblib
import numpy as np
import onnx
import pytest
from test_lawfree import SMALL as LAWFREE_SMALL
from test_lawfree import pad
from test_structured import SMALL as STRUCTURED_SMALL
from test_structured import info, presses

from haptics_train.closed_loop import OnnxStepper
from haptics_train.contract import validate_model
from haptics_train.export import provenance, to_contract_onnx
from haptics_train.metrics import loop_work
from haptics_train.models import TrainConfig, make_model
from haptics_train.models.blend import (
    BLEND_NAME,
    WEIGHT_GRID,
    BlendError,
    BlendModel,
    blendable,
)
from haptics_train.pipeline import export_models, remove_blend, trial_blends
from haptics_train.study.report import blend_sentence
from haptics_train.study.run import blend_partners


def training() -> tuple[list[np.ndarray], list[np.ndarray], list]:
    x, v = presses([0.01, 0.02, 0.015, 0.025, 0.006], 2.0)
    _, y = pad(x, v)
    return [np.column_stack([x, v])], [y], [info(len(x))]


@pytest.fixture(scope="module")
def members():
    X, y, inf = training()
    a = make_model("structured", hyper=STRUCTURED_SMALL).fit(X, y, info=inf)
    b = make_model("lawfree", hyper=LAWFREE_SMALL).fit(X, y, info=inf)
    return a, b


def held_out() -> tuple[np.ndarray, np.ndarray]:
    x, v = presses([0.018, 0.008], 1.3)  # depths and a rate neither member was fitted on
    return x, np.column_stack([x, v])


def test_the_blend_is_the_mean_of_its_members_and_dissipates(members):
    a, b = members
    m = BlendModel.of(a, b)
    x, X = held_out()
    np.testing.assert_allclose(m.predict(X), 0.5 * (a.predict(X) + b.predict(X)))
    served = m.predict_served(X)
    np.testing.assert_allclose(served, 0.5 * (a.predict_served(X) + b.predict_served(X)))
    assert m.name == BLEND_NAME and m.state_size == a.state_size + b.state_size
    assert m.train_info_["members"] == [a.name, b.name]
    assert np.all(served >= 0) and loop_work(x, served) > 0  # pushes only, absorbs energy
    # closer to the object than the worse member (a mean is never further than both)
    obj, _ = pad(x, X[:, 1])
    err = {k: np.sqrt(np.mean((f - obj) ** 2)) for k, f in
           (("a", a.predict_served(X)), ("b", b.predict_served(X)), ("blend", served))}
    assert err["blend"] <= max(err["a"], err["b"]), err


def test_the_blend_is_served_as_one_stateful_graph_in_parity(members, fused_ops):
    m = BlendModel.of(*members)
    for fused in (True, False):  # the fused nodes, and the members' multi-node graphs
        om = to_contract_onnx(m, provenance(m, TrainConfig(progress=False), None, None),
                              fused=fused)  # fmt: skip
        meta = validate_model(om)
        ops = [n.op_type for n in om.graph.node]
        assert ops == ["BlendStep"] if fused else len(ops) > 2, ops  # one node when fused
        assert meta["haptics.kind"] == "stateful"
        assert meta["haptics.state_size"] == str(m.state_size)
        assert float(meta["haptics.step_s"]) == m.serve_dt_
        _, X = held_out()
        st = OnnxStepper(om)
        got = np.array([st.step(r) for r in X.astype(np.float32)])
        np.testing.assert_allclose(got, m.predict_served(X), atol=2e-3)


def test_fit_fits_both_members_like_a_voting_regressor():
    X, y, inf = training()
    m = BlendModel([make_model("structured", hyper=STRUCTURED_SMALL),
                    make_model("lawfree", hyper=LAWFREE_SMALL)]).fit(X, y, info=inf)  # fmt: skip
    assert all(hasattr(k, "train_info_") for k in m.members_)
    assert np.isfinite(m.predict(X[0])).all()


def test_models_it_cannot_blend_are_refused_with_why(members):
    a, b = members
    sd = make_model("sd_poly2")
    sd.fit(np.array([[0.001, 0.0], [0.002, 0.0]]), np.array([1.0, 2.0]))
    with pytest.raises(BlendError, match="not a stateful model"):
        BlendModel.of(a, sd)
    with pytest.raises(BlendError, match=f"both are {a.name}"):
        BlendModel.of(a, a)
    other = copy.deepcopy(b)
    other.serve_dt_ = 2 * b.serve_dt_  # exported for a loop of another rate
    assert "steps at" in (blendable(a, other) or "")
    with pytest.raises(BlendError, match="weights"):
        BlendModel((a, b), {"weights": [0.5, -0.5]})
    assert blendable(a, b) is None


def test_the_study_tries_the_first_with_every_other_felt_candidate():
    ranking = [{"model": "s", "felt_rmse_n": 0.05}, {"model": "v", "felt_rmse_n": None},
               {"model": "l", "felt_rmse_n": 0.07}, {"model": "p", "felt_rmse_n": 0.08}]
    assert blend_partners(ranking) == ("s", ["l", "p"])
    assert blend_partners(ranking[1:]) == ("l", ["p"])
    assert blend_partners(ranking[:2]) is None


def test_trial_blends_are_servable_files_and_skip_what_cannot_blend(members, tmp_path, fused_ops):
    a, b = members
    sd = make_model("sd_poly2")
    sd.fit(np.array([[0.001, 0.0], [0.002, 0.0]]), np.array([1.0, 2.0]))
    cfg = TrainConfig(progress=False)
    for m in (a, b, sd):
        joblib.dump({"model": m, "config": cfg}, tmp_path / f"{m.name}.joblib")
    files = trial_blends(tmp_path, a.name, [sd.name, b.name], tmp_path / "trials")
    assert list(files) == [b.name]  # sd_poly2 is stateless: left out, not an error
    om = onnx.load(str(files[b.name]))
    assert validate_model(om)["haptics.state_size"] == str(a.state_size + b.state_size)
    _, X = held_out()
    st = OnnxStepper(om)
    got = np.array([st.step(r) for r in X.astype(np.float32)])
    np.testing.assert_allclose(got, BlendModel.of(a, b).predict_served(X), atol=2e-3)
    assert not (tmp_path / "blend.onnx").exists()  # trials never become the folder's blend
    # a weight of the grid: its own file, the weighted mean
    w = WEIGHT_GRID[1]
    got_w = trial_blends(tmp_path, a.name, [b.name], tmp_path / "trials", w)
    assert got_w[b.name] != files[b.name]
    st = OnnxStepper(onnx.load(str(got_w[b.name])))
    got = np.array([st.step(r) for r in X.astype(np.float32)])
    want = w[0] * a.predict_served(X) + w[1] * b.predict_served(X)
    np.testing.assert_allclose(got, want, atol=2e-3)
    assert np.abs(want - BlendModel.of(a, b).predict_served(X)).max() > 1e-2  # not the mean


def test_the_chosen_trial_is_the_exported_blends_graph(members, tmp_path, fused_ops):
    """The study lets the chosen trial's ranking runs stand for the built blend's (study/run.py,
    `_blend`): the trial file and the blend `export_models` writes must step alike. Export adds
    metadata only (provenance, cost, reference steps); the graphs are the same bytes."""
    a, b = members
    cfg = TrainConfig(progress=False)
    for m in (a, b):
        joblib.dump({"model": m, "config": cfg}, tmp_path / f"{m.name}.joblib")
    w = WEIGHT_GRID[1]
    trial = onnx.load(str(trial_blends(tmp_path, a.name, [b.name], tmp_path / "trials", w)[b.name]))
    export_models([(BlendModel.of(a, b, w), cfg)], None, tmp_path)
    built = onnx.load(str(tmp_path / f"{BLEND_NAME}.onnx"))
    assert built.graph.SerializeToString() == trial.graph.SerializeToString()
    assert built.opset_import == trial.opset_import
    _, X = held_out()
    steps = [OnnxStepper(m) for m in (trial, built)]
    got = np.array([[st.step(r) for st in steps] for r in X.astype(np.float32)])
    np.testing.assert_array_equal(got[:, 0], got[:, 1])


def test_an_earlier_studys_blend_is_removed_and_nothing_else(tmp_path):
    (tmp_path / "predictions").mkdir()
    for f in ("blend.joblib", "blend.onnx", "predictions/blend.npz", "structured.onnx"):
        joblib.dump({}, tmp_path / f)
    (tmp_path / "results.json").write_text(json.dumps({"blend": {}, "structured": {"x": 1}}))
    assert remove_blend(tmp_path)
    assert sorted(p.name for p in tmp_path.rglob("*") if p.is_file()) == [
        "results.json", "structured.onnx"]  # fmt: skip
    assert json.loads((tmp_path / "results.json").read_text()) == {"structured": {"x": 1}}
    assert not remove_blend(tmp_path)


def test_the_report_says_what_the_blend_is_made_of_and_how_it_was_chosen():
    entry = {
        "members": ["s", "l"],
        "weights": [0.75, 0.25],
        "partners_felt_n": {"l": 0.0412, "p": 0.05},
        "weights_felt_n": [{"weights": list(w), "felt_rmse_n": 0.04} for w in WEIGHT_GRID],
    }
    text = blend_sentence(entry)
    assert "0.75 x `s` + 0.25 x `l`" in text and "of the 2 partners" in text
    assert "(0.0412 N)" in text and "0.5 / 0.5, 0.75 / 0.25, 0.25 / 0.75" in text
    # an earlier study's entry, before partners and weights were chosen
    earlier = {"members": ["s", "l"], "weights": [0.5, 0.5]}
    assert "the mean of `s` and `l`" in blend_sentence(earlier)
