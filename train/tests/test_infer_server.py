"""Exported models pass infer-server's own validation and give the same forces there
(skipped only when the infer-server binary is not built)."""

import json
import subprocess

import numpy as np
import pytest

from haptics_train.export import onnx_predict, provenance, save_onnx, to_contract_onnx
from haptics_train.models import TrainConfig, fit_recordings, make_model
from haptics_train.vocab import FEATURE_NAMES

CFG = TrainConfig(decimate=10, progress=False)


@pytest.fixture(scope="module")
def exported(synth, tmp_path_factory):
    out = tmp_path_factory.mktemp("onnx")
    files = {}
    for algo, fs, hyper in [
        ("sd_poly2", "x_v", None),
        ("rf", "six", {"n_estimators": 10, "max_depth": 6}),
        ("dnn", "nine", {"epochs": 1}),
        ("lstm", "six", {"iterations": 5, "streams": 8, "chunk": 20}),
        ("dnn", "xva_f", {"epochs": 1}),
        ("lstm_slow", "x_v", {"iterations": 5, "streams": 4, "state_step_s": 0.001,
                              "horizon_s": 0.02, "hidden": 8, "head": 8}),
    ]:
        m = make_model(algo, fs, hyper=hyper)
        fit_recordings(m, synth.train, CFG)
        om = to_contract_onnx(m, provenance(m, CFG, synth, None))
        files[m.name] = (m, om, save_onnx(om, out / f"{m.name}.onnx"))
    return files


def _run(server, *args):
    return subprocess.run([str(server), *args], capture_output=True, text=True, timeout=120,
                          cwd=server.parents[2])  # fmt: skip


def test_exported_models_pass_infer_server_validation(exported, infer_server):
    for name, (_, _, path) in exported.items():
        if name == "dnn_xva_f":
            continue
        r = _run(infer_server, "validate", str(path), "--json")
        assert r.returncode == 0, (name, r.stdout, r.stderr)
        assert json.loads(r.stdout.strip().splitlines()[-1])["ok"] is True


def test_model_needing_a_feature_the_loop_lacks_is_refused(exported, infer_server):
    # f_previous is not in rt-loop's nine-feature schema: the server must say so
    _, _, path = exported["dnn_xva_f"]
    r = _run(infer_server, "validate", str(path))
    assert r.returncode == 1, (r.stdout, r.stderr)
    r = _run(infer_server, "validate", str(path), "--schema", ",".join(FEATURE_NAMES))
    assert r.returncode == 0, (r.stdout, r.stderr)


def test_infer_server_predicts_what_onnxruntime_predicts(exported, synth, infer_server, tmp_path):
    rec = synth.test[0]
    for name in ("rf_six", "lstm_six", "sd_poly2", "lstm_slow"):
        m, om, path = exported[name]
        n = 300
        csv = tmp_path / f"{name}.csv"
        # plain CSV (infer-server reads an unquoted header)
        np.savetxt(csv, rec.matrix(m.features)[:n], delimiter=",", header=",".join(m.features),
                   comments="", fmt="%.17g")  # fmt: skip
        r = _run(infer_server, "predict", str(path), "--csv", str(csv))
        assert r.returncode == 0, (name, r.stderr)
        got = np.array([float(v) for v in r.stdout.split()])
        ref = onnx_predict(om, rec, m.features, limit=n)
        np.testing.assert_allclose(got, ref, atol=1e-4, err_msg=name)
