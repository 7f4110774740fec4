"""Against a real lockstep recording of rt-loop (skipped when the binary is not built)."""

import subprocess

import numpy as np
import pytest

from haptics_train.closed_loop import replay_features
from haptics_train.data import load_recording
from haptics_train.features import F_PREVIOUS, FEEDBACK_FEATURES
from haptics_train.models import TrainConfig, fit_recordings, make_model


def _record(rt_loop, out, decimate=1):
    subprocess.run(
        [str(rt_loop), "run", "--experiment", "abstraction", "--clock", "lockstep",
         "--seed", "3", "--ramp-rate", "6.2", "--cycles", "3", "--record", str(out),
         "--decimate", str(decimate), "--no-progress"],
        check=True, capture_output=True, cwd=rt_loop.parents[2], timeout=120,
    )  # fmt: skip
    return load_recording(out)


@pytest.fixture(scope="module")
def recording(tmp_path_factory, rt_loop):
    return _record(rt_loop, tmp_path_factory.mktemp("rt") / "r.parquet")


def test_previous_force_is_the_previous_control_step_even_in_decimated_recordings(
    recording, rt_loop, tmp_path
):
    full = recording
    assert full.row_step == 1
    f = full.column("rtob_force")
    np.testing.assert_allclose(full.column(F_PREVIOUS)[1:], f[:-1], rtol=1e-12, atol=1e-12)
    dec = _record(rt_loop, tmp_path / "d.parquet", decimate=3)  # lockstep: same run
    assert dec.row_step == 3
    steps = dec.column("step").astype(int)
    moving = (steps > 0) & (
        (dec.column("position_x") != 0) | (dec.column("velocity") != 0)
        | (dec.column("acceleration") != 0)
    )  # fmt: skip
    # exact wherever the loop had a non-zero divisor ...
    np.testing.assert_allclose(dec.column(F_PREVIOUS)[moving], f[steps[moving] - 1],
                               rtol=1e-12, atol=1e-12)  # fmt: skip
    # ... interpolated between rows where the probe is exactly at rest
    rest = (steps > 0) & ~moving
    assert rest.any()
    np.testing.assert_allclose(dec.column(F_PREVIOUS)[rest], f[steps[rest] - 1], atol=2e-3)


def test_closed_loop_feature_twin_matches_rt_loop_exactly(recording):
    f = replay_features(recording, recording.column("rtob_force"))
    for k in FEEDBACK_FEATURES:
        if k == F_PREVIOUS:
            continue
        np.testing.assert_array_equal(f[k], recording.column(k), err_msg=k)
    assert recording.column("cycle_no").max() >= 3


def test_models_train_on_a_real_recording(recording):
    m = make_model("rf", "six", hyper={"n_estimators": 10, "max_depth": 6})
    fit_recordings(m, [recording], TrainConfig(decimate=10, progress=False))
    pred = m.predict(recording.matrix(m.features))
    y = recording.target()
    assert np.sqrt(np.mean((pred - y) ** 2)) < 0.5 * y.std()
