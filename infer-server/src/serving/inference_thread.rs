//! The inference thread: attaches to rt-loop's shared-memory segment, answers every feature
//! vector in order with the active model's force, tagged with the step's sequence number.
//!
//! A plain OS thread (never an async task), pinned to a CPU where the OS permits. Per step:
//! receive from the features ring, pick up a newly activated model if one is pending
//! ([`crate::serving::handoff`]), reset a stateful model at a run start, run the model
//! ([`crate::model::engine::StepEngine::step`]), send the force, record the ring-to-ring latency
//! ([`crate::serving::latency`]) and bump the counters in [`InferenceCounters`]. None of this allocates, locks
//! or makes a syscall, except the futex wait/wake of the rings' wait strategy, or with
//! [`WaitStrategy::PeriodSync`] the one absolute sleep per step before the step is due
//! ([`crate::serving::period_sync`]). Attaching,
//! re-attaching after the loop restarts, and publishing the segment's schema happen between
//! runs, not per step.
//!
//! Every message gets an answer, even when there is nothing sensible to say: without a model,
//! with a model validated against another schema, or when ONNX Runtime fails, the answer is
//! NaN with a flag ([`force_flags`]), so a lockstep loop falls back at once instead of waiting.
//! A message whose words do not decode (a corrupt or hostile writer) is counted, reported by
//! the main thread, and skipped: the thread serves on with the next one.

use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use haptics_proto::{FeatureMsg, ForceMsg, Segment};
use shm_ring::{
    monotonic_ns, sleep_until_ns, Consumer, DecodeError, RecvError, SegmentName, WaitStrategy,
};

use shm_ring::os::rt_thread::{CpuChoice, RtRequest};

use crate::model::contract::{FeatureSchema, ModelKind};
use crate::model::engine::StepError;
use crate::serving::attachment::{LoopEndpoints, SharedEndpoints};
use crate::serving::handoff::{Offered, Taker};
use crate::serving::keep_awake::KeepAwake;
use crate::serving::latency::{self, LatencyReader, LatencyRecorder};
use crate::serving::period_sync::{PeriodSync, Plan};

/// Bits of `ForceMsg::flags` the server sets. 0 = a normal answer from the model.
pub mod force_flags {
    /// No model is active: `force` is NaN.
    pub const NO_MODEL: u32 = 1;
    /// ONNX Runtime failed this step (or the vector was shorter than the schema): NaN.
    pub const STEP_ERROR: u32 = 2;
    /// The active model was validated against another feature schema than this segment's;
    /// the server waits for the control side to revalidate it: NaN.
    pub const SCHEMA_MISMATCH: u32 = 4;
    /// The model itself returned NaN or an infinity (passed on as is). A stateful model's
    /// state is reset after such a step (it would stay poisoned otherwise).
    pub const NON_FINITE: u32 = 8;
    /// A feature the model uses is NaN/Inf: the model was not run (its state is untouched): NaN.
    pub const BAD_FEATURES: u32 = 16;
}

/// How the inference thread attaches and waits.
#[derive(Debug, Clone)]
pub struct InferenceConfig {
    pub segment: SegmentName,
    /// How the thread waits for features (and for room in the forces ring). Tests use `Park`.
    pub wait: WaitStrategy,
    /// CPU to pin the thread to (`None`: not pinned).
    pub cpu: Option<usize>,
    /// SCHED_FIFO priority (1-99) for the thread (`None`: the default scheduler). Only with a
    /// parking wait strategy on a small machine: a spinning FIFO thread owns its core.
    pub rt_priority: Option<i32>,
    /// Return when the loop goes away instead of waiting for the next one.
    pub exit_when_loop_gone: bool,
    /// Keep `cpu` awake between steps with a `SCHED_IDLE` spinner ([`crate::serving::keep_awake`]);
    /// only with a `cpu`.
    pub keep_awake: bool,
}

/// Counters the inference thread keeps; any thread may read them. Each has a single writer
/// (the inference thread), so updates are plain relaxed load/store pairs.
#[derive(Debug, Default)]
pub struct InferenceCounters {
    /// Feature messages answered (all of them, whatever the answer).
    pub answered: AtomicU64,
    /// Answers computed by a model (flags 0 or NON_FINITE).
    pub predicted: AtomicU64,
    pub no_model: AtomicU64,
    pub step_errors: AtomicU64,
    pub schema_mismatch: AtomicU64,
    pub non_finite: AtomicU64,
    /// Steps refused because a feature the model uses was NaN/Inf.
    pub bad_features: AtomicU64,
    /// Stateful-model resets (run starts / run id changes).
    pub resets: AtomicU64,
    /// Model switches picked up between steps.
    pub switches: AtomicU64,
    pub attachments: AtomicU64,
    /// Feature messages left over from a previous server, skipped at attach.
    pub skipped_on_attach: AtomicU64,
    /// Sequence number of the last answered message.
    pub last_seq: AtomicU64,
    /// Generation of the model the thread runs (0: none).
    pub model_generation: AtomicU64,
    /// The first step (`FeatureMsg::seq`) a newly activated model answered, and that model's
    /// generation (written in that order; read the generation first, with Acquire).
    pub effective_seq: AtomicU64,
    pub effective_generation: AtomicU64,
    pub attached: AtomicBool,
    /// CPU the thread is pinned to, -1 when not pinned (not asked, or not permitted).
    pub pinned_cpu: AtomicI64,
    /// SCHED_FIFO priority obtained, 0 when running on the default scheduler.
    pub rt_priority: AtomicI64,
    /// Feature messages whose words did not decode: skipped (see [`InferenceCounters::last_undecodable`]).
    pub undecodable: AtomicU64,
    /// The CPU the keep-awake spinner keeps awake once set up; -1: none.
    pub keep_awake_cpu: AtomicI64,
    /// Time it spent spinning, microseconds: the wall time of its spin chunks (preemptions by
    /// other threads included, so at most the CPU time it took from the halt).
    pub keep_awake_spun_us: AtomicU64,
    /// Why the last undecodable message was refused (written with `try_lock`, never waited on).
    pub last_undecodable: Mutex<Option<DecodeError>>,
    /// The period-synchronised wait ([`crate::serving::period_sync`]): the learnt period (0: not locked),
    /// the wake-up margin, how often it locked on and re-learnt, and the planned wake-ups after
    /// which no message came.
    pub sync_period_ns: AtomicU64,
    pub sync_margin_ns: AtomicU64,
    pub sync_locks: AtomicU64,
    pub sync_relearns: AtomicU64,
    pub sync_missed_wakes: AtomicU64,
    /// Why the period-synchronised wait let go of its lock ([`crate::serving::period_sync::LetGo`]):
    /// the loop went quiet, sent faster than the learnt period, left a gap, restarted.
    pub sync_let_go: [AtomicU64; 4],
    /// Work done ahead after answering (fused-ops ahead.rs: an LSTM's next recurrent product):
    /// the answers after which some ran, and the time it took in all. It is off the answer's
    /// latency, not off the thread's CPU time: `ahead_ns / ahead_runs` is what each costs.
    pub ahead_runs: AtomicU64,
    pub ahead_ns: AtomicU64,
}

#[inline(always)]
fn bump(a: &AtomicU64) {
    add(a, 1);
}

/// `a += v` for a counter with this thread as its only writer (a load and a store, no RMW).
#[inline(always)]
fn add(a: &AtomicU64, v: u64) {
    a.store(a.load(Ordering::Relaxed).wrapping_add(v), Ordering::Relaxed);
}

/// A plain snapshot of [`InferenceCounters`] for reports.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct StatsSnapshot {
    pub answered: u64,
    pub predicted: u64,
    pub no_model: u64,
    pub step_errors: u64,
    pub schema_mismatch: u64,
    pub non_finite: u64,
    pub bad_features: u64,
    pub resets: u64,
    pub switches: u64,
    pub attachments: u64,
    pub skipped_on_attach: u64,
    pub last_seq: u64,
    pub model_generation: u64,
    pub effective_seq: u64,
    pub effective_generation: u64,
    pub attached: bool,
    pub pinned_cpu: i64,
    pub rt_priority: i64,
    pub undecodable: u64,
    pub keep_awake_cpu: i64,
    pub keep_awake_spun_us: u64,
    pub sync_period_ns: u64,
    pub sync_margin_ns: u64,
    pub sync_locks: u64,
    pub sync_relearns: u64,
    pub sync_missed_wakes: u64,
    /// quiet, faster, gap, restart.
    pub sync_let_go: [u64; 4],
    pub ahead_runs: u64,
    pub ahead_ns: u64,
}

impl InferenceCounters {
    pub fn snapshot(&self) -> StatsSnapshot {
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        StatsSnapshot {
            answered: l(&self.answered),
            predicted: l(&self.predicted),
            no_model: l(&self.no_model),
            step_errors: l(&self.step_errors),
            schema_mismatch: l(&self.schema_mismatch),
            non_finite: l(&self.non_finite),
            bad_features: l(&self.bad_features),
            resets: l(&self.resets),
            switches: l(&self.switches),
            attachments: l(&self.attachments),
            skipped_on_attach: l(&self.skipped_on_attach),
            last_seq: l(&self.last_seq),
            model_generation: l(&self.model_generation),
            effective_generation: self.effective_generation.load(Ordering::Acquire),
            effective_seq: l(&self.effective_seq),
            attached: self.attached.load(Ordering::Relaxed),
            pinned_cpu: self.pinned_cpu.load(Ordering::Relaxed),
            rt_priority: self.rt_priority.load(Ordering::Relaxed),
            undecodable: l(&self.undecodable),
            keep_awake_cpu: self.keep_awake_cpu.load(Ordering::Relaxed),
            keep_awake_spun_us: l(&self.keep_awake_spun_us),
            sync_period_ns: l(&self.sync_period_ns),
            sync_margin_ns: l(&self.sync_margin_ns),
            sync_locks: l(&self.sync_locks),
            sync_relearns: l(&self.sync_relearns),
            sync_missed_wakes: l(&self.sync_missed_wakes),
            sync_let_go: [0, 1, 2, 3].map(|i| l(&self.sync_let_go[i])),
            ahead_runs: l(&self.ahead_runs),
            ahead_ns: l(&self.ahead_ns),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum InferenceError {
    #[error("shared memory: {0}")]
    Segment(#[from] shm_ring::Error),
    #[error("the segment's feature schema is unusable: {0}")]
    Schema(#[from] crate::model::contract::SchemaError),
    #[error("the features ring failed: {0}")]
    Ring(RecvError),
    #[error("could not start the inference thread: {0}")]
    Spawn(std::io::Error),
}

/// Handle on the running inference thread.
pub struct InferenceThread {
    handle: Option<JoinHandle<Result<(), InferenceError>>>,
    stop: Arc<AtomicBool>,
    stats: Arc<InferenceCounters>,
    latency: LatencyReader,
    schema: Arc<Mutex<Option<FeatureSchema>>>,
    endpoints: Arc<SharedEndpoints>,
    /// The spinner keeping the inference CPU awake, when asked for (stopped on drop).
    _keep_awake: Option<KeepAwake>,
}

impl InferenceThread {
    /// Starts the thread. It attaches (and re-attaches) to `cfg.segment` by itself; models
    /// arrive through `taker`'s [`crate::serving::handoff::Activator`].
    pub fn spawn(cfg: InferenceConfig, taker: Taker) -> Result<Self, InferenceError> {
        let stop = Arc::new(AtomicBool::new(false));
        let stats = Arc::new(InferenceCounters {
            pinned_cpu: AtomicI64::new(-1),
            keep_awake_cpu: AtomicI64::new(-1),
            ..Default::default()
        });
        let keep_awake = match (cfg.keep_awake, cfg.cpu) {
            (true, Some(cpu)) => Some(
                KeepAwake::spawn("infer-server", cpu, Arc::clone(&stats))
                    .map_err(InferenceError::Spawn)?,
            ),
            _ => None,
        };
        let (recorder, latency) = latency::histogram();
        let schema = Arc::new(Mutex::new(None));
        let endpoints = Arc::new(SharedEndpoints::default());
        let worker = Worker {
            cfg,
            taker,
            stop: Arc::clone(&stop),
            stats: Arc::clone(&stats),
            recorder,
            schema: Arc::clone(&schema),
            endpoints: Arc::clone(&endpoints),
        };
        let handle = std::thread::Builder::new()
            .name("inference".into())
            .spawn(move || worker.run())
            .map_err(InferenceError::Spawn)?;
        Ok(Self {
            handle: Some(handle),
            stop,
            stats,
            latency,
            schema,
            endpoints,
            _keep_awake: keep_awake,
        })
    }

    /// The telemetry ring, command mailbox and link of the current attachment.
    pub fn endpoints(&self) -> &Arc<SharedEndpoints> {
        &self.endpoints
    }

    pub fn stats(&self) -> &InferenceCounters {
        &self.stats
    }

    /// Ring-to-ring latency of every answered step, nanoseconds.
    pub fn latency(&self) -> &LatencyReader {
        &self.latency
    }

    /// The feature schema of the segment the thread is attached to (None while detached). The
    /// control side validates models against it.
    pub fn segment_schema(&self) -> Option<FeatureSchema> {
        self.schema.lock().map(|s| s.clone()).unwrap_or(None)
    }

    pub fn is_finished(&self) -> bool {
        self.handle.as_ref().is_none_or(|h| h.is_finished())
    }

    /// Asks the thread to stop without waiting (it notices within ~200 ms).
    pub fn request_stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }

    /// Asks the thread to stop (it notices within ~100 ms) and waits for it.
    pub fn stop(mut self) -> Result<(), InferenceError> {
        self.stop.store(true, Ordering::Relaxed);
        self.join_inner()
    }

    /// Waits for the thread to end by itself (`exit_when_loop_gone`).
    pub fn join(mut self) -> Result<(), InferenceError> {
        self.join_inner()
    }

    fn join_inner(&mut self) -> Result<(), InferenceError> {
        match self.handle.take() {
            Some(h) => h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)),
            None => Ok(()),
        }
    }
}

impl Drop for InferenceThread {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// How long one wait for a feature lasts before the thread re-checks `stop`.
const RECV_SLICE: Duration = Duration::from_millis(100);
/// How long one attach attempt waits for a loop before re-checking `stop`.
const ATTACH_SLICE: Duration = Duration::from_millis(200);

struct Worker {
    cfg: InferenceConfig,
    taker: Taker,
    stop: Arc<AtomicBool>,
    stats: Arc<InferenceCounters>,
    recorder: LatencyRecorder,
    schema: Arc<Mutex<Option<FeatureSchema>>>,
    endpoints: Arc<SharedEndpoints>,
}

impl Worker {
    fn run(mut self) -> Result<(), InferenceError> {
        // The one real-time set-up of both processes (shm_ring::os::rt_thread); kept for the
        // thread's life. What the system refuses is reported and the thread runs on without it.
        let obtained = RtRequest {
            fifo_priority: self.cfg.rt_priority,
            cpu: self.cfg.cpu.map_or(CpuChoice::Any, CpuChoice::Cpu),
            lock_memory: false,
        }
        .apply()
        .keep();
        if let Some(cpu) = obtained.pinned_cpu {
            self.stats.pinned_cpu.store(cpu as i64, Ordering::Relaxed);
        }
        if let Some(prio) = obtained.fifo_priority {
            self.stats.rt_priority.store(prio as i64, Ordering::Relaxed);
        }
        for warning in obtained.warnings() {
            eprintln!("infer-server: {warning}; the inference thread runs without it");
        }
        // Kernels stepped here queue their next step's state-only work, done after each answer.
        haptics_ort_host::serve_ahead_on_this_thread();
        let mut active: Option<Box<Offered>> = None;
        let mut attached_once = false;
        while !self.stop.load(Ordering::Relaxed) {
            let segment = match Segment::attach_timeout(&self.cfg.segment, ATTACH_SLICE) {
                Ok(s) => s,
                Err(e) if e.is_transient() => {
                    if attached_once && self.cfg.exit_when_loop_gone {
                        return Ok(());
                    }
                    continue;
                }
                Err(e) => return Err(e.into()),
            };
            attached_once = true;
            let done = self.serve_segment(segment, &mut active)?;
            if done || self.cfg.exit_when_loop_gone {
                return Ok(());
            }
        }
        Ok(())
    }

    /// Serves one attachment until the loop goes away (Ok(false)) or `stop` (Ok(true)).
    fn serve_segment(
        &mut self,
        segment: Segment,
        active: &mut Option<Box<Offered>>,
    ) -> Result<bool, InferenceError> {
        let haptics_proto::ServerSide {
            mut features_rx,
            mut forces_tx,
            telemetry_rx,
            commands_tx,
            link,
            skipped_on_attach,
        } = segment.server_side()?;
        features_rx.set_wait_strategy(self.cfg.wait);
        forces_tx.set_wait_strategy(self.cfg.wait);
        let schema = FeatureSchema::new(link.feature_names())?;
        let stats = Arc::clone(&self.stats);
        bump(&stats.attachments);
        stats
            .skipped_on_attach
            .fetch_add(skipped_on_attach, Ordering::Relaxed);
        if let Ok(mut s) = self.schema.lock() {
            *s = Some(schema.clone());
        }
        // Telemetry and commands belong to other threads; publish them for this attachment.
        self.endpoints.publish(LoopEndpoints {
            attachment: stats.attachments.load(Ordering::Relaxed),
            link: link.clone(),
            telemetry_rx: Some(telemetry_rx),
            commands_tx,
        });
        stats.attached.store(true, Ordering::Relaxed);

        let matches = |a: &Option<Box<Offered>>| {
            a.as_ref()
                .is_some_and(|o| o.engine.info().schema == schema.names())
        };
        let mut usable = matches(active);
        let mut last_run: Option<u32> = None;
        // A new loop: learn its period afresh (nothing of the last one applies).
        let mut sync = (self.cfg.wait == WaitStrategy::PeriodSync).then(PeriodSync::new);
        let result = loop {
            if self.stop.load(Ordering::Relaxed) {
                break Ok(true);
            }
            let received = match sync.as_mut() {
                Some(sync) => recv_synced(&mut features_rx, sync, &stats),
                None => features_rx.recv_timeout(RECV_SLICE),
            };
            let msg: FeatureMsg = match received {
                Ok(m) => m,
                Err(RecvError::Decode(e)) => {
                    // The slot was consumed; its words make no message (a corrupt or hostile
                    // writer). Count it, leave the reason for the main thread to log, serve on.
                    // The loop renders that step without an answer, as it would a late one.
                    bump(&stats.undecodable);
                    if let Ok(mut last) = stats.last_undecodable.try_lock() {
                        *last = Some(e);
                    }
                    continue;
                }
                Err(RecvError::Timeout) => {
                    link.heartbeat();
                    // A wait with a deadline that spins (the `dedicated` profile's
                    // `WaitStrategy::Spin`) checks nothing but the deadline, so only here can a
                    // loop that left be noticed: a whole slice without a message, then one
                    // liveness query (a syscall, made while there is nothing to serve). The
                    // period-synchronised wait times out on a late step too: it notices a gone
                    // loop in its parked phase instead, so it pays nothing here.
                    if sync.is_none() && !link.peer_alive() {
                        break Ok(false);
                    }
                    // A model may arrive while the loop is idle (e.g. before its first step).
                    if self.taker.take(active) {
                        bump(&stats.switches);
                        usable = matches(active);
                        last_run = None;
                    }
                    continue;
                }
                Err(RecvError::PeerGone) => break Ok(false),
                Err(RecvError::Corrupt(c)) => {
                    // Another writer damaged the ring (shm-ring counts it: features_rx.corrupt()).
                    // A slot with a wrong sequence word was skipped: serve on. Impossible indices
                    // stay until the loop, which owns the segment, re-creates it and lets go of
                    // this one: then re-attach (to the new one); until then poll gently.
                    if !link.peer_alive() {
                        break Ok(false);
                    }
                    if matches!(c, shm_ring::CorruptRing::Indices { .. }) {
                        std::thread::sleep(Duration::from_millis(1));
                    }
                    continue;
                }
            };
            let t0 = Instant::now();
            if let Some(sync) = sync.as_mut() {
                sync.observe(msg.timestamp_ns, msg.seq, monotonic_ns());
            }

            // ---- real-time section: no allocation, no lock, no syscall ----
            if self.taker.take(active) {
                bump(&stats.switches);
                usable = matches(active);
                last_run = None; // a fresh engine starts from a zero state
            }
            let (force, flags, generation) = match active.as_mut() {
                None => {
                    bump(&stats.no_model);
                    (f64::NAN, force_flags::NO_MODEL, 0)
                }
                Some(a) if !usable => {
                    bump(&stats.schema_mismatch);
                    (f64::NAN, force_flags::SCHEMA_MISMATCH, a.generation)
                }
                Some(a) => {
                    if msg.is_run_start() || last_run.is_some_and(|r| r != msg.run_id) {
                        a.engine.reset();
                        bump(&stats.resets);
                    }
                    last_run = Some(msg.run_id);
                    match a.engine.step(msg.features()) {
                        Ok(f) if f.is_finite() => {
                            bump(&stats.predicted);
                            (f as f64, 0, a.generation)
                        }
                        Ok(f) => {
                            bump(&stats.predicted);
                            bump(&stats.non_finite);
                            if a.engine.kind() == ModelKind::Stateful {
                                // A NaN/Inf force usually means a poisoned h/c: every later
                                // step of the run would be NaN too. Start again from zero.
                                a.engine.reset();
                                bump(&stats.resets);
                            }
                            (f as f64, force_flags::NON_FINITE, a.generation)
                        }
                        Err(StepError::NonFiniteFeature { .. }) => {
                            bump(&stats.bad_features);
                            (f64::NAN, force_flags::BAD_FEATURES, a.generation)
                        }
                        Err(_) => {
                            bump(&stats.step_errors);
                            (f64::NAN, force_flags::STEP_ERROR, a.generation)
                        }
                    }
                }
            };
            let answer = ForceMsg {
                seq: msg.seq,
                force,
                model_id: generation as u32,
                flags,
                inference_ns: t0.elapsed().as_nanos() as u64,
            };
            if forces_tx.send(answer).is_err() {
                break Ok(false); // the loop's process is gone
            }
            if generation != 0 && generation != stats.effective_generation.load(Ordering::Relaxed) {
                stats.effective_seq.store(msg.seq, Ordering::Relaxed);
                stats
                    .effective_generation
                    .store(generation, Ordering::Release);
            }
            self.recorder.record(t0.elapsed().as_nanos() as u64);
            bump(&stats.answered);
            stats.last_seq.store(msg.seq, Ordering::Relaxed);
            stats.model_generation.store(generation, Ordering::Relaxed);
            link.heartbeat();
            // ---- end of real-time section ----

            // The answer is out: do the next step's state-only work now, while the loop has
            // nothing for this thread (a stateful model's; none queued: one clock read). No
            // allocation, no lock; it delays nothing a step waits for, since the next request
            // comes a period after this one.
            let t_ahead = Instant::now();
            if haptics_ort_host::run_ahead() > 0 {
                bump(&stats.ahead_runs);
                add(&stats.ahead_ns, t_ahead.elapsed().as_nanos() as u64);
            }
        };
        stats.attached.store(false, Ordering::Relaxed);
        self.endpoints.clear();
        if let Ok(mut s) = self.schema.lock() {
            *s = None;
        }
        result
    }
}

/// One receive under the period-synchronised wait: a message already waiting is taken at once;
/// otherwise, once the period is learnt, sleep until shortly before the next step is due and
/// spin until it arrives (or give up half a period after it was due); before that, the ring's
/// own spin-then-park wait. No allocation; one `clock_nanosleep` per step.
fn recv_synced(
    rx: &mut Consumer<FeatureMsg>,
    sync: &mut PeriodSync,
    stats: &InferenceCounters,
) -> Result<FeatureMsg, RecvError> {
    if let Some(m) = rx.try_recv()? {
        return Ok(m);
    }
    let result = match sync.plan(monotonic_ns()) {
        Plan::Park => {
            rx.set_wait_strategy(WaitStrategy::DEFAULT_SPIN_THEN_PARK);
            rx.recv_timeout(RECV_SLICE)
        }
        Plan::Sleep {
            wake_ns,
            give_up_ns,
        } => {
            sleep_until_ns(wake_ns);
            let woke = monotonic_ns();
            sync.woke(wake_ns, woke);
            rx.set_wait_strategy(WaitStrategy::Spin);
            let spin_for = Duration::from_nanos(give_up_ns.saturating_sub(woke));
            let r = rx.recv_deadline(Instant::now() + spin_for);
            if matches!(r, Err(RecvError::Timeout)) {
                sync.missed();
            }
            r
        }
    };
    stats
        .sync_period_ns
        .store(sync.period_ns(), Ordering::Relaxed);
    stats
        .sync_margin_ns
        .store(sync.margin_ns(), Ordering::Relaxed);
    stats.sync_locks.store(sync.locks, Ordering::Relaxed);
    stats.sync_relearns.store(sync.relearns, Ordering::Relaxed);
    stats
        .sync_missed_wakes
        .store(sync.missed_wakes, Ordering::Relaxed);
    let g = sync.let_go;
    for (counter, value) in stats
        .sync_let_go
        .iter()
        .zip([g.quiet, g.faster, g.gap, g.restart])
    {
        counter.store(value, Ordering::Relaxed);
    }
    result
}
