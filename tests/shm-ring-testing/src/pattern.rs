//! Deterministic message contents for the multi-process tests, the peer tool and the
//! benchmark: every field of message `seq` is a pure function of `seq`, so a receiver can
//! check a slot completely (a torn, stale, reordered or duplicated slot fails the check).

use haptics_proto::{FeatureMsg, ForceMsg, MAX_FEATURES};

/// SplitMix64: a cheap, well-mixed 64-bit hash.
pub fn mix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

fn unit(x: u64) -> f64 {
    (x >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// The feature message number `seq` (15 pseudo-random values plus a checksum in the last).
pub fn feature(seq: u64) -> FeatureMsg {
    let mut values = [0.0; MAX_FEATURES];
    let mut sum: u64 = seq;
    for (i, v) in values[..MAX_FEATURES - 1].iter_mut().enumerate() {
        *v = unit(mix(seq.wrapping_mul(31).wrapping_add(i as u64))) * 2.0 - 1.0;
        sum = sum.rotate_left(7) ^ v.to_bits();
    }
    values[MAX_FEATURES - 1] = f64::from_bits(mix(sum) >> 12 | 0x3ff0_0000_0000_0000);
    FeatureMsg {
        seq,
        timestamp_ns: seq.wrapping_mul(1_000_000),
        run_id: (seq >> 20) as u32,
        flags: (seq & 1023 == 0) as u32,
        len: MAX_FEATURES as u8,
        values,
    }
}

/// Checks that `msg` is exactly `feature(expected_seq)`.
pub fn check_feature(msg: &FeatureMsg, expected_seq: u64) -> Result<(), String> {
    let want = feature(expected_seq);
    if msg.seq != expected_seq {
        return Err(format!(
            "feature seq {} where {expected_seq} was expected",
            msg.seq
        ));
    }
    let same_bits = msg
        .values
        .iter()
        .zip(&want.values)
        .all(|(a, b)| a.to_bits() == b.to_bits());
    if !same_bits
        || msg.timestamp_ns != want.timestamp_ns
        || msg.run_id != want.run_id
        || msg.flags != want.flags
        || msg.len != want.len
    {
        return Err(format!(
            "feature {expected_seq} is torn or corrupt: {msg:?}"
        ));
    }
    Ok(())
}

/// The force that answers feature `seq` (the echo server's "model").
pub fn force(seq: u64) -> ForceMsg {
    let h = mix(seq ^ 0x5eed);
    ForceMsg {
        seq,
        force: unit(h) * 20.0,
        model_id: (h >> 40) as u32,
        flags: 0,
        inference_ns: mix(h) >> 24,
    }
}

/// Checks that `msg` is exactly `force(expected_seq)`.
pub fn check_force(msg: &ForceMsg, expected_seq: u64) -> Result<(), String> {
    let want = force(expected_seq);
    if msg.seq != expected_seq {
        return Err(format!(
            "force seq {} where {expected_seq} was expected",
            msg.seq
        ));
    }
    if msg.force.to_bits() != want.force.to_bits()
        || msg.model_id != want.model_id
        || msg.inference_ns != want.inference_ns
        || msg.flags != 0
    {
        return Err(format!("force {expected_seq} is torn or corrupt: {msg:?}"));
    }
    Ok(())
}
