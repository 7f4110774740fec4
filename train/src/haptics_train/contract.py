"""Checks an ONNX file against docs/model-contract.md (what infer-server validates)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx

from .closed_loop import session

KINDS = ("stateless", "stateful")


class ContractError(ValueError):
    pass


def _dims(vi: onnx.ValueInfoProto) -> list[int | str]:
    t = vi.type.tensor_type
    return [d.dim_value if d.HasField("dim_value") else (d.dim_param or "?") for d in t.shape.dim]


def _check_io(
    vi: onnx.ValueInfoProto, name: str, shape: list[int | str | None], problems: list[str]
) -> None:
    if vi.name != name:
        problems.append(f"expected {name!r}, found {vi.name!r}")
        return
    if vi.type.tensor_type.elem_type != onnx.TensorProto.FLOAT:
        problems.append(f"{name}: not float32")
    dims = _dims(vi)
    if len(dims) != len(shape):
        problems.append(f"{name}: rank {len(dims)}, expected {len(shape)} ({shape})")
        return
    for got, want in zip(dims, shape, strict=True):
        if isinstance(want, int) and got != want:
            problems.append(f"{name}: shape {dims}, expected {shape}")
            return


def load_onnx(path: str | Path) -> onnx.ModelProto:
    """The file as an ONNX model, or a ContractError in one line (a file that is not ONNX makes
    protobuf raise its own DecodeError, which is no user's business)."""
    p = Path(path)
    if not p.is_file():
        raise ContractError(f"{p}: no such file")
    try:
        return onnx.load(str(p))
    except Exception as e:  # noqa: BLE001 - protobuf's errors have no common public base
        raise ContractError(f"{p}: not an ONNX model ({type(e).__name__}: {e})") from e


def validate_model(
    model: str | Path | onnx.ModelProto, schema: list[str] | None = None
) -> dict[str, str]:
    """Raises ContractError listing every problem; returns the haptics.* metadata if valid."""
    m = model if isinstance(model, onnx.ModelProto) else load_onnx(model)
    meta = {p.key: p.value for p in m.metadata_props}
    problems: list[str] = []
    for key in ("haptics.features", "haptics.kind", "haptics.units", "haptics.provenance"):
        if not meta.get(key):
            problems.append(f"metadata {key} missing")
    kind = meta.get("haptics.kind", "")
    if kind and kind not in KINDS:
        problems.append(f"haptics.kind {kind!r} not in {KINDS}")
    names = [n for n in meta.get("haptics.features", "").split(",") if n]
    if len(set(names)) != len(names) or any(n != n.strip() for n in names):
        problems.append("haptics.features: names must be unique, without spaces")
    if schema is not None:
        unknown = [n for n in names if n not in schema]
        if unknown:
            problems.append(f"features not in the schema: {unknown}")
    nf = len(names)
    inputs = [i for i in m.graph.input if i.name not in {t.name for t in m.graph.initializer}]
    outputs = list(m.graph.output)
    if kind == "stateful":
        h = int(meta.get("haptics.state_size", "0") or 0)
        want_in = [("features", [1, nf]), ("h_in", [1, 1, h]), ("c_in", [1, 1, h])]
        want_out = [("force", [1, 1]), ("h_out", [1, 1, h]), ("c_out", [1, 1, h])]
        if h <= 0:
            problems.append("haptics.state_size missing for a stateful model")
    else:
        want_in = [("features", [None, nf])]
        want_out = [("force", [None, 1])]
    if len(inputs) != len(want_in):
        problems.append(f"{len(inputs)} inputs, expected {[w[0] for w in want_in]}")
    else:
        for vi, (n, s) in zip(inputs, want_in, strict=True):
            _check_io(vi, n, s, problems)
    if len(outputs) != len(want_out):
        problems.append(f"{len(outputs)} outputs, expected {[w[0] for w in want_out]}")
    else:
        for vi, (n, s) in zip(outputs, want_out, strict=True):
            _check_io(vi, n, s, problems)
    if not problems:
        try:
            sess = session(m)
            feeds = {"features": np.zeros((1, nf), dtype=np.float32)}
            if kind == "stateful":
                h = int(meta["haptics.state_size"])
                feeds["h_in"] = np.zeros((1, 1, h), dtype=np.float32)
                feeds["c_in"] = np.zeros((1, 1, h), dtype=np.float32)
            out = sess.run(None, feeds)
            if not np.isfinite(out[0]).all() or out[0].shape != (1, 1):
                problems.append(f"warm-up output not a finite [1, 1]: {out[0]!r}")
            from .reference import check_reference  # reference.py steps models as served

            if (wrong := check_reference(m)) is not None:
                problems.append(wrong)
        except Exception as e:  # noqa: BLE001 - any runtime failure is a contract failure
            problems.append(f"onnxruntime cannot run it: {e}")
    if problems:
        raise ContractError("; ".join(problems))
    return {k: v for k, v in meta.items() if k.startswith("haptics.")}
