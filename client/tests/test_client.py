"""The client against the real rt-loop and infer-server (conftest.py starts them)."""

import json
import os

import numpy as np
import pytest

import haptics
from haptics import pb


def test_status_and_figures(client):
    s = client.status()
    assert isinstance(s, pb.Status)
    assert s.loop_alive and s.board == "sim" and s.clock == "realtime"
    assert s.token_required
    f = client.figures()
    assert f["loop_alive"] is True
    keys = ("rate_hz", "on_time", "late_one", "held", "fallback", "round_trip_latency.p99_us",
            "active_model.name", "experiment.running")  # fmt: skip
    for key in keys:
        assert key in f, key


def test_models_list_load_swap_unload(client, system):
    names = {m.name: m for m in client.models()}
    assert {"soft_spring.onnx", "stiff_spring.onnx"} <= set(names), names
    assert client.active_model().name == "soft_spring.onnx"
    m = client.load("stiff_spring.onnx")
    assert m.name == "stiff_spring.onnx" and m.state == pb.MODEL_STATE_LOADED
    assert list(m.features) == ["position_x", "velocity"]
    sw = client.swap("stiff_spring.onnx")
    assert sw.model.name == "stiff_spring.onnx" and sw.effective_step >= 0  # 0: loop idle
    assert client.active_model().name == "stiff_spring.onnx"
    client.unload("soft_spring.onnx")
    states = {m.name: m.state for m in client.models()}
    assert states["soft_spring.onnx"] == pb.MODEL_STATE_AVAILABLE
    # the active model cannot be unloaded: the server's refusal, typed
    with pytest.raises(haptics.NotPossibleNow, match="unload stiff_spring"):
        client.unload("stiff_spring.onnx")
    client.swap("soft_spring.onnx")


def test_upload_a_file_and_swap_to_it(client, system, tmp_path):
    up = tmp_path / "uploaded_spring.onnx"
    up.write_bytes(system.models["stiff_spring"].read_bytes())
    m = client.upload(up)
    assert m.name.startswith("uploaded_spring") and m.state == pb.MODEL_STATE_LOADED
    sw = client.swap(up)
    assert sw.model.name.startswith("uploaded_spring")
    client.swap("soft_spring.onnx")


def test_bad_models_are_typed(client, tmp_path):
    broken = tmp_path / "broken.onnx"
    broken.write_bytes(b"this is not an onnx model")
    with pytest.raises(haptics.BadModel, match="bad model"):
        client.upload(broken)
    with pytest.raises(haptics.BadModel):
        client.load("no_such_model.onnx")
    with pytest.raises(haptics.BadModel):
        client.swap("no_such_model")
    assert client.active_model().name == "soft_spring.onnx"  # still serving


def test_token_wrong_or_missing_is_typed(system, tmp_path, monkeypatch):
    monkeypatch.delenv("HAPTICS_TOKEN", raising=False)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))  # no connection file here
    with haptics.Client(system.address, token="not-the-token") as c:
        # Reads that show live data need the token too (docs/control-plane.md, local trust).
        with pytest.raises(haptics.WrongToken, match="token"):
            c.status()
        with pytest.raises(haptics.WrongToken, match="token"):
            c.swap("stiff_spring.onnx")
    with haptics.Client(system.address, instance="none-such") as c:
        assert c.info.token is None
        with pytest.raises(haptics.WrongToken):
            c.stop_experiment()


def test_connection_file_gives_address_and_token(system, tmp_path, monkeypatch):
    """Client() with no argument, as in the notebook: the address and token come from the
    connection file (written here as infer-server writes it)."""
    for k in ("HAPTICS_ADDR", "HAPTICS_TOKEN", "HAPTICS_INSTANCE"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    d = tmp_path / "haptics"
    d.mkdir(mode=0o700)
    f = d / "default.json"
    f.write_text(json.dumps({"instance": "default", "pid": system.server.pid,
                             "grpc": system.address, "http": system.http, "token": system.token,
                             "page": f"{system.http}/#token={system.token}"}))  # fmt: skip
    os.chmod(f, 0o600)
    with haptics.Client() as c:
        assert c.address == system.address and c.info.token == system.token
        c.swap("stiff_spring.onnx")  # a change: the token was sent
        c.swap("soft_spring.onnx")


def test_experiment_options_refused_are_typed(client):
    with pytest.raises(haptics.Refused, match="INVALID_ARGUMENT"):
        client.start_experiment("abstraction", ramp_rate=-1.0)
    with pytest.raises(haptics.Refused):
        client.start_experiment("juggling")


def test_experiment_telemetry_window_and_rows(client):
    client.start_experiment("abstraction", ramp_rate=6.0, cycles=2, f_max_start=3.0,
                            f_max_step=1.0)  # fmt: skip
    try:
        rows = list(client.telemetry_rows(decimation=100, count=20))
        assert len(rows) == 20 and all(isinstance(r, pb.TelemetrySample) for r in rows)
        assert all(r.steps == 100 for r in rows[1:-1])
        assert np.all(np.diff([r.step for r in rows]) > 0)
        w = client.telemetry(seconds=1.0, decimation=haptics.PAGE_DECIMATION)
        # 10 kHz, 10 steps a bucket: about 1000 buckets in one second
        assert len(w) > 300, len(w)
        for col in ("step", "time_s", "f_ref", "position_x", "rtob_force_min", "F_true_max",
                    "model_id_max"):  # fmt: skip
            assert col in w.columns, col
        assert np.all(w["rtob_force_min"] <= w["rtob_force_max"])
        frame = w.to_polars()
        assert frame.height == len(w) and "position_x_max" in frame.columns
        # the client kept up: every step of the window's span is in some bucket
        span = int(w["step"][-1] + w["steps"][-1] - w["step"][0])
        assert w.steps_received == span, (w.steps_received, span)
        assert client.status().experiment.kind == "abstraction"
    finally:
        client.stop_experiment()
    s = client.wait_experiment(timeout=20)
    assert not s.experiment.running


def test_run_experiment_waits_until_done(client):
    s = client.run_experiment("abstraction", timeout=60, ramp_rate=20.0, cycles=1,
                              f_max_start=2.0)  # fmt: skip
    assert not s.experiment.running and s.experiment.kind in ("idle", "abstraction")
    assert s.step > 10_000  # hold 1.5 s + ramps + hold: well over a second at 10 kHz


def test_read_recording_uses_the_training_reader(system, tmp_path):
    import subprocess

    from conftest import binary

    out = tmp_path / "r.parquet"
    subprocess.run(
        [str(binary("rt-loop", "HAPTICS_RT_LOOP")), "run", "--experiment", "abstraction",
         "--clock", "lockstep", "--seed", "3", "--ramp-rate", "6.2", "--cycles", "1",
         "--record", str(out), "--no-progress", "--instance", f"{system.instance}-rec"],
        check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    rec = haptics.read_recording(out)
    assert len(rec) > 1000 and "f_previous" in rec.frame.columns
    assert rec.run["experiment"] == "abstraction" and rec.run["seed"] == 3
    from haptics_train.data import load_recording

    ref = load_recording(out)
    np.testing.assert_array_equal(rec["rtob_force"], ref.column("rtob_force"))


def test_live_telemetry_drains_without_blocking_and_loses_nothing(client):
    import time

    with client.live_telemetry(decimation=50) as live:
        t0 = time.monotonic()
        assert len(live.drain()) == 0  # the loop idles: nothing yet, and no waiting
        assert time.monotonic() - t0 < 0.5
        client.start_experiment("abstraction", ramp_rate=20.0, cycles=1, f_max_start=2.0)
        parts = []
        try:
            for _ in range(6):
                time.sleep(0.3)
                parts.append(live.drain())
        finally:
            client.stop_experiment()
        client.wait_experiment(timeout=20)
    steps = np.concatenate([p["step"] for p in parts if len(p)])
    counts = np.concatenate([p["steps"] for p in parts if len(p)])
    assert len(steps) > 20
    # consecutive buckets across drains: each starts where the previous ended
    np.testing.assert_array_equal(steps[1:], steps[:-1] + counts[:-1])
