//! The control side in one object: the inference thread, the active model, validation and
//! activation. This is what `infer-server serve` runs and what the gRPC and web layers call
//! (share it as `Arc<InferenceControl>`: every method takes `&self`).
//!
//! Activation: load and validate on the caller's thread (never the inference thread), against
//! the schema of the segment the thread is attached to (the standard nine while detached), then
//! hand the engine over with one atomic swap ([`crate::serving::handoff`]). A refused model leaves the
//! active one in place, and the error says why.

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Mutex;
use std::time::Duration;

use haptics_proto::LoopStatusLink;

use crate::model::contract::FeatureSchema;
use crate::model::engine::StepEngine;
use crate::model::runtime::Runtime;
use crate::model::{ModelError, ModelInfo, SessionConfig};
use crate::serving::attachment::SharedEndpoints;
use crate::serving::handoff::{self, Activator, Offered};
use crate::serving::inference_thread::{
    InferenceConfig, InferenceError, InferenceThread, StatsSnapshot,
};
use crate::serving::latency::LatencyReader;

/// The model the control side last activated.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ActiveModel {
    pub generation: u64,
    pub path: PathBuf,
    pub info: ModelInfo,
}

/// What [`InferenceControl::maintain`] did.
#[derive(Debug)]
pub enum MaintenanceEvent {
    /// A loop with another feature schema attached; the active model was revalidated against it
    /// and re-activated.
    Revalidated(Box<ActiveModel>),
    /// ... and the active model does not fit the new schema. The inference thread answers
    /// NaN + SCHEMA_MISMATCH (the loop renders its fallback) until another model is activated.
    RevalidationFailed { path: PathBuf, error: ModelError },
}

struct Control {
    activator: Activator,
    active: Option<ActiveModel>,
}

pub struct InferenceControl {
    rt: &'static Runtime,
    session: SessionConfig,
    thread: InferenceThread,
    control: Mutex<Control>,
}

impl InferenceControl {
    /// Starts the inference thread (it attaches to `cfg.segment` by itself, and again whenever
    /// a new loop creates it). No model is active yet.
    pub fn start(
        rt: &'static Runtime,
        cfg: InferenceConfig,
        session: SessionConfig,
    ) -> Result<Self, InferenceError> {
        let (activator, taker) = handoff::channel();
        let thread = InferenceThread::spawn(cfg, taker)?;
        Ok(Self {
            rt,
            session,
            thread,
            control: Mutex::new(Control {
                activator,
                active: None,
            }),
        })
    }

    pub fn runtime(&self) -> &'static Runtime {
        self.rt
    }

    /// How sessions are configured (threads, spinning, warm-up).
    pub fn session_config(&self) -> &SessionConfig {
        &self.session
    }

    /// The schema models are validated against now: the attached segment's, else the nine.
    pub fn schema(&self) -> FeatureSchema {
        self.thread
            .segment_schema()
            .unwrap_or_else(FeatureSchema::standard)
    }

    /// Validates `path` against the current schema without activating it.
    pub fn validate(&self, path: &Path) -> Result<ModelInfo, ModelError> {
        StepEngine::load(self.rt, path, &self.schema(), &self.session).map(|e| e.info().clone())
    }

    /// Loads, validates and activates `path`. The inference thread switches before its next
    /// step; a refused model leaves the active one running.
    pub fn activate(&self, path: &Path) -> Result<ActiveModel, ModelError> {
        let schema = self.schema();
        let engine = StepEngine::load(self.rt, path, &schema, &self.session)?;
        Ok(self.activate_engine(engine, path))
    }

    /// Activates an engine loaded earlier (e.g. kept by a model registry). Its state is reset.
    pub fn activate_engine(&self, engine: StepEngine, path: &Path) -> ActiveModel {
        let info = engine.info().clone();
        let mut control = self.control.lock().unwrap_or_else(|p| p.into_inner());
        let generation = control.activator.offer(engine);
        let active = ActiveModel {
            generation,
            path: path.to_path_buf(),
            info,
        };
        control.active = Some(active.clone());
        active
    }

    /// The first step (`FeatureMsg::seq`) that `generation` answered, once it has answered one.
    pub fn effective_step(&self, generation: u64) -> Option<u64> {
        let s = self.thread.stats();
        (s.effective_generation.load(Ordering::Acquire) == generation)
            .then(|| s.effective_seq.load(Ordering::Relaxed))
    }

    /// Waits (sleeping) until `generation` has answered a step, up to `timeout`; returns that
    /// step. `None` at the timeout (e.g. no loop is attached, or a newer model replaced it).
    pub fn wait_effective(&self, generation: u64, timeout: Duration) -> Option<u64> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            if let Some(step) = self.effective_step(generation) {
                return Some(step);
            }
            if std::time::Instant::now() >= deadline {
                return None;
            }
            std::thread::sleep(Duration::from_micros(500));
        }
    }

    /// Waits (sleeping) until the inference thread runs `generation` or later.
    pub fn wait_active(&self, generation: u64, timeout: Duration) -> bool {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            if self.thread.stats().snapshot().model_generation >= generation
                || self
                    .control
                    .lock()
                    .map(|c| c.activator.active_generation() >= generation)
                    .unwrap_or(false)
            {
                return true;
            }
            if std::time::Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// The model last activated (it becomes the running one at the inference thread's next
    /// step; [`InferenceControl::stats`]`.model_generation` says which one answered last).
    pub fn active(&self) -> Option<ActiveModel> {
        self.control
            .lock()
            .map(|c| c.active.clone())
            .unwrap_or(None)
    }

    /// Housekeeping, every few tens of milliseconds from any control thread: drops the engine
    /// the inference thread gave back, and revalidates the active model when a loop with a
    /// different feature schema has attached.
    pub fn maintain(&self) -> Option<MaintenanceEvent> {
        let (path, validated_for) = {
            let mut control = self.control.lock().unwrap_or_else(|p| p.into_inner());
            control.activator.collect_retired();
            let active = control.active.as_ref()?;
            (active.path.clone(), active.info.schema.clone())
        };
        let schema = self.thread.segment_schema()?;
        if schema.names() == validated_for.as_slice() {
            return None;
        }
        match StepEngine::load(self.rt, &path, &schema, &self.session) {
            Ok(engine) => {
                let info = engine.info().clone();
                let mut control = self.control.lock().unwrap_or_else(|p| p.into_inner());
                let generation = control.activator.offer(engine);
                let active = ActiveModel {
                    generation,
                    path,
                    info,
                };
                control.active = Some(active.clone());
                Some(MaintenanceEvent::Revalidated(Box::new(active)))
            }
            Err(error) => {
                // Remember the schema it failed for, so the failure is reported once.
                let mut control = self.control.lock().unwrap_or_else(|p| p.into_inner());
                if let Some(a) = control.active.as_mut() {
                    a.info.schema = schema.names().to_vec();
                }
                Some(MaintenanceEvent::RevalidationFailed { path, error })
            }
        }
    }

    /// Takes back an engine the inference thread has replaced (a registry keeps it loaded);
    /// `None` when none is waiting. Until it is collected the thread takes no newer offer.
    pub fn collect_retired(&self) -> Option<Box<Offered>> {
        let mut control = self.control.lock().unwrap_or_else(|p| p.into_inner());
        control.activator.collect_retired()
    }

    /// Takes back the pending offer of `generation` if the inference thread has not taken it
    /// (no loop attached), and makes `previous` the active model again. `None`: it was taken
    /// (or another offer replaced it) and nothing changed.
    pub fn withdraw(&self, generation: u64, previous: Option<ActiveModel>) -> Option<Box<Offered>> {
        let mut control = self.control.lock().unwrap_or_else(|p| p.into_inner());
        if control.active.as_ref().map(|a| a.generation) != Some(generation) {
            return None;
        }
        let offered = control.activator.withdraw()?;
        if offered.generation != generation {
            // Not ours (cannot happen while activations are serialised): put nothing back.
            return Some(offered);
        }
        control.active = previous;
        Some(offered)
    }

    /// Generation of the engine the inference thread has taken (0: none).
    pub fn running_generation(&self) -> u64 {
        let control = self.control.lock().unwrap_or_else(|p| p.into_inner());
        control.activator.active_generation()
    }

    /// Whether the inference thread is attached to a loop's segment now.
    pub fn attached(&self) -> bool {
        self.thread.stats().attached.load(Ordering::Relaxed)
    }

    /// The attached loop's status block, if it published one (a short lock on the endpoints,
    /// then a seqlock read: never waits on the loop).
    pub fn loop_status(&self) -> Option<haptics_proto::LoopStatus> {
        let link = self.endpoints().lock().as_ref().map(|ep| ep.link.clone())?;
        link.loop_status()
    }

    /// The telemetry ring, command mailbox and link of the current attachment.
    pub fn endpoints(&self) -> &std::sync::Arc<SharedEndpoints> {
        self.thread.endpoints()
    }

    /// The inference thread's counters, read in place (cheap: no snapshot of all of them).
    pub fn counters(&self) -> &crate::serving::inference_thread::InferenceCounters {
        self.thread.stats()
    }

    pub fn stats(&self) -> StatsSnapshot {
        self.thread.stats().snapshot()
    }

    /// Ring-to-ring latency of every answered step (ns); snapshot it without stopping the thread.
    pub fn latency(&self) -> &LatencyReader {
        self.thread.latency()
    }

    /// Whether the inference thread has ended (only with `exit_when_loop_gone`, or on an error).
    pub fn is_finished(&self) -> bool {
        self.thread.is_finished()
    }

    /// Asks the inference thread to stop, without waiting ([`InferenceControl::is_finished`] tells when
    /// it has; for a `InferenceControl` shared in an `Arc`).
    pub fn request_stop(&self) {
        self.thread.request_stop();
    }

    /// Stops the inference thread (or collects its end) and reports how it ended.
    pub fn shutdown(self) -> Result<(), InferenceError> {
        if self.thread.is_finished() {
            self.thread.join()
        } else {
            self.thread.stop()
        }
    }
}
