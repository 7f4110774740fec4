"""Prepares the model-family benchmark (benches/model_families.rs, run by scripts/bench-models.sh).

Usage: bench_models_prep.py DATASET OUT [--retrain]

- trains one model of each family the product can train on DATASET (small, fast
  hyperparameters: the cost of a call depends on the graph's structure, not on how well it was
  trained) into OUT/trained (kept: later runs re-export the same fitted models, so graphs built
  before and after a change of the export carry the same parameters; --retrain fits again);
- exports each with the contract's metadata into OUT/families (`haptics_train.export`, which
  checks parity with `predict` on the first test recording: printed, and failing above 1e-4 N);
- for the models exported as one fused node (fused-ops/: structured, lawfree, prony, the dense
  networks, the LSTMs, lstm_slow, svr, the spring-dampers, the forests), also writes
  their multi-node graph of standard operators as OUT/families/NAME_graph.onnx (same fitted
  model, same metadata), so one run measures the fused node against the graph it replaces;
- `lawfree_net`: the fitted `lawfree` read through the widest network its training may keep
  (lawfree_net.py), fused and as a graph, parity checked as above;
- writes OUT/families/identity.onnx: one node, the stateless contract's input and output (the
  floor of calling ONNX Runtime at all);
- OUT/families/nodes.json: each graph's node count;
- OUT/families/features.f64: 30 000 rows of the test recording's features in the segment's
  order (little-endian f64, ten per row), replayed by the benchmark.

Parity above 1e-4 N is printed on stderr (not fatal: the benchmark measures cost).
"""

from __future__ import annotations

import inspect
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper

from haptics_train.data import load_data
from haptics_train.models import TrainConfig
from haptics_train.pipeline import export_models, load_models, train_models
from haptics_train.reference import add_reference
from haptics_train.vocab import FEATURE_NAMES as SCHEMA_NAMES

#: one model per family (the spring-dampers, linear, SVR, forests, networks, feedback networks,
#: the structured and law-free stateful models)
SPECS = ("sd_poly2", "lr:six", "svr:six", "rf:six", "rf:memory", "dnn:six", "lstm:six",
         "dnn_fb:six", "lstm_fb:six", "prony", "structured", "lstm_slow", "lawfree")  # fmt: skip

#: small and fast; the graphs keep their served shapes (the thesis's layer sizes are the
#: defaults and are not changed here, only how long they train)
HYPER: dict[str, dict] = {
    "rf": {"n_estimators": 100, "max_depth": 12},
    "svr": {"max_rows": 2000},
    "dnn": {"epochs": 2},
    "lstm": {"iterations": 60},
    "lstm_slow": {"iterations": 60, "horizon_s": 0.5, "burn_in_s": 0.2, "streams": 8},
    # the linear readout here; its network readout is its own family below (`lawfree_net`)
    "lawfree": {"network_steps": 0},
}

#: `lawfree` read through the costliest network `haptics-train train` may keep (the widest of
#: lawfree_net.NET_GRID, on top of the linear readout), trained briefly: the served cost
#: depends on the widths, not on how long it trained
NET_FAMILY = ("residual", 32, 1e-4)
NET_STEPS = 300

PARITY_N = 1e-4
ROWS = 30_000


def identity(n_features: int) -> onnx.ModelProto:
    """features [N, n] -> force [N, 1] in one node (ReduceSum over the features)."""
    g = helper.make_graph(
        [helper.make_node("ReduceSum", ["features", "axes"], ["force"], keepdims=1)],
        "identity",
        [helper.make_tensor_value_info("features", TensorProto.FLOAT, ["N", n_features])],
        [helper.make_tensor_value_info("force", TensorProto.FLOAT, ["N", 1])],
        [helper.make_tensor("axes", TensorProto.INT64, [1], [1])],
    )
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    names = SCHEMA_NAMES[:n_features]
    for k, v in {"haptics.features": ",".join(names), "haptics.kind": "stateless",
                 "haptics.units": "N",
                 "haptics.provenance": json.dumps({"model": "identity"})}.items():  # fmt: skip
        m.metadata_props.add(key=k, value=v)
    onnx.checker.check_model(m)
    return m


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    dataset, out = load_data(argv[0]), Path(argv[1])
    trained, fam = out / "trained", out / "families"
    if "--retrain" in argv and trained.exists():
        shutil.rmtree(trained)
    # stateless models on every 100th control step (100 Hz rows): the graph is the same, the
    # training five times shorter than the pipeline's default 500 Hz
    cfg = TrainConfig(progress=False, target_rate_hz=100.0)
    missing = [s for s in SPECS if not (trained / f"{_name(s)}.joblib").exists()]
    if missing:
        train_models(dataset, missing, cfg, trained, hyper=HYPER, feedback_noise_candidates=[])
    models = load_models(trained, [_name(s) for s in SPECS])
    results = export_models(models, dataset, trained)
    if fam.exists():
        shutil.rmtree(fam)
    fam.mkdir(parents=True)
    bad = []
    for m, _ in models:
        shutil.copy(trained / f"{m.name}.onnx", fam / f"{m.name}.onnx")
        if "fused" in inspect.signature(m.to_onnx).parameters:
            graph = m.to_onnx(fused=False)  # the multi-node graph the fused node replaces
            meta = onnx.load(str(fam / f"{m.name}.onnx")).metadata_props
            graph.metadata_props.extend(meta)
            # its own reference steps in place of the fused node's: the graph's float32
            # arithmetic is not the fused node's (lawfree's slow filters, the SVR's kernel sum
            # differ by about 1e-4 N)
            add_reference(graph, dataset.test[0], m.features)
            onnx.save(graph, str(fam / f"{m.name}_graph.onnx"))
        p = results[m.name].get("parity", {})
        if not p or p["max_abs_diff"] > PARITY_N or not p["all_finite"]:
            bad.append(f"{m.name}: {p}")
    bad += lawfree_net({m.name: m for m, _ in models}["lawfree"], dataset, cfg, fam)
    onnx.save(identity(2), str(fam / "identity.onnx"))
    nodes = {f.stem: len(onnx.load(str(f)).graph.node) for f in sorted(fam.glob("*.onnx"))}
    (fam / "nodes.json").write_text(json.dumps(nodes, indent=1))
    rec = dataset.test[0]
    rows = rec.matrix(list(SCHEMA_NAMES))
    start = max(0, len(rows) // 2 - ROWS // 2)
    np.ascontiguousarray(rows[start : start + ROWS], dtype="<f8").tofile(fam / "features.f64")
    print(f"[bench-models] {len(nodes)} graphs in {fam}: {nodes}", flush=True)
    if bad:
        # reported, not fatal: the benchmark measures cost (skl2onnx's float32 SVR graph, the
        # export before the fused SvrStep, differed from scikit-learn's float64 by ~8e-4 N)
        print("[bench-models] parity with predict above 1e-4 N:\n  " + "\n  ".join(bad),
              file=sys.stderr)  # fmt: skip
    return 0


def lawfree_net(lf: object, dataset: object, cfg: TrainConfig, fam: Path) -> list[str]:
    """Writes FAM/lawfree_net.onnx (the fused node) and its multi-node graph: `lf` read through
    a network of `NET_FAMILY`; returns the parity failures (stepped through ONNX Runtime
    against `predict_served` over 3000 rows from the middle of the test recording)."""
    from haptics_train.closed_loop import OnnxStepper
    from haptics_train.data import training_arrays
    from haptics_train.export import provenance, to_contract_onnx
    from haptics_train.models.lawfree_net import fit_network_readout

    X, y, params = training_arrays(dataset.train, lf.features, lf.layout, (), cfg.target,
                                   cfg.decimate, cfg.target_rate_hz)  # fmt: skip
    valid = [(r.matrix(lf.features), r.target(cfg.target), 1.0 / r.sample_rate_hz)
             for r in dataset.validation]  # fmt: skip
    net, _ = fit_network_readout(lf, X, y, params["info"], valid, grid=(NET_FAMILY,),
                                 max_steps=NET_STEPS)  # fmt: skip
    prov = provenance(net, cfg, dataset, None)
    fused, graph = to_contract_onnx(net, prov), to_contract_onnx(net, prov, fused=False)
    for m in (fused, graph):
        add_reference(m, dataset.test[0], net.features)
    onnx.save(fused, str(fam / "lawfree_net.onnx"))
    onnx.save(graph, str(fam / "lawfree_net_graph.onnx"))
    rec = dataset.test[0]
    xv = rec.matrix(list(net.features))
    xv = xv[len(xv) // 2 : len(xv) // 2 + 3000]  # mid-recording: in contact, the force moving
    ref = net.predict_served(xv, 1.0 / rec.sample_rate_hz)
    if not np.ptp(ref) > 0:
        return [f"lawfree_net: the parity rows hold no force ({rec.name})"]
    # the fused node is what export writes; the graph's float32 state cannot hold the slow
    # filters' steps at 10 kHz (lawfree.rs: a drift of about 5e-4 N, the linear readout's too)
    fused_err, graph_err = (
        float(np.max(np.abs(np.array([st.step(r) for r in xv.astype(np.float32)]) - ref)))
        for st in (OnnxStepper(fused), OnnxStepper(graph)))  # fmt: skip
    print(f"[bench-models] lawfree_net: parity max |onnx - predict| {fused_err:.2e} N (the "
          f"multi-node graph {graph_err:.2e} N)", flush=True)  # fmt: skip
    return [f"lawfree_net: {fused_err:.2e} N"] if not fused_err <= PARITY_N else []


def _name(spec: str) -> str:
    """The saved model's name for a spec (rf:six -> rf_six, structured -> structured)."""
    algo, _, fset = spec.partition(":")
    return f"{algo}_{fset}" if fset else algo


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
