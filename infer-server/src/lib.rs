//! infer-server: runs the active ONNX model on every loop step.
//!
//! - [`app`]: `infer-server serve` as a function of its configuration and a shutdown signal
//!   ([`app::run`]): the threads, the control plane, housekeeping and the order of shutdown.
//! - [`cli`]: the command line (clap) and the serve flags turned into an [`app::AppConfig`].
//! - [`commands`]: the one-shot subcommands `validate`, `predict`, `runtime`.
//! - [`exit`]: the process's exit codes.
//! - [`runtime`]: finds and loads ONNX Runtime (the PyPI wheel's library, `load-dynamic`).
//! - [`contract`]: the model contract (metadata keys, input/output names, the nine features).
//! - [`model`]: loading and validating a model file against the contract and a feature schema.
//! - [`engine`]: [`engine::StepEngine`], the allocation-free per-step runner.
//! - [`latency`]: a lock-free HDR-style latency histogram the inference thread writes and any
//!   thread reads.
//! - [`handoff`]: hands a freshly validated engine to the inference thread between two steps.
//! - [`period_sync`]: learns the loop's period and phase so the inference thread sleeps until
//!   just before each step instead of parking (the period-synchronised wait).
//! - [`profile`]: the wait profiles (dedicated core, period-synchronised, shared) chosen from
//!   the machine.
//! - [`inference_thread`]: the inference thread over rt-loop's shared-memory segment.
//! - [`inference_control`]: [`inference_control::InferenceControl`], the control side of that
//!   thread (validate, activate, revalidate, stats) that `serve`, gRPC and the web page call.
//! - [`attachment`]: the segment's telemetry ring, command mailbox and link, shared by the
//!   inference thread with the rest of the server while it is attached.
//! - [`registry`]: the model directory and the models in memory (load, activate, unload).
//! - [`telemetry`]: the thread that drains the telemetry ring into the control plane's
//!   broadcast, and what it learns about the loop (step, rate, phase, liveness).
//! - [`control_backend`]: [`control_backend::ControlBackend`], the `control_plane::Backend`
//!   of this server: the registry, the telemetry and the mailbox behind gRPC and the page.

pub mod app;
pub mod attachment;
pub mod cli;
pub mod commands;
pub mod contract;
pub mod contract_check;
pub mod control_backend;
pub mod engine;
pub mod exit;
pub mod handoff;
pub mod inference_control;
pub mod inference_thread;
pub mod keep_awake;
pub mod latency;
pub mod memory_limit;
pub mod model;
pub mod period_sync;
pub mod profile;
pub mod registry;
pub mod runtime;
pub mod telemetry;

pub use contract::{FeatureSchema, ModelKind};
pub use engine::{StepEngine, StepError};
pub use model::{ModelError, ModelInfo, SessionConfig};
pub use runtime::{Runtime, RuntimeError};
