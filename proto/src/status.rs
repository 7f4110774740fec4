//! The loop-status block: what the loop reports about itself (clock, board, scheduling
//! obtained, recorder state, the experiment's name, counters, round-trip and jitter
//! percentiles) for infer-server's status, written by the loop about every 100 ms, never per
//! step, into the segment header's status block (`shm_ring::StatusBlock`, a seqlock: readers
//! never see half of one publication). This module says what its words mean.
//!
//! REAL-TIME: [`LoopStatusLink::publish_loop_status`] allocates nothing, takes no lock, makes
//! no syscall (an on-stack word array, then the seqlock's relaxed stores). Text fields are
//! fixed-size byte arrays ([`StatusText`]), filled with `core::fmt` (no allocation) and
//! truncated at a character boundary.

use std::fmt;

use shm_ring::{Link, STATUS_WORDS};

/// Bytes of [`LoopStatus::board`].
pub const BOARD_BYTES: usize = 32;
/// Bytes of [`LoopStatus::scheduling`].
pub const SCHEDULING_BYTES: usize = 64;
/// Bytes of [`LoopStatus::recorder`].
pub const RECORDER_BYTES: usize = 128;
/// Bytes of [`LoopStatus::experiment`].
pub const EXPERIMENT_BYTES: usize = 32;
/// Bytes of [`LoopStatus::board_fault`].
pub const BOARD_FAULT_BYTES: usize = 64;

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

    fn store(&self, out: &mut [u64]) {
        for (word, chunk) in out.iter_mut().zip(self.bytes.chunks_exact(8)) {
            *word = u64::from_le_bytes(chunk.try_into().expect("8-byte chunk"));
        }
    }

    fn load(words: &[u64]) -> Self {
        let mut bytes = [0u8; N];
        for (chunk, word) in bytes.chunks_exact_mut(8).zip(words) {
            chunk.copy_from_slice(&word.to_le_bytes());
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
    /// Steps rendered by a model's answer that was above the force limit, at the limit
    /// (issue 23: a device saturates; not a rung, a count beside them).
    pub saturated: u64,
    /// Steps whose answer did not come before the per-step deadline.
    pub deadline_misses: u64,
    /// Steps that ended after the next period had begun (realtime clock).
    pub overruns: u64,
    /// Round trip features -> force as the loop observed it.
    pub round_trip: Quantiles,
    /// |actual period - nominal period| (realtime clock).
    pub period_jitter: Quantiles,
    /// Board failures that ended a run (a read, a DAC write or a watchdog kick failed, the
    /// board gone, its watchdog tripped) since the loop started: each put the motor at 0 A.
    pub board_faults: u64,
    /// The last such failure's reason ("" when none).
    pub board_fault: StatusText<BOARD_FAULT_BYTES>,
    /// Snapshots a real board's FIFO lost (counted, not fatal), this run.
    pub board_fifo_overflows: u64,
    /// Snapshots with a quadrature error (counted, not fatal), this run.
    pub board_quadrature_errors: u64,
    /// The passivity layer (issue 20): whether its damper acts (the observer always runs),
    pub passivity_on: bool,
    /// the energy the rendered object holds by its observer (received - returned, less the
    /// forgotten dissipated energy), J,
    pub passivity_energy_j: f64,
    /// the gross energy the object received from the hand and returned to it, J,
    pub passivity_received_j: f64,
    pub passivity_returned_j: f64,
    /// the largest damping it applied this run, N s/m,
    pub passivity_damping_ns_per_m: f64,
    /// and the steps on which it changed the rendered force.
    pub passivity_active_steps: u64,
    /// The filters the loop computes its velocity and acceleration features with (its
    /// `g_v`, `g_a`), rad/s: infer-server compares a model's `haptics.feature_gains` with them.
    pub velocity_gain_rad_s: f64,
    pub acceleration_gain_rad_s: f64,
}

const fn words(bytes: usize) -> usize {
    bytes / 8
}

/// Where each field sits in the block's words (the order of layout version 5; changing it
/// changes the segment layout: bump `shm_ring::LAYOUT_VERSION`).
mod at {
    use super::*;
    pub const UPDATED_UNIX_NS: usize = 0;
    pub const CLOCK: usize = 1;
    pub const RATE_HZ: usize = 2;
    pub const RUNNING: usize = 3;
    pub const RUN_ID: usize = 4;
    pub const STEPS: usize = 5;
    pub const FALLBACKS: usize = 6;
    pub const DEADLINE_MISSES: usize = 7;
    pub const OVERRUNS: usize = 8;
    pub const ROUND_TRIP: usize = 9;
    pub const PERIOD_JITTER: usize = ROUND_TRIP + 5;
    pub const BOARD: usize = PERIOD_JITTER + 5;
    pub const SCHEDULING: usize = BOARD + words(BOARD_BYTES);
    pub const RECORDER: usize = SCHEDULING + words(SCHEDULING_BYTES);
    // layout version 3: the ladder's counters and the experiment's name
    pub const ON_TIME: usize = RECORDER + words(RECORDER_BYTES);
    pub const LATE_ONE: usize = ON_TIME + 1;
    pub const HELD: usize = ON_TIME + 2;
    pub const FALLBACK_STEPS: usize = ON_TIME + 3;
    pub const CORRUPT: usize = ON_TIME + 4;
    pub const MAX_TRANSITION_STEP_N: usize = ON_TIME + 5;
    pub const EXPERIMENT: usize = ON_TIME + 6;
    // layout version 4: saturated steps (issue 23), the board's failures and the passivity layer's figures (issue 20)
    pub const SATURATED: usize = EXPERIMENT + words(EXPERIMENT_BYTES);
    pub const BOARD_FAULTS: usize = SATURATED + 1;
    pub const BOARD_FIFO_OVERFLOWS: usize = BOARD_FAULTS + 1;
    pub const BOARD_QUADRATURE_ERRORS: usize = BOARD_FAULTS + 2;
    pub const BOARD_FAULT: usize = BOARD_FAULTS + 3;
    pub const PASSIVITY_ON: usize = BOARD_FAULT + words(BOARD_FAULT_BYTES);
    pub const PASSIVITY_ENERGY_J: usize = PASSIVITY_ON + 1;
    pub const PASSIVITY_RECEIVED_J: usize = PASSIVITY_ON + 2;
    pub const PASSIVITY_RETURNED_J: usize = PASSIVITY_ON + 3;
    pub const PASSIVITY_DAMPING: usize = PASSIVITY_ON + 4;
    pub const PASSIVITY_ACTIVE_STEPS: usize = PASSIVITY_ON + 5;
    // layout version 5: the features' filter gains
    pub const VELOCITY_GAIN: usize = PASSIVITY_ON + 6;
    pub const ACCELERATION_GAIN: usize = VELOCITY_GAIN + 1;
    pub const END: usize = VELOCITY_GAIN + 2;
}

const _: () = assert!(
    at::END == STATUS_WORDS,
    "LoopStatus must fill the status block"
);

fn store_q(out: &mut [u64], q: &Quantiles) {
    out[..5].copy_from_slice(&[q.p50_ns, q.p99_ns, q.p999_ns, q.max_ns, q.count]);
}

fn load_q(w: &[u64]) -> Quantiles {
    Quantiles {
        p50_ns: w[0],
        p99_ns: w[1],
        p999_ns: w[2],
        max_ns: w[3],
        count: w[4],
    }
}

impl LoopStatus {
    /// The block's words for this status (`generation` is the block's, not stored).
    pub fn to_words(&self) -> [u64; STATUS_WORDS] {
        let mut w = [0u64; STATUS_WORDS];
        w[at::UPDATED_UNIX_NS] = self.updated_unix_ns;
        w[at::CLOCK] = self.clock as u64;
        w[at::RATE_HZ] = self.rate_hz.to_bits();
        w[at::RUNNING] = u64::from(self.running);
        w[at::RUN_ID] = self.run_id;
        w[at::STEPS] = self.steps;
        w[at::FALLBACKS] = self.fallbacks;
        w[at::DEADLINE_MISSES] = self.deadline_misses;
        w[at::OVERRUNS] = self.overruns;
        store_q(&mut w[at::ROUND_TRIP..], &self.round_trip);
        store_q(&mut w[at::PERIOD_JITTER..], &self.period_jitter);
        self.board.store(&mut w[at::BOARD..]);
        self.scheduling.store(&mut w[at::SCHEDULING..]);
        self.recorder.store(&mut w[at::RECORDER..]);
        w[at::ON_TIME] = self.on_time;
        w[at::LATE_ONE] = self.late_one;
        w[at::HELD] = self.held;
        w[at::FALLBACK_STEPS] = self.fallback_steps;
        w[at::CORRUPT] = self.corrupt;
        w[at::MAX_TRANSITION_STEP_N] = self.max_transition_step_n.to_bits();
        self.experiment.store(&mut w[at::EXPERIMENT..]);
        w[at::SATURATED] = self.saturated;
        w[at::BOARD_FAULTS] = self.board_faults;
        w[at::BOARD_FIFO_OVERFLOWS] = self.board_fifo_overflows;
        w[at::BOARD_QUADRATURE_ERRORS] = self.board_quadrature_errors;
        self.board_fault.store(&mut w[at::BOARD_FAULT..]);
        w[at::PASSIVITY_ON] = u64::from(self.passivity_on);
        w[at::PASSIVITY_ENERGY_J] = self.passivity_energy_j.to_bits();
        w[at::PASSIVITY_RECEIVED_J] = self.passivity_received_j.to_bits();
        w[at::PASSIVITY_RETURNED_J] = self.passivity_returned_j.to_bits();
        w[at::PASSIVITY_DAMPING] = self.passivity_damping_ns_per_m.to_bits();
        w[at::PASSIVITY_ACTIVE_STEPS] = self.passivity_active_steps;
        w[at::VELOCITY_GAIN] = self.velocity_gain_rad_s.to_bits();
        w[at::ACCELERATION_GAIN] = self.acceleration_gain_rad_s.to_bits();
        w
    }

    /// The status the block's words of publication `generation` say.
    pub fn from_words(generation: u64, w: &[u64; STATUS_WORDS]) -> LoopStatus {
        LoopStatus {
            generation,
            updated_unix_ns: w[at::UPDATED_UNIX_NS],
            clock: LoopClock::from_word(w[at::CLOCK]),
            board: StatusText::load(&w[at::BOARD..]),
            rate_hz: f64::from_bits(w[at::RATE_HZ]),
            scheduling: StatusText::load(&w[at::SCHEDULING..]),
            recorder: StatusText::load(&w[at::RECORDER..]),
            running: w[at::RUNNING] != 0,
            run_id: w[at::RUN_ID],
            steps: w[at::STEPS],
            fallbacks: w[at::FALLBACKS],
            deadline_misses: w[at::DEADLINE_MISSES],
            overruns: w[at::OVERRUNS],
            round_trip: load_q(&w[at::ROUND_TRIP..]),
            period_jitter: load_q(&w[at::PERIOD_JITTER..]),
            experiment: StatusText::load(&w[at::EXPERIMENT..]),
            on_time: w[at::ON_TIME],
            late_one: w[at::LATE_ONE],
            held: w[at::HELD],
            fallback_steps: w[at::FALLBACK_STEPS],
            corrupt: w[at::CORRUPT],
            max_transition_step_n: f64::from_bits(w[at::MAX_TRANSITION_STEP_N]),
            saturated: w[at::SATURATED],
            board_faults: w[at::BOARD_FAULTS],
            board_fault: StatusText::load(&w[at::BOARD_FAULT..]),
            board_fifo_overflows: w[at::BOARD_FIFO_OVERFLOWS],
            board_quadrature_errors: w[at::BOARD_QUADRATURE_ERRORS],
            passivity_on: w[at::PASSIVITY_ON] != 0,
            passivity_energy_j: f64::from_bits(w[at::PASSIVITY_ENERGY_J]),
            passivity_received_j: f64::from_bits(w[at::PASSIVITY_RECEIVED_J]),
            passivity_returned_j: f64::from_bits(w[at::PASSIVITY_RETURNED_J]),
            passivity_damping_ns_per_m: f64::from_bits(w[at::PASSIVITY_DAMPING]),
            passivity_active_steps: w[at::PASSIVITY_ACTIVE_STEPS],
            velocity_gain_rad_s: f64::from_bits(w[at::VELOCITY_GAIN]),
            acceleration_gain_rad_s: f64::from_bits(w[at::ACCELERATION_GAIN]),
        }
    }
}

/// The loop status through a segment's [`Link`] (its header's status block).
pub trait LoopStatusLink {
    /// Publishes the loop's status (a seqlock; readers never see a torn snapshot). Loop side
    /// only (the single writer): `None` on a server's handle, else the generation written.
    /// Call it about every 100 ms, not per step; it allocates nothing, takes no lock and
    /// makes no syscall.
    fn publish_loop_status(&self, status: &LoopStatus) -> Option<u64>;
    /// The loop's last published status, `None` if it never published (or died mid-write).
    fn loop_status(&self) -> Option<LoopStatus>;
}

impl LoopStatusLink for Link {
    fn publish_loop_status(&self, status: &LoopStatus) -> Option<u64> {
        self.publish_status(&status.to_words())
    }

    fn loop_status(&self) -> Option<LoopStatus> {
        self.status()
            .map(|(generation, words)| LoopStatus::from_words(generation, &words))
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
        let block = shm_ring::StatusBlock::default();
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
            saturated: 17,
            board_faults: 18,
            board_fault: StatusText::new("S826_DacDataWrite returned S826_ERR_NOTREADY"),
            board_fifo_overflows: 19,
            board_quadrature_errors: 20,
            passivity_on: true,
            passivity_energy_j: 0.25,
            passivity_received_j: 1.5,
            passivity_returned_j: 1.25,
            passivity_damping_ns_per_m: 80.0,
            passivity_active_steps: 21,
            velocity_gain_rad_s: 30.0,
            acceleration_gain_rad_s: 100.0,
        };
        assert_eq!(block.publish(&s.to_words()), 1);
        let (generation, words) = block.read().expect("published");
        let back = LoopStatus::from_words(generation, &words);
        assert_eq!(back, LoopStatus { generation: 1, ..s });
        // a writer that died mid-publication: readers give up, the next publication heals it
        block.simulate_torn_write();
        assert!(block.read().is_none());
        assert_eq!(block.publish(&s.to_words()), 2);
        assert_eq!(block.read().unwrap().0, 2);
    }
}
