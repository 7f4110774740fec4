"""scripts/swap-windows.py: misses near swaps, near control calls and away, as
`scripts/bench-loaded.sh` reports them."""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np
from conftest import script_module


def _module() -> ModuleType:
    return script_module("swap-windows.py")


# 100 cycles of 3 300 steps: a swap at 1 000, a control call at 2 650 (no window overlaps)
N = 330_000
SWAPS = np.arange(100) * 3300 + 1000
CONTROLS = np.arange(100) * 3300 + 2650


def test_near_mask_marks_the_window_either_side() -> None:
    m = _module().near_mask(20, np.array([5, 18]), 2)
    assert np.flatnonzero(m).tolist() == [3, 4, 5, 6, 7, 16, 17, 18, 19]


def test_misses_at_the_swaps_only() -> None:
    miss = np.zeros(N, dtype=bool)
    miss[SWAPS + 10] = True  # one miss 1 ms after every swap
    miss[SWAPS[::20] + 800] = True  # a few away from both (1.8 ms into a cycle): the denominator
    f = _module().swap_windows(miss, SWAPS, CONTROLS, window=500, lead=500)
    assert f["misses_near"] == 100
    assert f["misses_control"] == 0
    assert f["misses_away"] > 0
    assert f["swap_miss_ratio"] > 10
    assert f["swap_control_ratio"] == 0.0
    assert f["swap_over_control"] == math.inf


def test_misses_at_every_call_alike_give_a_ratio_of_one() -> None:
    miss = np.zeros(N, dtype=bool)
    miss[SWAPS + 10] = True
    miss[CONTROLS - 10] = True
    miss[SWAPS[::20] + 800] = True
    f = _module().swap_windows(miss, SWAPS, CONTROLS, window=500, lead=500)
    assert f["swap_over_control"] == 1.0
    assert f["swap_miss_ratio"] == f["swap_control_ratio"] > 10


def test_steps_before_the_lead_are_left_out_and_counts_add_up() -> None:
    miss = np.zeros(N, dtype=bool)
    miss[:300] = True  # the run's start, before the first event less the lead
    f = _module().swap_windows(miss, SWAPS, CONTROLS, window=500, lead=500)
    assert f["misses_near"] + f["misses_control"] + f["misses_away"] == 0
    assert f["steps_near"] + f["steps_control"] + f["steps_away"] == N - (1000 - 500)
    assert f["steps_near"] == 100 * 1001
    assert f["steps_control"] == 100 * 1001
    assert f["swap_miss_ratio"] == 0.0


def test_events_outside_the_recording_are_ignored() -> None:
    miss = np.zeros(1000, dtype=bool)
    miss[500] = True
    f = _module().swap_windows(miss, np.array([500, 5000, -3]), np.array([]), window=10, lead=1000)
    assert f["steps_near"] == 21
    assert f["misses_near"] == 1
    assert f["swap_miss_ratio"] == math.inf
