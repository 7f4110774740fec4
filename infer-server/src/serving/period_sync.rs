//! The period-synchronised wait: the inference thread learns when the next feature message is
//! due and sleeps until just before it, instead of parking on the futex after a short spin.
//!
//! Why: rt-loop sends one feature vector per period (100 us at 10 kHz) and waits at most its
//! deadline (50 us) for the answer. A server that parks between steps makes the loop pay a
//! futex wake-up and the machine's wake-up latency on every step (tens of microseconds on a
//! small machine, the largest part of the round trip and the cause of most misses); one that
//! spins through the whole period takes a core for itself. This one wakes on an absolute
//! clock (`clock_nanosleep(TIMER_ABSTIME)`, SCHED_FIFO where permitted, so the kernel wakes it
//! on time) a margin before the step is due and spins only through the margin and the loop's own
//! send jitter: the loop's futex wake disappears in the common case, and the core is free for
//! most of the period.
//!
//! How it learns (all from the messages themselves, nothing configured):
//! - the period: the median spacing of the loop's send timestamps (`FeatureMsg::timestamp_ns`,
//!   CLOCK_MONOTONIC since the loop's origin) over [`LEARN_STEPS`] consecutive steps, refined
//!   over the whole learning span; a loop that is not periodic (lockstep) is never locked onto;
//! - the clock offset: `timestamp_ns` counts from the loop's origin, so the smallest
//!   `arrival - timestamp_ns` ever seen is the origin on this process's clock (plus the ring's
//!   transfer time, well under a microsecond);
//! - the phase: the loop sends at its grid time plus its own wake-up latency, so the grid is the
//!   floor of the send times: a send earlier than the grid moves the grid there at once, later
//!   sends pull it up slowly ([`CREEP`]), and the period is re-measured over the ever longer
//!   span since the lock (the send jitter of its two ends divided by thousands of periods);
//! - the margin: a running 99th percentile of how late this thread's own wake-ups are.
//!
//! It gives up (parks, as the default spin-then-park wait) when nothing arrives for
//! [`MISS_LIMIT`] periods in a row (the loop idles or stopped), when the timestamps jump (a new
//! loop) or a gap of many periods appears, and learns again from the next messages.
//!
//! [`PeriodSync`] is plain arithmetic on numbers the caller passes in (no clock, no syscall,
//! no allocation), so it is tested with synthetic timelines; the inference thread
//! (`inference_thread.rs`, `recv_synced`) does the sleeping.

/// Consecutive steps whose spacing is learnt before locking on.
pub const LEARN_STEPS: usize = 128;
/// Periods without a message, while locked, after which the loop is taken to idle.
pub const MISS_LIMIT: u32 = 20;
/// A message this many periods after the previous one is a gap: learn again.
pub const GAP_PERIODS: f64 = 50.0;
/// How fast the grid follows sends that come later than it (per step, fraction of the excess).
pub const CREEP: f64 = 1.0 / 64.0;
/// Shortest and longest period locked onto (20 us .. 100 ms).
pub const MIN_PERIOD_NS: f64 = 20_000.0;
pub const MAX_PERIOD_NS: f64 = 100_000_000.0;
/// The margin before the due time: never less than this (covers the clock read and the
/// transfer), never more than this fraction of the period.
pub const MIN_MARGIN_NS: f64 = 3_000.0;
pub const MAX_MARGIN_FRACTION: f64 = 0.5;
/// Quantile the wake-up lateness tracker follows, and its step (ns).
const LATE_QUANTILE: f64 = 0.99;
const LATE_STEP_NS: f64 = 400.0;

/// What the caller should do before the next receive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Plan {
    /// Not locked: use the ring's own wait (spin briefly, then park).
    Park,
    /// Sleep until `wake_ns` (absolute, CLOCK_MONOTONIC), then spin until the message arrives
    /// or `give_up_ns` passes (then call [`PeriodSync::missed`]).
    Sleep { wake_ns: u64, give_up_ns: u64 },
}

/// The period/phase learner. See the module documentation.
#[derive(Debug, Clone)]
pub struct PeriodSync {
    // learning
    diffs: [u64; LEARN_STEPS],
    learnt: usize,
    first_ts: u64,
    last_ts: u64,
    last_seq: u64,
    have_last: bool,
    /// min(arrival - timestamp), i.e. the loop's origin on this clock; i64::MAX: unknown.
    offset: i64,
    // locked
    locked: bool,
    period: f64,
    /// Grid time (this clock, ns) of the last step received or skipped.
    grid: f64,
    /// Send time of the step the lock started from, and the periods counted since: the period
    /// is re-measured over this ever longer baseline.
    base_sent: f64,
    base_periods: f64,
    next_refine: f64,
    misses: u32,
    late_q: f64,
    // counters (read by the stats)
    pub locks: u64,
    pub relearns: u64,
    pub missed_wakes: u64,
    /// Why it let go: the loop went quiet (MISS_LIMIT), sent twice within a period, left a gap
    /// of more than GAP_PERIODS, or restarted (timestamps or sequence went back).
    pub let_go: LetGo,
}

/// Counts of the reasons [`PeriodSync`] let go of a lock (for the statistics line).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LetGo {
    pub quiet: u64,
    pub faster: u64,
    pub gap: u64,
    pub restart: u64,
}

impl Default for PeriodSync {
    fn default() -> Self {
        Self::new()
    }
}

impl PeriodSync {
    pub fn new() -> Self {
        PeriodSync {
            diffs: [0; LEARN_STEPS],
            learnt: 0,
            first_ts: 0,
            last_ts: 0,
            last_seq: 0,
            have_last: false,
            offset: i64::MAX,
            locked: false,
            period: 0.0,
            grid: 0.0,
            base_sent: 0.0,
            base_periods: 0.0,
            next_refine: 0.0,
            misses: 0,
            late_q: 10_000.0,
            locks: 0,
            relearns: 0,
            missed_wakes: 0,
            let_go: LetGo::default(),
        }
    }

    pub fn is_locked(&self) -> bool {
        self.locked
    }

    /// The learnt period, ns (0 while learning).
    pub fn period_ns(&self) -> u64 {
        if self.locked {
            self.period as u64
        } else {
            0
        }
    }

    /// How long before the due time the thread wakes, ns.
    pub fn margin_ns(&self) -> u64 {
        let cap = if self.period > 0.0 {
            self.period * MAX_MARGIN_FRACTION
        } else {
            f64::MAX
        };
        (self.late_q + MIN_MARGIN_NS).clamp(MIN_MARGIN_NS, cap) as u64
    }

    /// Forgets everything but the counters and the lateness estimate (a new loop, or a gap).
    pub fn relearn(&mut self) {
        if self.locked || self.learnt > 0 {
            self.relearns += 1;
        }
        self.learnt = 0;
        self.have_last = false;
        self.locked = false;
        self.offset = i64::MAX;
        self.misses = 0;
    }

    /// What to do now (`now_ns`: CLOCK_MONOTONIC) before waiting for the next message.
    pub fn plan(&self, now_ns: u64) -> Plan {
        if !self.locked {
            return Plan::Park;
        }
        // The next grid slot whose give-up time is still ahead: after a slot that came to
        // nothing (the loop overran, or sends late) the grid stays where the sends put it, and
        // the plan moves on to the next slot. Spin at most half a period past the due time.
        let now = now_ns as f64;
        let behind = ((now - self.grid - 0.5 * self.period) / self.period).floor() + 1.0;
        let due = self.grid + self.period * behind.max(1.0);
        let wake = (due - self.margin_ns() as f64).max(now);
        let give_up = due.max(now) + self.period * 0.5;
        Plan::Sleep {
            wake_ns: wake as u64,
            give_up_ns: give_up as u64,
        }
    }

    /// A planned sleep ended `woke_ns` (asked: `wake_ns`): feeds the lateness estimate.
    pub fn woke(&mut self, wake_ns: u64, woke_ns: u64) {
        let late = woke_ns.saturating_sub(wake_ns) as f64;
        // Stochastic quantile tracking: up by q*step when above, down by (1-q)*step below.
        if late > self.late_q {
            self.late_q += LATE_QUANTILE * LATE_STEP_NS;
        } else {
            self.late_q -= (1.0 - LATE_QUANTILE) * LATE_STEP_NS;
        }
        self.late_q = self.late_q.clamp(0.0, 10_000_000.0);
    }

    /// The spin after a planned sleep ran to `give_up_ns` without a message: the loop skipped
    /// the step, sends late, or stopped. The grid stays (the next message places itself on it);
    /// after [`MISS_LIMIT`] in a row, unlock.
    pub fn missed(&mut self) {
        self.missed_wakes += 1;
        if !self.locked {
            return;
        }
        self.misses += 1;
        if self.misses >= MISS_LIMIT {
            self.let_go.quiet += 1;
            self.relearn();
        }
    }

    /// A message with loop time `timestamp_ns` and sequence `seq` was received at
    /// `arrival_ns` (this clock).
    pub fn observe(&mut self, timestamp_ns: u64, seq: u64, arrival_ns: u64) {
        if self.have_last && (timestamp_ns <= self.last_ts || seq <= self.last_seq) {
            // A new loop (its clock origin and sequence restart): learn it afresh.
            self.let_go.restart += u64::from(self.locked);
            self.relearn();
        }
        let lag = arrival_ns as i64 - timestamp_ns as i64;
        self.offset = self.offset.min(lag);
        let sent = (timestamp_ns as i64 + self.offset) as f64;
        if self.locked {
            self.track(sent);
        }
        if !self.locked {
            // (also right after `track` let go: this message starts the next learning run)
            self.learn(timestamp_ns, seq);
        }
        self.last_ts = timestamp_ns;
        self.last_seq = seq;
        self.have_last = true;
    }

    fn learn(&mut self, ts: u64, seq: u64) {
        if !self.have_last || seq != self.last_seq + 1 {
            // Start (or restart) the run of consecutive steps.
            self.learnt = 0;
            self.first_ts = ts;
            return;
        }
        self.diffs[self.learnt] = ts - self.last_ts;
        self.learnt += 1;
        if self.learnt < LEARN_STEPS {
            return;
        }
        self.learnt = 0;
        // In place, between steps: LEARN_STEPS words, no allocation.
        self.diffs.sort_unstable();
        let median = self.diffs[LEARN_STEPS / 2] as f64;
        let steady = self
            .diffs
            .iter()
            .filter(|&&d| (d as f64 - median).abs() <= 0.25 * median)
            .count();
        let first = ts;
        let span = (ts - self.first_ts) as f64;
        self.first_ts = first;
        if !(MIN_PERIOD_NS..=MAX_PERIOD_NS).contains(&median) || steady * 10 < LEARN_STEPS * 9 {
            return; // not a periodic loop (lockstep, or too irregular): keep parking
        }
        // The mean of the steady spacings is a better first guess than the median (a loop's
        // send jitter need not be symmetric); the whole span over the periods it holds, which
        // that guess counts without error for any loop within a per cent of it, is the period.
        let (sum, n) = self
            .diffs
            .iter()
            .filter(|&&d| (d as f64 - median).abs() <= 0.25 * median)
            .fold((0.0, 0.0), |(s, n), &d| (s + d as f64, n + 1.0));
        let mean = sum / n;
        // A step is one period unless it came three quarters of one later (a skipped step), as
        // in `track`.
        let periods: f64 = self
            .diffs
            .iter()
            .map(|&d| (d as f64 / mean + 0.25).floor().max(1.0))
            .sum();
        self.period = span / periods;
        self.grid = (ts as i64 + self.offset) as f64;
        self.base_sent = self.grid;
        self.base_periods = 0.0;
        self.next_refine = 256.0;
        self.locked = true;
        self.locks += 1;
        self.misses = 0;
    }

    fn track(&mut self, sent: f64) {
        // A send comes after its grid time, by the loop's wake-up latency and work (up to
        // three quarters of a period is still read as late, not as the next step).
        let mut k = ((sent - self.grid) / self.period + 0.25).floor();
        // ...but a send that would pull the grid back by more than a tenth of a period is a
        // late send of the slot before (a loop that woke more than 3/4 period late), not an
        // early one of this slot.
        if k >= 2.0 && sent - (self.grid + k * self.period) < -0.1 * self.period {
            k -= 1.0;
        }
        // k == 0: a second message within the same period, so the loop does not run at the
        // learnt period (it sent sparsely while learning, e.g. while it held the server for
        // gone, and now sends every step): learn again rather than sleep through its steps.
        if !(1.0..=GAP_PERIODS).contains(&k) {
            if k < 1.0 {
                self.let_go.faster += 1;
            } else {
                self.let_go.gap += 1;
            }
            self.relearn();
            return;
        }
        self.misses = 0;
        let on_grid = self.grid + k * self.period;
        let excess = sent - on_grid;
        let correction = if excess < 0.0 { excess } else { excess * CREEP };
        self.grid = on_grid + correction;
        self.base_periods += k;
        // Re-measure the period over the baseline since the lock, at doubling intervals (then
        // every 65536 periods), from a send near the grid (a late one would bias it): the
        // jitter of the two ends is divided by ever more periods.
        if self.base_periods >= self.next_refine && excess.abs() < 0.1 * self.period {
            self.period = (self.grid - self.base_sent) / self.base_periods;
            self.next_refine = (self.next_refine * 2.0).min(self.base_periods + 65_536.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic loop: grid at `origin + n*period`, sent `jitter(n)` after its grid time,
    /// seen by the server `transfer` later. Loop time counts from `loop_origin`.
    fn feed(
        sync: &mut PeriodSync,
        steps: std::ops::Range<u64>,
        period: u64,
        jitter: impl Fn(u64) -> u64,
    ) {
        let loop_origin = 5_000_000_000u64;
        for n in steps {
            let sent = loop_origin + 1_000_000 + n * period + jitter(n);
            sync.observe(sent - loop_origin, n, sent + 300);
        }
    }

    /// A sync that has watched 500 steps of a steady 10 kHz loop, each sent 1 us late.
    fn after_steady_10khz() -> PeriodSync {
        let mut s = PeriodSync::new();
        feed(&mut s, 0..500, 100_000, |_| 1_000);
        s
    }

    fn jitter(n: u64) -> u64 {
        // 2..22 us (a hash of n), a few late ones of 60 us.
        let h = n.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40;
        2_000 + (h % 20_000) + if n.is_multiple_of(97) { 60_000 } else { 0 }
    }

    #[test]
    fn learns_period_and_phase_of_a_jittery_loop() {
        let mut s = PeriodSync::new();
        feed(&mut s, 0..(LEARN_STEPS as u64 + 1), 100_000, jitter);
        assert!(s.is_locked());
        let p = s.period_ns() as f64;
        assert!((p - 100_000.0).abs() < 500.0, "period {p}");
        feed(&mut s, (LEARN_STEPS as u64 + 1)..3000, 100_000, jitter);
        // The grid sits near the earliest sends (2 us after the grid time + 0.3 us transfer).
        let expected_grid = 5_000_000_000.0 + 1_000_000.0 + 2999.0 * 100_000.0 + 2_300.0;
        let off = s.grid - expected_grid;
        assert!((-1_000.0..5_000.0).contains(&off), "grid off by {off}");
        match s.plan(0) {
            Plan::Sleep {
                wake_ns,
                give_up_ns,
            } => {
                let due = s.grid + 100_000.0;
                assert!(wake_ns as f64 <= due && wake_ns as f64 >= due - 50_000.0);
                assert!(give_up_ns as f64 > due);
            }
            Plan::Park => panic!("locked but told to park"),
        }
    }

    #[test]
    fn follows_a_loop_whose_period_drifts_from_the_learnt_one() {
        let mut s = after_steady_10khz();
        assert!(s.is_locked());
        // From step 500 on the loop's period is 100.02 us (its clock runs slow, say).
        feed(&mut s, 500..30_000, 100_000, |n| 1_000 + (n - 500) * 20);
        let p = s.period;
        assert!((p - 100_020.0).abs() < 3.0, "period {p}");
        assert!(s.is_locked());
    }

    #[test]
    fn a_lockstep_loop_is_never_locked_onto() {
        let mut s = PeriodSync::new();
        // Steps as fast as the answers come: 8..60 us apart, irregular.
        let mut ts = 1_000u64;
        for n in 0..2000u64 {
            ts += 8_000 + (n * 104_729 % 52_000);
            s.observe(ts, n, ts + 10_000_000);
        }
        assert!(!s.is_locked());
        assert_eq!(s.plan(0), Plan::Park);
    }

    #[test]
    fn unlocks_when_the_loop_idles_and_relearns_a_new_loop() {
        let mut s = after_steady_10khz();
        assert!(s.is_locked());
        for _ in 0..MISS_LIMIT {
            s.missed();
        }
        assert!(!s.is_locked());
        assert_eq!(s.plan(0), Plan::Park);
        // A new loop: its timestamps and sequence numbers start again, at 200 us.
        let origin = 9_000_000_000u64;
        for n in 0..(LEARN_STEPS as u64 + 1) {
            let sent = origin + n * 200_000 + 1_500;
            s.observe(sent - origin + 10, n + 1, sent + 200);
        }
        assert!(s.is_locked());
        assert!((s.period_ns() as f64 - 200_000.0).abs() < 500.0);
        assert!(s.relearns >= 1);
    }

    #[test]
    fn a_send_later_than_the_give_up_keeps_the_lock_and_the_grid() {
        let mut s = after_steady_10khz();
        let grid = s.grid;
        // Step 500 comes 70 us late: the planned spin gives up at due + 50 us first.
        let Plan::Sleep { give_up_ns, .. } = s.plan(grid as u64) else {
            panic!("locked")
        };
        s.missed();
        let Plan::Sleep { wake_ns, .. } = s.plan(give_up_ns) else {
            panic!("still locked")
        };
        assert!(
            wake_ns as f64 > grid + 150_000.0,
            "the plan moved on to the next slot"
        );
        feed(&mut s, 500..501, 100_000, |_| 70_000);
        assert!(s.is_locked());
        assert!(
            (s.grid - (grid + 100_000.0)).abs() < 2_000.0,
            "grid {}",
            s.grid - grid
        );
        feed(&mut s, 501..2000, 100_000, |_| 1_000);
        assert!(s.is_locked());
        assert_eq!(s.relearns, 0);
    }

    #[test]
    fn a_loop_that_sends_faster_than_the_learnt_period_is_learnt_again() {
        let mut s = PeriodSync::new();
        // Every 100th step of a 10 kHz loop (10 ms apart), then every step.
        for n in 0..300u64 {
            let t = 1_000_000 + n * 10_000_000;
            s.observe(t, n + 1, t + 500);
        }
        assert!(s.is_locked());
        assert!((s.period_ns() as f64 - 10_000_000.0).abs() < 10_000.0);
        let t0 = 1_000_000 + 300 * 10_000_000u64;
        for n in 0..200u64 {
            let t = t0 + n * 100_000;
            s.observe(t, 301 + n, t + 500);
        }
        assert!(s.is_locked());
        assert!(
            (s.period_ns() as f64 - 100_000.0).abs() < 500.0,
            "period {}",
            s.period_ns()
        );
    }

    #[test]
    fn a_send_late_by_most_of_a_period_is_not_taken_for_the_next_slot() {
        let mut s = after_steady_10khz();
        // Step 500 is sent 85 us late, step 501 on time: neither is a reason to let go.
        feed(&mut s, 500..501, 100_000, |_| 85_000);
        feed(&mut s, 501..1000, 100_000, |_| 1_000);
        assert!(s.is_locked());
        assert_eq!(s.relearns, 0);
    }

    #[test]
    fn a_gap_of_many_periods_relearns() {
        let mut s = after_steady_10khz();
        assert!(s.is_locked());
        // The same loop, 100 ms later (a pause between runs).
        feed(&mut s, 1500..1501, 100_000, |_| 1_000);
        assert!(!s.is_locked());
    }

    #[test]
    fn the_margin_follows_late_wake_ups_within_bounds() {
        let mut s = after_steady_10khz();
        for _ in 0..20_000 {
            s.woke(0, 30_000);
        }
        let m = s.margin_ns();
        assert!(m > 25_000 && m <= 50_000, "margin {m}");
        for _ in 0..200_000 {
            s.woke(0, 1_000);
        }
        assert!(s.margin_ns() < 10_000, "margin {}", s.margin_ns());
    }
}
