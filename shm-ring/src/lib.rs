//! Lock-free shared-memory rings between `rt-loop` and `infer-server`.
//!
//! One segment per loop instance (`/haptics-<instance>`, mode 0600) holds a validated header
//! and four single-producer single-consumer channels: features (loop to server), forces
//! (server to loop), telemetry (loop to server, overwrites the oldest) and a command mailbox
//! (server to loop). Every byte of the segment is accessed only through atomics, so two
//! processes racing on it is defined behaviour, not luck. See `docs/shm-ring.md`.
//!
//! ```no_run
//! use shm_ring::{Config, Segment, SegmentName, FeatureMsg, ForceMsg};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let name = SegmentName::for_instance("default")?;
//! // rt-loop:
//! let mut lp = Segment::create(&name, &Config::default())?.loop_side()?;
//! lp.features_tx.try_send(FeatureMsg { seq: 1, ..Default::default() })?;
//! // infer-server (another process):
//! let mut sv = Segment::attach(&name)?.server_side()?;
//! let f = sv.features_rx.recv()?;
//! sv.forces_tx.send(ForceMsg { seq: f.seq, force: 1.5, ..Default::default() })?;
//! # Ok(()) }
//! ```

mod fixed_str;
mod message;
mod messages;
mod overwrite;
#[doc(hidden)]
pub mod pattern;
mod ring_mem;
mod spsc;
mod sync;
mod wait;

/// Hooks for the loom models in `tests/loom.rs` (compiled only under `--cfg loom`).
#[cfg(loom)]
#[doc(hidden)]
pub mod loom_hooks {
    use crate::ring_mem::Signal;
    use crate::sync::{AtomicU32, Ordering};

    /// A bare wake signal with the real `register_waiter` / `notify` code.
    pub struct Handshake(Signal);

    impl Default for Handshake {
        fn default() -> Self {
            Handshake(Signal {
                epoch: AtomicU32::new(0),
                parked: AtomicU32::new(0),
            })
        }
    }

    impl Handshake {
        /// Waiter side: returns the epoch it would sleep on.
        pub fn register_waiter(&self) -> u32 {
            crate::wait::register_waiter(&self.0)
        }
        /// Notifier side, after publishing.
        pub fn notify(&self) {
            crate::wait::notify(&self.0)
        }
        /// Whether a futex wait on `epoch` would return at once (the value moved).
        pub fn epoch_moved(&self, epoch: u32) -> bool {
            self.0.epoch.load(Ordering::Acquire) != epoch
        }
    }
}

#[cfg(not(loom))]
mod endpoints;
#[cfg(not(loom))]
mod error;
/// Entry points for the `cargo fuzz` targets in `fuzz/` (not a stable API).
#[cfg(not(loom))]
#[doc(hidden)]
pub mod fuzzing;
#[cfg(not(loom))]
mod header;
#[cfg(not(loom))]
mod loop_status;
#[cfg(not(loom))]
pub mod os;
#[cfg(not(loom))]
mod segment;

pub use fixed_str::{FixedStr, FixedStrError, FIXED_STR_BYTES};
pub use message::{layout_id, DecodeError, Message, MAX_WORDS};
pub use messages::{
    Command, CommandKind, FeatureMsg, ForceMsg, TelemetryRow, COMMAND_VALUES, MAX_FEATURES,
};
pub use overwrite::{heap_overwrite_channel, OverwriteConsumer, OverwriteProducer};
pub use ring_mem::slot_words;
pub use spsc::{heap_channel, Consumer, CorruptRing, Producer, RecvError, SendError};
pub use wait::WaitStrategy;
#[cfg(not(loom))]
pub use wait::{monotonic_ns, sleep_until_ns};

#[cfg(not(loom))]
pub use endpoints::{LoopSide, ServerSide};
#[cfg(not(loom))]
pub use error::Error;
#[cfg(not(loom))]
pub use header::{Channel, LAYOUT_VERSION, MAGIC};
#[cfg(not(loom))]
pub use loop_status::{
    LoopClock, LoopStatus, Quantiles, StatusText, BOARD_BYTES, EXPERIMENT_BYTES, RECORDER_BYTES,
    SCHEDULING_BYTES,
};
#[cfg(not(loom))]
pub use segment::{
    Config, Corruption, Link, Role, Segment, SegmentInfo, SegmentName, StaleSegment, MAX_CAPACITY,
    THESIS_FEATURES,
};
