"""Stateful models are served at the loop's period, whatever the rows they were fitted on.

A recording made with rt-loop's `--decimate 2` has one row every two control steps, but the
loop steps a model's state once per control step. `structured`, `prony` and `lawfree` decay
their states as exp(-dt / tau): fitted at the rows' period and exported at it, they relaxed
twice as fast as the object when served (the sponge at DECIMATE=2: `structured` 0.333 N felt
instead of 0.150, `lawfree` 5.08 N). They are now fitted at the rows' period and exported at
the loop's (`serve_dt_`, `haptics.step_s` in the metadata), which infer-server checks against
the loop's rate. Here on a relaxing object simulated at a 2 kHz loop and recorded every second
step, stepped as served through ONNX Runtime at every loop step."""

import numpy as np
import pytest

from haptics_train.closed_loop import OnnxStepper
from haptics_train.data import SequenceInfo
from haptics_train.export import parity, provenance, to_contract_onnx
from haptics_train.models import TrainConfig, make_model
from haptics_train.models.base import LOOP_RATE_HZ_DEFAULT, serve_dt

LOOP_HZ = 2000.0
DECIMATE = 2
TAU_S = 0.3

HYPER = {
    "structured": {
        "yield_frac": [0.1, 0.2], "densification_frac": [1.6], "densification_exponents": [2.0],
        "taus_s": [0.1, 0.3, 1.0], "hysteresis_frac": [0.04], "friction_lengths_m": [2e-5],
        "set_frac": [0.0],
    },
    "lawfree": {"taus_s": [0.1, 0.3, 1.0, 3.0], "play_frac": [0.02, 0.1]},
    "prony": {},
}  # fmt: skip


def relaxing_object(depths: list[float], period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """[x, v] at every loop step of cosine presses, and the force of a spring with one
    relaxing branch (tau 0.3 s, driven by the compression's increments)."""
    t = np.arange(0, period_s, 1 / LOOP_HZ)
    x = np.concatenate([-0.002 + (d + 0.002) * 0.5 * (1 - np.cos(2 * np.pi * t / period_s))
                        for d in depths])  # fmt: skip
    v = np.gradient(x, 1 / LOOP_HZ)
    e = np.maximum(x, 0.0)
    d = np.exp(-1 / (LOOP_HZ * TAU_S))
    q = np.zeros_like(x)
    de = np.diff(e, prepend=0.0)
    for n in range(1, len(x)):
        q[n] = d * q[n - 1] + 300.0 * de[n]
    f = np.where(e > 0, np.maximum(200.0 * e + 2e4 * e**2 + q, 0.0), 0.0)
    return np.column_stack([x, v]), f


def rows_info(n_rows: int, loop_rate_hz: float = LOOP_HZ) -> SequenceInfo:
    rate = LOOP_HZ / DECIMATE
    return SequenceInfo(
        sample_rate_hz=rate, duration_s=n_rows / rate, stride=1, row_step=DECIMATE,
        contact_off_n=0.05, loop_rate_hz=loop_rate_hz,
    )  # fmt: skip


@pytest.fixture(scope="module")
def training() -> tuple[np.ndarray, np.ndarray]:
    X, f = relaxing_object([0.01, 0.02, 0.015, 0.025], 2.0)
    return X[::DECIMATE], f[::DECIMATE]


def stepped(m: object, X: np.ndarray) -> np.ndarray:
    """The exported graph stepped once per row of X, as infer-server steps it."""
    onnx_model = to_contract_onnx(m, provenance(m, TrainConfig(), None, None), fused=False)
    st = OnnxStepper(onnx_model)
    return np.array([st.step(r) for r in X])


def test_the_serving_period_is_the_recording_loops_else_rt_loops_default():
    assert serve_dt("m", [rows_info(10)]) == pytest.approx(1 / LOOP_HZ)
    # imported data (a testing machine at 50 Hz): no loop recorded it, served at 10 kHz
    imported = SequenceInfo(50.0, 10.0, 1, 1, 0.05)
    assert serve_dt("m", [imported]) == pytest.approx(1 / LOOP_RATE_HZ_DEFAULT)
    with pytest.warns(UserWarning, match="loops at different rates"):
        serve_dt("m", [rows_info(10), rows_info(10, 4000.0), rows_info(10, 4000.0)])


@pytest.mark.parametrize("algo", ["structured", "prony", "lawfree"])
def test_a_model_fitted_on_decimated_rows_relaxes_at_the_fitted_speed_when_served(
    algo, training
):
    Xr, fr = training
    m = make_model(algo, hyper=HYPER[algo])
    m.fit([Xr], [fr], info=[rows_info(len(Xr))])
    assert m.dt_ == pytest.approx(DECIMATE / LOOP_HZ)
    assert m.serve_dt_ == pytest.approx(1 / LOOP_HZ)
    assert m.train_info_["serve_dt_s"] == pytest.approx(1 / LOOP_HZ)
    om = to_contract_onnx(m, provenance(m, TrainConfig(), None, None), fused=False)
    meta = {p.key: p.value for p in om.metadata_props}
    assert float(meta["haptics.step_s"]) == pytest.approx(1 / LOOP_HZ)

    # a press it was not fitted on, at every loop step, as the loop serves it
    X, _ = relaxing_object([0.018], 2.5)
    served = stepped(m, X)
    framework = getattr(m, "predict_served", m.predict)
    # parity at the serving period
    ref = framework(X, dt=1 / LOOP_HZ)
    assert np.max(np.abs(served - ref)) < 1e-3 * max(1.0, np.abs(ref).max())
    # the force the model predicts on the rows it was fitted at, at the same instants
    on_rows = framework(X[::DECIMATE])
    err = np.sqrt(np.mean((served[::DECIMATE] - on_rows) ** 2))
    # what the old export did: the graph stepped at the rows' period, once per loop step
    m.serve_dt_ = m.dt_
    old = stepped(m, X)
    err_old = np.sqrt(np.mean((old[::DECIMATE] - on_rows) ** 2))
    assert err < 0.3 * err_old, (err, err_old)
    assert err < 0.02 * np.abs(on_rows).max(), (err, np.abs(on_rows).max())


def test_parity_compares_graph_and_framework_at_the_serving_period(training, tmp_path):
    """`export.parity` steps the framework at the graph's period on a decimated recording."""
    from haptics_train.data import Recording

    Xr, fr = training
    m = make_model("prony", hyper=HYPER["prony"])
    m.fit([Xr], [fr], info=[rows_info(len(Xr))])
    rec = Recording("decimated", {
        "time": np.arange(len(Xr)) * DECIMATE / LOOP_HZ, "step": np.arange(len(Xr)) * DECIMATE,
        "position_x": Xr[:, 0], "velocity": Xr[:, 1], "rtob_force": fr,
    })  # fmt: skip
    p = parity(m, to_contract_onnx(m, provenance(m, TrainConfig(), None, None), fused=False), rec)
    assert p["max_abs_diff"] < 1e-4 and p["rows_with_force"] > 100, p
