//! The loop's segment, as seen by the rest of the server.
//!
//! The inference thread attaches to rt-loop's segment (and re-attaches when a new loop starts).
//! It keeps the features and forces rings for itself and publishes the other endpoints here:
//! the telemetry ring (taken by the control side's telemetry thread, `control::telemetry`), the
//! command mailbox (used by the control side to start and stop experiments) and the [`Link`]
//! (liveness, heartbeats). Each endpoint keeps the mapping alive by itself, so a holder that
//! outlives the attachment reads a dead loop's memory safely and simply sees it go quiet.
//!
//! Publishing happens once per attachment, off the hot path; the lock here is never taken by
//! the inference thread while it serves steps.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};

use haptics_proto::{Command, TelemetryRow};
use shm_ring::{Link, OverwriteConsumer, Producer};

/// The endpoints of one attachment that the inference thread does not use.
pub struct LoopEndpoints {
    /// Counts attachments of this server (1 for the first).
    pub attachment: u64,
    pub link: Link,
    /// Taken by the telemetry thread (`None` once taken).
    pub telemetry_rx: Option<OverwriteConsumer<TelemetryRow>>,
    pub commands_tx: Producer<Command>,
}

/// Where the inference thread publishes [`LoopEndpoints`] while it is attached.
#[derive(Default)]
pub struct SharedEndpoints {
    slot: Mutex<Option<LoopEndpoints>>,
    /// The attachment number of what is in `slot`, 0 while detached (read without the lock).
    current: AtomicU64,
}

impl SharedEndpoints {
    pub(crate) fn publish(&self, endpoints: LoopEndpoints) {
        let attachment = endpoints.attachment;
        *self.lock() = Some(endpoints);
        self.current.store(attachment, Ordering::Release);
    }

    pub(crate) fn clear(&self) {
        self.current.store(0, Ordering::Release);
        *self.lock() = None;
    }

    /// The attachment number now published (0: no loop attached). Lock-free.
    pub fn current(&self) -> u64 {
        self.current.load(Ordering::Acquire)
    }

    /// The endpoints of the current attachment, if any (a short lock: do not block under it).
    pub fn lock(&self) -> MutexGuard<'_, Option<LoopEndpoints>> {
        self.slot.lock().unwrap_or_else(|p| p.into_inner())
    }
}
