#!/usr/bin/env python3
"""How far a served model's prediction is from the object's own force (F_object) and from the
felt force (F_true) on a hand run: the comparison the page and the study make.

Runs `rt-loop run --experiment shadow` (the simulated hand pressing the simulated object
through the transparent motor) with `infer-server serve --model MODEL` beside it, then prints
the RMSE of F_pred against F_object and against F_true over the whole run and over the hand
programme's holds, rests and moves (the programme's own windows: rt-loop's `[hand]` schedule).

Usage: scripts/object-force-gap.py [--model models/structured.onnx] [--hand study|default]
                                   [--seed 1] [--material materials/sponge.toml] [--json OUT]
Needs target/release/rt-loop and target/release/infer-server (cargo build --release).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "train" / "src"))

from haptics_train.study import STUDY_HAND, find_tools, run_loop, write_config  # noqa: E402

#: rt-loop's HandConfig::default (rt-loop/src/experiment/hand.rs): the page's shadow runs use it
DEFAULT_HAND = {"stiffness": 1500.0, "damping": 15.0, "depth_m": 0.030, "press_s": 1.5,
                "hold_s": 1.0, "release_s": 1.5, "rest_s": 1.0, "repeats": 3,
                "depth_step_m": 0.002}  # fmt: skip


def windows(t: np.ndarray, hand: dict[str, float]) -> dict[str, np.ndarray]:
    """Masks of the hand programme's phases at times `t` (as HandConfig::setpoint)."""
    period = hand["press_s"] + hand["hold_s"] + hand["release_s"] + hand["rest_s"]
    u = t - hand["rest_s"]
    inside = (u >= 0) & (u < period * hand["repeats"])
    tc = np.where(inside, u - np.floor(u / period) * period, -1.0)
    press, hold = hand["press_s"], hand["press_s"] + hand["hold_s"]
    release = hold + hand["release_s"]
    return {
        "all": np.ones_like(t, dtype=bool),
        "holds": inside & (tc >= press) & (tc < hold),
        "rests": ~inside | (tc >= release),
        "moves": inside & (tc < press) | inside & (tc >= hold) & (tc < release),
    }


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.sqrt(np.mean((a[ok] - b[ok]) ** 2))) if ok.any() else math.nan


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="models/structured.onnx")
    ap.add_argument("--hand", choices=("study", "default"), default="study")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--material", default="materials/sponge.toml")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    hand = STUDY_HAND if a.hand == "study" else DEFAULT_HAND
    tools = find_tools(ROOT, None, None)
    with tempfile.TemporaryDirectory() as work:
        cfg = Path(work) / "hand.toml"
        write_config(cfg, a.seed, hand)
        model = Path(a.model).resolve()
        run = run_loop(
            tools, model.stem, "shadow",
            ["--config", str(cfg), "--clock", "lockstep", "--seed", str(a.seed),
             "--material", a.material, "--experiment", "shadow"],
            Path(work) / "shadow.parquet", server_model=model,
            instance=f"gap-{os.getpid()}",
        )  # fmt: skip
        if not run.ok or "F_object" not in run.series:
            print(f"the shadow run failed or has no F_object: {run.note or run.stop}")
            return 1
    s = run.series
    doc = {"model": model.stem, "hand": a.hand, "seed": a.seed, "material": a.material,
           "steps": run.steps, "served": run.served, "fallbacks": run.fallbacks,
           "segments": {}}  # fmt: skip
    print(f"{model.stem} on a {a.hand} hand run ({run.steps} steps, {run.served} served, "
          f"{run.fallbacks} fallbacks), F_pred RMSE in N:")
    heads = ("segment", "rows", "vs F_object", "vs F_true", "F_true-F_object")
    print("{:>8} {:>7} {:>12} {:>10} {:>16}".format(*heads))
    for name, m in windows(s["time"], hand).items():
        row = {"rows": int(m.sum()),
               "vs_object_rmse_n": rmse(s["F_pred"][m], s["F_object"][m]),
               "vs_true_rmse_n": rmse(s["F_pred"][m], s["F_true"][m]),
               "true_minus_object_rmse_n": rmse(s["F_true"][m], s["F_object"][m])}  # fmt: skip
        doc["segments"][name] = row
        print(f"{name:>8} {row['rows']:>7} {row['vs_object_rmse_n']:>12.3f} "
              f"{row['vs_true_rmse_n']:>10.3f} {row['true_minus_object_rmse_n']:>16.3f}")
    if a.json:
        a.json.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
