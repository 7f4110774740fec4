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

The state steps once per row at the training recordings' period `dt` (in the metadata, like the
LSTM it is served once per step and must be trained at the rate it is served at). Exported to
ONNX as a stateful model: `h_in`/`h_out` carry the K branch states, `c_in`/`c_out` are passed
through (the contract's second state).
"""

from __future__ import annotations

import warnings

import numpy as np
import onnx
import torch
from scipy.optimize import nnls
from scipy.signal import lfilter

from ..closed_loop import contact_thresholds
from ..data import Recording
from .base import ForceModel, TrainConfig, row_stride
from .torch_export import export_stateful

PRONY_DEFAULT = {"poly": 3, "tau_min_steps": 5, "tau_min_s": 0.02, "tau_max_s": 30.0, "n_tau": 6}


def branch_states(v: np.ndarray, dt: float, taus: np.ndarray) -> np.ndarray:
    """[n, K] Maxwell-branch states along a velocity series (zero before the first row)."""
    e = np.exp(-dt / taus)
    gain = taus * (1.0 - e)
    # s[n] = e s[n-1] + gain v[n]: a first-order IIR filter per branch
    return np.column_stack([lfilter([g], [1.0, -ei], v) for g, ei in zip(gain, e, strict=True)])


class _PronyModule(torch.nn.Module):
    def __init__(self, k: np.ndarray, w: np.ndarray, e: np.ndarray, gain: np.ndarray) -> None:
        super().__init__()
        f32 = torch.float32
        self.register_buffer("k", torch.tensor(k, dtype=f32))
        self.register_buffer("w", torch.tensor(w, dtype=f32).reshape(1, 1, -1))
        self.register_buffer("e", torch.tensor(e, dtype=f32).reshape(1, 1, -1))
        self.register_buffer("g", torch.tensor(gain, dtype=f32).reshape(1, 1, -1))

    def forward(
        self, features: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        x = features[:, 0:1]
        v = features[:, 1:2].reshape(1, 1, 1)
        s = h * self.e + self.g * v
        spring = torch.zeros_like(x)
        for i in range(self.k.shape[0] - 1, -1, -1):  # Horner: k1 x + k2 x^2 + ...
            spring = (spring + self.k[i]) * x
        f = spring + (s * self.w).sum(dim=2)
        return torch.relu(f), s, c + 0.0


class PronyModel(ForceModel):
    algo = "prony"
    kind = "stateful"

    def __init__(self, hyper: dict | None = None) -> None:
        super().__init__(("position_x", "velocity"), "x_v", {**PRONY_DEFAULT, **(hyper or {})})
        self.k = np.zeros(int(self.hyper["poly"]))
        self.w = np.zeros(0)
        self.taus = np.zeros(0)
        self.dt = 0.0

    @property
    def name(self) -> str:
        return "prony"

    def fit(self, recs: list[Recording], cfg: TrainConfig) -> None:
        h = self.hyper
        dts = np.array([1.0 / r.sample_rate_hz for r in recs])
        self.dt = float(np.median(dts))
        if np.any(np.abs(dts / self.dt - 1) > 0.01):
            warnings.warn(f"prony: training recordings at different rates ({1 / dts} Hz); "
                          f"the model steps at {1 / self.dt:g} Hz", stacklevel=2)  # fmt: skip
        span = max(float(r.columns["time"][-1] - r.columns["time"][0]) for r in recs)
        lo = max(float(h["tau_min_steps"]) * self.dt, float(h["tau_min_s"]))
        hi = max(min(float(h["tau_max_s"]), span), 2 * lo)
        self.taus = np.geomspace(lo, hi, int(h["n_tau"]))
        rows_a, rows_y = [], []
        for r in recs:
            x, v = r.column("position_x"), r.column("velocity")
            y = r.target(cfg.target)
            s = branch_states(v, self.dt, self.taus)
            k = row_stride(r, cfg.decimate, cfg.target_rate_hz)
            keep = np.zeros(len(y), dtype=bool)
            keep[::k] = True
            keep &= y > contact_thresholds(r)[1]  # contact rows: the clamp is not fitted
            poly = np.column_stack([x**j for j in range(1, int(h["poly"]) + 1)])
            rows_a.append(np.column_stack([poly, -poly, s])[keep])
            rows_y.append(y[keep])
        a, y = np.concatenate(rows_a), np.concatenate(rows_y)
        scale = np.abs(a).max(axis=0)
        scale[scale == 0] = 1.0
        coef, res = nnls(a / scale, y, maxiter=50 * a.shape[1])
        coef = coef / scale
        p = int(h["poly"])
        self.k = coef[:p] - coef[p : 2 * p]
        self.w = coef[2 * p :]
        self.train_info = {
            "rows": int(len(y)),
            "dt_s": self.dt,
            "taus_s": self.taus.tolist(),
            "k": self.k.tolist(),
            "w": self.w.tolist(),
            "fit_rmse": float(res / np.sqrt(len(y))),
        }

    def predict_matrix(self, x: np.ndarray) -> np.ndarray:
        s = branch_states(x[:, 1], self.dt, self.taus)
        spring = sum(self.k[j] * x[:, 0] ** (j + 1) for j in range(len(self.k)))
        return np.maximum(spring + s @ self.w, 0.0)

    def to_onnx(self) -> onnx.ModelProto:
        e = np.exp(-self.dt / self.taus)
        mod = _PronyModule(self.k, self.w, e, self.taus * (1.0 - e))
        return export_stateful(mod, len(self.features), len(self.taus))
