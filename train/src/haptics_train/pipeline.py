"""Train -> export (with parity) -> evaluate, persisting models and results under a folder.

Layout of the models folder:
  <name>.joblib   the trained framework model (ForceModel object)
  <name>.onnx     the exported model (docs/model-contract.md)
  results.json    per model: hyperparameters, training info, parity, free-run and one-step
                  metrics on every validation and test recording, and pooled
  baselines.json  the same for persistence, mean and sd_poly2
  recommendation.json  the model with the lowest validation free-run RMSE (when there is a
                  validation recording), and the ranking
  predictions/<name>.npz  test-set predictions (for the report's plots)
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import joblib
import numpy as np
import onnx

from .blocked_validation import BLOCKED_VALIDATION, blocked_scores
from .contract import ContractError
from .cost import COST_KEY, measure_cost
from .dagger import fit_dagger
from .data import Dataset
from .evaluate import BASELINES, evaluate, pooled_metrics, score_baselines
from .export import parity, provenance, save_onnx, to_contract_onnx
from .fidelity import (
    RECOMMENDATION_FILE,
    load_recommendation,
    merge,
    pooled_rmse,
    recommendation,
    validation_score,
)
from .holds import spec_algo, spec_dataset
from .lawfree_selection import (
    BOTH_SCORES_RULE,
    DAMAGE_RULE,
    NETWORK_RULE,
    choose_on_both,
    keep_at_margin,
    lawfree_candidates,
    lawfree_damage_candidate,
    network_skipped,
    try_network_readout,
)
from .metrics import fmt_figure
from .models import ForceModel, TrainConfig, fit_recordings, parse_spec
from .models.blend import BLEND_NAME, WEIGHTS, BlendModel, blendable
from .models.lawfree_net import NET_MAX_STEPS
from .models.structured import INDENTATION, StructuredModel
from .reference import add_reference

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
    # structured stateful: nonlinear spring + Prony series, kinematics only, dissipative
    "prony",
    # structured stateful: equilibrium, Maxwell branches, hysteresis, permanent set; the
    # bench's friction fitted beside it and not rendered
    "structured",
    # (not `structured_path` nor `structured_hyst`: validation, which ranks this comparison,
    # prefers them where a hand feels them further; scripts/fidelity-study.sh trains them, and
    # the study's felt force chooses)
    # assumes no law: fading memory in time + play operators on the path, an MLP on them
    # (issue 23); the bench's friction fitted beside it and not rendered
    "lawfree",
)


def _configured(spec: str, preset: str, hyper: dict[str, dict] | None, extra: dict) -> ForceModel:
    """The unfitted model of `spec`, the user's hyper-parameters and `extra` on top."""
    m = parse_spec(spec, preset)
    algo = spec_algo(spec)
    for key in (algo.removesuffix("_fb"), algo) if algo.endswith("_fb") else (algo,):
        if hyper and key in hyper:
            m.hyper.update(hyper[key])
    m.hyper.update(extra)
    return m


def _fit_one(
    spec: str, preset: str, hyper: dict[str, dict] | None, extra: dict, dataset: Dataset,
    cfg: TrainConfig,
) -> ForceModel:
    m = _configured(spec, preset, hyper, extra)
    t0 = time.perf_counter()
    fit_recordings(m, dataset.train, cfg)
    m.train_info_.setdefault("fit_seconds", round(time.perf_counter() - t0, 2))
    return m


#: What the validation choices (a family's candidates below, DAgger's round) are scored by.
SELECTION_METRIC = (
    "free-run RMSE on the rows where the probe is pressed and slides (evaluate.sliding_metrics; "
    "all rows where a validation recording has none), pooled over the validation recordings"
)


def validation_free_run_rmse(model: ForceModel, cfg: TrainConfig, dataset: Dataset) -> float:
    """The model's free-run (closed-loop) RMSE pooled over the validation recordings, on the
    rows where the probe is pressed and slides (the `sliding` score the recommendation ranks
    by, `fidelity.validation_score`), or over all rows where there are none. Why the same rows
    as the ranking: over all rows the stick friction no model can know sets a floor every good
    candidate shares, and a choice made there follows noise (docs/laws.md, "Ranked on the rows
    where the probe slides"): `lawfree`'s ridge chosen on all rows took the smallest on each
    of the three objects checked, the one that felt worst on Bouc-Wen and Hunt-Crossley."""
    return validation_free_run_scores(model, cfg, dataset)[0]


def validation_free_run_scores(
    model: ForceModel, cfg: TrainConfig, dataset: Dataset
) -> tuple[float, float]:
    """(`validation_free_run_rmse`, the same free run's RMSE over every validation row)."""
    draft = to_contract_onnx(model, provenance(model, cfg, dataset, None))
    preds = [evaluate(model, draft, r, cfg)[1] for r in dataset.validation]
    # scored as the recommendation scores a results.json entry, so the two cannot drift apart
    entry = {"validation_pooled": pooled_metrics(dataset.validation, preds, cfg.target)}
    v, every = validation_score(entry), pooled_rmse(entry, "validation")
    return (float("nan") if v is None else v, float("nan") if every is None else every)




def _candidates(
    algo: str, hyper: dict[str, dict] | None, feedback_noise: list[float] | None, dataset: Dataset
) -> tuple[str, list[tuple[str, dict]]] | None:
    """What `train_models` chooses on validation for `algo` (the parameter's name and the
    candidates), or None: no validation recording, no candidates, or the user set it."""
    if not dataset.validation:
        # lawfree alone can be validated on blocks of its training recordings
        # (blocked_validation.py): its free run is its one-step prediction
        if algo == "lawfree" and dataset.train:
            options = lawfree_candidates((hyper or {}).get(algo, {}))
            return ("readout", options) if options else None
        return None
    if algo.endswith("_fb") and feedback_noise:
        return "feedback_noise_frac", [
            (str(c), {"feedback_noise": None, "feedback_noise_frac": c}) for c in feedback_noise
        ]
    if algo == "lawfree":
        options = lawfree_candidates((hyper or {}).get(algo, {}))
        return ("readout", options) if options else None
    # every variant of structured (structured_path, structured_hyst too) has the same two bases
    if isinstance(parse_spec(algo), StructuredModel) and not set(INDENTATION) & set(
        (hyper or {}).get(algo, {})
    ):
        # the foam's basis, or with the indentation elements (structured.py): on the bench's
        # foams they fitted no closer on validation, on Bouc-Wen 8 % and the gel 54 % closer
        # (docs/laws.md, "Indentation shapes")
        return "basis", [("foam", {}), ("indentation", dict(INDENTATION))]
    return None


class _Tried:
    """The candidates `train_models` has scored for one spec: on the validation recordings,
    or, where the dataset has none, on held-out blocks of its training recordings
    (`blocked_validation.py`; the candidate itself is then fitted only once chosen)."""

    def __init__(self, spec: str, preset: str, hyper: dict[str, dict] | None, dataset: Dataset,
                 cfg: TrainConfig, parameter: str) -> None:  # fmt: skip
        self.spec, self.preset, self.hyper = spec, preset, hyper
        self.dataset, self.cfg, self.parameter = dataset, cfg, parameter
        self.blocked = not dataset.validation
        self.sliding: dict[str, float] = {}
        self.every: dict[str, float] = {}
        self.extras: dict[str, dict] = {}
        self.fitted: dict[str, ForceModel] = {}

    def score(self, label: str, extra: dict) -> None:
        """Scores the spec with `extra` on top: its validation free run (the candidate fitted
        on every training row), or its blocks' (`blocked_scores`)."""
        self.extras[label] = extra
        if self.blocked:
            s, e = blocked_scores(lambda: _configured(self.spec, self.preset, self.hyper, extra),
                                  self.dataset, self.cfg)  # fmt: skip
            where = "held-out blocks"
        else:
            cand = _fit_one(self.spec, self.preset, self.hyper, extra, self.dataset, self.cfg)
            self.fitted[label] = cand
            s, e = validation_free_run_scores(cand, self.cfg, self.dataset)
            where = "validation"
        self.sliding[label], self.every[label] = s, e
        print(f"[train] {self.spec} {self.parameter} {label}: {where} free-run RMSE "
              f"{fmt_figure(s)} N (every row {fmt_figure(e)} N)", flush=True)  # fmt: skip

    def chosen(self, label: str) -> tuple[object, ForceModel]:
        """(the value itself where the parameter is a hyper-parameter, else its label; the
        candidate fitted on every training row)."""
        extra = self.extras[label]
        if label not in self.fitted:
            self.fitted[label] = _fit_one(self.spec, self.preset, self.hyper, extra,
                                          self.dataset, self.cfg)  # fmt: skip
        return extra.get(self.parameter, label), self.fitted[label]


def feature_gains_note(dataset: Dataset) -> str | None:
    """A warning when the dataset's recordings had their velocity and acceleration computed
    with different filters (more than 1 % apart), else None. An import derives its gains from
    its file's rate (g dt = 0.2), so tests logged at different rates get different filters, and
    a feature then means something else in each: a model fitted on one is scored and chosen on
    another as if they agreed. The remedy is to import them with the same `--g-v/--g-a`."""
    recs = [*dataset.train, *dataset.validation, *dataset.test]
    gains = {r.name: g for r in recs if (g := r.feature_gains) is not None}
    if len(gains) < 2:
        return None
    ref = next(iter(gains.values()))
    if all(abs(g[k] / ref[k] - 1) <= 0.01 for g in gains.values() for k in (0, 1)):
        return None
    listed = ", ".join(f"{n} {g[0]:.4g} / {g[1]:.4g}" for n, g in gains.items())
    return (f"the recordings' velocity / acceleration filters differ (g_v / g_a rad/s: {listed}): "
            "a feature means something else in each; import them with the same --g-v and "
            "--g-a (at most the slowest file's rate allows)")  # fmt: skip


def train_models(
    dataset: Dataset,
    specs: list[str],
    cfg: TrainConfig,
    out: Path,
    preset: str = "default",
    hyper: dict[str, dict] | None = None,
    feedback_noise_candidates: list[float] | None = None,
) -> list[ForceModel]:
    """Fits every spec and saves it. For the feedback-noise networks (`*_fb`), when the dataset
    has validation recordings and candidates are given, each candidate fraction of the force
    range is trained and the one with the lowest free-run RMSE on the validation recordings is
    kept (the test recordings play no part in the choice; `train_info_["selection"]`); for
    `lawfree` likewise its readout, ridge and memory span (`lawfree_candidates`), less what
    `hyper` sets. The score is `validation_free_run_rmse`: the sliding rows, as the
    recommendation ranks; `lawfree`'s candidates must also be near the best over every
    validation row (`choose_on_both`), and its choice is tried once more with the irreversible
    memory, kept where it is clearly closer (`keep_at_margin`)."""
    for spec in specs:
        parse_spec(spec, preset)  # an unknown algorithm or feature set stops before any training
        spec_dataset(dataset, spec)  # so does a `+holds` spec on a dataset without holds
    if (note := feature_gains_note(dataset)) is not None:
        print(f"[train] warning: {note}", flush=True)
    out.mkdir(parents=True, exist_ok=True)
    models = []
    every_recording = dataset
    for spec in specs:
        # what this model trains and chooses on: the hold recordings only for `+holds` (holds.py)
        dataset = spec_dataset(every_recording, spec)
        algo = spec_algo(spec)
        candidates = _candidates(algo, hyper, feedback_noise_candidates, dataset)
        print(f"[train] {spec} on {len(dataset.train)} recordings ...", flush=True)
        try:
            if not candidates:
                m = _fit_one(spec, preset, hyper, {}, dataset, cfg)
            else:
                parameter, options = candidates
                both = algo == "lawfree"
                rule = BOTH_SCORES_RULE if both else f"the lowest {SELECTION_METRIC}"
                user = (hyper or {}).get(algo, {})
                if both and "damage_frac" not in user:
                    rule += DAMAGE_RULE
                where = "" if dataset.validation else f" ({BLOCKED_VALIDATION})"
                print(f"[train] {algo}: {parameter} chosen by {rule}{where}", flush=True)
                tried = _Tried(spec, preset, hyper, dataset, cfg, parameter)
                for label, extra in options:
                    tried.score(label, extra)
                scored, every = tried.sliding, tried.every
                pick = choose_on_both(scored, every) if both else min(
                    scored, key=lambda k: scored[k] if np.isfinite(scored[k]) else np.inf)
                damage = lawfree_damage_candidate(pick, dict(options)[pick], user) if both else None
                if damage is not None:
                    tried.score(*damage)
                    if keep_at_margin(scored, every, pick, damage[0]):
                        pick = damage[0]
                chosen, m = tried.chosen(pick)
                network = None
                steps = int(user.get("network_steps", NET_MAX_STEPS))
                skip = network_skipped(m) if both else None
                if both and not tried.blocked and steps > 0 and skip is not None:
                    network = {"skipped": skip}
                    print(f"[train] lawfree network readout not tried: {skip}", flush=True)
                elif both and not tried.blocked and steps > 0:
                    rule += NETWORK_RULE
                    m, network = try_network_readout(
                        m, dataset, cfg, scored[pick], every[pick],
                        lambda c, ds=dataset: validation_free_run_scores(c, cfg, ds), steps)
                m.train_info_["selection"] = {
                    "parameter": parameter,
                    "metric": SELECTION_METRIC,
                    "rule": rule,
                    "validation": [r.name for r in dataset.validation] or BLOCKED_VALIDATION,
                    "candidates": scored,
                    "candidates_every_row": every,
                    "chosen": chosen,
                }
                if network is not None:
                    m.train_info_["selection"]["network_readout"] = network
            rounds = int(m.hyper.get("dagger_rounds") or 0)
            if rounds:
                if not dataset.validation:
                    raise ValueError("DAgger chooses its round on a validation recording; "
                                     "the dataset has none")  # fmt: skip
                m = fit_dagger(m, dataset.train, cfg, rounds,
                               lambda c, ds=dataset: validation_free_run_rmse(c, cfg, ds),
                               SELECTION_METRIC)  # fmt: skip
        except (ValueError, RuntimeError, FloatingPointError) as e:
            # one model failing (e.g. a diverging network) must not lose the others
            print(f"[train] {spec} FAILED: {e}", flush=True)
            continue
        joblib.dump({"model": m, "config": cfg}, out / f"{m.name}.joblib")
        print(f"[train] {m.name}: {m.train_info_}", flush=True)
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
    fidelity: Path | None = None,
) -> dict:
    """Free-run (closed-loop) and one-step metrics on every validation and test recording, per
    recording and pooled -> results.json (merged with earlier results) and
    predictions/<name>.npz; the baselines (persistence, mean, sd_poly2) -> baselines.json.
    Closed loop steps an in-memory export. Prints free run first, each beside the baselines.
    The recommendation -> recommendation.json and, with `fidelity`, its keys of that file."""
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
        entry = results.get(model.name, {})
        entry.pop("error", None)
        entry.update({
            "algo": model.algo,
            "feature_set": model.feature_set,
            "features": list(model.features),
            "kind": model.kind,
            "hyperparameters": model.hyper,
            "training": {**cfg.to_dict(), **model.train_info_},
        })  # fmt: skip
        preds: dict[str, np.ndarray] = {}
        for split in ("validation", "test"):
            recs = dataset.split(split)
            evals, plist = [], []
            for rec in recs:
                r, p = evaluate(model, draft, rec, cfg, closed_loop=closed_loop)
                evals.append(r)
                plist.append(p)
                for k, v in p.items():
                    preds[f"{rec.name}:{k}"] = v.astype(np.float32)
            entry[split] = evals
            if recs:
                entry[f"{split}_pooled"] = pooled_metrics(recs, plist, cfg.target)
            else:
                entry.pop(f"{split}_pooled", None)
        np.savez_compressed(folder / "predictions" / f"{model.name}.npz", **preds)
        results[model.name] = entry
        tp = entry["test_pooled"]
        print(
            f"[evaluate] {model.name}: test (pooled over {len(dataset.test)}) free-run RMSE "
            f"{fmt_figure(tp.get('closed_loop', {}).get('rmse'))} N, one-step RMSE "
            f"{fmt_figure(tp['one_step']['rmse'])} N",
            flush=True,
        )
        _save_results(folder, results)
    if models:
        cfg = models[0][1]
        trained_sd = next((m for m, _ in models if m.name == "sd_poly2"), None)
        base = score_baselines(dataset, cfg, trained_sd)
        (folder / "baselines.json").write_text(json.dumps(base, indent=1, default=float))
        rec_path = folder / RECOMMENDATION_FILE
        doc = recommendation(results, [r.name for r in dataset.validation])
        if doc is not None:
            # the model to render: ranked on the validation recordings by free run (the test
            # recordings play no part in it); the study adds the felt force
            rec_path.write_text(json.dumps(doc, indent=1, default=float))
            top = doc["ranking"][0]
            print(f"[evaluate] recommended (validation free run): {doc['recommended']} "
                  f"(sliding rows {fmt_figure(top['validation_sliding_rmse_n'])} N, all rows "
                  f"{fmt_figure(top['validation_free_run_rmse_n'])} N; test "
                  f"{fmt_figure(doc['free_run_rmse_n'])} N) -> {rec_path}", flush=True)  # fmt: skip
            if fidelity is not None:
                merge(fidelity, {"recommended": doc["recommended"],
                                 "free_run_rmse_n": doc["free_run_rmse_n"],
                                 "free_run_true_rmse_n": doc["free_run_true_rmse_n"]})  # fmt: skip
        else:
            rec_path.unlink(missing_ok=True)
            if not dataset.validation:
                # said, not silent: a user's own dataset often has no validation recording, and
                # without this line the missing recommendation.json is found only by its absence
                print("[evaluate] no model recommended: the dataset has no validation recording "
                      "(validation_*.parquet, or role = \"validation\" in a manifest), and the "
                      "recommendation is chosen on validation only, never on the test recordings; "
                      "record one, or serve a model by name (HAPTICS_MODEL=NAME)",
                      flush=True)  # fmt: skip
        print(comparison_table(results, base, [m.name for m, _ in models]), flush=True)
    return results


def comparison_table(results: dict, base: dict, names: list[str], split: str = "test") -> str:
    """Plain-text table: free-run RMSE first, then one-step RMSE, for the baselines and the
    models, pooled over the split's recordings (what `evaluate` prints)."""
    rows = [("model", "free-run RMSE", "contact", "max", "% range", "loop work %", "one-step")]
    learned = [n for n in names if n not in BASELINES]  # a trained sd_poly2 is the baseline
    for n, e in [*((b, base[b]) for b in BASELINES), *((n, results.get(n, {})) for n in learned)]:
        pool = e.get(f"{split}_pooled")
        if not pool:
            continue
        c, o = pool.get("closed_loop", {}), pool["one_step"]
        figures = (c.get("rmse"), c.get("contact_rmse"), c.get("max_abs"),
                   c.get("rmse_pct_range"), c.get("loop_work_error_pct"), o["rmse"])  # fmt: skip
        rows.append((n, *(fmt_figure(v) for v in figures)))
    w = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = [f"[evaluate] {split}, pooled (N; baselines first):"]
    lines += ["  " + "  ".join(c.ljust(w[i]) for i, c in enumerate(r)) for r in rows]
    return "\n".join(lines)


def export_models(
    models: list[tuple[ForceModel, TrainConfig]], dataset: Dataset | None, folder: Path
) -> dict:
    """<name>.onnx with the contract metadata (metrics from results.json when evaluated) and the
    ONNX-vs-framework parity on the first test recording."""
    results = load_results(folder)
    rec = load_recommendation(folder)
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
        if rec is not None:
            # the recommendation travels with the model: which one the pipeline recommends,
            # this model's place in the ranking and why
            place = next((i + 1 for i, r in enumerate(rec["ranking"]) if r["model"] == model.name),
                         None)  # fmt: skip
            m.metadata_props.add(key="haptics.recommendation", value=json.dumps({
                "recommended": rec["recommended"], "this_model_rank": place,
                "of": len(rec["ranking"]), "metric": rec["metric"],
            }))  # fmt: skip
        if dataset is not None and (recs := dataset.test or dataset.train):
            # steps the server checks its own engine against when it loads the model
            # (reference.py): a build that reads the graph otherwise refuses it, not renders it
            ref = add_reference(m, recs[0], model.features)
            print(f"[export] {model.name}: {len(ref['force'])} reference steps "
                  f"({ref['source']}), checked by infer-server when it loads it", flush=True)
        # what one call costs on this machine, as infer-server steps it (docs/model-contract.md)
        m.metadata_props.add(key=COST_KEY, value=json.dumps(measure_cost(m)))
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
        if not metrics:
            print(f"[export] {model.name} is not evaluated: its file carries no metrics and it "
                  f"is not in the recommendation (haptics-train evaluate --names {model.name} "
                  "scores it)", flush=True)  # fmt: skip
        _save_results(folder, results)
    return results


def trial_blends(
    folder: Path,
    first: str,
    others: list[str],
    out: Path,
    weights: tuple[float, float] = WEIGHTS,
) -> dict[str, Path]:
    """The blends of `first` with each of `others` (models of `folder`) at `weights`, written
    to `out` as servable ONNX files only (the contract's metadata; no evaluation, parity nor
    reference: the study runs them on its ranking programmes to choose `first`'s partner and
    the weights, then builds the chosen one properly with `blend_models`). Other name -> file;
    a model that cannot be blended with `first` is left out and said why."""
    out.mkdir(parents=True, exist_ok=True)
    (a, cfg), *rest = load_models(folder, [first, *others])
    files: dict[str, Path] = {}
    for (b, _), name in zip(rest, others, strict=True):
        why = blendable(a, b)
        if why is not None:
            print(f"[blend] {first} with {name}: not tried ({why})", flush=True)
            continue
        model = BlendModel.of(a, b, weights)
        prov = provenance(model, cfg, None, None)
        tag = f"with_{name}_w{round(100 * weights[0])}"
        files[name] = save_onnx(to_contract_onnx(model, prov), out / f"{tag}.onnx")
    return files


def blend_models(
    folder: Path, dataset: Dataset, pair: tuple[str, str], weights: tuple[float, float] = WEIGHTS
) -> BlendModel:
    """`blend` (models/blend.py) of two trained models of `folder`: saved as blend.joblib,
    then evaluated and exported like any model (results.json entry, predictions, blend.onnx
    with its reference steps, cost and parity). Refused with why (`BlendError`) when the two
    cannot be blended. The study calls it with the pair and weights its ranking runs chose."""
    (a, cfg), (b, _) = load_models(folder, list(pair))
    model = BlendModel.of(a, b, weights)
    cfg.progress = False
    joblib.dump({"model": model, "config": cfg}, folder / f"{BLEND_NAME}.joblib")
    print(f"[blend] {BLEND_NAME} = {model.weights[0]:g} {a.name} + {model.weights[1]:g} {b.name}",
          flush=True)  # fmt: skip
    evaluate_models([(model, cfg)], dataset, folder)
    export_models([(model, cfg)], dataset, folder)
    return model


def remove_blend(folder: Path) -> bool:
    """Removes `folder`'s blend (its .joblib, .onnx, predictions and results.json entry): a
    blend is made of the candidates a study's ranking runs chose, so one left from an earlier
    study is no candidate of the next. True when there was one."""
    found = False
    for f in (folder / f"{BLEND_NAME}.joblib", folder / f"{BLEND_NAME}.onnx",
              folder / "predictions" / f"{BLEND_NAME}.npz"):  # fmt: skip
        if f.exists():
            f.unlink()
            found = True
    results = load_results(folder)
    if results.pop(BLEND_NAME, None) is not None:
        _save_results(folder, results)
        found = True
    return found
