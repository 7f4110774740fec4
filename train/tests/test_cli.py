"""The command line end to end on a tiny synthetic dataset."""

import json
from pathlib import Path

import numpy as np
import onnx
import pytest

from haptics_train.cli import main
from haptics_train.models.lawfree import LAWFREE_DEFAULT
from haptics_train.synthetic import write_dataset


def test_pipeline_end_to_end(tmp_path, capsys):
    synth_root = write_dataset(tmp_path / "dataset", cycles=2)  # smaller than the shared one
    models = tmp_path / "models"
    report = tmp_path / "report"
    main([
        "pipeline", "--dataset", str(synth_root), "--models-dir", str(models),
        "--out", str(report), "--decimate", "10", "--no-progress",
        "--models", "sd_poly2,rf:six,lstm:six,dnn:memory,prony",
        "--rf-trees", "5", "--lstm-iterations", "5", "--dnn-epochs", "1",
    ])  # fmt: skip
    res = json.loads((models / "results.json").read_text())
    assert set(res) == {"sd_poly2", "rf_six", "lstm_six", "dnn_memory", "prony"}
    for name, r in res.items():
        t = r["test"][0]
        assert t["recording"] == "test_2.1"
        assert {"r2", "mae", "mse", "rmse", "max_abs", "rmse_pct_range", "contact_rmse",
                "loop_work_error", "loop_work_error_pct"} <= set(t["one_step"])  # fmt: skip
        assert r["test_pooled"]["closed_loop"]["rmse"] == t["closed_loop"]["rmse"]  # one test
        assert "closed_loop" in t
        assert r["parity"]["max_abs_diff"] < 1e-3, name
        m = onnx.load(str(models / f"{name}.onnx"))
        prov = json.loads({p.key: p.value for p in m.metadata_props}["haptics.provenance"])
        assert prov["metrics"]["test_2.1"]["one_step"]["rmse"] == t["one_step"]["rmse"]
        assert prov["dataset"]["test"][0]["name"] == "test_2.1"
        assert prov["hyperparameters"] == r["hyperparameters"]
    # models with force feedback really ran in closed loop
    assert res["rf_six"]["test"][0]["closed_loop_same_as_one_step"] is False
    assert res["dnn_memory"]["test"][0]["closed_loop_same_as_one_step"] is False
    assert res["sd_poly2"]["test"][0]["closed_loop_same_as_one_step"] is True
    text = (report / "README.md").read_text()
    assert "rf_six" in text and "Table 6.2" in text and "0.34" in text
    assert (report / "analysis.md").exists() and (report / "pearson.png").exists()
    assert (report / "test_rf_six.png").exists()

    main(["validate", str(models / "rf_six.onnx"), str(models / "lstm_six.onnx")])
    assert "ok (stateful" in capsys.readouterr().out
    # every export carries its reference steps (reference.py): the parity recording's rows in
    # contact, the force its ONNX Runtime computed; validate steps them again, and a force
    # spoiled by 1 mN is refused, naming the step
    from haptics_train.contract import ContractError, validate_model
    from haptics_train.reference import REFERENCE_KEY, REFERENCE_STEPS

    for name in res:
        m = onnx.load(str(models / f"{name}.onnx"))
        ref = json.loads({p.key: p.value for p in m.metadata_props}[REFERENCE_KEY])
        assert len(ref["force"]) == len(ref["inputs"]) == REFERENCE_STEPS, name
        assert ref["source"].startswith("test_2.1") and np.ptp(ref["force"]) > 0.1, name
        validate_model(m)
        ref["force"][7] += 1e-3
        spoiled = onnx.load(str(models / f"{name}.onnx"))
        for p in spoiled.metadata_props:
            if p.key == REFERENCE_KEY:
                p.value = json.dumps(ref)
        with pytest.raises(ContractError, match=f"{REFERENCE_KEY}: step 7 of 32"):
            validate_model(spoiled)


def test_missing_dataset_is_a_clear_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["train", "--dataset", str(tmp_path / "none"), "--models-dir", str(tmp_path)])
    assert e.value.code == 2
    assert "record-dataset.sh" in capsys.readouterr().err


def test_unknown_model_spec_is_a_clear_error(synth_root, tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["train", "--dataset", str(synth_root), "--models-dir", str(tmp_path),
              "--models", "rf:sixx", "--no-progress"])  # fmt: skip
    assert "unknown feature set" in capsys.readouterr().err


def test_step_by_step_commands(tmp_path, capsys):
    root = write_dataset(tmp_path / "dataset", cycles=2)  # no validation recording
    models = tmp_path / "m"
    common = ["--dataset", str(root), "--models-dir", str(models), "--no-progress"]
    main(["train", *common, "--models", "sd_poly1,dnn_fb:six", "--dnn-epochs", "1",
          "--feedback-noise", "0.7"])  # fmt: skip
    assert (models / "dnn_fb_six.joblib").exists() and not (models / "results.json").exists()
    capsys.readouterr()
    main(["evaluate", *common, "--names", "dnn_fb_six"])
    # nothing is recommended without a validation recording, and evaluate says why
    out = capsys.readouterr().out
    assert "no model recommended: the dataset has no validation recording" in out, out
    assert not (models / "recommendation.json").exists()
    res = json.loads((models / "results.json").read_text())
    assert (
        list(res) == ["dnn_fb_six"]
        and res["dnn_fb_six"]["hyperparameters"]["feedback_noise"] == 0.7
    )
    main(["export", *common])
    assert (models / "sd_poly1.onnx").exists() and (models / "dnn_fb_six.onnx").exists()
    main(["evaluate", *common, "--names", "sd_poly1", "--no-closed-loop"])
    main(["report", *common, "--out", str(tmp_path / "r")])
    text = (tmp_path / "r" / "README.md").read_text()
    assert "`dnn_fb_six`" in text and "`sd_poly1`" in text


def synthetic_manifest(tmp_path: Path, recs: tuple[tuple[str, float, str], ...]) -> Path:
    """A TOML manifest of synthetic recordings (name, ramp rate, role), seeded 0, 1, .. in order."""
    from haptics_train.synthetic import write_recording

    for seed, (name, rate, _) in enumerate(recs):
        write_recording(tmp_path / "recs" / f"{name}.parquet", ramp_rate=rate, seed=seed, cycles=2)
    man = tmp_path / "set.toml"
    man.write_text("\n".join(
        f'[recordings.{n}]\npath = "recs/{n}.parquet"\nrole = "{role}"\nsource = "synthetic"\n'
        for n, _, role in recs
    ))  # fmt: skip
    return man


def test_manifest_validation_selection_and_baselines(tmp_path, capsys):
    """A TOML manifest with a validation recording: the feedback noise is chosen on it (free
    run), the test is scored per recording and pooled, the baselines are printed first."""
    man = synthetic_manifest(tmp_path, (("a", 0.8, "train"), ("b", 3.9, "train"),
                                        ("v", 2.9, "validation"), ("t1", 2.1, "test"),
                                        ("t2", 6.2, "test")))  # fmt: skip
    models = tmp_path / "m"
    main(["pipeline", "--manifest", str(man), "--models-dir", str(models), "--out",
          str(tmp_path / "r"), "--no-progress", "--models", "sd_poly2,dnn_fb:six",
          "--dnn-epochs", "1", "--feedback-noise-candidates", "0.05,0.3"])  # fmt: skip
    out = capsys.readouterr().out
    res = json.loads((models / "results.json").read_text())
    sel = res["dnn_fb_six"]["training"]["selection"]
    assert sel["validation"] == ["v"] and set(sel["candidates"]) == {"0.05", "0.3"}
    assert sel["chosen"] == float(min(sel["candidates"], key=sel["candidates"].get))
    assert res["dnn_fb_six"]["hyperparameters"]["feedback_noise_frac"] == sel["chosen"]
    assert [e["recording"] for e in res["dnn_fb_six"]["test"]] == ["t1", "t2"]
    assert [e["recording"] for e in res["dnn_fb_six"]["validation"]] == ["v"]
    pool = res["dnn_fb_six"]["test_pooled"]["closed_loop"]
    per = [e["closed_loop"] for e in res["dnn_fb_six"]["test"]]
    rows = [e["rows"] for e in res["dnn_fb_six"]["test"]]
    mse = sum(p["mse"] * n for p, n in zip(per, rows, strict=True)) / sum(rows)
    assert pool["mse"] == pytest.approx(mse, rel=1e-9)
    # the synthetic recordings know the object's own force: the rendered force is scored
    # against it too, per recording and pooled
    true = [e["rendered_vs_true"] for e in res["dnn_fb_six"]["test"]]
    mse_true = sum(p["mse"] * n for p, n in zip(true, rows, strict=True)) / sum(rows)
    assert res["dnn_fb_six"]["test_pooled"]["rendered_vs_true"]["mse"] == pytest.approx(mse_true)
    sd = res["sd_poly2"]["test"][0]
    assert sd["rendered_vs_true"]["rmse"] != sd["closed_loop"]["rmse"]  # another reference
    rec = json.loads((models / "recommendation.json").read_text())
    assert rec["validation"] == ["v"] and rec["recommended"] == rec["ranking"][0]["model"]
    best = res[rec["recommended"]]["test_pooled"]["rendered_vs_true"]["rmse"]
    assert rec["free_run_true_rmse_n"] == best
    v = {r["model"]: r["validation_free_run_rmse_n"] for r in rec["ranking"]}
    assert v[rec["recommended"]] == min(v.values())
    assert v["dnn_fb_six"] == res["dnn_fb_six"]["validation_pooled"]["closed_loop"]["rmse"]
    base = json.loads((models / "baselines.json").read_text())
    assert set(base) == {"persistence", "mean", "sd_poly2"}
    # persistence wins one-step by far and loses free run: both printed, free run first
    p = base["persistence"]["test_pooled"]
    assert p["one_step"]["rmse"] < 0.2 * p["closed_loop"]["rmse"]
    table = out[out.index("[evaluate] test, pooled"):].splitlines()
    assert table[1].split()[:3] == ["model", "free-run", "RMSE"]
    assert [ln.split()[0] for ln in table[2:6]] == ["persistence", "mean", "sd_poly2",
                                                     "dnn_fb_six"]  # fmt: skip
    text = (tmp_path / "r" / "README.md").read_text()
    assert "persistence" in text and "validation" in text


def test_manifest_errors_are_clear(tmp_path, capsys):
    man = tmp_path / "m.toml"
    man.write_text('[recordings.a]\npath = "a.parquet"\nrole = "training"\n')
    with pytest.raises(SystemExit):
        main(["train", "--manifest", str(man), "--models-dir", str(tmp_path)])
    assert "role must be one of" in capsys.readouterr().err
    man.write_text('[recordings.a]\npath = "nope.parquet"\nrole = "train"\n')
    with pytest.raises(SystemExit):
        main(["train", "--manifest", str(man), "--models-dir", str(tmp_path)])
    assert "no such recording" in capsys.readouterr().err
    # a training recording alone: the refusal says how to set a test aside
    from haptics_train.synthetic import write_recording

    write_recording(tmp_path / "a.parquet", ramp_rate=6.2, cycles=1)
    man.write_text('[recordings.a]\npath = "a.parquet"\nrole = "train"\n')
    with pytest.raises(SystemExit):
        main(["train", "--manifest", str(man), "--models-dir", str(tmp_path)])
    assert f"--manifest {man} --role test" in capsys.readouterr().err


def test_defaults_scale_with_the_data(tmp_path):
    """Decimation from the rate, feedback noise from the force range, LSTM horizon in s."""
    from haptics_train.data import load_recording, row_stride
    from haptics_train.models import TrainConfig, fit_recordings, make_model
    from haptics_train.synthetic import write_recording

    rec = load_recording(write_recording(tmp_path / "r.parquet", ramp_rate=6.2, cycles=2))
    assert rec.sample_rate_hz == pytest.approx(10_000)
    assert row_stride(rec, None, 500.0) == 20 and row_stride(rec, 10) == 10
    slow = rec.head(len(rec))
    slow.columns = {**rec.columns, "time": rec.columns["time"] * 200}  # 50 Hz rows
    assert row_stride(slow, None, 500.0) == 1
    m = make_model("dnn_fb", "six", hyper={"epochs": 1})
    fit_recordings(m, [rec], TrainConfig(progress=False))
    y = rec.target()
    span = np.percentile(y, 99) - np.percentile(y, 1)
    assert m.train_info_["feedback_noise_n"] == pytest.approx(0.2 * span, rel=0.05)
    lstm = make_model("lstm", "xva", hyper={"iterations": 1, "streams": 2, "horizon_s": 0.002})
    fit_recordings(lstm, [rec], TrainConfig(progress=False))
    assert lstm.train_info_["chunk_steps"] == 20
    assert lstm.train_info_["horizon_s_effective"] == pytest.approx(0.002)


def test_lawfree_choice_needs_both_validation_scores():
    """`choose_on_both`: the candidate best on the sliding rows loses to one within 4 % of it
    there that is 20 % closer over every row (a slow memory the rests show); a candidate best
    on both wins; a diverged candidate (NaN) is never chosen and does not set the best."""
    from haptics_train.lawfree_selection import choose_on_both

    nan = float("nan")
    assert choose_on_both({"a": 1.0, "b": 1.04}, {"a": 1.2, "b": 1.0}) == "b"
    assert choose_on_both({"a": 1.0, "b": 1.2}, {"a": 1.1, "b": 1.0}) == "a"
    assert choose_on_both({"a": 1.0, "b": 1.1}, {"a": 1.0, "b": 1.05}) == "a"
    assert choose_on_both({"a": nan, "b": 2.0, "c": 2.1}, {"a": 0.1, "b": 3.0, "c": 2.0}) == "c"
    assert choose_on_both({"a": nan, "b": 2.0}, {"a": nan, "b": nan}) == "b"


def test_irreversible_memory_is_kept_only_when_clearly_closer_on_both_scores():
    """`keep_at_margin`: kept at 10 % closer on both scores (0.9x), not at 2 % (within
    the recordings' noise), not when it is closer on the sliding rows alone; never when its
    own score is not finite, always when the grid's choice has none."""
    from haptics_train.lawfree_selection import KEEP_MARGIN, keep_at_margin

    nan = float("nan")

    def keep(sliding: float, every: float, grid: tuple[float, float] = (1.0, 1.0)) -> bool:
        return keep_at_margin({"g": grid[0], "d": sliding}, {"g": grid[1], "d": every},
                              "g", "d")  # fmt: skip

    assert KEEP_MARGIN == 0.9
    assert keep(0.9, 0.9) and keep(0.2, 0.7)
    assert not keep(0.98, 0.98) and not keep(0.5, 0.95) and not keep(0.95, 0.5)
    assert not keep(nan, 0.5) and not keep(0.5, nan)
    assert keep(0.5, 0.5, (nan, 1.0))


def test_lawfree_readout_is_chosen_on_validation(tmp_path):
    """`lawfree`'s readout, ridge and memory span (`lawfree_selection.lawfree_candidates`) are
    chosen on the validation recording's free run over its sliding rows, like the
    recommendation, then the choice is tried once with the irreversible memory and once read
    through each network of `NET_GRID` (the best kept only at the margin); what the user sets
    is not searched."""
    from haptics_train.data import load_manifest
    from haptics_train.lawfree_selection import (
        BOTH_SCORES_RULE,
        DAMAGE_RULE,
        LAWFREE_DAMAGE_FRAC,
        LAWFREE_READOUTS,
        LAWFREE_RIDGES,
        LAWFREE_SPANS_S,
        NETWORK_RULE,
        choose_on_both,
        keep_at_margin,
        lawfree_candidates,
    )
    from haptics_train.models.lawfree_net import NET_GRID
    from haptics_train.pipeline import SELECTION_METRIC, _candidates

    man = synthetic_manifest(tmp_path, (("a", 0.8, "train"), ("b", 3.9, "train"),
                                        ("v", 2.9, "validation"), ("t", 2.1, "test")))  # fmt: skip
    models = tmp_path / "m"
    main(["pipeline", "--manifest", str(man), "--models-dir", str(models), "--out",
          str(tmp_path / "r"), "--no-progress", "--models", "lawfree",
          "--lawfree-network-steps", "300"])  # fmt: skip
    res = json.loads((models / "results.json").read_text())["lawfree"]
    sel = res["training"]["selection"]
    options = dict(lawfree_candidates({}))
    assert len(options) == len(LAWFREE_READOUTS) * len(LAWFREE_RIDGES) * len(LAWFREE_SPANS_S)
    assert sel["parameter"] == "readout" and sel["validation"] == ["v"]
    assert sel["metric"] == SELECTION_METRIC
    grid = {k: v for k, v in sel["candidates"].items() if k in options}
    grid_every = {k: sel["candidates_every_row"][k] for k in grid}
    assert list(grid) == list(options)
    assert sel["rule"] == BOTH_SCORES_RULE + DAMAGE_RULE + NETWORK_RULE
    pick = choose_on_both(grid, grid_every)
    damage = f"{pick}, damage memory"
    # the grid, then its choice with the irreversible memory, each scored
    assert list(sel["candidates"]) == [*options, damage]
    assert list(sel["candidates_every_row"]) == [*options, damage]
    kept = keep_at_margin(sel["candidates"], sel["candidates_every_row"], pick, damage)
    assert sel["chosen"] == (damage if kept else pick)
    for key, value in options[pick].items():
        assert res["hyperparameters"][key] == value, key
    assert res["hyperparameters"]["damage_frac"] == (list(LAWFREE_DAMAGE_FRAC) if kept else [])
    # then the choice read through every network of the grid, the best kept at the margin
    net = sel["network_readout"]
    assert len(net["candidates_every_row"]) == len(NET_GRID)
    best = min(net["candidates_every_row"].values())
    assert net["chosen"]["validation_every_row_rmse_n"] == pytest.approx(best)
    c = sel["chosen"]
    net_kept = keep_at_margin({"n": net["validation"], "c": sel["candidates"][c]},
                              {"n": net["validation_every_row"],
                               "c": sel["candidates_every_row"][c]}, "c", "n")  # fmt: skip
    assert net["kept"] == net_kept
    assert ("network_readout" in res["training"]) == net_kept
    # the score is the sliding rows' when the validation recording has them, as evaluate wrote
    sliding = res["validation_pooled"]["sliding"]
    assert sliding["rows"] > 0
    score = net["validation"] if net_kept else sel["candidates"][sel["chosen"]]
    assert score == pytest.approx(sliding["rmse"], rel=1e-6)
    ds = load_manifest(man)
    taus = LAWFREE_DEFAULT["taus_s"]
    spans = [(f"memory {s:g} s", [t for t in taus if t <= s]) for s in LAWFREE_SPANS_S]
    # every span keeps the fastest filters and drops the slowest: a span is a prefix of the grid
    assert [len(t) for _, t in spans] == sorted({len(t) for _, t in spans})
    assert spans[-1][1] == taus and len(spans[0][1]) < len(taus)
    assert _candidates("lawfree", {"lawfree": {"memory_at_surface": True}}, None, ds) == (
        "readout", [(f"ridge {r:g}, {sl}", {"ridge": r, "taus_s": st})
                    for r in LAWFREE_RIDGES for sl, st in spans])  # fmt: skip
    only_ridge = _candidates("lawfree", {"lawfree": {"ridge": 1e-3}}, None, ds)
    readouts = [(f"{label}, {sl}", {**h, "taus_s": st})
                for label, h in LAWFREE_READOUTS for sl, st in spans]  # fmt: skip
    assert only_ridge == ("readout", readouts)
    only_span = _candidates("lawfree", {"lawfree": {"memory_at_surface": True, "ridge": 1e-3}},
                            None, ds)  # fmt: skip
    assert only_span == ("readout", [(sl, {"taus_s": st}) for sl, st in spans])
    all_set = {"lawfree": {"memory_at_surface": True, "ridge": 1e-3, "taus_s": [0.1, 1.0]}}
    assert _candidates("lawfree", all_set, None, ds) is None
    assert _candidates("prony", None, None, ds) is None  # structured: test_structured.py
