"""The study's hand, fitted to the object: pressed no harder than the bench can render.

The study's hands press to fixed set-points (`protocol.STUDY_HAND`: 28, 31, 34 mm). A stiffer
object pushes back harder there: the Bouc-Wen pad's reference reaches 19 N, the poroelastic
gel's 15 N, where the motor renders at most 14.2 N (its current limit, 0.59 A, times the
nominal force constant). In reproduction the rendered object then gives way, the hand goes
deeper, every model (the oracle too) answers beyond `reproduction.max_force_n` and is rendered
at the limit: the study measures the motor, not the model (the Bouc-Wen oracle had 8,544
saturated steps and a felt error of 1.44 N, 58x the sponge's floor).

So before the study the reference is run with the standard hand, and while its peak force is
above `FORCE_HEADROOM` of the force the bench can render, every set-point of every hand
(headline, fast, ranking) is scaled by one factor, searched on the reference alone (a shadow
run: no model sees it). An object within the bench's range (the default sponge: 11.7 N) keeps
the standard hand. The factor, the peak and the limit go into the study's results and report.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..data import load_recording
from .processes import Tools, run_loop, write_config
from .protocol import StudyError

#: The share of the bench's renderable force the reference may reach: the rest is left for the
#: friction and inertia the rendering also has to overcome.
FORCE_HEADROOM = 0.9
#: Reference runs the search may take (each 0.1-0.5 s in lockstep).
MAX_TRIES = 8
#: The smallest factor: below it the presses would hardly enter the object.
MIN_FACTOR = 0.3


def scaled_hand(hand: dict[str, float], factor: float) -> dict[str, float]:
    """`hand` with its set-points (the first depth and the step between presses) times
    `factor`; stiffness, damping and timing unchanged."""
    return {**hand, "depth_m": hand["depth_m"] * factor,
            "depth_step_m": hand["depth_step_m"] * factor}  # fmt: skip


def renderable_force_n(config: dict) -> float:
    """The largest force the bench of a run's configuration (the recording's `haptics.run`
    `config`) renders: the loop's force limit (`reproduction.max_force_n`) or the motor's
    current limit times the nominal force constant (`params.current_limit`, `params.k_fn`),
    whichever is lower; NaN when the configuration says neither."""
    limits = []
    rep = config.get("reproduction")
    if isinstance(rep, dict) and _finite(rep.get("max_force_n")):
        limits.append(float(rep["max_force_n"]))
    p = config.get("params")
    if isinstance(p, dict) and _finite(p.get("current_limit")) and _finite(p.get("k_fn")):
        limits.append(float(p["current_limit"]) * float(p["k_fn"]))
    limits = [v for v in limits if v > 0]
    return min(limits) if limits else math.nan


def next_factor(factor: float, peak_n: float, target_n: float) -> float:
    """The next factor to try: the set-points scaled down by the square root of the force's
    excess (a stiffening object's force grows faster than its depth), 2 % more for margin."""
    return factor * math.sqrt(target_n / peak_n) * 0.98


def _finite(v: object) -> bool:
    return isinstance(v, int | float) and math.isfinite(v)


def fit_hand(
    tools: Tools,
    work: Path,
    hand: dict[str, float],
    seed: int,
    extra: list[str],
    clock: str,
    say: Callable[[str], None],
) -> dict:
    """The factor the study's hands are scaled by (1 when the object is within the bench's
    range), searched on shadow references: {"factor", "peak_n" (the reference's peak force at
    the standard set-points), "peak_scaled_n" (at the factor), "renderable_n", "target_n",
    "tries"}."""
    factor, tries, first_peak, peak, limit = 1.0, 0, math.nan, math.nan, math.nan
    while True:
        cfg = work / "hand_probe.toml"
        write_config(cfg, seed, scaled_hand(hand, factor), clock)
        out = work / "hand_probe.parquet"
        r = run_loop(tools, "hand probe", "reference",
                     ["--config", str(cfg), "--clock", clock, "--seed", str(seed),
                      "--experiment", "shadow", *extra], out)  # fmt: skip
        if not r.ok or "F_true" not in r.series:
            raise StudyError(f"the hand's probe (shadow) run failed: {r.note or r.stop}")
        tries += 1
        peak = float(np.nanmax(np.abs(r.series["F_true"])))
        if tries == 1:
            first_peak = peak
            run = load_recording(out).meta.get("haptics.run")
            config = run.get("config") if isinstance(run, dict) else None
            limit = renderable_force_n(config if isinstance(config, dict) else {})
        target = FORCE_HEADROOM * limit
        if not math.isfinite(target) or peak <= target:
            break
        if tries >= MAX_TRIES or factor <= MIN_FACTOR:
            say(
                f"hand: the reference still peaks at {peak:.2f} N (> {target:.2f} N) at "
                f"{factor:.3f}x the set-points after {tries} runs; the study goes on there"
            )
            break
        factor = max(MIN_FACTOR, next_factor(factor, peak, target))
    out.unlink(missing_ok=True)
    if factor < 1.0:
        say(
            f"hand: the reference peaked at {first_peak:.2f} N at the standard set-points, "
            f"above {FORCE_HEADROOM:.0%} of the {limit:.2f} N the bench renders; every hand's "
            f"set-points scaled by {factor:.3f} (peak {peak:.2f} N, {tries} reference runs)"
        )
    return {"factor": factor, "peak_n": first_peak, "peak_scaled_n": peak,
            "renderable_n": limit, "target_n": FORCE_HEADROOM * limit, "tries": tries}  # fmt: skip
