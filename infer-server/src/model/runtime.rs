//! Finding and loading the ONNX Runtime shared library: the shared host crate's
//! (`ort-host/src/runtime.rs`, which rt-loop's ONNX objects load it through too), re-exported
//! here so `infer_server::Runtime` stays where callers find it.

pub use haptics_ort_host::runtime::*;
