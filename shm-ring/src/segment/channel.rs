//! What a segment carries, described by the layer above it: each channel's name, kind
//! (lossless or overwriting), which side writes it, the shape of its message type (payload
//! words and layout fingerprint) and its default capacity. The segment sizes its rings from
//! these descriptions and refuses a peer whose descriptions differ; it never names a message
//! type itself.
//!
//! A protocol crate (haptics-proto's `layout`) declares typed channel ids, [`Lossless`] and
//! [`Overwrite`], and builds its endpoints from a segment with them
//! (`Segment::producer(FEATURES)`), so only the upper layer knows which type travels where.
//!
//! Imports nothing of the crate but the message trait.

use std::marker::PhantomData;

use crate::ring::message::Message;

/// Channels per segment: the header has a fixed array of channel descriptions (changing it
/// changes the layout version).
pub const CHANNELS: usize = 4;

/// Which side a handle is: the creator of the segment (rt-loop) or the one attached to it
/// (infer-server).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// The creator (rt-loop).
    Loop,
    /// The attached side (infer-server).
    Server,
}

impl Role {
    pub fn name(self) -> &'static str {
        match self {
            Role::Loop => "loop",
            Role::Server => "server",
        }
    }

    /// The other side.
    pub fn peer(self) -> Role {
        match self {
            Role::Loop => Role::Server,
            Role::Server => Role::Loop,
        }
    }
}

/// How a channel's ring treats a full ring.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChannelKind {
    /// `Producer` / `Consumer`: a full ring refuses (or the producer waits); nothing is lost.
    Lossless,
    /// `OverwriteProducer` / `OverwriteConsumer`: the producer overwrites the oldest message;
    /// the consumer counts what it lost.
    Overwrite,
}

/// Payload words and layout fingerprint of one channel's message type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MessageShape {
    pub words: usize,
    pub layout_id: u64,
}

impl MessageShape {
    /// The shape of `M`.
    pub const fn of<M: Message>() -> MessageShape {
        MessageShape {
            words: M::WORDS,
            layout_id: M::LAYOUT_ID,
        }
    }
}

/// One channel as the segment needs to know it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelSpec {
    /// For errors and diagnostics ("features").
    pub name: &'static str,
    pub kind: ChannelKind,
    /// The side that writes (produces); the other side reads.
    pub writer: Role,
    pub shape: MessageShape,
    /// Slots when the creator's `Config` leaves the capacity at 0.
    pub default_capacity: usize,
}

/// A lossless channel carrying `M`, at position `index` of the protocol's channel list.
pub struct Lossless<M> {
    index: usize,
    _message: PhantomData<fn() -> M>,
}

/// An overwriting channel carrying `M`, at position `index` of the protocol's channel list.
pub struct Overwrite<M> {
    index: usize,
    _message: PhantomData<fn() -> M>,
}

macro_rules! typed_channel {
    ($ty:ident, $kind:expr) => {
        impl<M: Message> $ty<M> {
            /// The channel at `index` (`< CHANNELS`; checked when the protocol's channel list
            /// is built, see [`ChannelSpec`]).
            pub const fn at(index: usize) -> Self {
                assert!(index < CHANNELS, "channel index out of range");
                $ty {
                    index,
                    _message: PhantomData,
                }
            }

            /// Its position in the protocol's channel list.
            pub const fn index(&self) -> usize {
                self.index
            }

            /// Its description, for the protocol's channel list.
            pub const fn spec(
                &self,
                name: &'static str,
                writer: Role,
                default_capacity: usize,
            ) -> ChannelSpec {
                ChannelSpec {
                    name,
                    kind: $kind,
                    writer,
                    shape: MessageShape::of::<M>(),
                    default_capacity,
                }
            }
        }

        impl<M> Clone for $ty<M> {
            fn clone(&self) -> Self {
                *self
            }
        }

        impl<M> Copy for $ty<M> {}
    };
}

typed_channel!(Lossless, ChannelKind::Lossless);
typed_channel!(Overwrite, ChannelKind::Overwrite);
