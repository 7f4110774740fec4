//! infer-server: runs the active ONNX model on every loop step.
//!
//! - [`runtime`]: finds and loads ONNX Runtime (the PyPI wheel's library, `load-dynamic`).
//! - [`contract`]: the model contract (metadata keys, input/output names, the nine features).
//! - [`model`]: loading and validating a model file against the contract and a feature schema.
//! - [`engine`]: [`engine::StepEngine`], the allocation-free per-step runner.
//! - [`latency`]: a lock-free HDR-style latency histogram the inference thread writes and any
//!   thread reads.
//! - [`handoff`]: hands a freshly validated engine to the inference thread between two steps.
//! - [`serve`]: the inference thread over rt-loop's shared-memory segment.
//! - [`server`]: [`server::Server`], the control side (validate, activate, revalidate, stats)
//!   that `serve`, gRPC and the web page call.

pub mod contract;
pub mod engine;
pub mod handoff;
pub mod latency;
pub mod model;
pub mod runtime;
pub mod serve;
pub mod server;

pub use contract::{FeatureSchema, ModelKind};
pub use engine::{StepEngine, StepError};
pub use model::{ModelError, ModelInfo, SessionConfig};
pub use runtime::{Runtime, RuntimeError};
