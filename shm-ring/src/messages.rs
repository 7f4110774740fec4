//! The four message types that cross the segment, and their word encodings.
//!
//! Field lists are fingerprinted (`Message::LAYOUT_ID`) into the segment header: change a
//! field here and bump the description string, and older peers are refused at attach time.

use crate::fixed_str::{FixedStr, FIXED_STR_WORDS};
use crate::message::{layout_id, DecodeError, Message};

/// Most feature values one step can carry (the thesis's table has nine).
pub const MAX_FEATURES: usize = 16;

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

/// The full state of one loop step, loop to server, for live plots and statistics: the same
/// columns as a recording row (`docs/recording-format.md`), plus the run id.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[allow(missing_docs)]
pub struct TelemetryRow {
    pub run_id: u32,
    pub step: u64,
    pub timestamp: u32,
    pub time: f64,
    pub dt: f64,
    pub f_ref: f64,
    pub rtob_force: f64,
    pub dob_force: f64,
    pub counts: i32,
    pub position_x: f64,
    pub velocity: f64,
    pub acceleration: f64,
    pub i_a_ref: f64,
    pub i_motor: f64,
    pub analog_out_motor: u16,
    pub phase: u8,
    pub f_true: f64,
    pub f_pred: f64,
    pub fallback: bool,
    pub cycle_no: u32,
    pub f_previous_x: f64,
    pub f_previous_v: f64,
    pub f_previous_a: f64,
    pub deformation: f64,
    pub area_fx: f64,
}

impl TelemetryRow {
    const FLOATS: usize = 17;

    fn floats(&self) -> [f64; Self::FLOATS] {
        [
            self.time,
            self.dt,
            self.f_ref,
            self.rtob_force,
            self.dob_force,
            self.position_x,
            self.velocity,
            self.acceleration,
            self.i_a_ref,
            self.i_motor,
            self.f_true,
            self.f_pred,
            self.f_previous_x,
            self.f_previous_v,
            self.f_previous_a,
            self.deformation,
            self.area_fx,
        ]
    }
}

impl Message for TelemetryRow {
    const WORDS: usize = 4 + Self::FLOATS;
    const LAYOUT_ID: u64 = layout_id(
        "TelemetryRow v1: run_id u64, step u64, timestamp u32|counts i32, \
         analog_out_motor u16|phase u8<<16|fallback u8<<24|cycle_no u32<<32, time, dt, f_ref, \
         rtob_force, dob_force, position_x, velocity, acceleration, i_a_ref, i_motor, f_true, \
         f_pred, f_previous_x, f_previous_v, f_previous_a, deformation, area_fx (f64)",
    );

    fn encode(&self, out: &mut [u64]) {
        out[0] = self.run_id as u64;
        out[1] = self.step;
        out[2] = self.timestamp as u64 | (self.counts as u32 as u64) << 32;
        out[3] = self.analog_out_motor as u64
            | (self.phase as u64) << 16
            | (self.fallback as u64) << 24
            | (self.cycle_no as u64) << 32;
        for (word, value) in out[4..4 + Self::FLOATS].iter_mut().zip(self.floats()) {
            *word = value.to_bits();
        }
    }

    fn decode(w: &[u64]) -> Result<Self, DecodeError> {
        let fallback = (w[3] >> 24) & 0xff;
        if fallback > 1 {
            return Err(DecodeError::InvalidField {
                field: "TelemetryRow.fallback",
                value: fallback,
            });
        }
        let f = |i: usize| f64::from_bits(w[4 + i]);
        Ok(TelemetryRow {
            run_id: w[0] as u32,
            step: w[1],
            timestamp: w[2] as u32,
            counts: (w[2] >> 32) as u32 as i32,
            analog_out_motor: w[3] as u16,
            phase: (w[3] >> 16) as u8,
            fallback: fallback == 1,
            cycle_no: (w[3] >> 32) as u32,
            time: f(0),
            dt: f(1),
            f_ref: f(2),
            rtob_force: f(3),
            dob_force: f(4),
            position_x: f(5),
            velocity: f(6),
            acceleration: f(7),
            i_a_ref: f(8),
            i_motor: f(9),
            f_true: f(10),
            f_pred: f(11),
            f_previous_x: f(12),
            f_previous_v: f(13),
            f_previous_a: f(14),
            deformation: f(15),
            area_fx: f(16),
        })
    }
}

/// What a command asks the loop to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum CommandKind {
    /// Start the experiment named in `name` with `values` as its arguments.
    StartExperiment = 1,
    /// Stop the running experiment (the loop ramps down safely).
    StopExperiment = 2,
    /// Set the loop parameter named in `name` to `values[0]`.
    SetParameter = 3,
}

impl CommandKind {
    fn from_u64(v: u64) -> Option<Self> {
        match v {
            1 => Some(CommandKind::StartExperiment),
            2 => Some(CommandKind::StopExperiment),
            3 => Some(CommandKind::SetParameter),
            _ => None,
        }
    }
}

/// Values a command carries.
pub const COMMAND_VALUES: usize = 4;

/// A small fixed command, server to loop (the mailbox). The loop validates it like any other
/// outside input: names it does not know and values out of range are refused, not applied.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    /// Server-chosen id, so an acknowledgement or a log line can name the command.
    pub id: u64,
    pub kind: CommandKind,
    /// Experiment name (`StartExperiment`) or parameter name (`SetParameter`).
    pub name: FixedStr,
    pub values: [f64; COMMAND_VALUES],
}

impl Message for Command {
    const WORDS: usize = 2 + FIXED_STR_WORDS + COMMAND_VALUES;
    const LAYOUT_ID: u64 = layout_id(
        "Command v1: id u64, kind u64 (1 start, 2 stop, 3 set), name [u8; 32], values [f64; 4]",
    );

    fn encode(&self, out: &mut [u64]) {
        out[0] = self.id;
        out[1] = self.kind as u64;
        out[2..2 + FIXED_STR_WORDS].copy_from_slice(&self.name.to_words());
        for (word, value) in out[2 + FIXED_STR_WORDS..].iter_mut().zip(&self.values) {
            *word = value.to_bits();
        }
    }

    fn decode(w: &[u64]) -> Result<Self, DecodeError> {
        let kind = CommandKind::from_u64(w[1]).ok_or(DecodeError::InvalidField {
            field: "Command.kind",
            value: w[1],
        })?;
        let name =
            FixedStr::from_words(&w[2..2 + FIXED_STR_WORDS]).ok_or(DecodeError::InvalidField {
                field: "Command.name",
                value: w[2],
            })?;
        let mut values = [0.0; COMMAND_VALUES];
        for (value, word) in values.iter_mut().zip(&w[2 + FIXED_STR_WORDS..Self::WORDS]) {
            *value = f64::from_bits(*word);
        }
        Ok(Command {
            id: w[0],
            kind,
            name,
            values,
        })
    }
}
