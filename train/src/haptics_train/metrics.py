"""Regression metrics of the thesis (eqs. 7.15-7.19): R2, MAE, MSE, RMSE."""

from __future__ import annotations

import math

import numpy as np


def regression_metrics(y_true: np.ndarray, y_pred: np.ndarray) -> dict[str, float]:
    """R2 = 1 - SS_res / SS_tot, MAE = mean|e|, MSE = mean e^2, RMSE = sqrt(MSE).

    A prediction that is not finite everywhere scores NaN/inf rather than being silently
    dropped: a model that diverges in closed loop must show it.
    """
    y = np.asarray(y_true, dtype=np.float64).ravel()
    p = np.asarray(y_pred, dtype=np.float64).ravel()
    if y.shape != p.shape:
        raise ValueError(f"shape mismatch: {y.shape} vs {p.shape}")
    if y.size == 0:
        raise ValueError("no samples")
    e = y - p
    with np.errstate(over="ignore", invalid="ignore"):
        mse = float(np.mean(e * e))
        mae = float(np.mean(np.abs(e)))
        ss_tot = float(np.sum((y - y.mean()) ** 2))
        ss_res = float(np.sum(e * e))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else float("nan")
    rmse = math.sqrt(mse) if mse >= 0 and math.isfinite(mse) else float("inf")
    return {"r2": r2, "mae": mae, "mse": mse, "rmse": rmse}
