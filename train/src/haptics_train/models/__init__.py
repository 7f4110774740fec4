"""Model registry: algorithm name + feature set + preset -> an untrained ForceModel (the
estimator shape and the arrays each model takes: `base`)."""

from __future__ import annotations

from ..features import feature_set
from ..holds import HOLDS_ALGOS, HOLDS_KEY, HOLDS_SPEC, split_spec
from .base import ForceModel, NotFittedError, TrainConfig, fit_recordings, predict_at
from .lawfree import LawFreeModel
from .networks import DNN_THESIS, LSTM_THESIS, DenseModel, LSTMModel
from .prony import PronyModel
from .sklearn_models import RF_THESIS, SVR_THESIS, ForestModel, LinearModel, SVRModel
from .slow_lstm import SlowLSTMModel
from .spring_damper import SpringDamper
from .structured import StructuredHystModel, StructuredModel, StructuredPathModel

ALGOS = ("sd_const", "sd_poly1", "sd_poly2", "lr", "svr", "rf", "dnn", "lstm", "dnn_fb", "lstm_fb",
         "prony", "structured", "structured_path", "structured_hyst", "lstm_slow", "lawfree")

#: `dnn_fb` / `lstm_fb`: the same networks trained with feedback noise on the previous force
#: (see networks.perturb_previous_force), for a closed loop that does not drift. Its scale is a
#: fraction of the training force's range (0.2: ~2.6 N on the bench's 0-14 N ramps, where a
#: fixed 2.5 N was tuned; 0.24 N on a 1.2 N elastomer test); `feedback_noise` (N) overrides it.
FEEDBACK_NOISE_FRAC = 0.2

__all__ = [
    "ALGOS",
    "ForceModel",
    "NotFittedError",
    "TrainConfig",
    "fit_recordings",
    "make_model",
    "parse_spec",
    "predict_at",
]


def make_model(
    algo: str, fset: str = "six", preset: str = "default", hyper: dict | None = None
) -> ForceModel:
    """`preset="thesis"` takes the thesis's hyperparameters (docs/physics.md, "What the thesis
    reports"); `hyper` overrides."""
    if preset not in ("default", "thesis"):
        raise ValueError(f"unknown preset {preset!r} (default|thesis)")
    thesis = preset == "thesis"
    h = dict(hyper or {})
    if algo.startswith("sd_"):
        order = {"sd_const": 0, "sd_poly1": 1, "sd_poly2": 2}.get(algo)
        if order is None:
            raise ValueError(f"unknown spring-damper {algo!r} (sd_const|sd_poly1|sd_poly2)")
        return SpringDamper(order)
    if algo == "prony":
        return PronyModel(h)  # always on x, v (kinematics only)
    if algo == "structured":
        return StructuredModel(h)  # always on x, v (kinematics only)
    if algo == "structured_path":
        return StructuredPathModel(h)  # the same, its bench term on the path's velocity
    if algo == "structured_hyst":
        return StructuredHystModel(h)  # structured_path, its hysteresis also of its own size
    if algo == "lawfree":
        return LawFreeModel(h)  # always on x, v (kinematics only)
    fs = feature_set(fset)
    if algo == "lstm_slow":
        if fs.uses_feedback:
            raise ValueError(f"lstm_slow takes kinematics only; {fset!r} feeds the force back")
        return SlowLSTMModel(fs.features, fs.name, h)
    if algo == "lr":
        return LinearModel(fs.features, fs.name)
    if algo == "svr":
        return SVRModel(fs.features, fs.name, {**(SVR_THESIS if thesis else {}), **h})
    if algo == "rf":
        return ForestModel(fs.features, fs.name, {**(RF_THESIS if thesis else {}), **h})
    if algo in ("dnn", "dnn_fb"):
        fb = {"feedback_noise_frac": FEEDBACK_NOISE_FRAC} if algo == "dnn_fb" else {}
        m = DenseModel(fs.features, fs.name, {**(DNN_THESIS if thesis else {}), **fb, **h})
        m.algo = algo
        return m
    if algo in ("lstm", "lstm_fb"):
        fb = {"feedback_noise_frac": FEEDBACK_NOISE_FRAC} if algo == "lstm_fb" else {}
        m = LSTMModel(fs.features, fs.name, {**(LSTM_THESIS if thesis else {}), **fb, **h})
        m.algo = algo
        return m
    raise ValueError(f"unknown algorithm {algo!r} (known: {', '.join(ALGOS)})")


def parse_spec(spec: str, preset: str = "default") -> ForceModel:
    """`rf:six`, `lstm:xva_f`, `sd_poly2` (spring-dampers always use x and v), `lstm_slow`
    (x and v unless a kinematics-only set is named); `structured+holds`: trained on the
    dataset's press-and-hold recordings too (holds.py), for the models of `HOLDS_ALGOS`."""
    base, holds = split_spec(spec)
    algo, _, fset = base.partition(":")
    algo = algo.strip()
    if holds and (algo not in HOLDS_ALGOS or fset):
        raise ValueError(f"{spec}: only {', '.join(HOLDS_ALGOS)} take {HOLDS_SPEC} (holds.py)")
    default = "x_v" if algo == "lstm_slow" else "six"  # kinematics only
    return make_model(algo, (fset or default).strip(), preset, {HOLDS_KEY: True} if holds else None)
