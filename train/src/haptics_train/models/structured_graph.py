"""The ONNX graph of `structured` (one control step of the object's force), built by hand.

The same step as `StructuredModel._parts` (see structured.py for the physics), written as a
few vector operations over the state [q (K branches), u (M hysteresis), set, largest depth,
previous e] so ONNX Runtime dispatches a few dozen nodes instead of one per scalar:

- the permanent set: s' = s + kg [loaded] relu(target - s) - kr [not loaded] relu(s - keep
  target), the two branches of the law in one two-element vector (target = max_m (md /
  ref)^k, the fitted exponent k and reference depth ref = D: one Pow, none when k = 1);
  when the fitted magnitude max_m is 0 the set stays 0 and the law is left out;
- the equilibrium at e (one MatMul with the fitted coefficients over [plateaus, poles,
  overs]): tanh(e / y) plateaus and the densification poles u^-n - 1 + n/d u^(-n-1) relu(e -
  0.95 d), u = max(1 - e/d, 0.05) (= 1 - min(e, 0.95 d)/d), the per-pole exponents n one
  constant vector of a single Pow. Past 0.95 d, u is exactly 0.05, so the linear
  continuation is n/d 20^(n+1) relu(e - 0.95 d): a constant folded into the MatMul's
  weights times one Relu; the -1s are one constant added after it. Columns whose fitted
  weight is exactly 0 are left out (they add exactly 0), a kind with none left with its nodes;
- the K Maxwell branches q' = d q + dF_eq and the M Dahl states as one vector each;
- the force f_eq + q'.g + f_eq u'.h as one MatMul, clamped at 0, 0 out of contact;
- `c` (which the model needs for nothing else) carries f_eq at the previous e, so the
  equilibrium is evaluated once per step.

ONNX Runtime's cost per node on the 2-core machine (benchmarked with chains of one op): a
unary op ~0.19 us, a binary op ~0.27, MatMul ~0.34, Slice/Concat ~0.42, Split ~0.5, a
comparison with Where ~1.1: the graph prefers MatMuls with constant selectors to slicing and
arithmetic (Sign, products) to comparisons.

`structured_fused` writes the same step as one node of the project's fused operator,
`ai.haptics:StructuredStep` (fused-ops/src/structured.rs): one dispatch instead of 50-56, the
fitted values as its attributes (raw, not derived: the kernel derives decays and gains in
float64 once). It is what `StructuredModel.to_onnx()` exports; the multi-node graph stays
(`to_onnx(fused=False)`) for ONNX Runtimes without the library and for the parity tests that
compare the two.

The graph reads what the fit resolved and chose (`m.basis_`: lengths in metres, one exponent
per pole, the set law's shape; `m.set_max_m_`; the coefficients), never the grids' values, so
it follows whatever the fit chose.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import onnx
from onnx import TensorProto, helper

from .base import served_dt
from .onnx_graph import Graph, floats_attr, fused_stateful_model, row, stateful_model

if TYPE_CHECKING:
    from .structured import StructuredModel

#: The compression (a fraction of the depth scale D) under which a depth-scaled branch's time
#: stops shrinking: at first contact e / D is 0, and a time of 0 would empty the branch every
#: step (structured.py `depth_times`, the kernel's `depth_floor_m`).
DEPTH_FLOOR = 1e-3


def _weights(m: StructuredModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fitted equilibrium weights `a_` split: (plateaus, poles, indentation powers)."""
    b = m.basis_
    a = np.asarray(m.a_, dtype=np.float64)
    j1, j2 = len(b["yield_m"]), len(b["yield_m"]) + len(b["densification_m"])
    return a[:j1], a[j1:j2], a[j2:]


def _equilibrium(g: Graph, ec: str, m: StructuredModel) -> str:
    """F_eq at the clamped compression `ec` [1, 1, 1] (the basis of `equilibrium_basis` times
    the fitted `a_`), zero-weight columns left out."""
    b = m.basis_
    a_t, a_d, a_p = _weights(m)
    yld = np.asarray(b["yield_m"], dtype=np.float64)
    dens = np.asarray(b["densification_m"], dtype=np.float64)
    dexp = np.asarray(b["densification_exponent"], dtype=np.float64)
    pw = np.asarray(b.get("power_exponents", []), dtype=np.float64)
    kt, kd, kp = a_t != 0.0, a_d != 0.0, a_p != 0.0
    if not (kt.any() or kd.any() or kp.any()):
        kt[0] = True  # an all-zero equilibrium: one column of weight 0 keeps the graph whole
    cols, w = [], []
    if kt.any():
        cols.append(g.op("Tanh", g.op("Mul", ec, g.const(row(1.0 / yld[kt])))))
        w.append(a_t[kt])
    if kd.any():
        d, n, ad = dens[kd], dexp[kd], a_d[kd]
        u = g.op("Max", g.op("Add", g.op("Mul", ec, g.const(row(-1.0 / d))), g.const(1.0)),
                 g.const(0.05))  # fmt: skip
        cols.append(g.op("Pow", u, g.const(row(-n))))
        cols.append(g.op("Relu", g.op("Sub", ec, g.const(row(0.95 * d)))))
        w += [ad, ad * n / d * 20.0 ** (n + 1.0)]
    if kp.any():  # the indentation powers (e / D)^p
        en = g.op("Mul", ec, g.const(1.0 / float(b["depth_scale_m"])))
        cols.append(g.op("Pow", en, g.const(row(pw[kp]))))
        w.append(a_p[kp])
    basis = cols[0] if len(cols) == 1 else g.op("Concat", *cols, axis=2)
    fe = g.op("MatMul", basis, g.const(np.concatenate(w).reshape(-1, 1)))
    if kd.any():
        fe = g.op("Add", fe, g.const(-float(a_d[kd].sum())))
    return fe


def structured_graph(m: StructuredModel) -> onnx.ModelProto:
    b = m.basis_
    taus = np.asarray(b["taus_s"], dtype=np.float64)
    dtaus = np.asarray(b.get("depth_taus_s", []), dtype=np.float64)
    nk, nd = len(taus), len(dtaus)
    gk = np.asarray(m.g_, dtype=np.float64)  # [fixed times, depth-scaled]
    hw = np.asarray(m.h_, dtype=np.float64)
    hl = np.asarray(b["hysteresis_lengths_m"], dtype=np.float64)
    nm = len(hw)
    dt = served_dt(m)
    state = nk + nd + nm + 3
    first = row(np.eye(1, state))  # [1, 0, ..., 0]

    g = Graph("structured")
    # x by a MatMul: cheaper in ONNX Runtime than a Slice, Gather or Split (measured)
    x = g.op("MatMul", "features", g.const(np.eye(len(m.features), 1)), hint="x")  # [1, 1]
    if nd:
        q, qd, u, s, md, e_prev = g.split("h_in", [nk, nd, nm, 1, 1, 1], axis=2, hint="st")
    else:
        q, u, s, md, e_prev = g.split("h_in", [nk, nm, 1, 1, 1], axis=2, hint="st")
    md2 = g.op("Max", md, x, hint="md")  # [1, 1, 1]

    set_m = float(m.set_max_m_)
    if set_m > 0.0:
        k = float(b["set_exponent"])
        c1 = set_m / float(b["set_reference_m"]) ** k
        keep = float(b["set_keep_fraction"])
        kg = min(dt / float(b["set_tau_grow_s"]), 1.0)
        kr = min(dt / float(b["set_tau_recover_s"]), 1.0)
        # r = relu([target - s, s - keep target]), target = c1 md^k
        mdk = md2 if k == 1.0 else g.op("Pow", md2, g.const(k))
        t = g.op("Mul", mdk, g.const(row([c1, -keep * c1])))
        r = g.op("Relu", g.op("Add", t, g.op("Mul", s, g.const(row([-1.0, 1.0])))))
        thr = g.op("Max", g.op("Mul", md2, g.const(float(b["set_loaded_fraction"]))), s)
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
    fe = _equilibrium(g, ec, m)
    # c carries f_eq at the previous e in its first element (0 at the zero state, as f_eq(0))
    dfeq = g.op("Sub", fe, g.op("MatMul", "c_in", g.const(first.reshape(-1, 1))))
    c_out = g.op("Mul", fe, g.const(first))
    decay = np.exp(-dt / taus)
    q2 = g.op("Add", g.op("Mul", q, g.const(row(decay))), dfeq, hint="q")
    if nd:
        # depth-scaled: qd' = (exp(-(dt D / tau_k) / max(e, floor D)) qd + dF_eq) in contact,
        # else 0 (emptied; structured.py `depth_times`, `depth_decays`)
        depth = float(b["depth_scale_m"])
        inv = g.op("Reciprocal", g.op("Max", ec, g.const(DEPTH_FLOOR * depth)))
        dd = g.op("Exp", g.op("Mul", inv, g.const(row(-dt * depth / dtaus))))
        qd2 = g.op("Mul", g.op("Add", g.op("Mul", dd, qd), dfeq), contact, hint="qd")
        q2 = g.op("Concat", q2, qd2, axis=2)

    de = g.op("Sub", ec, g.op("Relu", e_prev))
    att = g.op("Exp", g.op("Mul", g.op("Abs", de), g.const(row(-1.0 / hl))))
    sg = g.op("Sign", de)
    # a u + (1 - a) sign(de) = sign + a (u - sign); 0 out of contact
    u2 = g.op("Mul", g.op("Add", sg, g.op("Mul", att, g.op("Sub", u, sg))), contact, hint="u")

    # a hysteresis of its own size (hc u beside h F_eq u) only where fitted: without it the
    # graph is the one exported before it existed
    hc = m.hysteresis_forces()
    own = [(u2, hc)] if hc.any() else []
    cols = [(q2, gk), (g.op("Mul", u2, fe), hw), *own, (fe, np.ones(1))]
    terms = g.op("Concat", *(c for c, _ in cols), axis=2)
    weights = np.concatenate([w for _, w in cols])
    f = g.op("MatMul", terms, g.const(weights.reshape(-1, 1)))
    force = g.op("Mul", g.op("Relu", f), contact)
    h_out = g.op("Concat", q2, u2, s, md2, e, axis=2)
    return stateful_model(g, len(m.features), state, force, h_out, c_out)


def structured_fused(m: StructuredModel) -> onnx.ModelProto:
    """The step as one `ai.haptics:StructuredStep` node (attribute names: the kernel's,
    fused-ops/src/structured.rs `from_attrs`). Columns whose fitted weight is exactly 0 are
    left out (they add exactly 0), as in the multi-node graph."""
    b = m.basis_
    a_t, a_d, a_p = _weights(m)
    kt, kd, kp = a_t != 0.0, a_d != 0.0, a_p != 0.0
    nk, nm = len(b["taus_s"]), len(m.h_)
    dtaus = list(b.get("depth_taus_s", []))
    state = len(m.g_) + nm + 3
    attrs = [
        helper.make_attribute("dt_s", served_dt(m)),
        floats_attr("yield_m", np.asarray(b["yield_m"])[kt]),
        floats_attr("a_yield", a_t[kt]),
        floats_attr("densification_m", np.asarray(b["densification_m"])[kd]),
        floats_attr("densification_exponent", np.asarray(b["densification_exponent"])[kd]),
        floats_attr("a_densification", a_d[kd]),
        floats_attr("taus_s", b["taus_s"]),
        floats_attr("branch_gains", m.g_[:nk]),
        floats_attr("hysteresis_m", b["hysteresis_lengths_m"]),
        floats_attr("hysteresis_gains", m.h_),
        helper.make_attribute("set_max_m", float(m.set_max_m_)),
    ]
    if kp.any() or dtaus:  # the indentation elements (absent: none, as before them)
        attrs += [
            helper.make_attribute("depth_scale_m", float(b["depth_scale_m"])),
            helper.make_attribute("depth_floor", DEPTH_FLOOR),
            floats_attr("power_exponents", np.asarray(b["power_exponents"])[kp]),
            floats_attr("a_power", a_p[kp]),
            floats_attr("depth_taus_s", dtaus),
            floats_attr("depth_gains", m.g_[nk:]),
        ]
    hc = m.hysteresis_forces()
    if hc.any():  # absent: none (the kernel reads zeros, as before the attribute)
        attrs.append(floats_attr("hysteresis_constant_n", hc))
    if float(m.set_max_m_) > 0.0:
        attrs += [helper.make_attribute(k, float(b[k])) for k in (
            "set_reference_m", "set_exponent", "set_tau_grow_s", "set_tau_recover_s",
            "set_loaded_fraction", "set_keep_fraction")]  # fmt: skip
    return fused_stateful_model("StructuredStep", attrs, len(m.features), state, "structured")
