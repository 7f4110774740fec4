//! Lock-free shared-memory rings between two processes (rt-loop and infer-server).
//!
//! Layered like iceoryx2's building blocks and concepts (`docs/shm-ring.md`, "Layers"):
//!
//! - building blocks, each usable alone: `ring` (the rings in any memory: `sync` atomics, std
//!   or loom; `message`, a message as `u64` words; `mem`, a ring's memory; `wait`, spinning and
//!   the futex event count; `spsc`, the lossless ring; `overwrite`, the ring that overwrites
//!   the oldest), `fixed_str`, `status_block` (a seqlock block), [`os`] (shared memory, liveness
//!   locks, real-time thread set-up, shutdown);
//! - the concept on top: `segment` (a named segment of channels with liveness, validation and
//!   recovery: `segment::channel`, what a segment carries, described by the layer above;
//!   `segment::header`, its header and layout; `segment::{name, config, shared, check, info}`,
//!   its name, what a creator asks for, the mapping every endpoint holds, the checks of its
//!   memory and what a header says; [`Protocol`], how the layer above says which
//!   message types travel where and builds its endpoints).
//!
//! One segment per loop instance (`/haptics-<instance>`, mode 0600) holds a validated header
//! and four single-producer single-consumer channels. Every byte of the segment is accessed
//! only through atomics, so two processes racing on it is defined behaviour, not luck. The
//! haptics system's protocol is `haptics_proto::layout::Haptics`; here a one-word message
//! stands in for all four channels:
//!
//! ```no_run
//! use shm_ring::{layout_id, ChannelSpec, Config, Consumer, DecodeError, Error, Lossless,
//!                Message, Producer, Protocol, Role, Segment, SegmentName, CHANNELS};
//! #[derive(Clone, Copy)]
//! struct Word(u64);
//! impl Message for Word {
//!     const WORDS: usize = 1;
//!     const LAYOUT_ID: u64 = layout_id("Word v1: u64");
//!     fn encode(&self, out: &mut [u64]) { out[0] = self.0 }
//!     fn decode(w: &[u64]) -> Result<Self, DecodeError> { Ok(Word(w[0])) }
//! }
//! const UP: Lossless<Word> = Lossless::at(0);
//! const DOWN: Lossless<Word> = Lossless::at(1);
//! struct Words;
//! impl Protocol for Words {
//!     const CHANNELS: [ChannelSpec; CHANNELS] = [
//!         UP.spec("up", Role::Loop, 64),
//!         DOWN.spec("down", Role::Server, 64),
//!         Lossless::<Word>::at(2).spec("spare-a", Role::Loop, 2),
//!         Lossless::<Word>::at(3).spec("spare-b", Role::Server, 2),
//!     ];
//!     type LoopSide = (Producer<Word>, Consumer<Word>);
//!     type ServerSide = (Consumer<Word>, Producer<Word>);
//!     fn loop_side(s: Segment<Self>) -> Result<Self::LoopSide, Error> {
//!         Ok((s.producer(UP)?, s.consumer(DOWN)?))
//!     }
//!     fn server_side(s: Segment<Self>) -> Result<Self::ServerSide, Error> {
//!         Ok((s.consumer(UP)?, s.producer(DOWN)?))
//!     }
//! }
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let name = SegmentName::for_instance("default")?;
//! // rt-loop:
//! let (mut up, _down) = Segment::<Words>::create(&name, &Config::default())?.loop_side()?;
//! up.try_send(Word(1))?;
//! // infer-server (another process):
//! let (mut up_rx, mut down_tx) = Segment::<Words>::attach(&name)?.server_side()?;
//! let w = up_rx.recv()?;
//! down_tx.send(Word(w.0 * 2))?;
//! # Ok(()) }
//! ```

mod fixed_str;
mod ring;

/// Hooks for the loom models in `tests/loom.rs` (compiled only under `--cfg loom`). Kept in the
/// library, unlike the other test support (`tests/shm-ring-testing`), because they drive the
/// private wake signal (`ring::mem::Signal`, `ring::wait::register_waiter` / `notify`), which no public
/// API exposes; outside loom builds they do not exist.
#[cfg(loom)]
#[doc(hidden)]
pub mod loom_hooks {
    use crate::ring::mem::Signal;
    use crate::ring::sync::{AtomicU32, Ordering};

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
            crate::ring::wait::register_waiter(&self.0)
        }
        /// Notifier side, after publishing.
        pub fn notify(&self) {
            crate::ring::wait::notify(&self.0)
        }
        /// Whether a futex wait on `epoch` would return at once (the value moved).
        pub fn epoch_moved(&self, epoch: u32) -> bool {
            self.0.epoch.load(Ordering::Acquire) != epoch
        }
    }
}

/// What a hostile peer can do to shared memory, for the fuzz targets (not a stable API).
#[cfg(not(loom))]
#[doc(hidden)]
pub mod hostile;
#[cfg(not(loom))]
pub mod os;
#[cfg(not(loom))]
mod segment;
#[cfg(not(loom))]
mod status_block;

pub use fixed_str::{FixedStr, FixedStrError, FIXED_STR_BYTES, FIXED_STR_WORDS};
pub use ring::mem::slot_words;
pub use ring::message::{layout_id, DecodeError, Message, MAX_WORDS};
pub use ring::overwrite::{heap_overwrite_channel, OverwriteConsumer, OverwriteProducer};
pub use ring::spsc::{heap_channel, Consumer, CorruptRing, Producer, RecvError, SendError};
pub use ring::wait::WaitStrategy;
#[cfg(not(loom))]
pub use ring::wait::{monotonic_ns, sleep_until_ns};

#[cfg(not(loom))]
pub use segment::channel::{
    ChannelKind, ChannelSpec, Lossless, MessageShape, Overwrite, Role, CHANNELS,
};
#[cfg(not(loom))]
pub use segment::error::Error;
#[cfg(not(loom))]
pub use segment::header::{LAYOUT_VERSION, MAGIC, MAX_SCHEMA_NAMES};
#[cfg(not(loom))]
pub use segment::{
    Config, Corruption, Link, Protocol, Segment, SegmentInfo, SegmentName, StaleSegment,
    MAX_CAPACITY,
};
#[cfg(not(loom))]
pub use status_block::{StatusBlock, STATUS_WORDS};
