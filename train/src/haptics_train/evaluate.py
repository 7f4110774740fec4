"""One-step and closed-loop evaluation of a trained model on held-out recordings."""

from __future__ import annotations

import time

import numpy as np
import onnx

from .closed_loop import OnnxStepper, simulate
from .data import Recording
from .features import FEEDBACK_FEATURES
from .metrics import regression_metrics
from .models.base import ForceModel, TrainConfig


def needs_feedback(model: ForceModel) -> bool:
    return any(f in FEEDBACK_FEATURES for f in model.features)


def evaluate(
    model: ForceModel,
    onnx_model: onnx.ModelProto,
    rec: Recording,
    cfg: TrainConfig,
    closed_loop: bool = True,
) -> tuple[dict, dict[str, np.ndarray]]:
    """Metrics at every row of `rec`:

    - one-step: the framework model on the recorded features (the previous force is the
      measured one, as the thesis scored);
    - closed-loop: the exported ONNX model stepped through the recording as the server runs
      it, every force-dependent feature (ratios, f_previous, cycle features) rebuilt from its
      own predictions. A model without any such feature gets the same inputs either way, so
      its closed-loop result is its one-step result (`closed_loop_same_as_one_step`).
    """
    y = rec.target(cfg.target)
    t0 = time.perf_counter()
    one = model.predict_recording(rec)
    res: dict = {
        "recording": rec.name,
        "rows": int(len(y)),
        "row_step": rec.row_step,
        "one_step": regression_metrics(y, one),
        "one_step_seconds": round(time.perf_counter() - t0, 2),
    }
    preds = {"one_step": one}
    if closed_loop:
        if needs_feedback(model):
            t0 = time.perf_counter()
            cl = simulate(
                OnnxStepper(onnx_model), rec, model.features, progress=cfg.progress,
                desc=f"{model.name} closed loop",
            )  # fmt: skip
            res["closed_loop"] = regression_metrics(y, cl)
            res["closed_loop_seconds"] = round(time.perf_counter() - t0, 2)
            res["closed_loop_us_per_step"] = round(1e6 * res["closed_loop_seconds"] / len(y), 2)
            res["closed_loop_same_as_one_step"] = False
            preds["closed_loop"] = cl
        else:
            res["closed_loop"] = dict(res["one_step"])
            res["closed_loop_same_as_one_step"] = True
            preds["closed_loop"] = one
    return res, preds
