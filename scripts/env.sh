# Sourced by the scripts: where the project's own installs live.
_root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
if [ -f "$_root/.ort/libonnxruntime.so" ]; then
  export ORT_DYLIB_PATH="$_root/.ort/libonnxruntime.so"
fi
if [ -d "$_root/.venv/bin" ]; then
  export HAPTICS_PYTHON="$_root/.venv/bin/python"
fi
unset _root

# One build command for every script: cargo unifies dependency features over the packages it is
# asked for, so building a different set (rt-loop alone, say) recompiles shared dependencies.
haptics_build() {
  # s826-double: the C-ABI double of the Sensoray 826 library (test support; HAPTICS_BOARD=s826)
  # haptics-fused-ops: libhaptics_fused_ops.so, the fused ONNX operators Python onnxruntime
  # registers (train's export parity and cost; infer-server links the same crate)
  cargo build --release -p rt-loop -p infer-server -p hapticctl -p s826-double -p haptics-fused-ops
}
