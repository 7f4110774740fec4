"""Which rows `structured` and `lawfree` fit (models/contact_rows.py)."""

from __future__ import annotations

import numpy as np
import pytest

from haptics_train.data import SequenceInfo
from haptics_train.models.contact_rows import fitted_rows, sliding_rows

OFF = 0.25  # rt-loop's contact_off_n


def test_a_row_counts_by_the_objects_force_not_the_target():
    """Friction 0.9 N. Releasing (v < 0) with the object at 0.5 N the target reads -0.4 N: kept
    (the rule that compared the target with the threshold dropped it). Pressing with the
    object at 0 (the probe past the surface, not touching it yet) the target reads +0.9 N:
    dropped. Stuck rows never count; out of contact every sliding row counts."""
    f = 0.9
    x = np.array([0.002, 0.002, 0.002, 0.002, 0.002, -0.001, -0.001])
    v = np.array([-0.01, 0.01, 0.01, -0.01, 0.0, -0.01, 0.01])
    obj = np.array([0.5, 0.0, 0.5, 0.1, 3.0, 0.0, 0.0])
    t = obj + f * np.sign(v)
    keep = fitted_rows(x, v, t, OFF, f, 1e-4)
    assert keep.tolist() == [True, False, True, False, False, True, True]
    # no free air measured: the target's own rule
    assert fitted_rows(x, v, t, OFF, 0.0, 1e-4).tolist() == (
        ((np.abs(v) > 1e-4) & ((x <= 0) | (t > OFF))).tolist())


def test_the_friction_is_what_the_free_air_shows():
    rng = np.random.default_rng(1)
    x = np.r_[-0.01 * np.ones(400), 0.005 * np.ones(400)]
    v = np.r_[rng.choice([-0.02, 0.02], 400), rng.choice([-0.02, 0.02], 400)]
    t = np.r_[0.7 * np.sign(v[:400]) + 0.01 * rng.standard_normal(400), 5 + np.zeros(400)]
    info = SequenceInfo(sample_rate_hz=1000.0, duration_s=0.8, stride=1, row_step=1,
                        contact_off_n=OFF, loop_rate_hz=1000.0)  # fmt: skip
    xv = np.column_stack([x, v])
    assert sliding_rows([xv], [t], [info], 1e-4)[0] == pytest.approx(0.7, abs=0.01)
    inside = np.column_stack([x[400:], v[400:]])
    assert sliding_rows([inside], [t[400:]], [info], 1e-4)[0] == 0.0


def test_a_row_counts_once_the_probe_has_slid_one_way_for_the_settling_time():
    """Through a reversal the bench sticks and the filtered velocity still has the old sign: the
    rows within `settle_s` of a change of sign (or of a stop) are not fitted; an import
    (`settle_s` 0) keeps every sliding row."""
    from haptics_train.models.contact_rows import settled

    v = np.array([0.01, 0.01, 0.01, 0.01, -0.01, -0.01, -0.01, 0.0, 0.01, 0.01, 0.01])
    assert settled(v, 1e-4, 3).tolist() == [
        False, False, True, True, False, False, True, False, False, False, True]
    assert settled(v, 1e-4, 1).tolist() == (np.abs(v) > 1e-4).tolist()
    x = 0.005 * np.ones(400)
    v = np.r_[0.02 * np.ones(200), -0.02 * np.ones(200)]
    t = 5 + 0.9 * np.sign(v)
    xv = np.column_stack([x, v])

    def info(settle_s: float) -> SequenceInfo:
        return SequenceInfo(sample_rate_hz=1000.0, duration_s=0.4, stride=2, row_step=1,
                            contact_off_n=OFF, loop_rate_hz=1000.0, settle_s=settle_s)  # fmt: skip

    keep = sliding_rows([xv], [t], [info(0.1)], 1e-4)[1][0][3]
    # 200 rows thinned by 2: 100 each way, the first 50 of each (0.1 s) not counted
    assert keep.sum() == 2 * (100 - 49)
    assert not keep[100:149].any() and keep[149:].all()
    assert sliding_rows([xv], [t], [info(0.0)], 1e-4)[1][0][3].all()


def test_the_settling_time_is_three_time_constants_of_rt_loops_velocity_filter():
    from haptics_train.data import Recording, settle_s

    def rec(run: dict | None) -> Recording:
        return Recording("r", {"time": np.arange(3.0)}, {"haptics.run": run} if run else {})

    assert settle_s(rec({"config": {"params": {"g_v": 30.0}}})) == pytest.approx(0.1)
    assert settle_s(rec({"config": {"params": {"g_v": 60.0}}})) == pytest.approx(0.05)
    assert settle_s(rec(None)) == 0.0  # an import
    assert settle_s(rec({"filters": {"g_v": 30.0, "g_a": 100.0}})) == 0.0  # an import's filters
