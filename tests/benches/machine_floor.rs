//! The machine's own floor for `scripts/bench-loaded.sh`, and the in-process model call.
//!
//! 1. Floor: two threads pass a message every 100 us through a real shared-memory ring (a
//!    segment in /dev/shm, shm-ring's rings), both spinning, pinned to the CPUs the product
//!    uses (the loop's: the last online CPU, as rt-loop pins itself; the server's: the one its
//!    automatic profile picks), SCHED_FIFO where permitted. A round trip over 50 us is a miss;
//!    whatever misses here is the machine (interrupts, other work, SMIs), not the product.
//! 2. In process: ONNX Runtime's call of the model (`StepEngine::step`) back to back, p50.
//!
//! Spins both cores for FLOOR_SECONDS (a benchmark only; never in tests).
//! Env: FLOOR_SECONDS (default 20), BENCH_MODEL (default models/rf_six.onnx).
//! Prints a line of text per part and, last, one JSON object.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use haptics_proto::{FeatureMsg, ForceMsg, Segment, MAX_FEATURES};
use haptics_system_tests::repo_root;
use hdrhistogram::Histogram;
use infer_server::serving::profile::{self, Machine, Profile};
use infer_server::{FeatureSchema, Runtime, SessionConfig, StepEngine};
use shm_ring::{monotonic_ns, SegmentName, WaitStrategy};

const PERIOD_NS: u64 = 100_000;
const DEADLINE_NS: u64 = 50_000;

fn pin_fifo(cpu: Option<usize>, priority: i32) {
    if let Some(cpu) = cpu {
        let _ = shm_ring::os::rt_thread::pin_current_thread(cpu);
    }
    let _ = shm_ring::os::rt_thread::set_fifo(priority);
}

fn hist() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 60_000_000_000, 3).unwrap()
}

/// Two threads, one message every 100 us each way; returns (round trips, misses, histogram).
fn floor(
    seconds: f64,
    loop_cpu: Option<usize>,
    server_cpu: Option<usize>,
) -> (u64, u64, Histogram<u64>) {
    let name = SegmentName::for_instance(&format!("floor-{}", std::process::id())).unwrap();
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    lp.forces_rx.set_wait_strategy(WaitStrategy::Spin);
    let mut sv = Segment::attach(&name).unwrap().server_side().unwrap();
    sv.features_rx.set_wait_strategy(WaitStrategy::Spin);
    let done = Arc::new(AtomicBool::new(false));
    let server_done = Arc::clone(&done);
    let server = std::thread::spawn(move || {
        pin_fifo(server_cpu, profile::INFERENCE_PRIORITY);
        while !server_done.load(Ordering::Relaxed) {
            match sv.features_rx.recv_timeout(Duration::from_millis(100)) {
                Ok(f) => {
                    let answer = ForceMsg {
                        seq: f.seq,
                        force: f.values[0],
                        model_id: 1,
                        flags: 0,
                        inference_ns: 0,
                    };
                    if sv.forces_tx.send(answer).is_err() {
                        break;
                    }
                }
                Err(shm_ring::RecvError::Timeout) => continue,
                Err(_) => break,
            }
        }
    });
    let looper = std::thread::spawn(move || {
        pin_fifo(loop_cpu, 80);
        let mut h = hist();
        let mut misses = 0u64;
        let start = monotonic_ns();
        let end = start + (seconds * 1e9) as u64;
        let mut next = start + PERIOD_NS;
        let mut seq = 0u64;
        while next < end {
            while monotonic_ns() < next {
                std::hint::spin_loop();
            }
            seq += 1;
            let t0 = monotonic_ns();
            let msg = FeatureMsg {
                seq,
                timestamp_ns: t0 - start,
                run_id: 1,
                flags: 0,
                len: 9,
                values: [0.5; MAX_FEATURES],
            };
            lp.features_tx.try_send(msg).expect("one message in flight");
            // Wait for this step's answer however long it takes (a late one is a miss, and
            // still drained so the next step starts clean).
            loop {
                let a = lp
                    .forces_rx
                    .recv_timeout(Duration::from_secs(5))
                    .expect("the floor's server answers");
                if a.seq == seq {
                    break;
                }
            }
            let rtt = monotonic_ns() - t0;
            h.saturating_record(rtt.max(1));
            if rtt > DEADLINE_NS {
                misses += 1;
            }
            next += PERIOD_NS;
            let now = monotonic_ns();
            if now > next {
                next += (now - next) / PERIOD_NS * PERIOD_NS + PERIOD_NS; // overran: next grid point
            }
        }
        (h.len(), misses, h)
    });
    let result = looper.join().unwrap();
    done.store(true, Ordering::Relaxed);
    server.join().unwrap();
    result
}

fn in_process_p50_us(model: &std::path::Path) -> f64 {
    let rt = Runtime::init(None).expect("ONNX Runtime (source scripts/env.sh)");
    let mut engine = StepEngine::load(
        rt,
        model,
        &FeatureSchema::standard(),
        &SessionConfig::default(),
    )
    .expect("the default model loads");
    let mut h = hist();
    let width = FeatureSchema::standard().len();
    let mut x = vec![0.0f64; width];
    for t in 0..22_000u64 {
        for (i, v) in x.iter_mut().enumerate() {
            *v = 0.01 * ((t as f64) * 1e-3 + i as f64).sin();
        }
        let t0 = Instant::now();
        let y = engine.step(&x).expect("step");
        let dt = t0.elapsed().as_nanos() as u64;
        std::hint::black_box(y);
        if t >= 2_000 {
            h.saturating_record(dt.max(1));
        }
    }
    h.value_at_quantile(0.5) as f64 / 1000.0
}

fn main() {
    // `cargo bench` passes --bench; nothing else is taken from the command line.
    let seconds: f64 = std::env::var("FLOOR_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20.0);
    let model = std::env::var("BENCH_MODEL")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|_| repo_root().join("models/rf_six.onnx"));
    let machine = Machine::detect();
    let product = profile::settings(Profile::Auto, &machine);
    let loop_cpu = profile::loop_cpu(&machine);
    let p50 = in_process_p50_us(&model);
    println!(
        "in-process ONNX Runtime call of {}: p50 {p50:.2} us",
        model.display()
    );
    let (n, misses, h) = floor(seconds, loop_cpu, product.cpu);
    let miss_pm = misses as f64 * 1e6 / n.max(1) as f64;
    let us = |q: f64| h.value_at_quantile(q) as f64 / 1000.0;
    println!(
        "machine floor: {n} round trips every 100 us, loop CPU {loop_cpu:?}, server CPU {:?}, both spinning: p50 {:.2} us p99 {:.2} us p99.9 {:.2} us max {:.1} us; {misses} over 50 us = {miss_pm:.0} per million",
        product.cpu,
        us(0.5),
        us(0.99),
        us(0.999),
        h.max() as f64 / 1000.0
    );
    println!(
        "{}",
        serde_json::json!({
            "floor_round_trips": n,
            "floor_misses": misses,
            "floor_miss_pm": miss_pm,
            "floor_p50_us": us(0.5),
            "floor_p99_us": us(0.99),
            "floor_p999_us": us(0.999),
            "inprocess_p50_us": p50,
        })
    );
}
