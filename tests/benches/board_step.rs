//! The time a board's per-step calls take (read + write + kick, as `Rig::step` makes them),
//! paced at 10 kHz for BOARD_STEP_SECONDS (default 5): rt-loop's simulated bench, and the
//! Sensoray 826 driver on its C-ABI double (`target/release/libs826_double.so`). On the double
//! the figure is the driver plus the double's own card emulation and the same simulated
//! physics, so the difference between the two is an upper bound on what the driver and the
//! C ABI add per step. A real card's figure is its PCIe register access instead (docs/lab.md).
//! Prints a line per board and, last, one JSON object.
//!
//!   cargo bench -p haptics-system-tests --bench board_step

use haptics_system_tests::bin_dir;
use hdrhistogram::Histogram;
use rt_loop::board::s826::{S826Board, S826Config};
use rt_loop::board::sim::{SimBoard, SimConfig, SimTime, SimWorld};
use rt_loop::board::Board;
use std::time::{Duration, Instant};

fn measure(board: &mut dyn Board, seconds: f64) -> Histogram<u64> {
    let mut h = Histogram::<u64>::new_with_bounds(1, 10_000_000_000, 3).unwrap();
    board.configure().expect("configure");
    board.activate(100_000).expect("activate");
    let period = Duration::from_micros(100);
    let start = Instant::now();
    let mut k = 0u32;
    let word = rt_loop::control::dac::current_to_word(0.05, 0.6);
    while start.elapsed().as_secs_f64() < seconds {
        k += 1;
        let next = start + period * k;
        while Instant::now() < next {
            std::hint::spin_loop();
        }
        let t0 = Instant::now();
        board.read().expect("read");
        board.write(word).expect("write");
        board.kick().expect("kick");
        let _ = h.record(t0.elapsed().as_nanos() as u64);
    }
    board.deactivate();
    board.shutdown();
    h
}

fn line(name: &str, h: &Histogram<u64>) -> serde_json::Value {
    let us = |q: f64| h.value_at_quantile(q) as f64 / 1e3;
    println!(
        "{name:<26} steps {:>7}  p50 {:>6.2} us  p99 {:>6.2} us  p99.9 {:>7.2} us  max {:>8.1} us",
        h.len(),
        us(0.5),
        us(0.99),
        us(0.999),
        h.max() as f64 / 1e3
    );
    serde_json::json!({"steps": h.len(), "p50_us": us(0.5), "p99_us": us(0.99), "p999_us": us(0.999)})
}

fn main() {
    let secs: f64 = std::env::var("BOARD_STEP_SECONDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(5.0);
    let world = SimWorld {
        sponge: None,
        hand: None,
    };
    let mut sim = SimBoard::new(SimConfig::default(), world, SimTime::Wall, 1);
    let sim_h = measure(&mut sim, secs);
    let sim_j = line("sim", &sim_h);
    let lib = bin_dir().join("libs826_double.so");
    assert!(
        lib.is_file(),
        "{} is missing: cargo build --release -p s826-double",
        lib.display()
    );
    std::env::set_var("S826_DOUBLE_WORLD", "free");
    let cfg = S826Config {
        lib: Some(lib),
        watchdog_us: Some(100_000),
        ..S826Config::default()
    };
    let mut s826 = S826Board::new(0, cfg, 0.59, 0.6, 10_000.0).expect("load the double");
    let s826_h = measure(&mut s826, secs);
    let s826_j = line("s826 on the double", &s826_h);
    println!(
        "{}",
        serde_json::json!({"seconds": secs, "sim": sim_j, "s826_double": s826_j})
    );
}
