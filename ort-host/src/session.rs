//! A session built for one control step at a time, the same way in both processes.
//!
//! Why each setting: the step runs on the caller's thread (one intra-op thread, no inter-op
//! pool, nothing spinning: two spinning threads starve a two-core machine), every graph
//! optimisation is applied once at load, and memory patterns plan the intermediate tensors once
//! (with fixed shapes, later runs are served from ONNX Runtime's arena). The fused operators
//! (`fused-ops/`, domain `ai.haptics`, one node per physics-shaped model) are registered on every
//! session, so a model with them and one without load alike in either process.

use ort::environment::Environment;
use ort::session::builder::{GraphOptimizationLevel, SessionBuilder};
use ort::session::Session;

use crate::runtime::one_line;

/// What may differ between the processes' sessions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SessionSettings {
    /// ONNX Runtime's intra-op threads (1: the caller's thread alone).
    pub intra_threads: usize,
    /// Let ONNX Runtime's threads spin between runs (only with `intra_threads` > 1).
    pub spinning: bool,
}

impl Default for SessionSettings {
    fn default() -> Self {
        SessionSettings {
            intra_threads: 1,
            spinning: false,
        }
    }
}

/// Why a session could not be made. One line each.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// A setting or the fused operators' registration was refused (not the graph's fault).
    #[error("{0}")]
    Options(String),
    /// ONNX Runtime could not load the graph: corrupt, an unknown operator, a bad opset.
    #[error("{0}")]
    Graph(String),
}

/// A builder with the product's settings and the fused operators; the caller may add its own
/// (infer-server's bounded arena) before [`commit`].
pub fn builder(env: &Environment, s: SessionSettings) -> Result<SessionBuilder, SessionError> {
    let opt = |e: ort::Error<SessionBuilder>| SessionError::Options(one_line(&e.to_string()));
    Session::builder(env)
        .map_err(|e| SessionError::Options(one_line(&e.to_string())))?
        .with_intra_threads(s.intra_threads.max(1))
        .map_err(opt)?
        .with_inter_threads(1)
        .map_err(opt)?
        .with_parallel_execution(false)
        .map_err(opt)?
        .with_intra_op_spinning(s.spinning)
        .map_err(opt)?
        .with_inter_op_spinning(s.spinning)
        .map_err(opt)?
        .with_optimization_level(GraphOptimizationLevel::All)
        .map_err(opt)?
        // memory patterns and the CPU arena (both ONNX Runtime's defaults, stated because the
        // no-allocation-per-step claims rest on them)
        .with_memory_pattern(true)
        .map_err(opt)?
        .with_operators(
            haptics_fused_ops::domain().map_err(|e| {
                SessionError::Options(format!("the fused operators (ai.haptics): {e}"))
            })?,
        )
        .map_err(opt)
}

/// Creates the session from the graph's bytes, one creation at a time in this process: ONNX
/// Runtime adds a custom-op domain to a process-wide schema registry while it creates a session,
/// unguarded, so two at once race (measured in infer-server: "the domain is already exist"
/// refusals and segfaults with two test threads loading models). Loading is never on the
/// real-time path, so the lock costs nothing there.
pub fn commit(mut builder: SessionBuilder, bytes: &[u8]) -> Result<Session, SessionError> {
    static CREATING: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _one_at_a_time = CREATING
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    builder
        .commit_from_memory(bytes)
        .map_err(|e| SessionError::Graph(one_line(&e.to_string())))
}
