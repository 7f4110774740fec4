//! Lock-free shared-memory rings between `rt-loop` and `infer-server`.
//!
//! One segment per loop instance (`/haptics-<instance>`, mode 0600) holds a validated header
//! and four single-producer single-consumer channels: features (loop to server), forces
//! (server to loop), telemetry (loop to server, overwrites the oldest) and a command mailbox
//! (server to loop). Every byte of the segment is accessed only through atomics, so two
//! processes racing on it is defined behaviour, not luck. See `docs/shm-ring.md`.
//!
//! The segment is generic over a [`Protocol`]: the message type of each channel. The haptics
//! system's is `haptics_proto::layout::Haptics` (with `FeatureMsg`, `ForceMsg`, ...); here a
//! one-word message stands in for all four:
//!
//! ```no_run
//! use shm_ring::{layout_id, Config, DecodeError, Message, Protocol, Segment, SegmentName};
//! #[derive(Clone, Copy)]
//! struct Word(u64);
//! impl Message for Word {
//!     const WORDS: usize = 1;
//!     const LAYOUT_ID: u64 = layout_id("Word v1: u64");
//!     fn encode(&self, out: &mut [u64]) { out[0] = self.0 }
//!     fn decode(w: &[u64]) -> Result<Self, DecodeError> { Ok(Word(w[0])) }
//! }
//! struct Words;
//! impl Protocol for Words {
//!     type Features = Word;
//!     type Forces = Word;
//!     type Telemetry = Word;
//!     type Commands = Word;
//! }
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let name = SegmentName::for_instance("default")?;
//! // rt-loop:
//! let mut lp = Segment::<Words>::create(&name, &Config::default())?.loop_side()?;
//! lp.features_tx.try_send(Word(1))?;
//! // infer-server (another process):
//! let mut sv = Segment::<Words>::attach(&name)?.server_side()?;
//! let f = sv.features_rx.recv()?;
//! sv.forces_tx.send(Word(f.0 * 2))?;
//! # Ok(()) }
//! ```

mod fixed_str;
mod message;
mod overwrite;
mod protocol;
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
pub mod os;
#[cfg(not(loom))]
mod segment;
#[cfg(not(loom))]
mod status_block;

pub use fixed_str::{FixedStr, FixedStrError, FIXED_STR_BYTES, FIXED_STR_WORDS};
pub use message::{layout_id, DecodeError, Message, MAX_WORDS};
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
pub use header::{Channel, LAYOUT_VERSION, MAGIC, MAX_SCHEMA_NAMES};
pub use protocol::{MessageShape, Protocol};
#[cfg(not(loom))]
pub use segment::{
    Config, Corruption, Link, Role, Segment, SegmentInfo, SegmentName, StaleSegment, MAX_CAPACITY,
};
#[cfg(not(loom))]
pub use status_block::{StatusBlock, STATUS_WORDS};
