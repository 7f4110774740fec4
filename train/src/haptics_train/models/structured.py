"""`structured`: a stateful model of a foam-like object in the shape of its physics, driven by
kinematics only (x, v), dissipative by construction, and the bench's friction identified
beside it but not rendered.

Why: the learned models fed back their own force drift or inject energy in the loop, and a
nonlinear spring with a Prony series (`prony`) lacks the hysteresis and the permanent set the
object has. This model has each element of a viscoelastic foam, every one fitted:

    e(t)   = x(t) - set(t)                              compression past the permanent set
    F_eq   = sum_j a_j phi_j(e)                         equilibrium: tanh plateaus + densification
    q_i(t) = d_i q_i(t - dt) + dF_eq(t)                 Maxwell branch i, d_i = exp(-dt / tau_i)
    u_m(t) = Dahl state of the compression path (length L_m, in [-1, 1], 0 out of contact)
    object = max(0, F_eq + sum_i g_i q_i + sum_m h_m F_eq u_m)   (0 out of contact)
    bench  = sum_l c_l z_l + b v                        Dahl friction on x (length L_l), viscous

a_j, g_i, h_m, c_l >= 0 by non-negative least squares: the equilibrium curve only stiffens with
depth, every Maxwell branch and hysteresis element only dissipates (a Dahl element's loop runs
clockwise), so the model cannot drift or inject energy. The permanent set follows the foam's
compression-set law (grows toward max_m (largest depth / reference)^2 while loaded, recovers
toward a kept fraction), its magnitude max_m chosen among candidates by the training fit.

The target the bench records (the RFOB estimate) is the object's force plus the bench's own
friction; the friction is fitted as its own term on the rows where the probe slides (|v| above
`fit_min_speed_mps`: when it sticks, the friction is any value the force controller leaves,
which kinematics cannot tell) and `predict` returns object + bench: what the RFOB reads in
reproduction too. The ONNX graph renders the object only (`predict_served`): the bench adds its
own friction under the hand, so rendering it as well would count it twice (issue 11).

The state steps once per row at the training period `dt`, like `prony`. Exported as a stateful
model: `h_in`/`h_out` carry [q_1..q_K, u_1..u_M, set, largest depth, previous e]; `c_in`/`c_out`
carry the equilibrium force at the previous e in their first element (the graph is built by
hand: structured_graph.py).

Sequences layout (`models.base`): `fit(X, y, info)`, X one [n_i, 2] array (x, v) per recording,
rows in time order. Fitted attributes: `dt_`, `set_max_m_`, `a_` (equilibrium), `g_`
(branches), `h_` (hysteresis), `c_` (friction), `b_` (viscous), `train_info_`.
"""

from __future__ import annotations

import math

import numpy as np
import onnx
from scipy.optimize import nnls
from scipy.signal import lfilter

from ..data import SequenceInfo
from ..features import KINEMATICS
from .base import ForceModel, check_sequences, step_dt
from .structured_graph import structured_graph

STRUCTURED_DEFAULT: dict = {
    "yield_m": [0.001, 0.002, 0.003, 0.005, 0.008, 0.012],
    "densification_m": [0.035, 0.040, 0.045, 0.055, 0.070],
    "taus_s": [0.02, 0.06, 0.2, 0.7, 2.5, 9.0, 30.0],
    "hysteresis_lengths_m": [2e-4, 1e-3, 4e-3],
    "friction_lengths_m": [2e-5, 1e-4, 5e-4],
    "set_max_m": [0.0, 0.0015, 0.0025, 0.0035],
    # the compression-set law's shape (its magnitude max_m is fitted)
    "set_reference_m": 0.030,
    "set_tau_grow_s": 3.0,
    "set_loaded_fraction": 0.6,
    "set_tau_recover_s": 40.0,
    "set_keep_fraction": 0.6,
    "fit_min_speed_mps": 1e-4,
    "iterations": 2,
}


def dahl(path: np.ndarray, length: float, reset: np.ndarray | None = None) -> np.ndarray:
    """The Dahl state u in [-1, 1] along a path, exact for a straight step: u approaches the
    sign of the motion over `length` of travel, whatever the rate (rate-independent
    hysteresis). Where `reset`, u = 0. A plain loop: the recursion is nonlinear."""
    out = np.empty(len(path))
    u = 0.0
    prev = float(path[0]) if len(path) else 0.0
    rs = reset.tolist() if reset is not None else [False] * len(path)
    exp = math.exp
    for n, (p, r) in enumerate(zip(path.tolist(), rs, strict=True)):
        dp = p - prev
        prev = p
        if r:
            u = 0.0
        elif dp > 0.0:
            a = exp(-dp / length)
            u = a * u + 1.0 - a
        elif dp < 0.0:
            a = exp(dp / length)
            u = a * u - (1.0 - a)
        out[n] = u
    return out


def permanent_set(x: np.ndarray, dt: float, max_m: float, h: dict) -> np.ndarray:
    """The compression set along x (m): grows toward max_m (largest depth / reference)^2 while
    the probe is loaded (deeper than a fraction of the largest depth, in contact), recovers
    toward a kept fraction of it otherwise (rt-loop's sponge law, SPEC section 7)."""
    out = np.zeros(len(x))
    if max_m <= 0.0:
        return out
    s = md = 0.0
    kg = min(dt / float(h["set_tau_grow_s"]), 1.0)
    kr = min(dt / float(h["set_tau_recover_s"]), 1.0)
    ref, lf, keep = (
        float(h["set_reference_m"]),
        float(h["set_loaded_fraction"]),
        float(h["set_keep_fraction"]),
    )
    for n, xn in enumerate(x.tolist()):
        md = max(md, xn)
        target = max_m * (md / ref) ** 2
        loaded = xn > lf * md and xn - s > 0.0
        if loaded and s < target:
            s += (target - s) * kg
        elif not loaded and s > keep * target:
            s -= (s - keep * target) * kr
        out[n] = s
    return out


def equilibrium_basis(e: np.ndarray, h: dict) -> np.ndarray:
    """[n, J] the equilibrium's basis at compression e (0 at e <= 0, each rising with e):
    tanh(e / y) plateaus and (1 - e/d)^-2 - 1 densification, continued linearly past 0.95 d."""
    e = np.maximum(e, 0.0)
    cols = [np.tanh(e / y) for y in h["yield_m"]]
    for d in h["densification_m"]:
        cap = 0.95 * d
        u = 1.0 - np.minimum(e, cap) / d
        cols.append(u**-2 - 1.0 + 2.0 / d * u**-3 * np.maximum(e - cap, 0.0))
    return np.column_stack(cols)


def _object_columns(
    x: np.ndarray, dt: float, set_m: float, a: np.ndarray | None, v: np.ndarray, h: dict
) -> tuple[np.ndarray, np.ndarray]:
    """(columns of the object's force, e). With `a` (an equilibrium fitted already): basis,
    Maxwell branches driven by dF_eq, hysteresis F_eq u_m; without (the first pass): basis and
    velocity-driven branches."""
    e = x - permanent_set(x, dt, set_m, h)
    basis = equilibrium_basis(e, h)
    taus = np.asarray(h["taus_s"], dtype=float)
    decay = np.exp(-dt / taus)
    if a is None:
        br = [lfilter([t * (1 - d)], [1.0, -d], v) for t, d in zip(taus, decay, strict=True)]
        return np.column_stack([basis, *br]), e
    feq = basis @ a
    dfeq = np.diff(feq, prepend=0.0)
    br = [lfilter([1.0], [1.0, -d], dfeq) for d in decay]
    out = e <= 0.0
    ep = np.maximum(e, 0.0)
    hy = [feq * dahl(ep, L, out) for L in h["hysteresis_lengths_m"]]
    return np.column_stack([basis, *br, *hy]), e


def _bench_columns(x: np.ndarray, v: np.ndarray, h: dict) -> np.ndarray:
    """Dahl friction states on x and the viscous term (+v, -v: its sign left free)."""
    return np.column_stack([*(dahl(x, L) for L in h["friction_lengths_m"]), v, -v])


class StructuredModel(ForceModel):
    algo = "structured"
    kind = "stateful"
    layout = "sequences"
    defaults = STRUCTURED_DEFAULT

    def __init__(self, hyper: dict | None = None, *, seed: int = 0, progress: bool = False) -> None:
        super().__init__(KINEMATICS[:2], "x_v", hyper, seed=seed, progress=progress)

    @property
    def name(self) -> str:
        return "structured"

    @property
    def state_size(self) -> int:
        return len(self.hyper["taus_s"]) + len(self.hyper["hysteresis_lengths_m"]) + 3

    def fit(
        self, X: list[np.ndarray], y: list[np.ndarray], info: list[SequenceInfo]
    ) -> StructuredModel:
        seqs, targets = check_sequences(X, y, len(self.features), len(info))
        h = self.hyper
        self.dt_ = step_dt("structured", info)
        # Fitted on every stride-th row, the states stepped at that rate (the Dahl states are
        # rate-independent, the branches exact for the increments they are driven by).
        rows = []
        for xv, yy, i in zip(seqs, targets, info, strict=True):
            k = max(1, i.stride)
            x, v, t = xv[::k, 0], xv[::k, 1], yy[::k]
            keep = (t > i.contact_off_n) & (np.abs(v) > float(h["fit_min_speed_mps"]))
            rows.append((x, v, t, keep, self.dt_ * k, _bench_columns(x, v, h)))
        best: dict | None = None
        by_set: dict[str, float] = {}
        for set_m in h["set_max_m"]:
            a = None
            for _ in range(1 + int(h["iterations"])):
                fit = self._fit_pass(rows, float(set_m), a)
                a = fit["coef"][: fit["nb"]]
            by_set[str(set_m)] = fit["rmse"]
            if best is None or fit["rmse"] < best["rmse"]:
                best = {**fit, "set_max_m": float(set_m)}
        assert best is not None
        coef, nb, nk = best["coef"], best["nb"], len(h["taus_s"])
        nm = len(h["hysteresis_lengths_m"])
        self.set_max_m_ = best["set_max_m"]
        self.a_ = coef[:nb]
        self.g_ = coef[nb : nb + nk]
        self.h_ = coef[nb + nk : nb + nk + nm]
        bench = coef[nb + nk + nm :]
        self.c_ = bench[:-2]
        self.b_ = float(bench[-2] - bench[-1])
        self.n_features_in_ = len(self.features)
        self.train_info_ = {
            "rows": best["rows"],
            "dt_s": self.dt_,
            "set_max_m": self.set_max_m_,
            "fit_rmse_by_set_max_m": by_set,
            "fit_rmse": best["rmse"],
            "equilibrium": self.a_.tolist(),
            "branch_gains": self.g_.tolist(),
            "hysteresis": self.h_.tolist(),
            "friction_n": self.c_.tolist(),
            "viscous_ns_per_m": self.b_,
        }
        return self

    def _fit_pass(self, rows: list, set_m: float, a: np.ndarray | None) -> dict:
        h = self.hyper
        mats, ys = [], []
        nb = len(h["yield_m"]) + len(h["densification_m"])
        for x, v, t, keep, dt, bench in rows:
            obj, _ = _object_columns(x, dt, set_m, a, v, h)
            mats.append(np.column_stack([obj, bench])[keep])
            ys.append(t[keep])
        m, y = np.concatenate(mats), np.concatenate(ys)
        scale = np.abs(m).max(axis=0)
        scale[scale == 0] = 1.0
        coef, res = nnls(m / scale, y, maxiter=50 * m.shape[1])
        return {"coef": coef / scale, "nb": nb, "rmse": float(res / np.sqrt(len(y))),
                "rows": int(len(y))}  # fmt: skip

    def _parts(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._check_fitted()
        xv = self._check_X(X)
        x, v = xv[:, 0], xv[:, 1]
        obj, e = _object_columns(x, self.dt_, self.set_max_m_, self.a_, v, self.hyper)
        f = obj @ np.concatenate([self.a_, self.g_, self.h_])
        served = np.where(e > 0.0, np.maximum(f, 0.0), 0.0)
        bench = _bench_columns(x, v, self.hyper)[:, :-2] @ self.c_ + self.b_ * v
        return served, bench

    def predict(self, X: np.ndarray) -> np.ndarray:
        """The force the RFOB reads: the object's plus the bench's friction (one sequence,
        from zero state)."""
        served, bench = self._parts(X)
        return served + bench

    def predict_served(self, X: np.ndarray) -> np.ndarray:
        """The object's force alone: what the ONNX graph renders."""
        return self._parts(X)[0]

    def to_onnx(self) -> onnx.ModelProto:
        self._check_fitted()
        return structured_graph(self)
