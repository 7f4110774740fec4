"""Free-run (closed-loop) and one-step evaluation of a trained model on held-out recordings,
and the baselines every model is printed beside: persistence F(t-1), the training mean and the
spring-damper sd_poly2. At 10 kHz repeating the previous force is nearly perfect one-step, so a
one-step figure means nothing without persistence's beside it; free run is what reproduction
feels, so it comes first."""

from __future__ import annotations

import time

import numpy as np
import onnx

from .closed_loop import OnnxStepper, contact_thresholds, simulate
from .data import Dataset, Recording, to_rows
from .features import F_PREVIOUS, FEEDBACK_FEATURES, TARGET_DEFAULT
from .metrics import force_metrics, pooled, regression_metrics
from .models.base import ForceModel, TrainConfig, fit_recordings, predict_at
from .truth import is_hand_run, object_truth


def true_column(rec: Recording) -> str | None:
    """The simulated object's own force in `rec` (`truth.object_truth`: F_object, or F_true
    where a recording predates it, said on stdout when that was a hand run); None on a real or
    imported recording."""
    hand = is_hand_run(rec.meta, rec.name)
    truth = object_truth(rec.columns, rec.name, hand)
    if hand and truth.note:
        print(f"[evaluate] {truth.note}", flush=True)
    return truth.column


def needs_feedback(model: ForceModel) -> bool:
    return any(f in FEEDBACK_FEATURES for f in model.features)


def evaluate(
    model: ForceModel,
    onnx_model: onnx.ModelProto,
    rec: Recording,
    cfg: TrainConfig,
    closed_loop: bool = True,
) -> tuple[dict, dict[str, np.ndarray]]:
    """Metrics at every row of `rec`:

    - one-step: the framework model on the recorded features (the previous force is the
      measured one, as the thesis scored);
    - closed-loop: the exported ONNX model stepped through the recording as the server runs
      it, every force-dependent feature (ratios, f_previous, cycle features) rebuilt from its
      own predictions. A model without any such feature gets the same inputs either way, so
      its closed-loop result is its one-step result (`closed_loop_same_as_one_step`);
    - rendered vs true (simulated recordings only): the force the graph renders against the
      object's own force `F_object` (`F_true` on a recording older than that column).
    """
    y = rec.target(cfg.target)
    x = rec.column("position_x")
    contact = contact_thresholds(rec)[1]
    t0 = time.perf_counter()
    # at the recording's own rows' period (a test logged at another rate than training)
    one = predict_at(model, rec.matrix(model.features), 1.0 / rec.sample_rate_hz)
    res: dict = {
        "recording": rec.name,
        "rows": int(len(y)),
        "row_step": rec.row_step,
        "one_step": force_metrics(y, one, x, contact),
        "one_step_seconds": round(time.perf_counter() - t0, 2),
    }
    preds = {"one_step": one}
    if closed_loop:
        if needs_feedback(model):
            t0 = time.perf_counter()
            cl = simulate(
                OnnxStepper(onnx_model), rec, model.features, progress=cfg.progress,
                desc=f"{model.name} closed loop",
            )  # fmt: skip
            res["closed_loop"] = force_metrics(y, cl, x, contact)
            res["closed_loop_seconds"] = round(time.perf_counter() - t0, 2)
            res["closed_loop_us_per_step"] = round(1e6 * res["closed_loop_seconds"] / len(y), 2)
            res["closed_loop_same_as_one_step"] = False
            preds["closed_loop"] = cl
        else:
            res["closed_loop"] = dict(res["one_step"])
            res["closed_loop_same_as_one_step"] = True
            preds["closed_loop"] = one
        true = true_column(rec)
        if true is not None:
            # On the simulated bench the object's own force is known: what the graph renders
            # (`structured` leaves the bench's friction out of it) against it. The recorded
            # target (the RFOB estimate) carries the bench's friction and, while the probe
            # sticks, whatever force the controller leaves, which no model of the object can
            # or should follow.
            served = getattr(model, "predict_served", None)
            if served is not None:
                preds["rendered"] = served(rec.matrix(model.features), 1.0 / rec.sample_rate_hz)
            rendered = preds.get("rendered", preds["closed_loop"])
            res["rendered_vs_true"] = force_metrics(rec.column(true), rendered, x, contact)
            res["true_column"] = true
    return res, preds


#: Speed above which the probe slides, m/s: the rows of the `sliding` free-run score, on a
#: recording whose pressing motion is fast enough to tell (below).
SLIDING_MPS = 1e-3

#: On a slower recording, the probe slides above this fraction of its own pressing speed (the
#: 99th percentile of |v| in contact, `sliding_speed`).
SLIDING_FRACTION = 0.1


def sliding_speed(rec: Recording) -> float:
    """The speed (m/s) above which `rec`'s probe counts as sliding: `SLIDING_MPS`, or a tenth
    of the recording's own pressing speed where that is lower.

    Why both: on the bench a stuck probe reads under 0.01 mm/s, and the bench's programmes
    press at 10-47 mm/s (99th percentile in contact) on the sponge, the foams and the gel, so
    the absolute threshold decides there; on the slower Bouc-Wen and Hunt-Crossley objects
    (5-14 mm/s) the relative one counts the rows that creep at 0.5-1 mm/s too. A testing
    machine loads at a constant rate that can be well under 1 mm/s (0.25-0.5 mm/s in the
    leave-one-rate-out tests, docs/examples at 0.5): every row of such a test was below the
    absolute threshold, so the whole recording dropped out of the pooled score, and a
    validation choice over a slow and a fast rate saw only the fast one (docs/laws.md, "A slow
    validation test was not scored")."""
    x, v = rec.column("position_x"), np.abs(rec.column("velocity"))
    pressed = v[x > 0.0]
    if len(pressed) == 0:
        return SLIDING_MPS
    return min(SLIDING_MPS, SLIDING_FRACTION * float(np.percentile(pressed, 99)))


def sliding_rows(rec: Recording) -> np.ndarray:
    """The rows of `rec` where the probe is pressed into the object (x > 0) and slides
    (|v| above `sliding_speed`); every row where it has none (a recording that never presses),
    so each recording counts in the pooled score as `SELECTION_METRIC` says."""
    keep = (rec.column("position_x") > 0.0) & (np.abs(rec.column("velocity")) > sliding_speed(rec))
    return keep if keep.any() else np.ones(len(keep), dtype=bool)


def sliding_metrics(
    recs: list[Recording], preds: list[dict[str, np.ndarray]], target: str
) -> dict[str, float]:
    """The free run's regression metrics over the rows where the probe is pressed into the
    object and slides (`sliding_rows`), pooled.

    Why: the recorded target (the RFOB estimate) holds the bench's friction. While the probe
    slides it is the sliding friction, a function of the motion that a model can follow; while
    it sticks (every hold and turn of a force-controlled ramp) it is whatever the force
    controller leaves, up to the breakaway force, which no function of the kinematics knows.
    Over all rows those stick rows set a floor of about 0.4 N on the simulated bench that every
    good model shares, so the all-row score ranks models by noise; over the sliding rows the
    same models score 0.09-0.3 N and their order follows their error against the object's own
    force (docs/laws.md). On a rig without friction (testing-machine data) it drops only the
    rests and the turning points, at any loading rate (`sliding_speed`)."""
    ys, ps = [], []
    for r, p in zip(recs, preds, strict=True):
        keep = sliding_rows(r)
        ys.append(r.target(target)[keep])
        ps.append(np.asarray(p["closed_loop"])[keep])
    y, pr = np.concatenate(ys), np.concatenate(ps)
    if len(y) == 0:
        return {"rows": 0, "rmse": float("nan")}
    return {"rows": int(len(y)), **regression_metrics(y, pr)}


def pooled_metrics(
    recs: list[Recording], preds: list[dict[str, np.ndarray]], target: str
) -> dict[str, dict]:
    """Per kind (one_step, closed_loop), the metrics over all recordings taken together."""
    out: dict[str, dict] = {}
    for kind in ("closed_loop", "one_step"):
        if all(kind in p for p in preds):
            out[kind] = pooled([
                (r.target(target), p[kind], r.column("position_x"), contact_thresholds(r)[1])
                for r, p in zip(recs, preds, strict=True)
            ])  # fmt: skip
    if recs and all("closed_loop" in p for p in preds):
        out["sliding"] = sliding_metrics(recs, preds, target)
    trues = [true_column(r) for r in recs]
    if recs and all("closed_loop" in p for p in preds) and None not in trues:
        # the rendered force against the simulated object's own (see `evaluate`)
        out["rendered_vs_true"] = pooled([
            (r.column(t), p.get("rendered", p["closed_loop"]), r.column("position_x"),
             contact_thresholds(r)[1])
            for r, p, t in zip(recs, preds, trues, strict=True)
        ])  # fmt: skip
    return out


BASELINES = ("persistence", "mean", "sd_poly2")


def baseline_predictions(
    dataset: Dataset, cfg: TrainConfig, sd_poly2: ForceModel | None = None
) -> dict[str, dict[str, list[dict[str, np.ndarray]]]]:
    """name -> split -> per recording {one_step, closed_loop} predictions:

    - persistence: one-step F(t-1), the measured force of the previous control step; in free
      run it has only its own output to repeat, so it holds the first measured force;
    - mean: the training recordings' mean force, everywhere;
    - sd_poly2: the 2nd-order spring-damper fitted on the training recordings (kinematics
      only, so free run equals one-step); the trained one when given.
    """
    if sd_poly2 is None:
        from .models import make_model

        sd_poly2 = fit_recordings(make_model("sd_poly2"), dataset.train, cfg)
    _, y_train = to_rows(dataset.train, ("position_x",), cfg.target, cfg.decimate,
                         cfg.target_rate_hz)  # fmt: skip
    mean = float(np.mean(y_train))
    out: dict[str, dict[str, list[dict[str, np.ndarray]]]] = {b: {} for b in BASELINES}
    for split in ("validation", "test"):
        for b in BASELINES:
            out[b][split] = []
        for rec in dataset.split(split):
            y = rec.target(cfg.target)
            # F(t-1) of the previous control step (exact from the ratio features) for the
            # RFOB target; the previous row of any other target column
            prev = (rec.column(F_PREVIOUS) if cfg.target == TARGET_DEFAULT
                    else np.concatenate([[0.0], y[:-1]]))  # fmt: skip
            out["persistence"][split].append(
                {"one_step": prev, "closed_loop": np.full(len(y), y[0])}
            )
            m = np.full(len(y), mean)
            out["mean"][split].append({"one_step": m, "closed_loop": m})
            sd = sd_poly2.predict(rec.matrix(sd_poly2.features))
            out["sd_poly2"][split].append({"one_step": sd, "closed_loop": sd})
    return out


def score_baselines(
    dataset: Dataset, cfg: TrainConfig, sd_poly2: ForceModel | None = None
) -> dict[str, dict]:
    """name -> {split: [per recording metrics], split_pooled: {kind: metrics}}."""
    preds = baseline_predictions(dataset, cfg, sd_poly2)
    out: dict[str, dict] = {}
    for b, by_split in preds.items():
        entry: dict = {}
        for split, plist in by_split.items():
            recs = dataset.split(split)
            entry[split] = [
                {
                    "recording": r.name,
                    "rows": len(r),
                    **{
                        k: force_metrics(r.target(cfg.target), p[k], r.column("position_x"),
                                         contact_thresholds(r)[1])
                        for k in ("closed_loop", "one_step")
                    },
                }
                for r, p in zip(recs, plist, strict=True)
            ]  # fmt: skip
            if recs:
                entry[f"{split}_pooled"] = pooled_metrics(recs, plist, cfg.target)
        out[b] = entry
    return out


def ranking(results: dict, split: str = "validation") -> list[tuple[str, float]]:
    """Models by pooled free-run RMSE on `split`, best first (diverged last); never one-step."""
    scored = [
        (n, ((r.get(f"{split}_pooled") or {}).get("closed_loop") or {}).get("rmse"))
        for n, r in results.items()
    ]
    return sorted(
        ((n, float(v)) for n, v in scored if v is not None),
        key=lambda nv: (not np.isfinite(nv[1]), nv[1]),
    )
