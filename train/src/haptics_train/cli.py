"""Command line of haptics-train: analyze, train, evaluate, export, report, import, validate,
pipeline, study. Run from the repository root (default paths are relative to it)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from .data import DataError, load_dataset
from .features import FEATURE_SETS
from .models import ALGOS, TrainConfig
from .pipeline import DEFAULT_SPECS

DEFAULT_DATASET = "data/dataset"
DEFAULT_MODELS = "models"
DEFAULT_REPORT = "docs/report"


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--dataset",
        default=DEFAULT_DATASET,
        help="folder with train_*.parquet and test_*.parquet (default %(default)s)",
    )
    p.add_argument("--models-dir", default=DEFAULT_MODELS, help="default %(default)s")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def _train_opts(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--models",
        default=",".join(DEFAULT_SPECS),
        help="comma-separated ALGO[:FEATURESET] specs; algorithms: "
        f"{', '.join(ALGOS)}; feature sets: {', '.join(FEATURE_SETS)} "
        "(default: the full comparison)",
    )
    p.add_argument(
        "--preset",
        choices=("default", "thesis"),
        default="default",
        help="thesis = the thesis's hyperparameters (SPEC section 6)",
    )
    p.add_argument(
        "--decimate",
        type=int,
        default=20,
        help="keep every Nth control step for stateless training (default 20)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--target", default="rtob_force")
    p.add_argument("--rf-trees", type=int)
    p.add_argument("--rf-depth", type=int)
    p.add_argument("--svr-rows", type=int, help="SVR training subsample (default 5000)")
    p.add_argument("--dnn-epochs", type=int)
    p.add_argument("--lstm-iterations", type=int)
    p.add_argument(
        "--feedback-noise",
        type=float,
        help="N, scale of the previous-force error dnn_fb/lstm_fb train with (default 2.5)",
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
    if a.feedback_noise is not None:
        h["dnn_fb"] = {"feedback_noise": a.feedback_noise}
        h["lstm_fb"] = {"feedback_noise": a.feedback_noise}
    return {k: v for k, v in h.items() if v}


def _names(a: argparse.Namespace) -> list[str] | None:
    return [n.strip() for n in a.names.split(",")] if getattr(a, "names", None) else None


def cmd_analyze(a: argparse.Namespace) -> None:
    from .analysis import analyze

    ds = load_dataset(a.dataset)
    print(analyze(ds, Path(a.out), decimate=a.decimate))


def cmd_train(a: argparse.Namespace) -> None:
    from .pipeline import train_models

    ds = load_dataset(a.dataset)
    cfg = TrainConfig(decimate=a.decimate, target=a.target, seed=a.seed, progress=not a.no_progress)
    specs = [s.strip() for s in a.models.split(",") if s.strip()]
    train_models(ds, specs, cfg, Path(a.models_dir), a.preset, _hyper(a))


def cmd_evaluate(a: argparse.Namespace) -> None:
    from .pipeline import evaluate_models, load_models

    ds = load_dataset(a.dataset)
    models = load_models(Path(a.models_dir), _names(a))
    for _, cfg in models:
        cfg.progress = not a.no_progress
    evaluate_models(models, ds, Path(a.models_dir), closed_loop=not a.no_closed_loop)


def cmd_export(a: argparse.Namespace) -> None:
    from .pipeline import export_models, load_models

    ds = load_dataset(a.dataset) if not a.no_parity else None
    export_models(load_models(Path(a.models_dir), _names(a)), ds, Path(a.models_dir))


def cmd_report(a: argparse.Namespace) -> None:
    from .report import write_report

    ds = load_dataset(a.dataset)
    print(write_report(Path(a.models_dir), ds, Path(a.out)))


def cmd_import(a: argparse.Namespace) -> None:
    from .importer import import_series

    rec = import_series(
        a.input,
        a.out,
        a.time_col,
        a.position_col,
        a.force_col,
        a.time_unit,
        a.position_unit,
        a.rt_loop,
    )
    print(f"{a.out}: {len(rec)} rows, columns {len(rec.columns)}")


def cmd_validate(a: argparse.Namespace) -> None:
    from .contract import validate_model

    schema = a.schema.split(",") if a.schema else None
    for p in a.files:
        meta = validate_model(p, schema)
        print(f"{p}: ok ({meta['haptics.kind']}, features {meta['haptics.features']})")


def cmd_pipeline(a: argparse.Namespace) -> None:
    from .analysis import analyze
    from .pipeline import evaluate_models, export_models, train_models
    from .report import write_report

    t0 = time.perf_counter()
    ds = load_dataset(a.dataset)
    out = Path(a.out)
    folder = Path(a.models_dir)
    print(f"[pipeline] analysis -> {analyze(ds, out, decimate=a.decimate)}", flush=True)
    cfg = TrainConfig(decimate=a.decimate, target=a.target, seed=a.seed, progress=not a.no_progress)
    specs = [s.strip() for s in a.models.split(",") if s.strip()]
    models = [(m, cfg) for m in train_models(ds, specs, cfg, folder, a.preset, _hyper(a))]
    evaluate_models(models, ds, folder)
    export_models(models, ds, folder)
    print(f"[pipeline] report -> {write_report(folder, ds, out)}")
    print(f"[pipeline] done in {time.perf_counter() - t0:.0f} s")


def cmd_study(a: argparse.Namespace) -> None:
    from .study import StudyError, run_study

    try:
        run_study(
            root=Path.cwd(),
            models_dir=Path(a.models_dir),
            out_dir=Path(a.out),
            work=Path(a.work),
            trajectory=Path(a.trajectory),
            names=_names(a),
            seed=a.seed,
            rt_loop=a.rt_loop,
            infer_server=a.infer_server,
            shadow_predictions=not a.no_shadow_predictions,
        )
    except StudyError as e:
        raise RuntimeError(str(e)) from None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="haptics-train", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("analyze", help="dataset statistics as the thesis did (Markdown + PNG)")
    _common(s)
    s.add_argument("--out", default=DEFAULT_REPORT)
    s.add_argument("--decimate", type=int, default=20)
    s.set_defaults(fn=cmd_analyze)

    s = sub.add_parser("train", help="train models on the training recordings")
    _common(s)
    _train_opts(s)
    s.set_defaults(fn=cmd_train)

    s = sub.add_parser("evaluate", help="one-step and closed-loop metrics on the test recording")
    _common(s)
    s.add_argument("--names", help="comma-separated model names (default: all trained)")
    s.add_argument("--no-closed-loop", action="store_true")
    s.set_defaults(fn=cmd_evaluate)

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
    s.add_argument("--input", required=True, help="CSV or Parquet file")
    s.add_argument("--out", required=True, help="recording to write (.parquet)")
    s.add_argument("--time-col", required=True)
    s.add_argument("--position-col", required=True)
    s.add_argument("--force-col", required=True)
    s.add_argument("--time-unit", default="s", choices=("s", "ms", "us"))
    s.add_argument("--position-unit", default="m", choices=("m", "mm", "um"))
    s.add_argument("--force-unit", default="N", choices=("N", "mN"))
    s.add_argument("--rt-loop", help="rt-loop binary (else $HAPTICS_RT_LOOP, target/release)")
    s.set_defaults(fn=cmd_import)

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
        default=f"{DEFAULT_DATASET}/test_2.1.parquet",
        help="recording whose position the replay follows (default %(default)s)",
    )
    s.add_argument("--seed", type=int, default=1)
    s.add_argument("--rt-loop", help="rt-loop binary (default target/release/rt-loop)")
    s.add_argument("--infer-server", help="default target/release/infer-server")
    s.add_argument(
        "--no-shadow-predictions",
        action="store_true",
        help="skip the models' predictions along the real interaction (halves the run time)",
    )
    s.set_defaults(fn=cmd_study)

    s = sub.add_parser("pipeline", help="analyze + train + evaluate + export + report")
    _common(s)
    _train_opts(s)
    s.add_argument("--out", default=DEFAULT_REPORT, help="report folder (default %(default)s)")
    s.set_defaults(fn=cmd_pipeline)
    return p


def main(argv: list[str] | None = None) -> None:
    a = build_parser().parse_args(argv)
    torch.set_num_threads(getattr(a, "threads", 1) or 1)
    try:
        a.fn(a)
    except (DataError, FileNotFoundError, ValueError, RuntimeError) as e:
        print(f"haptics-train {a.command}: error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    except KeyboardInterrupt:
        raise SystemExit(130) from None


if __name__ == "__main__":
    main()
