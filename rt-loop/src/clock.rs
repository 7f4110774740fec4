//! The realtime clock: a fixed period on absolute deadlines (`clock_nanosleep` with
//! `TIMER_ABSTIME` on CLOCK_MONOTONIC, so errors never accumulate), overrun counting and period
//! jitter in HDR histograms (allocated up front; recording into them allocates nothing).
//! The lockstep clock needs no code: the loop just runs the next step at once.

use crate::percentiles::PercentilesUs;
use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};
use shm_ring::os::rt_thread::{CpuChoice, RtRequest};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RealtimeConfig {
    /// SCHED_FIFO priority (1-99); 0 leaves the scheduler alone.
    pub priority: i32,
    /// Pin the loop thread to this CPU; -2: the last online CPU; -1: no pinning.
    pub cpu: i32,
    /// mlockall(MCL_CURRENT | MCL_FUTURE) so no page fault stalls the loop.
    pub lock_memory: bool,
    /// Keep the loop's CPU awake between periods with a `SCHED_IDLE` spinner
    /// (`shm_ring::os::keep_awake`): `auto` does where the bench steps an ONNX object, whose
    /// graph runs on the loop's thread and costs a few times more on a core that slept
    /// (docs/laws/onnx.md, "What it costs the realtime loop"); never under a CPU quota.
    pub keep_awake: KeepAwake,
}

/// When the loop's CPU is kept awake ([`RealtimeConfig::keep_awake`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum KeepAwake {
    /// With an ONNX object, pinned, and no CPU quota.
    #[default]
    Auto,
    /// Whenever the loop thread is pinned (a quota too).
    On,
    Off,
}

impl KeepAwake {
    /// Whether a run keeps its CPU awake: `onnx_object` says what the bench steps, `quota` is
    /// the process's CPU quota where there is one.
    pub fn wanted(self, onnx_object: bool, quota: Option<&str>) -> bool {
        match self {
            KeepAwake::Auto => onnx_object && quota.is_none(),
            KeepAwake::On => true,
            KeepAwake::Off => false,
        }
    }
}

impl Default for RealtimeConfig {
    fn default() -> Self {
        RealtimeConfig {
            priority: 80,
            cpu: -2,
            lock_memory: true,
            keep_awake: KeepAwake::Auto,
        }
    }
}

impl RealtimeConfig {
    /// The loop thread's real-time set-up as asked by this configuration (the one set-up of
    /// both processes, `shm_ring::os::rt_thread`: each refused step is reported, never fatal,
    /// and everything is undone when the run's guard drops).
    pub fn request(&self) -> RtRequest {
        RtRequest {
            fifo_priority: (self.priority > 0).then_some(self.priority),
            cpu: CpuChoice::from_i32(self.cpu),
            lock_memory: self.lock_memory,
        }
    }
}

// One implementation of the absolute-deadline sleep and the clock read, shared with
// infer-server's period-synchronised wait.
use shm_ring::{monotonic_ns as now_ns, sleep_until_ns};

/// Realtime clock statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct JitterStats {
    pub period_us: f64,
    /// |actual period - nominal period|.
    pub period_jitter: PercentilesUs,
    /// Wake-up time minus deadline.
    pub wake_latency: PercentilesUs,
    /// Steps whose work ended after the next deadline (that deadline was skipped).
    pub overruns: u64,
}

pub struct RealtimeClock {
    period_ns: u64,
    next: u64,
    last_wake: u64,
    overruns: u64,
    jitter: Histogram<u64>,
    latency: Histogram<u64>,
}

impl RealtimeClock {
    pub fn new(rate_hz: f64) -> Self {
        let period_ns = (1e9 / rate_hz).round().max(1.0) as u64;
        let h = || Histogram::<u64>::new_with_bounds(1, 10_000_000_000, 3).expect("valid bounds");
        RealtimeClock {
            period_ns,
            next: 0,
            last_wake: 0,
            overruns: 0,
            jitter: h(),
            latency: h(),
        }
    }

    /// Sets the first deadline one period from now.
    pub fn start(&mut self) {
        let now = now_ns();
        self.next = now + self.period_ns;
        self.last_wake = now;
    }

    /// Sleeps until the next deadline. If the deadline has already passed, the step overran:
    /// it is counted and the clock moves on to the next deadline still ahead (no burst of
    /// catch-up steps). No allocation, one or two syscalls.
    #[inline]
    pub fn wait(&mut self) {
        let now = now_ns();
        if now >= self.next {
            self.overruns += 1;
            let missed = (now - self.next) / self.period_ns + 1;
            self.next += missed * self.period_ns;
        }
        sleep_until_ns(self.next);
        let woke = now_ns();
        self.latency
            .saturating_record(woke.saturating_sub(self.next).max(1));
        let period = woke - self.last_wake;
        self.jitter
            .saturating_record(period.abs_diff(self.period_ns).max(1));
        self.last_wake = woke;
        self.next += self.period_ns;
    }

    /// Steps that overran so far.
    pub fn overruns(&self) -> u64 {
        self.overruns
    }

    /// The period jitter histogram (ns).
    pub fn jitter(&self) -> &Histogram<u64> {
        &self.jitter
    }

    pub fn stats(&self) -> JitterStats {
        JitterStats {
            period_us: self.period_ns as f64 / 1000.0,
            period_jitter: PercentilesUs::of(&self.jitter),
            wake_latency: PercentilesUs::of(&self.latency),
            overruns: self.overruns,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::KeepAwake;

    /// `auto` keeps the CPU awake for an ONNX object only, and never under a CPU quota (the
    /// spinner would spend it and the throttled cgroup would stop the loop with it).
    #[test]
    fn keep_awake_auto_is_for_onnx_objects_without_a_quota() {
        let q = Some("50000 100000 (/sys/fs/cgroup/cpu.max)");
        assert!(KeepAwake::Auto.wanted(true, None));
        assert!(!KeepAwake::Auto.wanted(false, None));
        assert!(!KeepAwake::Auto.wanted(true, q));
        assert!(KeepAwake::On.wanted(false, q));
        assert!(!KeepAwake::Off.wanted(true, None));
    }
}
