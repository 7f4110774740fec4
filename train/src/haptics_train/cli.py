"""Command line of haptics-train: analyze, train, evaluate, ood, export, report, import,
validate, pipeline, study, presses. Run from the repository root (default paths are relative
to it)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from .data import DataError, Dataset, load_data
from .features import FEATURE_SETS
from .holds import HOLDS_ALGOS, HOLDS_SPEC
from .importer import DEFAULT_MAX_GAP_FACTOR, FORCE_UNITS, POSITION_UNITS, TIME_UNITS
from .models import ALGOS, TrainConfig
from .pipeline import DEFAULT_SPECS
from .presses import DEFAULT_SEED

DEFAULT_DATASET = "data/dataset"
DEFAULT_MODELS = "models"
DEFAULT_REPORT = "docs/report"


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--dataset",
        default=DEFAULT_DATASET,
        help="folder with train_*.parquet, validation_*.parquet (optional) and test_*.parquet "
        "(default %(default)s)",
    )
    p.add_argument(
        "--manifest",
        help="TOML dataset manifest naming each recording with its role (train, validation, "
        "test), source and notes; replaces --dataset (docs/train.md)",
    )
    p.add_argument("--models-dir", default=DEFAULT_MODELS, help="default %(default)s")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def _data(a: argparse.Namespace) -> Dataset:
    return load_data(a.dataset, getattr(a, "manifest", None))


def _rows_opts(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--decimate",
        type=int,
        help="keep every Nth control step for stateless training (default: derived per "
        "recording from its rate and --target-rate-hz)",
    )
    p.add_argument(
        "--target-rate-hz",
        type=float,
        default=500.0,
        help="row rate stateless models train at when --decimate is not given (default "
        "%(default)s: every 20th step of the 10 kHz bench, every row of a 50 Hz import)",
    )


def _train_opts(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--models",
        default=",".join(DEFAULT_SPECS),
        help="comma-separated ALGO[:FEATURESET] specs; algorithms: "
        f"{', '.join(ALGOS)}; feature sets: {', '.join(FEATURE_SETS)}; "
        f"{', '.join(HOLDS_ALGOS)} also as ALGO{HOLDS_SPEC}: trained on the dataset's "
        "press-and-hold recordings too, named ALGO_holds (holds.py) "
        "(default: the full comparison)",
    )
    p.add_argument(
        "--preset",
        choices=("default", "thesis"),
        default="default",
        help="thesis = the thesis's hyperparameters (docs/physics.md, 'What the thesis reports')",
    )
    _rows_opts(p)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--target", default="rtob_force")
    p.add_argument("--rf-trees", type=int)
    p.add_argument("--rf-depth", type=int)
    p.add_argument("--svr-rows", type=int, help="SVR training subsample (default 5000)")
    p.add_argument("--dnn-epochs", type=int)
    p.add_argument("--lstm-iterations", type=int)
    p.add_argument(
        "--lstm-horizon-s",
        type=float,
        help="LSTM truncated-BPTT window in seconds (default 1.0, capped at 50 steps)",
    )
    p.add_argument(
        "--lawfree-network-steps",
        type=int,
        help="mini-batches each of lawfree's network readouts trains for at most (default "
        "15000; 0: the network readout is not tried; lawfree_net.py)",
    )
    p.add_argument(
        "--feedback-noise",
        type=float,
        help="N, scale of the previous-force error dnn_fb/lstm_fb train with (default: "
        "--feedback-noise-frac of the training force's range)",
    )
    p.add_argument(
        "--feedback-noise-frac",
        type=float,
        help="feedback noise as a fraction of the training force's 1-99 percentile range "
        "(default 0.2)",
    )
    p.add_argument(
        "--feedback-noise-candidates",
        default="0.1,0.2,0.4",
        help="fractions of the force range tried for dnn_fb/lstm_fb, the one with the lowest "
        "free-run RMSE on the validation recordings kept (needs a validation recording; "
        "'' or an explicit --feedback-noise/--feedback-noise-frac: no search; "
        "default %(default)s)",
    )
    p.add_argument(
        "--dagger-rounds",
        type=int,
        default=0,
        help="dnn_fb: rounds of DAgger (roll out in free run on the training recordings, add "
        "the visited states labelled with the recorded force, refit); the round with the "
        "lowest validation free-run RMSE is kept (default 0: none)",
    )
    p.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch threads (default 1: on a busy 2-core machine more threads "
        "oversubscribe and run ~10x slower)",
    )


def _hyper(a: argparse.Namespace) -> dict[str, dict]:
    h: dict[str, dict] = {"rf": {}, "svr": {}, "dnn": {}, "lstm": {}}
    # (dnn_fb / lstm_fb also take the dnn / lstm entries)
    if a.rf_trees:
        h["rf"]["n_estimators"] = a.rf_trees
    if a.rf_depth:
        h["rf"]["max_depth"] = a.rf_depth
    if a.svr_rows:
        h["svr"]["max_rows"] = a.svr_rows
    if a.dnn_epochs:
        h["dnn"]["epochs"] = a.dnn_epochs
    if a.lstm_iterations:
        h["lstm"]["iterations"] = a.lstm_iterations
    if a.lstm_horizon_s:
        h["lstm"]["horizon_s"] = a.lstm_horizon_s
    if a.lawfree_network_steps is not None:
        if a.lawfree_network_steps < 0:
            raise SystemExit("haptics-train: --lawfree-network-steps must be >= 0")
        h["lawfree"] = {"network_steps": a.lawfree_network_steps}
    if a.feedback_noise is not None:
        h["dnn_fb"] = {"feedback_noise": a.feedback_noise, "feedback_noise_frac": None}
        h["lstm_fb"] = dict(h["dnn_fb"])
    elif a.feedback_noise_frac is not None:
        h["dnn_fb"] = {"feedback_noise_frac": a.feedback_noise_frac}
        h["lstm_fb"] = dict(h["dnn_fb"])
    if a.dagger_rounds:
        h["dnn_fb"] = {**h.get("dnn_fb", {}), "dagger_rounds": a.dagger_rounds}
    return {k: v for k, v in h.items() if v}


def _candidates(a: argparse.Namespace) -> list[float]:
    if a.feedback_noise is not None or a.feedback_noise_frac is not None:
        return []
    return [float(c) for c in a.feedback_noise_candidates.split(",") if c.strip()]


def _cfg(a: argparse.Namespace) -> TrainConfig:
    return TrainConfig(decimate=a.decimate, target=a.target, seed=a.seed,
                       progress=not a.no_progress, target_rate_hz=a.target_rate_hz)  # fmt: skip


def _names(a: argparse.Namespace) -> list[str] | None:
    return [n.strip() for n in a.names.split(",")] if getattr(a, "names", None) else None


def cmd_analyze(a: argparse.Namespace) -> None:
    from .analysis import analyze

    ds = _data(a)
    print(analyze(ds, Path(a.out), decimate=a.decimate, target_rate_hz=a.target_rate_hz))


def cmd_train(a: argparse.Namespace) -> None:
    from .pipeline import train_models

    ds = _data(a)
    specs = [s.strip() for s in a.models.split(",") if s.strip()]
    train_models(ds, specs, _cfg(a), Path(a.models_dir), a.preset, _hyper(a), _candidates(a))


def cmd_evaluate(a: argparse.Namespace) -> None:
    from .pipeline import evaluate_models, load_models

    ds = _data(a)
    models = load_models(Path(a.models_dir), _names(a))
    for _, cfg in models:
        cfg.progress = not a.no_progress
    evaluate_models(models, ds, Path(a.models_dir), closed_loop=not a.no_closed_loop,
                    fidelity=Path(a.fidelity) if a.fidelity else None)  # fmt: skip


def cmd_ood(a: argparse.Namespace) -> None:
    from .fidelity import load_recommendation
    from .ood import OOD_FILE, score_suite, write_fidelity, write_readme_section
    from .pipeline import load_models

    folder = Path(a.models_dir)
    names = _names(a)
    rec = load_recommendation(folder)
    if names is None:
        if rec is None:
            raise ValueError(f"no --names and no recommendation in {folder} (haptics-train "
                             "evaluate with a validation recording writes one)")  # fmt: skip
        names = [rec["recommended"]]
    models = load_models(folder, names)
    doc = score_suite(models, Path(a.suite), folder / OOD_FILE)
    print(f"[ood] -> {folder / OOD_FILE}")
    if a.readme:
        write_readme_section(Path(a.readme), doc, rec["recommended"] if rec else None)
        print(f"[ood] table -> {a.readme}")
    if a.fidelity and rec is not None and rec["recommended"] in doc:
        write_fidelity(doc, rec["recommended"], Path(a.fidelity))
        print(f"[ood] {rec['recommended']}: worst free-run RMSE "
              f"{doc[rec['recommended']]['worst_rmse_n']:.4g} N, "
              f"{doc[rec['recommended']]['diverged']} diverged -> {a.fidelity}")  # fmt: skip


def cmd_export(a: argparse.Namespace) -> None:
    from .pipeline import export_models, load_models

    ds = _data(a) if not a.no_parity else None
    export_models(load_models(Path(a.models_dir), _names(a)), ds, Path(a.models_dir))


def cmd_report(a: argparse.Namespace) -> None:
    from .report import write_report

    ds = _data(a)
    print(write_report(Path(a.models_dir), ds, Path(a.out)))


def cmd_import(a: argparse.Namespace) -> None:
    from .data import write_manifest_entry
    from .importer import describe_import, import_series, unit_notes

    if a.role and not a.manifest:
        raise DataError("--role needs --manifest (the manifest the recording is added to)")
    rec = import_series(
        a.input,
        a.out,
        a.time_col,
        a.position_col,
        a.force_col,
        sample_rate_hz=a.sample_rate_hz,
        time_unit=a.time_unit,
        position_unit=a.position_unit,
        force_unit=a.force_unit,
        rt_loop=a.rt_loop,
        g_v=a.g_v,
        g_a=a.g_a,
        contact_on_n=a.contact_on_n,
        contact_off_n=a.contact_off_n,
        resample_hz=a.resample_hz,
        repair=a.repair,
        max_gap_factor=a.max_gap_factor,
        compression_negative=a.compression_negative,
        overwrite=a.overwrite,
    )
    for note in unit_notes(rec):
        print(f"haptics-train import: warning: {note}", file=sys.stderr)
    print(f"{a.out}: {describe_import(rec)}")
    if a.manifest:
        name = a.name or Path(a.out).stem
        write_manifest_entry(a.manifest, name, a.out, a.role or "train",
                             a.source or str(Path(a.input).resolve()), a.notes or "")  # fmt: skip
        print(f"{a.manifest}: recordings.{name} (role {a.role or 'train'})")


def cmd_validate(a: argparse.Namespace) -> None:
    from .contract import validate_model

    schema = a.schema.split(",") if a.schema else None
    for p in a.files:
        meta = validate_model(p, schema)
        print(f"{p}: ok ({meta['haptics.kind']}, features {meta['haptics.features']})")


def cmd_presses(a: argparse.Namespace) -> None:
    from .presses import write_trajectory

    depth, duration = write_trajectory(Path(a.dataset), Path(a.out), a.seed)
    print(f"{a.out}: press-and-hold programme, {duration:.1f} s, depths scaled by the ramps' "
          f"deepest compression {1e3 * depth:.2f} mm")  # fmt: skip


def cmd_pipeline(a: argparse.Namespace) -> None:
    from .analysis import analyze
    from .pipeline import evaluate_models, export_models, train_models
    from .report import write_report

    t0 = time.perf_counter()
    ds = _data(a)
    out = Path(a.out)
    folder = Path(a.models_dir)
    an = analyze(ds, out, decimate=a.decimate, target_rate_hz=a.target_rate_hz)
    print(f"[pipeline] analysis -> {an}", flush=True)
    cfg = _cfg(a)
    specs = [s.strip() for s in a.models.split(",") if s.strip()]
    trained = train_models(ds, specs, cfg, folder, a.preset, _hyper(a), _candidates(a))
    models = [(m, cfg) for m in trained]
    evaluate_models(models, ds, folder, fidelity=Path(a.fidelity) if a.fidelity else None)
    export_models(models, ds, folder)
    print(f"[pipeline] report -> {write_report(folder, ds, out)}")
    print(f"[pipeline] done in {time.perf_counter() - t0:.0f} s")


def cmd_blend(a: argparse.Namespace) -> None:
    from .pipeline import blend_models

    names = _names(a) or []
    if len(names) != 2:
        raise ValueError(f"--names takes two models, got {len(names)}: {','.join(names)}")
    try:
        w = tuple(float(v) for v in a.weights.split(","))
    except ValueError:
        w = ()
    if len(w) != 2:
        raise ValueError(f"--weights takes two numbers, comma-separated: got {a.weights!r}")
    blend_models(Path(a.models_dir), _data(a), (names[0], names[1]), (w[0], w[1]))


def cmd_study(a: argparse.Namespace) -> None:
    from .study import StudyError, run_study

    trajectory = a.trajectory
    if trajectory is None:
        # the first test recording: the manifest's when given, else the bench's test_2.1
        trajectory = (
            load_data(DEFAULT_DATASET, a.manifest).test[0].source
            if a.manifest
            else f"{DEFAULT_DATASET}/test_2.1.parquet"
        )
    try:
        run_study(
            root=Path.cwd(),
            models_dir=Path(a.models_dir),
            out_dir=Path(a.out),
            work=Path(a.work),
            trajectory=Path(trajectory),
            names=_names(a),
            seed=a.seed,
            rt_loop=a.rt_loop,
            infer_server=a.infer_server,
            shadow_predictions=not a.no_shadow_predictions,
            material=Path(a.material),
            bench=Path(a.bench) if a.bench else None,
            bench_models_dir=Path(a.bench_models_dir) if a.bench_models_dir else None,
            clock=a.clock,
            fidelity=Path(a.fidelity) if a.fidelity else None,
            headline=a.headline,
            dataset=Path(a.dataset) if a.dataset else None,
        )
    except StudyError as e:
        raise RuntimeError(str(e)) from None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="haptics-train", description=__doc__)
    p.add_argument("--debug", action="store_true",
                   help="show the Python traceback of an error (anywhere on the line)")  # fmt: skip
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("analyze", help="dataset statistics as the thesis did (Markdown + PNG)")
    _common(s)
    s.add_argument("--out", default=DEFAULT_REPORT)
    _rows_opts(s)
    s.set_defaults(fn=cmd_analyze)

    s = sub.add_parser("train", help="train models on the training recordings")
    _common(s)
    _train_opts(s)
    s.set_defaults(fn=cmd_train)

    s = sub.add_parser("evaluate", help="one-step and closed-loop metrics on the test recording")
    _common(s)
    s.add_argument("--names", help="comma-separated model names (default: all trained)")
    s.add_argument("--no-closed-loop", action="store_true")
    s.add_argument("--fidelity", help="write the recommendation's keys (recommended, "
                   "free_run_rmse_n) into this JSON file (e.g. docs/fidelity.json)")  # fmt: skip
    s.set_defaults(fn=cmd_evaluate)

    s = sub.add_parser("ood", help="free-run RMSE on the out-of-distribution suite "
                       "(scripts/record-ood.sh) -> MODELS_DIR/ood.json")  # fmt: skip
    _common(s)
    s.add_argument("--suite", default="data/ood", help="folder of the suite's recordings "
                   "(default %(default)s)")  # fmt: skip
    s.add_argument("--names", help="comma-separated model names (default: the recommended)")
    s.add_argument("--fidelity", help="write the recommended model's suite keys "
                   "(ood_free_run_rmse_n, ood_diverged) into this JSON file")  # fmt: skip
    s.add_argument("--readme", help="put the suite's table into this study README (in place "
                   "of an earlier one, else before its Timings section)")  # fmt: skip
    s.set_defaults(fn=cmd_ood)

    s = sub.add_parser("export", help="ONNX files with contract metadata + parity check")
    _common(s)
    s.add_argument("--names", help="comma-separated model names (default: all trained)")
    s.add_argument("--no-parity", action="store_true", help="no dataset needed")
    s.set_defaults(fn=cmd_export)

    s = sub.add_parser("report", help="Markdown report from the evaluated models")
    _common(s)
    s.add_argument("--out", default=DEFAULT_REPORT)
    s.set_defaults(fn=cmd_report)

    s = sub.add_parser(
        "import", help="a series measured elsewhere -> a recording (rt-loop features)"
    )
    s.add_argument("--input", required=True,
                   help="delimited text (.csv, .tsv, .txt: the separator, decimal mark, header "
                   "line, units row and encoding are found from the file) or Parquet")
    s.add_argument("--out", required=True,
                   help="recording to write (.parquet; an existing one needs --overwrite)")
    s.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    s.add_argument("--time-col", help="name, or name of a 'name [unit]' header (or, for a file "
                   "without a time column, --sample-rate-hz)")
    s.add_argument("--sample-rate-hz", type=float,
                   help="a file without a time column: its rows' sampling rate (the time is the "
                   "row's index over it; a lost sample cannot be seen)")
    s.add_argument("--position-col", required=True,
                   help="displacement column (into the object), as --time-col")
    s.add_argument("--force-col", required=True, help="force column, as --time-col")
    s.add_argument("--time-unit", choices=tuple(TIME_UNITS),
                   help="default: the header's unit ('t [ms]'), else s (said in the "
                   "output)")  # fmt: skip
    s.add_argument("--position-unit", choices=tuple(POSITION_UNITS),
                   help="default: the header's unit, else m (said in the output; values over "
                   "1 m are then refused)")  # fmt: skip
    s.add_argument("--force-unit", choices=tuple(FORCE_UNITS),
                   help="default: the header's unit, else N (said in the output; values over "
                   "1 kN are then refused)")  # fmt: skip
    s.add_argument("--g-v", type=float,
                   help="velocity filter gain, rad/s (default: the loop's 30 capped at g dt 0.2)")
    s.add_argument("--g-a", type=float,
                   help="acceleration filter gain, rad/s (default: 100 capped at g dt 0.2)")
    s.add_argument("--contact-on-n", type=float,
                   help="contact starts above this force, N (default: from the noise floor)")
    s.add_argument("--contact-off-n", type=float, help="contact ends below this force, N")
    s.add_argument("--resample-hz", type=float, help="put the series on a uniform grid")
    s.add_argument("--repair", action="store_true",
                   help="interpolate non-finite values and gaps, drop rows whose time does not "
                   "increase (counted in the metadata) instead of refusing them")
    s.add_argument("--max-gap-factor", type=float, default=DEFAULT_MAX_GAP_FACTOR,
                   help="a period above this multiple of the median is a gap "
                   "(default %(default)s)")
    s.add_argument("--compression-negative", action="store_true",
                   help="the machine records compression as negative displacement and force: "
                   "both are negated (the product's convention: into the object and pushing "
                   "back are positive)")  # fmt: skip
    s.add_argument("--manifest", help="add the recording to this TOML manifest")
    s.add_argument("--role", choices=("train", "validation", "test"),
                   help="its role in the manifest (default train)")
    s.add_argument("--name", help="its name in the manifest (default: the output's stem)")
    s.add_argument("--source", help="where the data came from (default: the input path)")
    s.add_argument("--notes", help="remarks recorded in the manifest")
    s.add_argument("--rt-loop", help="rt-loop binary (else $HAPTICS_RT_LOOP, target/release)")
    s.set_defaults(fn=cmd_import)

    s = sub.add_parser(
        "presses",
        help="the press-and-hold programme of a dataset's train_hold / validation_hold "
        "recordings (rt-loop position-replay reads it; PRESSES=1 scripts/record-dataset.sh)",
    )
    s.add_argument("--dataset", default=DEFAULT_DATASET,
                   help="its force ramps (train_*.parquet) set the depths (default %(default)s)")
    s.add_argument("--out", required=True, help="trajectory Parquet (time, position_x)")
    s.add_argument("--seed", type=int, default=DEFAULT_SEED,
                   help="the presses' order and holds (default %(default)s)")
    s.set_defaults(fn=cmd_presses)

    s = sub.add_parser("validate", help="check ONNX files against docs/model-contract.md")
    s.add_argument("files", nargs="+")
    s.add_argument("--schema", help="comma-separated feature names the loop provides")
    s.set_defaults(fn=cmd_validate)

    s = sub.add_parser(
        "study", help="reproduction study (thesis 6.4.3/6.4.4): served models vs the sponge"
    )
    s.add_argument("--models-dir", default=DEFAULT_MODELS, help="default %(default)s")
    s.add_argument("--names", help="comma-separated model names (default: every *.onnx)")
    s.add_argument("--out", default="docs/study", help="report folder (default %(default)s)")
    s.add_argument("--work", default="data/study", help="raw recordings (default %(default)s)")
    s.add_argument(
        "--trajectory",
        help="recording whose position the replay follows (default: the first test recording "
        f"of --manifest, else {DEFAULT_DATASET}/test_2.1.parquet)",
    )
    s.add_argument("--manifest", help="TOML dataset manifest (its first test recording)")
    s.add_argument("--seed", type=int, default=1)
    s.add_argument("--rt-loop", help="rt-loop binary (default target/release/rt-loop)")
    s.add_argument("--infer-server", help="default target/release/infer-server")
    s.add_argument(
        "--no-shadow-predictions",
        action="store_true",
        help="skip the models' predictions along the real interaction (halves the run time)",
    )
    s.add_argument(
        "--material",
        default="materials/sponge.toml",
        help="the simulated object (rt-loop --material; default %(default)s)",
    )
    s.add_argument(
        "--bench",
        help="bench file (rt-loop identify-friction): every reproduction also runs with the "
        "friction compensated (see --headline)",
    )
    s.add_argument(
        "--bench-models-dir",
        help="models trained on recordings made with --bench (default: --models-dir)",
    )
    s.add_argument(
        "--clock", choices=("lockstep", "realtime"), default="lockstep", help="rt-loop's clock"
    )
    s.add_argument(
        "--headline",
        choices=("off", "on"),
        default="off",
        help="friction setting of the goal lines and docs/fidelity.json (on needs --bench; "
        "default %(default)s: as scripts/up.sh renders)",
    )
    s.add_argument(
        "--fidelity",
        default="docs/fidelity.json",
        help="merge the study's keys into this file ('' to skip; default %(default)s)",
    )
    s.add_argument(
        "--dataset",
        help="the models' dataset folder: with it (and the headline off) the study also builds "
        "`blend`: the candidate its ranking runs put first, blended with the partner and "
        "weights that felt closest on those runs; recommends it where it felt closest there "
        "(models/blend.py)",
    )
    s.set_defaults(fn=cmd_study)

    s = sub.add_parser("blend", help="the mean of two trained stateful models as one model "
                       "(blend.joblib, evaluated and exported as blend.onnx)")  # fmt: skip
    _common(s)
    s.add_argument("--names", required=True, help="the two models, comma-separated")
    s.add_argument(
        "--weights",
        default="0.5,0.5",
        help="their weights, comma-separated, non-negative (default %(default)s; a study's "
        "choice is in its recommendation.json, `blend`)",
    )
    s.set_defaults(fn=cmd_blend)

    s = sub.add_parser("pipeline", help="analyze + train + evaluate + export + report")
    _common(s)
    _train_opts(s)
    s.add_argument("--out", default=DEFAULT_REPORT, help="report folder (default %(default)s)")
    s.add_argument("--fidelity", help="write the recommendation's keys into this JSON file")
    s.set_defaults(fn=cmd_pipeline)
    return p


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else list(argv)
    # --debug is accepted anywhere on the line (before or after the subcommand).
    debug = "--debug" in args
    a = build_parser().parse_args([x for x in args if x != "--debug"])
    torch.set_num_threads(getattr(a, "threads", 1) or 1)
    try:
        a.fn(a)
    except KeyboardInterrupt:
        raise SystemExit(130) from None
    except Exception as e:  # noqa: BLE001 - every error is one line unless --debug
        if debug:
            raise
        print(f"haptics-train {a.command}: error: {one_line(e)}", file=sys.stderr)
        raise SystemExit(2) from None


#: The errors a user's input or files cause; anything else is a fault of ours, said so.
USER_ERRORS = (DataError, FileNotFoundError, ValueError, RuntimeError, OSError)


def one_line(e: BaseException) -> str:
    """The error as one line: its message for a user error, else its type too and where to see
    the traceback (a multi-line message, e.g. a child's stderr, is joined with "; ")."""
    msg = "; ".join(ln.strip() for ln in str(e).splitlines() if ln.strip()) or type(e).__name__
    if isinstance(e, USER_ERRORS):
        return msg
    return f"{type(e).__name__}: {msg} (an internal error; --debug shows the traceback)"


if __name__ == "__main__":
    main()
