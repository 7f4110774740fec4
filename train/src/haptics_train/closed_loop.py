"""Closed-loop evaluation: the previous force inside the features is the model's own
previous prediction, exactly as rt-loop builds the features in reproduction.

At every control step t (every row of the loop-rate recording, in order):
  f_previous_x(t) = F_pred(t-1) / x(t)   (likewise / v(t), / a(t)); on a zero divisor the
                                          ratio keeps its previous (closed-loop) value
  f_previous(t)   = F_pred(t-1)
The kinematic and per-cycle features come from the recording. Step 0 uses the recorded
features as they are (there is no previous prediction yet).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np
import onnx
import onnxruntime as ort
from tqdm.auto import tqdm

from .data import Recording
from .features import F_PREVIOUS, RATIO_DIVISORS


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
    opts = ort.SessionOptions()
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


def previous_force_features(
    rec: Recording, features: tuple[str, ...], force: np.ndarray
) -> np.ndarray:
    """The previous-force features recomputed from a force series (vectorised, open loop).

    With the measured force this must reproduce the recorded columns: a check that train/
    and rt-loop agree on the definitions.
    """
    x = rec.matrix(features).copy()
    prev = np.empty_like(force)
    prev[0] = np.nan
    prev[1:] = force[:-1]
    for j, f in enumerate(features):
        if f == F_PREVIOUS:
            x[1:, j] = prev[1:]
        elif f in RATIO_DIVISORS:
            d = rec.column(RATIO_DIVISORS[f])
            with np.errstate(divide="ignore", invalid="ignore"):
                r = np.where(d != 0, prev / d, np.nan)
            r[0] = x[0, j]
            # hold-last-value on zero divisors: forward fill
            idx = np.where(np.isnan(r), 0, np.arange(len(r)))
            np.maximum.accumulate(idx, out=idx)
            x[:, j] = r[idx]
    return x


def simulate(
    stepper: Stepper,
    rec: Recording,
    features: tuple[str, ...],
    progress: bool = False,
    desc: str = "closed loop",
) -> np.ndarray:
    """Predictions at every row with the previous force fed back from the model itself."""
    x = rec.matrix(features)
    n = len(x)
    pred = np.empty(n)
    ratio = [
        (j, rec.column(RATIO_DIVISORS[f])) for j, f in enumerate(features) if f in RATIO_DIVISORS
    ]
    direct = [j for j, f in enumerate(features) if f == F_PREVIOUS]
    stepper.reset()
    row = x[0].copy()
    held = {j: float(row[j]) for j, _ in ratio}
    pred[0] = stepper.step(row)
    for t in tqdm(range(1, n), desc=desc, disable=not progress, mininterval=1.0, miniters=10000):
        row = x[t].copy()
        fp = pred[t - 1]
        for j, d in ratio:
            dt = d[t]
            if dt != 0.0:
                held[j] = fp / dt
            row[j] = held[j]
        for j in direct:
            row[j] = fp
        pred[t] = stepper.step(row)
        if not np.isfinite(pred[t]):
            # Diverged: the rest is undefined. NaN makes every metric say so (RMSE inf).
            pred[t:] = np.nan
            break
    return pred
