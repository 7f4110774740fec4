#!/usr/bin/env python3
"""The floor of the free-run figure: how close ANY model of the object can come to the recorded
training target (the RFOB estimate) on a recording, when it knows the object's own force.

The free run scores a model's force plus its bench friction against the RFOB's estimate. The
estimate also holds the bench's friction, the observer's lag and noise, which no object model
reproduces exactly. So: the simulator's own object force (`F_object`, recorded beside every
step) plus the bench terms the models fit (Dahl friction states of x at 20, 100 and 500 um,
tanh(v / 1e-4), v, a constant), least squares on the scored recording itself (an optimistic
floor: fitted where it is scored). A model's free run cannot be expected below it, and the
ratio sd_poly2 / floor bounds what "N times better than sd_poly2" can reach on that recording.

Usage: scripts/free-run-floor.py DATASET_DIR [DATASET_DIR ...]   (each holding test_*.parquet)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from haptics_train import data as D
from haptics_train.data import TARGET_DEFAULT
from haptics_train.models.structured import dahl

FRICTION_LENGTHS_M = (2e-5, 1e-4, 5e-4)


def floor(rec: D.Recording) -> tuple[float, float]:
    """(RMSE of the target against F_object alone, against F_object + fitted bench terms), N."""
    y = rec.target(TARGET_DEFAULT)
    fo, x, v = (rec.columns[c] for c in ("F_object", "position_x", "velocity"))
    bench = [dahl(x, length) for length in FRICTION_LENGTHS_M]
    a = np.column_stack([fo, *bench, np.tanh(v / 1e-4), v, np.ones_like(v)])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    return float(np.sqrt(np.mean((y - fo) ** 2))), float(np.sqrt(np.mean((y - a @ coef) ** 2)))


def main(dirs: list[str]) -> int:
    if not dirs:
        print(__doc__, file=sys.stderr)
        return 2
    for d in dirs:
        for path in sorted(Path(d).glob("test_*.parquet")):
            rec = D.load_recording(path)
            if "F_object" not in rec.columns:
                print(f"{path}: no F_object column (recorded before it existed, or not simulated)")
                continue
            alone, fitted = floor(rec)
            print(f"{path}: target {TARGET_DEFAULT} vs F_object {alone:.3f} N; "
                  f"with fitted bench terms {fitted:.3f} N (the free-run floor)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
