//! A status block in the segment header: a fixed number of words that one side (the loop)
//! publishes about every 100 ms and the other reads, never per step. What the words mean is
//! the protocol's business (haptics-proto's `status` encodes its `LoopStatus` into them);
//! this module only makes a publication atomic as a whole.
//!
//! A seqlock, like one telemetry slot: the writer (the only one) stores an odd sequence word,
//! a release fence, every word (relaxed atomics), then the next even sequence word (release).
//! A reader loads the sequence word (acquire), the words (relaxed), an acquire fence and the
//! sequence word again; the snapshot counts only if both are the same even value, so a reader
//! never sees half of one publication and half of another. Every word is an `AtomicU64`, as in
//! the rest of the segment: a racing read is a stale value that the sequence words discard,
//! never a data race.
//!
//! REAL-TIME: [`StatusBlock::publish`] allocates nothing, takes no lock, makes no syscall
//! (`STATUS_WORDS + 2` relaxed stores).

use std::sync::atomic::{fence, AtomicU64, Ordering};

/// Words of a status publication (fixed: part of the header's layout).
pub const STATUS_WORDS: usize = 77;

/// How many times a reader retries while the writer is mid-publication (one or two retries
/// are the most ever needed unless the writer died mid-write).
const READ_TRIES: usize = 1000;

/// The block in the header. `#[repr(C)]`, atomics only; all zero = never published.
#[repr(C)]
pub struct StatusBlock {
    seq: AtomicU64,
    words: [AtomicU64; STATUS_WORDS],
}

impl Default for StatusBlock {
    fn default() -> Self {
        StatusBlock {
            seq: AtomicU64::new(0),
            words: std::array::from_fn(|_| AtomicU64::new(0)),
        }
    }
}

impl StatusBlock {
    /// Writes a publication. Single writer. REAL-TIME safe: no allocation, no lock, no
    /// syscall. Returns the generation written (1 for the first).
    pub fn publish(&self, words: &[u64; STATUS_WORDS]) -> u64 {
        let r = Ordering::Relaxed;
        let seq = self.seq.load(r);
        // An odd word left by a writer that died mid-publication: start from the next even.
        let base = seq & !1;
        self.seq.store(base + 1, r);
        fence(Ordering::Release);
        for (cell, word) in self.words.iter().zip(words) {
            cell.store(*word, r);
        }
        self.seq.store(base + 2, Ordering::Release);
        (base + 2) / 2
    }

    /// One consistent publication and its generation, or `None` if nothing was published
    /// (or the writer stays mid-write, i.e. died while writing).
    pub fn read(&self) -> Option<(u64, [u64; STATUS_WORDS])> {
        for _ in 0..READ_TRIES {
            let s1 = self.seq.load(Ordering::Acquire);
            if s1 == 0 {
                return None;
            }
            if s1 & 1 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let words = std::array::from_fn(|i| self.words[i].load(Ordering::Relaxed));
            fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) == s1 {
                return Some((s1 / 2, words));
            }
            std::hint::spin_loop();
        }
        None
    }

    /// Leaves the block as a writer that died mid-publication would (for tests).
    #[doc(hidden)]
    pub fn simulate_torn_write(&self) {
        let seq = self.seq.load(Ordering::Relaxed);
        self.seq.store(seq | 1, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn publish_read_and_a_torn_write_heal() {
        let block = StatusBlock::default();
        assert!(block.read().is_none());
        let words: [u64; STATUS_WORDS] = std::array::from_fn(|i| i as u64 * 3 + 1);
        assert_eq!(block.publish(&words), 1);
        assert_eq!(block.read(), Some((1, words)));
        // a writer that died mid-publication: readers give up, the next publication heals it
        block.simulate_torn_write();
        assert!(block.read().is_none());
        assert_eq!(block.publish(&words), 2);
        assert_eq!(block.read().unwrap().0, 2);
    }
}
