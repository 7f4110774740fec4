//! The control plane's simulated backend: an in-memory `control_plane::Backend` over a
//! simulated loop, for the tests of control-plane and hapticctl (and, as the `control-plane-sim`
//! binary, for developing the page). Test support, not shipped: it lives under `tests/`, not in
//! the control-plane library. It keeps real state (a model directory, loaded models, the active
//! one, experiments) and a loop thread that steps at `rate_hz` in wall-clock time and publishes
//! telemetry through the control plane's own types, so the services are tested against something
//! that behaves like infer-server. Its "model files" are small JSON documents, not ONNX:
//! `{"kind": "stateless", "features": ["position_x", "velocity"], "gain": 1.0, "warmup": "ok"}`.
//! The real processes (rt-loop on the simulated bench + infer-server) are the end-to-end tests'.
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serde::Deserialize;
use tokio::sync::broadcast;

use control_plane::backend::*;
use control_plane::telemetry::{series, Bucket, TelemetryBatch, TelemetryHub, N_SERIES};
use control_plane::ControlError;

/// Features the simulated loop provides: the real loop's schema (the segment's feature names,
/// from haptics-proto), so a model file that fits the sim fits rt-loop and the other way round.
pub const SCHEMA: &[&str] = &haptics_proto::features::SCHEMA_NAMES;
/// Every `SPIKE_EVERY` steps F_res has a spike of `SPIKE_N` newtons, so tests can check that
/// decimation keeps spikes.
pub const SPIKE_EVERY: u64 = 997;
pub const SPIKE_N: f64 = 50.0;

#[derive(Debug, Deserialize)]
struct SimModelFile {
    kind: String,
    features: Vec<String>,
    #[serde(default = "one")]
    gain: f64,
    /// "ok" or "nan": what the warm-up run produces.
    #[serde(default)]
    warmup: Option<String>,
}

fn one() -> f64 {
    1.0
}

/// The bytes of a simulated model file.
pub fn model_file(features: &[&str], gain: f64) -> Vec<u8> {
    serde_json::json!({ "kind": "stateless", "features": features, "gain": gain })
        .to_string()
        .into_bytes()
}

/// A model whose warm-up outputs NaN.
pub fn nan_model_file() -> Vec<u8> {
    serde_json::json!({ "kind": "stateless", "features": ["position_x"], "warmup": "nan" })
        .to_string()
        .into_bytes()
}

struct Loaded {
    info: ModelInfo,
    gain: f64,
}

struct State {
    directory: BTreeMap<String, Vec<u8>>,
    /// Loaded models, and failed loads (info.state == Failed).
    models: BTreeMap<String, Loaded>,
    active: Option<String>,
    alive: bool,
    experiment: ExperimentStatus,
    last_experiment: Option<ExperimentRequest>,
    next_model_id: u32,
    /// The next step the loop will run.
    step: u64,
    fallbacks: u64,
    predictions: u64,
    swaps: Vec<u64>,
    /// When the current run started (wall clock sets the step count).
    run_start: Instant,
}

struct Inner {
    state: Mutex<State>,
    hub: TelemetryHub,
    stop: AtomicBool,
    rate_hz: f64,
    started: Instant,
}

pub struct SimBackend {
    inner: Arc<Inner>,
    thread: Option<JoinHandle<()>>,
}

impl SimBackend {
    /// A loop at `rate_hz` with the given "files" in its model directory.
    pub fn new(rate_hz: f64, directory: Vec<(String, Vec<u8>)>) -> Arc<Self> {
        let inner = Arc::new(Inner {
            state: Mutex::new(State {
                directory: directory.into_iter().collect(),
                models: BTreeMap::new(),
                active: None,
                alive: true,
                experiment: ExperimentStatus {
                    kind: "idle".into(),
                    ..Default::default()
                },
                last_experiment: None,
                next_model_id: 1,
                step: 0,
                fallbacks: 0,
                predictions: 0,
                swaps: Vec::new(),
                run_start: Instant::now(),
            }),
            hub: TelemetryHub::new(1024),
            stop: AtomicBool::new(false),
            rate_hz,
            started: Instant::now(),
        });
        let thread_inner = Arc::clone(&inner);
        let thread = std::thread::Builder::new()
            .name("sim-loop".into())
            .spawn(move || run_loop(&thread_inner))
            .expect("spawn sim loop");
        Arc::new(Self {
            inner,
            thread: Some(thread),
        })
    }

    /// A directory with `a.onnx` (gain 1) and `b.onnx` (gain 2), both valid.
    pub fn with_two_models(rate_hz: f64) -> Arc<Self> {
        Self::new(
            rate_hz,
            vec![
                (
                    "a.onnx".into(),
                    model_file(&["position_x", "velocity"], 1.0),
                ),
                (
                    "b.onnx".into(),
                    model_file(&["position_x", "velocity"], 2.0),
                ),
            ],
        )
    }

    /// Detaches (false) or re-attaches (true) the simulated loop; a re-attached loop is a new
    /// run that starts again at step 0.
    pub fn set_loop_alive(&self, alive: bool) {
        let mut s = self.lock();
        if alive && !s.alive {
            s.step = 0;
            s.run_start = Instant::now();
        }
        s.alive = alive;
    }

    pub fn last_experiment(&self) -> Option<ExperimentRequest> {
        self.lock().last_experiment.clone()
    }

    /// Effective steps of every swap so far.
    pub fn swaps(&self) -> Vec<u64> {
        self.lock().swaps.clone()
    }

    pub fn step(&self) -> u64 {
        self.lock().step
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.inner.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn load_locked(s: &mut State, source: ModelSource) -> Result<ModelInfo, ControlError> {
        let name = source.name().to_string();
        if s.active.as_deref() == Some(name.as_str()) {
            return Err(ControlError::FailedPrecondition(format!(
                "{name} is active: activate another model before reloading it"
            )));
        }
        let bytes = match source {
            ModelSource::Upload { bytes, .. } => {
                s.directory.insert(name.clone(), bytes.clone());
                bytes
            }
            ModelSource::Directory { .. } => s.directory.get(&name).cloned().ok_or_else(|| {
                ControlError::NotFound(format!("no model {name:?} in the model directory"))
            })?,
        };
        let result = validate(&bytes);
        match result {
            Ok(file) => {
                let id = s.next_model_id;
                s.next_model_id += 1;
                let info = ModelInfo {
                    name: name.clone(),
                    state: ModelState::Loaded,
                    kind: file.kind,
                    features: file.features,
                    units: "N".into(),
                    provenance_json: r#"{"trainer":"sim"}"#.into(),
                    error: None,
                    size_bytes: bytes.len() as u64,
                    model_id: id,
                    active_since_step: None,
                    cost_json: String::new(),
                    reference_steps: 0,
                };
                s.models.insert(
                    name,
                    Loaded {
                        info: info.clone(),
                        gain: file.gain,
                    },
                );
                Ok(info)
            }
            Err(e) => {
                let mut info = ModelInfo::available(name.clone(), bytes.len() as u64);
                info.state = ModelState::Failed;
                info.error = Some(e.to_string());
                s.models.insert(name, Loaded { info, gain: 0.0 });
                Err(e)
            }
        }
    }
}

fn validate(bytes: &[u8]) -> Result<SimModelFile, ControlError> {
    let file: SimModelFile = serde_json::from_slice(bytes)
        .map_err(|e| ControlError::InvalidArgument(format!("not a model file: {e}")))?;
    if file.kind != "stateless" && file.kind != "stateful" {
        return Err(ControlError::InvalidArgument(format!(
            "haptics.kind is {:?}, expected stateless or stateful",
            file.kind
        )));
    }
    if let Some(missing) = file.features.iter().find(|f| !SCHEMA.contains(&f.as_str())) {
        return Err(ControlError::FailedPrecondition(format!(
            "the model needs feature {missing:?}, which the loop does not provide (it has {})",
            SCHEMA.join(", ")
        )));
    }
    if file.warmup.as_deref() == Some("nan") || !file.gain.is_finite() {
        return Err(ControlError::InvalidArgument(
            "the warm-up run produced NaN".into(),
        ));
    }
    Ok(file)
}

impl Drop for SimBackend {
    fn drop(&mut self) {
        self.inner.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The simulated loop: every 2 ms, runs the steps that wall-clock time asks for and publishes
/// them as one batch of single-step buckets. Sleeps between batches (never spins).
fn run_loop(inner: &Inner) {
    let period = Duration::from_millis(2);
    while !inner.stop.load(Ordering::Relaxed) {
        std::thread::sleep(period);
        let mut s = inner.state.lock().unwrap_or_else(|e| e.into_inner());
        if !s.alive {
            continue;
        }
        let target = (s.run_start.elapsed().as_secs_f64() * inner.rate_hz) as u64;
        if target <= s.step {
            continue;
        }
        let gain = s
            .active
            .as_ref()
            .and_then(|n| s.models.get(n))
            .map(|m| m.gain);
        let ramp = s.experiment.running;
        let mut batch = Vec::with_capacity((target - s.step) as usize);
        for i in s.step..target {
            let t = i as f64 / inner.rate_hz;
            let w = std::f64::consts::TAU;
            let x = 0.001 * (1.0 - (w * t).cos());
            let v = 0.001 * w * (w * t).sin();
            let a = 0.001 * w * w * (w * t).cos();
            let f_true = 2000.0 * x + 5.0 * v;
            let mut values = [0.0; N_SERIES];
            values[series::F_REF] = if ramp { 2.0 * (t % 2.0) } else { 0.0 };
            values[series::RTOB_FORCE] = f_true + if i % SPIKE_EVERY == 0 { SPIKE_N } else { 0.0 };
            values[series::F_PRED] = gain.map_or(f64::NAN, |g| g * f_true);
            values[series::POSITION_X] = x;
            values[series::VELOCITY] = v;
            values[series::ACCELERATION] = a;
            values[series::F_TRUE] = f_true;
            // no hand in this simulation: the felt force is the object's own
            values[series::F_OBJECT] = f_true;
            batch.push(Bucket::step(i, t, values, gain.is_none()));
        }
        let n = target - s.step;
        if gain.is_some() {
            s.predictions += n;
        } else {
            s.fallbacks += n;
        }
        s.step = target;
        drop(s);
        inner.hub.publish(batch);
    }
}

impl Backend for SimBackend {
    fn list_models(&self) -> Result<Vec<ModelInfo>, ControlError> {
        let s = self.lock();
        let mut out: BTreeMap<String, ModelInfo> = s
            .directory
            .iter()
            .map(|(n, b)| (n.clone(), ModelInfo::available(n.clone(), b.len() as u64)))
            .collect();
        for (n, m) in &s.models {
            out.insert(n.clone(), m.info.clone());
        }
        if let Some(a) = &s.active {
            if let Some(m) = out.get_mut(a) {
                m.state = ModelState::Active;
            }
        }
        Ok(out.into_values().collect())
    }

    fn load_model(&self, source: ModelSource) -> Result<ModelInfo, ControlError> {
        Self::load_locked(&mut self.lock(), source)
    }

    fn activate_model(&self, name: &str, load_if_needed: bool) -> Result<Activation, ControlError> {
        let mut s = self.lock();
        let loaded = matches!(s.models.get(name), Some(m) if m.info.state == ModelState::Loaded);
        if !loaded && s.active.as_deref() != Some(name) {
            if !s.directory.contains_key(name) {
                return Err(ControlError::NotFound(format!("no model {name:?}")));
            }
            if !load_if_needed {
                return Err(ControlError::FailedPrecondition(format!(
                    "{name} is not loaded: load it first"
                )));
            }
            Self::load_locked(&mut s, ModelSource::Directory { name: name.into() })?;
        }
        if !s.alive {
            return Err(ControlError::FailedPrecondition(
                "no loop is attached to answer".into(),
            ));
        }
        // The loop thread takes the lock for each batch: the next step it runs is the first
        // one the new model answers.
        let effective_step = s.step;
        if let Some(prev) = s.active.take() {
            if let Some(m) = s.models.get_mut(&prev) {
                m.info.state = ModelState::Loaded;
                m.info.active_since_step = None;
            }
        }
        let m = s.models.get_mut(name).expect("loaded above");
        m.info.state = ModelState::Active;
        m.info.active_since_step = Some(effective_step);
        let model = m.info.clone();
        s.active = Some(name.into());
        s.swaps.push(effective_step);
        Ok(Activation {
            model,
            effective_step,
            warnings: Vec::new(),
        })
    }

    fn unload_model(&self, name: &str) -> Result<(), ControlError> {
        let mut s = self.lock();
        if s.active.as_deref() == Some(name) {
            return Err(ControlError::FailedPrecondition(format!(
                "{name} is the active model: activate another one first"
            )));
        }
        match s.models.remove(name) {
            Some(_) => Ok(()),
            None => Err(ControlError::NotFound(format!("no loaded model {name:?}"))),
        }
    }

    fn active_model(&self) -> Option<ModelInfo> {
        let s = self.lock();
        s.active
            .as_ref()
            .and_then(|n| s.models.get(n))
            .map(|m| m.info.clone())
    }

    fn status(&self) -> StatusSnapshot {
        let s = self.lock();
        let active_model = s
            .active
            .as_ref()
            .and_then(|n| s.models.get(n))
            .map(|m| m.info.clone());
        let latency = Latency {
            p50_us: 6.0,
            p99_us: 14.0,
            p999_us: 31.0,
            max_us: 40.0,
            count: s.predictions,
        };
        StatusSnapshot {
            loop_status: LoopStatus {
                alive: s.alive,
                clock: "realtime".into(),
                board: "sim".into(),
                rate_hz: if s.alive { self.inner.rate_hz } else { 0.0 },
                step: s.step,
                fallbacks: s.fallbacks,
                deadline_misses: 0,
                // the simulated loop has no ladder: a step is served or falls back
                on_time: s.predictions,
                late_one: 0,
                held: 0,
                fallback: s.fallbacks,
                corrupt: 0,
                max_transition_step_n: 0.0,
                saturated: 0,
                board_faults: 0,
                board_fault: String::new(),
                board_fifo_overflows: 0,
                board_quadrature_errors: 0,
                scheduling: "SCHED_OTHER".into(),
                recorder: "off".into(),
                telemetry_drops: 0,
                experiment: s.experiment.clone(),
                round_trip_latency: latency,
                overruns: 0,
                period_jitter: Latency::default(),
                passivity: Default::default(),
            },
            server: ServerStatus {
                inference_latency: latency,
                predictions: s.predictions,
                uptime_s: self.inner.started.elapsed().as_secs_f64(),
                version: "sim".into(),
            },
            active_model,
        }
    }

    fn start_experiment(&self, request: &ExperimentRequest) -> Result<(), ControlError> {
        let mut s = self.lock();
        if !s.alive {
            return Err(ControlError::FailedPrecondition(
                "no loop is attached".into(),
            ));
        }
        if s.experiment.running {
            return Err(ControlError::FailedPrecondition(format!(
                "an experiment is already running ({}): stop it first",
                s.experiment.kind
            )));
        }
        s.experiment = ExperimentStatus {
            kind: request.kind.as_str().into(),
            running: true,
            cycle: 1,
            phase: haptics_proto::phase::Phase::RampUp.name().into(),
        };
        s.last_experiment = Some(request.clone());
        Ok(())
    }

    fn stop_experiment(&self) -> Result<(), ControlError> {
        let mut s = self.lock();
        if !s.alive {
            return Err(ControlError::FailedPrecondition(
                "no loop is attached".into(),
            ));
        }
        s.experiment = ExperimentStatus {
            kind: "idle".into(),
            ..Default::default()
        };
        Ok(())
    }

    fn subscribe_telemetry(&self) -> broadcast::Receiver<TelemetryBatch> {
        self.inner.hub.subscribe()
    }
}
