//! Hot swap under a 10 kHz loop: 100 swaps between the random forest and the dense network
//! (benches/make_bench_models.py) through the real registry (`Registry::activate`, the same call
//! gRPC makes) while this benchmark's main thread plays a loop paced at 10 kHz with a 50 us
//! deadline over a real segment, answered by the real inference thread.
//!
//! Prints each swap's effective step (the first answered by the new model, checked against the
//! `model_id` of the answers), lost steps (must be 0: every step answered in order), and the
//! deadline misses per million steps near swaps (within +-5 ms of an effective step) and away
//! from them, with the round-trip percentiles of both.
//!
//! Env: BENCH_WAIT=spin|park|spin-park (default spin-park), BENCH_SPINS, BENCH_SWAPS (100),
//! BENCH_SWAP_EVERY_MS (30), BENCH_SERVER_CPU / BENCH_LOOP_CPU, BENCH_RT_PRIO.

mod common;

use common::{bench_models, repo_root};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use haptics_proto::{FeatureMsg, Segment};
use infer_server::control::inference_control::InferenceControl;
use infer_server::control::registry::Registry;
use infer_server::serving::inference_thread::InferenceConfig;
use infer_server::{Runtime, SessionConfig};
use shm_ring::{SegmentName, WaitStrategy};

fn env_usize(name: &str) -> Option<usize> {
    std::env::var(name).ok().and_then(|s| s.parse().ok())
}

fn wait_env() -> WaitStrategy {
    match std::env::var("BENCH_WAIT").as_deref() {
        Ok("park") => WaitStrategy::Park,
        Ok("spin") => WaitStrategy::Spin,
        _ => match env_usize("BENCH_SPINS") {
            Some(spins) => WaitStrategy::SpinThenPark {
                spins: spins as u32,
            },
            None => WaitStrategy::DEFAULT_SPIN_THEN_PARK,
        },
    }
}

fn quantile(sorted: &[u64], q: f64) -> u64 {
    if sorted.is_empty() {
        return 0;
    }
    sorted[((sorted.len() as f64 * q).ceil() as usize).clamp(1, sorted.len()) - 1]
}

struct Step {
    seq: u64,
    rtt_ns: u64,
    model_id: u32,
}

fn main() {
    let swaps = env_usize("BENCH_SWAPS").unwrap_or(100);
    let every = Duration::from_millis(env_usize("BENCH_SWAP_EVERY_MS").unwrap_or(30) as u64);
    let wait = wait_env();
    let rt_prio = env_usize("BENCH_RT_PRIO").map(|p| p as i32);
    let rt = Runtime::init(None).unwrap_or_else(|e| panic!("{e}"));
    let src = bench_models();
    let dir = repo_root().join(format!("target/bench-swap-models-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for m in ["rf", "dense"] {
        std::fs::copy(src.join(format!("{m}.onnx")), dir.join(format!("{m}.onnx"))).unwrap();
    }

    let seg =
        SegmentName::new(&format!("/infer-server-swap-bench-{}", std::process::id())).unwrap();
    let mut lp = Segment::create(&seg, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    lp.forces_rx.set_wait_strategy(wait);
    let server = Arc::new(
        InferenceControl::start(
            rt,
            InferenceConfig {
                segment: seg.clone(),
                wait,
                cpu: env_usize("BENCH_SERVER_CPU"),
                rt_priority: rt_prio,
                exit_when_loop_gone: true,
                keep_awake: false,
            },
            SessionConfig::default(),
        )
        .unwrap(),
    );
    let registry = Arc::new(Registry::new(Arc::clone(&server), &dir));
    while !server.attached() {
        std::thread::sleep(Duration::from_millis(1));
    }
    for m in ["rf.onnx", "dense.onnx"] {
        registry
            .load(control_plane::ModelSource::Directory { name: m.into() })
            .unwrap();
    }

    // The swapper: a control-plane thread, as gRPC's blocking pool would be.
    let done = Arc::new(AtomicBool::new(false));
    let swapper = {
        let registry = Arc::clone(&registry);
        let done = Arc::clone(&done);
        std::thread::spawn(move || {
            let mut out = Vec::new();
            std::thread::sleep(Duration::from_millis(200));
            for i in 0..swaps {
                let name = if i % 2 == 0 { "rf.onnx" } else { "dense.onnx" };
                let t0 = Instant::now();
                let a = registry.activate(name, false).unwrap();
                out.push((a.effective_step, a.model.model_id, t0.elapsed()));
                let _ = registry.maintain();
                std::thread::sleep(every);
            }
            std::thread::sleep(Duration::from_millis(200));
            done.store(true, Ordering::Relaxed);
            out
        })
    };

    if let Some(cpu) = env_usize("BENCH_LOOP_CPU") {
        if let Err(e) = shm_ring::os::rt_thread::pin_current_thread(cpu) {
            println!("loop thread not pinned: {e}");
        }
    }
    if let Some(p) = rt_prio {
        if let Err(e) = shm_ring::os::rt_thread::set_fifo(p) {
            println!("loop thread not SCHED_FIFO: {e}");
        }
    }
    let period = Duration::from_micros(100);
    let deadline = 50_000u64;
    let mut steps: Vec<Step> = Vec::with_capacity(1 << 20);
    let mut msg = FeatureMsg {
        len: 9,
        run_id: 1,
        flags: FeatureMsg::RUN_START,
        ..FeatureMsg::default()
    };
    let mut seq = 0u64;
    let mut next = Instant::now() + period;
    while !done.load(Ordering::Relaxed) {
        common::pace_until(next, wait != WaitStrategy::Spin);
        next += period;
        seq += 1;
        msg.seq = seq;
        for j in 0..9 {
            msg.values[j] = (((seq as usize * 31 + j * 17) % 200) as f64 / 100.0) - 1.0;
        }
        let t0 = Instant::now();
        lp.features_tx.try_send(msg).unwrap();
        let a = lp.forces_rx.recv_timeout(Duration::from_secs(5)).unwrap();
        let rtt = t0.elapsed().as_nanos() as u64;
        assert_eq!(a.seq, seq, "answers in order");
        msg.flags = 0;
        steps.push(Step {
            seq,
            rtt_ns: rtt,
            model_id: a.model_id,
        });
        lp.heartbeat();
    }
    let swaps_done = swapper.join().unwrap();

    // Every step answered once, in order; model ids switch exactly at the effective steps.
    let lost = steps
        .windows(2)
        .filter(|w| w[1].seq != w[0].seq + 1)
        .count();
    let mut wrong = 0;
    for (i, &(from, id, _)) in swaps_done.iter().enumerate() {
        let until = swaps_done.get(i + 1).map_or(u64::MAX, |s| s.0);
        wrong += steps
            .iter()
            .filter(|s| s.seq >= from && s.seq < until && s.model_id != id)
            .count();
    }
    let near = |seq: u64| swaps_done.iter().any(|s| seq.abs_diff(s.0) <= 50);
    let first = swaps_done[0].0.saturating_sub(1000);
    let mut near_rtt = Vec::new();
    let mut away_rtt = Vec::new();
    for s in steps.iter().filter(|s| s.seq >= first) {
        if near(s.seq) {
            near_rtt.push(s.rtt_ns);
        } else {
            away_rtt.push(s.rtt_ns);
        }
    }
    // The first step each new model answers runs on cold caches.
    let mut first_rtt: Vec<u64> = swaps_done
        .iter()
        .filter_map(|s| steps.iter().find(|x| x.seq == s.0).map(|x| x.rtt_ns))
        .collect();
    first_rtt.sort_unstable();
    let first_misses = first_rtt.iter().filter(|&&r| r > deadline).count();
    let misses = |v: &[u64]| v.iter().filter(|&&r| r > deadline).count();
    let (near_miss, away_miss) = (misses(&near_rtt), misses(&away_rtt));
    near_rtt.sort_unstable();
    away_rtt.sort_unstable();
    let mut swap_ms: Vec<u64> = swaps_done.iter().map(|s| s.2.as_micros() as u64).collect();
    swap_ms.sort_unstable();

    println!(
        "hot swap under a 10 kHz loop (50 us deadline): {} swaps rf <-> dense, wait {wait:?}, SCHED_FIFO {rt_prio:?}, load average {}",
        swaps_done.len(),
        std::fs::read_to_string("/proc/loadavg")
            .unwrap_or_default()
            .split(' ')
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    );
    println!(
        "effective steps: {}",
        swaps_done
            .iter()
            .map(|s| s.0.to_string())
            .collect::<Vec<_>>()
            .join(" ")
    );
    println!(
        "steps {} lost {lost} answered by the wrong model {wrong}; activate call p50 {} us max {} us",
        steps.len(),
        quantile(&swap_ms, 0.5),
        swap_ms.last().copied().unwrap_or(0)
    );
    println!(
        "{:<28} {:>8} {:>8} {:>8} {:>9} {:>9} {:>10}",
        "round trip, ns", "steps", "p50", "p99", "p99.9", "max", "miss/1e6"
    );
    for (label, v, m) in [
        ("a new model's first step", &first_rtt, first_misses),
        ("within 5 ms of a swap", &near_rtt, near_miss),
        ("away from swaps", &away_rtt, away_miss),
    ] {
        println!(
            "{label:<28} {:>8} {:>8} {:>8} {:>9} {:>9} {:>10.1}",
            v.len(),
            quantile(v, 0.5),
            quantile(v, 0.99),
            quantile(v, 0.999),
            v.last().copied().unwrap_or(0),
            m as f64 * 1e6 / v.len().max(1) as f64
        );
    }
    drop(lp);
    drop(registry);
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(lost, 0, "lost steps");
    assert_eq!(wrong, 0, "answers from the wrong model");
}
