"""A tiny fake sponge bench for tests and demos (numpy only, no rt-loop needed).

It is *not* the project's sponge simulation (that lives in rt-loop); it only produces
recordings with every column of docs/recording-format.md, with the same feature definitions
(pseudo-derivative velocity/acceleration, and the force-dependent features through
`closed_loop.FeatureTracker`, the twin of rt-loop's extractor), a nonlinear, rate-dependent,
hysteretic force and noise, so that the pipeline has something real to learn.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from .closed_loop import replay_features
from .data import recording_from_columns
from .features import NINE

DT = 1e-4  # 10 kHz


def _schedule(ramp_rate: float, cycles: int, depth_per_cycle: float, hold: float) -> tuple:
    """Prescribed compression: per cycle hold at rest, ramp in, hold, ramp out."""
    xs, phases, cyc = [], [], []
    rest = 0.0
    speed = ramp_rate * 1.5e-2  # m/s: faster ramps press faster (short test runs)
    for c in range(1, cycles + 1):
        top = depth_per_cycle * c
        n_hold = int(hold / DT)
        n_ramp = max(int((top - rest) / speed / DT), 2)
        segs = [
            (np.full(n_hold, rest), 0),
            (np.linspace(rest, top, n_ramp), 1),
            (np.full(n_hold, top), 2),
            (np.linspace(top, rest, n_ramp), 3),
        ]
        for seg, ph in segs:
            xs.append(seg)
            phases.append(np.full(len(seg), ph))
            cyc.append(np.full(len(seg), c))
        rest += 0.04 * top * 0.2  # permanent set grows with the largest compression
    xs.append(np.full(int(hold / DT), rest))
    phases.append(np.full(int(hold / DT), 6))
    cyc.append(np.full(int(hold / DT), cycles))
    return np.concatenate(xs), np.concatenate(phases), np.concatenate(cyc)


def make_recording_columns(
    ramp_rate: float = 2.0,
    cycles: int = 3,
    seed: int = 0,
    depth_per_cycle: float = 0.006,
    hold: float = 0.05,
    noise: float = 0.02,
) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    x_cmd, phase, cycle = _schedule(ramp_rate, cycles, depth_per_cycle, hold)
    n = len(x_cmd)
    counts = np.round(x_cmd / 5e-6).astype(np.int64)
    x = counts * 5e-6
    time = np.arange(n) * DT
    v = np.zeros(n)
    a = np.zeros(n)
    f_true = np.zeros(n)
    f_res = np.zeros(n)
    v_int = a_int = 0.0
    vv = aa = 0.0
    z = 0.0  # relaxation state (viscoelastic element)
    lp = 0.0  # observer low-pass
    for t in range(n):
        v_int += vv * DT
        vv = 30.0 * (x[t] - v_int)
        a_int += aa * DT
        aa = 100.0 * (vv - a_int)
        v[t], a[t] = vv, aa
        xt = max(x_cmd[t], 0.0)
        z += (xt - z) / 0.5 * DT
        elastic = 150.0 * xt + 4.0e5 * xt**3
        visco = 200.0 * (xt - z)
        f = max(elastic + visco + 30.0 * vv * (xt > 0), 0.0)
        f_true[t] = f
        lp += 300.0 * (f - lp) * DT
        f_res[t] = lp + noise * rng.standard_normal()
    # The force-dependent features by the same rules as rt-loop's FeatureExtractor.
    feats = replay_features(
        recording_from_columns("synthetic", {
            "time": time, "rtob_force": f_res, "position_x": x, "velocity": v,
            "acceleration": a, **{k: np.zeros(n) for k in NINE[3:]},
        }),
        f_res,
    )  # fmt: skip
    f_ref = np.where(phase == 6, 0.0, f_true)
    i_ref = np.clip(f_ref / 24.0, -0.7, 0.7)
    i_motor = np.clip(i_ref, -0.59, 0.59)
    return {
        "step": np.arange(n, dtype=np.uint64),
        "timestamp": (np.round(time * 1e6).astype(np.int64) % (1 << 32)).astype(np.uint32),
        "time": time,
        "dt": np.full(n, DT),
        "F_ref": f_ref,
        "rtob_force": f_res,
        "dob_force": 0.1 * rng.standard_normal(n),
        "counts": counts.astype(np.int32),
        "position_x": x,
        "velocity": v,
        "acceleration": a,
        "I_a_ref": i_ref,
        "I_motor": i_motor,
        "analog_out_motor": np.clip(32768 + i_motor / 0.6 * 32767, 0, 65535).astype(np.uint16),
        "phase": phase.astype(np.uint8),
        "F_true": f_true,
        "F_pred": np.full(n, np.nan),
        "fallback": np.zeros(n, dtype=bool),
        "cycle_no": feats["cycle_no"].astype(np.uint32),
        "f_previous_x": feats["f_previous_x"],
        "f_previous_v": feats["f_previous_v"],
        "f_previous_a": feats["f_previous_a"],
        "deformation": feats["deformation"],
        "area_fx": feats["area_fx"],
        # no hand: the felt force is the object's own
        "F_object": f_true,
    }


def write_recording(path: str | Path, ramp_rate: float = 2.0, **kw: object) -> Path:
    path = Path(path)
    cols = make_recording_columns(ramp_rate=ramp_rate, **kw)  # type: ignore[arg-type]
    table = pa.table(cols)
    run = {"experiment": "abstraction", "board": "synthetic-test-sponge", "ramp_rate": ramp_rate}
    table = table.replace_schema_metadata({"haptics.run": json.dumps(run)})
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path)
    return path


def write_dataset(
    root: str | Path,
    train_rates: tuple[float, ...] = (0.8, 1.8, 3.9, 6.2),
    test_rate: float = 2.1,
    validation_rate: float | None = None,
    **kw: object,
) -> Path:
    """`train_<rate>`, `test_<rate>` and, when `validation_rate` is given, `validation_<rate>`."""
    root = Path(root)
    for i, r in enumerate(train_rates):
        write_recording(root / f"train_{r}.parquet", ramp_rate=r, seed=i, **kw)
    if validation_rate is not None:
        write_recording(root / f"validation_{validation_rate}.parquet", ramp_rate=validation_rate,
                        seed=98, **kw)  # fmt: skip
    write_recording(root / f"test_{test_rate}.parquet", ramp_rate=test_rate, seed=99, **kw)
    return root
