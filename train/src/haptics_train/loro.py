"""Leave-one-rate-out evaluation on loading-unloading tests imported from CSV, as a lab with a
materials-testing machine would run it: every rate is held out once, the models train on the
others, every choice is made on validation tests at rates outside all three (one slower, one
faster: so the choice is one for extrapolation in rate), and the held-out rate is scored once,
free run first, beside persistence, the mean and sd_poly2.

With no real multi-rate public data available here (docs/train.md), the input is the SYNTHETIC
elastomer of `viscoelastic` (three rates and two validation rates, 50 Hz, mm/N CSV); it says
so. Everything goes through the product's own commands' code: `import_series` (rt-loop
features), a TOML manifest per fold, `train_models`, `evaluate_models`.

    python -m haptics_train.loro --work data/elastomer --out docs/report/elastomer-loro.md
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
from .importer import describe_import, import_series
from .models import TrainConfig
from .pipeline import evaluate_models, train_models
from .viscoelastic import RATES_MM_S, VALIDATION_RATES_MM_S, Elastomer, write_tests

#: the learned models compared (sd_poly2 is trained too: it is the baseline of record)
SPECS: tuple[str, ...] = ("sd_poly2", "prony", "rf:xva", "dnn:xva", "lstm:xva", "rf:six",
                          "dnn_fb:six", "lstm_fb:six")  # fmt: skip


#: feedback-noise fractions tried on the validation test
CANDIDATES: tuple[float, ...] = (0.05, 0.2)


def _f(v: float | None) -> str:
    if v is None:
        return "-"
    return f"{v:.4f}" if np.isfinite(v) else "diverged"


def run(work: Path, specs: tuple[str, ...], quick: bool = False, seed: int = 0) -> dict:
    """Imports the tests, runs one fold per held-out rate; returns the table's numbers."""
    t0 = time.perf_counter()
    work.mkdir(parents=True, exist_ok=True)
    csvs = write_tests(work / "csv")
    imported = {}
    for c in csvs:
        rec = import_series(c, work / "imported" / f"{c.stem}.parquet", "time", "displacement",
                            "force")  # fmt: skip
        imported[c.stem] = rec
        print(f"[loro] {c.name}: {describe_import(rec)}", flush=True)
    vals = [f"rate_{r:g}" for r in VALIDATION_RATES_MM_S]
    # 300 TBPTT iterations (half the default) keep the 3 folds x 3 LSTM fits within minutes
    # on a shared 2-core machine; the data are a few thousand rows
    hyper: dict[str, dict] = {"lstm": {"iterations": 300}}
    if quick:
        hyper = {"dnn": {"epochs": 3}, "lstm": {"iterations": 60}, "rf": {"n_estimators": 20}}
    folds = {}
    for held in RATES_MM_S:
        name = f"rate_{held:g}"
        fold = work / f"fold_{name}"
        man = fold / "dataset.toml"
        man.unlink(missing_ok=True)
        src = "SYNTHETIC QLV elastomer (haptics_train.viscoelastic), 50 Hz CSV"
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

        def pooled(e: dict, split: str, kind: str = "closed_loop") -> float | None:
            return ((e.get(f"{split}_pooled") or {}).get(kind) or {}).get("rmse")

        folds[name] = {
            "test": {n: pooled(e, "test") for n, e in [*base.items(), *res.items()]},
            "validation": {n: pooled(e, "validation") for n, e in res.items()},
            "one_step_persistence": pooled(base["persistence"], "test", "one_step"),
            "range_n": float(np.ptp(ds.test[0].target())),
        }
    return {"folds": folds, "seconds": round(time.perf_counter() - t0, 1),
            "material": Elastomer().__dict__, "validation": ", ".join(vals)}  # fmt: skip


def table(out: dict, specs: tuple[str, ...]) -> str:
    """The Markdown report of `run`, every sentence computed from its numbers."""
    folds = out["folds"]
    learned = [s.replace(":", "_") for s in specs if s.replace(":", "_") not in BASELINES]
    names = [*BASELINES, *learned]
    md = ["# Leave-one-rate-out on loading-unloading tests (SYNTHETIC data)", ""]
    md.append(
        "**Synthetic stand-in, not a measurement**: no public dataset of loading-unloading "
        "tests of one material at several rates, with a licence that allows a sample, could be "
        "obtained here (the one real curve found, an AFM approach-retract curve, has a single "
        "rate: docs/train.md). The tests are the "
        "`haptics_train.viscoelastic` elastomer (Fung quasi-linear viscoelasticity: a cubic "
        "instantaneous spring with a two-term Prony relaxation function; not the class of the "
        f"`prony` model), parameters `{json.dumps(out['material'])}`, one loading-unloading "
        "cycle per CSV "
        "(`time [s]`, `displacement [mm]`, `force [N]`, 50 Hz), imported with "
        f"`haptics-train import`. Validation (every choice), at rates outside the three: "
        f"`{out['validation']}`. Each column "
        "holds one rate out (test), the models train on the other two."
    )
    md += ["", "Free-run RMSE on the held-out rate, N:", ""]
    rows = []
    for n in names:
        rows.append([f"`{n}`" + (" (baseline)" if n in BASELINES else ""),
                     *[_f(f["test"].get(n)) for f in folds.values()]])  # fmt: skip
    rows.append(["force range of the held-out test", *[f"{f['range_n']:.3f}" for f in
                                                       folds.values()]])  # fmt: skip
    md.append(md_table(["model", *[f"held out: {k}" for k in folds]], rows))
    md += [""]
    for k, f in folds.items():
        val = {n: v for n, v in f["validation"].items() if n in learned and v is not None}
        if not val:
            continue
        best = min(val, key=lambda n: val[n] if np.isfinite(val[n]) else np.inf)
        t, sd = f["test"].get(best), f["test"].get("sd_poly2")
        ratio = sd / t if t and sd and np.isfinite(t) else float("nan")
        md.append(
            f"- held out {k}: recommended on validation `{best}` ({_f(val[best])} N there); on "
            f"the held-out rate {_f(t)} N vs sd_poly2 {_f(sd)} N: {ratio:.2f}x"
            f" ({'meets' if ratio >= 2 else 'misses'} the 2x goal); persistence one-step "
            f"{_f(f['one_step_persistence'])} N."
        )
    md += ["", f"Run time: {out['seconds']:.0f} s. Reproduce: `.venv/bin/python -m "
           "haptics_train.loro --work data/elastomer --out docs/report/elastomer-loro.md`.",
           ""]  # fmt: skip
    return "\n".join(md)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--work", default="data/elastomer")
    p.add_argument("--out", default="docs/report/elastomer-loro.md")
    p.add_argument("--models", default=",".join(SPECS))
    p.add_argument("--quick", action="store_true", help="small models (a smoke run)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--from-json", help="re-render the table from a previous run's .json")
    a = p.parse_args()
    import torch

    torch.set_num_threads(1)
    specs = tuple(s.strip() for s in a.models.split(",") if s.strip())
    if a.from_json:
        res = json.loads(Path(a.from_json).read_text())
    else:
        res = run(Path(a.work), specs, a.quick, a.seed)
    text = table(res, specs)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(text)
    Path(a.out).with_suffix(".json").write_text(json.dumps(res, indent=1, default=float))
    print(text)


if __name__ == "__main__":
    main()
