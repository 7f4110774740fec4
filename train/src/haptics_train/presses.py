"""Press-and-hold presses at a hand's speeds: the position programme of the dataset's
`train_hold` and `validation_hold` recordings (`PRESSES=1 scripts/record-dataset.sh` replays
one of each seed with rt-loop's position controller, `--experiment position-replay`).

Why: the thesis's recordings are force-controlled ramps of 0.8-6.2 N/s that turn round at
their peak. A hand presses at 10-100 mm/s and holds, and what it feels there (the fast
relaxation, the creep and compression set of a hold, the release after one) is what the ramps
show least: a model chosen and trained on ramps alone renders those parts from extrapolation
(docs/laws.md, "Presses and holds at a hand's speeds in training"). The motor drives these
presses, so the RFOB reads the object's force plus the bench's friction, as in every other
training recording (a hand's own presses cannot be a target: the RFOB would read the hand).

Nothing here is a material's number. Depths are fractions of the deepest compression of the
dataset's ramps (`ramp_depth_m`), so the same programme suits a 5 mm gel and a 40 mm foam;
the speeds span a hand's (a slow, a firm and a quick press); the holds and rests are drawn
from ranges long enough to show relaxation and recovery over seconds, the time scale of a
hand's hold, without a model learning one fixed duration.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

#: Press depths as fractions of the ramps' deepest compression: shallow to nearly as deep.
DEPTH_FRACTIONS = (0.25, 0.45, 0.65, 0.8, 0.95)
#: Peak press and release speeds, m/s (a cosine profile: the mean is 2/pi of the peak).
SPEEDS_MPS = (0.01, 0.04, 0.08)
#: Hold at depth and rest off the object, s: drawn uniformly in these ranges.
HOLD_S = (1.5, 3.5)
REST_S = (1.0, 2.5)
#: Where the probe waits between presses, m: just off the surface (x = 0 is first contact).
CLEAR_M = -0.001
#: The programme's time step, s (rt-loop interpolates between the rows at its own rate).
STEP_S = 1e-3
#: The seed of the presses' order and holds (record-dataset.sh validates on another).
DEFAULT_SEED = 5
#: The training recordings that are not force ramps, so never the depth scale.
NOT_RAMPS = ("train_air", "train_hold")


def press_hold_trajectory(
    depth_m: float, seed: int = DEFAULT_SEED, step_s: float = STEP_S
) -> tuple[np.ndarray, np.ndarray]:
    """(time s, position m) of the programme: every depth fraction at every speed once, in an
    order drawn by `seed`; each a press with a cosine speed profile, a hold, a release to
    `CLEAR_M` at the same speed and a rest. `depth_m` is the ramps' deepest compression."""
    if not (np.isfinite(depth_m) and depth_m > 0.0):
        raise ValueError(f"the ramps' depth must be a positive length in m, got {depth_m}")
    if depth_m > 0.2:
        raise ValueError(f"a ramp depth of {depth_m} m is not a compression in m (a unit error?)")
    rng = np.random.default_rng(seed)
    plan = [(f * depth_m, s) for f in DEPTH_FRACTIONS for s in SPEEDS_MPS]
    order = rng.permutation(len(plan))
    pieces = [np.full(int(0.5 / step_s), CLEAR_M)]

    def move(start: float, end: float, speed: float) -> np.ndarray:
        n = max(int(np.pi / 2 * abs(end - start) / speed / step_s), 2)
        k = np.arange(1, n + 1) / n
        path = start + (end - start) * (0.5 - 0.5 * np.cos(np.pi * k))
        path[-1] = end  # exactly: the hold that follows is at this depth
        return path

    for i in order:
        depth, speed = plan[i]
        pieces.append(move(CLEAR_M, depth, speed))
        pieces.append(np.full(int(rng.uniform(*HOLD_S) / step_s), depth))
        pieces.append(move(depth, CLEAR_M, speed))
        pieces.append(np.full(int(rng.uniform(*REST_S) / step_s), CLEAR_M))
    x = np.concatenate(pieces)
    return np.arange(len(x)) * step_s, x


def ramp_depth_m(dataset: Path) -> float:
    """The deepest compression of the dataset's force ramps (`train_*.parquet` but
    `NOT_RAMPS`): the largest `position_x`."""
    files = [p for p in sorted(Path(dataset).glob("train_*.parquet")) if p.stem not in NOT_RAMPS]
    if not files:
        raise FileNotFoundError(f"{dataset}: no train_*.parquet ramp recording to scale by")
    deepest = max(float(pq.read_table(p, columns=["position_x"]).column(0).to_numpy().max())
                  for p in files)  # fmt: skip
    if not deepest > 0.0:
        raise ValueError(f"{dataset}: the ramps never pressed the object (largest x {deepest})")
    return deepest


def write_trajectory(dataset: Path, out: Path, seed: int = DEFAULT_SEED) -> tuple[float, float]:
    """Writes the programme for `dataset`'s ramps to `out` (columns time, position_x: what
    `rt-loop run --trajectory` reads). Returns (depth scale m, duration s)."""
    depth = ramp_depth_m(dataset)
    t, x = press_hold_trajectory(depth, seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.table({"time": t, "position_x": x}), out)
    return depth, float(t[-1])
