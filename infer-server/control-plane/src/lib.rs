//! The control plane of infer-server: the `haptics.v1` gRPC services (with health and
//! reflection) and the HTTP side (page, `/api`, `/ws/telemetry`, `/metrics`), over a [`Backend`]
//! that infer-server implements. See `docs/control-plane.md`.
//!
//! ```no_run
//! # fn demo(backend: std::sync::Arc<dyn control_plane::Backend>) -> anyhow::Result<()> {
//! let shutdown = control_plane::Shutdown::new();
//! // From a signal handler or another thread: shutdown.trigger();
//! control_plane::serve(control_plane::Config::default(), backend, shutdown)?;
//! # Ok(()) }
//! ```

pub mod auth;
pub mod backend;
pub mod config;
mod core;
pub mod error;
pub mod grpc;
pub mod grpc_auth;
pub mod host_policy;
pub mod http;
pub mod server;
pub mod shutdown;
pub mod stats;
pub mod telemetry;
pub mod uploads;

/// The generated `haptics.v1` messages, clients and servers (haptics-proto's, feature `grpc`).
pub use haptics_proto::grpc as pb;

pub use backend::{
    Activation, Backend, ExperimentKind, ExperimentRequest, ExperimentStatus, Latency, LoopStatus,
    ModelInfo, ModelSource, ModelState, ServerStatus, StatusSnapshot,
};
pub use config::Config;
pub use error::ControlError;
pub use server::{bind, serve, serve_async, start, Bound, Running};
pub use shutdown::Shutdown;
pub use telemetry::{Bucket, TelemetryBatch, TelemetryHub};
