//! Wake-up latency: this crate's futex wait against a `raw_sync` event, the design card's
//! candidate for signalling across processes (issue 15, docs/architecture.md).
//!
//! Two threads play ping-pong through memory mapped `MAP_SHARED` (the same kind of memory two
//! processes share; both primitives are the process-shared kind):
//!
//! - `shm-ring futex`: two rings of this crate (`heap_channel`), both sides
//!   [`WaitStrategy::Park`], so every wait re-checks once and sleeps on the shared futex;
//! - `raw_sync event`: two auto-reset `raw_sync::events::Event`s (a process-shared pthread mutex
//!   and condition variable) in the mapping; the pinger sets one, the ponger waits on it.
//!
//! The pinger writes the time into the message (futex) or a shared word (event) just before it
//! signals; the ponger reads the clock as soon as its wait returns: that difference is the
//! one-way wake-up latency. The pinger's own round trip (two wake-ups) is reported beside it.
//! Back to back (the next ping at once) and paced at 10 kHz (the loop's rate: the ponger has
//! been asleep ~100 us before every wake-up). Threads are neither pinned nor real-time.
//!
//! `cargo bench -p shm-ring --bench wake` runs every variant `WAKE_BENCH_SECS` seconds (default
//! 3) `WAKE_BENCH_RUNS` times (default 3) and prints the median of the runs' percentiles.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use hdrhistogram::Histogram;
use raw_sync::events::{Event, EventInit, EventState};
use raw_sync::Timeout;
use shm_ring::{heap_channel, layout_id, monotonic_ns, sleep_until_ns, DecodeError, Message};
use shm_ring::{Consumer, Producer, WaitStrategy};

/// A ping: its sequence number and the time it was sent.
#[derive(Clone, Copy, Debug, Default)]
struct Ping {
    seq: u64,
    sent_ns: u64,
}

impl Message for Ping {
    const WORDS: usize = 2;
    const LAYOUT_ID: u64 = layout_id("Ping{seq:u64,sent_ns:u64}");
    fn encode(&self, out: &mut [u64]) {
        out[0] = self.seq;
        out[1] = self.sent_ns;
    }
    fn decode(words: &[u64]) -> Result<Self, DecodeError> {
        Ok(Ping {
            seq: words[0],
            sent_ns: words[1],
        })
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Pace {
    BackToBack,
    Hz10k,
}

impl Pace {
    const PERIOD_NS: u64 = 100_000;

    fn name(self) -> &'static str {
        match self {
            Pace::BackToBack => "back to back",
            Pace::Hz10k => "10 kHz",
        }
    }

    /// Before ping number `i` of a run that started at `start_ns`.
    fn before(self, start_ns: u64, i: u64) {
        if self == Pace::Hz10k {
            sleep_until_ns(start_ns + i * Self::PERIOD_NS);
        }
    }
}

fn hist() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 10_000_000_000, 3).expect("valid bounds")
}

/// One run's histograms (ns): one-way wake-up at the ponger, round trip at the pinger.
struct Run {
    wake: Histogram<u64>,
    round_trip: Histogram<u64>,
}

/// Memory mapped shared and anonymous, unmapped on drop.
struct SharedPage {
    ptr: *mut u8,
    len: usize,
}

// SAFETY: plain memory; the primitives placed in it do their own synchronisation.
unsafe impl Send for SharedPage {}
unsafe impl Sync for SharedPage {}

impl SharedPage {
    fn new(len: usize) -> SharedPage {
        // SAFETY: a fresh anonymous mapping at a kernel-chosen address.
        let ptr = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                len,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_SHARED | libc::MAP_ANONYMOUS,
                -1,
                0,
            )
        };
        assert_ne!(
            ptr,
            libc::MAP_FAILED,
            "mmap: {}",
            std::io::Error::last_os_error()
        );
        SharedPage {
            ptr: ptr.cast(),
            len,
        }
    }
}

impl Drop for SharedPage {
    fn drop(&mut self) {
        // SAFETY: our mapping; the threads using it have been joined.
        unsafe { libc::munmap(self.ptr.cast(), self.len) };
    }
}

/// The pinger's side of a run: `ping(seq, sent_ns)` signals, `pong(seq)` waits for the answer;
/// the round trips (ns) of every ping sent for `secs`.
fn pinger(
    pace: Pace,
    secs: f64,
    mut ping: impl FnMut(u64, u64),
    mut pong: impl FnMut(u64),
) -> Histogram<u64> {
    let mut round_trip = hist();
    let start = monotonic_ns();
    let end = start + (secs * 1e9) as u64;
    let mut i = 1;
    while monotonic_ns() < end {
        pace.before(start, i);
        let sent_ns = monotonic_ns();
        ping(i, sent_ns);
        pong(i);
        round_trip.saturating_record((monotonic_ns() - sent_ns).max(1));
        i += 1;
    }
    round_trip
}

fn futex_run(pace: Pace, secs: f64) -> Run {
    let (mut ping_tx, mut ping_rx): (Producer<Ping>, Consumer<Ping>) = heap_channel(4);
    let (mut pong_tx, mut pong_rx): (Producer<Ping>, Consumer<Ping>) = heap_channel(4);
    for w in [&mut ping_rx, &mut pong_rx] {
        w.set_wait_strategy(WaitStrategy::Park);
    }
    ping_tx.set_wait_strategy(WaitStrategy::Park);
    pong_tx.set_wait_strategy(WaitStrategy::Park);
    let ponger = std::thread::spawn(move || {
        let mut wake = hist();
        // seq 0 ends the run.
        while let Ok(p) = ping_rx.recv() {
            let now = monotonic_ns();
            if p.seq == 0 {
                break;
            }
            wake.saturating_record(now.saturating_sub(p.sent_ns).max(1));
            pong_tx.send(p).expect("pong");
        }
        wake
    });
    let round_trip = pinger(
        pace,
        secs,
        |seq, sent_ns| ping_tx.send(Ping { seq, sent_ns }).expect("ping"),
        |seq| assert_eq!(pong_rx.recv().expect("pong").seq, seq),
    );
    ping_tx.send(Ping::default()).expect("stop");
    Run {
        wake: ponger.join().expect("ponger"),
        round_trip,
    }
}

/// The bytes one `raw_sync` event occupies at `at`, rounded up to 64.
fn event_span(at: *mut u8) -> usize {
    Event::size_of(Some(at)).div_ceil(64) * 64
}

fn raw_sync_run(pace: Pace, secs: f64) -> Run {
    let page = Arc::new(SharedPage::new(4096));
    // Layout: [sent_ns word (64 B)] [ping event] [pong event].
    let base = page.ptr;
    // SAFETY (all pointer arithmetic below): offsets stay inside the 4096-byte mapping.
    let ping_at = unsafe { base.add(64) };
    let pong_at = unsafe { ping_at.add(event_span(ping_at)) };
    assert!(pong_at as usize + event_span(pong_at) <= base as usize + page.len);
    // SAFETY: fresh, zeroed, suitably sized and aligned memory for each event.
    let (ping, _) = unsafe { Event::new(ping_at, true) }.expect("ping event");
    let (pong, _) = unsafe { Event::new(pong_at, true) }.expect("pong event");
    // SAFETY: the first word of the page, 8-aligned, accessed only atomically.
    let sent = unsafe { &*(base as *const AtomicU64) };
    // The ponger opens the events from the memory, as another process would.
    let (ping_addr, pong_addr, base_addr) = (ping_at as usize, pong_at as usize, base as usize);
    let ponger = {
        let page = Arc::clone(&page);
        std::thread::spawn(move || {
            let _keep = page;
            // SAFETY: events initialised above in this mapping, which `_keep` keeps alive.
            let (ping, _) = unsafe { Event::from_existing(ping_addr as *mut u8) }.expect("ping");
            let (pong, _) = unsafe { Event::from_existing(pong_addr as *mut u8) }.expect("pong");
            // SAFETY: as for `sent` above.
            let sent = unsafe { &*(base_addr as *const AtomicU64) };
            let mut wake = hist();
            loop {
                ping.wait(Timeout::Infinite).expect("wait ping");
                let now = monotonic_ns();
                let sent_ns = sent.load(Ordering::Acquire);
                if sent_ns == 0 {
                    break;
                }
                wake.saturating_record(now.saturating_sub(sent_ns).max(1));
                pong.set(EventState::Signaled).expect("set pong");
            }
            wake
        })
    };
    let round_trip = pinger(
        pace,
        secs,
        |_, sent_ns| {
            sent.store(sent_ns, Ordering::Release);
            ping.set(EventState::Signaled).expect("set ping");
        },
        |_| pong.wait(Timeout::Infinite).expect("wait pong"),
    );
    sent.store(0, Ordering::Release);
    ping.set(EventState::Signaled).expect("stop");
    let wake = ponger.join().expect("ponger");
    drop((ping, pong));
    Run { wake, round_trip }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "?".into())
}

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --benches` runs this too: keep that short.
    let quick = !std::env::args().any(|a| a == "--bench");
    let secs: f64 = if quick {
        0.2
    } else {
        env_or("WAKE_BENCH_SECS", 3.0)
    };
    let runs: usize = if quick {
        1
    } else {
        env_or("WAKE_BENCH_RUNS", 3)
    };
    println!(
        "wake-up latency, ping-pong between two threads over MAP_SHARED memory, unpinned, \
         SCHED_OTHER; {secs} s per variant, median of {runs} run(s); load average before: {}",
        load_average()
    );
    println!(
        "{:<16} {:<13} {:>12} {:>12} {:>12} {:>12} {:>10}",
        "primitive", "pace", "wake p50 us", "wake p99 us", "rtt p50 us", "rtt p99 us", "pings/run"
    );
    type Variant = (&'static str, fn(Pace, f64) -> Run);
    let variants: [Variant; 2] = [
        ("shm-ring futex", futex_run),
        ("raw_sync event", raw_sync_run),
    ];
    for pace in [Pace::BackToBack, Pace::Hz10k] {
        for (name, run) in variants {
            let results: Vec<Run> = (0..runs).map(|_| run(pace, secs)).collect();
            let med = |f: &dyn Fn(&Run) -> u64| {
                median(results.iter().map(|r| f(r) as f64 / 1000.0).collect())
            };
            println!(
                "{:<16} {:<13} {:>12.2} {:>12.2} {:>12.2} {:>12.2} {:>10.0}",
                name,
                pace.name(),
                med(&|r| r.wake.value_at_quantile(0.5)),
                med(&|r| r.wake.value_at_quantile(0.99)),
                med(&|r| r.round_trip.value_at_quantile(0.5)),
                med(&|r| r.round_trip.value_at_quantile(0.99)),
                median(results.iter().map(|r| r.round_trip.len() as f64).collect()),
            );
        }
    }
    println!("load average after: {}", load_average());
}
