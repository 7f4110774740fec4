"""Which rows the models that fit the bench's friction beside the object (`structured`,
`lawfree`) learn from.

The recorded target (the RFOB estimate) is the object's force plus the bench's friction, which
opposes the motion: pressing, the target is the object plus the friction; releasing, the object
less it. A row counts where the probe slides (|v| above a threshold: when it sticks, the
friction is any value the force controller leaves, which kinematics cannot tell), and either
out of contact (x <= 0: the target is the friction alone, which is what tells it from the
object's hysteresis) or pressing the object: its force, the target less the friction in the
direction of motion, above the contact threshold.

Why the friction and not the target: with the target compared to the threshold, every release
was dropped while the object pushed less than the friction plus the threshold (on the sponge
bench, 0.9 + 0.25 N). That stretch of a release decides where the probe comes to rest (where the
object's force falls under the friction), so where the hand meets it on the next press; unfitted,
the rendered sponge rested the probe 0.3 mm further out than the real one and the hand felt
+0.4 N for 50 ms at each re-contact (docs/laws.md).

A row also counts only once the probe has slid one way for a while (`settled`: the
recording's `settle_s`, three time constants of rt-loop's velocity filter, 0.1 s by default).
Through a reversal the bench sticks, and the RFOB holds whatever friction the controller
leaves, while the recorded velocity, filtered, still has the sign of the motion before: the
friction the fit assumes (in the direction of that sign) is then wrong by up to twice its
size. Those rows taught `lawfree` a Bouc-Wen object 0.23 N off under a hand and `structured`
the sponge 0.08 N off; without them, 0.16 and 0.07 N (docs/laws.md, "Rows after a
reversal"). Imported tests (a load cell, no bench) have `settle_s` 0 and keep every row.
"""

from __future__ import annotations

import numpy as np

from ..data import SequenceInfo


def sliding_rows(
    seqs: list[np.ndarray], targets: list[np.ndarray], info: list[SequenceInfo], min_speed: float
) -> tuple[float, list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]]]:
    """Each recording thinned to every `stride`-th row, once, for both steps: the friction
    the free air shows over all of them ([`free_air_friction`]), then each recording's
    (x, v, target, rows to fit ([`fitted_rows`]), stride)."""
    thin = []
    for xv, yy, i in zip(seqs, targets, info, strict=True):
        k = max(1, i.stride)
        # the settling time in the thinned rows (at least one: the row itself)
        n = max(1, round(i.settle_s * i.sample_rate_hz / k))
        thin.append((xv[::k, 0], xv[::k, 1], yy[::k], i.contact_off_n, k, n))
    friction = free_air_friction([(x, v, t) for x, v, t, *_ in thin], min_speed)
    return friction, [(x, v, t, fitted_rows(x, v, t, off, friction, min_speed, n), k)
                      for x, v, t, off, k, n in thin]  # fmt: skip


def free_air_friction(
    rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]], min_speed: float
) -> float:
    """The bench's friction as the free air shows it: the median |target| over the rows
    (x, v, target) where the probe slides out of contact, x <= 0 and |v| > `min_speed`; there
    the target is the friction alone. 0 when no recording has such a row (a testing
    machine's): the rule of [`fitted_rows`] is then the target's own."""
    air = [np.abs(t[(x <= 0) & (np.abs(v) > min_speed)]) for x, v, t in rows]
    pooled = np.concatenate(air) if air else np.empty(0)
    return float(np.median(pooled)) if len(pooled) else 0.0


def fitted_rows(
    x: np.ndarray, v: np.ndarray, t: np.ndarray, contact_off_n: float, friction_n: float,
    min_speed: float, settle_rows: int = 1,
) -> np.ndarray:  # fmt: skip
    """The rows to fit (module docstring): sliding one way for the last `settle_rows` rows
    ([`settled`]; 1: sliding), and out of contact or with the object's force,
    `t - friction_n sign(v)`, above `contact_off_n`."""
    slide = settled(v, min_speed, settle_rows)
    return slide & ((x <= 0) | (t - friction_n * np.sign(v) > contact_off_n))


def settled(v: np.ndarray, min_speed: float, rows: int) -> np.ndarray:
    """The rows where the probe has slid one way (|v| above `min_speed`, one sign) for the
    last `rows` rows, this one included (module docstring)."""
    s = np.sign(v) * (np.abs(v) > min_speed)
    i = np.arange(len(s))
    # where each run of one sign starts: a row that differs from the one before
    start = np.maximum.accumulate(np.where(np.r_[True, s[1:] != s[:-1]], i, 0))
    return (s != 0) & (i - start + 1 >= rows)
