"""The common shape of every force model: fit on recordings, predict one-step, export ONNX."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass

import numpy as np
import onnx

from ..data import Recording
from ..features import TARGET_DEFAULT


@dataclass
class TrainConfig:
    """What every model shares: which rows, which target, which seed."""

    #: stateless models train on one row every `decimate` control steps (a recording made
    #: with rt-loop's --decimate k has one row per k steps: the stride is decimate / k rows);
    #: None: derived per recording from its rate and `target_rate_hz`
    decimate: int | None = None
    target: str = TARGET_DEFAULT
    seed: int = 0
    #: show progress bars
    progress: bool = True
    #: the row rate stateless models train at when `decimate` is None (the bench: 10 kHz
    #: loop / 20 = 500 Hz; a 50 Hz import keeps every row)
    target_rate_hz: float = 500.0

    def to_dict(self) -> dict:
        return asdict(self)


def row_stride(rec: Recording, decimate: int | None, target_rate_hz: float = 500.0) -> int:
    """Rows between kept rows: `decimate` control steps, else the recording's row rate over the
    target rate (at least 1)."""
    if decimate is not None:
        return max(1, round(decimate / rec.row_step))
    rate = rec.sample_rate_hz
    return max(1, round(rate / target_rate_hz)) if np.isfinite(rate) else 1


def stacked(
    recs: list[Recording], features: tuple[str, ...], cfg: TrainConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Decimated rows of all recordings: X [n, f] float64 and y [n], non-finite rows dropped."""
    strides = [row_stride(r, cfg.decimate, cfg.target_rate_hz) for r in recs]
    xs = [r.matrix(features, k) for r, k in zip(recs, strides, strict=True)]
    ys = [r.target(cfg.target, k) for r, k in zip(recs, strides, strict=True)]
    x = np.concatenate(xs)
    y = np.concatenate(ys)
    ok = np.isfinite(x).all(axis=1) & np.isfinite(y)
    return x[ok], y[ok]


class ForceModel(ABC):
    """A trained reaction-force model of one algorithm on one feature set."""

    algo: str = ""
    kind: str = "stateless"

    def __init__(self, features: tuple[str, ...], feature_set: str, hyper: dict) -> None:
        self.features = tuple(features)
        self.feature_set = feature_set
        self.hyper = dict(hyper)
        self.train_info: dict = {}

    @property
    def name(self) -> str:
        return f"{self.algo}_{self.feature_set}"

    @abstractmethod
    def fit(self, recs: list[Recording], cfg: TrainConfig) -> None: ...

    @abstractmethod
    def predict_matrix(self, x: np.ndarray) -> np.ndarray:
        """One-step predictions for rows of features (stateless models)."""

    def predict_recording(self, rec: Recording) -> np.ndarray:
        """One-step predictions at every row of a recording, in order (recorded features)."""
        return self.predict_matrix(rec.matrix(self.features))

    @abstractmethod
    def to_onnx(self) -> onnx.ModelProto:
        """The graph of docs/model-contract.md (metadata is added by `export`)."""
