"""ONNX Runtime sessions that know the project's fused operators (domain `ai.haptics`).

The fused operators (fused-ops/, one node per physics-shaped model: `StructuredStep`) live in a
Rust library, `libhaptics_fused_ops.so`, which `cargo build --release -p haptics-fused-ops`
builds (scripts/env.sh's `haptics_build` does). Every session train opens goes through
`session_options`, so a model with the fused node and one without load alike; a model that
needs the library when it is missing fails with one line saying how to build it.
"""

from __future__ import annotations

import os
from pathlib import Path

import onnx
import onnxruntime as ort

#: the custom-op domain of the fused operators (fused-ops/src/lib.rs `DOMAIN`)
DOMAIN = "ai.haptics"
#: the Cargo package that builds the library
PACKAGE = "haptics-fused-ops"
LIB_ENV = "HAPTICS_FUSED_OPS_LIB"
_LIB_NAME = "libhaptics_fused_ops.so"


class FusedOpsMissing(RuntimeError):
    """The model uses a fused operator and the library that runs it is not built."""


def repo_root() -> Path:
    """The repository this package lives in (train/src/haptics_train/ -> the root)."""
    return Path(__file__).resolve().parents[3]


def library_path() -> Path:
    """Where the library is: `$HAPTICS_FUSED_OPS_LIB`, else target/release/ of the repository
    (`$CARGO_TARGET_DIR/release/` when that is set)."""
    env = os.environ.get(LIB_ENV)
    if env:
        return Path(env)
    target = os.environ.get("CARGO_TARGET_DIR")
    base = Path(target) if target else repo_root() / "target"
    return base / "release" / _LIB_NAME


def uses_fused_ops(model: onnx.ModelProto | bytes | str | Path) -> bool:
    """True when the model has a node of the fused operators' domain."""
    if isinstance(model, (str, Path)):
        model = onnx.load(str(model))
    elif isinstance(model, bytes):
        model = onnx.load_from_string(model)
    return any(n.domain == DOMAIN for n in model.graph.node)


def missing_message() -> str:
    return (f"the model uses the fused operators ({DOMAIN}) and {library_path()} does not exist: "
            f"run `cargo build --release -p {PACKAGE}` (or set {LIB_ENV})")  # fmt: skip


def session_options(required: bool = False) -> ort.SessionOptions:
    """SessionOptions with the fused operators registered when the library exists. With
    `required` (the model has a fused node), a missing library raises `FusedOpsMissing`."""
    so = ort.SessionOptions()
    lib = library_path()
    if lib.is_file():
        so.register_custom_ops_library(str(lib))
    elif required:
        raise FusedOpsMissing(missing_message())
    return so


def session_options_for(model: onnx.ModelProto | bytes | str | Path) -> ort.SessionOptions:
    """`session_options`, the library required when `model` has a fused node."""
    return session_options(required=uses_fused_ops(model))
