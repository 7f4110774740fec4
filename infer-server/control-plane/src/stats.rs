//! The control plane's own counters, exported on `/metrics` beside the backend's figures.
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

#[derive(Debug, Default)]
pub struct Stats {
    pub ws_clients: AtomicU64,
    pub ws_frames: AtomicU64,
    pub ws_bytes: AtomicU64,
    pub grpc_streams: AtomicU64,
    pub grpc_samples: AtomicU64,
    /// Telemetry batches a slow client missed (broadcast lag).
    pub lagged_batches: AtomicU64,
    pub requests_ok: AtomicU64,
    pub requests_failed: AtomicU64,
    /// Model uploads refused for their size (over --max-upload-mib).
    pub uploads_refused_too_large: AtomicU64,
    /// Model uploads received whole and refused by the load (not a valid model).
    pub uploads_refused_invalid: AtomicU64,
}

impl Stats {
    pub fn add(counter: &AtomicU64, n: u64) {
        counter.fetch_add(n, Relaxed);
    }

    pub fn get(counter: &AtomicU64) -> u64 {
        counter.load(Relaxed)
    }
}

/// Counts a gauge up for as long as it lives.
pub struct GaugeGuard<'a>(&'a AtomicU64);

impl<'a> GaugeGuard<'a> {
    pub fn new(gauge: &'a AtomicU64) -> Self {
        gauge.fetch_add(1, Relaxed);
        Self(gauge)
    }
}

impl Drop for GaugeGuard<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Relaxed);
    }
}
