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
from onnx import helper
from torch import nn

from .onnx_graph import (
    Graph,
    floats_attr,
    fused_stateful_model,
    fused_stateless_model,
    stateful_model,
    stateless_model,
)

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
#: the fused kernel's names (fused-ops/src/math.rs `Activation::parse`)
_FUSED_ACTS = {nn.Tanh: "tanh", nn.ReLU: "relu", nn.Sigmoid: "sigmoid", nn.SiLU: "silu"}


def dense_fused(net: DenseNet, n_features: int, clip: float) -> onnx.ModelProto:
    """The network as one `ai.haptics:DenseStep` node (fused-ops/src/dense.rs; attribute
    names: its `from_attrs`): the same folded weights as `dense_graph`, each Linear with the
    activation after it (identity when none), the target scaling folded into the last Linear
    when the network ends in one, else in `out_scale`/`out_offset`."""
    mods = [m for m in net.body if not isinstance(m, nn.Dropout)]
    layers: list[tuple[nn.Linear, str]] = []
    for m in mods:
        if isinstance(m, nn.Linear):
            layers.append((m, "identity"))
        elif type(m) in _FUSED_ACTS and layers and layers[-1][1] == "identity":
            layers[-1] = (layers[-1][0], _FUSED_ACTS[type(m)])
        else:
            raise ValueError(f"dense fused: no DenseStep form for {type(m).__name__} here")
    scale, offset = float(net.out.scale), float(net.out.offset)
    folded = isinstance(mods[-1], nn.Linear)
    weights, biases = [], []
    for i, (m, _) in enumerate(layers):
        w, b = _np(m.weight), _np(m.bias)
        if i == 0:
            w, b = _folded_input(w, b, net.inp)
        if folded and i == len(layers) - 1:
            w, b = w * scale, b * scale + offset
        weights.append(w.ravel())
        biases.append(b)
    attrs = [
        helper.make_attribute("widths", [n_features] + [m.out_features for m, _ in layers]),
        floats_attr("weights", np.concatenate(weights)),
        floats_attr("biases", np.concatenate(biases)),
        helper.make_attribute("activations", ",".join(a for _, a in layers)),
        *_soft_attrs(net.inp, clip),
        helper.make_attribute("out_scale", 1.0 if folded else scale),
        helper.make_attribute("out_offset", 0.0 if folded else offset),
    ]
    return fused_stateless_model("DenseStep", attrs, n_features, "dense")


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


def _soft_attrs(inp: InputScaler, clip: float) -> list[onnx.AttributeProto]:
    """The fused kernels' input scaling (fused-ops/src/scaler.rs): s of the soft features, 0
    for the others, and the clip."""
    soft = _np(inp.soft).astype(bool)
    return [floats_attr("soft_scale", np.where(soft, _np(inp.s), 0.0)),
            helper.make_attribute("clip", float(clip))]  # fmt: skip


def lstm_fused(net: LSTMNet, n_features: int, clip: float) -> onnx.ModelProto:
    """One step as one `ai.haptics:LstmStep` node (fused-ops/src/lstm.rs; attribute names: its
    `from_attrs`): the same folded weights as `lstm_graph`, in torch's gate order (i, f, g, o);
    the state h, c as the graph's."""
    hid = net.lstm.hidden_size
    w_ih, b_ih = _folded_input(_np(net.lstm.weight_ih_l0), _np(net.lstm.bias_ih_l0), net.inp)
    scale, offset = float(net.out.scale), float(net.out.offset)
    attrs = [
        *_soft_attrs(net.inp, clip),
        floats_attr("input_weights", w_ih),
        floats_attr("recurrent_weights", _np(net.lstm.weight_hh_l0)),
        floats_attr("biases", b_ih + _np(net.lstm.bias_hh_l0)),
        floats_attr("head_weights", _np(net.head.weight)[0] * scale),
        helper.make_attribute("head_bias", float(_np(net.head.bias)[0] * scale + offset)),
    ]
    return fused_stateful_model("LstmStep", attrs, n_features, hid, "lstm")


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
