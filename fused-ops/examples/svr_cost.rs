//! What one row of `ai.haptics:SvrStep` costs, the kernel alone (no ONNX Runtime), warm: the
//! arithmetic docs/infer-server.md quotes for `svr_six` ("The support vectors in blocks").
//!
//! The SVR is synthetic, of the served model's shape (the row's cost depends on the number of
//! support vectors and features, not on their values: the kernel is branch-free): S support
//! vectors of 6 standardised features (`scripts/bench-models.sh`'s `svr_six` keeps about 1 700;
//! the product's default `max_rows` 5 000 allows up to 5 000), gamma 1/6 (scikit-learn's
//! `scale` on standardised features), dual coefficients in [-10, 10] (C = 10). Rows are drawn
//! from the same range. Each row is timed alone (`Instant` around the call: ~20-40 ns of the
//! figures are the clock). Prints p50/p99/p99.9/max per row and the mean per support vector.
//!
//! Run: `cargo run --release -p haptics-fused-ops --example svr_cost [ROWS]` (default 20000).

use std::collections::HashMap;
use std::hint::black_box;
use std::time::Instant;

use haptics_fused_ops::{Attrs, RowModel, SvrParams};

/// Attributes from a map (what the exporter would write).
#[derive(Default)]
struct Map(HashMap<&'static str, Vec<f32>>);

impl Attrs for Map {
    fn float(&self, name: &str) -> Option<f32> {
        self.0.get(name).and_then(|v| v.first().copied())
    }
    fn floats(&self, name: &str) -> Option<Vec<f32>> {
        self.0.get(name).cloned()
    }
    fn ints(&self, _: &str) -> Option<Vec<i64>> {
        None
    }
    fn string(&self, _: &str) -> Option<String> {
        None
    }
}

/// A small deterministic generator (xorshift64*), so every run measures the same model.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    /// Uniform in [-1, 1).
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 23) as f32 - 1.0
    }
}

const FEATURES: usize = 6;

/// An RBF SVR with `s` support vectors over standardised features.
fn svr(s: usize, rng: &mut Rng) -> Map {
    let mut m = Map::default();
    m.0.insert("feature_mean", vec![0.0; FEATURES]);
    m.0.insert("feature_scale", vec![1.0; FEATURES]);
    m.0.insert(
        "support_vectors",
        (0..s * FEATURES).map(|_| 2.0 * rng.unit()).collect(),
    );
    m.0.insert("coefficients", (0..s).map(|_| 10.0 * rng.unit()).collect());
    m.0.insert("gamma", vec![1.0 / FEATURES as f32]);
    m.0.insert("intercept", vec![0.5]);
    m
}

fn quantile(sorted: &[u64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize] as f64 / 1000.0
}

fn main() {
    let rows: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(20_000);
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "SvrStep's row alone, {rows} rows each, warm, per row in us; load average {}",
        load.split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    );
    println!(
        "{:<18} {:>7} {:>7} {:>7} {:>7} {:>10}",
        "support vectors", "p50", "p99", "p99.9", "max", "ns/vector"
    );
    for s in [500, 1_700, 5_000] {
        let mut p = SvrParams::from_attrs(&svr(s, &mut rng)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(p.support_vectors(), s);
        let xs: Vec<[f32; FEATURES]> = (0..rows)
            .map(|_| std::array::from_fn(|_| 2.0 * rng.unit()))
            .collect();
        let mut sum = 0.0f32;
        for x in xs.iter().take(rows / 10) {
            sum += p.predict(x); // warm-up
        }
        let mut ns = Vec::with_capacity(rows);
        for x in &xs {
            let t = Instant::now();
            sum += p.predict(black_box(x));
            ns.push(t.elapsed().as_nanos() as u64);
        }
        black_box(sum);
        ns.sort_unstable();
        let mean = ns.iter().sum::<u64>() as f64 / ns.len() as f64;
        println!(
            "{:<18} {:>7.2} {:>7.2} {:>7.2} {:>7.2} {:>10.2}",
            s,
            quantile(&ns, 0.5),
            quantile(&ns, 0.99),
            quantile(&ns, 0.999),
            quantile(&ns, 1.0),
            mean / s as f64,
        );
    }
}
