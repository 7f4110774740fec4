//! Wait profiles: how the inference thread waits, where it runs and with which privileges,
//! chosen from what the machine has and permits.
//!
//! Why: the right wait depends on the machine. With a core to spare (an isolated CPU, or
//! enough cores) the thread spins on a core of its own and answers within a few microseconds;
//! on a small machine a spinning thread would take the core the rest of the system (the page,
//! the control plane, ONNX Runtime's own work) needs, and a thread that parks makes the loop pay
//! a futex wake-up every step, so it uses the period-synchronised wait
//! ([`crate::serving::period_sync`]); on one core it can only park. The profile is picked automatically,
//! printed at start and can be overridden (`infer-server serve --profile`), and each explicit
//! flag (`--wait`, `--cpu`, `--rt-priority`, `--mlock`) overrides its part of it.

use shm_ring::os::rt_thread::Permissions;
use shm_ring::WaitStrategy;

/// SCHED_FIFO priority the profiles give the inference thread: below rt-loop's default (80),
/// so the loop always preempts it on a shared core.
pub const INFERENCE_PRIORITY: i32 = 70;

/// What the machine has and permits, as far as the inference thread is concerned.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Machine {
    /// CPUs this process may run on (its affinity mask), ascending.
    pub cpus: Vec<usize>,
    /// CPUs listed in /sys/devices/system/cpu/isolated.
    pub isolated: Vec<usize>,
    /// Whether SCHED_FIFO was granted to a probe thread.
    pub rt_permitted: bool,
    /// Whether mlockall can be expected to succeed (root, or an unlimited RLIMIT_MEMLOCK).
    pub mlock_permitted: bool,
    /// Whether a thread may set its own CPU affinity.
    pub affinity_permitted: bool,
    /// The CPU quota of this process's cgroup (or an ancestor's), as the kernel states it,
    /// where there is one ([`cpu_quota`]): a spinner would spend it.
    pub cpu_quota: Option<String>,
}

/// The profiles, from most to least dedicated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Profile {
    /// Pick from the machine ([`choose`]).
    Auto,
    /// Spin on a core of its own (an isolated CPU, else the first CPU that is not the loop's).
    Dedicated,
    /// Period-synchronised wait: sleep until shortly before each step, spin through its arrival.
    Period,
    /// Spin briefly, then park on the futex (one core, or a machine shared with other work).
    Shared,
}

/// The settings a profile resolves to.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    pub profile: Profile,
    pub wait: WaitStrategy,
    pub cpu: Option<usize>,
    pub rt_priority: Option<i32>,
    pub mlock: bool,
    /// Keep the inference CPU awake between steps with a `SCHED_IDLE` spinner
    /// ([`crate::serving::keep_awake`]): the period-synchronised wait on a pinned CPU.
    pub keep_awake: bool,
}

/// rt-loop's default CPU: the last online one (`RealtimeConfig::cpu == -2`).
pub fn loop_cpu(machine: &Machine) -> Option<usize> {
    machine.cpus.last().copied()
}

/// The profile `auto` stands for on `machine`.
pub fn choose(machine: &Machine) -> Profile {
    let spare_isolated = machine
        .isolated
        .iter()
        .any(|c| Some(*c) != loop_cpu(machine) && machine.cpus.contains(c));
    if machine.affinity_permitted && (spare_isolated || machine.cpus.len() >= 4) {
        Profile::Dedicated
    } else if machine.cpus.len() >= 2 {
        Profile::Period
    } else {
        Profile::Shared
    }
}

/// The settings of `profile` (`Auto` resolved) on `machine`.
pub fn settings(profile: Profile, machine: &Machine) -> Settings {
    let profile = match profile {
        Profile::Auto => choose(machine),
        p => p,
    };
    let loop_cpu = loop_cpu(machine);
    let not_loop = |c: &&usize| Some(**c) != loop_cpu;
    let spare = machine
        .isolated
        .iter()
        .filter(|c| machine.cpus.contains(c))
        .find(not_loop)
        .or_else(|| machine.cpus.iter().find(not_loop))
        .copied()
        .filter(|_| machine.affinity_permitted);
    let fifo = machine.rt_permitted.then_some(INFERENCE_PRIORITY);
    match profile {
        Profile::Dedicated => {
            let isolated = spare.is_some_and(|c| machine.isolated.contains(&c));
            Settings {
                profile,
                wait: WaitStrategy::Spin,
                cpu: spare,
                // A spinning FIFO thread owns its core: only where nothing else is scheduled.
                rt_priority: fifo.filter(|_| isolated),
                mlock: machine.mlock_permitted,
                // A spinning thread keeps its CPU busy by itself.
                keep_awake: false,
            }
        }
        Profile::Period => Settings {
            profile,
            wait: WaitStrategy::PeriodSync,
            cpu: spare,
            rt_priority: fifo,
            mlock: machine.mlock_permitted,
            // The thread sleeps most of each period: its CPU would halt (module keep_awake).
            // Not under a CPU quota: the spinner's time counts against it, and a throttled
            // cgroup stops the inference thread too.
            keep_awake: spare.is_some() && machine.cpu_quota.is_none(),
        },
        Profile::Shared | Profile::Auto => Settings {
            profile: Profile::Shared,
            wait: WaitStrategy::DEFAULT_SPIN_THEN_PARK,
            cpu: None,
            rt_priority: None,
            mlock: machine.mlock_permitted,
            // Not pinned: there is no one CPU to keep awake.
            keep_awake: false,
        },
    }
}

/// Parses a kernel CPU list ("1,3-5"). Bad parts are ignored (an empty list is the answer).
pub fn parse_cpu_list(text: &str) -> Vec<usize> {
    let mut out = Vec::new();
    for part in text.trim().split(',').filter(|p| !p.is_empty()) {
        match part.split_once('-') {
            Some((a, b)) => {
                if let (Ok(a), Ok(b)) = (a.trim().parse::<usize>(), b.trim().parse::<usize>()) {
                    out.extend(a..=b.min(a + 4096));
                }
            }
            None => {
                if let Ok(c) = part.trim().parse() {
                    out.push(c);
                }
            }
        }
    }
    out
}

impl Machine {
    /// Looks at this machine and this process's permissions (a short-lived probe thread tries
    /// SCHED_FIFO and setting its affinity, so the calling thread is left as it was).
    pub fn detect() -> Machine {
        let isolated = std::fs::read_to_string("/sys/devices/system/cpu/isolated")
            .map(|t| parse_cpu_list(&t))
            .unwrap_or_default();
        let cpus = allowed_cpus();
        // The probe of shm_ring::os::rt_thread, the one real-time set-up of both processes.
        let permitted = Permissions::probe();
        let (rt_permitted, affinity_permitted) = (permitted.fifo, permitted.affinity);
        let mut lim = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: valid pointer to a local rlimit.
        let unlimited = unsafe { libc::getrlimit(libc::RLIMIT_MEMLOCK, &mut lim) } == 0
            && lim.rlim_cur == libc::RLIM_INFINITY;
        // SAFETY: no arguments, no memory effects.
        let root = unsafe { libc::geteuid() } == 0;
        Machine {
            cpus,
            isolated,
            rt_permitted,
            mlock_permitted: root || unlimited,
            affinity_permitted,
            cpu_quota: std::fs::read_to_string("/proc/self/cgroup")
                .ok()
                .and_then(|t| cpu_quota(&t, |p| std::fs::read_to_string(p).ok())),
        }
    }

    /// One line for the start-up message.
    pub fn describe(&self) -> String {
        let yes = |b: bool| if b { "permitted" } else { "not permitted" };
        let isolated = if self.isolated.is_empty() {
            "none".to_string()
        } else {
            format!("{:?}", self.isolated)
        };
        let quota = self
            .cpu_quota
            .as_ref()
            .map_or(String::new(), |q| format!(", CPU quota {q}"));
        format!(
            "{} CPUs, isolated {isolated}, RT priority {}, mlock {}, affinity {}{quota}",
            self.cpus.len(),
            yes(self.rt_permitted),
            yes(self.mlock_permitted),
            yes(self.affinity_permitted)
        )
    }
}

impl Settings {
    /// One line for the start-up message.
    pub fn describe(&self) -> String {
        let wait = match self.wait {
            WaitStrategy::Spin => "spin".to_string(),
            WaitStrategy::PeriodSync => "period-synchronised".to_string(),
            WaitStrategy::SpinThenPark { spins } => format!("spin {spins} then park"),
            WaitStrategy::Park => "park".to_string(),
        };
        let cpu = self
            .cpu
            .map_or("not pinned".to_string(), |c| format!("CPU {c}"));
        let prio = self
            .rt_priority
            .map_or("default scheduler".to_string(), |p| {
                format!("SCHED_FIFO {p}")
            });
        let awake = match (self.keep_awake, self.cpu) {
            (true, Some(c)) => {
                format!(", CPU {c} kept awake (a SCHED_IDLE spinner while steps flow)")
            }
            _ => String::new(),
        };
        format!(
            "wait {wait}, {cpu}, {prio}, memory {}{awake}",
            if self.mlock { "locked" } else { "not locked" }
        )
    }
}

// The quota's reader lives beside the spinner it guards (shm_ring::os::keep_awake).
pub use shm_ring::os::keep_awake::cpu_quota;

pub(crate) fn allowed_cpus() -> Vec<usize> {
    // SAFETY: cpu_set_t is plain data; CPU_ISSET reads within it.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        if libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) != 0 {
            let n = libc::sysconf(libc::_SC_NPROCESSORS_ONLN).max(1) as usize;
            return (0..n).collect();
        }
        (0..libc::CPU_SETSIZE as usize)
            .filter(|&c| libc::CPU_ISSET(c, &set))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn machine(cpus: usize, isolated: &[usize], rt: bool) -> Machine {
        Machine {
            cpus: (0..cpus).collect(),
            isolated: isolated.to_vec(),
            rt_permitted: rt,
            mlock_permitted: rt,
            affinity_permitted: true,
            cpu_quota: None,
        }
    }

    #[test]
    fn the_period_profile_keeps_its_cpu_awake_unless_under_a_cpu_quota() {
        let mut m = machine(2, &[], true);
        assert!(settings(Profile::Auto, &m).keep_awake);
        assert!(!settings(Profile::Dedicated, &m).keep_awake);
        assert!(!settings(Profile::Shared, &m).keep_awake);
        m.cpu_quota = Some("100000 100000 (/sys/fs/cgroup/cpu.max)".into());
        let s = settings(Profile::Auto, &m);
        assert_eq!(s.profile, Profile::Period);
        assert!(!s.keep_awake, "a spinner would spend the quota");
        assert!(m.describe().contains("CPU quota 100000 100000"));
    }

    #[test]
    fn a_cpu_quota_is_found_in_the_cgroup_or_an_ancestor_v1_and_v2() {
        use std::collections::HashMap;
        let files: HashMap<&str, &str> = HashMap::from([
            ("/sys/fs/cgroup/cpu.max", "max 100000\n"),
            ("/sys/fs/cgroup/docker/cpu.max", "50000 100000\n"),
            ("/sys/fs/cgroup/docker/abc/cpu.max", "max 100000\n"),
            ("/sys/fs/cgroup/free/cpu.max", "max 100000\n"),
            ("/sys/fs/cgroup/cpu,cpuacct/cpu.cfs_quota_us", "-1\n"),
            (
                "/sys/fs/cgroup/cpu,cpuacct/lxc/x/cpu.cfs_quota_us",
                "200000\n",
            ),
            ("/sys/fs/cgroup/cpu,cpuacct/none/cpu.cfs_quota_us", "-1\n"),
        ]);
        let read = |p: &str| files.get(p).map(|s| s.to_string());
        // v2, the quota on the parent
        let q = cpu_quota("0::/docker/abc\n", read).unwrap();
        assert!(
            q.starts_with("50000 100000 (/sys/fs/cgroup/docker/cpu.max)"),
            "{q}"
        );
        // v2, none anywhere up to the root
        assert_eq!(cpu_quota("0::/free\n", read), None);
        // v1's cpu controller (the unified line empty at the root, as on hybrid systems)
        let v1 = "4:memory:/m\n2:cpu,cpuacct:/lxc/x\n0::/\n";
        assert!(cpu_quota(v1, read).unwrap().starts_with("200000 ("));
        assert_eq!(cpu_quota("2:cpu,cpuacct:/none\n0::/\n", read), None);
        // unreadable files and odd lines: no quota, no panic
        assert_eq!(cpu_quota("garbage\n0::/nowhere\n", |_| None), None);
        assert!(
            cpu_quota("garbage\n0::/docker\n", read).is_some(),
            "an odd line hid the rest"
        );
    }

    #[test]
    fn two_cores_get_the_period_wait_off_the_loops_cpu() {
        let s = settings(Profile::Auto, &machine(2, &[], true));
        assert_eq!(s.profile, Profile::Period);
        assert_eq!(s.wait, WaitStrategy::PeriodSync);
        assert_eq!(s.cpu, Some(0));
        assert_eq!(s.rt_priority, Some(INFERENCE_PRIORITY));
        assert!(s.mlock);
        let s = settings(Profile::Auto, &machine(2, &[], false));
        assert_eq!((s.rt_priority, s.mlock), (None, false));
    }

    #[test]
    fn an_isolated_cpu_or_many_cores_get_a_dedicated_spinning_core() {
        let s = settings(Profile::Auto, &machine(4, &[2, 3], true));
        assert_eq!(s.profile, Profile::Dedicated);
        assert_eq!(s.wait, WaitStrategy::Spin);
        assert_eq!(s.cpu, Some(2), "an isolated CPU that is not the loop's (3)");
        assert_eq!(s.rt_priority, Some(INFERENCE_PRIORITY));
        // Many cores, none isolated: spin on CPU 0, but not as SCHED_FIFO (it would own a core
        // the scheduler also gives to other work).
        let s = settings(Profile::Auto, &machine(8, &[], true));
        assert_eq!(
            (s.profile, s.cpu, s.rt_priority),
            (Profile::Dedicated, Some(0), None)
        );
        // Isolating only the loop's CPU leaves none to spare on a 2-core machine.
        assert_eq!(choose(&machine(2, &[1], true)), Profile::Period);
    }

    #[test]
    fn one_core_parks_and_an_explicit_profile_wins() {
        let m = machine(1, &[], true);
        assert_eq!(settings(Profile::Auto, &m).profile, Profile::Shared);
        assert_eq!(settings(Profile::Auto, &m).cpu, None);
        let s = settings(Profile::Shared, &machine(16, &[3], true));
        assert_eq!(
            (s.wait, s.cpu),
            (WaitStrategy::DEFAULT_SPIN_THEN_PARK, None)
        );
        let s = settings(Profile::Period, &machine(1, &[], false));
        assert_eq!((s.wait, s.cpu), (WaitStrategy::PeriodSync, None));
    }

    #[test]
    fn cpu_lists_parse_as_the_kernel_writes_them() {
        assert_eq!(parse_cpu_list("\n"), Vec::<usize>::new());
        assert_eq!(parse_cpu_list("1,3-5\n"), vec![1, 3, 4, 5]);
        assert_eq!(parse_cpu_list("2"), vec![2]);
        assert_eq!(parse_cpu_list("x,7"), vec![7]);
    }

    #[test]
    fn detect_describes_this_machine() {
        let m = Machine::detect();
        assert!(!m.cpus.is_empty());
        assert!(m.describe().contains("CPUs"));
        assert!(settings(Profile::Auto, &m).describe().starts_with("wait "));
    }
}
