"""The reproduction study of the thesis (sections 6.4.3 and 6.4.4) on the simulated bench.

The same simulated hand (rt-loop's `[hand]`, a press-hold-release programme) presses

- the simulated real sponge through a transparent motor (`shadow`): the reference felt force;
- the virtual sponge rendered by each served ONNX model (`reproduction --model shm` beside
  `infer-server serve`), and by rt-loop's built-in spring-damper.

"Felt force" is the recording's `F_true`: in reproduction and shadow it is the force the
simulated hand pushes with (docs/rt-loop.md), the same quantity on both sides. Both runs use
the lockstep clock and the same seed, so the hand's programme and the loop's time grid are the
same; the felt forces are compared at the reference's time stamps (R2, MAE, MSE, RMSE).

Beside it, the thesis's own 6.4.4 comparison: the model predicting along the real interaction
(`shadow --model shm`: F_pred, built from the model's own previous predictions, against the
felt force F_true), and the position-replay validation of 6.4.3: a recorded trajectory replayed
with the position PID on the simulated sponge, its force against the recording's.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from .metrics import regression_metrics

#: Thesis Table 6.18 (position-replay validation) and Table 6.19 (reproduction).
THESIS_REPLAY = {"r2": 0.95, "mae": 0.42, "mse": 0.33, "rmse": 0.57}
THESIS_REPRO_RF = {"r2": 0.76, "mae": 0.84, "mse": 1.46, "rmse": 1.21}
THESIS_REPRO_SD = {"r2": -71.58, "mae": 8.71, "mse": 438.83, "rmse": 20.95}
GOAL_RMSE = 1.21
GOAL_RATIO = 10.0
SPRING_DAMPERS = ("sd_const", "sd_poly1", "sd_poly2")

#: The study's hand: three presses to 28, 31 and 34 mm set-points, 9.5 s of loop time.
STUDY_HAND = {
    "stiffness": 1500.0,
    "damping": 15.0,
    "depth_m": 0.028,
    "depth_step_m": 0.003,
    "press_s": 1.0,
    "hold_s": 0.5,
    "release_s": 1.0,
    "rest_s": 0.5,
    "repeats": 3,
}

#: The sensitivity run: the same depths, pressed and released 2.5 times faster.
FAST_HAND = {**STUDY_HAND, "press_s": 0.4, "release_s": 0.4}
FAST_BEST = 3
BUILTIN = "rt-loop builtin spring-damper"
#: rt-loop's oracle model: the material's own physics driven by the measured motion, rendered
#: through the same force loop: the rendering floor no learned model can beat.
ORACLE = "oracle"
DEFAULT_MATERIAL = "materials/sponge.toml"
#: docs/fidelity.json keys the study fills (the pipeline fills the others).
FIDELITY_KEYS = ("oracle_felt_rmse_n", "sd_poly2_felt_rmse_n", "felt_rmse_n", "felt_fast_rmse_n")

SERIES = ("time", "position_x", "F_true", "F_pred", "rtob_force", "fallback")


class StudyError(RuntimeError):
    """A step of the study that cannot run, with the reason."""


# ---------------------------------------------------------------------------------------------
# alignment and metrics (pure; tested on synthetic data)


def align(
    t_ref: np.ndarray, t_run: np.ndarray, y_run: np.ndarray, tol: float = 1e-9
) -> tuple[np.ndarray, np.ndarray]:
    """`y_run` at the reference's time stamps, and the mask of reference samples it covers.

    Both series start at their own t[0] (lockstep runs of the same programme start at 0). The
    run is linearly interpolated onto the reference grid; reference samples outside the run's
    time span (a run that stopped early) are not covered: they get NaN and mask False, so a
    short run cannot be scored on data it never produced.
    """
    t_ref = np.asarray(t_ref, dtype=np.float64) - float(t_ref[0])
    t_run = np.asarray(t_run, dtype=np.float64) - float(t_run[0])
    y_run = np.asarray(y_run, dtype=np.float64)
    if t_run.shape != y_run.shape or t_run.size < 2:
        raise ValueError("a run needs at least two (time, value) samples of equal length")
    if np.any(np.diff(t_run) < 0):
        raise ValueError("run time must be non-decreasing")
    covered = (t_ref >= t_run[0] - tol) & (t_ref <= t_run[-1] + tol)
    out = np.full(t_ref.shape, np.nan)
    out[covered] = np.interp(t_ref[covered], t_run, y_run)
    return out, covered


def compare(
    t_ref: np.ndarray, f_ref: np.ndarray, t_run: np.ndarray, f_run: np.ndarray
) -> dict[str, float]:
    """R2/MAE/MSE/RMSE of a run's force against the reference force, aligned by time, plus
    `coverage`: the fraction of the reference's duration the run covered."""
    y_run, covered = align(t_ref, t_run, f_run)
    if not covered.any():
        raise ValueError("the run covers none of the reference's time span")
    m = regression_metrics(np.asarray(f_ref, dtype=np.float64)[covered], y_run[covered])
    m["coverage"] = float(covered.mean())
    return m


def ratio(sd_rmse: float, best_rmse: float) -> float:
    """How many times closer to the reference the best model is than the spring-damper."""
    if not (math.isfinite(sd_rmse) and math.isfinite(best_rmse)) or best_rmse <= 0:
        return float("nan")
    return sd_rmse / best_rmse


# ---------------------------------------------------------------------------------------------
# running the processes


@dataclass
class Tools:
    rt_loop: Path
    infer_server: Path
    env: dict[str, str]


@dataclass
class Run:
    """One rt-loop run of the study and what came of it."""

    name: str
    kind: str  # reference | reproduction | shadow | replay
    path: Path
    ok: bool
    stop: str = ""
    wall_s: float = 0.0
    steps: int = 0
    served: int = 0
    fallbacks: int = 0
    note: str = ""
    series: dict[str, np.ndarray] = field(default_factory=dict)


def find_tools(root: Path, rt_loop: str | None, infer_server: str | None) -> Tools:
    def pick(given: str | None, name: str) -> Path:
        p = Path(given) if given else root / "target" / "release" / name
        if not p.is_file():
            raise StudyError(f"{p} not found: build it with `cargo build --release -p {name}`")
        return p

    env = dict(os.environ)
    ort = root / ".ort" / "libonnxruntime.so"
    if "ORT_DYLIB_PATH" not in env and ort.is_file():
        env["ORT_DYLIB_PATH"] = str(ort)
    return Tools(pick(rt_loop, "rt-loop"), pick(infer_server, "infer-server"), env)


def read_series(path: Path, columns: tuple[str, ...] = SERIES) -> dict[str, np.ndarray]:
    table = pq.read_table(path, columns=list(columns))
    return {c: np.asarray(table.column(c), dtype=np.float64) for c in columns}


def write_config(path: Path, seed: int, hand: dict[str, float], clock: str = "lockstep") -> None:
    lines = [f"seed = {seed}", f'clock = "{clock}"', "", "[hand]"]
    lines += [f"{k} = {v}" for k, v in hand.items()]
    path.write_text("\n".join(lines) + "\n")


def _summary(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def run_loop(
    tools: Tools,
    name: str,
    kind: str,
    args: list[str],
    out: Path,
    server_model: Path | None = None,
    instance: str = "",
    timeout_s: float = 300.0,
) -> Run:
    """rt-loop run ARGS --record OUT (and, for a served model, infer-server beside it)."""
    summary = out.with_suffix(".summary.json")
    for p in (out, summary):
        p.unlink(missing_ok=True)
    cmd = [str(tools.rt_loop), "run", *args, "--record", str(out), "--overwrite"]
    cmd += ["--no-progress", "--summary-json", str(summary)]
    server: subprocess.Popen[str] | None = None
    t0 = time.perf_counter()
    if server_model is not None:
        srv_cmd = [str(tools.infer_server), "serve", "--model", str(server_model)]
        srv_cmd += ["--instance", instance, "--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0"]
        srv_cmd += ["--wait", "park", "--exit-when-loop-gone"]
        server = subprocess.Popen(
            srv_cmd,
            env=tools.env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        cmd += ["--model", "shm", "--instance", instance, "--server-wait-s", "20"]
    loop = subprocess.Popen(
        cmd, env=tools.env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    note = ""
    try:
        while loop.poll() is None:
            if server is not None and server.poll() not in (None, 0):
                # The server refused the model (it validates at start): the loop would only
                # wait for a server that never comes.
                loop.terminate()
                note = "infer-server refused the model: " + _last_line(server.stderr)
                break
            if time.perf_counter() - t0 > timeout_s:
                loop.terminate()
                note = f"timed out after {timeout_s:.0f} s"
                break
            time.sleep(0.02)
        loop_err = loop.communicate(timeout=30)[1]
    finally:
        if server is not None:
            try:
                server.wait(timeout=10)
            except subprocess.TimeoutExpired:
                server.terminate()
                server.wait(timeout=10)
    wall = time.perf_counter() - t0
    if not note and loop.returncode != 0 and server is not None and server.returncode:
        # The server refused the model after attaching: the loop saw it go away first.
        note = "infer-server refused the model: " + _last_line(server.stderr)
    s = _summary(summary)
    model = s.get("model") or {}
    run = Run(
        name=name,
        kind=kind,
        path=out,
        ok=loop.returncode == 0 and out.is_file(),
        stop=str(s.get("stop", "")),
        wall_s=wall,
        steps=int(s.get("steps", 0) or 0),
        served=int(model.get("served", 0) or 0),
        fallbacks=int(model.get("fallbacks", 0) or 0),
        note=note,
    )
    if not run.note and loop.returncode != 0:
        # An aborted run (e.g. position-limit) says why in its summary's stop reason.
        run.note = f"rt-loop exit {loop.returncode}"
        if not run.stop:
            run.note += ": " + _last_line_text(loop_err)
    if out.is_file():
        run.series = read_series(out)
    return run


def _last_line(stream: object) -> str:
    try:
        text = stream.read() if stream is not None else ""  # type: ignore[attr-defined]
    except (OSError, ValueError):
        text = ""
    return _last_line_text(text)


def _last_line_text(text: str) -> str:
    lines = [ln.strip() for ln in (text or "").splitlines() if ln.strip()]
    return lines[-1][:300] if lines else ""


# ---------------------------------------------------------------------------------------------
# the study


@dataclass
class Row:
    name: str
    how: str  # "served (ONNX)" / "rt-loop builtin"
    repro: dict[str, float] | None
    shadow: dict[str, float] | None
    run: Run
    shadow_run: Run | None
    learned: bool


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


def _fmt(v: float | None, nd: int = 3) -> str:
    if v is None or not math.isfinite(v):
        return "-"
    return f"{v:.{nd}f}"


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
) -> Path:
    """The study. With `bench` (a bench file of `rt-loop identify-friction`) every reproduction
    runs twice: without friction compensation and with it (`--bench`, in the reference too),
    the latter with the models of `bench_models_dir` (trained on recordings made with the same
    bench file) when given. `headline` picks the setting of the goal lines, the plots, the fast
    hand, the position replay and docs/fidelity.json: `off` (default) is how the product renders
    today (no bench file in scripts/up.sh), `on` the compensated setting."""
    t_start = time.perf_counter()
    tools = find_tools(root, rt_loop, infer_server)
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
    settings: dict[str, tuple[Run, list[Row]]] = {}
    settings["off"] = _reproduce_all(
        tools, files, work, "", STUDY_HAND, seed, shadow_predictions, say, common, clock
    )
    primary = headline
    extra = common
    if bench is not None:
        extra_on = [*common, "--bench", str(bench)]
        files_on = study_models(bench_models_dir, names) if bench_models_dir else files
        settings["on"] = _reproduce_all(
            tools, files_on, work, "fc_", STUDY_HAND, seed, shadow_predictions, say, extra_on, clock
        )
        if primary == "on":
            extra, files = extra_on, files_on
    ref, rows = settings[primary]

    # The same presses, 2.5 times faster, for the best learned models, the spring-dampers and
    # the oracle (in the headline setting).
    ranked = sorted((r for r in rows if r.learned and _rankable(r)), key=_rmse)
    keep = {r.name for r in ranked[:FAST_BEST]} | set(SPRING_DAMPERS)
    fast_files = [f for f in files if f.stem in keep]
    fast_ref, fast_rows = _reproduce_all(
        tools, fast_files, work, "fast_", FAST_HAND, seed, False, say, extra, clock
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

    results = _load_results(models_dir)
    total = time.perf_counter() - t_start
    _plots(out_dir, ref, rows, rec, rep_s)
    setup = {
        "material": str(material),
        "bench": str(bench) if bench else None,
        "clock": clock,
        "headline": primary,
    }
    readme = _write_readme(
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
    )
    doc = _json(rows, replay, total, fast_rows)
    doc["setup"] = setup
    doc["friction"] = {k: _floor_summary(v[1]) for k, v in settings.items()}
    (out_dir / "results.json").write_text(json.dumps(doc, indent=1))
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
) -> tuple[Run, list[Row]]:
    """The reference (shadow on the simulated object), the oracle, then every model's
    reproduction (and, optionally, its prediction along the real interaction), then the
    builtin spring-damper, all with the same hand programme, seed, material and bench file
    (`extra`: rt-loop flags)."""
    cfg = work / f"{tag}hand.toml"
    write_config(cfg, seed, hand, clock)
    base = ["--config", str(cfg), "--clock", clock, "--seed", str(seed), *(extra or [])]
    ref = run_loop(
        tools,
        "sponge",
        "reference",
        [*base, "--experiment", "shadow"],
        work / f"{tag}reference.parquet",
    )
    if not ref.ok:
        raise StudyError(f"the reference (shadow) run failed: {ref.note or ref.stop}")
    say(f"{tag}reference: simulated sponge, {ref.steps} steps in {ref.wall_s:.1f} s")
    t_ref, f_ref = ref.series["time"], ref.series["F_true"]
    rows: list[Row] = []
    o = run_loop(
        tools,
        ORACLE,
        "reproduction",
        [*base, "--experiment", "reproduction", "--model", "oracle"],
        work / f"{tag}repro_oracle.parquet",
    )
    ro = _score(t_ref, f_ref, o)
    rows.append(Row(o.name, "rt-loop oracle", ro, None, o, None, False))
    say(f"{tag}oracle: felt-force RMSE {_fmt(ro['rmse'] if ro else None)} N (the floor)")
    pid = os.getpid()
    for f in files:
        name = f.stem
        inst = f"study-{pid}-{name}"
        r = run_loop(
            tools,
            name,
            "reproduction",
            [*base, "--experiment", "reproduction"],
            work / f"{tag}repro_{name}.parquet",
            server_model=f.resolve(),
            instance=inst,
        )
        repro = _score(t_ref, f_ref, r)
        sh = None
        sh_m = None
        if shadow_predictions and r.series:
            sh = run_loop(
                tools,
                name,
                "shadow",
                [*base, "--experiment", "shadow"],
                work / f"{tag}shadow_{name}.parquet",
                server_model=f.resolve(),
                instance=inst,
            )
            if sh.series and sh.served > 0:
                sh_m = regression_metrics(sh.series["F_true"], sh.series["F_pred"])
        learned = name not in SPRING_DAMPERS
        rows.append(Row(name, "served ONNX", repro, sh_m, r, sh, learned=learned))
        say(
            f"{tag}{name}: felt-force RMSE {_fmt(repro['rmse'] if repro else None)} N, "
            f"{r.served} served / {r.fallbacks} fallbacks, stop {r.stop or '-'}, "
            f"{r.wall_s:.1f} s {r.note}"
        )
    b = run_loop(
        tools,
        BUILTIN,
        "reproduction",
        [*base, "--experiment", "reproduction"],
        work / f"{tag}repro_builtin.parquet",
    )
    rb = _score(t_ref, f_ref, b)
    rows.append(Row(b.name, "rt-loop builtin", rb, None, b, None, False))
    say(f"{tag}builtin spring-damper: felt-force RMSE {_fmt(rb['rmse'] if rb else None)} N")
    return ref, rows


def _rmse(r: Row) -> float:
    return r.repro["rmse"] if r.repro else math.inf


def _score(t_ref: np.ndarray, f_ref: np.ndarray, r: Run) -> dict[str, float] | None:
    if not r.series or r.steps == 0:
        return None
    return compare(t_ref, f_ref, r.series["time"], r.series["F_true"])


def _load_results(models_dir: Path) -> dict:
    try:
        return json.loads((models_dir / "results.json").read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def _offline(results: dict, name: str) -> str:
    """`one-step / closed-loop` test RMSE of docs/report for a model, '-' if not evaluated."""
    res = results.get(name) if isinstance(results, dict) else None
    tests = res.get("test") if isinstance(res, dict) else None
    if not isinstance(tests, list) or not tests or not isinstance(tests[0], dict):
        return "-"
    one = (tests[0].get("one_step") or {}).get("rmse")
    cl = (tests[0].get("closed_loop") or {}).get("rmse")
    return f"{_fmt(one)} / {_fmt(cl)}"


def _rankable(r: Row) -> bool:
    return (
        r.repro is not None
        and r.run.ok
        and r.repro["coverage"] > 0.999
        and math.isfinite(r.repro["rmse"])
    )


def _best(rows: list[Row], learned: bool, key: str = "repro") -> Row | None:
    cand = [r for r in rows if r.learned == learned and _rankable(r) and getattr(r, key)]
    if not cand:
        return None
    return min(cand, key=lambda r: getattr(r, key)["rmse"])


def _sd2(rows: list[Row]) -> Row | None:
    return next((r for r in rows if r.name == "sd_poly2"), None)


def _named(rows: list[Row], name: str) -> Row | None:
    return next((r for r in rows if r.name == name), None)


def _felt(r: Row | None) -> float:
    return r.repro["rmse"] if r is not None and r.repro and _rankable(r) else math.nan


def _floor_summary(rows: list[Row]) -> dict[str, object]:
    """Felt-force RMSE of the oracle (floor), sd_poly2, the builtin and the best learned model
    of one friction setting."""
    best = _best(rows, True)
    return {
        "oracle_felt_rmse_n": _felt(_named(rows, ORACLE)),
        "sd_poly2_felt_rmse_n": _felt(_sd2(rows)),
        "builtin_felt_rmse_n": _felt(_named(rows, BUILTIN)),
        "best_learned": best.name if best else None,
        "best_learned_felt_rmse_n": _felt(best),
        "models": {r.name: _felt(r) for r in rows},
    }


def _nan_to_none(v: float) -> float | None:
    return v if math.isfinite(v) else None


def write_fidelity(path: Path, rows: list[Row], fast_rows: list[Row], setting: str = "off") -> dict:
    """Merges the study's keys into docs/fidelity.json (the pipeline writes the others):
    the oracle's and sd_poly2's felt force, and the felt force (normal and fast hand) of the
    recommended model when the pipeline has named one (`recommended`) and it was in the study,
    else of the best learned model (`felt_model` says which)."""
    try:
        doc = json.loads(path.read_text())
        if not isinstance(doc, dict):
            doc = {}
    except (OSError, json.JSONDecodeError):
        doc = {}
    rec = doc.get("recommended")
    model = _named(rows, rec) if isinstance(rec, str) else None
    if model is None or not _rankable(model):
        model = _best(rows, True)
    fast = _named(fast_rows, model.name) if model is not None else None
    doc["oracle_felt_rmse_n"] = _nan_to_none(_felt(_named(rows, ORACLE)))
    doc["sd_poly2_felt_rmse_n"] = _nan_to_none(_felt(_sd2(rows)))
    doc["felt_rmse_n"] = _nan_to_none(_felt(model))
    doc["felt_fast_rmse_n"] = _nan_to_none(_felt(fast))
    doc["felt_model"] = model.name if model is not None else None
    doc["felt_friction_compensation"] = setting
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1) + "\n")
    return doc


# ---------------------------------------------------------------------------------------------
# plots and report


def _plots(out: Path, ref: Run, rows: list[Row], rec: dict, rep: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ranked = sorted((r for r in rows if r.learned and _rankable(r)), key=_rmse)
    show = ranked[:3]
    sd2 = _sd2(rows)
    if sd2 is not None and sd2.run.series:
        show.append(sd2)
    rs = ref.series
    fig, ax = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    ax[0].plot(rs["time"], rs["F_true"], "k", lw=1.6, label="simulated sponge (reference)")
    for r in show:
        s = r.run.series
        ax[0].plot(s["time"], s["F_true"], lw=0.9, label=f"{r.name} (RMSE {r.repro['rmse']:.2f} N)")  # type: ignore[index]
    ax[0].set_ylabel("felt force F_true [N]")
    ax[0].legend(fontsize=8)
    ax[0].grid(alpha=0.3)
    ax[1].plot(rs["time"], 1000 * rs["position_x"], "k", lw=1.6, label="simulated sponge")
    for r in show:
        s = r.run.series
        ax[1].plot(s["time"], 1000 * s["position_x"], lw=0.9, label=r.name)
    ax[1].set_xlabel("time [s]")
    ax[1].set_ylabel("depth x [mm]")
    ax[1].grid(alpha=0.3)
    fig.suptitle(
        "the same simulated hand on the simulated sponge and on virtual sponges", fontsize=10
    )
    fig.tight_layout()
    fig.savefig(out / "felt_force_time.png", dpi=90)
    plt.close(fig)

    n = len(show)
    fig, ax = plt.subplots(1, max(n, 1), figsize=(4.2 * max(n, 1), 4), sharey=True, squeeze=False)
    for i, r in enumerate(show):
        a = ax[0][i]
        a.plot(1000 * rs["position_x"], rs["F_true"], "k", lw=1.2, label="simulated sponge")
        s = r.run.series
        a.plot(1000 * s["position_x"], s["F_true"], "tab:red", lw=0.9, label=r.name)
        a.set_xlabel("depth x [mm]")
        a.set_title(r.name, fontsize=9)
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    ax[0][0].set_ylabel("felt force F_true [N]")
    fig.tight_layout()
    fig.savefig(out / "felt_force_depth.png", dpi=90)
    plt.close(fig)

    ok = sorted((r for r in rows if r.repro is not None), key=_rmse)
    fig, ax = plt.subplots(figsize=(10, 4))
    names = [r.name.replace("rt-loop builtin spring-damper", "builtin sd") for r in ok]
    vals = [min(r.repro["rmse"], 10.0) for r in ok]  # type: ignore[index]
    colors = ["tab:blue" if r.learned else "tab:gray" for r in ok]
    ax.bar(names, vals, color=colors)
    ax.axhline(GOAL_RMSE, color="tab:red", ls="--", lw=1, label="thesis RF 1.21 N")
    ax.set_ylabel("felt-force RMSE vs simulated sponge [N]")
    ax.tick_params(axis="x", rotation=60, labelsize=8)
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "rmse.png", dpi=90)
    plt.close(fig)

    fig, ax = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    ax[0].plot(rec["time"], rec["rtob_force"], "k", lw=1.0, label="recording (force control)")
    ax[0].plot(
        rep["time"],
        rep["rtob_force"],
        "tab:red",
        lw=0.7,
        label="position replay on the simulated sponge",
    )
    ax[0].set_ylabel("force response F_res [N]")
    ax[0].legend(fontsize=8)
    ax[0].grid(alpha=0.3)
    ax[1].plot(rec["time"], 1000 * rec["position_x"], "k", lw=1.0, label="recording")
    ax[1].plot(rep["time"], 1000 * rep["position_x"], "tab:red", lw=0.7, label="replay")
    ax[1].set_xlabel("time [s]")
    ax[1].set_ylabel("depth x [mm]")
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "position_replay.png", dpi=80)
    plt.close(fig)


def _metric_cells(m: dict[str, float] | None) -> list[str]:
    if m is None:
        return ["-", "-", "-", "-"]
    return [_fmt(m["r2"]), _fmt(m["mae"]), _fmt(m["mse"]), _fmt(m["rmse"])]


def _write_readme(
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
) -> Path:
    setup = setup or {"material": DEFAULT_MATERIAL, "bench": None, "clock": "lockstep"}
    best = _best(rows, True)
    sd2 = _sd2(rows)
    sd2_rmse = sd2.repro["rmse"] if sd2 and sd2.repro else float("nan")
    best_rmse = best.repro["rmse"] if best and best.repro else float("nan")
    k = ratio(sd2_rmse, best_rmse)
    met_rmse = best_rmse <= GOAL_RMSE
    met_ratio = math.isfinite(k) and k >= GOAL_RATIO
    h = STUDY_HAND
    dur = h["rest_s"] + h["repeats"] * (h["press_s"] + h["hold_s"] + h["release_s"] + h["rest_s"])
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
        "- **Reference**: `shadow`, the hand presses the simulated object "
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
        f"`{best.name if best else '-'}`: RMSE {_fmt(best_rmse)} N, "
        f"R2 {_fmt(best.repro['r2'] if best and best.repro else None)} |\n"
        "| 2nd-order spring-damper | RMSE 20.95 N, R2 -71.58 | "
        f"`sd_poly2`: RMSE {_fmt(sd2_rmse)} N, "
        f"R2 {_fmt(sd2.repro['r2'] if sd2 and sd2.repro else None)} |\n"
        f"| spring-damper RMSE / best RMSE | 17.3x | {_fmt(k, 2)}x |\n"
    )
    L.append(
        f"- Best learned model at or below 1.21 N RMSE: **{'met' if met_rmse else 'not met'}** "
        f"({_fmt(best_rmse)} N).\n"
        f"- At least ten times closer than the 2nd-order spring-damper: "
        f"**{'met' if met_ratio else 'not met'}** ({_fmt(k, 2)}x).\n"
    )
    pb = _best(rows, True, key="shadow")
    if pb is not None and pb.shadow is not None and sd2 is not None and sd2.shadow is not None:
        L.append(
            "The thesis's Table 6.19 itself compared the forces *predicted* along a real "
            "interaction (model and spring-damper) with the measured one. The same here "
            "(`pred along real` below: each model fed the hand-on-sponge run, F_pred vs the "
            f"felt force): best learned `{pb.name}` RMSE {_fmt(pb.shadow['rmse'])} N "
            f"(R2 {_fmt(pb.shadow['r2'])}), `sd_poly2` {_fmt(sd2.shadow['rmse'])} N "
            f"(R2 {_fmt(sd2.shadow['r2'])}): "
            f"{_fmt(ratio(sd2.shadow['rmse'], pb.shadow['rmse']), 2)}x.\n"
        )
    fast_note = "not run."
    if fast_rows:
        fb, fsd = _best(fast_rows, True), _sd2(fast_rows)
        if fb and fsd and fb.repro and fsd.repro:
            fast_note = (
                f"{_fmt(ratio(fsd.repro['rmse'], fb.repro['rmse']), 2)}x (sensitivity run below)."
            )
    L.extend(_floor_section(settings or {}, setup, fast_note))
    L.append("## Felt force: every served model against the simulated sponge\n")
    L.append(
        "`repro` = reproduction (the hand on the virtual sponge) vs the reference's felt force. "
        "`pred along real` = the thesis's own 6.4.4 comparison: `shadow --model shm`, the model "
        "predicting along the real interaction from its own previous predictions, F_pred vs "
        "the felt force F_true of that run. `one-step` / `closed-loop` = the offline "
        "test-set RMSE of docs/report (held-out 2.1 N/s ramps). Wall = seconds for the "
        "reproduction run (both processes, start to end).\n"
    )
    L.append(
        "| model | how | repro R2 | repro MAE | repro MSE | repro RMSE | pred along real RMSE "
        "| pred along real R2 | offline one-step / closed-loop RMSE | served / fallbacks "
        "| stop | wall s |"
    )
    L.append("|---|---|---|---|---|---|---|---|---|---|---|---|")
    order = sorted(rows, key=lambda r: (not _rankable(r), r.repro["rmse"] if r.repro else math.inf))
    for r in order:
        off = _offline(results, r.name)
        stop = r.run.stop or "-"
        if r.repro is not None and r.repro["coverage"] < 0.999:
            stop += f" (covers {100 * r.repro['coverage']:.0f} %)"
        if r.run.note:
            stop += f": {r.run.note}"
        L.append(
            f"| `{r.name}` | {r.how} | " + " | ".join(_metric_cells(r.repro)) + " | "
            f"{_fmt(r.shadow['rmse'] if r.shadow else None)} | "
            f"{_fmt(r.shadow['r2'] if r.shadow else None)} | {off} | "
            f"{r.run.served} / {r.run.fallbacks} | {stop} | {r.run.wall_s:.1f} |"
        )
    L.append("")
    L.append("![felt-force RMSE per model](rmse.png)\n")
    L.append(
        "The best three learned models and `sd_poly2` against the simulated sponge, over "
        "time (felt force and depth):\n"
    )
    L.append("![felt force over time](felt_force_time.png)\n")
    L.append("and over depth (felt force against the probe's depth):\n")
    L.append("![felt force over depth](felt_force_depth.png)\n")

    rf = replay["rtob_force"]
    tf = replay["F_true"]
    px = replay["position_x"]
    L.append("## Position-replay validation (thesis 6.4.3, Table 6.18)\n")
    L.append(
        f"The held-out recording `{trajectory.name}` (force-controlled ramps at 2.1 N/s, "
        f"14 cycles) gives the position reference; `rt-loop run --experiment position-replay` "
        "follows it with the thesis's PID (C_p 700, C_d 12, C_i 1000, current = PID M_n/K_fn, "
        f"plus the DOB estimate) on the simulated sponge, from a fresh sponge as the recording "
        f"started: {rep.steps} steps in {rep.wall_s:.1f} s of wall time. The force response "
        "(RFOB estimate, what the thesis measured) and the true contact force of the replay are "
        "compared with the recording's at the same time.\n"
    )
    L.append("| quantity | R2 | MAE | MSE | RMSE |\n|---|---|---|---|---|")
    L.append("| thesis Table 6.18 (force response) | 0.95 | 0.42 | 0.33 | 0.57 |")
    L.append("| force response F_res (RFOB) | " + " | ".join(_metric_cells(rf)) + " |")
    L.append("| true contact force F_true | " + " | ".join(_metric_cells(tf)) + " |")
    L.append(
        f"| depth x (mm) | {_fmt(px['r2'])} | {_fmt(1000 * px['mae'])} | - | "
        f"{_fmt(1000 * px['rmse'])} |\n"
    )
    L.append(
        f"Depth tracking {_fmt(1000 * px['rmse'])} mm RMS; force response (RFOB) RMSE "
        f"{_fmt(rf['rmse'])} N against the true contact force's {_fmt(tf['rmse'])} N. The "
        "models' predictions along this same trajectory (closed loop, each fed its own "
        "previous predictions) are in docs/report/README.md.\n"
    )
    L.append("![position replay](position_replay.png)\n")
    if fast_ref is not None and fast_rows:
        fh = FAST_HAND
        L.append("## Sensitivity: a faster hand (not part of the goal)\n")
        L.append(
            f"The same three presses with press and release in {fh['press_s']} s instead of "
            f"{h['press_s']} s (the reference re-run with that hand too), for the "
            f"{FAST_BEST} best learned models above and the spring-dampers. Reported whatever "
            "it shows. Fallbacks are steps whose served force was refused (beyond "
            "`reproduction.max_force_n`, late or missing): the loop rendered its built-in "
            "fallback instead.\n"
        )
        L.append("| model | R2 | MAE | MSE | RMSE | served / fallbacks | stop |")
        L.append("|---|---|---|---|---|---|---|")
        for r in sorted(fast_rows, key=lambda r: (not _rankable(r), _rmse(r))):
            L.append(
                f"| `{r.name}` | " + " | ".join(_metric_cells(r.repro)) + " | "
                f"{r.run.served} / {r.run.fallbacks} | {r.run.stop or '-'} {r.run.note} |"
            )
        fb = _best(fast_rows, True)
        fsd = _sd2(fast_rows)
        if fb and fsd and fb.repro and fsd.repro:
            L.append(
                f"\nFaster hand: best learned `{fb.name}` {_fmt(fb.repro['rmse'])} N, "
                f"`sd_poly2` {_fmt(fsd.repro['rmse'])} N: "
                f"{_fmt(ratio(fsd.repro['rmse'], fb.repro['rmse']), 2)}x.\n"
            )
        else:
            L.append("")
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


def _floor_section(
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
    L.append("| setting | oracle (floor) | sd_poly2 | builtin | best learned | best / oracle |")
    L.append("|---|---|---|---|---|---|")
    for key, (_, rows) in settings.items():
        f = _floor_summary(rows)
        o, b = float(f["oracle_felt_rmse_n"]), float(f["best_learned_felt_rmse_n"])  # type: ignore[arg-type]
        L.append(
            f"| {key} | {_fmt(o)} | {_fmt(float(f['sd_poly2_felt_rmse_n']))} | "  # type: ignore[arg-type]
            f"{_fmt(float(f['builtin_felt_rmse_n']))} | "  # type: ignore[arg-type]
            f"{'`' + str(f['best_learned']) + '` ' if f['best_learned'] else ''}{_fmt(b)} | "
            f"{_fmt(b / o if o > 0 else math.nan, 2)}x |"
        )
    L.append("")
    for key, (_, rows) in settings.items():
        o = _felt(_named(rows, ORACLE))
        sd = _felt(_sd2(rows))
        if math.isfinite(o) and math.isfinite(sd) and o > 0:
            L.append(
                f"- `{key}`: sd_poly2 renders {_fmt(sd / o, 1)}x the floor's error; a model "
                f"at the floor would be {_fmt(sd / o, 1)}x closer than sd_poly2.\n"
            )
    L.append(f"- Faster hand, best learned vs sd_poly2: {fast_note}\n")
    head = settings.get(str(setup.get("headline", "off"))) or next(iter(settings.values()))
    o, b = _felt(_named(head[1], ORACLE)), _felt(_best(head[1], True))
    on = settings.get("on")
    floor_on = _felt(_named(on[1], ORACLE)) if on else math.nan

    def met(ok: bool) -> str:
        return "**met**" if ok else "**not met**"

    L.append("Issue 11 goals (felt force, the headline setting):\n")
    L.append(f"- Best learned at most 0.20 N: {met(b <= 0.20)} ({_fmt(b)} N).\n")
    L.append(
        f"- Within 1.5x of the oracle's floor: {met(o > 0 and b / o <= 1.5)} "
        f"({_fmt(b / o if o > 0 else math.nan, 2)}x).\n"
    )
    L.append(
        f"- Floor at most 0.10 N with friction compensated: {met(floor_on <= 0.10)} "
        f"({_fmt(floor_on)} N{'' if on else ', no bench file given'}).\n"
    )
    return L


def _json(
    rows: list[Row], replay: dict, total_s: float, fast_rows: list[Row] | None = None
) -> dict:
    return {
        "total_wall_s": total_s,
        "position_replay": replay,
        "fast_hand": {r.name: r.repro for r in fast_rows or []},
        "models": {
            r.name: {
                "how": r.how,
                "reproduction": r.repro,
                "prediction_along_real": r.shadow,
                "served": r.run.served,
                "fallbacks": r.run.fallbacks,
                "stop": r.run.stop,
                "note": r.run.note,
                "wall_s": r.run.wall_s,
            }
            for r in rows
        },
    }


def clean_work(work: Path) -> None:
    """Removes the study's raw recordings (kept by default for inspection)."""
    if work.is_dir():
        shutil.rmtree(work)
