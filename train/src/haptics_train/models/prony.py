"""`prony`: a structured stateful model of a viscoelastic object, driven by kinematics only.

    F = max(0, k1 x + k2 x^2 + k3 x^3 + sum_i w_i s_i),
    s_i(t) = e_i s_i(t - dt) + tau_i (1 - e_i) v(t),   e_i = exp(-dt / tau_i)

A nonlinear equilibrium spring plus a generalised Maxwell (Prony) series: each s_i is the
velocity low-passed with time constant tau_i (times tau_i), i.e. the stretch of a Maxwell
element's spring, exact for a velocity held over the step. The relaxation times are a fixed
log-spaced grid (from a few steps to tens of seconds); the spring coefficients and the Prony
weights are fitted by non-negative least squares on the contact rows (w_i >= 0, the springs'
sign free), so every Maxwell branch can only dissipate: the model cannot drift or inject energy
the way a model fed back its own force can. The force is clamped at 0: the object only pushes.

The state steps once per row at the training recordings' period `dt`; the export re-discretises
it at the period of the loop that recorded them (`serve_dt_`, `haptics.step_s`: the loop steps
it once per control step, and a decimated recording's rows are several steps apart). Exported to
ONNX as a stateful model: `h_in`/`h_out` carry the K branch states; the fused node (the default
export, fused-ops/src/prony.rs) carries their low parts in `c_in`/`c_out`, which the multi-node
graph (`to_onnx(fused=False)`) passes through.

Sequences layout (`models.base`): `fit(X, y, info)` with X one [n_i, 2] array (x, v) per
recording, every row in time order, y the [n_i] targets and `info` their `SequenceInfo` (row
rate: `dt`; duration: the longest relaxation time; stride and contact threshold: the rows the
least squares are fitted on). Fitted attributes: `k_` (spring), `w_` (Prony weights), `taus_`
(relaxation times, s), `dt_` (the step, s).
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import helper
from scipy.optimize import nnls
from scipy.signal import lfilter

from ..data import SequenceInfo
from ..features import KINEMATICS
from .base import ForceModel, check_sequences, serve_dt, served_dt, step_dt
from .onnx_graph import Graph, floats_attr, fused_stateful_model, row, stateful_model

PRONY_DEFAULT = {"poly": 3, "tau_min_steps": 5, "tau_min_s": 0.02, "tau_max_s": 30.0, "n_tau": 6}


def branch_states(v: np.ndarray, dt: float, taus: np.ndarray) -> np.ndarray:
    """[n, K] Maxwell-branch states along a velocity series (zero before the first row)."""
    e = np.exp(-dt / taus)
    gain = taus * (1.0 - e)
    # s[n] = e s[n-1] + gain v[n]: a first-order IIR filter per branch
    return np.column_stack([lfilter([g], [1.0, -ei], v) for g, ei in zip(gain, e, strict=True)])


def prony_graph(k: np.ndarray, w: np.ndarray, e: np.ndarray, gain: np.ndarray) -> onnx.ModelProto:
    """One step as a handful of vector nodes (models/onnx_graph.py says why not torch.onnx):
    s' = e s + gain v; F = relu([x, x^2, ..., s'] . [k, w])."""
    g = Graph("prony")
    x, v = g.split("features", [1, 1], axis=1, hint="xv")  # [1, 1] each
    s = g.op("Add", g.op("Mul", "h_in", g.const(row(e))), g.op("Mul", v, g.const(row(gain))))
    powers = g.op("Pow", x, g.const(row(np.arange(1, len(k) + 1))))  # [1, 1, P]
    terms = g.op("Concat", powers, s, axis=2)
    f = g.op("MatMul", terms, g.const(np.concatenate([k, w]).reshape(-1, 1)))
    return stateful_model(g, 2, len(w), g.op("Relu", f), s)


def prony_fused(k: np.ndarray, w: np.ndarray, taus: np.ndarray, dt: float) -> onnx.ModelProto:
    """One step as one `ai.haptics:PronyStep` node (fused-ops/src/prony.rs; attribute names:
    its `from_attrs`): the raw fitted values, the decays computed in float64 by the kernel; `c`
    carries the branches' low parts (the graph passes it through)."""
    attrs = [
        helper.make_attribute("dt_s", float(dt)),
        floats_attr("taus_s", taus),
        floats_attr("branch_weights", w),
        floats_attr("spring", k),
    ]
    return fused_stateful_model("PronyStep", attrs, 2, len(w), "prony")


class PronyModel(ForceModel):
    algo = "prony"
    kind = "stateful"
    #: its state steps in time (decays exp(-dt / tau)): `predict_at` steps it at a
    #: recording's own period
    steps_in_time = True
    layout = "sequences"
    defaults = PRONY_DEFAULT
    _legacy_fitted = ("k", "w", "taus", "dt")

    def __init__(
        self, hyper: dict | None = None, *, seed: int = 0, progress: bool = False
    ) -> None:
        super().__init__(KINEMATICS[:2], "x_v", hyper, seed=seed, progress=progress)

    @property
    def name(self) -> str:
        return "prony"

    def fit(
        self, X: list[np.ndarray], y: list[np.ndarray], info: list[SequenceInfo]
    ) -> PronyModel:
        seqs, targets = check_sequences(X, y, len(self.features), len(info))
        h = self.hyper
        dt = step_dt("prony", info, one_rate=False)
        span = max(i.duration_s for i in info)
        lo = max(float(h["tau_min_steps"]) * dt, float(h["tau_min_s"]))
        hi = max(min(float(h["tau_max_s"]), span), 2 * lo)
        taus = np.geomspace(lo, hi, int(h["n_tau"]))
        rows_a, rows_y = [], []
        for xv, y, i in zip(seqs, targets, info, strict=True):
            x, v = xv[:, 0], xv[:, 1]
            s = branch_states(v, 1.0 / i.sample_rate_hz, taus)  # at its own rows' period
            keep = np.zeros(len(y), dtype=bool)
            keep[:: i.stride] = True
            keep &= y > i.contact_off_n  # contact rows: the clamp is not fitted
            keep &= x > 0.0  # and pressed: out of contact the force is the bench's friction
            poly = np.column_stack([x**j for j in range(1, int(h["poly"]) + 1)])
            rows_a.append(np.column_stack([poly, -poly, s])[keep])
            rows_y.append(y[keep])
        a, y = np.concatenate(rows_a), np.concatenate(rows_y)
        scale = np.abs(a).max(axis=0)
        scale[scale == 0] = 1.0
        coef, res = nnls(a / scale, y, maxiter=50 * a.shape[1])
        coef = coef / scale
        p = int(h["poly"])
        self.dt_ = dt
        self.serve_dt_ = serve_dt("prony", info)
        self.taus_ = taus
        self.k_ = coef[:p] - coef[p : 2 * p]
        self.w_ = coef[2 * p :]
        self.n_features_in_ = len(self.features)
        self.train_info_ = {
            "rows": int(len(y)),
            "dt_s": self.dt_,
            "serve_dt_s": self.serve_dt_,
            "taus_s": self.taus_.tolist(),
            "k": self.k_.tolist(),
            "w": self.w_.tolist(),
            "fit_rmse": float(res / np.sqrt(len(y))),
        }
        return self

    def predict(self, X: np.ndarray, dt: float | None = None) -> np.ndarray:
        """One sequence (x, v rows in time order) stepped from zero branch states at `dt`
        (default: the training rows' period)."""
        return self.predict_served(X, dt)

    def predict_served(self, X: np.ndarray, dt: float | None = None) -> np.ndarray:
        """`predict` stepped at `dt` (default: the training rows' period; the graph steps at
        `serve_dt_`, the loop's)."""
        self._check_fitted()
        x = self._check_X(X)
        s = branch_states(x[:, 1], self.dt_ if dt is None else dt, self.taus_)
        spring = sum(self.k_[j] * x[:, 0] ** (j + 1) for j in range(len(self.k_)))
        return np.maximum(spring + s @ self.w_, 0.0)

    def to_onnx(self, fused: bool = True) -> onnx.ModelProto:
        """One `ai.haptics:PronyStep` node (the fused operator: needs libhaptics_fused_ops.so
        where it runs), or with `fused=False` the multi-node graph (same state in `h`)."""
        self._check_fitted()
        dt = served_dt(self)
        if fused:
            return prony_fused(self.k_, self.w_, self.taus_, dt)
        e = np.exp(-dt / self.taus_)
        return prony_graph(self.k_, self.w_, e, self.taus_ * (1.0 - e))
