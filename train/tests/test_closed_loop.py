import numpy as np
import pytest

from haptics_train.closed_loop import FeatureTracker, FunctionStepper, replay_features, simulate
from haptics_train.data import recording_from_columns
from haptics_train.features import NINE


def _rec(x, v=None, a=None, force=None):
    n = len(x)
    cols = {
        "time": np.arange(n) * 1e-4,
        "rtob_force": np.zeros(n) if force is None else np.asarray(force, float),
        "position_x": np.asarray(x, float),
        "velocity": np.ones(n) if v is None else np.asarray(v, float),
        "acceleration": np.ones(n) if a is None else np.asarray(a, float),
    }
    for k in NINE[3:]:
        cols[k] = np.full(n, -999.0)  # recorded values the closed loop must NOT use
    return recording_from_columns("t", cols)


def test_tracker_ratios_hold_last_value_like_rt_loop():
    # the same case as rt-loop's features.rs unit test
    tr = FeatureTracker()
    f0 = tr.begin(0.0, 0.0, 0.0)
    assert (f0["f_previous_x"], f0["f_previous_v"], f0["f_previous_a"]) == (0.0, 0.0, 0.0)
    tr.commit(0.0, 2.0)
    f1 = tr.begin(0.01, 0.5, 4.0)
    assert (f1["f_previous_x"], f1["f_previous_v"], f1["f_previous_a"]) == (200.0, 4.0, 0.5)
    tr.commit(0.01, 3.0)
    f2 = tr.begin(0.0, 0.0, -2.0)
    assert (f2["f_previous_x"], f2["f_previous_v"], f2["f_previous_a"]) == (200.0, 4.0, -1.5)
    assert f2["f_previous"] == 3.0


def test_tracker_cycle_area_and_deformation_of_a_known_loop():
    # load along F = k x to x1, unload along F = k (x - d): area = k d x1 - k d^2 / 2 ... the
    # trapezoid rule is exact for piecewise-linear F(x), so compare with the polygon area.
    k, d, x1 = 100.0, 0.002, 0.01
    xs_up = np.linspace(0, x1, 101)
    xs_dn = np.linspace(x1, d, 101)
    tr = FeatureTracker(contact_on_n=0.5, contact_off_n=0.25)
    for x in xs_up:
        tr.begin(x, 1.0, 1.0)
        tr.commit(x, k * x)
    for x in xs_dn:
        tr.begin(x, -1.0, 1.0)
        tr.commit(x, k * (x - d))
    f = tr.begin(d, 0.0, 0.0)
    # the cycle ends on the first unloading step where k (x - d) < 0.25 N
    x_end = xs_dn[np.argmax(k * (xs_dn - d) < 0.25)]
    assert f["cycle_no"] == 2.0
    assert f["deformation"] == x_end
    # trapezoids are exact on piecewise-linear F(x): loading area minus unloading area
    exact = k * x1**2 / 2 - (k * (x1 - d) ** 2 / 2 - k * (x_end - d) ** 2 / 2)
    assert f["area_fx"] == pytest.approx(exact, rel=1e-9)


def test_closed_loop_feeds_the_models_own_prediction_back():
    # Model: F = f_previous_x * x + 1 = F_pred(t-1) + 1 (x never 0), so in closed loop the
    # prediction counts up 1, 2, 3, ... whatever the recorded features say.
    n = 50
    rec = _rec(np.linspace(0.001, 0.01, n))
    feats = ("position_x", "f_previous_x")
    pred = simulate(FunctionStepper(lambda r: r[1] * r[0] + 1.0), rec, feats)
    np.testing.assert_allclose(pred, np.arange(1, n + 1), rtol=1e-12)


def test_closed_loop_holds_the_ratio_on_zero_divisor():
    x = np.array([0.01, 0.02, 0.0, 0.0, 0.04])
    rec = _rec(x)
    seen = []

    def model(r):
        seen.append(r[1])
        return 10.0 * (len(seen))  # predictions 10, 20, 30, ...

    simulate(FunctionStepper(model), rec, ("position_x", "f_previous_x"))
    # t0: 0 (no previous); t1: 10/0.02; t2, t3: x = 0 -> held 500; t4: 40/0.04
    np.testing.assert_allclose(seen, [0.0, 500.0, 500.0, 500.0, 1000.0])


def test_closed_loop_divergence_becomes_nan_and_scores_inf():
    n = 1100
    rec = _rec(np.full(n, 0.01), force=np.full(n, 1.0))
    # F = 2 F(t-1) + 1: 1, 3, 7, ... 2^(t+1) - 1, overflows float64 after ~1023 steps
    pred = simulate(FunctionStepper(lambda r: 2.0 * r[1] * r[0] + 1.0),
                    rec, ("position_x", "f_previous_x"))  # fmt: skip
    np.testing.assert_allclose(pred[:10], 2.0 ** np.arange(1, 11) - 1, rtol=1e-12)
    assert np.isnan(pred[-1])
    assert np.isfinite(pred[:1000]).all()


def test_replay_with_measured_force_reproduces_synthetic_columns(synth):
    rec = synth.test[0]
    f = replay_features(rec, rec.column("rtob_force"))
    for k in ("f_previous_x", "f_previous_v", "f_previous_a", "cycle_no", "area_fx"):
        np.testing.assert_array_equal(f[k], rec.column(k), err_msg=k)
