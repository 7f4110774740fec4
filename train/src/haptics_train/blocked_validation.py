"""Validation without a validation recording: contiguous blocks of the training recordings
held out in turn.

A dataset imported from a testing machine often has a few tests and none set aside to
validate on (the README's example: one test to train on, one to test). `lawfree`'s choices
(readout, ridge, memory span) were then left at their defaults, the least shrinkage and the
longest memory of its grid: on one 42 s loading-unloading cycle that is 66 weights fitted to
0.002 N, and a free run 1.9x further off on the test at another rate than the spring-damper's
(docs/train.md, "Choices without a validation recording").

Here each training recording is cut into `HOLDOUT_BLOCKS` contiguous blocks of rows; for
block b, the model is fitted without block b of every recording and scored on it. A block is
contiguous because neighbouring rows of a force series are nearly copies of each other: rows
held out at random would be scored against their own neighbours. The memory runs along every
row during the fit and the scoring, so a held-out block keeps the history that leads into it.
Scored as validation recordings are (`pipeline.validation_free_run_scores`): the free run's
RMSE pooled over the held-out rows where the probe is pressed and slides
(`evaluate.sliding_rows`) and over every held-out row.

Only for a model whose free run is its one-step prediction (kinematics in, force out: no
feature made from its own force) and whose `fit` takes `holdout`: `lawfree`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .data import Dataset, training_arrays
from .evaluate import sliding_rows
from .models import ForceModel, TrainConfig, predict_at

#: Blocks each training recording is cut into. Five: each fit keeps four fifths of every
#: recording, and each held-out block is long enough to hold a loading or an unloading.
HOLDOUT_BLOCKS = 5

#: What `train_info_["selection"]["validation"]` says where the blocks stood in for
#: validation recordings.
BLOCKED_VALIDATION = (
    f"no validation recording: {HOLDOUT_BLOCKS} contiguous blocks of every training recording, "
    "each held out in turn"
)


def blocks(n: int, k: int = HOLDOUT_BLOCKS) -> list[np.ndarray]:
    """`k` boolean masks of `n` rows, each one contiguous block, together every row once."""
    edges = np.linspace(0, n, k + 1).round().astype(int)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m = np.zeros(n, dtype=bool)
        m[lo:hi] = True
        out.append(m)
    return out


def blocked_scores(
    make: Callable[[], ForceModel], dataset: Dataset, cfg: TrainConfig
) -> tuple[float, float]:
    """(RMSE over the held-out rows where the probe slides, RMSE over every held-out row),
    pooled over the `HOLDOUT_BLOCKS` folds and the training recordings; `make` returns an
    unfitted model with its hyper-parameters set. NaN where a fold's fit fails."""
    if not dataset.train:
        raise ValueError("blocked validation needs training recordings")
    probe = make()
    X, y, params = training_arrays(dataset.train, probe.features, probe.layout,
                                   probe.aux_columns, cfg.target, cfg.decimate,
                                   cfg.target_rate_hz)  # fmt: skip
    if probe.layout != "sequences":
        raise ValueError(f"{probe.name}: blocked validation needs a sequence model")
    masks = [blocks(len(x)) for x in X]
    sliding = [sliding_rows(r) for r in dataset.train]
    sq_slide: list[np.ndarray] = []
    sq_every: list[np.ndarray] = []
    for b in range(HOLDOUT_BLOCKS):
        holdout = [m[b] for m in masks]
        model = make()
        model.set_params(seed=cfg.seed, progress=False)
        try:
            model.fit(X, y, **params, holdout=holdout)
        except (ValueError, FloatingPointError):
            return float("nan"), float("nan")
        for x, yy, out, slide, rec in zip(X, y, holdout, sliding, dataset.train, strict=True):
            err = predict_at(model, x, 1.0 / rec.sample_rate_hz) - yy
            sq_every.append(err[out] ** 2)
            sq_slide.append(err[out & slide] ** 2)

    def rmse(parts: list[np.ndarray]) -> float:
        pooled = np.concatenate(parts)
        return float(np.sqrt(np.mean(pooled))) if len(pooled) else float("nan")

    every = rmse(sq_every)
    slide_score = rmse(sq_slide)
    # as `evaluate.sliding_metrics`: a recording that never slides counts with every row
    return (slide_score if np.isfinite(slide_score) else every), every
