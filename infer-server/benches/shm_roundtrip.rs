//! Round trip loop -> shared memory -> inference thread -> shared memory -> loop, per model,
//! beside the same model called in process. The "loop" here is this benchmark's main thread
//! (rt-loop's own benchmark adds its control step and deadline logic on top).
//!
//! Two runs per model:
//! - lockstep: send, wait for the answer, repeat (as fast as possible);
//! - paced at 10 kHz: one step every 100 us, the answer expected within a 50 us deadline;
//!   a step whose answer comes later counts as a miss.
//!
//! Both sides spin (WaitStrategy::Spin) by default: on a two-core machine that takes both
//! cores, which is allowed in a benchmark only. BENCH_WAIT=park|spin-park to compare.
//! BENCH_SPINS (spin-park's spin budget), BENCH_STEPS (default 100000), BENCH_SERVER_CPU / BENCH_LOOP_CPU to pin, BENCH_RT_PRIO=N to
//! run both threads SCHED_FIFO at N (use with park or spin-park: never spin FIFO on two cores).
//! Models come from benches/make_bench_models.py (see step_latency.rs).

mod common;

use common::bench_models;
use std::time::{Duration, Instant};

use haptics_proto::{FeatureMsg, Segment};
use infer_server::serving::handoff;
use infer_server::serving::inference_thread::{InferenceConfig, InferenceThread};
use infer_server::{FeatureSchema, Runtime, SessionConfig, StepEngine};
use shm_ring::{SegmentName, WaitStrategy};

fn quantile(sorted: &[u64], q: f64) -> u64 {
    sorted[((sorted.len() as f64 * q).ceil() as usize).clamp(1, sorted.len()) - 1]
}

fn row(label: &str, samples: &mut [u64], misses: Option<u64>) {
    samples.sort_unstable();
    let per_million = misses.map(|m| m as f64 * 1e6 / samples.len() as f64);
    println!(
        "{label:<34} {:>7} {:>7} {:>8} {:>9} {}",
        quantile(samples, 0.5),
        quantile(samples, 0.99),
        quantile(samples, 0.999),
        samples.last().unwrap(),
        per_million.map_or("-".into(), |m| format!("{m:>10.1}"))
    );
}

fn input(t: u64, msg: &mut FeatureMsg) {
    for j in 0..9 {
        msg.values[j] = (((t as usize * 31 + j * 17) % 200) as f64 / 100.0) - 1.0;
    }
}

fn wait_env() -> WaitStrategy {
    match std::env::var("BENCH_WAIT").as_deref() {
        Ok("park") => WaitStrategy::Park,
        Ok("spin-park") => match env_usize("BENCH_SPINS") {
            Some(spins) => WaitStrategy::SpinThenPark {
                spins: spins as u32,
            },
            None => WaitStrategy::DEFAULT_SPIN_THEN_PARK,
        },
        _ => WaitStrategy::Spin,
    }
}

fn env_usize(name: &str) -> Option<usize> {
    std::env::var(name).ok().and_then(|s| s.parse().ok())
}

fn main() {
    let filter: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let steps = env_usize("BENCH_STEPS").unwrap_or(100_000) as u64;
    let wait = wait_env();
    let rt = Runtime::init(None).unwrap_or_else(|e| panic!("{e}"));
    let dir = bench_models();
    if let Some(cpu) = env_usize("BENCH_LOOP_CPU") {
        if let Err(e) = shm_ring::os::rt_thread::pin_current_thread(cpu) {
            println!("loop thread not pinned: {e}");
        }
    }
    let rt_prio = env_usize("BENCH_RT_PRIO").map(|p| p as i32);
    if let Some(p) = rt_prio {
        // The "loop" thread gets the same SCHED_FIFO priority as the inference thread.
        if let Err(e) = shm_ring::os::rt_thread::set_fifo(p) {
            println!("loop thread not SCHED_FIFO: {e}");
        }
    }
    println!(
        "shared-memory round trip vs in-process call, ns; {steps} steps per row; wait {wait:?}; SCHED_FIFO {rt_prio:?}; load average {}",
        std::fs::read_to_string("/proc/loadavg")
            .unwrap_or_default()
            .split(' ')
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    );
    println!(
        "{:<34} {:>7} {:>7} {:>8} {:>9} {:>10}",
        "model / path", "p50", "p99", "p99.9", "max", "miss/1e6"
    );
    let schema = FeatureSchema::standard();
    for (name, label) in [
        ("rf", "random forest 100 x d9"),
        ("dense", "dense 9-150-25-1"),
        ("lstm", "LSTM 100"),
    ] {
        if !filter.is_empty() && !filter.iter().any(|f| name.contains(f.as_str())) {
            continue;
        }
        let path = dir.join(format!("{name}.onnx"));
        let mut samples = Vec::with_capacity(steps as usize);

        // In process, same thread, same inputs.
        {
            let mut engine =
                StepEngine::load(rt, &path, &schema, &SessionConfig::default()).unwrap();
            let mut msg = FeatureMsg {
                len: 9,
                ..FeatureMsg::default()
            };
            for t in 0..steps {
                input(t, &mut msg);
                let t0 = Instant::now();
                std::hint::black_box(engine.step(msg.features()).unwrap());
                samples.push(t0.elapsed().as_nanos() as u64);
            }
            row(&format!("{label}: in-process"), &mut samples, None);
        }

        let seg = SegmentName::new(&format!(
            "/infer-server-bench-{}-{name}",
            std::process::id()
        ))
        .unwrap();
        let mut lp = Segment::create(&seg, &haptics_proto::layout::config())
            .unwrap()
            .loop_side()
            .unwrap();
        lp.forces_rx.set_wait_strategy(wait);
        let (mut activator, taker) = handoff::channel();
        let thread = InferenceThread::spawn(
            InferenceConfig {
                segment: seg.clone(),
                wait,
                cpu: env_usize("BENCH_SERVER_CPU"),
                rt_priority: rt_prio,
                exit_when_loop_gone: true,
                keep_awake: false,
            },
            taker,
        )
        .unwrap();
        let generation = activator
            .offer(StepEngine::load(rt, &path, &schema, &SessionConfig::default()).unwrap());
        assert!(activator.wait_active(generation, Duration::from_secs(10)));
        while thread.segment_schema().is_none() {
            std::thread::sleep(Duration::from_millis(1));
        }
        let mut seq = 0u64;
        let mut msg = FeatureMsg {
            len: 9,
            run_id: 1,
            flags: FeatureMsg::RUN_START,
            ..FeatureMsg::default()
        };
        let mut one = |msg: &mut FeatureMsg, seq: &mut u64| -> Duration {
            *seq += 1;
            msg.seq = *seq;
            input(*seq, msg);
            let t0 = Instant::now();
            lp.features_tx.try_send(*msg).unwrap();
            let a = lp.forces_rx.recv_timeout(Duration::from_secs(5)).unwrap();
            let took = t0.elapsed();
            assert_eq!(a.seq, *seq);
            assert_eq!(a.flags, 0);
            msg.flags = 0;
            took
        };
        for _ in 0..2_000 {
            one(&mut msg, &mut seq);
        }
        samples.clear();
        for _ in 0..steps {
            samples.push(one(&mut msg, &mut seq).as_nanos() as u64);
        }
        row(&format!("{label}: shm lockstep"), &mut samples, None);

        // Paced at 10 kHz with a 50 us deadline. With a spinning wait strategy the loop spins to
        // its next tick; otherwise it sleeps to 30 us before it and spins the rest, as a loop
        // that leaves the other core to the server must.
        let period = Duration::from_micros(100);
        let deadline = 50_000u64;
        samples.clear();
        let mut misses = 0u64;
        let mut next = Instant::now() + period;
        for _ in 0..steps {
            common::pace_until(next, wait != WaitStrategy::Spin);
            next += period;
            let took = one(&mut msg, &mut seq).as_nanos() as u64;
            if took > deadline {
                misses += 1;
            }
            samples.push(took);
        }
        row(
            &format!("{label}: shm 10 kHz, 50 us"),
            &mut samples,
            Some(misses),
        );
        let server = thread.latency().snapshot();
        println!(
            "{:<34} {:>7} {:>7} {:>8} {:>9}",
            format!("{label}: server ring-to-ring"),
            server.quantile(0.5),
            server.quantile(0.99),
            server.quantile(0.999),
            server.max
        );
        drop(lp);
        thread.join().unwrap();
    }
}
