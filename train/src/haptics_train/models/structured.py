"""`structured`: a stateful model of a foam-like object in the shape of its physics, driven by
kinematics only (x, v), dissipative by construction, and the bench's friction identified
beside it but not rendered.

Why: the learned models fed back their own force drift or inject energy in the loop, and a
nonlinear spring with a Prony series (`prony`) lacks the hysteresis and the permanent set the
object has. This model has each element of a viscoelastic foam:

    e(t)   = x(t) - set(t)                              compression past the permanent set
    F_eq   = sum_j a_j phi_j(e)                         equilibrium: tanh plateaus + poles
                                                        (+ indentation powers (e/D)^p)
    q_i(t) = d_i q_i(t - dt) + dF_eq(t)                 Maxwell branch i, d_i = exp(-dt / tau_i)
    r_k(t) = d_k(e) r_k(t - dt) + dF_eq(t)              depth-scaled branch k (when chosen),
                                                        d_k(e) = exp(-dt / (tau_k e / D)),
                                                        emptied out of contact
    u_m(t) = Dahl state of the compression path (length L_m, in [-1, 1], 0 out of contact)
    object = max(0, F_eq + sum_i g_i q_i + sum_k g_k r_k + sum_m (h_m F_eq + hc_m) u_m)
                                                        (0 out of contact; hc_m only in
                                                        `structured_hyst`, below)
    bench  = sum_l c_l z_l + b v                        Dahl friction on x (length L_l), viscous
                                                        (v: the recorded velocity, or for
                                                        `structured_path` the path's)

What is fitted and what is a grid (issue 23: no number is read off a material file):

- Fitted on the training rows by non-negative least squares: a_j, g_i, h_m, hc_m, c_l >= 0 (the
  equilibrium curve only stiffens with depth, every Maxwell branch and hysteresis element only
  dissipates, so the model cannot drift or inject energy), b.
- Measured on the training data: the depth scale D (`depth_scale_m_`), the largest
  compression in the training rows. Every length of the basis is a multiple of D, so the same
  grids fit a 5 mm gel and a 40 mm foam.
- Generic grids, spanning soft materials in the literature, whose columns the least squares
  weight (every one is kept; a weight of 0 drops it):
  - plateaus tanh(e / (y D)), y in `yield_frac` 0.02..0.8 (log): from a knee at 2 % of the
    deepest press (stiff-then-soft cellular foams, Gibson & Ashby 1997, ch. 5) to an almost
    linear spring over the whole range (gels, tissue);
  - poles (1 - e/(p D))^-n - 1, p in `densification_frac` 1.1..4 and n in
    `densification_exponents` 1..3: densification just past the deepest press (foams pressed
    near their densification strain, 0.5-0.9 of the thickness) to a gently stiffening curve
    (rubber-like and neo-Hookean indentation); continued linearly past 95 % of p D;
  - relaxation times `taus_s` 0.01..100 s, half a decade apart: the relaxation spectra of
    polymer foams, hydrogels and soft tissue reported in indentation and stress-relaxation
    tests (Hu et al. 2010; Fung 1993 ch. 7) lie within 1e-2..1e3 s, and a recording of a few
    minutes cannot identify a longer one;
  - hysteresis Dahl lengths `hysteresis_frac` (0.01..0.3 D), the bench's friction lengths
    `friction_lengths_m` (20-500 um: a few encoder counts to a fraction of a mm; the bench's,
    not the object's).
- Two indentation elements, empty in the defaults and tried as one candidate basis,
  `INDENTATION`, which `haptics-train train` keeps where the validation recording's free run
  is closer with it (pipeline.py, `_candidates`; docs/laws.md, "Indentation shapes"):
  - powers (e/D)^p, p in `power_exponents` 1, 1.5, 2: the force of an indenter on an elastic
    half-space grows as the depth to the power 1 (flat punch), 1.5 (sphere, Hertz) or 2
    (cone) (Sneddon 1965, Int. J. Eng. Sci. 3:47). Every plateau and pole above starts
    linearly, so none has the sphere's zero slope at first contact;
  - branches whose relaxation time grows with the compression, tau_k e / D, tau_k in
    `depth_taus_s` 0.03..30 s (at the depth scale D) half a decade apart, emptied out of
    contact: in a poroelastic material (gels, soft tissue, open-cell sponges full of fluid)
    the solvent flows over the contact's size, so the relaxation time is a^2 / D_p, and under
    a sphere a^2 = R e (Hu, Zhao, Vlassak & Suo 2010, Appl. Phys. Lett. 96:121904); a
    viscoelastic material's does not depend on the depth (the branches above).
  With them `structured` shares its class with the bench's `poroelastic` law (docs/laws.md's
  class notes); the grids are the literature's shapes, none of the gel's constants.
- Fitted on the training rows, one coordinate at a time, bracketed by generic grids:
  the compression-set law, target = s_max (largest depth / D)^k (s_max = `set_frac` x D,
  0..0.3 D; k in 1..3), grown with time constant `set_tau_grow_s` (0.3..30 s) while loaded
  (deeper than `set_loaded_fraction` 0.3..0.9 of the largest depth), recovering with
  `set_tau_recover_s` (3..300 s) toward `set_keep_fraction` (0.2..0.8) of it. Compression set
  of flexible foams is 2-30 % of the compression in ASTM D3574 tests; a set of 0 (no set) is a
  candidate, so an object without one gets none. Each candidate is scored by the residual
  of the whole fit (the linear pass and `set_search_iterations` nonlinear passes, on every
  `set_search_stride`-th row); after the grid, each value is refined `set_refine` times toward
  its neighbours (geometric halves), so the law is fitted and the grid only brackets it. The
  linear pass alone, the first version's score, picked laws that doubled the error on the
  object's own force on validation (sponge 0.307 against 0.189 N; foam-b 0.549 against 0.206;
  foam-c 0.260 against 0.201: docs/laws.md). The chosen values are `set_law_`.

The target the bench records (the RFOB estimate) is the object's force plus the bench's own
friction; the friction is fitted as its own term on the rows where the probe slides (|v| above
`fit_min_speed_mps`: when it sticks, the friction is any value the force controller leaves,
which kinematics cannot tell; on an rt-loop recording, only once it has slid one way for 0.1 s,
since through a reversal the filtered velocity still has the old sign: contact_rows.py), in
contact and out of it, both ways: out of contact the target
is the friction alone (record-dataset.sh's free-air sweeps), which is what tells it from the
object's hysteresis and damping, the same columns inside the object. (Until 2026-11-27 the
rows out of contact counted only where their target exceeded the contact threshold, i.e.
moving toward the object: the fit then gave the sponge's bench 0.98 N and 3.2 N s/m where it
reads 0.91 N in contact, and the rendered object was 0.07 N too soft on every press:
docs/laws.md.) Inside the object a row counts where the object's own force, the target less
the friction in the direction of motion, exceeds the contact threshold, the friction being
what the free air shows (`free_air_friction_n`; contact_rows.py, which says why: until
2026-11-27 the target itself had to exceed it, and the end of every release went unfitted).
`predict` returns object + bench: what the RFOB reads in reproduction too. The ONNX graph
renders the object only (`predict_served`): the bench adds its own friction under the hand, so
rendering it as well would count it twice (issue 11).

The state steps once per row at the training period `dt` when fitted, and at the loop's period
`serve_dt_` when exported (`haptics.step_s`), like `prony`. Exported as a stateful
model: `h_in`/`h_out` carry [q_1..q_K (fixed times, then depth-scaled), u_1..u_M, set, largest
depth, previous e]; `c_in`/`c_out` carry the equilibrium force at the previous e in their
first element (the graph is built by hand: structured_graph.py).

Sequences layout (`models.base`): `fit(X, y, info)`, X one [n_i, 2] array (x, v) per recording,
rows in time order. Fitted attributes: `dt_`, `depth_scale_m_`, `basis_` (the resolved basis in
metres and seconds: what the graph and `predict` step), `set_law_`, `set_max_m_`, `a_`
(equilibrium: plateaus, poles, powers), `g_` (branches: fixed times, then depth-scaled), `h_`
(hysteresis), `hc_` (hysteresis of its own size: zeros but in `structured_hyst`), `c_`
(friction), `b_` (viscous), `train_info_`.
"""

from __future__ import annotations

import math
from itertools import repeat

import numpy as np
import onnx
from scipy.linalg import solve_banded
from scipy.ndimage import uniform_filter1d
from scipy.optimize import nnls
from scipy.signal import lfilter
from threadpoolctl import threadpool_limits

from ..data import SequenceInfo
from ..features import KINEMATICS
from ..holds import holds_name
from .base import ForceModel, check_sequences, serve_dt, step_dt
from .contact_rows import sliding_rows
from .structured_graph import DEPTH_FLOOR, structured_fused, structured_graph

#: The grids (see the module docstring for each range and why). Lengths are fractions of the
#: training data's depth scale D; times in seconds.
STRUCTURED_DEFAULT: dict = {
    "yield_frac": [0.02, 0.05, 0.1, 0.2, 0.4, 0.8],
    "densification_frac": [1.1, 1.3, 1.7, 2.5, 4.0],
    "densification_exponents": [1.0, 2.0, 3.0],
    "taus_s": [0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0],
    "hysteresis_frac": [0.01, 0.05, 0.3],
    "friction_lengths_m": [2e-5, 1e-4, 5e-4],
    # the indentation elements: none by default; `INDENTATION` is the candidate that has them
    "power_exponents": [],
    "depth_taus_s": [],
    # the compression-set law: each a grid, chosen by the training fit
    "set_frac": [0.0, 0.02, 0.05, 0.1, 0.2, 0.3],
    "set_exponent": [1.0, 2.0, 3.0],
    "set_tau_grow_s": [0.3, 1.0, 3.0, 10.0, 30.0],
    "set_loaded_fraction": [0.3, 0.5, 0.7, 0.9],
    "set_tau_recover_s": [3.0, 10.0, 30.0, 100.0, 300.0],
    "set_keep_fraction": [0.2, 0.5, 0.8],
    "set_sweeps": 2,
    "set_search_iterations": 2,
    "set_search_stride": 2,
    "set_refine": 2,
    "fit_min_speed_mps": 1e-4,
    "iterations": 2,
    # the bench's viscous term on the recorded velocity (0) or the path's over this window
    # (`bench_velocity`; `structured_path` sets it)
    "bench_velocity_window_s": 0.0,
    # hysteresis only as a fraction of F_eq (False), or also of its own size (True:
    # `constant_hysteresis`; `structured_hyst` sets it)
    "hysteresis_constant": False,
}

#: The indentation elements (module docstring): the candidate basis `haptics-train train`
#: tries beside the default one and keeps where the validation recording is closer with it.
INDENTATION: dict = {
    "power_exponents": [1.0, 1.5, 2.0],
    "depth_taus_s": [0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0],
}

#: The set law's grids, in the order the coordinate search visits them.
SET_KEYS = ("set_frac", "set_exponent", "set_tau_grow_s", "set_loaded_fraction",
            "set_tau_recover_s", "set_keep_fraction")  # fmt: skip


def dahl(path: np.ndarray, length: float, reset: np.ndarray | None = None) -> np.ndarray:
    """The Dahl state u in [-1, 1] along a path, exact for a straight step: u approaches the
    sign of the motion over `length` of travel, whatever the rate (rate-independent
    hysteresis). Where `reset`, u = 0. A plain loop on Python floats: the recursion is
    nonlinear (appending to a list, not storing into the array row by row: a fit calls it
    about 1,700 times, and that store was a third of its cost)."""
    ps = path.tolist()
    got: list[float] = []
    keep = got.append
    u = 0.0
    prev = ps[0] if ps else 0.0
    exp = math.exp
    resets = repeat(False, len(ps)) if reset is None else reset.tolist()
    for p, r in zip(ps, resets, strict=True):
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
        keep(u)
    return np.array(got, dtype=float)


def permanent_set(x: np.ndarray, dt: float, max_m: float, h: dict) -> np.ndarray:
    """The compression set along x (m): grows toward max_m (largest depth / reference)^k while
    the probe is loaded (deeper than a fraction of the largest depth, in contact), recovers
    toward a kept fraction of it otherwise (a compression-set law of the kind of rt-loop's
    sponge, docs/physics.md, "The simulated sponge bench"; its shape `h` is the fitted
    `set_law_`, never a material's)."""
    if max_m <= 0.0:
        return np.zeros(len(x))
    s = md = 0.0
    kg = min(dt / float(h["set_tau_grow_s"]), 1.0)
    kr = min(dt / float(h["set_tau_recover_s"]), 1.0)
    ref, lf, keep, k = (
        float(h["set_reference_m"]),
        float(h["set_loaded_fraction"]),
        float(h["set_keep_fraction"]),
        float(h["set_exponent"]),
    )
    got: list[float] = []
    store = got.append
    target = max_m * (md / ref) ** k
    for xn in x.tolist():
        if xn > md:
            # the target moves only with the deepest compression: a power per new depth,
            # not per row
            md = xn
            target = max_m * (md / ref) ** k
        loaded = xn > lf * md and xn - s > 0.0
        if loaded and s < target:
            s += (target - s) * kg
        elif not loaded and s > keep * target:
            s -= (s - keep * target) * kr
        store(s)
    return np.array(got, dtype=float)


def equilibrium_basis(e: np.ndarray, h: dict) -> np.ndarray:
    """[n, J] the equilibrium's basis at compression e (0 at e <= 0, each rising with e):
    tanh(e / y) plateaus and (1 - e/d)^-n - 1 poles, continued linearly past 0.95 d. `h` is the
    resolved basis (`basis_`: lengths in m, one exponent per pole), then the indentation
    powers (e / D)^p where it has them."""
    e = np.maximum(e, 0.0)
    cols = [np.tanh(e / y) for y in h["yield_m"]]
    for d, n in zip(h["densification_m"], h["densification_exponent"], strict=True):
        cap = 0.95 * d
        u = 1.0 - np.minimum(e, cap) / d
        cols.append(u**-n - 1.0 + n / d * u ** (-n - 1) * np.maximum(e - cap, 0.0))
    cols += [(e / h["depth_scale_m"]) ** p for p in h.get("power_exponents", [])]
    return np.column_stack(cols)


def equilibrium_size(h: dict) -> int:
    """The number of equilibrium columns (plateaus, poles, powers) of the resolved basis `h`."""
    return len(h["yield_m"]) + len(h["densification_m"]) + len(h.get("power_exponents", []))


def branch_count(h: dict) -> int:
    """The number of relaxation branches (fixed times, then depth-scaled) of the basis `h`."""
    return len(h["taus_s"]) + len(h.get("depth_taus_s", []))


def depth_times(e: np.ndarray, h: dict) -> np.ndarray:
    """[n, K'] the depth-scaled branches' time at each row, tau_k max(e/D, `DEPTH_FLOOR`); [n, 0]
    for a basis without them (one resolved before them has no `depth_scale_m` either)."""
    taus = np.asarray(h.get("depth_taus_s", []), dtype=float)
    if len(taus) == 0:
        return np.empty((len(e), 0))
    return taus[None, :] * np.maximum(e / h["depth_scale_m"], DEPTH_FLOOR)[:, None]


def depth_decays(times: np.ndarray, e: np.ndarray, dt: float) -> np.ndarray:
    """[n, K'] the per-row decays exp(-dt / time) of the depth-scaled branches at their
    `depth_times`, 0 out of contact (e <= 0: emptied)."""
    return np.where((e > 0.0)[:, None], np.exp(-dt / times), 0.0)


def varying_filter(u: np.ndarray, d: np.ndarray) -> np.ndarray:
    """q_n = d_n q_(n-1) + u_n from q = 0, for per-row decays d in [0, 1): the lower
    bidiagonal system (I - diag(d_1.., -1)) q = u, solved by LAPACK's banded solver in one
    pass (a Python loop over the rows took 4 s a fit; no pivoting happens, |d| < 1)."""
    if len(u) == 0:
        return u.copy()
    ab = np.ones((2, len(u)))
    ab[1, :-1] = -d[1:]
    ab[1, -1] = 0.0
    return solve_banded((1, 0), ab, u, check_finite=False)


class _Geometry:
    """What the object's columns need that the equilibrium's weights do not change, for one
    sequence and one set law: e (the compression less the set), the basis at e, the
    depth-scaled branches' times and decays, the contact mask, and the Dahl states (computed
    on first use: the linear pass needs none). A fit's passes share one set law and differ
    only in the weights, so `_fit` keeps one per sequence across its passes: the set, the
    basis and the Dahl states are loops or powers over every row, computed once instead of
    once a pass."""

    def __init__(self, x: np.ndarray, dt: float, set_m: float, h: dict) -> None:
        self.h = h
        self.e = x - permanent_set(x, dt, set_m, h)
        self.basis = equilibrium_basis(self.e, h)
        self.decay = np.exp(-dt / np.asarray(h["taus_s"], dtype=float))
        self.tk = depth_times(self.e, h)
        self.dd = depth_decays(self.tk, self.e, dt)
        self.inside = (self.e > 0.0)[:, None]
        self._dahl: list[np.ndarray] | None = None

    def dahl_states(self) -> list[np.ndarray]:
        """The Dahl states along the compression, reset out of contact, one per length."""
        if self._dahl is None:
            ep = np.maximum(self.e, 0.0)
            out = ~self.inside[:, 0]
            self._dahl = [dahl(ep, L, out) for L in self.h["hysteresis_lengths_m"]]
        return self._dahl


def _object_columns(
    x: np.ndarray,
    dt: float,
    set_m: float,
    a: np.ndarray | None,
    v: np.ndarray,
    h: dict,
    geo: _Geometry | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(columns of the object's force, e). With `a` (an equilibrium fitted already): basis,
    Maxwell branches driven by dF_eq, hysteresis F_eq u_m; without (the first pass): basis and
    velocity-driven branches. `geo`: the sequence's `_Geometry` for this set law (`x`, `dt`,
    `set_m` and `h`), when the caller keeps one."""
    g = _Geometry(x, dt, set_m, h) if geo is None else geo
    e, basis, decay, tk, dd = g.e, g.basis, g.decay, g.tk, g.dd
    # Every column is 0 where the probe is out of the object (e <= 0), as the served force
    # is: a branch's state still decays there after a release, and the fit, which counts the
    # rows out of contact (the bench's friction alone), must not credit it with a force the
    # model never renders.
    inside = g.inside
    taus = np.asarray(h["taus_s"], dtype=float)
    if a is None:
        br = [lfilter([t * (1 - d)], [1.0, -d], v) for t, d in zip(taus, decay, strict=True)]
        # a depth-scaled branch driven by v likewise, at its time of the row
        drive = tk * (1.0 - dd) * (v * inside[:, 0])[:, None]
        br += [varying_filter(drive[:, k], dd[:, k]) for k in range(dd.shape[1])]
        return np.column_stack([basis, *br]) * inside, e
    feq = basis @ a
    dfeq = np.diff(feq, prepend=0.0)
    br = [lfilter([1.0], [1.0, -d], dfeq) for d in decay]
    # emptied out of contact: driven only inside, and its decay 0 there
    br += [varying_filter(dfeq * inside[:, 0], dd[:, k]) for k in range(dd.shape[1])]
    us = g.dahl_states()
    hy = [feq * u for u in us]
    hy += [u for u, k in zip(us, constant_hysteresis(h), strict=True) if k]
    return np.column_stack([basis, *br, *hy]) * inside, e


def constant_hysteresis(h: dict) -> list[bool]:
    """Which Dahl hysteresis states also carry a force of their own size, not a fraction of
    F_eq (`hysteresis_constant`): those longer than the bench's longest friction length, so
    the object's hysteresis is never the bench's friction under another name."""
    if not h.get("hysteresis_constant", False):
        return [False] * len(h["hysteresis_lengths_m"])
    longest = max((float(f) for f in h["friction_lengths_m"]), default=0.0)
    return [float(L) > longest for L in h["hysteresis_lengths_m"]]


def path_velocity(x: np.ndarray, dt: float, window_s: float) -> np.ndarray:
    """The probe's velocity read off its path, centred so it does not lag: x averaged over
    `window_s` (ends held), then differenced. It looks ahead, so it only ever explains a
    recording (the bench's friction in the target), never a served force."""
    n = int(round(window_s / dt)) if dt > 0.0 else 1
    xs = uniform_filter1d(x, n, mode="nearest") if 1 < n < len(x) else x
    return np.gradient(xs, dt) if len(xs) > 1 else np.zeros(len(x))


def bench_velocity(x: np.ndarray, v: np.ndarray, h: dict, dt: float) -> np.ndarray:
    """The velocity the bench's viscous term is a multiple of: the recorded one (rt-loop's
    filtered estimate, 33 ms behind at its default g_v), or with `bench_velocity_window_s`
    the path's (`path_velocity`). A model saved before the key existed used the recorded one."""
    w = float(h.get("bench_velocity_window_s", 0.0))
    return path_velocity(x, dt, w) if w > 0.0 else v


def _bench_columns(x: np.ndarray, v: np.ndarray, h: dict, dt: float) -> np.ndarray:
    """Dahl friction states on x and the viscous term (+v, -v: its sign left free)."""
    v = bench_velocity(x, v, h, dt)
    return np.column_stack([*(dahl(x, L) for L in h["friction_lengths_m"]), v, -v])


def _middle(grid: list) -> float:
    """The grid's middle value (the coordinate search's start)."""
    return float(grid[(len(grid) - 1) // 2])


def resolve_basis(h: dict, depth: float) -> dict:
    """The basis in metres and seconds for a depth scale D (m): the grids of `h` (fractions of
    D) made lengths; one (length, exponent) pair per pole."""
    poles = [(p * depth, float(n)) for p in h["densification_frac"]
             for n in h["densification_exponents"]]  # fmt: skip
    return {
        "yield_m": [float(y) * depth for y in h["yield_frac"]],
        "densification_m": [d for d, _ in poles],
        "densification_exponent": [n for _, n in poles],
        "taus_s": [float(t) for t in h["taus_s"]],
        "hysteresis_lengths_m": [float(f) * depth for f in h["hysteresis_frac"]],
        "friction_lengths_m": [float(f) for f in h["friction_lengths_m"]],
        "depth_scale_m": float(depth),
        "power_exponents": [float(p) for p in h.get("power_exponents", [])],
        "depth_taus_s": [float(t) for t in h.get("depth_taus_s", [])],
        "bench_velocity_window_s": float(h.get("bench_velocity_window_s", 0.0)),
        "hysteresis_constant": bool(h.get("hysteresis_constant", False)),
    }


def nnls_gram(m: np.ndarray, y: np.ndarray) -> np.ndarray:
    """argmin ||m c - y|| over c >= 0, solved on the Gram matrix: with m'm = L L' (Cholesky),
    ||m c - y||^2 = ||L' c - L^-1 m'y||^2 + const, an NNLS of [k, k] instead of [n, k]. Why:
    scipy's NNLS on the 145,000 training rows took 1.1 s a pass, 80 % of the fit; this takes a
    few ms, so the set law's search can afford whole fits. A ridge of 1e-10 of the diagonal's
    mean keeps the factorisation defined when two columns coincide (m is column-scaled)."""
    g = m.T @ m
    g[np.diag_indices_from(g)] += 1e-10 * float(np.mean(np.diag(g))) + 1e-300
    low = np.linalg.cholesky(g)
    rhs = np.linalg.solve(low, m.T @ y)
    coef, _ = nnls(low.T, rhs, maxiter=50 * m.shape[1])
    return coef


def _between(grid: list, value: float, level: int) -> list[float]:
    """The points between `value` and its grid neighbours at 1/2^(level+1) of the way, in log
    (geometric) terms; 0 is never a neighbour (a set of 0 is its own candidate)."""
    g = [float(x) for x in grid if float(x) > 0.0]
    if value <= 0.0 or len(g) < 2:
        return []
    lo = max((x for x in g if x < value), default=None)
    hi = min((x for x in g if x > value), default=None)
    f = 0.5 ** (level + 1)
    return [value * (n / value) ** f for n in (lo, hi) if n is not None]


def _thin(rows: list, k: int, h: dict) -> list:
    """The training rows at every k-th row (the states stepped at k times the period: the Dahl
    states are rate-independent, the branches exact for the increments that drive them), for
    the set law's search."""
    if k <= 1:
        return rows
    out = []
    for x, v, t, keep, dt, _ in rows:
        x, v = x[::k], v[::k]
        out.append((x, v, t[::k], keep[::k], dt * k, _bench_columns(x, v, h, dt * k)))
    return out


def _set_shape(law: dict, depth: float) -> dict:
    """The set law's shape as `permanent_set` and the graph read it (reference = D)."""
    return {
        "set_reference_m": depth,
        "set_exponent": float(law["set_exponent"]),
        "set_tau_grow_s": float(law["set_tau_grow_s"]),
        "set_loaded_fraction": float(law["set_loaded_fraction"]),
        "set_tau_recover_s": float(law["set_tau_recover_s"]),
        "set_keep_fraction": float(law["set_keep_fraction"]),
    }


class StructuredModel(ForceModel):
    algo = "structured"
    kind = "stateful"
    #: its state steps in time (decays exp(-dt / tau)): `predict_at` steps it at a
    #: recording's own period
    steps_in_time = True
    layout = "sequences"
    defaults = STRUCTURED_DEFAULT

    def __init__(self, hyper: dict | None = None, *, seed: int = 0, progress: bool = False) -> None:
        super().__init__(KINEMATICS[:2], "x_v", hyper, seed=seed, progress=progress)

    @property
    def name(self) -> str:
        return self.algo + holds_name(self.hyper)  # `structured_holds`: holds.py

    @property
    def state_size(self) -> int:
        h = self.hyper
        return (len(h["taus_s"]) + len(h.get("depth_taus_s", [])) + len(h["hysteresis_frac"])
                + 3)  # fmt: skip

    def fit(
        self, X: list[np.ndarray], y: list[np.ndarray], info: list[SequenceInfo]
    ) -> StructuredModel:
        # One BLAS thread: the fit's products are [145,000 x 50]; on a machine whose cores
        # the loop and a build share, OpenBLAS's threads wait on each other (26 s fit with one
        # thread against 116 s with two, measured with a build running).
        with threadpool_limits(1, user_api="blas"):
            return self._fit_sequences(X, y, info)

    def _fit_sequences(
        self, X: list[np.ndarray], y: list[np.ndarray], info: list[SequenceInfo]
    ) -> StructuredModel:
        seqs, targets = check_sequences(X, y, len(self.features), len(info))
        h = self.hyper
        self.dt_ = step_dt("structured", info, one_rate=False)
        self.serve_dt_ = serve_dt("structured", info)
        # Fitted on every stride-th row, the states stepped at that rate (the Dahl states are
        # rate-independent, the branches exact for the increments they are driven by).
        # sliding, out of contact or pressing the object (contact_rows.py)
        friction, thinned = sliding_rows(seqs, targets, info, float(h["fit_min_speed_mps"]))
        rows = []
        depth = 0.0
        # each recording stepped at its own rows' period (as lawfree)
        for (x, v, t, keep, k), i in zip(thinned, info, strict=True):
            step = k / i.sample_rate_hz
            rows.append((x, v, t, keep, step, _bench_columns(x, v, h, step)))
            if keep.any():
                depth = max(depth, float(x[keep].max()))
        if depth <= 0.0:
            raise ValueError("structured: no training row in contact (x > 0 with force)")
        self.depth_scale_m_ = depth
        self.basis_ = resolve_basis(h, depth)
        # The compression-set law, one coordinate at a time over its grids, each candidate
        # scored by the first (linear) pass's residual; the full passes then run once.
        search_rows = _thin(rows, int(h["set_search_stride"]), h)
        law = {key: _middle(h[key]) for key in SET_KEYS}
        law["set_frac"] = 0.0
        scores: dict[str, float] = {}

        def score(cand: dict) -> float:
            key = repr(sorted(cand.items()))
            if key not in scores:
                b = {**self.basis_, **_set_shape(cand, depth)}
                scores[key] = self._fit(
                    search_rows, float(cand["set_frac"]) * depth, b, int(h["set_search_iterations"])
                )["rmse"]
            return scores[key]

        best_score = score(law)
        for _ in range(int(h["set_sweeps"])):
            moved = False
            for key in SET_KEYS:
                if key != "set_frac" and law["set_frac"] == 0.0:
                    continue  # no set: its shape does not matter
                for val in h[key]:
                    cand = {**law, key: float(val)}
                    sc = score(cand)
                    if sc < best_score - 1e-12:
                        law, best_score, moved = cand, sc, True
            if not moved:
                break
        # Between the grid's points: each value tried at the geometric middle toward both
        # neighbours, then the quarter, ... (`set_refine` halvings): the law is fitted, the
        # grid only brackets it.
        for level in range(int(h["set_refine"])):
            for key in SET_KEYS:
                if key != "set_frac" and law["set_frac"] == 0.0:
                    continue
                for val in _between(h[key], law[key], level):
                    cand = {**law, key: val}
                    sc = score(cand)
                    if sc < best_score - 1e-12:
                        law, best_score = cand, sc
        self.basis_.update(_set_shape(law, depth))
        self.set_law_ = dict(law)
        self.set_max_m_ = float(law["set_frac"]) * depth
        fit = self._fit(rows, self.set_max_m_, self.basis_, int(h["iterations"]))
        coef, nb, nk = fit["coef"], fit["nb"], branch_count(self.basis_)
        nm = len(self.basis_["hysteresis_lengths_m"])
        self.a_ = coef[:nb]
        self.g_ = coef[nb : nb + nk]
        self.h_ = coef[nb + nk : nb + nk + nm]
        mask = np.asarray(constant_hysteresis(self.basis_), dtype=bool)
        self.hc_ = np.zeros(nm)
        self.hc_[mask] = coef[nb + nk + nm : nb + nk + nm + int(mask.sum())]
        bench = coef[nb + nk + nm + int(mask.sum()) :]
        self.c_ = bench[:-2]
        self.b_ = float(bench[-2] - bench[-1])
        self.n_features_in_ = len(self.features)
        self.train_info_ = {
            "rows": fit["rows"],
            "dt_s": self.dt_,
            "serve_dt_s": self.serve_dt_,
            "depth_scale_m": depth,
            "free_air_friction_n": friction,
            "set_law": self.set_law_,
            "set_max_m": self.set_max_m_,
            "set_candidates_scored": len(scores),
            "set_search_rmse": best_score,
            "fit_rmse": fit["rmse"],
            "equilibrium": self.a_.tolist(),
            "branch_gains": self.g_.tolist(),
            "hysteresis": self.h_.tolist(),
            "hysteresis_constant_n": self.hc_.tolist(),
            "friction_n": self.c_.tolist(),
            "viscous_ns_per_m": self.b_,
        }
        return self

    def _fit(self, rows: list, set_m: float, b: dict, iterations: int) -> dict:
        """The whole fit for one set law: a linear pass (velocity-driven branches), then
        `iterations` passes with the branches and hysteresis driven by the equilibrium of the
        pass before."""
        a = None
        geos: list[_Geometry] = []  # one per sequence, shared by the passes (one set law)
        for _ in range(1 + iterations):
            fit = self._fit_pass(rows, set_m, a, b, geos)
            a = fit["coef"][: fit["nb"]]
        return fit

    def _fit_pass(
        self, rows: list, set_m: float, a: np.ndarray | None, b: dict, geos: list[_Geometry]
    ) -> dict:
        mats, ys = [], []
        nb = equilibrium_size(b)
        for i, (x, v, t, keep, dt, bench) in enumerate(rows):
            if i == len(geos):
                geos.append(_Geometry(x, dt, set_m, b))
            obj, _ = _object_columns(x, dt, set_m, a, v, b, geos[i])
            mats.append(np.column_stack([obj, bench])[keep])
            ys.append(t[keep])
        m, y = np.concatenate(mats), np.concatenate(ys)
        scale = np.abs(m).max(axis=0)
        scale[scale == 0] = 1.0
        coef = nnls_gram(m / scale, y) / scale
        rmse = float(np.sqrt(np.mean((m @ coef - y) ** 2)))
        return {"coef": coef, "nb": nb, "rmse": rmse, "rows": int(len(y))}

    def _parts(self, X: np.ndarray, dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        self._check_fitted()
        xv = self._check_X(X)
        x, v = xv[:, 0], xv[:, 1]
        dt = self.dt_ if dt is None else dt
        obj, e = _object_columns(x, dt, self.set_max_m_, self.a_, v, self.basis_)
        hc = self.hysteresis_forces()[np.asarray(constant_hysteresis(self.basis_), dtype=bool)]
        f = obj @ np.concatenate([self.a_, self.g_, self.h_, hc])
        served = np.where(e > 0.0, np.maximum(f, 0.0), 0.0)
        cols = _bench_columns(x, v, self.basis_, dt)  # ..., +v, -v: the viscous term's velocity
        bench = cols[:, :-2] @ self.c_ + self.b_ * cols[:, -2]
        return served, bench

    def hysteresis_forces(self) -> np.ndarray:
        """`hc_`, the hysteresis forces of their own size (N, one per Dahl state): zeros for a
        model pickled before they existed (what `predict` and both graphs render)."""
        hc = getattr(self, "hc_", None)
        return np.zeros(len(self.h_)) if hc is None else np.asarray(hc, dtype=np.float64)

    def predict(self, X: np.ndarray, dt: float | None = None) -> np.ndarray:
        """The force the RFOB reads: the object's plus the bench's friction (one sequence,
        from zero state, stepped at `dt`: default the training rows' period)."""
        served, bench = self._parts(X, dt)
        return served + bench

    def predict_served(self, X: np.ndarray, dt: float | None = None) -> np.ndarray:
        """The object's force alone: what the ONNX graph renders, stepped at `dt` (default:
        the training rows' period; the graph steps at `serve_dt_`, the loop's)."""
        return self._parts(X, dt)[0]

    def to_onnx(self, fused: bool = True) -> onnx.ModelProto:
        """One `ai.haptics:StructuredStep` node (the fused operator: needs
        libhaptics_fused_ops.so where it runs), or with `fused=False` the multi-node graph
        of standard operators (same state, same step)."""
        self._check_fitted()
        return structured_fused(self) if fused else structured_graph(self)


#: `structured_path`'s window (`path_velocity`): 10 ms, five rows at the fit's 2 ms, enough
#: to average the encoder's 5 um counts (2.5 mm/s a row alone) and short beside a hand's press;
#: set once, before the test that adopted the variant, and never tuned (docs/laws.md).
PATH_WINDOW_S = 0.01


class StructuredPathModel(StructuredModel):
    """`structured` whose bench term's viscous friction is a multiple of the path's velocity
    (`path_velocity`, no lag) instead of the recorded, filtered one. The object's part and
    the served graph are the same kind; only what the fit attributes to the bench moves, and
    with it the object's fast response. Which of the two a hand feels closer is not what
    validation shows (docs/laws.md, "The bench's velocity"): the study chooses by felt force
    on its ranking runs, so both are candidates there."""

    algo = "structured_path"
    defaults = {**STRUCTURED_DEFAULT, "bench_velocity_window_s": PATH_WINDOW_S}


#: `structured_hyst`'s hysteresis lengths, fractions of D: from 1 % of the deepest press
#: (the default grid's shortest) to half of it, about half a decade apart; the lengths over which
#: a rubber-like or granular material's hysteresis saturates after a reversal are a few per
#: cent to tens of per cent of its strain range (Bouc-Wen fits of elastomer pads and
#: isolators: Ismail, Ikhouane & Rodellar 2009, Arch. Comput. Methods Eng. 16:161). Only
#: those longer than the bench's longest friction length get a force of their own.
HYST_FRAC = [0.01, 0.03, 0.05, 0.1, 0.2, 0.3, 0.5]


class StructuredHystModel(StructuredPathModel):
    """`structured_path` whose Dahl hysteresis states also carry a force of their own size
    (`constant_hysteresis`), not only a fraction of F_eq: a hysteretic material whose loop
    keeps its height at every depth (a Bouc-Wen pad's z, bounded whatever the compression) is
    out of reach of F_eq u alone, and `structured` felt such an object 0.70 N off (docs/laws.md,
    "A hysteresis of the object's own size"). Its states are `structured`'s Dahl states on a
    finer grid (`HYST_FRAC`); the served kernel is the same, with one more weight per state."""

    algo = "structured_hyst"
    defaults = {**StructuredPathModel.defaults, "hysteresis_constant": True,
                "hysteresis_frac": HYST_FRAC}  # fmt: skip
