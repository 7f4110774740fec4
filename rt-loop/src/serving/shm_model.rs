//! [`ShmModel`]: the [`ForceModel`] that asks infer-server over shared memory (issue 4).
//!
//! Per step: the step's features go into the segment's features ring tagged with a sequence
//! number, then the loop waits for the answer carrying that number, bounded by a deadline
//! (realtime: `deadline_us`, default 50 us; lockstep: a generous safety timeout, so lockstep
//! runs wait for every answer and stay deterministic). Anything else (late, missing, a flagged
//! or NaN answer, no server attached) is a `None` or a non-finite value, which the experiment
//! replaces with the fallback spring-damper and counts.
//!
//! Why the wait is bounded: the loop owns a motor. A server that stalls (page fault, GC in a
//! neighbour, a swap, a crash) must never stall the current update, the watchdog kick or the
//! safety checks, so the loop never waits past the step's deadline, whatever the server does.
//!
//! REAL-TIME PATH: [`ShmModel::predict`] allocates nothing, takes no lock and does no I/O.
//! Its only syscalls: a `FUTEX_WAKE` when the server is parked (inside `try_send`), a futex
//! wait when the wait strategy parks (lockstep), and one `fcntl` liveness probe every
//! [`LIVENESS_EVERY`] steps (and when a new server attachment is seen).

use crate::features::Features;
use crate::serving::model::{Answer, ForceModel, Miss};
use crate::stop::Shutdown;
use haptics_proto::{FeatureMsg, ForceMsg};
use hdrhistogram::Histogram;
use shm_ring::{Consumer, Link, Producer, RecvError, SendError, WaitStrategy};
use std::any::Any;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Steps between two liveness probes of the server (one `fcntl` each): 0.1 s at 10 kHz.
pub const LIVENESS_EVERY: u32 = 1024;
/// After a new server attachment is seen, the loop waits this long (rendering the fallback)
/// before sending to it: the server skips whatever is queued while it attaches, so a request
/// sent in that window could be skipped and, in lockstep, waited for in vain.
pub const SETTLE_AFTER_ATTACH: Duration = Duration::from_millis(50);

/// How the loop waits for each answer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AnswerWait {
    /// Realtime: give up `deadline` after sending (fallback for that step).
    Deadline(Duration),
    /// Lockstep: wait for every answer; `safety` only guards against a server that is attached
    /// but hung (then the step falls back and the run goes on). After `give_up_after`
    /// timeouts in a row the server is treated as gone (nothing sent, no wait) until its
    /// heartbeat moves again: a hung server costs a few safety timeouts, not one per step.
    Lockstep {
        safety: Duration,
        give_up_after: u32,
    },
}

/// Why [`ShmClient::wait_for_model`] saw no model answer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ModelWaitError {
    #[error("the server went away")]
    ServerGone,
    #[error("interrupted")]
    Interrupted,
    /// The server answers, flagged (no model active, schema mismatch, ...).
    #[error("the server answers with flags {0} (1: no model active, 4: schema mismatch)")]
    Flagged(u32),
    #[error("the server does not answer")]
    NoAnswer,
}

/// Default of `give_up_after` (`--give-up-after`).
pub const DEFAULT_GIVE_UP_AFTER: u32 = 3;

/// Counters of the shared-memory client, readable from any thread while the loop runs
/// (relaxed atomics, one writer: the loop thread).
#[derive(Debug, Default)]
pub struct ShmCounters {
    /// Requests sent to the server.
    pub sent: AtomicU64,
    /// Answers received in time with a usable force (flags 0).
    pub answered: AtomicU64,
    /// The deadline passed before the answer came (deadline misses).
    pub late: AtomicU64,
    /// Steps with no server attached (nothing sent).
    pub no_server: AtomicU64,
    /// The features ring was full (the server is far behind).
    pub ring_full: AtomicU64,
    /// Answers in time but flagged by the server (no model, bad features, schema mismatch...).
    pub flagged: AtomicU64,
    /// Late answers to earlier steps thrown away.
    pub stale_discarded: AtomicU64,
    /// The server went away during a wait or a liveness probe.
    pub server_lost: AtomicU64,
    /// New server attachments seen.
    pub attachments_seen: AtomicU64,
    /// Answers to the previous step that arrived one period late and were used.
    pub late_used: AtomicU64,
    /// Lockstep steps skipped because the server is treated as hung (heartbeat still).
    pub hung: AtomicU64,
    /// Times the server was declared hung (`give_up_after` timeouts in a row).
    pub hung_declared: AtomicU64,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct ShmCountersSnapshot {
    pub sent: u64,
    pub answered: u64,
    pub late: u64,
    pub no_server: u64,
    pub ring_full: u64,
    pub flagged: u64,
    pub stale_discarded: u64,
    pub server_lost: u64,
    pub attachments_seen: u64,
    pub late_used: u64,
    pub hung: u64,
    pub hung_declared: u64,
}

impl ShmCounters {
    pub fn snapshot(&self) -> ShmCountersSnapshot {
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        ShmCountersSnapshot {
            sent: l(&self.sent),
            answered: l(&self.answered),
            late: l(&self.late),
            no_server: l(&self.no_server),
            ring_full: l(&self.ring_full),
            flagged: l(&self.flagged),
            stale_discarded: l(&self.stale_discarded),
            server_lost: l(&self.server_lost),
            attachments_seen: l(&self.attachments_seen),
            late_used: l(&self.late_used),
            hung: l(&self.hung),
            hung_declared: l(&self.hung_declared),
        }
    }
}

#[inline]
fn bump(a: &AtomicU64) {
    // single writer: a load and a store, no read-modify-write bus lock
    a.store(a.load(Ordering::Relaxed) + 1, Ordering::Relaxed);
}

/// The loop's ends of the request/answer rings, with the state that outlives one run.
pub struct ShmClient {
    features_tx: Producer<FeatureMsg>,
    forces_rx: Consumer<ForceMsg>,
    link: Link,
    schema_len: usize,
    next_seq: u64,
    run_id: u32,
    run_start: bool,
    connected: bool,
    seen_attachments: u64,
    settle_until: Option<Instant>,
    liveness_countdown: u32,
    origin: Instant,
    /// `counters.late` when the current run began (the status reports the run's misses).
    late_at_run_start: u64,
    /// The previous step's request, sent and not answered by its deadline: its answer may
    /// still be used for the next step (`Answer::LateOne`).
    pending_prev: Option<(u64, Instant)>,
    /// Lockstep: safety timeouts in a row.
    timeouts_in_a_row: u32,
    /// Lockstep: the server's heartbeat when it was declared hung (`None`: not hung).
    hung_at_heartbeat: Option<u64>,
    /// Loop-observed round trip (send to matching answer), ns; preallocated, recording never
    /// allocates (`saturating_record` clamps to the range).
    pub round_trip_ns: Histogram<u64>,
    pub counters: Arc<ShmCounters>,
    /// Fresh endpoints when the segment is re-created after corruption (`shm_renew`).
    pub renewal: Option<crate::serving::shm_renew::Renewal>,
    /// Ends the waits for a server or a model early (Ctrl-C while waiting).
    shutdown: Option<Shutdown>,
    /// The server's id of the model whose answer was last used (`ForceMsg.model_id`; 0: none
    /// yet this run).
    last_model_id: u32,
}

impl ShmClient {
    /// The waits for a server and for its model give up at once when `shutdown` is requested.
    pub fn stop_on(&mut self, shutdown: Shutdown) {
        self.shutdown = Some(shutdown);
    }

    fn stop_requested(&self) -> bool {
        self.shutdown.as_ref().is_some_and(Shutdown::is_requested)
    }

    /// The segment's schema must be [`crate::features::SCHEMA_NAMES`] (checked by
    /// `shm_io::create_segment`): the values sent are `Features::as_schema_array()`.
    pub fn new(
        mut features_tx: Producer<FeatureMsg>,
        mut forces_rx: Consumer<ForceMsg>,
        link: Link,
        wait: WaitStrategy,
    ) -> Self {
        features_tx.set_wait_strategy(WaitStrategy::Park);
        forces_rx.set_wait_strategy(wait);
        let schema_len = link.feature_names().len();
        ShmClient {
            features_tx,
            forces_rx,
            seen_attachments: link.server_attachments(),
            connected: link.peer_alive(),
            link,
            schema_len,
            next_seq: 1,
            run_id: 0,
            run_start: true,
            settle_until: None,
            liveness_countdown: LIVENESS_EVERY,
            origin: Instant::now(),
            late_at_run_start: 0,
            pending_prev: None,
            timeouts_in_a_row: 0,
            hung_at_heartbeat: None,
            round_trip_ns: Histogram::new_with_bounds(1, 60_000_000_000, 3)
                .expect("valid histogram bounds"),
            counters: Arc::new(ShmCounters::default()),
            renewal: None,
            shutdown: None,
            last_model_id: 0,
        }
    }

    /// Moves to the endpoints of a segment the keeper re-created after finding the old one
    /// corrupt (`shm_renew`); the old ones go back to the keeper thread to be dropped there.
    /// Per step: one relaxed load while nothing is pending; a swap moves a few pointers (no
    /// allocation, no syscall). Until a server attaches to the new segment there is none.
    #[inline]
    pub fn renew_if_pending(&mut self) {
        let Some(renewal) = self.renewal.as_mut().filter(|r| r.pending()) else {
            return;
        };
        let (tx, rx, link) = (&mut self.features_tx, &mut self.forces_rx, &mut self.link);
        if renewal.swap_client(|new| crate::serving::shm_renew::ClientEnds {
            features_tx: std::mem::replace(tx, new.features_tx),
            forces_rx: std::mem::replace(rx, new.forces_rx),
            link: std::mem::replace(link, new.link),
        }) {
            self.seen_attachments = self.link.server_attachments();
            self.connected = false;
            self.run_start = true;
            self.pending_prev = None;
            self.timeouts_in_a_row = 0;
            self.hung_at_heartbeat = None;
        }
    }

    pub fn link(&self) -> &Link {
        &self.link
    }

    pub fn set_wait_strategy(&mut self, wait: WaitStrategy) {
        self.forces_rx.set_wait_strategy(wait);
    }

    /// Whether a server is attached and alive (one `fcntl`; off the real-time path).
    pub fn server_alive(&self) -> bool {
        self.link.server_attachments() > 0 && self.link.peer_alive()
    }

    /// Waits (off the real-time path) until a server is attached, up to `timeout`, then lets
    /// it settle (see [`SETTLE_AFTER_ATTACH`]). Returns whether one is.
    pub fn wait_for_server(&mut self, timeout: Duration) -> bool {
        let end = Instant::now() + timeout;
        loop {
            self.renew_if_pending();
            self.link.heartbeat();
            if self.server_alive() {
                std::thread::sleep(SETTLE_AFTER_ATTACH);
                self.seen_attachments = self.link.server_attachments();
                self.connected = true;
                self.settle_until = None;
                return true;
            }
            // Ctrl-C while waiting: give up at once
            if Instant::now() >= end || self.stop_requested() {
                return false;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// Waits (off the real-time path) until the attached server answers with a model (flags 0),
    /// up to `timeout`, probing with zero feature vectors flagged `RUN_START` (so a stateful
    /// model starts the real run fresh anyway). Lockstep runs call it first, so that every
    /// step of the run is answered by the model; an answer still flagged at the end is
    /// returned as the error (its flags, e.g. 1 = no model active).
    pub fn wait_for_model(&mut self, timeout: Duration) -> Result<(), ModelWaitError> {
        let end = Instant::now() + timeout;
        let mut last_flags = None;
        loop {
            self.link.heartbeat();
            let seq = self.next_seq;
            self.next_seq += 1;
            let msg = FeatureMsg {
                seq,
                timestamp_ns: 0,
                run_id: self.run_id,
                flags: FeatureMsg::RUN_START,
                len: self.schema_len.min(16) as u8,
                values: [0.0; 16],
            };
            if self.features_tx.try_send(msg).is_ok() {
                let deadline = Instant::now() + Duration::from_millis(500);
                loop {
                    match self.forces_rx.recv_deadline(deadline) {
                        Ok(a) if a.seq < seq => continue,
                        Ok(a) if a.seq == seq && a.flags == 0 => return Ok(()),
                        Ok(a) => {
                            last_flags = Some(a.flags);
                            break;
                        }
                        Err(RecvError::PeerGone) => return Err(ModelWaitError::ServerGone),
                        Err(_) => break,
                    }
                }
            }
            if self.stop_requested() {
                return Err(ModelWaitError::Interrupted);
            }
            if Instant::now() >= end {
                return Err(match last_flags {
                    Some(f) => ModelWaitError::Flagged(f),
                    None => ModelWaitError::NoAnswer,
                });
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Prepares a new run (off the real-time path): next message flagged `RUN_START` with a new
    /// run id, answers left over from an earlier run thrown away.
    pub fn begin_run(&mut self) {
        self.renew_if_pending();
        self.run_id = self.run_id.wrapping_add(1);
        self.run_start = true;
        let stale = self.forces_rx.skip_pending();
        self.counters
            .stale_discarded
            .fetch_add(stale, Ordering::Relaxed);
        self.connected = self.server_alive();
        self.seen_attachments = self.link.server_attachments();
        self.late_at_run_start = self.counters.late.load(Ordering::Relaxed);
        self.last_model_id = 0;
        self.pending_prev = None;
        self.timeouts_in_a_row = 0;
        self.hung_at_heartbeat = None;
    }

    /// Deadline misses of the current run and the round-trip percentiles into the status
    /// block's fields. About every 100 ms on the loop thread: no allocation (the percentiles
    /// walk the preallocated histogram's buckets), no lock.
    pub fn report_status(&self, status: &mut haptics_proto::LoopStatus) {
        status.deadline_misses = self
            .counters
            .late
            .load(Ordering::Relaxed)
            .saturating_sub(self.late_at_run_start);
        status.round_trip = crate::percentiles::quantiles(&self.round_trip_ns);
    }

    pub fn run_id(&self) -> u32 {
        self.run_id
    }

    /// The server's id of the model whose answer was last used (0: none yet this run).
    pub fn last_model_id(&self) -> u32 {
        self.last_model_id
    }

    /// One request/answer exchange: this step's answer if it comes in time, `None` otherwise.
    /// REAL-TIME PATH (see the module doc).
    #[inline]
    pub fn exchange(&mut self, step: u64, features: &Features, wait: AnswerWait) -> Option<f64> {
        match self.answer(step, features, wait) {
            Answer::OnTime(f) => Some(f),
            _ => None,
        }
    }

    /// One request/answer exchange for the degradation ladder: this step's answer in time
    /// (`OnTime`), else the previous step's answer if it arrived one period late (`LateOne`),
    /// else why not (`Missing`). Every miss is counted in exactly one counter of
    /// [`ShmCounters`] (`late`, `no_server`, `ring_full`, `flagged`, `server_lost`, `hung`).
    /// REAL-TIME PATH (see the module doc).
    #[inline]
    pub fn answer(&mut self, _step: u64, features: &Features, wait: AnswerWait) -> Answer {
        self.renew_if_pending();
        let c = &*self.counters;
        // Only the previous step's request can be answered "one period late".
        let pending_prev = self.pending_prev.take();
        // A new server (a restart after a crash, or the first one): one atomic load per step.
        let att = self.link.server_attachments();
        if att != self.seen_attachments {
            self.seen_attachments = att;
            bump(&c.attachments_seen);
            self.settle_until = Some(Instant::now() + SETTLE_AFTER_ATTACH);
            self.connected = self.link.peer_alive();
            self.run_start = true; // the new server starts the model's state afresh
            self.hung_at_heartbeat = None;
            self.timeouts_in_a_row = 0;
        }
        self.liveness_countdown -= 1;
        if self.liveness_countdown == 0 {
            self.liveness_countdown = LIVENESS_EVERY;
            let alive = self.link.peer_alive();
            if self.connected && !alive {
                bump(&c.server_lost);
            }
            self.connected = alive && att > 0;
        }
        if !self.connected {
            bump(&c.no_server);
            return Answer::Missing(Miss::NoServer);
        }
        if let Some(t) = self.settle_until {
            if Instant::now() < t {
                bump(&c.no_server);
                return Answer::Missing(Miss::NoServer);
            }
            self.settle_until = None;
        }
        if let Some(hb) = self.hung_at_heartbeat {
            // one relaxed atomic load: the server's heartbeat moves again when it works again
            if self.link.peer_heartbeat() == hb {
                bump(&c.hung);
                return Answer::Missing(Miss::Hung);
            }
            self.hung_at_heartbeat = None;
            self.timeouts_in_a_row = 0;
        }
        let seq = self.next_seq;
        self.next_seq += 1;
        let all = features.as_schema_array();
        let mut values = [0.0f64; 16];
        let n = self.schema_len.min(all.len());
        values[..n].copy_from_slice(&all[..n]);
        let sent_at = Instant::now();
        let msg = FeatureMsg {
            seq,
            timestamp_ns: sent_at.duration_since(self.origin).as_nanos() as u64,
            run_id: self.run_id,
            flags: if self.run_start {
                FeatureMsg::RUN_START
            } else {
                0
            },
            len: n as u8,
            values,
        };
        match self.features_tx.try_send(msg) {
            Ok(()) => {}
            Err(SendError::Full(_)) => {
                bump(&c.ring_full);
                return Answer::Missing(Miss::RingFull);
            }
            Err(_) => {
                bump(&c.server_lost);
                self.connected = false;
                return Answer::Missing(Miss::ServerLost);
            }
        }
        self.run_start = false;
        bump(&c.sent);
        let deadline = sent_at
            + match wait {
                AnswerWait::Deadline(d) => d,
                AnswerWait::Lockstep { safety, .. } => safety,
            };
        let mut late_prev: Option<(f64, u32)> = None;
        loop {
            match self.forces_rx.recv_deadline(deadline) {
                Ok(a) if a.seq < seq => match pending_prev {
                    Some((ps, pt)) if a.seq == ps && late_prev.is_none() => {
                        // the previous step's answer, one period late: kept for this step
                        let rtt = pt.elapsed().as_nanos() as u64;
                        self.round_trip_ns.saturating_record(rtt.max(1));
                        if a.flags == 0 && a.force.is_finite() {
                            late_prev = Some((a.force, a.model_id));
                        } else {
                            bump(&c.stale_discarded);
                        }
                    }
                    // older still: its step is long rendered
                    _ => bump(&c.stale_discarded),
                },
                Ok(a) if a.seq == seq => {
                    let rtt = sent_at.elapsed().as_nanos() as u64;
                    self.round_trip_ns.saturating_record(rtt.max(1));
                    self.timeouts_in_a_row = 0;
                    if late_prev.is_some() {
                        // superseded by this step's own answer
                        bump(&c.stale_discarded);
                    }
                    if a.flags != 0 {
                        bump(&c.flagged);
                        return Answer::Missing(Miss::Flagged);
                    }
                    bump(&c.answered);
                    self.last_model_id = a.model_id;
                    return Answer::OnTime(a.force);
                }
                Ok(_) => {
                    // an answer from the future cannot come from a sane server: refuse it
                    bump(&c.flagged);
                    return Answer::Missing(Miss::Flagged);
                }
                Err(RecvError::Timeout) => {
                    bump(&c.late);
                    self.pending_prev = Some((seq, sent_at));
                    if let AnswerWait::Lockstep { give_up_after, .. } = wait {
                        self.timeouts_in_a_row += 1;
                        if self.timeouts_in_a_row >= give_up_after.max(1) {
                            bump(&c.hung_declared);
                            self.hung_at_heartbeat = Some(self.link.peer_heartbeat());
                        }
                    }
                    return match late_prev {
                        Some((f, model_id)) => {
                            bump(&c.late_used);
                            self.last_model_id = model_id;
                            Answer::LateOne(f)
                        }
                        None => Answer::Missing(Miss::Late),
                    };
                }
                Err(RecvError::PeerGone) => {
                    bump(&c.server_lost);
                    self.connected = false;
                    return Answer::Missing(Miss::ServerLost);
                }
                Err(_) => {
                    bump(&c.flagged);
                    return Answer::Missing(Miss::Flagged);
                }
            }
        }
    }
}

/// A [`ShmClient`] as a run's [`ForceModel`]. The run gives its model back with its result
/// ([`crate::run::RunOutcome`]); [`ShmModel::from_model`] recognises it there, so a long-running
/// loop keeps one client (its counters, its sequence numbers) across experiments.
pub struct ShmModel {
    client: ShmClient,
    wait: AnswerWait,
    server_wait: Duration,
    /// `rt-loop run --model shm`: the run needs a server with an active model before its
    /// first step ([`ShmModel::require_server`]); the reason if there was none.
    require: Option<String>,
    start_error: Option<String>,
}

impl ShmModel {
    /// `server_wait`: how long `begin_run` waits for a server to attach (0: not at all, the
    /// run starts on the fallback and switches to the model when a server comes).
    pub fn new(client: ShmClient, wait: AnswerWait, server_wait: Duration) -> Self {
        ShmModel {
            client,
            wait,
            server_wait,
            require: None,
            start_error: None,
        }
    }

    /// The served model a run gave back; `None` when `model` is another kind of model.
    pub fn from_model(model: Box<dyn ForceModel>) -> Option<ShmModel> {
        let any: Box<dyn Any> = model;
        any.downcast::<ShmModel>().ok().map(|m| *m)
    }

    /// The run must not start without a server serving a model: `begin_run` (called after
    /// the loop wrote 0 A and armed the watchdog) waits up to the server wait for one, and
    /// [`ForceModel::start_error`] says why not. `instance`: for the error's advice.
    pub fn require_server(mut self, instance: &str) -> Self {
        self.require = Some(instance.to_string());
        self
    }

    pub fn client(&self) -> &ShmClient {
        &self.client
    }

    pub fn client_mut(&mut self) -> &mut ShmClient {
        &mut self.client
    }

    pub fn into_client(self) -> ShmClient {
        self.client
    }
}

impl ForceModel for ShmModel {
    fn name(&self) -> &str {
        "infer-server (shm)"
    }

    fn begin_run(&mut self) {
        let server_wait = self.server_wait;
        let require = self.require.clone();
        let c = self.client_mut();
        // each run's round trip on its own (zeroes the buckets: no allocation)
        c.round_trip_ns.reset();
        let mut error = None;
        if let Some(instance) = require {
            // off the real-time path, before the first step; the loop is at 0 A
            let name = format!("/haptics-{instance}");
            eprintln!(
                "rt-loop: segment {name} created; waiting up to {} s for infer-server (infer-server serve --instance {instance})",
                server_wait.as_secs_f64()
            );
            if !c.wait_for_server(server_wait) {
                error = Some(format!(
                    "no infer-server attached to {name} within {} s: start `infer-server serve --instance {instance} --model MODEL` (or raise --server-wait-s)",
                    server_wait.as_secs_f64()
                ));
            } else if let Err(e) = c.wait_for_model(server_wait.max(Duration::from_secs(1))) {
                // every step should be answered by the model (in lockstep: must)
                error = Some(format!(
                    "infer-server attached to {name} but serves no model: {e}; activate one (infer-server serve --model M, or hapticctl swap M)"
                ));
            } else {
                eprintln!("rt-loop: infer-server attached");
            }
        } else if !server_wait.is_zero() && !c.server_alive() {
            c.wait_for_server(server_wait);
        }
        c.begin_run();
        self.start_error = error;
    }

    fn start_error(&self) -> Option<&str> {
        self.start_error.as_deref()
    }

    fn report_status(&self, status: &mut haptics_proto::LoopStatus) {
        self.client.report_status(status);
    }

    #[inline]
    fn predict(&mut self, step: u64, features: &Features) -> Option<f64> {
        self.client.exchange(step, features, self.wait)
    }

    #[inline]
    fn answer(&mut self, step: u64, features: &Features) -> Answer {
        self.client.answer(step, features, self.wait)
    }

    #[inline]
    fn model_id(&self) -> u32 {
        self.client.last_model_id()
    }
}
