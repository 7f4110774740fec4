"""Scoring: a run's felt force against the reference's, aligned by time, and the picks the
report and docs/fidelity.json make from the scores (best learned model, sd_poly2, the oracle's
floor). Pure functions on arrays and rows: tested on synthetic series."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..metrics import regression_metrics
from ..truth import FELT_FORCE, OBJECT_FORCE, object_truth
from .processes import Run
from .protocol import BUILTIN, FAST_ALWAYS, FAST_BEST, ORACLE, SPRING_DAMPERS


def align(
    t_ref: np.ndarray, t_run: np.ndarray, y_run: np.ndarray, tol: float = 1e-9
) -> tuple[np.ndarray, np.ndarray]:
    """`y_run` at the reference's time stamps, and the mask of reference samples it covers.

    Both series start at their own t[0] (lockstep runs of the same programme start at 0). The
    run is linearly interpolated onto the reference grid; reference samples outside the run's
    time span (a run that stopped early) are not covered: they get NaN and mask False, so a
    short run cannot be scored on data it never produced.
    """
    t_ref = np.asarray(t_ref, dtype=np.float64) - float(t_ref[0])
    t_run = np.asarray(t_run, dtype=np.float64) - float(t_run[0])
    y_run = np.asarray(y_run, dtype=np.float64)
    if t_run.shape != y_run.shape or t_run.size < 2:
        raise ValueError("a run needs at least two (time, value) samples of equal length")
    if np.any(np.diff(t_run) < 0):
        raise ValueError("run time must be non-decreasing")
    covered = (t_ref >= t_run[0] - tol) & (t_ref <= t_run[-1] + tol)
    out = np.full(t_ref.shape, np.nan)
    out[covered] = np.interp(t_ref[covered], t_run, y_run)
    return out, covered


def compare(
    t_ref: np.ndarray, f_ref: np.ndarray, t_run: np.ndarray, f_run: np.ndarray
) -> dict[str, float]:
    """R2/MAE/MSE/RMSE of a run's force against the reference force, aligned by time, plus
    `coverage`: the fraction of the reference's duration the run covered."""
    y_run, covered = align(t_ref, t_run, f_run)
    if not covered.any():
        raise ValueError("the run covers none of the reference's time span")
    m = regression_metrics(np.asarray(f_ref, dtype=np.float64)[covered], y_run[covered])
    m["coverage"] = float(covered.mean())
    return m


def ratio(sd_rmse: float, best_rmse: float) -> float:
    """How many times closer to the reference the best model is than the spring-damper."""
    if not (math.isfinite(sd_rmse) and math.isfinite(best_rmse)) or best_rmse <= 0:
        return float("nan")
    return sd_rmse / best_rmse


#: The hand programme's phases, in the order rt-loop's hand goes through them
#: (rt-loop/src/experiment/hand.rs, `HandConfig::setpoint`).
HAND_PHASES = ("press", "hold", "release", "rest")


def cycle_s(hand: dict[str, float]) -> float:
    """One cycle of the hand programme: press, hold, release and rest."""
    return hand["press_s"] + hand["hold_s"] + hand["release_s"] + hand["rest_s"]


def programme_s(hand: dict[str, float]) -> float:
    """The whole programme's loop time: the first rest, then every cycle."""
    return hand["rest_s"] + hand["repeats"] * cycle_s(hand)


def hand_phase(t: np.ndarray, hand: dict[str, float]) -> np.ndarray:
    """Which phase of the hand programme each time stamp falls in (an index into
    HAND_PHASES), as rt-loop's hand computes its set-point: a rest of `rest_s` first, then
    `repeats` cycles of press, hold, release and rest; after the last cycle, rest. `t` is
    loop time from the run's start."""
    t = np.asarray(t, dtype=np.float64) - float(t[0]) - hand["rest_s"]
    ends = np.cumsum([hand["press_s"], hand["hold_s"], hand["release_s"], hand["rest_s"]])
    period = float(ends[-1])
    k = np.floor(t / period)
    tc = t - k * period
    phase = np.searchsorted(ends, tc, side="right")
    rest = HAND_PHASES.index("rest")
    outside = (t < 0) | (k >= hand["repeats"])
    # min: a time stamp rounding onto the period's end is still its rest
    return np.where(outside, rest, np.minimum(phase, rest))


def felt_error(
    t_ref: np.ndarray, f_ref: np.ndarray, r: Run
) -> tuple[np.ndarray, np.ndarray] | None:
    """A run's felt force minus the reference's on the reference's time stamps, and the mask
    of those the run covered (`align`); None for a run with nothing to score."""
    if not r.series or r.steps == 0:
        return None
    y, covered = align(t_ref, r.series["time"], r.series["F_true"])
    if not covered.any():
        return None
    return y - np.asarray(f_ref, dtype=np.float64), covered


def felt_by_phase(
    t_ref: np.ndarray, f_ref: np.ndarray, r: Run, hand: dict[str, float]
) -> dict[str, dict[str, float | None]] | None:
    """Where a run's felt-force error sits in the hand programme: per phase, the share of the
    time (`time_share`), the share of the squared error (`sq_error_share`), the RMSE and the
    mean error (`bias_n`, run minus reference: negative when the operator pushes with less
    force than on the real object, i.e. the rendering is softer there). Scored where the run
    covered the reference, like `compare` (shares of an error that is exactly zero are None);
    None for a run with nothing to score."""
    err = felt_error(t_ref, f_ref, r)
    if err is None:
        return None
    e, covered = err[0][err[1]], err[1]
    ph = hand_phase(t_ref, hand)[covered]
    total = float(np.sum(e**2))
    out: dict[str, dict[str, float | None]] = {}
    for i, name in enumerate(HAND_PHASES):
        m = ph == i
        if not m.any():
            continue
        sq = float(np.sum(e[m] ** 2))
        out[name] = {
            "time_share": float(m.mean()),
            "sq_error_share": sq / total if total > 0 else None,
            "rmse": math.sqrt(sq / int(m.sum())),
            "bias_n": float(e[m].mean()),
        }
    return out


def felt_by_press(
    t_ref: np.ndarray, f_ref: np.ndarray, r: Run, hand: dict[str, float]
) -> list[float] | None:
    """A run's felt-force RMSE over each cycle of the hand programme (press, hold, release and
    rest; the first rest and anything after the last cycle left out), in order; scored where
    the run covered the reference, like `compare`; a cycle it did not cover at all is NaN.
    None for a run with nothing to score."""
    err = felt_error(t_ref, f_ref, r)
    if err is None:
        return None
    e, covered = err
    t = np.asarray(t_ref, dtype=np.float64) - float(t_ref[0]) - hand["rest_s"]
    k = np.floor(t / cycle_s(hand))
    out = []
    for i in range(int(hand["repeats"])):
        m = (k == i) & covered
        out.append(math.sqrt(float(np.mean(e[m] ** 2))) if m.any() else math.nan)
    return out


@dataclass
class Row:
    name: str
    how: str  # "served (ONNX)" / "rt-loop builtin"
    repro: dict[str, float] | None
    shadow: dict[str, float] | None
    run: Run
    shadow_run: Run | None
    learned: bool
    #: the truth `shadow` was scored against (F_object; F_true in an older recording)
    shadow_truth: str = OBJECT_FORCE
    #: why it is not F_object, when it is not
    shadow_note: str = ""
    #: `felt_by_phase` of the reproduction: where in the hand programme its error sits
    by_phase: dict[str, dict[str, float | None]] | None = None
    #: `felt_by_press` of the reproduction: its felt-force RMSE press by press
    by_press: list[float] | None = None


def prediction_along_real(sh: Run) -> tuple[dict[str, float] | None, str, str]:
    """The thesis's 6.4.4 comparison on a shadow run: F_pred (the model along the real
    interaction) against the simulated object's own force F_object, like with like (the hand's
    F_true also carries the bench's friction and mass, which an object model does not
    predict); `felt_rmse` beside it is the same against F_true. Also the column used and, when
    it is not F_object (a recording older than it), why."""
    if not sh.series or sh.served == 0:
        return None, OBJECT_FORCE, ""
    truth = object_truth(sh.series, sh.name, hand=True)
    if truth.column is None:
        return None, OBJECT_FORCE, truth.note
    m = regression_metrics(sh.series[truth.column], sh.series["F_pred"])
    m["felt_rmse"] = regression_metrics(sh.series[FELT_FORCE], sh.series["F_pred"])["rmse"]
    return m, truth.column, truth.note


def repro_rmse(r: Row) -> float:
    return r.repro["rmse"] if r.repro else math.inf


def score_run(t_ref: np.ndarray, f_ref: np.ndarray, r: Run) -> dict[str, float] | None:
    if not r.series or r.steps == 0:
        return None
    return compare(t_ref, f_ref, r.series["time"], r.series["F_true"])


def rankable(r: Row) -> bool:
    return (
        r.repro is not None
        and r.run.ok
        and r.repro["coverage"] > 0.999
        and math.isfinite(r.repro["rmse"])
    )


def best_row(rows: list[Row], learned: bool, key: str = "repro") -> Row | None:
    cand = [r for r in rows if r.learned == learned and rankable(r) and getattr(r, key)]
    if not cand:
        return None
    return min(cand, key=lambda r: getattr(r, key)["rmse"])


def fast_models(rows: list[Row]) -> set[str]:
    """The models the fast hand and the long session run (besides the oracle): the
    `FAST_BEST` learned models closest on the headline, the spring-dampers, and `FAST_ALWAYS`
    (the models every law's table shows), each where it was studied."""
    ranked = sorted((r for r in rows if r.learned and rankable(r)), key=repro_rmse)
    studied = {r.name for r in rows}
    always = (set(SPRING_DAMPERS) | set(FAST_ALWAYS)) & studied
    return {r.name for r in ranked[:FAST_BEST]} | always


def sd2_row(rows: list[Row]) -> Row | None:
    return next((r for r in rows if r.name == "sd_poly2"), None)


def named_row(rows: list[Row], name: str) -> Row | None:
    return next((r for r in rows if r.name == name), None)


def felt_rmse(r: Row | None) -> float:
    return r.repro["rmse"] if r is not None and r.repro and rankable(r) else math.nan


def run_flags(r: Row, rows: list[Row]) -> list[str]:
    """What a reader must know beside a run's felt-force figure (issue 23): steps rendered at
    the force limit (`saturated`), answers refused (`refused`: NaN/Inf), and, for the oracle,
    that it is not the floor (a model felt closer than the object's own physics: the floor is
    broken, e.g. by saturation or refusals) or, for a model, that it beat the oracle."""
    out = []
    if r.run.saturated:
        out.append(f"{r.run.saturated} saturated")
    if r.run.rejected:
        out.append(f"{r.run.rejected} refused")
    oracle = felt_rmse(named_row(rows, ORACLE))
    mine = felt_rmse(r)
    if math.isfinite(oracle):
        if r.name == ORACLE:
            below = [o.name for o in rows if o.name != ORACLE and felt_rmse(o) < oracle]
            if below:
                out.append("oracle not the floor: " + ", ".join(sorted(below)) + " felt closer")
        elif math.isfinite(mine) and mine < oracle:
            out.append("below the oracle")
    return out


def flags_text(r: Row, rows: list[Row]) -> str:
    return "; ".join(run_flags(r, rows)) or "-"


def floor_summary(rows: list[Row]) -> dict[str, object]:
    """Felt-force RMSE of the oracle (floor), sd_poly2, the builtin and the best learned model
    of one friction setting."""
    best = best_row(rows, True)
    return {
        "oracle_felt_rmse_n": felt_rmse(named_row(rows, ORACLE)),
        "sd_poly2_felt_rmse_n": felt_rmse(sd2_row(rows)),
        "builtin_felt_rmse_n": felt_rmse(named_row(rows, BUILTIN)),
        "best_learned": best.name if best else None,
        "best_learned_felt_rmse_n": felt_rmse(best),
        "models": {r.name: felt_rmse(r) for r in rows},
        "flags": {r.name: run_flags(r, rows) for r in rows if run_flags(r, rows)},
    }


def nan_to_none(v: float) -> float | None:
    return v if math.isfinite(v) else None
