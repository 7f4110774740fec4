//! The per-step request and answer between rt-loop and infer-server (the features and
//! forces channels), and their word encodings. The telemetry row and the commands, the other
//! two channels, are in `telemetry` and `command`.
//!
//! Field lists are fingerprinted (`Message::LAYOUT_ID`) into the segment header: change a
//! field here and bump the description string, and older peers are refused at attach time.

use shm_ring::{layout_id, DecodeError, Message};

use crate::features::MAX_FEATURES;

/// One step's features, loop to server.
///
/// Values are `f64`: the recordings, the feature extraction and the fallback model all work
/// in `f64`, so the ring carries exactly what was recorded; the server narrows to the model's
/// input type (usually `f32`). `values[..len]` follow the segment's feature schema order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeatureMsg {
    /// Loop step sequence number; the force that answers it carries the same number.
    pub seq: u64,
    /// Loop time of the step in nanoseconds (since the run started).
    pub timestamp_ns: u64,
    /// Identifies the run; a stateful model resets its state when this changes.
    pub run_id: u32,
    /// Bit set: [`FeatureMsg::RUN_START`] and future flags.
    pub flags: u32,
    /// Number of meaningful entries in `values` (at most [`MAX_FEATURES`]).
    pub len: u8,
    pub values: [f64; MAX_FEATURES],
}

impl FeatureMsg {
    /// First step of a run: a stateful model must reset its hidden state before this one.
    pub const RUN_START: u32 = 1;

    /// The meaningful feature values.
    pub fn features(&self) -> &[f64] {
        &self.values[..self.len as usize]
    }

    /// Whether this step starts a new run.
    pub fn is_run_start(&self) -> bool {
        self.flags & Self::RUN_START != 0
    }
}

impl Default for FeatureMsg {
    fn default() -> Self {
        FeatureMsg {
            seq: 0,
            timestamp_ns: 0,
            run_id: 0,
            flags: 0,
            len: 0,
            values: [0.0; MAX_FEATURES],
        }
    }
}

impl Message for FeatureMsg {
    const WORDS: usize = 4 + MAX_FEATURES;
    const LAYOUT_ID: u64 = layout_id(
        "FeatureMsg v1: seq u64, timestamp_ns u64, run_id u32|flags u32, len u64, values [f64; 16]",
    );

    fn encode(&self, out: &mut [u64]) {
        out[0] = self.seq;
        out[1] = self.timestamp_ns;
        out[2] = self.run_id as u64 | (self.flags as u64) << 32;
        out[3] = self.len as u64;
        for (word, value) in out[4..4 + MAX_FEATURES].iter_mut().zip(&self.values) {
            *word = value.to_bits();
        }
    }

    fn decode(w: &[u64]) -> Result<Self, DecodeError> {
        if w[3] > MAX_FEATURES as u64 {
            return Err(DecodeError::InvalidField {
                field: "FeatureMsg.len",
                value: w[3],
            });
        }
        let mut values = [0.0; MAX_FEATURES];
        for (value, word) in values.iter_mut().zip(&w[4..4 + MAX_FEATURES]) {
            *value = f64::from_bits(*word);
        }
        Ok(FeatureMsg {
            seq: w[0],
            timestamp_ns: w[1],
            run_id: w[2] as u32,
            flags: (w[2] >> 32) as u32,
            len: w[3] as u8,
            values,
        })
    }
}

/// The model's answer to one step, server to loop.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ForceMsg {
    /// The `FeatureMsg::seq` this answers.
    pub seq: u64,
    /// Predicted reaction force, newtons. The loop still checks it (finite, in range).
    pub force: f64,
    /// Which model produced it (the server's registry id).
    pub model_id: u32,
    /// Bit set, reserved for the server's status flags (0 today).
    pub flags: u32,
    /// Time the model took for this step, nanoseconds.
    pub inference_ns: u64,
}

impl Message for ForceMsg {
    const WORDS: usize = 4;
    const LAYOUT_ID: u64 =
        layout_id("ForceMsg v1: seq u64, force f64, model_id u32|flags u32, inference_ns u64");

    fn encode(&self, out: &mut [u64]) {
        out[0] = self.seq;
        out[1] = self.force.to_bits();
        out[2] = self.model_id as u64 | (self.flags as u64) << 32;
        out[3] = self.inference_ns;
    }

    fn decode(w: &[u64]) -> Result<Self, DecodeError> {
        Ok(ForceMsg {
            seq: w[0],
            force: f64::from_bits(w[1]),
            model_id: w[2] as u32,
            flags: (w[2] >> 32) as u32,
            inference_ns: w[3],
        })
    }
}
