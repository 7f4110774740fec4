"""Running the study: the reference, the oracle, every served model and the builtin
spring-damper with the same hand, seed and material (and again with friction compensation,
with a faster hand and over a longer session), the position replay, the ranking runs that
re-rank the recommendation; then the scores, figures and report."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import statistics
import time
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import TypeVar

from ..fidelity import RECOMMENDATION_FILE, load_recommendation, merge, recommendation
from ..truth import OBJECT_FORCE
from .hand import fit_hand, scaled_hand
from .plot import write_plots
from .processes import Run, Tools, find_tools, read_series, run_loop, write_config
from .protocol import (
    BUILTIN,
    DEFAULT_MATERIAL,
    FAST_HAND,
    LONG_HAND,
    ORACLE,
    RANK2_HAND,
    RANK2_SEED_OFFSET,
    RANK_HAND,
    RANK_SEED_OFFSET,
    SPRING_DAMPERS,
    STUDY_HAND,
    StudyError,
)
from .report import fmt, load_results, results_json, write_fidelity, write_readme
from .score import (
    Row,
    compare,
    fast_models,
    felt_by_phase,
    felt_by_press,
    felt_rmse,
    floor_summary,
    prediction_along_real,
    score_run,
)

# a trial's key: a partner's name, or a pair of weights
K = TypeVar("K", bound=Hashable)
# the run tags of the two ranking programmes (`study`'s hands and lists)
RANKING_TAGS = ("rank_", "rank2_")


def study_models(models_dir: Path, names: list[str] | None) -> list[Path]:
    files = sorted(models_dir.glob("*.onnx"))
    if names:
        wanted = set(names)
        files = [f for f in files if f.stem in wanted]
        missing = wanted - {f.stem for f in files}
        if missing:
            raise StudyError(f"no such model in {models_dir}: {', '.join(sorted(missing))}")
    if not files:
        raise StudyError(f"no *.onnx model in {models_dir} (train them: haptics-train pipeline)")
    return files


def run_study(
    root: Path,
    models_dir: Path,
    out_dir: Path,
    work: Path,
    trajectory: Path,
    names: list[str] | None = None,
    seed: int = 1,
    replay_seed: int = 2,
    rt_loop: str | None = None,
    infer_server: str | None = None,
    shadow_predictions: bool = True,
    log: bool = True,
    material: Path = Path(DEFAULT_MATERIAL),
    bench: Path | None = None,
    bench_models_dir: Path | None = None,
    clock: str = "lockstep",
    fidelity: Path | None = None,
    headline: str = "off",
    dataset: Path | None = None,
) -> Path:
    """The study. With `bench` (a bench file of `rt-loop identify-friction`) every reproduction
    runs twice: without friction compensation and with it (`--bench`, in the reference too),
    the latter with the models of `bench_models_dir` (trained on recordings made with the same
    bench file) when given. `headline` picks the setting of the goal lines, the plots, the fast
    hand, the position replay and docs/fidelity.json: `off` (default) is how the product renders
    today (no bench file in scripts/up.sh), `on` the compensated setting."""
    t_start = time.perf_counter()
    tools = find_tools(root, rt_loop, infer_server)
    from ..pipeline import remove_blend  # the pipeline's imports are heavy: only when needed

    if dataset is not None and headline == "off" and remove_blend(models_dir):
        print(f"[study] removed the blend of an earlier study from {models_dir}", flush=True)
    files = study_models(models_dir, names)
    if not material.is_file():
        raise StudyError(f"no material file {material}")
    if bench is not None and not bench.is_file():
        raise StudyError(f"no bench file {bench} (rt-loop identify-friction --out {bench})")
    if headline not in ("off", "on") or (headline == "on" and bench is None):
        raise StudyError(f"headline must be off, or on with a bench file (got {headline})")
    if clock not in ("lockstep", "realtime"):
        raise StudyError(f"clock must be lockstep or realtime (got {clock})")
    if not trajectory.is_file():
        raise StudyError(f"no trajectory recording {trajectory} (scripts/record-dataset.sh)")
    work.mkdir(parents=True, exist_ok=True)
    out_dir.mkdir(parents=True, exist_ok=True)

    def say(msg: str) -> None:
        if log:
            print(f"[study] {msg}", flush=True)

    common = ["--material", str(material)]
    # every hand pressed no harder than the bench renders (hand.py): the standard set-points,
    # or all of them scaled by one factor searched on the reference alone
    hand_fit = fit_hand(tools, work, STUDY_HAND, seed, common, clock, say)
    hand, fast_hand, rank_hand, rank2_hand, long_hand = (
        scaled_hand(h, hand_fit["factor"])
        for h in (STUDY_HAND, FAST_HAND, RANK_HAND, RANK2_HAND, LONG_HAND)
    )
    settings: dict[str, tuple[Run, list[Row]]] = {}
    settings["off"] = _reproduce_all(
        tools, files, work, "", hand, seed, shadow_predictions, say, common, clock
    )
    primary = headline
    extra = common
    if bench is not None:
        extra_on = [*common, "--bench", str(bench)]
        files_on = study_models(bench_models_dir, names) if bench_models_dir else files
        settings["on"] = _reproduce_all(
            tools, files_on, work, "fc_", hand, seed, shadow_predictions, say, extra_on, clock
        )
        if primary == "on":
            extra, files = extra_on, files_on
    ref, rows = settings[primary]

    # The same presses, 2.5 times faster, for the best learned models, those every law's table
    # shows, the spring-dampers and the oracle (in the headline setting).
    keep = fast_models(rows)
    fast_files = [f for f in files if f.stem in keep]
    fast_ref, fast_rows = _reproduce_all(
        tools, fast_files, work, "fast_", fast_hand, seed, False, say, extra, clock
    )
    # A session four times as long for the same models: does a model's error grow as its
    # slow memories leave the state they start a session in?
    _, long_rows = _reproduce_all(
        tools, fast_files, work, "long_", long_hand, seed, False, say, extra, clock
    )

    rep = run_loop(
        tools,
        "position replay",
        "replay",
        [
            "--experiment",
            "position-replay",
            "--clock",
            "lockstep",
            "--seed",
            str(replay_seed),
            "--trajectory",
            str(trajectory),
            *extra,
        ],
        work / "replay.parquet",
    )
    if not rep.ok:
        raise StudyError(f"the position replay failed: {rep.note or rep.stop}")
    rec = read_series(trajectory, ("time", "position_x", "F_true", "rtob_force"))
    rep_s = read_series(rep.path, ("time", "position_x", "F_true", "rtob_force"))
    replay = {
        c: compare(rec["time"], rec[c], rep_s["time"], rep_s[c])
        for c in ("rtob_force", "F_true", "position_x")
    }
    say(
        f"position replay: RFOB force RMSE {replay['rtob_force']['rmse']:.3f} N "
        f"R2 {replay['rtob_force']['r2']:.3f} ({rep.steps} steps in {rep.wall_s:.1f} s)"
    )

    results = load_results(models_dir)
    # The re-rank's felt force comes from runs of their own (two other hand programmes, each
    # with its own seed): the headline runs above are scored once and choose nothing. Done
    # before the report, which says what was recommended and how it felt on the headline runs.
    rank_files = [f for f in study_models(models_dir, names) if f.stem in results]
    felt_doc = None
    if rank_files and load_recommendation(models_dir) is not None:
        programmes = []
        for tag, rh, offset in zip(RANKING_TAGS, (rank_hand, rank2_hand),
                                   (RANK_SEED_OFFSET, RANK2_SEED_OFFSET), strict=True):  # fmt: skip
            _, rank_rows = _reproduce_all(
                tools, rank_files, work, tag, rh, seed + offset, False, say, common, clock
            )
            programmes.append(rank_rows)
        felt_doc = rerank_by_felt(models_dir, results, programmes)
        if dataset is not None and primary == "off" and felt_doc is not None:
            r1, r2 = RANKING_TAGS
            hands = {r1: (rank_hand, seed + RANK_SEED_OFFSET),
                     r2: (rank2_hand, seed + RANK2_SEED_OFFSET), "": (hand, seed),
                     "fast_": (fast_hand, seed), "long_": (long_hand, seed)}  # fmt: skip
            lists = {r1: programmes[0], r2: programmes[1], "": rows,
                     "fast_": fast_rows, "long_": long_rows}  # fmt: skip
            felt_doc = _blend(tools, models_dir, dataset, felt_doc, work, hands, lists,
                              programmes, say, common, clock) or felt_doc  # fmt: skip
            results = load_results(models_dir)
    total = time.perf_counter() - t_start
    write_plots(out_dir, ref, rows, rec, rep_s)
    setup = {
        "material": str(material),
        "bench": str(bench) if bench else None,
        "clock": clock,
        "headline": primary,
        "hand": hand,
        "fast_hand": fast_hand,
        "rank_hand": rank_hand,
        "rank2_hand": rank2_hand,
        "long_hand": long_hand,
        "hand_fit": hand_fit,
    }
    readme = write_readme(
        out_dir,
        ref,
        rows,
        replay,
        rep,
        trajectory,
        results,
        total,
        seed,
        fast_ref,
        fast_rows,
        settings,
        setup,
        felt_doc,
        long_rows,
    )
    doc = results_json(rows, replay, total, fast_rows, long_rows)
    doc["setup"] = setup
    doc["friction"] = {k: floor_summary(v[1]) for k, v in settings.items()}
    doc["recommendation"] = felt_doc
    (out_dir / "results.json").write_text(json.dumps(doc, indent=1))
    if felt_doc is not None:
        say(f"recommended (the ranking runs' felt force, the geometric mean of the two "
            f"programmes; validation where not measured): "
            f"{felt_doc['recommended']}")  # fmt: skip
        if fidelity is not None:
            keys = ("recommended", "free_run_rmse_n", "free_run_true_rmse_n")
            merge(fidelity, {k: felt_doc.get(k) for k in keys})
    if fidelity is not None:
        write_fidelity(fidelity, rows, fast_rows, primary)
        say(f"fidelity keys -> {fidelity}")
    say(f"report -> {readme} ({total:.0f} s)")
    return readme


def _reproduce_all(
    tools: Tools,
    files: list[Path],
    work: Path,
    tag: str,
    hand: dict[str, float],
    seed: int,
    shadow_predictions: bool,
    say: Callable[[str], None],
    extra: list[str] | None = None,
    clock: str = "lockstep",
    floors: bool = True,
) -> tuple[Run, list[Row]]:
    """The reference (shadow on the simulated object), the oracle, then every model's
    reproduction (and, optionally, its prediction along the real interaction, against the
    object's own force F_object), then the
    builtin spring-damper, all with the same hand programme, seed, material and bench file
    (`extra`: rt-loop flags). `floors` False: no oracle and no builtin spring-damper (a model
    added to runs that have them already, `_blend`)."""
    cfg = work / f"{tag}hand.toml"
    write_config(cfg, seed, hand, clock)
    base = ["--config", str(cfg), "--clock", clock, "--seed", str(seed), *(extra or [])]
    pid = os.getpid()

    def loop(
        name: str,
        kind: str,
        experiment: str,
        file: str,
        flags: tuple[str, ...] = (),
        model: Path | None = None,
    ) -> Run:
        """One rt-loop run of this hand programme (recorded as work/TAG FILE.parquet); with
        `model`, served by an infer-server of its own."""
        return run_loop(
            tools,
            name,
            kind,
            [*base, "--experiment", experiment, *flags],
            work / f"{tag}{file}.parquet",
            server_model=None if model is None else model.resolve(),
            instance="" if model is None else f"study-{pid}-{name}",
        )

    ref = loop("sponge", "reference", "shadow", "reference")
    if not ref.ok:
        raise StudyError(f"the reference (shadow) run failed: {ref.note or ref.stop}")
    say(f"{tag}reference: simulated object, {ref.steps} steps in {ref.wall_s:.1f} s")
    t_ref, f_ref = ref.series["time"], ref.series["F_true"]
    rows: list[Row] = []

    def rt_loop_row(
        name: str, file: str, how: str, flags: tuple[str, ...] = ()
    ) -> dict[str, float] | None:
        """The reproduction by rt-loop's own model (no server), scored and kept."""
        r = loop(name, "reproduction", "reproduction", f"repro_{file}", flags)
        score = score_run(t_ref, f_ref, r)
        phases = felt_by_phase(t_ref, f_ref, r, hand)
        rows.append(Row(r.name, how, score, None, r, None, False, by_phase=phases,
                        by_press=felt_by_press(t_ref, f_ref, r, hand)))  # fmt: skip
        return score

    if floors:
        ro = rt_loop_row(ORACLE, "oracle", "rt-loop oracle", ("--model", "oracle"))
        say(f"{tag}oracle: felt-force RMSE {fmt(ro['rmse'] if ro else None)} N (the floor)")
    for f in files:
        name = f.stem
        r = loop(name, "reproduction", "reproduction", f"repro_{name}", model=f)
        repro = score_run(t_ref, f_ref, r)
        sh = None
        sh_m, sh_truth, sh_note = None, OBJECT_FORCE, ""
        if shadow_predictions and r.series:
            sh = loop(name, "shadow", "shadow", f"shadow_{name}", model=f)
            sh_m, sh_truth, sh_note = prediction_along_real(sh)
            if sh_note:
                say(f"{tag}{name}: {sh_note}")
        learned = name not in SPRING_DAMPERS
        phases = felt_by_phase(t_ref, f_ref, r, hand)
        rows.append(
            Row(name, "served ONNX", repro, sh_m, r, sh, learned, sh_truth, sh_note, phases,
                felt_by_press(t_ref, f_ref, r, hand))
        )  # fmt: skip
        say(
            f"{tag}{name}: felt-force RMSE {fmt(repro['rmse'] if repro else None)} N, "
            f"{r.served} served / {r.fallbacks} fallbacks, stop {r.stop or '-'}, "
            f"{r.wall_s:.1f} s {r.note}"
        )
    if floors:
        rb = rt_loop_row(BUILTIN, "builtin", "rt-loop builtin")
        say(f"{tag}builtin spring-damper: felt-force RMSE {fmt(rb['rmse'] if rb else None)} N")
    return ref, rows


def blend_partners(ranking: list[dict]) -> tuple[str, list[str]] | None:
    """The blend's first member and the partners tried with it: the first candidate of the
    ranking (best first) with a felt force on the ranking runs, and every other one with one,
    in ranking order; None when fewer than two have one."""
    felt = [e["model"] for e in ranking if e.get("felt_rmse_n") is not None]
    return (felt[0], felt[1:]) if len(felt) >= 2 else None


def _blend(
    tools: Tools,
    models_dir: Path,
    dataset: Path,
    felt_doc: dict,
    work: Path,
    hands: dict[str, tuple[dict[str, float], int]],
    lists: dict[str, list[Row]],
    programmes: list[list[Row]],
    say: Callable[[str], None],
    common: list[str],
    clock: str,
) -> dict | None:
    """`blend` of the candidate the ranking runs put first with the partner that blends
    closest: the equal-weight blend of the first with every other candidate (`blend_partners`;
    those that cannot be blended with it are left out) is run on the two ranking programmes
    (`pipeline.trial_blends`: files only); the pair whose geometric mean felt closest there
    is run again at the grid's other weights (`WEIGHT_GRID`), and the closest of its weights
    is built, evaluated and exported (pipeline.blend_models), run with every other hand of the
    study (`hands`: tag -> programme and seed; its rows appended to `lists`; on the ranking
    programmes the chosen trial's rows stand for it, the same graph run alike), and the
    recommendation ranked again with its felt force beside the others'.
    The partner and the weights are chosen on the ranking runs only, as the recommendation
    is; the headline runs choose nothing. The recommendation document, or None (said why)
    when no blend can be built."""
    from ..data import load_data
    from ..models.blend import BLEND_NAME, WEIGHT_GRID, WEIGHTS, BlendError
    from ..pipeline import blend_models, trial_blends

    found = blend_partners(felt_doc["ranking"])
    if found is None:
        say("blend: fewer than two candidates with a felt force; none built")
        return None
    first, others = found

    # ranking programme's tag -> trial file's stem -> its row: the chosen trial's rows stand
    # for the built blend's on these programmes (below)
    ran: dict[str, dict[str, Row]] = {}

    def ranking_runs(files: dict[K, Path], tag: str) -> dict[K, float]:
        """Each trial's felt force on the two ranking programmes, the geometric mean as the
        recommendation takes it (`ranking_felt`: a trial that fell back or failed on either
        programme has none); all the trials of one call share each programme's reference run."""
        programmes: list[list[Row]] = []
        for rank in RANKING_TAGS:
            hand, seed = hands[rank]
            _, got = _reproduce_all(tools, list(files.values()), work, f"{tag}{rank}", hand,
                                    seed, False, say, common, clock, floors=False)  # fmt: skip
            programmes.append(got)
            ran.setdefault(rank, {}).update((r.name, r) for r in got)
        # rows are named by their file's stem
        key_of = {f.stem: key for key, f in files.items()}
        return {key_of[stem]: statistics.geometric_mean(v)
                for stem, v in ranking_felt(programmes, key_of).items()}  # fmt: skip

    trials = trial_blends(models_dir, first, others, work / "blend_trials")
    partners = ranking_runs(trials, "trial_")
    if not partners:
        say(f"blend: no blend with {first} ran on both ranking programmes; none built")
        return None
    partner = min(partners, key=lambda n: partners[n])
    say(f"blend: {first} with each of {len(partners)} partners, equal weights, on the ranking "
        f"runs; {partner} felt closest ({fmt(partners[partner])} N)")  # fmt: skip
    # then the pair's weights, on the same runs: the grid's other weights in one call
    files = {w: trial_blends(models_dir, first, [partner], work / "blend_trials", w)[partner]
             for w in WEIGHT_GRID if w != WEIGHTS}  # fmt: skip
    by_weight = {WEIGHTS: partners[partner], **ranking_runs(files, "trial_w_")}
    weights = min(by_weight, key=lambda w: by_weight[w])
    chosen = (trials[partner] if weights == WEIGHTS else files[weights]).stem
    say(f"blend: weights {weights[0]:g} / {weights[1]:g} felt closest on the ranking runs "
        f"({fmt(by_weight[weights])} N)")  # fmt: skip
    pair = (first, partner)
    try:
        blend_models(models_dir, load_data(dataset), pair, weights)
    except BlendError as e:
        say(f"blend: none built ({e})")
        return None
    file = models_dir / f"{BLEND_NAME}.onnx"
    for tag, (hand, seed) in hands.items():
        if chosen in ran.get(tag, {}):
            # The ranking programmes have run this blend already, as the chosen trial: the same
            # members and weights in the same one-node graph (`trial_blends`, `blend_models`),
            # the same programme, seed and lockstep clock, so running blend.onnx again there
            # gives the same run (4 runs, about 9 s of a study). Its rows, named for the blend.
            row = ran[tag][chosen]
            run = dataclasses.replace(row.run, name=BLEND_NAME)
            lists[tag].append(dataclasses.replace(row, name=BLEND_NAME, run=run))
            continue
        # the headline setting's flags: no bench file (the blend is built "off")
        _, got = _reproduce_all(tools, [file], work, tag, hand, seed, False, say, common,
                                clock, floors=False)  # fmt: skip
        lists[tag].extend(got)
    doc = rerank_by_felt(models_dir, load_results(models_dir), programmes)
    if doc is not None:
        entry = next(e for e in doc["ranking"] if e["model"] == BLEND_NAME)
        best = next(e for e in doc["ranking"] if e["model"] != BLEND_NAME)
        say(f"blend of {pair[0]} and {pair[1]}: ranking runs {fmt(entry.get('felt_rmse_n'))} N "
            f"against {best['model']}'s {fmt(best.get('felt_rmse_n'))} N: "
            f"{'recommended' if doc['recommended'] == BLEND_NAME else 'not recommended'}")
        doc["blend"] = {
            "members": list(pair),
            "weights": list(weights),
            "partners_felt_n": partners,
            "weights_felt_n": [{"weights": list(w), "felt_rmse_n": v}
                               for w, v in by_weight.items()],  # fmt: skip
        }
        (models_dir / RECOMMENDATION_FILE).write_text(json.dumps(doc, indent=1) + "\n")
    return doc


def ranking_felt(programmes: list[list[Row]], results: dict) -> dict[str, list[float]]:
    """Each model's felt force on every ranking programme (name -> one RMSE per programme, in
    order), for the models of `results` rankable in every one: a model that fell back or failed
    on one programme has no felt force, and is ranked by validation, as with one programme."""
    out: dict[str, list[float]] = {}
    for name in results:
        # felt_rmse is NaN for a missing or unrankable run
        felt = [felt_rmse(next((r for r in rows if r.name == name), None)) for rows in programmes]
        if felt and all(math.isfinite(f) and f > 0 for f in felt):
            out[name] = felt
    return out


def rerank_by_felt(models_dir: Path, results: dict, programmes: list[list[Row]]) -> dict | None:
    """The pipeline's recommendation ranked again with the felt force of the ranking runs
    (`programmes`: one list of rows per hand programme, each another programme and seed than
    the headline's, without friction compensation, the models of `models_dir`), written back to
    its recommendation.json; None when the pipeline recommended nothing (no validation run).

    A model's felt force is the geometric mean over the programmes (scale-free: a programme
    whose forces are larger weighs no more), each programme's value kept beside it in its
    ranking entry (`felt_by_programme_n`)."""
    prior = load_recommendation(models_dir)
    if prior is None:
        return None
    each = ranking_felt(programmes, results)
    felt = {k: statistics.geometric_mean(v) for k, v in each.items()}
    doc = recommendation(results, list(prior.get("validation") or []), felt)
    if doc is not None:
        for e in doc["ranking"]:
            e["felt_by_programme_n"] = each.get(e["model"])
        (models_dir / RECOMMENDATION_FILE).write_text(json.dumps(doc, indent=1) + "\n")
    return doc


def clean_work(work: Path) -> None:
    """Removes the study's raw recordings (kept by default for inspection)."""
    if work.is_dir():
        shutil.rmtree(work)
