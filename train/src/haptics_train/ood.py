"""Scores trained models on the out-of-distribution suite (scripts/record-ood.sh): what the
training recordings never show a model (shuffled peaks, minor loops, long holds, rates outside
the training range, position-controlled presses, hand presses). Free run, as in reproduction:
a feedback model steps its exported graph on its own predictions (`evaluate.evaluate`).

The target of each recording is the model's training target, except the hand presses: in
`shadow` the force loop holds the RFOB near 0 N, so their target is the simulated object's own
force F_object, and the force compared with it is the one the model renders (for `structured`
the object without the bench's friction): like with like. F_true there is the hand's force,
which also carries the bench's friction (up to 1 N while the probe rests) and mass; a
recording made before rt-loop wrote F_object is scored against F_true instead, and its row and
the report say so (`truth.object_truth`). On simulated recordings every run is also scored as
rendered against the object's own force: `rendered_vs_true_rmse`, `worst_true_rmse_n`. A
free run diverges when it is not finite or leaves three times the recording's force range: it
is counted, and its RMSE is reported as it is.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .closed_loop import contact_thresholds
from .data import Recording, load_recording
from .evaluate import evaluate
from .export import provenance, to_contract_onnx
from .fidelity import merge
from .metrics import force_metrics
from .models import ForceModel, TrainConfig
from .truth import FELT_FORCE, object_truth

OOD_FILE = "ood.json"


def is_hand(name: str) -> bool:
    """A hand press of the suite (scripts/record-ood.sh names them hand_*)."""
    return name.startswith("hand_")


def target_column(rec: Recording, cfg: TrainConfig) -> tuple[str, str]:
    """The column a suite recording is scored against (see the module docstring) and, when a
    hand press had to fall back to the felt force, why."""
    if not is_hand(rec.name):
        return cfg.target, ""
    truth = object_truth(rec.columns, rec.name, hand=True)
    return truth.column or FELT_FORCE, truth.note


def diverged(y: np.ndarray, pred: np.ndarray) -> bool:
    """A free run that is not finite or runs beyond three times the force range."""
    if not np.all(np.isfinite(pred)):
        return True
    span = max(float(np.max(np.abs(y))), 1.0)
    return bool(np.max(np.abs(pred)) > 3.0 * span)


def score_suite(
    models: list[tuple[ForceModel, TrainConfig]], suite: Path, out: Path | None = None
) -> dict:
    """name -> {recordings: {rec: metrics + target + diverged}, worst_rmse_n, diverged};
    written to `out` (JSON) when given."""
    paths = sorted(suite.glob("*.parquet"))
    if not paths:
        raise FileNotFoundError(f"no *.parquet recordings in {suite} (scripts/record-ood.sh)")
    doc: dict = {}
    recs = [load_recording(p) for p in paths]
    for model, cfg in models:
        draft = to_contract_onnx(model, provenance(model, cfg, None, None))
        rows: dict = {}
        for rec in recs:
            col, note = target_column(rec, cfg)
            rcfg = TrainConfig(**{**cfg.to_dict(), "target": col, "progress": False})
            res, preds = evaluate(model, draft, rec, rcfg)
            # the free run (`predict` for a kinematics-only model: object + the bench's
            # friction, as the RFOB reads it); on a hand press the force the model renders
            # (the object alone), compared with the object's own force
            pred = preds["closed_loop"]
            if is_hand(rec.name):
                pred = preds.get("rendered", pred)
            y = rec.column(col)
            m = force_metrics(y, pred, rec.column("position_x"), contact_thresholds(rec)[1])
            rows[rec.name] = {"target": col, "rows": len(y), "diverged": diverged(y, pred), **m}
            if note:
                rows[rec.name]["target_note"] = note
                print(f"[ood] {note}", flush=True)
            if "rendered_vs_true" in res:  # simulated: the rendered force vs the object's own
                rows[rec.name]["rendered_vs_true_rmse"] = res["rendered_vs_true"]["rmse"]
            print(f"[ood] {model.name} {rec.name}: free-run RMSE {m['rmse']:.4g} N"
                  f"{' DIVERGED' if rows[rec.name]['diverged'] else ''}", flush=True)  # fmt: skip
        rmses = [r["rmse"] for r in rows.values()]
        worst = max(rmses, key=lambda v: v if math.isfinite(v) else math.inf)
        doc[model.name] = {
            "recordings": rows,
            "worst_rmse_n": worst,
            "worst_recording": next(k for k, r in rows.items() if r["rmse"] == worst),
            "worst_true_rmse_n": max((r["rendered_vs_true_rmse"] for r in rows.values()
                                      if "rendered_vs_true_rmse" in r), default=None),
            "diverged": sum(r["diverged"] for r in rows.values()),
        }
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(doc, indent=1, default=float))
    return doc


def fidelity_keys(doc: dict, recommended: str) -> dict:
    """docs/fidelity.json's suite keys for the recommended model."""
    e = doc[recommended]
    return {"ood_free_run_rmse_n": e["worst_rmse_n"], "ood_diverged": e["diverged"],
            "ood_worst_recording": e["worst_recording"],
            "ood_true_free_run_rmse_n": e.get("worst_true_rmse_n")}  # fmt: skip


def write_fidelity(doc: dict, recommended: str, path: Path) -> dict:
    return merge(path, fidelity_keys(doc, recommended))


OOD_HEADING = "## Out-of-distribution suite"


def _cell(v: float) -> str:
    return f"{v:.3f}" if math.isfinite(v) else "inf"


def readme_section(doc: dict, recommended: str | None = None) -> list[str]:
    """The suite's table (free-run RMSE, N, model by recording) and its sentences, every one
    computed from `doc` (`score_suite`'s)."""
    names = list(doc)
    recs = sorted({r for e in doc.values() for r in e["recordings"]})
    true = any(e.get("worst_true_rmse_n") is not None for e in doc.values())
    L = [f"{OOD_HEADING}\n",
         "Free-run RMSE (N) of each model on each recording of the suite "
         "(`scripts/record-ood.sh`, scored by `haptics-train ood`); the hand presses are "
         "scored as rendered against the simulated object's own force F_object (not the "
         "hand's F_true, which carries the bench's friction and mass too), the others "
         "against the training target. "
         "A run is counted diverged when it is not finite or leaves three times the "
         "recording's force range."
         + (" After the slash: the rendered force against the simulated object's own force "
            "on every recording." if true else "") + "\n",
         "| recording | " + " | ".join(f"`{n}`" for n in names) + " |",
         "|---|" + "---|" * len(names)]  # fmt: skip

    def both(v: float, t: float | None) -> str:
        return _cell(v) + ("" if t is None else f" / {_cell(t)}")

    for r in recs:
        cells = []
        for n in names:
            e = doc[n]["recordings"].get(r)
            cells.append("-" if e is None else both(e["rmse"], e.get("rendered_vs_true_rmse"))
                         + (" (diverged)" if e["diverged"] else ""))  # fmt: skip
        L.append(f"| {r} | " + " | ".join(cells) + " |")
    L.append("| **worst** | " + " | ".join(both(doc[n]["worst_rmse_n"],
                                                doc[n].get("worst_true_rmse_n"))
                                           for n in names) + " |\n")  # fmt: skip
    for n in names:
        e = doc[n]
        tag = " (the recommended model)" if n == recommended else ""
        t = e.get("worst_true_rmse_n")
        L.append(f"- `{n}`{tag}: worst {_cell(e['worst_rmse_n'])} N on "
                 f"`{e['worst_recording']}`, {e['diverged']} of {len(e['recordings'])} "
                 "recordings diverged"
                 + ("." if t is None else f"; against the object's own force, worst "
                    f"{_cell(t)} N."))  # fmt: skip
    notes = sorted({r["target_note"] for e in doc.values() for r in e["recordings"].values()
                    if r.get("target_note")})  # fmt: skip
    if notes:
        L.append("\nScored against the felt force instead of the object's own: "
                 + "; ".join(notes) + ".")
    return [*L, ""]


def write_readme_section(readme: Path, doc: dict, recommended: str | None = None) -> None:
    """Puts the suite's section into a study README: in place of an earlier one, else before
    its `## Timings` (else at the end)."""
    text = readme.read_text() if readme.exists() else ""
    lines = text.split("\n")
    sec = readme_section(doc, recommended)
    heads = [i for i, line in enumerate(lines) if line.startswith("## ")]
    start = next((i for i in heads if lines[i].startswith(OOD_HEADING)), None)
    if start is not None:
        end = next((i for i in heads if i > start), len(lines))
    else:
        start = end = next((i for i in heads if lines[i].startswith("## Timings")), len(lines))
    readme.write_text("\n".join([*lines[:start], *sec, *lines[end:]]))
