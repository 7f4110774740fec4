"""A user's own tests, as they come (train/): choices without a validation recording
(blocked_validation.py: `lawfree` fitted without held-out blocks of its training rows, scored on
them, and chosen that way by `train_models`), tests logged at other rates (a model whose state
steps in time stepped at each recording's own period), and recordings whose features used other
filters (named before training)."""

import dataclasses
import json

import numpy as np
import pytest
from test_lawfree import SMALL, pad
from test_structured import RATE, info, presses

from haptics_train.blocked_validation import BLOCKED_VALIDATION, HOLDOUT_BLOCKS, blocks
from haptics_train.data import load_manifest, write_manifest_entry
from haptics_train.export import provenance, to_contract_onnx
from haptics_train.import_fixtures import write_examples
from haptics_train.importer import import_series
from haptics_train.lawfree_selection import lawfree_candidates
from haptics_train.models import TrainConfig, make_model, predict_at
from haptics_train.pipeline import feature_gains_note, train_models


def test_blocks_cover_every_row_once_each_contiguous():
    for n in (5, 7, 1001):
        masks = blocks(n)
        assert len(masks) == HOLDOUT_BLOCKS
        assert (np.sum(masks, axis=0) == 1).all()
        for m in masks:
            rows = np.flatnonzero(m)
            assert len(rows) and (np.diff(rows) == 1).all()


def test_held_out_rows_play_no_part_in_the_fit():
    """Rows held out may carry any target: the fit is the same as with their true one, and it
    differs from the fit on every row."""
    x, v = presses([0.01, 0.02, 0.015, 0.025, 0.006], 2.0)
    _, y = pad(x, v)
    X = [np.column_stack([x, v])]
    out = blocks(len(x))[2]
    spoiled = np.where(out, y + 50.0, y)
    a = make_model("lawfree", hyper=SMALL).fit(X, [y], info=[info(len(x))], holdout=[out])
    b = make_model("lawfree", hyper=SMALL).fit(X, [spoiled], info=[info(len(x))], holdout=[out])
    every = make_model("lawfree", hyper=SMALL).fit(X, [y], info=[info(len(x))])
    np.testing.assert_array_equal(a.w_, b.w_)
    np.testing.assert_array_equal(a.c_, b.c_)
    assert not np.allclose(a.w_, every.w_)
    with pytest.raises(ValueError, match="one mask per sequence"):
        make_model("lawfree", hyper=SMALL).fit(X, [y], info=[info(len(x))], holdout=[out[:-1]])


def test_lawfree_is_chosen_on_held_out_blocks_without_a_validation_recording(tmp_path, rt_loop):
    """The README's example dataset (one test to train on, one to test): every candidate of
    the grid is scored on held-out blocks of the training test, the choice is the best by the
    rule, the saved model is that candidate fitted on every row, and the test plays no part."""
    csvs = write_examples(tmp_path / "csv")
    man = tmp_path / "dataset.toml"
    for c, role in zip(csvs, ("train", "test"), strict=True):
        out = tmp_path / f"{c.stem}.parquet"
        import_series(c, out, "time", "displacement", "force", position_unit="mm",
                      force_unit="mN", rt_loop=str(rt_loop))  # fmt: skip
        write_manifest_entry(man, c.stem, out, role, "SYNTHETIC", "")
    ds = load_manifest(man)
    assert not ds.validation
    (m,) = train_models(ds, ["lawfree"], TrainConfig(seed=0, progress=False), tmp_path / "m")
    sel = m.train_info_["selection"]
    assert sel["validation"] == BLOCKED_VALIDATION
    grid = [label for label, _ in lawfree_candidates({})]
    assert set(grid) <= set(sel["candidates"]) and len(sel["candidates"]) == len(grid) + 1
    assert all(np.isfinite(v) for v in sel["candidates"].values())
    # the saved model is the chosen candidate's hyper-parameters fitted on every row
    chosen = next(label for label in sel["candidates"] if sel["chosen"] == label)
    extra = dict(lawfree_candidates({})).get(chosen)
    if extra is not None:  # a grid candidate (not the irreversible memory's)
        assert all(m.hyper[k] == v for k, v in extra.items())
    assert m.train_info_["rows"] > 0
    # the export names the filters its features were computed with (the 50 Hz import's)
    meta = {p.key: p.value for p in to_contract_onnx(m, provenance(m, TrainConfig(), ds, None))
            .metadata_props}  # fmt: skip
    gains = json.loads(meta["haptics.feature_gains"])
    assert gains == pytest.approx({"g_v": 10.0, "g_a": 10.0})


def test_a_model_stepping_in_time_is_stepped_at_each_recordings_own_period():
    """The same presses logged at 1 kHz and at 500 Hz: predicted at its own period the 500 Hz
    log follows the 1 kHz prediction; stepped per row at the training period (what happened
    before) its memory ran twice as fast. Fitted on both logs at once, each at its own period,
    the model predicts as one fitted on the 1 kHz log alone."""
    x, v = presses([0.01, 0.02, 0.015, 0.025, 0.006], 2.0)
    _, y = pad(x, v)
    fast = np.column_stack([x, v])
    slow, y_slow = fast[::2], y[::2]
    info_slow = dataclasses.replace(info(len(slow)), sample_rate_hz=RATE / 2)
    m = make_model("lawfree", hyper=SMALL).fit([fast], [y], info=[info(len(x))])
    want = m.predict(fast)[::2]
    at_own = predict_at(m, slow, 2.0 / RATE)
    per_row = m.predict(slow)
    err_own = float(np.sqrt(np.mean((at_own - want) ** 2)))
    err_row = float(np.sqrt(np.mean((per_row - want) ** 2)))
    assert err_own < 0.2 * err_row, (err_own, err_row)
    both = make_model("lawfree", hyper=SMALL).fit([fast, slow], [y, y_slow],
                                                  info=[info(len(x)), info_slow])  # fmt: skip
    # (0.0025 N here; 0.048 N with the 500 Hz log stepped at the 1 kHz period)
    both_err = float(np.sqrt(np.mean((predict_at(both, fast, 1.0 / RATE) - m.predict(fast)) ** 2)))
    assert both_err < 0.01, both_err


def test_recordings_whose_features_used_other_filters_are_named(tmp_path, rt_loop):
    """An import derives its filters from its file's rate: a test logged at 100 Hz beside one
    at 50 Hz gets other filters, and training says so; imported with the same gains, not."""
    csv = write_examples(tmp_path / "csv")[1]
    man = tmp_path / "dataset.toml"
    kw = {"position_unit": "mm", "force_unit": "mN", "rt_loop": str(rt_loop)}
    for name, extra in (("at50", {}), ("at100", {"resample_hz": 100.0})):
        out = tmp_path / f"{name}.parquet"
        import_series(csv, out, "time", "displacement", "force", **kw, **extra)
        write_manifest_entry(man, name, out, "train" if name == "at50" else "test", "S", "")
    note = feature_gains_note(load_manifest(man))
    assert note is not None and "at50 10 / 10" in note and "at100 20 / 20" in note, note
    out = tmp_path / "at100.parquet"
    import_series(csv, out, "time", "displacement", "force", **kw, resample_hz=100.0, g_v=10.0,
                  g_a=10.0, overwrite=True)  # fmt: skip
    assert feature_gains_note(load_manifest(man)) is None
