//! A short UTF-8 string stored inline in 32 bytes (four `u64` words): feature names in the
//! header, experiment and parameter names in commands. Fixed size, so no allocation and no
//! pointer ever crosses the process boundary.

use std::fmt;

/// Bytes a [`FixedStr`] can hold.
pub const FIXED_STR_BYTES: usize = 32;
/// Words a [`FixedStr`] occupies.
pub const FIXED_STR_WORDS: usize = FIXED_STR_BYTES / 8;

/// A UTF-8 string of at most 32 bytes, zero-padded.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct FixedStr {
    bytes: [u8; FIXED_STR_BYTES],
    len: u8,
}

/// A string does not fit a [`FixedStr`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FixedStrError {
    #[error("`{0}` is longer than {FIXED_STR_BYTES} bytes")]
    TooLong(String),
    #[error("`{0}` contains a NUL byte")]
    Nul(String),
}

impl FixedStr {
    /// Copies `s` in; refuses strings over 32 bytes or containing NUL (the padding byte).
    pub fn new(s: &str) -> Result<Self, FixedStrError> {
        if s.len() > FIXED_STR_BYTES {
            return Err(FixedStrError::TooLong(s.to_owned()));
        }
        if s.as_bytes().contains(&0) {
            return Err(FixedStrError::Nul(s.to_owned()));
        }
        let mut bytes = [0u8; FIXED_STR_BYTES];
        bytes[..s.len()].copy_from_slice(s.as_bytes());
        Ok(FixedStr {
            bytes,
            len: s.len() as u8,
        })
    }

    /// The string.
    pub fn as_str(&self) -> &str {
        // Only ever built from a `&str` or validated in `from_words`.
        std::str::from_utf8(&self.bytes[..self.len as usize]).unwrap_or("")
    }

    pub fn to_words(self) -> [u64; FIXED_STR_WORDS] {
        let mut words = [0u64; FIXED_STR_WORDS];
        for (word, chunk) in words.iter_mut().zip(self.bytes.chunks_exact(8)) {
            *word = u64::from_le_bytes(chunk.try_into().expect("8-byte chunk"));
        }
        words
    }

    /// Rebuilds from words; `None` if the bytes are not NUL-padded UTF-8.
    pub fn from_words(words: &[u64]) -> Option<Self> {
        let mut bytes = [0u8; FIXED_STR_BYTES];
        for (chunk, word) in bytes.chunks_exact_mut(8).zip(words) {
            chunk.copy_from_slice(&word.to_le_bytes());
        }
        let len = bytes
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(FIXED_STR_BYTES);
        if bytes[len..].iter().any(|&b| b != 0) {
            return None;
        }
        std::str::from_utf8(&bytes[..len]).ok()?;
        Some(FixedStr {
            bytes,
            len: len as u8,
        })
    }
}

impl fmt::Debug for FixedStr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self.as_str(), f)
    }
}

impl fmt::Display for FixedStr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}
