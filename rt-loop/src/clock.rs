//! The realtime clock: a fixed period on absolute deadlines (`clock_nanosleep` with
//! `TIMER_ABSTIME` on CLOCK_MONOTONIC, so errors never accumulate), overrun counting and period
//! jitter in HDR histograms (allocated up front; recording into them allocates nothing).
//! The lockstep clock needs no code: the loop just runs the next step at once.

use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RealtimeConfig {
    /// SCHED_FIFO priority (1-99); 0 leaves the scheduler alone.
    pub priority: i32,
    /// Pin the loop thread to this CPU; -2: the last online CPU; -1: no pinning.
    pub cpu: i32,
    /// mlockall(MCL_CURRENT | MCL_FUTURE) so no page fault stalls the loop.
    pub lock_memory: bool,
}

impl Default for RealtimeConfig {
    fn default() -> Self {
        RealtimeConfig {
            priority: 80,
            cpu: -2,
            lock_memory: true,
        }
    }
}

/// What [`make_thread_realtime`] changed, restored when dropped (the loop thread goes back to
/// its previous scheduling, affinity and memory locking after the run).
pub struct RealtimeGuard {
    policy: libc::c_int,
    param: libc::sched_param,
    affinity: Option<libc::cpu_set_t>,
    locked: bool,
    sched_changed: bool,
    /// What was obtained, for the loop-status block: the CPU pinned to, the SCHED_FIFO
    /// priority, and why SCHED_FIFO was refused (errno name).
    pinned_cpu: Option<i32>,
    fifo_priority: Option<i32>,
    fifo_refused: Option<String>,
    /// One line per step that was not permitted (the run carries on without it).
    pub warnings: Vec<String>,
}

fn last_cpu() -> i32 {
    // SAFETY: sysconf has no memory effects.
    let n = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
    (n.max(1) - 1) as i32
}

/// Tries to make the calling thread real-time: mlockall, pinning to a CPU (`cpu >= 0`, or the
/// last online CPU for `cpu == -2`), SCHED_FIFO. Each step that is not permitted becomes a
/// warning and the run carries on.
pub fn make_thread_realtime(cfg: &RealtimeConfig) -> RealtimeGuard {
    let mut g = RealtimeGuard {
        // SAFETY: plain queries of the calling thread.
        policy: unsafe { libc::sched_getscheduler(0) },
        param: libc::sched_param { sched_priority: 0 },
        affinity: None,
        locked: false,
        sched_changed: false,
        pinned_cpu: None,
        fifo_priority: None,
        fifo_refused: None,
        warnings: Vec::new(),
    };
    // SAFETY: valid pointer to a local sched_param.
    unsafe { libc::sched_getparam(0, &mut g.param) };
    if cfg.lock_memory {
        // SAFETY: plain syscall without pointers.
        let r = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
        if r == 0 {
            g.locked = true;
        } else {
            g.warnings.push(format!(
                "mlockall failed: {}",
                std::io::Error::last_os_error()
            ));
        }
    }
    let cpu = if cfg.cpu == -2 { last_cpu() } else { cfg.cpu };
    if cpu >= 0 {
        // SAFETY: cpu_set_t is plain data, zero-initialised, handled through the libc macros.
        unsafe {
            let mut old: libc::cpu_set_t = std::mem::zeroed();
            if libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut old) == 0 {
                g.affinity = Some(old);
            }
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_SET(cpu as usize, &mut set);
            if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0 {
                g.pinned_cpu = Some(cpu);
            } else {
                g.affinity = None;
                g.warnings.push(format!(
                    "pinning to CPU {cpu} failed: {}",
                    std::io::Error::last_os_error()
                ));
            }
        }
    }
    if cfg.priority > 0 {
        let param = libc::sched_param {
            sched_priority: cfg.priority.clamp(1, 99),
        };
        // SAFETY: valid pointer to a local sched_param.
        let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
        if r == 0 {
            g.sched_changed = true;
            g.fifo_priority = Some(param.sched_priority);
        } else {
            g.fifo_refused = Some(errno_name(std::io::Error::last_os_error()));
            g.warnings.push(format!(
                "SCHED_FIFO priority {} not permitted: {}",
                cfg.priority,
                std::io::Error::last_os_error()
            ));
        }
    }
    g
}

/// `EPERM`, `EINVAL`, ... for the status line (the number for anything else).
fn errno_name(e: std::io::Error) -> String {
    match e.raw_os_error() {
        Some(libc::EPERM) => "EPERM".into(),
        Some(libc::EINVAL) => "EINVAL".into(),
        Some(libc::EACCES) => "EACCES".into(),
        Some(libc::ESRCH) => "ESRCH".into(),
        Some(n) => format!("errno {n}"),
        None => e.to_string(),
    }
}

impl RealtimeGuard {
    /// What the thread actually obtained, for the status: "SCHED_FIFO 80 cpu 1 mlocked",
    /// "SCHED_OTHER (FIFO refused: EPERM) cpu 1", ...
    pub fn describe(&self) -> String {
        let mut s = match (self.fifo_priority, &self.fifo_refused) {
            (Some(p), _) => format!("SCHED_FIFO {p}"),
            (None, Some(why)) => format!("SCHED_OTHER (FIFO refused: {why})"),
            (None, None) => "SCHED_OTHER".into(),
        };
        if let Some(cpu) = self.pinned_cpu {
            s.push_str(&format!(" cpu {cpu}"));
        }
        if self.locked {
            s.push_str(" mlocked");
        }
        s
    }
}

impl Drop for RealtimeGuard {
    fn drop(&mut self) {
        // SAFETY: restoring values read from this same thread; pointers are to owned locals.
        unsafe {
            if self.sched_changed {
                libc::sched_setscheduler(0, self.policy, &self.param);
            }
            if let Some(set) = self.affinity.as_ref() {
                libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), set);
            }
            if self.locked {
                libc::munlockall();
            }
        }
    }
}

// One implementation of the absolute-deadline sleep and the clock read, shared with
// infer-server's period-synchronised wait.
use shm_ring::{monotonic_ns as now_ns, sleep_until_ns};

/// Percentiles of a histogram in microseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Percentiles {
    pub p50_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub max_us: f64,
    pub samples: u64,
}

impl Percentiles {
    fn of(h: &Histogram<u64>) -> Percentiles {
        let us = |v: u64| v as f64 / 1000.0;
        Percentiles {
            p50_us: us(h.value_at_quantile(0.5)),
            p99_us: us(h.value_at_quantile(0.99)),
            p999_us: us(h.value_at_quantile(0.999)),
            max_us: us(h.max()),
            samples: h.len(),
        }
    }
}

/// Realtime clock statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct JitterStats {
    pub period_us: f64,
    /// |actual period - nominal period|.
    pub period_jitter: Percentiles,
    /// Wake-up time minus deadline.
    pub wake_latency: Percentiles,
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
            period_jitter: Percentiles::of(&self.jitter),
            wake_latency: Percentiles::of(&self.latency),
            overruns: self.overruns,
        }
    }
}
