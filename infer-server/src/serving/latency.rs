//! A lock-free latency histogram: the inference thread records, anyone reads, nobody waits.
//!
//! HDR-style log-linear buckets (128 sub-buckets per power of two above 256 ns, exact below), so
//! any recorded value is within 1/128 (0.8 %) of its bucket's bounds, from 1 ns to ~68 s; larger
//! values land in the last bucket and still set `max` exactly. Each bucket is an `AtomicU64`.
//!
//! There is exactly one writer ([`LatencyRecorder`] is not `Clone`), so recording is a relaxed
//! load plus a relaxed store per counter (no read-modify-write, no locked instruction) and never
//! blocks. Readers ([`LatencyReader`]) copy the buckets whenever they like; a snapshot taken
//! while the writer runs may miss the steps recorded during the copy, never more. Readers that
//! want an interval (e.g. "the last second") subtract two snapshots instead of resetting, which
//! would need the writer's cooperation.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

const SUB_BITS: u32 = 7; // 128 sub-buckets per power of two
const SUB: u64 = 1 << SUB_BITS;
const MAX_EXP: u32 = 36; // values up to 2^36 ns (~68.7 s) are resolved
/// Number of buckets: exact values 0..256, then 128 per power of two from 2^8 to 2^MAX_EXP.
pub const BUCKETS: usize = (2 * SUB + (MAX_EXP as u64 - SUB_BITS as u64 - 1) * SUB) as usize;

#[inline]
fn bucket_of(v: u64) -> usize {
    if v < 2 * SUB {
        return v as usize;
    }
    let e = 63 - v.leading_zeros(); // floor(log2 v) >= 8
    if e >= MAX_EXP {
        return BUCKETS - 1;
    }
    let shift = e - SUB_BITS;
    ((e - SUB_BITS) as u64 * SUB + (v >> shift)) as usize
}

/// Inclusive lower and exclusive upper bound of bucket `i`.
fn bucket_bounds(i: usize) -> (u64, u64) {
    let i = i as u64;
    if i < 2 * SUB {
        return (i, i + 1);
    }
    let k = i / SUB; // >= 2
    let e = k + SUB_BITS as u64 - 1;
    let m = i % SUB + SUB;
    let shift = e - SUB_BITS as u64;
    (m << shift, (m + 1) << shift)
}

struct Shared {
    buckets: Box<[AtomicU64]>,
    count: AtomicU64,
    sum: AtomicU64,
    max: AtomicU64,
    min: AtomicU64,
}

/// The writing half. Exactly one exists per histogram.
pub struct LatencyRecorder {
    shared: Arc<Shared>,
}

/// A reading handle; clone it freely.
#[derive(Clone)]
pub struct LatencyReader {
    shared: Arc<Shared>,
}

/// Creates an empty histogram. Allocates; do it before the loop starts.
pub fn histogram() -> (LatencyRecorder, LatencyReader) {
    let shared = Arc::new(Shared {
        buckets: (0..BUCKETS).map(|_| AtomicU64::new(0)).collect(),
        count: AtomicU64::new(0),
        sum: AtomicU64::new(0),
        max: AtomicU64::new(0),
        min: AtomicU64::new(u64::MAX),
    });
    (
        LatencyRecorder {
            shared: Arc::clone(&shared),
        },
        LatencyReader { shared },
    )
}

#[inline(always)]
fn bump(a: &AtomicU64, by: u64) {
    // Single writer: a plain load + store is exact and cheaper than fetch_add.
    a.store(
        a.load(Ordering::Relaxed).wrapping_add(by),
        Ordering::Relaxed,
    );
}

impl LatencyRecorder {
    /// Records one latency in nanoseconds. Real-time safe: no allocation, no lock, wait-free.
    #[inline]
    pub fn record(&mut self, nanos: u64) {
        let s = &*self.shared;
        bump(&s.buckets[bucket_of(nanos)], 1);
        bump(&s.sum, nanos);
        if nanos > s.max.load(Ordering::Relaxed) {
            s.max.store(nanos, Ordering::Relaxed);
        }
        if nanos < s.min.load(Ordering::Relaxed) {
            s.min.store(nanos, Ordering::Relaxed);
        }
        // Release: a reader that sees this count also sees the bucket it counts (best effort:
        // the buckets are read one by one anyway).
        s.count
            .store(s.count.load(Ordering::Relaxed) + 1, Ordering::Release);
    }

    pub fn reader(&self) -> LatencyReader {
        LatencyReader {
            shared: Arc::clone(&self.shared),
        }
    }
}

impl LatencyReader {
    /// Copies the histogram. Allocates (the bucket array); never blocks the writer.
    pub fn snapshot(&self) -> LatencySnapshot {
        let s = &*self.shared;
        let count = s.count.load(Ordering::Acquire);
        let buckets: Vec<u64> = s
            .buckets
            .iter()
            .map(|b| b.load(Ordering::Relaxed))
            .collect();
        let min = s.min.load(Ordering::Relaxed);
        LatencySnapshot {
            total: buckets.iter().sum(),
            count,
            sum: s.sum.load(Ordering::Relaxed),
            max: s.max.load(Ordering::Relaxed),
            min: if min == u64::MAX { 0 } else { min },
            buckets,
        }
    }
}

/// A copy of a histogram at one moment.
#[derive(Debug, Clone, PartialEq)]
pub struct LatencySnapshot {
    buckets: Vec<u64>,
    /// Sum of the bucket counts (what percentiles are computed over).
    total: u64,
    /// Steps recorded when the snapshot started (may be a little behind `total`).
    pub count: u64,
    pub sum: u64,
    pub max: u64,
    pub min: u64,
}

impl LatencySnapshot {
    /// Number of samples the percentiles are computed over.
    pub fn samples(&self) -> u64 {
        self.total
    }

    pub fn mean(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum as f64 / self.count as f64
        }
    }

    /// The value at quantile `q` (0..=1): the upper bound of the bucket holding it, capped at the
    /// recorded max, so the figure never flatters (HDR's "highest equivalent value").
    pub fn quantile(&self, q: f64) -> u64 {
        if self.total == 0 {
            return 0;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.total as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (i, &c) in self.buckets.iter().enumerate() {
            seen += c;
            if seen >= rank {
                return (bucket_bounds(i).1 - 1).min(self.max);
            }
        }
        self.max
    }

    /// Samples strictly above `nanos` (exact at bucket boundaries, else within one bucket).
    pub fn count_above(&self, nanos: u64) -> u64 {
        self.buckets
            .iter()
            .enumerate()
            .filter(|(i, _)| bucket_bounds(*i).0 > nanos)
            .map(|(_, c)| c)
            .sum()
    }

    /// `self - earlier`: the samples recorded between two snapshots of the same histogram (min
    /// and max are those of the later snapshot, i.e. since the start).
    pub fn since(&self, earlier: &LatencySnapshot) -> LatencySnapshot {
        let buckets: Vec<u64> = self
            .buckets
            .iter()
            .zip(&earlier.buckets)
            .map(|(a, b)| a.saturating_sub(*b))
            .collect();
        LatencySnapshot {
            total: buckets.iter().sum(),
            buckets,
            count: self.count.saturating_sub(earlier.count),
            sum: self.sum.saturating_sub(earlier.sum),
            max: self.max,
            min: self.min,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_are_contiguous_and_tight() {
        let mut prev_hi = 0;
        for i in 0..BUCKETS {
            let (lo, hi) = bucket_bounds(i);
            assert_eq!(
                lo,
                prev_hi,
                "bucket {i} does not start where {} ended",
                i.max(1) - 1
            );
            assert!(hi > lo);
            // relative width <= 1/128 above the exact range
            if lo >= 256 {
                assert!((hi - lo) * 128 <= lo, "bucket {i} [{lo},{hi}) too wide");
            }
            prev_hi = hi;
        }
        for v in [0u64, 1, 255, 256, 257, 1000, 12_345, 1 << 20, (1 << 36) - 1] {
            let (lo, hi) = bucket_bounds(bucket_of(v));
            assert!(lo <= v && v < hi, "{v} not in its bucket [{lo},{hi})");
        }
        assert_eq!(bucket_of(u64::MAX), BUCKETS - 1);
    }

    #[test]
    fn quantiles_of_a_known_distribution() {
        let (mut w, r) = histogram();
        // 1..=10000 ns, once each: p50 = 5000, p99 = 9900, max = 10000.
        for v in 1..=10_000u64 {
            w.record(v);
        }
        let s = r.snapshot();
        assert_eq!(s.samples(), 10_000);
        assert_eq!(s.max, 10_000);
        assert_eq!(s.min, 1);
        for (q, exact) in [(0.5, 5000u64), (0.99, 9900), (0.999, 9990), (1.0, 10_000)] {
            let got = s.quantile(q);
            assert!(
                got >= exact && (got - exact) as f64 <= exact as f64 / 128.0 + 1.0,
                "q{q}: got {got}, exact {exact}"
            );
        }
        assert!((s.mean() - 5000.5).abs() < 1e-9);
        assert_eq!(s.count_above(10_000), 0);
        // 9985..=10000 share buckets of width 64 near 10k; count_above is bucket-granular.
        let above = s.count_above(9_000);
        assert!((900..=1000).contains(&above), "{above}");
    }

    #[test]
    fn interval_by_subtraction() {
        let (mut w, r) = histogram();
        for _ in 0..100 {
            w.record(1_000);
        }
        let a = r.snapshot();
        for _ in 0..50 {
            w.record(50_000);
        }
        let d = r.snapshot().since(&a);
        assert_eq!(d.samples(), 50);
        assert_eq!(d.count, 50);
        assert!(d.quantile(0.01) >= 50_000);
    }

    #[test]
    fn readers_see_progress_while_the_writer_runs() {
        let (mut w, r) = histogram();
        let reader = std::thread::spawn(move || {
            let mut last = 0;
            for _ in 0..1000 {
                let s = r.snapshot();
                assert!(s.count >= last, "count went backwards");
                last = s.count;
                std::thread::yield_now();
            }
        });
        for i in 0..200_000u64 {
            w.record(i % 5000);
        }
        reader.join().unwrap();
        assert_eq!(w.reader().snapshot().samples(), 200_000);
    }
}
