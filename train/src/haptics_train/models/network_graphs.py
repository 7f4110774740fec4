"""The ONNX graphs of the dense network and the LSTM (networks.py), built from their weights
(models/onnx_graph.py says why not torch.onnx).

What differs from the traced graph, all folded at export in float64: asinh is one `Asinh` node
(the traced graph writes it out in eight), the standardisation (z - mu) / sd is folded into the
first layer's weights and bias (the LSTM's input weights), and the target's de-standardisation
into the last layer (when the network ends in a Linear). The dense graph keeps a dynamic batch;
SiLU is written x * sigmoid(x), which ONNX Runtime fuses into one kernel.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import onnx
from torch import nn

from .onnx_graph import Graph, stateful_model, stateless_model

if TYPE_CHECKING:
    from .networks import DenseNet, InputScaler, LSTMNet


def _np(t: object) -> np.ndarray:
    return t.detach().double().numpy()  # type: ignore[attr-defined]


def _soft(g: Graph, x: str, inp: InputScaler, clip: float, shape: tuple[int, ...]) -> str:
    """asinh(clip(x / s)) on the soft (ratio) features, the others as they are (before the
    standardisation, which the caller folds into its first weights). `shape`: the constants'
    shape (broadcasting sets the result's)."""
    soft = _np(inp.soft).astype(bool)
    if not soft.any():
        return x
    u = g.op("Clip", g.op("Mul", x, g.const((1.0 / _np(inp.s)).reshape(shape))),
             g.const(-clip), g.const(clip))  # fmt: skip
    return g.op("Where", g.const(soft.reshape(shape), "soft", np.bool_), g.op("Asinh", u), x)


def _folded_input(w: np.ndarray, b: np.ndarray, inp: InputScaler) -> tuple[np.ndarray, np.ndarray]:
    """W ((z - mu) / sd) + b = (W / sd) z + (b - W mu / sd), W [out, in]."""
    mu, sd = _np(inp.mu), _np(inp.sd)
    return w / sd, b - w @ (mu / sd)


_ACTS = {nn.Tanh: "Tanh", nn.ReLU: "Relu", nn.Sigmoid: "Sigmoid"}


def dense_graph(net: DenseNet, n_features: int, clip: float) -> onnx.ModelProto:
    """features [N, n] -> force [N, 1]: Gemm per Linear, the activations, scalers folded."""
    g = Graph("dense")
    h = _soft(g, "features", net.inp, clip, (n_features,))
    mods = [m for m in net.body if not isinstance(m, nn.Dropout)]
    scale, offset = float(net.out.scale), float(net.out.offset)
    linears = [i for i, m in enumerate(mods) if isinstance(m, nn.Linear)]
    out_folded = linears[-1] == len(mods) - 1
    for i, m in enumerate(mods):
        if isinstance(m, nn.Linear):
            w, b = _np(m.weight), _np(m.bias)
            if i == linears[0]:
                w, b = _folded_input(w, b, net.inp)
            if i == len(mods) - 1:
                w, b = w * scale, b * scale + offset
            h = g.op("Gemm", h, g.const(w.T), g.const(b))
        elif isinstance(m, nn.SiLU):
            h = g.op("Mul", h, g.op("Sigmoid", h))
        elif type(m) in _ACTS:
            h = g.op(_ACTS[type(m)], h)
        else:
            raise ValueError(f"dense graph: no ONNX form for {type(m).__name__}")
    if not out_folded:
        h = g.op("Add", g.op("Mul", h, g.const(scale)), g.const(offset))
    return stateless_model(g, n_features, h)


def lstm_graph(net: LSTMNet, n_features: int, clip: float) -> onnx.ModelProto:
    """One step: the ONNX LSTM op on the scaled features (the standardisation folded into its
    input weights), the head with the target scaling folded in."""
    hid = net.lstm.hidden_size
    g = Graph("lstm")
    z = _soft(g, "features", net.inp, clip, (1, 1, n_features))
    if z == "features":
        z = g.op("Reshape", z, g.ints([1, 1, n_features]))
    # torch's gate rows are i, f, g, o; ONNX's i, o, f, c
    order = np.r_[0:hid, 3 * hid : 4 * hid, hid : 2 * hid, 2 * hid : 3 * hid]
    w_ih, b_ih = _folded_input(_np(net.lstm.weight_ih_l0), _np(net.lstm.bias_ih_l0), net.inp)
    w = g.const(w_ih[order][None])
    r = g.const(_np(net.lstm.weight_hh_l0)[order][None])
    bias = g.const(np.concatenate([b_ih[order], _np(net.lstm.bias_hh_l0)[order]])[None])
    h_out, c_out = g.fresh("lstm_h"), g.fresh("lstm_c")
    g.node("LSTM", [z, w, r, bias, "", "h_in", "c_in"], ["", h_out, c_out], hidden_size=hid)
    scale, offset = float(net.out.scale), float(net.out.offset)
    force = g.op("Add", g.op("MatMul", h_out, g.const(_np(net.head.weight).T * scale)),
                 g.const(_np(net.head.bias) * scale + offset))  # fmt: skip
    return stateful_model(g, n_features, hid, force, h_out, c_out)
