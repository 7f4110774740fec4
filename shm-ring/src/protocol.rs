//! What a segment carries, as the segment needs to know it: the message type of each of its
//! four channels. The protocol crate that uses the segment (haptics-proto) names the types;
//! the segment only needs their shapes (payload words, layout fingerprint) to size the rings
//! and to refuse a peer built with a different field list.
//!
//! SEAM (issue 15): the channels are still the four of the haptics segment (features, forces,
//! telemetry overwriting, commands) and `endpoints` still bundles them per side; the protocol
//! only supplies the message types. Making the channel set itself generic is shm-ring's next
//! step.

use crate::message::Message;

/// The message types of a segment's four channels.
pub trait Protocol: 'static {
    /// Loop to server, lossless (`Producer`/`Consumer`).
    type Features: Message;
    /// Server to loop, lossless.
    type Forces: Message;
    /// Loop to server, overwrites the oldest (`OverwriteProducer`/`OverwriteConsumer`).
    type Telemetry: Message;
    /// Server to loop, lossless (the mailbox).
    type Commands: Message;
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

/// The four channels' shapes of `P`, in header order.
pub(crate) fn shapes<P: Protocol>() -> [MessageShape; 4] {
    [
        MessageShape::of::<P::Features>(),
        MessageShape::of::<P::Forces>(),
        MessageShape::of::<P::Telemetry>(),
        MessageShape::of::<P::Commands>(),
    ]
}
