"""The reproduction study's alignment and metrics on synthetic series, and one real rt-loop
pair (reference and builtin reproduction) when the binary is built."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from haptics_train.study import (
    DEFAULT_MATERIAL,
    ORACLE,
    STUDY_HAND,
    Row,
    Run,
    Tools,
    align,
    compare,
    ratio,
    run_loop,
    write_config,
    write_fidelity,
)
from haptics_train.study.report import floor_section, phase_section
from haptics_train.study.score import (
    HAND_PHASES,
    fast_models,
    felt_by_phase,
    hand_phase,
    run_flags,
)


def test_align_identical_grid_is_identity() -> None:
    t = np.arange(0.0, 1.0, 1e-4)
    y = np.sin(7 * t)
    out, covered = align(t, t, y)
    assert covered.all()
    np.testing.assert_array_equal(out, y)


def test_align_interpolates_other_grid_and_start_offset() -> None:
    # The run starts at device time 5 s and is sampled on a coarser, jittered grid: aligned by
    # time since its own start, a linear signal comes back exactly on the reference's grid.
    t_ref = np.linspace(0.0, 2.0, 2001)
    rng = np.random.default_rng(0)
    t_run = np.sort(np.concatenate([[0.0, 2.0], rng.uniform(0.0, 2.0, 300)])) + 5.0
    y_run = 3.0 * (t_run - 5.0) - 1.0
    out, covered = align(t_ref, t_run, y_run)
    assert covered.all()
    np.testing.assert_allclose(out, 3.0 * t_ref - 1.0, atol=1e-12)


def test_short_run_is_scored_only_where_it_ran() -> None:
    t = np.arange(0.0, 10.0, 0.01)
    ref = np.where(t < 4.0, 1.0, 5.0)
    # The run stopped at 3.99 s (e.g. a position-limit abort) and matched the reference
    # exactly while it ran: no penalty from samples it never produced, coverage says 40 %.
    n = 400
    out, covered = align(t, t[:n], ref[:n])
    assert covered.sum() == n
    assert np.isnan(out[n:]).all()
    m = compare(t, ref, t[:n], ref[:n])
    assert m["rmse"] == 0.0
    assert m["coverage"] == pytest.approx(0.4)


def test_compare_known_offset() -> None:
    t = np.linspace(0.0, 1.0, 1001)
    ref = 10.0 * np.sin(2 * np.pi * t) ** 2
    c = 0.5
    m = compare(t, ref, t, ref + c)
    assert m["mae"] == pytest.approx(c)
    assert m["rmse"] == pytest.approx(c)
    assert m["mse"] == pytest.approx(c * c)
    assert m["r2"] == pytest.approx(1.0 - c * c / np.var(ref))
    assert m["coverage"] == 1.0


def test_compare_sees_a_time_lag() -> None:
    # The same force delayed by 50 ms scores worse than the same force on time: the
    # comparison is by time, not by sorting or by depth.
    t = np.arange(0.0, 3.0, 1e-3)
    ref = np.clip(8.0 * np.sin(2 * np.pi * t), 0.0, None)
    on_time = compare(t, ref, t, ref)
    late = compare(t, ref, t, np.interp(t - 0.05, t, ref, left=0.0))
    assert on_time["rmse"] == 0.0
    assert late["rmse"] > 0.5
    assert late["r2"] < 0.99


def test_align_refuses_bad_runs() -> None:
    t = np.linspace(0.0, 1.0, 11)
    with pytest.raises(ValueError):
        align(t, t[::-1].copy(), t)  # time going backwards
    with pytest.raises(ValueError):
        align(t, t[:1], t[:1])  # one sample
    with pytest.raises(ValueError):
        align(t, t, t[:5])


def test_ratio() -> None:
    assert ratio(20.95, 1.21) == pytest.approx(17.31, abs=0.01)
    assert ratio(1.0, 0.1) == pytest.approx(10.0)
    assert math.isnan(ratio(1.0, 0.0))
    assert math.isnan(ratio(math.inf, 1.0))


def test_reference_and_builtin_reproduction_with_rt_loop(rt_loop: Path, tmp_path: Path) -> None:
    hand = {**STUDY_HAND, "repeats": 1, "press_s": 0.5, "hold_s": 0.2, "release_s": 0.5}
    cfg = tmp_path / "hand.toml"
    write_config(cfg, 1, hand)
    tools = Tools(rt_loop, rt_loop, dict(os.environ))
    base = ["--config", str(cfg), "--clock", "lockstep"]
    ref = run_loop(
        tools, "ref", "reference", [*base, "--experiment", "shadow"], tmp_path / "ref.parquet"
    )
    again = run_loop(
        tools, "ref2", "reference", [*base, "--experiment", "shadow"], tmp_path / "ref2.parquet"
    )
    rep = run_loop(
        tools,
        "sd",
        "reproduction",
        [*base, "--experiment", "reproduction"],
        tmp_path / "rep.parquet",
    )
    assert ref.ok and again.ok and rep.ok, (ref.note, again.note, rep.note)
    assert ref.steps == rep.steps > 10_000
    # The hand pressed the sponge: several newtons felt at the 28 mm set-point.
    assert 3.0 < float(np.max(ref.series["F_true"])) < 15.0
    # Lockstep with one seed is deterministic: the reference compares to itself exactly.
    same = compare(
        ref.series["time"], ref.series["F_true"], again.series["time"], again.series["F_true"]
    )
    assert same["rmse"] == 0.0
    # The built-in spring-damper feels like the sponge, roughly, but not exactly.
    m = compare(ref.series["time"], ref.series["F_true"], rep.series["time"], rep.series["F_true"])
    assert m["coverage"] == 1.0
    assert 0.05 < m["rmse"] < 5.0
    assert m["r2"] > 0.3


def test_a_refused_model_is_reported_not_waited_for(
    rt_loop: Path, infer_server: Path, tmp_path: Path
) -> None:
    # A corrupt model: infer-server refuses it at start (exit 1); the study must stop the
    # loop that waits for a server, say why, and leave no shared-memory segment behind.
    bad = tmp_path / "broken.onnx"
    bad.write_bytes(b"not an onnx model")
    cfg = tmp_path / "hand.toml"
    write_config(cfg, 1, {**STUDY_HAND, "repeats": 1})
    env = dict(os.environ)
    ort = Path(__file__).resolve().parents[2] / ".ort" / "libonnxruntime.so"
    if "ORT_DYLIB_PATH" not in env and ort.is_file():
        env["ORT_DYLIB_PATH"] = str(ort)
    tools = Tools(rt_loop, infer_server, env)
    inst = f"study-test-{os.getpid()}"
    r = run_loop(
        tools,
        "broken",
        "reproduction",
        ["--config", str(cfg), "--clock", "lockstep", "--experiment", "reproduction"],
        tmp_path / "rep.parquet",
        server_model=bad,
        instance=inst,
        timeout_s=60,
    )
    assert not r.ok
    assert "refused" in r.note, r.note
    assert r.wall_s < 15  # not the loop's 20 s server wait
    assert not (tmp_path / "rep.parquet").exists()
    assert not Path(f"/dev/shm/haptics-{inst}").exists()


def _row(name: str, rmse: float, learned: bool) -> Row:
    run = Run(name=name, kind="reproduction", path=Path(name), ok=True)
    m = {"r2": 0.9, "mae": rmse, "mse": rmse * rmse, "rmse": rmse, "coverage": 1.0}
    return Row(name, "test", m, None, run, None, learned)


def test_fidelity_keys_follow_the_numbers_and_the_recommendation(tmp_path: Path) -> None:
    rows = [
        _row(ORACLE, 0.05, False),
        _row("sd_poly2", 1.5, False),
        _row("rf_memory", 0.4, True),
        _row("dnn_fb_six", 0.3, True),
    ]
    fast = [_row("rf_memory", 0.6, True), _row("dnn_fb_six", 0.7, True)]
    path = tmp_path / "fidelity.json"
    doc = write_fidelity(path, rows, fast)
    assert doc["felt_model"] == "dnn_fb_six"
    assert (doc["felt_rmse_n"], doc["felt_fast_rmse_n"]) == (0.3, 0.7)
    assert (doc["oracle_felt_rmse_n"], doc["sd_poly2_felt_rmse_n"]) == (0.05, 1.5)
    assert doc["felt_friction_compensation"] == "off"
    # the pipeline's recommendation wins over the study's best, and its keys are kept
    path.write_text(json.dumps({"recommended": "rf_memory", "free_run_rmse_n": 0.2}))
    doc = write_fidelity(path, rows, fast, "on")
    assert doc["felt_model"] == "rf_memory" and doc["felt_rmse_n"] == 0.4
    assert doc["felt_friction_compensation"] == "on"
    assert doc["felt_fast_rmse_n"] == 0.6 and doc["free_run_rmse_n"] == 0.2
    assert json.loads(path.read_text()) == doc


def test_fast_hand_runs_the_best_and_the_models_every_table_shows() -> None:
    rows = [
        _row(ORACLE, 0.05, False),
        _row("sd_poly2", 1.5, False),
        _row("structured", 0.07, True),
        _row("structured_path", 0.08, True),
        _row("structured_hyst", 0.09, True),
        _row("lawfree", 0.20, True),
        _row("rf_memory", 0.50, True),
        _row("dnn_fb_six", 0.10, True),
    ]
    # the three closest learned models, then the table's models however far they felt
    assert fast_models(rows) == {
        "structured", "structured_path", "structured_hyst", "lawfree", "rf_memory", "sd_poly2"
    }  # fmt: skip
    # a model named in FAST_ALWAYS but not studied is not asked for
    assert fast_models(rows[:3]) == {"structured", "sd_poly2"}


def test_floor_section_is_computed_from_the_numbers() -> None:
    ref = Run(name="ref", kind="reference", path=Path("r"), ok=True)
    good = [_row(ORACLE, 0.08, False), _row("sd_poly2", 1.6, False), _row("m", 0.1, True)]
    bad = [_row(ORACLE, 0.3, False), _row("sd_poly2", 1.2, False), _row("m", 0.9, True)]
    text = "\n".join(
        floor_section({"off": (ref, bad), "on": (ref, good)}, {"headline": "on"}, "-")
    )
    assert "| on | 0.080 | 1.600 | - | `m` 0.100 | 1.25x | - |" in text
    assert "| off | 0.300 | 1.200 | - | `m` 0.900 | 3.00x | - |" in text
    assert "Best learned at most 0.20 N: **met** (0.100 N)" in text
    assert "Within 1.5x of the oracle's floor: **met** (1.25x)" in text
    assert "Floor at most 0.10 N with friction compensated: **met** (0.080 N)" in text
    text = "\n".join(floor_section({"off": (ref, bad)}, {"headline": "off"}, "-"))
    assert "Best learned at most 0.20 N: **not met** (0.900 N)" in text
    assert "no bench file given" in text


def test_runs_with_saturated_or_refused_steps_and_a_broken_floor_are_flagged() -> None:
    ref = Run(name="ref", kind="reference", path=Path("r"), ok=True)
    rows = [_row(ORACLE, 0.3, False), _row("sd_poly2", 1.2, False), _row("m", 0.2, True)]
    rows[0].run.saturated, rows[0].run.rejected = 120, 3
    assert run_flags(rows[0], rows) == [
        "120 saturated",
        "3 refused",
        "oracle not the floor: m felt closer",
    ]
    assert run_flags(rows[2], rows) == ["below the oracle"]
    assert run_flags(rows[1], rows) == []
    text = "\n".join(floor_section({"off": (ref, rows)}, {"headline": "off"}, "-"))
    assert (
        "| `oracle`: 120 saturated, 3 refused, oracle not the floor: m felt closer; "
        "`m`: below the oracle |" in text
    ), text


def test_oracle_renders_the_floor_with_rt_loop(rt_loop: Path, tmp_path: Path) -> None:
    # The oracle (the material's own physics) feels like the object within a small fraction of
    # the builtin spring-damper's error, with and without friction compensation.
    hand = {**STUDY_HAND, "repeats": 1, "press_s": 0.5, "hold_s": 0.2, "release_s": 0.5}
    cfg = tmp_path / "hand.toml"
    write_config(cfg, 1, hand)
    bench = tmp_path / "bench.toml"
    bench.write_text("[friction]\ncoulomb_n = 0.88\nviscous = 4.8\n")
    tools = Tools(rt_loop, rt_loop, dict(os.environ))
    root = Path(__file__).resolve().parents[2]
    for extra in ([], ["--bench", str(bench)]):
        base = ["--config", str(cfg), "--material", str(root / DEFAULT_MATERIAL), *extra]
        ref = run_loop(
            tools, "ref", "reference", [*base, "--experiment", "shadow"], tmp_path / "ref.parquet"
        )
        runs = {
            name: run_loop(
                tools,
                name,
                "reproduction",
                [*base, "--experiment", "reproduction", *model],
                tmp_path / f"{name}.parquet",
            )
            for name, model in (("oracle", ["--model", "oracle"]), ("builtin", []))
        }
        rmse = {}
        for name, r in runs.items():
            assert r.ok, (name, r.note, r.stop)
            m = compare(
                ref.series["time"], ref.series["F_true"], r.series["time"], r.series["F_true"]
            )
            rmse[name] = m["rmse"]
        assert rmse["oracle"] < 0.2, (extra, rmse)
        assert rmse["oracle"] < 0.25 * rmse["builtin"], (extra, rmse)


def test_hand_phase_follows_rt_loops_programme() -> None:
    # STUDY_HAND: a 0.5 s rest, then three cycles of press 1.0, hold 0.5, release 1.0,
    # rest 0.5 s (rt-loop/src/experiment/hand.rs); after the last cycle, rest.
    t = np.array([0.25, 0.6, 1.6, 2.2, 3.2, 3.6, 6.6, 9.4, 9.6, 12.0]) + 7.0  # any start
    t = np.concatenate([[7.0], t])
    names = [HAND_PHASES[i] for i in hand_phase(t, STUDY_HAND)]
    assert names == ["rest", "rest", "press", "hold", "release", "rest", "press", "press",
                     "rest", "rest", "rest"]  # fmt: skip


def _phase_run(f: np.ndarray, t: np.ndarray) -> Run:
    return Run(name="m", kind="reproduction", path=Path("m"), ok=True, steps=t.size,
               series={"time": t, "F_true": f})  # fmt: skip


def test_felt_by_phase_puts_the_error_where_it_is() -> None:
    t = np.arange(0.0, 9.5, 1e-3)
    ph = np.array([HAND_PHASES[i] for i in hand_phase(t, STUDY_HAND)])
    ref = np.zeros_like(t)
    run = np.where(ph == "hold", -0.2, np.where(ph == "rest", 0.1, 0.0))
    out = felt_by_phase(t, ref, _phase_run(run, t), STUDY_HAND)
    assert out is not None
    hold_s, rest_s = 3 * 0.5, 0.5 + 3 * 0.5
    sq_hold, sq_rest = 0.04 * hold_s, 0.01 * rest_s
    assert out["hold"]["sq_error_share"] == pytest.approx(sq_hold / (sq_hold + sq_rest), rel=1e-2)
    assert out["rest"]["sq_error_share"] == pytest.approx(sq_rest / (sq_hold + sq_rest), rel=1e-2)
    assert out["press"]["sq_error_share"] == 0.0
    assert out["hold"]["bias_n"] == pytest.approx(-0.2)
    assert out["hold"]["rmse"] == pytest.approx(0.2)
    assert out["press"]["time_share"] == pytest.approx(3.0 / 9.5, rel=1e-2)
    assert sum(v["time_share"] for v in out.values()) == pytest.approx(1.0)
    # a perfect run: shares of nothing are None, not NaN (results.json stays JSON)
    perfect = felt_by_phase(t, ref, _phase_run(ref, t), STUDY_HAND)
    assert perfect is not None and perfect["hold"]["sq_error_share"] is None
    json.dumps(perfect, allow_nan=False)


def test_phase_section_says_where_the_best_models_error_sits() -> None:
    t = np.arange(0.0, 9.5, 1e-3)
    ph = np.array([HAND_PHASES[i] for i in hand_phase(t, STUDY_HAND)])
    ref = np.zeros_like(t)
    rows = [_row(ORACLE, 0.03, False), _row("sd_poly2", 1.2, False), _row("m", 0.1, True)]
    errs = {ORACLE: np.where(ph == "release", 0.03, 0.0),
            "sd_poly2": np.where(ph == "press", 1.0, 0.1),
            "m": np.where(ph == "press", -0.15, 0.02)}  # fmt: skip
    for r in rows:
        r.by_phase = felt_by_phase(t, ref, _phase_run(errs[r.name], t), STUDY_HAND)
    text = "\n".join(phase_section(rows))
    m = rows[2].by_phase
    assert m is not None
    share = m["press"]["sq_error_share"]
    assert share is not None and share > 0.9
    assert (
        f"The largest share of `m`'s squared felt-force error, {100 * share:.0f} %, falls in "
        "the press phases, which take 32 % of the time; there the hand pushes 0.150 N less "
        "than on the object on average (RMSE 0.150 N)." in text
    ), text
    assert "| `oracle` | 0 % (0.000 N, +0.000 N) |" in text
    assert text.count("| `") == 3


def test_recommendation_section_names_what_is_served_and_how_it_felt() -> None:
    """The report says which model the product serves, quotes the multiples `fidelity.rank`
    chose it by, and where another ranked model felt closer on the headline runs, says so with
    both figures; with no recommendation it says that instead of naming one."""
    from haptics_train.fidelity import recommendation
    from haptics_train.study.report import recommendation_section

    def entry(sliding: float) -> dict:
        return {"validation_pooled": {"sliding": {"rmse": sliding},
                                      "closed_loop": {"rmse": 0.4}}}  # fmt: skip

    results = {"lawfree": entry(0.1), "structured": entry(0.265), "sd_poly2": entry(0.9)}
    ranking_felt = {"lawfree": 0.16, "structured": 0.168, "sd_poly2": 0.96}
    rec = recommendation(results, ["validation_5.0"], ranking_felt)
    assert rec is not None and rec["recommended"] == "lawfree"
    for e in rec["ranking"]:  # the score is the felt multiple of the two it reports
        assert e["score"] == e["felt_multiple"]
    rows = [_row(ORACLE, 0.006, False), _row("sd_poly2", 1.249, False),
            _row("lawfree", 0.294, True), _row("structured", 0.137, True)]  # fmt: skip
    text = "\n".join(recommendation_section(rec, rows, {"rank_hand": {"press_s": 1.3,
                                            "hold_s": 0.5, "release_s": 0.8}}))  # fmt: skip
    assert "| `lawfree` | 0.100 | 1.00x | 0.160 | 1.00x | 1.00 | 0.294 |" in text, text
    assert "| `structured` | 0.265 | 2.65x | 0.168 | 1.05x | 1.05 | 0.137 |" in text, text
    assert "press 1.3 s, hold 0.5 s, release 0.8 s" in text
    assert (
        "- Recommended: `lawfree`, felt 0.294 N on these runs; 49.00x the oracle's 0.006 N "
        "(issue 23: at most 2x, not met); sd_poly2 1.249 N, 4.25x its error (at least 3x, met)."
        in text
    ), text
    assert (
        "- `structured` felt closer on these runs: 0.137 N, 2.15x closer than `lawfree`. The "
        "ranking put `lawfree` first: score 1.00 (validation 1.00x, ranking runs 1.00x) "
        "against `structured`'s 1.05 (2.65x, 1.05x)." in text
    ), text
    # two ranking programmes: both described, each model's two figures beside their mean
    for e in rec["ranking"]:
        e["felt_by_programme_n"] = [e["felt_rmse_n"] * 0.8, e["felt_rmse_n"] / 0.8]
    two = {"rank_hand": {"press_s": 1.3, "hold_s": 0.5, "release_s": 0.8},
           "rank2_hand": {"press_s": 0.7, "hold_s": 1.0, "release_s": 1.2}}  # fmt: skip
    text = "\n".join(recommendation_section(rec, rows, two))
    assert (
        "the ranking runs (2 other hand programmes, each with its own seed: press 1.3 s, hold "
        "0.5 s, release 0.8 s; press 0.7 s, hold 1.0 s, release 1.2 s; the geometric mean of a "
        "model's felt force over them)" in text
    ), text
    assert "| `lawfree` | 0.100 | 1.00x | 0.160 (0.128 / 0.200) | 1.00x | 1.00 | 0.294 |" in text
    for e in rec["ranking"]:
        del e["felt_by_programme_n"]
    # the recommended model is also the closest here: said, and no other model is named
    rows[3] = _row("structured", 0.5, True)
    text = "\n".join(recommendation_section(rec, rows, {}))
    assert "`lawfree` is also the ranked model that felt closest on these runs." in text
    assert "felt closer" not in text
    # a goal met is said to be met
    rows[2] = _row("lawfree", 0.01, True)
    text = "\n".join(recommendation_section(rec, rows, {}))
    assert "1.67x the oracle's 0.006 N (issue 23: at most 2x, met)" in text, text
    # no recommendation: none is named
    text = "\n".join(recommendation_section(None, rows, {}))
    assert "No recommendation was ranked" in text and "Recommended:" not in text


def test_felt_by_press_scores_each_cycle_of_the_programme() -> None:
    """Press k's RMSE is the error of cycle k alone (press, hold, release and rest); the first
    rest is in no cycle; a cycle the run did not reach is NaN."""
    from haptics_train.study.protocol import LONG_ENDS, LONG_HAND
    from haptics_train.study.score import felt_by_press

    t = np.arange(0.0, 9.5, 1e-3)
    cycle = np.floor((t - STUDY_HAND["rest_s"]) / 3.0)
    err = np.where(t < STUDY_HAND["rest_s"], 5.0, 0.1 * (cycle + 1))  # the first rest: ignored
    out = felt_by_press(t, np.zeros_like(t), _phase_run(err, t), STUDY_HAND)
    assert out == pytest.approx([0.1, 0.2, 0.3], rel=1e-9)
    short = t < 5.0  # the run stopped in the second cycle: the third is not scored
    out = felt_by_press(t, np.zeros_like(t), _phase_run(err[short], t[short]), STUDY_HAND)
    assert out is not None and out[:2] == pytest.approx([0.1, 0.2]) and math.isnan(out[2])
    assert LONG_HAND["repeats"] >= 2 * LONG_ENDS and LONG_HAND["depth_step_m"] == 0.0


def test_long_section_compares_the_first_presses_with_the_last() -> None:
    from haptics_train.study.protocol import LONG_HAND
    from haptics_train.study.report import long_section

    rows = [_row(ORACLE, 0.01, False), _row("sd_poly2", 1.0, False), _row("m", 0.2, True),
            _row("steady", 0.1, True)]  # fmt: skip
    rows[0].by_press = [0.01] * 12
    rows[1].by_press = [1.0] * 12
    rows[2].by_press = [0.1, 0.1, 0.1] + [0.2] * 6 + [0.3, 0.3, 0.3]
    rows[3].by_press = [0.1] * 11 + [math.nan]  # a press it did not reach: no ratio
    text = "\n".join(long_section(rows, LONG_HAND))
    assert "12 presses to one set-point (31 mm" in text and "36.5 s of loop time" in text
    assert "| `m` | 0.200 | 0.100 | 0.300 | 3.00x | 0 / 0 |" in text, text
    assert "| `steady` | 0.100 | 0.100 | - | - |" in text, text
    assert "- Error grown by more than a quarter from the first presses to the last: `m` " \
           "(0.100 -> 0.300 N, 3.00x)." in text, text  # fmt: skip
    rows[2].by_press = [0.1] * 12
    text = "\n".join(long_section(rows, LONG_HAND))
    assert "the first presses to the last: none." in text
    assert long_section([], LONG_HAND) == []
