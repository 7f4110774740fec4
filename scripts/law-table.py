#!/usr/bin/env python3
"""The per-law table of issue 23 from the runs' own JSON: for each law, the oracle, sd_poly2,
rf_memory, structured, lawfree and the recommended model; felt force (the study's hand),
fast hand, free run on the held-out test recording; the flags beside each figure.

Usage: scripts/law-table.py OUT.md LAW=DIR [LAW=DIR ...]
  DIR holds models/results.json and models/recommendation.json (haptics-train train/evaluate,
  the recommendation re-ranked by the study) and study/results.json (haptics-train study --out
  DIR/study). Writes OUT.md and OUT.json (the same numbers)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

MODELS = ("oracle", "sd_poly2", "rf_memory", "structured", "structured_path", "structured_hyst",
          "lawfree", "structured_holds", "structured_path_holds", "structured_hyst_holds",
          "lawfree_holds", "blend")


def read(p: Path) -> dict:
    try:
        d = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError):
        return {}
    return d if isinstance(d, dict) else {}


def num(v: object) -> float:
    return float(v) if isinstance(v, int | float) and math.isfinite(v) else math.nan


def fmt(v: float, nd: int = 3) -> str:
    return "-" if not math.isfinite(v) else f"{v:.{nd}f}"


def weights(doc: dict) -> tuple[float, float]:
    """The blend's weights (an earlier study's entry has none: equal)."""
    w = doc.get("blend_weights") or [0.5, 0.5]
    return float(w[0]), float(w[1])


def law_rows(d: Path) -> dict:
    res = read(d / "models" / "results.json")
    rec = read(d / "models" / "recommendation.json")
    st = read(d / "study" / "results.json")
    sm = st.get("models") or {}
    fast = st.get("fast_hand") or {}
    blend = rec.get("blend") or {}
    out: dict = {"recommended": rec.get("recommended"), "models": {},
                 "blend": blend.get("members"), "blend_weights": blend.get("weights")}  # fmt: skip
    for name in (*MODELS, rec.get("recommended")):
        if not name or name in out["models"]:
            continue
        e = sm.get(name) or {}
        free = ((res.get(name) or {}).get("test_pooled") or {}).get("closed_loop") or {}
        val = ((res.get(name) or {}).get("validation_pooled") or {}).get("closed_loop") or {}
        slide = ((res.get(name) or {}).get("test_pooled") or {}).get("sliding") or {}
        vslide = ((res.get(name) or {}).get("validation_pooled") or {}).get("sliding") or {}
        out["models"][name] = {
            "felt_rmse_n": num((e.get("reproduction") or {}).get("rmse")),
            "fast_rmse_n": num((fast.get(name) or {}).get("rmse")),
            "free_run_rmse_n": num(free.get("rmse")),
            "validation_free_run_rmse_n": num(val.get("rmse")),
            "free_run_sliding_rmse_n": num(slide.get("rmse")),
            "validation_sliding_rmse_n": num(vslide.get("rmse")),
            "flags": e.get("flags") or [],
        }
    return out


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    out = Path(argv[0])
    laws = {}
    for arg in argv[1:]:
        law, _, d = arg.partition("=")
        laws[law] = law_rows(Path(d))
    L = [
        "# Measured on every law (issue 23)\n",
        ("Written by `scripts/law-table.py` from the runs' JSON. Felt force: the study's hand "
        "(three presses, lockstep, no friction compensation) against the object itself, RMSE "
        "in N; fast: the same presses 2.5x faster; free run: the model's free-run RMSE on the "
        "held-out test recording (2.1 N/s ramps) against the recorded RFOB force, over every "
        "row and over the rows where the probe is pressed and slides (`sliding`: the rows "
        "whose friction a model can know; evaluate.py). The recommendation is the model that "
        "felt closest on the study's ranking runs (two other hand programmes, each with its own "
        "seed; the geometric mean over both; `fidelity.rank`), "
        "never on these; the validation recording's sliding rows rank a model without them. "
        "A model whose name ends in `_holds` was trained, and made its choices, on the "
        "dataset's press-and-hold recordings too (`+holds`, holds.py); the others never saw "
        "them. Where a dataset has them, the validation columns pool both validation "
        "recordings for every model. `blend` is the model the ranking runs put first, blended "
        "with the partner and the weights that felt closest on the same runs (models/blend.py; "
        "its members and weights per law under the goals), built by the study and ranked on "
        "the same runs.\n"),
        ("The laws and their sources: docs/laws.md; an object whose law is an ONNX graph "
         "(`law = \"onnx\"`) and how to write one: [onnx.md](onnx.md).\n"),
        ("| law | model | felt | fast | free run | free run, sliding | validation free run "
         "| validation, sliding | flags |"),
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for law, doc in laws.items():
        for name, m in doc["models"].items():
            tag = f"`{name}`" + (" (recommended)" if name == doc["recommended"] else "")
            L.append(
                f"| {law} | {tag} | {fmt(m['felt_rmse_n'])} | {fmt(m['fast_rmse_n'])} | "
                f"{fmt(m['free_run_rmse_n'])} | {fmt(m['free_run_sliding_rmse_n'])} | "
                f"{fmt(m['validation_free_run_rmse_n'])} | "
                f"{fmt(m['validation_sliding_rmse_n'])} | "
                f"{'; '.join(m['flags']) or '-'} |"
            )
    L.append("\n## Goals, per law\n")
    for law, doc in laws.items():
        ms = doc["models"]
        r = ms.get(doc["recommended"] or "", {})
        o, sd, lf = ms.get("oracle", {}), ms.get("sd_poly2", {}), ms.get("lawfree", {})

        def ratio(a: dict, b: dict, key: str) -> float:
            x, y = num(a.get(key)), num(b.get(key))
            return x / y if math.isfinite(x) and math.isfinite(y) and y > 0 else math.nan

        felt_vs_oracle = ratio(r, o, "felt_rmse_n")
        sd_vs_rec = ratio(sd, r, "felt_rmse_n")
        sd_vs_lf_felt = ratio(sd, lf, "felt_rmse_n")
        sd_vs_lf_free = ratio(sd, lf, "free_run_rmse_n")
        sd_vs_lf_slide = ratio(sd, lf, "free_run_sliding_rmse_n")
        L.append(
            f"- {law}: recommended `{doc['recommended']}` felt {fmt(felt_vs_oracle, 2)}x the "
            f"oracle's (goal <= 2: {'met' if felt_vs_oracle <= 2 else 'not met'}), sd_poly2 "
            f"{fmt(sd_vs_rec, 2)}x the recommended's (goal >= 3: "
            f"{'met' if sd_vs_rec >= 3 else 'not met'}); lawfree: sd_poly2 {fmt(sd_vs_lf_felt, 2)}x"
            f" its felt force and {fmt(sd_vs_lf_free, 2)}x its free run (goal >= 2: "
            f"{'met' if min(sd_vs_lf_felt, sd_vs_lf_free) >= 2 else 'not met'}; on the sliding "
            f"rows {fmt(sd_vs_lf_slide, 2)}x)."
            + (f" `blend`: {weights(doc)[0]:g} x `{doc['blend'][0]}` + {weights(doc)[1]:g} x "
               f"`{doc['blend'][1]}`." if doc.get("blend") else "")
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(L) + "\n")
    out.with_suffix(".json").write_text(json.dumps(laws, indent=1, default=str) + "\n")
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
