"""The command line end to end on a tiny synthetic dataset."""

import json

import onnx
import pytest

from haptics_train.cli import main
from haptics_train.synthetic import write_dataset


def test_pipeline_end_to_end(tmp_path, capsys):
    synth_root = write_dataset(tmp_path / "dataset", cycles=2)  # smaller than the shared one
    models = tmp_path / "models"
    report = tmp_path / "report"
    main([
        "pipeline", "--dataset", str(synth_root), "--models-dir", str(models),
        "--out", str(report), "--decimate", "10", "--no-progress",
        "--models", "sd_poly2,rf:six,lstm:six,dnn:memory",
        "--rf-trees", "5", "--lstm-iterations", "5", "--dnn-epochs", "1",
    ])  # fmt: skip
    res = json.loads((models / "results.json").read_text())
    assert set(res) == {"sd_poly2", "rf_six", "lstm_six", "dnn_memory"}
    for name, r in res.items():
        t = r["test"][0]
        assert t["recording"] == "test_2.1"
        assert set(t["one_step"]) == {"r2", "mae", "mse", "rmse"}
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


def test_step_by_step_commands(tmp_path):
    root = write_dataset(tmp_path / "dataset", cycles=2)
    models = tmp_path / "m"
    common = ["--dataset", str(root), "--models-dir", str(models), "--no-progress"]
    main(["train", *common, "--models", "sd_poly1,dnn_fb:six", "--dnn-epochs", "1",
          "--feedback-noise", "0.7"])  # fmt: skip
    assert (models / "dnn_fb_six.joblib").exists() and not (models / "results.json").exists()
    main(["evaluate", *common, "--names", "dnn_fb_six"])
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
