"""Misses near hot swaps, near control calls that swap nothing, and away from both:
`scripts/bench-loaded.sh`'s swap figures.

Why a control: on a shared two-core machine any control-plane call (a client process started,
a gRPC request served, the client woken) can delay a step, and the host's own bursts move a
ratio of a few dozen misses by several units between runs. A status call from the same kind of
client, made between the swaps, tells what the swap itself adds: `swap_over_control` near 1
means the misses near a swap are what any call costs on this host, not the swap.

Each step is "near" an event when it lies within `window` steps (50 ms at 10 kHz) of it; the
benchmark spaces the events so that no step is near both a swap and a control call.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def near_mask(n_steps: int, events: np.ndarray, window: int) -> np.ndarray:
    """True for the steps within `window` of any of `events` (step indices, any order)."""
    mark = np.zeros(n_steps + 1, dtype=np.int64)
    ev = np.asarray(events, dtype=np.int64)
    np.add.at(mark, np.clip(ev - window, 0, n_steps), 1)
    np.add.at(mark, np.clip(ev + window + 1, 0, n_steps), -1)
    return np.cumsum(mark)[:n_steps] > 0


def _ratio(a: float, b: float) -> float:
    if b > 0:
        return a / b
    return 0.0 if a == 0 else math.inf


def swap_windows(
    miss: np.ndarray,
    swaps: np.ndarray,
    controls: np.ndarray,
    *,
    window: int = 500,
    lead: int = 2000,
) -> dict[str, Any]:
    """Misses per step near swaps, near control calls and away from both.

    `miss`: one bool per recorded step; `swaps`, `controls`: the steps (indices into `miss`) at
    which each swap took effect and each control call was answered. Steps before the first
    event less `lead` are left out (the run's start, before any call). Ratios are of misses per
    step; a ratio over an empty denominator is inf (0 when its numerator is 0 too)."""
    miss = np.asarray(miss, dtype=bool)
    n = len(miss)
    swaps = np.asarray([s for s in swaps if 0 <= s < n], dtype=np.int64)
    controls = np.asarray([c for c in controls if 0 <= c < n], dtype=np.int64)
    every = np.concatenate([swaps, controls])
    first = max(0, int(every.min()) - lead) if len(every) else 0
    near_s = near_mask(n, swaps, window)[first:]
    near_c = near_mask(n, controls, window)[first:] & ~near_s
    away = ~near_s & ~near_c
    m = miss[first:]

    def rate(mask: np.ndarray) -> float:
        return float(m[mask].sum()) / max(1, int(mask.sum()))

    near_rate, control_rate, away_rate = rate(near_s), rate(near_c), rate(away)
    return {
        "miss_near": near_rate,
        "miss_control": control_rate,
        "miss_away": away_rate,
        "misses_near": int(m[near_s].sum()),
        "misses_control": int(m[near_c].sum()),
        "misses_away": int(m[away].sum()),
        "steps_near": int(near_s.sum()),
        "steps_control": int(near_c.sum()),
        "steps_away": int(away.sum()),
        "swap_miss_ratio": _ratio(near_rate, away_rate),
        "swap_control_ratio": _ratio(control_rate, away_rate),
        "swap_over_control": _ratio(near_rate, control_rate),
    }
