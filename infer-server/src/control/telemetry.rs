//! The telemetry thread: drains the loop's telemetry ring into the control plane's broadcast,
//! and keeps what the rows say about the loop (step, rate, phase, cycle, fallbacks, liveness)
//! in atomics that the status call reads without waiting on anyone.
//!
//! A plain OS thread at the normal scheduling policy (never the inference thread, never a tokio
//! task). Every `period` (4 ms by default) it takes every row waiting in the ring, turns each
//! into a one-step [`Bucket`] (the control plane merges them further per client, min/max, so
//! spikes survive) and publishes them as one batch. Publishing never blocks: a slow client
//! lags and loses batches on its own side. When the loop lags us by more than the ring (8192
//! rows by default: 0.8 s at 10 kHz) the oldest rows are overwritten and counted as drops.

use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use control_plane::{Bucket, TelemetryHub};
use haptics_proto::TelemetryRow;
use shm_ring::{Link, OverwriteConsumer};

use crate::serving::attachment::SharedEndpoints;

/// A loop whose heartbeat and telemetry have both been still this long counts as not alive.
pub const STALE_AFTER: Duration = Duration::from_secs(1);

/// One telemetry row as a one-step bucket, series in the web protocol's order.
pub fn bucket_of(row: &TelemetryRow) -> Bucket {
    Bucket::step(
        row.step,
        row.time,
        haptics_proto::series::values(row),
        row.fallback,
    )
}

/// What the telemetry thread learned about the loop of the current attachment. Single writer
/// (the telemetry thread), any readers.
#[derive(Debug)]
pub struct LoopObserver {
    epoch: Instant,
    /// The attachment these figures belong to (0: none yet).
    pub attachment: AtomicU64,
    /// Rows received during this attachment.
    pub rows: AtomicU64,
    pub last_step: AtomicU64,
    /// Device time of the last row, seconds (f64 bits).
    last_time: AtomicU64,
    pub run_id: AtomicU32,
    pub phase: AtomicU32,
    pub cycle: AtomicU32,
    /// Rows with `fallback` set, during this attachment (a lower bound when rows were dropped).
    pub fallbacks: AtomicU64,
    /// Rows lost because we lagged, during this attachment.
    pub dropped: AtomicU64,
    /// Steps per second over the last ~0.5 s (f64 bits).
    rate_hz: AtomicU64,
    /// Nanoseconds since `epoch` of the last row, and of the last change of the loop's heartbeat.
    last_row_ns: AtomicU64,
    last_heartbeat_ns: AtomicU64,
    /// The loop's process holds its liveness lock (sampled every ~25 ms).
    pub peer_alive: AtomicBool,
}

impl Default for LoopObserver {
    fn default() -> Self {
        Self {
            epoch: Instant::now(),
            attachment: AtomicU64::new(0),
            rows: AtomicU64::new(0),
            last_step: AtomicU64::new(0),
            last_time: AtomicU64::new(0),
            run_id: AtomicU32::new(0),
            phase: AtomicU32::new(0),
            cycle: AtomicU32::new(0),
            fallbacks: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            rate_hz: AtomicU64::new(0),
            last_row_ns: AtomicU64::new(0),
            last_heartbeat_ns: AtomicU64::new(0),
            peer_alive: AtomicBool::new(false),
        }
    }
}

impl LoopObserver {
    fn now_ns(&self) -> u64 {
        self.epoch.elapsed().as_nanos() as u64
    }

    pub fn last_time_s(&self) -> f64 {
        f64::from_bits(self.last_time.load(Ordering::Relaxed))
    }

    pub fn rate_hz(&self) -> f64 {
        f64::from_bits(self.rate_hz.load(Ordering::Relaxed))
    }

    /// Time since the last row, if any came during this attachment.
    pub fn since_last_row(&self) -> Option<Duration> {
        (self.rows.load(Ordering::Relaxed) > 0).then(|| {
            Duration::from_nanos(
                self.now_ns()
                    .saturating_sub(self.last_row_ns.load(Ordering::Relaxed)),
            )
        })
    }

    /// Whether the loop of `attachment` (the one attached now) is alive: its process holds its
    /// lock, and its heartbeat or its telemetry moved within [`STALE_AFTER`].
    pub fn alive(&self, attachment: u64) -> bool {
        if attachment == 0
            || self.attachment.load(Ordering::Acquire) != attachment
            || !self.peer_alive.load(Ordering::Relaxed)
        {
            return false;
        }
        let now = self.now_ns();
        let recent = |t: &AtomicU64| {
            let t = t.load(Ordering::Relaxed);
            t != 0 && now.saturating_sub(t) < STALE_AFTER.as_nanos() as u64
        };
        recent(&self.last_heartbeat_ns) || recent(&self.last_row_ns)
    }

    fn reset(&self, attachment: u64) {
        for a in [
            &self.rows,
            &self.last_step,
            &self.last_time,
            &self.fallbacks,
            &self.dropped,
            &self.rate_hz,
            &self.last_row_ns,
            &self.last_heartbeat_ns,
        ] {
            a.store(0, Ordering::Relaxed);
        }
        for a in [&self.run_id, &self.phase, &self.cycle] {
            a.store(0, Ordering::Relaxed);
        }
        self.peer_alive.store(false, Ordering::Relaxed);
        self.attachment.store(attachment, Ordering::Release);
    }

    fn row(&self, row: &TelemetryRow, now_ns: u64) {
        self.rows.fetch_add(1, Ordering::Relaxed);
        self.last_step.store(row.step, Ordering::Relaxed);
        self.last_time.store(row.time.to_bits(), Ordering::Relaxed);
        self.run_id.store(row.run_id, Ordering::Relaxed);
        self.phase.store(u32::from(row.phase), Ordering::Relaxed);
        self.cycle.store(row.cycle_no, Ordering::Relaxed);
        if row.fallback {
            self.fallbacks.fetch_add(1, Ordering::Relaxed);
        }
        self.last_row_ns.store(now_ns.max(1), Ordering::Relaxed);
    }
}

/// Handle on the telemetry thread.
pub struct TelemetryThread {
    handle: Option<JoinHandle<()>>,
    stop: Arc<AtomicBool>,
}

impl TelemetryThread {
    /// Starts the thread: it follows `endpoints` (taking each attachment's telemetry ring),
    /// publishes on `hub` and keeps `observer` up to date every `period`.
    pub fn spawn(
        endpoints: Arc<SharedEndpoints>,
        hub: TelemetryHub,
        observer: Arc<LoopObserver>,
        period: Duration,
    ) -> std::io::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let thread_stop = Arc::clone(&stop);
        let handle = std::thread::Builder::new()
            .name("telemetry".into())
            .spawn(move || run(&endpoints, &hub, &observer, period, &thread_stop))?;
        Ok(Self {
            handle: Some(handle),
            stop,
        })
    }

    /// Stops the thread (within one period) and waits for it.
    pub fn stop(mut self) {
        self.stop_inner();
    }

    fn stop_inner(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

impl Drop for TelemetryThread {
    fn drop(&mut self) {
        self.stop_inner();
    }
}

/// Most buckets in one published batch (a burst after a stall is split).
const MAX_BATCH: usize = 4096;
const LIVENESS_EVERY: Duration = Duration::from_millis(25);
const RATE_WINDOW: Duration = Duration::from_millis(500);

fn run(
    endpoints: &SharedEndpoints,
    hub: &TelemetryHub,
    observer: &LoopObserver,
    period: Duration,
    stop: &AtomicBool,
) {
    let mut rx: Option<OverwriteConsumer<TelemetryRow>> = None;
    let mut link: Option<Link> = None;
    let mut attachment = 0;
    let mut dropped_at_attach = 0;
    let mut batch: Vec<Bucket> = Vec::with_capacity(MAX_BATCH);
    let mut last_heartbeat = 0u64;
    let mut last_liveness = Instant::now() - LIVENESS_EVERY;
    // (when, step) at the start of the rate window.
    let mut window: Option<(Instant, u64)> = None;
    while !stop.load(Ordering::Relaxed) {
        let current = endpoints.current();
        if current != attachment {
            attachment = current;
            rx = None;
            link = None;
            window = None;
            observer.reset(attachment);
            if current != 0 {
                if let Some(ep) = endpoints.lock().as_mut() {
                    if ep.attachment == current {
                        rx = ep.telemetry_rx.take();
                        link = Some(ep.link.clone());
                        last_heartbeat = ep.link.peer_heartbeat();
                    }
                }
            }
            dropped_at_attach = u64::MAX; // taken after the first drain
        }
        let now = Instant::now();
        if let Some(r) = rx.as_mut() {
            let now_ns = observer.now_ns();
            loop {
                match r.try_recv() {
                    Ok(Some(row)) => {
                        observer.row(&row, now_ns);
                        batch.push(bucket_of(&row));
                        if batch.len() >= MAX_BATCH {
                            hub.publish(std::mem::take(&mut batch));
                        }
                    }
                    Ok(None) => break,
                    Err(e) => {
                        eprintln!("infer-server: telemetry ring unusable ({e}); ignoring it until the next loop attaches");
                        rx = None;
                        break;
                    }
                }
            }
            if let Some(r) = rx.as_ref() {
                // Rows overwritten before we attached were never ours to lose.
                if dropped_at_attach == u64::MAX {
                    dropped_at_attach = r.dropped();
                }
                observer
                    .dropped
                    .store(r.dropped() - dropped_at_attach, Ordering::Relaxed);
            }
        }
        if !batch.is_empty() {
            hub.publish(std::mem::take(&mut batch));
            batch.reserve(MAX_BATCH);
        }
        if let Some(l) = &link {
            let hb = l.peer_heartbeat();
            if hb != last_heartbeat {
                last_heartbeat = hb;
                observer
                    .last_heartbeat_ns
                    .store(observer.now_ns().max(1), Ordering::Relaxed);
            }
            if now.duration_since(last_liveness) >= LIVENESS_EVERY {
                last_liveness = now;
                observer.peer_alive.store(l.peer_alive(), Ordering::Relaxed);
            }
        }
        update_rate(observer, &mut window, now);
        std::thread::sleep(period);
    }
}

fn update_rate(observer: &LoopObserver, window: &mut Option<(Instant, u64)>, now: Instant) {
    let quiet = observer
        .since_last_row()
        .is_none_or(|d| d > Duration::from_secs(1));
    if quiet {
        observer.rate_hz.store(0f64.to_bits(), Ordering::Relaxed);
        *window = None;
        return;
    }
    let step = observer.last_step.load(Ordering::Relaxed);
    match *window {
        Some((_, s0)) if step < s0 => *window = Some((now, step)), // a new run
        Some((t0, s0)) => {
            let dt = now.duration_since(t0);
            if dt >= RATE_WINDOW {
                let rate = (step - s0) as f64 / dt.as_secs_f64();
                observer.rate_hz.store(rate.to_bits(), Ordering::Relaxed);
                *window = Some((now, step));
            }
        }
        None => *window = Some((now, step)),
    }
}
