//! Keeps the inference thread's CPU awake between steps: a spinner at `SCHED_IDLE`, pinned to
//! that CPU, that runs only while steps flow.
//!
//! Why: with the period-synchronised wait ([`crate::serving::period_sync`]) the inference thread sleeps
//! most of each period. On a virtual machine an idle CPU halts (the guest's idle driver hands the
//! virtual CPU back to the host), and the timer that wakes the thread must first get the host to
//! run that virtual CPU again: now and then tens of microseconds late, which makes the step late.
//! A busy CPU never halts: `scripts/bench-loaded.sh`'s hog condition (a CPU burner on this CPU)
//! was late less often than its idle condition in every run on this project's VM. This thread
//! keeps the CPU busy from the scheduler's lowest class: any other thread that wakes on the CPU
//! (the inference thread at its timer, the page, the control plane) preempts it at once (the
//! kernel's wake-up check always prefers a normal or real-time thread over a `SCHED_IDLE` one),
//! so what it takes is the halt, not anyone's time. Measured: docs/infer-server.md, "Keeping the
//! inference CPU awake".
//!
//! What it costs is power and appearances: while a loop runs, its CPU shows busy (`top` shows
//! infer-server near 100 % of a CPU, the load average counts the spinner as runnable).
//!
//! It spins only while steps flow (the inference thread's `answered` counter moved within the
//! last [`IDLE_AFTER`]) and sleeps otherwise, so a server with no loop, or a loop between
//! experiments, burns nothing. Its loop has no `pause` instruction: a hypervisor's pause-loop
//! exiting takes the CPU back from a guest that spins on `pause`, which is the very halt this
//! thread is there to avoid. It never touches the inference thread's data besides reading that
//! counter, and where the system refuses `SCHED_IDLE` or the pinning it does not spin at all (a
//! spinner at the normal class would take half of the CPU from everyone else): it says why and
//! ends.

use std::hint::black_box;
use std::io;
use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use shm_ring::os::rt_thread::{pin_current_thread, set_idle};

use crate::serving::inference_thread::InferenceCounters;

/// How long after the last answered step the spinner goes on before it sleeps.
pub const IDLE_AFTER: Duration = Duration::from_millis(50);
/// How long one sleep lasts while no steps flow (the first spin after steps resume waits at most
/// this long: the first steps of a run are served as before, with a halting CPU).
const SLEEP_SLICE: Duration = Duration::from_millis(10);
/// Iterations of one spin chunk between two looks at the counters (a few microseconds).
const CHUNK: u64 = 4096;

/// Handle on the spinner: dropping it stops the thread (within [`SLEEP_SLICE`]) and waits for it.
pub struct KeepAwake {
    stop: Arc<AtomicBool>,
    tid: Arc<AtomicI64>,
    handle: Option<JoinHandle<()>>,
}

impl KeepAwake {
    /// Starts the spinner for `cpu`. It reads `counters.answered` to know whether steps flow,
    /// and writes `keep_awake_cpu` (once set up) and `keep_awake_spun_us`.
    pub fn spawn(cpu: usize, counters: Arc<InferenceCounters>) -> io::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let tid = Arc::new(AtomicI64::new(0));
        let (s, t) = (Arc::clone(&stop), Arc::clone(&tid));
        let handle = std::thread::Builder::new()
            .name("keep-awake".into())
            .spawn(move || run(cpu, &s, &t, &counters))?;
        Ok(Self {
            stop,
            tid,
            handle: Some(handle),
        })
    }

    /// The spinner's thread id (`gettid`); 0 until it has started.
    pub fn tid(&self) -> i64 {
        self.tid.load(Ordering::Relaxed)
    }
}

impl Drop for KeepAwake {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

fn run(cpu: usize, stop: &AtomicBool, tid: &AtomicI64, steps: &InferenceCounters) {
    // SAFETY: gettid has no arguments and no memory effects.
    tid.store(unsafe { libc::gettid() } as i64, Ordering::Relaxed);
    // The class first: until it is SCHED_IDLE the thread must not spin.
    if let Err(e) = set_idle() {
        eprintln!(
            "infer-server: keep-awake: SCHED_IDLE refused ({e}); CPU {cpu} is not kept awake"
        );
        return;
    }
    if let Err(e) = pin_current_thread(cpu) {
        eprintln!("infer-server: keep-awake: pinning to CPU {cpu} refused ({e}); not kept awake");
        return;
    }
    steps.keep_awake_cpu.store(cpu as i64, Ordering::Relaxed);
    let mut seen = steps.answered.load(Ordering::Relaxed);
    let mut moved = Instant::now();
    let mut x = 1u64;
    while !stop.load(Ordering::Relaxed) {
        let answered = steps.answered.load(Ordering::Relaxed);
        let now = Instant::now();
        if answered != seen {
            seen = answered;
            moved = now;
        }
        if now.duration_since(moved) > IDLE_AFTER {
            std::thread::sleep(SLEEP_SLICE);
            continue;
        }
        // Plain arithmetic the compiler must keep, no `pause` (see the module's doc).
        for i in 0..CHUNK {
            x = black_box(x.wrapping_mul(6364136223846793005).wrapping_add(i));
        }
        steps
            .keep_awake_spun_us
            .fetch_add(now.elapsed().as_micros() as u64, Ordering::Relaxed);
    }
    black_box(x);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The thread's scheduling state, policy and allowed CPUs, as the kernel reports them.
    fn thread_state(tid: i64) -> (char, i32, Vec<usize>) {
        let stat = std::fs::read_to_string(format!("/proc/self/task/{tid}/stat")).unwrap();
        // Fields after the command name (which is in parentheses and may hold spaces).
        let rest: Vec<&str> = stat[stat.rfind(')').unwrap() + 2..].split(' ').collect();
        let state = rest[0].chars().next().unwrap();
        // field 41 of proc(5)
        let policy: i32 = rest[38].parse().unwrap();
        // SAFETY: cpu_set_t is plain data, filled by the kernel.
        let cpus = unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            assert_eq!(
                libc::sched_getaffinity(tid as i32, std::mem::size_of_val(&set), &mut set),
                0
            );
            (0..64).filter(|&c| libc::CPU_ISSET(c, &set)).collect()
        };
        (state, policy, cpus)
    }

    fn first_allowed_cpu() -> usize {
        crate::serving::profile::allowed_cpus()[0]
    }

    #[test]
    fn spins_at_sched_idle_on_its_cpu_only_while_steps_flow_and_stops_when_dropped() {
        let steps = Arc::new(InferenceCounters {
            keep_awake_cpu: AtomicI64::new(-1),
            ..Default::default()
        });
        let cpu = first_allowed_cpu();
        let keeper = KeepAwake::spawn(cpu, Arc::clone(&steps)).unwrap();
        let t0 = Instant::now();
        while steps.keep_awake_cpu.load(Ordering::Relaxed) < 0
            && t0.elapsed() < Duration::from_secs(5)
        {
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(
            steps.keep_awake_cpu.load(Ordering::Relaxed),
            cpu as i64,
            "never set up"
        );
        let tid = keeper.tid();
        let (_, policy, cpus) = thread_state(tid);
        assert_eq!(policy, libc::SCHED_IDLE, "the spinner must be SCHED_IDLE");
        assert_eq!(cpus, vec![cpu], "pinned to its CPU alone");

        // Steps flow (one every 2 ms): the spinner is runnable (running, or queued behind
        // whatever else runs on its CPU) nearly always.
        let mut running = 0;
        for _ in 0..100 {
            steps.answered.fetch_add(1, Ordering::Relaxed);
            std::thread::sleep(Duration::from_millis(2));
            running += usize::from(thread_state(tid).0 == 'R');
        }
        assert!(
            running >= 60,
            "runnable in {running} of 100 samples while steps flow"
        );
        // It did spin (at SCHED_IDLE it may wait long on a busy CPU: up to 5 s of steps).
        let t0 = Instant::now();
        while steps.keep_awake_spun_us.load(Ordering::Relaxed) == 0
            && t0.elapsed() < Duration::from_secs(5)
        {
            steps.answered.fetch_add(1, Ordering::Relaxed);
            std::thread::sleep(Duration::from_millis(2));
        }
        assert!(
            steps.keep_awake_spun_us.load(Ordering::Relaxed) > 0,
            "never spun"
        );

        // No step for longer than IDLE_AFTER: it goes to sleep and stays asleep (runnable only
        // for its short looks): ten samples in a row asleep, within 5 s (a busy CPU may keep a
        // SCHED_IDLE thread from running, and so from noticing, for a while).
        let asleep = |want: char, bump: bool| {
            let (t0, mut in_row) = (Instant::now(), 0);
            while in_row < 10 && t0.elapsed() < Duration::from_secs(5) {
                if bump {
                    steps.answered.fetch_add(1, Ordering::Relaxed);
                }
                std::thread::sleep(Duration::from_millis(3));
                in_row = if thread_state(tid).0 == want {
                    in_row + 1
                } else {
                    0
                };
            }
            in_row >= 10
        };
        assert!(asleep('S', false), "still spinning without steps");
        // Steps again: it spins again.
        assert!(asleep('R', true), "not spinning again once steps resumed");

        let t = Instant::now();
        drop(keeper);
        assert!(
            t.elapsed() < Duration::from_secs(1),
            "stopping took {:?}",
            t.elapsed()
        );
        // The join returns when the kernel clears the thread's id at its exit, a moment before
        // the task (and its /proc entry) is released: allow that moment.
        let task = format!("/proc/self/task/{tid}");
        let t = Instant::now();
        while std::path::Path::new(&task).exists() && t.elapsed() < Duration::from_secs(1) {
            std::thread::sleep(Duration::from_millis(1));
        }
        assert!(
            !std::path::Path::new(&task).exists(),
            "the thread is still there 1 s after it was joined"
        );
    }
}
