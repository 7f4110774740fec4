"""Choices without a validation recording (blocked_validation.py): `lawfree` fitted without
held-out blocks of its training rows, scored on them, and chosen that way by `train_models`
when the dataset has no validation recording."""

import numpy as np
import pytest
from test_lawfree import SMALL, pad
from test_structured import info, presses

from haptics_train.blocked_validation import BLOCKED_VALIDATION, HOLDOUT_BLOCKS, blocks
from haptics_train.data import load_manifest, write_manifest_entry
from haptics_train.import_fixtures import write_examples
from haptics_train.importer import import_series
from haptics_train.models import TrainConfig, make_model
from haptics_train.pipeline import lawfree_candidates, train_models


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
