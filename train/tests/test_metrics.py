import math

import numpy as np
import pytest

from haptics_train.metrics import active_work_note, loop_work, regression_metrics


def test_hand_worked_example():
    # e = y - p = [0, 0, 0, -1]; mean y = 2.5, SS_tot = 2.25 + 0.25 + 0.25 + 2.25 = 5
    m = regression_metrics(np.array([1.0, 2.0, 3.0, 4.0]), np.array([1.0, 2.0, 3.0, 5.0]))
    assert m["mse"] == pytest.approx(0.25)
    assert m["mae"] == pytest.approx(0.25)
    assert m["rmse"] == pytest.approx(0.5)
    assert m["r2"] == pytest.approx(1 - 1 / 5)


def test_second_hand_worked_example_with_mixed_signs():
    # e = [1, -2, 0.5]: MSE = (1 + 4 + 0.25) / 3 = 1.75, MAE = 3.5 / 3
    y = np.array([2.0, -1.0, 0.5])
    p = np.array([1.0, 1.0, 0.0])
    m = regression_metrics(y, p)
    assert m["mse"] == pytest.approx(1.75)
    assert m["mae"] == pytest.approx(3.5 / 3)
    assert m["rmse"] == pytest.approx(math.sqrt(1.75))
    # mean y = 0.5: SS_tot = 2.25 + 2.25 + 0 = 4.5; SS_res = 5.25
    assert m["r2"] == pytest.approx(1 - 5.25 / 4.5)


def test_mean_predictor_has_zero_r2_and_perfect_has_one():
    y = np.array([3.0, 1.0, 4.0, 1.0, 5.0])
    assert regression_metrics(y, np.full(5, y.mean()))["r2"] == pytest.approx(0.0)
    perfect = regression_metrics(y, y)
    assert perfect["r2"] == 1.0 and perfect["rmse"] == 0.0


def test_diverged_prediction_scores_infinite_rmse_not_dropped():
    m = regression_metrics(np.array([1.0, 2.0, 3.0]), np.array([1.0, np.nan, np.nan]))
    assert m["rmse"] == math.inf


def test_shape_mismatch_is_an_error():
    with pytest.raises(ValueError):
        regression_metrics(np.zeros(3), np.zeros(4))


def test_force_metrics_by_hand():
    from haptics_train.metrics import force_metrics, loop_work, pooled

    # a square loop in the force-depth plane: load at 2 N from x=0 to 1, unload at 1 N back
    x = np.array([0.0, 1.0, 1.0, 0.0])
    f = np.array([2.0, 2.0, 1.0, 1.0])
    assert loop_work(x, f) == pytest.approx(2.0 * 1 + 1.5 * 0 + 1.0 * -1)  # = 1 J dissipated
    y = np.array([0.0, 1.0, 3.0, 0.0])
    p = np.array([0.0, 2.0, 3.0, 0.5])
    m = force_metrics(y, p, np.array([0.0, 1.0, 2.0, 0.0]), contact_n=0.5)
    assert m["max_abs"] == 1.0
    assert m["rmse"] == pytest.approx(np.sqrt((1 + 0.25) / 4))
    assert m["rmse_pct_range"] == pytest.approx(100 * m["rmse"] / 3.0)
    assert m["contact_rows"] == 2 and m["contact_rmse"] == pytest.approx(np.sqrt(1 / 2))
    # work true: 0.5*1 + 2*1 + 1.5*(-2) = -0.5; predicted: 1 + 2.5 - 3.5 = 0
    assert m["loop_work_true"] == pytest.approx(-0.5)
    assert m["loop_work_error"] == pytest.approx(0.5)
    assert m["loop_work_error_pct"] == pytest.approx(100.0)
    both = pooled([(y, p, x, 0.5), (y, y, x, 0.5)])
    assert both["mse"] == pytest.approx(m["mse"] / 2)
    assert both["contact_rows"] == 4 and both["contact_rmse"] == pytest.approx(np.sqrt(1 / 4))
    diverged = force_metrics(y, np.array([0.0, np.inf, 0.0, 0.0]), x, 0.5)
    assert diverged["rmse"] == float("inf") and diverged["max_abs"] == float("inf")


def test_a_model_that_gives_energy_back_over_its_training_recordings_is_told() -> None:
    # a press and release along a loop: loading above unloading absorbs, the reverse gives back
    x = np.concatenate([np.linspace(0.0, 0.01, 50), np.linspace(0.01, 0.0, 50)])
    up, down = 1000.0 * x[:50], 800.0 * x[50:]
    absorbs = loop_work(x, np.concatenate([up, down]))
    gives = loop_work(x, np.concatenate([800.0 * x[:50], 1000.0 * x[50:]]))
    assert absorbs == pytest.approx(0.01, rel=0.05) and gives == pytest.approx(-absorbs)
    assert active_work_note([absorbs, absorbs]) is None
    assert active_work_note([absorbs, -5e-6]) is None  # noise where the probe barely meets it
    note = active_work_note([absorbs, gives, absorbs])
    assert note is not None and "recording 2 of 3: 0.01 J" in note and "passivity" in note
