"""The recommendation rule (validation free run, never one-step; the felt force where the study
measured it; test recordings play no part) and docs/fidelity.json's keys."""

import json

import numpy as np
import pytest

from haptics_train.data import Recording, recording_from_columns
from haptics_train.evaluate import SLIDING_MPS, pooled_metrics, sliding_rows, sliding_speed
from haptics_train.features import NINE
from haptics_train.fidelity import FIDELITY_KEYS, merge, rank, recommendation
from haptics_train.ood import diverged, write_readme_section


def entry(val: float, test: float, one_step: float = 0.001) -> dict:
    pool = lambda v: {"closed_loop": {"rmse": v}, "one_step": {"rmse": one_step}}  # noqa: E731
    return {"validation_pooled": pool(val), "test_pooled": pool(test)}


RESULTS = {
    "persistent": entry(2.0, 0.01),  # best one-step and best test: neither counts
    "a": entry(0.5, 0.9),
    "b": entry(0.4, 0.6),
    "runaway": entry(float("inf"), 0.1),
    "unscored": {"error": "export breaks the contract"},
}


def test_ranked_by_validation_free_run_never_one_step_nor_test():
    names = [r["model"] for r in rank(RESULTS)]
    assert names == ["b", "a", "persistent", "runaway"]
    doc = recommendation(RESULTS, ["validation_5.0"])
    assert doc["recommended"] == "b" and doc["free_run_rmse_n"] == 0.6


def test_ranked_on_the_sliding_rows_where_scored():
    """A model whose error sits where the probe slides loses to one whose error sits where it
    sticks (the bench's stick friction, which no model knows), although over all rows it
    scores better; files without the sliding score rank by all rows."""
    n = 2000
    x = np.full(n, 0.01)
    v = np.where(np.arange(n) % 2 == 0, 0.0, 0.01)  # every other row stuck
    rng = np.random.default_rng(0)
    y = 2.0 + np.where(v == 0, rng.normal(0.0, 0.4, n), 0.0)
    cols = {"time": np.arange(n) * 1e-3, "rtob_force": y, "position_x": x, "velocity": v,
            "acceleration": np.zeros(n), **{c: np.zeros(n) for c in NINE[3:]}}  # fmt: skip
    rec = recording_from_columns("validation_5.0", cols)
    follows = {"closed_loop": np.full(n, 2.0)}  # right while sliding
    biased = {"closed_loop": np.where(v == 0, y, 2.3)}  # off by 0.3 N while sliding
    scored = {name: {"validation_pooled": pooled_metrics([rec], [p], "rtob_force"),
                     "test_pooled": {"closed_loop": {"rmse": 1.0}}}
              for name, p in (("follows", follows), ("biased", biased))}  # fmt: skip
    assert scored["follows"]["validation_pooled"]["sliding"]["rows"] == n // 2
    assert scored["follows"]["validation_pooled"]["sliding"]["rmse"] == 0.0
    all_rows = {k: e["validation_pooled"]["closed_loop"]["rmse"] for k, e in scored.items()}
    assert all_rows["biased"] < all_rows["follows"]  # all rows: the noise decides
    ranking = rank(scored)
    assert [r["model"] for r in ranking] == ["follows", "biased"]
    assert ranking[1]["validation_sliding_rmse_n"] == pytest.approx(0.3)
    assert ranking[1]["validation_free_run_rmse_n"] == all_rows["biased"]
    # a results file written before the sliding score: all rows, as it was
    old = {k: {**e, "validation_pooled": {"closed_loop": e["validation_pooled"]["closed_loop"]}}
           for k, e in scored.items()}  # fmt: skip
    assert [r["model"] for r in rank(old)] == ["biased", "follows"]


def _ramp(name: str, rate_mps: float, depth_m: float = 0.01) -> tuple[Recording, np.ndarray]:
    """A testing machine's loading-unloading test at `rate_mps` (50 Hz, a rest either side)
    whose force is the depth in N/mm: (the recording, its force)."""
    n_ramp = int(round(depth_m / rate_mps * 50))
    x = np.concatenate([np.zeros(20), np.linspace(0, depth_m, n_ramp),
                        np.linspace(depth_m, 0, n_ramp), np.zeros(20)])  # fmt: skip
    v = np.gradient(x, 0.02)
    n = len(x)
    cols = {"time": np.arange(n) * 0.02, "rtob_force": 1e3 * x, "position_x": x, "velocity": v,
            "acceleration": np.zeros(n), **{c: np.zeros(n) for c in NINE[3:]}}  # fmt: skip
    return recording_from_columns(name, cols), 1e3 * x


def test_a_slow_validation_test_is_scored_not_dropped():
    """A testing machine loads at well under 1 mm/s: its pressing rows slide at its own speed,
    so a slow validation test counts in the sliding score beside a fast one (each recording's
    threshold, `sliding_speed`), instead of leaving the choice to the fast one alone."""
    slow, y_slow = _ramp("rate_0.25", 0.25e-3)
    fast, y_fast = _ramp("rate_16", 16e-3)
    assert sliding_speed(fast) == SLIDING_MPS  # fast enough: the bench's threshold
    assert sliding_speed(slow) == pytest.approx(0.1 * 0.25e-3, rel=0.05)
    rows = sliding_rows(slow)
    assert rows.sum() > 0.9 * (len(rows) - 40)  # every pressing row but the turning points
    assert not rows[:20].any() and not rows[-20:].any()  # not the rests
    # a model right on the fast test and 0.5 N off on the slow one scores the slow one's error
    wrong_when_slow = [{"closed_loop": y_slow + 0.5}, {"closed_loop": y_fast}]
    m = pooled_metrics([slow, fast], wrong_when_slow, "rtob_force")["sliding"]
    assert m["rows"] > sliding_rows(fast).sum() + 0.9 * len(rows) - 40
    assert m["rmse"] > 0.45


def test_felt_force_counts_where_measured():
    # b leads offline and renders badly in the loop: the felt force decides
    assert recommendation(RESULTS, ["v"], felt={"b": 1.5, "a": 0.45})["recommended"] == "a"


def test_the_felt_force_decides_alone_where_measured():
    # a is 3.2x closer in the loop, b 1.25x closer offline: the felt force alone scores both
    # (the larger of the two multiples, the rule until 2026-11-30, served the model that felt
    # further on every object where the two rules disagreed: fidelity's docstring)
    doc = recommendation(RESULTS, ["v"], felt={"a": 0.15, "b": 0.48})
    assert doc["recommended"] == "a"
    by = {r["model"]: r for r in doc["ranking"]}
    assert by["a"]["score"] == 1.0 and by["b"]["score"] == 0.48 / 0.15, by
    # both multiples are reported for what the study's report quotes
    assert by["a"]["validation_multiple"] == 0.5 / 0.4 and by["b"]["validation_multiple"] == 1.0
    # without a felt force a model is scored offline alone; a diverged one ranks last
    assert by["persistent"]["score"] == 2.0 / 0.4 and by["runaway"]["score"] == float("inf")
    # a diverged validation free run ranks last even where its felt force is the best
    doc = recommendation(RESULTS, ["v"], felt={"runaway": 0.01, "a": 0.15, "b": 0.48})
    assert doc["recommended"] == "a" and doc["ranking"][-1]["model"] == "runaway"


def test_no_recommendation_without_validation():
    assert recommendation(RESULTS, []) is None


def test_merge_keeps_other_keys_and_writes_null_for_non_finite(tmp_path):
    p = tmp_path / "fidelity.json"
    p.write_text(json.dumps({"felt_rmse_n": 0.3, "extra": 1}))
    merge(p, {"recommended": "b", "ood_free_run_rmse_n": float("nan")})
    doc = json.loads(p.read_text())
    assert doc == {"felt_rmse_n": 0.3, "extra": 1, "recommended": "b", "ood_free_run_rmse_n": None}


def test_the_documented_keys_are_the_keys_the_writers_write(tmp_path):
    """FIDELITY_KEYS against what the study, the suite and the pipeline's recommendation
    actually write into docs/fidelity.json (issue 23: before, the constant was compared with a
    copy of itself)."""
    from pathlib import Path

    from haptics_train.ood import write_fidelity as write_ood
    from haptics_train.study import ORACLE, Row, Run
    from haptics_train.study.report import write_fidelity as write_study

    def row(name: str, rmse: float, learned: bool) -> Row:
        m = {"r2": 0.9, "mae": rmse, "mse": rmse * rmse, "rmse": rmse, "coverage": 1.0}
        return Row(name, "t", m, None, Run(name=name, kind="r", path=Path(name), ok=True), None,
                   learned)  # fmt: skip

    p = tmp_path / "fidelity.json"
    doc = recommendation(RESULTS, ["validation_5.0"])
    merge(p, {k: doc[k] for k in ("recommended", "free_run_rmse_n", "free_run_true_rmse_n")})
    rows = [row(ORACLE, 0.05, False), row("sd_poly2", 1.5, False), row("b", 0.3, True)]
    write_study(p, rows, [row("b", 0.4, True)])
    suite = {"b": {"worst_rmse_n": 0.7, "diverged": 0, "worst_recording": "r"}}
    written = set(write_ood(suite, "b", p))
    assert set(FIDELITY_KEYS) <= written, set(FIDELITY_KEYS) - written
    got = json.loads(p.read_text())
    assert (got["recommended"], got["felt_rmse_n"], got["ood_free_run_rmse_n"]) == ("b", 0.3, 0.7)


def test_divergence():
    y = np.array([0.0, 5.0, 10.0])
    assert not diverged(y, y + 1.0)
    assert diverged(y, np.array([0.0, np.nan, 1.0]))
    assert diverged(y, np.array([0.0, 40.0, 1.0]))


def test_ood_table_is_computed_and_replaces_its_earlier_self(tmp_path):
    def e(rmse: float, div: bool = False) -> dict:
        return {"rmse": rmse, "diverged": div}

    doc = {
        "a": {"recordings": {"r1": e(0.3), "r2": e(0.9)}, "worst_rmse_n": 0.9,
              "worst_recording": "r2", "diverged": 0},
        "b": {"recordings": {"r1": e(7.0, True), "r2": e(0.2)}, "worst_rmse_n": 7.0,
              "worst_recording": "r1", "diverged": 1},
    }  # fmt: skip
    readme = tmp_path / "README.md"
    readme.write_text("# Study\n\n## Results\n\ntext\n\n## Timings\n\n12 s\n")
    write_readme_section(readme, doc, "a")
    first = readme.read_text()
    assert first.index("## Results") < first.index("## Out-of-distribution") < first.index(
        "## Timings")
    assert "| r1 | 0.300 | 7.000 (diverged) |" in first
    assert "| **worst** | 0.900 | 7.000 |" in first
    assert "- `a` (the recommended model): worst 0.900 N on `r2`, 0 of 2" in first
    assert "- `b`: worst 7.000 N on `r1`, 1 of 2 recordings diverged." in first
    doc["a"]["worst_rmse_n"] = 0.5
    # simulated recordings: the rendered force against the object's own after a slash
    doc["a"]["recordings"]["r1"]["rendered_vs_true_rmse"] = 0.1
    doc["a"]["worst_true_rmse_n"] = 0.1
    write_readme_section(readme, doc, "a")
    second = readme.read_text()
    assert second.count("## Out-of-distribution") == 1 and "worst 0.500 N" in second
    assert "| r1 | 0.300 / 0.100 | 7.000 (diverged) |" in second
    assert "diverged; against the object's own force, worst 0.100 N." in second
    assert second.endswith("## Timings\n\n12 s\n")


def test_study_reranks_with_the_felt_force(tmp_path):
    from types import SimpleNamespace

    from haptics_train.study.run import rerank_by_felt

    def row(name: str, felt: float) -> SimpleNamespace:
        return SimpleNamespace(name=name, repro={"rmse": felt, "coverage": 1.0},
                               run=SimpleNamespace(ok=True))  # fmt: skip

    (tmp_path / "recommendation.json").write_text(
        json.dumps(recommendation(RESULTS, ["validation_5.0"]))
    )
    doc = rerank_by_felt(
        tmp_path, RESULTS, [[row("b", 1.5), row("a", 0.45), row("oracle", 0.02)]]
    )
    assert doc["recommended"] == "a"
    assert json.loads((tmp_path / "recommendation.json").read_text())["recommended"] == "a"
    assert rerank_by_felt(tmp_path / "none", RESULTS, [[]]) is None  # no pipeline recommendation


def test_two_ranking_programmes_rank_by_the_geometric_mean(tmp_path):
    """With two ranking programmes a model's felt force is the geometric mean of its two (each
    kept in its entry): a model ahead on one programme only loses to one ahead on both by
    more; a model that fell back on one programme has no felt force and is ranked by
    validation, as with one programme."""
    import math
    from types import SimpleNamespace

    from haptics_train.study.run import rerank_by_felt

    def row(name: str, felt: float, ok: bool = True) -> SimpleNamespace:
        return SimpleNamespace(name=name, repro={"rmse": felt, "coverage": 1.0 if ok else 0.5},
                               run=SimpleNamespace(ok=True))  # fmt: skip

    (tmp_path / "recommendation.json").write_text(
        json.dumps(recommendation(RESULTS, ["validation_5.0"]))
    )
    # "b" is ahead on the first programme (0.40 against 0.45), "a" on the second by more
    first = [row("a", 0.45), row("b", 0.40)]
    second = [row("a", 0.30), row("b", 0.60)]
    doc = rerank_by_felt(tmp_path, RESULTS, [first, second])
    by = {e["model"]: e for e in doc["ranking"]}
    assert doc["recommended"] == "a"
    assert by["a"]["felt_rmse_n"] == pytest.approx(math.sqrt(0.45 * 0.30))
    assert by["b"]["felt_rmse_n"] == pytest.approx(math.sqrt(0.40 * 0.60))
    assert by["a"]["felt_by_programme_n"] == [0.45, 0.30]
    # the first programme alone would have picked "b": the rule differs from one programme
    assert rerank_by_felt(tmp_path, RESULTS, [first])["recommended"] == "b"
    # "a" not rankable on the second programme (it covered half the run): no felt force, so
    # its validation multiple scores it
    doc = rerank_by_felt(tmp_path, RESULTS, [first, [row("a", 0.30, ok=False), row("b", 0.60)]])
    by = {e["model"]: e for e in doc["ranking"]}
    assert by["a"]["felt_rmse_n"] is None and by["a"]["felt_by_programme_n"] is None
    assert by["a"]["score"] == by["a"]["validation_multiple"]
