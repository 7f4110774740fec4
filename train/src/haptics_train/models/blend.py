"""`blend`: the weighted mean of two fitted stateful models' forces, each stepping its own state.

Why: on the bench laws the study's best candidates often err in different places (a
`structured` fit and a `lawfree` one, or a fit with and without the press-and-hold recordings),
and a mean of two such answers is closer than either on some objects (docs/laws.md, "The mean
of the two best", "The blend's partner and weights"). It is a candidate the study's felt force
chooses, never a replacement: the study takes the candidate its ranking runs put first, tries
it with every other at equal weights on the same ranking programmes, then the closest pair at
the weights of `WEIGHT_GRID`, and recommends the result only where it felt closest there
(study/run.py, `_blend`).

What it is:

    F = w_a F_a(x, v; s_a) + w_b F_b(x, v; s_b),   w_a, w_b >= 0 (`weights`; 1/2 each by default)

with s_a and s_b the members' own states, stepped side by side. Both members are kinematics-in
models (the same features, no previous force), so each one's answer does not depend on the
other's. Each member dissipates by construction (`structured`'s non-negative weights,
`lawfree`'s passive memory), and a non-negative-weighted sum of two forces along the same
motion absorbs the same weighted sum of their energies, so the blend dissipates too: no gain,
no energy injected. The study's weights sum to 1, so the blend stays between its members.

Served as one stateful ONNX model: `h_in`/`c_in` hold the members' states one after the other
([s_a, s_b]). By default (fused members) one node, `ai.haptics:BlendStep` (`blend_fused`;
fused-ops/src/blend.rs), which steps the members' own kernels one after the other: one ONNX
Runtime dispatch, the arithmetic of both. With `fused=False` (or members without a fused node)
each member's graph is kept as it is, its names prefixed `a_` / `b_`, with slices, a weighted
sum and concatenations around them (`blend_graph`: about eleven dispatches more).

Estimator shape: `fit(X, y, info)` fits both members on the same sequences (scikit-learn's
`VotingRegressor` fits its estimators the same way); `BlendModel.of(a, b)` takes two members
fitted already, which is how the study builds it. Fitted attributes: `members_`, `serve_dt_`,
`feature_gains_`, `train_info_`.
"""

from __future__ import annotations

import math
from typing import Self

import numpy as np
import onnx
from onnx import TensorProto, compose, helper, numpy_helper

from .base import ForceModel, NotFittedError

#: The members' weights by default (`haptics-train blend`, and the study's partner search).
WEIGHTS = (0.5, 0.5)

#: The weights the study tries on the pair it chose, the first on the ranking's first (docs/laws.md,
#: "The blend's partner and weights"): a grid fixed before its test, never fitted to an object.
WEIGHT_GRID = ((0.5, 0.5), (0.75, 0.25), (0.25, 0.75))

#: The name of the blend in a models folder (its .joblib and .onnx); one per folder.
BLEND_NAME = "blend"

STATE_IO = ("h_in", "c_in")


class BlendError(ValueError):
    """Two models that cannot be blended (with why)."""


def blendable(a: ForceModel, b: ForceModel) -> str | None:
    """Why `a` and `b` cannot be blended, or None when they can: both stateful models whose
    state steps in time (`steps_in_time`), fitted, on the same kinematic features, exported for
    the same loop period."""
    for m in (a, b):
        if m.kind != "stateful":
            return f"{m.name} is not a stateful model (kind {m.kind})"
        if not getattr(m, "steps_in_time", False):
            # lstm_slow: its state steps at the object's pace (100 Hz), not once a loop period
            return f"{m.name}'s state does not step at the loop's period (steps_in_time)"
        if not hasattr(m, "train_info_"):
            return f"{m.name} is not fitted"
    if a.name == b.name:
        return f"both are {a.name}"
    if tuple(a.features) != tuple(b.features):
        return f"{a.name} reads {','.join(a.features)}, {b.name} {','.join(b.features)}"
    da, db = getattr(a, "serve_dt_", None), getattr(b, "serve_dt_", None)
    if da is None or db is None or not math.isclose(float(da), float(db), rel_tol=1e-9):
        return f"{a.name} steps at {da} s, {b.name} at {db} s"
    ga, gb = getattr(a, "feature_gains_", None), getattr(b, "feature_gains_", None)
    if ga != gb:
        return f"{a.name}'s features were filtered with {ga}, {b.name}'s with {gb}"
    return None


class BlendModel(ForceModel):
    """The weighted mean of two stateful members (module docstring)."""

    algo = BLEND_NAME
    kind = "stateful"
    layout = "sequences"
    steps_in_time = True
    defaults: dict = {"weights": list(WEIGHTS)}

    def __init__(
        self,
        members: tuple[ForceModel, ForceModel] | list[ForceModel],
        hyper: dict | None = None,
        *,
        seed: int = 0,
        progress: bool = False,
    ) -> None:
        members = tuple(members)
        if len(members) != 2:
            raise BlendError(f"a blend has two members, got {len(members)}")
        super().__init__(members[0].features, members[0].feature_set, hyper, seed=seed,
                         progress=progress)  # fmt: skip
        self.members = members
        w = [float(v) for v in self.hyper["weights"]]
        if len(w) != 2 or not all(math.isfinite(v) and v >= 0 for v in w) or sum(w) <= 0:
            raise BlendError(f"weights must be two non-negative numbers, not both 0: {w}")

    @property
    def name(self) -> str:
        return BLEND_NAME

    @classmethod
    def of(cls, a: ForceModel, b: ForceModel, weights: tuple[float, float] = WEIGHTS) -> Self:
        """The blend of two members fitted already (refused, with why: `blendable`)."""
        why = blendable(a, b)
        if why is not None:
            raise BlendError(f"cannot blend {a.name} and {b.name}: {why}")
        m = cls((a, b), {"weights": list(weights)})
        m._fitted_from_members()
        return m

    @property
    def weights(self) -> tuple[float, float]:
        w = self.hyper["weights"]
        return float(w[0]), float(w[1])

    def fit(self, X: object, y: object, **fit_params: object) -> Self:
        """Fits both members on the same sequences, then blends them."""
        for m in self.members:
            m.fit(X, y, **fit_params)
        why = blendable(*self.members)
        if why is not None:
            raise BlendError(f"cannot blend the fitted members: {why}")
        self._fitted_from_members()
        return self

    def _fitted_from_members(self) -> None:
        a, b = self.members
        self.members_ = (a, b)
        self.serve_dt_ = float(a.serve_dt_)  # type: ignore[attr-defined]
        self.feature_gains_ = getattr(a, "feature_gains_", None)
        self.n_features_in_ = len(self.features)
        self.train_info_ = {
            "members": [a.name, b.name],
            "weights": list(self.weights),
            "member_algos": [a.algo, b.algo],
            "state_sizes": [a.state_size, b.state_size],  # type: ignore[attr-defined]
            "serve_dt_s": self.serve_dt_,
        }

    @property
    def state_size(self) -> int:
        self._check_fitted()
        return int(sum(m.state_size for m in self.members_))  # type: ignore[attr-defined]

    def _mean(self, method: str, X: np.ndarray, dt: float | None) -> np.ndarray:
        self._check_fitted()
        x = self._check_X(X)
        out = np.zeros(len(x))
        for w, m in zip(self.weights, self.members_, strict=True):
            f = getattr(m, method, None) or m.predict
            out += w * np.asarray(f(x, dt=dt), dtype=np.float64)
        return out

    def predict(self, X: np.ndarray, dt: float | None = None) -> np.ndarray:
        """The mean of the members' `predict` (what the recorded target reads: `structured`'s
        includes the bench's friction it identified) along one sequence from zero state."""
        return self._mean("predict", X, dt)

    def predict_served(self, X: np.ndarray, dt: float | None = None) -> np.ndarray:
        """The mean of what the members' graphs render (the object, not the bench)."""
        return self._mean("predict_served", X, dt)

    def to_onnx(self, fused: bool = True) -> onnx.ModelProto:
        if not hasattr(self, "members_"):
            raise NotFittedError("blend is not fitted: BlendModel.of(a, b) or fit first")
        graphs = [m.to_onnx(fused=fused) for m in self.members_]  # type: ignore[call-arg]
        one = blend_fused(graphs[0], graphs[1], self.weights) if fused else None
        return one if one is not None else blend_graph(graphs[0], graphs[1], self.weights)


#: The fused operators a `BlendStep` node can hold (fused-ops/src/blend.rs).
FUSED_MEMBERS = ("StructuredStep", "LawFreeStep")
FUSED_DOMAIN = "ai.haptics"


def _fused_node(m: onnx.ModelProto) -> onnx.NodeProto | None:
    """The graph's one node when it is a fused member's, stepping the contract's tensors."""
    nodes = list(m.graph.node)
    if len(nodes) != 1:
        return None
    n = nodes[0]
    ok = (n.domain == FUSED_DOMAIN and n.op_type in FUSED_MEMBERS
          and list(n.input) == ["features", *STATE_IO]
          and list(n.output) == ["force", "h_out", "c_out"])  # fmt: skip
    return n if ok else None


def blend_fused(
    a: onnx.ModelProto, b: onnx.ModelProto, weights: tuple[float, float] = WEIGHTS
) -> onnx.ModelProto | None:
    """One `ai.haptics:BlendStep` node (fused-ops/src/blend.rs) holding both members' fused
    nodes: `a_op`, `b_op` name them, `weights`, and each member's attributes prefixed `a.` /
    `b.`; None unless both graphs are one such node. One dispatch instead of about eleven
    (`blend_graph`), the arithmetic the same."""
    na, nb = _fused_node(a), _fused_node(b)
    if na is None or nb is None:
        return None
    ha, hb = _state_size(a), _state_size(b)
    node = helper.make_node("BlendStep", ["features", *STATE_IO], ["force", "h_out", "c_out"],
                            domain=FUSED_DOMAIN, name="blend", a_op=na.op_type,
                            b_op=nb.op_type, weights=[float(w) for w in weights])  # fmt: skip
    for prefix, n in (("a.", na), ("b.", nb)):
        for att in n.attribute:
            copy = onnx.AttributeProto()
            copy.CopyFrom(att)
            copy.name = prefix + att.name
            node.attribute.append(copy)
    nf = [d.dim_value for d in a.graph.input[0].type.tensor_type.shape.dim]
    graph = helper.make_graph([node], "blend", *_contract_io(nf, ha + hb))
    m = helper.make_model(graph, opset_imports=_opsets(a, b),
                          ir_version=max(a.ir_version, b.ir_version))  # fmt: skip
    onnx.checker.check_model(m)
    return m


def _contract_io(nf: list[int], h: int) -> tuple[list, list]:
    """The stateful contract's inputs and outputs for `nf` features and a state of H = `h`."""
    f32 = TensorProto.FLOAT

    def io(name: str, shape: list[int]) -> onnx.ValueInfoProto:
        return helper.make_tensor_value_info(name, f32, shape)

    state = [1, 1, h]
    return ([io("features", nf), io("h_in", state), io("c_in", state)],
            [io("force", [1, 1]), io("h_out", state), io("c_out", state)])  # fmt: skip


def _state_size(m: onnx.ModelProto) -> int:
    inputs = {i.name: i for i in m.graph.input}
    if set(STATE_IO) - inputs.keys() or "features" not in inputs:
        raise BlendError("a member graph must take features, h_in and c_in (stateful contract)")
    dims = [[d.dim_value for d in inputs[n].type.tensor_type.shape.dim] for n in STATE_IO]
    if dims[0] != dims[1] or len(dims[0]) != 3 or dims[0][:2] != [1, 1] or dims[0][2] < 1:
        raise BlendError(f"a member's state must be [1, 1, H] for h_in and c_in, got {dims}")
    return dims[0][2]


def _opsets(a: onnx.ModelProto, b: onnx.ModelProto) -> list:
    found: dict[str, int] = {}
    for op in [*a.opset_import, *b.opset_import]:
        if op.domain in found and found[op.domain] != op.version:
            raise BlendError(f"the members import domain {op.domain or 'ai.onnx'} at versions "
                             f"{found[op.domain]} and {op.version}")  # fmt: skip
        found[op.domain] = op.version
    return [helper.make_opsetid(d, v) for d, v in found.items()]


def blend_graph(
    a: onnx.ModelProto, b: onnx.ModelProto, weights: tuple[float, float] = WEIGHTS
) -> onnx.ModelProto:
    """One stateful graph of the stateful contract from two: `features` feeds both, `h_in` /
    `c_in` are split at the first member's state size, each member's graph runs as it is (its
    names prefixed `a_` / `b_`), the force is w_a F_a + w_b F_b and the states are concatenated
    back. Metadata is left to the exporter."""
    ha, hb = _state_size(a), _state_size(b)
    nf = [d.dim_value for d in a.graph.input[0].type.tensor_type.shape.dim]
    pa, pb = compose.add_prefix(a, "a_"), compose.add_prefix(b, "b_")
    h = ha + hb
    consts = {
        "blend_start": [0], "blend_split": [ha], "blend_end": [h], "blend_axis": [2],
    }  # fmt: skip
    init = [numpy_helper.from_array(np.array(v, dtype=np.int64), k) for k, v in consts.items()]
    init += [numpy_helper.from_array(np.array([w], dtype=np.float32), f"blend_w{i}")
             for i, w in enumerate(weights)]  # fmt: skip
    nodes = []
    for p in ("a_", "b_"):
        nodes.append(helper.make_node("Identity", ["features"], [f"{p}features"]))
    for s in ("h", "c"):
        nodes.append(helper.make_node(
            "Slice", [f"{s}_in", "blend_start", "blend_split", "blend_axis"], [f"a_{s}_in"]))
        nodes.append(helper.make_node(
            "Slice", [f"{s}_in", "blend_split", "blend_end", "blend_axis"], [f"b_{s}_in"]))
    nodes += [*pa.graph.node, *pb.graph.node]
    nodes += [
        helper.make_node("Mul", ["a_force", "blend_w0"], ["blend_fa"]),
        helper.make_node("Mul", ["b_force", "blend_w1"], ["blend_fb"]),
        helper.make_node("Add", ["blend_fa", "blend_fb"], ["force"]),
        helper.make_node("Concat", ["a_h_out", "b_h_out"], ["h_out"], axis=2),
        helper.make_node("Concat", ["a_c_out", "b_c_out"], ["c_out"], axis=2),
    ]
    graph = helper.make_graph(
        nodes,
        "blend",
        *_contract_io(nf, h),
        [*init, *pa.graph.initializer, *pb.graph.initializer],
        value_info=[*pa.graph.value_info, *pb.graph.value_info],
    )
    m = helper.make_model(graph, opset_imports=_opsets(a, b),
                          ir_version=max(a.ir_version, b.ir_version))  # fmt: skip
    onnx.checker.check_model(m)
    return m
