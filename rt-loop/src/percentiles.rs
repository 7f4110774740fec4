//! Percentiles of the loop's HDR histograms (all recorded in nanoseconds), in the three shapes
//! their readers want: the status block's [`Quantiles`] (ns), the run summary's round trip
//! ([`Percentiles`], µs) and the realtime clock's jitter ([`PercentilesUs`], µs). One module so
//! that the clock, the shared-memory client, the side channel and the run all read a histogram
//! the same way without importing one another.
//!
//! No allocation: reading a percentile walks the histogram's preallocated buckets (a few
//! microseconds), so the status figures may be taken on the loop thread about every 100 ms,
//! never per step.

use haptics_proto::Quantiles;
use hdrhistogram::Histogram;
use serde::Serialize;

fn us(ns: u64) -> f64 {
    ns as f64 / 1e3
}

/// The status block's percentiles, ns (all 0 for an empty histogram).
pub fn quantiles(h: &Histogram<u64>) -> Quantiles {
    if h.is_empty() {
        return Quantiles::default();
    }
    Quantiles {
        p50_ns: h.value_at_quantile(0.5),
        p99_ns: h.value_at_quantile(0.99),
        p999_ns: h.value_at_quantile(0.999),
        max_ns: h.max(),
        count: h.len(),
    }
}

/// Latency percentiles, µs: the run summary's `round_trip_us` (its JSON keys `p50`, `p99`,
/// `p999`, `max`, `count`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Percentiles {
    pub p50: f64,
    pub p99: f64,
    pub p999: f64,
    pub max: f64,
    pub count: u64,
}

impl Percentiles {
    /// The histogram's percentiles; `None` when it holds nothing.
    pub fn of(h: &Histogram<u64>) -> Option<Percentiles> {
        (!h.is_empty()).then(|| Percentiles {
            p50: us(h.value_at_quantile(0.5)),
            p99: us(h.value_at_quantile(0.99)),
            p999: us(h.value_at_quantile(0.999)),
            max: us(h.max()),
            count: h.len(),
        })
    }
}

/// Percentiles, µs, with the keys of the realtime clock's statistics in the run summary
/// (`p50_us`, `p99_us`, `p999_us`, `max_us`, `samples`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PercentilesUs {
    pub p50_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub max_us: f64,
    pub samples: u64,
}

impl PercentilesUs {
    pub fn of(h: &Histogram<u64>) -> PercentilesUs {
        PercentilesUs {
            p50_us: us(h.value_at_quantile(0.5)),
            p99_us: us(h.value_at_quantile(0.99)),
            p999_us: us(h.value_at_quantile(0.999)),
            max_us: us(h.max()),
            samples: h.len(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_three_shapes_agree_and_an_empty_histogram_is_zero_or_none() {
        let mut h = Histogram::<u64>::new_with_bounds(1, 60_000_000_000, 3).unwrap();
        assert_eq!(quantiles(&h), Quantiles::default());
        assert_eq!(Percentiles::of(&h), None);
        for v in 1..=1000u64 {
            h.record(v * 1000).unwrap();
        }
        let q = quantiles(&h);
        let p = Percentiles::of(&h).unwrap();
        let u = PercentilesUs::of(&h);
        assert_eq!((q.count, p.count, u.samples), (1000, 1000, 1000));
        assert!((p.p50 - 500.0).abs() < 1.0, "{p:?}");
        assert_eq!(p.p50, us(q.p50_ns));
        assert_eq!(u.p99_us, p.p99);
        assert_eq!(u.max_us, us(q.max_ns));
    }
}
