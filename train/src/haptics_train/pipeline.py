"""Train -> export (with parity) -> evaluate, persisting models and results under a folder.

Layout of the models folder:
  <name>.joblib   the trained framework model (ForceModel object)
  <name>.onnx     the exported model (docs/model-contract.md)
  results.json    per model: hyperparameters, training info, parity, one-step and
                  closed-loop metrics on every test recording
  predictions/<name>.npz  test-set predictions (for the report's plots)
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import joblib
import numpy as np
import onnx

from .contract import ContractError
from .data import Dataset
from .evaluate import evaluate
from .export import parity, provenance, save_onnx, to_contract_onnx
from .models import ForceModel, TrainConfig, parse_spec

#: The pipeline's default comparison: Table 6.2 baselines, Table 6.15 algorithms on the six
#: features, Table 6.10 ablation, and the better-conditioned/memory alternatives.
DEFAULT_SPECS: tuple[str, ...] = (
    # Table 6.2 baselines
    "sd_const",
    "sd_poly1",
    "sd_poly2",
    # Table 6.15: the algorithms on the six features
    "lr:six",
    "svr:six",
    "rf:six",
    "dnn:six",
    "lstm:six",
    # Table 6.10 ablation (+ kinematics only, memory features, the previous force itself)
    "rf:x",
    "rf:x_v",
    "rf:xva",
    "rf:memory",
    "rf:xva_f",
    # networks: kinematics only, and trained with feedback noise for the closed loop
    "dnn:xva",
    "dnn_fb:six",
    "lstm_fb:six",
)


def train_models(
    dataset: Dataset,
    specs: list[str],
    cfg: TrainConfig,
    out: Path,
    preset: str = "default",
    hyper: dict[str, dict] | None = None,
) -> list[ForceModel]:
    out.mkdir(parents=True, exist_ok=True)
    models = []
    for spec in specs:
        m = parse_spec(spec, preset)
        algo = spec.partition(":")[0].strip()
        for key in (algo.removesuffix("_fb"), algo) if algo.endswith("_fb") else (algo,):
            if hyper and key in hyper:
                m.hyper.update(hyper[key])
                if hasattr(m, "max_rows") and "max_rows" in hyper[key]:
                    m.max_rows = hyper[key]["max_rows"]  # type: ignore[attr-defined]
        t0 = time.perf_counter()
        print(f"[train] {m.name} on {len(dataset.train)} recordings ...", flush=True)
        try:
            m.fit(dataset.train, cfg)
        except (ValueError, RuntimeError, FloatingPointError) as e:
            # one model failing (e.g. a diverging network) must not lose the others
            print(f"[train] {m.name} FAILED: {e}", flush=True)
            continue
        m.train_info.setdefault("fit_seconds", round(time.perf_counter() - t0, 2))
        joblib.dump({"model": m, "config": cfg}, out / f"{m.name}.joblib")
        print(f"[train] {m.name}: {m.train_info}", flush=True)
        models.append(m)
    return models


def load_models(
    folder: Path, names: list[str] | None = None
) -> list[tuple[ForceModel, TrainConfig]]:
    paths = sorted(folder.glob("*.joblib"))
    if names:
        paths = [folder / f"{n}.joblib" for n in names]
    if not paths:
        raise FileNotFoundError(f"no trained models (*.joblib) in {folder}")
    out = []
    for p in paths:
        blob = joblib.load(p)
        out.append((blob["model"], blob["config"]))
    return out


def _results_path(folder: Path) -> Path:
    return folder / "results.json"


def load_results(folder: Path) -> dict:
    p = _results_path(folder)
    return json.loads(p.read_text()) if p.exists() else {}


def _save_results(folder: Path, results: dict) -> None:
    _results_path(folder).write_text(json.dumps(results, indent=1, default=float))


def evaluate_models(
    models: list[tuple[ForceModel, TrainConfig]],
    dataset: Dataset,
    folder: Path,
    closed_loop: bool = True,
) -> dict:
    """One-step and closed-loop metrics on every test recording -> results.json (merged with
    earlier results) and predictions/<name>.npz. Closed loop steps an in-memory export."""
    results = load_results(folder)
    (folder / "predictions").mkdir(parents=True, exist_ok=True)
    for model, cfg in models:
        print(f"[evaluate] {model.name}", flush=True)
        try:
            draft = to_contract_onnx(model, provenance(model, cfg, dataset, None))
        except ContractError as e:
            print(f"[evaluate] {model.name} FAILED: its export breaks the contract: {e}")
            results[model.name] = {"algo": model.algo, "feature_set": model.feature_set,
                                   "error": f"export breaks the contract: {e}"}  # fmt: skip
            _save_results(folder, results)
            continue
        evals = []
        preds = {}
        for rec in dataset.test:
            r, p = evaluate(model, draft, rec, cfg, closed_loop=closed_loop)
            evals.append(r)
            for k, v in p.items():
                preds[f"{rec.name}:{k}"] = v.astype(np.float32)
        np.savez_compressed(folder / "predictions" / f"{model.name}.npz", **preds)
        entry = results.get(model.name, {})
        entry.pop("error", None)
        entry.update({
            "algo": model.algo,
            "feature_set": model.feature_set,
            "features": list(model.features),
            "kind": model.kind,
            "hyperparameters": model.hyper,
            "training": {**cfg.to_dict(), **model.train_info},
            "test": evals,
        })  # fmt: skip
        results[model.name] = entry
        e0 = evals[0]
        print(
            f"[evaluate] {model.name}: one-step RMSE {e0['one_step']['rmse']:.3f} N, "
            f"closed-loop RMSE {e0.get('closed_loop', {}).get('rmse', float('nan')):.3f} N",
            flush=True,
        )
        _save_results(folder, results)
    return results


def export_models(
    models: list[tuple[ForceModel, TrainConfig]], dataset: Dataset | None, folder: Path
) -> dict:
    """<name>.onnx with the contract metadata (metrics from results.json when evaluated) and the
    ONNX-vs-framework parity on the first test recording."""
    results = load_results(folder)
    for model, cfg in models:
        entry = results.setdefault(model.name, {})
        if "error" in entry:
            print(f"[export] {model.name} skipped: {entry['error']}", flush=True)
            continue
        metrics = {
            e["recording"]: {"one_step": e["one_step"], "closed_loop": e.get("closed_loop")}
            for e in entry.get("test", [])
        }
        m = to_contract_onnx(model, provenance(model, cfg, dataset, metrics))
        path = save_onnx(m, folder / f"{model.name}.onnx")
        entry["onnx"] = str(path)
        entry["onnx_bytes"] = path.stat().st_size
        if dataset is not None:
            entry["parity"] = parity(model, onnx.load(str(path)), dataset.test[0])
            print(
                f"[export] {path}: parity max |onnx - framework| "
                f"{entry['parity']['max_abs_diff']:.2e} over {entry['parity']['rows']} rows",
                flush=True,
            )
        else:
            print(f"[export] {path}", flush=True)
        _save_results(folder, results)
    return results
