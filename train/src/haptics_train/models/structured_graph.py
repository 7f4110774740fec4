"""The ONNX graph of `structured` (one control step of the object's force), built by hand.

The same step as `StructuredModel._parts` (see structured.py for the physics), written as a
few vector operations over the state [q (K branches), u (M hysteresis), set, largest depth,
previous e] so ONNX Runtime dispatches a few dozen nodes instead of one per scalar:

- the permanent set: s' = s + kg [loaded] relu(target - s) - kr [not loaded] relu(s - keep
  target), the two branches of the law in one two-element vector (target = max_m (md /
  ref)^2); when the fitted magnitude max_m is 0 the set stays 0 and the law is left out;
- the equilibrium at e and at the previous e at once (a [2, J] basis, one MatMul with the
  fitted coefficients): tanh(e / y) plateaus and the densification r^2 - 1 + 2/d r^3 relu(e -
  0.95 d), r = 1 / max(1 - e/d, 0.05) (= 1 / (1 - min(e, 0.95 d)/d));
- the K Maxwell branches q' = d q + dF_eq and the M Dahl states as one vector each;
- the force f_eq + q'.g + f_eq u'.h as one MatMul, clamped at 0, 0 out of contact;
- `c` (which the model needs for nothing else) carries f_eq at the previous e, so the
  equilibrium is evaluated once per step.

ONNX Runtime's cost per node on the 2-core machine (benchmarked with chains of one op): a
unary op ~0.19 us, a binary op ~0.27, MatMul ~0.34, Slice/Concat ~0.42, Split ~0.5, a
comparison with Where ~1.1: the graph prefers MatMuls with constant selectors to slicing and
arithmetic (Sign, products) to comparisons.

Only the fitted arrays' values are read; their lengths come from the hyperparameters, so the
graph follows whatever the fit chose.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import onnx
from onnx import TensorProto

from .onnx_graph import Graph, row, stateful_model

if TYPE_CHECKING:
    from .structured import StructuredModel


def structured_graph(m: StructuredModel) -> onnx.ModelProto:
    h = m.hyper
    a = np.asarray(m.a_, dtype=np.float64)
    gk = np.asarray(m.g_, dtype=np.float64)
    hw = np.asarray(m.h_, dtype=np.float64)
    yld = np.asarray(h["yield_m"], dtype=np.float64)
    dens = np.asarray(h["densification_m"], dtype=np.float64)
    taus = np.asarray(h["taus_s"], dtype=np.float64)
    hl = np.asarray(h["hysteresis_lengths_m"], dtype=np.float64)
    nk, nm, j1 = len(gk), len(hw), len(yld)
    a_t, a_d = a[:j1], a[j1:]
    dt = float(m.dt_)
    state = nk + nm + 3
    first = row(np.eye(1, state))  # [1, 0, ..., 0]

    g = Graph("structured")
    # x by a MatMul: cheaper in ONNX Runtime than a Slice, Gather or Split (measured)
    x = g.op("MatMul", "features", g.const(np.eye(len(m.features), 1)), hint="x")  # [1, 1]
    q, u, s, md, e_prev = g.split("h_in", [nk, nm, 1, 1, 1], axis=2, hint="st")
    md2 = g.op("Max", md, x, hint="md")  # [1, 1, 1]

    set_m = float(m.set_max_m_)
    if set_m > 0.0:
        c1 = set_m / float(h["set_reference_m"]) ** 2
        keep = float(h["set_keep_fraction"])
        kg = min(dt / float(h["set_tau_grow_s"]), 1.0)
        kr = min(dt / float(h["set_tau_recover_s"]), 1.0)
        # r = relu([target - s, s - keep target]), target = c1 md^2
        t = g.op("Mul", g.op("Mul", md2, md2), g.const(row([c1, -keep * c1])))
        r = g.op("Relu", g.op("Add", t, g.op("Mul", s, g.const(row([-1.0, 1.0])))))
        thr = g.op("Max", g.op("Mul", md2, g.const(float(h["set_loaded_fraction"]))), s)
        loaded = g.op("Cast", g.op("Greater", x, thr), to=TensorProto.FLOAT)
        # s' = s + [kg loaded, -kr (1 - loaded)] . r
        gate = g.op("Add", g.op("Mul", loaded, g.const(row([kg, kr]))), g.const(row([0.0, -kr])))
        step = g.op("MatMul", g.op("Mul", gate, r), g.const(np.ones((2, 1))))
        s = g.op("Add", s, step, hint="set")
    # (max_m 0: the set stays at its zero start, s' = s)

    e = g.op("Sub", x, s, hint="e")  # [1, 1, 1]
    ec = g.op("Relu", e)
    # 1 in contact, else 0: arithmetic, cheaper than a comparison and a Where (measured)
    contact = g.op("Sign", ec)
    plateau = g.op("Tanh", g.op("Mul", ec, g.const(row(1.0 / yld))))
    un = g.op("Max", g.op("Add", g.op("Mul", ec, g.const(row(-1.0 / dens))), g.const(1.0)),
              g.const(0.05))  # fmt: skip
    rr = g.op("Reciprocal", un)
    r2 = g.op("Mul", rr, rr)
    over = g.op("Mul", g.op("Mul", r2, rr),
                g.op("Relu", g.op("Sub", ec, g.const(row(0.95 * dens)))))  # fmt: skip
    basis = g.op("Concat", plateau, r2, over, axis=2)  # [1, 1, J1 + 2 Jd]
    w = np.concatenate([a_t, a_d, 2.0 * a_d / dens]).reshape(-1, 1)
    fe = g.op("Add", g.op("MatMul", basis, g.const(w)), g.const(-float(a_d.sum())), hint="f_eq")
    # c carries f_eq at the previous e in its first element (0 at the zero state, as f_eq(0))
    dfeq = g.op("Sub", fe, g.op("MatMul", "c_in", g.const(first.reshape(-1, 1))))
    c_out = g.op("Mul", fe, g.const(first))
    decay = np.exp(-dt / taus)
    q2 = g.op("Add", g.op("Mul", q, g.const(row(decay))), dfeq, hint="q")

    de = g.op("Sub", ec, g.op("Relu", e_prev))
    att = g.op("Exp", g.op("Mul", g.op("Abs", de), g.const(row(-1.0 / hl))))
    sg = g.op("Sign", de)
    # a u + (1 - a) sign(de) = sign + a (u - sign); 0 out of contact
    u2 = g.op("Mul", g.op("Add", sg, g.op("Mul", att, g.op("Sub", u, sg))), contact, hint="u")

    terms = g.op("Concat", q2, g.op("Mul", u2, fe), fe, axis=2)
    f = g.op("MatMul", terms, g.const(np.concatenate([gk, hw, [1.0]]).reshape(-1, 1)))
    force = g.op("Mul", g.op("Relu", f), contact)
    h_out = g.op("Concat", q2, u2, s, md2, e, axis=2)
    return stateful_model(g, len(m.features), state, force, h_out, c_out)
