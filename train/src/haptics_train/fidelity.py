"""The recommended model and docs/fidelity.json, in one place so the pipeline, the
out-of-distribution scoring and the study agree on the rule and the keys (issue 11).

The rule: models are ranked by their free-run (closed-loop) RMSE pooled over the validation
recordings, never by one-step, on the rows where the probe is pressed and slides (`sliding`,
evaluate.py says why: the all-row score's floor is the bench's stick friction, 0.4 N, which
ranked by noise; where a results file has no sliding score, all rows). Where the study has
measured a model's felt force (on runs of their own, not the headline's), that felt force
decides, as a multiple of the best measured model's; a model without one is scored by its
validation multiple, and a model whose validation free run diverged ranks last whatever it felt.
The test recordings play no part.

Why the felt force alone where it is measured (2026-11-30; docs/laws.md, "The felt force
decides where it is measured"): until then the score was the larger of the two multiples, so
that a model held both offline and in the loop. On every object where the two rules disagreed,
the larger-of-two rule served the model that felt further from the object, on the headline as
on the ranking runs: the gel, a Mullins-softening and a stiff Hunt-Crossley object, then, tested
once with the rule written down beforehand, two of five fresh objects (a second gel 0.488 N
where the felt rule's pick felt 0.128 N; a second Hunt-Crossley 0.167 against 0.105 N), and
never the other way. The validation free run is scored against the RFOB, which holds the
bench's stick and the observer's lag; the felt force against the object itself, which is what a
user gets. Off the simulator (a real rig, imported data) there is no felt force and the rule is
the validation free run, as before.

Why multiples and not newtons: the two errors have different floors. The free run is scored
against the recorded RFOB estimate, which holds the bench's friction, its noise and a 3 % gain
no model of the object can follow (about 0.4 N on the simulated objects); the felt force against
the object itself, whose floor (the oracle) is 0.005-0.03 N. A model without a felt force is
compared with the others by the multiple of its own score.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

#: docs/fidelity.json's keys (issue 11's "Show"), numbers in N, `ood_diverged` a count.
FIDELITY_KEYS = (
    "recommended",
    "free_run_rmse_n",
    "ood_free_run_rmse_n",
    "ood_diverged",
    "felt_rmse_n",
    "felt_fast_rmse_n",
    "oracle_felt_rmse_n",
    "sd_poly2_felt_rmse_n",
)
RECOMMENDATION_FILE = "recommendation.json"


def _finite(v: object) -> float | None:
    return float(v) if isinstance(v, int | float) and math.isfinite(v) else None


def pooled_rmse(entry: dict, split: str, kind: str = "closed_loop") -> float | None:
    """A results.json entry's pooled free-run RMSE on `split` (None: not scored); `kind`
    "rendered_vs_true": the rendered force against the simulated object's own."""
    pool = entry.get(f"{split}_pooled") or {}
    v = (pool.get(kind) or {}).get("rmse")
    return float(v) if isinstance(v, int | float) else None


def validation_score(entry: dict) -> float | None:
    """The free-run RMSE a model is ranked by: on the validation recordings' sliding rows,
    else (a results file written before that score existed) over all rows."""
    v = pooled_rmse(entry, "validation", "sliding")
    return v if v is not None and math.isfinite(v) else pooled_rmse(entry, "validation")


def rank(results: dict, felt: dict[str, float] | None = None) -> list[dict]:
    """Models with a validation free-run RMSE (`validation_score`), best first: each scored by
    its measured felt-force RMSE (`felt`, name -> N) as a multiple of the best measured one
    (`felt_multiple`), or where it has none by its validation RMSE as a multiple of the best
    model's (`validation_multiple`, reported for every model); a non-finite validation score
    (a diverged free run) ranks last, felt or not."""
    felt = felt or {}
    rows = []
    for name, entry in results.items():
        if not isinstance(entry, dict):
            continue
        v = validation_score(entry)
        if v is None:
            continue
        rows.append((name, v, _finite(felt.get(name))))
    v_best = min((v for _, v, _ in rows if math.isfinite(v) and v > 0), default=math.nan)
    # the best felt force among the models that hold offline (a diverged one sets no scale)
    f_best = min((f for _, v, f in rows if f is not None and f > 0 and math.isfinite(v)),
                 default=math.nan)  # fmt: skip
    out = []
    for name, v, f in rows:
        v_mult = v / v_best if math.isfinite(v) and math.isfinite(v_best) else math.inf
        f_mult = f / f_best if f is not None and math.isfinite(f_best) else None
        score = v_mult if f_mult is None or not math.isfinite(v_mult) else f_mult
        out.append({"model": name, "validation_free_run_rmse_n": pooled_rmse(results[name],
                    "validation"), "validation_sliding_rmse_n": pooled_rmse(results[name],
                    "validation", "sliding"), "felt_rmse_n": f,
                    # both multiples (the study's report quotes them, so it cannot drift
                    # from the rule); the score is the felt one where there is one
                    "validation_multiple": v_mult, "felt_multiple": f_mult,
                    "score": score})  # fmt: skip
    return sorted(out, key=lambda r: r["score"])


def recommendation(results: dict, validation: list[str], felt: dict[str, float] | None = None
                   ) -> dict | None:  # fmt: skip
    """The recommendation document (models/recommendation.json), None without any ranked
    model or validation recording."""
    ranking = rank(results, felt)
    if not ranking or not validation:
        return None
    best = ranking[0]["model"]
    return {
        "recommended": best,
        "metric": "free-run RMSE pooled over the validation recordings' rows where the probe "
        "is pressed and slides (all rows where not scored); where the study measured a felt "
        "force, that felt force (the geometric mean over its ranking programmes); each as a "
        "multiple of the best model's",
        "validation": validation,
        "free_run_rmse_n": pooled_rmse(results[best], "test"),
        # the rendered force against the simulated object's own (None off the simulator)
        "free_run_true_rmse_n": pooled_rmse(results[best], "test", "rendered_vs_true"),
        "ranking": ranking,
    }


def read_object(path: Path) -> dict:
    """The JSON object at `path`; {} when it is missing, unreadable or not an object."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return {}
    return doc if isinstance(doc, dict) else {}


def load_recommendation(models_dir: Path) -> dict | None:
    doc = read_object(models_dir / RECOMMENDATION_FILE)
    return doc if isinstance(doc.get("recommended"), str) else None


def merge(path: Path, keys: dict) -> dict:
    """Merges `keys` into the JSON object at `path` (created when missing); returns it."""
    doc = read_object(path)
    doc.update({k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in keys.items()})  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1) + "\n")
    return doc
