//! Every model family as infer-server serves it: each ONNX file of a folder is loaded into a
//! `StepEngine` exactly as the server loads it (`SessionConfig::default()`, the segment's
//! schema), handed to the real inference thread (`InferenceThread`, the wait profile infer-server
//! picks on this machine) over a real shared-memory segment, and stepped at 10 kHz by this
//! benchmark's main thread standing in for the loop: one run, the state carried from step to
//! step as served. The cost of a call is what the inference thread itself reports in each
//! answer (`ForceMsg::inference_ns`: from the message's receipt to the answer, the model's step
//! included), the allocations per call are counted by a malloc interposer over the whole
//! process while the measured steps run (the loop side allocates nothing).
//!
//! Run by `scripts/bench-models.sh`, which trains and exports one model of each family and the
//! `identity` graph (one node, the stateless contract's input and output: the floor of calling
//! ONNX Runtime at all). By hand:
//!   `cargo bench -p infer-server --bench model_families -- DIR`
//! DIR holds `NAME.onnx` files; optional `DIR/nodes.json` ({NAME: node count}) and
//! `DIR/features.f64` (little-endian f64 rows of the segment's ten features, replayed in order;
//! without it a synthetic press is fed). Env: BENCH_STEPS (measured steps per model, default
//! 20000), BENCH_WARM (steps before measuring, default 2000), BENCH_IO_BINDING=1|0 (bind the
//! inputs and outputs once and step with `RunWithBinding`, or step with `Run`; default: what
//! infer-server does, `SessionConfig::default()`), BENCH_PROFILE (`bench_profile`), BENCH_CPU
//! (the inference thread's CPU instead of the profile's), BENCH_KEEP_AWAKE=1|0 (the keep-awake
//! spinner on the inference thread's CPU, or none; default: the profile's, as infer-server).
//! Prints a table, and as its last line one JSON object:
//! `{"families": {NAME: {"p50_us", "p99_us", "p999_us", "max_us", "allocs_per_call", "nodes",
//!   "delayed_calls", "faulted_calls", "p999_clean_us", "ahead_us"}}, "identity_p50_us": ..,
//!   "floor": {..}, "load": "..", "steps": .., "keep_awake": ..}`.
//! `ahead_us` (column `ahead`) is the work the inference thread did after each answer for the
//! next step (fused-ops ahead.rs: an LSTM's recurrent product reads only the state the step
//! wrote), mean per answer; null where a model has none. It is not in the call's latency and it
//! is in the thread's CPU time: a step costs p50 + ahead of it.
//! `delayed_calls` counts the measured calls during whose round trip the inference thread
//! waited on the run queue (its schedstat's wait time rose: the scheduler ran something else on
//! its core), `faulted_calls` those during which it took a page fault; `p999_clean_us` is the
//! p99.9 of the calls with neither: the model's own tail, apart from those two of the machine's
//! (`ThreadEvents`). All three null where the kernel keeps no scheduler statistics. `floor`
//! ({"p50_us", "p99_us", "p999_us", "max_us"}) is the machine's own: a fixed section of
//! arithmetic timed on a thread set up as the inference thread, with no model (`floor_samples`).

mod common;
#[path = "common/malloc_count.rs"]
mod malloc_count;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use haptics_proto::{FeatureMsg, Segment};
use infer_server::serving::handoff;
use infer_server::serving::inference_thread::{InferenceConfig, InferenceThread};
use infer_server::serving::profile::{self, Machine, Profile};
use infer_server::{FeatureSchema, Runtime, SessionConfig, StepEngine};
use shm_ring::os::rt_thread::{CpuChoice, RtRequest};
use shm_ring::{monotonic_ns, SegmentName, WaitStrategy};

/// The segment's schema as rt-loop publishes it (the nine of Table 3.1, then `f_previous`).
fn schema_names() -> Vec<String> {
    haptics_proto::SCHEMA_NAMES
        .iter()
        .map(|s| s.to_string())
        .collect()
}

/// BENCH_PROFILE=auto|dedicated|period|shared: the inference thread's wait profile (default
/// auto, what infer-server picks; `dedicated` spins on a core of its own: the best tuning, to
/// set beside the default).
fn bench_profile() -> Profile {
    match std::env::var("BENCH_PROFILE").as_deref() {
        Ok("dedicated") => Profile::Dedicated,
        Ok("period") => Profile::Period,
        Ok("shared") => Profile::Shared,
        Ok("auto") | Err(_) => Profile::Auto,
        Ok(other) => panic!("BENCH_PROFILE={other}: one of auto, dedicated, period, shared"),
    }
}

/// The inference thread's settings on `machine`: the profile's ([`bench_profile`]), its CPU
/// replaced by BENCH_CPU where that is set (on a many-core machine: does the CPU the profile
/// picks, the first that is not the loop's, have a noisier tail than another?).
fn bench_settings(machine: &Machine) -> profile::Settings {
    let mut chosen = profile::settings(bench_profile(), machine);
    if let Some(cpu) = env_usize("BENCH_CPU") {
        chosen.cpu = Some(cpu);
    }
    match std::env::var("BENCH_KEEP_AWAKE").as_deref() {
        Ok("1") => chosen.keep_awake = true,
        Ok("0") => chosen.keep_awake = false,
        Ok(other) => panic!("BENCH_KEEP_AWAKE={other}: 1 or 0"),
        Err(_) => {}
    }
    // The spinner needs a pinned CPU (infer-server refuses --keep-awake on without one).
    chosen.keep_awake &= chosen.cpu.is_some();
    chosen
}

fn env_usize(name: &str) -> Option<usize> {
    std::env::var(name).ok().and_then(|s| s.parse().ok())
}

/// The feature rows to replay: the recording's (`features.f64`), else a synthetic 1 Hz press
/// of 0-10 mm with its velocity and a spring-like force (so trees and branches move).
fn feature_rows(dir: &Path, n: usize) -> Vec<[f64; 10]> {
    if let Ok(bytes) = std::fs::read(dir.join("features.f64")) {
        let rows: Vec<[f64; 10]> = bytes
            .chunks_exact(80)
            .map(|c| {
                std::array::from_fn(|j| f64::from_le_bytes(c[j * 8..j * 8 + 8].try_into().unwrap()))
            })
            .collect();
        if !rows.is_empty() {
            return rows;
        }
    }
    (0..n.max(1))
        .map(|t| {
            let w = 2.0 * std::f64::consts::PI;
            let s = t as f64 * 1e-4;
            let x = 0.005 * (1.0 - (w * s).cos());
            let v = 0.005 * w * (w * s).sin();
            let a = 0.005 * w * w * (w * s).cos();
            let f = 800.0 * x;
            [
                x,
                v,
                a,
                f / x.max(1e-4),
                f / v.abs().max(1e-3),
                f / a.abs().max(1e-2),
                1.0,
                x,
                f * x,
                f,
            ]
        })
        .collect()
}

struct Row {
    name: String,
    nodes: Option<u64>,
    p50: u64,
    p99: u64,
    p999: u64,
    max: u64,
    allocs: f64,
    /// calls whose round trip saw the inference thread wait on the run queue, or take a page
    /// fault, and the p99.9 of the others (None without scheduler statistics)
    delayed: Option<usize>,
    faulted: Option<usize>,
    p999_clean: Option<u64>,
    /// work done ahead after each answer, mean ns (Served::ahead_ns)
    ahead_ns: Option<f64>,
}

/// What the kernel counts for the inference thread, read before each request and after its
/// answer: its time waiting on the run queue (ns; the second field of
/// `/proc/self/task/TID/schedstat`) and its page faults (minor + major, fields 10 and 12 of its
/// `stat`). A rise of the first means the scheduler kept the thread off its core during that
/// round trip (another process, or this benchmark's own main thread, ran instead); of the
/// second, that the call touched memory the kernel had to map (in a virtual machine, possibly
/// a page the host had taken back). Either way the call's time then holds the machine's, not
/// only the model's. Diagnostic of the benchmark only; the served path reads nothing like it.
struct ThreadEvents {
    schedstat: std::fs::File,
    stat: std::fs::File,
}

/// One reading of [`ThreadEvents`].
#[derive(Clone, Copy, PartialEq)]
struct Events {
    run_queue_wait_ns: u64,
    faults: u64,
}

impl ThreadEvents {
    /// The newest thread named `inference` (the one `InferenceThread::spawn` just started);
    /// None where /proc has no schedstat (a kernel without scheduler statistics).
    fn of_inference_thread() -> Option<Self> {
        let tid = std::fs::read_dir("/proc/self/task")
            .ok()?
            .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
            .filter(|tid| {
                std::fs::read_to_string(format!("/proc/self/task/{tid}/comm"))
                    .is_ok_and(|c| c.trim_end() == "inference")
            })
            .max()?;
        let open = |f: &str| std::fs::File::open(format!("/proc/self/task/{tid}/{f}")).ok();
        let mut w = ThreadEvents {
            schedstat: open("schedstat")?,
            stat: open("stat")?,
        };
        w.read()?;
        Some(w)
    }

    /// Reads both files into stack buffers (no allocation: the benchmark counts them).
    fn read(&mut self) -> Option<Events> {
        use std::os::unix::fs::FileExt;
        let mut buf = [0u8; 512];
        let n = self.schedstat.read_at(&mut buf, 0).ok()?;
        let run_queue_wait_ns = std::str::from_utf8(&buf[..n])
            .ok()?
            .split_ascii_whitespace()
            .nth(1)?
            .parse()
            .ok()?;
        let n = self.stat.read_at(&mut buf, 0).ok()?;
        let text = std::str::from_utf8(&buf[..n]).ok()?;
        // after "pid (comm) ": state is field 3, minflt field 10, majflt field 12
        let mut rest = text[text.rfind(')')? + 1..].split_ascii_whitespace();
        let minflt: u64 = rest.nth(7)?.parse().ok()?;
        let majflt: u64 = rest.nth(1)?.parse().ok()?;
        Some(Events {
            run_queue_wait_ns,
            faults: minflt + majflt,
        })
    }
}

/// The machine's own floor for the inference thread: a thread set up as the profile sets the
/// inference thread (its CPU, its FIFO priority), woken every period, timing a fixed section of
/// arithmetic whose median is about the identity call's. No model, no ring, no ONNX Runtime:
/// whatever stretches its tail (interrupts on that core, the hypervisor taking the virtual
/// CPU, caches flushed by other work) stretches every model's alike.
fn floor_samples(warm: usize, steps: usize) -> Vec<u64> {
    let machine = Machine::detect();
    let chosen = bench_settings(&machine);
    std::thread::spawn(move || {
        let _rt = RtRequest {
            fifo_priority: chosen.rt_priority,
            cpu: chosen.cpu.map_or(CpuChoice::Any, CpuChoice::Cpu),
            lock_memory: false,
        }
        .apply();
        // ~1.5 us of dependent floating-point work on this class of CPU (a multiply-add chain
        // the compiler cannot fold: its seed comes through black_box)
        let section = |seed: f64| {
            let mut x = seed;
            for _ in 0..1500 {
                x = x * 0.999_999 + 1e-9;
            }
            std::hint::black_box(x)
        };
        let period = Duration::from_micros(100);
        let mut next = Instant::now() + period;
        let mut out = Vec::with_capacity(steps);
        for i in 0..warm + steps {
            common::pace_until(next, true);
            next += period;
            let t = monotonic_ns();
            section(std::hint::black_box(i as f64));
            let dt = monotonic_ns() - t;
            if i >= warm {
                out.push(dt);
            }
        }
        out
    })
    .join()
    .expect("the floor thread")
}

fn quantile(sorted: &[u64], q: f64) -> u64 {
    sorted[((sorted.len() as f64 * q).ceil() as usize).clamp(1, sorted.len()) - 1]
}

/// What `serve` measured: the inference thread's own per-call times of the measured steps;
/// with scheduler statistics, the same for the calls during whose round trip it neither waited
/// on the run queue nor faulted, and the counts of those that did; the allocations per call.
struct Served {
    samples: Vec<u64>,
    clean: Option<(Vec<u64>, usize, usize)>,
    allocs: f64,
    /// Work done ahead after the answers of the measured steps (fused-ops ahead.rs), mean per
    /// answer that had some, in ns; `None`: none had. Off the answer's latency (`samples`),
    /// on the thread's CPU: a call costs p50 + this.
    ahead_ns: Option<f64>,
}

/// Serves `path` through the inference thread for `warm + steps` steps at 10 kHz.
fn serve(
    rt: &'static Runtime,
    path: &Path,
    rows: &[[f64; 10]],
    warm: usize,
    steps: usize,
) -> Served {
    let names = schema_names();
    let schema = FeatureSchema::new(names.clone()).unwrap();
    let stem = path.file_stem().unwrap().to_string_lossy().to_string();
    let seg = SegmentName::new(&format!("/bench-models-{}-{stem}", std::process::id())).unwrap();
    let config = shm_ring::Config {
        feature_names: names,
        ..haptics_proto::layout::config()
    };
    let mut lp = Segment::create(&seg, &config).unwrap().loop_side().unwrap();
    lp.forces_rx
        .set_wait_strategy(WaitStrategy::DEFAULT_SPIN_THEN_PARK);
    let machine = Machine::detect();
    let chosen = bench_settings(&machine);
    let (mut activator, taker) = handoff::channel();
    let thread = InferenceThread::spawn(
        InferenceConfig {
            segment: seg.clone(),
            wait: chosen.wait,
            cpu: chosen.cpu,
            rt_priority: chosen.rt_priority,
            exit_when_loop_gone: true,
            keep_awake: chosen.keep_awake,
        },
        taker,
    )
    .unwrap();
    let mut cfg = SessionConfig::default();
    if let Ok(v) = std::env::var("BENCH_IO_BINDING") {
        cfg.io_binding = v == "1";
    }
    let engine = StepEngine::load(rt, path, &schema, &cfg)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let generation = activator.offer(engine);
    assert!(activator.wait_active(generation, Duration::from_secs(10)));
    while thread.segment_schema().is_none() {
        std::thread::sleep(Duration::from_millis(1));
    }
    let mut msg = FeatureMsg {
        len: 10,
        run_id: 1,
        flags: FeatureMsg::RUN_START,
        ..FeatureMsg::default()
    };
    let period = Duration::from_micros(100);
    let start = Instant::now();
    let t0_ns = monotonic_ns();
    let mut next = start + period;
    let mut samples = Vec::with_capacity(steps);
    let mut events = ThreadEvents::of_inference_thread();
    let mut clean = events.as_ref().map(|_| Vec::with_capacity(steps));
    let (mut delayed, mut faulted) = (0usize, 0usize);
    let ahead_of = |t: &InferenceThread| {
        let s = t.stats().snapshot();
        (s.ahead_runs, s.ahead_ns)
    };
    let mut ahead_from = (0, 0);
    for i in 0..warm + steps {
        if i == warm {
            malloc_count::start();
            ahead_from = ahead_of(&thread);
        }
        // Paced like the loop (on two cores a spinning "loop" would take the core the
        // inference thread needs).
        common::pace_until(next, true);
        next += period;
        msg.seq = i as u64 + 1;
        msg.timestamp_ns = monotonic_ns() - t0_ns;
        msg.values[..10].copy_from_slice(&rows[i % rows.len()]);
        let before = events.as_mut().and_then(ThreadEvents::read);
        lp.features_tx.try_send(msg).unwrap();
        let answer = lp.forces_rx.recv_timeout(Duration::from_secs(5)).unwrap();
        let after = events.as_mut().and_then(ThreadEvents::read);
        assert_eq!(answer.seq, msg.seq);
        assert_eq!(answer.flags, 0, "{stem}: answer flags {}", answer.flags);
        msg.flags = 0;
        if i >= warm {
            samples.push(answer.inference_ns);
            if let (Some(c), Some(a), Some(b)) = (clean.as_mut(), before, after) {
                let waited = b.run_queue_wait_ns != a.run_queue_wait_ns;
                let fault = b.faults != a.faults;
                delayed += usize::from(waited);
                faulted += usize::from(fault);
                if !waited && !fault {
                    c.push(answer.inference_ns);
                }
            }
        }
    }
    let allocs = malloc_count::stop() as f64 / steps as f64;
    // The last answer's work ahead may still be running: a period is plenty.
    std::thread::sleep(period);
    let ahead_to = ahead_of(&thread);
    let runs = ahead_to.0 - ahead_from.0;
    let ahead_ns = (runs > 0).then(|| (ahead_to.1 - ahead_from.1) as f64 / runs as f64);
    drop(lp);
    let _ = thread.join();
    Served {
        samples,
        clean: clean.map(|c| (c, delayed, faulted)),
        allocs,
        ahead_ns,
    }
}

fn main() {
    let dir: PathBuf = std::env::args()
        .skip(1)
        .find(|a| !a.starts_with('-'))
        .map(PathBuf::from)
        .unwrap_or_else(|| common::repo_root().join("target/bench-models/families"));
    let steps = env_usize("BENCH_STEPS").unwrap_or(20_000);
    let warm = env_usize("BENCH_WARM").unwrap_or(2_000);
    let rt = Runtime::init(None).unwrap_or_else(|e| panic!("{e}"));
    let nodes: BTreeMap<String, u64> = std::fs::read_to_string(dir.join("nodes.json"))
        .ok()
        .and_then(|s| serde_json::from_str(&s).ok())
        .unwrap_or_default();
    let mut models: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "onnx"))
        .collect();
    // identity first (the floor), then by name
    models.sort_by_key(|p| {
        let s = p.file_stem().unwrap().to_string_lossy().to_string();
        (!s.starts_with("identity"), s)
    });
    let rows = feature_rows(&dir, warm + steps);
    let load = std::fs::read_to_string("/proc/loadavg")
        .unwrap_or_default()
        .split(' ')
        .take(3)
        .collect::<Vec<_>>()
        .join(" ");
    let machine = Machine::detect();
    let settings = bench_settings(&machine);
    let binding = std::env::var("BENCH_IO_BINDING")
        .map(|v| v == "1")
        .unwrap_or(SessionConfig::default().io_binding);
    println!(
        "model families served by the inference thread ({}), ONNX Runtime {}, {}, 10 kHz, {steps} steps each after {warm}; per call, us; load average {load}",
        settings.describe(),
        rt.version(),
        if binding { "RunWithBinding" } else { "Run" },
    );
    println!(
        "{:<22} {:>6} {:>8} {:>8} {:>8} {:>8} {:>12} {:>8} {:>8} {:>12} {:>8}",
        "model",
        "nodes",
        "p50",
        "p99",
        "p99.9",
        "max",
        "allocs/call",
        "delayed",
        "faulted",
        "p99.9 clean",
        "ahead"
    );
    let us = |ns: u64| ns as f64 / 1000.0;
    // the floor's half before the models, half after: the load of the whole run
    let floor_before = floor_samples(warm, steps / 2);
    let mut out = Vec::new();
    for path in &models {
        let name = path.file_stem().unwrap().to_string_lossy().to_string();
        let Served {
            mut samples,
            clean,
            allocs,
            ahead_ns,
        } = serve(rt, path, &rows, warm, steps);
        samples.sort_unstable();
        let (delayed, faulted) = (clean.as_ref().map(|c| c.1), clean.as_ref().map(|c| c.2));
        let p999_clean = clean.and_then(|(mut u, _, _)| {
            u.sort_unstable();
            (!u.is_empty()).then(|| quantile(&u, 0.999))
        });
        let row = Row {
            nodes: nodes.get(&name).copied(),
            p50: quantile(&samples, 0.5),
            p99: quantile(&samples, 0.99),
            p999: quantile(&samples, 0.999),
            max: *samples.last().unwrap(),
            allocs,
            delayed,
            faulted,
            p999_clean,
            ahead_ns,
            name,
        };
        println!(
            "{:<22} {:>6} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>12.2} {:>8} {:>8} {:>12} {:>8}",
            row.name,
            row.nodes.map_or("-".into(), |n| n.to_string()),
            us(row.p50),
            us(row.p99),
            us(row.p999),
            us(row.max),
            row.allocs,
            row.delayed.map_or("-".into(), |n| n.to_string()),
            row.faulted.map_or("-".into(), |n| n.to_string()),
            row.p999_clean
                .map_or("-".into(), |n| format!("{:.2}", us(n))),
            row.ahead_ns
                .map_or("-".into(), |n| format!("{:.2}", n / 1000.0)),
        );
        out.push(row);
    }
    let families: serde_json::Map<String, serde_json::Value> = out
        .iter()
        .filter(|r| r.name != "identity")
        .map(|r| {
            (
                r.name.clone(),
                serde_json::json!({
                    "p50_us": us(r.p50),
                    "p99_us": us(r.p99),
                    "p999_us": us(r.p999),
                    "max_us": us(r.max),
                    "allocs_per_call": r.allocs,
                    "nodes": r.nodes,
                    "delayed_calls": r.delayed,
                    "faulted_calls": r.faulted,
                    "p999_clean_us": r.p999_clean.map(us),
                    "ahead_us": r.ahead_ns.map(|n| n / 1000.0),
                }),
            )
        })
        .collect();
    let mut floor = floor_before;
    floor.extend(floor_samples(warm, steps / 2));
    floor.sort_unstable();
    let fq = |q: f64| us(quantile(&floor, q));
    println!(
        "{:<22} {:>6} {:>8.2} {:>8.2} {:>8.2} {:>8.2}   (the machine's floor: {steps} sections of fixed arithmetic, half before the models and half after, the inference thread's CPU and priority, no model)",
        "floor",
        "-",
        fq(0.5),
        fq(0.99),
        fq(0.999),
        us(*floor.last().unwrap()),
    );
    let identity = out.iter().find(|r| r.name == "identity").map(|r| us(r.p50));
    println!(
        "{}",
        serde_json::json!({
            "families": families,
            "identity_p50_us": identity,
            "floor": {"p50_us": fq(0.5), "p99_us": fq(0.99), "p999_us": fq(0.999), "max_us": us(*floor.last().unwrap())},
            "steps": steps,
            "load": load,
            "keep_awake": settings.keep_awake,
            "io_binding": binding,
        })
    );
}
