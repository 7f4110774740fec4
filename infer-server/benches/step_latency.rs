//! In-process per-step latency of the three model families at the thesis's sizes, through
//! `StepEngine::step` (the inference thread's call), and for comparison through `ort`'s safe
//! `Session::run` (allocating inputs and outputs per call). Also counts the C-level allocations
//! (`malloc` & co., which ONNX Runtime's C++ `new` ends in) made per step, with an interposer.
//!
//! Run: `cargo bench -p infer-server --bench step_latency` (env: BENCH_STEPS, default 200000).
//! Models are generated with the project's venv (benches/make_bench_models.py: scikit-learn +
//! skl2onnx random forest 100 x depth 9, torch dense 9-150-25-1, torch LSTM 100 units).

mod common;
#[path = "common/malloc_count.rs"]
mod malloc_count;

use common::bench_models;
use std::path::Path;
use std::time::Instant;

use infer_server::{FeatureSchema, Runtime, SessionConfig, StepEngine};

// ---- benchmark ------------------------------------------------------------------------------

struct Percentiles {
    p50: u64,
    p90: u64,
    p99: u64,
    p999: u64,
    max: u64,
    mean: f64,
}

fn percentiles(samples: &mut [u64]) -> Percentiles {
    samples.sort_unstable();
    let q =
        |p: f64| samples[((samples.len() as f64 * p).ceil() as usize).clamp(1, samples.len()) - 1];
    Percentiles {
        p50: q(0.5),
        p90: q(0.9),
        p99: q(0.99),
        p999: q(0.999),
        max: *samples.last().unwrap(),
        mean: samples.iter().sum::<u64>() as f64 / samples.len() as f64,
    }
}

fn print_row(label: &str, p: &Percentiles, allocs_per_step: f64) {
    println!(
        "{label:<40} {:>8} {:>8} {:>8} {:>9} {:>9} {:>9.0} {:>10.2}",
        p.p50, p.p90, p.p99, p.p999, p.max, p.mean, allocs_per_step
    );
}

/// A feature vector that moves every step (trees take different paths, the LSTM's state moves).
fn input_at(t: usize, v: &mut [f64; 9]) {
    for (j, x) in v.iter_mut().enumerate() {
        *x = (((t * 31 + j * 17) % 200) as f64 / 100.0) - 1.0;
    }
}

fn bench_engine(
    engine: &mut StepEngine,
    steps: usize,
    samples: &mut Vec<u64>,
) -> (Percentiles, f64) {
    let mut v = [0.0f64; 9];
    let mut sink = 0.0f32;
    for t in 0..2_000 {
        input_at(t, &mut v);
        sink += engine.step(&v).unwrap();
    }
    samples.clear();
    malloc_count::start();
    for t in 0..steps {
        input_at(t, &mut v);
        let t0 = Instant::now();
        sink += engine.step(&v).unwrap();
        samples.push(t0.elapsed().as_nanos() as u64);
    }
    let allocs = malloc_count::stop() as f64 / steps as f64;
    std::hint::black_box(sink);
    (percentiles(samples), allocs)
}

/// The same model through ort's safe API: inputs built per call, outputs allocated by ONNX
/// Runtime, `SessionOutputs` map; what a straightforward integration would do.
fn bench_safe_run(path: &Path, steps: usize, samples: &mut Vec<u64>) -> (Percentiles, f64) {
    use ort::session::Session;
    use ort::value::Tensor;
    let rt = Runtime::init(None).unwrap();
    // the product's session (ort-host: the fused operators registered), run through ort's safe API
    let builder = haptics_ort_host::session::builder(rt.environment(), Default::default()).unwrap();
    let mut session: Session =
        haptics_ort_host::session::commit(builder, &std::fs::read(path).unwrap()).unwrap();
    let mut v = [0.0f64; 9];
    let mut run = |t: usize| -> f32 {
        input_at(t, &mut v);
        let data: Vec<f32> = v.iter().map(|&x| x as f32).collect();
        let input = Tensor::from_array(([1usize, 9], data)).unwrap();
        let out = session.run(ort::inputs!["features" => input]).unwrap();
        out["force"].try_extract_tensor::<f32>().unwrap().1[0]
    };
    let mut sink = 0.0f32;
    for t in 0..2_000 {
        sink += run(t);
    }
    samples.clear();
    malloc_count::start();
    for t in 0..steps {
        let t0 = Instant::now();
        sink += run(t);
        samples.push(t0.elapsed().as_nanos() as u64);
    }
    let allocs = malloc_count::stop() as f64 / steps as f64;
    std::hint::black_box(sink);
    (percentiles(samples), allocs)
}

fn main() {
    // `cargo bench` passes `--bench`; a filter argument selects models by name.
    let filter: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let steps: usize = std::env::var("BENCH_STEPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(200_000);
    let rt = Runtime::init(None).unwrap_or_else(|e| panic!("{e}"));
    if let Some(cpu) = std::env::var("BENCH_CPU").ok().and_then(|s| s.parse().ok()) {
        match shm_ring::os::rt_thread::pin_current_thread(cpu) {
            Ok(()) => println!("pinned to CPU {cpu}"),
            Err(e) => println!("not pinned ({e})"),
        }
    }
    let dir = bench_models();
    println!(
        "infer-server step latency, in process, one thread, ONNX Runtime {} ({} steps per row, ns; load average {})",
        rt.version(),
        steps,
        std::fs::read_to_string("/proc/loadavg").unwrap_or_default().split(' ').take(3).collect::<Vec<_>>().join(" ")
    );
    println!(
        "{:<40} {:>8} {:>8} {:>8} {:>9} {:>9} {:>9} {:>10}",
        "model / path", "p50", "p90", "p99", "p99.9", "max", "mean", "mallocs/st"
    );
    let schema = FeatureSchema::standard();
    let mut samples = Vec::with_capacity(steps);
    for (name, label) in [
        ("rf", "random forest 100 x d9"),
        ("dense", "dense 9-150-25-1"),
        ("lstm", "LSTM 100 units"),
    ] {
        if !filter.is_empty() && !filter.iter().any(|f| name.contains(f.as_str())) {
            continue;
        }
        let path = dir.join(format!("{name}.onnx"));
        let run = SessionConfig {
            io_binding: false,
            ..SessionConfig::default()
        };
        let mut engine =
            StepEngine::load(rt, &path, &schema, &run).unwrap_or_else(|e| panic!("{name}: {e}"));
        let (p, a) = bench_engine(&mut engine, steps, &mut samples);
        print_row(&format!("{label} (StepEngine Run)"), &p, a);
        drop(engine);
        let binding = SessionConfig {
            io_binding: true,
            ..SessionConfig::default()
        };
        let mut engine = StepEngine::load(rt, &path, &schema, &binding)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let (p, a) = bench_engine(&mut engine, steps, &mut samples);
        print_row(&format!("{label} (StepEngine IoBinding)"), &p, a);
        if name != "lstm" {
            let (p, a) = bench_safe_run(&path, steps, &mut samples);
            print_row(&format!("{label} (ort run)"), &p, a);
        }
    }
}
