//! What the kernel-cost examples (`forest_cost`, `svr_cost`) share: attributes from maps, a
//! deterministic generator, a quantile of sorted timings and the machine's load average.
//! (`examples/common/` holds no `main.rs`, so Cargo does not take it for an example.)

use std::collections::HashMap;

use haptics_fused_ops::Attrs;

/// Attributes from maps (what the exporter would write).
#[derive(Default)]
pub struct Map {
    pub floats: HashMap<&'static str, Vec<f32>>,
    pub ints: HashMap<&'static str, Vec<i64>>,
}

impl Attrs for Map {
    fn float(&self, name: &str) -> Option<f32> {
        self.floats.get(name).and_then(|v| v.first().copied())
    }
    fn floats(&self, name: &str) -> Option<Vec<f32>> {
        self.floats.get(name).cloned()
    }
    fn ints(&self, name: &str) -> Option<Vec<i64>> {
        self.ints.get(name).cloned()
    }
    fn string(&self, _: &str) -> Option<String> {
        None
    }
}

/// A small deterministic generator (xorshift64*), so every run measures the same model.
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    /// Uniform in [-1, 1).
    pub fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 23) as f32 - 1.0
    }
}

/// The `q` quantile of `sorted` nanoseconds, in microseconds.
pub fn quantile(sorted: &[u64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize] as f64 / 1000.0
}

/// The 1, 5 and 15 minute load averages as the kernel prints them ("" off Linux).
pub fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .unwrap_or_default()
        .split_whitespace()
        .take(3)
        .collect::<Vec<_>>()
        .join(" ")
}
