"""DAgger for the feedback networks: train on the states the model itself visits in free run.

Feedback noise (`models/networks.py`) perturbs the measured previous force with i.i.d. errors;
in reproduction the errors the model meets are its own, correlated over seconds. Dataset
aggregation (Ross, Gordon & Bagnell 2011) closes that gap: fit as usual, roll the model out in
free run on every training recording (its own previous force fed back, `closed_loop.simulate`,
exactly as rt-loop serves it), keep the decimated rows it visited with the force it fed back
as F(t-1) but the *recorded* force as the target, add them to the training rows and refit;
repeat. The round kept is the one with the lowest free-run RMSE on the validation recordings
(round 0 is the plain fit, so DAgger can only be chosen when it helps there); the test
recordings take no part. Only stateless row models whose sole feedback is the previous force
(`dnn_fb`/`dnn` on `six`, `xva_f`) qualify: their closed-loop state is that one number.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Sequence

import numpy as np

from .closed_loop import OnnxStepper, simulate
from .data import Recording, row_stride, training_arrays
from .features import (
    F_PREVIOUS,
    FEEDBACK_FEATURES,
    KINEMATICS,
    PREVIOUS_FORCE_FEATURES,
    RATIO_DIVISORS,
)
from .models.base import ForceModel, TrainConfig


def check_dagger(model: ForceModel) -> None:
    """Refuses a model DAgger cannot roll out row by row (stateful, or cycle feedback)."""
    if model.layout != "rows" or not model.aux_columns:
        raise ValueError(f"{model.name}: DAgger needs a stateless feedback network (dnn_fb)")
    other = [f for f in model.features if f in FEEDBACK_FEATURES
             and f not in PREVIOUS_FORCE_FEATURES]  # fmt: skip
    if other or not any(f in PREVIOUS_FORCE_FEATURES for f in model.features):
        raise ValueError(f"{model.name}: DAgger needs the previous force as the only fed-back "
                         f"feature (found {other or 'none'})")  # fmt: skip


def visited_rows(
    model: ForceModel, rec: Recording, rollout: np.ndarray, target: str, stride: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X, y, aux) of every `stride`-th row of `rec` as the free run `rollout` visited it:
    F(t-1) = the rollout's previous force, the ratios recomputed from it (held at the recorded
    value where the divisor is 0, as feedback noise does), the target the recorded force.
    Rows after a divergence (non-finite rollout) are dropped."""
    cols = (*model.features, *model.aux_columns)
    xa = rec.matrix(cols, stride)
    y = rec.target(target, stride)
    prev = np.concatenate([[0.0], rollout[:-1]])[::stride][: len(y)]
    nf = len(model.features)
    x, aux = xa[:, :nf].copy(), xa[:, nf:].copy()
    aux[:, 0] = prev
    for j, f in enumerate(model.features):
        if f == F_PREVIOUS:
            x[:, j] = prev
        elif f in RATIO_DIVISORS:
            d = aux[:, 1 + KINEMATICS.index(RATIO_DIVISORS[f])]
            with np.errstate(divide="ignore", invalid="ignore"):
                x[:, j] = np.where(d != 0, prev / np.where(d != 0, d, 1.0), x[:, j])
    ok = np.isfinite(x).all(axis=1) & np.isfinite(y) & np.isfinite(aux).all(axis=1)
    return x[ok], y[ok], aux[ok]


def rollout(model: ForceModel, rec: Recording, progress: bool = False) -> np.ndarray:
    """The model's free run on `rec`, stepped through its ONNX graph as infer-server would."""
    return simulate(OnnxStepper(model.to_onnx()), rec, model.features, progress,
                    desc=f"{model.name} rollout {rec.name}")  # fmt: skip


def fit_dagger(
    model: ForceModel,
    recs: Sequence[Recording],
    cfg: TrainConfig,
    rounds: int,
    score: Callable[[ForceModel], float],
    metric: str = "free-run RMSE, pooled over the validation recordings",
) -> ForceModel:
    """`model` (fitted on `recs`) refined by `rounds` DAgger rounds; returns the round with the
    lowest `score` (the validation free-run RMSE; `metric` says which rows), its history in
    `train_info_["dagger"]`."""
    check_dagger(model)
    if rounds < 1:
        return model
    t0 = time.perf_counter()
    X, y, params = training_arrays(recs, model.features, model.layout, model.aux_columns,
                                   cfg.target, cfg.decimate, cfg.target_rate_hz)  # fmt: skip
    aux = params["aux"]
    assert isinstance(X, np.ndarray) and isinstance(y, np.ndarray) and isinstance(aux, np.ndarray)
    base_rows = len(y)
    current = model
    history = [{"round": 0, "rows": base_rows, "validation_free_run_rmse": score(model)}]
    best = (history[0]["validation_free_run_rmse"], 0, model)
    for r in range(1, rounds + 1):
        added = [visited_rows(current, rec, rollout(current, rec, cfg.progress), cfg.target,
                              row_stride(rec, cfg.decimate, cfg.target_rate_hz))
                 for rec in recs]  # fmt: skip
        X = np.concatenate([X, *(a[0] for a in added)])
        y = np.concatenate([y, *(a[1] for a in added)])
        aux = np.concatenate([aux, *(a[2] for a in added)])
        nxt = copy.deepcopy(model)  # same hyperparameters and seed, refitted from scratch
        nxt.fit(X, y, aux=aux)
        v = score(nxt)
        history.append({"round": r, "rows": int(len(y)), "validation_free_run_rmse": v})
        print(f"[dagger] {model.name} round {r}: {len(y)} rows, validation free-run RMSE "
              f"{v:.4g} N", flush=True)  # fmt: skip
        if np.isfinite(v) and (not np.isfinite(best[0]) or v < best[0]):
            best = (v, r, nxt)
        current = nxt
    chosen = best[2]
    # the refit's own figures, beside what the plain fit recorded (e.g. the noise selection)
    chosen.train_info_ = {**model.train_info_, **chosen.train_info_}
    chosen.train_info_["dagger"] = {
        "rounds": rounds,
        "chosen_round": best[1],
        "metric": metric,
        "history": history,
        "seconds": round(time.perf_counter() - t0, 1),
    }
    return chosen
