"""`+holds` specs (holds.py): which recordings each model trains and chooses on."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from haptics_train import pipeline
from haptics_train.data import Dataset, Recording
from haptics_train.holds import spec_algo, spec_dataset, split_spec
from haptics_train.models import TrainConfig, parse_spec


def _rec(name: str) -> Recording:
    return Recording(name, {"time": np.zeros(1)})


def _dataset(holds: bool = True) -> Dataset:
    extra = [_rec("train_hold")] if holds else []
    return Dataset(
        train=[_rec("train_0.8"), _rec("train_air"), *extra],
        test=[_rec("test_2.1")],
        root="ds",
        validation=[_rec("validation_5.0"), *([_rec("validation_hold")] if holds else [])],
    )


def _names(recs: list[Recording]) -> list[str]:
    return [r.name for r in recs]


def test_a_holds_spec_is_named_for_it_and_only_the_studys_candidates_take_it() -> None:
    assert split_spec("structured_hyst+holds") == ("structured_hyst", True)
    assert split_spec("rf:memory") == ("rf:memory", False)
    assert (spec_algo("lawfree+holds"), spec_algo("rf:memory")) == ("lawfree", "rf")
    for algo in ("structured", "structured_path", "structured_hyst", "lawfree"):
        m = parse_spec(f"{algo}+holds")
        assert m.name == f"{algo}_holds" and m.hyper["train_holds"] is True
        assert parse_spec(algo).name == algo
    for spec in ("rf:memory+holds", "sd_poly2+holds", "structured:six+holds"):
        with pytest.raises(ValueError, match="take \\+holds"):
            parse_spec(spec)


def test_only_a_holds_spec_sees_the_hold_recordings() -> None:
    ds = _dataset()
    plain = spec_dataset(ds, "structured")
    assert _names(plain.train) == ["train_0.8", "train_air"]
    assert _names(plain.validation) == ["validation_5.0"]
    assert plain.test == ds.test
    assert spec_dataset(ds, "structured+holds") is ds
    # a dataset without holds is every model's as it is
    bare = _dataset(holds=False)
    assert spec_dataset(bare, "lawfree") is bare
    with pytest.raises(ValueError, match="PRESSES=1"):
        spec_dataset(bare, "lawfree+holds")


def test_train_models_fits_and_chooses_each_spec_on_its_own_recordings(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    seen: dict[str, set] = {}

    def fit(spec: str, preset: str, hyper: dict | None, extra: dict, dataset: Dataset,
            cfg: TrainConfig):  # fmt: skip
        seen.setdefault(spec, set()).add((tuple(_names(dataset.train)),
                                          tuple(_names(dataset.validation))))  # fmt: skip
        m = pipeline._configured(spec, preset, hyper, extra)
        m.train_info_ = {}
        return m

    chosen_on: dict[str, list[str]] = {}

    def score(m: object, cfg: TrainConfig, dataset: Dataset) -> tuple[float, float]:
        chosen_on.setdefault(m.name, []).extend(_names(dataset.validation))  # type: ignore[attr-defined]
        return 1.0, 1.0

    monkeypatch.setattr(pipeline, "_fit_one", fit)
    monkeypatch.setattr(pipeline, "validation_free_run_scores", score)
    cfg = TrainConfig(progress=False)
    models = pipeline.train_models(_dataset(), ["structured", "structured+holds"], cfg, tmp_path)
    assert [m.name for m in models] == ["structured", "structured_holds"]
    assert seen["structured"] == {(("train_0.8", "train_air"), ("validation_5.0",))}
    assert seen["structured+holds"] == {
        (("train_0.8", "train_air", "train_hold"), ("validation_5.0", "validation_hold"))
    }
    # its basis is chosen on its own validation recordings too
    assert set(chosen_on["structured"]) == {"validation_5.0"}
    assert set(chosen_on["structured_holds"]) == {"validation_5.0", "validation_hold"}
    assert (tmp_path / "structured_holds.joblib").is_file()
    # asked for on a dataset without them: stopped before any training, with the remedy
    with pytest.raises(ValueError, match="PRESSES=1"):
        pipeline.train_models(_dataset(holds=False), ["structured", "lawfree+holds"], cfg,
                              tmp_path / "none")  # fmt: skip
    assert not (tmp_path / "none").exists()
