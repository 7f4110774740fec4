"""Linear regression, SVR and random forest (scikit-learn), exported with skl2onnx, or the SVR
and the forest as one node of the project's fused operators (fused-ops/)."""

from __future__ import annotations

import time

import numpy as np
import onnx
from onnx import helper
from skl2onnx import convert_sklearn
from skl2onnx.common.data_types import FloatTensorType
from sklearn.ensemble import RandomForestRegressor
from sklearn.linear_model import LinearRegression
from sklearn.pipeline import Pipeline, make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVR
from tqdm.auto import tqdm

from .base import ForceModel, check_rows
from .onnx_graph import floats_attr, fused_stateless_model, ints_attr

#: ai.onnx.ml 3 is what ONNX Runtime 1.2x-1.31 serve for TreeEnsembleRegressor and friends.
TARGET_OPSET = {"": 17, "ai.onnx.ml": 3}


def _to_onnx(estimator: object, n_features: int) -> onnx.ModelProto:
    return convert_sklearn(
        estimator,
        initial_types=[("features", FloatTensorType([None, n_features]))],
        final_types=[("force", FloatTensorType([None, 1]))],
        target_opset=TARGET_OPSET,
    )


class SklearnModel(ForceModel):
    """Shared fit/predict for the scikit-learn regressors (rows layout). Fitted attribute:
    `estimator_`, the fitted scikit-learn estimator (or pipeline)."""

    #: train on float32 features so that float32 ONNX thresholds take the same branches
    float32_features = False
    _legacy_fitted = ("estimator",)

    def _make(self) -> Pipeline | RandomForestRegressor:
        raise NotImplementedError

    def _fit_estimator(self, est: Pipeline | RandomForestRegressor, x: np.ndarray,
                       y: np.ndarray) -> None:  # fmt: skip
        est.fit(x, y)

    def fit(self, X: np.ndarray, y: np.ndarray) -> SklearnModel:
        x, y = check_rows(X, y, len(self.features))
        n_all = len(y)
        # `max_rows` (hyper): at most this many training rows, a random subsample; None = all
        max_rows = int(self.hyper["max_rows"]) if self.hyper.get("max_rows") else None
        if max_rows is not None and n_all > max_rows:
            rng = np.random.default_rng(self.seed)
            keep = np.sort(rng.choice(n_all, max_rows, replace=False))
            x, y = x[keep], y[keep]
        if self.float32_features:
            x = x.astype(np.float32)
        est = self._make()
        t0 = time.perf_counter()
        self._fit_estimator(est, x, y)
        self.estimator_ = est
        self.n_features_in_ = x.shape[1]
        self.train_info_ = {
            "rows": int(len(y)),
            "rows_available": int(n_all),
            "fit_seconds": round(time.perf_counter() - t0, 2),
        }
        return self

    def predict(self, X: np.ndarray) -> np.ndarray:
        self._check_fitted()
        x = self._check_X(X)
        if self.float32_features:
            x = x.astype(np.float32)
        return np.asarray(self.estimator_.predict(x), dtype=np.float64)

    def to_onnx(self) -> onnx.ModelProto:
        self._check_fitted()
        return _to_onnx(self.estimator_, len(self.features))


class LinearModel(SklearnModel):
    algo = "lr"
    defaults = {"scaler": "standard"}

    def _make(self) -> Pipeline:
        return make_pipeline(StandardScaler(), LinearRegression())


SVR_THESIS = {"kernel": "rbf", "C": 0.1, "gamma": 0.002, "epsilon": 1e-4, "max_rows": 5000}
SVR_DEFAULT = {"kernel": "rbf", "C": 10.0, "gamma": "scale", "epsilon": 0.01, "max_rows": 5000}


class SVRModel(SklearnModel):
    """RBF SVR on standardised features.

    Kernel SVR scales quadratically-to-cubically with rows and its prediction cost grows with
    the support vectors, so it is fitted on a random subsample (`max_rows`, default 5000 of the
    decimated rows); the subsample is part of the hyperparameters and the provenance.
    """

    algo = "svr"
    defaults = SVR_DEFAULT

    def _make(self) -> Pipeline:
        h = self.hyper
        return make_pipeline(
            StandardScaler(),
            SVR(kernel=h["kernel"], C=h["C"], gamma=h["gamma"], epsilon=h["epsilon"]),
        )

    def to_onnx(self, fused: bool = True) -> onnx.ModelProto:
        """One `ai.haptics:SvrStep` node (the fused operator: needs libhaptics_fused_ops.so
        where it runs) for the RBF kernel, or with `fused=False` (or another kernel)
        skl2onnx's Scaler + SVMRegressor graph."""
        self._check_fitted()
        svr = self.estimator_[-1]
        if not fused or svr.kernel != "rbf":
            return _to_onnx(self.estimator_, len(self.features))
        return svr_fused(self.estimator_[0], svr, len(self.features))


def svr_fused(scaler: StandardScaler, svr: SVR, n_features: int) -> onnx.ModelProto:
    """The pipeline as one `ai.haptics:SvrStep` node (fused-ops/src/svr.rs; attribute names:
    its `from_attrs`): the scaler's mean and scale, the support vectors in the scaled space,
    the dual coefficients, gamma (as the fit resolved it) and the intercept."""
    attrs = [
        floats_attr("feature_mean", scaler.mean_),
        floats_attr("feature_scale", scaler.scale_),
        floats_attr("support_vectors", svr.support_vectors_),
        floats_attr("coefficients", svr.dual_coef_[0]),
        helper.make_attribute("gamma", float(svr._gamma)),
        helper.make_attribute("intercept", float(svr.intercept_[0])),
    ]
    return fused_stateless_model("SvrStep", attrs, n_features, "svr")


RF_THESIS = {"n_estimators": 1000, "max_depth": 6}
RF_DEFAULT = {"n_estimators": 100, "max_depth": 9, "min_samples_leaf": 1}


class ForestModel(SklearnModel):
    algo = "rf"
    float32_features = True
    defaults = RF_DEFAULT

    def _make(self) -> RandomForestRegressor:
        h = self.hyper
        return RandomForestRegressor(
            n_estimators=int(h["n_estimators"]),
            max_depth=None if h.get("max_depth") is None else int(h["max_depth"]),
            min_samples_leaf=int(h.get("min_samples_leaf", 1)),
            n_jobs=2,
            random_state=self.seed,
        )

    #: trees grown per step of the progress bar
    PROGRESS_CHUNK = 10

    def _fit_estimator(self, est: Pipeline | RandomForestRegressor, x: np.ndarray,
                       y: np.ndarray) -> None:  # fmt: skip
        """Grows the forest in chunks of trees with a progress bar (the default forest takes
        about a minute on two cores). scikit-learn's warm start draws each added tree's seed
        from the same random_state sequence, so the forest equals the one a single fit grows."""
        assert isinstance(est, RandomForestRegressor)
        total = est.n_estimators
        if not self.progress or total <= self.PROGRESS_CHUNK:
            est.fit(x, y)
            return
        est.set_params(warm_start=True)
        with tqdm(total=total, desc=f"{self.name} trees") as bar:
            for n in range(self.PROGRESS_CHUNK, total + self.PROGRESS_CHUNK, self.PROGRESS_CHUNK):
                est.set_params(n_estimators=min(n, total))
                est.fit(x, y)
                bar.update(len(est.estimators_) - bar.n)
        est.set_params(warm_start=False)

    def to_onnx(self, fused: bool = True) -> onnx.ModelProto:
        """One `ai.haptics:ForestStep` node (the fused operator: needs libhaptics_fused_ops.so
        where it runs), or with `fused=False` skl2onnx's TreeEnsembleRegressor + Cast graph."""
        self._check_fitted()
        if not fused:
            return _to_onnx(self.estimator_, len(self.features))
        return forest_fused(self.estimator_, len(self.features))


def thresholds_down(t: np.ndarray) -> np.ndarray:
    """scikit-learn's float64 thresholds as the largest float32 at or below each: for every
    float32 x, `x <= result` exactly when `x <= t` (scikit-learn compares the float32 feature
    widened to float64), so the float32 comparison takes the same branch on every row, where
    rounding to the nearest float32 would flip the rows between the two."""
    t32 = np.asarray(t, dtype=np.float64).astype(np.float32)
    above = t32.astype(np.float64) > t
    t32[above] = np.nextafter(t32[above], np.float32(-np.inf))
    return t32


def forest_fused(forest: RandomForestRegressor, n_features: int) -> onnx.ModelProto:
    """The forest as one `ai.haptics:ForestStep` node (fused-ops/src/forest.rs; attribute names:
    its module doc): each tree's `tree_` arrays one tree after the other (children as
    tree-local indices, -1 at a leaf), the thresholds rounded down to float32
    (`thresholds_down`), the node values (the kernel reads them at the leaves and divides by
    the number of trees)."""
    trees = [e.tree_ for e in forest.estimators_]
    if any(t.n_outputs != 1 for t in trees):
        raise ValueError("forest_fused: one output per tree (a force), not several")
    cat = np.concatenate
    attrs = [
        ints_attr("n_features", [n_features]),
        ints_attr("tree_sizes", [t.node_count for t in trees]),
        ints_attr("children_left", cat([t.children_left for t in trees])),
        ints_attr("children_right", cat([t.children_right for t in trees])),
        ints_attr("split_features", cat([t.feature for t in trees])),
        floats_attr("thresholds", cat([thresholds_down(t.threshold) for t in trees])),
        floats_attr("leaf_values", cat([t.value[:, 0, 0] for t in trees])),
    ]
    return fused_stateless_model("ForestStep", attrs, n_features, "rf")
