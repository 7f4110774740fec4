//! Wait strategies and the futex event count that parking uses.
//!
//! A side that waits (for data, or for space) first re-checks its ring; if it decides to park,
//! it sets `Signal::parked` and sleeps on the futex word `Signal::epoch`. The other side, after
//! publishing, checks `parked` and only then pays for `FUTEX_WAKE`, so when nobody parks the
//! data path stays free of syscalls. The notifier clears `parked` as it wakes (a swap), so a
//! burst of pushes while the waiter is still waking up costs one syscall, not one per push.
//! Each signal has at most one waiter (one consumer waits for data, one producer for space).
//! The futex is the shared (non-private) kind, so it works across processes on the segment.
//!
//! No lost wake-up (the classic store-buffer pattern, both sides fenced `SeqCst`):
//! waiter: `parked = 1; fence; re-check ring`; notifier: `publish; fence; load parked`.
//! At least one of them sees the other's write, so either the waiter finds the data, or the
//! notifier sees the waiter, bumps `epoch` and wakes it; a bump between the waiter's read of
//! `epoch` and its `FUTEX_WAIT` makes the wait return at once (the kernel compares the value).

use crate::ring::mem::Signal;
use crate::ring::sync::{fence, Ordering};

/// How a side waits when its ring is empty (receiver) or full (sender).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WaitStrategy {
    /// Busy-poll. Lowest latency; burns a core. Use only where a core is dedicated to it
    /// (never on both sides of a 2-core machine, except in the benchmark).
    Spin,
    /// Busy-poll `spins` times, then park on the futex.
    SpinThenPark { spins: u32 },
    /// Park on the futex right away (after one re-check). Costs a wake-up syscall per wait.
    Park,
    /// For a consumer whose producer sends on a fixed period (infer-server's inference
    /// thread): the caller learns the period and phase, sleeps on an absolute clock
    /// ([`sleep_until_ns`]) until shortly before the next message is due and then spins
    /// ([`WaitStrategy::Spin`] with a deadline). The ring's own waits under this strategy, used
    /// while nothing is learnt yet, are [`WaitStrategy::DEFAULT_SPIN_THEN_PARK`]'s.
    PeriodSync,
}

impl WaitStrategy {
    /// Spin-then-park with a spin budget of roughly a few microseconds.
    pub const DEFAULT_SPIN_THEN_PARK: WaitStrategy = WaitStrategy::SpinThenPark { spins: 2000 };

    #[cfg(not(loom))]
    fn spins(self) -> u32 {
        match self {
            WaitStrategy::Spin => u32::MAX,
            WaitStrategy::SpinThenPark { spins } => spins,
            WaitStrategy::PeriodSync => WaitStrategy::DEFAULT_SPIN_THEN_PARK.spins(),
            WaitStrategy::Park => 0,
        }
    }
}

impl Default for WaitStrategy {
    fn default() -> Self {
        WaitStrategy::DEFAULT_SPIN_THEN_PARK
    }
}

/// CLOCK_MONOTONIC now, nanoseconds (a vDSO read, no syscall). The same clock as
/// `std::time::Instant` on Linux, so a peer's `Instant`-based timestamps compare with it.
#[cfg(not(loom))]
#[inline]
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: valid pointer; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Sleeps until CLOCK_MONOTONIC reads `deadline_ns` (`clock_nanosleep` with `TIMER_ABSTIME`:
/// an absolute deadline, so a late wake-up does not push the next one later). Returns at once
/// for a deadline already past. One syscall, no allocation.
#[cfg(not(loom))]
pub fn sleep_until_ns(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: valid pointers; absolute sleep on CLOCK_MONOTONIC.
        let r = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if r != libc::EINTR {
            break;
        }
    }
}

/// Wakes whoever parks on `signal`, if anyone does. Called right after publishing.
/// Cost when nobody waits: one `SeqCst` fence and one load; no syscall.
#[inline]
pub(crate) fn notify(signal: &Signal) {
    notify_if(signal, true)
}

/// As [`notify`], but only wakes if `worth_it` (the waiter's condition can hold now). The
/// caller must guarantee that `worth_it == false` implies the waiter's condition is false,
/// and that a later publish will call again; then skipping the wake loses nothing.
#[inline]
pub(crate) fn notify_if(signal: &Signal, worth_it: bool) {
    fence(Ordering::SeqCst);
    if worth_it
        && signal.parked.load(Ordering::Relaxed) != 0
        && signal.parked.swap(0, Ordering::Relaxed) != 0
    {
        signal.epoch.fetch_add(1, Ordering::Release);
        #[cfg(not(loom))]
        futex::wake_all(&signal.epoch);
    }
}

/// The waiter's half of the handshake: read the epoch, announce ourselves, fence. After
/// this the caller re-checks its ring and, if still nothing, sleeps on `epoch` having the
/// returned value (so any bump since makes the sleep return at once).
#[inline]
pub(crate) fn register_waiter(signal: &Signal) -> u32 {
    let epoch = signal.epoch.load(Ordering::Acquire);
    signal.parked.store(1, Ordering::SeqCst);
    fence(Ordering::SeqCst);
    epoch
}

/// The waiter is done waiting (found what it wanted or gave up).
#[cfg(not(loom))]
#[inline]
fn unregister_waiter(signal: &Signal) {
    signal.parked.store(0, Ordering::Relaxed);
}

/// Why a wait ended without a result.
#[cfg(not(loom))]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum WaitEnd {
    Timeout,
    PeerGone,
}

/// Longest single park: a parked side wakes at least this often to re-check its deadline and
/// whether the peer process is still alive.
#[cfg(not(loom))]
pub(crate) const PARK_SLICE: std::time::Duration = std::time::Duration::from_millis(10);

/// Spins between liveness checks in an unbounded spin (a check is one `fcntl` syscall).
#[cfg(not(loom))]
const SPINS_PER_CHECK: u32 = 1 << 14;

/// Runs `attempt` until it yields a value, the deadline passes, or `peer_alive` says no.
#[cfg(not(loom))]
pub(crate) fn wait_for<T>(
    signal: &Signal,
    strategy: WaitStrategy,
    deadline: Option<std::time::Instant>,
    peer_alive: Option<&(dyn Fn() -> bool + Send + Sync)>,
    mut attempt: impl FnMut() -> Option<T>,
) -> Result<T, WaitEnd> {
    use std::time::Instant;
    let gone = || peer_alive.is_some_and(|alive| !alive());
    let past = |deadline: Option<Instant>| deadline.is_some_and(|d| Instant::now() >= d);

    // Spin phase.
    let spins = strategy.spins();
    let mut spun: u32 = 0;
    while spun < spins {
        if let Some(value) = attempt() {
            return Ok(value);
        }
        crate::ring::sync::spin_hint();
        spun += 1;
        if deadline.is_some() {
            // Bounded wait (the loop's `recv_deadline`): the deadline ends it, so no liveness
            // syscall is made while spinning; `Instant::now` is a vDSO read, not a syscall.
            if spun & 63 == 0 && past(deadline) {
                return Err(WaitEnd::Timeout);
            }
        } else if spun & (SPINS_PER_CHECK - 1) == 0 && gone() {
            // Unbounded spin: only a dead peer can end it.
            return Err(WaitEnd::PeerGone);
        }
    }

    // Park phase.
    loop {
        let epoch = register_waiter(signal);
        if let Some(value) = attempt() {
            unregister_waiter(signal);
            return Ok(value);
        }
        let mut slice = PARK_SLICE;
        if let Some(d) = deadline {
            let now = Instant::now();
            if now >= d {
                unregister_waiter(signal);
                return Err(WaitEnd::Timeout);
            }
            slice = slice.min(d - now);
        }
        let woken = futex::wait(&signal.epoch, epoch, slice);
        unregister_waiter(signal);
        if let Some(value) = attempt() {
            return Ok(value);
        }
        if past(deadline) {
            return Err(WaitEnd::Timeout);
        }
        // Only a timed-out park (no wake-up for a whole slice) pays for a liveness check.
        if !woken && gone() {
            return Err(WaitEnd::PeerGone);
        }
    }
}

#[cfg(not(loom))]
mod futex {
    use std::sync::atomic::AtomicU32;
    use std::time::Duration;

    /// Sleeps while `*word == expected`, at most `timeout`. Returns false on timeout.
    /// Shared (not `FUTEX_PRIVATE_FLAG`): the word may live in memory mapped by two processes.
    pub(super) fn wait(word: &AtomicU32, expected: u32, timeout: Duration) -> bool {
        let ts = libc::timespec {
            tv_sec: timeout.as_secs() as libc::time_t,
            tv_nsec: timeout.subsec_nanos() as libc::c_long,
        };
        // SAFETY: `word` is a valid, aligned u32 for the duration of the call; the kernel
        // only reads it. A spurious or early return is harmless: callers re-check.
        let rc = unsafe {
            libc::syscall(
                libc::SYS_futex,
                word.as_ptr(),
                libc::FUTEX_WAIT,
                expected,
                &ts as *const libc::timespec,
                std::ptr::null::<u32>(),
                0u32,
            )
        };
        !(rc == -1 && std::io::Error::last_os_error().raw_os_error() == Some(libc::ETIMEDOUT))
    }

    /// Wakes every waiter parked on `word`.
    pub(super) fn wake_all(word: &AtomicU32) {
        // SAFETY: as above; FUTEX_WAKE does not access user memory beyond the address key.
        unsafe {
            libc::syscall(
                libc::SYS_futex,
                word.as_ptr(),
                libc::FUTEX_WAKE,
                i32::MAX,
                std::ptr::null::<libc::timespec>(),
                std::ptr::null::<u32>(),
                0u32,
            );
        }
    }
}
