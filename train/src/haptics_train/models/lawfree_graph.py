"""The ONNX graph of `lawfree` (one control step of the object's force), built by hand
(models/onnx_graph.py says why not torch.onnx; structured_graph.py gives ONNX Runtime's cost
per node).

The same step as `LawFreeModel.predict_served` (see lawfree.py for the model), over the whole
state [s (K filters), p (P plays), (u_max)] at once, so no node slices it:

- [u, v/V] = [x/D, v/V] contact (u = relu(x)/D: x/D times contact is 0 out of contact), one
  MatMul with a constant diagonal; contact = sign(relu(x/D));
- the state in one pass: lin = st A + u B (A = [d_k, 1, 1], B = [1 - d_k, 0, 0]: the filters
  step, the plays and u_max keep their value), then clamped to [u - L, u + R] (L = [1e30, r, 0],
  R = [1e30, r, 1e30]: the filters are never clamped, each play stays within its half-width r
  of u, u_max never below u);
- with the irreversible memory (`damage_frac` c), its inputs c (1 - exp(d / c)) from d = u -
  u_max, the last of u - state (one MatMul picks d / c, then Exp, Sub, Mul);
- the readout sum_j q_j sum_i W_ij phi_i, w = min(u, 1), as [q] W (one MatMul) times
  phi = [1, w, w^2, 1 - exp(-w/a_1), ..] (one Pow of w by [0, 1, 2], with depth scales a
  Mul, Exp, Sub and Concat; one MatMul), q = [u, v/V, u - state];
- with the network readout (`m.network`, lawfree_net.py): q' = [q, w] through MatMul, Add,
  Tanh twice and a last MatMul, added to the linear readout or in its place;
- relu, times contact. `c` is passed through.

`lawfree_fused` writes the same step as one node of the project's fused operator,
`ai.haptics:LawFreeStep` (fused-ops/src/lawfree.rs): one dispatch instead of about 22. It is what
`LawFreeModel.to_onnx()` exports; `to_onnx(fused=False)` keeps this multi-node graph.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import onnx
from onnx import helper

from .onnx_graph import Graph, floats_attr, fused_stateful_model, row, stateful_model

if TYPE_CHECKING:
    from .lawfree import LawFreeModel

#: the filters' clamp half-width: never reached (u is O(1)), so the filters are not clamped
_NO_CLAMP = 1e30


def lawfree_graph(m: LawFreeModel, decay: np.ndarray) -> onnx.ModelProto:
    """The graph of fitted `m`; `decay` the filters' d_k (float32-rounded, as `predict` uses)."""
    widths = np.asarray(m.widths_, dtype=np.float64)
    k, p = len(decay), len(widths)
    damage = np.asarray(m.damage_fracs, dtype=np.float64)  # empty without the memory
    top = int(m.has_damage)  # u_max: one more state
    scales = np.asarray(m.readout_depth_scales, dtype=np.float64)
    nb = 3 + len(scales)
    n_in = 2 + k + p + top + len(damage)
    w = np.asarray(m.w_, dtype=np.float64).reshape(nb, n_in).T  # [inputs, 3 + S]
    g = Graph("lawfree")
    # x/D on its own (for u and contact) and [x/D, v/V]: MatMuls, cheaper than slicing
    xd = g.op(
        "MatMul", "features", g.const(np.array([[1.0 / m.depth_scale_m_], [0.0]]).reshape(1, 2, 1))
    )
    u = g.op("Relu", xd, hint="u")  # [1, 1, 1]
    contact = g.op("Sign", u)
    scale = np.diag([1.0 / m.depth_scale_m_, 1.0 / m.speed_scale_mps_]).reshape(1, 2, 2)
    uv = g.op("Mul", g.op("MatMul", "features", g.const(scale)), contact, hint="uv")  # [1, 1, 2]

    a = np.concatenate([decay, np.ones(p + top)])
    b = np.concatenate([1.0 - decay, np.zeros(p + top)])
    below = np.concatenate([np.full(k, _NO_CLAMP), widths, np.zeros(top)])
    above = np.concatenate([np.full(k, _NO_CLAMP), widths, np.full(top, _NO_CLAMP)])
    lin = g.op("Add", g.op("Mul", "h_in", g.const(row(a))), g.op("Mul", u, g.const(row(b))))
    state = g.op("Min", g.op("Max", lin, g.op("Sub", u, g.const(row(below)))),
                 g.op("Add", u, g.const(row(above))), hint="state")  # fmt: skip

    mem = g.op("Sub", u, state)  # [1, 1, K + P (+ 1)]: the last is d = u - u_max
    parts = [uv, mem]
    if len(damage):
        pick = np.zeros((k + p + top, len(damage)))
        pick[-1] = 1.0 / damage  # d / c for each c
        e = g.op("Exp", g.op("MatMul", mem, g.const(pick)))
        parts.append(g.op("Mul", g.op("Sub", g.const(1.0), e), g.const(row(damage))))
    q = g.op("Concat", *parts, axis=2)  # [1, 1, inputs]
    c = g.op("MatMul", q, g.const(w))  # [1, 1, 3 + S]: q.W_i for each basis function
    # phi = [1, w, w^2, 1 - exp(-w/a)..], w = min(u, 1): the weights stop growing past the
    # deepest training press
    wu = g.op("Min", u, g.const(1.0))
    phi = g.op("Pow", wu, g.const(np.array([0.0, 1.0, 2.0]).reshape(3, 1)))  # [1, 3, 1]
    if len(scales):
        e = g.op("Exp", g.op("Mul", wu, g.const((-1.0 / scales).reshape(len(scales), 1))))
        phi = g.op("Concat", phi, g.op("Sub", g.const(1.0), e), axis=1)  # [1, 3 + S, 1]
    f = g.op("MatMul", c, phi)  # [1, 1, 1]
    net = m.network
    if net is not None:
        # the network readout (lawfree_net.py): q' = [q, w] through two tanh layers, alone or
        # on top of the linear readout
        qw = g.op("Concat", q, wu, axis=2)  # [1, 1, inputs + 1]
        h = g.op("Tanh", g.op("Add", g.op("MatMul", qw, g.const(net.w1.T)), g.const(row(net.b1))))
        h = g.op("Tanh", g.op("Add", g.op("MatMul", h, g.const(net.w2.T)), g.const(row(net.b2))))
        out = g.op("Add", g.op("MatMul", h, g.const(net.w3.reshape(-1, 1))), g.const(net.b3))
        f = g.op("Add", f, out) if net.residual else out
    force = g.op("Mul", g.op("Relu", f), contact)
    return stateful_model(g, len(m.features), m.state_size, force, state)


def lawfree_fused(m: LawFreeModel, decay: np.ndarray) -> onnx.ModelProto:
    """The step as one `ai.haptics:LawFreeStep` node (attribute names: the kernel's,
    fused-ops/src/lawfree.rs `from_attrs`); the filters' a = d and b = 1 - d rounded to
    float32 as `predict` rounds them."""
    widths = np.asarray(m.widths_, dtype=np.float64)
    attrs = [
        helper.make_attribute("depth_scale_m", float(m.depth_scale_m_)),
        helper.make_attribute("speed_scale_mps", float(m.speed_scale_mps_)),
        floats_attr("filter_decay", decay),
        floats_attr("filter_gain", 1.0 - decay),
        floats_attr("play_widths", widths),
        # the network alone renders without the linear readout: its weights written as zeros
        floats_attr("readout", m.w_ if m.network is None or m.network.residual
                    else np.zeros_like(m.w_)),
    ]
    net = m.network
    if net is not None:  # absent: the linear readout alone (fused-ops/src/lawfree.rs)
        attrs += [floats_attr("net_w1", net.w1.ravel()), floats_attr("net_b1", net.b1),
                  floats_attr("net_w2", net.w2.ravel()), floats_attr("net_b2", net.b2),
                  floats_attr("net_w3", net.w3), floats_attr("net_b3", [net.b3])]
    scales = m.readout_depth_scales
    if scales:  # absent: the readout of 1, w, w^2 alone (models exported before the scales)
        attrs.append(floats_attr("readout_depth_scales", scales))
    if m.has_damage:  # absent: no irreversible memory (and no u_max in the state)
        attrs.append(floats_attr("damage_frac", m.damage_fracs))
    state = m.state_size
    return fused_stateful_model("LawFreeStep", attrs, len(m.features), state, "lawfree")
