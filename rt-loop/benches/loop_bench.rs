//! `cargo bench -p rt-loop --bench loop_bench`: lockstep steps per second (loop alone, and
//! with the Parquet recorder), and the realtime clock's period jitter and overruns at 10 kHz.
//! RT_BENCH_SECONDS sets the realtime duration (default 10 s).

use rt_loop::config::{ClockKind, RunConfig};
use std::time::Instant;

fn cfg() -> RunConfig {
    let mut c = RunConfig {
        material: concat!(env!("CARGO_MANIFEST_DIR"), "/../materials/sponge.toml").into(),
        ..RunConfig::default()
    };
    c.ramp.ramp_rate = 1.8;
    c
}

/// CPU time of this thread, s (steps per CPU-second do not depend on how loaded the machine is).
fn thread_cpu_s() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: valid pointer.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn main() {
    // 1. lockstep, loop only (board physics + observers + control + features), 5 repeats
    let mut rates = vec![];
    let mut cpu_rates = vec![];
    for _ in 0..5 {
        let mut rig = rt_loop::run::build_rig(&cfg(), None).unwrap();
        let t = Instant::now();
        let c0 = thread_cpu_s();
        let mut n = 0u64;
        let mut sink = 0.0;
        while n < 1_000_000 {
            match rig.step() {
                Ok(r) => sink += r.rtob_force,
                Err(_) => break,
            }
            n += 1;
        }
        std::hint::black_box(sink);
        rates.push(n as f64 / t.elapsed().as_secs_f64());
        cpu_rates.push(n as f64 / (thread_cpu_s() - c0));
    }
    println!(
        "lockstep loop only:        median {:.2} M steps/s (min {:.2}, max {:.2}) over 5 x 1M steps",
        percentile(&mut rates, 0.5) / 1e6,
        rates[0] / 1e6,
        rates[rates.len() - 1] / 1e6
    );
    println!(
        "lockstep loop only per CPU-second: median {:.2} M steps/s ({:.0} ns per step)",
        percentile(&mut cpu_rates, 0.5) / 1e6,
        1e9 / percentile(&mut cpu_rates, 0.5)
    );

    // 2. lockstep with the Parquet recorder (full rate, lossless)
    let dir = std::env::temp_dir().join(format!("rt-loop-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut c = cfg();
    c.max_duration_s = Some(200.0);
    c.record = Some(dir.join("bench.parquet"));
    let s = rt_loop::run::run(&c, None, None).unwrap();
    let rep = s.recorder.as_ref().unwrap();
    println!(
        "lockstep + Parquet recorder: {:.2} M steps/s ({} steps, {} rows written, {:.1} bytes/row)",
        s.steps_per_s / 1e6,
        s.steps,
        rep.rows_written,
        rep.bytes as f64 / rep.rows_written.max(1) as f64
    );
    let _ = std::fs::remove_dir_all(&dir);

    // 3. realtime clock at 10 kHz
    let secs: f64 = std::env::var("RT_BENCH_SECONDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10.0);
    let mut c = cfg();
    c.clock = ClockKind::Realtime;
    c.max_duration_s = Some(secs);
    let s = rt_loop::run::run(&c, None, None).unwrap();
    for w in &s.warnings {
        println!("realtime set-up warning: {w}");
    }
    let j = s.jitter.unwrap();
    println!(
        "realtime 10 kHz for {secs} s: {} steps, {} overruns ({:.4} %)",
        s.steps,
        j.overruns,
        100.0 * j.overruns as f64 / s.steps.max(1) as f64
    );
    println!(
        "  period jitter |T - 100 us|: p50 {:.2} us  p99 {:.2} us  p99.9 {:.2} us  max {:.2} us",
        j.period_jitter.p50_us,
        j.period_jitter.p99_us,
        j.period_jitter.p999_us,
        j.period_jitter.max_us
    );
    println!(
        "  wake-up latency:            p50 {:.2} us  p99 {:.2} us  p99.9 {:.2} us  max {:.2} us",
        j.wake_latency.p50_us, j.wake_latency.p99_us, j.wake_latency.p999_us, j.wake_latency.max_us
    );
}
