"""Leave-one-rate-out evaluation on loading-unloading tests imported from CSV, as a lab with a
materials-testing machine would run it: every rate is held out once, the models train on the
others, every choice is made on validation tests at rates outside all three (one slower, one
faster: so the choice is one for extrapolation in rate), and the held-out rate is scored once,
free run first, beside persistence, the mean and sd_poly2.

With no real multi-rate public data available here (docs/train.md), the input is SYNTHETIC
(three rates and two validation rates, 50 Hz, mm/N CSV), from one of the generators of
`loro_laws` (`--generator`): the QLV elastomer of `viscoelastic` (`qlv`, the default), or the
bench's own laws driven by `rt-loop object-force` (`bouc-wen`, `gel`, `hunt-crossley`: laws no
model here shares); it says so. Everything goes through the product's own commands' code:
`import_series` (rt-loop features), a TOML manifest per fold, `train_models`,
`evaluate_models`. Each report holds the computed class notes (which model shares a class with
which law) and the issue's goals per fold: the recommended model (chosen on validation) at
least 3x better than sd_poly2 on the held-out rate, the law-free learner at least 2x.

    python -m haptics_train.loro --generator gel     # docs/report/gel-loro.md (+ .json)
    python -m haptics_train.loro                     # qlv: docs/report/elastomer-loro.md
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from .analysis import md_table
from .data import load_manifest, write_manifest_entry
from .evaluate import BASELINES
from .fidelity import pooled_rmse
from .importer import describe_import, import_series
from .loro_laws import GENERATORS, LAWS, class_notes
from .models import TrainConfig
from .pipeline import evaluate_models, train_models
from .viscoelastic import RATES_MM_S, VALIDATION_RATES_MM_S

#: the learned models compared (sd_poly2 is trained too: it is the baseline of record)
SPECS: tuple[str, ...] = ("sd_poly2", "prony", "rf:xva", "dnn:xva", "lstm:xva", "rf:six",
                          "dnn_fb:six", "lstm_fb:six", "structured", "lawfree")  # fmt: skip

#: the issue's goals on the held-out rate: recommended and law-free learner vs sd_poly2
GOAL_RECOMMENDED = 3.0
GOAL_LAWFREE = 2.0


#: feedback-noise fractions tried on the validation test
CANDIDATES: tuple[float, ...] = (0.05, 0.2)


def _f(v: float | None) -> str:
    if v is None:
        return "-"
    return f"{v:.4f}" if np.isfinite(v) else "diverged"


def run(work: Path, specs: tuple[str, ...], quick: bool = False, seed: int = 0,
        generator: str = "qlv") -> dict:  # fmt: skip
    """Writes the generator's tests, imports them, runs one fold per held-out rate; returns the
    table's numbers."""
    t0 = time.perf_counter()
    gen = GENERATORS[generator]
    work.mkdir(parents=True, exist_ok=True)
    csvs = gen.write_tests(work / "csv")
    imported = {}
    for c in csvs:
        # the work folder is this run's own: the CSVs were just written again, so their imports
        # are replaced too (a second run on the default folder refused to start before)
        rec = import_series(c, work / "imported" / f"{c.stem}.parquet", "time", "displacement",
                            "force", overwrite=True)  # fmt: skip
        imported[c.stem] = rec
        print(f"[loro] {c.name}: {describe_import(rec)}", flush=True)
    vals = [f"rate_{r:g}" for r in VALIDATION_RATES_MM_S]
    # 300 TBPTT iterations (half the default) keep the 3 folds x 3 LSTM fits within minutes
    # on a shared 2-core machine; the data are a few thousand rows
    hyper: dict[str, dict] = {"lstm": {"iterations": 300}}
    if quick:
        hyper = {"dnn": {"epochs": 3}, "lstm": {"iterations": 60}, "rf": {"n_estimators": 20},
                 "lawfree": {"network_steps": 100}}
    folds = {}
    for held in RATES_MM_S:
        name = f"rate_{held:g}"
        fold = work / f"fold_{name}"
        man = fold / "dataset.toml"
        man.unlink(missing_ok=True)
        src = f"SYNTHETIC {LAWS[gen.law].title} ({LAWS[gen.law].source}), 50 Hz CSV"
        for r in RATES_MM_S:
            n = f"rate_{r:g}"
            write_manifest_entry(man, n, work / "imported" / f"{n}.parquet",
                                 "test" if r == held else "train", src, f"{r:g} mm/s")  # fmt: skip
        for r, v in zip(VALIDATION_RATES_MM_S, vals, strict=True):
            write_manifest_entry(man, v, work / "imported" / f"{v}.parquet", "validation", src,
                                 f"{r:g} mm/s")  # fmt: skip
        ds = load_manifest(man)
        cfg = TrainConfig(seed=seed, progress=False)
        models = train_models(ds, list(specs), cfg, fold / "models", hyper=hyper,
                              feedback_noise_candidates=list(CANDIDATES))  # fmt: skip
        (fold / "models" / "results.json").unlink(missing_ok=True)
        res = evaluate_models([(m, cfg) for m in models], ds, fold / "models")
        base = json.loads((fold / "models" / "baselines.json").read_text())

        folds[name] = {
            "test": {n: pooled_rmse(e, "test") for n, e in [*base.items(), *res.items()]},
            "validation": {n: pooled_rmse(e, "validation") for n, e in res.items()},
            # the product's ranking score (fidelity.validation_score: where the probe slides)
            "validation_sliding": {n: pooled_rmse(e, "validation", "sliding")
                                   for n, e in res.items()},  # fmt: skip
            "one_step_persistence": pooled_rmse(base["persistence"], "test", "one_step"),
            "range_n": float(np.ptp(ds.test[0].target())),
            "lawfree_network": network_note(models),
        }
    return {"generator": generator, "law": gen.law, "folds": folds, "quick": quick,
            "hyper": hyper, "seconds": round(time.perf_counter() - t0, 1),
            "material": gen.params(), "validation": ", ".join(vals)}  # fmt: skip


def network_note(models: list) -> dict | None:
    """What `lawfree`'s network readout did in a fold (`lawfree_selection.try_network_readout`): its
    validation scores against the linear readout's, whether it was kept, the network chosen;
    None where `lawfree` was not trained or the network not tried."""
    lf = next((m for m in models if m.name == "lawfree"), None)
    sel = (lf.train_info_.get("selection") or {}) if lf is not None else {}
    net = sel.get("network_readout")
    if net is None:
        return None
    if "skipped" in net:
        return {"skipped": net["skipped"]}
    return {"kept": net["kept"], "validation": net["validation"],
            "validation_every_row": net["validation_every_row"], "chosen": net["chosen"],
            "against": sel["candidates"][sel["chosen"]],
            "against_every_row": sel["candidates_every_row"][sel["chosen"]]}  # fmt: skip


def network_lines(folds: dict) -> list[str]:
    """The report's lines on `lawfree`'s network readout, one per fold where it was tried."""
    tried = {k: f["lawfree_network"] for k, f in folds.items() if f.get("lawfree_network")}
    if not tried:
        return []
    md = ["", "`lawfree`'s network readout (tried on its validated choice, kept where it is at "
          "most 0.9x the linear readout's on both validation scores; models/lawfree_net.py):", ""]
    for k, n in tried.items():
        if "skipped" in n:
            md.append(f"- held out {k}: not tried: {n['skipped']}.")
            continue
        c = n["chosen"]
        md.append(f"- held out {k}: {'kept' if n['kept'] else 'not kept'}: validation "
                  f"{_f(n['validation'])} N against {_f(n['against'])} N "
                  f"({n['validation'] / n['against']:.2f}x; every row "
                  f"{n['validation_every_row'] / n['against_every_row']:.2f}x); the network: "
                  f"{c['mode']}, {c['hidden']} wide, decay {c['weight_decay']:g}, epoch "
                  f"{c['epoch']}.")  # fmt: skip
    return md


def _ratio(sd: float | None, t: float | None) -> float:
    """sd_poly2's error over the model's (NaN when either is missing or diverged)."""
    if t is None or sd is None or not (np.isfinite(t) and np.isfinite(sd)) or t <= 0:
        return float("nan")
    return sd / t


def goals(out: dict, specs: tuple[str, ...]) -> dict[str, dict]:
    """Per fold: the model recommended on validation (learned models only, the lowest pooled
    free-run RMSE over the validation rates, on the rows where the probe slides as the product
    ranks them, over all rows for a report written before that score) and the law-free
    learner, each on the held-out rate against sd_poly2, and whether the issue's goals are
    met."""
    learned = [s.replace(":", "_") for s in specs if s.replace(":", "_") not in BASELINES]
    res = {}
    for k, f in out["folds"].items():
        scores = f.get("validation_sliding") or {}
        if not scores or any(v is None for v in scores.values()):
            scores = f["validation"]
        val = {n: v for n, v in scores.items() if n in learned and v is not None}
        sd = f["test"].get("sd_poly2")
        g: dict = {"sd_poly2": sd}
        if val:
            best = min(val, key=lambda n: val[n] if np.isfinite(val[n]) else np.inf)
            r = _ratio(sd, f["test"].get(best))
            g["recommended"] = {"model": best, "validation": val[best],
                                "test": f["test"].get(best), "ratio": r,
                                "met": bool(r >= GOAL_RECOMMENDED)}  # fmt: skip
        if "lawfree" in f["test"]:
            r = _ratio(sd, f["test"]["lawfree"])
            g["lawfree"] = {"test": f["test"]["lawfree"], "ratio": r,
                            "met": bool(r >= GOAL_LAWFREE)}  # fmt: skip
        res[k] = g
    return res


def _met(g: dict, goal: float) -> str:
    r = g["ratio"]
    if not np.isfinite(r):
        return f"**misses** the {goal:g}x goal: no finite ratio"
    if g["met"]:
        return f"meets the {goal:g}x goal"
    return f"**misses** the {goal:g}x goal by a factor {goal / r:.2f}"


def _intro(out: dict) -> str:
    law = LAWS[out.get("law", "qlv")]
    common = (
        f"one loading-unloading cycle per CSV (`time [s]`, `displacement [mm]`, `force [N]`, "
        f"50 Hz), imported with `haptics-train import`. Validation (every choice), at rates "
        f"outside the three: `{out['validation']}`. Each column holds one rate out (test), the "
        "models train on the other two."
    )
    if out.get("generator", "qlv") == "qlv":
        return (
            "**Synthetic stand-in, not a measurement**: no public dataset of loading-unloading "
            "tests of one material at several rates, with a licence that allows a sample, could "
            "be obtained here (the one real curve found, an AFM approach-retract curve, has a "
            "single rate: docs/train.md). The tests are the `haptics_train.viscoelastic` "
            "elastomer (Fung quasi-linear viscoelasticity: a cubic instantaneous spring with a "
            "two-term Prony relaxation function; near the classes of `prony` and `structured`, "
            f"see the class notes), parameters `{json.dumps(out['material'])}`, " + common
        )
    return (
        "**Synthetic, not a measurement**: the tests are the bench's own object of law "
        f"*{law.title}*, {law.source}, driven along the loading-unloading motion by "
        "`rt-loop object-force` (the study's oracle path: a fresh object stepped at 10 kHz with "
        "the bench's sub-steps, corners of the motion exact) with Gaussian force noise added "
        f"(`{json.dumps(out['material'])}`), the same rates as the QLV elastomer "
        "(docs/report/elastomer-loro.md), " + common
    )


def table(out: dict, specs: tuple[str, ...]) -> str:
    """The Markdown report of `run`, every sentence computed from its numbers."""
    folds = out["folds"]
    learned = [s.replace(":", "_") for s in specs if s.replace(":", "_") not in BASELINES]
    names = [*BASELINES, *learned]
    gen = out.get("generator", "qlv")
    law = out.get("law", "qlv")
    md = [f"# Leave-one-rate-out on loading-unloading tests: {gen} (SYNTHETIC data)", "",
          _intro(out)]  # fmt: skip
    if out.get("quick"):
        md += ["", f"**Quick run** (smoke-sized models: `{json.dumps(out.get('hyper'))}`); "
               "not the figures of record."]  # fmt: skip
    md += ["", "Free-run RMSE on the held-out rate, N:", ""]
    rows = []
    for n in names:
        rows.append([f"`{n}`" + (" (baseline)" if n in BASELINES else ""),
                     *[_f(f["test"].get(n)) for f in folds.values()]])  # fmt: skip
    rows.append(["force range of the held-out test", *[f"{f['range_n']:.3f}" for f in
                                                       folds.values()]])  # fmt: skip
    md.append(md_table(["model", *[f"held out: {k}" for k in folds]], rows))
    notes = class_notes(["sd_poly2", *learned], law)
    md += ["", f"Class notes (computed from `loro_laws.MODEL_CLASSES`): which model shares a "
           f"class with which law; this report's law is **{law}** ({LAWS[law].title}).", ""]
    crow = [[f"`{m}`", r["class"], *[r[k] for k in LAWS]] for m, r in notes["rows"].items()]
    md.append(md_table(["model", "its class", *[(f"**{k}**" if k == law else k) for k in LAWS]],
                       crow))  # fmt: skip
    md.append("")
    if notes["no_class_shared"]:
        md.append(f"- **No model shares this law's class** ({law}): no model here contains it "
                  "or is one element away; every figure above is out of class.")
    else:
        md.append(f"- Models sharing this law's class: "
                  f"{', '.join(f'`{m}`' for m in notes['shares']) or 'none'}; one element "
                  f"away: {', '.join(f'`{m}`' for m in notes['near']) or 'none'}.")
    md += ["", "Goals per fold (the recommendation is chosen on validation only; the held-out "
           "rate is scored once):", ""]
    g = goals(out, specs)
    for k, f in folds.items():
        gk = g[k]
        line = f"- held out {k}:"
        if "recommended" in gk:
            r = gk["recommended"]
            line += (f" recommended on validation `{r['model']}` ({_f(r['validation'])} N "
                     f"there); on the held-out rate {_f(r['test'])} N vs sd_poly2 "
                     f"{_f(gk['sd_poly2'])} N: {r['ratio']:.2f}x ("
                     f"{_met(r, GOAL_RECOMMENDED)}).")  # fmt: skip
        if "lawfree" in gk:
            lf = gk["lawfree"]
            line += (f" Law-free learner `lawfree` {_f(lf['test'])} N: {lf['ratio']:.2f}x "
                     f"({_met(lf, GOAL_LAWFREE)}).")  # fmt: skip
        line += f" Persistence one-step {_f(f['one_step_persistence'])} N."
        md.append(line)
    for key, goal, what in (("recommended", GOAL_RECOMMENDED, "recommended model"),
                            ("lawfree", GOAL_LAWFREE, "law-free learner")):  # fmt: skip
        have = [gk[key] for gk in g.values() if key in gk]
        if have:
            met = sum(h["met"] for h in have)
            md.append(f"- The {what} meets the {goal:g}x goal in {met} of {len(have)} folds.")
    md += network_lines(folds)
    flag = " --quick" if out.get("quick") else ""
    md += ["", f"Run time: {out['seconds']:.0f} s. Reproduce: `.venv/bin/python -m "
           f"haptics_train.loro --generator {gen}{flag}`.", ""]  # fmt: skip
    return "\n".join(md)


def summary(reports: dict[str, dict]) -> str:
    """One table over the generators' reports (their .json, with `goals` and `class_notes`):
    per held-out rate, the recommended model and the law-free learner against sd_poly2."""
    rows = []
    for gen, out in reports.items():
        notes = out["class_notes"]
        shared = ", ".join(f"`{m}`" for m in notes["shares"] + notes["near"]) or "**none**"
        for k, g in out["goals"].items():
            r, lf = g.get("recommended"), g.get("lawfree")
            rows.append([gen, shared, k, _f(g["sd_poly2"]),
                         f"`{r['model']}` {_f(r['test'])}" if r else "-",
                         f"{r['ratio']:.2f}x {'met' if r['met'] else 'missed'}" if r else "-",
                         _f(lf["test"]) if lf else "-",
                         f"{lf['ratio']:.2f}x {'met' if lf['met'] else 'missed'}" if lf else "-",
                         ])  # fmt: skip
    md = [md_table(["generator", "models sharing or near its class", "held out", "sd_poly2",
                    "recommended (on validation)", "vs sd_poly2 (goal 3x)", "lawfree",
                    "vs sd_poly2 (goal 2x)"], rows), ""]  # fmt: skip
    unshared = [o for o in reports.values() if o["class_notes"]["no_class_shared"]]
    for scope, outs in (("every law", list(reports.values())),
                        ("the laws no model shares", unshared)):  # fmt: skip
        gs = [g for o in outs for g in o["goals"].values()]
        for key, goal, what in (("recommended", GOAL_RECOMMENDED, "recommended model"),
                                ("lawfree", GOAL_LAWFREE, "law-free learner")):  # fmt: skip
            have = [g[key]["met"] for g in gs if key in g]
            md.append(f"- On {scope}: the {what} meets the {goal:g}x goal in {sum(have)} of "
                      f"{len(have)} folds.")
    return "\n".join(md)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--generator", default="qlv", choices=sorted(GENERATORS),
                   help="the law the tests are generated from (default qlv)")  # fmt: skip
    p.add_argument("--work", help="working folder (default data/loro-GENERATOR; qlv: "
                   "data/elastomer)")  # fmt: skip
    p.add_argument("--out", help="the report (default docs/report/<generator>-loro.md; qlv: "
                   "docs/report/elastomer-loro.md); its .json beside it")  # fmt: skip
    p.add_argument("--models", default=",".join(SPECS))
    p.add_argument("--quick", action="store_true", help="small models (a smoke run)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--from-json", help="re-render the table from a previous run's .json")
    p.add_argument("--summary", action="store_true",
                   help="one table over every generator's report (docs/report/)")  # fmt: skip
    a = p.parse_args()
    if a.summary:
        reports = {g: json.loads(Path(f"docs/report/{v.report}.json").read_text())
                   for g, v in GENERATORS.items()}  # fmt: skip
        print(summary(reports))
        return
    import torch

    torch.set_num_threads(1)
    specs = tuple(s.strip() for s in a.models.split(",") if s.strip())
    gen = GENERATORS[a.generator]
    default_work = "data/elastomer" if a.generator == "qlv" else f"data/loro-{a.generator}"
    work = Path(a.work or default_work)
    out = Path(a.out or f"docs/report/{gen.report}.md")
    if a.from_json:
        res = json.loads(Path(a.from_json).read_text())
    else:
        res = run(work, specs, a.quick, a.seed, a.generator)
    learned = [s.replace(":", "_") for s in specs if s.replace(":", "_") not in BASELINES]
    res["class_notes"] = class_notes(["sd_poly2", *learned], res.get("law", "qlv"))
    res["goals"] = goals(res, specs)
    text = table(res, specs)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    out.with_suffix(".json").write_text(json.dumps(res, indent=1, default=float))
    print(text)


if __name__ == "__main__":
    main()
