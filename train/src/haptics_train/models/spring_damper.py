"""Spring-damper baselines (thesis 6.1): F = k(x) x + b(x) v with polynomial k and b.

order 0: constant k and b; order 1: k = k0 + k1 x, b = b0 + b1 x; order 2 adds x^2 terms.
Fitted by linear least squares on the decimated training rows in contact (X = [x, v], x > 0).
No intercept: a spring-damper exerts no force at rest at x = 0. Out of contact (a free-air
recording, record-dataset.sh's `train_air`) the target is the bench's friction, which a contact
law cannot hold: those rows are left out, so the baseline is fitted as it was before the dataset
had them.
"""

from __future__ import annotations

import numpy as np
import onnx

from ..features import KINEMATICS
from .base import ForceModel, check_rows
from .onnx_graph import Graph, floats_attr, fused_stateless_model, stateless_model


def design(x: np.ndarray, v: np.ndarray, order: int) -> np.ndarray:
    cols = [x * x**i for i in range(order + 1)] + [v * x**i for i in range(order + 1)]
    return np.column_stack(cols)


def spring_damper_graph(k: np.ndarray, b: np.ndarray) -> onnx.ModelProto:
    """F = x k(x) + v b(x) in five nodes for any batch (models/onnx_graph.py says why not
    torch.onnx): the powers of x, [k(x), b(x)] by one MatMul, then the dot with [x, v]."""
    g = Graph("spring_damper")
    x = g.op("Slice", "features", g.ints([0]), g.ints([1]), g.ints([1]))  # [N, 1]
    powers = g.op("Pow", x, g.const(np.arange(len(k)).reshape(1, -1)))  # [N, order + 1]
    kb = g.op("MatMul", powers, g.const(np.column_stack([k, b])))  # [N, 2]: k(x), b(x)
    f = g.op("ReduceSum", g.op("Mul", "features", kb), g.ints([1]), keepdims=1)
    return stateless_model(g, 2, f)


def spring_damper_fused(k: np.ndarray, b: np.ndarray) -> onnx.ModelProto:
    """The same law as one `ai.haptics:SpringDamperStep` node (fused-ops/src/spring_damper.rs;
    attribute names: its `from_attrs`): one dispatch instead of five (docs/infer-server.md)."""
    attrs = [floats_attr("k", k), floats_attr("b", b)]
    return fused_stateless_model("SpringDamperStep", attrs, 2, "spring_damper")


class SpringDamper(ForceModel):
    """Fitted attributes: `k_`, `b_` (the polynomial coefficients of k(x) and b(x), lowest
    order first)."""

    algo = "sd"
    _legacy_fitted = ("k", "b")

    def __init__(
        self, order: int = 2, feature_set: str = "x_v", *, seed: int = 0, progress: bool = False
    ) -> None:
        super().__init__(
            KINEMATICS[:2], feature_set, {"order": order}, seed=seed, progress=progress
        )
        self.order = order

    @property
    def name(self) -> str:
        return ("sd_const", "sd_poly1", "sd_poly2")[self.order]

    def fit(self, X: np.ndarray, y: np.ndarray) -> SpringDamper:
        if self.order not in (0, 1, 2):
            raise ValueError("spring-damper order must be 0, 1 or 2")
        x, y = check_rows(X, y, len(self.features))
        contact = x[:, 0] > 0.0
        if contact.any():  # rows out of contact are the bench's friction, not the object
            x, y = x[contact], y[contact]
        a = design(x[:, 0], x[:, 1], self.order)
        # Column scaling keeps the normal equations well conditioned (x ~ 1e-2, x^3 ~ 1e-6).
        scale = np.abs(a).max(axis=0)
        scale[scale == 0] = 1.0
        coef, *_ = np.linalg.lstsq(a / scale, y, rcond=None)
        coef = coef / scale
        self.k_ = coef[: self.order + 1]
        self.b_ = coef[self.order + 1 :]
        self.n_features_in_ = x.shape[1]
        self.train_info_ = {"rows": int(len(y)), "k": self.k_.tolist(), "b": self.b_.tolist()}
        return self

    def predict(self, X: np.ndarray) -> np.ndarray:
        self._check_fitted()
        x = self._check_X(X)
        return design(x[:, 0], x[:, 1], self.order) @ np.concatenate([self.k_, self.b_])

    def to_onnx(self, fused: bool = True) -> onnx.ModelProto:
        """One `ai.haptics:SpringDamperStep` node (the fused operator: needs
        libhaptics_fused_ops.so where it runs), or with `fused=False` the five-node graph."""
        self._check_fitted()
        if fused:
            return spring_damper_fused(self.k_, self.b_)
        return spring_damper_graph(self.k_, self.b_)
