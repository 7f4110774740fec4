//! The loop-status block of the segment header: what the loop reports about itself (clock,
//! board, scheduling obtained, recorder state, counters, round-trip and jitter percentiles)
//! for infer-server's status, written by the loop about every 100 ms, never per step.
//!
//! A seqlock, like one telemetry slot: the loop (the only writer) stores an odd sequence word,
//! a release fence, every field (relaxed atomics), then the next even sequence word (release).
//! A reader loads the sequence word (acquire), the fields (relaxed), an acquire fence and the
//! sequence word again; the snapshot counts only if both are the same even value, so a reader
//! never sees half of one publication and half of another. Every word is an `AtomicU64`, as in
//! the rest of the segment: a racing read is a stale value that the sequence words discard,
//! never a data race.
//!
//! REAL-TIME: [`StatusBlock::publish`] allocates nothing, takes no lock, makes no syscall
//! (about 60 relaxed stores). Text fields are fixed-size byte arrays ([`StatusText`]),
//! filled with `core::fmt` (no allocation) and truncated at a character boundary.

use std::fmt;
use std::sync::atomic::{fence, AtomicU64, Ordering};

/// Bytes of [`LoopStatus::board`].
pub const BOARD_BYTES: usize = 32;
/// Bytes of [`LoopStatus::scheduling`].
pub const SCHEDULING_BYTES: usize = 64;
/// Bytes of [`LoopStatus::recorder`].
pub const RECORDER_BYTES: usize = 128;
/// Bytes of [`LoopStatus::experiment`].
pub const EXPERIMENT_BYTES: usize = 32;

/// How the loop paces its steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LoopClock {
    /// Not reported (a loop that never published).
    #[default]
    Unknown = 0,
    /// Next step at once, simulated time: deterministic.
    Lockstep = 1,
    /// Absolute deadlines on CLOCK_MONOTONIC.
    Realtime = 2,
}

impl LoopClock {
    pub fn as_str(self) -> &'static str {
        match self {
            LoopClock::Unknown => "",
            LoopClock::Lockstep => "lockstep",
            LoopClock::Realtime => "realtime",
        }
    }

    fn from_word(w: u64) -> LoopClock {
        match w {
            1 => LoopClock::Lockstep,
            2 => LoopClock::Realtime,
            _ => LoopClock::Unknown,
        }
    }
}

/// A UTF-8 string of at most `N` bytes stored inline (`N` a multiple of 8). Writing more
/// truncates at the last whole character that fits; formatting into it (`write!`) never
/// allocates and never fails.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct StatusText<const N: usize> {
    bytes: [u8; N],
    len: usize,
}

impl<const N: usize> Default for StatusText<N> {
    fn default() -> Self {
        StatusText {
            bytes: [0; N],
            len: 0,
        }
    }
}

impl<const N: usize> StatusText<N> {
    /// `s`, truncated to fit.
    pub fn new(s: &str) -> Self {
        let mut t = Self::default();
        t.push_str(s);
        t
    }

    /// Replaces the text with `s` (truncated to fit).
    pub fn set(&mut self, s: &str) {
        self.clear();
        self.push_str(s);
    }

    pub fn clear(&mut self) {
        self.bytes = [0; N];
        self.len = 0;
    }

    /// Appends as much of `s` as fits, cut at a character boundary. Returns whether all of it did.
    pub fn push_str(&mut self, s: &str) -> bool {
        let room = N - self.len;
        let mut take = s.len().min(room);
        while !s.is_char_boundary(take) {
            take -= 1;
        }
        self.bytes[self.len..self.len + take].copy_from_slice(&s.as_bytes()[..take]);
        self.len += take;
        take == s.len()
    }

    pub fn as_str(&self) -> &str {
        // Only ever filled from `&str` cut at character boundaries, or validated on read.
        std::str::from_utf8(&self.bytes[..self.len]).unwrap_or("")
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    fn store(&self, cells: &[AtomicU64]) {
        for (cell, chunk) in cells.iter().zip(self.bytes.chunks_exact(8)) {
            cell.store(
                u64::from_le_bytes(chunk.try_into().expect("8-byte chunk")),
                Ordering::Relaxed,
            );
        }
    }

    fn load(cells: &[AtomicU64]) -> Self {
        let mut bytes = [0u8; N];
        for (chunk, cell) in bytes.chunks_exact_mut(8).zip(cells) {
            chunk.copy_from_slice(&cell.load(Ordering::Relaxed).to_le_bytes());
        }
        let end = bytes.iter().position(|&b| b == 0).unwrap_or(N);
        // A scribbled segment cannot make us return invalid UTF-8: keep the valid prefix.
        let len = match std::str::from_utf8(&bytes[..end]) {
            Ok(_) => end,
            Err(e) => e.valid_up_to(),
        };
        bytes[len..].fill(0);
        StatusText { bytes, len }
    }
}

impl<const N: usize> fmt::Write for StatusText<N> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        self.push_str(s);
        Ok(()) // truncation is the documented behaviour, not an error
    }
}

impl<const N: usize> fmt::Debug for StatusText<N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self.as_str(), f)
    }
}

impl<const N: usize> fmt::Display for StatusText<N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Percentiles of a latency distribution, nanoseconds (0 when `count` is 0).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Quantiles {
    pub p50_ns: u64,
    pub p99_ns: u64,
    pub p999_ns: u64,
    pub max_ns: u64,
    pub count: u64,
}

/// What the loop reports about itself (one snapshot of the block).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LoopStatus {
    /// Publications so far (1 for the first); 0 never comes out of a read.
    pub generation: u64,
    /// Wall clock (Unix ns) of this publication: tells a stale block from a live one.
    pub updated_unix_ns: u64,
    pub clock: LoopClock,
    /// "sim", "replay", ...
    pub board: StatusText<BOARD_BYTES>,
    /// The nominal step rate.
    pub rate_hz: f64,
    /// What the loop obtained, e.g. "SCHED_FIFO 80 cpu 1" or "SCHED_OTHER (FIFO refused: EPERM)".
    pub scheduling: StatusText<SCHEDULING_BYTES>,
    /// "off", "writing PATH rows N", "failed: reason".
    pub recorder: StatusText<RECORDER_BYTES>,
    /// Whether an experiment runs; the counters below are that run's (or the last run's).
    pub running: bool,
    pub run_id: u64,
    pub steps: u64,
    /// Steps not rendered by the model's on-time answer (late_one + held + fallback_steps).
    pub fallbacks: u64,
    /// The experiment running (or last run): "reproduction", "shadow", "abstraction", ...
    pub experiment: StatusText<EXPERIMENT_BYTES>,
    /// Degradation ladder (issue 14): steps rendered by the model's on-time answer,
    pub on_time: u64,
    /// by the previous step's answer arriving one period late,
    pub late_one: u64,
    /// by the last served force held (extrapolated),
    pub held: u64,
    /// by the fallback law (cross-faded).
    pub fallback_steps: u64,
    /// Ring slots or indices the loop found corrupt.
    pub corrupt: u64,
    /// Largest change of the rendered force in one step caused by a ladder transition, N.
    pub max_transition_step_n: f64,
    /// Steps whose answer did not come before the per-step deadline.
    pub deadline_misses: u64,
    /// Steps that ended after the next period had begun (realtime clock).
    pub overruns: u64,
    /// Round trip features -> force as the loop observed it.
    pub round_trip: Quantiles,
    /// |actual period - nominal period| (realtime clock).
    pub period_jitter: Quantiles,
}

const fn words(bytes: usize) -> usize {
    bytes / 8
}

/// The block in the header. `#[repr(C)]`, atomics only.
#[repr(C)]
pub(crate) struct StatusBlock {
    seq: AtomicU64,
    updated_unix_ns: AtomicU64,
    clock: AtomicU64,
    rate_hz_bits: AtomicU64,
    running: AtomicU64,
    run_id: AtomicU64,
    steps: AtomicU64,
    fallbacks: AtomicU64,
    deadline_misses: AtomicU64,
    overruns: AtomicU64,
    round_trip: [AtomicU64; 5],
    period_jitter: [AtomicU64; 5],
    board: [AtomicU64; words(BOARD_BYTES)],
    scheduling: [AtomicU64; words(SCHEDULING_BYTES)],
    recorder: [AtomicU64; words(RECORDER_BYTES)],
    // layout version 3: the ladder's counters and the experiment's name
    on_time: AtomicU64,
    late_one: AtomicU64,
    held: AtomicU64,
    fallback_steps: AtomicU64,
    corrupt: AtomicU64,
    max_transition_step_n_bits: AtomicU64,
    experiment: [AtomicU64; words(EXPERIMENT_BYTES)],
}

/// How many times a reader retries while the loop is mid-publication (it writes ~50 words,
/// so one or two retries are the most ever needed unless the loop died mid-write).
const READ_TRIES: usize = 1000;

fn store_q(cells: &[AtomicU64; 5], q: &Quantiles) {
    for (c, v) in cells
        .iter()
        .zip([q.p50_ns, q.p99_ns, q.p999_ns, q.max_ns, q.count])
    {
        c.store(v, Ordering::Relaxed);
    }
}

fn load_q(cells: &[AtomicU64; 5]) -> Quantiles {
    let l = |i: usize| cells[i].load(Ordering::Relaxed);
    Quantiles {
        p50_ns: l(0),
        p99_ns: l(1),
        p999_ns: l(2),
        max_ns: l(3),
        count: l(4),
    }
}

impl StatusBlock {
    /// Writes a snapshot. Single writer (the loop). REAL-TIME safe: no allocation, no lock,
    /// no syscall. Returns the generation written.
    pub(crate) fn publish(&self, s: &LoopStatus) -> u64 {
        let r = Ordering::Relaxed;
        let seq = self.seq.load(r);
        // An odd word left by a writer that died mid-publication: start from the next even.
        let base = seq & !1;
        self.seq.store(base + 1, r);
        fence(Ordering::Release);
        self.updated_unix_ns.store(s.updated_unix_ns, r);
        self.clock.store(s.clock as u64, r);
        self.rate_hz_bits.store(s.rate_hz.to_bits(), r);
        self.running.store(u64::from(s.running), r);
        self.run_id.store(s.run_id, r);
        self.steps.store(s.steps, r);
        self.fallbacks.store(s.fallbacks, r);
        self.deadline_misses.store(s.deadline_misses, r);
        self.overruns.store(s.overruns, r);
        store_q(&self.round_trip, &s.round_trip);
        store_q(&self.period_jitter, &s.period_jitter);
        s.board.store(&self.board);
        s.scheduling.store(&self.scheduling);
        s.recorder.store(&self.recorder);
        self.on_time.store(s.on_time, r);
        self.late_one.store(s.late_one, r);
        self.held.store(s.held, r);
        self.fallback_steps.store(s.fallback_steps, r);
        self.corrupt.store(s.corrupt, r);
        self.max_transition_step_n_bits
            .store(s.max_transition_step_n.to_bits(), r);
        s.experiment.store(&self.experiment);
        self.seq.store(base + 2, Ordering::Release);
        (base + 2) / 2
    }

    /// One consistent snapshot, or `None` if the loop never published (or stays mid-write,
    /// i.e. died while writing).
    pub(crate) fn read(&self) -> Option<LoopStatus> {
        for _ in 0..READ_TRIES {
            let s1 = self.seq.load(Ordering::Acquire);
            if s1 == 0 {
                return None;
            }
            if s1 & 1 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let r = Ordering::Relaxed;
            let snapshot = LoopStatus {
                generation: s1 / 2,
                updated_unix_ns: self.updated_unix_ns.load(r),
                clock: LoopClock::from_word(self.clock.load(r)),
                board: StatusText::load(&self.board),
                rate_hz: f64::from_bits(self.rate_hz_bits.load(r)),
                scheduling: StatusText::load(&self.scheduling),
                recorder: StatusText::load(&self.recorder),
                running: self.running.load(r) != 0,
                run_id: self.run_id.load(r),
                steps: self.steps.load(r),
                fallbacks: self.fallbacks.load(r),
                deadline_misses: self.deadline_misses.load(r),
                overruns: self.overruns.load(r),
                round_trip: load_q(&self.round_trip),
                period_jitter: load_q(&self.period_jitter),
                experiment: StatusText::load(&self.experiment),
                on_time: self.on_time.load(r),
                late_one: self.late_one.load(r),
                held: self.held.load(r),
                fallback_steps: self.fallback_steps.load(r),
                corrupt: self.corrupt.load(r),
                max_transition_step_n: f64::from_bits(self.max_transition_step_n_bits.load(r)),
            };
            fence(Ordering::Acquire);
            if self.seq.load(r) == s1 {
                return Some(snapshot);
            }
            std::hint::spin_loop();
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fmt::Write;

    #[test]
    fn text_truncates_at_a_character_boundary() {
        let mut t = StatusText::<8>::default();
        assert!(!t.push_str("abcdefgé")); // é is 2 bytes: only 7 + 0 fit
        assert_eq!(t.as_str(), "abcdefg");
        let mut t = StatusText::<16>::new("rows ");
        write!(t, "{}", 123456u64).unwrap();
        assert_eq!(t.as_str(), "rows 123456");
        t.set("x");
        assert_eq!(t.as_str(), "x");
    }

    #[test]
    fn block_round_trip_on_the_heap() {
        let block: StatusBlock = unsafe { std::mem::zeroed() };
        assert!(block.read().is_none());
        let s = LoopStatus {
            clock: LoopClock::Realtime,
            board: StatusText::new("sim"),
            rate_hz: 10_000.0,
            scheduling: StatusText::new("SCHED_FIFO 80 cpu 1"),
            recorder: StatusText::new("writing /tmp/a.parquet rows 12"),
            running: true,
            run_id: 3,
            steps: 7,
            fallbacks: 2,
            deadline_misses: 1,
            overruns: 4,
            round_trip: Quantiles {
                p50_ns: 1,
                p99_ns: 2,
                p999_ns: 3,
                max_ns: 4,
                count: 5,
            },
            period_jitter: Quantiles {
                p50_ns: 6,
                p99_ns: 7,
                p999_ns: 8,
                max_ns: 9,
                count: 10,
            },
            updated_unix_ns: 11,
            generation: 0,
            experiment: StatusText::new("shadow"),
            on_time: 12,
            late_one: 13,
            held: 14,
            fallback_steps: 15,
            corrupt: 16,
            max_transition_step_n: 0.04,
        };
        assert_eq!(block.publish(&s), 1);
        let back = block.read().expect("published");
        assert_eq!(back, LoopStatus { generation: 1, ..s });
        // a writer that died mid-publication: readers give up, the next publication heals it
        block.seq.store(3, Ordering::Relaxed);
        assert!(block.read().is_none());
        assert_eq!(block.publish(&s), 2);
        assert_eq!(block.read().unwrap().generation, 2);
    }
}
