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

use std::hint::black_box;
use std::time::Instant;

use haptics_fused_ops::{RowModel, SvrParams};

mod common;
use common::{load_average, quantile, Map, Rng};

const FEATURES: usize = 6;

/// An RBF SVR with `s` support vectors over standardised features.
fn svr(s: usize, rng: &mut Rng) -> Map {
    let mut m = Map::default();
    m.floats.insert("feature_mean", vec![0.0; FEATURES]);
    m.floats.insert("feature_scale", vec![1.0; FEATURES]);
    m.floats.insert(
        "support_vectors",
        (0..s * FEATURES).map(|_| 2.0 * rng.unit()).collect(),
    );
    m.floats
        .insert("coefficients", (0..s).map(|_| 10.0 * rng.unit()).collect());
    m.floats.insert("gamma", vec![1.0 / FEATURES as f32]);
    m.floats.insert("intercept", vec![0.5]);
    m
}

fn main() {
    let rows: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(20_000);
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    println!(
        "SvrStep's row alone, {rows} rows each, warm, per row in us; load average {}",
        load_average()
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
