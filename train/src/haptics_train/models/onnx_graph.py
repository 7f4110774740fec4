"""Hand-built ONNX graphs for the stateful contract (docs/model-contract.md), for models whose
step is a few vector operations.

Why not torch.onnx: the TorchScript exporter writes one node per scalar operation, slice,
stack and `zeros_like`, with shape computations at run time; ONNX Runtime pays its per-node
dispatch (about 0.1-0.2 us on the 2-core machine) on every one of them, every step. A graph
built here has its constants folded at export (initializers computed in float64, stored as
float32), every branch and element of a kind in one vector operation, fixed shapes, and
nothing computed from shapes when it runs. Whatever the fitted values are, the graph is the
same shape: the builders read the fitted arrays, never assume their values.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import onnx
from onnx import AttributeProto, TensorProto, helper, numpy_helper

#: the opset the hand-built graphs use (Split/ReduceSum take sizes/axes as inputs from 13 on)
OPSET = 17


class Graph:
    """Nodes and initializers in the making; every node's output gets a fresh name."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.nodes: list[onnx.NodeProto] = []
        self.inits: list[onnx.TensorProto] = []
        self._n = 0

    def fresh(self, hint: str) -> str:
        """A new value name."""
        return self._fresh(hint)

    def node(self, op_type: str, inputs: list[str], outputs: list[str], **attrs: object) -> None:
        """One node with the given (possibly several, or "" for none) outputs."""
        self.nodes.append(helper.make_node(op_type, inputs, outputs, **attrs))

    def _fresh(self, hint: str) -> str:
        self._n += 1
        return f"{hint}_{self._n}"

    def const(self, value: object, hint: str = "c", dtype: type = np.float32) -> str:
        """An initializer holding `value` (computed by the caller in float64, stored as
        `dtype`)."""
        name = self._fresh(hint)
        self.inits.append(numpy_helper.from_array(np.asarray(value, dtype=dtype), name))
        return name

    def ints(self, value: Sequence[int], hint: str = "i") -> str:
        return self.const(list(value), hint, np.int64)

    def op(self, op_type: str, *inputs: str, hint: str | None = None, **attrs: object) -> str:
        """One node with one output; returns the output's name."""
        out = self._fresh(hint or op_type.lower())
        self.nodes.append(helper.make_node(op_type, list(inputs), [out], **attrs))
        return out

    def split(self, x: str, sizes: Sequence[int], axis: int, hint: str = "part") -> list[str]:
        """`x` cut along `axis` into parts of `sizes` (one node)."""
        outs = [self._fresh(hint) for _ in sizes]
        self.nodes.append(
            helper.make_node("Split", [x, self.ints(sizes, "sizes")], outs, axis=axis)
        )
        return outs

    def model(
        self,
        inputs: list[onnx.ValueInfoProto],
        outputs: list[tuple[str, str, list[int | str]]],
    ) -> onnx.ModelProto:
        """The model, renaming each (value, contract name, shape) of `outputs` to its
        contract name (the node that made it writes it directly)."""
        rename = {value: name for value, name, _ in outputs}
        for n in self.nodes:
            n.output[:] = [rename.get(o, o) for o in n.output]
            n.input[:] = [rename.get(i, i) for i in n.input]
        outs = [helper.make_tensor_value_info(name, TensorProto.FLOAT, shape)
                for _, name, shape in outputs]  # fmt: skip
        g = helper.make_graph(self.nodes, self.name, inputs, outs, self.inits)
        m = helper.make_model(g, opset_imports=[helper.make_opsetid("", OPSET)])
        m.ir_version = 8
        onnx.checker.check_model(m)
        return m


def stateful_io(n_features: int, state: int) -> list[onnx.ValueInfoProto]:
    """The stateful contract's inputs: `features` [1, n], `h_in`, `c_in` [1, 1, H]."""
    return [
        helper.make_tensor_value_info("features", TensorProto.FLOAT, [1, n_features]),
        helper.make_tensor_value_info("h_in", TensorProto.FLOAT, [1, 1, state]),
        helper.make_tensor_value_info("c_in", TensorProto.FLOAT, [1, 1, state]),
    ]


def stateful_model(
    g: Graph, n_features: int, state: int, force: str, h_out: str, c_out: str | None = None,
    *, reshape_force: bool = True,
) -> onnx.ModelProto:
    """The stateful contract's model: `force` [1, 1] (reshaped from its one element unless
    `reshape_force` is False: already [1, 1]), `h_out`, and `c_out` (`c_in` passed through
    when the model has no second state)."""
    if reshape_force:
        force = g.op("Reshape", force, g.ints([1, 1], "force_shape"))
    if c_out is None:
        c_out = g.op("Identity", "c_in")
    s = [1, 1, state]
    outs = [(force, "force", [1, 1]), (h_out, "h_out", s), (c_out, "c_out", s)]
    return g.model(stateful_io(n_features, state), outs)


#: the project's fused operators' domain and its version (fused-ops/src/lib.rs `DOMAIN`)
FUSED_DOMAIN = "ai.haptics"
FUSED_VERSION = 1


def floats_attr(name: str, values: object) -> onnx.AttributeProto:
    """A FLOATS attribute, typed explicitly (`helper.make_attribute` cannot type an empty
    list)."""
    vals = [float(v) for v in np.ravel(np.asarray(values, dtype=np.float64))]
    return helper.make_attribute(name, vals, attr_type=AttributeProto.FLOATS)


def ints_attr(name: str, values: object) -> onnx.AttributeProto:
    """An INTS attribute, typed explicitly (as `floats_attr`)."""
    vals = [int(v) for v in np.ravel(np.asarray(values, dtype=np.int64))]
    return helper.make_attribute(name, vals, attr_type=AttributeProto.INTS)


def fused_stateful_model(
    op_type: str, attrs: list[onnx.AttributeProto], n_features: int, state: int, name: str
) -> onnx.ModelProto:
    """The stateful contract's model as one node of the fused operators (fused-ops/): inputs
    and outputs exactly those of the multi-node graphs, everything the model needs in `attrs`.
    Runs where libhaptics_fused_ops.so is registered (ort_ops.py; infer-server always)."""
    s = [1, 1, state]
    outs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, shape)
            for n, shape in (("force", [1, 1]), ("h_out", s), ("c_out", s))]  # fmt: skip
    return _fused_model(op_type, attrs, stateful_io(n_features, state), outs, name)


def fused_stateless_model(
    op_type: str, attrs: list[onnx.AttributeProto], n_features: int, name: str
) -> onnx.ModelProto:
    """The stateless contract's model (`features` [N, n] -> `force` [N, 1], any N) as one node
    of the fused operators."""
    inp = helper.make_tensor_value_info("features", TensorProto.FLOAT, ["N", n_features])
    out = helper.make_tensor_value_info("force", TensorProto.FLOAT, ["N", 1])
    return _fused_model(op_type, attrs, [inp], [out], name)


def _fused_model(
    op_type: str,
    attrs: list[onnx.AttributeProto],
    inputs: list[onnx.ValueInfoProto],
    outputs: list[onnx.ValueInfoProto],
    name: str,
) -> onnx.ModelProto:
    node = helper.make_node(op_type, [i.name for i in inputs], [o.name for o in outputs],
                            domain=FUSED_DOMAIN, name=name)  # fmt: skip
    node.attribute.extend(attrs)
    g = helper.make_graph([node], name, inputs, outputs)
    opsets = [helper.make_opsetid("", OPSET), helper.make_opsetid(FUSED_DOMAIN, FUSED_VERSION)]
    m = helper.make_model(g, opset_imports=opsets)
    m.ir_version = 8
    onnx.checker.check_model(m)
    return m


def stateless_model(g: Graph, n_features: int, force: str) -> onnx.ModelProto:
    """The stateless contract's model: `features` [N, n] -> `force` [N, 1]."""
    inp = helper.make_tensor_value_info("features", TensorProto.FLOAT, ["N", n_features])
    return g.model([inp], [(force, "force", ["N", 1])])


def row(v: object) -> np.ndarray:
    """A float64 vector as a [1, 1, n] constant (broadcasts against the [1, 1, n] state)."""
    return np.asarray(v, dtype=np.float64).reshape(1, 1, -1)


def scaled_input(g: Graph, x: str, soft: np.ndarray, s: np.ndarray, mu: np.ndarray,
                 sd: np.ndarray, clip: float) -> str:
    """`networks.InputScaler` on `x` [1, n]: asinh(clip(x / s)) on the soft (ratio) features,
    then (z - mu) / sd folded into one multiply and one add; [1, 1, n]."""
    if soft.any():
        u = g.op("Clip", g.op("Mul", x, g.const(row(1.0 / s))), g.const(-clip), g.const(clip))
        x = g.op("Where", g.const(row(soft), "soft", np.bool_), g.op("Asinh", u), x)
    return g.op("Add", g.op("Mul", x, g.const(row(1.0 / sd))), g.const(row(-mu / sd)), hint="z")
