//! The `Backend` trait: everything the control plane needs from infer-server. The gRPC and HTTP
//! services are thin translations over it, so both answer the same way.
//!
//! Every method may block (loading a model means reading, validating and warming it; activating
//! waits for the swap to take effect between two steps): the control plane calls them on tokio's
//! blocking pool, never on the real-time threads and never on a runtime worker.
use std::fmt;
use std::str::FromStr;

use crate::error::ControlError;
use crate::telemetry::TelemetryBatch;

/// The operations of the control plane. infer-server implements it over its model registry, the
/// inference thread and the shared-memory segment; the tests implement it over a simulated loop.
pub trait Backend: Send + Sync + 'static {
    /// Every model of the model directory and every uploaded one, with its state. Sorted by name.
    fn list_models(&self) -> Result<Vec<ModelInfo>, ControlError>;

    /// Reads, validates and warms a model, off the hot path, and keeps it loaded (not active).
    /// Loading a model that is already loaded reloads it only if it is not active; a failed load
    /// leaves every other model, and the active one, as it was.
    /// Errors: `NotFound` (no such file), `InvalidArgument` (corrupt file, wrong inputs or
    /// outputs, NaN/Inf on warm-up), `FailedPrecondition` (features the loop does not provide).
    fn load_model(&self, source: ModelSource) -> Result<ModelInfo, ControlError>;

    /// Makes a loaded model the active one with one atomic swap between two steps, and returns
    /// once the swap has taken effect, with the first step the new model answered. A stateful
    /// model starts from a fresh state. With `load_if_needed`, an available model is loaded first.
    /// Errors: `NotFound`, `FailedPrecondition` (not loaded and `!load_if_needed`, or no loop to
    /// answer), and any error of `load_model`.
    fn activate_model(&self, name: &str, load_if_needed: bool) -> Result<Activation, ControlError>;

    /// Drops a loaded model from memory. Errors: `NotFound`, `FailedPrecondition` (it is active).
    fn unload_model(&self, name: &str) -> Result<(), ControlError>;

    /// The model serving the loop, `None` when the loop runs on its fallback.
    fn active_model(&self) -> Option<ModelInfo>;

    /// A snapshot of the loop (read from the segment) and of the server. Must be cheap: it is
    /// called for every status request, twice a second per WebSocket and for every `/metrics`.
    fn status(&self) -> StatusSnapshot;

    /// Starts an experiment on the loop through the shared-memory command mailbox. The request
    /// was validated by the control plane (kind known, parameters finite and positive).
    /// Errors: `FailedPrecondition` (no loop attached, an experiment is already running).
    fn start_experiment(&self, request: &ExperimentRequest) -> Result<(), ControlError>;

    /// Stops the running experiment (no error when none runs). Errors: `FailedPrecondition` when
    /// no loop is attached.
    fn stop_experiment(&self) -> Result<(), ControlError>;

    /// A new receiver of the loop's telemetry: batches of consecutive buckets, in step order,
    /// published by the backend as they come off the telemetry ring (every few milliseconds).
    /// Buckets may be single steps or already decimated; the control plane merges them further
    /// for each client (min of minima, max of maxima), so spikes survive. A slow client lags and
    /// loses batches (counted), never the backend.
    fn subscribe_telemetry(&self) -> tokio::sync::broadcast::Receiver<TelemetryBatch>;
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelState {
    /// On disk, not loaded.
    Available,
    /// Validated and warm, not serving.
    Loaded,
    /// Serving the loop.
    Active,
    /// The last load failed; `ModelInfo::error` says why.
    Failed,
}

impl ModelState {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Available => "available",
            Self::Loaded => "loaded",
            Self::Active => "active",
            Self::Failed => "failed",
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct ModelInfo {
    /// The file name in the model directory, or the name given to an upload.
    pub name: String,
    pub state: ModelState,
    /// "stateless" or "stateful" (from the model's `haptics.kind` metadata); empty when unknown.
    pub kind: String,
    /// Input feature names, in input order (`haptics.features`).
    pub features: Vec<String>,
    pub units: String,
    pub provenance_json: String,
    pub error: Option<String>,
    pub size_bytes: u64,
    /// The id written beside each predicted force (0 when not loaded).
    pub model_id: u32,
    /// For the active model: the first step it answered.
    pub active_since_step: Option<u64>,
    /// What one call costs (`{"export": .., "warmup": ..}`, docs/model-contract.md); empty
    /// when not loaded.
    pub cost_json: String,
    /// The reference steps (`haptics.reference`) checked at load, all of which agreed; 0 when
    /// it carries none or is not loaded.
    pub reference_steps: u32,
}

impl ModelInfo {
    /// A model known by name only (e.g. a file not read yet).
    pub fn available(name: impl Into<String>, size_bytes: u64) -> Self {
        Self {
            name: name.into(),
            state: ModelState::Available,
            kind: String::new(),
            features: Vec::new(),
            units: String::new(),
            provenance_json: String::new(),
            error: None,
            size_bytes,
            model_id: 0,
            active_since_step: None,
            cost_json: String::new(),
            reference_steps: 0,
        }
    }
}

/// Where a model to load comes from.
#[derive(Clone, PartialEq, Eq)]
pub enum ModelSource {
    /// A file name inside the model directory (already checked to be a plain name: no `/`,
    /// no `..`).
    Directory { name: String },
    /// Uploaded bytes (already checked against the size limit), to be known as `name`.
    Upload { name: String, bytes: Vec<u8> },
}

impl ModelSource {
    pub fn name(&self) -> &str {
        match self {
            Self::Directory { name } | Self::Upload { name, .. } => name,
        }
    }
}

impl fmt::Debug for ModelSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Directory { name } => write!(f, "Directory({name:?})"),
            Self::Upload { name, bytes } => write!(f, "Upload({name:?}, {} bytes)", bytes.len()),
        }
    }
}

/// The result of a swap.
#[derive(Debug, Clone, PartialEq)]
pub struct Activation {
    pub model: ModelInfo,
    /// The first loop step (sequence number) answered by the new model.
    pub effective_step: u64,
    /// What the user should know about the model now served (e.g. features of other filters
    /// than the loop's): served anyway.
    pub warnings: Vec<String>,
}

#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Latency {
    pub p50_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub max_us: f64,
    pub count: u64,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct ExperimentStatus {
    /// "idle", "abstraction", "reproduction", "shadow", "position-replay".
    pub kind: String,
    pub running: bool,
    pub cycle: u32,
    /// e.g. "ramp-up", "ramp-down", "hold"; empty when idle.
    pub phase: String,
}

/// The loop side of the status, read from the shared-memory segment.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LoopStatus {
    /// False when no rt-loop is attached or its heartbeat stopped.
    pub alive: bool,
    /// "realtime" | "lockstep".
    pub clock: String,
    /// "sim" | "replay" | "real".
    pub board: String,
    /// Steps per second measured over the last ~second.
    pub rate_hz: f64,
    /// Steps since the loop started.
    pub step: u64,
    /// Steps not rendered by the model's on-time answer (late_one + held + fallback).
    pub fallbacks: u64,
    pub deadline_misses: u64,
    /// Degradation ladder of the current (or last) run (issue 14): steps rendered by the
    /// model's on-time answer, by the previous step's answer one period late, by the held
    /// (extrapolated) last served force, and by the cross-faded fallback law.
    pub on_time: u64,
    pub late_one: u64,
    pub held: u64,
    pub fallback: u64,
    /// Ring slots or indices the loop found corrupt.
    pub corrupt: u64,
    /// Largest change of the rendered force in one step caused by a ladder transition, N.
    pub max_transition_step_n: f64,
    /// Steps rendered by a model's answer above the force limit, at the limit (issue 23).
    pub saturated: u64,
    /// Board failures that ended a run since the loop started (each put the motor at 0 A).
    pub board_faults: u64,
    /// The last one's reason ("" when none).
    pub board_fault: String,
    /// The run's snapshots a real board's FIFO lost, and snapshots with a quadrature error
    /// (counted, not fatal).
    pub board_fifo_overflows: u64,
    pub board_quadrature_errors: u64,
    /// What the loop actually obtained: "SCHED_FIFO 80", "SCHED_OTHER", ...
    pub scheduling: String,
    /// "off", "writing PATH (rows)", "failed: reason".
    pub recorder: String,
    pub telemetry_drops: u64,
    pub experiment: ExperimentStatus,
    /// Round trip features -> force, as the loop observed it.
    pub round_trip_latency: Latency,
    /// Realtime steps that ended after the next period had begun.
    pub overruns: u64,
    /// |actual period - nominal period| (realtime clock).
    pub period_jitter: Latency,
    /// The passivity layer of the current (or last) run.
    pub passivity: PassivityStatus,
}

/// The passivity layer's figures (rt-loop's passivity module): whether its damper acts, the
/// energy the rendered object holds, received and returned (J, positive = into the object),
/// the largest damping it applied (N s/m) and the steps it acted on.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct PassivityStatus {
    pub on: bool,
    pub energy_j: f64,
    pub received_j: f64,
    pub returned_j: f64,
    pub damping_ns_per_m: f64,
    pub active_steps: u64,
}

impl LoopStatus {
    /// Whether the current (or last) run's recording failed: rt-loop's recorder text then
    /// starts with "failed" (`rt-loop/src/serving/shm_io.rs`, the recorder's status words).
    pub fn recorder_failed(&self) -> bool {
        self.recorder.starts_with("failed")
    }
}

/// The server side of the status.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ServerStatus {
    /// Ring to ring, measured by the server.
    pub inference_latency: Latency,
    pub predictions: u64,
    pub uptime_s: f64,
    pub version: String,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct StatusSnapshot {
    pub loop_status: LoopStatus,
    pub server: ServerStatus,
    pub active_model: Option<ModelInfo>,
}

/// The experiments the loop knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExperimentKind {
    Abstraction,
    Reproduction,
    Shadow,
    PositionReplay,
}

impl ExperimentKind {
    pub const ALL: [ExperimentKind; 4] = [
        Self::Abstraction,
        Self::Reproduction,
        Self::Shadow,
        Self::PositionReplay,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Self::Abstraction => "abstraction",
            Self::Reproduction => "reproduction",
            Self::Shadow => "shadow",
            Self::PositionReplay => "position-replay",
        }
    }
}

impl FromStr for ExperimentKind {
    type Err = ControlError;
    fn from_str(s: &str) -> Result<Self, ControlError> {
        Self::ALL
            .into_iter()
            .find(|k| k.as_str() == s)
            .ok_or_else(|| {
                ControlError::InvalidArgument(format!(
                    "unknown experiment kind {s:?}: expected one of abstraction, reproduction, \
                     shadow, position-replay"
                ))
            })
    }
}

/// A validated request to start an experiment. `None` parameters take the loop's defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct ExperimentRequest {
    pub kind: ExperimentKind,
    /// N/s, finite and > 0.
    pub ramp_rate: Option<f64>,
    /// > 0.
    pub cycles: Option<u32>,
    /// N, finite and > 0.
    pub f_max_start: Option<f64>,
    /// N, finite and >= 0.
    pub f_max_step: Option<f64>,
}

impl ExperimentRequest {
    /// Checks a request as it comes from a client; the error names the bad parameter.
    pub fn new(
        kind: &str,
        ramp_rate: Option<f64>,
        cycles: Option<u32>,
        f_max_start: Option<f64>,
        f_max_step: Option<f64>,
    ) -> Result<Self, ControlError> {
        let kind: ExperimentKind = kind.parse()?;
        let positive = |name: &str, v: Option<f64>, allow_zero: bool| match v {
            Some(x) if !x.is_finite() || x < 0.0 || (x == 0.0 && !allow_zero) => {
                Err(ControlError::InvalidArgument(format!(
                    "{name} must be a finite number {} 0, got {x}",
                    if allow_zero { ">=" } else { ">" }
                )))
            }
            _ => Ok(v),
        };
        let ramp_rate = positive("ramp_rate", ramp_rate, false)?;
        let f_max_start = positive("f_max_start", f_max_start, false)?;
        let f_max_step = positive("f_max_step", f_max_step, true)?;
        if cycles == Some(0) {
            return Err(ControlError::InvalidArgument(
                "cycles must be > 0".to_string(),
            ));
        }
        Ok(Self {
            kind,
            ramp_rate,
            cycles,
            f_max_start,
            f_max_step,
        })
    }
}

/// Checks a model name from a client: a plain file name, so a name can never reach outside the
/// model directory.
pub fn validate_model_name(name: &str) -> Result<(), ControlError> {
    let bad = |why: &str| {
        Err(ControlError::InvalidArgument(format!(
            "invalid model name {name:?}: {why}"
        )))
    };
    if name.is_empty() {
        return bad("empty");
    }
    if name.len() > 255 {
        return bad("longer than 255 bytes");
    }
    if name == "." || name == ".." || name.contains('/') || name.contains('\\') {
        return bad("must be a file name inside the model directory, not a path");
    }
    if name.chars().any(char::is_control) {
        return bad("contains control characters");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_cannot_escape_the_model_directory() {
        for bad in ["", ".", "..", "../x.onnx", "a/b.onnx", "a\\b", "x\n.onnx"] {
            assert!(
                matches!(
                    validate_model_name(bad),
                    Err(ControlError::InvalidArgument(_))
                ),
                "{bad:?}"
            );
        }
        for good in ["rf.onnx", "lstm-v2.onnx", "..hidden.onnx"] {
            validate_model_name(good).unwrap();
        }
    }

    #[test]
    fn experiment_parameters_are_checked() {
        let ok = ExperimentRequest::new("abstraction", Some(2.1), Some(10), None, Some(0.0));
        assert_eq!(ok.unwrap().kind, ExperimentKind::Abstraction);
        for (kind, rate, cycles, start) in [
            ("dance", None, None, None),
            ("shadow", Some(0.0), None, None),
            ("shadow", Some(f64::NAN), None, None),
            ("shadow", None, Some(0), None),
            ("shadow", None, None, Some(-1.0)),
        ] {
            let e = ExperimentRequest::new(kind, rate, cycles, start, None).unwrap_err();
            assert!(matches!(e, ControlError::InvalidArgument(_)), "{e}");
        }
        assert_eq!(
            "position-replay".parse::<ExperimentKind>().unwrap(),
            ExperimentKind::PositionReplay
        );
    }
}
