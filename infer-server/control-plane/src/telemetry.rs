//! Telemetry buckets, their decimation (min/max merge, so a force spike is never hidden) and the
//! binary WebSocket frame of `docs/web-protocol.md`.
use std::sync::Arc;

/// Series, in the order of the web protocol and of `TelemetrySample.min/max`, and the index of
/// each in `Bucket::min/max/last`: haptics-proto's.
pub use haptics_proto::series::{self, N_SERIES, SERIES};

/// `steps` consecutive loop steps starting at `first_step`: the minimum, maximum and last value
/// of every series. A single step is a bucket with min == max == last.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bucket {
    pub first_step: u64,
    /// Device time of the first step, in seconds (unwrapped).
    pub time_s: f64,
    pub steps: u32,
    /// Steps of the bucket that used the fallback model.
    pub fallbacks: u32,
    pub min: [f64; N_SERIES],
    pub max: [f64; N_SERIES],
    pub last: [f64; N_SERIES],
}

/// What a backend publishes: consecutive buckets in step order, shared by every subscriber.
pub type TelemetryBatch = Arc<[Bucket]>;

/// The broadcast a backend publishes its telemetry on: `publish` never blocks and never fails
/// (no subscriber, or a slow one, is not the publisher's problem).
#[derive(Debug, Clone)]
pub struct TelemetryHub {
    sender: tokio::sync::broadcast::Sender<TelemetryBatch>,
}

impl TelemetryHub {
    /// `capacity` batches are kept for slow subscribers (1024 is plenty at one batch per 2 ms).
    pub fn new(capacity: usize) -> Self {
        Self {
            sender: tokio::sync::broadcast::channel(capacity.max(1)).0,
        }
    }

    pub fn publish(&self, buckets: Vec<Bucket>) {
        if !buckets.is_empty() {
            let _ = self.sender.send(TelemetryBatch::from(buckets));
        }
    }

    /// For `Backend::subscribe_telemetry`.
    pub fn subscribe(&self) -> tokio::sync::broadcast::Receiver<TelemetryBatch> {
        self.sender.subscribe()
    }

    pub fn subscribers(&self) -> usize {
        self.sender.receiver_count()
    }
}

impl Bucket {
    /// One loop step. NaN values (F_pred without a model, F_true on a real board) are allowed.
    pub fn step(step: u64, time_s: f64, values: [f64; N_SERIES], fallback: bool) -> Self {
        Self {
            first_step: step,
            time_s,
            steps: 1,
            fallbacks: u32::from(fallback),
            min: values,
            max: values,
            last: values,
        }
    }

    /// The step after the bucket's last step.
    pub fn end_step(&self) -> u64 {
        self.first_step + u64::from(self.steps)
    }

    /// Extends this bucket with the one that follows it. `f64::min/max` ignore a NaN against a
    /// number, so a series that is NaN on some steps keeps the range of the others.
    pub fn merge(&mut self, next: &Bucket) {
        for s in 0..N_SERIES {
            self.min[s] = self.min[s].min(next.min[s]);
            self.max[s] = self.max[s].max(next.max[s]);
        }
        self.last = next.last;
        self.steps = self.steps.saturating_add(next.steps);
        self.fallbacks = self.fallbacks.saturating_add(next.fallbacks);
    }
}

/// Merges consecutive buckets until each covers at least `target` steps. A bucket never spans a
/// gap or a restart (the next bucket does not start where the previous one ended): the partial
/// one is emitted as it is.
#[derive(Debug)]
pub struct Decimator {
    target: u32,
    pending: Option<Bucket>,
}

impl Decimator {
    pub fn new(target: u32) -> Self {
        Self {
            target: target.max(1),
            pending: None,
        }
    }

    pub fn set_target(&mut self, target: u32) {
        self.target = target.max(1);
    }

    pub fn push(&mut self, bucket: &Bucket, out: &mut Vec<Bucket>) {
        match &mut self.pending {
            Some(p) if p.end_step() == bucket.first_step => p.merge(bucket),
            Some(p) => {
                out.push(*p);
                self.pending = Some(*bucket);
            }
            None => self.pending = Some(*bucket),
        }
        if let Some(p) = self.pending {
            if p.steps >= self.target {
                out.push(p);
                self.pending = None;
            }
        }
    }

    /// Emits the partial bucket, if any.
    pub fn flush(&mut self, out: &mut Vec<Bucket>) {
        if let Some(p) = self.pending.take() {
            out.push(p);
        }
    }
}

pub const FRAME_MAGIC: &[u8; 4] = b"HPT1";
pub const FRAME_VERSION: u16 = 1;
pub const FRAME_HEADER_BYTES: usize = 16;

/// Encodes the binary WebSocket frame (little-endian): header, then `t` of every bucket, then
/// min and max of every series of every bucket, as f32.
pub fn encode_frame(buckets: &[Bucket], out: &mut Vec<u8>) {
    out.clear();
    out.reserve(FRAME_HEADER_BYTES + buckets.len() * (8 + N_SERIES * 8));
    out.extend_from_slice(FRAME_MAGIC);
    out.extend_from_slice(&FRAME_VERSION.to_le_bytes());
    out.extend_from_slice(&(N_SERIES as u16).to_le_bytes());
    out.extend_from_slice(&(buckets.len() as u32).to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    for b in buckets {
        out.extend_from_slice(&b.time_s.to_le_bytes());
    }
    for b in buckets {
        for s in 0..N_SERIES {
            out.extend_from_slice(&(b.min[s] as f32).to_le_bytes());
            out.extend_from_slice(&(b.max[s] as f32).to_le_bytes());
        }
    }
}

/// A decoded frame: `t[b]`, and `min_max[b][s] = (min, max)`.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub n_series: usize,
    pub t: Vec<f64>,
    pub min_max: Vec<Vec<(f32, f32)>>,
}

/// Decodes a frame, for clients and tests; checks every length and the magic.
pub fn decode_frame(bytes: &[u8]) -> Result<Frame, String> {
    if bytes.len() < FRAME_HEADER_BYTES {
        return Err(format!(
            "frame of {} bytes is shorter than its header",
            bytes.len()
        ));
    }
    if &bytes[0..4] != FRAME_MAGIC {
        return Err("bad magic".into());
    }
    let u16_at = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]);
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    let version = u16_at(4);
    if version != FRAME_VERSION {
        return Err(format!("unknown frame version {version}"));
    }
    let n_series = usize::from(u16_at(6));
    let n_buckets = u32_at(8) as usize;
    let expected = FRAME_HEADER_BYTES + n_buckets * 8 + n_buckets * n_series * 8;
    if bytes.len() != expected {
        return Err(format!(
            "frame of {} bytes, expected {expected} for {n_buckets} buckets of {n_series} series",
            bytes.len()
        ));
    }
    let f64_at = |o: usize| f64::from_le_bytes(bytes[o..o + 8].try_into().unwrap());
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    let t = (0..n_buckets)
        .map(|b| f64_at(FRAME_HEADER_BYTES + 8 * b))
        .collect();
    let base = FRAME_HEADER_BYTES + 8 * n_buckets;
    let min_max = (0..n_buckets)
        .map(|b| {
            (0..n_series)
                .map(|s| {
                    let o = base + (b * n_series + s) * 8;
                    (f32_at(o), f32_at(o + 4))
                })
                .collect()
        })
        .collect();
    Ok(Frame {
        n_series,
        t,
        min_max,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn steps(from: u64, n: u64, spike_at: Option<u64>) -> Vec<Bucket> {
        (from..from + n)
            .map(|i| {
                let mut v = [i as f64; N_SERIES];
                v[series::F_PRED] = f64::NAN;
                if Some(i) == spike_at {
                    v[series::RTOB_FORCE] = 1000.0;
                }
                Bucket::step(i, i as f64 * 1e-4, v, i % 2 == 0)
            })
            .collect()
    }

    /// What `d` emits for `buckets` pushed in order (its pending bucket not flushed).
    fn pushed<'a>(d: &mut Decimator, buckets: impl IntoIterator<Item = &'a Bucket>) -> Vec<Bucket> {
        let mut out = Vec::new();
        for b in buckets {
            d.push(b, &mut out);
        }
        out
    }

    #[test]
    fn decimation_keeps_min_max_and_counts() {
        let mut d = Decimator::new(10);
        let mut out = pushed(&mut d, &steps(100, 35, Some(117)));
        assert_eq!(out.len(), 3);
        d.flush(&mut out);
        assert_eq!(out.len(), 4);
        assert_eq!(out[1].first_step, 110);
        assert_eq!(out[1].steps, 10);
        assert_eq!(out[1].time_s, 110.0 * 1e-4);
        assert_eq!(out[1].min[series::F_REF], 110.0);
        assert_eq!(out[1].max[series::F_REF], 119.0);
        assert_eq!(out[1].max[series::RTOB_FORCE], 1000.0, "the spike survives");
        assert_eq!(out[0].max[series::RTOB_FORCE], 109.0);
        assert!(out[1].min[series::F_PRED].is_nan());
        assert_eq!(out[1].last[series::F_REF], 119.0);
        assert_eq!(out[1].fallbacks, 5);
        assert_eq!(out[3].steps, 5);
    }

    #[test]
    fn nan_is_ignored_against_numbers() {
        let mut a = Bucket::step(0, 0.0, [f64::NAN; N_SERIES], false);
        a.merge(&Bucket::step(1, 0.1, [2.0; N_SERIES], false));
        assert_eq!(a.min, [2.0; N_SERIES]);
        assert_eq!(a.max, [2.0; N_SERIES]);
    }

    #[test]
    fn a_bucket_never_spans_a_gap_or_restart() {
        let mut d = Decimator::new(10);
        let out = pushed(&mut d, steps(0, 5, None).iter().chain(&steps(0, 12, None)));
        assert_eq!(out.len(), 2);
        assert_eq!((out[0].first_step, out[0].steps), (0, 5));
        assert_eq!((out[1].first_step, out[1].steps), (0, 10));
    }

    #[test]
    fn frame_round_trip_and_layout() {
        let buckets = pushed(&mut Decimator::new(4), &steps(0, 8, Some(5)));
        let mut bytes = Vec::new();
        encode_frame(&buckets, &mut bytes);
        assert_eq!(bytes.len(), 16 + 2 * 8 + 2 * N_SERIES * 8);
        assert_eq!(&bytes[..4], b"HPT1");
        assert_eq!(u16::from_le_bytes([bytes[6], bytes[7]]), N_SERIES as u16);
        let f = decode_frame(&bytes).unwrap();
        assert_eq!(f.t, vec![0.0, 4.0 * 1e-4]);
        assert_eq!(f.min_max[1][series::RTOB_FORCE], (4.0, 1000.0));
        assert_eq!(f.min_max[0][series::F_REF], (0.0, 3.0));
        assert!(f.min_max[0][series::F_PRED].0.is_nan());
        assert!(decode_frame(&bytes[..bytes.len() - 1]).is_err());
    }
}
