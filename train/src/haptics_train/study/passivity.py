"""The passivity layer's figures (issue 20 item 5), from real runs of rt-loop and infer-server:

1. a deliberately ACTIVE model (F = K x - B v, a negative damper whose force leads the motion)
   exported as ONNX with the model contract's metadata, rendered against the simulated hand with
   the layer off and on: the energy the object exchanged with the hand over time (the figure
   docs/passivity.png) and its totals;
2. the recommended models (sd_poly2, rf_memory, structured, as trained into `--models`) with the
   layer off and on: the felt-force RMSE against the study's reference (the hand on the
   simulated sponge), and its change.

Everything in lockstep (deterministic), with the study's hand programme and seed.

Usage: python -m haptics_train.study.passivity [--models models] [--out docs] [--work DIR]
Writes OUT/passivity.png and OUT/passivity.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from .processes import Run, Tools, find_tools, read_series, run_loop, write_config
from .protocol import STUDY_HAND, StudyError
from .score import score_run

#: The active model: F = K x - B v (N/m, N s/m); B above the hand's own damping (15 N s/m).
ACTIVE_K = 300.0
ACTIVE_B = 100.0
#: The models the product recommends (docs/fidelity.json, README).
RECOMMENDED = ("sd_poly2", "rf_memory", "structured")
#: The simulated bench's encoder, m/count.
M_PER_COUNT = 5e-6
COLUMNS = ("time", "counts", "F_ref", "F_pred", "F_true", "position_x", "velocity")


def write_active_model(path: Path, k: float = ACTIVE_K, b: float = ACTIVE_B) -> Path:
    """F = k position_x - b velocity as a stateless ONNX model with the contract's metadata
    (docs/model-contract.md): input `features` [N, 2] float32, output `force` [N, 1]."""
    w = numpy_helper.from_array(np.array([[k], [-b]], dtype=np.float32), "W")
    nodes = [helper.make_node("MatMul", ["features", "W"], ["force"])]
    x = helper.make_tensor_value_info("features", TensorProto.FLOAT, ["N", 2])
    y = helper.make_tensor_value_info("force", TensorProto.FLOAT, ["N", 1])
    graph = helper.make_graph(nodes, "active_negative_damper", [x], [y], initializer=[w])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 10
    provenance = {
        "model": "active_negative_damper",
        "purpose": "a deliberately active (energy-generating) model: the passivity layer's test",
        "hyperparameters": {"k_n_per_m": k, "b_ns_per_m": -b},
        "generator": "haptics_train.study.passivity.write_active_model",
    }
    helper.set_model_props(
        model,
        {
            "haptics.features": "position_x,velocity",
            "haptics.kind": "stateless",
            "haptics.units": "N",
            "haptics.provenance": json.dumps(provenance),
        },
    )
    onnx.checker.check_model(model)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, str(path))
    return path


def port_energy(series: dict[str, np.ndarray]) -> dict[str, np.ndarray | float]:
    """The energy into the rendered object, from a recording: the force rendered at step k
    (F = -F_ref: positive pushes the probe out) held until step k+1, times the encoder's
    displacement over that period (x positive into the object). `net` after each step, J."""
    f = -np.asarray(series["F_ref"], dtype=np.float64)
    x = np.asarray(series["counts"], dtype=np.float64) * M_PER_COUNT
    dw = np.where(np.isfinite(f[:-1]), f[:-1], 0.0) * np.diff(x)
    net = np.concatenate([[0.0], np.cumsum(dw)])
    return {
        "time": np.asarray(series["time"], dtype=np.float64),
        "net": net,
        "received_j": float(dw[dw > 0].sum()),
        "returned_j": float(-dw[dw < 0].sum()),
        "min_net_j": float(net.min()),
        "x_max_m": float(x.max()),
        "x_min_m": float(x.min()),
    }


def _summary(run: Run) -> dict:
    try:
        return json.loads(run.path.with_suffix(".summary.json").read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def _loop(tools: Tools, work: Path, cfg: Path, name: str, experiment: str, layer: str,
          model: Path | None) -> Run:  # fmt: skip
    args = ["--config", str(cfg), "--clock", "lockstep", "--experiment", experiment]
    args += ["--passivity", layer]
    return run_loop(
        tools,
        name,
        experiment,
        args,
        work / f"{name}-{layer}.parquet",
        server_model=None if model is None else model.resolve(),
        instance="" if model is None else f"passivity-{os.getpid()}-{name}-{layer}",
    )


def active_runs(tools: Tools, work: Path, cfg: Path) -> dict[str, dict]:
    model = write_active_model(work / "active.onnx")
    out: dict[str, dict] = {}
    for layer in ("off", "on"):
        r = _loop(tools, work, cfg, "active", "reproduction", layer, model)
        if not r.path.is_file():
            raise StudyError(f"the active model's run ({layer}) wrote nothing: {r.note or r.stop}")
        e = port_energy(read_series(r.path, COLUMNS))
        e["stop"] = r.stop
        e["summary"] = _summary(r).get("passivity")
        out[layer] = e
    return out


def felt_runs(tools: Tools, work: Path, cfg: Path, models: Path) -> dict[str, dict]:
    ref = _loop(tools, work, cfg, "reference", "shadow", "off", None)
    if not ref.ok:
        raise StudyError(f"the reference (shadow) run failed: {ref.note or ref.stop}")
    t_ref, f_ref = ref.series["time"], ref.series["F_true"]
    out: dict[str, dict] = {}
    for name in RECOMMENDED:
        f = models / f"{name}.onnx"
        if not f.is_file():
            print(f"[passivity] no {f}: skipped (train it: haptics-train pipeline)", flush=True)
            continue
        row: dict[str, float | str | None] = {}
        for layer in ("off", "on"):
            r = _loop(tools, work, cfg, name, "reproduction", layer, f)
            score = score_run(t_ref, f_ref, r)
            row[f"felt_rmse_{layer}_n"] = score["rmse"] if score else None
            row[f"stop_{layer}"] = r.stop
            p = _summary(r).get("passivity") or {}
            row[f"active_steps_{layer}"] = p.get("active_steps")
            row[f"energy_min_net_{layer}_j"] = p.get("min_net_j")
        off, on = row["felt_rmse_off_n"], row["felt_rmse_on_n"]
        if isinstance(off, float) and isinstance(on, float) and off > 0:
            row["change_pct"] = 100.0 * (on - off) / off
        out[name] = row
        print(f"[passivity] {name}: {row}", flush=True)
    return out


def plot(active: dict[str, dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
    styles = {"off": ("tab:red", "layer off"), "on": ("tab:blue", "layer on")}
    for layer, e in active.items():
        colour, label = styles[layer]
        totals = f"received {e['received_j']:.3f} J, returned {e['returned_j']:.3f} J"
        ax[0].plot(e["time"], e["net"], colour, lw=1.0, label=f"{label}: {totals}")
    ax[0].axhline(0.0, color="k", lw=0.6)
    ax[0].set_ylabel("energy into the object [J]\n(received - returned)")
    ax[0].legend(fontsize=8)
    ax[0].grid(alpha=0.3)
    for layer, e in active.items():
        colour, label = styles[layer]
        s = e["series"]
        ax[1].plot(s["time"], 1000 * s["counts"] * M_PER_COUNT, colour, lw=0.8, label=label)
    ax[1].set_xlabel("time [s]")
    ax[1].set_ylabel("probe position x [mm]")
    ax[1].legend(fontsize=8)
    ax[1].grid(alpha=0.3)
    fig.suptitle(
        f"An active model (F = {ACTIVE_K:g} x - {ACTIVE_B:g} v) against the simulated hand, "
        "lockstep, rt-loop + infer-server"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m haptics_train.study.passivity",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--models", type=Path, default=Path("models"))
    ap.add_argument("--out", type=Path, default=Path("docs"))
    ap.add_argument("--work", type=Path, default=Path("data/passivity"))
    ap.add_argument("--root", type=Path, default=Path("."))
    ap.add_argument("--skip-felt", action="store_true", help="only the active model's runs")
    a = ap.parse_args(argv)
    try:
        tools = find_tools(a.root, None, None)
        a.work.mkdir(parents=True, exist_ok=True)
        a.out.mkdir(parents=True, exist_ok=True)
        cfg = a.work / "hand.toml"
        write_config(cfg, 1, STUDY_HAND)
        active = active_runs(tools, a.work, cfg)
        for layer, e in active.items():
            e["series"] = read_series(a.work / f"active-{layer}.parquet", COLUMNS)
        plot(active, a.out / "passivity.png")
        felt = {} if a.skip_felt else felt_runs(tools, a.work, cfg, a.models)
    except StudyError as e:
        print(f"passivity: {e}", file=sys.stderr)
        return 2
    keep = ("received_j", "returned_j", "min_net_j", "x_max_m", "x_min_m", "stop", "summary")
    doc = {
        "active_model": {"k_n_per_m": ACTIVE_K, "b_ns_per_m": -ACTIVE_B},
        "hand": STUDY_HAND,
        "active": {layer: {k: e[k] for k in keep} for layer, e in active.items()},
        "felt": felt,
    }
    (a.out / "passivity.json").write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
