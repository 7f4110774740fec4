"""`lawfree`: a stateful model that assumes no law of the object, only that its force depends on
the history of the motion through a fading memory in time and a rate-independent memory of
the path, learned from data alone; kinematics (x, v) in, force out.

Why: `structured` and `prony` are shaped like particular laws (a foam, a Prony solid) and lose
accuracy the further an object's law is from theirs; the general learners (forests on memory
features, feedback networks, LSTMs) lost to a three-coefficient spring-damper on objects whose
law no model shares (issue 23). This model is a generic operator: any causal, time-invariant
operator with fading memory is approximated by a bank of stable linear filters followed by a
static polynomial map (Boyd & Chua, "Fading memory and the problem of approximating nonlinear
operators with Volterra series", IEEE Trans. Circuits Syst. 32(11), 1985), and rate-independent
hysteresis of the Preisach/Prandtl-Ishlinskii class by a superposition of play operators
(Krasnosel'skii & Pokrovskii, Systems with Hysteresis, 1989; Brokate & Sprekels 1996). So:

    u      = max(x, 0) / D                               compression, scaled by the data's depth
    s_k(t) = d_k s_k(t - dt) + (1 - d_k) u(t)            fading memory, d_k = exp(-dt / tau_k)
    p_r(t) = min(u + r, max(u - r, p_r(t - dt)))         play operators of half-width r (path)
    d(t)   = u - max(u(t'), t' <= t)                     optional: the depth below the deepest
                                                         compression so far (irreversible)
    q      = [u, v/V, u - s_k, u - p_r,                  inputs: now and the memory terms
              (d, c (1 - exp(d / c)))]
    phi    = [1, w, w^2, 1 - exp(-w/a_1), .., 1 - exp(-w/a_S)],  w = min(u, 1)
    object = max(0, sum_j q_j sum_i W_ij phi_i) x (x > 0)     (memory terms: W_1j = 0)
    bench  = sum_l c_l z_l                               the bench's friction (not rendered),
                                                         c_l >= 0: it dissipates

tau_k 0.01..100 s half a decade apart, r 0.005..0.4 of D, a_s 0.1, 0.3 of D and c 0.02, 0.05,
0.15 of D are grids of the time, path and depth scales, not of any material; D (the largest
compression) and V (the 99th percentile of |v|) are measured on the training data. How far
the memory reaches is the data's to say: `haptics-train train` fits the filters up to 1, 10
and 100 s and keeps the span whose validation free run is near the best both on the sliding
rows and over every row
(`lawfree_selection.LAWFREE_SPANS_S`, `choose_on_both`): a filter much slower than the training
recordings is fitted as a copy of the compression and extrapolates when a slower motion moves
it, while a foam's compression set needs the slow ones (docs/laws.md, "`lawfree`'s memory
span"). The irreversible memory (`damage_frac`, off by default) is a third kind: a fading
memory forgets and a play is wiped out by a larger excursion, but a material that softens
below the deepest load it has carried (the Mullins effect of filled rubbers, the
preconditioning of tissues, a foam's damage) remembers that load for good; `haptics-train
train` tries it once on the grid's choice and keeps it where validation prefers it
(`lawfree_selection.LAWFREE_DAMAGE_FRAC`). Every input's weight is a function
of the depth (phi), so a memory may grow with the compression as a relaxing or hysteretic force
does in soft materials: as a power (w, w^2) or saturating within a tenth or a third of the
deepest press (1 - exp(-w/a): soft materials stiffen early, and their memory with them), up to
the deepest training press (beyond it the force goes on linearly in u). A network readout
over the same memory (lawfree_net.py) is a choice `haptics-train train` makes on validation:
kept only where validation prefers it clearly, since a network fitted without that guard
extrapolated badly to rates it was not fitted on. A memory's weight has no
constant term (`memory_at_surface` false): the object holds no force at its own surface, and a
hysteresis of one size at every depth is the bench's friction, not the object's
(`_readout_mask`). Measured on the validation recordings of the six bench objects against
the object's own force (F_object), these two choices took the object's error from 0.38-1.03 N
to 0.34-0.49 N and the friction the fit identifies from 1.24-2.05 N to 1.08-1.30 N (the
simulated bench's is about 1 N). The readout
and the bench's friction (Dahl states of x, the Coulomb part of what `structured` identifies)
are fitted together by bounded ridge least squares on the rows where the probe slides (on an
rt-loop recording, once it has slid one way for 0.1 s: contact_rows.py), in contact and out
of it: out of contact the target is the friction alone, which is what tells
the friction from a hysteresis of the object (inside the object they look alike). The
friction is fitted because the recorded target (the RFOB estimate) holds it; rendering it
would count the bench's friction twice, so the graph renders the object only.

Free run by construction: no state depends on the model's own output (the force is not fed
back), so the one-step prediction IS the free run over the whole recording, and the state is
bounded whatever the input (the filters are stable, a play stays within r of u): the model
cannot drift. Dissipation is not enforced (the readout's signs are free); `train_info_`
reports the work the rendered object does over the training recordings (> 0: it absorbs), and
the fit warns when one of them gets energy back (`metrics.active_work_note`).

The state steps once per row at the training period `dt` when fitted, and at the loop's period
`serve_dt_` when exported (`haptics.step_s`), like `structured`. Exported as a
stateful model (docs/model-contract.md): `h_in`/`h_out` carry [s_1..s_K, p_1..p_P] (and
u_max last, with the irreversible memory); `c_in`/
`c_out` are passed through by the multi-node graph; the fused node (the default export,
fused-ops/src/lawfree.rs) carries the filters' low parts in `c` (a float32 state cannot hold
the slow filters' steps). The graph is built by hand (lawfree_graph.py): the state updates
and the readout as a few vector nodes. The filters' coefficients are rounded to float32 in
`predict` too, so it agrees with the graph within float32 arithmetic.

Sequences layout (`models.base`): `fit(X, y, info)`. Fitted attributes: `dt_`,
`depth_scale_m_`, `speed_scale_mps_`, `widths_`, `depth_scales_` (the a_s), `damage_fracs_`
(the c; empty without the irreversible memory), `w_` (the
readout's weights, (3 + S) blocks of one weight per input, zeros where `_readout_mask` left
a term out), `c_`
(friction), `net_` (the network readout, `NetReadout`, or None: `network`), `train_info_`.
"""

from __future__ import annotations

import time

import numpy as np
import onnx
from scipy.optimize import lsq_linear
from scipy.signal import lfilter

from ..data import SequenceInfo
from ..features import KINEMATICS
from ..holds import holds_name
from ..metrics import active_work_note, loop_work
from .base import ForceModel, check_sequences, serve_dt, served_dt, step_dt
from .contact_rows import sliding_rows
from .lawfree_graph import lawfree_fused, lawfree_graph
from .lawfree_net import NetReadout, with_w
from .structured import dahl

#: one recording's (x, v, target, the rows the readout is fitted on, the rows' period)
FitRows = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]

LAWFREE_DEFAULT: dict = {
    "taus_s": [0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0],
    "play_frac": [0.005, 0.02, 0.05, 0.15, 0.4],
    "friction_lengths_m": [2e-5, 1e-4, 5e-4],
    "fit_min_speed_mps": 1e-4,
    "ridge": 1e-4,
    "memory_at_surface": False,
    "readout_depth_scales": [0.1, 0.3],
    "damage_frac": [],
}


def damage_inputs(d: np.ndarray, fracs: list[float] | tuple[float, ...]) -> list[np.ndarray]:
    """The irreversible memory's readout inputs from d = u - u_max (<= 0, the depth below the
    deepest compression so far): d itself and c (1 - exp(d / c)) for each scale c (fractions
    of D), each 0 on a virgin loading and saturating at c as the probe backs off."""
    return [d, *(c * (1.0 - np.exp(d / c)) for c in fracs)]


def plays(u: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """[n, P] play operators of u (zero initial state), one per half-width r: p follows u
    once u leaves [p - r, p + r] (p = clamp(p, u - r, u + r)). A plain loop on Python floats,
    one width at a time: the recursion is nonlinear, and a row of numpy calls on P values
    cost about ten times as much (2.2 s on a validation recording of 785,000 rows, 4.4 s of
    the 7.7 s of scoring one candidate of `lawfree`'s grid)."""
    ul = u.tolist()
    out = np.empty((len(ul), len(widths)))
    for k, r in enumerate(widths.tolist()):
        col: list[float] = []
        keep = col.append
        p = 0.0
        for un in ul:
            lo = un - r
            if p < lo:
                p = lo
            else:
                hi = un + r
                if p > hi:
                    p = hi
            keep(p)
        out[:, k] = col
    return out


def _readout_mask(n_inputs: int, n_basis: int, memory_at_surface: bool) -> np.ndarray:
    """Which of `_readout_columns`' terms the fit may use. Without `memory_at_surface`, the
    memory terms (every input after u and v/V) enter only times w and w^2, so their force
    vanishes with the compression: an object holds no force at its own surface, and a
    hysteresis of the same size at every depth is what the bench's friction looks like inside
    the object; left free, the object's depth-free play terms and the friction's Dahl states
    are the same columns in contact, and the fit gave the friction 1.5-2x what `structured`
    identifies (foam-b: 2.05 N against 0.93 N), a rendered loop too narrow by the difference."""
    keep = np.ones(n_basis * n_inputs, dtype=bool)
    if not memory_at_surface:
        keep[2:n_inputs] = False
    return keep


def _readout_columns(
    z: np.ndarray, depth_scales: list[float] | tuple[float, ...] = ()
) -> np.ndarray:
    """[n, (3 + S) q] the readout's terms from its inputs q = [u, v/V, m_1..m_M] (m: the memory
    terms u - s_k, u - p_r): every input times 1, w, w^2 and 1 - exp(-w/a_s) (S depth scales)
    with w = min(u, 1) (so the compression's powers u, u^2, u^3, and a memory whose weight
    grows with the depth, as a relaxing or hysteretic force does in soft materials): a readout
    of a filter bank (Boyd & Chua 1985), block by block (all inputs times 1, then all times w,
    ...: the order of `w_`, the graph's and the fused operator's). Past the deepest training
    press (u > 1) the weights stop growing and the force continues linearly in u: a cubic
    fitted up to D would run away beyond it (the study's hand presses deeper than the
    force-controlled recordings)."""
    w = np.minimum(z[:, :1], 1.0)
    sat = [(1.0 - np.exp(-w / a)) * z for a in depth_scales]
    return np.column_stack([z, w * z, w * w * z, *sat])


class LawFreeModel(ForceModel):
    algo = "lawfree"
    kind = "stateful"
    #: its state steps in time (decays exp(-dt / tau)): `predict_at` steps it at a
    #: recording's own period
    steps_in_time = True
    layout = "sequences"
    defaults = LAWFREE_DEFAULT

    def __init__(self, hyper: dict | None = None, *, seed: int = 0, progress: bool = False) -> None:
        super().__init__(KINEMATICS[:2], "x_v", hyper, seed=seed, progress=progress)

    @property
    def name(self) -> str:
        return "lawfree" + holds_name(self.hyper)  # `lawfree_holds`: holds.py

    @property
    def state_size(self) -> int:
        return len(self.hyper["taus_s"]) + len(self.hyper["play_frac"]) + int(self.has_damage)

    @property
    def damage_fracs(self) -> list[float]:
        """The irreversible memory's scales c (none for a model pickled before it existed)."""
        return list(getattr(self, "damage_fracs_", ()))

    @property
    def has_damage(self) -> bool:
        """Whether the model carries the irreversible memory (u_max, one more state)."""
        return bool(self.hyper.get("damage_frac"))

    def _inputs(self, x: np.ndarray, v: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(the readout's inputs q [n, 2 + K + P (+ 1 + C)], contact mask) along one sequence
        stepped at `dt`; with the irreversible memory, d = u - u_max and its C saturating
        functions last."""
        u = np.maximum(x, 0.0) / self.depth_scale_m_
        contact = x > 0.0
        d = np.exp(-dt / np.asarray(self.hyper["taus_s"], dtype=float))
        a, b = d.astype(np.float32).astype(float), (1.0 - d).astype(np.float32).astype(float)
        s = np.column_stack([lfilter([bk], [1.0, -ak], u) for ak, bk in zip(a, b, strict=True)])
        p = plays(u, self.widths_)
        vn = np.where(contact, v / self.speed_scale_mps_, 0.0)
        cols = [u, vn, u[:, None] - s, u[:, None] - p]
        if self.has_damage:
            cols += damage_inputs(u - np.maximum.accumulate(u), self.damage_fracs)
        return np.column_stack(cols), contact

    def fit(
        self, X: list[np.ndarray], y: list[np.ndarray], info: list[SequenceInfo],
        holdout: list[np.ndarray] | None = None,
    ) -> LawFreeModel:  # fmt: skip
        """`holdout`: per sequence, the rows left out of the fit (a boolean mask as long as the
        sequence; `blocked_validation.py` scores the model on them). The memory still runs
        along every row: a held-out block keeps the history that leads into it."""
        h = self.hyper
        t0 = time.perf_counter()
        self.dt_ = step_dt("lawfree", info, one_rate=False)
        self.serve_dt_ = serve_dt("lawfree", info)
        self.net_ = None
        friction, picked = self._fit_rows(X, y, info, holdout)
        xs = np.concatenate([x[kp & (x > 0)] for x, _, _, kp, _ in picked])
        if len(xs) == 0:
            raise ValueError("lawfree: no training row in contact with the probe sliding")
        self.depth_scale_m_ = float(xs.max())
        vs = np.concatenate([np.abs(v[kp & (x > 0)]) for x, v, _, kp, _ in picked])
        self.speed_scale_mps_ = float(max(np.percentile(vs, 99), 1e-6))
        self.widths_ = np.asarray(h["play_frac"], dtype=float)
        mats, ts = [], []
        self.depth_scales_ = [float(a) for a in h["readout_depth_scales"]]
        if any(not (a > 0) for a in self.depth_scales_):
            raise ValueError(f"lawfree: readout_depth_scales must be > 0, got {self.depth_scales_}")
        self.damage_fracs_ = [float(c) for c in h.get("damage_frac") or []]
        if any(not (c > 0) for c in self.damage_fracs_):
            raise ValueError(f"lawfree: damage_frac must be > 0, got {self.damage_fracs_}")
        n_damage = 1 + len(self.damage_fracs_) if self.has_damage else 0
        mask = _readout_mask(2 + len(h["taus_s"]) + len(self.widths_) + n_damage,
                             3 + len(self.depth_scales_), bool(h["memory_at_surface"]))  # fmt: skip
        for x, v, t, keep, dt in picked:
            z, contact = self._inputs(x, v, dt)
            obj = _readout_columns(z, self.depth_scales_)[:, mask] * contact[:, None]
            bench = np.column_stack([dahl(x, L) for L in h["friction_lengths_m"]])
            mats.append(np.column_stack([obj, bench])[keep])
            ts.append(t[keep])
        a, t = np.concatenate(mats), np.concatenate(ts)
        nf = len(h["friction_lengths_m"])
        scale = np.abs(a).max(axis=0)
        scale[scale == 0] = 1.0
        # ridge on every weight (a generic readout must not chase noise, and the friction must
        # not buy what the object's terms explain), the bench's friction >= 0 (it dissipates).
        # No viscous bench term: inside the object it cannot be told from the object's own
        # v-terms when the probe seldom slides out of contact (force-controlled ramps), and a
        # large one cancelled by the object made a rendered object that gives energy back.
        # With the free-air recording (record-dataset.sh's train_air) it can be identified:
        # tried, bounded >= 0, it came out 0 on the sponge (the simulated bench's sliding
        # friction falls slightly with speed over 0.5-60 mm/s), so it stays out.
        ridge = float(h["ridge"]) * np.sqrt(len(t))
        n_obj = a.shape[1] - nf
        lo = np.r_[np.full(n_obj, -np.inf), np.zeros(nf)]
        sol = lsq_linear(np.vstack([a / scale, ridge * np.eye(a.shape[1])]),
                         np.r_[t, np.zeros(a.shape[1])],
                         bounds=(lo, np.full(a.shape[1], np.inf)))  # fmt: skip
        coef = sol.x / scale
        # the weights of every readout term (the ones the mask left out at 0): what the graph
        # and the fused operator carry
        self.w_ = np.zeros(len(mask))
        self.w_[mask] = coef[:n_obj]
        self.c_ = coef[n_obj:]
        resid = a @ coef - t
        self.n_features_in_ = len(self.features)
        self.train_info_ = {
            "rows": int(len(t)),
            "dt_s": self.dt_,
            "serve_dt_s": self.serve_dt_,
            "depth_scale_m": self.depth_scale_m_,
            "speed_scale_mps": self.speed_scale_mps_,
            "free_air_friction_n": friction,
            # the largest force fitted: what the free air's friction is measured against
            # (lawfree_selection.network_skipped)
            "target_max_n": float(np.max(np.abs(t))),
            "readout_terms": int(n_obj),
            "fit_rmse_n": float(np.sqrt(np.mean(resid**2))),
            "friction_n": self.c_.tolist(),
            "fit_seconds": round(time.perf_counter() - t0, 2),
        }
        # the work the rendered object does over each training recording (> 0: it absorbs);
        # dissipation is not enforced (the readout's signs are free), so say when it is not
        works = [
            loop_work(x, self.predict_served(np.column_stack([x, v]), dt))
            for x, v, _, _, dt in picked
        ]
        self.train_info_["object_work_j_per_recording"] = works
        if (note := active_work_note(works)) is not None:
            print(f"[train] {self.name}: warning: {note}", flush=True)
        return self

    def _fit_rows(
        self, X: list[np.ndarray], y: list[np.ndarray], info: list[SequenceInfo],
        holdout: list[np.ndarray] | None = None,
    ) -> tuple[float, list[FitRows]]:  # fmt: skip
        """(the friction the free air shows, each recording's (x, v, target, the rows the
        readout is fitted on, its rows' period)), as `fit` picks them."""
        seqs, targets = check_sequences(X, y, len(self.features), len(info))
        if holdout is not None and [len(m) for m in holdout] != [len(x) for x in seqs]:
            raise ValueError("lawfree: holdout needs one mask per sequence, as long as it")
        # sliding rows: in contact where the object's force is above the contact threshold, and
        # out of contact too, where the object is 0 and the target is the bench's friction
        # alone: that is what tells the friction from a hysteresis of the object, which inside
        # the object looks the same (a force step with the direction of motion); contact_rows.py
        friction, thinned = sliding_rows(seqs, targets, info,
                                         float(self.hyper["fit_min_speed_mps"]))  # fmt: skip
        if holdout is not None:
            thinned = [(x, v, t, keep & ~np.asarray(out, dtype=bool)[::k], k)  # fmt: skip
                       for (x, v, t, keep, k), out in zip(thinned, holdout, strict=True)]
        # each recording stepped at its own rows' period (tests logged at other rates: a
        # testing machine that records every 0.01 mm logs a faster test at a higher rate)
        return friction, [(x, v, t, keep, k / i.sample_rate_hz)
                          for (x, v, t, keep, k), i in zip(thinned, info, strict=True)]  # fmt: skip

    def fit_rows(
        self, X: list[np.ndarray], y: list[np.ndarray], info: list[SequenceInfo]
    ) -> list[FitRows]:
        """Each training recording's (x, v, target, the rows the readout was fitted on, their
        period): what the network readout (lawfree_net.py) is trained on."""
        self._check_fitted()
        return self._fit_rows(X, y, info)[1]

    @property
    def network(self) -> NetReadout | None:
        """The network readout where `haptics-train train` kept one (lawfree_net.py), else
        None (and for a model pickled before it existed)."""
        return getattr(self, "net_", None)

    def linear_object(self, z: np.ndarray) -> np.ndarray:
        """The linear readout's force from the readout's inputs, before the clamp."""
        return _readout_columns(z, self.readout_depth_scales) @ self.w_

    @property
    def readout_depth_scales(self) -> list[float]:
        """The fitted a_s (none for a model pickled before the depth functions existed)."""
        return list(getattr(self, "depth_scales_", ()))

    def _object(self, z: np.ndarray, contact: np.ndarray) -> np.ndarray:
        net = self.network
        if net is None:
            out = self.linear_object(z)
        else:
            # the network alone, or on top of the linear readout (lawfree_net.py)
            out = net(with_w(z)) + (self.linear_object(z) if net.residual else 0.0)
        return np.where(contact, np.maximum(out, 0.0), 0.0)

    def predict_served(self, X: np.ndarray, dt: float | None = None) -> np.ndarray:
        """The object's force alone (what the ONNX graph renders), one sequence from zero
        state, stepped at `dt` (default: the training period)."""
        self._check_fitted()
        xv = self._check_X(X)
        z, contact = self._inputs(xv[:, 0], xv[:, 1], self.dt_ if dt is None else dt)
        return self._object(z, contact)

    def predict(self, X: np.ndarray, dt: float | None = None) -> np.ndarray:
        """The force the RFOB reads: the object's plus the bench's friction (one sequence,
        from zero state, stepped at `dt`: default the training rows' period)."""
        served = self.predict_served(X, dt)
        xv = self._check_X(X)
        h = self.hyper
        bench = sum(c * dahl(xv[:, 0], L) for c, L in zip(self.c_, h["friction_lengths_m"],
                                                          strict=True))  # fmt: skip
        return served + bench

    def to_onnx(self, fused: bool = True) -> onnx.ModelProto:
        """One `ai.haptics:LawFreeStep` node (the fused operator: needs libhaptics_fused_ops.so
        where it runs), or with `fused=False` the multi-node graph (same state, same step)."""
        self._check_fitted()
        decay = np.exp(-served_dt(self) / np.asarray(self.hyper["taus_s"], dtype=float))
        return (lawfree_fused if fused else lawfree_graph)(self, decay)
