//! `control_plane::Backend` for infer-server: the model registry, the status read from the
//! segment, the inference thread's counters and the telemetry thread, and experiments posted
//! into the segment's command mailbox.
//!
//! Every method runs on the control plane's blocking pool. `status` reads atomics and one
//! histogram snapshot only (it never waits on the loop or on a registry operation).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use control_plane::{
    Activation, Backend, ControlError, ExperimentRequest, ExperimentStatus, Latency, LoopStatus,
    ModelInfo, ModelSource, ServerStatus, StatusSnapshot, TelemetryBatch, TelemetryHub,
};
use haptics_proto::experiment_args::ExperimentArgs;
use haptics_proto::Command;
use shm_ring::{FixedStr, SendError};

use crate::control::registry::Registry;
use crate::control::telemetry::LoopObserver;
use crate::serving::latency::LatencySnapshot;
use haptics_proto::{Phase, PHASE_NAMES};

const PHASE_DONE: u8 = Phase::Done as u8;

/// How long a posted start counts as running before the loop's telemetry confirms it.
const START_GRACE: Duration = Duration::from_millis(1500);

/// The experiment this server last asked the loop to start.
#[derive(Debug, Clone)]
struct Requested {
    kind: &'static str,
    at: Instant,
    attachment: u64,
    /// Rows received when it was posted: later rows show whether the loop runs it.
    rows_then: u64,
}

pub struct ControlBackend {
    registry: Arc<Registry>,
    hub: TelemetryHub,
    observer: Arc<LoopObserver>,
    started: Instant,
    version: String,
    requested: Mutex<Option<Requested>>,
    next_command_id: AtomicU64,
}

/// An experiment request as a mailbox command: the experiment's kind (`abstraction`,
/// `reproduction`, `shadow`, `position-replay`) and the options it sets; `None` leaves the
/// loop's default.
pub fn start_command(id: u64, request: &ExperimentRequest) -> Command {
    Command::Start {
        id,
        experiment: FixedStr::new(request.kind.as_str()).expect("experiment kinds are short"),
        args: ExperimentArgs {
            ramp_rate: request.ramp_rate,
            cycles: request.cycles,
            f_max_start: request.f_max_start,
            f_max_step: request.f_max_step,
        },
    }
}

/// The stop command.
pub fn stop_command(id: u64) -> Command {
    Command::Stop { id }
}

fn latency_of(s: &LatencySnapshot) -> Latency {
    let us = |ns: u64| ns as f64 / 1000.0;
    if s.count == 0 {
        return Latency::default();
    }
    Latency {
        p50_us: us(s.quantile(0.5)),
        p99_us: us(s.quantile(0.99)),
        p999_us: us(s.quantile(0.999)),
        max_us: us(s.max),
        count: s.count,
    }
}

/// The loop's own figures (the loop-status block) into the control plane's status: clock,
/// board, scheduling obtained, recorder state, and the current (or last) run's fallbacks,
/// deadline misses and round-trip percentiles as the loop counted them (exact, where the
/// telemetry rows only give a lower bound once rows were dropped).
pub fn apply_loop_block(status: &mut LoopStatus, b: &haptics_proto::LoopStatus) {
    let us = |ns: u64| ns as f64 / 1000.0;
    status.clock = b.clock.as_str().into();
    status.board = b.board.as_str().into();
    status.scheduling = if b.running || b.steps == 0 {
        b.scheduling.as_str().into()
    } else {
        format!("idle (last run: {})", b.scheduling)
    };
    status.recorder = b.recorder.as_str().into();
    if b.steps > 0 {
        status.fallbacks = b.fallbacks;
        status.deadline_misses = b.deadline_misses;
        status.on_time = b.on_time;
        status.late_one = b.late_one;
        status.held = b.held;
        status.fallback = b.fallback_steps;
        status.max_transition_step_n = b.max_transition_step_n;
        status.saturated = b.saturated;
        status.passivity = control_plane::backend::PassivityStatus {
            on: b.passivity_on,
            energy_j: b.passivity_energy_j,
            received_j: b.passivity_received_j,
            returned_j: b.passivity_returned_j,
            damping_ns_per_m: b.passivity_damping_ns_per_m,
            active_steps: b.passivity_active_steps,
        };
    }
    status.corrupt = b.corrupt;
    status.board_faults = b.board_faults;
    status.board_fault = b.board_fault.as_str().into();
    status.board_fifo_overflows = b.board_fifo_overflows;
    status.board_quadrature_errors = b.board_quadrature_errors;
    // The loop knows which experiment it runs; the rows' phase cannot tell a shadow run
    // (an autostarted one included) from a reproduction.
    if status.experiment.running && b.running && !b.experiment.is_empty() {
        status.experiment.kind = b.experiment.as_str().into();
    }
    let lat = |q: &haptics_proto::Quantiles| Latency {
        p50_us: us(q.p50_ns),
        p99_us: us(q.p99_ns),
        p999_us: us(q.p999_ns),
        max_us: us(q.max_ns),
        count: q.count,
    };
    if b.round_trip.count > 0 {
        status.round_trip_latency = lat(&b.round_trip);
    }
    status.overruns = b.overruns;
    if b.period_jitter.count > 0 {
        status.period_jitter = lat(&b.period_jitter);
    }
}

/// The active model as the status shows it: once the loop is gone, the step it became active at
/// belongs to a loop that no longer runs, so it is left out (the model is still the one the next
/// loop gets).
fn without_stale_step(model: Option<ModelInfo>, loop_alive: bool) -> Option<ModelInfo> {
    model.map(|mut m| {
        if !loop_alive {
            m.active_since_step = None;
        }
        m
    })
}

impl ControlBackend {
    /// The attached loop's status block, if it published one.
    fn loop_block(&self, attachment: u64) -> Option<haptics_proto::LoopStatus> {
        if attachment == 0 {
            return None;
        }
        self.registry.server().loop_status()
    }

    pub fn new(
        registry: Arc<Registry>,
        hub: TelemetryHub,
        observer: Arc<LoopObserver>,
        version: impl Into<String>,
    ) -> Self {
        Self {
            registry,
            hub,
            observer,
            started: Instant::now(),
            version: version.into(),
            requested: Mutex::new(None),
            next_command_id: AtomicU64::new(1),
        }
    }

    pub fn registry(&self) -> &Arc<Registry> {
        &self.registry
    }

    fn attachment(&self) -> u64 {
        self.registry.server().endpoints().current()
    }

    /// The experiment as the loop's telemetry (and our last request) shows it.
    fn experiment(&self, attachment: u64, alive: bool) -> ExperimentStatus {
        let idle = ExperimentStatus {
            kind: "idle".into(),
            ..Default::default()
        };
        if !alive {
            return idle;
        }
        let o = &self.observer;
        let phase = o.phase.load(Ordering::Relaxed) as u8;
        let rows = o.rows.load(Ordering::Relaxed);
        let flowing = o
            .since_last_row()
            .is_some_and(|d| d < Duration::from_millis(500));
        let requested = {
            let mut guard = self.requested.lock().unwrap_or_else(|p| p.into_inner());
            // A request is over once the loop's rows after it show it finished or stopped.
            let over = guard.as_ref().is_some_and(|r| {
                r.attachment != attachment
                    || (rows > r.rows_then && (phase == PHASE_DONE || !flowing))
                    || (rows == r.rows_then && r.at.elapsed() >= START_GRACE)
            });
            if over {
                *guard = None;
            }
            guard.clone()
        };
        // Rows since our request tell; before the first one, the request counts for a while.
        let pending = requested
            .as_ref()
            .is_some_and(|r| rows == r.rows_then && r.at.elapsed() < START_GRACE);
        let running = pending || (flowing && phase != PHASE_DONE);
        if !running {
            return idle;
        }
        let kind = match (&requested, phase) {
            (Some(r), _) => r.kind,
            (None, 4) => "position-replay",
            (None, 5) => "reproduction",
            (None, _) => "abstraction",
        };
        ExperimentStatus {
            kind: kind.into(),
            running: true,
            cycle: if pending {
                0
            } else {
                o.cycle.load(Ordering::Relaxed)
            },
            phase: if pending {
                "starting".into()
            } else {
                PHASE_NAMES
                    .get(usize::from(phase))
                    .copied()
                    .unwrap_or("unknown")
                    .into()
            },
        }
    }

    fn post(&self, command: Command) -> Result<(), ControlError> {
        let mut guard = self.registry.server().endpoints().lock();
        let Some(ep) = guard.as_mut() else {
            return Err(ControlError::FailedPrecondition(
                "no loop is attached (is rt-loop running?)".into(),
            ));
        };
        match ep.commands_tx.try_send(command) {
            Ok(()) => Ok(()),
            Err(SendError::Full(_)) | Err(SendError::Timeout(_)) => Err(ControlError::Unavailable(
                "the loop's command mailbox is full: the loop is not reading its commands".into(),
            )),
            Err(SendError::PeerGone(_)) => Err(ControlError::FailedPrecondition(
                "the loop has gone away".into(),
            )),
        }
    }
}

impl Backend for ControlBackend {
    fn list_models(&self) -> Result<Vec<ModelInfo>, ControlError> {
        self.registry.list()
    }

    fn load_model(&self, source: ModelSource) -> Result<ModelInfo, ControlError> {
        self.registry.load(source)
    }

    fn activate_model(&self, name: &str, load_if_needed: bool) -> Result<Activation, ControlError> {
        self.registry.activate(name, load_if_needed)
    }

    fn unload_model(&self, name: &str) -> Result<(), ControlError> {
        self.registry.unload(name)
    }

    fn active_model(&self) -> Option<ModelInfo> {
        self.registry.active()
    }

    fn status(&self) -> StatusSnapshot {
        let server = self.registry.server();
        let counters = server.counters();
        let attachment = self.attachment();
        let alive = self.observer.alive(attachment);
        let o = &self.observer;
        let rows = o.rows.load(Ordering::Relaxed);
        let step = if rows > 0 {
            o.last_step.load(Ordering::Relaxed)
        } else {
            counters.last_seq.load(Ordering::Relaxed)
        };
        let mut loop_status = LoopStatus {
            alive,
            rate_hz: if alive { o.rate_hz() } else { 0.0 },
            step,
            fallbacks: o.fallbacks.load(Ordering::Relaxed),
            telemetry_drops: o.dropped.load(Ordering::Relaxed),
            experiment: self.experiment(attachment, alive),
            ..LoopStatus::default()
        };
        // What the loop publishes about itself (the segment's loop-status block, ~10 Hz).
        if let Some(b) = self.loop_block(attachment) {
            apply_loop_block(&mut loop_status, &b);
        }
        StatusSnapshot {
            loop_status,
            server: ServerStatus {
                inference_latency: latency_of(&server.latency().snapshot()),
                predictions: counters.predicted.load(Ordering::Relaxed),
                uptime_s: self.started.elapsed().as_secs_f64(),
                version: self.version.clone(),
            },
            active_model: without_stale_step(self.registry.active(), alive),
        }
    }

    fn start_experiment(&self, request: &ExperimentRequest) -> Result<(), ControlError> {
        let attachment = self.attachment();
        if attachment == 0 || !self.observer.alive(attachment) {
            return Err(ControlError::FailedPrecondition(
                "no loop is attached (is rt-loop running?)".into(),
            ));
        }
        let current = self.experiment(attachment, true);
        if current.running {
            // The name the status shows: the loop's own (a shadow run's rows look like a
            // reproduction's), as `apply_loop_block` does.
            let kind = match self.loop_block(attachment) {
                Some(b) if b.running && !b.experiment.is_empty() => {
                    b.experiment.as_str().to_string()
                }
                _ => current.kind,
            };
            return Err(ControlError::FailedPrecondition(format!(
                "an experiment is already running ({kind}): stop it first (hapticctl experiment stop)"
            )));
        }
        let id = self.next_command_id.fetch_add(1, Ordering::Relaxed);
        self.post(start_command(id, request))?;
        *self.requested.lock().unwrap_or_else(|p| p.into_inner()) = Some(Requested {
            kind: request.kind.as_str(),
            at: Instant::now(),
            attachment,
            rows_then: self.observer.rows.load(Ordering::Relaxed),
        });
        Ok(())
    }

    fn stop_experiment(&self) -> Result<(), ControlError> {
        if self.attachment() == 0 {
            return Err(ControlError::FailedPrecondition(
                "no loop is attached (is rt-loop running?)".into(),
            ));
        }
        let id = self.next_command_id.fetch_add(1, Ordering::Relaxed);
        self.post(stop_command(id))?;
        *self.requested.lock().unwrap_or_else(|p| p.into_inner()) = None;
        Ok(())
    }

    fn subscribe_telemetry(&self) -> tokio::sync::broadcast::Receiver<TelemetryBatch> {
        self.hub.subscribe()
    }
}
