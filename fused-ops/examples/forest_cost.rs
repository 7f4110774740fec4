//! What one row of `ai.haptics:ForestStep` costs, the kernel alone (no ONNX Runtime), warm and
//! with cold caches: does the forest's size explain the served call's tail (docs/
//! infer-server.md, "Every model family")?
//!
//! The forests are synthetic, of the served forests' shape (the walk's cost depends on the
//! depth, the node count and where the nodes lie, not on the fitted values): T complete trees
//! of depth D over 6 features (every walk D steps, 2^(D+1) - 1 nodes a tree), random splits
//! and thresholds, rows uniform over the thresholds' range. Two shapes:
//! - 100 trees of depth 9 (1,023 nodes each, 102,300 in all: `rf` at its default
//!   `max_depth` 9, like models/rf_six.onnx's ~100,800 nodes);
//! - 100 trees of depth 12 (8,191 nodes each, 819,100: a bound on scripts/bench-models.sh's
//!   `max_depth` 12 forests, ~700,000 nodes).
//!
//! Each row is timed alone (`Instant` around the call: ~20-40 ns of the figures are the clock);
//! "warm": rows one after the other; "cold": before each row 8 MiB are written, more than the
//! L1 and L2 caches hold (what a preemption by another process leaves behind); "cold 64 MiB"
//! evicts more (the L3, where it is smaller). Prints a table of p50/p99/p99.9/max per row and
//! the mean per node visited.
//!
//! Run: `cargo run --release -p haptics-fused-ops --example forest_cost [ROWS]` (default 20000).

use std::hint::black_box;
use std::time::Instant;

use haptics_fused_ops::ForestParams;

mod common;
use common::{load_average, quantile, Map, Rng};

const FEATURES: usize = 6;

/// `trees` complete trees of depth `depth`, nodes in sklearn's depth-first order.
fn forest(trees: usize, depth: u32, rng: &mut Rng) -> Map {
    let size = (1usize << (depth + 1)) - 1;
    let mut m = Map::default();
    let (mut left, mut right, mut feat, mut thr, mut val) =
        (vec![], vec![], vec![], vec![], vec![]);
    for _ in 0..trees {
        // depth-first: a node's index, then its left subtree, then its right subtree
        fn grow(d: u32, depth: u32, rng: &mut Rng, out: &mut [&mut Vec<f32>; 5]) -> usize {
            let me = out[0].len();
            for v in out.iter_mut() {
                v.push(0.0);
            }
            if d == depth {
                out[0][me] = -1.0;
                out[1][me] = -1.0;
                out[2][me] = -2.0;
                out[4][me] = rng.unit() * 10.0;
                return me;
            }
            out[2][me] = (rng.next() % FEATURES as u64) as f32;
            out[3][me] = rng.unit() * 0.9;
            let l = grow(d + 1, depth, rng, out);
            let r = grow(d + 1, depth, rng, out);
            out[0][me] = l as f32;
            out[1][me] = r as f32;
            me
        }
        let (mut l, mut r, mut f, mut t, mut v) = (vec![], vec![], vec![], vec![], vec![]);
        grow(0, depth, rng, &mut [&mut l, &mut r, &mut f, &mut t, &mut v]);
        assert_eq!(l.len(), size);
        left.extend(l.iter().map(|&x| x as i64));
        right.extend(r.iter().map(|&x| x as i64));
        feat.extend(f.iter().map(|&x| x as i64));
        thr.extend(t);
        val.extend(v);
    }
    m.ints.insert("n_features", vec![FEATURES as i64]);
    m.ints.insert("tree_sizes", vec![size as i64; trees]);
    m.ints.insert("children_left", left);
    m.ints.insert("children_right", right);
    m.ints.insert("split_features", feat);
    m.floats.insert("thresholds", thr);
    m.floats.insert("leaf_values", val);
    m
}

/// Writes one byte per cache line of `buf` (evicts what the caches held).
fn evict(buf: &mut [u8]) {
    for line in buf.chunks_mut(64) {
        line[0] = line[0].wrapping_add(1);
    }
    black_box(&buf[0]);
}

/// The process's anonymous memory in huge pages, KiB (Linux; 0 elsewhere).
fn huge_kib() -> u64 {
    std::fs::read_to_string("/proc/self/smaps_rollup")
        .unwrap_or_default()
        .lines()
        .find_map(|l| l.strip_prefix("AnonHugePages:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or(0)
}

fn main() {
    let rows: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(20_000);
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let mut small = vec![0u8; 8 << 20];
    let mut big = vec![0u8; 64 << 20];
    println!(
        "ForestStep's row alone, {rows} rows each, per row in us; load average {}",
        load_average()
    );
    println!(
        "{:<24} {:>9} {:>8} {:>12} {:>7} {:>7} {:>7} {:>7} {:>10}",
        "forest", "nodes", "MiB", "caches", "p50", "p99", "p99.9", "max", "ns/visit"
    );
    for (trees, depth) in [(100, 9), (100, 12)] {
        let mut p = ForestParams::from_attrs_checked(&forest(trees, depth, &mut rng))
            .unwrap_or_else(|e| panic!("{e}"));
        let xs: Vec<[f32; FEATURES]> = (0..rows)
            .map(|_| std::array::from_fn(|_| rng.unit()))
            .collect();
        let visits = (trees * depth as usize) as f64;
        println!(
            "  ({} MiB of this process in transparent huge pages: the nodes' block, huge.rs)",
            huge_kib() / 1024
        );
        for (label, buf) in [
            ("warm", None),
            ("cold 8 MiB", Some(&mut small)),
            ("cold 64 MiB", Some(&mut big)),
        ] {
            let mut ns = Vec::with_capacity(rows);
            let mut sum = 0.0f32;
            let mut buf = buf;
            for x in xs.iter().take(rows / 10) {
                sum += p.predict(x); // warm-up: the first touch of every page
            }
            for x in &xs {
                if let Some(b) = buf.as_deref_mut() {
                    evict(b);
                }
                let t = Instant::now();
                sum += p.predict(black_box(x));
                ns.push(t.elapsed().as_nanos() as u64);
            }
            black_box(sum);
            ns.sort_unstable();
            let mean = ns.iter().sum::<u64>() as f64 / ns.len() as f64;
            println!(
                "{:<24} {:>9} {:>8.2} {:>12} {:>7.2} {:>7.2} {:>7.2} {:>7.2} {:>10.2}",
                format!("{trees} trees, depth {depth}"),
                p.nodes(),
                p.bytes() as f64 / (1 << 20) as f64,
                label,
                quantile(&ns, 0.5),
                quantile(&ns, 0.99),
                quantile(&ns, 0.999),
                quantile(&ns, 1.0),
                mean / visits,
            );
        }
    }
}
