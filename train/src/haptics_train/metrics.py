"""Regression metrics of the thesis (eqs. 7.15-7.19): R2, MAE, MSE, RMSE; and the force
metrics a felt force is judged by (maximum error, error relative to the range, contact-only
RMSE, error of the dissipated energy)."""

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


def loop_work(x: np.ndarray, f: np.ndarray) -> float:
    """Net work done on the object over the series, J: the trapezoid integral of F dx. Over
    whole loading-unloading cycles it is the area of the force-depth loops, the energy the
    object dissipated."""
    x = np.asarray(x, dtype=np.float64).ravel()
    f = np.asarray(f, dtype=np.float64).ravel()
    with np.errstate(over="ignore", invalid="ignore"):
        return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(x)))


#: |work| below this over a recording is numerical noise, not energy given back: the bench's
#: free-air recordings, where the probe barely meets the object, read within 2e-4 J of zero
ACTIVE_WORK_TOL_J = 1e-3


def active_work_note(works: list[float], tol_j: float = ACTIVE_WORK_TOL_J) -> str | None:
    """What to tell a user whose model, rendered along its own training recordings, did
    negative net work on one of them (`works`: `loop_work` per recording, J): over a recording
    that starts and ends at rest a passive object absorbs energy; one that gives it back can feel
    active in the hand. None when every recording absorbed (or stayed within `tol_j` of 0)."""
    bad = [(i, w) for i, w in enumerate(works) if w < -tol_j]
    if not bad:
        return None
    which = ", ".join(f"recording {i + 1} of {len(works)}: {-w:.3g} J" for i, w in bad)
    return (
        f"the rendered object gives energy back over its training recordings ({which}); a "
        "passive object absorbs it, so this model can feel active: rt-loop's passivity layer "
        "bounds it (on by default for a real board, `--passivity on` on the bench)"
    )


def force_metrics(
    y_true: np.ndarray, y_pred: np.ndarray, x: np.ndarray, contact_n: float
) -> dict[str, float]:
    """The regression metrics plus what a free-run force must get right to feel right:

    - `max_abs`: the largest error, N;
    - `rmse_pct_range`: RMSE as a percentage of the measured force's range (max - min);
    - `contact_rmse`: RMSE over the rows in contact (measured force above `contact_n`, the
      recording's contact-off threshold), N: the rows the hand feels;
    - `loop_work_true` / `loop_work_error`: the dissipated energy (force-depth loop area, J) and
      the prediction's error on it; `loop_work_error_pct` relative to the true one.
    """
    y = np.asarray(y_true, dtype=np.float64).ravel()
    p = np.asarray(y_pred, dtype=np.float64).ravel()
    m: dict[str, float] = regression_metrics(y, p)
    e = y - p
    rng = float(np.max(y) - np.min(y))
    with np.errstate(over="ignore", invalid="ignore"):
        m["max_abs"] = float(np.max(np.abs(e))) if np.all(np.isfinite(e)) else float("inf")
        m["rmse_pct_range"] = 100.0 * m["rmse"] / rng if rng > 0 else float("nan")
        c = y > contact_n
        m["contact_rows"] = int(c.sum())
        m["contact_rmse"] = (
            math.sqrt(float(np.mean(e[c] ** 2))) if c.any() else float("nan")
        )
        if not math.isfinite(m["contact_rmse"]) and c.any():
            m["contact_rmse"] = float("inf")
        w_true = loop_work(x, y)
        w_pred = loop_work(x, p)
        m["loop_work_true"] = w_true
        m["loop_work_error"] = w_pred - w_true if math.isfinite(w_pred) else float("inf")
        m["loop_work_error_pct"] = (
            100.0 * m["loop_work_error"] / abs(w_true) if w_true != 0 else float("nan")
        )
    return m


def pooled(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, float]]) -> dict[str, float]:
    """`force_metrics` over several recordings taken together (every row weighs the same;
    loop work summed over the recordings)."""
    ys = np.concatenate([p[0] for p in parts])
    ps = np.concatenate([p[1] for p in parts])
    m = force_metrics(ys, ps, np.zeros(len(ys)), float("inf"))
    per = [force_metrics(y, p, x, c) for y, p, x, c in parts]
    c_rows = sum(q["contact_rows"] for q in per)
    m["contact_rows"] = c_rows
    m["contact_rmse"] = (
        math.sqrt(sum(q["contact_rmse"] ** 2 * q["contact_rows"] for q in per) / c_rows)
        if c_rows else float("nan")
    )  # fmt: skip
    m["loop_work_true"] = sum(q["loop_work_true"] for q in per)
    m["loop_work_error"] = sum(q["loop_work_error"] for q in per)
    w = m["loop_work_true"]
    m["loop_work_error_pct"] = 100.0 * m["loop_work_error"] / abs(w) if w != 0 else float("nan")
    return m


def fmt_figure(v: float | None) -> str:
    """A figure (an RMSE, a percentage) as the training logs print it: 4 significant digits,
    "-" when there is none, "diverged" when it is not finite."""
    if v is None:
        return "-"
    return f"{v:.4g}" if np.isfinite(v) else "diverged"
