//! ONNX Runtime for the bench's ONNX objects ([`super::onnx`]): found, checked and loaded once
//! per process by the host crate both processes share (`ort-host/`, the same search and
//! version check as infer-server's: `ORT_DYLIB_PATH`, else `.ort/libonnxruntime.so` above the
//! executable, the working directory or the crate, where `scripts/setup.sh` puts it).

use ort::environment::Environment;

pub use haptics_ort_host::one_line;

/// The process-wide ONNX Runtime environment, loading the library on the first call. The
/// error is one line that says what to run; it is the same on every later call (a library can
/// be loaded once per process).
pub fn environment() -> Result<&'static Environment, String> {
    haptics_ort_host::Runtime::init(None)
        .map(|rt| rt.environment())
        .map_err(|e| one_line(&e.to_string()))
}
