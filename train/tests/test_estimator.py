"""The models' estimator shape (fit(X, y) / predict(X) on arrays, fitted attributes ending in
`_`) and the one conversion of recordings into those arrays (`data.training_arrays`)."""

import numpy as np
import pytest

from haptics_train.data import (
    SequenceInfo,
    contact_thresholds,
    row_stride,
    to_rows,
    to_sequences,
    training_arrays,
)
from haptics_train.features import KINEMATICS
from haptics_train.models import NotFittedError, TrainConfig, fit_recordings, make_model
from haptics_train.models.networks import AUX
from haptics_train.vocab import THESIS_FEATURES


def _xy(n: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = np.column_stack([rng.uniform(0, 0.03, n), rng.uniform(-0.05, 0.05, n)])
    return x, 500.0 * x[:, 0] + 30.0 * x[:, 1]


def test_rows_layout_takes_arrays_and_returns_self() -> None:
    x, y = _xy()
    m = make_model("sd_poly1")
    assert m.fit(x, y) is m
    assert m.n_features_in_ == 2 and set(m.train_info_) >= {"rows", "k", "b"}
    np.testing.assert_allclose(m.predict(x), y, atol=1e-9)
    rf = make_model("rf", "x_v", hyper={"n_estimators": 5, "max_depth": 4})
    assert rf.fit(x, y).predict(x).shape == (len(y),)
    assert hasattr(rf, "estimator_") and not hasattr(rf, "estimator")


def test_unfitted_and_misshaped_inputs_are_refused() -> None:
    x, y = _xy()
    m = make_model("sd_poly2")
    with pytest.raises(NotFittedError, match="not fitted"):
        m.predict(x)
    with pytest.raises(NotFittedError):
        m.to_onnx()
    with pytest.raises(ValueError, match=r"X must be \[n, 2\]"):
        m.fit(x[:, :1], y)
    with pytest.raises(ValueError, match="one target per row"):
        m.fit(x, y[:-1])
    m.fit(x, y)
    with pytest.raises(ValueError, match=r"position_x, velocity"):
        m.predict(np.zeros((3, 5)))
    with pytest.raises(ValueError, match="no parameter"):
        m.set_params(depth=3)


def test_sequences_layout_for_stateful_models() -> None:
    x, y = _xy(600)
    info = [SequenceInfo(1000.0, 0.299, 1, 1, 0.0), SequenceInfo(1000.0, 0.299, 1, 1, 0.0)]
    m = make_model("prony")
    assert m.layout == "sequences" and m.kind == "stateful"
    with pytest.raises(ValueError, match="lists of sequences"):
        m.fit(x, y, info=info)
    with pytest.raises(ValueError, match="one SequenceInfo per sequence"):
        m.fit([x[:300], x[300:]], [y[:300], y[300:]], info=info[:1])
    assert m.fit([x[:300], x[300:]], [y[:300], y[300:]], info=info) is m
    assert m.dt_ == pytest.approx(1e-3) and len(m.taus_) == m.hyper["n_tau"]
    assert m.predict(x[:300]).shape == (300,)


def test_feedback_noise_needs_the_aux_columns() -> None:
    x, y = _xy(200)
    six = THESIS_FEATURES[:6]  # Table 3.1's first six, in the vocabulary's order
    m = make_model("dnn_fb", "six", hyper={"epochs": 1})
    assert m.aux_columns == AUX
    x6 = np.column_stack([x, np.zeros((len(y), 4))])
    assert m.features == six
    with pytest.raises(ValueError, match="feedback noise needs `aux`"):
        m.fit(x6, y)
    aux = np.column_stack([y, x, np.zeros(len(y))])
    assert m.fit(x6, y, aux=aux).predict(x6).shape == (len(y),)


def test_training_arrays_is_the_recordings_conversion(synth) -> None:
    cfg = TrainConfig(decimate=5, progress=False)
    recs = synth.train
    feats = KINEMATICS
    x, y, params = training_arrays(recs, feats, "rows", (), cfg.target, cfg.decimate)
    assert params == {}
    k = [row_stride(r, 5) for r in recs]
    assert len(y) == sum(len(range(0, len(r), s)) for r, s in zip(recs, k, strict=True))
    np.testing.assert_array_equal(x[: len(recs[0].target(cfg.target, k[0]))],
                                  recs[0].matrix(feats, k[0]))  # fmt: skip
    xr, yr = to_rows(recs, feats, cfg.target, cfg.decimate)
    np.testing.assert_array_equal(x, xr)
    np.testing.assert_array_equal(y, yr)
    xa, ya, pa = training_arrays(recs, feats, "rows", AUX, cfg.target, cfg.decimate)
    np.testing.assert_array_equal(xa, x)
    assert pa["aux"].shape == (len(ya), len(AUX))  # type: ignore[union-attr]
    xs, ys, ps = training_arrays(recs, feats, "sequences", AUX, cfg.target, cfg.decimate)
    assert [len(s) for s in xs] == [len(r) for r in recs]  # type: ignore[union-attr]
    info = ps["info"]
    assert [i.stride for i in info] == k  # type: ignore[union-attr]
    assert [i.contact_off_n for i in info] == [contact_thresholds(r)[1] for r in recs]  # type: ignore[union-attr]
    assert len(ps["aux"]) == len(recs)  # type: ignore[arg-type]
    sx, sy, sinfo = to_sequences(recs, feats, cfg.target, cfg.decimate)
    np.testing.assert_array_equal(sx[0], xs[0])  # type: ignore[index]
    with pytest.raises(ValueError, match="unknown layout"):
        training_arrays(recs, feats, "grid")


def test_fit_recordings_equals_fit_on_its_arrays(synth) -> None:
    cfg = TrainConfig(decimate=5, progress=False, seed=4)
    a = fit_recordings(make_model("rf", "six", hyper={"n_estimators": 5}), synth.train, cfg)
    x, y, _ = training_arrays(synth.train, a.features, "rows", (), cfg.target, cfg.decimate)
    b = make_model("rf", "six", hyper={"n_estimators": 5}).set_params(seed=4).fit(x, y)
    rows = synth.test[0].matrix(a.features)
    # equal up to the order the forest's two jobs add their trees in
    np.testing.assert_allclose(a.predict(rows), b.predict(rows), rtol=1e-12, atol=1e-12)
