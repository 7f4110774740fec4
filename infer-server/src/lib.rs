//! infer-server: runs the active ONNX model on every loop step.
//!
//! Layout: the process at the top, three folders under it, each a layer that names only the
//! ones below it (`control` uses `serving` and `model`; `serving` uses `model`):
//!
//! - [`app`]: `infer-server serve` as a function of its configuration and a shutdown signal
//!   ([`app::run`]): the threads, the control plane, housekeeping and the order of shutdown.
//! - [`cli`]: the command line (clap) and the serve flags turned into an [`app::AppConfig`].
//! - [`commands`]: the one-shot subcommands `validate`, `predict`, `runtime`.
//! - [`exit`]: the process's exit codes.
//! - [`model`]: a model, from its file to the engine that steps it.
//!   - [`model::contract`]: the model contract (metadata keys, input/output names, the nine
//!     features); [`model::contract_check`]: its checks on plain data.
//!   - [`model::runtime`]: finds and loads ONNX Runtime (the PyPI wheel's library,
//!     `load-dynamic`); [`model::memory_limit`]: the arena that bounds a model's memory.
//!   - [`model::engine`]: [`model::engine::StepEngine`], the allocation-free per-step runner.
//! - [`serving`]: the real-time side, the inference thread and how it waits.
//!   - [`serving::inference_thread`]: the inference thread over rt-loop's shared-memory segment.
//!   - [`serving::period_sync`]: learns the loop's period and phase so the inference thread
//!     sleeps until just before each step instead of parking (the period-synchronised wait);
//!     [`serving::keep_awake`]: keeps its CPU from halting between steps.
//!   - [`serving::profile`]: the wait profiles (dedicated core, period-synchronised, shared)
//!     chosen from the machine.
//!   - [`serving::latency`]: a lock-free HDR-style latency histogram the inference thread
//!     writes and any thread reads.
//!   - [`serving::handoff`]: hands a freshly validated engine to the inference thread between
//!     two steps.
//!   - [`serving::attachment`]: the segment's telemetry ring, command mailbox and link, shared
//!     by the inference thread with the rest of the server while it is attached.
//! - [`control`]: what the control plane (gRPC, the page, the CLI) reaches.
//!   - [`control::inference_control`]: [`control::inference_control::InferenceControl`], the
//!     control side of the inference thread (validate, activate, revalidate, stats).
//!   - [`control::registry`]: the model directory and the models in memory (load, activate,
//!     unload).
//!   - [`control::telemetry`]: the thread that drains the telemetry ring into the control
//!     plane's broadcast, and what it learns about the loop (step, rate, phase, liveness).
//!   - [`control::control_backend`]: [`control::control_backend::ControlBackend`], the
//!     `control_plane::Backend` of this server: the registry, the telemetry and the mailbox
//!     behind gRPC and the page.

pub mod app;
pub mod cli;
pub mod commands;
pub mod control;
pub mod exit;
pub mod model;
pub mod serving;

pub use model::contract::{FeatureSchema, ModelKind};
pub use model::engine::{StepEngine, StepError};
pub use model::runtime::{Runtime, RuntimeError};
pub use model::{ModelError, ModelInfo, SessionConfig};
