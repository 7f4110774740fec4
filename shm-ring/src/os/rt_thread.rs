//! Real-time thread set-up, written once for both processes: lock memory (`mlockall`), pin the
//! calling thread to a CPU, give it `SCHED_FIFO`. Each step the system refuses (no
//! `CAP_SYS_NICE`, a low `RLIMIT_MEMLOCK`, a CPU outside the allowed set) is reported, never
//! fatal: the loop still runs, only with more jitter, and the status block says what was
//! obtained ([`Obtained::describe`]).
//!
//! [`RtRequest::apply`] is the whole set-up for one thread, undone when its [`RtGuard`] drops
//! (rt-loop runs an experiment on the calling thread, which must go back to normal after it);
//! [`RtGuard::keep`] leaves it in place (a dedicated thread that ends with the work). The single
//! steps ([`pin_current_thread`], [`set_fifo`], [`set_normal`], [`lock_memory`],
//! [`unpin_current_thread`]) are public for the benchmarks and for threads that must *not* be
//! real-time (the control plane's runtime threads reset themselves with [`set_normal`]).
//!
//! Everything here is a syscall: call it before the real-time loop starts, never inside it.

use std::fmt;
use std::io;

/// Which CPU to pin the thread to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CpuChoice {
    /// Leave the affinity as it is.
    #[default]
    Any,
    /// The last online CPU (on a small machine the one the OS's housekeeping uses least).
    Last,
    /// This CPU.
    Cpu(usize),
}

impl CpuChoice {
    /// The historical command-line encoding: `-1` no pinning, `-2` the last online CPU, `n >= 0`
    /// CPU `n` (rt-loop's `realtime.cpu` and `--cpu`).
    pub fn from_i32(cpu: i32) -> CpuChoice {
        match cpu {
            -2 => CpuChoice::Last,
            n if n >= 0 => CpuChoice::Cpu(n as usize),
            _ => CpuChoice::Any,
        }
    }

    /// The CPU number this choice names on this machine (`None` for [`CpuChoice::Any`]).
    pub fn resolve(self) -> Option<usize> {
        match self {
            CpuChoice::Any => None,
            CpuChoice::Last => Some(online_cpus() - 1),
            CpuChoice::Cpu(n) => Some(n),
        }
    }
}

/// What to ask for. `Default`: nothing (a plain thread); see [`RtRequest::loop_thread`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RtRequest {
    /// `SCHED_FIFO` priority 1-99 (clamped); `None` leaves the scheduler alone.
    pub fifo_priority: Option<i32>,
    /// CPU affinity.
    pub cpu: CpuChoice,
    /// `mlockall(MCL_CURRENT | MCL_FUTURE)` so no page fault stalls the loop (process-wide).
    pub lock_memory: bool,
}

/// One step of the set-up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    LockMemory,
    Pin,
    Fifo,
}

/// A step the system refused: which, and the `errno` it answered.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refusal {
    pub step: Step,
    /// `EPERM`, `EINVAL`, ... (the number for anything else).
    pub errno: String,
    /// One line for a log: what was asked and the system's message.
    pub message: String,
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

/// What the thread obtained.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Obtained {
    /// The CPU the thread is pinned to.
    pub pinned_cpu: Option<usize>,
    /// The `SCHED_FIFO` priority it runs at.
    pub fifo_priority: Option<i32>,
    /// Whether this set-up locked the process's memory.
    pub memory_locked: bool,
    /// Each refused step, in order (the thread carries on without it).
    pub refused: Vec<Refusal>,
}

impl Obtained {
    /// The short text for the loop-status block: "SCHED_FIFO 80 cpu 1 mlocked",
    /// "SCHED_OTHER (FIFO refused: EPERM) cpu 1", "SCHED_OTHER".
    pub fn describe(&self) -> String {
        let fifo_refused = self.refused.iter().find(|r| r.step == Step::Fifo);
        let mut s = match (self.fifo_priority, fifo_refused) {
            (Some(p), _) => format!("SCHED_FIFO {p}"),
            (None, Some(r)) => format!("SCHED_OTHER (FIFO refused: {})", r.errno),
            (None, None) => "SCHED_OTHER".into(),
        };
        if let Some(cpu) = self.pinned_cpu {
            s.push_str(&format!(" cpu {cpu}"));
        }
        if self.memory_locked {
            s.push_str(" mlocked");
        }
        s
    }

    /// One line per refused step, for warnings in a log.
    pub fn warnings(&self) -> Vec<String> {
        self.refused.iter().map(|r| r.message.clone()).collect()
    }
}

impl RtRequest {
    /// rt-loop's defaults for its loop thread: `SCHED_FIFO` 80 on the last CPU, memory locked.
    pub fn loop_thread() -> RtRequest {
        RtRequest {
            fifo_priority: Some(80),
            cpu: CpuChoice::Last,
            lock_memory: true,
        }
    }

    /// Applies the request to the calling thread (memory locking to the whole process): each
    /// step that is refused is recorded in [`RtGuard::obtained`] and the next one is tried.
    /// The previous scheduling, affinity and memory locking come back when the guard drops.
    pub fn apply(&self) -> RtGuard {
        let mut g = RtGuard {
            previous: Previous::of_current_thread(),
            obtained: Obtained::default(),
            restore: true,
        };
        if self.lock_memory {
            match lock_memory() {
                Ok(()) => g.obtained.memory_locked = true,
                Err(e) => g.refuse(Step::LockMemory, format!("mlockall failed: {e}"), &e),
            }
        }
        if let Some(cpu) = self.cpu.resolve() {
            match pin_current_thread(cpu) {
                Ok(()) => g.obtained.pinned_cpu = Some(cpu),
                Err(e) => g.refuse(Step::Pin, format!("pinning to CPU {cpu} failed: {e}"), &e),
            }
        }
        if let Some(priority) = self.fifo_priority {
            let priority = priority.clamp(1, 99);
            match set_fifo(priority) {
                Ok(()) => g.obtained.fifo_priority = Some(priority),
                Err(e) => g.refuse(
                    Step::Fifo,
                    format!("SCHED_FIFO priority {priority} not permitted: {e}"),
                    &e,
                ),
            }
        }
        g
    }
}

/// The calling thread's settings before [`RtRequest::apply`].
struct Previous {
    policy: libc::c_int,
    param: libc::sched_param,
    affinity: Option<libc::cpu_set_t>,
}

impl Previous {
    fn of_current_thread() -> Previous {
        let mut param = libc::sched_param { sched_priority: 0 };
        // SAFETY: plain queries of the calling thread (pid 0) into locals; cpu_set_t is plain
        // data and may be zeroed.
        unsafe {
            let policy = libc::sched_getscheduler(0);
            libc::sched_getparam(0, &mut param);
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            let affinity =
                (libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) == 0)
                    .then_some(set);
            Previous {
                policy,
                param,
                affinity,
            }
        }
    }
}

/// The result of [`RtRequest::apply`]: what was obtained, undone on drop.
pub struct RtGuard {
    previous: Previous,
    obtained: Obtained,
    restore: bool,
}

impl RtGuard {
    fn refuse(&mut self, step: Step, message: String, e: &io::Error) {
        self.obtained.refused.push(Refusal {
            step,
            errno: errno_name(e),
            message,
        });
    }

    /// What the thread obtained.
    pub fn obtained(&self) -> &Obtained {
        &self.obtained
    }

    /// Shorthand for `obtained().describe()`.
    pub fn describe(&self) -> String {
        self.obtained.describe()
    }

    /// Leaves the thread (and the memory lock) as set up; for a dedicated thread whose end is
    /// the end of its work.
    pub fn keep(mut self) -> Obtained {
        self.restore = false;
        std::mem::take(&mut self.obtained)
    }
}

impl Drop for RtGuard {
    fn drop(&mut self) {
        if !self.restore {
            return;
        }
        let o = &self.obtained;
        // SAFETY: restoring values read from this same thread; pointers are to owned fields.
        unsafe {
            if o.fifo_priority.is_some() {
                libc::sched_setscheduler(0, self.previous.policy, &self.previous.param);
            }
            if let (Some(_), Some(set)) = (o.pinned_cpu, self.previous.affinity.as_ref()) {
                libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), set);
            }
            if o.memory_locked {
                libc::munlockall();
            }
        }
    }
}

fn cvt(rc: libc::c_int) -> io::Result<()> {
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Online CPUs (at least 1).
pub fn online_cpus() -> usize {
    // SAFETY: sysconf has no preconditions and no memory effects.
    (unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) }).max(1) as usize
}

/// Locks all of the process's present and future memory (`mlockall`).
pub fn lock_memory() -> io::Result<()> {
    // SAFETY: plain syscall without pointers.
    cvt(unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) })
}

fn set_affinity(set: &libc::cpu_set_t) -> io::Result<()> {
    // SAFETY: pid 0 is the calling thread; `set` is a valid, initialised cpu_set_t.
    cvt(unsafe { libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), set) })
}

/// Pins the calling thread to `cpu`.
pub fn pin_current_thread(cpu: usize) -> io::Result<()> {
    if cpu >= libc::CPU_SETSIZE as usize {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("CPU {cpu} is out of range"),
        ));
    }
    // SAFETY: cpu_set_t is plain data; CPU_SET writes within it (cpu < CPU_SETSIZE).
    let set = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        set
    };
    set_affinity(&set)
}

/// Lets the calling thread run on every online CPU again.
pub fn unpin_current_thread() -> io::Result<()> {
    let n = online_cpus().min(libc::CPU_SETSIZE as usize);
    // SAFETY: as in `pin_current_thread`, every index below CPU_SETSIZE.
    let set = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        for c in 0..n {
            libc::CPU_SET(c, &mut set);
        }
        set
    };
    set_affinity(&set)
}

/// Puts the calling thread in `SCHED_FIFO` at `priority` (1-99).
pub fn set_fifo(priority: i32) -> io::Result<()> {
    if !(1..=99).contains(&priority) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("priority {priority} is not in 1..=99"),
        ));
    }
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: pid 0 is the calling thread; `param` is initialised.
    cvt(unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) })
}

/// Puts the calling thread back on the normal scheduler (`SCHED_OTHER`): threads that must never
/// compete with the loop, even when spawned by a real-time thread (they inherit its policy).
pub fn set_normal() -> io::Result<()> {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: pid 0 is the calling thread; `param` is initialised.
    cvt(unsafe { libc::sched_setscheduler(0, libc::SCHED_OTHER, &param) })
}

/// Puts the calling thread in `SCHED_IDLE`: it runs only when nothing else on its CPU wants to,
/// and any other thread that wakes there preempts it at once (the kernel's wake-up check), so a
/// thread that must never take time from anyone (infer-server's keep-awake spinner) can still
/// keep its CPU busy. Lowering a thread's policy needs no privilege.
pub fn set_idle() -> io::Result<()> {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: pid 0 is the calling thread; `param` is initialised.
    cvt(unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) })
}

/// What this process may do, found by a short-lived probe thread (so the caller's own thread is
/// left as it was).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Permissions {
    /// `SCHED_FIFO` (priority 1) was granted.
    pub fifo: bool,
    /// Setting the affinity (to the thread's own mask) was accepted.
    pub affinity: bool,
}

impl Permissions {
    pub fn probe() -> Permissions {
        let probe = std::thread::spawn(|| {
            let fifo = set_fifo(1).is_ok();
            let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
            // SAFETY: pid 0 is this probe thread, which ends right after; `set` is a local.
            let got = unsafe {
                libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set)
            } == 0;
            Permissions {
                fifo,
                affinity: got && set_affinity(&set).is_ok(),
            }
        });
        probe.join().unwrap_or(Permissions {
            fifo: false,
            affinity: false,
        })
    }
}

/// `EPERM`, `EINVAL`, ... for the status line (the number for anything else).
fn errno_name(e: &io::Error) -> String {
    match e.raw_os_error() {
        Some(libc::EPERM) => "EPERM".into(),
        Some(libc::EINVAL) => "EINVAL".into(),
        Some(libc::EACCES) => "EACCES".into(),
        Some(libc::ESRCH) => "ESRCH".into(),
        Some(libc::ENOMEM) => "ENOMEM".into(),
        Some(n) => format!("errno {n}"),
        None => e.kind().to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The current thread's affinity mask, as CPU numbers.
    fn affinity() -> Vec<usize> {
        // SAFETY: plain query of the calling thread into a local.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            assert_eq!(
                libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set),
                0
            );
            (0..libc::CPU_SETSIZE as usize)
                .filter(|&c| libc::CPU_ISSET(c, &set))
                .collect()
        }
    }

    fn policy() -> libc::c_int {
        // SAFETY: plain query.
        unsafe { libc::sched_getscheduler(0) }
    }

    #[test]
    fn cpu_choice_keeps_the_command_line_encoding() {
        assert_eq!(CpuChoice::from_i32(-1), CpuChoice::Any);
        assert_eq!(CpuChoice::from_i32(-2), CpuChoice::Last);
        assert_eq!(CpuChoice::from_i32(3), CpuChoice::Cpu(3));
        assert_eq!(CpuChoice::Last.resolve(), Some(online_cpus() - 1));
        assert_eq!(CpuChoice::Any.resolve(), None);
    }

    /// Each step is either obtained or reported, never both, never silent; the thread comes
    /// back as it was when the guard drops. On a thread of its own so the test harness's thread
    /// is untouched whatever happens.
    #[test]
    fn apply_reports_every_step_and_restores_on_drop() {
        std::thread::spawn(|| {
            let before_affinity = affinity();
            let before_policy = policy();
            let req = RtRequest {
                fifo_priority: Some(1),
                cpu: CpuChoice::Cpu(before_affinity[0]),
                lock_memory: false,
            };
            let g = req.apply();
            let o = g.obtained().clone();
            let refused = |s: Step| o.refused.iter().any(|r| r.step == s);
            assert!(o.pinned_cpu.is_some() != refused(Step::Pin), "{o:?}");
            assert!(o.fifo_priority.is_some() != refused(Step::Fifo), "{o:?}");
            assert!(
                !o.memory_locked && !refused(Step::LockMemory),
                "not asked for"
            );
            if o.pinned_cpu.is_some() {
                assert_eq!(affinity(), vec![before_affinity[0]]);
            }
            if o.fifo_priority.is_some() {
                assert_eq!(policy(), libc::SCHED_FIFO);
                assert!(g.describe().starts_with("SCHED_FIFO 1"), "{}", g.describe());
            } else {
                assert!(
                    g.describe().starts_with("SCHED_OTHER (FIFO refused: "),
                    "{}",
                    g.describe()
                );
            }
            assert_eq!(o.warnings().len(), o.refused.len());
            drop(g);
            assert_eq!(affinity(), before_affinity);
            assert_eq!(policy(), before_policy);
        })
        .join()
        .unwrap();
    }

    #[test]
    fn keep_leaves_the_thread_set_up() {
        std::thread::spawn(|| {
            let cpu = affinity()[0];
            let o = RtRequest {
                cpu: CpuChoice::Cpu(cpu),
                ..RtRequest::default()
            }
            .apply()
            .keep();
            if o.pinned_cpu.is_some() {
                assert_eq!(affinity(), vec![cpu]);
            }
            unpin_current_thread().unwrap();
        })
        .join()
        .unwrap();
    }

    #[test]
    fn bad_arguments_are_refused_not_clamped_silently() {
        assert_eq!(
            pin_current_thread(libc::CPU_SETSIZE as usize)
                .unwrap_err()
                .kind(),
            io::ErrorKind::InvalidInput
        );
        assert_eq!(set_fifo(0).unwrap_err().kind(), io::ErrorKind::InvalidInput);
        assert_eq!(
            set_fifo(100).unwrap_err().kind(),
            io::ErrorKind::InvalidInput
        );
        // A CPU the machine does not have: reported as a refused step, the rest goes on.
        std::thread::spawn(|| {
            let g = RtRequest {
                cpu: CpuChoice::Cpu(libc::CPU_SETSIZE as usize - 1),
                ..RtRequest::default()
            }
            .apply();
            assert_eq!(g.obtained().pinned_cpu, None);
            assert_eq!(g.obtained().refused[0].step, Step::Pin);
            assert_eq!(g.describe(), "SCHED_OTHER");
        })
        .join()
        .unwrap();
    }

    #[test]
    fn describe_matches_the_status_texts() {
        let o = Obtained {
            pinned_cpu: Some(1),
            fifo_priority: Some(80),
            memory_locked: true,
            refused: vec![],
        };
        assert_eq!(o.describe(), "SCHED_FIFO 80 cpu 1 mlocked");
        let o = Obtained {
            pinned_cpu: Some(1),
            refused: vec![Refusal {
                step: Step::Fifo,
                errno: "EPERM".into(),
                message: "no".into(),
            }],
            ..Obtained::default()
        };
        assert_eq!(o.describe(), "SCHED_OTHER (FIFO refused: EPERM) cpu 1");
    }

    #[test]
    fn probe_leaves_the_caller_alone() {
        let before = (affinity(), policy());
        let p = Permissions::probe();
        assert_eq!((affinity(), policy()), before);
        // Whatever the probe found, apply() agrees with it for FIFO.
        std::thread::spawn(move || {
            let g = RtRequest {
                fifo_priority: Some(1),
                ..RtRequest::default()
            }
            .apply();
            assert_eq!(g.obtained().fifo_priority.is_some(), p.fifo);
        })
        .join()
        .unwrap();
    }
}
