//! The JSON shapes of the HTTP API: the status object the page reads (docs/web-protocol.md) and
//! the model list.
use serde::Serialize;

use crate::backend::{Latency, ModelInfo, StatusSnapshot};

#[derive(Debug, Serialize)]
pub struct StatusJson {
    #[serde(rename = "type", skip_serializing_if = "Option::is_none")]
    pub kind: Option<&'static str>,
    pub server: ServerJson,
    #[serde(rename = "loop")]
    pub loop_: LoopJson,
    pub active_model: Option<ActiveModelJson>,
}

#[derive(Debug, Serialize)]
pub struct ServerJson {
    pub version: String,
    pub uptime_s: f64,
    pub token_required: bool,
    pub max_upload_bytes: u64,
    pub predictions: u64,
    pub inference_latency_us: LatencyJson,
}

#[derive(Debug, Serialize)]
pub struct LatencyJson {
    pub p50: f64,
    pub p99: f64,
    pub p999: f64,
    pub max: f64,
    pub count: u64,
}

impl From<&Latency> for LatencyJson {
    fn from(l: &Latency) -> Self {
        Self {
            p50: l.p50_us,
            p99: l.p99_us,
            p999: l.p999_us,
            max: l.max_us,
            count: l.count,
        }
    }
}

#[derive(Debug, Serialize)]
pub struct LoopJson {
    pub alive: bool,
    pub clock: String,
    pub board: String,
    pub rate_hz: f64,
    pub steps: u64,
    pub deadline_misses: u64,
    pub fallbacks: u64,
    /// Degradation ladder (issue 14): every step of the run in exactly one of these four.
    pub on_time: u64,
    pub late_one: u64,
    pub held: u64,
    pub fallback: u64,
    pub corrupt: u64,
    pub max_transition_step_n: f64,
    /// Steps rendered at the force limit (a model answered above it).
    pub saturated: u64,
    /// Board failures that ended a run (each at 0 A), the last one's reason, and the run's
    /// counted non-fatal troubles.
    pub board_faults: u64,
    pub board_fault: String,
    pub board_fifo_overflows: u64,
    pub board_quadrature_errors: u64,
    pub latency_us: LatencyJson,
    pub experiment: ExperimentJson,
    pub scheduling: String,
    pub recorder: String,
    pub recorder_failed: bool,
    pub telemetry_drops: u64,
    pub overruns: u64,
    pub period_jitter_us: LatencyJson,
    /// The passivity layer of the current (or last) run.
    pub passivity: crate::backend::PassivityStatus,
}

#[derive(Debug, Serialize)]
pub struct ExperimentJson {
    pub kind: String,
    pub running: bool,
    pub cycle: u32,
    pub phase: String,
}

#[derive(Debug, Serialize)]
pub struct ActiveModelJson {
    pub name: String,
    pub kind: String,
    pub features: Vec<String>,
    pub since_step: Option<u64>,
    pub model_id: u32,
}

impl StatusJson {
    pub fn new(
        s: &StatusSnapshot,
        token_required: bool,
        max_upload_bytes: usize,
        kind: Option<&'static str>,
    ) -> Self {
        let l = &s.loop_status;
        Self {
            kind,
            server: ServerJson {
                version: s.server.version.clone(),
                uptime_s: s.server.uptime_s,
                token_required,
                max_upload_bytes: max_upload_bytes as u64,
                predictions: s.server.predictions,
                inference_latency_us: (&s.server.inference_latency).into(),
            },
            loop_: LoopJson {
                alive: l.alive,
                clock: l.clock.clone(),
                board: l.board.clone(),
                rate_hz: l.rate_hz,
                steps: l.step,
                deadline_misses: l.deadline_misses,
                fallbacks: l.fallbacks,
                on_time: l.on_time,
                late_one: l.late_one,
                held: l.held,
                fallback: l.fallback,
                corrupt: l.corrupt,
                max_transition_step_n: l.max_transition_step_n,
                saturated: l.saturated,
                board_faults: l.board_faults,
                board_fault: l.board_fault.clone(),
                board_fifo_overflows: l.board_fifo_overflows,
                board_quadrature_errors: l.board_quadrature_errors,
                latency_us: (&l.round_trip_latency).into(),
                experiment: ExperimentJson {
                    kind: if l.experiment.kind.is_empty() {
                        "idle".into()
                    } else {
                        l.experiment.kind.clone()
                    },
                    running: l.experiment.running,
                    cycle: l.experiment.cycle,
                    phase: l.experiment.phase.clone(),
                },
                scheduling: l.scheduling.clone(),
                recorder: l.recorder.clone(),
                recorder_failed: l.recorder_failed(),
                telemetry_drops: l.telemetry_drops,
                overruns: l.overruns,
                period_jitter_us: (&l.period_jitter).into(),
                passivity: l.passivity,
            },
            active_model: s.active_model.as_ref().map(|m| ActiveModelJson {
                name: m.name.clone(),
                kind: m.kind.clone(),
                features: m.features.clone(),
                since_step: m.active_since_step,
                model_id: m.model_id,
            }),
        }
    }
}

#[derive(Debug, Serialize)]
pub struct ModelJson {
    pub name: String,
    pub state: &'static str,
    pub kind: String,
    pub features: Vec<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    pub units: String,
    pub size_bytes: u64,
    pub model_id: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub active_since_step: Option<u64>,
    /// The model's provenance, parsed when it is JSON (else the raw string).
    pub provenance: serde_json::Value,
    /// What one call costs: `{"export": .., "warmup": ..}` (null when not loaded).
    pub cost: serde_json::Value,
    /// The reference steps checked at load, all agreeing (0: none carried, or not loaded).
    pub reference_steps: u32,
}

impl From<&ModelInfo> for ModelJson {
    fn from(m: &ModelInfo) -> Self {
        Self {
            name: m.name.clone(),
            state: m.state.as_str(),
            kind: m.kind.clone(),
            features: m.features.clone(),
            error: m.error.clone(),
            units: m.units.clone(),
            size_bytes: m.size_bytes,
            model_id: m.model_id,
            active_since_step: m.active_since_step,
            provenance: if m.provenance_json.is_empty() {
                serde_json::Value::Null
            } else {
                serde_json::from_str(&m.provenance_json)
                    .unwrap_or_else(|_| serde_json::Value::String(m.provenance_json.clone()))
            },
            cost: serde_json::from_str(&m.cost_json).unwrap_or(serde_json::Value::Null),
            reference_steps: m.reference_steps,
        }
    }
}
