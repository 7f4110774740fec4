"""ONNX export with the contract's metadata, and parity against the framework."""

from __future__ import annotations

import datetime as dt
import json
import subprocess
from functools import partial
from pathlib import Path

import numpy as np
import onnx

from . import __version__
from .closed_loop import OnnxStepper, session
from .contract import validate_model
from .data import Dataset, Recording
from .features import PREVIOUS_FORCE_FEATURES
from .models.base import ForceModel, TrainConfig


def git_commit(cwd: str | Path | None = None) -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=cwd, capture_output=True, text=True, timeout=10
        )
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _jsonable(o: object) -> object:
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, float) and not np.isfinite(o):
        return None
    return o


def provenance(
    model: ForceModel, cfg: TrainConfig, dataset: Dataset | None, metrics: dict | None
) -> dict:
    ds = None
    if dataset is not None:
        ds = {
            "root": dataset.root,
            "train": [{"name": r.name, "sha256": r.sha256[:16]} for r in dataset.train],
            "validation": [{"name": r.name, "sha256": r.sha256[:16]}
                           for r in dataset.validation],
            "test": [{"name": r.name, "sha256": r.sha256[:16]} for r in dataset.test],
            "manifest": dataset.manifest or None,
        }  # fmt: skip
    return _jsonable(
        {
            "model": model.name,
            "algo": model.algo,
            "feature_set": model.feature_set,
            "dataset": ds,
            "git_commit": git_commit(Path(__file__).parent),
            "hyperparameters": model.hyper,
            "training": {**cfg.to_dict(), **model.train_info_},
            "metrics": metrics or {},
            "created": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "decimation": cfg.decimate,
            "haptics_train_version": __version__,
        }
    )  # type: ignore[return-value]


def to_contract_onnx(model: ForceModel, prov: dict, **onnx_kw: object) -> onnx.ModelProto:
    """The model's ONNX with the contract's metadata; `onnx_kw` goes to its `to_onnx` (e.g.
    `fused=False`: structured's and lawfree's multi-node graph instead of the fused node)."""
    m = model.to_onnx(**onnx_kw)
    m.producer_name = "haptics-train"
    m.producer_version = __version__
    m.doc_string = f"haptics reaction-force model {model.name}"
    meta = {
        "haptics.features": ",".join(model.features),
        "haptics.kind": model.kind,
        "haptics.units": "N",
        "haptics.provenance": json.dumps(prov, sort_keys=True),
    }
    if model.kind == "stateful":
        h_in = next(i for i in m.graph.input if i.name == "h_in")
        meta["haptics.state_size"] = str(h_in.type.tensor_type.shape.dim[-1].dim_value)
    if any(f in PREVIOUS_FORCE_FEATURES for f in model.features):
        meta["haptics.previous_force"] = "step"
    if getattr(model, "serve_dt_", None):
        # the period the state is stepped at (its decays are exp(-step / tau)): one control
        # step of the loop it is meant for; infer-server refuses it beside a loop of another
        meta["haptics.step_s"] = repr(float(model.serve_dt_))  # type: ignore[attr-defined]
    gains = getattr(model, "feature_gains_", None)
    if gains is not None:
        # the filters of its training features: infer-server names a loop whose are others
        meta["haptics.feature_gains"] = json.dumps({"g_v": gains[0], "g_a": gains[1]})
    del m.metadata_props[:]
    for k, v in meta.items():
        m.metadata_props.add(key=k, value=v)
    onnx.checker.check_model(m)
    validate_model(m)
    return m


def onnx_predict(
    m: onnx.ModelProto, rec: Recording, features: tuple[str, ...], limit: int | None = None
) -> np.ndarray:
    """The exported model's one-step predictions on a recording's recorded features."""
    x = rec.matrix(features)[:limit].astype(np.float32)
    kinds = {p.key: p.value for p in m.metadata_props}
    if kinds.get("haptics.kind") == "stateful":
        st = OnnxStepper(m)
        return np.array([st.step(row) for row in x])
    sess = session(m)
    out = [sess.run(None, {"features": x[i : i + 65536]})[0][:, 0] for i in range(0, len(x), 65536)]
    return np.concatenate(out).astype(np.float64)


def parity(
    model: ForceModel, m: onnx.ModelProto, rec: Recording, stateful_limit: int = 20_000
) -> dict:
    """Max |ONNX - framework| over the test recording (a prefix for stepped stateful models:
    the approach before the first contact, then `stateful_limit` rows in contact, so that the
    comparison covers forces and not only the zeros before the probe touches the object)."""
    # a model whose graph renders only part of what it predicts (structured: the object, not
    # the bench's friction) is compared on that part
    predict = getattr(model, "predict_served", model.predict)
    if getattr(model, "serve_dt_", None) and hasattr(model, "predict_served"):
        # the graph steps its state at the loop's period, which the rows of a decimated (or
        # imported) recording are not: compare both stepped at the graph's period
        predict = partial(predict, dt=float(model.serve_dt_))  # type: ignore[attr-defined]

    x = rec.matrix(model.features)
    if model.kind == "stateful":
        # stepping in Python costs tens of us a row, so the whole recording would take minutes;
        # the framework's answer on a causal prefix is the prefix of its answer, so one call
        # finds the first force and gives the reference
        ref = predict(x[: min(len(x), _CONTACT_SEARCH_ROWS + stateful_limit)])
        touched = np.flatnonzero(contact_rows(rec, ref))
        first = int(touched[0]) if len(touched) else 0
        limit = min(len(ref), first + stateful_limit)
        ref = ref[:limit]
    else:
        limit, first = None, None
        ref = predict(x)
    got = onnx_predict(m, rec, model.features, limit)
    diff = np.abs(got - ref)
    return {
        "rows": int(len(ref)),
        "rows_with_force": int(np.count_nonzero(np.abs(np.nan_to_num(ref)) >= 0.01)),
        "max_abs_diff": float(np.nanmax(diff)) if len(diff) else 0.0,
        "mean_abs_diff": float(np.nanmean(diff)) if len(diff) else 0.0,
        "all_finite": bool(np.isfinite(got).all()),
        **({} if first is None else {"first_contact_row": first}),
    }


def contact_rows(rec: Recording, ref: np.ndarray) -> np.ndarray:
    """Rows of contact: a force of at least 0.01 N with the probe in the object (position > 0,
    when the recording has the position: a network answers a small force out of contact too,
    so the force alone would call the whole approach contact)."""
    pressed = np.abs(np.nan_to_num(ref)) >= 0.01
    if "position_x" in rec.columns:
        pressed &= np.nan_to_num(rec.column("position_x")[: len(ref)]) > 0.0
    return pressed


#: How far into a recording a stateful model's parity looks for its first force (rows).
_CONTACT_SEARCH_ROWS = 200_000


def save_onnx(m: onnx.ModelProto, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(m, str(path))
    return path
