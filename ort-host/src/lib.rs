//! ONNX Runtime, hosted the one way this product runs it, for both processes that run graphs:
//! infer-server (the served model, every control step) and rt-loop (a bench object whose law is
//! an ONNX graph, `law = "onnx"`). Before this crate each had its own copy of the library
//! search and of the I/O binding, and they had drifted: rt-loop's sessions did not register the
//! fused operators, so an exported `structured` model (one `ai.haptics:StructuredStep` node)
//! could be served but not used as a bench object.
//!
//! Four parts, each usable alone:
//! - [`runtime`]: find `libonnxruntime.so` (flag, `ORT_DYLIB_PATH`, `.ort/` above the
//!   executable or the working directory), check its version, load it once per process;
//! - [`session`]: a session built for a real-time step (the caller's thread only, nothing
//!   spinning, every graph optimisation, memory patterns, the fused operators registered),
//!   created one at a time in the process (ONNX Runtime's custom-op registry is unguarded);
//! - [`reference`]: the reference steps an exported model carries (`haptics.reference`),
//!   parsed and compared the one way both processes check a graph they open;
//! - [`binding`]: inputs and outputs bound once ([`binding::Binding`]), so the per-step call is
//!   `RunWithBinding` on preallocated tensors, and ONNX Runtime's statuses read or released.
//!
//! Everything here runs off the real-time path except [`binding::Binding::run`] and
//! [`binding::release`], which allocate nothing and take no lock.

pub mod binding;
pub mod reference;
pub mod runtime;
pub mod session;

pub use binding::Binding;
/// Work done ahead (fused-ops ahead.rs): a serving thread opts in once, then runs what the
/// kernels it stepped queued after each answer.
pub use haptics_fused_ops::{run_ahead, serve_ahead_on_this_thread};
pub use runtime::{one_line, Runtime, RuntimeError, REPO_LIB_PATH, SETUP_COMMAND};
pub use session::{SessionError, SessionSettings};
