//! How a message becomes the `u64` words of a slot, and back.
//!
//! Every slot payload is an array of `AtomicU64` words (see `ring_mem`), so a message is
//! encoded to plain words on the producer's stack, stored word by word with atomic stores, and
//! decoded from words loaded with atomic loads. No shared byte is ever read with a plain load.

/// Most payload words any message may use (bounds the on-stack encode buffer).
pub const MAX_WORDS: usize = 40;

/// A fixed-size message that can travel through a ring.
pub trait Message: Sized {
    /// Payload words this message occupies (at most [`MAX_WORDS`]).
    const WORDS: usize;
    /// Fingerprint of the field list: stored in the segment header, so that two builds that
    /// disagree on a message's layout refuse to talk instead of misreading each other.
    const LAYOUT_ID: u64;
    /// Writes exactly `Self::WORDS` words into `out[..Self::WORDS]`.
    fn encode(&self, out: &mut [u64]);
    /// Reads a message back from `words[..Self::WORDS]`; rejects words that do not make a
    /// valid message (an unknown enum tag, an out-of-range length).
    fn decode(words: &[u64]) -> Result<Self, DecodeError>;
}

/// A slot's words did not form a valid message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    #[error("field `{field}` holds an invalid value {value:#x}")]
    InvalidField { field: &'static str, value: u64 },
}

/// FNV-1a over a field-list description; `const` so a layout id is a compile-time constant.
pub const fn layout_id(description: &str) -> u64 {
    let bytes = description.as_bytes();
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    let mut i = 0;
    while i < bytes.len() {
        hash ^= bytes[i] as u64;
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
        i += 1;
    }
    hash
}
