# Sourced by the scripts: where the project's own installs live.
_root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
if [ -f "$_root/.ort/libonnxruntime.so" ]; then
  export ORT_DYLIB_PATH="$_root/.ort/libonnxruntime.so"
fi
if [ -d "$_root/.venv/bin" ]; then
  export HAPTICS_PYTHON="$_root/.venv/bin/python"
fi
unset _root

# One build command for every script: cargo unifies dependency features over the packages and
# targets it is asked for, so building a different set (rt-loop alone, say) recompiles shared
# dependencies with other features, and the next command recompiles them back.
#
# Every library and binary of the workspace, and its examples: selecting examples makes cargo
# resolve features with the workspace's dev-dependencies, exactly as scripts/test.sh's `cargo
# build ... --tests --examples` and `cargo test --workspace` do. So up.sh, the record and bench
# scripts and the test command share every compiled dependency: run one after another, none
# recompiles anything (before, each switch rebuilt ~50 crates, Arrow and Parquet among them, and
# replaced target/release/libhaptics_fused_ops.so under any Python process loading it).
# Among the libraries: libs826_double.so (the C-ABI double of the Sensoray 826 library,
# HAPTICS_BOARD=s826) and libhaptics_fused_ops.so (the fused ONNX operators Python onnxruntime
# registers for train's export parity and cost; infer-server links the same crate).
# Extra arguments select more targets of the same build (scripts/test.sh: --tests).
haptics_build() {
  cargo build --release --workspace --lib --bins --examples "$@"
}
