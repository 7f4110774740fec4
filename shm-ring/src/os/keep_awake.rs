//! Keeps a CPU awake while work flows on it: a spinner at `SCHED_IDLE`, pinned to that CPU.
//!
//! Why: a real-time thread that sleeps between periods (infer-server's inference thread, rt-loop's
//! loop thread) leaves its CPU idle, and on a virtual machine an idle CPU halts: the guest's
//! idle driver hands the virtual CPU back to the host, the timer that wakes the thread must first
//! get the host to run that virtual CPU again (now and then tens of microseconds late), and
//! the thread then runs cold. A busy CPU never halts. This thread keeps the CPU busy from the
//! scheduler's lowest class: any other thread that wakes on the CPU preempts it at once (the
//! kernel's wake-up check always prefers a normal or real-time thread over a `SCHED_IDLE`
//! one), so what it takes is the halt, not anyone's time. Measured: docs/infer-server.md,
//! "Keeping the inference CPU awake", and docs/laws/onnx.md, "What it costs the realtime loop".
//!
//! What it costs is power and appearances: while work flows, its CPU shows busy (`top` shows
//! the process near 100 % of a CPU, the load average counts the spinner as runnable).
//!
//! It spins only while work flows (the owner's [`Activity::steps`] counter moved within the
//! last [`IDLE_AFTER`]) and sleeps otherwise, so a process between runs burns nothing. Its
//! loop has no `pause` instruction: a hypervisor's pause-loop exiting takes the CPU back from a
//! guest that spins on `pause`, which is the very halt this thread is there to avoid. It never
//! touches the owner's data besides reading that counter and writing its own figures, and
//! where the system refuses `SCHED_IDLE` or the pinning it does not spin at all (a spinner at
//! the normal class would take half of the CPU from everyone else): it says why and ends.
//! Under a CPU quota ([`cpu_quota`]: `docker run --cpus`, a cgroup's `cpu.max`) its owners leave
//! it out: the spinner's time counts against the quota, and a throttled cgroup stops the
//! real-time thread with it.

use std::hint::black_box;
use std::io;
use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::rt_thread::{pin_current_thread, set_idle};

/// How long after the last step the spinner goes on before it sleeps.
pub const IDLE_AFTER: Duration = Duration::from_millis(50);
/// How long one sleep lasts while no steps flow (the first spin after steps resume waits at most
/// this long: the first steps of a run are served as before, with a halting CPU).
const SLEEP_SLICE: Duration = Duration::from_millis(10);
/// Iterations of one spin chunk between two looks at the counters (a few microseconds).
const CHUNK: u64 = 4096;

/// What the spinner reads and writes of its owner: all relaxed atomics (no ordering with the
/// owner's data is needed: the counter only says whether work flows).
pub trait Activity: Send + Sync + 'static {
    /// A counter the owner moves with its work (steps served, periods run).
    fn steps(&self) -> u64;
    /// Called once the spinner runs at `SCHED_IDLE` on `cpu`.
    fn set_up(&self, cpu: usize);
    /// Adds microseconds spun.
    fn add_spun_us(&self, us: u64);
}

/// Handle on the spinner: dropping it stops the thread (within [`SLEEP_SLICE`]) and waits for it.
pub struct KeepAwake {
    stop: Arc<AtomicBool>,
    tid: Arc<AtomicI64>,
    handle: Option<JoinHandle<()>>,
}

impl KeepAwake {
    /// Starts the spinner for `cpu`; `who` names the process in its messages.
    pub fn spawn<A: Activity>(who: &'static str, cpu: usize, activity: Arc<A>) -> io::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let tid = Arc::new(AtomicI64::new(0));
        let (s, t) = (Arc::clone(&stop), Arc::clone(&tid));
        let handle = std::thread::Builder::new()
            .name("keep-awake".into())
            .spawn(move || run(who, cpu, &s, &t, &*activity))?;
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

fn run(who: &str, cpu: usize, stop: &AtomicBool, tid: &AtomicI64, work: &dyn Activity) {
    // SAFETY: gettid has no arguments and no memory effects.
    tid.store(unsafe { libc::gettid() } as i64, Ordering::Relaxed);
    // The class first: until it is SCHED_IDLE the thread must not spin.
    if let Err(e) = set_idle() {
        eprintln!("{who}: keep-awake: SCHED_IDLE refused ({e}); CPU {cpu} is not kept awake");
        return;
    }
    if let Err(e) = pin_current_thread(cpu) {
        eprintln!("{who}: keep-awake: pinning to CPU {cpu} refused ({e}); not kept awake");
        return;
    }
    work.set_up(cpu);
    let mut seen = work.steps();
    let mut moved = Instant::now();
    let mut x = 1u64;
    while !stop.load(Ordering::Relaxed) {
        let steps = work.steps();
        let now = Instant::now();
        if steps != seen {
            seen = steps;
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
        work.add_spun_us(now.elapsed().as_micros() as u64);
    }
    black_box(x);
}

/// The simplest owner: a step counter and the spinner's figures, for a loop that only needs to
/// count its steps (rt-loop's).
#[derive(Debug)]
pub struct StepCounter {
    pub steps: std::sync::atomic::AtomicU64,
    /// The CPU the spinner runs on once set up; -1 before (or when it was refused).
    pub cpu: AtomicI64,
    pub spun_us: std::sync::atomic::AtomicU64,
}

impl Default for StepCounter {
    fn default() -> Self {
        StepCounter {
            steps: Default::default(),
            cpu: AtomicI64::new(-1),
            spun_us: Default::default(),
        }
    }
}

impl Activity for StepCounter {
    fn steps(&self) -> u64 {
        self.steps.load(Ordering::Relaxed)
    }
    fn set_up(&self, cpu: usize) {
        self.cpu.store(cpu as i64, Ordering::Relaxed);
    }
    fn add_spun_us(&self, us: u64) {
        self.spun_us.fetch_add(us, Ordering::Relaxed);
    }
}

/// The CPU quota that applies to this process, from `/proc/self/cgroup`'s text and a reader of
/// cgroup files: cgroup v2's `cpu.max` ("QUOTA PERIOD", "max" for none) or v1's
/// `cpu.cfs_quota_us` (-1 for none), in the process's cgroup or any ancestor (a quota set on a
/// parent, e.g. a container's, limits every cgroup below it). `None`: no quota found.
pub fn cpu_quota(cgroup: &str, read: impl Fn(&str) -> Option<String>) -> Option<String> {
    for line in cgroup.lines() {
        let mut parts = line.splitn(3, ':');
        let (Some(_), Some(controllers), Some(path)) = (parts.next(), parts.next(), parts.next())
        else {
            continue;
        };
        // v2 (the unified hierarchy, "0::/path") and v1's cpu controller ("N:cpu,cpuacct:/path").
        let files: Vec<(String, &str)> = if controllers.is_empty() {
            vec![("/sys/fs/cgroup".into(), "cpu.max")]
        } else if controllers.split(',').any(|c| c == "cpu") {
            vec![
                (format!("/sys/fs/cgroup/{controllers}"), "cpu.cfs_quota_us"),
                ("/sys/fs/cgroup/cpu".into(), "cpu.cfs_quota_us"),
            ]
        } else {
            continue;
        };
        let mut dir = path.trim_end_matches('/').to_string();
        loop {
            for (root, file) in &files {
                let Some(text) = read(&format!("{root}{dir}/{file}")) else {
                    continue;
                };
                let quota = text.split_whitespace().next().unwrap_or("max");
                if quota != "max" && quota != "-1" {
                    return Some(format!("{} ({root}{dir}/{file})", text.trim()));
                }
            }
            match dir.rfind('/') {
                Some(i) => dir.truncate(i),
                None => break,
            }
        }
    }
    None
}

/// [`cpu_quota`] of the calling process (`/proc/self/cgroup`), where there is one.
pub fn process_cpu_quota() -> Option<String> {
    std::fs::read_to_string("/proc/self/cgroup")
        .ok()
        .and_then(|t| cpu_quota(&t, |p| std::fs::read_to_string(p).ok()))
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
        (state, policy, cpus_of(tid as i32))
    }

    /// The CPUs a thread may run on (0: the calling thread).
    fn cpus_of(tid: i32) -> Vec<usize> {
        // SAFETY: cpu_set_t is plain data, filled by the kernel.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            assert_eq!(
                libc::sched_getaffinity(tid, std::mem::size_of_val(&set), &mut set),
                0
            );
            (0..64).filter(|&c| libc::CPU_ISSET(c, &set)).collect()
        }
    }

    #[test]
    fn spins_at_sched_idle_on_its_cpu_only_while_steps_flow_and_stops_when_dropped() {
        let steps = Arc::new(StepCounter::default());
        let cpu = cpus_of(0)[0];
        let keeper = KeepAwake::spawn("test", cpu, Arc::clone(&steps)).unwrap();
        let t0 = Instant::now();
        while steps.cpu.load(Ordering::Relaxed) < 0 && t0.elapsed() < Duration::from_secs(5) {
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(
            steps.cpu.load(Ordering::Relaxed),
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
            steps.steps.fetch_add(1, Ordering::Relaxed);
            std::thread::sleep(Duration::from_millis(2));
            running += usize::from(thread_state(tid).0 == 'R');
        }
        assert!(
            running >= 60,
            "runnable in {running} of 100 samples while steps flow"
        );
        // It did spin (at SCHED_IDLE it may wait long on a busy CPU: up to 5 s of steps).
        let t0 = Instant::now();
        while steps.spun_us.load(Ordering::Relaxed) == 0 && t0.elapsed() < Duration::from_secs(5) {
            steps.steps.fetch_add(1, Ordering::Relaxed);
            std::thread::sleep(Duration::from_millis(2));
        }
        assert!(steps.spun_us.load(Ordering::Relaxed) > 0, "never spun");

        // No step for longer than IDLE_AFTER: it goes to sleep and stays asleep (runnable only
        // for its short looks): ten samples in a row asleep, within 5 s (a busy CPU may keep a
        // SCHED_IDLE thread from running, and so from noticing, for a while).
        let asleep = |want: char, bump: bool| {
            let (t0, mut in_row) = (Instant::now(), 0);
            while in_row < 10 && t0.elapsed() < Duration::from_secs(5) {
                if bump {
                    steps.steps.fetch_add(1, Ordering::Relaxed);
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
