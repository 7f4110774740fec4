"""The study's written outputs: docs/study/README.md (every sentence computed from the
numbers), results.json and the study's keys of docs/fidelity.json."""

from __future__ import annotations

import json
import math
from pathlib import Path

from ..fidelity import merge, read_object
from ..truth import OBJECT_FORCE
from .processes import Run
from .protocol import (
    DEFAULT_MATERIAL,
    FAST_ALWAYS,
    FAST_BEST,
    FAST_HAND,
    GOAL_RATIO,
    GOAL_RMSE,
    LONG_ENDS,
    LONG_GREW,
    LONG_HAND,
    ORACLE,
    STUDY_HAND,
)
from .score import (
    HAND_PHASES,
    Row,
    best_row,
    felt_rmse,
    flags_text,
    floor_summary,
    named_row,
    nan_to_none,
    programme_s,
    rankable,
    ratio,
    repro_rmse,
    run_flags,
    sd2_row,
)


def fmt(v: float | None, nd: int = 3) -> str:
    if v is None or not math.isfinite(v):
        return "-"
    return f"{v:.{nd}f}"


def load_results(models_dir: Path) -> dict:
    try:
        return json.loads((models_dir / "results.json").read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def offline_rmse(results: dict, name: str) -> str:
    """`one-step / closed-loop` test RMSE of docs/report for a model, '-' if not evaluated."""
    res = results.get(name) if isinstance(results, dict) else None
    tests = res.get("test") if isinstance(res, dict) else None
    if not isinstance(tests, list) or not tests or not isinstance(tests[0], dict):
        return "-"
    one = (tests[0].get("one_step") or {}).get("rmse")
    cl = (tests[0].get("closed_loop") or {}).get("rmse")
    return f"{fmt(one)} / {fmt(cl)}"


def write_fidelity(path: Path, rows: list[Row], fast_rows: list[Row], setting: str = "off") -> dict:
    """Merges the study's keys into docs/fidelity.json (the pipeline writes the others):
    the oracle's and sd_poly2's felt force, and the felt force (normal and fast hand) of the
    recommended model when the pipeline has named one (`recommended`) and it was in the study,
    else of the best learned model (`felt_model` says which)."""
    rec = read_object(path).get("recommended")
    model = named_row(rows, rec) if isinstance(rec, str) else None
    if model is None or not rankable(model):
        model = best_row(rows, True)
    fast = named_row(fast_rows, model.name) if model is not None else None
    return merge(
        path,
        {
            "oracle_felt_rmse_n": nan_to_none(felt_rmse(named_row(rows, ORACLE))),
            "sd_poly2_felt_rmse_n": nan_to_none(felt_rmse(sd2_row(rows))),
            "felt_rmse_n": nan_to_none(felt_rmse(model)),
            "felt_fast_rmse_n": nan_to_none(felt_rmse(fast)),
            "felt_model": model.name if model is not None else None,
            "felt_friction_compensation": setting,
        },
    )


def metric_cells(m: dict[str, float] | None) -> list[str]:
    if m is None:
        return ["-", "-", "-", "-"]
    return [fmt(m["r2"]), fmt(m["mae"]), fmt(m["mse"]), fmt(m["rmse"])]


def hand_note(fit: dict | None) -> str:
    """The sentence saying whether the hand was scaled to the object (study/hand.py)."""
    if not fit or not math.isfinite(fit.get("renderable_n", math.nan)):
        return ""
    if fit["factor"] >= 1.0:
        return (
            f"  At these set-points the reference peaks at {fit['peak_n']:.2f} N, within "
            f"{fit['target_n'] / fit['renderable_n']:.0%} of the {fit['renderable_n']:.2f} N "
            "the bench renders (the lower of `reproduction.max_force_n` and the motor's current "
            "limit times its nominal force constant): the standard hand.\n"
        )
    return (
        f"  **Scaled to the object:** at the standard set-points the reference peaked at "
        f"{fit['peak_n']:.2f} N, above {fit['target_n'] / fit['renderable_n']:.0%} of the "
        f"{fit['renderable_n']:.2f} N the bench renders (the lower of "
        "`reproduction.max_force_n` and the motor's current limit times its nominal force "
        f"constant), so every hand's set-points (headline, fast, ranking) are "
        f"{fit['factor']:.3f}x the standard ones (searched on {fit['tries']} reference runs, "
        f"none with a model; the reference now peaks at {fit['peak_scaled_n']:.2f} N).\n"
    )


def write_readme(
    out: Path,
    ref: Run,
    rows: list[Row],
    replay: dict[str, dict[str, float]],
    rep: Run,
    trajectory: Path,
    results: dict,
    total_s: float,
    seed: int,
    fast_ref: Run | None = None,
    fast_rows: list[Row] | None = None,
    settings: dict[str, tuple[Run, list[Row]]] | None = None,
    setup: dict | None = None,
    recommendation: dict | None = None,
    long_rows: list[Row] | None = None,
) -> Path:
    """The study's README. `recommendation`: the pipeline's recommendation re-ranked with the
    ranking runs' felt force (`study.run.rerank_by_felt`; None where there was none): the
    report says which model the product serves and how it felt on these runs."""
    setup = setup or {"material": DEFAULT_MATERIAL, "bench": None, "clock": "lockstep"}
    best = best_row(rows, True)
    sd2 = sd2_row(rows)
    sd2_rmse = sd2.repro["rmse"] if sd2 and sd2.repro else float("nan")
    best_rmse = best.repro["rmse"] if best and best.repro else float("nan")
    k = ratio(sd2_rmse, best_rmse)
    met_rmse = best_rmse <= GOAL_RMSE
    met_ratio = math.isfinite(k) and k >= GOAL_RATIO
    h = setup.get("hand") or STUDY_HAND
    dur = programme_s(h)
    L: list[str] = []
    L.append("# Reproduction study (thesis 6.4.3 and 6.4.4) on the simulated bench\n")
    L.append(
        "Written by `bash scripts/reproduction-study.sh` (`haptics-train study`). Everything "
        f"below was measured by the real processes: `rt-loop run` ({setup['clock']} clock, seed "
        f"{seed}, material `{setup['material']}`, bench file "
        f"{'`' + str(setup['bench']) + '`' if setup.get('bench') else 'none'}) "
        "and, per model, `infer-server serve --model models/NAME.onnx` beside "
        "`rt-loop run --experiment reproduction --model shm`, exchanging features and forces "
        "over shared memory every control step (10 kHz loop time).\n"
    )
    L.append("## Set-up\n")
    L.append(
        f"- **The hand** (rt-loop `[hand]`): stiffness {h['stiffness']:.0f} N/m, damping "
        f"{h['damping']:.0f} N s/m, {h['repeats']} presses (press {h['press_s']} s, hold "
        f"{h['hold_s']} s, release {h['release_s']} s, rest {h['rest_s']} s) to set-points of "
        + ", ".join(
            f"{1000 * (h['depth_m'] + i * h['depth_step_m']):.0f}" for i in range(int(h["repeats"]))
        )
        + f" mm: {dur:.1f} s of loop time, {ref.steps} control steps per run.\n"
        + hand_note(setup.get("hand_fit"))
        + "- **Reference**: `shadow`, the hand presses the simulated object "
        f"(`{setup['material']}`) through a transparent motor (F_cmd = 0).\n"
        "- **Oracle** (`rt-loop run --model oracle`): the object's own physics (a separate "
        "instance of the same material model) driven by the measured motion, rendered through "
        "the same force loop: the rendering floor.\n"
        "- **Friction compensation**: with a bench file (`rt-loop identify-friction`), the RFOB "
        "subtracts the identified friction (`--bench`) in the reference and in every "
        "reproduction alike; `off` = without (the thesis code's `friction_model` = 0).\n"
        "- **Reproduction**: no sponge; the motor renders F_cmd = -F_pred of the served model; "
        "the features' previous force is the model's own previous prediction.\n"
        "- **Felt force** = the recording's `F_true`, which in both `shadow` and "
        "`reproduction` is the force the simulated hand pushes with (docs/rt-loop.md), i.e. "
        "what the operator feels, including the motor's friction and inertia on both sides. "
        "Both runs have the same seed and programme, so their time stamps are identical; the "
        "run is interpolated onto the reference's time stamps anyway (`study.align`), and a "
        "run that stopped early is scored only on the time it covered (`coverage`) and left "
        "out of the ranking.\n"
        "- Metrics: R2, MAE, MSE, RMSE (thesis eqs. 7.15-7.19) of the felt force against the "
        "reference's at every control step.\n"
    )

    L.append("## Result against the goal\n")
    L.append(
        "| | thesis (Table 6.19) | this study |\n|---|---|---|\n"
        "| best learned model | random forest: RMSE 1.21 N, R2 0.76 | "
        f"`{best.name if best else '-'}`: RMSE {fmt(best_rmse)} N, "
        f"R2 {fmt(best.repro['r2'] if best and best.repro else None)} |\n"
        "| 2nd-order spring-damper | RMSE 20.95 N, R2 -71.58 | "
        f"`sd_poly2`: RMSE {fmt(sd2_rmse)} N, "
        f"R2 {fmt(sd2.repro['r2'] if sd2 and sd2.repro else None)} |\n"
        f"| spring-damper RMSE / best RMSE | 17.3x | {fmt(k, 2)}x |\n"
    )
    L.append(
        f"- Best learned model at or below 1.21 N RMSE: **{'met' if met_rmse else 'not met'}** "
        f"({fmt(best_rmse)} N).\n"
        f"- At least ten times closer than the 2nd-order spring-damper: "
        f"**{'met' if met_ratio else 'not met'}** ({fmt(k, 2)}x).\n"
    )
    L.append(
        "The best learned model here is the one closest on these runs, as the thesis's table "
        "picked it; the model the product serves is chosen without them (the recommendation, "
        "below).\n"
    )
    pb = best_row(rows, True, key="shadow")
    if pb is not None and pb.shadow is not None and sd2 is not None and sd2.shadow is not None:
        L.append(
            "The thesis's Table 6.19 itself compared the forces *predicted* along a real "
            "interaction (model and spring-damper) with the measured one. The same here "
            "(`pred along real` below: each model fed the hand-on-sponge run, F_pred vs "
            f"{truth_text(pb)}): best learned `{pb.name}` RMSE {fmt(pb.shadow['rmse'])} N "
            f"(R2 {fmt(pb.shadow['r2'])}), `sd_poly2` {fmt(sd2.shadow['rmse'])} N "
            f"(R2 {fmt(sd2.shadow['r2'])}): "
            f"{fmt(ratio(sd2.shadow['rmse'], pb.shadow['rmse']), 2)}x. Against the hand's "
            f"F_true instead (the felt force, the bench's friction and mass included) "
            f"`{pb.name}` would read {fmt(pb.shadow.get('felt_rmse'))} N.\n"
        )
    notes = [r.shadow_note for r in rows if r.shadow_note]
    if notes:
        L.append("Predictions along the real interaction scored against the felt force "
                 "instead of the object's own: " + "; ".join(notes) + ".\n")  # fmt: skip
    L.extend(recommendation_section(recommendation, rows, setup))
    fast_note = "not run."
    if fast_rows:
        fb, fsd = best_row(fast_rows, True), sd2_row(fast_rows)
        if fb and fsd and fb.repro and fsd.repro:
            fast_note = (
                f"{fmt(ratio(fsd.repro['rmse'], fb.repro['rmse']), 2)}x (sensitivity run below)."
            )
    L.extend(floor_section(settings or {}, setup, fast_note))
    L.append("## Felt force: every served model against the simulated object\n")
    L.append(
        "`repro` = reproduction (the hand on the virtual sponge) vs the reference's felt force. "
        "`pred along real` = the thesis's own 6.4.4 comparison: `shadow --model shm`, the model "
        "predicting along the real interaction from its own previous predictions, F_pred vs "
        "the simulated object's own force F_object of that run (not the hand's F_true). "
        "`one-step` / `closed-loop` = the offline "
        "test-set RMSE of docs/report (held-out 2.1 N/s ramps). Wall = seconds for the "
        "reproduction run (both processes, start to end).\n"
    )
    L.append(
        "| model | how | repro R2 | repro MAE | repro MSE | repro RMSE | pred along real RMSE "
        "| pred along real R2 | offline one-step / closed-loop RMSE | served / fallbacks "
        "| flags | stop | wall s |"
    )
    L.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    order = sorted(rows, key=lambda r: (not rankable(r), r.repro["rmse"] if r.repro else math.inf))
    for r in order:
        off = offline_rmse(results, r.name)
        stop = r.run.stop or "-"
        if r.repro is not None and r.repro["coverage"] < 0.999:
            stop += f" (covers {100 * r.repro['coverage']:.0f} %)"
        if r.run.note:
            stop += f": {r.run.note}"
        L.append(
            f"| `{r.name}` | {r.how} | " + " | ".join(metric_cells(r.repro)) + " | "
            f"{fmt(r.shadow['rmse'] if r.shadow else None)} | "
            f"{fmt(r.shadow['r2'] if r.shadow else None)} | {off} | "
            f"{r.run.served} / {r.run.fallbacks} | {flags_text(r, rows)} | {stop} | "
            f"{r.run.wall_s:.1f} |"
        )
    L.append("")
    L.append("![felt-force RMSE per model](rmse.png)\n")
    L.append(
        "The best three learned models and `sd_poly2` against the simulated object, over "
        "time (felt force and depth):\n"
    )
    L.append("![felt force over time](felt_force_time.png)\n")
    L.append("and over depth (felt force against the probe's depth):\n")
    L.append("![felt force over depth](felt_force_depth.png)\n")
    L.extend(phase_section(rows))

    rf = replay["rtob_force"]
    tf = replay["F_true"]
    px = replay["position_x"]
    L.append("## Position-replay validation (thesis 6.4.3, Table 6.18)\n")
    L.append(
        f"The held-out recording `{trajectory.name}` (force-controlled ramps at 2.1 N/s, "
        f"14 cycles) gives the position reference; `rt-loop run --experiment position-replay` "
        "follows it with the thesis's PID (C_p 700, C_d 12, C_i 1000, current = PID M_n/K_fn, "
        f"plus the DOB estimate) on the simulated object, from a fresh sponge as the recording "
        f"started: {rep.steps} steps in {rep.wall_s:.1f} s of wall time. The force response "
        "(RFOB estimate, what the thesis measured) and the true contact force of the replay are "
        "compared with the recording's at the same time.\n"
    )
    L.append("| quantity | R2 | MAE | MSE | RMSE |\n|---|---|---|---|---|")
    L.append("| thesis Table 6.18 (force response) | 0.95 | 0.42 | 0.33 | 0.57 |")
    L.append("| force response F_res (RFOB) | " + " | ".join(metric_cells(rf)) + " |")
    L.append("| true contact force F_true | " + " | ".join(metric_cells(tf)) + " |")
    L.append(
        f"| depth x (mm) | {fmt(px['r2'])} | {fmt(1000 * px['mae'])} | - | "
        f"{fmt(1000 * px['rmse'])} |\n"
    )
    L.append(
        f"Depth tracking {fmt(1000 * px['rmse'])} mm RMS; force response (RFOB) RMSE "
        f"{fmt(rf['rmse'])} N against the true contact force's {fmt(tf['rmse'])} N. The "
        "models' predictions along this same trajectory (closed loop, each fed its own "
        "previous predictions) are in docs/report/README.md.\n"
    )
    L.append("![position replay](position_replay.png)\n")
    if fast_ref is not None and fast_rows:
        fh = setup.get("fast_hand") or FAST_HAND
        L.append("## Sensitivity: a faster hand (not part of the goal)\n")
        L.append(
            f"The same three presses with press and release in {fh['press_s']} s instead of "
            f"{h['press_s']} s (the reference re-run with that hand too), for the "
            f"{FAST_BEST} best learned models above, "
            f"{', '.join(f'`{n}`' for n in FAST_ALWAYS)} wherever studied, and the "
            "spring-dampers. Reported whatever "
            "it shows. Fallbacks are steps whose served force was refused (NaN/Inf), late or "
            "missing: the loop rendered its built-in fallback instead; an answer beyond "
            "`reproduction.max_force_n` is rendered at the limit and flagged `saturated`.\n"
        )
        L.append("| model | R2 | MAE | MSE | RMSE | served / fallbacks | flags | stop |")
        L.append("|---|---|---|---|---|---|---|---|")
        for r in sorted(fast_rows, key=lambda r: (not rankable(r), repro_rmse(r))):
            L.append(
                f"| `{r.name}` | " + " | ".join(metric_cells(r.repro)) + " | "
                f"{r.run.served} / {r.run.fallbacks} | {flags_text(r, fast_rows)} | "
                f"{r.run.stop or '-'} {r.run.note} |"
            )
        fb = best_row(fast_rows, True)
        fsd = sd2_row(fast_rows)
        if fb and fsd and fb.repro and fsd.repro:
            L.append(
                f"\nFaster hand: best learned `{fb.name}` {fmt(fb.repro['rmse'])} N, "
                f"`sd_poly2` {fmt(fsd.repro['rmse'])} N: "
                f"{fmt(ratio(fsd.repro['rmse'], fb.repro['rmse']), 2)}x.\n"
            )
        else:
            L.append("")
    L.extend(long_section(long_rows, setup.get("long_hand") or LONG_HAND))
    L.append("## Timings\n")
    L.append(
        f"Whole study: {total_s:.0f} s of wall time on the shared 2-core machine (builds not "
        f"included). Reference run {ref.wall_s:.2f} s; per model, reproduction and "
        "prediction-along-real runs of the loop and infer-server together: see the `wall s` "
        "column (lockstep: the loop waits for every answer, the server parks between "
        "messages).\n"
    )
    L.append("## Reproduce\n")
    L.append(
        "```\nbash scripts/reproduction-study.sh   # builds release, runs, writes docs/study/\n"
        ".venv/bin/haptics-train study --names rf_memory,sd_poly2   # a subset\n"
        "# issue 11 from nothing for one material: identify the friction (bench.toml), record\n"
        "# and train without and with it, then this study with --bench/--bench-models-dir\n"
        "bash scripts/fidelity-study.sh [--material materials/foam-b.toml]\n"
        "# flags: --material FILE, --bench FILE, --bench-models-dir DIR, --headline off|on,\n"
        "#        --clock lockstep|realtime, --fidelity FILE ('' to skip)\n```\n"
    )
    L.append(
        "Raw recordings stay in `data/study/` (not committed); `results.json` here has "
        "every number of the tables.\n"
    )
    path = out / "README.md"
    path.write_text("\n".join(L))
    return path


def phase_section(rows: list[Row]) -> list[str]:
    """Where in the hand programme the felt-force error sits, for the oracle, the best learned
    model and sd_poly2 (each row's `felt_by_phase`); every sentence from the numbers."""
    best = best_row(rows, True)
    picked = [r for r in (named_row(rows, ORACLE), best, sd2_row(rows)) if r and r.by_phase]
    if not picked:
        return []
    L = ["### Where the felt error sits in the hand programme\n"]
    L.append(
        "Each reproduction's felt-force error split by the phase of the hand programme it "
        "falls in: the share of the squared error (the phase's RMSE; the mean error, the hand's "
        "force in the reproduction minus on the object: negative where it pushes with less "
        "force, i.e. the rendering is softer there). The time each phase takes: "
        + ", ".join(
            f"{p} {100 * (picked[0].by_phase.get(p) or {}).get('time_share', 0.0):.0f} %"
            for p in HAND_PHASES
        )
        + ".\n"
    )
    L.append("| model | " + " | ".join(HAND_PHASES) + " |")
    L.append("|---|" + "---|" * len(HAND_PHASES))

    def cell(r: Row, p: str) -> str:
        v = (r.by_phase or {}).get(p)
        if not v:
            return "-"
        share = v["sq_error_share"]
        pct = "-" if share is None else f"{100 * share:.0f} %"
        return f"{pct} ({fmt(v['rmse'])} N, {v['bias_n']:+.3f} N)"

    for r in picked:
        L.append(f"| `{r.name}` | " + " | ".join(cell(r, p) for p in HAND_PHASES) + " |")
    L.append("")
    if best is not None and best.by_phase:
        shares = {p: v["sq_error_share"] for p, v in best.by_phase.items()}
        if all(v is not None for v in shares.values()):
            top = max(shares, key=lambda p: shares[p] or 0.0)
            v = best.by_phase[top]
            side = "less" if v["bias_n"] < 0 else "more"
            L.append(
                f"The largest share of `{best.name}`'s squared felt-force error, "
                f"{100 * (v['sq_error_share'] or 0.0):.0f} %, falls in the {top} phases, which "
                f"take {100 * v['time_share']:.0f} % of the time; there the hand pushes "
                f"{abs(v['bias_n']):.3f} N {side} than on the object on average (RMSE "
                f"{fmt(v['rmse'])} N).\n"
            )
    return L


def _press_mean(by_press: list[float] | None, part: slice) -> float:
    """The RMSE over the presses `part` of a run's `felt_by_press` (the root of the mean of
    their mean squares: each press is as long as the others); NaN where any is missing."""
    vals = (by_press or [])[part]
    if not vals or not all(math.isfinite(v) for v in vals):
        return math.nan
    return math.sqrt(sum(v * v for v in vals) / len(vals))


def long_section(rows: list[Row] | None, hand: dict) -> list[str]:
    """The longer session (`protocol.LONG_HAND`): each model's felt force over the whole
    session and over its first and last `LONG_ENDS` presses; which models' error grew by more
    than `LONG_GREW` times from the first presses to the last. Computed from the numbers."""
    if not rows:
        return []
    n = int(hand["repeats"])
    dur = programme_s(hand)
    first, last = slice(0, LONG_ENDS), slice(n - LONG_ENDS, n)
    L = ["## Sensitivity: a longer session (not part of the goal)\n"]
    L.append(
        f"{n} presses to one set-point ({1000 * hand['depth_m']:.0f} mm, the headline's middle "
        f"one), the headline's timing: {dur:.1f} s of loop time against the headline's three "
        "presses from rest, for the models of the faster hand and the oracle. A memory slower "
        "than the headline's session shows here: the last presses against the first. Reported "
        "whatever it shows.\n"
    )
    L.append(
        f"| model | felt RMSE (N) | presses 1-{LONG_ENDS} | presses {n - LONG_ENDS + 1}-{n} "
        "| last / first | served / fallbacks | flags |"
    )
    L.append("|---|---|---|---|---|---|---|")
    grew = []
    for r in sorted(rows, key=lambda r: (not rankable(r), repro_rmse(r))):
        a, b = _press_mean(r.by_press, first), _press_mean(r.by_press, last)
        k = b / a if math.isfinite(a) and math.isfinite(b) and a > 0 else math.nan
        if r.name != ORACLE and math.isfinite(k) and k > LONG_GREW:
            grew.append(f"`{r.name}` ({fmt(a)} -> {fmt(b)} N, {fmt(k, 2)}x)")
        L.append(
            f"| `{r.name}` | {fmt(r.repro['rmse'] if r.repro else None)} | "
            f"{fmt(a if math.isfinite(a) else None)} | {fmt(b if math.isfinite(b) else None)} | "
            f"{_times(k)} | {r.run.served} / {r.run.fallbacks} | {flags_text(r, rows)} |"
        )
    L.append("")
    L.append(
        "- Error grown by more than a quarter from the first presses to the last: "
        + (", ".join(grew) if grew else "none")
        + ".\n"
    )
    return L


def _times(v: object) -> str:
    return f"{fmt(v, 2)}x" if isinstance(v, int | float) and math.isfinite(v) else "-"


def blend_sentence(blend: dict) -> str:
    """What the study's `blend` is made of and how its parts were chosen, from the
    recommendation's `blend` entry (study/run.py, `_blend`)."""
    a, b = blend["members"][:2]
    wa, wb = (blend.get("weights") or [0.5, 0.5])[:2]
    tried = blend.get("partners_felt_n") or {}
    grid = [e["weights"] for e in blend.get("weights_felt_n") or []]
    if not tried:  # an earlier study's entry: the first two of its ranking, equal weights
        return (f"`blend` is the mean of `{a}` and `{b}`, the two models the ranking runs put "
                "first before it was built, each stepping its own state (models/blend.py); it "
                "ran on the same ranking programmes and is ranked like the others.\n")  # fmt: skip
    return (
        f"`blend` is {wa:g} x `{a}` + {wb:g} x `{b}`, each stepping its own state "
        f"(models/blend.py). `{a}` is the model the ranking runs put first before it was "
        f"built; of the {len(tried)} partners tried with it at equal weights, `{b}` felt "
        f"closest on those runs ({fmt(tried.get(b), 4)} N), and of the weights tried "
        f"({', '.join(f'{w[0]:g} / {w[1]:g}' for w in grid)}) these. It is ranked like the "
        "others.\n"
    )


def recommendation_section(rec: dict | None, rows: list[Row], setup: dict) -> list[str]:
    """Which model the product serves (`rec`: the recommendation re-ranked by the study, the
    ranking as `fidelity.rank` wrote it), the multiples that chose it, and how it felt on these
    runs, which chose nothing: against the oracle and sd_poly2 (issue 23's goals) and, where
    another learned model felt closer here, by how much and why the ranking preferred the
    recommended one. Every sentence computed from the numbers."""
    L = ["## The recommendation: the model the product serves\n"]
    ranking = (rec or {}).get("ranking") or []
    if not ranking:
        return L + [
            "No recommendation was ranked (the models' folder names none: a dataset without a "
            "validation recording), so none is reported here; the tables below rank these runs "
            "only.\n"
        ]
    hands = [h for h in (setup.get("rank_hand"), setup.get("rank2_hand")) if h]
    described = [
        f"press {h['press_s']} s, hold {h['hold_s']} s, release {h['release_s']} s"
        for h in hands
        if {"press_s", "hold_s", "release_s"} <= h.keys()
    ]
    n = len(hands)
    if n > 1:
        runs = (
            f"the ranking runs ({n} other hand programmes, each with its own seed"
            + (f": {'; '.join(described)}" if described else "")
            + "; the geometric mean of a model's felt force over them)"
        )
    else:
        runs = "the ranking runs (another hand programme and seed" + (
            f": {described[0]})" if described else ")"
        )
    L.append(
        "Chosen without these runs: each model's free run on the validation recordings (the "
        f"rows where the probe is pressed and slides) and its felt force on {runs}, each as a "
        "multiple of the best model's; the ranking runs' multiple is the score where it was "
        "measured, the validation's where not (`fidelity.rank`). The last column is the felt "
        "force on the runs above, scored once.\n"
    )
    L.append(
        "| model | validation, sliding (N) | x best | ranking runs, felt (N) | x best | score "
        "| these runs, felt (N) |"
    )
    L.append("|---|---|---|---|---|---|---|")
    for e in ranking:
        v = e.get("validation_sliding_rmse_n")
        if v is None:
            v = e.get("validation_free_run_rmse_n")
        here = felt_rmse(named_row(rows, e["model"]))
        each = e.get("felt_by_programme_n") or []
        felt = fmt(e.get("felt_rmse_n"))
        if len(each) > 1:
            felt += " (" + " / ".join(fmt(f) for f in each) + ")"
        L.append(
            f"| `{e['model']}` | {fmt(v)} | {_times(e.get('validation_multiple'))} | "
            f"{felt} | {_times(e.get('felt_multiple'))} | "
            f"{fmt(e.get('score'), 2)} | {fmt(here if math.isfinite(here) else None)} |"
        )
    L.append("")
    blend = (rec or {}).get("blend")
    if blend and blend.get("members"):
        L.append(blend_sentence(blend))
    name = rec["recommended"]
    mine = felt_rmse(named_row(rows, name))
    if not math.isfinite(mine):
        return L + [
            f"- Recommended: `{name}`; it has no felt force on these runs (not run, or its run "
            "is not rankable: see the flags below).\n"
        ]
    o, sd = felt_rmse(named_row(rows, ORACLE)), felt_rmse(sd2_row(rows))
    parts = [f"- Recommended: `{name}`, felt {fmt(mine)} N on these runs"]
    if math.isfinite(o) and o > 0:
        k = mine / o
        met = "met" if k <= 2 else "not met"
        parts.append(f"{fmt(k, 2)}x the oracle's {fmt(o)} N (issue 23: at most 2x, {met})")
    if math.isfinite(sd):
        k = sd / mine
        met = "met" if k >= 3 else "not met"
        parts.append(f"sd_poly2 {fmt(sd)} N, {fmt(k, 2)}x its error (at least 3x, {met})")
    L.append("; ".join(parts) + ".\n")
    by = {e["model"]: e for e in ranking}
    ranked = [r for r in rows if r.name in by and math.isfinite(felt_rmse(r))]
    closest = min(ranked, key=felt_rmse, default=None)
    if closest is None or closest.name == name:
        L.append(f"- `{name}` is also the ranked model that felt closest on these runs.\n")
        return L
    # both are in the ranking: `closest` was picked among its models, `name` heads it
    c, served = by[closest.name], by[name]
    L.append(
        f"- `{closest.name}` felt closer on these runs: {fmt(felt_rmse(closest))} N, "
        f"{fmt(mine / felt_rmse(closest), 2)}x closer than `{name}`. The ranking put `{name}` "
        f"first: score {fmt(served.get('score'), 2)} (validation "
        f"{_times(served.get('validation_multiple'))}, ranking runs "
        f"{_times(served.get('felt_multiple'))}) against `{closest.name}`'s "
        f"{fmt(c.get('score'), 2)} ({_times(c.get('validation_multiple'))}, "
        f"{_times(c.get('felt_multiple'))}). These runs choose nothing: the product serves "
        "the recommended model.\n"
    )
    return L


def floor_section(
    settings: dict[str, tuple[Run, list[Row]]], setup: dict, fast_note: str
) -> list[str]:
    """The rendering floor (oracle) beside sd_poly2, the builtin and the best learned model,
    per friction setting; every sentence computed from the numbers."""
    L = ["## Rendering floor and friction compensation\n"]
    if not settings:
        return L + ["Not measured in this run.\n"]
    L.append(
        "Felt-force RMSE (N) against the reference of the same setting. `off`: no friction "
        "model in the RFOB; `on`: the bench file's friction subtracted "
        f"({setup.get('bench') or '-'}).\n"
    )
    L.append(
        "| setting | oracle (floor) | sd_poly2 | builtin | best learned | best / oracle "
        "| flags (saturated / refused steps, a broken floor) |"
    )
    L.append("|---|---|---|---|---|---|---|")
    for key, (_, rows) in settings.items():
        f = floor_summary(rows)
        o, b = float(f["oracle_felt_rmse_n"]), float(f["best_learned_felt_rmse_n"])  # type: ignore[arg-type]
        flags = "; ".join(f"`{n}`: {', '.join(v)}" for n, v in f["flags"].items()) or "-"  # type: ignore[attr-defined]
        L.append(
            f"| {key} | {fmt(o)} | {fmt(float(f['sd_poly2_felt_rmse_n']))} | "  # type: ignore[arg-type]
            f"{fmt(float(f['builtin_felt_rmse_n']))} | "  # type: ignore[arg-type]
            f"{'`' + str(f['best_learned']) + '` ' if f['best_learned'] else ''}{fmt(b)} | "
            f"{fmt(b / o if o > 0 else math.nan, 2)}x | {flags} |"
        )
    L.append("")
    for key, (_, rows) in settings.items():
        o = felt_rmse(named_row(rows, ORACLE))
        sd = felt_rmse(sd2_row(rows))
        if math.isfinite(o) and math.isfinite(sd) and o > 0:
            L.append(
                f"- `{key}`: sd_poly2 renders {fmt(sd / o, 1)}x the floor's error; a model "
                f"at the floor would be {fmt(sd / o, 1)}x closer than sd_poly2.\n"
            )
    L.append(f"- Faster hand, best learned vs sd_poly2: {fast_note}\n")
    head = settings.get(str(setup.get("headline", "off"))) or next(iter(settings.values()))
    o, b = felt_rmse(named_row(head[1], ORACLE)), felt_rmse(best_row(head[1], True))
    on = settings.get("on")
    floor_on = felt_rmse(named_row(on[1], ORACLE)) if on else math.nan

    def met(ok: bool) -> str:
        return "**met**" if ok else "**not met**"

    L.append("Issue 11 goals (felt force, the headline setting):\n")
    L.append(f"- Best learned at most 0.20 N: {met(b <= 0.20)} ({fmt(b)} N).\n")
    L.append(
        f"- Within 1.5x of the oracle's floor: {met(o > 0 and b / o <= 1.5)} "
        f"({fmt(b / o if o > 0 else math.nan, 2)}x).\n"
    )
    L.append(
        f"- Floor at most 0.10 N with friction compensated: {met(floor_on <= 0.10)} "
        f"({fmt(floor_on)} N{'' if on else ', no bench file given'}).\n"
    )
    return L


def truth_text(r: Row) -> str:
    """What a row's prediction along the real interaction was scored against."""
    if r.shadow_truth == OBJECT_FORCE:
        return "the simulated object's own force F_object"
    return f"the felt force {r.shadow_truth} (no F_object in that recording)"


def results_json(
    rows: list[Row],
    replay: dict,
    total_s: float,
    fast_rows: list[Row] | None = None,
    long_rows: list[Row] | None = None,
) -> dict:
    return {
        "total_wall_s": total_s,
        "position_replay": replay,
        "fast_hand": {r.name: r.repro for r in fast_rows or []},
        "long_session": {
            r.name: {
                "reproduction": r.repro,
                "felt_by_press": (
                    None if r.by_press is None else [nan_to_none(v) for v in r.by_press]
                ),
            }
            for r in long_rows or []
        },
        "models": {
            r.name: {
                "how": r.how,
                "reproduction": r.repro,
                "prediction_along_real": r.shadow,
                "felt_by_hand_phase": r.by_phase,
                "prediction_along_real_against": r.shadow_truth if r.shadow else None,
                "served": r.run.served,
                "fallbacks": r.run.fallbacks,
                "saturated": r.run.saturated,
                "refused": r.run.rejected,
                "flags": run_flags(r, rows),
                "stop": r.run.stop,
                "note": r.run.note,
                "wall_s": r.run.wall_s,
            }
            for r in rows
        },
    }
