"""Closed-loop evaluation: every feature that depends on the force is rebuilt from the
model's own previous predictions, exactly as rt-loop builds the features in reproduction.

rt-loop's `FeatureExtractor` (rt-loop/src/features.rs) works per control step t as
`begin(x, v, a)` -> features, then `commit(x, F)` with the step's force; in reproduction F is
the model's prediction. `FeatureTracker` below is its line-for-line Python twin:

- f_previous_x/v/a(t) = F(t-1) / x(t), v(t), a(t); on a divisor exactly 0 the ratio keeps
  its previous value; all three are 0 before the first committed force;
- cycle segmentation on the committed force with hysteresis (loaded above `contact_on_n`,
  a cycle ends on the step F falls below `contact_off_n`): then `area_fx` (trapezoid integral
  of F dx since the previous cycle end), `deformation` (x at that step) and `cycle_no` + 1;
- f_previous(t) = F(t-1) (train/'s better-conditioned extra feature, 0 before the first).

The kinematics (x, v, a) come from the recording. A recording made with rt-loop's
`--decimate k` has only every k-th control step; the closed loop then steps through the rows it
has, so "previous" is the previous *row* (k steps back), an approximation of the loop (record
with DECIMATE=1 for the exact closed loop). `tests/test_rt_loop_parity.py` checks that
the twin reproduces the columns rt-loop wrote when fed the recorded force.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

import numpy as np
import onnx
import onnxruntime as ort
from tqdm.auto import tqdm

from .data import Recording, contact_thresholds
from .features import F_PREVIOUS, FEEDBACK_FEATURES
from .ort_ops import session_options_for


class Stepper(Protocol):
    def reset(self) -> None: ...
    def step(self, row: np.ndarray) -> float: ...


class FunctionStepper:
    """A stateless model given as a function of one feature row (tests, baselines)."""

    def __init__(self, fn: Callable[[np.ndarray], float]) -> None:
        self.fn = fn

    def reset(self) -> None:
        pass

    def step(self, row: np.ndarray) -> float:
        return float(self.fn(row))


def session(model: onnx.ModelProto | bytes | str) -> ort.InferenceSession:
    opts = session_options_for(model)  # the fused operators registered (ort_ops.py)
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    data = model.SerializeToString() if isinstance(model, onnx.ModelProto) else model
    return ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])


class OnnxStepper:
    """Steps an exported model one control step at a time, as infer-server serves it."""

    def __init__(self, model: onnx.ModelProto | bytes | str) -> None:
        self.sess = session(model)
        meta = self.sess.get_modelmeta().custom_metadata_map
        self.stateful = meta.get("haptics.kind") == "stateful" or len(self.sess.get_inputs()) == 3
        n = self.sess.get_inputs()[0].shape[-1]
        self.x = np.zeros((1, int(n)), dtype=np.float32)
        if self.stateful:
            hshape = [int(d) for d in self.sess.get_inputs()[1].shape]
            self.h0 = np.zeros(hshape, dtype=np.float32)
        self.reset()

    def reset(self) -> None:
        if self.stateful:
            self.h = self.h0.copy()
            self.c = self.h0.copy()

    def step(self, row: np.ndarray) -> float:
        with np.errstate(over="ignore", invalid="ignore"):
            self.x[0, :] = row  # float64 -> float32; an overflow shows up as inf output
        if self.stateful:
            f, self.h, self.c = self.sess.run(
                None, {"features": self.x, "h_in": self.h, "c_in": self.c}
            )
            return float(f[0, 0])
        return float(self.sess.run(None, {"features": self.x})[0][0, 0])


class FeatureTracker:
    """Python twin of rt-loop's FeatureExtractor (see the module docstring)."""

    def __init__(self, contact_on_n: float = 0.5, contact_off_n: float = 0.25) -> None:
        if not contact_off_n < contact_on_n:
            raise ValueError("contact_off_n must be below contact_on_n")
        self.on, self.off = contact_on_n, contact_off_n
        self.prev_force = 0.0
        self.has_prev = False
        self.f_px = self.f_pv = self.f_pa = 0.0
        self.cycle_no = 1
        self.deformation = 0.0
        self.area = 0.0
        self.loaded = False
        self.area_acc = 0.0
        self.seg_x = 0.0
        self.seg_f = 0.0

    def begin(self, x: float, v: float, a: float) -> dict[str, float]:
        if self.has_prev:
            f = self.prev_force
            if x != 0.0:
                self.f_px = f / x
            if v != 0.0:
                self.f_pv = f / v
            if a != 0.0:
                self.f_pa = f / a
        return {
            "position_x": x,
            "velocity": v,
            "acceleration": a,
            "f_previous_x": self.f_px,
            "f_previous_v": self.f_pv,
            "f_previous_a": self.f_pa,
            "cycle_no": float(self.cycle_no),
            "deformation": self.deformation,
            "area_fx": self.area,
            F_PREVIOUS: self.prev_force if self.has_prev else 0.0,
        }

    def commit(self, x: float, force: float) -> None:
        f = force if math.isfinite(force) else 0.0
        if self.has_prev:
            self.area_acc += 0.5 * (f + self.seg_f) * (x - self.seg_x)
        if not self.loaded and f > self.on:
            self.loaded = True
        elif self.loaded and f < self.off:
            self.loaded = False
            self.area = self.area_acc
            self.deformation = x
            self.area_acc = 0.0
            self.cycle_no += 1
        self.seg_x = x
        self.seg_f = f
        self.prev_force = force
        self.has_prev = True


def replay_features(rec: Recording, force: np.ndarray) -> dict[str, np.ndarray]:
    """Every force-dependent feature recomputed open-loop from a force series (with the
    measured force this must reproduce the recorded columns)."""
    tr = FeatureTracker(*contact_thresholds(rec))
    x, v, a = rec.column("position_x"), rec.column("velocity"), rec.column("acceleration")
    names = [*FEEDBACK_FEATURES]
    out = {k: np.empty(len(x)) for k in names}
    for t in range(len(x)):
        row = tr.begin(float(x[t]), float(v[t]), float(a[t]))
        for k in names:
            out[k][t] = row[k]
        tr.commit(float(x[t]), float(force[t]))
    return out


def simulate(
    stepper: Stepper,
    rec: Recording,
    features: tuple[str, ...],
    progress: bool = False,
    desc: str = "closed loop",
) -> np.ndarray:
    """Predictions at every row, each feature rebuilt from the model's own past predictions."""
    rows = rec.matrix(features)
    n = len(rows)
    pred = np.empty(n)
    tr = FeatureTracker(*contact_thresholds(rec))
    x, v, a = rec.column("position_x"), rec.column("velocity"), rec.column("acceleration")
    fb = [(j, f) for j, f in enumerate(features) if f in FEEDBACK_FEATURES]
    stepper.reset()
    for t in tqdm(range(n), desc=desc, disable=not progress, mininterval=1.0, miniters=10000):
        xt = float(x[t])
        feats = tr.begin(xt, float(v[t]), float(a[t]))
        row = rows[t]
        for j, f in fb:
            row[j] = feats[f]
        p = stepper.step(row)
        pred[t] = p
        if not math.isfinite(p):
            # Diverged: the rest is undefined. NaN makes every metric say so (RMSE inf).
            pred[t:] = np.nan
            break
        tr.commit(xt, p)
    return pred
