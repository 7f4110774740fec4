"""The object's own force F_object against the felt force F_true: which one each comparison of
an object-only model uses (the study's prediction along the real interaction, the OOD suite's
hand presses, the rendered-vs-true figure), and the stated fallback for recordings older than
the column. One real shadow run of rt-loop when the binary is built."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from haptics_train.data import Recording
from haptics_train.models import TrainConfig
from haptics_train.ood import readme_section, target_column
from haptics_train.study import STUDY_HAND, Row, Run, Tools, read_series, run_loop, write_config
from haptics_train.study.score import prediction_along_real
from haptics_train.truth import FELT_FORCE, OBJECT_FORCE, is_hand_run, object_truth

N = 1000


def _hand_series(with_object: bool = True) -> dict[str, np.ndarray]:
    """A hand press: the object's force, and the hand's = object + 1 N of friction at rest."""
    t = np.arange(N) * 1e-4
    obj = 5.0 * np.sin(np.pi * t / t[-1]) ** 2
    s = {"time": t, "F_true": obj + 1.0, "F_pred": obj + 0.05}
    if with_object:
        s["F_object"] = obj
    return s


def test_the_object_force_is_chosen_and_a_fallback_is_said() -> None:
    assert object_truth(_hand_series(), "r", hand=True).column == OBJECT_FORCE
    assert object_truth(_hand_series(), "r", hand=True).note == ""
    old = object_truth(_hand_series(False), "old", hand=True)
    assert old.column == FELT_FORCE and not old.is_object
    assert "old" in old.note and "no F_object column" in old.note and "friction" in old.note
    no_hand = object_truth(_hand_series(False), "abs", hand=False)
    assert no_hand.column == FELT_FORCE and "same force without a hand" in no_hand.note
    nan = {**_hand_series(), "F_object": np.full(N, np.nan)}
    assert object_truth(nan, "repro", hand=True).column == FELT_FORCE
    assert "F_object is NaN" in object_truth(nan, "repro", hand=True).note
    assert object_truth({"time": np.zeros(3)}, "real", hand=False).column is None
    assert is_hand_run({"haptics.run": {"experiment": "shadow"}})
    assert not is_hand_run({"haptics.run": {"experiment": "abstraction"}}, "hand_x")
    assert is_hand_run({}, "hand_slow") and not is_hand_run({}, "ramp_12")


def test_prediction_along_the_real_interaction_uses_the_object_force() -> None:
    run = Run("m", "shadow", Path("m.parquet"), True, served=N, series=_hand_series())
    m, col, note = prediction_along_real(run)
    assert m is not None and col == OBJECT_FORCE and note == ""
    # the object model is 0.05 N off the object, ~1 N off the hand (its friction)
    assert m["rmse"] == pytest.approx(0.05)
    assert m["felt_rmse"] == pytest.approx(0.95)
    old = Run("m", "shadow", Path("m.parquet"), True, served=N, series=_hand_series(False))
    m, col, note = prediction_along_real(old)
    assert m is not None and col == FELT_FORCE and m["rmse"] == pytest.approx(0.95)
    assert "no F_object column" in note
    unserved = Run("m", "shadow", Path("m.parquet"), True, served=0, series=_hand_series())
    assert prediction_along_real(unserved)[0] is None


def test_ood_hand_presses_are_scored_against_the_object_with_a_stated_fallback() -> None:
    cfg = TrainConfig()
    rec = Recording("hand_slow", _hand_series())
    assert target_column(rec, cfg) == (OBJECT_FORCE, "")
    col, note = target_column(Recording("hand_slow", _hand_series(False)), cfg)
    assert col == FELT_FORCE and "hand_slow" in note
    assert target_column(Recording("ramp_12", _hand_series()), cfg) == (cfg.target, "")
    doc = {"a": {"recordings": {"hand_slow": {"rmse": 0.9, "diverged": False,
                                              "target": col, "target_note": note}},
                 "worst_rmse_n": 0.9, "worst_recording": "hand_slow", "diverged": 0}}  # fmt: skip
    text = "\n".join(readme_section(doc, "a"))
    assert "object's own force F_object" in text
    assert "felt force instead of the object's own: hand_slow: no F_object column" in text


def test_read_series_leaves_out_a_missing_f_object_only(tmp_path: Path) -> None:
    s = _hand_series(False)
    s.update(position_x=np.zeros(N), rtob_force=np.zeros(N), fallback=np.zeros(N))
    pq.write_table(pa.table(s), tmp_path / "old.parquet")
    got = read_series(tmp_path / "old.parquet")
    assert "F_object" not in got and set(got) >= {"time", "F_true", "F_pred"}
    del s["F_pred"]
    pq.write_table(pa.table(s), tmp_path / "bad.parquet")
    with pytest.raises(Exception, match="F_pred"):
        read_series(tmp_path / "bad.parquet")


def test_rt_loop_records_the_object_force_on_a_hand_run(rt_loop: Path, tmp_path: Path) -> None:
    hand = {**STUDY_HAND, "repeats": 1, "press_s": 0.5, "hold_s": 0.5, "release_s": 0.5}
    cfg = tmp_path / "hand.toml"
    write_config(cfg, 1, hand)
    tools = Tools(rt_loop, rt_loop, dict(os.environ))
    args = ["--config", str(cfg), "--clock", "lockstep", "--experiment", "shadow"]
    ref = run_loop(tools, "sponge", "reference", args, tmp_path / "ref.parquet")
    assert ref.ok, ref.note
    s = ref.series
    assert object_truth(s, "ref", hand=True).column == OBJECT_FORCE
    assert np.isfinite(s["F_object"]).all() and 3.0 < s["F_object"].max() < 15.0
    # pressed and at rest (the hold): the hand's force is the object's plus what the
    # friction holds, up to its 1 N breakaway, which an object model cannot predict
    v = np.gradient(s["position_x"], s["time"])
    rest = (np.abs(v) < 1e-4) & (s["F_true"] > 1.0)
    gap = np.abs(s["F_true"] - s["F_object"])[rest]
    assert rest.sum() > 1000 and 0.3 < float(np.median(gap)) < 2.0
    # the builtin spring-damper's F_pred (no server): scored like a served model's
    m, col, _ = prediction_along_real(Run("builtin", "shadow", ref.path, True, served=1,
                                          series=s))  # fmt: skip
    assert m is not None and col == OBJECT_FORCE and m["rmse"] != m["felt_rmse"]


def test_the_study_readme_says_which_truth_the_prediction_along_real_met(tmp_path: Path) -> None:
    from haptics_train.study.report import results_json, write_readme

    def row(name: str, felt: float, along: float, learned: bool, series: dict) -> Row:
        run = Run(name, "reproduction", Path(name), True, steps=N, served=N)
        m = {"r2": 0.9, "mae": felt, "mse": felt * felt, "rmse": felt, "coverage": 1.0}
        sh = Run(name, "shadow", Path(name), True, served=N, series=series)
        along_m, col, note = prediction_along_real(sh)
        assert along_m is not None
        along_m["rmse"] = along
        return Row(name, "served ONNX", m, along_m, run, sh, learned, col, note)

    rows = [row("structured", 0.06, 0.13, True, _hand_series()),
            row("sd_poly2", 1.36, 2.41, False, _hand_series(False))]  # fmt: skip
    cell = {"r2": 1.0, "mae": 0.1, "mse": 0.01, "rmse": 0.1}
    replay = {"rtob_force": cell, "F_true": cell, "position_x": cell}
    ref = Run("sponge", "reference", Path("ref"), True, steps=N)
    readme = write_readme(tmp_path, ref, rows, replay, ref, Path("test_2.1.parquet"), {}, 1.0, 1)
    text = readme.read_text()
    assert "F_pred vs the simulated object's own force F_object): best learned `structured` " \
           "RMSE 0.130 N" in text
    assert "`structured` would read 0.950 N" in text  # against the hand's F_true
    assert "scored against the felt force instead of the object's own: sd_poly2: no F_object" \
           in text
    doc = results_json(rows, replay, 1.0)
    assert doc["models"]["structured"]["prediction_along_real_against"] == OBJECT_FORCE
    assert doc["models"]["sd_poly2"]["prediction_along_real_against"] == FELT_FORCE
