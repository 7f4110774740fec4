"""The common shape of every force model, scikit-learn's: parameters stored by `__init__`,
checked by `fit(X, y)`, fitted attributes ending in `_`, `predict(X)` on arrays; and
`to_onnx()` for infer-server.

Models take arrays, never recordings: `data.training_arrays` turns recordings into the layout a
model declares (`layout`), and `fit_recordings` below is the one call that does both.

- `layout = "rows"` (the stateless models: spring-dampers, lr, svr, rf, dnn):
  `fit(X, y)` with X [n, f] float64, the columns `features` in order, one row per kept control
  step (decimated, from every training recording), y [n] the target force in N.
- `layout = "sequences"` (the stateful models, lstm and prony, whose state steps once per row):
  `fit(X, y, info=...)` with X a list of [n_i, f] arrays, one per recording, every row in time
  order, y the matching list of [n_i] targets, and `info` one `data.SequenceInfo` per sequence
  (its row rate, duration, decimation stride, control steps per row, contact threshold).
- Feedback-noise networks (`dnn_fb`, `lstm_fb`, `aux_columns` set) also take `aux`: the
  previous force F(t-1) and x, v, a of the same rows ([n, 4], or one [n_i, 4] per sequence),
  to rebuild the previous-force features around a perturbed F(t-1).

`predict(X)` always takes one [n, f] array: independent rows for a stateless model, one
sequence stepped from zero state for a stateful one (one-step: the recorded features, the
previous force the measured one). The closed loop, where the previous force is the model's own
prediction, steps the exported ONNX graph (`closed_loop.simulate`).
"""

from __future__ import annotations

import warnings
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Self

import numpy as np
import onnx

from ..data import Recording, SequenceInfo, training_arrays
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


class NotFittedError(RuntimeError):
    """`predict` or `to_onnx` on a model that has not been fitted."""


class ForceModel(ABC):
    """A reaction-force model of one algorithm on one feature set.

    Parameters (set by `__init__`, changed only through `set_params` or `hyper`): `features`,
    `feature_set`, `hyper` (the algorithm's defaults merged with the overrides given: what the
    provenance records), `seed`, `progress`. Fitted attributes end in `_`: every model has
    `n_features_in_` and `train_info_` (what the fit saw and did, for the provenance).
    """

    algo: str = ""
    kind: str = "stateless"
    #: which arrays `fit` takes (see the module docstring)
    layout: str = "rows"
    #: columns passed to `fit` as `aux` beside the features (feedback-noise training)
    aux_columns: tuple[str, ...] = ()
    #: the algorithm's default hyperparameters, which `hyper` overrides
    defaults: dict = {}

    def __init__(
        self,
        features: tuple[str, ...],
        feature_set: str,
        hyper: dict | None = None,
        *,
        seed: int = 0,
        progress: bool = False,
    ) -> None:
        self.features = tuple(features)
        self.feature_set = feature_set
        self.hyper = {**self.defaults, **(hyper or {})}
        self.seed = seed
        self.progress = progress

    @property
    def name(self) -> str:
        return f"{self.algo}_{self.feature_set}"

    def set_params(self, **params: object) -> Self:
        """Changes parameters set by `__init__` (scikit-learn's `set_params`)."""
        for k, v in params.items():
            if k not in ("features", "feature_set", "hyper", "seed", "progress"):
                raise ValueError(f"{type(self).__name__} has no parameter {k!r}")
            setattr(self, k, v)
        return self

    @abstractmethod
    def fit(self, X: object, y: object, **fit_params: object) -> Self:
        """Fits on arrays in this model's `layout`; returns the model."""

    @abstractmethod
    def predict(self, X: np.ndarray) -> np.ndarray:
        """[n] force predictions for X [n, f] (rows, or one sequence from zero state)."""

    @abstractmethod
    def to_onnx(self) -> onnx.ModelProto:
        """The graph of docs/model-contract.md (metadata is added by `export`)."""

    def _check_X(self, X: np.ndarray) -> np.ndarray:
        """X as a 2-D float64 array with this model's feature count."""
        x = np.asarray(X, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != len(self.features):
            raise ValueError(
                f"{self.name}: X must be [n, {len(self.features)}] ({', '.join(self.features)}),"
                f" got shape {x.shape}"
            )
        return x

    def _check_fitted(self) -> None:
        if not hasattr(self, "train_info_"):
            raise NotFittedError(f"{self.name} is not fitted: call fit(X, y) first")

    def __setstate__(self, state: dict) -> None:
        # Models pickled (models/*.joblib) before the estimator shape named their fitted
        # attributes without the trailing underscore; they load as fitted models still.
        for old in ("train_info", *self._legacy_fitted):
            if old in state:
                state[f"{old}_"] = state.pop(old)
        if "train_info_" in state and "n_features_in_" not in state:
            state["n_features_in_"] = len(state.get("features", ()))
        state.setdefault("seed", 0)
        state.setdefault("progress", False)
        state.pop("max_rows", None)  # derived from `hyper` in fit now
        self.__dict__.update(state)

    #: fitted attributes that older pickles hold without the trailing underscore
    _legacy_fitted: tuple[str, ...] = ()


def check_rows(X: object, y: object, n_features: int) -> tuple[np.ndarray, np.ndarray]:
    """The rows layout checked: X [n, n_features] and y [n] float64, n >= 1."""
    x = np.asarray(X, dtype=np.float64)
    yy = np.asarray(y, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != n_features:
        raise ValueError(f"X must be [n, {n_features}], got shape {x.shape}")
    if yy.shape != (x.shape[0],):
        raise ValueError(f"y must be [{x.shape[0]}] (one target per row of X), got {yy.shape}")
    if x.shape[0] == 0:
        raise ValueError("no training rows")
    return x, yy


def check_sequences(
    X: object, y: object, n_features: int, n_info: int | None = None
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The sequences layout checked: lists of [n_i, n_features] and [n_i] float64 arrays."""
    if isinstance(X, np.ndarray) or isinstance(y, np.ndarray):
        raise ValueError("X and y must be lists of sequences (one array per recording)")
    xs = [np.asarray(x, dtype=np.float64) for x in X]  # type: ignore[attr-defined]
    ys = [np.asarray(v, dtype=np.float64) for v in y]  # type: ignore[attr-defined]
    if not xs or len(xs) != len(ys):
        raise ValueError(f"X and y must hold the same number (>= 1) of sequences: {len(xs)}, "
                         f"{len(ys)}")  # fmt: skip
    for i, (x, v) in enumerate(zip(xs, ys, strict=True)):
        if x.ndim != 2 or x.shape[1] != n_features or v.shape != (x.shape[0],):
            raise ValueError(
                f"sequence {i}: X must be [n, {n_features}] and y [n], got {x.shape}, {v.shape}"
            )
    if n_info is not None and n_info != len(xs):
        raise ValueError(f"info must hold one SequenceInfo per sequence ({len(xs)}), got {n_info}")
    return xs, ys


def step_dt(algo: str, info: Sequence[SequenceInfo], one_rate: bool = True) -> float:
    """The step of a stateful model fitted on these sequences: their median row interval, s;
    with `one_rate` (a model that steps every sequence at that one step), a warning where
    their rates differ by more than 1 %. A model that steps each sequence at its own period
    (`predict_at`) passes False."""
    dts = np.array([1.0 / i.sample_rate_hz for i in info])
    dt = float(np.median(dts))
    if one_rate and np.any(np.abs(dts / dt - 1) > 0.01):
        warnings.warn(f"{algo}: training recordings at different rates ({1 / dts} Hz); "
                      f"the model steps at {1 / dt:g} Hz", stacklevel=3)  # fmt: skip
    return dt


#: rt-loop's default rate, Hz (`--rate-hz`): the serving rate of a model fitted on data no loop
#: recorded (imported from a testing machine)
LOOP_RATE_HZ_DEFAULT = 10_000.0


def serve_dt(algo: str, info: Sequence[SequenceInfo]) -> float:
    """The period a stateful model is served at, s: the loop steps its state once per control
    step, whatever the rows' rate. The loop that recorded the training sequences (their median;
    a warning where they differ by more than 1 %), else rt-loop's default rate (imported data:
    a 50 Hz testing machine's model still runs in a 10 kHz loop). Models whose states decay as
    exp(-dt / tau) are fitted at the rows' step (`step_dt`) and re-discretised at this one on
    export, so a model fitted on decimated rows relaxes at the speed it was fitted at."""
    rates = np.array([i.loop_rate_hz for i in info], dtype=float)
    rates = rates[np.isfinite(rates) & (rates > 0)]
    if len(rates) == 0:
        return 1.0 / LOOP_RATE_HZ_DEFAULT
    rate = float(np.median(rates))
    if np.any(np.abs(rates / rate - 1) > 0.01):
        warnings.warn(f"{algo}: training recordings from loops at different rates ({rates} Hz); "
                      f"the model is served at {rate:g} Hz", stacklevel=3)  # fmt: skip
    return 1.0 / rate


def served_dt(model: object) -> float:
    """The period a fitted stateful model's graph steps its state at (`serve_dt_`; a model
    pickled before it existed has only `dt_`, the rows' period)."""
    return float(getattr(model, "serve_dt_", None) or model.dt_)  # type: ignore[attr-defined]


def fit_recordings(model: ForceModel, recs: Sequence[Recording], cfg: TrainConfig) -> ForceModel:
    """Fits `model` on recordings: their arrays in the model's layout (`data.training_arrays`)
    with the configuration's target, rows and seed."""
    X, y, params = training_arrays(
        recs, model.features, model.layout, model.aux_columns, cfg.target, cfg.decimate,
        cfg.target_rate_hz,
    )  # fmt: skip
    model.set_params(seed=cfg.seed, progress=cfg.progress)
    fitted = model.fit(X, y, **params)
    # the filters its velocity and acceleration features were computed with, where every
    # recording says the same (export writes them: `haptics.feature_gains`)
    gains = {r.feature_gains for r in recs}
    fitted.feature_gains_ = next(iter(gains)) if len(gains) == 1 else None
    return fitted


def predict_at(model: ForceModel, X: np.ndarray, period_s: float) -> np.ndarray:
    """`model.predict` along rows `period_s` apart: a model whose state steps in time
    (`steps_in_time`: `lawfree`, `structured`, `prony`) is stepped at that period, so a
    recording logged at another rate than the training ones relaxes at the right speed;
    any other model predicts row by row as it was fitted."""
    if getattr(model, "steps_in_time", False):
        return model.predict(X, dt=period_s)  # type: ignore[call-arg]
    return model.predict(X)
